//! Bad glTF gives a typed error or a warning naming the file or primitive, never a panic.

use std::path::Path;

use treelod_build::{BuildError, import_gltf, import_gltf_bytes};

/// A glTF JSON with one triangle primitive whose positions live in buffer 0 (`uri`, 36 bytes).
fn gltf_json(uri: &str, extra: &str, mode: u32, with_normals: bool) -> String {
    let normals = if with_normals { r#","NORMAL":1"# } else { "" };
    format!(
        r#"{{"asset":{{"version":"2.0"}}{extra},
        "buffers":[{{"byteLength":72,"uri":"{uri}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":36}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
          {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC3"}}],
        "meshes":[{{"name":"leaves","primitives":[{{"attributes":{{"POSITION":0{normals}}},"mode":{mode}}}]}}],
        "nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],"scene":0}}"#
    )
}

fn data_uri(floats: &[f32]) -> String {
    use base64::Engine as _;
    let bytes: Vec<u8> = floats.iter().flat_map(|f| f.to_le_bytes()).collect();
    format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
}

const TRIANGLE: [f32; 18] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0];

fn import(json: &str) -> Result<treelod_build::scene::Scene, BuildError> {
    import_gltf_bytes(json.as_bytes(), Path::new("bad.gltf"), Some(Path::new("/nonexistent-dir")))
}

#[test]
fn a_valid_triangle_imports() {
    let scene = import(&gltf_json(&data_uri(&TRIANGLE), "", 4, true)).expect("imports");
    assert_eq!(scene.parts.len(), 1);
    assert_eq!(scene.parts[0].triangles, vec![[0, 1, 2]]);
    assert!(scene.source.content_hash.starts_with("sha256:"));
}

#[test]
fn a_missing_buffer_file_names_the_buffer() {
    let err = import(&gltf_json("tree.bin", "", 4, true)).unwrap_err();
    assert!(matches!(err, BuildError::MissingBuffer { index: 0, .. }), "{err}");
    assert!(err.to_string().starts_with("bad.gltf: buffer 0 (tree.bin) cannot be read"), "{err}");
}

#[test]
fn a_buffer_shorter_than_declared_is_missing_data() {
    let err = import(&gltf_json(&data_uri(&TRIANGLE[..9]), "", 4, true)).unwrap_err();
    assert!(matches!(err, BuildError::MissingBuffer { .. }), "{err}");
}

#[test]
fn compression_extensions_are_unsupported_by_name() {
    let extra =
        r#","extensionsUsed":["KHR_draco_mesh_compression"],"extensionsRequired":["KHR_draco_mesh_compression"]"#;
    let err = import(&gltf_json(&data_uri(&TRIANGLE), extra, 4, true)).unwrap_err();
    assert!(matches!(err, BuildError::Unsupported { .. }), "{err}");
    assert!(err.to_string().contains("KHR_draco_mesh_compression"), "{err}");
}

#[test]
fn lines_are_skipped_with_a_warning_and_missing_normals_are_computed() {
    let scene = import(&gltf_json(&data_uri(&TRIANGLE), "", 1, true)).expect("imports");
    assert!(scene.parts.is_empty());
    assert!(scene.warnings.iter().any(|w| w.contains("not triangles")), "{:?}", scene.warnings);
    let scene = import(&gltf_json(&data_uri(&TRIANGLE), "", 4, false)).expect("imports");
    assert!(scene.warnings.iter().any(|w| w.contains("no normals")), "{:?}", scene.warnings);
    let n = scene.parts[0].normals[0];
    assert!((n[2] - 1.0).abs() < 1e-6, "computed face normal {n:?}");
}

#[test]
fn nan_positions_import_and_the_build_drops_them() {
    let mut floats = TRIANGLE;
    floats[0] = f32::NAN;
    let scene = import(&gltf_json(&data_uri(&floats), "", 4, true)).expect("imports");
    let err = treelod_build::build_block(
        "bad",
        &[treelod_build::Placed { scene: &scene, translation: glam::Vec3::ZERO }],
        &treelod_build::BuildConfig::default(),
        "t",
    )
    .unwrap_err();
    assert!(matches!(err, BuildError::NoGeometry { .. }), "{err}");
    assert!(err.to_string().contains("1 dropped"), "{err}");
}

#[test]
fn garbage_empty_and_missing_files_are_typed_errors() {
    for bytes in [&b""[..], b"glTF\x02\x00\x00\x00garbage", b"{not json", b"\x00\x01\x02"] {
        let err = import_gltf_bytes(bytes, Path::new("junk.glb"), None).unwrap_err();
        assert!(matches!(err, BuildError::Gltf { .. }), "{err}");
        assert!(err.to_string().starts_with("junk.glb: "), "{err}");
    }
    let err = import_gltf(Path::new("/nonexistent/tree.glb")).unwrap_err();
    assert!(matches!(err, BuildError::Io { .. }), "{err}");
}

#[test]
fn a_position_accessor_that_does_not_exist_is_an_error_not_a_panic() {
    // gltf-json's own validation would index the accessors with it unchecked.
    let json = r#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":7}}]}],
        "nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]}"#;
    let err = import(json).expect_err("refused");
    assert!(matches!(err, BuildError::Gltf { .. }), "{err:?}");
    let message = err.to_string();
    assert!(message.contains("bad.gltf") && message.contains("POSITION: accessor 7 does not exist"), "{message}");
}

#[test]
fn a_glb_header_shorter_than_itself_is_an_error() {
    for length in [0u32, 8, 11] {
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(length.to_le_bytes());
        let err = import_gltf_bytes(&glb, Path::new("bad.glb"), None).unwrap_err();
        assert!(matches!(err, BuildError::Gltf { .. }), "{err}");
        assert!(err.to_string().contains("GLB header declares"), "{err}");
    }
}
