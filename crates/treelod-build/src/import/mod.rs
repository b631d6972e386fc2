//! glTF 2.0 import: every scene node's triangle primitives, with world transforms applied, into a
//! [`Scene`] in metres, Y up (glTF's own conventions, so the unit scale is 1).
//!
//! Buffers come from the GLB binary chunk, data URIs or files beside a `.gltf`; base-colour
//! textures are decoded (PNG, JPEG) and kept with their original bytes; `KHR_texture_transform`
//! is applied to the texture coordinates and `KHR_mesh_quantization`'s integer attributes are
//! read.
//!
//! The input is untrusted (a library's files, from anywhere), so nothing in it can make the import
//! panic, hang or allocate without bound:
//! - every accessor a primitive uses is validated before it is read (`import/accessor.rs`);
//! - what the file makes the import read, decode and expand is charged to [`ImportLimits`] before
//!   the allocation: bytes (file, buffers, decoded images, accessors per instance), each image's
//!   pixels from its header, node instances after expanding the hierarchy, triangles;
//! - URIs resolve only inside the model's directory unless allowed (`import/uri.rs`), and only regular
//!   files are read (a FIFO would block, `/dev/zero` never end);
//! - names longer than 256 bytes are cut, with a warning.
//!
//! What cannot be read is a typed error naming the file and the glTF object
//! (`meshes[2].primitives[0].indices: accessors[5] …`); what can be skipped is a warning naming the
//! primitive (points and lines, unknown image types).

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;
use std::rc::Rc;

use glam::{Mat3, Mat4, Vec3};
use sha2::Digest as _;

use crate::error::BuildError;
use crate::scene::{AlphaMode, Image, ImageEncoding, Material, Part, Scene, SourceInfo};
use accessor::Use;
use limits::Budget;
pub use limits::{ImportLimits, Limit, read_source};

mod accessor;
mod limits;
mod uri;

/// Extensions that change how geometry or images are stored, which treelod does not decode.
const UNDECODED: [&str; 3] = ["KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_texture_basisu"];

/// `KHR_mesh_quantization`: integer positions, normals and texture coordinates.
const MESH_QUANTIZATION: &str = "KHR_mesh_quantization";

/// The extensions a file may *require*: the import reads them (`KHR_texture_transform` is applied
/// to the texture coordinates, `KHR_mesh_quantization`'s types are read by `accessor`). Any other
/// required extension is refused as unsupported.
const READ_EXTENSIONS: [&str; 2] = ["KHR_texture_transform", MESH_QUANTIZATION];

/// The name a tree imported from `path` gets: the file stem (`"tree"` if there is none). Outputs
/// written to a directory are named after it.
#[must_use]
pub fn scene_name(path: &Path) -> String {
    path.file_stem().map_or_else(|| "tree".to_owned(), |s| s.to_string_lossy().into_owned())
}

/// The content hash an import records for a source file of these bytes (spec §7.1
/// `Source::content_hash`): `"sha256:<lowercase hex>"`.
#[must_use]
pub fn content_hash(bytes: &[u8]) -> String {
    format!("sha256:{}", hex(&sha2::Sha256::digest(bytes)))
}

/// Reads the glTF (`.glb` or `.gltf`) at `path`.
///
/// # Errors
/// [`BuildError::Io`] if the file cannot be read; the other variants for a file that is not
/// valid glTF 2.0 or needs a feature treelod lacks.
pub fn import_gltf(path: &Path) -> Result<Scene, BuildError> {
    import_gltf_with(path, &ImportLimits::default())
}

/// Reads the glTF at `path` within `limits`.
///
/// # Errors
/// As [`import_gltf`]; [`BuildError::Limit`] for a file over a limit.
pub fn import_gltf_with(path: &Path, limits: &ImportLimits) -> Result<Scene, BuildError> {
    let bytes = read_source(path, limits)?;
    import_gltf_bytes_with(&bytes, path, path.parent(), limits)
}

/// Reads a glTF held in memory. `path` names it in messages and metadata; `base_dir` resolves
/// relative buffer and image URIs (none: such URIs are missing).
///
/// # Errors
/// As [`import_gltf`].
pub fn import_gltf_bytes(bytes: &[u8], path: &Path, base_dir: Option<&Path>) -> Result<Scene, BuildError> {
    import_gltf_bytes_with(bytes, path, base_dir, &ImportLimits::default())
}

