//! Scene files: which containers to draw and where, for `treelod render` and `treelod view`.
//!
//! A path ending in `.treelod` is a scene of its own: one model drawn once with the identity
//! transform. Any other path is read as a JSON scene file (version 1):
//!
//! ```json
//! {
//!   "version": 1,
//!   "models": ["oak.treelod", "../trees/maple.treelod"],
//!   "instances": [
//!     {"model": 0, "translation": [0.0, 0.0, 0.0]},
//!     {"model": 1, "translation": [12.5, 0.0, -3.0], "rotation_y_degrees": 30.0, "scale": 1.1},
//!     {"model": 0, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 5,0,5,1]}
//!   ]
//! }
//! ```
//!
//! - `version` (required): 1. A larger version is refused as unsupported, anything else as invalid.
//! - `models` (required, at least one): container paths, relative to the directory of the scene
//!   file (absolute paths are used as they are). Every one must exist.
//! - `instances` (required, may be empty): each names a `model` (index into `models`) and either
//!   `translation` `[x, y, z]` (metres; required in this form) with optional `rotation_y_degrees`
//!   (about +y, counter-clockwise seen from above; default 0) and `scale` (uniform, positive;
//!   default 1), applied as scale, then rotation, then translation; or `matrix`: the 16 numbers
//!   of a world-from-model affine matrix, column-major (OpenGL/glam order: the translation is
//!   elements 12..15), whose last row is `0 0 0 1` and whose determinant is not zero. The renderer
//!   expects rotations, translations and uniform scales.
//! - Unknown fields are refused everywhere, so a misspelt field is an error rather than ignored.
//!
//! Every error names the scene file (or the model file) and what is wrong; bad input never panics.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Quat, Vec3};
use serde::Deserialize;
use treelod_format::{Container, ErrorClass};
use treelod_render::{Instance, Renderer};

/// The scene format version this build reads and writes.
pub const VERSION: u32 = 1;

/// Models and where their instances stand.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Container paths, resolved against the scene file's directory.
    pub models: Vec<PathBuf>,
    /// Instances, each an index into [`Self::models`] and a world-from-model transform.
    pub instances: Vec<SceneInstance>,
}

/// One placed tree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneInstance {
    /// Index into [`Scene::models`].
    pub model: usize,
    /// World from model.
    pub transform: Mat4,
}

