//! Impostor planes in a built container (spec §6.10): the demo tree's levels in the block cell,
//! the atlas image, the exact cut `verify` checks, per-tree hierarchies in a block, determinism
//! and setting errors.

use glam::Vec3;
use treelod_build::{BuildConfig, BuildError, DemoTreeConfig, ImpostorConfig, Placed, build_block, demo_tree};
use treelod_format::{Compression, Container, image_format};

fn with_impostors() -> BuildConfig {
    BuildConfig { impostors: Some(ImpostorConfig::default()), ..BuildConfig::default() }
}

#[test]
fn the_demo_tree_gets_three_nested_levels_in_the_block_cell_and_verifies() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let out = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &with_impostors(), "t")
        .expect("builds");
    assert_eq!(out.stats.planes_per_level, [32, 16, 8]);
    // A cluster of one cluster is the same plane, kept once: at most 56 records.
    let n = out.stats.planes;
    assert!((40..=56).contains(&n), "{n} planes");
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    let container = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&container).expect("verifies: the planes' exact cut, bounds, image index");
    let cells = container.cells();
    let block = cells.last().expect("a block cell");
    assert_eq!((block.planes.first, u64::from(block.planes.count)), (0, n));
    assert!(cells[..cells.len() - 1].iter().all(|c| c.planes.count == 0), "planes live in the block cell");
    // The roots are the 8 coarsest planes, the 32 finest start at τ = 0.
    let planes = container.planes();
    assert_eq!(planes.iter().filter(|p| p.hi == f32::INFINITY).count(), 8);
    assert_eq!(planes.iter().filter(|p| p.lo == 0.0).count(), 32);
    // The atlas: the last image, RGBA8 sRGB with 5 mips, referenced by every plane.
    let atlas_index = container.images().len() - 1;
    let atlas = &container.images()[atlas_index];
    assert_eq!((atlas.format, atlas.mip_count), (image_format::RGBA8_SRGB, 5));
    assert_eq!([atlas.width, atlas.height], out.stats.atlas);
    assert!(planes.iter().all(|p| p.image as usize == atlas_index));
    let keys: Vec<&str> = container.metadata().settings.iter().map(|s| s.key.as_str()).collect();
    assert!(keys.contains(&"impostors.levels") && keys.contains(&"impostors.texels_per_metre"), "{keys:?}");
    // Without the option nothing changes: no planes, no atlas.
    let plain = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "t")
        .expect("builds");
    assert!(plain.data.planes.is_empty());
    assert_eq!(plain.data.images.len(), atlas_index);
}

#[test]
fn each_tree_of_a_block_gets_its_own_hierarchy_and_threads_do_not_change_the_bytes() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 600, ..DemoTreeConfig::default() });
    let trees: Vec<Placed<'_>> =
        (0..2).map(|i| Placed { scene: &scene, translation: Vec3::new(i as f32 * 12.0, 0.0, 0.0) }).collect();
    let bytes_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| {
            let out = build_block("pair", &trees, &with_impostors(), "t").expect("builds");
            assert_eq!(out.stats.planes_per_level, [64, 32, 16]);
            out.data.to_bytes(Compression::default()).expect("writes")
        })
    };
    let bytes = bytes_with(1);
    assert_eq!(bytes, bytes_with(2));
    let container = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&container).expect("verifies");
    // No plane spans both trees (12 m apart, each about 8 m across).
    for p in container.planes() {
        let (c, u, v) = (Vec3::from_array(p.center), Vec3::from_array(p.axis_u), Vec3::from_array(p.axis_v));
        let reach = u.abs() + v.abs();
        assert!(c.x + reach.x < 8.0 || c.x - reach.x > 4.0, "plane {p:?} spans the gap");
    }
}

#[test]
fn bad_impostor_settings_are_setting_errors() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 50, ..DemoTreeConfig::default() });
    for bad in [
        ImpostorConfig { levels: vec![8, 16], ..ImpostorConfig::default() },
        ImpostorConfig { levels: Vec::new(), ..ImpostorConfig::default() },
        ImpostorConfig { alpha_scale: f32::NAN, ..ImpostorConfig::default() },
        ImpostorConfig { texels_per_metre: 0.0, ..ImpostorConfig::default() },
    ] {
        let config = BuildConfig { impostors: Some(bad), ..BuildConfig::default() };
        let err = build_block("x", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").unwrap_err();
        assert!(matches!(err, BuildError::Setting(_)), "{err}");
    }
}
