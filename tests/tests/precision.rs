//! Precision trimming (`treelod_build::precision`): rounding a container's floats keeps every rule
//! of the spec, including the exact cut, and makes the demo tree's compressed container smaller.

use glam::Vec3;
use proptest::prelude::*;
use treelod_build::precision::{Precision, trim};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, build_block, demo_tree};
use treelod_format::{Compression, Container, verify};
use treelod_tests::{SyntheticOptions, synthetic};

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Hierarchies whose thresholds are close together are the hard case: rounding makes some of
    /// their intervals empty, and the cut must still hold.
    #[test]
    fn trimmed_synthetic_containers_still_verify(
        seed in any::<u64>(),
        position in 2u32..=23,
        size in 1u32..=23,
        uv in 2u32..=23,
        normal in 1u32..=16,
    ) {
        let options = SyntheticOptions {
            grid: [2, 2, 1],
            triangles_per_cell: 0..=12,
            ellipsoids_per_cell: 0..=0,
            lines_per_cell: 0..=0,
            planes_per_cell: 0..=0,
            prune_leaves_per_cell: 0..=4,
            curve_samples: 3,
            ..SyntheticOptions::minimal()
        };
        let mut data = synthetic(seed, &options);
        trim(&mut data, &Precision { position, uv, size, normal });
        let container = Container::from_bytes(&data.to_bytes(Compression::None).unwrap()).unwrap();
        if let Err(e) = verify(&container) {
            return Err(TestCaseError::fail(format!("{e} (bits: position {position}, size {size})")));
        }
    }
}

#[test]
fn the_trimmed_demo_tree_verifies_and_compresses_smaller() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig { precision: Precision::FULL, ..BuildConfig::default() };
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "test").expect("builds");
    let compression = Compression::Zstd { level: 9 };
    let full = built.data.to_bytes(compression).unwrap().len();
    let mut data = built.data.clone();
    trim(&mut data, &Precision::default());
    let bytes = data.to_bytes(compression).unwrap();
    verify(&Container::from_bytes(&bytes).unwrap()).expect("the trimmed tree verifies");
    // The build trims by default, to the same bits.
    let default =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "test")
            .expect("builds");
    assert_eq!(default.data.vertices, data.vertices);
    assert_eq!(default.data.points, data.points);
    eprintln!("demo tree: {full} bytes, trimmed {} bytes", bytes.len());
    assert!((bytes.len() as f64) < 0.9 * full as f64, "{} bytes trimmed vs {full}", bytes.len());
    // Positions move by at most their rounding.
    for (a, b) in built.data.vertices.iter().zip(&data.vertices) {
        for axis in 0..3 {
            let (x, y) = (a.position[axis], b.position[axis]);
            assert!((x - y).abs() <= x.abs() * 2f32.powi(-16), "{x} → {y}");
        }
    }
}