/// Reads a glTF held in memory within `limits` (`bytes` count towards
/// [`ImportLimits::max_decoded_bytes`]).
///
/// # Errors
/// As [`import_gltf_with`].
pub fn import_gltf_bytes_with(
    bytes: &[u8],
    path: &Path,
    base_dir: Option<&Path>,
    limits: &ImportLimits,
) -> Result<Scene, BuildError> {
    let mut budget = Budget::new(limits, path);
    budget.take_bytes("the file", bytes.len() as u64)?;
    let gltf_error = |message: String| BuildError::Gltf { path: path.to_owned(), message };
    // As `gltf::Gltf::from_slice`, but parsed once and with the binary chunk borrowed from `bytes`
    // rather than copied; the required extensions are checked before validation, which would fail
    // on an undecoded one with a less helpful message.
    let (mut root, blob): (gltf::json::Root, Option<Cow<'_, [u8]>>) = if bytes.starts_with(b"glTF") {
        // `Glb::from_slice` subtracts the 12-byte header from the declared length unchecked.
        if let Some(length) = bytes.get(8..12).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            && length < 12
        {
            return Err(gltf_error(format!("GLB header declares {length} bytes, less than the header's own 12")));
        }
        let glb = gltf::binary::Glb::from_slice(bytes).map_err(|e| gltf_error(e.to_string()))?;
        let root = gltf::json::deserialize::from_slice(&glb.json)
            .map_err(|e| gltf_error(gltf::Error::Deserialize(e).to_string()))?;
        (root, glb.bin)
    } else {
        let root = gltf::json::deserialize::from_slice(bytes)
            .map_err(|e| gltf_error(gltf::Error::Deserialize(e).to_string()))?;
        (root, None)
    };
    check_required_extensions(&root, path)?;
    let quantization = root.extensions_used.iter().chain(&root.extensions_required).any(|e| e == MESH_QUANTIZATION);
    // Every required extension is one this importer reads (checked above); `gltf`'s validation
    // knows only those its own features enable and would refuse `KHR_mesh_quantization`.
    root.extensions_required.clear();
    // gltf-json's validation indexes `accessors` with a primitive's POSITION index unchecked
    // (gltf-json 1.4.1, mesh.rs): an index past the end would panic there, so it is refused here.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let position = gltf::json::validation::Checked::Valid(gltf::json::mesh::Semantic::Positions);
            if let Some(index) = primitive.attributes.get(&position)
                && index.value() >= root.accessors.len()
            {
                return Err(gltf_error(format!(
                    "invalid: meshes[{m}].primitives[{p}].attributes.POSITION: accessor {} does not exist ({} accessors)",
                    index.value(),
                    root.accessors.len()
                )));
            }
        }
    }
    let document = match gltf::Document::from_json(root) {
        Ok(d) => d,
        Err(gltf::Error::Validation(errors)) => {
            let list: Vec<String> = errors.iter().take(3).map(|(p, e)| format!("{p}: {e}")).collect();
            return Err(gltf_error(format!("invalid: {}", list.join("; "))));
        }
        Err(e) => return Err(gltf_error(e.to_string())),
    };
    let roots: Vec<gltf::Node> = match document.default_scene().or_else(|| document.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let children: std::collections::BTreeSet<usize> =
                document.nodes().flat_map(|n| n.children().map(|c| c.index())).collect();
            document.nodes().filter(|n| !children.contains(&n.index())).collect()
        }
    };
    // The instances and triangles the node hierarchy expands to, counted from the JSON before any
    // buffer is read, so a file that would expand past a limit costs nothing.
    count_instances(&document, &roots, quantization, path, &mut budget)?;
    let buffers = load_buffers(&document, blob, path, base_dir, &mut budget)?;
    let mut scene = Scene {
        name: scene_name(path),
        source: SourceInfo {
            path: path.to_string_lossy().replace('\\', "/"),
            content_hash: content_hash(bytes),
            byte_length: bytes.len() as u64,
            unit_scale: 1.0,
        },
        ..Scene::default()
    };
    scene.images = load_images(&document, &buffers, path, base_dir, &mut budget, &mut scene.warnings)?;
    // Per material: the texture coordinate set its base colour reads and that set's transform.
    let mut texturing: Vec<(u32, Option<UvTransform>)> = Vec::new();
    for m in document.materials() {
        let pbr = m.pbr_metallic_roughness();
        let texture = pbr.base_color_texture();
        let transform = texture.as_ref().and_then(gltf::texture::Info::texture_transform);
        let set = transform.as_ref().and_then(gltf::texture::TextureTransform::tex_coord);
        let set = set.unwrap_or_else(|| texture.as_ref().map_or(0, gltf::texture::Info::tex_coord));
        texturing.push((set, transform.as_ref().map(UvTransform::new).filter(|t| !t.is_identity())));
        let image = texture.map(|t| t.texture().source().index()).filter(|&i| scene.images[i].width > 0);
        let what = format!("materials[{}].name", m.index().unwrap_or(0));
        let base_color = pbr.base_color_factor();
        let alpha_cutoff = m.alpha_cutoff().unwrap_or(0.5);
        if !base_color.iter().all(|c| c.is_finite()) || !alpha_cutoff.is_finite() {
            return Err(BuildError::InvalidData {
                path: path.to_owned(),
                what: format!(
                    "materials[{}]: baseColorFactor {base_color:?} and alphaCutoff {alpha_cutoff} must be finite",
                    m.index().unwrap_or(0)
                ),
            });
        }
        scene.materials.push(Material {
            name: bounded_name(m.name().unwrap_or(""), &what, &mut scene.warnings),
            base_color,
            image,
            alpha_mode: match m.alpha_mode() {
                gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
                gltf::material::AlphaMode::Mask => AlphaMode::Mask,
                gltf::material::AlphaMode::Blend => AlphaMode::Blend,
            },
            alpha_cutoff,
            double_sided: m.double_sided(),
        });
    }
    let default_material = scene.materials.len();
    let source = accessor::Source { buffers: &buffers, quantization, path };
    // Each primitive is read once, in its mesh's space, and placed at each of its instances.
    let mut primitives: BTreeMap<(usize, usize), Option<Rc<LocalPrimitive>>> = BTreeMap::new();
    let mut names: BTreeMap<(&'static str, usize), String> = BTreeMap::new();
    // Bounded: `count_instances` refused cycles, depths over `MAX_DEPTH` and instances over the
    // limit.
    let mut stack: Vec<(gltf::Node, Mat4)> = roots.into_iter().rev().map(|n| (n, Mat4::IDENTITY)).collect();
    while let Some((node, parent)) = stack.pop() {
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            let mut name = |kind: &'static str, index: usize, name: Option<&str>, warnings: &mut Vec<String>| {
                names
                    .entry((kind, index))
                    .or_insert_with(|| bounded_name(name.unwrap_or(""), &format!("{kind}[{index}].name"), warnings))
                    .clone()
            };
            let mesh_name = name("meshes", mesh.index(), mesh.name(), &mut scene.warnings);
            let node_name = name("nodes", node.index(), node.name(), &mut scene.warnings);
            for primitive in mesh.primitives() {
                let label = format!("meshes[{}].primitives[{}]", mesh.index(), primitive.index());
                let material = primitive.material().index().unwrap_or(default_material);
                let (set, transform) = texturing.get(material).copied().unwrap_or((0, None));
                let local = match primitives.get(&(mesh.index(), primitive.index())) {
                    Some(local) => local.clone(),
                    None => {
                        let read = read_primitive(
                            &primitive,
                            &label,
                            &source,
                            set,
                            transform,
                            &mut budget,
                            &mut scene.warnings,
                        )?
                        .map(Rc::new);
                        primitives.insert((mesh.index(), primitive.index()), read.clone());
                        read
                    }
                };
                let Some(local) = local else { continue };
                let mut part = local.place(world, &label, &mut budget)?;
                part.primitive = primitive.index();
                part.node_name = node_name.clone();
                part.mesh_name = mesh_name.clone();
                part.material = material;
                scene.parts.push(part);
            }
        }
        stack.extend(node.children().collect::<Vec<_>>().into_iter().rev().map(|c| (c, world)));
    }
    if scene.parts.iter().any(|p| p.material == default_material) {
        scene.materials.push(Material { base_color: [1.0; 4], alpha_cutoff: 0.5, ..Material::default() });
    }
    Ok(scene)
}

