//! Trees cast into shadow maps the host renders itself (an engine's directional-light
//! cascades, `Renderer::set_host_shadow_views`), on the Vulkan backend (Mesa lavapipe in CI):
//! the map's texels the trees cover against the full mesh's, in both depth conventions, with the
//! map's near plane cutting the tree (casters pancaked onto it where depth can be clamped), and
//! what is refused; and trees receiving the host's maps (`Renderer::receive_host_shadows`) as
//! they receive the renderer's own.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, ball, demo_built, gpu, mask_precision_recall, open_verified};
use glam::{Mat4, Vec3, Vec4, vec3};
use treelod_build::{BuildConfig, Placed, build_block};
use treelod_format::Container;
use treelod_render::offscreen::{Gpu, Image, Readback, render_prepared_timed};
use treelod_render::{
    Camera, DepthConvention, FrameStats, HostShadowCascade, HostShadowError, HostShadowView, Instance, Renderer,
    Settings, Shadows, Technique,
};

/// Texels per side of the host's map.
const MAP: u32 = 256;

/// The host's depth format (Bevy's shadow maps' too).
const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// A host's orthographic light view of the tree along `sun`: a square of half-side `radius`
/// around `centre`, its near plane `near` in front of the centre towards the sun and its far
/// plane `depth` behind that, in `convention` (reverse Z as Bevy's cascades: near at 1).
fn light_view(centre: Vec3, sun: Vec3, radius: f32, near: f32, depth: f32, convention: DepthConvention) -> Mat4 {
    let view = glam::camera::rh::view::look_to_mat4(centre + sun * near, -sun, Vec3::Y);
    let standard = glam::camera::rh::proj::directx::orthographic(-radius, radius, -radius, radius, 0.0, depth) * view;
    match convention {
        DepthConvention::Standard => standard,
        // z' = w − z: near (0) to 1, far (1) to 0.
        DepthConvention::Reverse => {
            Mat4::from_cols(Vec4::X, Vec4::Y, Vec4::new(0.0, 0.0, -1.0, 0.0), Vec4::new(0.0, 0.0, 1.0, 1.0)) * standard
        }
    }
}

/// The host's map after the renderer drew its trees into it (cleared to the convention's far
/// depth first): each texel's depth, rows top to bottom.
fn host_map(gpu: &Gpu, renderer: &Renderer, convention: DepthConvention, k: usize) -> Vec<f32> {
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("host shadow map"),
        size: wgpu::Extent3d { width: MAP, height: MAP, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: FORMAT,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
    {
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("host shadow pass"),
            color_attachments: &[],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(convention.far()),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            ..wgpu::RenderPassDescriptor::default()
        });
        renderer.render_host_shadow(k, &mut pass);
    }
    let readback = Readback::record(&gpu.device, &mut encoder, &texture);
    gpu.queue.submit([encoder.finish()]);
    let texels = readback.read(&gpu.device).expect("reads the map back");
    texels.rgba.chunks_exact(4).map(|t| f32::from_le_bytes([t[0], t[1], t[2], t[3]])).collect()
}

/// A renderer of one tree drawing into the host's map `light` for `camera`'s frame: the frame's
/// counts and the map.
fn cast(
    gpu: &Gpu,
    container: &Arc<Container>,
    settings: Settings,
    convention: DepthConvention,
    light: Mat4,
    camera: &Camera,
) -> (FrameStats, Vec<f32>) {
    let mut renderer = Renderer::with_depth_convention(&gpu.device, Gpu::formats(), settings, convention);
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).expect("uploads");
    renderer.set_instances(&[Instance { model: tree, transform: Mat4::IDENTITY }]);
    let taken = renderer.set_host_shadow_views(
        &gpu.device,
        FORMAT,
        &[HostShadowView { clip_from_world: light, resolution: MAP }],
    );
    assert_eq!(taken, 1, "an orthographic view is taken");
    // The policy's and the streaming's state settle over a few frames.
    let mut stats = FrameStats::default();
    for _ in 0..4 {
        stats = renderer.prepare(&gpu.device, &gpu.queue, camera);
    }
    (stats, host_map(gpu, &renderer, convention, 0))
}

