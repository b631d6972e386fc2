//! Pruning end to end (spec §6.11) on the demo tree: the container verifies, each cell lists the
//! leaves whose centre it holds, every leaf triangle belongs to exactly one pruned leaf, the curves
//! and settings are written, and the bytes do not depend on the thread count.

use glam::Vec3;
use treelod_build::prune::{LAMBDAS, PruneConfig, PruneOrder};
use treelod_build::{BuildConfig, BuildError, DemoTreeConfig, Placed, build_block, demo_tree};
use treelod_format::{Compression, Container, material_class};

/// Small images and few views: the test checks the plumbing, not the numbers.
fn config(order: PruneOrder) -> BuildConfig {
    let prune = PruneConfig { order, resolution: 64, views: 3, ..PruneConfig::default() };
    BuildConfig { prune: Some(prune), ..BuildConfig::default() }
}

fn demo_bytes(config: &BuildConfig) -> Vec<u8> {
    let scene = demo_tree(&DemoTreeConfig { leaves: 400, ..DemoTreeConfig::default() });
    let out = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], config, "test")
        .expect("the demo tree builds");
    out.data.to_bytes(Compression::default()).expect("writes")
}

#[test]
fn a_pruned_demo_tree_verifies_and_lists_every_leaf_once_in_its_cell() {
    let bytes = demo_bytes(&config(PruneOrder::Combined));
    let c = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&c).expect("verifies");

    // Every leaf quad of the demo tree is one leaf of two triangles.
    assert_eq!(c.prune_leaves().len(), 400);
    assert!(c.prune_leaves().iter().all(|l| l.triangle_count == 2 && l.area > 0.0));
    // The pruned triangles are the leaf triangles of TRIANGLES, each once.
    let leaf = |m: u32| c.materials()[m as usize].class == material_class::LEAF;
    let key = |t: &treelod_format::TriangleRecord| {
        let mut i = t.indices;
        i.sort_unstable();
        (i, t.material)
    };
    let mut gilet: Vec<_> = c.triangles().iter().filter(|t| leaf(t.material)).map(key).collect();
    let mut pruned: Vec<_> = c.prune_triangles().iter().map(key).collect();
    gilet.sort_unstable();
    pruned.sort_unstable();
    assert_eq!(gilet, pruned);
    assert!(c.prune_triangles().iter().all(|t| leaf(t.material)), "bark is never pruned");

    // Each grid cell lists the leaves whose centre it holds; the block cell none.
    let block = c.block();
    let (lo, hi) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let dims = Vec3::new(block.grid[0] as f32, block.grid[1] as f32, block.grid[2] as f32);
    let cells = c.cells();
    for (index, cell) in cells.iter().enumerate() {
        for l in &c.prune_leaves()[cell.prune_leaves.as_usize()] {
            let g = ((Vec3::from_array(l.center) - lo) / ((hi - lo) / dims)).floor().clamp(Vec3::ZERO, dims - 1.0);
            let expected =
                g.x as usize + block.grid[0] as usize * (g.y as usize + block.grid[1] as usize * g.z as usize);
            assert_eq!(index, expected, "leaf at {:?}", l.center);
        }
    }
    assert_eq!(cells.last().expect("block cell").prune_leaves.count, 0);

    // s_opt(λ) at the λ samples, never below 1, 1 where nothing is pruned; λ(h) over 20 heights.
    let scale = c.prune_scale();
    assert_eq!(scale.iter().map(|s| s.x).collect::<Vec<f32>>(), LAMBDAS);
    assert!(scale.iter().all(|s| s.y >= 1.0) && scale.last().map(|s| s.y) == Some(1.0), "{scale:?}");
    assert!(scale[0].y > 1.0, "few survivors are scaled up: {scale:?}");
    let lambda = c.prune_lambda();
    assert_eq!(lambda.len(), 20);
    assert!(lambda.windows(2).all(|w| w[0].x < w[1].x && w[0].y <= w[1].y), "{lambda:?}");
    assert!(lambda.iter().all(|s| s.y > 0.0 && s.y <= 1.0), "{lambda:?}");

    // The settings say how it was built.
    let setting = |key: &str| c.metadata().settings.iter().find(|s| s.key == key).map(|s| s.value.clone());
    assert_eq!(setting("prune.order").as_deref(), Some("combined"));
    assert_eq!(setting("prune.min_quality").as_deref(), Some("0.9"));
    assert_eq!(setting("prune.views").as_deref(), Some("3"));
}

#[test]
fn pruned_builds_are_identical_whatever_the_thread_count() {
    for order in [PruneOrder::Density, PruneOrder::Combined] {
        let config = config(order);
        let with = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| demo_bytes(&config))
        };
        assert_eq!(with(1), with(3), "{order:?}");
    }
}

#[test]
fn pruning_is_opt_in_and_its_settings_are_checked() {
    let plain = demo_bytes(&BuildConfig::default());
    let c = Container::from_bytes(&plain).expect("opens");
    assert!(c.prune_leaves().is_empty() && c.prune_scale().is_empty() && c.prune_lambda().is_empty());
    assert!(c.metadata().settings.iter().all(|s| !s.key.starts_with("prune.")));

    let scene = demo_tree(&DemoTreeConfig { leaves: 10, ..DemoTreeConfig::default() });
    for bad in [
        PruneConfig { min_quality: 1.5, ..PruneConfig::default() },
        PruneConfig { resolution: 8, ..PruneConfig::default() },
        PruneConfig { views: 0, ..PruneConfig::default() },
    ] {
        let config = BuildConfig { prune: Some(bad), ..BuildConfig::default() };
        let err = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").unwrap_err();
        assert!(matches!(err, BuildError::Setting(_)), "{err}");
    }
}

#[test]
fn the_report_compares_every_order_against_cook() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 300, ..DemoTreeConfig::default() });
    let report = treelod_build::prune_report(
        "demo",
        &[Placed { scene: &scene, translation: Vec3::ZERO }],
        &config(PruneOrder::Density),
    )
    .expect("reports");
    assert_eq!(report.leaves, 300);
    assert_eq!(report.orders.iter().map(|o| o.order).collect::<Vec<_>>(), PruneOrder::ALL);
    assert_eq!(report.cook_quality.len(), LAMBDAS.len());
    for o in &report.orders {
        assert_eq!((o.scale.len(), o.quality.len(), o.lambda_curve.len()), (LAMBDAS.len(), LAMBDAS.len(), 20));
        // s_opt is at least as good as no scaling, and at λ = 1 perfect.
        assert_eq!(o.quality.last(), Some(&1.0));
        assert!(o.lambda > 0.0 && o.lambda <= 1.0);
    }
    // With the same stochastic order, s_opt never scores below Cook's 1/λ at a sampled λ.
    let stochastic = &report.orders[0];
    for (q_opt, q_cook) in stochastic.quality.iter().zip(&report.cook_quality) {
        assert!(q_opt + 0.02 >= *q_cook, "s_opt {q_opt} against Cook {q_cook}");
    }
}
