//! Pruning, the build side (Neubert, Pirk, Deussen and Dachsbacher 2011; spec §6.11): the leaves
//! of a block, a priority list of them, the optimal scale `s_opt(λ)` of the survivors and the
//! fraction `λ(h)` to draw at each projected height.
//!
//! - **Leaves** ([`find_leaves`]): a leaf is a connected set of leaf-class triangles of one part,
//!   connected through shared vertex indices. A leaf card showing a twig with many botanical
//!   leaves (Sapling's and ez-tree's cards, an atlas quad) is one leaf: it is pruned and scaled
//!   whole, as the artist made it. A closed low-poly canopy blob is one leaf too; pruning it is
//!   pruning the canopy, so its quality drops fast and the measured curves account for that.
//! - **Priority orders** ([`priority_order`], §3 of the paper), most important first:
//!   stochastic (Cook et al. 2007: a seeded shuffle); density (the metaball field of the leaf
//!   centres thinned greedily, densest leaf first, until no leaf is denser than the median, then
//!   stochastic); orientation (leaves facing along the outward normal of the field's tight hull
//!   first); combined (`P_sil² + P_density`, plus a little noise).
//! - **Quality** ([`Scorer`]): pixel coverage of the pruned and scaled leaves plus the whole bark
//!   against the full model, on the CPU rasteriser ([`crate::raster`]), averaged over views:
//!   Precision `P`, Recall `R` and `Q = 1 − ‖(1 − P, 1 − R)‖` (the paper's eqs. 1 and 4).
//! - **`s_opt(λ)`** ([`scale_curve`]): at each λ of [`LAMBDAS`], the scale `s ≥ 1` that minimises
//!   `(1 − P)² + (1 − R)²` (eq. 3). `s` is a factor on each survivor's *area*, as in the paper and
//!   in Cook's `s = 1/λ`: the runtime scales distances from the leaf centre by `√s`.
//! - **`λ(h)`** ([`lambda_curve`]): at each of the paper's normalised distances, mapped to a
//!   projected height, the smallest `λ` whose `Q` with `s_opt` reaches both Cook's quality there
//!   and the minimum quality.
//!
//! Everything is deterministic: fixed seeds, stable sorts, sums in a fixed order, and rayon only
//! where each result is computed alone and collected in order (leaves' densities, views).

use std::cmp::{Ordering, Reverse};
use std::collections::{BinaryHeap, HashMap};

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use treelod_format::{CurveSample, Setting, VertexRecord};

use crate::error::BuildError;
use treelod_eval::metrics::quality;

use crate::raster::{AlphaMask, Mask, RasterTriangle, View, coverage, fill_triangle, rasterize};
use crate::rng::SplitMix64;

/// The λ at which `s_opt` is sampled (`PRUNE_SCALE`'s `x`): steps of 0.05 up to 0.4, of 0.1 above
/// (Neubert et al. Fig. 7).
pub const LAMBDAS: [f32; 14] = [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0];

/// Influence radius of a metaball generator, as a fraction of the plant's height (the paper: 5 %).
pub const FIELD_RADIUS: f32 = 0.05;

/// Amplitude of the noise added to the orientation and combined survival probabilities (in
/// `[0, 1]`), so that leaves of equal score are not drawn in a spatially correlated order.
pub const ORDER_NOISE: f32 = 0.05;

/// Width of the final bracket of the `s_opt` search, in `ln s`: `s` to about ±4 %.
pub const SCALE_TOLERANCE: f32 = 0.08;

/// Projected block height, pixels, of normalised distance 0 in `λ(h)`: a tree about as tall as the
/// screen.
pub const NEAR_PIXELS: f32 = 1024.0;

/// Projected block height, pixels, of normalised distance 1 in `λ(h)`.
pub const FAR_PIXELS: f32 = 32.0;

/// The leaves' priority order (Neubert et al. §3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PruneOrder {
    /// A seeded shuffle (Cook et al. 2007).
    Stochastic,
    /// Dense regions pruned first until the density has evened out, then stochastic (§3.1.1).
    #[default]
    Density,
    /// Leaves facing away from the field's outward normal pruned first (§3.2).
    Orientation,
    /// `P_sil² + P_density`, normalised, plus a little randomness (§3.3).
    Combined,
}

impl PruneOrder {
    /// Every order, in the order of the paper.
    pub const ALL: [Self; 4] = [Self::Stochastic, Self::Density, Self::Orientation, Self::Combined];

    /// The spelling of the `prune.order` setting and of the command line.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Stochastic => "stochastic",
            Self::Density => "density",
            Self::Orientation => "orientation",
            Self::Combined => "combined",
        }
    }

    /// The order spelled `name` ([`Self::as_str`]).
    #[must_use]
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.as_str() == name)
    }
}

/// Pruning tunables (recorded in the container's settings as `prune.*`, spec §7.1).
#[derive(Clone, Debug, PartialEq)]
pub struct PruneConfig {
    /// The priority order. Default [`PruneOrder::Density`]: at equal quality (`Q ≥ 0.9`) it
    /// saved the most leaf geometry on six of the seven shared models (`treelod build
    /// --prune-report`); `orientation` and `combined` scored better only at the smallest λ on
    /// some of them (distant trees, as the paper found for its silhouette order).
    pub order: PruneOrder,
    /// Minimum quality `Q` that `λ(h)` keeps, in `[0, 1]`: at each distance `λ(h)` reaches the
    /// quality of Cook's pruning there (the paper's rule), and never less than this. Default 0.9
    /// (the paper fixes no number; 0 follows Cook's quality at every distance).
    pub min_quality: f32,
    /// Side of the square images `s_opt` is measured on, pixels, `16 ..= 4096`; the block's
    /// bounding sphere spans the image. Default 256.
    pub resolution: u32,
    /// View directions measured ([`crate::raster::view_directions`]), `1 ..= 64`. Default 8
    /// (6 around the tree over half a turn, 2 from 45° above).
    pub views: u32,
    /// Seed of the stochastic parts of the orders. Default 1.
    pub seed: u64,
}

impl Default for PruneConfig {
    fn default() -> Self {
        Self { order: PruneOrder::Density, min_quality: 0.9, resolution: 256, views: 8, seed: 1 }
    }
}

impl PruneConfig {
    /// Checks the ranges documented on the fields.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the field.
    pub fn validate(&self) -> Result<(), BuildError> {
        if !(0.0..=1.0).contains(&self.min_quality) {
            return Err(BuildError::Setting(format!("prune min quality {}: must be in [0, 1]", self.min_quality)));
        }
        if !(16..=4096).contains(&self.resolution) {
            return Err(BuildError::Setting(format!("prune resolution {}: must be in 16..=4096", self.resolution)));
        }
        if !(1..=64).contains(&self.views) {
            return Err(BuildError::Setting(format!("prune views {}: must be in 1..=64", self.views)));
        }
        Ok(())
    }

    /// The `prune.*` settings (spec §7.1), sorted by key.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        let setting = |key: &str, value: String| Setting { key: format!("prune.{key}"), value };
        vec![
            setting("min_quality", self.min_quality.to_string()),
            setting("order", self.order.as_str().to_owned()),
            setting("resolution", self.resolution.to_string()),
            setting("seed", self.seed.to_string()),
            setting("views", self.views.to_string()),
        ]
    }
}

