//! What the rendering tests share: the Vulkan adapter they must get, the background they clear to,
//! and coverage precision and recall of one image against another.

#![allow(dead_code, reason = "each test file uses part of it")]

use std::sync::Arc;

use glam::{Mat4, Vec3};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, build_block, demo_tree};
use treelod_format::{Compression, Container};
use treelod_render::offscreen::{Gpu, Image};
use treelod_render::{Instance, Renderer, Settings};

/// White: a pixel of another colour is covered.
pub const BACKGROUND: wgpu::Color = wgpu::Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 };

/// The adapter: the tests run on Vulkan (lavapipe in CI) and fail without one.
pub fn gpu() -> Gpu {
    let gpu = Gpu::new().expect("a GPU adapter (install mesa-vulkan-drivers for lavapipe)");
    assert_eq!(gpu.info.backend, wgpu::Backend::Vulkan, "rendering tests run on Vulkan, got {:?}", gpu.info);
    gpu
}

/// Pixels that differ from the white background (by more than a few levels).
pub fn covered(image: &Image) -> Vec<bool> {
    image.rgba.chunks_exact(4).map(|p| p[0] < 250 || p[1] < 250 || p[2] < 250).collect()
}

/// Precision and recall of `test`'s covered pixels against `reference`'s.
pub fn precision_recall(test: &Image, reference: &Image) -> (f64, f64) {
    mask_precision_recall(&covered(test), &covered(reference))
}

/// Precision and recall of the pixel mask `test` against `reference`.
pub fn mask_precision_recall(test: &[bool], reference: &[bool]) -> (f64, f64) {
    let both = test.iter().zip(reference).filter(|(a, b)| **a && **b).count() as f64;
    let n_test = test.iter().filter(|a| **a).count() as f64;
    let n_reference = reference.iter().filter(|a| **a).count() as f64;
    (both / n_test.max(1.0), both / n_reference.max(1.0))
}

/// Pixels of `shadowed` darker than 0.85 of the same pixel of `lit` (the ground without
/// shadows): the shadow mask.
pub fn shadow_mask(shadowed: &Image, lit: &Image) -> Vec<bool> {
    shadowed
        .rgba
        .chunks_exact(4)
        .zip(lit.rgba.chunks_exact(4))
        .map(|(s, l)| f32::from(s[1]) < 0.85 * f32::from(l[1]))
        .collect()
}

/// The sunlight a shadow takes from the ground: the sum over pixels of `1 − shadowed / lit`.
pub fn light_taken(shadowed: &Image, lit: &Image) -> f64 {
    shadowed
        .rgba
        .chunks_exact(4)
        .zip(lit.rgba.chunks_exact(4))
        .map(|(s, l)| 1.0 - f64::from(s[1]) / f64::from(l[1]).max(1.0))
        .sum()
}

/// A renderer with `settings` drawing one instance of `container` at the origin.
pub fn one_tree(gpu: &Gpu, container: &Arc<Container>, settings: Settings) -> Renderer {
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).expect("uploads");
    renderer.set_instances(&[Instance { model: tree, transform: Mat4::IDENTITY }]);
    renderer
}

/// The bark (non-leaf) triangles of `container`'s full mesh.
pub fn bark_triangles(container: &Container) -> u64 {
    let leaf = |t: &&treelod_format::TriangleRecord| {
        container.materials()[t.material as usize].class == treelod_format::material_class::LEAF
    };
    container.triangles().iter().filter(|t| !leaf(t)).count() as u64
}

/// The default demo tree built with `config`, opened from its uncompressed bytes.
pub fn demo_built(config: &BuildConfig) -> Arc<Container> {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], config, "test").expect("builds");
    Arc::new(Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens"))
}

/// Writes `image` as a PPM under `$TREELOD_TEST_IMAGES` when that is set, for looking at failures.
pub fn keep(image: &Image, name: &str) {
    if let Some(dir) = std::env::var_os("TREELOD_TEST_IMAGES") {
        let mut ppm = format!("P6 {} {} 255\n", image.width, image.height).into_bytes();
        ppm.extend(image.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]));
        std::fs::write(std::path::Path::new(&dir).join(format!("{name}.ppm")), ppm).expect("writes");
    }
}
