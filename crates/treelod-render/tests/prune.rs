//! Pruned leaves on the Vulkan backend (Mesa lavapipe in CI): a prefix `λ` of each cell's priority
//! list with the survivors scaled (Neubert et al. 2011), bark drawn whole, and the occlusion
//! factor measured from the depth buffer.
//!
//! The priority lists here are made by the test from the demo tree's leaf triangles (one leaf per
//! triangle, a seeded shuffle per cell), so what is checked is the renderer's side of spec §6.11
//! whatever order a build chooses.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, gpu, one_tree, precision_recall};
use glam::{Mat4, Vec3, vec3};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, SplitMix64, build_block, demo_tree};
use treelod_format::{Compression, Container, CurveSample, PruneLeafRecord, Range, material_class};
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, render_image};
use treelod_render::{Camera, DrawSource, Instance, Pruning, Renderer, Settings, Technique};

/// The demo tree with a priority list per cell: every leaf triangle its own leaf, shuffled.
fn pruned_demo() -> Container {
    // s_opt(λ): a gentler growth than Cook's 1/λ.
    pruned_demo_scaled(vec![
        CurveSample { x: 0.1, y: 3.0 },
        CurveSample { x: 0.5, y: 1.5 },
        CurveSample { x: 1.0, y: 1.0 },
    ])
}

/// [`pruned_demo`] (the same priority lists) with `s_opt(λ)` sampled by `prune_scale`.
fn pruned_demo_scaled(prune_scale: Vec<CurveSample>) -> Container {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "test")
            .expect("the demo tree builds");
    let mut data = built.data;
    let leaf_material: Vec<bool> = data.materials.iter().map(|m| m.class == material_class::LEAF).collect();
    let mut rng = SplitMix64(7);
    for cell in &mut data.cells {
        let first = data.prune_leaves.len() as u32;
        let mut leaves: Vec<_> = data.triangles[cell.triangles.as_usize()]
            .iter()
            .filter(|t| leaf_material[t.material as usize])
            .copied()
            .collect();
        for i in (1..leaves.len()).rev() {
            leaves.swap(i, rng.below(i as u64 + 1) as usize);
        }
        for triangle in leaves {
            let corners = triangle.indices.map(|i| Vec3::from_array(data.vertices[i as usize].position));
            let leaf = data.prune_leaves.len() as u32;
            data.prune_leaves.push(PruneLeafRecord {
                center: ((corners[0] + corners[1] + corners[2]) / 3.0).to_array(),
                area: 0.5 * (corners[1] - corners[0]).cross(corners[2] - corners[0]).length(),
                first_triangle: data.prune_triangles.len() as u32,
                triangle_count: 1,
            });
            data.prune_triangles.push(treelod_format::TriangleRecord { leaf, ..triangle });
        }
        cell.prune_leaves = Range { first, count: data.prune_leaves.len() as u32 - first };
    }
    data.prune_scale = prune_scale;
    data.prune_lambda = vec![CurveSample { x: 20.0, y: 0.2 }, CurveSample { x: 400.0, y: 1.0 }];
    let container = Container::from_bytes(&data.to_bytes(Compression::None).expect("encodes")).expect("opens");
    treelod_format::verify(&container).expect("the synthetic priority lists follow the spec");
    container
}

fn camera_at(container: &Container, offset: Vec3, size: u32) -> Camera {
    let block = container.block();
    let centre = 0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max));
    Camera::look_at(centre + offset, centre, 0.8, size, size)
}

/// A fixed `λ` for the tree, no occlusion, no point tree.
fn pruning(lambda: f32) -> Pruning {
    Pruning { lambda: Some(lambda), occlusion: false, spt_below_pixels: 0.0, ..Pruning::default() }
}

