//! What the rendering tests share: the Vulkan adapter they must get, the background they clear to,
//! and coverage precision and recall of one image against another.

#![allow(dead_code, reason = "each test file uses part of it")]

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use glam::{Mat4, Vec3};
use treelod_build::scene::{AlphaMode, Material, Part, Scene};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, build_block, demo_tree};
use treelod_eval::metrics::Coverage;
use treelod_format::{
    BlockRecord, CellRecord, Compression, Container, ContainerData, MaterialInfo, MaterialRecord, Metadata, NO_IMAGE,
    PointRecord, Range, Source, Tree, TriangleRecord, VertexRecord, pack,
};
use treelod_render::offscreen::{Gpu, Image, render_image};
use treelod_render::{Camera, DrawSource, FrameStats, Instance, Renderer, Settings};
use treelod_runtime::{DrawRange, Kind, ModelLod};

/// White: a pixel of another colour is covered.
pub const BACKGROUND: wgpu::Color = wgpu::Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 };

/// The adapter: the tests run on Vulkan (lavapipe in CI) and fail without one.
pub fn gpu() -> Gpu {
    let gpu = Gpu::new().expect("a GPU adapter (install mesa-vulkan-drivers for lavapipe)");
    assert_eq!(gpu.info.backend, wgpu::Backend::Vulkan, "rendering tests run on Vulkan, got {:?}", gpu.info);
    gpu
}

/// Pixels that differ from the white background (by more than a few levels).
pub fn covered(image: &Image) -> Vec<bool> {
    image.rgba.chunks_exact(4).map(|p| p[0] < 250 || p[1] < 250 || p[2] < 250).collect()
}

/// Precision and recall of `test`'s covered pixels against `reference`'s.
pub fn precision_recall(test: &Image, reference: &Image) -> (f64, f64) {
    mask_precision_recall(&covered(test), &covered(reference))
}

/// The pixels of `image` that are clearly red and clearly blue (one channel 20 levels above the
/// other two): which of two levels coloured red and blue shows.
pub fn reds_and_blues(image: &Image) -> (usize, usize) {
    let (mut reds, mut blues) = (0, 0);
    for p in image.rgba.chunks_exact(4) {
        if p[0] > p[1].saturating_add(20) && p[0] > p[2].saturating_add(20) {
            reds += 1;
        } else if p[2] > p[0].saturating_add(20) && p[2] > p[1].saturating_add(20) {
            blues += 1;
        }
    }
    (reds, blues)
}

/// A branch line from `p0` (radius `r0`) to `p1` (radius `r1`) drawn for `τ ∈ [lo, hi)`, standing
/// for the source segments `segments` (first, count).
pub fn line_record(
    p0: Vec3,
    r0: f32,
    p1: Vec3,
    r1: f32,
    color: u32,
    (lo, hi): (f32, f32),
    segments: (u32, u32),
) -> treelod_format::LineRecord {
    treelod_format::LineRecord {
        p0: p0.to_array(),
        r0,
        p1: p1.to_array(),
        r1,
        color,
        lo,
        hi,
        leaf_first: segments.0,
        leaf_count: segments.1,
        flags: 0,
    }
}

