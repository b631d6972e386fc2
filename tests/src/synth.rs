//! The synthetic container generator.

use core::ops::RangeInclusive;

use treelod_build::{SptNode, flatten};
use treelod_format::pack::{oct_encode, rgba8, unorm16x2};
use treelod_format::{
    BillboardRecord, BlockRecord, CalibrationRecord, CellRecord, ChainCalibrationRecord, ChainFlipCalibrationRecord,
    ContainerData, CurveSample, ElevationCalibrationRecord, EllipsoidRecord, FlipCalibrationRecord, ImageRecord,
    LineRecord, LodLevelRecord, MaterialInfo, MaterialRecord, NO_IMAGE, OctahedralDepthRecord,
    OctahedralNormalGridRecord, OctahedralNormalRecord, OctahedralRecord, PlaneDiffuseRecord, PlaneLeafRecord,
    PlaneRecord, PointRecord, PruneLeafRecord, Range, SectionKind, Setting, Source, Tree, TriangleRecord, VertexRecord,
    billboard_kind, calibration_technique, image_format,
};

use crate::rng::SplitMix64;

/// What [`synthetic`] puts into a container.
///
/// Counts given as ranges are drawn per cell from the range (inclusive). A range `0..=0` leaves the
/// kind out. Every combination gives a valid container as long as the grid is valid (each axis
/// `1 ..= 256`, at most 65 536 cells; axes outside `1 ..= 256` are clamped, a larger product makes
/// a container the writer refuses).
#[derive(Clone, Debug, PartialEq)]
pub struct SyntheticOptions {
    /// Cells along x, y, z.
    pub grid: [u32; 3],
    /// Triangles of each grid cell, each with a leaf point, under a binary point hierarchy.
    pub triangles_per_cell: RangeInclusive<u32>,
    /// Leaves of each grid cell's ellipsoid hierarchy.
    pub ellipsoids_per_cell: RangeInclusive<u32>,
    /// Leaves of each grid cell's line hierarchy.
    pub lines_per_cell: RangeInclusive<u32>,
    /// Leaves of each grid cell's plane hierarchy. Planes use an impostor atlas image, which is
    /// added when this range is not `0..=0`.
    pub planes_per_cell: RangeInclusive<u32>,
    /// Pruned leaves of each grid cell, each with one or two triangles in `PRUNE_TRIANGLES`.
    pub prune_leaves_per_cell: RangeInclusive<u32>,
    /// Leaves of the block cell's ellipsoid hierarchy (0: none).
    pub block_ellipsoids: u32,
    /// Samples of each pruning curve, `PRUNE_SCALE` and `PRUNE_LAMBDA` (0: none).
    pub curve_samples: u32,
    /// Levels of each tree's baseline LoD chain (spec §6.12), each of one to three triangles over
    /// the written vertices (0: none; needs triangles).
    pub lod_levels: u32,
    /// A facing and a crossed baseline billboard quad per tree (spec §6.13), sampling the
    /// impostor atlas (needs planes).
    pub billboards: bool,
    /// Materials. At least one is made when triangles are.
    pub materials: u32,
    /// Raw RGBA8 textures with random mip chains that materials may use.
    pub textures: u32,
    /// Add one image stored as a (valid, tiny) PNG file.
    pub png_image: bool,
    /// Source trees of the block (`BlockRecord::tree_count`, metadata trees and sources); at least 1.
    pub tree_count: u32,
    /// Kinds of extension sections with random bytes. Known kinds are ignored; the list is sorted
    /// and deduplicated.
    pub extension_kinds: Vec<u32>,
    /// Ambient occlusion (spec §6.14, 1.2): a random byte per vertex, point and plane.
    pub ao: bool,
    /// Indirect texturing of the impostor planes (spec §6.10.1, 1.3): every plane samples a
    /// region of 2..=6 × 2..=6 texels (inside an 8 × 8 cell, so an empty border surrounds it) of
    /// one `LEAF_SLOTS` image appended to `IMAGES`, whose slots name its leaves, and has
    /// `leaf_count` random `PLANE_LEAVES` records. The RGBA atlas stays for the billboards. Needs
    /// planes and a material; drawn after everything else, so the rest of the container is the
    /// same as without it.
    pub indirect_planes: bool,
    /// Ambient occlusion of the ellipsoids (spec §6.14, 1.3): a random byte per ellipsoid, in
    /// `ELLIPSOID_AO`. Drawn last, so the rest of the container is the same as without it.
    pub ellipsoid_ao: bool,
    /// Ambient occlusion of the lines (spec §6.14, 1.4): a random byte per line, in `LINE_AO`.
    /// Drawn last, so the rest of the container is the same as without it.
    pub line_ao: bool,
    /// Calibration tables (spec §6.15, 1.5): a random subset of the techniques (always `FULL`),
    /// each with three or four samples of growing projected height, falling error in `[0, 1]`
    /// and a whole number of primitives, in `CALIBRATION`. Drawn last, so the rest of the
    /// container is the same as without it.
    pub calibration: bool,
    /// Calibration tables per elevation (spec §6.16, 1.7): `CALIBRATION`'s pairs of technique and
    /// height at the elevations 0, 30, 60 and 90 degrees, each error the mean's scaled by a
    /// random factor of `[0.5, 1.5]` (clamped to `[0, 1]`), the primitives the mean's, in
    /// `CALIBRATION_ELEVATIONS`. Needs `calibration`; drawn last, so the rest of the container is
    /// the same as without it.
    pub calibration_elevations: bool,
    /// Calibration tables of the techniques added after 1.11 (spec §6.18, 1.12): a random
    /// non-empty subset of the codes `FIRST_ADDED .. COUNT` (today `OCTAHEDRAL` alone), each with
    /// three or four samples of growing projected height, falling error in `[0, 1]` and a whole
    /// number of primitives, in `CALIBRATION_ADDED`; with `calibration_elevations`, their pairs
    /// of technique and height at each elevation of `CALIBRATION_ELEVATIONS`, errors scaled as
    /// there, in `CALIBRATION_ELEVATIONS_ADDED`. Needs `calibration`; drawn last, so the rest of
    /// the container is the same as without it.
    pub calibration_added: bool,
    /// The block's far lines (spec §6.9.1, 1.9): a random binary hierarchy over copies of the
    /// cells' coarsest lines (the `LINES` records with `hi = +∞`), inner lines from the start of
    /// their run's first leaf to the end of its last, in `FAR_LINES`, `τ_far` √2 times the coarsest
    /// lines' largest `lo` (or the smallest cell edge when that is 0); with `line_ao`, a random byte
    /// per far line in `FAR_LINE_AO`. Drawn last, so the rest of the container is the same as
    /// without it.
    pub far_lines: bool,
    /// The planes' diffuse response (spec §6.10.2, 1.10): a `PlaneDiffuseRecord` per plane in
    /// `PLANE_DIFFUSE`, `flat` a random `unorm16` and `scattered` a random one of at most
    /// `65535 − flat` (shares summing to at most 1). Drawn last, so the rest of the container is
    /// the same as without it.
    pub plane_diffuse: bool,
    /// An octahedral impostor per tree (spec §6.13.1, 1.11) in `OCTAHEDRAL`, on the impostor
    /// atlas that the billboards sample (needs planes): its centre inside the block, a random
    /// radius, views per side drawn from `octahedral_frames`, a random rectangle of the atlas and,
    /// with `ao`, a random occlusion (0 without). Drawn last, so the rest of the container is the
    /// same as without it.
    pub octahedral: bool,
    /// The range each octahedral impostor's views per side (`frames`) are drawn from, inclusive,
    /// within `2 ..= 64`: `2 ..= 16` in the presets, `2 ..= 2` in [`SyntheticOptions::small`].
    pub octahedral_frames: RangeInclusive<u32>,
    /// The octahedral views' depth planes (spec §6.13.2, 1.13): for each `OCTAHEDRAL` record, in
    /// order, its `frames²` views' planes in `OCTAHEDRAL_DEPTH` (view `(i, j)` at `j·frames + i`),
    /// one in eight all zero (a view that shows nothing), the others with an offset in
    /// `[−0.5, 0.5)` and slopes in `[−0.8, 0.8)`. Needs `octahedral`; drawn last, so the rest of the
    /// container is the same as without it.
    pub octahedral_depth: bool,
    /// The points' facing (spec §6.5.1, 1.14): a random byte per point in `POINT_FACING`. Drawn
    /// last, so the rest of the container is the same as without it.
    pub point_facing: bool,
    /// The octahedral views' normals (spec §6.13.3): for each `OCTAHEDRAL` record, in order, a
    /// grid of normal cells whose corner lies right of the colour grid where the image has room
    /// for a grid of the colour grid's size, else left of it, else against the image's right edge
    /// (over part of the colour grid): always inside the image. As 1.15's `OCTAHEDRAL_NORMALS`
    /// (that grid, [`NormalGrids::ColourSize`]) or 1.16's `OCTAHEDRAL_NORMAL_GRIDS` (half of it
    /// from the same corner, [`NormalGrids::HalfSize`]), or none. Draws no random numbers, so the
    /// rest of the container is the same as without it. Needs `octahedral`.
    pub octahedral_normals: NormalGrids,
    /// The calibration's FLIP error (spec §6.19, 1.17): rows over every view
    /// ([`FlipCalibrationRecord::EVERY_VIEW`]) and at the elevations 30 and 90 degrees, each of the
    /// techniques `FULL` and `OCTAHEDRAL` (a base code and an added one: the section holds any
    /// code) at three heights growing strictly from a few pixels (the same for every row), a
    /// falling FLIP error in `[0, 1]`, in `CALIBRATION_FLIP`. The rows are self-describing and
    /// need no other section. Drawn last, so the rest of the container is the same as without
    /// it.
    pub calibration_flip: bool,
    /// The LoD chain levels' FLIP error (spec §6.20, 1.18): for each `CHAIN_CALIBRATION` record
    /// (so it needs `chain_calibration`, and gives no rows without it), a row at its level and
    /// height, as the build measures them on the same drawings, a falling FLIP error in `[0, 1]`
    /// within each level, in `CHAIN_CALIBRATION_FLIP`. Drawn last, so the rest of the container
    /// is the same as without it.
    pub chain_calibration_flip: bool,
    /// The LoD chain's per-level calibration (spec §6.17, 1.8): for each level of the chain
    /// (`lod_levels`), three samples of growing projected height, falling error in `[0, 1]` and
    /// the level's triangle count, in `CHAIN_CALIBRATION`. Drawn last, so the rest of the
    /// container is the same as without it.
    pub chain_calibration: bool,
    /// The impostor atlas stored as BC7 (spec §6.7 format 7, 1.6): its RGBA8 levels encoded by
    /// the build's encoder into blocks appended to `IMAGE_DATA`, the record pointing at them (the
    /// RGBA8 bytes stay, unreferenced). Done last, so the rest of the container is the same as
    /// without it.
    pub bc7_atlas: bool,
    /// Block name in the metadata; `None` gives `synthetic-<seed in hex>`.
    pub name: Option<String>,
}