#[test]
fn all_leaves_unscaled_draw_the_full_mesh_and_a_prefix_draws_fewer() {
    let gpu = gpu();
    let container = Arc::new(pruned_demo());
    let mut renderer = one_tree(&gpu, &container, Settings::default());
    let cam = camera_at(&container, vec3(0.0, 0.0, 15.0), 256);
    let total = container.triangles().len() as u64;
    let leaves = container.prune_leaves().len() as u64;
    let bark = total - leaves;

    renderer.settings_mut().technique = Technique::Full;
    let (full, _) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    renderer.settings_mut().technique = Technique::PruneOpt;
    renderer.settings_mut().pruning = pruning(1.0);
    let (all, stats) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    assert_eq!(
        (stats.submitted[Primitive::Triangle], stats.submitted[Primitive::Point]),
        (total, 0),
        "λ = 1 draws every triangle and no point"
    );
    assert_eq!(
        (stats.instances.get(Technique::PruneOpt), stats.instances_visible, stats.leaves_pruned),
        (1, 1, leaves)
    );
    let (p, r) = precision_recall(&all, &full);
    assert!(p > 0.995 && r > 0.995, "λ = 1 covers what the full mesh covers: P {p:.4}, R {r:.4}");
    let bark_draws: Vec<_> = renderer.draws().iter().filter(|d| d.source == DrawSource::Bark).collect();
    assert_eq!(bark_draws.len(), 1);
    assert_eq!(u64::from(bark_draws[0].count), bark);

    // A quarter of the leaves: each cell draws ceil(λ·count) leaves, one run of triangles each.
    // Survivors unscaled (no technique leaves them so: the same priority lists with s_opt ≡ 1,
    // drawn with `PruneOpt`), scaled by s_opt (`PruneOpt`), and by Cook's 1/λ (`PruneCook`).
    let unscaled = Arc::new(pruned_demo_scaled(vec![CurveSample { x: 0.1, y: 1.0 }, CurveSample { x: 1.0, y: 1.0 }]));
    assert!(
        unscaled.prune_leaves() == container.prune_leaves()
            && unscaled.prune_triangles() == container.prune_triangles()
            && unscaled.cells() == container.cells(),
        "the same priority lists"
    );
    let mut unscaled_renderer = one_tree(&gpu, &unscaled, Settings::default());
    let mut recalls = Vec::new();
    for (name, technique, flat) in [
        ("unscaled", Technique::PruneOpt, true),
        ("s_opt", Technique::PruneOpt, false),
        ("Cook", Technique::PruneCook, false),
    ] {
        let (renderer, container) =
            if flat { (&mut unscaled_renderer, &unscaled) } else { (&mut renderer, &container) };
        renderer.settings_mut().technique = technique;
        renderer.settings_mut().pruning = pruning(0.25);
        let (image, stats) = render_image(&gpu, renderer, &cam, BACKGROUND).expect("renders");
        let expected: u64 = container.cells().iter().map(|c| u64::from(c.prune_leaves.count.div_ceil(4))).sum();
        assert_eq!(stats.instances.get(technique), 1, "{name}: {stats:?}");
        assert_eq!(stats.leaves_pruned, expected);
        assert_eq!(stats.submitted[Primitive::Triangle], bark + expected, "{name}");
        for draw in renderer.draws().iter().filter(|d| d.source == DrawSource::PrunedLeaves) {
            assert_eq!(draw.count, container.cells()[draw.cell as usize].prune_leaves.count.div_ceil(4));
        }
        let (p, r) = precision_recall(&image, &full);
        eprintln!("λ = 0.25, {name}: P {p:.3}, R {r:.3}");
        recalls.push(r);
    }
    // Pruning loses coverage; growing the survivors wins it back, Cook's 1/λ (4× the area) most.
    assert!(recalls[0] < 0.95, "pruning three leaves in four loses coverage: R {:.3}", recalls[0]);
    assert!(recalls[1] > recalls[0] + 0.02, "s_opt restores coverage: {recalls:?}");
    assert!(recalls[2] > recalls[1], "Cook's larger scale covers more: {recalls:?}");
}

