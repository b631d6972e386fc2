//! BC7 atlases (spec §6.7 formats 6, 7) on the Vulkan backend (Mesa lavapipe in CI): uploaded as
//! stored where the device samples BC textures, decoded to RGBA8 on upload where it does not, and
//! drawn like the RGBA8 atlases of older containers.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, covered, demo_built, gpu, keep, one_tree, precision_recall};
use glam::{Vec3, vec3};
use treelod_build::{AtlasFormat, BuildConfig, ImpostorConfig, LodChainConfig};
use treelod_format::{Container, image_format};
use treelod_render::offscreen::{Gpu, Image, render_image};
use treelod_render::{Camera, Primitive, Settings, Technique};

/// The demo tree with impostors and billboards, atlases stored as `format`.
fn demo(format: AtlasFormat) -> Arc<Container> {
    demo_built(&BuildConfig {
        impostors: Some(ImpostorConfig::default()),
        baselines: Some(LodChainConfig::default()),
        atlas_format: format,
        ..BuildConfig::default()
    })
}

/// The formats of the images planes and billboards sample.
fn atlas_formats(container: &Container) -> (u32, u32) {
    let images = container.images();
    let plane = container.planes().first().map_or(0, |p| images[p.image as usize].format);
    let billboard = container.billboards().first().map_or(0, |b| images[b.image as usize].format);
    (plane, billboard)
}

/// The cameras the comparisons use: three directions around the tree at 15 and 45 m.
fn cameras(container: &Container) -> Vec<Camera> {
    let block = container.block();
    let centre = 0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max));
    let mut out = Vec::new();
    for distance in [15.0f32, 45.0] {
        for k in 0..3 {
            let a = k as f32 * 2.1 + 0.3;
            out.push(Camera::look_at(centre + distance * vec3(a.sin(), 0.2, a.cos()), centre, 0.8, 160, 160));
        }
    }
    out
}

/// Renders `technique` of `container` on `gpu` from every camera; each image with the primitives
/// of the technique's kind.
fn render_all(gpu: &Gpu, container: &Arc<Container>, technique: Technique) -> Vec<(Image, u64)> {
    let mut renderer = one_tree(gpu, container, Settings { technique, ..Settings::default() });
    let kind = if technique == Technique::Impostors { Primitive::Plane } else { Primitive::Billboard };
    cameras(container)
        .iter()
        .map(|cam| {
            let (image, stats) = render_image(gpu, &mut renderer, cam, BACKGROUND).expect("renders");
            (image, stats.submitted[kind])
        })
        .collect()
}

/// The mean and largest RGB difference over the pixels both images cover (where one alone covers,
/// [`precision_recall`] counts it).
fn compare(a: &Image, b: &Image) -> (f64, u8) {
    let (ca, cb) = (covered(a), covered(b));
    let (mut total, mut max, mut n) = (0u64, 0u8, 0u64);
    for (i, (p, q)) in a.rgba.chunks_exact(4).zip(b.rgba.chunks_exact(4)).enumerate() {
        if !(ca[i] && cb[i]) {
            continue;
        }
        let d = (0..3).map(|c| p[c].abs_diff(q[c])).max().unwrap_or(0);
        total += u64::from(d);
        max = max.max(d);
        n += 1;
    }
    (total as f64 / n.max(1) as f64, max)
}

#[test]
fn the_build_stores_bc7_atlases_by_default_and_rgba8_when_asked() {
    let bc7 = demo(AtlasFormat::Bc7);
    let rgba8 = demo(AtlasFormat::Rgba8);
    assert_eq!(atlas_formats(&bc7), (image_format::BC7_SRGB, image_format::BC7_SRGB));
    assert_eq!(atlas_formats(&rgba8), (image_format::RGBA8_SRGB, image_format::RGBA8_SRGB));
    // BC7 is an image format of 1.6, which readers before it cannot sample; the octahedral views'
    // normal grids (OCTAHEDRAL_NORMAL_GRIDS, 1.16, which every build with baselines writes) mark
    // both files 1.16, and readers before it skip the kind (1.18 where the build measured the
    // calibration's FLIP error, CALIBRATION_FLIP of 1.17 and the chain levels' CHAIN_CALIBRATION_FLIP
    // of 1.18: with its `flip` feature, as in a workspace build).
    let minor = if bc7.calibration_flip().is_empty() { 16 } else { 18 };
    assert_eq!((bc7.header().minor, rgba8.header().minor), (minor, minor));
    assert!(rgba8.images().iter().all(|i| i.format != image_format::BC7_SRGB && i.format != image_format::BC7_LINEAR));
    treelod_format::verify(&bc7).expect("the BC7 container verifies");
    treelod_format::verify(&rgba8).expect("the RGBA8 container verifies");
    let setting = |c: &Container| {
        c.metadata().settings.iter().find(|s| s.key == "atlas.format").map(|s| s.value.clone()).unwrap_or_default()
    };
    assert_eq!((setting(&bc7), setting(&rgba8)), ("bc7".to_owned(), "rgba8".to_owned()));
    // Same planes, quads and regions: only the atlases' bytes differ, a quarter as many.
    assert_eq!(bc7.planes(), rgba8.planes());
    assert_eq!(bc7.billboards(), rgba8.billboards());
    let atlas_bytes = |c: &Container| {
        let images = c.images();
        images[c.planes()[0].image as usize].data_length + images[c.billboards()[0].image as usize].data_length
    };
    // BC7 is 1 byte a texel, RGBA8 4; the small levels (not multiples of 4) round up to whole
    // blocks, a little over a quarter in all.
    let (small, large) = (atlas_bytes(&bc7) as f64, atlas_bytes(&rgba8) as f64);
    assert!((3.5..=4.0).contains(&(large / small)), "{large} / {small}");
}

