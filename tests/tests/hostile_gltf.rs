//! A corpus of hostile glTF files generated in code (issue 28, "Untrusted glTF"): every class of
//! malformed and adversarial input a converted library may hold, each imported as `treelod build`
//! does and checked for
//!
//! - no panic (every import and build runs under `catch_unwind`),
//! - no hang (each case runs on a thread of its own with a deadline; a FIFO is released if one
//!   blocks),
//! - no bomb (a counting allocator bounds the peak heap of the import, 64 MiB unless the input
//!   itself is larger),
//! - the documented error class (`InvalidData` exit 3, `Unsupported` 4, `Limit`, `MissingBuffer`,
//!   `Image`, …) with a message naming the input file and the glTF object,
//! - and, for the inputs that must import, a build whose container writes and verifies.
//!
//! One test per case, so a failure names its case. The documents start from the small valid tree
//! of `treelod_tests::gltf` and change one thing.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::json;
use tempfile::TempDir;
use treelod_build::import::Limit;
use treelod_build::scene::Scene;
use treelod_build::{BuildConfig, BuildError, ImportLimits, Placed};
use treelod_format::{Compression, Container, verify};
use treelod_tests::alloc::{CountingAllocator, counting, exclusive, peak_during};
use treelod_tests::gltf::{
    self, Gltf, LEAF_VERTICES, LeafGeometry, SPARSE_VERTEX, accessor, component, jpeg_declaring, leaf_geometry,
    leaf_png, png, png_corrupt, png_declaring, tree,
};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

const MIB: usize = 1 << 20;
/// Peak heap of one import (and of the build of what imports) beyond its input.
const PEAK_LIMIT: usize = 64 * MIB;
/// Time one case may take before it counts as a hang.
const DEADLINE: Duration = Duration::from_secs(60);
/// Time a case with a FIFO or device may take: refusing one is immediate.
const PROMPT: Duration = Duration::from_secs(10);

// ---------------------------------------------------------------------------------------------
// Cases

/// The error classes of the importer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Invalid,
    Unsupported,
    Limit(Limit),
    MissingBuffer,
    Image,
    Gltf,
    Io,
    Other,
}

fn kind(err: &BuildError) -> Kind {
    match err {
        BuildError::InvalidData { .. } => Kind::Invalid,
        BuildError::Unsupported { .. } => Kind::Unsupported,
        BuildError::Limit { limit, .. } => Kind::Limit(*limit),
        BuildError::MissingBuffer { .. } => Kind::MissingBuffer,
        BuildError::Image { .. } => Kind::Image,
        BuildError::Gltf { .. } => Kind::Gltf,
        BuildError::Io { .. } => Kind::Io,
        _ => Kind::Other,
    }
}

/// What the build of an imported case must give.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Build {
    /// A container that writes and verifies.
    Verifies,
    /// `NoGeometry` (nothing drawable is left).
    NoGeometry,
    /// A verified container or any typed error of the build, never a container that fails
    /// verification.
    Either,
}

enum Expect {
    /// The import succeeds (with a warning containing the text, if given), `check` holds, and
    /// the build gives `build`.
    Imports { warning: Option<&'static str>, check: Option<fn(&Scene)>, build: Build },
    /// The import fails with one of `kinds`, its message naming the input and containing every
    /// entry of `names` (an entry `a|b` wants either).
    Fails { kinds: Vec<Kind>, names: Vec<String> },
    /// Anything but a panic, a hang or a bomb; what imports must build (or have no geometry).
    NoPanic,
}

enum Input {
    /// Bytes imported with `import_gltf_bytes_with` (no base directory), named `corpus/<case>.<ext>`.
    Bytes { ext: &'static str, bytes: Vec<u8> },
    /// A file imported with `import_gltf_with`; the directory lives as long as the case.
    File { _dir: Option<TempDir>, path: PathBuf },
}

struct Case {
    input: Input,
    limits: ImportLimits,
    expect: Expect,
    deadline: Duration,
    /// A FIFO to open for writing if the import blocks, so the blocked reader returns.
    fifo: Option<PathBuf>,
    /// Whether what imports is built too.
    build: bool,
}

impl Case {
    fn new(input: Input) -> Self {
        Self {
            input,
            limits: ImportLimits::default(),
            expect: Expect::NoPanic,
            deadline: DEADLINE,
            fifo: None,
            build: true,
        }
    }

    fn imports(mut self) -> Self {
        self.expect = Expect::Imports { warning: None, check: None, build: Build::Verifies };
        self
    }

    fn warning(mut self, text: &'static str) -> Self {
        if let Expect::Imports { warning, .. } = &mut self.expect {
            *warning = Some(text);
        }
        self
    }

    fn check(mut self, f: fn(&Scene)) -> Self {
        if let Expect::Imports { check, .. } = &mut self.expect {
            *check = Some(f);
        }
        self
    }

    fn builds(mut self, b: Build) -> Self {
        if let Expect::Imports { build, .. } = &mut self.expect {
            *build = b;
        }
        self
    }

    fn fails(mut self, kinds: &[Kind], names: &[&str]) -> Self {
        self.expect = Expect::Fails { kinds: kinds.to_vec(), names: names.iter().map(|s| (*s).to_owned()).collect() };
        self
    }

    fn invalid(self, names: &[&str]) -> Self {
        self.fails(&[Kind::Invalid], names)
    }

    fn unsupported(self, names: &[&str]) -> Self {
        self.fails(&[Kind::Unsupported], names)
    }

    fn limit(self, limit: Limit, names: &[&str]) -> Self {
        self.fails(&[Kind::Limit(limit)], names)
    }

    fn missing(self, names: &[&str]) -> Self {
        self.fails(&[Kind::MissingBuffer], names)
    }

    fn limits(mut self, limits: ImportLimits) -> Self {
        self.limits = limits;
        self
    }

    /// Import only: the build of a large input is the build's tests' business.
    fn import_only(mut self) -> Self {
        self.build = false;
        self
    }

    fn prompt(mut self) -> Self {
        self.deadline = PROMPT;
        self
    }