impl SyntheticOptions {
    /// One cell, one triangle, its leaf point and one material, nothing else: the smallest
    /// container with geometry.
    #[must_use]
    pub fn minimal() -> Self {
        Self {
            grid: [1, 1, 1],
            triangles_per_cell: 1..=1,
            ellipsoids_per_cell: 0..=0,
            lines_per_cell: 0..=0,
            planes_per_cell: 0..=0,
            prune_leaves_per_cell: 0..=0,
            block_ellipsoids: 0,
            curve_samples: 0,
            lod_levels: 0,
            billboards: false,
            materials: 1,
            textures: 0,
            png_image: false,
            tree_count: 1,
            extension_kinds: Vec::new(),
            ao: false,
            indirect_planes: false,
            ellipsoid_ao: false,
            line_ao: false,
            calibration: false,
            calibration_elevations: false,
            calibration_added: false,
            chain_calibration: false,
            far_lines: false,
            plane_diffuse: false,
            octahedral: false,
            octahedral_frames: 2..=16,
            octahedral_depth: false,
            point_facing: false,
            octahedral_normals: NormalGrids::None,
            calibration_flip: false,
            chain_calibration_flip: false,
            bc7_atlas: false,
            name: Some("minimal".into()),
        }
    }

    /// A Gilet container: `grid` cells of up to six triangles (some cells empty) with their point
    /// hierarchies, two materials and one texture.
    #[must_use]
    pub fn gilet(grid: [u32; 3]) -> Self {
        Self {
            grid,
            triangles_per_cell: 0..=6,
            materials: 2,
            textures: 1,
            name: Some("gilet".into()),
            ..Self::minimal()
        }
    }

    /// Every section kind of version 1.18 but 1.15's `OCTAHEDRAL_NORMALS` (a file holds it or
    /// 1.16's `OCTAHEDRAL_NORMAL_GRIDS`): a 2×1×2 grid with triangles, points, ellipsoids, lines,
    /// planes and pruning lists in every cell, a block-cell ellipsoid hierarchy, both curves, three
    /// materials, two textures, an atlas and a PNG image, two trees, each with a three-level
    /// baseline LoD chain and facing and crossed billboards, ambient occlusion (of the ellipsoids
    /// and lines too), indirectly textured planes (a `LEAF_SLOTS` image and `PLANE_LEAVES`),
    /// calibration tables (`CALIBRATION`, per elevation, `CALIBRATION_ELEVATIONS`, and the chain's
    /// per level, `CHAIN_CALIBRATION`), the block's far lines with their ambient occlusion
    /// (`FAR_LINES`, `FAR_LINE_AO`), the planes' diffuse response (`PLANE_DIFFUSE`), an
    /// octahedral impostor per tree (`OCTAHEDRAL`) with its views' depth planes
    /// (`OCTAHEDRAL_DEPTH`) and normals at half the colour's size (`OCTAHEDRAL_NORMAL_GRIDS`), the
    /// calibration of the techniques added after 1.11
    /// (`CALIBRATION_ADDED`, `CALIBRATION_ELEVATIONS_ADDED`), the points' facing
    /// (`POINT_FACING`), the calibration's FLIP error (`CALIBRATION_FLIP`) and the chain levels'
    /// (`CHAIN_CALIBRATION_FLIP`).
    #[must_use]
    pub fn everything() -> Self {
        Self {
            grid: [2, 1, 2],
            triangles_per_cell: 1..=5,
            ellipsoids_per_cell: 1..=4,
            lines_per_cell: 1..=3,
            planes_per_cell: 1..=3,
            prune_leaves_per_cell: 1..=3,
            block_ellipsoids: 5,
            curve_samples: 4,
            lod_levels: 3,
            billboards: true,
            materials: 3,
            textures: 2,
            png_image: true,
            tree_count: 2,
            extension_kinds: Vec::new(),
            ao: true,
            indirect_planes: true,
            ellipsoid_ao: true,
            line_ao: true,
            calibration: true,
            calibration_elevations: true,
            calibration_added: true,
            chain_calibration: true,
            far_lines: true,
            plane_diffuse: true,
            octahedral: true,
            octahedral_frames: 2..=16,
            octahedral_depth: true,
            point_facing: true,
            octahedral_normals: NormalGrids::HalfSize,
            calibration_flip: true,
            chain_calibration_flip: true,
            bc7_atlas: false,
            name: Some("everything".into()),
        }
    }

    /// A small valid file (a few KiB) with every kind of section, for tests that take a file
    /// apart (hostile input, mutation fuzzing): two cells, one tree, one material and texture,
    /// no PNG image, an octahedral impostor of 2 × 2 views (4 depth planes), and one unknown
    /// section kind (`0x0001_0000`).
    #[must_use]
    pub fn small() -> Self {
        Self {
            grid: [2, 1, 1],
            triangles_per_cell: 1..=3,
            ellipsoids_per_cell: 1..=2,
            lines_per_cell: 1..=1,
            planes_per_cell: 1..=1,
            prune_leaves_per_cell: 1..=1,
            block_ellipsoids: 2,
            curve_samples: 2,
            lod_levels: 2,
            materials: 1,
            textures: 1,
            png_image: false,
            tree_count: 1,
            extension_kinds: vec![0x0001_0000],
            octahedral_frames: 2..=2,
            name: Some("small".into()),
            ..Self::everything()
        }
    }
}

impl Default for SyntheticOptions {
    /// [`SyntheticOptions::everything`].
    fn default() -> Self {
        Self::everything()
    }
}

type V3 = [f32; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn scale(a: V3, s: f32) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn length(a: V3) -> f32 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
fn normalize_or(a: V3, fallback: V3) -> V3 {
    let l = length(a);
    if l > 1e-12 && l.is_finite() { scale(a, 1.0 / l) } else { fallback }
}
fn mean(points: &[V3]) -> V3 {
    let sum = points.iter().fold([0.0; 3], |acc, &p| add(acc, p));
    scale(sum, 1.0 / points.len().max(1) as f32)
}

/// The grid geometry of the block (spec §6.1).
#[derive(Clone)]
struct Grid {
    dims: [u32; 3],
    bounds_min: V3,
    /// `(bounds_max − bounds_min) / grid`, computed as the spec says.
    cell: V3,
}

impl Grid {
    fn cell_count(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    fn coords(&self, index: usize) -> [u32; 3] {
        let (gx, gy) = (self.dims[0] as usize, self.dims[1] as usize);
        [(index % gx) as u32, ((index / gx) % gy) as u32, (index / (gx * gy)) as u32]
    }

    /// The point at fractions `f` (each in `[0, 1]`) of grid cell `index`'s box.
    fn at(&self, index: usize, f: V3) -> V3 {
        let c = self.coords(index);
        core::array::from_fn(|i| self.bounds_min[i] + (c[i] as f32 + f[i]) * self.cell[i])
    }

    /// The smallest cell edge.
    fn min_edge(&self) -> f32 {
        self.cell.iter().copied().fold(f32::INFINITY, f32::min)
    }
}

fn fractions(rng: &mut SplitMix64, lo: f32, hi: f32) -> V3 {
    [rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi)]
}

fn random_color(rng: &mut SplitMix64) -> u32 {
    rgba8([rng.unit(), rng.unit(), rng.unit(), rng.uniform(0.2, 1.0)])
}

fn random_direction(rng: &mut SplitMix64) -> V3 {
    let v = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)];
    normalize_or(v, [0.0, 1.0, 0.0])
}