/// A triangle of the mesh pruning sees: vertex ids and the index of its alpha test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshTriangle {
    /// Indices into the mesh's vertices.
    pub v: [u32; 3],
    /// Index into the mesh's alpha masks, or [`crate::raster::NO_ALPHA`].
    pub alpha: u32,
}

/// A block's triangles as pruning sees them.
///
/// Every vertex index must be in range of `vertices` (the build checks this when it gathers
/// triangles); functions taking a mesh panic otherwise.
#[derive(Clone, Copy, Debug)]
pub struct PruneMesh<'a> {
    /// Vertices (position and UV are read), metres, block space.
    pub vertices: &'a [VertexRecord],
    /// Leaf-class triangles: pruned.
    pub leaves: &'a [MeshTriangle],
    /// Every other triangle: drawn whole in every image.
    pub bark: &'a [MeshTriangle],
    /// Alpha tests referenced by the triangles.
    pub alphas: &'a [AlphaMask],
}

impl PruneMesh<'_> {
    fn position(&self, v: u32) -> Vec3 {
        Vec3::from_array(self.vertices[v as usize].position)
    }

    fn raster(&self, t: &MeshTriangle) -> RasterTriangle {
        RasterTriangle {
            positions: t.v.map(|v| self.position(v)),
            uvs: t.v.map(|v| Vec2::from_array(self.vertices[v as usize].uv)),
            alpha: t.alpha,
        }
    }
}

/// One leaf: a run of [`Leaves::triangles`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Leaf {
    /// First entry in [`Leaves::triangles`].
    pub first: u32,
    /// Number of triangles, `≥ 1`.
    pub count: u32,
    /// Area-weighted centroid of its triangles: the pivot of its scaling, metres.
    pub centre: Vec3,
    /// One-sided area, m².
    pub area: f32,
    /// Unit area-weighted normal.
    pub normal: Vec3,
}

/// The leaves of a mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Leaves {
    /// In order of their first triangle.
    pub leaves: Vec<Leaf>,
    /// Indices into the mesh's leaf triangles, leaf by leaf, in mesh order within a leaf.
    pub triangles: Vec<u32>,
}

impl Leaves {
    /// The mesh triangle indices of `leaf`.
    #[must_use]
    pub fn triangles_of(&self, leaf: &Leaf) -> &[u32] {
        &self.triangles[leaf.first as usize..(leaf.first + leaf.count) as usize]
    }
}

/// Splits the leaf triangles of `mesh` into leaves: connected components through shared vertex
/// indices (see the module documentation), numbered in order of their first triangle.
///
/// # Panics
/// If a vertex index is out of range of `mesh.vertices`.
#[must_use]
pub fn find_leaves(mesh: &PruneMesh<'_>) -> Leaves {
    // Union-find over vertex ids; the smaller id becomes the root, so the result is canonical.
    let mut parent: Vec<u32> = (0..mesh.vertices.len() as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            let up = parent[parent[v as usize] as usize];
            parent[v as usize] = up;
            v = up;
        }
        v
    }
    for t in mesh.leaves {
        let a = root(&mut parent, t.v[0]);
        for &v in &t.v[1..] {
            let (ra, rb) = (root(&mut parent, a), root(&mut parent, v));
            let (lo, hi) = (ra.min(rb), ra.max(rb));
            parent[hi as usize] = lo;
        }
    }
    // Leaf ids in order of first triangle; then a counting sort keeps mesh order within a leaf.
    let mut leaf_of_root = vec![u32::MAX; mesh.vertices.len()];
    let mut leaf_of_triangle = Vec::with_capacity(mesh.leaves.len());
    let mut counts: Vec<u32> = Vec::new();
    for t in mesh.leaves {
        let r = root(&mut parent, t.v[0]) as usize;
        if leaf_of_root[r] == u32::MAX {
            leaf_of_root[r] = counts.len() as u32;
            counts.push(0);
        }
        counts[leaf_of_root[r] as usize] += 1;
        leaf_of_triangle.push(leaf_of_root[r]);
    }
    let mut next: Vec<u32> = counts
        .iter()
        .scan(0u32, |acc, &c| {
            let first = *acc;
            *acc += c;
            Some(first)
        })
        .collect();
    let firsts = next.clone();
    let mut triangles = vec![0u32; mesh.leaves.len()];
    for (i, &leaf) in leaf_of_triangle.iter().enumerate() {
        triangles[next[leaf as usize] as usize] = i as u32;
        next[leaf as usize] += 1;
    }
    let leaves = firsts
        .iter()
        .zip(&counts)
        .map(|(&first, &count)| {
            let (mut weighted, mut area, mut normal, mut mean) = (glam::DVec3::ZERO, 0.0f64, Vec3::ZERO, Vec3::ZERO);
            for &t in &triangles[first as usize..(first + count) as usize] {
                let [a, b, c] = mesh.leaves[t as usize].v.map(|v| mesh.position(v));
                let cross = (b - a).cross(c - a);
                let half = 0.5 * f64::from(cross.length());
                let centroid = (a + b + c) / 3.0;
                weighted += centroid.as_dvec3() * half;
                area += half;
                normal += cross;
                mean += centroid;
            }
            let centre = if area > 0.0 { (weighted / area).as_vec3() } else { mean / count as f32 };
            Leaf { first, count, centre, area: area as f32, normal: normal.normalize_or(Vec3::Y) }
        })
        .collect();
    Leaves { leaves, triangles }
}

pub use treelod_format::prune_leaves_drawn as leaves_drawn;

// ---------------------------------------------------------------------------------------------
// The metaball field (Neubert et al. §3.1, after Blinn 1982).

/// Leaf centres bucketed into cubes of the influence radius: a point's neighbours lie in the 27
/// cubes around it, so the field costs `O(n·k)` for `k` neighbours per leaf.
struct SpatialHash {
    inverse: f32,
    cubes: HashMap<[i32; 3], Vec<u32>>,
}

impl SpatialHash {
    fn new(points: &[Vec3], radius: f32) -> Self {
        let inverse = 1.0 / radius;
        let mut cubes: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (i, &p) in points.iter().enumerate() {
            cubes.entry(Self::key(p, inverse)).or_default().push(i as u32);
        }
        Self { inverse, cubes }
    }

    #[expect(clippy::cast_possible_truncation, reason = "saturating; far-out points share a cube")]
    fn key(p: Vec3, inverse: f32) -> [i32; 3] {
        (p * inverse).floor().to_array().map(|v| v as i32)
    }

    /// Calls `f` with every point in the 27 cubes around `p`, in a fixed order (cubes by offset,
    /// points by index), so sums over them are the same on every run.
    fn around(&self, p: Vec3, mut f: impl FnMut(u32)) {
        let [x, y, z] = Self::key(p, self.inverse);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let key = [x.saturating_add(dx), y.saturating_add(dy), z.saturating_add(dz)];
                    for &i in self.cubes.get(&key).map_or(&[][..], Vec::as_slice) {
                        f(i);
                    }
                }
            }
        }
    }
}

/// One generator's contribution `D_i(q) = (1 − ‖q − p_i‖²/r²)²` (eq. 5) at squared distance `d2`.
fn contribution(d2: f32, r2: f32) -> f64 {
    if d2 >= r2 {
        return 0.0;
    }
    let t = 1.0 - f64::from(d2) / f64::from(r2);
    t * t
}

