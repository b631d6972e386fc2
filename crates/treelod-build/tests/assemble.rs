//! The Gilet build end to end on small scenes made in code: counts, the exact cut at every
//! threshold, determinism across thread counts, the ambient occlusion of the written vertices, and
//! typed errors for scenes with nothing to draw.

use glam::Vec3;
use treelod_build::scene::{AlphaMode, Material, Part, Scene};
use treelod_build::{BuildConfig, BuildError, Placed, build_block};
use treelod_format::{Compression, Container, material_class};

/// A "tree": a trunk quad strip (bark) and `leaves` small quads scattered above it (leaves).
fn tiny_tree(leaves: u32) -> Scene {
    let mut bark = Part { mesh_name: "trunk".into(), material: 1, ..Part::default() };
    for i in 0..8u32 {
        let y = i as f32 * 0.5;
        bark.positions.extend([[-0.1, y, 0.0], [0.1, y, 0.0]]);
        bark.normals.extend([[0.0, 0.0, 1.0]; 2]);
        if i > 0 {
            let b = 2 * i;
            bark.triangles.extend([[b - 2, b - 1, b + 1], [b - 2, b + 1, b]]);
        }
    }
    let mut leaf = Part { mesh_name: "leaves".into(), material: 0, ..Part::default() };
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut rnd = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    for _ in 0..leaves {
        let c = Vec3::new(rnd() * 3.0 - 1.5, 2.5 + rnd() * 2.0, rnd() * 3.0 - 1.5);
        let s = 0.05 + 0.1 * rnd();
        let base = leaf.positions.len() as u32;
        for (dx, dy) in [(0.0, 0.0), (s, 0.0), (s, s), (0.0, s)] {
            leaf.positions.push((c + Vec3::new(dx, dy, 0.0)).to_array());
            leaf.normals.push([0.0, 0.0, 1.0]);
        }
        leaf.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
    }
    Scene {
        name: "tiny".into(),
        parts: vec![leaf, bark],
        materials: vec![
            Material {
                name: "leaves".into(),
                base_color: [0.2, 0.5, 0.1, 1.0],
                alpha_mode: AlphaMode::Opaque,
                double_sided: true,
                ..Material::default()
            },
            Material { name: "bark".into(), base_color: [0.4, 0.3, 0.2, 1.0], ..Material::default() },
        ],
        ..Scene::default()
    }
}

fn build(scene: &Scene, config: &BuildConfig) -> treelod_build::BuildOutput {
    build_block("tiny", &[Placed { scene, translation: Vec3::ZERO }], config, "treelod test").expect("builds")
}

#[test]
fn a_small_tree_builds_a_valid_container_with_every_triangle() {
    let scene = tiny_tree(300);
    let out = build(&scene, &BuildConfig::default());
    assert_eq!(out.stats.triangles_in, 600 + 14);
    assert_eq!(out.stats.triangles, 614);
    assert_eq!((out.stats.leaf_triangles, out.stats.bark_triangles), (600, 14));
    // 3.15 m wide, 4.65 m tall, 3 m deep: 4 cells across the shortest axis, cells kept near cubic.
    assert_eq!(out.stats.grid, [4, 6, 4]);
    assert_eq!(treelod_build::auto_grid(Vec3::splat(7.0)), [4, 4, 4], "Gilet's grid for one compact tree");
    assert_eq!(treelod_build::auto_grid(Vec3::new(80.0, 10.0, 80.0)), [16, 4, 16], "Gilet's 4x16x16 for a group");
    let classes: Vec<u32> = out.data.materials.iter().map(|m| m.class).collect();
    assert_eq!(classes, [material_class::LEAF, material_class::BARK]);
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    let container = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&container).expect("verifies: exact cut, ordering, bounds");
    // Every source triangle appears exactly once among the triangles.
    assert_eq!(container.triangles().len(), 614);
}

#[test]
fn output_is_identical_whatever_the_thread_count() {
    let scene = tiny_tree(500);
    let bytes_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| build(&scene, &BuildConfig::default()).data.to_bytes(Compression::default()).expect("writes"))
    };
    assert_eq!(bytes_with(1), bytes_with(3));
}

#[test]
fn degenerate_and_non_finite_triangles_are_dropped_with_a_warning() {
    let mut scene = tiny_tree(10);
    let part = &mut scene.parts[0];
    let n = part.positions.len() as u32;
    part.positions.push([f32::NAN, 0.0, 0.0]);
    part.triangles.push([0, 1, n]); // non-finite corner
    part.triangles.push([0, 0, 1]); // zero area
    let out = build(&scene, &BuildConfig::default());
    assert_eq!(out.stats.triangles_dropped, 2);
    assert!(
        out.warnings.iter().any(|w| w.contains("dropped 2 degenerate or non-finite triangles") && w.contains("leaves"))
    );
}

