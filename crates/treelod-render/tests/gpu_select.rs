//! GPU-driven selection on the Vulkan backend (Mesa lavapipe in CI): for a few hundred instances
//! of the demo tree at several cameras, the draw records the compute shaders write, read back,
//! equal the CPU selection (up to `f32` rounding of keys at a threshold), and both paths render
//! the same image.

mod common;

use std::sync::Arc;

use common::{assert_same_selection, differing};
use glam::{Mat4, Quat, Vec3, vec3};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, SplitMix64, build_block, demo_tree};
use treelod_format::{Compression, Container};
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, render_image};
use treelod_render::{Camera, Instance, ModelId, Renderer, Settings};
use treelod_runtime::{DrawRange, Kind, ModelLod};

const BACKGROUND: wgpu::Color = wgpu::Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 };

fn gpu() -> Gpu {
    let gpu = Gpu::new().expect("a GPU adapter (install mesa-vulkan-drivers for lavapipe)");
    assert_eq!(gpu.info.backend, wgpu::Backend::Vulkan, "rendering tests run on Vulkan, got {:?}", gpu.info);
    assert!(
        gpu.device.features().contains(wgpu::Features::MULTI_DRAW_INDIRECT_COUNT),
        "lavapipe offers MULTI_DRAW_INDIRECT_COUNT"
    );
    gpu
}

fn demo_container() -> Arc<Container> {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "test")
            .expect("the demo tree builds");
    Arc::new(Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens"))
}

/// 300 trees on a jittered 20 × 15 grid (15 m apart) in front of the origin, 40 far away (the far
/// path and its roots ranges), 20 behind the origin; random rotations and scales 0.8–1.2.
fn forest(model: ModelId) -> Vec<Instance> {
    let mut rng = SplitMix64(9);
    let mut place = |x: f32, z: f32| {
        let rotation = Quat::from_rotation_y(rng.range(0.0, std::f32::consts::TAU));
        let scale = Vec3::splat(rng.range(0.8, 1.2));
        let position = vec3(x + rng.range(-4.0, 4.0), 0.0, z + rng.range(-4.0, 4.0));
        Instance { model, transform: Mat4::from_scale_rotation_translation(scale, rotation, position) }
    };
    let mut instances = Vec::new();
    for i in 0..300 {
        instances.push(place((i % 20) as f32 * 15.0 - 150.0, -((i / 20) as f32) * 15.0));
    }
    for i in 0..40 {
        instances.push(place((i % 8) as f32 * 60.0 - 240.0, -400.0 - (i / 8) as f32 * 200.0));
    }
    for i in 0..20 {
        instances.push(place((i % 10) as f32 * 20.0 - 100.0, 60.0 + (i / 10) as f32 * 20.0));
    }
    instances
}

/// Cameras: near inside the forest, an overview, one looking along the forest's edge (half the
/// trees outside the frustum), and random ones.
fn cameras(width: u32, height: u32) -> Vec<(String, Camera)> {
    let mut cams = vec![
        ("near".to_owned(), Camera::look_at(vec3(3.0, 4.0, 10.0), vec3(-10.0, 3.0, -60.0), 0.9, width, height)),
        ("overview".to_owned(), Camera::look_at(vec3(0.0, 180.0, 250.0), vec3(0.0, 0.0, -300.0), 0.9, width, height)),
        ("edge".to_owned(), Camera::look_at(vec3(-160.0, 6.0, -100.0), vec3(-150.0, 4.0, 200.0), 1.0, width, height)),
    ];
    let mut rng = SplitMix64(77);
    for i in 0..4 {
        let eye = vec3(rng.range(-200.0, 200.0), rng.range(2.0, 120.0), rng.range(-300.0, 120.0));
        let target = vec3(rng.range(-150.0, 150.0), 0.0, rng.range(-250.0, 0.0));
        cams.push((format!("random-{i}"), Camera::look_at(eye, target, rng.range(0.5, 1.2), width, height)));
    }
    cams
}

