//! The shared tree models (`../shared/assets/trees`, see its SOURCES.md) import with the expected
//! triangle counts and leaf/bark split, build, and verify. The 669k and 154k Sapling models take
//! too long for CI in a debug build and are run with `--ignored`.

use std::path::PathBuf;

use glam::Vec3;
use treelod_build::{BuildConfig, Placed, build_block, import_gltf};
use treelod_format::{Compression, Container, verify};

fn model(name: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees").join(name);
    assert!(path.exists(), "{} is missing: the repository is checked out with ../shared beside it", path.display());
    path
}

/// Imports, builds and verifies one model; returns (triangles in, leaf triangles, bark triangles).
fn build(name: &str) -> (u64, u64, u64) {
    let scene = import_gltf(&model(name)).expect("imports");
    let out =
        build_block(&scene.name, &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "test")
            .expect("builds");
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    verify(&Container::from_bytes(&bytes).expect("opens")).expect("verifies");
    let s = out.stats;
    (s.triangles_in, s.leaf_triangles, s.bark_triangles)
}

#[test]
fn quaternius_low_poly_tree_splits_green_canopy_from_wood() {
    assert_eq!(build("quaternius-common-tree-1-3k.glb"), (2888, 528, 2360));
}

#[test]
fn ez_tree_oak_splits_by_material_name() {
    assert_eq!(build("ez-tree-oak-large-23k.glb"), (22566, 10560, 12006));
}

#[test]
fn ez_tree_pine_drops_only_degenerate_bark_triangles() {
    // 8 of the 12,192 bark triangles have zero area.
    assert_eq!(build("ez-tree-pine-large-19k.glb"), (19392, 7200, 12184));
}

#[test]
fn orchid_foliage_atlas_is_leaves_and_trunk_branches_twig_are_bark() {
    assert_eq!(build("plantcatalog-hk-orchid-tree-31k.glb"), (31004, 26268, 4736));
}

#[test]
fn jacaranda_opaque_leaf_polygons_are_leaves_by_name() {
    // 204 of the 26,124 branch and trunk triangles are degenerate and dropped.
    assert_eq!(build("polyhaven-jacaranda-tree-55k.glb"), (54953, 28829, 25920));
}

#[test]
#[ignore = "154k triangles: about 1 s in release, slow in debug"]
fn sapling_willow() {
    assert_eq!(build("sapling-weeping-willow-154k.glb"), (154200, 62340, 91860));
}

#[test]
#[ignore = "669k triangles: about 5 s in release, slow in debug"]
fn sapling_maple() {
    assert_eq!(build("sapling-japanese-maple-669k.glb"), (669344, 170880, 498464));
}