/// Renders `renderer`'s one tree, which holds a fine level in blue below `τ = e1` and a coarse
/// one in red above it (`e1` the metres per pixel at 20 m of a `fovy`, `height`² camera), from
/// 10 m, 40 m, 40 m at quality 4 and 15 m at quality 0.5, and checks each frame: the `source`
/// draw's `τ` is the metres per pixel over the quality; the fine level shows (all 3 records in
/// the prefix, blue only) where `τ < e1`, the coarse one (1 record, at least `min_reds` red
/// pixels, no blue) where not. `submitted` reads the kind's count from the frame's stats; `name`
/// names the kept images.
pub fn check_level_switch(
    gpu: &Gpu,
    renderer: &mut Renderer,
    (fovy, height): (f32, u32),
    source: DrawSource,
    submitted: impl Fn(&FrameStats) -> u64,
    min_reds: usize,
    name: &str,
) {
    let mpp = |d: f32| d * 2.0 * (0.5 * fovy).tan() / height as f32;
    let e1 = mpp(20.0);
    for (distance, quality, fine_level) in
        [(10.0, 1.0, true), (40.0, 1.0, false), (40.0, 4.0, true), (15.0, 0.5, false)]
    {
        renderer.settings_mut().ellipsoid_quality = quality;
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, distance), Vec3::ZERO, fovy, height, height);
        let (image, stats) = render_image(gpu, renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("{name}-level-{distance}-{quality}"));
        let (reds, blues) = reds_and_blues(&image);
        let draw = renderer.draws().iter().find(|d| d.source == source).copied().expect("a draw");
        eprintln!(
            "{distance} m, quality {quality}: τ {:.5} (switch {e1:.5}), {reds} red, {blues} blue",
            draw.tau_points
        );
        assert!((draw.tau_points - mpp(distance) / quality).abs() < 1e-3 * draw.tau_points);
        if fine_level {
            assert_eq!(submitted(&stats), 3, "the prefix holds both levels");
            assert!(blues > 100 && reds == 0, "the fine level: {reds} red, {blues} blue");
        } else {
            assert_eq!(submitted(&stats), 1, "the prefix is the coarse level");
            assert!(reds > min_reds && blues == 0, "the coarse level: {reds} red, {blues} blue");
        }
    }
}

/// Intersection over union of two pixel masks.
pub fn iou(a: &[bool], b: &[bool]) -> f64 {
    let both = a.iter().zip(b).filter(|(x, y)| **x && **y).count() as f64;
    let either = a.iter().zip(b).filter(|(x, y)| **x || **y).count() as f64;
    both / either.max(1.0)
}

/// The set pixels of a mask.
pub fn count(mask: &[bool]) -> usize {
    mask.iter().filter(|m| **m).count()
}

/// Precision and recall of the pixel mask `test` against `reference`, as `treelod_eval` defines
/// them.
pub fn mask_precision_recall(test: &[bool], reference: &[bool]) -> (f64, f64) {
    assert_eq!(test.len(), reference.len(), "masks of different sizes");
    Coverage::of_flags(reference, test).precision_recall()
}

/// Pixels of `shadowed` darker than 0.85 of the same pixel of `lit` (the ground without
/// shadows): the shadow mask.
pub fn shadow_mask(shadowed: &Image, lit: &Image) -> Vec<bool> {
    shadowed
        .rgba
        .chunks_exact(4)
        .zip(lit.rgba.chunks_exact(4))
        .map(|(s, l)| f32::from(s[1]) < 0.85 * f32::from(l[1]))
        .collect()
}

/// The sunlight a shadow takes from the ground: the sum over pixels of `1 − shadowed / lit`.
pub fn light_taken(shadowed: &Image, lit: &Image) -> f64 {
    shadowed
        .rgba
        .chunks_exact(4)
        .zip(lit.rgba.chunks_exact(4))
        .map(|(s, l)| 1.0 - f64::from(s[1]) / f64::from(l[1]).max(1.0))
        .sum()
}

/// A renderer with `settings` drawing one instance of `container` at the origin.
pub fn one_tree(gpu: &Gpu, container: &Arc<Container>, settings: Settings) -> Renderer {
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).expect("uploads");
    renderer.set_instances(&[Instance { model: tree, transform: Mat4::IDENTITY }]);
    renderer
}