/// The density `F(p_j) = Σ_i D_i(p_j)` at each leaf centre (the leaf itself included).
fn densities(centres: &[Vec3], hash: &SpatialHash, radius: f32) -> Vec<f64> {
    let r2 = radius * radius;
    centres
        .par_iter()
        .map(|&p| {
            let mut density = 0.0f64;
            hash.around(p, |i| density += contribution((p - centres[i as usize]).length_squared(), r2));
            density
        })
        .collect()
}

/// Largest voxel count of the distance transform in [`hull_normals`] (16 MiB of `f32`); coarser
/// voxels beyond.
const MAX_HULL_VOXELS: usize = 1 << 22;

/// The outward normal of the tight hull (the iso-surface `F = 0`, Neubert et al. §3.1: the
/// boundary of the union of the generators' balls of radius `radius`) at the point nearest to each
/// leaf centre: the direction in which the Euclidean distance to the outside of the union falls
/// fastest. The union is voxelised at `radius / 2` (coarser for huge blocks), the distance to
/// the nearest empty voxel computed exactly on that grid (Felzenszwalb and Huttenlocher's
/// transform, separable over the three axes), and its gradient taken by central differences of
/// the trilinearly interpolated distance, a voxel either side of the leaf centre. A leaf where
/// that gradient vanishes (the exact middle of a symmetric crown)
/// gets the zero vector.
///
/// The field's own gradient at a leaf is no substitute: where the leaves form a thin shell (leaves
/// at the branch tips of a crown) it points along the shell, away from the nearest neighbours,
/// not out of the crown.
fn hull_normals(centres: &[Vec3], radius: f32) -> Vec<Vec3> {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for &c in centres {
        lo = lo.min(c);
        hi = hi.max(c);
    }
    // Two empty voxels beyond the balls on every side, so the outside is reached.
    let mut voxel = 0.5 * radius;
    let dims = loop {
        let d = ((hi - lo + 2.0 * radius) / voxel).ceil() + 4.0;
        #[expect(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "finite and positive, checked below"
        )]
        let d = d.to_array().map(|v| if v.is_finite() { v.clamp(1.0, 1e7) as usize } else { 1 });
        if d[0] * d[1] * d[2] <= MAX_HULL_VOXELS {
            break d;
        }
        voxel *= 1.5;
    };
    let origin = lo - Vec3::splat(radius + 2.0 * voxel);
    let index = |x: usize, y: usize, z: usize| x + dims[0] * (y + dims[1] * z);
    let cell = |p: Vec3| {
        let g = ((p - origin) / voxel).floor();
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "inside the grid by construction")]
        let g = g.to_array().map(|v| v.max(0.0) as usize);
        [g[0].min(dims[0] - 1), g[1].min(dims[1] - 1), g[2].min(dims[2] - 1)]
    };
    // Occupied (inside the union of balls): voxel centres within `radius` of a generator.
    const FAR: f32 = 1e20;
    let mut d2 = vec![0.0f32; dims[0] * dims[1] * dims[2]];
    let reach = (radius / voxel).ceil() as usize + 1;
    for &c in centres {
        let g = cell(c);
        for z in g[2].saturating_sub(reach)..(g[2] + reach + 1).min(dims[2]) {
            for y in g[1].saturating_sub(reach)..(g[1] + reach + 1).min(dims[1]) {
                for x in g[0].saturating_sub(reach)..(g[0] + reach + 1).min(dims[0]) {
                    let centre = origin + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * voxel;
                    if centre.distance_squared(c) < radius * radius {
                        d2[index(x, y, z)] = FAR;
                    }
                }
            }
        }
    }
    // Squared distance (in voxels) to the nearest empty voxel, one axis at a time.
    let mut line = Vec::new();
    let mut out = Vec::new();
    for axis in 0..3 {
        let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
        for j in 0..dims[b] {
            for i in 0..dims[a] {
                let at = |t: usize| {
                    let mut g = [0; 3];
                    g[axis] = t;
                    g[a] = i;
                    g[b] = j;
                    index(g[0], g[1], g[2])
                };
                line.clear();
                line.extend((0..dims[axis]).map(|t| d2[at(t)]));
                distance_transform_1d(&line, &mut out);
                for (t, &v) in out.iter().enumerate() {
                    d2[at(t)] = v;
                }
            }
        }
    }
    let distance = |x: usize, y: usize, z: usize| d2[index(x, y, z)].sqrt();
    // The distance at any point, trilinear between voxel centres (clamped to the grid).
    let at = |p: Vec3| {
        let g = ((p - origin) / voxel - 0.5).max(Vec3::ZERO);
        let f = g.fract();
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "non-negative, clamped below")]
        let [x, y, z] = g.floor().to_array().map(|v| v as usize);
        let clamp = |v: usize, d: usize| v.min(d - 1);
        let (x0, x1, y0, y1, z0, z1) = (
            clamp(x, dims[0]),
            clamp(x + 1, dims[0]),
            clamp(y, dims[1]),
            clamp(y + 1, dims[1]),
            clamp(z, dims[2]),
            clamp(z + 1, dims[2]),
        );
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let plane = |z: usize| {
            lerp(
                lerp(distance(x0, y0, z), distance(x1, y0, z), f.x),
                lerp(distance(x0, y1, z), distance(x1, y1, z), f.x),
                f.y,
            )
        };
        lerp(plane(z0), plane(z1), f.z)
    };
    centres
        .iter()
        .map(|&c| {
            let h = voxel;
            let gradient = Vec3::new(
                at(c + Vec3::X * h) - at(c - Vec3::X * h),
                at(c + Vec3::Y * h) - at(c - Vec3::Y * h),
                at(c + Vec3::Z * h) - at(c - Vec3::Z * h),
            );
            // The distance to the outside falls towards the nearest hull point.
            (-gradient).normalize_or_zero()
        })
        .collect()
}

/// The 1-D squared distance transform of `f` (Felzenszwalb and Huttenlocher 2012): `out[q] =
/// min_p (q − p)² + f[p]`, by the lower envelope of the parabolas rooted at each `p`.
fn distance_transform_1d(f: &[f32], out: &mut Vec<f32>) {
    let n = f.len();
    out.clear();
    out.resize(n, 0.0);
    let mut roots: Vec<usize> = Vec::with_capacity(n);
    let mut bounds: Vec<f32> = Vec::with_capacity(n + 1);
    let intersection = |p: usize, q: usize| {
        let (pf, qf) = (p as f32, q as f32);
        ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
    };
    for (q, &value) in f.iter().enumerate() {
        if value >= 1e19 {
            continue;
        }
        while let Some(&p) = roots.last() {
            if roots.len() > 1 && intersection(p, q) <= bounds[bounds.len() - 1] {
                roots.pop();
                bounds.pop();
            } else {
                break;
            }
        }
        if let Some(&p) = roots.last() {
            bounds.push(intersection(p, q));
        }
        roots.push(q);
    }
    if roots.is_empty() {
        out.fill(f32::MAX);
        return;
    }
    let mut k = 0;
    for (q, slot) in out.iter_mut().enumerate() {
        while k < bounds.len() && bounds[k] < q as f32 {
            k += 1;
        }
        let p = roots[k];
        let d = q as f32 - p as f32;
        *slot = d * d + f[p];
    }
}

/// A seeded Fisher–Yates shuffle of `0..n`.
fn shuffled(n: usize, seed: u64) -> Vec<u32> {
    let mut order: Vec<u32> = (0..n as u32).collect();
    let mut rng = SplitMix64(seed);
    for i in (1..n).rev() {
        #[expect(clippy::cast_possible_truncation, reason = "below i + 1, an index")]
        let j = rng.below(i as u64 + 1) as usize;
        order.swap(i, j);
    }
    order
}