/// The texels the trees cover: nearer than the cleared far depth.
fn covered(map: &[f32], convention: DepthConvention) -> Vec<bool> {
    map.iter().map(|&d| d != convention.far()).collect()
}

fn count(mask: &[bool]) -> usize {
    mask.iter().filter(|m| **m).count()
}

#[test]
fn trees_cast_into_a_host_shadow_map_as_the_full_mesh_does() {
    let gpu = gpu();
    let container = demo_built(&BuildConfig::default());
    let block = container.block();
    let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let (centre, height) = (0.5 * (min + max), max.y - min.y);
    let sun = vec3(0.4, 0.8, 0.45).normalize();
    let radius = 0.8 * height;
    // The camera: the tree about 150 pixels high (points and triangles mixed).
    let camera = Camera::look_at(centre + vec3(0.0, 0.0, 4.0 * height), centre, 0.8, 320, 240);
    let standard = DepthConvention::Standard;
    let whole = light_view(centre, sun, radius, 2.0 * height, 4.0 * height, standard);
    let full = Settings { technique: Technique::Full, ..Settings::default() };

    let (full_stats, full_map) = cast(&gpu, &container, full, standard, whole, &camera);
    let reference = covered(&full_map, standard);
    eprintln!("full mesh: {} texels, host maps {:?}", count(&reference), full_stats.host_shadow);
    assert_eq!(full_stats.host_shadow.cascades, 1);
    assert_eq!(full_stats.shadow.cascades, 0, "the renderer's own cascades stay off");
    assert!(full_stats.host_shadow.primitives() > 0);
    assert!(count(&reference) > 2000, "the full mesh covers the map ({} texels)", count(&reference));
    assert!(full_map.iter().all(|d| (0.0..=1.0).contains(d)));

    // The default settings: the trees selected from the light's view, as the renderer's own
    // cascades select them.
    let (stats, map) = cast(&gpu, &container, Settings::default(), standard, whole, &camera);
    let (p, r) = mask_precision_recall(&covered(&map, standard), &reference);
    eprintln!(
        "defaults: {} texels, P {p:.3} R {r:.3}, {} primitives against {}",
        count(&covered(&map, standard)),
        stats.host_shadow.primitives(),
        full_stats.host_shadow.primitives()
    );
    assert!(p > 0.8 && r > 0.8, "the selected trees cast the full mesh's shadow: P {p:.3} R {r:.3}");
    // A default build holds the point tree alone: the policy has nothing else to choose.
    assert_eq!(stats.host_shadow.instances[Technique::Spt], 1, "{:?}", stats.host_shadow);
}

#[test]
fn host_views_that_are_not_orthographic_are_refused() {
    let gpu = gpu();
    let container = demo_built(&BuildConfig::default());
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("uploads");
    renderer.set_instances(&[Instance { model: tree, transform: Mat4::IDENTITY }]);
    let perspective = glam::camera::rh::proj::directx::perspective(0.8, 1.0, 0.1, 100.0)
        * glam::camera::rh::view::look_at_mat4(Vec3::splat(20.0), Vec3::ZERO, Vec3::Y);
    let singular = Mat4::ZERO;
    let ortho = light_view(Vec3::ZERO, vec3(0.3, 0.9, 0.2).normalize(), 10.0, 10.0, 20.0, DepthConvention::Standard);
    let views = [perspective, singular, ortho].map(|m| HostShadowView { clip_from_world: m, resolution: MAP });
    assert_eq!(renderer.set_host_shadow_views(&gpu.device, FORMAT, &views), 1, "only the orthographic view");
    let camera = Camera::look_at(vec3(0.0, 5.0, 30.0), Vec3::ZERO, 0.8, 160, 120);
    let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
    assert_eq!(stats.host_shadow.cascades, 1);
    assert!(stats.host_shadow.instances_visible == 1, "{:?}", stats.host_shadow);
    // `k` is the view's index in the list given: the refused views draw nothing.
    let standard = DepthConvention::Standard;
    assert!(count(&covered(&host_map(&gpu, &renderer, standard, 2), standard)) > 1000, "view 2 casts");
    assert_eq!(count(&covered(&host_map(&gpu, &renderer, standard, 0), standard)), 0, "view 0 was refused");
    let many = vec![views[2]; 12];
    assert_eq!(renderer.set_host_shadow_views(&gpu.device, FORMAT, &many), treelod_render::MAX_HOST_SHADOW_VIEWS);
    assert_eq!(renderer.set_host_shadow_views(&gpu.device, FORMAT, &[]), 0);
    let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
    assert_eq!(stats.host_shadow, treelod_render::ShadowStats::default(), "no host maps, nothing cast");
}

