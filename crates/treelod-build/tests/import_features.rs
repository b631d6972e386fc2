//! What the glTF import reads beyond plain float accessors: `KHR_texture_transform`,
//! `KHR_mesh_quantization`, sparse accessors, any JSON value as `extras`, instanced meshes, and
//! the limits and URI policy of `ImportLimits`.

use std::path::Path;

use base64::Engine as _;
use treelod_build::import::Limit;
use treelod_build::{BuildError, ImportLimits, import_gltf_bytes_with};

/// A base64 data URI of `bytes`.
fn data_uri(bytes: &[u8]) -> String {
    format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
}

fn floats(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|f| f.to_le_bytes()).collect()
}

/// One triangle in the XY plane with UVs (0,0) (1,0) (0,1): positions at bytes 0..36, UVs at 36..60.
fn triangle_buffer() -> Vec<u8> {
    let mut bytes = floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    bytes.extend(floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]));
    bytes
}

/// A glTF with [`triangle_buffer`], a textured material with `texture_info` (JSON members of the
/// `baseColorTexture` object beyond `index`), `extra` top-level members and `nodes`.
fn textured(texture_info: &str, extra: &str, nodes: &str) -> String {
    let buffer = triangle_buffer();
    // A 1×1 PNG so the texture exists.
    let png = one_pixel_png();
    let mut all = buffer.clone();
    all.extend(&png);
    format!(
        r#"{{"asset":{{"version":"2.0"}}{extra},
        "buffers":[{{"byteLength":{len},"uri":"{uri}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":24}},
                       {{"buffer":0,"byteOffset":60,"byteLength":{png_len}}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
          {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}}],
        "images":[{{"bufferView":2,"mimeType":"image/png"}}],
        "textures":[{{"source":0}}],
        "materials":[{{"name":"leaf","pbrMetallicRoughness":{{"baseColorTexture":{{"index":0{texture_info}}}}}}}],
        "meshes":[{{"name":"leaves","primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"material":0}}]}}],
        "nodes":{nodes},"scenes":[{{"nodes":[0]}}],"scene":0}}"#,
        len = all.len(),
        uri = data_uri(&all),
        png_len = png.len(),
    )
}

fn one_pixel_png() -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut out, 1, 1);
        encoder.set_color(png::ColorType::Rgba);
        let mut writer = encoder.write_header().expect("png header");
        writer.write_image_data(&[10, 200, 30, 255]).expect("png data");
    }
    out
}

fn import(json: &str, limits: &ImportLimits) -> Result<treelod_build::scene::Scene, BuildError> {
    import_gltf_bytes_with(json.as_bytes(), Path::new("tree.gltf"), None, limits)
}