/// Density thinning (§3.1.1): the densest leaf is removed and its contribution subtracted from its
/// neighbours, again and again, until no leaf is denser than the median density of all leaves
/// (the density has evened out). Returns each leaf's survival probability — 1 for the leaves left,
/// `median / F` at removal for the others, so later removals score higher — and the priority
/// order: the leaves left in a seeded shuffle (pure stochastic from there on), then the removed
/// ones, last removed first.
fn density_thinning(
    centres: &[Vec3],
    hash: &SpatialHash,
    radius: f32,
    densities: &[f64],
    seed: u64,
) -> (Vec<f32>, Vec<u32>) {
    let n = centres.len();
    let mut density: Vec<f64> = densities.to_vec();
    let mut sorted = density.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(n.saturating_sub(1) / 2).copied().unwrap_or(1.0);
    // Max-heap of (density, smaller index first), one entry per leaf. Densities only fall, so an
    // entry's key is at least its leaf's density: an entry popped with a stale key goes back with
    // the current one, and one popped with a current key is the densest leaf.
    #[derive(PartialEq)]
    struct Entry(f64, Reverse<u32>);
    impl Eq for Entry {}
    impl PartialOrd for Entry {
        fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
            Some(self.cmp(other))
        }
    }
    impl Ord for Entry {
        fn cmp(&self, other: &Self) -> Ordering {
            self.0.total_cmp(&other.0).then(self.1.cmp(&other.1))
        }
    }
    let mut heap: BinaryHeap<Entry> = density.iter().enumerate().map(|(i, &d)| Entry(d, Reverse(i as u32))).collect();
    let mut survival = vec![1.0f32; n];
    let mut removed_order: Vec<u32> = Vec::new();
    let mut removed = vec![false; n];
    let r2 = radius * radius;
    while let Some(Entry(d, Reverse(i))) = heap.pop() {
        let iu = i as usize;
        if removed[iu] {
            continue;
        }
        if d.to_bits() != density[iu].to_bits() {
            heap.push(Entry(density[iu], Reverse(i)));
            continue;
        }
        if d <= median {
            break;
        }
        removed[iu] = true;
        removed_order.push(i);
        survival[iu] = (median / d) as f32;
        let p = centres[iu];
        hash.around(p, |k| {
            let ku = k as usize;
            if !removed[ku] {
                density[ku] -= contribution((centres[ku] - p).length_squared(), r2);
            }
        });
    }
    let kept: Vec<u32> = (0..n as u32).filter(|&i| !removed[i as usize]).collect();
    let mut order: Vec<u32> = shuffled(kept.len(), seed).into_iter().map(|k| kept[k as usize]).collect();
    order.extend(removed_order.iter().rev());
    (survival, order)
}

/// Orientation survival probability (§3.2): `|cos α|` between a leaf's normal and the tight
/// hull's outward normal nearest to it ([`hull_normals`]; leaves are seen from both sides),
/// normalised to `[0, 1]` over the leaves. A leaf without hull direction counts as facing out.
fn orientation_survival(leaves: &[Leaf], normals: &[Vec3]) -> Vec<f32> {
    let cos: Vec<f32> = leaves
        .iter()
        .zip(normals)
        .map(|(leaf, &n)| if n == Vec3::ZERO { 1.0 } else { leaf.normal.dot(n).abs().min(1.0) })
        .collect();
    let (lo, hi) = cos.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &c| (lo.min(c), hi.max(c)));
    cos.iter().map(|&c| if hi > lo { (c - lo) / (hi - lo) } else { 1.0 }).collect()
}

/// Leaf indices sorted by descending `score + ORDER_NOISE·u` (`u` uniform in `[0, 1)` from
/// `seed`), ties by index.
fn by_survival(scores: &[f32], seed: u64) -> Vec<u32> {
    let mut rng = SplitMix64(seed ^ 0x6E6F_6973_6500_0000);
    let keyed: Vec<f32> = scores.iter().map(|&s| s + ORDER_NOISE * rng.unit()).collect();
    let mut order: Vec<u32> = (0..scores.len() as u32).collect();
    order.sort_by(|&a, &b| keyed[b as usize].total_cmp(&keyed[a as usize]).then(a.cmp(&b)));
    order
}

/// The priority list of `leaves` (indices, most important first) in `order`, for a plant `height`
/// metres tall (the metaball radius is [`FIELD_RADIUS`] of it). Deterministic for a `seed`.
#[must_use]
pub fn priority_order(leaves: &[Leaf], order: PruneOrder, height: f32, seed: u64) -> Vec<u32> {
    if order == PruneOrder::Stochastic || leaves.is_empty() {
        return shuffled(leaves.len(), seed);
    }
    let radius = field_radius(leaves, height);
    let centres: Vec<Vec3> = leaves.iter().map(|l| l.centre).collect();
    let hash = SpatialHash::new(&centres, radius);
    match order {
        PruneOrder::Stochastic => shuffled(leaves.len(), seed),
        PruneOrder::Density => {
            let densities = densities(&centres, &hash, radius);
            density_thinning(&centres, &hash, radius, &densities, seed).1
        }
        PruneOrder::Orientation => by_survival(&orientation_survival(leaves, &hull_normals(&centres, radius)), seed),
        PruneOrder::Combined => {
            let densities = densities(&centres, &hash, radius);
            let (density, _) = density_thinning(&centres, &hash, radius, &densities, seed);
            let silhouette = orientation_survival(leaves, &hull_normals(&centres, radius));
            let combined: Vec<f32> = silhouette.iter().zip(&density).map(|(s, d)| 0.5 * (s * s + d)).collect();
            by_survival(&combined, seed)
        }
    }
}

/// [`FIELD_RADIUS`] of `height`; of the leaves' extent when the height is zero (a flat block).
fn field_radius(leaves: &[Leaf], height: f32) -> f32 {
    let r = FIELD_RADIUS * height;
    if r.is_finite() && r > 0.0 {
        return r;
    }
    let (lo, hi) = leaves.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), l| {
        (lo.min(l.centre), hi.max(l.centre))
    });
    let extent = (hi - lo).max_element();
    if extent.is_finite() && extent > 0.0 { FIELD_RADIUS * extent } else { 1.0 }
}

// ---------------------------------------------------------------------------------------------
// Quality of pruned and scaled images (§2).

/// Which leaves a fraction `λ` draws: per cell, a prefix of the cell's part of the priority list.
#[derive(Clone, Debug)]
pub struct Prefixes {
    /// Per leaf, its position in its cell's list.
    rank: Vec<u32>,
    /// Per leaf, the number of leaves in its cell.
    count: Vec<u32>,
}

impl Prefixes {
    /// The per-cell lists of `order` (leaf indices, most important first) with `cell_of[leaf]`.
    #[must_use]
    pub fn new(order: &[u32], cell_of: &[u32]) -> Self {
        let mut per_cell: HashMap<u32, u32> = HashMap::new();
        let mut rank = vec![0u32; cell_of.len()];
        for &leaf in order {
            let next = per_cell.entry(cell_of[leaf as usize]).or_insert(0);
            rank[leaf as usize] = *next;
            *next += 1;
        }
        let count = cell_of.iter().map(|c| per_cell.get(c).copied().unwrap_or(0)).collect();
        Self { rank, count }
    }