#[test]
fn reverse_z_host_maps_hold_the_same_depths_mirrored() {
    let gpu = gpu();
    // An opaque ball: no hashed alpha test, whose pattern depends on the depth.
    let scene = ball(24);
    let config = BuildConfig { ao: None, ..BuildConfig::default() };
    let built = build_block(&scene.name, &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "test");
    let container = open_verified(&built.expect("builds").data);
    let sun = vec3(0.4, 0.8, 0.45).normalize();
    let camera = Camera::look_at(vec3(0.0, 1.0, 8.0), Vec3::ZERO, 0.8, 320, 240);
    let full = Settings { technique: Technique::Full, ..Settings::default() };
    let [standard, reverse] = [DepthConvention::Standard, DepthConvention::Reverse];
    let (_, map) =
        cast(&gpu, &container, full, standard, light_view(Vec3::ZERO, sun, 1.5, 3.0, 6.0, standard), &camera);
    let (_, map_reverse) =
        cast(&gpu, &container, full, reverse, light_view(Vec3::ZERO, sun, 1.5, 3.0, 6.0, reverse), &camera);
    let (mask, mask_reverse) = (covered(&map, standard), covered(&map_reverse, reverse));
    let (p, r) = mask_precision_recall(&mask_reverse, &mask);
    eprintln!("ball: {} texels, reverse Z P {p:.4} R {r:.4}", count(&mask));
    assert!(count(&mask) > 20_000, "the ball covers the map ({} texels)", count(&mask));
    assert!(p > 0.99 && r > 0.99, "reverse Z covers the same texels: P {p:.4} R {r:.4}");
    // The nearest surface's depth, mirrored to the precision of the two matrices.
    let both: Vec<(f32, f32)> =
        map.iter().zip(&map_reverse).filter(|(s, r)| **s < 1.0 && **r > 0.0).map(|(s, r)| (*s, *r)).collect();
    let worst = both.iter().map(|(s, r)| (1.0 - r - s).abs()).fold(0.0, f32::max);
    eprintln!("{} texels in both, largest |1 - reverse - standard| {worst:e}", both.len());
    assert!(worst < 1e-4, "depths mirror each other (largest difference {worst:e})");
    // Nearer is greater in reverse Z: the ball's front (towards the sun) is nearer than 0.5.
    let nearest = both.iter().map(|(s, _)| *s).fold(1.0, f32::min);
    let farthest = both.iter().map(|(s, _)| *s).fold(0.0, f32::max);
    eprintln!("standard depths {nearest} to {farthest}");
    // The ball's top, 1 m in front of its centre, 2 m behind the near plane of a 6 m range; its
    // rim about at the centre's depth.
    assert!((nearest - 2.0 / 6.0).abs() < 1e-3 && farthest < 0.52, "{nearest} to {farthest}");

    // The near plane through the ball's centre, as an engine fits a cascade's depth to the
    // view: where depth is clamped, the half towards the sun is pancaked onto the near plane
    // and still casts (the shadow's outline whole, its depth the near plane's); else it is
    // clipped away and the inside of the far half is seen.
    let (_, cut) = cast(&gpu, &container, full, reverse, light_view(Vec3::ZERO, sun, 1.5, 0.0, 6.0, reverse), &camera);
    let cut_mask = covered(&cut, reverse);
    let (p, r) = mask_precision_recall(&cut_mask, &mask);
    let on_near = cut.iter().filter(|d| **d == 1.0).count();
    let clamps = gpu.device.features().contains(wgpu::Features::DEPTH_CLIP_CONTROL);
    eprintln!("near plane through the ball (depth clamped: {clamps}): P {p:.4} R {r:.4}, {on_near} texels on it");
    assert!(p > 0.99 && r > 0.99, "the ball's outline is whole: P {p:.4} R {r:.4}");
    if clamps {
        assert!(on_near * 10 > count(&mask) * 9, "the near half lies on the near plane ({on_near} texels)");
    } else {
        assert_eq!(on_near, 0, "without clamping the near half is clipped");
    }
}