/// A 1×1×1 block over `[-10, 10]³` named `name`, with one opaque bark material of colour
/// `[0.8, 0.1, 0.1]`, and `cells` holding its grid cell: with `triangle`, one bark triangle (and
/// its point, as the sequential point tree needs) with bounds a little larger than it (the
/// point's position is the rounded centroid), else empty. The caller adds the block cell and its
/// records, then [`open_verified`].
pub fn one_cell_block(name: &str, triangle: Option<[Vec3; 3]>) -> ContainerData {
    let mut data = ContainerData {
        metadata: Metadata {
            generator: "test".into(),
            name: name.into(),
            sources: vec![Source::default()],
            trees: vec![Tree::default()],
            materials: vec![MaterialInfo { name: "bark".into(), classified_by: "name".into() }],
            ..Metadata::default()
        },
        block: BlockRecord {
            bounds_min: [-10.0; 3],
            bounds_max: [10.0; 3],
            grid: [1, 1, 1],
            tree_count: 1,
            ..BlockRecord::default()
        },
        materials: vec![MaterialRecord {
            base_color: [0.8, 0.1, 0.1, 1.0],
            image: NO_IMAGE,
            alpha_mode: 0,
            alpha_cutoff: 0.5,
            class: treelod_format::material_class::BARK,
            flags: 1,
            _pad: 0,
        }],
        ..ContainerData::default()
    };
    let mut grid_cell = CellRecord::default();
    if let Some(corners) = triangle {
        let normal = (corners[1] - corners[0]).cross(corners[2] - corners[0]).normalize();
        data.vertices = corners
            .iter()
            .map(|c| VertexRecord {
                position: c.to_array(),
                normal: pack::oct_encode(normal.to_array()),
                uv: [0.0; 2],
                color: u32::MAX,
            })
            .collect();
        data.triangles = vec![TriangleRecord { indices: [0, 1, 2], size: 1.0, leaf: 0, material: 0 }];
        let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
        data.points = vec![PointRecord {
            position: centroid.to_array(),
            radius: 0.5,
            normal: pack::oct_encode(normal.to_array()),
            color: 0xFF19_19CC,
            size: 1.0,
            lo: 0.0,
            hi: f32::INFINITY,
            leaf_first: 0,
            leaf_count: 1,
            flags: 0,
        }];
        let (lo, hi) =
            (corners[0].min(corners[1]).min(corners[2]) - 1e-3, corners[0].max(corners[1]).max(corners[2]) + 1e-3);
        grid_cell = CellRecord {
            bounds_min: lo.to_array(),
            bounds_max: hi.to_array(),
            triangles: Range { first: 0, count: 1 },
            points: Range { first: 0, count: 1 },
            ..CellRecord::default()
        };
    }
    data.cells = vec![grid_cell];
    data
}

/// Renders frames of `renderer` until every prefix it wants is resident (at most 4).
pub fn settled(gpu: &Gpu, renderer: &mut Renderer, camera: &Camera) -> (Image, FrameStats) {
    let mut frame = render_image(gpu, renderer, camera, BACKGROUND).expect("renders");
    for _ in 0..3 {
        if frame.1.ranges_clamped == 0 {
            break;
        }
        frame = render_image(gpu, renderer, camera, BACKGROUND).expect("renders");
    }
    assert_eq!(frame.1.ranges_clamped, 0, "everything is resident");
    frame
}

/// `data` written uncompressed and opened; it must verify.
pub fn open_verified(data: &ContainerData) -> Arc<Container> {
    let container = Container::from_bytes(&data.to_bytes(Compression::None).expect("encodes")).expect("opens");
    treelod_format::verify(&container).expect("a valid container");
    Arc::new(container)
}

/// The bark (non-leaf) triangles of `container`'s full mesh.
pub fn bark_triangles(container: &Container) -> u64 {
    let leaf =
        |t: &&TriangleRecord| container.materials()[t.material as usize].class == treelod_format::material_class::LEAF;
    container.triangles().iter().filter(|t| !leaf(t)).count() as u64
}

/// The default demo tree built with `config`, opened from its uncompressed bytes.
pub fn demo_built(config: &BuildConfig) -> Arc<Container> {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], config, "test").expect("builds");
    Arc::new(Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens"))
}

/// The demo tree with impostors and its baselines (planes, a chain and billboards for the policy
/// to choose from; the impostors set the billboards' budget) and calibration.
pub fn calibrated_demo() -> Arc<Container> {
    demo_built(&BuildConfig {
        impostors: Some(treelod_build::ImpostorConfig::default()),
        baselines: Some(treelod_build::LodChainConfig::default()),
        calibration: Some(treelod_build::CalibrationConfig { views: 1, supersample: 2, more_small_views: false }),
        ..BuildConfig::default()
    })
}