/// Refuses required extensions this importer does not read: the compression ones with a hint to
/// decode them first, any other by name (exit 4, unsupported, in the tool).
fn check_required_extensions(root: &gltf::json::Root, path: &Path) -> Result<(), BuildError> {
    for ext in &root.extensions_required {
        if UNDECODED.contains(&ext.as_str()) {
            return Err(BuildError::Unsupported {
                path: path.to_owned(),
                what: format!("required extension {ext} (decode it first, e.g. with gltf-transform)"),
            });
        }
        if !READ_EXTENSIONS.contains(&ext.as_str()) {
            return Err(BuildError::Unsupported {
                path: path.to_owned(),
                what: format!(
                    "required extension {ext} (treelod reads {}; a file that requires another cannot be drawn as its author meant)",
                    READ_EXTENSIONS.join(" and ")
                ),
            });
        }
    }
    Ok(())
}

/// Longest name (bytes) kept for a material, mesh or node: names only classify parts and label
/// messages and metadata, and a hostile file's 64 MB name must not reach the container.
const MAX_NAME_BYTES: usize = 256;

/// `name`, cut to [`MAX_NAME_BYTES`] at a character boundary with a warning naming `what`.
fn bounded_name(name: &str, what: &str, warnings: &mut Vec<String>) -> String {
    if name.len() <= MAX_NAME_BYTES {
        return name.to_owned();
    }
    let mut end = MAX_NAME_BYTES;
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    warnings.push(format!("{what} is {} bytes long; its first {end} bytes are kept", name.len()));
    name[..end].to_owned()
}

