//! Shadow maps on the Vulkan backend (Mesa lavapipe in CI): the demo tree's shadow on a ground
//! plane from every representation against the full mesh's (coverage precision and recall of
//! the shadow mask), the cost of the shadow pass, and trees receiving shadows.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, demo_built, gpu, light_taken, mask_precision_recall, shadow_mask};
use glam::{Mat4, Vec3, vec3};
use treelod_build::{BuildConfig, ImpostorConfig, LodChainConfig, PruneConfig};
use treelod_format::Container;
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, Image, render_prepared_scene};
use treelod_render::{Camera, FrameStats, Ground, Instance, Pruning, Renderer, Settings, Shadows, Technique};

/// The demo tree with every representation: points, pruning lists, impostors and baselines.
fn demo_everything() -> Arc<Container> {
    demo_built(&BuildConfig {
        prune: Some(PruneConfig::default()),
        impostors: Some(ImpostorConfig::default()),
        baselines: Some(LodChainConfig::default()),
        ..BuildConfig::default()
    })
}

fn keep(image: &Image, name: &str) {
    if let Some(dir) = std::env::var_os("TREELOD_TEST_IMAGES") {
        let mut ppm = format!("P6 {} {} 255\n", image.width, image.height).into_bytes();
        ppm.extend(image.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]));
        std::fs::write(std::path::Path::new(&dir).join(format!("{name}.ppm")), ppm).expect("writes");
    }
}

/// One frame of `renderer` for `camera`: the ground only (`trees: false`) or with the trees.
fn frame(gpu: &Gpu, renderer: &mut Renderer, ground: &Ground, camera: &Camera, trees: bool) -> (Image, FrameStats) {
    let stats = renderer.prepare(&gpu.device, &gpu.queue, camera);
    let (image, _) = render_prepared_scene(gpu, renderer, camera, BACKGROUND, Some(ground), trees).expect("renders");
    (image, stats)
}

#[test]
fn every_representation_casts_the_shadow_of_the_full_mesh() {
    let gpu = gpu();
    let container = demo_everything();
    let block = container.block();
    let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let sun = vec3(0.4, 0.8, 0.45).normalize();
    // Looking down at the ground where the shadow falls, from above the tree's top.
    let height = max.y - min.y;
    let shadow_centre = vec3(0.5 * (min.x + max.x), min.y, 0.5 * (min.z + max.z))
        - sun * (0.5 * height / sun.y) * vec3(1.0, 0.0, 1.0).length();
    let eye = shadow_centre + vec3(0.0, 3.0 * height, 0.3);
    let camera = Camera::look_at(eye, shadow_centre, 0.8, 200, 200);
    let shadows = Shadows { resolution: 512, cascades: 1, distance: 6.0 * height, ..Shadows::default() };
    let settings = Settings { sun, shadows: Some(shadows), ..Settings::default() };
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings { technique: Technique::Full, ..settings });
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("uploads");
    renderer.set_instances(&[Instance { model: tree, transform: Mat4::IDENTITY }]);
    let ground = Ground::under_instances(&gpu.device, &renderer);

    renderer.settings_mut().shadows = None;
    let (lit, _) = frame(&gpu, &mut renderer, &ground, &camera, false);
    keep(&lit, "shadow-lit");
    assert!(shadow_mask(&lit, &lit).iter().all(|m| !m));
    // The full mesh in a fine map (texels of a few millimetres), and in the map the
    // representations are drawn into.
    renderer.settings_mut().shadows = Some(Shadows { resolution: 4096, ..shadows });
    let (full, full_stats) = frame(&gpu, &mut renderer, &ground, &camera, false);
    keep(&full, "shadow-full");
    let (fine, reference) = (light_taken(&full, &lit), shadow_mask(&full, &lit));
    let area = reference.iter().filter(|m| **m).count();
    eprintln!("full mesh: {area} shadowed pixels, shadow pass {:?}", full_stats.shadow);
    assert!(area > 2000, "the full mesh casts a shadow ({area} pixels)");
    renderer.settings_mut().shadows = Some(shadows);
    let (full512, _) = frame(&gpu, &mut renderer, &ground, &camera, false);
    keep(&full512, "shadow-full512");
    let same_map = shadow_mask(&full512, &lit);
    let (p, r) = mask_precision_recall(&same_map, &reference);
    eprintln!(
        "full mesh, 512 texels: the fine map P {p:.3} R {r:.3}, light taken {:.3}",
        light_taken(&full512, &lit) / fine
    );

    // The representations that stand for the leaves (not the baselines): their shadow's mask
    // against the full mesh's in a map of the same resolution, and the light they take from the
    // ground against the full mesh's in a fine map.
    let cases: [(&str, Settings); 6] = [
        ("points", settings),
        (
            "pruned",
            Settings {
                technique: Technique::PruneOpt,
                pruning: Pruning { occlusion: false, spt_below_pixels: 0.0, ..Pruning::default() },
                ..settings
            },
        ),
        ("impostors", Settings { technique: Technique::Impostors, ..settings }),
        ("lod-chain", Settings { technique: Technique::LodChain, ..settings }),
        ("crossed", Settings { technique: Technique::Crossed, ..settings }),
        ("facing", Settings { technique: Technique::Billboard, ..settings }),
    ];
    for (name, case) in cases {
        *renderer.settings_mut() = case;
        let (image, stats) = frame(&gpu, &mut renderer, &ground, &camera, false);
        keep(&image, &format!("shadow-{name}"));
        let (p, r) = mask_precision_recall(&shadow_mask(&image, &lit), &same_map);
        let (p_fine, r_fine) = mask_precision_recall(&shadow_mask(&image, &lit), &reference);
        let taken = light_taken(&image, &lit) / fine;
        eprintln!(
            "{name}: against the same map P {p:.3} R {r:.3}, the fine map P {p_fine:.3} R {r_fine:.3}, \
             light taken {taken:.3}; shadow pass {:?}",
            stats.shadow
        );
        assert_eq!(stats.shadow.cascades, 1);
        match name {
            "points" => assert!(
                stats.shadow.submitted[Primitive::Point] > 0
                    && stats.shadow.submitted[Primitive::Triangle]
                        < full_stats.shadow.submitted[Primitive::Triangle] / 10
            ),
            "pruned" => {
                assert!(stats.shadow.submitted[Primitive::Triangle] < full_stats.shadow.submitted[Primitive::Triangle])
            }
            "impostors" => assert!(stats.shadow.submitted[Primitive::Plane] > 0),
            "lod-chain" | "crossed" | "facing" => continue,
            _ => unreachable!(),
        }
        assert!(p > 0.88 && r > 0.83, "{name}: the shadow's mask, P {p:.3} R {r:.3}");
        assert!((0.8..1.1).contains(&taken), "{name}: light taken from the ground {taken:.3} of the full mesh's");
    }
}