/// A triangle with vertices inside a grid cell (at least 5 % of the cell edge from its faces).
#[derive(Clone, Copy)]
struct Tri {
    corners: [V3; 3],
    normal: V3,
    area: f32,
    size: f32,
    material: u32,
}

impl Tri {
    fn random(rng: &mut SplitMix64, grid: &Grid, cell: usize, materials: u32) -> Self {
        let mut corners = [[0.0; 3]; 3];
        let mut area = 0.0;
        let mut normal = [0.0, 1.0, 0.0];
        for attempt in 0..16 {
            let center = fractions(rng, 0.25, 0.75);
            corners = core::array::from_fn(|_| {
                let offset = fractions(rng, -0.2, 0.2);
                grid.at(cell, add(center, offset))
            });
            if attempt == 15 {
                // Practically unreachable: a fixed right triangle in the cell.
                corners = [[0.3, 0.3, 0.5], [0.7, 0.3, 0.5], [0.3, 0.7, 0.5]].map(|f| grid.at(cell, f));
            }
            let n = cross(sub(corners[1], corners[0]), sub(corners[2], corners[0]));
            area = 0.5 * length(n);
            if area > 1e-6 {
                normal = normalize_or(n, normal);
                break;
            }
        }
        // Spec §2: the size of a triangle is the diameter of the disc of equal area.
        let size = 2.0 * (area / core::f32::consts::PI).sqrt();
        Self { corners, normal, area, size, material: rng.below(materials) }
    }

    fn centroid(&self) -> V3 {
        mean(&self.corners)
    }
}

/// A random binary hierarchy over `positions.len()` leaves: nodes `0 .. n` are the leaves, inner
/// nodes are appended after their children. Each split sorts along a random axis and cuts at a
/// random place, so clusters are roughly spatial.
fn binary_hierarchy(rng: &mut SplitMix64, positions: &[V3]) -> Vec<Vec<u32>> {
    fn split(rng: &mut SplitMix64, ids: &mut [u32], positions: &[V3], children: &mut Vec<Vec<u32>>) -> u32 {
        if let [only] = ids {
            return *only;
        }
        let axis = rng.below(3) as usize;
        ids.sort_by(|&a, &b| positions[a as usize][axis].total_cmp(&positions[b as usize][axis]).then(a.cmp(&b)));
        let cut = 1 + rng.below(ids.len() as u32 - 1) as usize;
        let (left, right) = ids.split_at_mut(cut);
        let l = split(rng, left, positions, children);
        let r = split(rng, right, positions, children);
        children.push(vec![l, r]);
        children.len() as u32 - 1
    }
    let mut children = vec![Vec::new(); positions.len()];
    let mut ids: Vec<u32> = (0..positions.len() as u32).collect();
    if !ids.is_empty() {
        split(rng, &mut ids, positions, &mut children);
    }
    children
}

/// Attributes of a node of a generic hierarchy: a centre and a bounding radius.
#[derive(Clone, Copy)]
struct Sphere {
    center: V3,
    radius: f32,
}

/// Bounding spheres of the inner nodes, from the leaves' spheres (children precede parents).
fn bounding_spheres(children: &[Vec<u32>], leaves: &[Sphere]) -> Vec<Sphere> {
    let mut nodes: Vec<Sphere> = leaves.to_vec();
    for kids in &children[leaves.len()..] {
        let center = mean(&kids.iter().map(|&k| nodes[k as usize].center).collect::<Vec<_>>());
        let radius = kids
            .iter()
            .map(|&k| length(sub(nodes[k as usize].center, center)) + nodes[k as usize].radius)
            .fold(0.0, f32::max);
        nodes.push(Sphere { center, radius });
    }
    nodes
}

/// Records of one cell and its reference positions (spec §6.2), appended to the container.
struct Builder<'a> {
    rng: SplitMix64,
    options: &'a SyntheticOptions,
    grid: Grid,
    data: ContainerData,
    materials: u32,
    atlas: Option<u32>,
    /// Reference positions of the cell being built.
    refs: Vec<V3>,
}