/// `KHR_texture_transform` of a base-colour texture: `uv' = T · R · S · uv` (offset, rotation
/// counter-clockwise in UV space, scale), applied to the texture coordinates at import, so the
/// container's single UV set addresses the image directly.
#[derive(Clone, Copy, Debug, PartialEq)]
struct UvTransform {
    /// Rows of the 2×3 affine map.
    rows: [[f32; 3]; 2],
}

impl UvTransform {
    fn new(t: &gltf::texture::TextureTransform<'_>) -> Self {
        let ([ox, oy], r, [sx, sy]) = (t.offset(), t.rotation(), t.scale());
        let (sin, cos) = r.sin_cos();
        Self { rows: [[cos * sx, sin * sy, ox], [-sin * sx, cos * sy, oy]] }
    }

    fn is_identity(&self) -> bool {
        self.rows == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    }

    fn apply(&self, [u, v]: [f32; 2]) -> [f32; 2] {
        let [a, b] = self.rows;
        [a[0] * u + a[1] * v + a[2], b[0] * u + b[1] * v + b[2]]
    }
}

fn load_buffers<'a>(
    document: &gltf::Document,
    mut blob: Option<Cow<'a, [u8]>>,
    path: &Path,
    base_dir: Option<&Path>,
    budget: &mut Budget<'_>,
) -> Result<Vec<Cow<'a, [u8]>>, BuildError> {
    let mut out = Vec::new();
    for buffer in document.buffers() {
        let missing = |uri: &str, reason: String| BuildError::MissingBuffer {
            path: path.to_owned(),
            index: buffer.index(),
            uri: uri.to_owned(),
            reason,
        };
        let what = format!("buffers[{}]", buffer.index());
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => {
                blob.take().ok_or_else(|| missing("GLB binary chunk", "the file has no binary chunk".into()))?
            }
            gltf::buffer::Source::Uri(uri) => Cow::Owned(
                read_uri(uri, base_dir, &what, path, budget)?.map_err(|reason| missing(&shown_uri(uri), reason))?,
            ),
        };
        if data.len() < buffer.length() {
            let uri = match buffer.source() {
                gltf::buffer::Source::Bin => "GLB binary chunk".to_owned(),
                gltf::buffer::Source::Uri(u) => shown_uri(u),
            };
            return Err(missing(&uri, format!("{} bytes, the file declares {}", data.len(), buffer.length())));
        }
        out.push(data);
    }
    Ok(out)
}

/// A URI as messages show it: data URIs cut after their media type.
fn shown_uri(uri: &str) -> String {
    match uri.strip_prefix("data:") {
        Some(rest) => format!("data:{}…", rest.split([';', ',']).next().unwrap_or("")),
        None if uri.len() > 200 => format!("{}…", uri.chars().take(200).collect::<String>()),
        None => uri.to_owned(),
    }
}

/// Bytes of a data URI or of a regular file relative to `base_dir`, charged to `budget` (`what`:
/// the glTF object, for a limit error). The outer error stops the import (a limit, a URI outside
/// the model's directory); the inner one is the reason the resource cannot be read.
fn read_uri(
    uri: &str,
    base_dir: Option<&Path>,
    what: &str,
    path: &Path,
    budget: &mut Budget<'_>,
) -> Result<Result<Vec<u8>, String>, BuildError> {
    use base64::Engine as _;
    if let Some(rest) = uri.strip_prefix("data:") {
        let Some((_, data)) = rest.split_once(";base64,") else {
            return Ok(Err("a data URI that is not base64".into()));
        };
        budget.take_bytes(what, (data.len() as u64).div_ceil(4) * 3)?;
        return Ok(base64::engine::general_purpose::STANDARD.decode(data).map_err(|e| format!("bad base64: {e}")));
    }
    let Some(dir) = base_dir else { return Ok(Err("no directory to resolve a relative URI".into())) };
    let file = match uri::resolve(uri, dir, budget.limits().allow_external_uris) {
        Ok(file) => file,
        Err(uri::Refused::Outside) => {
            return Err(BuildError::Unsupported {
                path: path.to_owned(),
                what: format!(
                    "{what} ({}) lies outside the model's directory; pass --allow-external-uris to read it",
                    shown_uri(uri)
                ),
            });
        }
        Err(uri::Refused::Scheme) => {
            return Ok(Err("not a relative file URI or data URI (treelod reads no network resources)".into()));
        }
    };
    match read_regular_file(&file, budget.bytes_left()) {
        Ok(bytes) => {
            budget.take_bytes(what, bytes.len() as u64)?;
            Ok(Ok(bytes))
        }
        Err(ReadError::TooLarge(n)) => {
            budget.take_bytes(what, n)?;
            Ok(Err(format!("{n} bytes")))
        }
        Err(e) => Ok(Err(format!("{}: {e}", file.display()))),
    }
}