#[test]
fn a_tree_in_the_shadow_of_another_is_darker_and_the_other_is_not() {
    let gpu = gpu();
    let container = demo_everything();
    let block = container.block();
    let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let height = max.y - min.y;
    let sun = vec3(0.0, 1.0, 0.0);
    // A tree straight above another (the sun overhead), and a third beside them, unshadowed.
    let above = Mat4::from_translation(vec3(0.0, 1.5 * height, 0.0));
    let beside = Mat4::from_translation(vec3(2.0 * (max.x - min.x), 0.0, 0.0));
    let centre = 0.5 * (min + max) + vec3(max.x - min.x, 0.75 * height, 0.0);
    let camera = Camera::look_at(centre + vec3(0.0, 0.0, 6.0 * height), centre, 0.8, 240, 240);
    let settings = Settings { sun, ambient: 0.3, ..Settings::default() };
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("uploads");
    renderer.set_instances(&[
        Instance { model: tree, transform: Mat4::IDENTITY },
        Instance { model: tree, transform: above },
        Instance { model: tree, transform: beside },
    ]);
    let ground = Ground::under_instances(&gpu.device, &renderer);
    let brightness = |renderer: &mut Renderer, name: &str| {
        let (image, _) = frame(&gpu, renderer, &ground, &camera, true);
        keep(&image, name);
        // Mean green of each tree's pixels (those off the ground's colour band), by screen region.
        let project = |p: Vec3| {
            let ndc = camera.view_proj().project_point3(p);
            ((0.5 * ndc.x + 0.5) * 240.0, (0.5 - 0.5 * ndc.y) * 240.0)
        };
        let regions = [Mat4::IDENTITY, above, beside].map(|t| {
            let (a, b) = (project(t.transform_point3(min)), project(t.transform_point3(max)));
            (a.0.min(b.0), a.1.min(b.1), a.0.max(b.0), a.1.max(b.1))
        });
        regions.map(|(x0, y0, x1, y1)| {
            let (mut sum, mut n) = (0.0, 0.0);
            for y in (y0.max(0.0) as u32)..(y1.min(239.0) as u32) {
                for x in (x0.max(0.0) as u32)..(x1.min(239.0) as u32) {
                    let p = image.pixel(x, y);
                    // Leaves: green well above red (the ground and background are greyer).
                    if f32::from(p[1]) > 1.15 * f32::from(p[0]) {
                        sum += f64::from(p[1]);
                        n += 1.0;
                    }
                }
            }
            sum / f64::max(n, 1.0)
        })
    };
    let without = brightness(&mut renderer, "receive-off");
    renderer.settings_mut().shadows =
        Some(Shadows { resolution: 1024, cascades: 2, distance: 8.0 * height, ..Shadows::default() });
    let with = brightness(&mut renderer, "receive-on");
    eprintln!("mean leaf green without shadows {without:?}, with {with:?}");
    assert!(with[0] < 0.8 * without[0], "the tree below is shadowed: {with:?} vs {without:?}");
    assert!(with[1] > 0.8 * without[1], "the tree above is lit: {with:?} vs {without:?}");
    assert!(with[2] > 0.8 * without[2], "the tree beside is lit: {with:?} vs {without:?}");
}
