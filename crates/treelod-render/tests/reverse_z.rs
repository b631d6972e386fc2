//! Reverse-Z depth (`DepthConvention::Reverse`, as Bevy draws): two overlapping trees drawn with
//! a reverse-Z infinite projection into a depth buffer cleared to 0 look as they do with the
//! standard projection and convention; with the standard depth test the far tree shows through.
//! The occlusion measurement of pruned trees reads such a buffer the right way round.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, covered, demo_built, gpu, keep};
use glam::{Mat4, Vec3, vec3};
use treelod_build::{BuildConfig, PruneConfig};
use treelod_render::Primitive;
use treelod_render::offscreen::{Image, render_image};
use treelod_render::{Camera, DepthConvention, Instance, Pruning, Renderer, Settings, Technique};

const SIZE: u32 = 256;
const FOVY: f32 = 0.8;

/// A renderer with `depth` drawing two demo trees, the second 6 m behind the first and 1.5 m
/// to the side, so that the first hides part of the second.
fn two_trees(
    gpu: &treelod_render::offscreen::Gpu,
    container: &Arc<treelod_format::Container>,
    depth: DepthConvention,
) -> Renderer {
    let mut renderer = Renderer::with_depth_convention(
        &gpu.device,
        treelod_render::offscreen::Gpu::formats(),
        Settings::default(),
        depth,
    );
    assert_eq!(renderer.depth_convention(), depth);
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).expect("uploads");
    renderer.set_instances(&[
        Instance { model: tree, transform: Mat4::IDENTITY },
        Instance { model: tree, transform: Mat4::from_translation(vec3(1.5, 0.0, -6.0)) },
    ]);
    renderer
}

/// Pixels whose colour differs by more than 24 levels in a channel.
fn differing(a: &Image, b: &Image) -> usize {
    a.rgba
        .chunks_exact(4)
        .zip(b.rgba.chunks_exact(4))
        .filter(|(p, q)| p.iter().zip(q.iter()).take(3).any(|(x, y)| x.abs_diff(*y) > 24))
        .count()
}

#[test]
fn reverse_z_draws_what_standard_depth_draws() {
    let gpu = gpu();
    let container = demo_built(&BuildConfig::default());
    let block = container.block();
    let centre = 0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max));
    let standard_camera =
        Camera::look_at(centre + vec3(0.0, 0.0, 11.0), centre - vec3(0.0, 0.0, 3.0), FOVY, SIZE, SIZE);
    // Bevy's projection: reverse Z, infinite far plane, the same near plane.
    let reverse_proj = glam::camera::rh::proj::directx::perspective_infinite_reverse(FOVY, 1.0, 0.05);
    let reverse_camera = Camera::from_matrices(standard_camera.view, reverse_proj, SIZE, SIZE);
    assert!(
        (reverse_camera.fovy - FOVY).abs() < 1e-5 && reverse_camera.position.distance(standard_camera.position) < 1e-3
    );

    let mut standard = two_trees(&gpu, &container, DepthConvention::Standard);
    let (reference, reference_stats) =
        render_image(&gpu, &mut standard, &standard_camera, BACKGROUND).expect("renders");
    let mut reverse = two_trees(&gpu, &container, DepthConvention::Reverse);
    let (image, stats) = render_image(&gpu, &mut reverse, &reverse_camera, BACKGROUND).expect("renders");
    // The standard depth test on reverse-Z depth keeps the farther fragment.
    let (wrong, _) = render_image(&gpu, &mut standard, &reverse_camera, BACKGROUND).expect("renders");
    keep(&reference, "reverse-z-reference");
    keep(&image, "reverse-z");
    keep(&wrong, "reverse-z-wrong-test");

    // The same selection (same eye, field of view and frustum sides).
    assert_eq!(stats.instances_visible, 2);
    assert_eq!(
        (stats.submitted[Primitive::Triangle], stats.submitted[Primitive::Point]),
        (reference_stats.submitted[Primitive::Triangle], reference_stats.submitted[Primitive::Point])
    );
    let trees = covered(&reference).iter().filter(|c| **c).count();
    let total = (SIZE * SIZE) as usize;
    assert!(trees > total / 10, "the trees cover {trees} of {total} pixels");
    let same = differing(&reference, &image);
    let swapped = differing(&reference, &wrong);
    eprintln!("{trees} tree pixels; {same} differ with reverse Z, {swapped} with the wrong depth test");
    // Depth precision differs between the two projections: a few pixels of near-coincident
    // leaves may resolve the other way.
    assert!(same * 200 < trees, "{same} of {trees} tree pixels differ with reverse Z");
    // Where the trees overlap the wrong test shows the far one: the comparison can tell.
    assert!(swapped > 20 * same.max(10), "{swapped} pixels differ with the wrong depth test");
}

#[test]
fn occlusion_reads_the_depth_buffer_of_either_convention() {
    let gpu = gpu();
    // Priority lists at a coarse measurement (the occlusion factor does not depend on it).
    let prune = PruneConfig { resolution: 64, views: 2, ..PruneConfig::default() };
    let container = demo_built(&BuildConfig { prune: Some(prune), ..BuildConfig::default() });
    let block = container.block();
    let centre = 0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max));
    let standard_camera = Camera::look_at(centre + vec3(0.0, 0.0, 10.0), centre, FOVY, SIZE, SIZE);
    let reverse_proj = glam::camera::rh::proj::directx::perspective_infinite_reverse(FOVY, 1.0, 0.05);
    for (depth, camera) in [
        (DepthConvention::Standard, standard_camera),
        (DepthConvention::Reverse, Camera::from_matrices(standard_camera.view, reverse_proj, SIZE, SIZE)),
    ] {
        let mut renderer = Renderer::with_depth_convention(
            &gpu.device,
            treelod_render::offscreen::Gpu::formats(),
            Settings::default(),
            depth,
        );
        let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("uploads");
        // A tree in front of the camera and one straight behind it.
        renderer.set_instances(&[
            Instance { model: tree, transform: Mat4::IDENTITY },
            Instance { model: tree, transform: Mat4::from_translation(vec3(0.0, 0.0, -25.0)) },
        ]);
        renderer.settings_mut().technique = Technique::PruneOpt;
        renderer.settings_mut().pruning =
            Pruning { lambda: Some(1.0), occlusion: true, spt_below_pixels: 0.0, ..Pruning::default() };
        // Frame 1 measures; frame 2 reads the measurement.
        render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        let f = renderer.visible_fractions().to_vec();
        eprintln!("{depth:?}: visible fractions {f:?}");
        assert!(f[0] > 0.95, "{depth:?}: the front tree is visible: {f:?}");
        assert!(f[1] < 0.5, "{depth:?}: the tree behind it is mostly hidden: {f:?}");
    }
}