impl Builder<'_> {
    fn push_vertex(&mut self, position: V3, normal: V3) -> u32 {
        let color = if self.rng.chance(0.5) { u32::MAX } else { random_color(&mut self.rng) };
        let uv = [self.rng.unit(), self.rng.unit()];
        self.data.vertices.push(VertexRecord { position, normal: oct_encode(normal), uv, color });
        self.data.vertices.len() as u32 - 1
    }

    fn push_triangle_vertices(&mut self, tri: &Tri) -> [u32; 3] {
        self.refs.extend_from_slice(&tri.corners);
        tri.corners.map(|c| self.push_vertex(c, tri.normal))
    }

    /// Gilet: triangles sorted by size, one leaf point per triangle, a binary hierarchy of inner
    /// points, flattened by `flatten` (spec §6.4, §6.5, §10).
    fn gilet_cell(&mut self, cell: usize) -> (Range, Range) {
        let count = self.rng.in_range(&self.options.triangles_per_cell);
        let tris: Vec<Tri> = (0..count).map(|_| Tri::random(&mut self.rng, &self.grid, cell, self.materials)).collect();
        let first_tri = self.data.triangles.len() as u32;
        let first_point = self.data.points.len() as u32;
        if tris.is_empty() {
            return (Range { first: first_tri, count: 0 }, Range { first: first_point, count: 0 });
        }
        let centroids: Vec<V3> = tris.iter().map(Tri::centroid).collect();
        let children = binary_hierarchy(&mut self.rng, &centroids);
        // Leaf spheres: centroid and equal-area radius; inner: bounding spheres (monotone radii).
        let leaves: Vec<Sphere> =
            tris.iter().zip(&centroids).map(|(t, &c)| Sphere { center: c, radius: t.size * 0.5 }).collect();
        let spheres = bounding_spheres(&children, &leaves);
        // Area-weighted normals and colours of the nodes.
        let mut normals: Vec<V3> = tris.iter().map(|t| t.normal).collect();
        let mut areas: Vec<f32> = tris.iter().map(|t| t.area).collect();
        let mut colors: Vec<[f32; 4]> = tris
            .iter()
            .map(|_| [self.rng.unit(), self.rng.unit(), self.rng.unit(), self.rng.uniform(0.3, 1.0)])
            .collect();
        for kids in &children[tris.len()..] {
            let area: f32 = kids.iter().map(|&k| areas[k as usize]).sum();
            let w = |k: u32| {
                if area > 0.0 { areas[k as usize] / area } else { 1.0 / kids.len() as f32 }
            };
            let normal = kids.iter().fold([0.0; 3], |acc, &k| add(acc, scale(normals[k as usize], w(k))));
            let color = kids
                .iter()
                .fold([0.0; 4], |acc: [f32; 4], &k| core::array::from_fn(|i| acc[i] + colors[k as usize][i] * w(k)));
            normals.push(normalize_or(normal, normals[kids[0] as usize]));
            areas.push(area);
            colors.push(color);
        }
        let sizes: Vec<f32> = spheres
            .iter()
            .enumerate()
            .map(|(i, s)| if i < tris.len() { tris[i].size } else { 2.0 * s.radius })
            .collect();
        let spt = flatten(&children, &sizes).expect("a synthetic hierarchy is a forest with finite sizes");
        for &node in &spt.order {
            let n = node as usize;
            let flat = spt.nodes[n];
            let (size, radius) = if n < tris.len() {
                // A leaf point keeps its triangle's size bit for bit (spec §6.5).
                (tris[n].size, tris[n].size * 0.5)
            } else {
                (flat.size, flat.size * 0.5)
            };
            self.refs.push(spheres[n].center);
            self.data.points.push(PointRecord {
                position: spheres[n].center,
                radius,
                normal: oct_encode(normals[n]),
                color: rgba8(colors[n]),
                size,
                lo: flat.lo,
                hi: flat.hi,
                leaf_first: flat.leaf_first,
                leaf_count: flat.leaf_count,
                flags: 0,
            });
        }
        // Triangles by size, largest first; ties by leaf id, so the order is fixed.
        let leaf_of = |i: usize| spt.leaf_id[i].expect("nodes 0 .. n are the leaves");
        let mut order: Vec<usize> = (0..tris.len()).collect();
        order.sort_by(|&a, &b| tris[b].size.total_cmp(&tris[a].size).then(leaf_of(a).cmp(&leaf_of(b))));
        for i in order {
            let indices = self.push_triangle_vertices(&tris[i]);
            self.data.triangles.push(TriangleRecord {
                indices,
                size: tris[i].size,
                leaf: leaf_of(i),
                material: tris[i].material,
            });
        }
        (
            Range { first: first_tri, count },
            Range { first: first_point, count: self.data.points.len() as u32 - first_point },
        )
    }

    /// A random binary hierarchy over `leaves`, flattened; calls `emit` per node in SPT order with
    /// the node's bounding sphere, its input index if it is a leaf, its flattened interval and run,
    /// and the map from leaf id to input leaf index. Leaves' sizes are `sizes_of_leaves`, inner
    /// nodes' sizes twice their bounding radius.
    fn spt_hierarchy(
        &mut self,
        leaves: &[Sphere],
        sizes_of_leaves: &[f32],
        mut emit: impl FnMut(&mut Self, &Sphere, Option<usize>, SptNode, &[usize]),
    ) {
        if leaves.is_empty() {
            return;
        }
        let centers: Vec<V3> = leaves.iter().map(|s| s.center).collect();
        let children = binary_hierarchy(&mut self.rng, &centers);
        let spheres = bounding_spheres(&children, leaves);
        let sizes: Vec<f32> = spheres
            .iter()
            .enumerate()
            .map(|(i, s)| sizes_of_leaves.get(i).copied().unwrap_or(2.0 * s.radius))
            .collect();
        let spt = flatten(&children, &sizes).expect("a synthetic hierarchy is a forest with finite sizes");
        let by_leaf = inputs_by_leaf(&spt.leaf_id, leaves.len());
        for &node in &spt.order {
            let n = node as usize;
            emit(self, &spheres[n], (n < leaves.len()).then_some(n), spt.nodes[n], &by_leaf);
        }
    }

    fn ellipsoids(&mut self, count: u32, place: impl Fn(&mut SplitMix64) -> V3, max_radius: f32) -> Range {
        let first = self.data.ellipsoids.len() as u32;
        let mut radii = Vec::new();
        let mut leaves = Vec::new();
        let mut orientations = Vec::new();
        for _ in 0..count {
            let r = fractions(&mut self.rng, 0.2, 1.0).map(|f| f * max_radius);
            let center = place(&mut self.rng);
            leaves.push(Sphere { center, radius: r.iter().copied().fold(0.0, f32::max) });
            radii.push(r);
            let q = [
                self.rng.uniform(-1.0, 1.0),
                self.rng.uniform(-1.0, 1.0),
                self.rng.uniform(-1.0, 1.0),
                self.rng.uniform(0.1, 1.0),
            ];
            let l = (q.iter().map(|v| v * v).sum::<f32>()).sqrt();
            orientations.push(q.map(|v| (v / l * 32767.0).round() as i16));
        }
        let sizes: Vec<f32> = leaves.iter().map(|s| 2.0 * s.radius).collect();
        self.spt_hierarchy(&leaves, &sizes, |b, sphere, leaf, flat, _by_leaf| {
            let (radii, orientation) = match leaf {
                Some(i) => (radii[i], orientations[i]),
                None => ([sphere.radius; 3], [0, 0, 0, 32767]),
            };
            b.refs.push(sphere.center);
            let color = random_color(&mut b.rng);
            let alpha_threshold = b.rng.unit();
            b.data.ellipsoids.push(EllipsoidRecord {
                center: sphere.center,
                radii,
                orientation,
                color,
                alpha_threshold,
                noise_mip: 0.5 * (1.0 + (flat.leaf_count as f32).log2()),
                lo: flat.lo,
                hi: flat.hi,
                leaf_first: flat.leaf_first,
                leaf_count: flat.leaf_count,
                flags: 0,
            });
        });
        Range { first, count: self.data.ellipsoids.len() as u32 - first }
    }

    fn lines(&mut self, cell: usize) -> Range {
        let first = self.data.lines.len() as u32;
        let count = self.rng.in_range(&self.options.lines_per_cell);
        let edge = self.grid.min_edge();
        let mut segments = Vec::new();
        let mut leaves = Vec::new();
        for _ in 0..count {
            let center = fractions(&mut self.rng, 0.25, 0.75);
            let p0 = self.grid.at(cell, add(center, fractions(&mut self.rng, -0.2, 0.2)));
            let p1 = self.grid.at(cell, add(center, fractions(&mut self.rng, -0.2, 0.2)));
            let (r0, r1) = (self.rng.uniform(0.01, 0.05) * edge, self.rng.uniform(0.01, 0.05) * edge);
            let radius = 0.5 * length(sub(p1, p0)) + r0.max(r1);
            leaves.push(Sphere { center: mean(&[p0, p1]), radius });
            segments.push((p0, r0, p1, r1));
        }
        let sizes: Vec<f32> = leaves.iter().map(|s| 2.0 * s.radius).collect();
        self.spt_hierarchy(&leaves, &sizes, |b, _sphere, leaf, flat, by_leaf| {
            let (p0, r0, p1, r1) = match leaf {
                Some(i) => segments[i],
                // An inner line: from the start of its run's first segment to the end of its last.
                None => {
                    let (a, ra, _, _) = segments[by_leaf[flat.leaf_first as usize]];
                    let (_, _, z, rz) = segments[by_leaf[(flat.leaf_first + flat.leaf_count - 1) as usize]];
                    (a, ra, z, rz)
                }
            };
            b.refs.extend_from_slice(&[p0, p1]);
            let color = random_color(&mut b.rng);
            b.data.lines.push(LineRecord {
                p0,
                r0,
                p1,
                r1,
                color,
                lo: flat.lo,
                hi: flat.hi,
                leaf_first: flat.leaf_first,
                leaf_count: flat.leaf_count,
                flags: 0,
            });
        });
        Range { first, count: self.data.lines.len() as u32 - first }
    }

    fn planes(&mut self, cell: usize) -> Range {
        let first = self.data.planes.len() as u32;
        let count = self.rng.in_range(&self.options.planes_per_cell);
        let Some(atlas) = self.atlas else {
            return Range { first, count: 0 };
        };
        let edge = self.grid.min_edge();
        let mut quads = Vec::new();
        let mut leaves = Vec::new();
        for _ in 0..count {
            let center = self.grid.at(cell, fractions(&mut self.rng, 0.2, 0.8));
            let normal = random_direction(&mut self.rng);
            let u_dir = normalize_or(cross(normal, [0.0, 1.0, 0.0]), [1.0, 0.0, 0.0]);
            let v_dir = normalize_or(cross(normal, u_dir), [0.0, 1.0, 0.0]);
            let (hu, hv) = (self.rng.uniform(0.05, 0.2) * edge, self.rng.uniform(0.05, 0.2) * edge);
            let (u0, v0) = (self.rng.uniform(0.0, 0.5), self.rng.uniform(0.0, 0.5));
            let (u1, v1) = (u0 + self.rng.uniform(0.0, 0.5), v0 + self.rng.uniform(0.0, 0.5));
            leaves.push(Sphere { center, radius: (hu * hu + hv * hv).sqrt() });
            quads.push((scale(u_dir, hu), scale(v_dir, hv), unorm16x2(u0, v0), unorm16x2(u1, v1)));
        }
        let sizes: Vec<f32> = leaves.iter().map(|s| 2.0 * s.radius).collect();
        self.spt_hierarchy(&leaves, &sizes, |b, sphere, leaf, flat, _by_leaf| {
            let (axis_u, axis_v, uv_min, uv_max) = match leaf {
                Some(i) => quads[i],
                None => {
                    let h = sphere.radius * core::f32::consts::FRAC_1_SQRT_2;
                    ([h, 0.0, 0.0], [0.0, h, 0.0], unorm16x2(0.0, 0.0), unorm16x2(1.0, 1.0))
                }
            };
            b.refs.push(sphere.center);
            b.data.planes.push(PlaneRecord {
                center: sphere.center,
                axis_u,
                axis_v,
                image: atlas,
                uv_min,
                uv_max,
                lo: flat.lo,
                hi: flat.hi,
                leaf_first: flat.leaf_first,
                leaf_count: flat.leaf_count,
            });
        });
        Range { first, count: self.data.planes.len() as u32 - first }
    }

    /// Neubert: pruned leaves in priority order (largest area first), their triangles tiling
    /// `PRUNE_TRIANGLES` in leaf order (spec §6.11).
    fn prune(&mut self, cell: usize) -> Range {
        let first = self.data.prune_leaves.len() as u32;
        let count = self.rng.in_range(&self.options.prune_leaves_per_cell);
        let mut leaves: Vec<Vec<Tri>> = (0..count)
            .map(|_| {
                (0..1 + self.rng.below(2))
                    .map(|_| Tri::random(&mut self.rng, &self.grid, cell, self.materials))
                    .collect()
            })
            .collect();
        let area = |tris: &Vec<Tri>| tris.iter().map(|t| t.area).sum::<f32>();
        leaves.sort_by(|a, b| area(b).total_cmp(&area(a)));
        for tris in leaves {
            let index = self.data.prune_leaves.len() as u32;
            let center = mean(&tris.iter().map(Tri::centroid).collect::<Vec<_>>());
            self.refs.push(center);
            let first_triangle = self.data.prune_triangles.len() as u32;
            for tri in &tris {
                let indices = tri.corners.map(|c| self.push_vertex(c, tri.normal));
                self.data.prune_triangles.push(TriangleRecord {
                    indices,
                    size: tri.size,
                    leaf: index,
                    material: tri.material,
                });
            }
            self.data.prune_leaves.push(PruneLeafRecord {
                center,
                area: area(&tris),
                first_triangle,
                triangle_count: tris.len() as u32,
            });
        }
        Range { first, count }
    }

    /// Closes the cell: its bounds are the box of the reference positions (zero when empty).
    fn push_cell(&mut self, ranges: [Range; 6]) {
        let (bounds_min, bounds_max) = if self.refs.is_empty() {
            ([0.0; 3], [0.0; 3])
        } else {
            let lo = self.refs.iter().fold([f32::INFINITY; 3], |m, p| core::array::from_fn(|i| m[i].min(p[i])));
            let hi = self.refs.iter().fold([f32::NEG_INFINITY; 3], |m, p| core::array::from_fn(|i| m[i].max(p[i])));
            (lo, hi)
        };
        self.refs.clear();
        let [triangles, points, ellipsoids, lines, planes, prune_leaves] = ranges;
        self.data.cells.push(CellRecord {
            bounds_min,
            bounds_max,
            triangles,
            points,
            ellipsoids,
            lines,
            planes,
            prune_leaves,
            flags: 0,
            _pad: 0,
        });
    }

    /// Appends an image's data to `IMAGE_DATA` at the next multiple of 16 and its record.
    fn push_image(&mut self, record: ImageRecord, bytes: &[u8]) -> u32 {
        push_image(&mut self.data, record, bytes)
    }

    fn raw_image(&mut self, width: u32, height: u32, format: u32, full_mips: bool) -> u32 {
        let max_mips = 32 - width.max(height).leading_zeros();
        let mip_count = if full_mips { max_mips } else { 1 + self.rng.below(max_mips) };
        let record = ImageRecord { width, height, mip_count, format, data_offset: 0, data_length: 0 };
        let length = record.expected_data_length().expect("small images") as usize;
        let bytes = self.rng.bytes(length);
        self.push_image(record, &bytes)
    }
}