/// Why a scene could not be loaded or added to a renderer. Every message starts with the path of
/// the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file (or a `.treelod` given as the scene) cannot be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// The scene file is not JSON, or not JSON of the scene format.
    #[error("{}: line {line}, column {column}: {message}", path.display())]
    Json {
        /// The scene file.
        path: PathBuf,
        /// Line of the problem, 1-based (0 if unknown).
        line: usize,
        /// Column of the problem, 1-based (0 if unknown).
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// The scene file's `version` is not one this build reads.
    #[error("{}: unknown scene version {version}: this treelod reads version {VERSION}", path.display())]
    Version {
        /// The scene file.
        path: PathBuf,
        /// The version found.
        version: u64,
    },
    /// The scene is well-formed JSON but breaks a rule of the format.
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The scene file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An instance names a model the scene does not list.
    #[error("{}: instance {instance}: model {model} is out of range (the scene lists {count} model(s))", path.display())]
    ModelIndex {
        /// The scene file.
        path: PathBuf,
        /// Index of the instance.
        instance: usize,
        /// The model index it names.
        model: usize,
        /// Models listed.
        count: usize,
    },
    /// A model file of the scene cannot be found or read.
    #[error("{}: model {index}: {}: {source}", path.display(), model.display())]
    MissingModel {
        /// The scene file.
        path: PathBuf,
        /// Index of the model.
        index: usize,
        /// The model path, resolved against the scene file's directory.
        model: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// A model is not a valid container.
    #[error("{}: {}", path.display(), format_reason(source))]
    Container {
        /// The model file.
        path: PathBuf,
        /// Why it does not open.
        source: treelod_format::Error,
    },
    /// The renderer refused a model.
    #[error("{}: {source}", path.display())]
    Render {
        /// The model file.
        path: PathBuf,
        /// Why.
        source: treelod_render::RenderError,
    },
}

impl SceneError {
    /// The class of the failure, which decides the exit code: unreadable files are
    /// [`ErrorClass::Io`], newer scene versions and models the device cannot hold
    /// [`ErrorClass::Unsupported`], the rest [`ErrorClass::Invalid`].
    #[must_use]
    pub fn class(&self) -> ErrorClass {
        match self {
            Self::Io { .. } | Self::MissingModel { .. } => ErrorClass::Io,
            Self::Version { version, .. } if *version > u64::from(VERSION) => ErrorClass::Unsupported,
            Self::Container { source, .. } => source.class(),
            Self::Render { .. } => ErrorClass::Unsupported,
            Self::Version { .. } | Self::Json { .. } | Self::Invalid { .. } | Self::ModelIndex { .. } => {
                ErrorClass::Invalid
            }
        }
    }
}

/// A format error without the path the format crate wraps around it (the message names it).
fn format_reason(error: &treelod_format::Error) -> String {
    match error {
        treelod_format::Error::InFile { source, .. } => format_reason(source),
        treelod_format::Error::Io { source, .. } => source.to_string(),
        other => other.to_string(),
    }
}

/// Whether `path` names a container rather than a scene file.
#[must_use]
pub fn is_container_path(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("treelod"))
}

/// Whether `path` names a glTF file: extension `.glb` or `.gltf`, any case.
#[must_use]
pub fn is_gltf_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("glb") || e.eq_ignore_ascii_case("gltf"))
}

impl Scene {
    /// One model, `path`, drawn once at the origin.
    #[must_use]
    pub fn single(path: &Path) -> Self {
        Self { models: vec![path.to_owned()], instances: vec![SceneInstance { model: 0, transform: Mat4::IDENTITY }] }
    }
}

/// Loads a scene. A `.treelod` path gives one model with one identity instance; otherwise a JSON
/// scene file (see the module documentation), whose model files must exist.
///
/// # Errors
/// [`SceneError`] naming the file and what is wrong.
pub fn load(path: &Path) -> Result<Scene, SceneError> {
    if is_container_path(path) {
        let metadata = std::fs::metadata(path).map_err(|source| SceneError::Io { path: path.to_owned(), source })?;
        if metadata.is_dir() {
            return Err(SceneError::Invalid {
                path: path.to_owned(),
                message: "is a directory, not a .treelod file".to_owned(),
            });
        }
        return Ok(Scene::single(path));
    }
    let bytes = std::fs::read(path).map_err(|source| SceneError::Io { path: path.to_owned(), source })?;
    let scene = parse(&bytes, path)?;
    for (index, model) in scene.models.iter().enumerate() {
        match std::fs::metadata(model) {
            Ok(m) if m.is_dir() => {
                return Err(SceneError::Invalid {
                    path: path.to_owned(),
                    message: format!("model {index}: {} is a directory, not a .treelod file", model.display()),
                });
            }
            Ok(_) => {}
            Err(source) => {
                return Err(SceneError::MissingModel { path: path.to_owned(), index, model: model.clone(), source });
            }
        }
    }
    Ok(scene)
}

/// The scene file as written, before validation.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    /// Checked by [`VersionOnly`] first.
    #[serde(rename = "version")]
    _version: serde::de::IgnoredAny,
    models: Vec<String>,
    instances: Vec<InstanceFile>,
}

/// One instance as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct InstanceFile {
    model: usize,
    translation: Option<[f64; 3]>,
    rotation_y_degrees: Option<f64>,
    scale: Option<f64>,
    matrix: Option<[f64; 16]>,
}