    fn fifo(mut self, path: PathBuf) -> Self {
        self.fifo = Some(path);
        self.prompt()
    }
}

/// The document as a `.gltf` with a data URI.
fn json_case(doc: &Gltf) -> Case {
    Case::new(Input::Bytes { ext: "gltf", bytes: doc.to_gltf() })
}

/// The document as a `.glb`.
fn glb_case(doc: &Gltf) -> Case {
    Case::new(Input::Bytes { ext: "glb", bytes: doc.to_glb() })
}

fn bytes_case(ext: &'static str, bytes: Vec<u8>) -> Case {
    Case::new(Input::Bytes { ext, bytes })
}

/// The tree with `edit` applied.
fn edited(edit: impl FnOnce(&mut Gltf)) -> Gltf {
    let mut doc = tree();
    edit(&mut doc);
    doc
}

fn leaf_accessor(doc: &mut Gltf, index: usize) -> &mut serde_json::Value {
    &mut doc.json["accessors"][index]
}

fn external_limits() -> ImportLimits {
    ImportLimits { allow_external_uris: true, ..ImportLimits::default() }
}

/// A temporary directory holding `model/` and `outside/` (with the tree's buffer and texture:
/// `outside/tree.bin`, `outside/leaf.png`).
fn model_dirs() -> (TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("model");
    let outside = dir.path().join("outside");
    std::fs::create_dir_all(&model).expect("model dir");
    std::fs::create_dir_all(&outside).expect("outside dir");
    std::fs::write(outside.join("tree.bin"), &tree().bin).expect("writes");
    std::fs::write(outside.join("leaf.png"), leaf_png()).expect("writes");
    (dir, model, outside)
}

/// `model/tree.gltf` of `doc` with `doc`'s buffer beside it unless the document names another
/// URI; the case imports it as a file.
fn file_case(doc: &Gltf, setup: impl FnOnce(&Path, &Path)) -> Case {
    let (dir, model, outside) = model_dirs();
    setup(&model, &outside);
    let path = doc.write_files(&model, "tree");
    Case::new(Input::File { _dir: Some(dir), path })
}

/// The tree whose buffer 0 is at `uri`.
fn buffer_at(uri: &str) -> Gltf {
    edited(|d| d.json["buffers"][0]["uri"] = uri.into())
}

/// The tree whose image 0 is at `uri`.
fn image_at(uri: &str) -> Gltf {
    edited(|d| d.json["images"][0] = json!({"uri": uri}))
}

fn mkfifo(path: &Path) {
    let status = std::process::Command::new("mkfifo").arg(path).status().expect("runs mkfifo");
    assert!(status.success(), "mkfifo {}", path.display());
}

#[cfg(unix)]
fn symlink(target: &Path, link: &Path) {
    std::os::unix::fs::symlink(target, link).expect("symlink");
}

/// An accessor `"sparse"` object substituting `indices` (u8) by `values` (vec3).
fn sparse(doc: &mut Gltf, indices: &[u8], values: &[[f32; 3]]) -> serde_json::Value {
    let i = doc.view(indices, None);
    let v = doc.view(&gltf::f32_bytes(values.as_flattened()), None);
    json!({"count": indices.len(), "indices": {"bufferView": i, "componentType": component::UNSIGNED_BYTE},
           "values": {"bufferView": v}})
}

fn leaves(scene: &Scene) -> &treelod_build::scene::Part {
    scene.parts.iter().find(|p| p.mesh_name == "leaves").expect("a leaf part")
}

fn close(a: &[f32], b: &[f32], eps: f32) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= eps)
}

/// `n` separate leaf quads in one primitive (32-bit indices), on a 1 m grid.
fn many_quads(n: u32) -> Gltf {
    let mut doc = tree();
    let (mut positions, mut normals, mut uvs, mut indices) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for q in 0..n {
        #[expect(clippy::cast_precision_loss, reason = "small")]
        let (x, z) = ((q % 317) as f32 * 0.05, (q / 317) as f32 * 0.05);
        let base = u32::try_from(positions.len()).expect("fewer than 2^32 vertices");
        for (dx, dy, u, v) in
            [(0.0, 0.0, 0.0, 1.0), (0.04, 0.0, 1.0, 1.0), (0.04, 0.04, 1.0, 0.0), (0.0, 0.04, 0.0, 0.0)]
        {
            positions.push([x + dx, 1.0 + dy, z]);
            normals.push([0.0, 0.0, 1.0]);
            uvs.push([u, v]);
        }
        indices.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    let accessors = [doc.vec3(&positions), doc.vec3(&normals), doc.vec2(&uvs), doc.indices_u32(&indices)];
    doc.json["meshes"][0]["primitives"][0] = json!({"attributes": {"POSITION": accessors[0], "NORMAL": accessors[1],
        "TEXCOORD_0": accessors[2]}, "indices": accessors[3], "material": 0});
    doc
}

/// A 64 MiB name.
fn huge_name() -> String {
    "n".repeat(64 * MIB)
}

fn check_truncated_names(scene: &Scene) {
    let longest = scene
        .parts
        .iter()
        .flat_map(|p| [p.node_name.len(), p.mesh_name.len()])
        .chain(scene.materials.iter().map(|m| m.name.len()))
        .max()
        .unwrap_or(0);
    assert!(longest < 64 * MIB, "a 64 MiB name was kept whole ({longest} bytes)");
}

// ---------------------------------------------------------------------------------------------
// Running a case

enum Outcome {
    Imported(Box<Scene>),
    Failed(BuildError),
}

fn run(name: &str, case: Case) {
    assert!(counting(), "the counting allocator is installed");
    let Case { input, limits, expect, deadline, fifo, build } = case;
    let (label, input_len) = match &input {
        Input::Bytes { ext, bytes } => (PathBuf::from(format!("corpus/{name}.{ext}")), bytes.len()),
        Input::File { path, .. } => (path.clone(), std::fs::metadata(path).map_or(0, |m| m.len() as usize)),
    };
    let peak_limit = PEAK_LIMIT + 4 * input_len;
    let start = Instant::now();
    let (received, peak) = peak_during(|| {
        let (tx, rx) = mpsc::channel();
        let thread_label = label.clone();
        let thread_limits = limits.clone();
        std::thread::Builder::new()
            .name(format!("import {name}"))
            .spawn(move || {
                let result = catch_unwind(AssertUnwindSafe(|| match &input {
                    Input::Bytes { bytes, .. } => {
                        treelod_build::import_gltf_bytes_with(bytes, &thread_label, None, &thread_limits)
                    }
                    Input::File { path, .. } => treelod_build::import_gltf_with(path, &thread_limits),
                }));
                let outcome = result.map(|r| match r {
                    Ok(scene) => Outcome::Imported(Box::new(scene)),
                    Err(e) => Outcome::Failed(e),
                });
                let _ = tx.send(outcome);
                drop(input);
            })
            .expect("spawns");
        rx.recv_timeout(deadline)
    });
    let elapsed = start.elapsed();
    let Ok(outcome) = received else {
        if let Some(fifo) = fifo {
            // Release a reader blocked opening the FIFO, so the thread ends.
            std::thread::spawn(move || drop(std::fs::OpenOptions::new().write(true).open(fifo)));
        }
        panic!("{name}: no answer within {deadline:?}: the import hangs");
    };
    let Ok(outcome) = outcome else { panic!("{name}: the importer panicked") };
    let peak = peak.process;
    match &outcome {
        Outcome::Imported(scene) => eprintln!(
            "{name}: imported ({} parts, {} warnings) in {elapsed:.2?}, peak heap {peak} bytes",
            scene.parts.len(),
            scene.warnings.len()
        ),
        Outcome::Failed(e) => {
            eprintln!("{name}: {:?} in {elapsed:.2?}, peak heap {peak} bytes: {}", kind(e), short(&e.to_string()));
        }
    }
    assert!(peak <= peak_limit, "{name}: peak heap {peak} bytes (limit {peak_limit}) for a {input_len}-byte input");
    assert!(elapsed <= deadline, "{name}: took {elapsed:?}");
    match (expect, outcome) {
        (Expect::Imports { warning, check, build: wanted }, Outcome::Imported(scene)) => {
            if let Some(text) = warning {
                assert!(
                    scene.warnings.iter().any(|w| text.split('|').any(|t| w.to_lowercase().contains(t))),
                    "{name}: no warning containing {text:?}: {:?}",
                    scene.warnings.iter().map(|w| short(w)).collect::<Vec<_>>()
                );
            }
            if let Some(check) = check {
                check(&scene);
            }
            if build {
                build_and_verify(name, &scene, wanted, peak_limit);
            }
        }
        (Expect::Imports { .. }, Outcome::Failed(e)) => {
            panic!("{name}: must import, but: {:?}: {}", kind(&e), short(&e.to_string()))
        }
        (Expect::Fails { kinds, .. }, Outcome::Imported(scene)) => {
            panic!("{name}: must fail with {kinds:?}, but imported {} parts: {:?}", scene.parts.len(), scene.warnings)
        }
        (Expect::Fails { kinds, names }, Outcome::Failed(e)) => {
            let message = e.to_string();
            assert!(kinds.contains(&kind(&e)), "{name}: want {kinds:?}, got {:?}: {}", kind(&e), short(&message));
            let shown = label.display().to_string();
            assert!(message.contains(&shown), "{name}: the message does not name the input {shown}: {message}");
            for want in names {
                assert!(
                    want.split('|').any(|w| message.contains(w)),
                    "{name}: the message does not name {want:?}: {}",
                    short(&message)
                );
            }
            assert!(!message.contains("Format {") && !message.contains("Error {"), "{name}: a debug struct: {message}");
            if kind(&e) == Kind::Image {
                assert!(!message.contains('{'), "{name}: a debug struct in an image error: {message}");
            }
        }
        (Expect::NoPanic, Outcome::Imported(scene)) => {
            if build {
                build_and_verify(name, &scene, Build::Either, peak_limit);
            }
        }
        (Expect::NoPanic, Outcome::Failed(e)) => {
            let message = e.to_string();
            let shown = label.display().to_string();
            assert!(message.contains(&shown), "{name}: the message does not name the input {shown}: {message}");
        }
    }
}

/// At most 300 characters of a message, so a 64 MiB name does not flood the log.
fn short(message: &str) -> String {
    if message.len() <= 300 {
        return message.to_owned();
    }
    let mut end = 300;
    while !message.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}… ({} bytes)", &message[..end], message.len())
}