    /// The leaves drawn at `lambda`, ascending.
    #[must_use]
    pub fn drawn(&self, lambda: f32) -> Vec<u32> {
        (0..self.rank.len() as u32)
            .filter(|&l| self.rank[l as usize] < leaves_drawn(self.count[l as usize], lambda))
            .collect()
    }
}

/// Precision and recall averaged over views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Score {
    /// Mean precision.
    pub precision: f64,
    /// Mean recall.
    pub recall: f64,
}

impl Score {
    /// The paper's error `(1 − P)² + (1 − R)²` (eq. 3).
    #[must_use]
    pub fn error(&self) -> f64 {
        (1.0 - self.precision).powi(2) + (1.0 - self.recall).powi(2)
    }

    /// `Q = 1 − ‖(1 − P, 1 − R)‖` (eq. 4).
    #[must_use]
    pub fn quality(&self) -> f64 {
        quality(self.precision, self.recall)
    }
}

/// The reference images of a block at one resolution: per view, the bark alone and the full model.
pub struct Images {
    views: Vec<View>,
    bark: Vec<Mask>,
    reference: Vec<Mask>,
    /// Per view, the leaf triangles' corners in pixels, in leaf order: scaling a leaf about its
    /// centre commutes with the orthographic projection, so each evaluation only scales these.
    corners: Vec<Vec<[Vec2; 3]>>,
    /// Per view, the leaf centres in pixels.
    centres: Vec<Vec<Vec2>>,
}

impl Images {
    /// The views.
    #[must_use]
    pub fn views(&self) -> &[View] {
        &self.views
    }

    /// The full model's coverage per view.
    #[must_use]
    pub fn reference(&self) -> &[Mask] {
        &self.reference
    }
}

/// Draws pruned and scaled blocks and scores them against the full model.
pub struct Scorer<'a> {
    mesh: PruneMesh<'a>,
    leaves: &'a Leaves,
    bark: Vec<RasterTriangle>,
    /// Leaf triangles in leaf order (`Leaves::triangles`).
    leaf_triangles: Vec<RasterTriangle>,
    sphere: (Vec3, f32),
    directions: Vec<Vec3>,
}

impl<'a> Scorer<'a> {
    /// A scorer of `mesh` with its `leaves`, seen from `directions`; images are fitted to the
    /// bounding sphere of all triangles.
    #[must_use]
    pub fn new(mesh: PruneMesh<'a>, leaves: &'a Leaves, directions: Vec<Vec3>) -> Self {
        let bark: Vec<RasterTriangle> = mesh.bark.iter().map(|t| mesh.raster(t)).collect();
        let leaf_triangles: Vec<RasterTriangle> =
            leaves.triangles.iter().map(|&t| mesh.raster(&mesh.leaves[t as usize])).collect();
        let corners = || bark.iter().chain(&leaf_triangles).flat_map(|t| t.positions);
        let sphere = crate::raster::bounding_sphere(corners());
        Self { mesh, leaves, bark, leaf_triangles, sphere, directions }
    }

    /// The bounding sphere the views are fitted to: centre and radius, metres.
    #[must_use]
    pub fn sphere(&self) -> (Vec3, f32) {
        self.sphere
    }

    /// The reference images at `size × size` pixels.
    #[must_use]
    pub fn images(&self, size: u32) -> Images {
        let views: Vec<View> =
            self.directions.iter().map(|&d| View::fit(d, self.sphere.0, self.sphere.1, size)).collect();
        let per_view: Vec<_> = views
            .par_iter()
            .map(|view| {
                let mut bark = Mask::new(view.size);
                rasterize(&mut bark, view, &self.bark, self.mesh.alphas);
                let mut full = bark.clone();
                rasterize(&mut full, view, &self.leaf_triangles, self.mesh.alphas);
                let corners: Vec<[Vec2; 3]> =
                    self.leaf_triangles.iter().map(|t| t.positions.map(|p| view.project(p))).collect();
                let centres: Vec<Vec2> = self.leaves.leaves.iter().map(|l| view.project(l.centre)).collect();
                (bark, full, corners, centres)
            })
            .collect();
        let mut images =
            Images { views, bark: Vec::new(), reference: Vec::new(), corners: Vec::new(), centres: Vec::new() };
        for (bark, full, corners, centres) in per_view {
            images.bark.push(bark);
            images.reference.push(full);
            images.corners.push(corners);
            images.centres.push(centres);
        }
        images
    }

    /// Precision and recall, averaged over the views of `images`, of the bark plus the leaves
    /// `drawn` (indices into the leaves) with their areas scaled by `scale` about their centres.
    #[must_use]
    pub fn score(&self, images: &Images, drawn: &[u32], scale: f32) -> Score {
        let k = scale.max(0.0).sqrt();
        let per_view: Vec<(f64, f64)> = (0..images.views.len())
            .into_par_iter()
            .map(|v| {
                let (corners, centres) = (&images.corners[v], &images.centres[v]);
                let mut mask = images.bark[v].clone();
                for &l in drawn {
                    let leaf = &self.leaves.leaves[l as usize];
                    let c = centres[l as usize];
                    let range = leaf.first as usize..(leaf.first + leaf.count) as usize;
                    for (t, p) in self.leaf_triangles[range.clone()].iter().zip(&corners[range]) {
                        let p = p.map(|q| c + (q - c) * k);
                        fill_triangle(&mut mask, p, t.uvs, self.mesh.alphas.get(t.alpha as usize));
                    }
                }
                coverage(&mask, &images.reference[v]).precision_recall()
            })
            .collect();
        let n = per_view.len().max(1) as f64;
        let (p, r) = per_view.iter().fold((0.0, 0.0), |(p, r), v| (p + v.0, r + v.1));
        Score { precision: p / n, recall: r / n }
    }
}

/// `s_opt` at `lambda` and its score: the `s ≥ 1` minimising `(1 − P)² + (1 − R)²` of the
/// leaves `drawn`. A golden-section search over `ln s ∈ [0, ln(3/λ)]` (three times Cook's
/// `1/λ`) down to a bracket of [`SCALE_TOLERANCE`], plus `s = 1` itself; the best point
/// evaluated wins (ties to the smaller `s`). 7 to 10 evaluations.
#[must_use]
pub fn optimal_scale(scorer: &Scorer<'_>, images: &Images, drawn: &[u32], lambda: f32) -> (f32, Score) {
    let mut best: Option<(f32, Score)> = None;
    let mut eval = |u: f32| {
        let s = u.exp();
        let score = scorer.score(images, drawn, s);
        let better = best
            .is_none_or(|(bs, b)| score.error() < b.error() || (score.error().total_cmp(&b.error()).is_eq() && s < bs));
        if better {
            best = Some((s, score));
        }
        score.error()
    };
    eval(0.0);
    let (mut lo, mut hi) = (0.0f32, (3.0 / lambda.clamp(0.01, 1.0)).ln());
    let phi = 0.5 * (5f32.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
    let (mut f1, mut f2) = (eval(x1), eval(x2));
    while hi - lo > SCALE_TOLERANCE {
        if f1 <= f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - phi * (hi - lo);
            f1 = eval(x1);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + phi * (hi - lo);
            f2 = eval(x2);
        }
    }
    best.unwrap_or((1.0, Score { precision: 1.0, recall: 1.0 }))
}