/// Two renderers of the same scene: the CPU path and the GPU path.
fn renderers(gpu: &Gpu, settings: Settings) -> (Renderer, Renderer, Arc<Container>) {
    let container = demo_container();
    let mut cpu = Renderer::new(&gpu.device, Gpu::formats(), settings);
    let mut on_gpu = Renderer::new(&gpu.device, Gpu::formats(), settings);
    let a = cpu.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
    on_gpu.enable_gpu_selection(&gpu.device, &gpu.queue).expect("an empty scene fits");
    let b = on_gpu.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
    cpu.set_instances(&forest(a));
    on_gpu.set_instances(&forest(b));
    (cpu, on_gpu, container)
}

fn gpu_ranges(gpu: &Gpu, renderer: &Renderer) -> Vec<DrawRange> {
    renderer.read_gpu_selection(&gpu.device, &gpu.queue).expect("reads back").expect("the GPU selected")
}

#[test]
fn gpu_selection_equals_the_cpu_selection_at_many_cameras() {
    let gpu = gpu();
    let mut roots_ranges = 0;
    for (label, settings) in [
        ("default", Settings::default()),
        (
            "bias",
            Settings { s_min: 0.7, s_max: 3.0, depth_bias_k: 0.8, shading: Some((0.4, 1.0)), ..Settings::default() },
        ),
    ] {
        let (mut cpu, mut on_gpu, container) = renderers(&gpu, settings);
        let lod = ModelLod::from_container(&container);
        let mut totals = (0usize, 0usize, 0usize);
        for (name, cam) in cameras(1280, 720) {
            let what = format!("{label}/{name}");
            let cpu_stats = cpu.prepare(&gpu.device, &gpu.queue, &cam);
            assert!(!cpu_stats.gpu_selection && cpu_stats.ranges_clamped == 0, "{what}: {cpu_stats:?}");
            let stats = on_gpu.prepare(&gpu.device, &gpu.queue, &cam);
            assert!(stats.gpu_selection, "{what}: {stats:?}");
            let reference = cpu.selection().ranges().to_vec();
            let ranges = gpu_ranges(&gpu, &on_gpu);
            assert!(ranges.len() > 10, "{what}: {} ranges", ranges.len());
            let tolerated = assert_same_selection(&what, &reference, &ranges, &lod);
            let roots = ranges.iter().filter(|r| r.kind == Kind::Roots).count();
            eprintln!(
                "{what}: {} ranges ({roots} roots ranges), {} visible instances, {tolerated} at a threshold",
                ranges.len(),
                cpu_stats.instances_visible
            );
            totals = (totals.0 + ranges.len(), totals.1 + roots, totals.2 + tolerated);
            // Instance indices are the caller's: each drawn instance is one the CPU drew.
            assert!(ranges.iter().all(|r| (r.instance as usize) < 360 && r.model == 0));
        }
        assert!(totals.2 * 1000 <= totals.0, "{label}: {totals:?}: rounding explains only a few ranges");
        roots_ranges += totals.1;
    }
    assert!(roots_ranges > 0, "some far tree is one roots range");
}

#[test]
fn gpu_statistics_arrive_a_frame_or_two_later_and_match_the_cpu() {
    let gpu = gpu();
    let (mut cpu, mut on_gpu, container) = renderers(&gpu, Settings::default());
    let lod = ModelLod::from_container(&container);
    let (_, cam) = cameras(640, 360).swap_remove(0);
    let expected = cpu.prepare(&gpu.device, &gpu.queue, &cam);
    let first = on_gpu.prepare(&gpu.device, &gpu.queue, &cam);
    assert_eq!((first.instances_visible, first.ranges), (0, 0), "nothing read back before the first frame");
    let exact = assert_same_selection("stats", cpu.selection().ranges(), &gpu_ranges(&gpu, &on_gpu), &lod) == 0;
    let mut stats = first;
    for _ in 0..20 {
        gpu.device.poll(wgpu::PollType::wait_indefinitely()).expect("polls");
        stats = on_gpu.prepare(&gpu.device, &gpu.queue, &cam);
        if stats.ranges > 0 {
            break;
        }
    }
    assert_eq!(stats.instances_visible, expected.instances_visible, "{stats:?} vs {expected:?}");
    assert_eq!(stats.ranges_dropped, 0);
    if exact {
        assert_eq!(
            (stats.ranges, stats.submitted[Primitive::Triangle], stats.submitted[Primitive::Point]),
            (expected.ranges, expected.submitted[Primitive::Triangle], expected.submitted[Primitive::Point])
        );
    }
}