/// Appends an image's data to `IMAGE_DATA` at the next multiple of 16 and its record; returns its
/// index.
fn push_image(data: &mut ContainerData, mut record: ImageRecord, bytes: &[u8]) -> u32 {
    let offset = data.image_data.len().div_ceil(16) * 16;
    data.image_data.resize(offset, 0);
    data.image_data.extend_from_slice(bytes);
    record.data_offset = offset as u64;
    record.data_length = bytes.len() as u64;
    data.images.push(record);
    data.images.len() as u32 - 1
}

/// Texels per side of the cell that holds one plane's region in the `LEAF_SLOTS` image.
const SLOT_CELL: u32 = 8;

/// Indirect texturing (spec §6.10.1): one `LEAF_SLOTS` image with a cell of `SLOT_CELL`² texels
/// per plane, row by row; each plane's rectangle is a random region of 2..=6 × 2..=6 texels inside
/// its cell, at least one texel from the cell's edge (so the texels a rectangle's rounded corners
/// may touch are empty), whose texels hold slot `a` (a leaf of the plane, or 0 one time in five)
/// and slot `b` (another leaf half the time, else 0); the rest of the image is 0. Each plane gets
/// `leaf_count` `PLANE_LEAVES` records with random affine maps, texture rectangles (or none),
/// materials and colours.
fn indirect_texturing(rng: &mut SplitMix64, data: &mut ContainerData) {
    let count = data.planes.len() as u32;
    let materials = data.materials.len() as u32;
    if count == 0 || materials == 0 {
        return;
    }
    let mut columns = 1;
    while columns * columns < count {
        columns += 1;
    }
    let (width, height) = (columns * SLOT_CELL, count.div_ceil(columns) * SLOT_CELL);
    let mut texels = vec![0u8; (width * height * 4) as usize];
    let image = data.images.len() as u32;
    for (p, plane) in data.planes.iter_mut().enumerate() {
        let (cell_x, cell_y) = ((p as u32 % columns) * SLOT_CELL, (p as u32 / columns) * SLOT_CELL);
        let (w, h) = (2 + rng.below(5), 2 + rng.below(5));
        let x0 = cell_x + 1 + rng.below(SLOT_CELL - 1 - w);
        let y0 = cell_y + 1 + rng.below(SLOT_CELL - 1 - h);
        let leaves = plane.leaf_count;
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                let a = if rng.chance(0.8) { 1 + rng.below(leaves) } else { 0 };
                let b = if a > 0 && leaves > 1 && rng.chance(0.5) {
                    // Another leaf than a: a step of 1 ..= leaves − 1 around the plane's leaves.
                    1 + (a + rng.below(leaves - 1)) % leaves
                } else {
                    0
                };
                let at = ((y * width + x) * 4) as usize;
                texels[at..at + 2].copy_from_slice(&(a as u16).to_le_bytes());
                texels[at + 2..at + 4].copy_from_slice(&(b as u16).to_le_bytes());
            }
        }
        plane.image = image;
        plane.uv_min = unorm16x2(x0 as f32 / width as f32, y0 as f32 / height as f32);
        plane.uv_max = unorm16x2((x0 + w) as f32 / width as f32, (y0 + h) as f32 / height as f32);
        for _ in 0..leaves {
            let uv0 = [rng.unit(), rng.unit()];
            let du = [rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)];
            let dv = [rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)];
            // A texture rectangle, or one time in four none (`uv_min = uv_max = 0`: not clipped).
            let (uv_min, uv_max) = if rng.chance(0.25) {
                (0, 0)
            } else {
                let (u0, v0) = (rng.uniform(0.0, 0.5), rng.uniform(0.0, 0.5));
                let (u1, v1) = (u0 + rng.uniform(0.0, 0.5), v0 + rng.uniform(0.0, 0.5));
                (unorm16x2(u0, v0), unorm16x2(u1, v1))
            };
            let material = rng.below(materials);
            let color = if rng.chance(0.5) { u32::MAX } else { random_color(rng) };
            data.plane_leaves.push(PlaneLeafRecord { uv0, du, dv, uv_min, uv_max, material, color });
        }
    }
    let record =
        ImageRecord { width, height, mip_count: 1, format: image_format::LEAF_SLOTS, data_offset: 0, data_length: 0 };
    push_image(data, record, &texels);
}

/// A valid PNG file (8-bit RGBA, stored deflate blocks) of `width × height` random texels.
fn png_file(rng: &mut SplitMix64, width: u32, height: u32) -> Vec<u8> {
    fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let start = out.len();
        out.extend_from_slice(kind);
        out.extend_from_slice(data);
        let crc = crc32fast::hash(&out[start..]);
        out.extend_from_slice(&crc.to_be_bytes());
    }
    let mut raw = Vec::new();
    for _ in 0..height {
        raw.push(0); // filter type None
        raw.extend(rng.bytes(width as usize * 4));
    }
    // zlib stream: header, one final stored block (raw is far below 65 535 bytes), Adler-32.
    let mut zlib = vec![0x78, 0x01, 0x01];
    let len = raw.len() as u16;
    zlib.extend_from_slice(&len.to_le_bytes());
    zlib.extend_from_slice(&(!len).to_le_bytes());
    zlib.extend_from_slice(&raw);
    let (mut a, mut b) = (1u32, 0u32);
    for &byte in &raw {
        a = (a + u32::from(byte)) % 65_521;
        b = (b + a) % 65_521;
    }
    zlib.extend_from_slice(&((b << 16) | a).to_be_bytes());
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 6, 0, 0, 0]); // 8 bits, RGBA, deflate, filter 0, no interlace
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"IDAT", &zlib);
    chunk(&mut png, b"IEND", &[]);
    png
}