/// What building an imported scene gave.
#[derive(Debug)]
enum Built {
    /// A container that writes, opens and verifies, of this many bytes.
    Verified(usize),
    /// A typed error of the build.
    Refused(BuildError),
    /// A container the build wrote that does not open or verify: never acceptable.
    Broken(treelod_format::Error),
}

/// Builds `scene` with cheap settings (2 × 2 × 2 grid, no occlusion), writes the container and
/// verifies it.
fn build_and_verify(name: &str, scene: &Scene, wanted: Build, peak_limit: usize) {
    let config = BuildConfig { grid: Some([2, 2, 2]), ..BuildConfig::default() };
    let start = Instant::now();
    let (result, peak) = peak_during(|| {
        catch_unwind(AssertUnwindSafe(|| {
            let trees = [Placed { scene, translation: glam::Vec3::ZERO }];
            let output = match treelod_build::build_block(name, &trees, &config, "treelod-tests hostile_gltf") {
                Ok(output) => output,
                Err(e) => return Built::Refused(e),
            };
            let bytes = match output.data.to_bytes(Compression::Zstd { level: 1 }) {
                Ok(bytes) => bytes,
                Err(e) => return Built::Refused(e.into()),
            };
            match Container::from_bytes(&bytes).and_then(|c| verify(&c)) {
                Ok(_) => Built::Verified(bytes.len()),
                Err(e) => Built::Broken(e),
            }
        }))
    });
    let result = result.unwrap_or_else(|_| panic!("{name}: the build panicked"));
    let shown = match &result {
        Built::Verified(n) => format!("a verified container of {n} bytes"),
        Built::Refused(e) => format!("refused: {}", short(&e.to_string())),
        Built::Broken(e) => format!("A CONTAINER THAT FAILS VERIFICATION: {e}"),
    };
    eprintln!("{name}: build: {shown} in {:.2?}, peak heap {} bytes", start.elapsed(), peak.process);
    match (wanted, result) {
        (_, Built::Broken(e)) => panic!("{name}: the build wrote a container that fails verification: {e}"),
        (Build::Verifies, Built::Verified(_)) | (Build::Either, _) => {}
        (Build::NoGeometry, Built::Refused(BuildError::NoGeometry { .. })) => {}
        (_, Built::Refused(e)) => panic!("{name}: the build fails: {}", short(&e.to_string())),
        (Build::NoGeometry, Built::Verified(_)) => panic!("{name}: built a container from no geometry"),
    }
    assert!(peak.process <= peak_limit, "{name}: the build's peak heap is {} bytes", peak.process);
}