fn percent_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%'
            && let Some(v) = s.get(i + 1..i + 3).and_then(|h| u8::from_str_radix(h, 16).ok())
        {
            out.push(v);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The document's images in its order: each base colour texture decoded (with its encoded
/// bytes), every other image an empty place.
fn load_images(
    document: &gltf::Document,
    buffers: &[Cow<'_, [u8]>],
    path: &Path,
    base_dir: Option<&Path>,
    budget: &mut Budget<'_>,
    warnings: &mut Vec<String>,
) -> Result<Vec<Image>, BuildError> {
    // Only a material's base colour texture is drawn: the other images (normal, roughness and
    // occlusion maps) are neither read nor decoded, nor counted against the limits, and keep an
    // empty place (4.2 MB of the shared maple's peak memory, a 1024² normal map).
    let mut base_colour = vec![false; document.images().len()];
    for m in document.materials() {
        if let Some(info) = m.pbr_metallic_roughness().base_color_texture()
            && let Some(slot) = base_colour.get_mut(info.texture().source().index())
        {
            *slot = true;
        }
    }
    let mut images = Vec::new();
    for image in document.images() {
        let index = image.index();
        if !base_colour[index] {
            images.push(Image::NONE);
            continue;
        }
        let what = format!("images[{index}]");
        let image_error = |message: String| BuildError::Image { path: path.to_owned(), index, message };
        // From the JSON rather than `gltf::Image::source`, which unwraps a missing mime type (of a
        // buffer-view image) and a missing URI (of an image with neither).
        let json = &document.as_json().images[index];
        let mime = json.mime_type.as_ref().map(|m| m.0.clone());
        let bytes = match (json.buffer_view, json.uri.as_deref()) {
            (Some(view), _) => {
                // A view index of a validated document exists.
                let view = document.views().nth(view.value());
                let data = view.as_ref().and_then(|view| {
                    buffers.get(view.buffer().index())?.get(view.offset()..view.offset().checked_add(view.length())?)
                });
                let data = data.ok_or_else(|| image_error("its buffer view lies outside the buffer".into()))?;
                budget.take_bytes(&what, data.len() as u64)?;
                data.to_vec()
            }
            (None, Some(uri)) => read_uri(uri, base_dir, &what, path, budget)?.map_err(image_error)?,
            (None, None) => return Err(image_error("it has neither a uri nor a bufferView".into())),
        };
        let Some(size) = treelod_format::image::encoded_size(&bytes) else {
            warnings.push(format!(
                "image {index} ({}) is neither PNG nor JPEG; its materials are drawn untextured",
                mime.unwrap_or_default()
            ));
            images.push(Image::NONE);
            continue;
        };
        let (w, h) = size.map_err(image_error)?;
        if w == 0 || h == 0 {
            return Err(image_error(format!("its header declares {w}x{h} pixels")));
        }
        let max = treelod_format::MAX_IMAGE_SIDE;
        if w > max || h > max {
            return Err(BuildError::Unsupported {
                path: path.to_owned(),
                what: format!(
                    "{what} is {w}x{h} pixels; a container holds images of at most {max} per side (scale it down)"
                ),
            });
        }
        budget.take_image(&what, w, h)?;
        let decoded = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
            treelod_format::image::decode_png(&bytes).map(|(w, h, rgba)| (w, h, rgba, ImageEncoding::Png))
        } else {
            treelod_format::image::decode_jpeg(&bytes).map(|(w, h, rgba)| (w, h, rgba, ImageEncoding::Jpeg))
        };
        let (width, height, rgba, encoding) = decoded.map_err(image_error)?;
        if (width, height) != (w, h) {
            return Err(image_error(format!("decodes to {width}x{height}, its header declares {w}x{h}")));
        }
        images.push(Image { width, height, rgba, encoded: bytes, encoding });
    }
    Ok(images)
}

/// Deepest node hierarchy read (levels below a scene's root).
const MAX_DEPTH: usize = 256;

/// Counts what the node hierarchy below `roots` expands to — node instances (a node once per path
/// from a root) and the triangles of the primitives they instance, from the accessors' declared
/// counts — and charges both to `budget`, before any buffer is read. Each node's subtree is
/// counted once (memoised), so a hierarchy that doubles at each of 25 levels costs 25 steps, not
/// 2^25. A cycle or a hierarchy deeper than [`MAX_DEPTH`] is invalid.
fn count_instances(
    document: &gltf::Document,
    roots: &[gltf::Node<'_>],
    quantization: bool,
    path: &Path,
    budget: &mut Budget<'_>,
) -> Result<(), BuildError> {
    #[derive(Clone, Copy)]
    enum State {
        Unseen,
        Open,
        Done(u64, u64),
    }
    struct Counter<'d> {
        states: Vec<State>,
        mesh_triangles: Vec<Option<u64>>,
        source: accessor::Source<'d, 'd>,
        budget: &'d Budget<'d>,
    }
    impl Counter<'_> {
        fn mesh(&mut self, mesh: &gltf::Mesh<'_>) -> Result<u64, BuildError> {
            if let Some(t) = self.mesh_triangles[mesh.index()] {
                return Ok(t);
            }
            let mut total = 0u64;
            for primitive in mesh.primitives() {
                let label = format!("meshes[{}].primitives[{}]", mesh.index(), primitive.index());
                let triangles = triangle_count(&primitive, &self.source, &label)?;
                // One primitive over the limit is named as the cause.
                self.budget.check(Limit::Triangles, &label, triangles)?;
                total = total.saturating_add(triangles);
            }
            self.mesh_triangles[mesh.index()] = Some(total);
            Ok(total)
        }

        /// Instances and triangles of `node`'s subtree.
        fn node(&mut self, node: &gltf::Node<'_>, depth: usize) -> Result<(u64, u64), BuildError> {
            let invalid = |what: String| BuildError::Gltf { path: self.source.path.to_owned(), message: what };
            match self.states[node.index()] {
                State::Done(instances, triangles) => return Ok((instances, triangles)),
                State::Open => {
                    return Err(invalid(format!("invalid: nodes[{}] is its own descendant (a cycle)", node.index())));
                }
                State::Unseen => {}
            }
            if depth > MAX_DEPTH {
                return Err(invalid(format!(
                    "node hierarchy deeper than {MAX_DEPTH} levels at nodes[{}]",
                    node.index()
                )));
            }
            self.states[node.index()] = State::Open;
            let mut instances = 1u64;
            let mut triangles = match node.mesh() {
                Some(mesh) => self.mesh(&mesh)?,
                None => 0,
            };
            for child in node.children() {
                let (i, t) = self.node(&child, depth + 1)?;
                instances = instances.saturating_add(i);
                triangles = triangles.saturating_add(t);
            }
            self.states[node.index()] = State::Done(instances, triangles);
            Ok((instances, triangles))
        }
    }
    let mut counter = Counter {
        states: vec![State::Unseen; document.nodes().len()],
        mesh_triangles: vec![None; document.meshes().len()],
        source: accessor::Source { buffers: &[], quantization, path },
        budget,
    };
    let (mut instances, mut triangles) = (0u64, 0u64);
    for root in roots {
        let (i, t) = counter.node(root, 0)?;
        instances = instances.saturating_add(i);
        triangles = triangles.saturating_add(t);
    }
    drop(counter);
    budget.take_instances("the node hierarchy", instances)?;
    budget.take_triangles("the node hierarchy's primitives", triangles)
}