fn close(a: [f32; 2], b: [f32; 2]) -> bool {
    (a[0] - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5
}

#[test]
fn texture_transform_is_applied_to_the_uvs() {
    let one_node = r#"[{"mesh":0}]"#;
    let plain = import(&textured("", "", one_node), &ImportLimits::default()).expect("imports");
    assert_eq!(plain.parts[0].uvs, vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    // Scale (2, 3), rotation 90°, offset (0.5, 0.25): u' = cos·2u + sin·3v + 0.5, v' = −sin·2u + cos·3v + 0.25.
    let info = r#","extensions":{"KHR_texture_transform":{"offset":[0.5,0.25],"rotation":1.5707964,"scale":[2,3]}}"#;
    let extra = r#","extensionsUsed":["KHR_texture_transform"],"extensionsRequired":["KHR_texture_transform"]"#;
    let scene = import(&textured(info, extra, one_node), &ImportLimits::default()).expect("imports");
    let uvs = &scene.parts[0].uvs;
    for (got, want) in uvs.iter().zip([[0.5, 0.25], [0.5, -1.75], [3.5, 0.25]]) {
        assert!(close(*got, want), "{uvs:?}");
    }
}

#[test]
fn texture_transform_tex_coord_overrides_the_set() {
    // The transform names set 1, which the primitive does not have: no UVs are read.
    let info = r#","extensions":{"KHR_texture_transform":{"texCoord":1}}"#;
    let scene = import(
        &textured(info, r#","extensionsUsed":["KHR_texture_transform"]"#, r#"[{"mesh":0}]"#),
        &ImportLimits::default(),
    )
    .expect("imports");
    assert!(scene.parts[0].uvs.is_empty());
}

#[test]
fn extras_of_any_json_type_are_accepted() {
    for extras in [r#"[1,2]"#, r#""text""#, "3", "null", r#"{"a":1}"#] {
        let extra = format!(r#","extras":{extras}"#);
        let nodes = format!(r#"[{{"mesh":0,"extras":{extras}}}]"#);
        let scene = import(&textured("", &extra, &nodes), &ImportLimits::default());
        assert!(scene.is_ok(), "extras {extras}: {:?}", scene.err());
    }
}

#[test]
fn unknown_required_extensions_are_unsupported_by_name() {
    for ext in ["KHR_materials_unlit", "EXT_made_up", "KHR_lights_punctual"] {
        let extra = format!(r#","extensionsUsed":["{ext}"],"extensionsRequired":["{ext}"]"#);
        let err = import(&textured("", &extra, r#"[{"mesh":0}]"#), &ImportLimits::default()).unwrap_err();
        assert!(matches!(err, BuildError::Unsupported { .. }), "{ext}: {err}");
        assert!(err.to_string().contains(ext), "{err}");
    }
}

#[test]
fn an_instanced_mesh_is_placed_at_each_instance() {
    // Node 0 holds two children that instance mesh 0, one moved by +5 in x and one mirrored.
    let nodes = r#"[{"children":[1,2]},{"mesh":0,"translation":[5,0,0]},{"mesh":0,"scale":[-1,1,1]}]"#;
    let scene = import(&textured("", "", nodes), &ImportLimits::default()).expect("imports");
    assert_eq!(scene.parts.len(), 2);
    assert_eq!(scene.parts[0].positions, vec![[5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0]]);
    assert_eq!(scene.parts[1].positions, vec![[0.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    // The mirror keeps the winding counter-clockwise, and face normals face the same way.
    assert_eq!(scene.parts[0].triangles, vec![[0, 1, 2]]);
    assert_eq!(scene.parts[1].triangles, vec![[0, 2, 1]]);
    assert!((scene.parts[1].normals[0][2] - 1.0).abs() < 1e-6, "{:?}", scene.parts[1].normals);
}

#[test]
fn node_instances_and_triangles_are_limited() {
    // Each node lists the next one twice: 2^12 instances of the last one, 12 levels deep.
    let depth = 12;
    let mut nodes: Vec<String> = (0..depth).map(|i| format!(r#"{{"children":[{0},{0}]}}"#, i + 1)).collect();
    nodes.push(r#"{"mesh":0}"#.into());
    let json = textured("", "", &format!("[{}]", nodes.join(",")));
    let scene = import(&json, &ImportLimits::default()).expect("4096 instances are within the defaults");
    assert_eq!(scene.parts.len(), 1 << depth);
    let limits = ImportLimits { max_instances: 1000, ..ImportLimits::default() };
    match import(&json, &limits) {
        Err(BuildError::Limit { limit: Limit::Instances, max: 1000, .. }) => {}
        other => panic!("expected the instance limit, got {other:?}"),
    }
    let limits = ImportLimits { max_triangles: 100, ..ImportLimits::default() };
    let err = import(&json, &limits).unwrap_err();
    assert!(matches!(err, BuildError::Limit { limit: Limit::Triangles, .. }), "{err}");
    assert!(err.to_string().contains("--max-triangles"), "{err}");
}

#[test]
fn quantized_positions_need_the_extension() {
    // Positions as normalized UNSIGNED_SHORT (4-byte aligned stride 8), normals as normalized BYTE.
    let mut bytes = Vec::new();
    for p in [[0u16, 0, 0], [65535, 0, 0], [0, 65535, 0]] {
        for c in p {
            bytes.extend(c.to_le_bytes());
        }
        bytes.extend([0, 0]);
    }
    for _ in 0..3 {
        bytes.extend([0u8, 0, 127, 0]);
    }
    let gltf = |extra: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}}{extra},
            "buffers":[{{"byteLength":36,"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":24,"byteStride":8}},{{"buffer":0,"byteOffset":24,"byteLength":12,"byteStride":4}}],
            "accessors":[
              {{"bufferView":0,"componentType":5123,"normalized":true,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
              {{"bufferView":1,"componentType":5120,"normalized":true,"count":3,"type":"VEC3"}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}}}}]}}],
            "nodes":[{{"mesh":0,"scale":[2,2,2]}}],"scenes":[{{"nodes":[0]}}]}}"#,
            uri = data_uri(&bytes)
        )
    };
    let err = import(&gltf(""), &ImportLimits::default()).unwrap_err();
    assert!(matches!(err, BuildError::InvalidData { .. }), "{err}");
    let text = err.to_string();
    assert!(text.contains("meshes[0].primitives[0].attributes.POSITION: accessors[0]"), "{text}");
    assert!(text.contains("KHR_mesh_quantization"), "{text}");
    let extra = r#","extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"]"#;
    let scene = import(&gltf(extra), &ImportLimits::default()).expect("imports");
    assert_eq!(scene.parts[0].positions, vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]]);
    assert_eq!(scene.parts[0].normals, vec![[0.0, 0.0, 1.0]; 3]);
}

#[test]
fn sparse_accessors_substitute_their_values() {
    // Base positions all zero (no buffer view); sparse indices 1, 2 set two corners.
    let mut bytes = vec![1u8, 0, 2, 0];
    bytes.extend(floats(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0]));
    let gltf = |indices: [u8; 2], count: u32| {
        let mut b = bytes.clone();
        b[0] = indices[0];
        b[2] = indices[1];
        format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":28,"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":4}},{{"buffer":0,"byteOffset":4,"byteLength":24}}],
            "accessors":[{{"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0],
              "sparse":{{"count":{count},"indices":{{"bufferView":0,"componentType":5123}},"values":{{"bufferView":1}}}}}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}]}}"#,
            uri = data_uri(&b)
        )
    };
    let scene = import(&gltf([1, 2], 2), &ImportLimits::default()).expect("imports");
    assert_eq!(scene.parts[0].positions, vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    for (indices, count) in [([2, 1], 2), ([1, 3], 2), ([1, 1], 2), ([1, 2], 4), ([1, 2], 0)] {
        let err = import(&gltf(indices, count), &ImportLimits::default()).unwrap_err();
        assert!(matches!(err, BuildError::InvalidData { .. } | BuildError::Gltf { .. }), "{indices:?} {count}: {err}");
        assert!(err.to_string().contains("accessors[0]") || err.to_string().contains("sparse"), "{err}");
    }
}