#[test]
fn nothing_drawable_is_a_typed_error() {
    let scene = Scene { name: "empty".into(), ..Scene::default() };
    let err = build_block("empty", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "t")
        .unwrap_err();
    assert!(matches!(err, BuildError::NoGeometry { .. }), "{err}");
    let bad_grid = BuildConfig { grid: Some([0, 4, 4]), ..BuildConfig::default() };
    let scene = tiny_tree(5);
    let err = build_block("g", &[Placed { scene: &scene, translation: Vec3::ZERO }], &bad_grid, "t").unwrap_err();
    assert!(matches!(err, BuildError::Setting(_)), "{err}");
    // Baselines whose octahedral impostor asks for one view are refused, naming the setting.
    let bad_baselines = BuildConfig {
        baselines: Some(treelod_build::LodChainConfig {
            octahedral: treelod_build::OctahedralConfig { views: 1, ..Default::default() },
            ..Default::default()
        }),
        ..BuildConfig::default()
    };
    let err = build_block("b", &[Placed { scene: &scene, translation: Vec3::ZERO }], &bad_baselines, "t").unwrap_err();
    assert!(matches!(&err, BuildError::Setting(m) if m.contains("octahedral views 1")), "{err}");
}

#[test]
fn a_block_of_trees_spans_one_grid() {
    let a = tiny_tree(50);
    let trees: Vec<Placed> =
        (0..4).map(|i| Placed { scene: &a, translation: Vec3::new(i as f32 * 4.0, 0.0, 0.0) }).collect();
    let out = build_block("row", &trees, &BuildConfig::default(), "t").expect("builds");
    assert_eq!(out.data.block.tree_count, 4);
    assert_eq!(out.data.metadata.trees.len(), 4);
    assert!(
        out.stats.grid[0] > out.stats.grid[2],
        "a row of trees gets more cells along its length: {:?}",
        out.stats.grid
    );
}

/// The ambient occlusion is traced on the vertices in their gathered order, before the per-cell
/// stage renumbers them: what the container holds is the occlusion of its written vertices as
/// the stage gives it from the written vertices and triangles, each triangle stopping rays by
/// its leaf point's alpha (as `benches/ao` reads a container back).
#[test]
fn the_written_occlusion_is_that_of_the_written_vertices() {
    use treelod_build::ambient::{AoTriangle, vertex_occlusion};
    use treelod_build::precision::Precision;
    use treelod_build::{AoConfig, DemoTreeConfig, demo_tree};
    use treelod_format::{MATERIAL_DOUBLE_SIDED, encode_ao};

    let scene = demo_tree(&DemoTreeConfig { leaves: 300, ..DemoTreeConfig::default() });
    // Full precision: rounded positions and normals would move the rays.
    let config = BuildConfig { ao: Some(AoConfig::default()), precision: Precision::FULL, ..BuildConfig::default() };
    let bytes = build(&scene, &config).data.to_bytes(Compression::default()).expect("writes");
    let c = Container::from_bytes(&bytes).expect("opens");
    let mut triangles = Vec::new();
    for cell in c.cells() {
        let cell_triangles = &c.triangles()[cell.triangles.as_usize()];
        let mut alpha_of_leaf = vec![1.0f32; cell_triangles.len()];
        for p in c.points()[cell.points.as_usize()].iter().filter(|p| p.lo == 0.0 && p.leaf_count == 1) {
            alpha_of_leaf[p.leaf_first as usize] = f32::from((p.color >> 24) as u8) / 255.0;
        }
        triangles.extend(cell_triangles.iter().map(|t| AoTriangle {
            v: t.indices,
            opacity: alpha_of_leaf[t.leaf as usize],
            two_sided: c.materials()[t.material as usize].flags & MATERIAL_DOUBLE_SIDED != 0,
        }));
    }
    assert!(triangles.iter().any(|t| t.opacity > 0.0 && t.opacity < 1.0), "leaves let some light through");
    let ao = config.ao.as_ref().expect("ambient occlusion by default");
    let written: Vec<u8> =
        vertex_occlusion(c.vertices(), &triangles, ao, &|_, _| {}).into_iter().map(encode_ao).collect();
    assert_eq!(written.len(), c.vertex_ao().len());
    let spread = written.iter().filter(|&&a| a > 20 && a < 235).count();
    assert!(spread > written.len() / 10, "partly occluded vertices: {spread} of {}", written.len());
    let differ: Vec<(usize, u8, u8)> = written
        .iter()
        .zip(c.vertex_ao())
        .enumerate()
        .filter(|(_, (a, b))| a != b)
        .map(|(i, (a, b))| (i, *a, *b))
        .collect();
    assert!(differ.is_empty(), "{} differ: {:?}", differ.len(), &differ[..differ.len().min(20)]);
}