/// `s_opt(λ)` at every λ of [`LAMBDAS`] (`s = 1` at λ = 1, where nothing is pruned), with the
/// score it reaches.
#[must_use]
pub fn scale_curve(scorer: &Scorer<'_>, images: &Images, prefixes: &Prefixes) -> Vec<(f32, f32, Score)> {
    LAMBDAS
        .iter()
        .map(|&lambda| {
            if lambda >= 1.0 {
                return (lambda, 1.0, Score { precision: 1.0, recall: 1.0 });
            }
            let (s, score) = optimal_scale(scorer, images, &prefixes.drawn(lambda), lambda);
            (lambda, s, score)
        })
        .collect()
}

/// The projected block heights, pixels, at which `λ(h)` is sampled, ascending, with their
/// normalised distances: the paper's 10 distances in `[0, 0.1)` and 10 in `[0.1, 1]`, mapped by
/// perspective, `h(d) = NEAR / (1 + d·(NEAR/FAR − 1))`, so `d = 0` is [`NEAR_PIXELS`] and `d = 1`
/// [`FAR_PIXELS`] (1024 to 32 pixels: 10 samples above about 280 pixels, 10 below).
#[must_use]
pub fn lambda_heights() -> Vec<(f32, f32)> {
    let distances = (0..10).map(|i| i as f32 / 100.0).chain((1..=10).map(|i| i as f32 / 10.0));
    let mut h: Vec<(f32, f32)> =
        distances.map(|d| (NEAR_PIXELS / (1.0 + d * (NEAR_PIXELS / FAR_PIXELS - 1.0)), d)).collect();
    h.reverse();
    h
}

/// `values` (one per λ of [`LAMBDAS`]) at `lambda`, linearly interpolated, clamped outside.
fn at_lambda(values: &[f64], lambda: f32) -> f64 {
    let i = LAMBDAS.partition_point(|&l| l < lambda);
    match (i.checked_sub(1).and_then(|a| values.get(a)), values.get(i)) {
        (Some(&a), Some(&b)) => {
            let t = f64::from((lambda - LAMBDAS[i - 1]) / (LAMBDAS[i] - LAMBDAS[i - 1]));
            a + t * (b - a)
        }
        (None, Some(&b)) => b,
        (Some(&a), None) => a,
        (None, None) => 1.0,
    }
}

/// The smallest λ (interpolated linearly in `Q` between the samples of [`LAMBDAS`]) with
/// `quality[i] ≥ target`, where `quality` holds one value per sample; 1 if none reaches it.
#[must_use]
pub fn lambda_reaching(quality: &[f64], target: f64) -> f32 {
    let Some(i) = quality.iter().position(|&q| q >= target) else { return 1.0 };
    if i == 0 {
        return LAMBDAS[0];
    }
    let (qa, qb) = (quality[i - 1], quality[i]);
    #[expect(clippy::cast_possible_truncation, reason = "a fraction in [0, 1]")]
    let t = if qb > qa { ((target - qa) / (qb - qa)).clamp(0.0, 1.0) as f32 } else { 1.0 };
    LAMBDAS[i - 1] + t * (LAMBDAS[i] - LAMBDAS[i - 1])
}

/// `λ(h)` (spec §6.11: `x` the block's projected height in pixels, strictly increasing), by
/// Neubert et al.'s rule (§2.5): at normalised distance `d`, Cook et al. draw
/// `λ_Cook = (1 − d)²` leaves scaled by `1/λ`, which reaches the quality `cook` (one value per λ
/// of [`LAMBDAS`], interpolated); the table holds the smallest λ whose quality with `s_opt`
/// (`quality`, per λ) reaches that too, and at least `min_quality`: Cook's quality with less
/// geometry, never below the minimum. Heights and distances as [`lambda_heights`]; λ never
/// decreases towards the camera.
///
/// Quality is measured at one image size: Precision and Recall hardly depend on the size a tree
/// is drawn at (the paper, §2.4; on the shared models `Q` differs by less than 0.01 between trees
/// 32 and 1024 pixels high), so the height enters through the distance alone.
#[must_use]
pub fn lambda_curve(quality: &[f64], cook: &[f64], min_quality: f32) -> Vec<CurveSample> {
    let mut previous = 0.0f32;
    lambda_heights()
        .into_iter()
        .map(|(pixels, d)| {
            let target = at_lambda(cook, (1.0 - d) * (1.0 - d)).max(f64::from(min_quality));
            previous = previous.max(lambda_reaching(quality, target));
            CurveSample { x: pixels, y: previous }
        })
        .collect()
}

/// `Q` of Cook et al.'s stochastic pruning at each λ of [`LAMBDAS`]: the leaves of `prefixes`
/// (a seeded shuffle) scaled by `s = 1/λ`.
#[must_use]
pub fn cook_quality(scorer: &Scorer<'_>, images: &Images, prefixes: &Prefixes) -> Vec<f64> {
    LAMBDAS
        .iter()
        .map(
            |&lambda| {
                if lambda >= 1.0 { 1.0 } else { scorer.score(images, &prefixes.drawn(lambda), 1.0 / lambda).quality() }
            },
        )
        .collect()
}

/// What pruning adds to a block.
#[derive(Clone, Debug, PartialEq)]
pub struct Pruned {
    /// The leaves.
    pub leaves: Leaves,
    /// Leaf indices, most important first.
    pub order: Vec<u32>,
    /// `PRUNE_SCALE`: `s_opt(λ)`.
    pub scale: Vec<CurveSample>,
    /// `PRUNE_LAMBDA`: `λ(h)`.
    pub lambda: Vec<CurveSample>,
}

/// The pruning of `mesh`: leaves, priority list, `s_opt(λ)` and `λ(h)`. `cell_of` gives the cell
/// of a leaf centre (the per-cell prefixes of spec §6.11); `height` is the block's height, metres
/// (the metaball radius).
///
/// # Errors
/// [`BuildError::Setting`] for a configuration out of range.
pub fn prune(
    mesh: PruneMesh<'_>,
    cell_of: impl Fn(Vec3) -> u32,
    height: f32,
    config: &PruneConfig,
) -> Result<Pruned, BuildError> {
    config.validate()?;
    let leaves = find_leaves(&mesh);
    let order = priority_order(&leaves.leaves, config.order, height, config.seed);
    let cells: Vec<u32> = leaves.leaves.iter().map(|l| cell_of(l.centre)).collect();
    let prefixes = Prefixes::new(&order, &cells);
    let scorer = Scorer::new(mesh, &leaves, crate::raster::view_directions(config.views as usize));
    let images = scorer.images(config.resolution);
    let scales = scale_curve(&scorer, &images, &prefixes);
    // Cook's baseline is the stochastic order, the same shuffle as `PruneOrder::Stochastic`.
    let stochastic = match config.order {
        PruneOrder::Stochastic => prefixes,
        _ => Prefixes::new(&shuffled(leaves.leaves.len(), config.seed), &cells),
    };
    let cook = cook_quality(&scorer, &images, &stochastic);
    drop((images, scorer));
    let quality: Vec<f64> = scales.iter().map(|s| s.2.quality()).collect();
    let lambda = lambda_curve(&quality, &cook, config.min_quality);
    let scale = scales.iter().map(|&(x, y, _)| CurveSample { x, y }).collect();
    Ok(Pruned { leaves, order, scale, lambda })
}