/// Only the version, read first so that a newer file is refused for its version, not for the
/// fields it adds.
#[derive(Deserialize)]
struct VersionOnly {
    version: Option<serde_json::Value>,
}

/// Parses and validates the text of a JSON scene file at `path`; model paths are resolved against
/// its directory but not checked.
///
/// # Errors
/// [`SceneError::Json`], [`SceneError::Version`], [`SceneError::Invalid`] or
/// [`SceneError::ModelIndex`].
pub fn parse(bytes: &[u8], path: &Path) -> Result<Scene, SceneError> {
    let json_error = |e: &serde_json::Error| {
        let text = e.to_string();
        let position = format!(" at line {} column {}", e.line(), e.column());
        let message = text.strip_suffix(&position).unwrap_or(&text).to_owned();
        SceneError::Json { path: path.to_owned(), line: e.line(), column: e.column(), message }
    };
    let invalid = |message: String| SceneError::Invalid { path: path.to_owned(), message };
    let head: VersionOnly = serde_json::from_slice(bytes).map_err(|e| json_error(&e))?;
    match head.version {
        None => return Err(invalid("missing field `version` (this treelod reads version 1)".to_owned())),
        Some(serde_json::Value::Number(n)) => match n.as_u64() {
            Some(v) if v == u64::from(VERSION) => {}
            Some(version) => return Err(SceneError::Version { path: path.to_owned(), version }),
            None => return Err(invalid(format!("`version` must be the integer {VERSION}, got {n}"))),
        },
        Some(other) => return Err(invalid(format!("`version` must be the integer {VERSION}, got {other}"))),
    }
    let file: SceneFile = serde_json::from_slice(bytes).map_err(|e| json_error(&e))?;
    if file.models.is_empty() {
        return Err(invalid("`models` is empty: a scene lists at least one .treelod file".to_owned()));
    }
    let base = path.parent().unwrap_or(Path::new(""));
    let mut models = Vec::with_capacity(file.models.len());
    for (index, model) in file.models.iter().enumerate() {
        if model.is_empty() {
            return Err(invalid(format!("model {index}: the path is empty")));
        }
        models.push(base.join(model));
    }
    let mut instances = Vec::with_capacity(file.instances.len());
    for (index, instance) in file.instances.iter().enumerate() {
        if instance.model >= models.len() {
            return Err(SceneError::ModelIndex {
                path: path.to_owned(),
                instance: index,
                model: instance.model,
                count: models.len(),
            });
        }
        let transform = instance_transform(instance).map_err(|m| invalid(format!("instance {index}: {m}")))?;
        instances.push(SceneInstance { model: instance.model, transform });
    }
    Ok(Scene { models, instances })
}

/// The world-from-model matrix of an instance, or what is wrong with it.
fn instance_transform(instance: &InstanceFile) -> Result<Mat4, String> {
    // JSON has no NaN or infinity, but numbers beyond f32's range become infinite when narrowed.
    let finite = |what: &str, values: &[f64]| -> Result<Vec<f32>, String> {
        let narrowed: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        if narrowed.iter().all(|v| v.is_finite()) {
            Ok(narrowed)
        } else {
            Err(format!("`{what}` must be finite numbers within f32 range, got {values:?}"))
        }
    };
    if let Some(matrix) = &instance.matrix {
        if instance.translation.is_some() || instance.rotation_y_degrees.is_some() || instance.scale.is_some() {
            return Err(
                "give either `matrix` or `translation` (with optional `rotation_y_degrees` and `scale`), not both"
                    .to_owned(),
            );
        }
        let m = finite("matrix", matrix)?;
        let mut cols = [0.0f32; 16];
        cols.copy_from_slice(&m);
        let transform = Mat4::from_cols_array(&cols);
        if transform.row(3) != glam::Vec4::new(0.0, 0.0, 0.0, 1.0) {
            return Err(format!(
                "`matrix` must be affine (column-major, last row 0 0 0 1), its last row is {:?}",
                transform.row(3).to_array()
            ));
        }
        let det = transform.determinant();
        if !det.is_finite() || det.abs() < 1e-12 {
            return Err("`matrix` is singular (determinant 0): it flattens the tree".to_owned());
        }
        return Ok(transform);
    }
    let Some(translation) = &instance.translation else {
        return Err("missing field `translation` (or give a `matrix`)".to_owned());
    };
    let t = finite("translation", translation)?;
    let rotation = finite("rotation_y_degrees", &[instance.rotation_y_degrees.unwrap_or(0.0)])?[0];
    let scale = finite("scale", &[instance.scale.unwrap_or(1.0)])?[0];
    if scale <= 0.0 {
        return Err(format!("`scale` must be positive, got {scale}"));
    }
    Ok(Mat4::from_scale_rotation_translation(
        Vec3::splat(scale),
        Quat::from_rotation_y(rotation.to_radians()),
        Vec3::new(t[0], t[1], t[2]),
    ))
}