/// The triangles a primitive makes, from its accessors' declared counts (checked for their use).
fn triangle_count(
    primitive: &gltf::Primitive<'_>,
    source: &accessor::Source<'_, '_>,
    label: &str,
) -> Result<u64, BuildError> {
    let corners = match primitive.indices() {
        Some(indices) => source.count(&indices, Use::Indices, &format!("{label}.indices"))?,
        None => match primitive.get(&gltf::Semantic::Positions) {
            Some(positions) => source.count(&positions, Use::Position, &format!("{label}.attributes.POSITION"))?,
            None => 0,
        },
    } as u64;
    Ok(match primitive.mode() {
        gltf::mesh::Mode::Triangles => corners / 3,
        gltf::mesh::Mode::TriangleStrip | gltf::mesh::Mode::TriangleFan => corners.saturating_sub(2),
        _ => 0,
    })
}

/// A primitive read in its mesh's space, shared by the mesh's instances.
struct LocalPrimitive {
    positions: Vec<[f32; 3]>,
    /// The file's normals, or `None`: computed from the faces at each instance, in world space.
    normals: Option<Vec<[f32; 3]>>,
    uvs: Vec<[f32; 2]>,
    colors: Vec<[f32; 4]>,
    triangles: Vec<[u32; 3]>,
}