/// A host's depth texture array of `layers` layers of `size`² texels, as an engine's
/// directional-light maps: drawn into and sampled.
fn host_array(gpu: &Gpu, size: u32, layers: u32, usage: wgpu::TextureUsages) -> wgpu::Texture {
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("host shadow maps"),
        size: wgpu::Extent3d { width: size, height: size, depth_or_array_layers: layers },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: FORMAT,
        usage,
        view_formats: &[],
    })
}

/// Mean green of the leaves (green well above red; the background is white) in each of
/// `regions` (pixel rectangles x0, y0, x1, y1).
fn leaf_green(image: &Image, regions: &[(f32, f32, f32, f32)]) -> Vec<f64> {
    let (w, h) = (image.width as f32 - 1.0, image.height as f32 - 1.0);
    regions
        .iter()
        .map(|&(x0, y0, x1, y1)| {
            let (mut sum, mut n) = (0.0, 0.0);
            for y in (y0.max(0.0) as u32)..(y1.min(h) as u32) {
                for x in (x0.max(0.0) as u32)..(x1.min(w) as u32) {
                    let p = image.pixel(x, y);
                    if f32::from(p[1]) > 1.15 * f32::from(p[0]) {
                        sum += f64::from(p[1]);
                        n += 1.0;
                    }
                }
            }
            sum / f64::max(n, 1.0)
        })
        .collect()
}

/// Texels per side of the maps the trees receive.
const RECEIVED: u32 = 1024;