/// [`calibrated_demo`] without its octahedral impostor and the impostor's calibration rows
/// (spec §6.13.1, §6.18), as a container of 1.11 reads to a runtime that skips them: the policy
/// then draws the demo tree with the point tree over a range of heights (with the impostor it
/// draws every tree below about 100 pixels with it, one quad each), which the tests of the
/// policy's mechanisms on the point tree's trees (transitions, budget, occlusion, GPU selection)
/// need.
pub fn calibrated_demo_without_octahedral() -> Arc<Container> {
    let mut data = ContainerData::from_container(&calibrated_demo());
    data.octahedral.clear();
    data.octahedral_normal_grids.clear();
    data.calibration_added.clear();
    data.calibration_elevations_added.clear();
    Arc::new(Container::from_bytes(&data.to_bytes(Compression::None).expect("encodes")).expect("opens"))
}

/// Writes `image` as a PPM under `$TREELOD_TEST_IMAGES` when that is set, for looking at failures.
pub fn keep(image: &Image, name: &str) {
    if let Some(dir) = std::env::var_os("TREELOD_TEST_IMAGES") {
        let mut ppm = format!("P6 {} {} 255\n", image.width, image.height).into_bytes();
        ppm.extend(image.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]));
        std::fs::write(std::path::Path::new(&dir).join(format!("{name}.ppm")), ppm).expect("writes");
    }
}

// GPU selection against the CPU's (gpu_select.rs, gpu_policy.rs).

/// The relative distance from a threshold within which `f32` rounding may put a key on the other
/// side.
pub const ROUNDING: f32 = 1e-5;

/// One range per (instance, cell, kind), a far-list range spread over the cells it stands for.
pub type Key = (u32, u32, Kind);
/// First, count, τ_p, τ_t, and whether it came from a far-list range.
pub type Entry = (u32, u32, f32, f32, bool);

pub fn by_cell(ranges: &[DrawRange], lod: &ModelLod) -> BTreeMap<Key, Entry> {
    let mut map = BTreeMap::new();
    for r in ranges {
        if r.kind == Kind::Roots {
            let far = lod.far_list();
            assert!((lod.roots().len()..=far.len()).contains(&(r.count as usize)), "{r:?}");
            let drawn = &far[..r.count as usize];
            for cell in lod.cells().iter().filter(|c| c.points().count > 0) {
                let points = cell.points().as_usize();
                let mut mine: Vec<u32> = drawn.iter().copied().filter(|&i| points.contains(&(i as usize))).collect();
                mine.sort_unstable();
                let n = mine.len() as u32;
                // A cell's share of the far list's prefix is a prefix of the cell's points.
                assert_eq!(mine, (cell.points().first..cell.points().first + n).collect::<Vec<_>>(), "{r:?}");
                if n > 0 {
                    let entry = (cell.points().first, n, r.tau_points, r.tau_triangles, true);
                    assert!(map.insert((r.instance, cell.index(), Kind::Points), entry).is_none(), "{r:?}");
                }
            }
        } else {
            let entry = (r.first, r.count, r.tau_points, r.tau_triangles, false);
            assert!(map.insert((r.instance, r.cell, r.kind), entry).is_none(), "two ranges for one cell: {r:?}");
        }
    }
    map
}