#[test]
fn decoded_bytes_are_limited_before_allocation() {
    let json = textured("", "", r#"[{"mesh":0}]"#);
    let limits = ImportLimits { max_decoded_bytes: json.len() as u64 + 10, ..ImportLimits::default() };
    let err = import(&json, &limits).unwrap_err();
    assert!(matches!(err, BuildError::Limit { limit: Limit::DecodedBytes, .. }), "{err}");
    assert!(err.to_string().contains("buffers[0]") && err.to_string().contains("--max-decoded-bytes"), "{err}");
    let limits = ImportLimits { max_image_pixels: 0, ..ImportLimits::default() };
    let err = import(&json, &limits).unwrap_err();
    assert!(matches!(err, BuildError::Limit { limit: Limit::ImagePixels, .. }), "{err}");
    assert!(err.to_string().contains("images[0]"), "{err}");
}

/// Only base colour textures are drawn: another image (here a normal map that does not decode)
/// is neither read nor refused, and keeps an empty place.
#[test]
fn images_that_are_no_base_colour_are_not_decoded() {
    let buffer = triangle_buffer();
    let png = one_pixel_png();
    let mut huge = png.clone();
    // The IHDR chunk's width and height.
    huge[16..24].copy_from_slice(&[0, 1, 0x86, 0xA0, 0, 1, 0x86, 0xA0]);
    let mut all = buffer.clone();
    all.extend(&png);
    all.extend(&huge);
    let json = |normal: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":{len},"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":24}},
                           {{"buffer":0,"byteOffset":60,"byteLength":{png_len}}},
                           {{"buffer":0,"byteOffset":{huge_at},"byteLength":{png_len}}}],
            "accessors":[
              {{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
              {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}}],
            "images":[{{"bufferView":2,"mimeType":"image/png"}},{{"bufferView":3,"mimeType":"image/png"}}],
            "textures":[{{"source":0}},{{"source":1}}],
            "materials":[{{"name":"leaf","pbrMetallicRoughness":{{"baseColorTexture":{{"index":{base}}}}},
              "normalTexture":{{"index":{normal}}}}}],
            "meshes":[{{"name":"leaves","primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"material":0}}]}}],
            "nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],"scene":0}}"#,
            len = all.len(),
            uri = data_uri(&all),
            png_len = png.len(),
            huge_at = 60 + png.len(),
            base = if normal == "1" { "0" } else { "1" },
        )
    };
    let limits = ImportLimits { max_image_pixels: 16, ..ImportLimits::default() };
    let scene = import(&json("1"), &limits).expect("the normal map is not read");
    assert_eq!((scene.images[0].width, scene.images[0].height), (1, 1));
    assert_eq!(&scene.images[0].rgba, &[10, 200, 30, 255]);
    assert!(scene.images[1].width == 0 && scene.images[1].rgba.is_empty() && scene.images[1].encoded.is_empty());
    assert_eq!(scene.materials[0].image, Some(0));
    assert!(!scene.warnings.iter().any(|w| w.contains("image")), "{:?}", scene.warnings);
    // The same image as the base colour is read, and refused.
    let err = import(&json("0"), &limits).unwrap_err();
    assert!(err.to_string().contains("image 1"), "{err}");
}

#[test]
fn long_names_are_cut_with_a_warning() {
    let long = "n".repeat(100_000);
    let json = textured("", "", &format!(r#"[{{"mesh":0,"name":"{long}"}}]"#));
    let scene = import(&json, &ImportLimits::default()).expect("imports");
    assert_eq!(scene.parts[0].node_name.len(), 256);
    assert!(scene.warnings.iter().any(|w| w.contains("nodes[0].name is 100000 bytes")), "{:?}", scene.warnings);
}

#[cfg(unix)]
#[test]
fn uris_stay_in_the_model_directory_and_read_only_regular_files() {
    let root = tempfile::tempdir().expect("temporary directory");
    let model = root.path().join("model");
    std::fs::create_dir(&model).expect("model directory");
    std::fs::write(root.path().join("outside.bin"), triangle_buffer()).expect("outside buffer");
    std::fs::write(model.join("inside.bin"), triangle_buffer()).expect("inside buffer");
    let gltf = |uri: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":60,"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}]}}"#
        )
    };
    let run = |uri: &str, allow_external_uris: bool| {
        let limits = ImportLimits { allow_external_uris, ..ImportLimits::default() };
        import_gltf_bytes_with(gltf(uri).as_bytes(), &model.join("tree.gltf"), Some(&model), &limits)
    };
    assert!(run("inside.bin", false).is_ok());
    let outside = root.path().join("outside.bin");
    for uri in ["../outside.bin", outside.to_str().expect("utf-8 path")] {
        let err = run(uri, false).unwrap_err();
        assert!(matches!(err, BuildError::Unsupported { .. }), "{uri}: {err}");
        assert!(err.to_string().contains("buffers[0]") && err.to_string().contains("--allow-external-uris"), "{err}");
        assert!(run(uri, true).is_ok(), "{uri} with --allow-external-uris");
    }
    // A FIFO is not read (it would block), nor a device that never ends.
    let fifo = model.join("pipe.bin");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
    assert!(made.success());
    let err = run("pipe.bin", false).unwrap_err();
    assert!(matches!(err, BuildError::MissingBuffer { .. }), "{err}");
    assert!(err.to_string().contains("not a regular file (a FIFO)"), "{err}");
    let err = run("/dev/zero", true).unwrap_err();
    assert!(err.to_string().contains("not a regular file (a character device)"), "{err}");
}