#[test]
fn trees_receive_the_host_shadow_maps_as_they_receive_their_own() {
    let gpu = gpu();
    let container = demo_built(&BuildConfig::default());
    let block = container.block();
    let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let height = max.y - min.y;
    // The sun nearly overhead: a tree above another shadows it, a third beside them is lit.
    let sun = vec3(0.05, 1.0, 0.03).normalize();
    let above = Mat4::from_translation(vec3(0.0, 1.5 * height, 0.0));
    let beside = Mat4::from_translation(vec3(2.0 * (max.x - min.x), 0.0, 0.0));
    let transforms = [Mat4::IDENTITY, above, beside];
    let look = 0.5 * (min + max) + vec3(max.x - min.x, 0.75 * height, 0.0);
    let camera = Camera::look_at(look + vec3(0.0, 0.0, 6.0 * height), look, 0.8, 240, 240);
    let project = |p: Vec3| {
        let ndc = camera.view_proj().project_point3(p);
        ((0.5 * ndc.x + 0.5) * 240.0, (0.5 - 0.5 * ndc.y) * 240.0)
    };
    let regions = transforms.map(|t| {
        let (a, b) = (project(t.transform_point3(min)), project(t.transform_point3(max)));
        (a.0.min(b.0), a.1.min(b.1), a.0.max(b.0), a.1.max(b.1))
    });
    let lit = Settings { sun, ambient: 0.3, ..Settings::default() };
    let renderer_with = |settings: Settings, convention: DepthConvention| {
        let mut renderer = Renderer::with_depth_convention(&gpu.device, Gpu::formats(), settings, convention);
        let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("uploads");
        renderer.set_instances(&transforms.map(|transform| Instance { model: tree, transform }));
        renderer
    };
    // Four frames each: the streaming and the policy's state settle.
    let settle = |renderer: &mut Renderer, host: Option<&dyn Fn(&Renderer)>| {
        let mut image = None;
        for _ in 0..4 {
            let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
            let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
            renderer.render_shadows(&mut encoder);
            gpu.queue.submit([encoder.finish()]);
            if let Some(host) = host {
                host(renderer);
            }
            image = Some((
                leaf_green(&render_prepared_timed(&gpu, renderer, &camera, BACKGROUND).expect("renders").0, &regions),
                stats,
            ));
        }
        image.expect("four frames")
    };

    let (unshadowed, _) = settle(&mut renderer_with(lit, DepthConvention::Standard), None);
    let own_settings = Settings {
        shadows: Some(Shadows { resolution: RECEIVED, cascades: 2, distance: 8.0 * height, ..Shadows::default() }),
        ..lit
    };
    let (own, stats) = settle(&mut renderer_with(own_settings, DepthConvention::Standard), None);
    assert_eq!(stats.shadow.cascades, 2);
    eprintln!("mean leaf green (below, above, beside): unshadowed {unshadowed:?}, the renderer's own maps {own:?}");
    assert!(own[0] < 0.8 * unshadowed[0], "own maps: the tree below is shadowed");

    for convention in [DepthConvention::Standard, DepthConvention::Reverse] {
        // The renderer's own cascades are set too: the host's maps replace them.
        let mut renderer = renderer_with(own_settings, convention);
        let (lo, hi) = renderer.instance_bounds().expect("bounds");
        let radius = 0.5 * (hi - lo).length();
        let light = light_view(0.5 * (lo + hi), sun, radius, 2.0 * radius, 4.0 * radius, convention);
        // The trees' map in layer 1; layer 0 holds a caster in front of everything, so reading
        // the wrong layer would shadow every tree.
        let maps = host_array(
            &gpu,
            RECEIVED,
            2,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let layer = |k: u32| {
            maps.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: k,
                array_layer_count: Some(1),
                ..wgpu::TextureViewDescriptor::default()
            })
        };
        let (front, trees) = (layer(0), layer(1));
        assert_eq!(
            renderer.set_host_shadow_views(
                &gpu.device,
                FORMAT,
                &[HostShadowView { clip_from_world: light, resolution: RECEIVED }]
            ),
            1
        );
        let cascade = HostShadowCascade { clip_from_world: light, layer: 1 };
        assert_eq!(renderer.receive_host_shadows(&gpu.device, &gpu.queue, &maps, &[cascade]), Ok(1));
        let host = |renderer: &Renderer| {
            let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
            for (view, depth) in [(&front, 1.0 - convention.far()), (&trees, convention.far())] {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("host shadow pass"),
                    color_attachments: &[],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view,
                        depth_ops: Some(wgpu::Operations {
                            load: wgpu::LoadOp::Clear(depth),
                            store: wgpu::StoreOp::Store,
                        }),
                        stencil_ops: None,
                    }),
                    ..wgpu::RenderPassDescriptor::default()
                });
                if std::ptr::eq(view, &trees) {
                    renderer.render_host_shadow(0, &mut pass);
                }
            }
            gpu.queue.submit([encoder.finish()]);
        };
        let (received, stats) = settle(&mut renderer, Some(&host));
        eprintln!("{convention:?}: the host's maps {received:?}");
        assert_eq!(stats.shadow.cascades, 0, "{convention:?}: the renderer's own cascades are not fitted");
        assert_eq!(stats.host_shadow.cascades, 1);
        assert_eq!(stats.host_shadows_received, 1);
        assert!(received[0] < 0.8 * unshadowed[0], "{convention:?}: the tree below is shadowed: {received:?}");
        assert!(received[1] > 0.8 * unshadowed[1], "{convention:?}: the tree above is lit: {received:?}");
        assert!(received[2] > 0.8 * unshadowed[2], "{convention:?}: the tree beside is lit: {received:?}");
        // Each crown shadows itself; the tree below is also in the shadow of the one above.
        assert!(received[0] < 0.95 * received[1].min(received[2]), "{convention:?}: {received:?}");
        for k in 0..3 {
            let (host_share, own_share) = (received[k] / unshadowed[k], own[k] / unshadowed[k]);
            assert!(
                (host_share - own_share).abs() < 0.1,
                "tree {k}: {host_share:.3} of the light with the host's maps, {own_share:.3} with the renderer's"
            );
        }
        // A renderer selecting on the GPU receives the same maps (the first one casts into them).
        let mut gpu_selected = renderer_with(lit, convention);
        gpu_selected.enable_gpu_selection(&gpu.device, &gpu.queue).expect("GPU selection");
        assert_eq!(gpu_selected.receive_host_shadows(&gpu.device, &gpu.queue, &maps, &[cascade]), Ok(1));
        let (on_gpu, stats) = settle(&mut gpu_selected, Some(&|_: &Renderer| host(&renderer)));
        eprintln!("{convention:?}: the host's maps, GPU selection {on_gpu:?}");
        assert!(stats.gpu_selection && stats.host_shadows_received == 1, "{stats:?}");
        for k in 0..3 {
            assert!((on_gpu[k] / received[k] - 1.0).abs() < 0.05, "{convention:?}: {on_gpu:?} vs {received:?}");
        }

        // An empty list stops: the trees receive the renderer's own cascades again.
        assert_eq!(renderer.receive_host_shadows(&gpu.device, &gpu.queue, &maps, &[]), Ok(0));
        let (stopped, stats) = settle(&mut renderer, Some(&host));
        eprintln!("{convention:?}: stopped {stopped:?}");
        assert_eq!(stats.shadow.cascades, 2);
        assert_eq!(stats.host_shadows_received, 0);
        // The same as a renderer of this convention that never received the host's maps.
        let (own_here, _) = settle(&mut renderer_with(own_settings, convention), None);
        for k in 0..3 {
            assert!(
                (stopped[k] / own_here[k] - 1.0).abs() < 0.01,
                "{convention:?}: own maps again: {stopped:?} vs {own_here:?}"
            );
        }
        // So does stopping outright; without own cascades the trees are lit.
        assert_eq!(renderer.receive_host_shadows(&gpu.device, &gpu.queue, &maps, &[cascade]), Ok(1));
        renderer.stop_receiving_host_shadows();
        renderer.settings_mut().shadows = None;
        let (lit_again, _) = settle(&mut renderer, Some(&host));
        for k in 0..3 {
            assert!((lit_again[k] / unshadowed[k] - 1.0).abs() < 0.02, "{convention:?}: lit: {lit_again:?}");
        }
    }
}