#[test]
fn both_paths_render_the_same_image() {
    let gpu = gpu();
    let settings = Settings { depth_bias_k: 0.5, shading: Some((0.5, 1.0)), ..Settings::default() };
    let (mut cpu, mut on_gpu, _) = renderers(&gpu, settings);
    for (name, cam) in cameras(256, 256).into_iter().take(4) {
        let (a, sa) = render_image(&gpu, &mut cpu, &cam, BACKGROUND).expect("renders");
        let (b, sb) = render_image(&gpu, &mut on_gpu, &cam, BACKGROUND).expect("renders");
        assert!(!sa.gpu_selection && sb.gpu_selection);
        let (diff, covered) = differing(&a, &b);
        eprintln!("{name}: {diff} of {covered} covered pixels differ");
        assert!(covered > 100, "{name}: the forest is in view");
        // Draw order within a bucket follows the atomics, so depth ties may resolve otherwise.
        assert!(diff * 200 <= covered, "{name}: {diff} of {covered} pixels differ");
    }
}

#[test]
fn instances_behind_the_camera_and_an_empty_list_draw_nothing() {
    let gpu = gpu();
    let container = demo_container();
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    let tree = renderer.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
    renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
    let cam = Camera::look_at(vec3(0.0, 4.0, 0.0), vec3(0.0, 4.0, -100.0), 0.8, 128, 128);

    // An empty list: no dispatch, no draw, no error.
    renderer.set_instances(&[]);
    let (image, stats) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    assert!(stats.gpu_selection);
    assert!(gpu_ranges(&gpu, &renderer).is_empty());
    assert!(image.rgba.chunks_exact(4).all(|p| p[..3] == [255, 255, 255]));

    // Behind the camera, near and far.
    let behind: Vec<Instance> = (0..100)
        .map(|i| Instance {
            model: tree,
            transform: Mat4::from_translation(vec3((i % 10) as f32 * 12.0 - 60.0, 0.0, 15.0 + (i / 10) as f32 * 90.0)),
        })
        .collect();
    renderer.set_instances(&behind);
    let (image, _) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    assert!(gpu_ranges(&gpu, &renderer).is_empty(), "nothing behind the camera is drawn");
    assert!(image.rgba.chunks_exact(4).all(|p| p[..3] == [255, 255, 255]));

    // Turned around, they are drawn; off again, the CPU selects.
    let back = Camera::look_at(vec3(0.0, 4.0, 0.0), vec3(0.0, 4.0, 100.0), 0.8, 128, 128);
    renderer.prepare(&gpu.device, &gpu.queue, &back);
    let ranges = gpu_ranges(&gpu, &renderer);
    assert!(!ranges.is_empty());
    renderer.disable_gpu_selection();
    let stats = renderer.prepare(&gpu.device, &gpu.queue, &back);
    assert!(!stats.gpu_selection && stats.ranges > 0);
    assert!(renderer.read_gpu_selection(&gpu.device, &gpu.queue).expect("reads").is_none());
    let lod = ModelLod::from_container(&container);
    assert_same_selection("behind, turned", renderer.selection().ranges(), &ranges, &lod);
}

#[test]
fn a_model_that_does_not_fit_the_budget_is_refused() {
    let gpu = gpu();
    let container = demo_container();
    let settings = Settings { memory_budget: 64 << 10, ..Settings::default() };
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
    renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("an empty scene fits");
    let error =
        renderer.add_model(&gpu.device, &gpu.queue, container).expect_err("the demo tree needs more than 64 KiB");
    assert!(matches!(error, treelod_render::RenderError::GpuSelectionBudget { model: 0, .. }), "{error}");
    assert!(renderer.gpu_selection_enabled());
}