/// Opens every model ([`Container::open`]), adds it to the renderer and sets the instances.
/// Returns the world bounds `(min, max)` of all instances (the transformed corners of each
/// model's block bounds); `(0, 0)` if there are none.
///
/// # Errors
/// [`SceneError::Container`] if a model does not open, [`SceneError::Render`] if the renderer
/// refuses it.
pub fn add_to_renderer(
    scene: &Scene,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    renderer: &mut Renderer,
) -> Result<(Vec3, Vec3), SceneError> {
    let models = open_models(scene)?;
    add_opened(scene, &models, device, queue, renderer)
}

/// Opens every model of `scene` ([`Container::open`]), in order, to be added to one renderer or
/// several ([`add_opened`]) without opening (and checking) the files again.
///
/// # Errors
/// [`SceneError::Invalid`] for a directory, [`SceneError::Container`] if a model does not open.
pub fn open_models(scene: &Scene) -> Result<Vec<Arc<Container>>, SceneError> {
    scene
        .models
        .iter()
        .map(|path| {
            if path.is_dir() {
                return Err(SceneError::Invalid {
                    path: path.clone(),
                    message: "is a directory, not a .treelod file".to_owned(),
                });
            }
            let container =
                Container::open(path).map_err(|source| SceneError::Container { path: path.clone(), source })?;
            Ok(Arc::new(container))
        })
        .collect()
}