#[test]
fn bc7_atlases_render_like_the_rgba8_atlases_of_older_containers() {
    let gpu = gpu();
    let (bc7, rgba8) = (demo(AtlasFormat::Bc7), demo(AtlasFormat::Rgba8));
    eprintln!(
        "adapter {:?}: TEXTURE_COMPRESSION_BC {}",
        gpu.info.name,
        gpu.device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC)
    );
    for technique in [Technique::Impostors, Technique::Billboard, Technique::Crossed] {
        let old = render_all(&gpu, &rgba8, technique);
        let new = render_all(&gpu, &bc7, technique);
        for (k, ((a, quads_a), (b, quads_b))) in old.iter().zip(&new).enumerate() {
            keep(a, &format!("bc7-{technique:?}-{k}-rgba8"));
            keep(b, &format!("bc7-{technique:?}-{k}-bc7"));
            assert!(*quads_a > 0, "{technique:?} {k}: the old container draws its quads");
            assert_eq!(quads_a, quads_b, "{technique:?} {k}");
            let (precision, recall) = precision_recall(b, a);
            let (mean, max) = compare(a, b);
            eprintln!("{technique:?} view {k}: P {precision:.4} R {recall:.4}, mean {mean:.2}, max {max}");
            // Measured on lavapipe: P 0.980-0.996, R 0.975-0.995, mean difference over the pixels
            // both cover 2.0-3.2 levels (largest 103, a leaf edge whose texel flipped its alpha
            // test and shows the leaf behind). Colours move by BC7's error.
            assert!(precision >= 0.96 && recall >= 0.96, "{technique:?} view {k}: P {precision:.4}, R {recall:.4}");
            assert!(mean < 5.0, "{technique:?} view {k}: mean difference {mean:.2}");
        }
    }
}

#[test]
fn decoding_on_the_cpu_renders_like_bc_textures() {
    let with_bc = gpu();
    let without = Gpu::without(wgpu::Features::TEXTURE_COMPRESSION_BC).expect("an adapter");
    assert!(!without.device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC));
    let offered = with_bc.device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC);
    eprintln!("{:?} offers TEXTURE_COMPRESSION_BC: {offered}", with_bc.info.name);
    let container = demo(AtlasFormat::Bc7);
    for technique in [Technique::Impostors, Technique::Billboard] {
        // The texture memory: blocks as stored with BC textures, four times that decoded.
        let resident = |gpu: &Gpu| {
            let mut renderer = one_tree(gpu, &container, Settings { technique, ..Settings::default() });
            let cam = &cameras(&container)[0];
            render_image(gpu, &mut renderer, cam, BACKGROUND).expect("renders").1.bytes_resident
        };
        if offered {
            assert!(resident(&with_bc) < resident(&without), "{technique:?}: the blocks are uploaded as they are");
        }
        let gpu_decoded = render_all(&with_bc, &container, technique);
        let cpu_decoded = render_all(&without, &container, technique);
        for (k, ((a, quads_a), (b, quads_b))) in gpu_decoded.iter().zip(&cpu_decoded).enumerate() {
            assert_eq!(quads_a, quads_b);
            assert!(*quads_a > 0);
            // The same pixels covered; colours within a level or two (measured on lavapipe: at most
            // 1 level, mean 0.53): the GPU filters the blocks' texels at more than 8 bits, the CPU
            // decoder rounds them to 8 bits first.
            let (mean, max) = compare(a, b);
            eprintln!("{technique:?} view {k}: GPU and CPU decoding differ by mean {mean:.3}, max {max}");
            assert_eq!(covered(a), covered(b), "{technique:?} view {k}: the same pixels");
            assert!(mean < 1.0 && max <= 4, "{technique:?} view {k}: mean {mean:.3}, max {max}");
        }
    }
}