/// A model none of whose trees is in view, added before one whose trees are: the first model's
/// buckets count no draw, and the second model's draws after them show as on the CPU path.
#[test]
fn a_model_with_no_tree_in_view_does_not_hide_the_next_models_trees() {
    let gpu = gpu();
    let container = demo_container();
    let mut cpu = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    let mut on_gpu = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    on_gpu.enable_gpu_selection(&gpu.device, &gpu.queue).expect("an empty scene fits");
    for renderer in [&mut cpu, &mut on_gpu] {
        let hidden = renderer.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
        let shown = renderer.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
        let row = |model: ModelId, z: f32| {
            (0..5).map(move |i| Instance {
                model,
                transform: Mat4::from_translation(vec3(i as f32 * 12.0 - 24.0, 0.0, z)),
            })
        };
        let instances: Vec<Instance> = row(hidden, 40.0).chain(row(shown, -40.0)).collect();
        renderer.set_instances(&instances);
    }
    let cam = Camera::look_at(vec3(0.0, 4.0, 0.0), vec3(0.0, 4.0, -100.0), 0.9, 160, 120);
    let (a, sa) = render_image(&gpu, &mut cpu, &cam, BACKGROUND).expect("renders");
    let (b, sb) = render_image(&gpu, &mut on_gpu, &cam, BACKGROUND).expect("renders");
    assert!(!sa.gpu_selection && sb.gpu_selection);
    let ranges = gpu_ranges(&gpu, &on_gpu);
    assert!(!ranges.is_empty() && ranges.iter().all(|r| r.model == 1), "only the second model is selected");
    let (diff, covered) = differing(&a, &b);
    assert!(covered > 100, "the second model's trees are in view: {covered} pixels");
    assert!(diff * 200 <= covered, "{diff} of {covered} pixels differ");
}

/// The draws name their instance's transform in a buffer the renderer uploads when the list of
/// instances changes. After a frame of one tree, a list of 300 (the buffer grows, and the bind
/// groups of both paths that hold it are made anew) whose last tree is the one in view, then the
/// same list with that tree moved (uploaded again, the buffer kept): each frame shows exactly what
/// a renderer given that list first shows, with CPU selection and with GPU selection.
#[test]
fn changed_instances_are_drawn_at_their_new_transforms_on_both_paths() {
    let gpu = gpu();
    let container = demo_container();
    let cam = Camera::look_at(vec3(0.0, 5.0, 16.0), vec3(0.0, 5.0, 0.0), 0.9, 160, 120);
    let behind = Mat4::from_translation(vec3(0.0, 0.0, 500.0));
    let row = |n: usize, seen: Mat4| -> Vec<Mat4> { (0..n).map(|i| if i + 1 == n { seen } else { behind }).collect() };
    let lists = [
        vec![Mat4::IDENTITY],
        row(300, Mat4::from_translation(vec3(-4.0, 0.0, 0.0))),
        row(
            300,
            Mat4::from_scale_rotation_translation(Vec3::splat(0.8), Quat::from_rotation_y(1.0), vec3(5.0, 0.0, 0.0)),
        ),
        // The transforms outgrow their buffer again (32,800 bytes past its 32 KiB), the
        // selection's draws not.
        row(410, Mat4::from_translation(vec3(3.0, 0.0, 0.0))),
    ];
    for gpu_selection in [false, true] {
        let new_renderer = || {
            let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
            let tree = renderer.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
            if gpu_selection {
                renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
            }
            (renderer, tree)
        };
        let (mut renderer, tree) = new_renderer();
        let mut images = Vec::new();
        for (k, list) in lists.iter().enumerate() {
            let instances: Vec<Instance> = list.iter().map(|&transform| Instance { model: tree, transform }).collect();
            renderer.set_instances(&instances);
            let (image, stats) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
            // GPU selection's counts are read back from an earlier frame.
            assert_eq!(stats.gpu_selection, gpu_selection, "list {k}");
            assert!(gpu_selection || stats.instances_visible == 1, "list {k}: {stats:?}");
            let (mut fresh, tree) = new_renderer();
            fresh.set_instances(&list.iter().map(|&transform| Instance { model: tree, transform }).collect::<Vec<_>>());
            let (reference, _) = render_image(&gpu, &mut fresh, &cam, BACKGROUND).expect("renders");
            let (diff, covered) = differing(&image, &reference);
            assert!(covered > 300 && diff == 0, "GPU selection {gpu_selection}, list {k}: {diff} of {covered} differ");
            images.push(image);
        }
        let (moved, covered) = differing(&images[1], &images[2]);
        assert!(moved * 4 > covered, "the moved tree is drawn elsewhere: {moved} of {covered} pixels differ");
    }
}