#[test]
fn lambda_follows_the_projected_height_and_far_trees_take_the_point_tree() {
    let gpu = gpu();
    let container = Arc::new(pruned_demo());
    let mut renderer = one_tree(&gpu, &container, Settings::default());
    renderer.settings_mut().technique = Technique::PruneOpt;
    renderer.settings_mut().pruning = Pruning {
        lambda: None,
        occlusion: false,
        spt_below_pixels: 30.0,
        hysteresis: treelod_render::Hysteresis { band: 0.0 },
        ..Pruning::default()
    };
    let mut lambdas = Vec::new();
    for distance in [8.0, 20.0, 40.0] {
        let cam = camera_at(&container, vec3(0.0, 0.0, distance), 256);
        let (_, stats) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
        assert_eq!(stats.instances.get(Technique::PruneOpt), 1, "pruned at {distance} m");
        let lambda = renderer.draws().iter().find(|d| d.source == DrawSource::PrunedLeaves).expect("leaves").tau_points;
        lambdas.push(lambda);
    }
    assert!(lambdas.windows(2).all(|w| w[0] > w[1]), "λ falls with distance: {lambdas:?}");
    // Below 30 pixels high the tree is drawn by its point tree.
    let cam = camera_at(&container, vec3(0.0, 0.0, 600.0), 256);
    let (_, stats) = render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    assert_eq!((stats.instances.get(Technique::PruneOpt), stats.instances_visible), (0, 1));
    assert_eq!(stats.instances.get(Technique::FALLBACK), 1, "counted under the point tree: {stats:?}");
    assert!(
        stats.submitted[Primitive::Point] > 0 && renderer.draws().iter().all(|d| d.source != DrawSource::PrunedLeaves)
    );
}

#[test]
fn a_tree_hidden_behind_another_draws_fewer_leaves_until_the_camera_jumps() {
    let gpu = gpu();
    let container = Arc::new(pruned_demo());
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    let tree = renderer.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
    // Tree 0 in front of the camera, tree 1 straight behind it, tree 2 off to the side.
    renderer.set_instances(&[
        Instance { model: tree, transform: Mat4::IDENTITY },
        Instance { model: tree, transform: Mat4::from_translation(vec3(0.0, 0.0, -25.0)) },
        Instance { model: tree, transform: Mat4::from_translation(vec3(30.0, 0.0, -25.0)) },
    ]);
    renderer.settings_mut().technique = Technique::PruneOpt;
    renderer.settings_mut().pruning =
        Pruning { lambda: Some(1.0), occlusion: true, spt_below_pixels: 0.0, ..Pruning::default() };
    let cam = camera_at(&container, vec3(0.0, 0.0, 10.0), 256);
    // Frame 1 measures; frame 2 uses the measurement.
    render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    render_image(&gpu, &mut renderer, &cam, BACKGROUND).expect("renders");
    let f = renderer.visible_fractions().to_vec();
    eprintln!("visible fractions {f:?}");
    assert!(f[0] > 0.95, "the front tree is visible, its own crown does not hide its hull: {f:?}");
    assert!(f[1] < 0.5, "the tree behind it is mostly hidden: {f:?}");
    assert_eq!(f[2], 1.0, "the third tree is off-screen and counts as visible: {f:?}");
    let lambda_of = |renderer: &Renderer, instance: u32| {
        renderer
            .draws()
            .iter()
            .find(|d| d.instance == instance && d.source == DrawSource::PrunedLeaves)
            .map(|d| d.tau_points)
    };
    let hidden = lambda_of(&renderer, 1).expect("the hidden tree still draws leaves");
    assert!((0.1..0.5).contains(&hidden), "λ of the hidden tree is its visible fraction, at least 0.1: {hidden}");
    assert_eq!(lambda_of(&renderer, 0), Some(1.0));

    // After a jump to the other side the old depth says nothing: every tree counts as visible.
    let behind = camera_at(&container, vec3(0.0, 0.0, -45.0), 256);
    render_image(&gpu, &mut renderer, &behind, BACKGROUND).expect("renders");
    assert!(renderer.visible_fractions().iter().all(|&f| f == 1.0), "{:?}", renderer.visible_fractions());
}