#[test]
fn host_shadow_maps_that_cannot_be_received_are_refused() {
    let gpu = gpu();
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    let light = light_view(Vec3::ZERO, vec3(0.3, 0.9, 0.2).normalize(), 10.0, 10.0, 20.0, DepthConvention::Standard);
    let sampled = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
    let receive = |renderer: &mut Renderer, maps: &wgpu::Texture, layer: u32| {
        renderer.receive_host_shadows(
            &gpu.device,
            &gpu.queue,
            maps,
            &[HostShadowCascade { clip_from_world: light, layer }],
        )
    };
    let maps = host_array(&gpu, MAP, 2, sampled);
    assert_eq!(receive(&mut renderer, &maps, 2), Err(HostShadowError::NoLayer { layer: 2, layers: 2 }));
    let unsampled = host_array(&gpu, MAP, 2, wgpu::TextureUsages::RENDER_ATTACHMENT);
    assert_eq!(receive(&mut renderer, &unsampled, 0), Err(HostShadowError::NotSampled));
    let colour = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("not a depth texture"),
        size: wgpu::Extent3d { width: MAP, height: MAP, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: sampled,
        view_formats: &[],
    });
    let error = receive(&mut renderer, &colour, 0).expect_err("a colour texture is refused");
    assert!(error.to_string().contains("not a 2D depth texture array"), "{error}");
    // Perspective views are left out; one layer of a 2D texture is taken.
    let perspective = glam::camera::rh::proj::directx::perspective(0.8, 1.0, 0.1, 100.0)
        * glam::camera::rh::view::look_at_mat4(Vec3::splat(20.0), Vec3::ZERO, Vec3::Y);
    let single = host_array(&gpu, MAP, 1, sampled);
    let cascades = [
        HostShadowCascade { clip_from_world: perspective, layer: 0 },
        HostShadowCascade { clip_from_world: light, layer: 0 },
    ];
    assert_eq!(renderer.receive_host_shadows(&gpu.device, &gpu.queue, &single, &cascades), Ok(1));
    let many = vec![HostShadowCascade { clip_from_world: light, layer: 1 }; 6];
    assert_eq!(renderer.receive_host_shadows(&gpu.device, &gpu.queue, &maps, &many), Ok(treelod_render::MAX_CASCADES));
    // Each frame's call over the same texture keeps the bind group; another texture gets its own.
    let bound = renderer.shadow_bind_group().clone();
    assert_eq!(receive(&mut renderer, &maps, 0), Ok(1));
    assert_eq!(&bound, renderer.shadow_bind_group(), "the same texture, the same bind group");
    assert_eq!(receive(&mut renderer, &single, 0), Ok(1));
    assert_ne!(&bound, renderer.shadow_bind_group(), "another texture");
    renderer.stop_receiving_host_shadows();
}