fn hex(rng: &mut SplitMix64, bytes: usize) -> String {
    rng.bytes(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// Builds a valid container from `seed` and `options`. Deterministic: the same arguments always
/// give the same data (and so, with the same compression, the same file bytes).
///
/// Geometry: the block's bounds are a random box split into the grid; each grid cell gets
/// triangles with vertices inside the cell (so every centroid lies in its cell), a leaf point per
/// triangle (`size` = the triangle's size bit for bit, `lo = 0`) under a random binary hierarchy
/// of inner points (`size = 2·radius`, monotone), flattened with [`treelod_build::flatten`] and
/// written in its `order`, with the triangles' `leaf` ids taken from its `leaf_id` and the
/// triangles sorted by size, largest first. Ellipsoid, line and plane hierarchies are flattened
/// the same way; pruned leaves come in priority order. Cell bounds are the tight box of the
/// records' reference positions (spec §6.2), all-zero for an empty cell.
#[must_use]
pub fn synthetic(seed: u64, options: &SyntheticOptions) -> ContainerData {
    let mut rng = SplitMix64::new(seed);
    let dims = options.grid.map(|g| g.clamp(1, 256));
    let bounds_min = [rng.uniform(-4.0, 4.0), rng.uniform(-1.0, 1.0), rng.uniform(-4.0, 4.0)];
    let extent: V3 = core::array::from_fn(|i| rng.uniform(0.5, 3.0) * dims[i] as f32);
    let bounds_max = add(bounds_min, extent);
    // Spec §6.1: c = (bounds_max − bounds_min) / grid, from the stored bounds.
    let cell = core::array::from_fn(|i| (bounds_max[i] - bounds_min[i]) / dims[i] as f32);
    let grid = Grid { dims, bounds_min, cell };
    let makes_triangles = *options.triangles_per_cell.end() > 0 || *options.prune_leaves_per_cell.end() > 0;
    let materials = if makes_triangles { options.materials.max(1) } else { options.materials };
    let tree_count = options.tree_count.max(1);

    let mut b =
        Builder { rng, options, grid, data: ContainerData::default(), materials, atlas: None, refs: Vec::new() };

    // Images first: textures (random mip chains), the impostor atlas (full chain), the PNG.
    for _ in 0..options.textures {
        let (w, h) = (1 << b.rng.below(5), 1 << b.rng.below(5));
        b.raw_image(w, h, image_format::RGBA8_SRGB, false);
    }
    if *options.planes_per_cell.end() > 0 {
        b.atlas = Some(b.raw_image(8, 4, image_format::RGBA8_LINEAR, true));
    }
    if options.png_image {
        let png = png_file(&mut b.rng, 2, 2);
        let record = ImageRecord {
            width: 2,
            height: 2,
            mip_count: 1,
            format: image_format::PNG,
            data_offset: 0,
            data_length: 0,
        };
        b.push_image(record, &png);
    }

    for m in 0..materials {
        let image = if options.textures > 0 && b.rng.chance(0.7) { b.rng.below(options.textures) } else { NO_IMAGE };
        let base_color = [b.rng.unit(), b.rng.unit(), b.rng.unit(), b.rng.uniform(0.5, 1.0)];
        let record = MaterialRecord {
            base_color,
            image,
            alpha_mode: b.rng.below(3),
            alpha_cutoff: b.rng.unit(),
            class: b.rng.below(3),
            flags: b.rng.below(2),
            _pad: 0,
        };
        b.data.materials.push(record);
        let classified_by = ["name", "mesh", "node", "geometry", "override", "default"][b.rng.below(6) as usize];
        let name = if b.rng.chance(0.9) { format!("material-{m}") } else { String::new() };
        b.data.metadata.materials.push(MaterialInfo { name, classified_by: classified_by.into() });
    }

    for index in 0..b.grid.cell_count() {
        let (triangles, points) = b.gilet_cell(index);
        let count = b.rng.in_range(&options.ellipsoids_per_cell);
        let max_radius = 0.2 * b.grid.min_edge();
        let geometry = b.grid.clone();
        let ellipsoids = b.ellipsoids(count, |rng| geometry.at(index, fractions(rng, 0.2, 0.8)), max_radius);
        let lines = b.lines(index);
        let planes = b.planes(index);
        let prune_leaves = b.prune(index);
        b.push_cell([triangles, points, ellipsoids, lines, planes, prune_leaves]);
    }

    // The block cell: an ellipsoid hierarchy over the whole block, empty ranges elsewhere.
    let max_radius = 0.1 * extent.iter().copied().fold(f32::INFINITY, f32::min);
    let ellipsoids = b.ellipsoids(
        options.block_ellipsoids,
        |rng| core::array::from_fn(|i| bounds_min[i] + rng.uniform(0.1, 0.9) * extent[i]),
        max_radius,
    );
    let end = |len: usize| Range { first: len as u32, count: 0 };
    let ranges = [
        end(b.data.triangles.len()),
        end(b.data.points.len()),
        ellipsoids,
        end(b.data.lines.len()),
        end(b.data.planes.len()),
        end(b.data.prune_leaves.len()),
    ];
    b.push_cell(ranges);

    // Pruning curves (spec §6.11): s_opt(λ) ≥ 1 on λ ∈ (0, 1], λ(height) in (0, 1].
    let n = options.curve_samples;
    for k in 0..n {
        let lambda = (k + 1) as f32 / n as f32;
        b.data.prune_scale.push(CurveSample { x: lambda, y: 1.0 / lambda.sqrt() });
        b.data.prune_lambda.push(CurveSample { x: (8u32 << k.min(20)) as f32, y: lambda });
    }

    // Baselines (spec §6.12, §6.13): per tree a chain of shrinking fractions and growing errors over
    // random written triangles' vertices, and billboards on the atlas.
    let vertex_count = b.data.vertices.len() as u32;
    if options.lod_levels > 0 && vertex_count > 0 && !b.data.materials.is_empty() {
        for tree in 0..tree_count {
            let mut error = 0.0f32;
            for level in 0..options.lod_levels {
                let first = b.data.lod_triangles.len() as u32;
                for _ in 0..1 + b.rng.below(3) {
                    let indices = [b.rng.below(vertex_count), b.rng.below(vertex_count), b.rng.below(vertex_count)];
                    let material = b.rng.below(b.data.materials.len() as u32);
                    let size = b.rng.uniform(0.01, 0.5);
                    b.data.lod_triangles.push(TriangleRecord { indices, size, leaf: 0, material });
                }
                error += b.rng.uniform(0.0, 0.2);
                b.data.lod_levels.push(LodLevelRecord {
                    tree,
                    level,
                    triangles: Range { first, count: b.data.lod_triangles.len() as u32 - first },
                    error,
                    fraction: 0.5 / (level + 1) as f32,
                });
            }
        }
    }
    if let (true, Some(atlas)) = (options.billboards, b.atlas) {
        for tree in 0..tree_count {
            for kind in [billboard_kind::FACING, billboard_kind::CROSSED] {
                let center = core::array::from_fn(|i| bounds_min[i] + b.rng.uniform(0.3, 0.7) * extent[i]);
                let (r, h) = (b.rng.uniform(0.2, 1.0), b.rng.uniform(0.2, 1.0));
                b.data.billboards.push(BillboardRecord {
                    center,
                    axis_u: [r, 0.0, 0.0],
                    axis_v: [0.0, h, 0.0],
                    image: atlas,
                    uv_min: unorm16x2(0.0, 0.0),
                    uv_max: unorm16x2(b.rng.uniform(0.1, 1.0), b.rng.uniform(0.1, 1.0)),
                    tree,
                    kind,
                    reserved: [0; 2],
                });
            }
        }
    }

    b.data.block = BlockRecord { bounds_min, bounds_max, grid: dims, tree_count, flags: 0, _pad: 0 };

    let mut rng = b.rng;
    let meta = &mut b.data.metadata;
    meta.generator = format!("treelod-tests {}", env!("CARGO_PKG_VERSION"));
    meta.name = options.name.clone().unwrap_or_else(|| format!("synthetic-{seed:x}"));
    for t in 0..tree_count {
        let content_hash = if rng.chance(0.8) { format!("blake3:{}", hex(&mut rng, 32)) } else { String::new() };
        meta.sources.push(Source {
            path: format!("trees/tree-{t}.glb"),
            content_hash,
            byte_length: u64::from(rng.next_u32()),
            unit_scale: if rng.chance(0.5) { 1.0 } else { 0.01 },
        });
        let corner = |rng: &mut SplitMix64| -> V3 { core::array::from_fn(|i| bounds_min[i] + rng.unit() * extent[i]) };
        let (p, q) = (corner(&mut rng), corner(&mut rng));
        meta.trees.push(Tree {
            name: format!("tree-{t}"),
            source: t,
            translation: corner(&mut rng),
            bounds_min: core::array::from_fn(|i| p[i].min(q[i])),
            bounds_max: core::array::from_fn(|i| p[i].max(q[i])),
        });
    }
    let mut settings = vec![
        ("grid".to_owned(), format!("{}x{}x{}", dims[0], dims[1], dims[2])),
        ("synthetic.seed".to_owned(), seed.to_string()),
        ("gilet.cluster_max".to_owned(), "2".to_owned()),
    ];
    if !b.data.prune_leaves.is_empty() || n > 0 {
        settings.push(("prune.min_quality".to_owned(), "0.9".to_owned()));
    }
    settings.sort();
    meta.settings = settings.into_iter().map(|(key, value)| Setting { key, value }).collect();

    let mut kinds: Vec<u32> =
        options.extension_kinds.iter().copied().filter(|&k| SectionKind(k).record_size().is_none()).collect();
    kinds.sort_unstable();
    kinds.dedup();
    for kind in kinds {
        let len = 1 + rng.below(48) as usize;
        b.data.extra_sections.push((kind, rng.bytes(len)));
    }
    if options.ao {
        b.data.vertex_ao = rng.bytes(b.data.vertices.len());
        b.data.point_ao = rng.bytes(b.data.points.len());
        b.data.plane_ao = rng.bytes(b.data.planes.len());
    }
    if options.indirect_planes {
        indirect_texturing(&mut rng, &mut b.data);
    }
    if options.ellipsoid_ao {
        b.data.ellipsoid_ao = rng.bytes(b.data.ellipsoids.len());
    }
    if options.line_ao {
        b.data.line_ao = rng.bytes(b.data.lines.len());
    }
    if options.calibration {
        b.data.calibration = calibration(&mut rng, 0..calibration_technique::FIRST_ADDED);
    }
    if options.calibration_elevations {
        b.data.calibration_elevations = calibration_elevations(&mut rng, &ELEVATIONS, &b.data.calibration);
    }
    if options.chain_calibration {
        b.data.chain_calibration = chain_calibration(&mut rng, &b.data.lod_levels);
    }
    if options.far_lines {
        b.data.far_lines = far_lines(&mut rng, &b.data.lines, b.grid.min_edge());
        if options.line_ao {
            b.data.far_line_ao = rng.bytes(b.data.far_lines.len());
        }
    }
    if options.plane_diffuse {
        b.data.plane_diffuse = b
            .data
            .planes
            .iter()
            .map(|_| {
                let flat = rng.below(0x1_0000);
                let scattered = rng.below(0x1_0000 - flat);
                PlaneDiffuseRecord { flat: flat as u16, scattered: scattered as u16 }
            })
            .collect();
    }
    if let (true, Some(atlas)) = (options.octahedral, b.atlas) {
        for tree in 0..tree_count {
            let center = core::array::from_fn(|i| bounds_min[i] + rng.uniform(0.3, 0.7) * extent[i]);
            let radius = rng.uniform(0.2, 1.5);
            // 2 + below(15) for the presets' 2 ..= 16, as before the range was an option.
            let frames = rng.in_range(&options.octahedral_frames);
            let (u0, v0) = (rng.uniform(0.0, 0.5), rng.uniform(0.0, 0.5));
            let (u1, v1) = (u0 + rng.uniform(0.1, 0.5), v0 + rng.uniform(0.1, 0.5));
            let occlusion = if options.ao { rng.unit() } else { 0.0 };
            let flat = rng.below(0x1_0000);
            let diffuse = PlaneDiffuseRecord { flat: flat as u16, scattered: rng.below(0x1_0000 - flat) as u16 };
            b.data.octahedral.push(OctahedralRecord {
                center,
                radius,
                image: atlas,
                uv_min: unorm16x2(u0, v0),
                uv_max: unorm16x2(u1, v1),
                frames,
                tree,
                occlusion,
                diffuse,
                reserved: 0,
            });
        }
    }
    if options.calibration_added && !b.data.calibration.is_empty() {
        b.data.calibration_added =
            calibration(&mut rng, calibration_technique::FIRST_ADDED..calibration_technique::COUNT);
        let mut elevations: Vec<f32> = b.data.calibration_elevations.iter().map(|r| r.elevation).collect();
        elevations.dedup();
        b.data.calibration_elevations_added = calibration_elevations(&mut rng, &elevations, &b.data.calibration_added);
    }
    if options.octahedral_depth {
        let views: u32 = b.data.octahedral.iter().map(|o| o.frames * o.frames).sum();
        b.data.octahedral_depth = (0..views)
            .map(|_| {
                if rng.chance(0.125) {
                    OctahedralDepthRecord::default()
                } else {
                    OctahedralDepthRecord {
                        offset: rng.uniform(-0.5, 0.5),
                        slope_s: rng.uniform(-0.8, 0.8),
                        slope_t: rng.uniform(-0.8, 0.8),
                    }
                }
            })
            .collect();
    }
    if options.bc7_atlas
        && let Some(atlas) = b.atlas
    {
        let record = b.data.images[atlas as usize];
        let start = record.data_offset as usize;
        let levels = treelod_format::image::decode_levels(&record, &b.data.image_data[start..])
            .expect("the synthetic atlas has its levels");
        let mut blocks = Vec::new();
        for (level, texels) in levels.iter().enumerate() {
            let (w, h) = record.level_size(level as u32);
            blocks.extend(treelod_build::atlas_format::encode_bc7(texels, w, h));
        }
        let offset = b.data.image_data.len().div_ceil(16) * 16;
        b.data.image_data.resize(offset, 0);
        b.data.image_data.extend_from_slice(&blocks);
        b.data.images[atlas as usize] = ImageRecord {
            format: image_format::BC7_LINEAR,
            data_offset: offset as u64,
            data_length: blocks.len() as u64,
            ..record
        };
    }
    if options.point_facing {
        b.data.point_facing = rng.bytes(b.data.points.len());
    }
    match options.octahedral_normals {
        NormalGrids::None => {}
        NormalGrids::ColourSize => b.data.octahedral_normals = b.data.octahedral.iter().map(normal_grid).collect(),
        NormalGrids::HalfSize => {
            b.data.octahedral_normal_grids = b.data.octahedral.iter().map(half_normal_grid).collect();
        }
    }
    if options.calibration_flip {
        b.data.calibration_flip = calibration_flip(&mut rng);
    }
    if options.chain_calibration_flip {
        b.data.chain_calibration_flip = chain_calibration_flip(&mut rng, &b.data.chain_calibration);
    }
    b.data
}

/// The LoD chain levels' FLIP error (spec §6.20): a row at the level and height of each record of
/// `chain` (`CHAIN_CALIBRATION`, sorted by level, then height, and its levels every tree's, so the
/// rows are too), each level's first error in `[0.05, 1]` and each next the one before times a
/// factor in `[0.2, 0.9]`.
fn chain_calibration_flip(rng: &mut SplitMix64, chain: &[ChainCalibrationRecord]) -> Vec<ChainFlipCalibrationRecord> {
    let mut records: Vec<ChainFlipCalibrationRecord> = Vec::with_capacity(chain.len());
    for r in chain {
        let flip = match records.last() {
            Some(prev) if prev.level == r.level => prev.flip * rng.uniform(0.2, 0.9),
            _ => rng.uniform(0.05, 1.0),
        };
        records.push(ChainFlipCalibrationRecord { level: r.level, height: r.height, flip });
    }
    records
}

/// The calibration's FLIP error (spec §6.19): rows over every view, then at 30 and 90 degrees,
/// each of `FULL` and `OCTAHEDRAL` at three heights growing strictly from a few pixels (drawn
/// once, the same for every technique and elevation, as the build measures them), each error
/// the one before times a factor in `[0.2, 0.9]` from a first in `[0.05, 1]`.
fn calibration_flip(rng: &mut SplitMix64) -> Vec<FlipCalibrationRecord> {
    let first = rng.uniform(4.0, 16.0);
    let second = first * rng.uniform(1.5, 3.0);
    let heights = [first, second, second * rng.uniform(1.5, 3.0)];
    let mut records = Vec::new();
    for elevation in [FlipCalibrationRecord::EVERY_VIEW, 30.0, 90.0] {
        for technique in [calibration_technique::FULL, calibration_technique::OCTAHEDRAL] {
            let mut flip = rng.uniform(0.05, 1.0);
            for height in heights {
                records.push(FlipCalibrationRecord { elevation, technique, height, flip });
                flip *= rng.uniform(0.2, 0.9);
            }
        }
    }
    records
}

/// How [`synthetic`] gives the octahedral views' normals (spec §6.13.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NormalGrids {
    /// Neither `OCTAHEDRAL_NORMALS` nor `OCTAHEDRAL_NORMAL_GRIDS`: every view lit as a whole.
    #[default]
    None,
    /// 1.15's `OCTAHEDRAL_NORMALS`: a grid of the colour grid's size.
    ColourSize,
    /// 1.16's `OCTAHEDRAL_NORMAL_GRIDS`: a grid of half the colour grid's size (rounded down, in
    /// unorm16 steps) from the corner `ColourSize` gives, as the `treelod` build stores them.
    HalfSize,
}

/// Where the normal grid of the octahedral impostor `o` lies (spec §6.13.3), in unorm16 steps: a
/// grid of the colour grid's size right of it (`u` from the colour grid's `u_max`) where that fits
/// in the image (`u + width ≤ 65536`), else left of it (ending at its `u_min`) where that fits,
/// else against the image's right edge; `v` that of the colour grid. Always inside the image, as
/// `verify` checks.
fn normal_grid(o: &OctahedralRecord) -> OctahedralNormalRecord {
    let (u0, v0, u1) = (o.uv_min & 0xFFFF, o.uv_min >> 16, o.uv_max & 0xFFFF);
    let width = u1 - u0;
    let u = if u1 + width <= 0x1_0000 {
        u1
    } else if width <= u0 {
        u0 - width
    } else {
        0x1_0000 - width
    };
    OctahedralNormalRecord { uv_min: (v0 << 16) | u }
}

/// The normal grid of the octahedral impostor `o` at half its colour grid's size (spec §6.13.3,
/// 1.16): from [`normal_grid`]'s corner, `(uv_max − uv_min)/2` steps across (rounded down). Inside
/// the image, since the whole colour grid's size fits there, and not empty for a colour grid of
/// at least two steps per side (the generator's are at least 0.1 of the image).
fn half_normal_grid(o: &OctahedralRecord) -> OctahedralNormalGridRecord {
    let uv_min = normal_grid(o).uv_min;
    let (w, h) = (((o.uv_max & 0xFFFF) - (o.uv_min & 0xFFFF)) / 2, ((o.uv_max >> 16) - (o.uv_min >> 16)) / 2);
    OctahedralNormalGridRecord { uv_min, uv_max: (((uv_min >> 16) + h) << 16) | ((uv_min & 0xFFFF) + w) }
}

/// The block's far lines (spec §6.9.1): copies of the coarsest `lines` (those with `hi = +∞`, in
/// order) as the leaves of a random binary hierarchy, flattened; an inner line runs from the start
/// of its run's first leaf to the end of its last (so it lies inside the block, as they do), and
/// its `lo` is `τ_far = √2 ·` the coarsest lines' largest `lo` (`edge` when that is 0) plus its
/// bounding diameter, so the least positive `lo` is at least `τ_far` (spec §6.9.1's rule).
fn far_lines(rng: &mut SplitMix64, lines: &[LineRecord], edge: f32) -> Vec<LineRecord> {
    let coarsest: Vec<LineRecord> = lines.iter().filter(|l| l.hi == f32::INFINITY).copied().collect();
    if coarsest.is_empty() {
        return Vec::new();
    }
    let largest_lo = coarsest.iter().map(|l| l.lo).fold(0.0, f32::max);
    let tau_far = if largest_lo > 0.0 { core::f32::consts::SQRT_2 * largest_lo } else { edge };
    let leaves: Vec<Sphere> = coarsest
        .iter()
        .map(|l| Sphere { center: mean(&[l.p0, l.p1]), radius: 0.5 * length(sub(l.p1, l.p0)) + l.r0.max(l.r1) })
        .collect();
    let centers: Vec<V3> = leaves.iter().map(|s| s.center).collect();
    let children = binary_hierarchy(rng, &centers);
    let spheres = bounding_spheres(&children, &leaves);
    // Leaves 0 (their lo is 0 whatever the size), inner nodes τ_far and more.
    let sizes: Vec<f32> = spheres
        .iter()
        .enumerate()
        .map(|(i, s)| if i < leaves.len() { 0.0 } else { tau_far + 2.0 * s.radius })
        .collect();
    let spt = flatten(&children, &sizes).expect("a synthetic hierarchy is a forest with finite sizes");
    let by_leaf = inputs_by_leaf(&spt.leaf_id, leaves.len());
    spt.order
        .iter()
        .map(|&node| {
            let (n, flat) = (node as usize, spt.nodes[node as usize]);
            let source = if n < leaves.len() {
                coarsest[n]
            } else {
                let first = coarsest[by_leaf[flat.leaf_first as usize]];
                let last = coarsest[by_leaf[(flat.leaf_first + flat.leaf_count - 1) as usize]];
                LineRecord { p1: last.p1, r1: last.r1, color: random_color(rng), ..first }
            };
            LineRecord {
                lo: flat.lo,
                hi: flat.hi,
                leaf_first: flat.leaf_first,
                leaf_count: flat.leaf_count,
                flags: 0,
                ..source
            }
        })
        .collect()
}

/// The elevations of the build's tables per elevation (spec §6.16), degrees.
const ELEVATIONS: [f32; 4] = [0.0, 30.0, 60.0, 90.0];

/// Calibration tables per elevation (spec §6.16, §6.18): `calibration`'s pairs of technique and
/// height at `elevations`, each error the mean's times a random factor in `[0.5, 1.5]` clamped to
/// `[0, 1]`, the primitives the mean's (the same views' distance at each elevation).
fn calibration_elevations(
    rng: &mut SplitMix64,
    elevations: &[f32],
    calibration: &[CalibrationRecord],
) -> Vec<ElevationCalibrationRecord> {
    let mut records = Vec::new();
    for &elevation in elevations {
        for c in calibration {
            let error = (c.error * rng.uniform(0.5, 1.5)).clamp(0.0, 1.0);
            records.push(ElevationCalibrationRecord {
                elevation,
                technique: c.technique,
                height: c.height,
                error,
                primitives: c.primitives,
            });
        }
    }
    records
}

/// The LoD chain's per-level tables (spec §6.17): for each level every tree of `levels` has,
/// three samples whose heights grow strictly from a few pixels, whose errors fall within
/// `[0, 1]`, and whose primitive count is the level's triangles over every tree.
fn chain_calibration(rng: &mut SplitMix64, levels: &[LodLevelRecord]) -> Vec<ChainCalibrationRecord> {
    let mut trees: Vec<u32> = levels.iter().map(|l| l.tree).collect();
    trees.sort_unstable();
    trees.dedup();
    let depth = trees
        .iter()
        .map(|&t| levels.iter().filter(|l| l.tree == t).map(|l| l.level + 1).max().unwrap_or(0))
        .min()
        .unwrap_or(0);
    let mut records = Vec::new();
    for level in 0..depth {
        #[expect(clippy::cast_precision_loss, reason = "a few triangles")]
        let primitives = levels.iter().filter(|l| l.level == level).map(|l| l.triangles.count).sum::<u32>() as f32;
        let mut height = rng.uniform(4.0, 16.0);
        let mut error = rng.uniform(0.05, 1.0);
        for _ in 0..3 {
            records.push(ChainCalibrationRecord { level, height, error, primitives });
            height *= rng.uniform(1.5, 3.0);
            error *= rng.uniform(0.2, 0.9);
        }
    }
    records
}

/// Calibration tables (spec §6.15, §6.18) of the codes `techniques`: the first (`FULL` for
/// `CALIBRATION`) and each other with probability ½, in ascending order, each with three or four
/// samples whose heights grow strictly from a few pixels, whose errors fall within `[0, 1]` and
/// whose primitive counts are whole numbers.
fn calibration(rng: &mut SplitMix64, techniques: core::ops::Range<u32>) -> Vec<CalibrationRecord> {
    let mut records = Vec::new();
    let first = techniques.start;
    for technique in techniques {
        if technique != first && !rng.chance(0.5) {
            continue;
        }
        let mut height = rng.uniform(4.0, 16.0);
        let mut error = rng.uniform(0.05, 1.0);
        let primitives = rng.uniform(1.0, 4096.0).round();
        for _ in 0..3 + rng.below(2) {
            records.push(CalibrationRecord { technique, height, error, primitives });
            height *= rng.uniform(1.5, 3.0);
            error *= rng.uniform(0.2, 0.9);
        }
    }
    records
}

/// Per leaf id of a flattened hierarchy, the input node that is that leaf (`leaf_id`: per input
/// node, its leaf id if it is a leaf), for `leaves` leaves.
fn inputs_by_leaf(leaf_id: &[Option<u32>], leaves: usize) -> Vec<usize> {
    let mut by_leaf = vec![0; leaves];
    for (input, id) in leaf_id.iter().enumerate() {
        if let Some(id) = id {
            by_leaf[*id as usize] = input;
        }
    }
    by_leaf
}