macro_rules! corpus {
    ($($(#[$attr:meta])* $name:ident: $case:expr;)*) => {
        $(
            #[test]
            $(#[$attr])*
            fn $name() {
                let _alone = exclusive();
                run(stringify!($name), $case);
            }
        )*
        /// Every case of the corpus, in order.
        const CASES: &[&str] = &[$(stringify!($name)),*];
    };
}

#[test]
fn the_corpus_covers_every_class() {
    // The classes of issue 28, each with at least one case whose name starts with the prefix.
    for prefix in [
        "valid_",
        "indices_",
        "texcoord_",
        "color_",
        "position_",
        "stride_",
        "sparse_",
        "index_",
        "image_",
        "png_",
        "jpeg_",
        "nodes_",
        "values_",
        "uri_",
        "fifo_",
        "dev_zero",
        "required_",
        "extras_",
        "name_",
        "glb_",
        "limit_",
    ] {
        assert!(CASES.iter().any(|c| c.starts_with(prefix)), "no case for {prefix}");
    }
    assert!(CASES.len() >= 80, "{} cases", CASES.len());
}

// ---------------------------------------------------------------------------------------------
// The corpus

const LEAF_POSITION_PATH: &str = "meshes[0].primitives[0].attributes.POSITION";
const LEAF_INDICES_PATH: &str = "meshes[0].primitives[0].indices";
const LEAF_UV_PATH: &str = "meshes[0].primitives[0].attributes.TEXCOORD_0";

corpus! {
    // Valid files: they import and build.
    valid_tree_gltf: json_case(&tree()).imports().check(|s| {
        assert_eq!(s.parts.len(), 2);
        assert_eq!(leaves(s).triangles.len(), 12);
        assert!(s.materials.iter().any(|m| m.image.is_some()), "the leaf texture");
    });
    valid_tree_glb: glb_case(&tree()).imports();
    valid_tree_files: file_case(&image_at("textures/leaf.png"), |model, _| {
        std::fs::create_dir(model.join("textures")).unwrap();
        std::fs::write(model.join("textures/leaf.png"), leaf_png()).unwrap();
    }).imports().check(|s| assert!(s.materials.iter().any(|m| m.image.is_some())));
    valid_interleaved: json_case(&gltf::tree_interleaved()).imports();
    valid_sparse: json_case(&gltf::tree_sparse()).imports().check(|s| {
        let p = leaves(s).positions[0];
        let want = [SPARSE_VERTEX[0], SPARSE_VERTEX[1] + 0.5, SPARSE_VERTEX[2]];
        assert!(close(&p, &want, 1e-6), "sparse vertex {p:?}, want {want:?}");
    });
    valid_quantized: glb_case(&gltf::tree_quantized()).imports().check(|s| {
        let LeafGeometry { positions, .. } = leaf_geometry();
        let p = leaves(s).positions[0];
        let want = [positions[0][0], positions[0][1] + 0.5, positions[0][2]];
        assert!(close(&p, &want, 1e-3), "quantised vertex {p:?}, want {want:?}");
    });
    valid_quantized_used_not_required: json_case(&{
        let mut d = gltf::tree_quantized();
        d.json.as_object_mut().unwrap().remove("extensionsRequired");
        d
    }).imports();
    valid_texture_transform: json_case(&gltf::tree_texture_transform()).imports().check(|s| {
        // offset (0.5, 0.25) + scale (0.5, 0.5) × uv: (1, 1) -> (1, 0.75), (1, 0) -> (1, 0.25).
        let uvs = &leaves(s).uvs;
        assert!(close(&uvs[1], &[1.0, 0.75], 1e-5), "transformed UV {:?}, want [1.0, 0.75]", uvs[1]);
        assert!(close(&uvs[2], &[1.0, 0.25], 1e-5), "transformed UV {:?}, want [1.0, 0.25]", uvs[2]);
    });
    valid_normalized_attributes: json_case(&gltf::tree_normalized_attributes()).imports().check(|s| {
        let part = leaves(s);
        assert!(close(&part.uvs[2], &[1.0, 0.0], 1e-4), "UV {:?}", part.uvs[2]);
        assert_eq!(part.colors.len(), LEAF_VERTICES);
    });
    valid_extras_gltf: json_case(&gltf::tree_extras()).imports();
    extras_every_kind_glb: glb_case(&gltf::tree_extras()).imports();
    extras_root_string: json_case(&edited(|d| d.json["extras"] = "hello".into())).imports();
    extras_root_number: json_case(&edited(|d| d.json["extras"] = 7.into())).imports();
    extras_deeply_nested: bytes_case("gltf", {
        // 100,000 nested arrays: a recursive reader must refuse them, not overflow its stack.
        let json = String::from_utf8(tree().to_gltf()).unwrap();
        let deep = format!("{}{}", "[".repeat(100_000), "]".repeat(100_000));
        format!("{},\"extras\":{deep}}}", &json[..json.len() - 1]).into_bytes()
    });
    valid_unknown_extension_used_only: json_case(&edited(|d| d.use_extension("EXT_treelod_unknown", false))).imports();
    valid_quantization_required_on_float_data: json_case(&edited(|d| d.use_extension("KHR_mesh_quantization", true))).imports();
    valid_points_skipped_with_warning: json_case(&edited(|d| d.json["meshes"][0]["primitives"][0]["mode"] = 0.into()))
        .imports().warning("not triangles");
    valid_no_normals_computed: json_case(&edited(|d| {
        d.json["meshes"][0]["primitives"][0]["attributes"].as_object_mut().unwrap().remove("NORMAL");
    })).imports().warning("no normals");
    valid_all_degenerate_builds_nothing: json_case(&edited(|d| {
        for view in [1, 5] {
            d.view_bytes_mut(view).fill(0);
        }
    })).imports().builds(Build::NoGeometry);
    valid_unknown_image_type_skipped: json_case(&edited(|d| {
        let view = d.view(b"GIF89a\x01\x00\x01\x00\x00\x00\x00;", None);
        d.json["images"][0] = json!({"bufferView": view, "mimeType": "image/gif"});
    }));

    // Values a reader accepts but the container refuses: non-finite numbers must not reach a
    // container that then fails verification (found by fuzz_smoke).
    values_base_color_overflow: json_case(&edited(|d| {
        d.json["materials"][1]["pbrMetallicRoughness"]["baseColorFactor"] = json!([0.3, -1e39, 0.1, 1.0]);
    }));
    values_texcoord_nan: json_case(&edited(|d| {
        let uvs = d.view_bytes_mut(3);
        uvs[..8].copy_from_slice(&gltf::f32_bytes(&[f32::NAN, f32::INFINITY]));
    }));
    values_texcoord_view_misaligned: json_case(&edited(|d| d.json["bufferViews"][3]["byteOffset"] = 3.into()));
    values_color_nan: json_case(&edited(|d| {
        let view = d.view(&gltf::f32_bytes(&[f32::NAN; 4 * LEAF_VERTICES]), None);
        let colors = d.accessor(view, component::FLOAT, LEAF_VERTICES, "VEC4");
        d.json["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = colors.into();
    }));
    values_position_nan_and_huge: json_case(&edited(|d| {
        let positions = d.view_bytes_mut(1);
        positions[..24].copy_from_slice(&gltf::f32_bytes(&[f32::NAN, 3e38, -3e38, f32::INFINITY, 1e-45, 0.0]));
    }));
    values_translation_near_f32_max: json_case(&edited(|d| d.json["nodes"][1]["translation"] = json!([0.0, 0.5, 3.4e38])));
    values_alpha_cutoff_nan_like: json_case(&edited(|d| d.json["materials"][0]["alphaCutoff"] = json!(-1e39)));

    // Accessor component types and types (panics in gltf's readers on main).
    indices_float: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["componentType"] = component::FLOAT.into()))
        .invalid(&[LEAF_INDICES_PATH, "accessors[3]"]);
    indices_byte: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["componentType"] = component::BYTE.into()))
        .invalid(&[LEAF_INDICES_PATH, "accessors[3]"]);
    indices_short: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["componentType"] = component::SHORT.into()))
        .invalid(&[LEAF_INDICES_PATH, "accessors[3]"]);
    indices_normalized: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["normalized"] = true.into()))
        .invalid(&[LEAF_INDICES_PATH, "accessors[3]"]);
    indices_vec3: json_case(&edited(|d| {
        let a = leaf_accessor(d, accessor::LEAF_INDICES);
        a["type"] = "VEC3".into();
        a["count"] = 12.into();
    })).invalid(&[LEAF_INDICES_PATH, "accessors[3]"]);
    indices_ubyte_valid: json_case(&edited(|d| {
        let LeafGeometry { indices, .. } = leaf_geometry();
        let bytes: Vec<u8> = indices.iter().map(|&i| u8::try_from(i).unwrap()).collect();
        let view = d.view(&bytes, None);
        *leaf_accessor(d, accessor::LEAF_INDICES) =
            json!({"bufferView": view, "componentType": component::UNSIGNED_BYTE, "count": bytes.len(), "type": "SCALAR"});
    })).imports();
    texcoord_byte: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_UV)["componentType"] = component::BYTE.into()))
        .invalid(&[LEAF_UV_PATH, "accessors[2]"]);
    texcoord_ubyte_unnormalized: json_case(&edited(|d| {
        leaf_accessor(d, accessor::LEAF_UV)["componentType"] = component::UNSIGNED_BYTE.into();
    })).invalid(&[LEAF_UV_PATH, "accessors[2]"]);
    texcoord_vec3: json_case(&edited(|d| {
        let a = leaf_accessor(d, accessor::LEAF_UV);
        a["type"] = "VEC3".into();
        a["count"] = 16.into();
    })).invalid(&[LEAF_UV_PATH, "accessors[2]"]);
    texcoord_scalar: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_UV)["type"] = "SCALAR".into()))
        .invalid(&[LEAF_UV_PATH, "accessors[2]"]);
    color_scalar_float: json_case(&edited(|d| {
        let view = d.view(&gltf::f32_bytes(&[1.0; LEAF_VERTICES]), None);
        let colors = d.accessor(view, component::FLOAT, LEAF_VERTICES, "SCALAR");
        d.json["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = colors.into();
    })).invalid(&["meshes[0].primitives[0].attributes.COLOR_0", "accessors[7]"]);
    color_ubyte_unnormalized: json_case(&edited(|d| {
        let view = d.view(&[255; 4 * LEAF_VERTICES], None);
        let colors = d.accessor(view, component::UNSIGNED_BYTE, LEAF_VERTICES, "VEC4");
        d.json["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = colors.into();
    })).invalid(&["meshes[0].primitives[0].attributes.COLOR_0", "accessors[7]"]);
    color_vec3_float_valid: json_case(&edited(|d| {
        let view = d.view(&gltf::f32_bytes(&[0.5; 3 * LEAF_VERTICES]), None);
        let colors = d.accessor(view, component::FLOAT, LEAF_VERTICES, "VEC3");
        d.json["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = colors.into();
    })).imports().check(|s| assert_eq!(leaves(s).colors.len(), LEAF_VERTICES));
    normal_vec2: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_NORMAL)["type"] = "VEC2".into()))
        .invalid(&["meshes[0].primitives[0].attributes.NORMAL", "accessors[1]"]);
    position_vec2: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["type"] = "VEC2".into()))
        .fails(&[Kind::Invalid, Kind::Gltf], &[LEAF_POSITION_PATH, "accessors[0]"]);
    position_ubyte_over_float_data: json_case(&edited(|d| {
        leaf_accessor(d, accessor::LEAF_POSITION)["componentType"] = component::UNSIGNED_BYTE.into();
    })).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    position_short_without_quantization: json_case(&{
        let mut d = gltf::tree_quantized();
        let object = d.json.as_object_mut().unwrap();
        object.remove("extensionsUsed");
        object.remove("extensionsRequired");
        d
    }).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    position_double_component: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["componentType"] = 5130.into()))
        .fails(&[Kind::Invalid, Kind::Gltf], &[]);

    // Accessor bounds.
    stride_smaller_than_element: json_case(&edited(|d| d.json["bufferViews"][1]["byteStride"] = 8.into()))
        .invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    stride_smaller_than_element_glb: glb_case(&edited(|d| d.json["bufferViews"][1]["byteStride"] = 4.into()))
        .invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    position_count_past_view: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["count"] = 25.into()))
        .invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    position_offset_past_view: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["byteOffset"] = 4096.into()))
        .invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    position_view_past_buffer: json_case(&edited(|d| {
        let len = d.bin.len();
        d.json["bufferViews"][1]["byteOffset"] = (len - 100).into();
    })).invalid(&[&format!("{LEAF_POSITION_PATH}|bufferViews[1]")]);
    position_count_zero: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["count"] = 0.into()))
        .invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    position_count_2_32: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["count"] = (1u64 << 32).into()))
        .fails(&[Kind::Invalid, Kind::Limit(Limit::DecodedBytes)], &[LEAF_POSITION_PATH]);
    indices_count_past_view: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["count"] = 37.into()))
        .invalid(&[LEAF_INDICES_PATH, "accessors[3]"]);
    indices_count_2_31: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["count"] = (1u64 << 31).into()))
        .fails(&[Kind::Invalid, Kind::Limit(Limit::DecodedBytes), Kind::Limit(Limit::Triangles)], &["meshes[0].primitives[0]"]);
    indices_no_buffer_view: json_case(&edited(|d| {
        leaf_accessor(d, accessor::LEAF_INDICES).as_object_mut().unwrap().remove("bufferView");
    }));
    index_equal_to_vertex_count: json_case(&edited(|d| {
        let indices = d.view_bytes_mut(4);
        let n = indices.len();
        indices[n - 2..].copy_from_slice(&24u16.to_le_bytes());
    })).invalid(&[LEAF_INDICES_PATH, "index 24 out of range: the primitive has 24 vertices"]);
    index_u32_max: json_case(&edited(|d| d.view_bytes_mut(7)[..4].copy_from_slice(&u32::MAX.to_le_bytes())))
        .invalid(&["meshes[1].primitives[0].indices", "out of range"]);
    index_out_of_range_glb: glb_case(&edited(|d| d.view_bytes_mut(4)[..2].copy_from_slice(&1000u16.to_le_bytes())))
        .invalid(&[LEAF_INDICES_PATH, "index 1000 out of range: the primitive has 24 vertices"]);
    sparse_count_over_count: json_case(&edited(|d| {
        let values = vec![[0.0; 3]; 25];
        let indices: Vec<u8> = (0..25).collect();
        let s = sparse(d, &indices, &values);
        leaf_accessor(d, accessor::LEAF_POSITION)["sparse"] = s;
    })).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    sparse_indices_not_increasing: json_case(&edited(|d| {
        let s = sparse(d, &[3, 1], &[[0.0; 3]; 2]);
        leaf_accessor(d, accessor::LEAF_POSITION)["sparse"] = s;
    })).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    sparse_indices_repeated: json_case(&edited(|d| {
        let s = sparse(d, &[2, 2], &[[0.0; 3]; 2]);
        leaf_accessor(d, accessor::LEAF_POSITION)["sparse"] = s;
    })).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    sparse_index_out_of_range: json_case(&edited(|d| {
        let s = sparse(d, &[24], &[[0.0; 3]]);
        leaf_accessor(d, accessor::LEAF_POSITION)["sparse"] = s;
    })).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    sparse_values_view_short: json_case(&edited(|d| {
        let mut s = sparse(d, &[0, 1], &[[0.0; 3]; 2]);
        let short = d.view(&[0; 12], None);
        s["values"]["bufferView"] = short.into();
        leaf_accessor(d, accessor::LEAF_POSITION)["sparse"] = s;
    })).invalid(&[LEAF_POSITION_PATH, "accessors[0]"]);
    sparse_no_view_count_2_31: json_case(&edited(|d| {
        let s = sparse(d, &[0], &[[1.0; 3]]);
        *leaf_accessor(d, accessor::LEAF_POSITION) =
            json!({"componentType": component::FLOAT, "count": 1u64 << 31, "type": "VEC3", "sparse": s,
                   "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]});
    })).fails(&[Kind::Invalid, Kind::Limit(Limit::DecodedBytes)], &[LEAF_POSITION_PATH]);
    sparse_no_view_count_2_31_on_normals: glb_case(&edited(|d| {
        let s = sparse(d, &[0], &[[1.0; 3]]);
        *leaf_accessor(d, accessor::LEAF_NORMAL) =
            json!({"componentType": component::FLOAT, "count": 1u64 << 31, "type": "VEC3", "sparse": s});
    })).fails(&[Kind::Invalid, Kind::Limit(Limit::DecodedBytes)], &["meshes[0].primitives[0].attributes.NORMAL"]);
    sparse_no_view_valid: json_case(&edited(|d| {
        // Bark normals from a sparse accessor over zeros: valid glTF.
        let s = sparse(d, &(0..8).collect::<Vec<u8>>(), &[[0.0, 0.0, 1.0]; 8]);
        *leaf_accessor(d, accessor::BARK_NORMAL) =
            json!({"componentType": component::FLOAT, "count": 8, "type": "VEC3", "sparse": s});
    })).imports();

    // References to objects that do not exist.
    missing_indices_accessor: json_case(&edited(|d| d.json["meshes"][0]["primitives"][0]["indices"] = 99.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_normal_accessor: json_case(&edited(|d| d.json["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = 99.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_material: json_case(&edited(|d| d.json["meshes"][0]["primitives"][0]["material"] = 99.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_texture_image: json_case(&edited(|d| d.json["textures"][0]["source"] = 99.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_node_mesh: json_case(&edited(|d| d.json["nodes"][1]["mesh"] = 99.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_child_node: json_case(&edited(|d| d.json["nodes"][0]["children"] = json!([1, 99])))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_scene_node: json_case(&edited(|d| d.json["scenes"][0]["nodes"] = json!([7])))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_buffer_view: json_case(&edited(|d| leaf_accessor(d, accessor::LEAF_POSITION)["bufferView"] = 99.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_buffer: json_case(&edited(|d| d.json["bufferViews"][1]["buffer"] = 3.into()))
        .fails(&[Kind::Gltf, Kind::Invalid], &[]);
    missing_scene: json_case(&edited(|d| d.json["scene"] = 5.into())).fails(&[Kind::Gltf, Kind::Invalid], &[]);

    // Node hierarchies.
    nodes_doubling_25_deep: json_case(&edited(|d| {
        // 25 nodes, each listing the next twice: 2^24 instances of the leaves.
        let nodes: Vec<_> = (0..25).map(|i| if i < 24 { json!({"children": [i + 1, i + 1]}) } else { json!({"mesh": 0}) }).collect();
        d.json["nodes"] = nodes.into();
        d.json["scenes"][0]["nodes"] = json!([0]);
    })).limit(Limit::Instances, &[]);
    nodes_doubling_8_deep: json_case(&edited(|d| {
        let nodes: Vec<_> = (0..9).map(|i| if i < 8 { json!({"children": [i + 1, i + 1]}) } else { json!({"mesh": 0}) }).collect();
        d.json["nodes"] = nodes.into();
        d.json["scenes"][0]["nodes"] = json!([0]);
    })).imports().check(|s| assert_eq!(s.parts.len(), 256, "2^8 instances of the leaves"));
    nodes_self_cycle: json_case(&edited(|d| d.json["nodes"][1]["children"] = json!([1])))
        .fails(&[Kind::Gltf, Kind::Invalid, Kind::Limit(Limit::Instances)], &[]);
    nodes_two_cycle: json_case(&edited(|d| {
        d.json["nodes"][1]["children"] = json!([2]);
        d.json["nodes"][2]["children"] = json!([1]);
    })).fails(&[Kind::Gltf, Kind::Invalid, Kind::Limit(Limit::Instances)], &[]);
    nodes_scene_lists_a_node_twice: json_case(&edited(|d| d.json["scenes"][0]["nodes"] = json!([0, 0])))
        .imports().check(|s| assert_eq!(s.parts.len(), 4));
    nodes_matrix_huge: json_case(&edited(|d| {
        d.json["nodes"][1]["matrix"] = json!([1e39, 0, 0, 0, 0, 1e39, 0, 0, 0, 0, 1e39, 0, 0, 0, 0, 1]);
        d.json["nodes"][1].as_object_mut().unwrap().remove("translation");
    }));
    nodes_matrix_and_trs_nan_like: json_case(&edited(|d| d.json["nodes"][1]["scale"] = json!([-1e38, 1e-45, 0]) ));

    // 10^5 separate leaf quads: the import stays fast and small (the 10^6-quad tree spent
    // its time in the build's occlusion stage, which the build's own tests time).
    nodes_many_leaf_quads: glb_case(&many_quads(100_000)).imports().import_only().check(|s| {
        assert_eq!(leaves(s).triangles.len(), 200_000);
    });

    // Resource limits as options.
    limit_instances_option: json_case(&tree()).limits(ImportLimits { max_instances: 2, ..ImportLimits::default() })
        .limit(Limit::Instances, &[]);
    limit_triangles_option: json_case(&tree()).limits(ImportLimits { max_triangles: 10, ..ImportLimits::default() })
        .limit(Limit::Triangles, &[]);
    limit_decoded_bytes_option: glb_case(&tree()).limits(ImportLimits { max_decoded_bytes: 1000, ..ImportLimits::default() })
        .limit(Limit::DecodedBytes, &[]);
    limit_image_pixels_option: json_case(&tree()).limits(ImportLimits { max_image_pixels: 15, ..ImportLimits::default() })
        .limit(Limit::ImagePixels, &["images[0]"]);
    limit_buffer_length_2_40: json_case(&edited(|d| d.json["buffers"][0]["byteLength"] = (1u64 << 40).into()))
        .fails(&[Kind::MissingBuffer, Kind::Limit(Limit::DecodedBytes), Kind::Invalid, Kind::Gltf], &[]);

    // Images.
    // 30000² pixels is over the pixel limit and over the container's 16384 per side: either
    // refusal, before decoding.
    png_declaring_30000_squared: json_case(&edited(|d| {
        let view = d.view(&png_declaring(30000, 30000), None);
        d.json["images"][0]["bufferView"] = view.into();
    })).fails(&[Kind::Limit(Limit::ImagePixels), Kind::Unsupported], &["images[0]"]);
    png_declaring_30000_squared_glb: glb_case(&edited(|d| {
        let view = d.view(&png_declaring(30000, 30000), None);
        d.json["images"][0]["bufferView"] = view.into();
    })).fails(&[Kind::Limit(Limit::ImagePixels), Kind::Unsupported], &["images[0]"]);
    jpeg_declaring_30000_squared: json_case(&edited(|d| {
        let view = d.view(&jpeg_declaring(30000, 30000), None);
        d.json["images"][0] = json!({"bufferView": view, "mimeType": "image/jpeg"});
    })).fails(&[Kind::Limit(Limit::ImagePixels), Kind::Unsupported], &["images[0]"]);
    jpeg_declaring_65535_squared_data_uri: json_case(&edited(|d| {
        d.json["images"][0] = json!({"uri": gltf::data_uri("image/jpeg", &jpeg_declaring(65535, 65535))});
    })).fails(&[Kind::Limit(Limit::ImagePixels), Kind::Unsupported], &["images[0]"]);
    // 16000² fits the container but not the default pixel limit (8192²).
    png_declaring_16000_squared: json_case(&edited(|d| {
        let view = d.view(&png_declaring(16000, 16000), None);
        d.json["images"][0]["bufferView"] = view.into();
    })).limit(Limit::ImagePixels, &["images[0]"]);
    jpeg_declaring_16000_squared: glb_case(&edited(|d| {
        let view = d.view(&jpeg_declaring(16000, 16000), None);
        d.json["images"][0] = json!({"bufferView": view, "mimeType": "image/jpeg"});
    })).limit(Limit::ImagePixels, &["images[0]"]);
    png_wider_than_container: json_case(&edited(|d| {
        let view = d.view(&png(20000, 1, 1, &[128; 20000]), None);
        d.json["images"][0]["bufferView"] = view.into();
    })).unsupported(&["images[0]"]);
    png_taller_than_container: json_case(&edited(|d| {
        let view = d.view(&png(1, 20000, 1, &[128; 20000]), None);
        d.json["images"][0]["bufferView"] = view.into();
    })).unsupported(&["images[0]"]);
    png_corrupt_data: json_case(&edited(|d| {
        let view = d.view(&png_corrupt(), None);
        d.json["images"][0]["bufferView"] = view.into();
    })).fails(&[Kind::Image], &["image 0|images[0]"]);
    png_truncated: json_case(&edited(|d| {
        let bytes = leaf_png();
        let view = d.view(&bytes[..bytes.len() / 2], None);
        d.json["images"][0]["bufferView"] = view.into();
    })).fails(&[Kind::Image], &["image 0|images[0]"]);
    image_view_past_buffer: json_case(&edited(|d| d.json["bufferViews"][0]["byteLength"] = 1_000_000.into()))
        .fails(&[Kind::Invalid, Kind::Image, Kind::Gltf, Kind::MissingBuffer], &[]);
    image_view_without_mime_type: json_case(&edited(|d| {
        d.json["images"][0].as_object_mut().unwrap().remove("mimeType");
    }));
    image_without_uri_or_view: json_case(&edited(|d| d.json["images"][0] = json!({"name": "nothing"})));
    image_garbage_bytes_as_png: json_case(&edited(|d| {
        let view = d.view(&[0xAB; 300], None);
        d.json["images"][0]["bufferView"] = view.into();
    }));

    // Required extensions: read, or refused by name (exit 4).
    required_draco: json_case(&edited(|d| d.use_extension("KHR_draco_mesh_compression", true)))
        .unsupported(&["KHR_draco_mesh_compression"]);
    required_meshopt: json_case(&edited(|d| d.use_extension("EXT_meshopt_compression", true)))
        .unsupported(&["EXT_meshopt_compression"]);
    required_basisu: json_case(&edited(|d| d.use_extension("KHR_texture_basisu", true)))
        .unsupported(&["KHR_texture_basisu"]);
    required_unknown: glb_case(&edited(|d| d.use_extension("EXT_treelod_hostile", true)))
        .unsupported(&["EXT_treelod_hostile"]);
    required_known_but_unread: json_case(&edited(|d| d.use_extension("KHR_materials_volume", true)))
        .unsupported(&["KHR_materials_volume"]);
    required_texture_transform: glb_case(&gltf::tree_texture_transform()).imports();
    required_quantization: glb_case(&gltf::tree_quantized()).imports();

    // Names.
    name_node_64_mib: json_case(&edited(|d| d.json["nodes"][1]["name"] = huge_name().into()))
        .imports().warning("truncat|bytes are kept").check(check_truncated_names);
    name_mesh_64_mib: glb_case(&edited(|d| d.json["meshes"][0]["name"] = huge_name().into()))
        .imports().warning("truncat|bytes are kept").check(check_truncated_names);
    name_material_64_mib: json_case(&edited(|d| d.json["materials"][0]["name"] = huge_name().into()))
        .imports().warning("truncat|bytes are kept").check(check_truncated_names);
    name_control_characters: json_case(&edited(|d| {
        d.json["nodes"][1]["name"] = "a\u{0}b\u{202e}c\r\n\u{1b}[31m".into();
        d.json["meshes"][0]["name"] = "\u{feff}".into();
        d.json["materials"][0]["name"] = "\u{10ffff}".into();
    })).imports();

    // GLB containers.
    glb_truncated: bytes_case("glb", {
        let bytes = tree().to_glb();
        bytes[..bytes.len() / 2].to_vec()
    }).fails(&[Kind::Gltf, Kind::MissingBuffer], &[]);
    glb_total_length_lie: bytes_case("glb", {
        let mut bytes = tree().to_glb();
        bytes[8..12].copy_from_slice(&0x8000_0000u32.to_le_bytes());
        bytes
    }).fails(&[Kind::Gltf, Kind::MissingBuffer], &[]);
    glb_json_chunk_length_lie: bytes_case("glb", {
        let mut bytes = tree().to_glb();
        bytes[12..16].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        bytes
    }).fails(&[Kind::Gltf, Kind::MissingBuffer], &[]);
    glb_bin_chunk_length_lie: bytes_case("glb", {
        let mut bytes = tree().to_glb();
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        bytes[20 + json_len..24 + json_len].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        bytes
    }).fails(&[Kind::Gltf, Kind::MissingBuffer], &[]);
    glb_no_bin_chunk: bytes_case("glb", {
        let json = serde_json::to_vec(&tree().finished_json(None)).unwrap();
        gltf::glb(&json, None)
    }).missing(&["buffer 0"]);
    glb_bin_shorter_than_buffer: glb_case(&edited(|d| {
        let len = d.bin.len();
        d.json["buffers"][0]["byteLength"] = (len + 100).into();
    })).missing(&["buffer 0"]);
    glb_version_1: bytes_case("glb", {
        let mut bytes = tree().to_glb();
        bytes[4] = 1;
        bytes
    }).fails(&[Kind::Gltf, Kind::Unsupported], &[]);

    // URIs: only inside the model's directory, only regular files.
    uri_relative_inside: file_case(&tree(), |_, _| {}).imports();
    uri_relative_subdirectory: file_case(&buffer_at("data/tree%20buffer.bin"), |model, _| {
        std::fs::create_dir(model.join("data")).unwrap();
        std::fs::write(model.join("data/tree buffer.bin"), tree().bin).unwrap();
    }).imports();
    uri_dotdot: file_case(&buffer_at("../outside/tree.bin"), |_, _| {}).unsupported(&["--allow-external-uris"]);
    uri_dotdot_allowed: file_case(&buffer_at("../outside/tree.bin"), |_, _| {}).limits(external_limits()).imports();
    uri_dotdot_inside_then_out: file_case(&buffer_at("data/../../outside/tree.bin"), |model, _| {
        std::fs::create_dir(model.join("data")).unwrap();
    }).unsupported(&["--allow-external-uris"]);
    uri_percent_encoded_dotdot: file_case(&buffer_at("%2E%2E/outside/tree.bin"), |_, _| {})
        .unsupported(&["--allow-external-uris"]);
    uri_absolute: {
        let (dir, model, outside) = model_dirs();
        let doc = buffer_at(outside.join("tree.bin").to_str().unwrap());
        Case::new(Input::File { path: doc.write_files(&model, "tree"), _dir: Some(dir) })
    }.unsupported(&["--allow-external-uris"]);
    uri_absolute_allowed: {
        let (dir, model, outside) = model_dirs();
        let doc = buffer_at(outside.join("tree.bin").to_str().unwrap());
        Case::new(Input::File { path: doc.write_files(&model, "tree"), _dir: Some(dir) })
    }.limits(external_limits()).imports();
    uri_file_scheme: {
        let (dir, model, outside) = model_dirs();
        let doc = buffer_at(&format!("file://{}", outside.join("tree.bin").display()));
        Case::new(Input::File { path: doc.write_files(&model, "tree"), _dir: Some(dir) })
    }.fails(&[Kind::Unsupported, Kind::MissingBuffer], &[]);
    #[cfg(unix)]
    uri_symlink_out: file_case(&buffer_at("link.bin"), |model, outside| symlink(&outside.join("tree.bin"), &model.join("link.bin")))
        .unsupported(&["--allow-external-uris"]);
    #[cfg(unix)]
    uri_symlinked_directory_out: file_case(&buffer_at("sub/tree.bin"), |model, outside| symlink(outside, &model.join("sub")))
        .unsupported(&["--allow-external-uris"]);
    #[cfg(unix)]
    uri_symlink_out_allowed: file_case(&buffer_at("link.bin"), |model, outside| symlink(&outside.join("tree.bin"), &model.join("link.bin")))
        .limits(external_limits()).imports();
    #[cfg(unix)]
    uri_symlink_inside: file_case(&buffer_at("link.bin"), |model, _| {
        std::fs::write(model.join("real.bin"), tree().bin).unwrap();
        symlink(Path::new("real.bin"), &model.join("link.bin"));
    }).imports();
    uri_image_dotdot: file_case(&image_at("../outside/leaf.png"), |_, _| {}).unsupported(&["--allow-external-uris"]);
    uri_image_absolute: {
        let (dir, model, outside) = model_dirs();
        let doc = image_at(outside.join("leaf.png").to_str().unwrap());
        Case::new(Input::File { path: doc.write_files(&model, "tree"), _dir: Some(dir) })
    }.unsupported(&["--allow-external-uris"]);
    uri_missing_file: file_case(&buffer_at("missing.bin"), |_, _| {}).missing(&["buffer 0", "missing.bin"]);
    uri_missing_image: file_case(&image_at("missing.png"), |_, _| {})
        .fails(&[Kind::MissingBuffer, Kind::Image, Kind::Io], &["missing.png"]);
    uri_directory: file_case(&buffer_at("data"), |model, _| std::fs::create_dir(model.join("data")).unwrap())
        .missing(&["buffer 0", "not a regular file"]).prompt();
    uri_relative_without_base_dir: json_case(&buffer_at("tree.bin")).missing(&["buffer 0"]);
    uri_data_bad_base64: json_case(&buffer_at("data:application/octet-stream;base64,@@@@"))
        .fails(&[Kind::MissingBuffer, Kind::Gltf, Kind::Invalid], &["buffer 0|buffers[0]"]);
    uri_data_not_base64: json_case(&buffer_at("data:application/octet-stream,abcd"))
        .fails(&[Kind::MissingBuffer, Kind::Gltf, Kind::Invalid, Kind::Unsupported], &["buffer 0|buffers[0]"]);
    #[cfg(unix)]
    dev_zero_buffer: file_case(&buffer_at("/dev/zero"), |_, _| {}).unsupported(&["--allow-external-uris"]).prompt();
    #[cfg(unix)]
    dev_zero_buffer_allowed: file_case(&buffer_at("/dev/zero"), |_, _| {}).limits(external_limits())
        .missing(&["buffer 0", "not a regular file"]).prompt();
    #[cfg(unix)]
    dev_zero_image_allowed: file_case(&image_at("/dev/zero"), |_, _| {}).limits(external_limits())
        .fails(&[Kind::MissingBuffer, Kind::Image, Kind::Io, Kind::Invalid], &["not a regular file"]).prompt();
    #[cfg(unix)]
    fifo_buffer: {
        let (dir, model, _) = model_dirs();
        mkfifo(&model.join("pipe.bin"));
        let path = buffer_at("pipe.bin").write_files(&model, "tree");
        Case::new(Input::File { path, _dir: Some(dir) }).fifo(model.join("pipe.bin"))
    }.missing(&["buffer 0", "not a regular file"]);
    #[cfg(unix)]
    fifo_image: {
        let (dir, model, _) = model_dirs();
        mkfifo(&model.join("pipe.png"));
        let path = image_at("pipe.png").write_files(&model, "tree");
        Case::new(Input::File { path, _dir: Some(dir) }).fifo(model.join("pipe.png"))
    }.fails(&[Kind::MissingBuffer, Kind::Image, Kind::Io, Kind::Invalid], &["not a regular file"]);
    #[cfg(unix)]
    fifo_input: {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tree.gltf");
        mkfifo(&path);
        Case::new(Input::File { path: path.clone(), _dir: Some(dir) }).fifo(path)
    }.fails(&[Kind::Io], &[]);
    input_directory: {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tree.gltf");
        std::fs::create_dir(&path).unwrap();
        Case::new(Input::File { path, _dir: Some(dir) }).prompt()
    }.fails(&[Kind::Io], &[]);
}

#[test]
fn error_messages_name_the_primitive_and_accessor_in_glb_too() {
    // The same accessor error in a .gltf and a .glb gives the same message but for the file name.
    let doc = edited(|d| leaf_accessor(d, accessor::LEAF_INDICES)["componentType"] = component::FLOAT.into());
    let limits = ImportLimits::default();
    let a = treelod_build::import_gltf_bytes_with(&doc.to_gltf(), Path::new("x.gltf"), None, &limits);
    let b = treelod_build::import_gltf_bytes_with(&doc.to_glb(), Path::new("x.glb"), None, &limits);
    match (a, b) {
        (Err(a), Err(b)) => assert_eq!(a.to_string().replace("x.gltf", "x.glb"), b.to_string()),
        (a, b) => panic!("both must fail: {:?} / {:?}", a.map(|_| ()), b.map(|_| ())),
    }
}

/// Writes the generator's valid documents (`.gltf` and `.glb`) into `$TREELOD_GLTF_SEEDS` when it
/// is set: seeds for `cargo fuzz run import_gltf` (docs/fuzzing.md). Without it, checks that the
/// seeds are distinct and small.
#[test]
fn write_seeds() {
    let files = gltf::valid_files();
    let mut names: Vec<&str> = files.iter().map(|(name, _)| name.as_str()).collect();
    names.dedup();
    assert_eq!(names.len(), files.len());
    assert!(files.iter().all(|(_, bytes)| bytes.len() < 16 << 10), "seeds stay small");
    if let Some(dir) = std::env::var_os("TREELOD_GLTF_SEEDS") {
        let dir = PathBuf::from(dir);
        std::fs::create_dir_all(&dir).expect("creates the seed directory");
        for (name, bytes) in &files {
            std::fs::write(dir.join(name), bytes).expect("writes a seed");
        }
    }
}