/// One priority order in a [`PruneReport`].
#[derive(Clone, Debug, PartialEq)]
pub struct OrderReport {
    /// The order.
    pub order: PruneOrder,
    /// `s_opt` at each λ of [`LAMBDAS`].
    pub scale: Vec<f32>,
    /// `Q` with `s_opt` at each λ.
    pub quality: Vec<f64>,
    /// The smallest λ with `Q ≥` the minimum quality (interpolated between samples).
    pub lambda: f32,
    /// `λ(h)` of this order ([`lambda_curve`]).
    pub lambda_curve: Vec<CurveSample>,
}

/// The orders compared at one image size (`treelod build --prune-report`): the issue's "geometry
/// saved at equal Q" against Cook et al.'s stochastic order with `s = 1/λ`.
#[derive(Clone, Debug, PartialEq)]
pub struct PruneReport {
    /// Leaves found.
    pub leaves: usize,
    /// Image side, pixels.
    pub resolution: u32,
    /// The block's projected height in the horizontal views, pixels.
    pub pixel_height: f32,
    /// The quality compared at.
    pub min_quality: f32,
    /// `Q` of the stochastic order with `s_Cook = 1/λ` at each λ of [`LAMBDAS`].
    pub cook_quality: Vec<f64>,
    /// The smallest λ reaching the quality that way.
    pub cook_lambda: f32,
    /// Each order with `s_opt`, in [`PruneOrder::ALL`] order.
    pub orders: Vec<OrderReport>,
}