impl LocalPrimitive {
    /// The primitive at one instance: positions and normals in world space, winding kept
    /// counter-clockwise under a mirroring transform.
    fn place(&self, world: Mat4, label: &str, budget: &mut Budget<'_>) -> Result<Part, BuildError> {
        let n = self.positions.len() as u64;
        let bytes = n * (12 + 12 + 8 * u64::from(!self.uvs.is_empty()) + 16 * u64::from(!self.colors.is_empty()))
            + 12 * self.triangles.len() as u64;
        budget.take_bytes(label, bytes)?;
        let flip = world.determinant() < 0.0;
        let positions: Vec<[f32; 3]> =
            self.positions.iter().map(|&p| world.transform_point3(Vec3::from_array(p)).to_array()).collect();
        let triangles: Vec<[u32; 3]> =
            self.triangles.iter().map(|&t| if flip { [t[0], t[2], t[1]] } else { t }).collect();
        let normals = match &self.normals {
            Some(normals) => {
                let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
                normals
                    .iter()
                    .map(|&v| (normal_matrix * Vec3::from_array(v)).normalize_or(Vec3::Y).to_array())
                    .collect()
            }
            None => face_normals(&positions, &triangles),
        };
        Ok(Part {
            positions,
            normals,
            uvs: self.uvs.clone(),
            colors: self.colors.clone(),
            triangles,
            ..Part::default()
        })
    }
}

/// Reads one primitive in its mesh's space, every accessor validated first (`accessor`), or
/// `None` (with a warning) if it holds no triangles.
fn read_primitive(
    primitive: &gltf::Primitive<'_>,
    label: &str,
    source: &accessor::Source<'_, '_>,
    tex_coord_set: u32,
    transform: Option<UvTransform>,
    budget: &mut Budget<'_>,
    warnings: &mut Vec<String>,
) -> Result<Option<LocalPrimitive>, BuildError> {
    let mode = primitive.mode();
    if !matches!(mode, gltf::mesh::Mode::Triangles | gltf::mesh::Mode::TriangleStrip | gltf::mesh::Mode::TriangleFan) {
        warnings.push(format!("{label}: {mode:?} primitive is not triangles, skipped"));
        return Ok(None);
    }
    let attribute = |semantic: gltf::Semantic| {
        primitive.get(&semantic).map(|a| (a, format!("{label}.attributes.{}", semantic.to_string())))
    };
    let Some((position, position_path)) = attribute(gltf::Semantic::Positions) else {
        warnings.push(format!("{label}: no POSITION attribute, skipped"));
        return Ok(None);
    };
    let positions: Vec<[f32; 3]> = source.read_floats(&position, Use::Position, &position_path, budget)?;
    let n = positions.len();
    let corners: Vec<u32> = match primitive.indices() {
        Some(indices) => {
            let indices_path = format!("{label}.indices");
            let corners = source.read_indices(&indices, &indices_path, budget)?;
            if let Some(bad) = corners.iter().find(|&&i| i as usize >= n) {
                return Err(BuildError::InvalidData {
                    path: source.path.to_owned(),
                    what: format!(
                        "{indices_path}: index {bad} out of range: the primitive has {n} vertices (indices 0..={})",
                        n - 1
                    ),
                });
            }
            corners
        }
        #[expect(clippy::cast_possible_truncation, reason = "accessor counts are below the decoded-byte limit")]
        None => (0..n as u32).collect(),
    };
    let triangles: Vec<[u32; 3]> = match mode {
        gltf::mesh::Mode::TriangleStrip => corners
            .windows(3)
            .enumerate()
            .map(|(i, t)| if i % 2 == 0 { [t[0], t[1], t[2]] } else { [t[1], t[0], t[2]] })
            .collect(),
        gltf::mesh::Mode::TriangleFan => corners.windows(2).skip(1).map(|t| [corners[0], t[0], t[1]]).collect(),
        _ => corners.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
    };
    drop(corners);
    let same_count = |what: &str, count: usize| {
        if count == n {
            Ok(())
        } else {
            Err(BuildError::InvalidData {
                path: source.path.to_owned(),
                what: format!(
                    "{what} has {count} elements, POSITION has {n}: a primitive's attributes must have the same count"
                ),
            })
        }
    };
    let normals = match attribute(gltf::Semantic::Normals) {
        Some((accessor, at)) => {
            let normals: Vec<[f32; 3]> = source.read_floats(&accessor, Use::Normal, &at, budget)?;
            same_count(&at, normals.len())?;
            Some(normals)
        }
        None => {
            warnings.push(format!("{label}: no normals, computed from the faces"));
            None
        }
    };
    let uvs: Vec<[f32; 2]> = match attribute(gltf::Semantic::TexCoords(tex_coord_set)) {
        Some((accessor, at)) => {
            let uvs: Vec<[f32; 2]> = source.read_floats(&accessor, Use::TexCoord, &at, budget)?;
            same_count(&at, uvs.len())?;
            match transform {
                Some(t) => {
                    let uvs: Vec<[f32; 2]> = uvs.into_iter().map(|uv| t.apply(uv)).collect();
                    if let Some(i) = uvs.iter().position(|uv| !uv.iter().all(|x| x.is_finite())) {
                        return Err(BuildError::InvalidData {
                            path: source.path.to_owned(),
                            what: format!(
                                "{at}: the material's KHR_texture_transform maps element {i} to {:?}, not finite",
                                uvs[i]
                            ),
                        });
                    }
                    uvs
                }
                None => uvs,
            }
        }
        None => Vec::new(),
    };
    let colors: Vec<[f32; 4]> = match attribute(gltf::Semantic::Colors(0)) {
        Some((accessor, at)) => {
            let colors: Vec<[f32; 4]> = source.read_floats(&accessor, Use::Color, &at, budget)?;
            same_count(&at, colors.len())?;
            colors
        }
        None => Vec::new(),
    };
    Ok(Some(LocalPrimitive { positions, normals, uvs, colors, triangles }))
}