/// Asserts that the GPU's ranges are the CPU's: the same (instance, cell, kind, first, count),
/// except where every element between the two counts has its key (triangle size, point `hi`)
/// within [`ROUNDING`] of the threshold. Returns how many ranges differed that way.
pub fn assert_same_selection(what: &str, cpu: &[DrawRange], gpu: &[DrawRange], lod: &ModelLod) -> usize {
    let (a, b) = (by_cell(cpu, lod), by_cell(gpu, lod));
    let roots = |ranges: &[DrawRange]| -> BTreeSet<u32> {
        ranges.iter().filter(|r| r.kind == Kind::Roots).map(|r| r.instance).collect()
    };
    let cells: BTreeMap<u32, &treelod_runtime::CellLod> = lod.cells().iter().map(|c| (c.index(), c)).collect();
    let mut tolerated = 0;
    for key in a.keys().chain(b.keys()).collect::<BTreeSet<_>>() {
        let (x, y) = (a.get(key), b.get(key));
        if let (Some(x), Some(y)) = (x, y) {
            assert_eq!(x.0, y.0, "{what}: {key:?}: first differs: cpu {x:?}, gpu {y:?}");
            if !x.4 && !y.4 {
                for (s, t) in [(x.2, y.2), (x.3, y.3)] {
                    assert!((s - t).abs() <= ROUNDING * s.abs().max(t.abs()), "{what}: {key:?}: cpu {x:?}, gpu {y:?}");
                }
            }
            if x.1 == y.1 {
                continue;
            }
        }
        // Counts differ: only keys at the threshold may lie between them.
        let count = |e: Option<&Entry>| e.map_or(0, |e| e.1) as usize;
        let (lo, hi) = (count(x).min(count(y)), count(x).max(count(y)));
        let cell = cells.get(&key.1).unwrap_or_else(|| panic!("{what}: {key:?}: no such cell"));
        let keys = match key.2 {
            Kind::Triangles => lod.triangle_sizes(cell),
            _ => lod.point_hi(cell),
        };
        let taus: Vec<f32> =
            [x, y].into_iter().flatten().map(|e| if key.2 == Kind::Triangles { e.3 } else { e.2 }).collect();
        for &k in &keys[lo..hi] {
            assert!(
                taus.iter().any(|&tau| (k - tau).abs() <= ROUNDING * tau.abs()),
                "{what}: {key:?}: cpu {x:?}, gpu {y:?}: key {k} is not at a threshold {taus:?}"
            );
        }
        tolerated += 1;
    }
    if tolerated == 0 {
        assert_eq!(roots(cpu), roots(gpu), "{what}: far-list ranges");
    }
    tolerated
}

/// Pixels of `a` and `b` that differ by more than 48 in a channel, and pixels covered in either.
pub fn differing(a: &Image, b: &Image) -> (usize, usize) {
    let covered = |p: &[u8]| p[0] < 250 || p[1] < 250 || p[2] < 250;
    let mut diff = 0;
    let mut any = 0;
    for (p, q) in a.rgba.chunks_exact(4).zip(b.rgba.chunks_exact(4)) {
        any += usize::from(covered(p) || covered(q));
        diff += usize::from(p.iter().zip(q).any(|(x, y)| x.abs_diff(*y) > 48));
    }
    (diff, any)
}

/// A scene of `part` alone, its material an opaque green named after the scene.
pub fn green(name: &str, part: Part, double_sided: bool) -> Scene {
    Scene {
        name: name.into(),
        parts: vec![part],
        materials: vec![Material {
            name: name.into(),
            base_color: [0.2, 0.6, 0.1, 1.0],
            alpha_mode: AlphaMode::Opaque,
            double_sided,
            ..Material::default()
        }],
        ..Scene::default()
    }
}

/// A closed, opaque UV sphere of radius 1 about the origin, `rings` rings of `2·rings` quads.
pub fn ball(rings: u32) -> Scene {
    let mut part = Part { mesh_name: "ball".into(), material: 0, ..Part::default() };
    let segments = 2 * rings;
    for j in 0..=rings {
        let theta = std::f32::consts::PI * j as f32 / rings as f32;
        for i in 0..=segments {
            let phi = std::f32::consts::TAU * i as f32 / segments as f32;
            let n = [theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()];
            part.positions.push(n);
            part.normals.push(n);
        }
    }
    for j in 0..rings {
        for i in 0..segments {
            let a = j * (segments + 1) + i;
            let b = a + segments + 1;
            part.triangles.extend([[a, b, a + 1], [a + 1, b, b + 1]]);
        }
    }
    green("ball", part, false)
}
