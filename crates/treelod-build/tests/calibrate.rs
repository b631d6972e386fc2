//! Calibration (spec §6.15) through the whole build: every representation the demo tree is built
//! with gets a row at each height, the table verifies, is the same whatever the thread count, and
//! says what is known of the representations (the full mesh's cost is its triangle count, the point
//! tree converges to the full mesh up close and costs far less far away, a billboard is worse up
//! close than far away).

use glam::Vec3;
use treelod_build::calibrate::{CalibrationConfig, HEIGHTS, calibrate};
use treelod_build::{
    BuildConfig, DemoTreeConfig, EllipsoidConfig, ImpostorConfig, LodChainConfig, Placed, build_block, demo_tree,
};
use treelod_format::{CalibrationRecord, Compression, Container, calibration_technique as t, verify};

fn config() -> BuildConfig {
    BuildConfig {
        impostors: Some(ImpostorConfig::default()),
        ellipsoids: Some(EllipsoidConfig::default()),
        baselines: Some(LodChainConfig::default()),
        calibration: Some(CalibrationConfig { views: 2, ..CalibrationConfig::default() }),
        ..BuildConfig::default()
    }
}

fn row(records: &[CalibrationRecord], technique: u32) -> Vec<CalibrationRecord> {
    records.iter().filter(|r| r.technique == technique).copied().collect()
}

#[test]
fn the_demo_tree_is_calibrated_for_every_representation_it_holds() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let out = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let records = &out.data.calibration;
    for technique in [t::FULL, t::SPT, t::IMPOSTORS, t::ELLIPSOIDS, t::LOD_CHAIN, t::BILLBOARD, t::CROSSED] {
        let heights: Vec<f32> = row(records, technique).iter().map(|r| r.height).collect();
        assert_eq!(heights, HEIGHTS, "{:?}", t::name(technique));
    }
    assert!(row(records, t::PRUNE_OPT).is_empty(), "built without pruning: no pruning rows");

    // Written, it opens and verifies, and dump's reader returns the same records.
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    let container = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(container.calibration(), records.as_slice());
    // CALIBRATION is a kind of 1.5, the impostors' BC7 atlas (the default) one of 1.6, and the chain's
    // per-level tables a kind of 1.7, which makes the file 1.7.
    assert_eq!(container.header().minor, 7, "the chain's per-level tables are a kind of 1.7");
    assert_eq!(container.chain_calibration(), out.data.chain_calibration.as_slice());
    verify(&container).expect("verifies");

    // The full mesh draws every triangle at every height.
    let triangles = out.data.triangles.len() as f32;
    assert!(row(records, t::FULL).iter().all(|r| r.primitives == triangles));
    // The point tree draws fewer primitives the smaller the tree, far fewer than the mesh at 8
    // pixels, and at the largest height it is the full mesh's image.
    let spt = row(records, t::SPT);
    assert!(spt.windows(2).all(|w| w[0].primitives <= w[1].primitives), "{spt:?}");
    assert!(spt[0].primitives < 0.2 * triangles, "{spt:?}");
    let full_near = row(records, t::FULL)[HEIGHTS.len() - 1].error;
    assert!(spt[HEIGHTS.len() - 1].error <= full_near * 1.2 + 1e-3, "{spt:?} vs {full_near}");
    // One quad is the whole tree: a poorer image up close than at 8 pixels, and poorer than the
    // point tree up close.
    let billboard = row(records, t::BILLBOARD);
    assert!(billboard.iter().all(|r| r.primitives == 1.0));
    assert!(billboard[HEIGHTS.len() - 1].error > billboard[0].error, "{billboard:?}");
    assert!(billboard[HEIGHTS.len() - 1].error > 2.0 * spt[HEIGHTS.len() - 1].error, "{billboard:?} {spt:?}");
}

#[test]
fn calibration_is_the_same_whatever_the_thread_count() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool");
        pool.install(|| calibrate(&built.data, &CalibrationConfig { views: 2, ..CalibrationConfig::default() }))
    };
    let one = with(1);
    assert!(!one.records.is_empty() && !one.chain_levels.is_empty());
    assert_eq!(one, with(3));
    assert_eq!(one.records, built.data.calibration, "the build's table is the calibration of what it wrote");
    assert_eq!(one.chain_levels, built.data.chain_calibration, "and so are the chain's levels");
}

#[test]
fn a_build_without_calibration_writes_none() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig::default();
    let out = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").expect("builds");
    assert!(out.data.calibration.is_empty());
    assert!(out.data.chain_calibration.is_empty());
    assert!(!out.data.metadata.settings.iter().any(|s| s.key.starts_with("calibration.")));
}