/// Area-weighted vertex normals.
fn face_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| Vec3::from_array(positions[i as usize]));
        let n = (b - a).cross(c - a);
        if n.is_finite() {
            for &i in t {
                acc[i as usize] += n;
            }
        }
    }
    acc.into_iter().map(|n| n.normalize_or(Vec3::Y).to_array()).collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Why a file could not be read whole.
#[derive(Debug)]
enum ReadError {
    /// The operating system's error.
    Io(std::io::Error),
    /// Not a regular file: what it is instead.
    NotRegular(&'static str),
    /// Longer than the bytes allowed: its length.
    TooLarge(u64),
}

impl ReadError {
    /// The error of reading the source file `path` ([`read_source`]): [`BuildError::Io`], or
    /// [`BuildError::Limit`] for a file larger than the decoded-byte limit.
    fn into_build_error(self, path: &Path, limits: &ImportLimits) -> BuildError {
        match self {
            Self::Io(source) => BuildError::Io { path: path.to_owned(), source },
            Self::NotRegular(kind) => BuildError::Io {
                path: path.to_owned(),
                source: std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("not a regular file ({kind})")),
            },
            Self::TooLarge(amount) => BuildError::Limit {
                path: path.to_owned(),
                what: "the file".to_owned(),
                limit: Limit::DecodedBytes,
                amount,
                max: limits.max_decoded_bytes,
            },
        }
    }
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Io(e) => write!(f, "{e}"),
            Self::NotRegular(kind) => write!(f, "not a regular file ({kind})"),
            Self::TooLarge(n) => write!(f, "{n} bytes, more than the {} limit allows", Limit::DecodedBytes.option()),
        }
    }
}

/// The whole of a regular file of at most `max` bytes. Devices, FIFOs and directories are refused
/// before they are opened for reading (a FIFO would block, `/dev/zero` never end); the length is
/// checked from the metadata first and the read stops at `max + 1` bytes in case the file grows.
fn read_regular_file(path: &Path, max: u64) -> Result<Vec<u8>, ReadError> {
    use std::io::Read as _;
    let meta = std::fs::metadata(path).map_err(ReadError::Io)?;
    let kind = meta.file_type();
    if !kind.is_file() {
        return Err(ReadError::NotRegular(file_kind(&kind)));
    }
    if meta.len() > max {
        return Err(ReadError::TooLarge(meta.len()));
    }
    let file = std::fs::File::open(path).map_err(ReadError::Io)?;
    // The metadata may be stale: never read more than the limit.
    let mut bytes = Vec::with_capacity(usize::try_from(meta.len()).unwrap_or(0));
    file.take(max.saturating_add(1)).read_to_end(&mut bytes).map_err(ReadError::Io)?;
    if bytes.len() as u64 > max {
        return Err(ReadError::TooLarge(bytes.len() as u64));
    }
    Ok(bytes)
}

/// What a file that is not a regular file is, for messages.
fn file_kind(kind: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        if kind.is_fifo() {
            return "a FIFO";
        }
        if kind.is_char_device() {
            return "a character device";
        }
        if kind.is_block_device() {
            return "a block device";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    if kind.is_dir() { "a directory" } else { "not a file" }
}