/// [`add_to_renderer`] with the models already opened by [`open_models`] (`models[i]` is
/// `scene.models[i]`).
///
/// # Errors
/// [`SceneError::Render`] if the renderer refuses a model.
pub fn add_opened(
    scene: &Scene,
    models: &[Arc<Container>],
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    renderer: &mut Renderer,
) -> Result<(Vec3, Vec3), SceneError> {
    let mut ids = Vec::with_capacity(models.len());
    for (path, container) in scene.models.iter().zip(models) {
        let id = renderer
            .add_model(device, queue, Arc::clone(container))
            .map_err(|source| SceneError::Render { path: path.clone(), source })?;
        ids.push(id);
    }
    // `load` checks the indices; a hand-made `Scene` with a bad one is skipped, not a panic.
    let instances: Vec<Instance> = scene
        .instances
        .iter()
        .filter_map(|instance| Some(Instance { model: *ids.get(instance.model)?, transform: instance.transform }))
        .collect();
    renderer.set_instances(&instances);
    Ok(renderer.instance_bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gltf_paths_are_told_from_containers_and_scenes() {
        assert!(is_gltf_path(Path::new("a/tree.glb")) && is_gltf_path(Path::new("TREE.GLTF")));
        assert!(!is_gltf_path(Path::new("tree.treelod")) && !is_gltf_path(Path::new("forest.json")));
        assert!(!is_gltf_path(Path::new("glb")));
        let single = Scene::single(Path::new("a/tree.treelod"));
        assert_eq!(single.models, [PathBuf::from("a/tree.treelod")]);
        assert_eq!(single.instances, [SceneInstance { model: 0, transform: Mat4::IDENTITY }]);
    }

    fn parse_str(text: &str) -> Result<Scene, SceneError> {
        parse(text.as_bytes(), Path::new("scenes/forest.json"))
    }

    fn message(result: Result<Scene, SceneError>) -> String {
        match result {
            Ok(scene) => panic!("expected an error, got {scene:?}"),
            Err(e) => {
                let text = e.to_string();
                assert!(text.starts_with("scenes/forest.json: "), "the message names the file: {text}");
                text
            }
        }
    }

    #[test]
    fn a_full_scene_parses_with_paths_relative_to_the_scene_file() {
        let scene = parse_str(
            r#"{"version": 1, "models": ["a.treelod", "../b.treelod", "/abs/c.treelod"],
                "instances": [
                  {"model": 0, "translation": [1, 2, 3]},
                  {"model": 1, "translation": [0, 0, 0], "rotation_y_degrees": 90, "scale": 2},
                  {"model": 2, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 5,6,7,1]}
                ]}"#,
        )
        .expect("parses");
        assert_eq!(
            scene.models,
            [PathBuf::from("scenes/a.treelod"), PathBuf::from("scenes/../b.treelod"), PathBuf::from("/abs/c.treelod")]
        );
        assert_eq!(scene.instances.len(), 3);
        assert_eq!(scene.instances[0].transform, Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)));
        // 90° about +y takes +x to -z, then the scale doubles it.
        let p = scene.instances[1].transform.transform_point3(Vec3::X);
        assert!((p - Vec3::new(0.0, 0.0, -2.0)).length() < 1e-5, "{p}");
        assert_eq!(scene.instances[2].model, 2);
        assert_eq!(scene.instances[2].transform.w_axis, glam::Vec4::new(5.0, 6.0, 7.0, 1.0));
    }

    #[test]
    fn an_empty_instance_list_is_allowed() {
        let scene = parse_str(r#"{"version": 1, "models": ["a.treelod"], "instances": []}"#).expect("parses");
        assert!(scene.instances.is_empty());
    }

    #[test]
    fn bad_json_names_line_and_column() {
        let text = message(parse_str("{\"version\": 1,\n  \"models\": [\"a.treelod\",]\n}"));
        assert!(text.contains("line 2, column"), "{text}");
        let text = message(parse_str(""));
        assert!(text.contains("line 1"), "{text}");
        let text = message(parse_str("[1, 2]"));
        assert!(text.contains("line 1"), "{text}");
    }

    #[test]
    fn versions_other_than_1_are_refused() {
        let newer = parse_str(r#"{"version": 2, "models": ["a.treelod"], "instances": [], "new_field": true}"#);
        let Err(e) = newer else { panic!("accepted") };
        assert_eq!(e.class(), ErrorClass::Unsupported);
        assert!(e.to_string().contains("unknown scene version 2"), "{e}");
        let Err(e) = parse_str(r#"{"version": 0, "models": ["a.treelod"], "instances": []}"#) else { panic!() };
        assert_eq!(e.class(), ErrorClass::Invalid);
        for text in [r#"{"models": [], "instances": []}"#, r#"{"version": "1", "models": [], "instances": []}"#] {
            assert!(message(parse_str(text)).contains("version"));
        }
    }

    #[test]
    fn unknown_fields_are_refused() {
        let text = message(parse_str(r#"{"version": 1, "models": ["a.treelod"], "instances": [], "extra": 1}"#));
        assert!(text.contains("unknown field `extra`"), "{text}");
        let text = message(parse_str(
            r#"{"version": 1, "models": ["a.treelod"], "instances": [{"model": 0, "translation": [0,0,0], "rotation": 5}]}"#,
        ));
        assert!(text.contains("unknown field `rotation`"), "{text}");
    }

    #[test]
    fn bad_instances_are_refused_with_their_index() {
        let scene = |instance: &str| {
            parse_str(&format!(
                r#"{{"version": 1, "models": ["a.treelod", "b.treelod"], "instances": [{{"model": 0, "translation": [0,0,0]}}, {instance}]}}"#
            ))
        };
        let Err(e) = scene(r#"{"model": 2, "translation": [0,0,0]}"#) else { panic!() };
        assert!(matches!(e, SceneError::ModelIndex { instance: 1, model: 2, count: 2, .. }), "{e}");
        assert!(e.to_string().contains("instance 1: model 2 is out of range"), "{e}");
        for (instance, expected) in [
            (r#"{"model": 0, "translation": [0,0,0], "scale": 0}"#, "`scale` must be positive"),
            (r#"{"model": 0, "translation": [0,0,0], "scale": -1}"#, "`scale` must be positive"),
            (r#"{"model": 0, "translation": [0,0,0], "scale": 1e300}"#, "`scale` must be finite"),
            (r#"{"model": 0, "translation": [1e39,0,0]}"#, "`translation` must be finite"),
            (r#"{"model": 0, "translation": [0,0,0], "rotation_y_degrees": -1e200}"#, "`rotation_y_degrees` must be"),
            (r#"{"model": 0}"#, "missing field `translation`"),
            (r#"{"model": 0, "translation": [0,0]}"#, "line 1"),
            (r#"{"model": -1, "translation": [0,0,0]}"#, "line 1"),
            (r#"{"model": 0, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], "scale": 2}"#, "not both"),
            (r#"{"model": 0, "matrix": [0,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}"#, "singular"),
            (r#"{"model": 0, "matrix": [1,0,0,1, 0,1,0,0, 0,0,1,0, 0,0,0,1]}"#, "affine"),
            (r#"{"model": 0, "matrix": [1,0,0,0]}"#, "line 1"),
        ] {
            let text = message(scene(instance));
            if !expected.starts_with("line") {
                assert!(text.contains("instance 1: "), "{instance}: {text}");
            }
            assert!(text.contains(expected), "{instance}: {text}");
        }
    }

    #[test]
    fn empty_model_lists_and_paths_are_refused() {
        assert!(message(parse_str(r#"{"version": 1, "models": [], "instances": []}"#)).contains("`models` is empty"));
        assert!(message(parse_str(r#"{"version": 1, "models": [""], "instances": []}"#)).contains("model 0"));
    }

    #[test]
    fn load_checks_model_files_and_takes_a_container_path_as_a_scene() {
        let dir = std::env::temp_dir().join(format!("treelod-scene-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("creates");
        let scene_path = dir.join("forest.json");
        std::fs::write(&scene_path, r#"{"version": 1, "models": ["nope.treelod"], "instances": []}"#).expect("writes");
        let Err(e) = load(&scene_path) else { panic!("a missing model is an error") };
        assert!(matches!(e, SceneError::MissingModel { index: 0, .. }), "{e}");
        assert_eq!(e.class(), ErrorClass::Io);
        assert!(e.to_string().starts_with(&format!("{}: model 0: ", scene_path.display())), "{e}");

        let model = dir.join("tree.TREELOD");
        std::fs::write(&model, b"not checked by load").expect("writes");
        let scene = load(&model).expect("a .treelod path is a scene of one instance");
        assert_eq!(scene.models, [model]);
        assert_eq!(scene.instances, [SceneInstance { model: 0, transform: Mat4::IDENTITY }]);

        let Err(e) = load(&dir.join("missing.json")) else { panic!() };
        assert_eq!(e.class(), ErrorClass::Io);
        let Err(e) = load(&dir) else { panic!("a directory is no scene") };
        assert_eq!(e.class(), ErrorClass::Io);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