/// Compares every priority order with `s_opt` against Cook's stochastic pruning with `1/λ` on the
/// images of `config` (its order is ignored): per order the `s_opt(λ)` curve, `Q` along it, the
/// λ needed for `config.min_quality` and `λ(h)`.
///
/// # Errors
/// [`BuildError::Setting`] for a configuration out of range.
pub fn compare(
    mesh: PruneMesh<'_>,
    cell_of: impl Fn(Vec3) -> u32,
    height: f32,
    config: &PruneConfig,
) -> Result<PruneReport, BuildError> {
    config.validate()?;
    let leaves = find_leaves(&mesh);
    let cells: Vec<u32> = leaves.leaves.iter().map(|l| cell_of(l.centre)).collect();
    let scorer = Scorer::new(mesh, &leaves, crate::raster::view_directions(config.views as usize));
    let images = scorer.images(config.resolution);
    let min = f64::from(config.min_quality);
    let mut cook = Vec::new();
    let mut orders = Vec::new();
    for order in PruneOrder::ALL {
        // Stochastic comes first: Cook's baseline is its shuffle.
        let prefixes = Prefixes::new(&priority_order(&leaves.leaves, order, height, config.seed), &cells);
        if order == PruneOrder::Stochastic {
            cook = cook_quality(&scorer, &images, &prefixes);
        }
        let scales = scale_curve(&scorer, &images, &prefixes);
        let quality: Vec<f64> = scales.iter().map(|s| s.2.quality()).collect();
        orders.push(OrderReport {
            order,
            scale: scales.iter().map(|s| s.1).collect(),
            lambda: lambda_reaching(&quality, min),
            lambda_curve: lambda_curve(&quality, &cook, config.min_quality),
            quality,
        });
    }
    let radius = scorer.sphere().1;
    Ok(PruneReport {
        leaves: leaves.leaves.len(),
        resolution: config.resolution,
        pixel_height: config.resolution as f32 * height / (2.0 * radius.max(1e-6)),
        min_quality: config.min_quality,
        cook_lambda: lambda_reaching(&cook, min),
        cook_quality: cook,
        orders,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::NO_ALPHA;
    use crate::rng::SplitMix64;

    /// A vertex at `p` (UV and colour unused here).
    fn vertex(p: Vec3) -> VertexRecord {
        VertexRecord { position: p.to_array(), normal: 0, uv: [0.0, 0.0], color: u32::MAX }
    }

    /// Square leaves of side `side` at `centres`, facing `normals`: four vertices, two triangles
    /// each.
    fn quads(centres: &[Vec3], normals: &[Vec3], side: f32) -> (Vec<VertexRecord>, Vec<MeshTriangle>) {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        for (&c, &n) in centres.iter().zip(normals) {
            let u = n.any_orthonormal_vector() * (0.5 * side);
            let v = n.cross(u);
            let base = vertices.len() as u32;
            vertices.extend([c - u - v, c + u - v, c + u + v, c - u + v].map(vertex));
            triangles.push(MeshTriangle { v: [base, base + 1, base + 2], alpha: NO_ALPHA });
            triangles.push(MeshTriangle { v: [base, base + 2, base + 3], alpha: NO_ALPHA });
        }
        (vertices, triangles)
    }

    fn random_unit(rng: &mut SplitMix64) -> Vec3 {
        loop {
            let v = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            if (0.01..=1.0).contains(&v.length_squared()) {
                return v.normalize();
            }
        }
    }

    fn leaves_of(centres: &[Vec3], normals: &[Vec3]) -> Vec<Leaf> {
        let (vertices, triangles) = quads(centres, normals, 0.05);
        let mesh = PruneMesh { vertices: &vertices, leaves: &triangles, bark: &[], alphas: &[] };
        find_leaves(&mesh).leaves
    }

    #[test]
    fn leaves_are_connected_triangles_with_their_centre_and_area() {
        // Two unit squares (two triangles each) and a lone triangle.
        let (mut vertices, mut triangles) = quads(&[Vec3::ZERO, Vec3::new(5.0, 0.0, 0.0)], &[Vec3::Z, Vec3::Y], 1.0);
        let base = vertices.len() as u32;
        vertices.extend([Vec3::new(0.0, 3.0, 0.0), Vec3::new(3.0, 3.0, 0.0), Vec3::new(0.0, 6.0, 0.0)].map(vertex));
        triangles.insert(1, MeshTriangle { v: [base, base + 1, base + 2], alpha: NO_ALPHA });
        let mesh = PruneMesh { vertices: &vertices, leaves: &triangles, bark: &[], alphas: &[] };
        let leaves = find_leaves(&mesh);
        assert_eq!(leaves.leaves.len(), 3);
        // Numbered by first triangle; a leaf's triangles in mesh order.
        assert_eq!(leaves.triangles_of(&leaves.leaves[0]), [0, 2]);
        assert_eq!(leaves.triangles_of(&leaves.leaves[1]), [1]);
        assert_eq!(leaves.triangles_of(&leaves.leaves[2]), [3, 4]);
        let square = leaves.leaves[0];
        assert!((square.area - 1.0).abs() < 1e-6 && square.centre.abs_diff_eq(Vec3::ZERO, 1e-6));
        assert!(square.normal.abs_diff_eq(Vec3::Z, 1e-6) || square.normal.abs_diff_eq(-Vec3::Z, 1e-6));
        let lone = leaves.leaves[1];
        assert!((lone.area - 4.5).abs() < 1e-5 && lone.centre.abs_diff_eq(Vec3::new(1.0, 4.0, 0.0), 1e-5));
    }

    #[test]
    fn every_order_is_a_deterministic_permutation() {
        let mut rng = SplitMix64(5);
        let centres: Vec<Vec3> = (0..500).map(|_| 3.0 * random_unit(&mut rng) * rng.unit().cbrt()).collect();
        let normals: Vec<Vec3> = (0..500).map(|_| random_unit(&mut rng)).collect();
        let leaves = leaves_of(&centres, &normals);
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
        for order in PruneOrder::ALL {
            let list = priority_order(&leaves, order, 6.0, 7);
            let mut sorted = list.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..500).collect::<Vec<u32>>(), "{order:?} is a permutation");
            assert_eq!(list, priority_order(&leaves, order, 6.0, 7), "{order:?} is repeatable");
            assert_eq!(list, one.install(|| priority_order(&leaves, order, 6.0, 7)), "{order:?} on one thread");
            assert_ne!(list, priority_order(&leaves, order, 6.0, 8), "{order:?} depends on the seed");
            assert_eq!(PruneOrder::parse(order.as_str()), Some(order));
        }
    }

    #[test]
    fn density_order_prunes_a_dense_clump_first() {
        // 300 leaves spread through a 10 m cube, 300 in a clump of 0.4 m: the metaball radius
        // (5 % of 10 m) sees dozens of neighbours in the clump, a few outside it.
        let mut rng = SplitMix64(2);
        let mut centres: Vec<Vec3> =
            (0..300).map(|_| Vec3::new(rng.range(0.0, 10.0), rng.range(0.0, 10.0), rng.range(0.0, 10.0))).collect();
        centres.extend((0..300).map(|_| Vec3::splat(5.0) + 0.2 * random_unit(&mut rng) * rng.unit()));
        let leaves = leaves_of(&centres, &vec![Vec3::Y; 600]);
        let list = priority_order(&leaves, PruneOrder::Density, 10.0, 1);
        let in_clump = |l: &u32| *l >= 300;
        // The last 250 (the first pruned) are all clump leaves; the clump keeps few survivors.
        assert!(list[350..].iter().all(in_clump), "dense leaves go first");
        let kept = list[..300].iter().filter(|l| in_clump(l)).count();
        assert!(kept < 30, "{kept} clump leaves among the first 300");
        // Stochastic ignores density: about half the last 250 are clump leaves.
        let stochastic = priority_order(&leaves, PruneOrder::Stochastic, 10.0, 1);
        let late = stochastic[350..].iter().filter(|l| in_clump(l)).count();
        assert!((90..160).contains(&late), "{late}");
    }

    #[test]
    fn orientation_order_keeps_outer_leaves_facing_out_first() {
        // A crown: 1500 leaves filling a ball of 2 m (about 20 within the metaball radius of
        // 0.5 m each), half facing outwards (radial normal), half edge-on (tangential). In the
        // outer layer, where the hull is near, the orders keep the outward-facing leaves first.
        let mut rng = SplitMix64(3);
        let centres: Vec<Vec3> = (0..1500).map(|_| 2.0 * random_unit(&mut rng) * rng.unit().cbrt()).collect();
        let normals: Vec<Vec3> = centres
            .iter()
            .enumerate()
            .map(|(i, c)| if i % 2 == 0 { c.normalize() } else { c.normalize().any_orthonormal_vector() })
            .collect();
        let leaves = leaves_of(&centres, &normals);
        let outer = |l: u32| centres[l as usize].length() > 1.6;
        for order in [PruneOrder::Orientation, PruneOrder::Combined] {
            let list = priority_order(&leaves, order, 10.0, 1);
            let first = &list[..750];
            let facing = first.iter().filter(|&&l| outer(l) && l % 2 == 0).count();
            let edge_on = first.iter().filter(|&&l| outer(l) && l % 2 == 1).count();
            assert!(facing > 3 * edge_on, "{order:?}: {facing} outer leaves facing out, {edge_on} edge-on first");
        }
        // Stochastic does not care.
        let list = priority_order(&leaves, PruneOrder::Stochastic, 10.0, 1);
        let facing = list[..750].iter().filter(|&&l| outer(l) && l % 2 == 0).count();
        let edge_on = list[..750].iter().filter(|&&l| outer(l) && l % 2 == 1).count();
        assert!(facing < 2 * edge_on, "stochastic: {facing} and {edge_on}");
    }

    #[test]
    fn lambda_curve_matches_cooks_quality_with_less_geometry_and_keeps_the_minimum() {
        // Q with s_opt rises linearly from 0.5 at λ = 0.05 to 1 at λ = 1; Cook's is 0.1 lower
        // below λ = 1.
        let quality: Vec<f64> = LAMBDAS.iter().map(|&l| 0.5 + 0.5 * f64::from(l - 0.05) / 0.95).collect();
        let cook: Vec<f64> = quality.iter().zip(LAMBDAS).map(|(q, l)| if l < 1.0 { q - 0.1 } else { 1.0 }).collect();
        let curve = lambda_curve(&quality, &cook, 0.0);
        assert_eq!(curve.len(), 20);
        assert!(curve.windows(2).all(|w| w[0].x < w[1].x && w[0].y <= w[1].y), "{curve:?}");
        assert_eq!((curve[0].x, curve[19].x), (FAR_PIXELS, NEAR_PIXELS));
        // At d = 0 Cook draws everything: so do we.
        assert_eq!(curve[19].y, 1.0);
        // At d = 0.5 Cook draws λ = 0.25; the same quality needs 0.1/0.5·0.95 = 0.19 less here.
        let mid = curve.iter().find(|s| (s.x - NEAR_PIXELS / (1.0 + 0.5 * 31.0)).abs() < 1e-3).expect("d = 0.5");
        assert!((mid.y - (0.25 - 0.19)).abs() < 0.01, "{mid:?}");
        // A minimum quality of 0.9 holds λ at 0.81 or more everywhere.
        let floor = lambda_curve(&quality, &cook, 0.9);
        assert!(floor.iter().all(|s| s.y >= 0.81 - 1e-4), "{floor:?}");
        assert_eq!(lambda_reaching(&quality, 2.0), 1.0);
        assert_eq!(lambda_reaching(&quality, 0.0), LAMBDAS[0]);
    }

    #[test]
    fn scaling_pruned_leaves_restores_coverage() {
        // A ball of 800 small opaque quads: at λ = 0.25 the unscaled survivors leave holes, and
        // the optimal scale is above 1 and scores better.
        let mut rng = SplitMix64(9);
        let centres: Vec<Vec3> = (0..800).map(|_| random_unit(&mut rng) * rng.unit().cbrt()).collect();
        let normals: Vec<Vec3> = (0..800).map(|_| random_unit(&mut rng)).collect();
        let (vertices, triangles) = quads(&centres, &normals, 0.12);
        let mesh = PruneMesh { vertices: &vertices, leaves: &triangles, bark: &[], alphas: &[] };
        let leaves = find_leaves(&mesh);
        let order = priority_order(&leaves.leaves, PruneOrder::Stochastic, 2.0, 1);
        let prefixes = Prefixes::new(&order, &vec![0; leaves.leaves.len()]);
        let scorer = Scorer::new(mesh, &leaves, crate::raster::view_directions(4));
        let images = scorer.images(96);
        let drawn = prefixes.drawn(0.25);
        assert_eq!(drawn.len(), 200);
        let unscaled = scorer.score(&images, &drawn, 1.0);
        assert_eq!(unscaled.precision, 1.0, "unscaled survivors cover only pixels of the full model");
        let (s, best) = optimal_scale(&scorer, &images, &drawn, 0.25);
        assert!(s > 1.5, "s_opt {s}");
        assert!(best.quality() > unscaled.quality() + 0.05, "{best:?} against {unscaled:?}");
        // Everything drawn unscaled is the reference itself.
        let all = prefixes.drawn(1.0);
        assert_eq!(scorer.score(&images, &all, 1.0), Score { precision: 1.0, recall: 1.0 });
    }
}
