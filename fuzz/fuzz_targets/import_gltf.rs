//! Fuzzes the glTF import: arbitrary bytes (a `.gltf` or a `.glb`) are imported with small limits
//! and no base directory (relative URIs are missing, nothing outside is read), and what imports is
//! built with tiny settings (a 2 × 2 × 2 grid, no ambient occlusion) when it has at most 4096
//! triangles. Neither may panic, and a container the build writes must verify.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use treelod_build::{BuildConfig, ImportLimits, Placed};
use treelod_format::{Compression, Container};

fuzz_target!(|data: &[u8]| {
    let limits = ImportLimits {
        max_decoded_bytes: 32 << 20,
        max_image_pixels: 1 << 20,
        max_instances: 4096,
        max_triangles: 1 << 16,
        allow_external_uris: false,
    };
    let name = if data.starts_with(b"glTF") { "fuzz.glb" } else { "fuzz.gltf" };
    let Ok(scene) = treelod_build::import_gltf_bytes_with(data, Path::new(name), None, &limits) else {
        return;
    };
    let triangles: usize = scene.parts.iter().map(|p| p.triangles.len()).sum();
    if triangles > 4096 {
        return;
    }
    let config = BuildConfig { grid: Some([2, 2, 2]), ..BuildConfig::default() };
    let trees = [Placed { scene: &scene, translation: glam::Vec3::ZERO }];
    if let Ok(output) = treelod_build::build_block("fuzz", &trees, &config, "treelod-fuzz") {
        let bytes = output.data.to_bytes(Compression::None).expect("a built container writes");
        let container = Container::from_bytes(&bytes).expect("a built container opens");
        if let Err(e) = treelod_format::verify(&container) {
            panic!("a built container does not verify: {e}");
        }
    }
});
