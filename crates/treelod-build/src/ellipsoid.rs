//! Leaf ellipsoids (Clasen, Paar and Prohaska 2011 §3.1, §4, §6; spec §6.8, §10): per grid cell,
//! one ellipsoid per leaf and nested levels of ellipsoid clusters above them, each level drawn in
//! one interval of `τ`.
//!
//! - **Leaves** are [`crate::prune::find_leaves`]' connected sets of leaf-class triangles of one
//!   part (as impostors and pruning take them); a leaf belongs to the grid cell holding its centre
//!   (the area-weighted centroid), as pruned leaves do.
//! - **Leaf ellipsoids**: [`EllipsoidConfig::samples`] deterministic stratified samples over the
//!   leaf's surface (sample `k` at `(k + ½)/N` of the cumulative area picks the triangle, the
//!   remainder and the golden-ratio sequence place it uniformly in it); samples that fail the
//!   material's alpha test ([`AlphaMask`]) are dropped (all kept if none passes), so a leaf card
//!   becomes the ellipsoid of its opaque leaves. Their mean and covariance give the centre and,
//!   by PCA ([`symmetric_eigen`]), the axes; the semi-axes are `2σ` (a uniform disc or ellipse of
//!   semi-axis `a` has `σ = a/2` along it), and the thinnest is at least [`MIN_THICKNESS`] (5 %)
//!   of the largest, so a flat leaf has some volume. A leaf whose samples coincide gets the disc of
//!   its area. The colour is the mean over the leaf's triangles of the texture × factor × vertex
//!   colour over the texels that pass the alpha test ([`crate::texture::integrate`], as Gilet's
//!   points), weighted by each triangle's opaque area; its alpha is 1.
//! - **Image error** ([`crate::raster::multiscale_error`], Clasen §4): coverage of the cell's
//!   leaves (alpha-tested triangles) and of a set of ellipsoids in [`EllipsoidConfig::views`]
//!   orthographic views of [`EllipsoidConfig::resolution`]² pixels fitted to the cell's leaves
//!   ([`crate::raster::view_directions`]), the mean over views of the multi-scale RMSE summary
//!   (the mean over its levels, from single pixels to the whole view, as `treelod_eval::metrics`
//!   defines it).
//!   The ellipsoids are drawn as the renderer draws them ([`crate::raster::fill_ellipsoid_noise`]):
//!   each pixel of an ellipsoid's projection is hit on its front surface only (a hole shows what
//!   lies behind it, other ellipsoids, never its own back: `ellipsoid_hit` takes the nearer
//!   root) and is a hole where the renderer's noise cube, sampled at the hit's local direction,
//!   is below the threshold `t`. The cube is the renderer's, texel for texel (the same hash), at
//!   the mip the renderer picks for the ellipsoid when the level is drawn on screen
//!   (`runtime_noise_levels`: its `noise_mip`, or the coarser level of the pixel footprint of an
//!   ellipsoid about `√2·`[`EllipsoidConfig::pixels`] across). So a threshold `t` cuts about the
//!   share `t` of each ellipsoid in holes of the sizes the renderer cuts, relative to the
//!   ellipsoid (at mip 3 or 4, a few pixels wide in the build's views, about a pixel on
//!   screen), and where ellipsoids overlap a pixel stays covered with probability `1 − t^m`.
//! - **Calibration** (Clasen §3.1): every level's semi-axes are scaled by a factor of
//!   [`SCALE_FACTORS`] (0.5, 0.6, …, 1.6) and its ellipsoids given a noise alpha-test threshold of
//!   [`THRESHOLDS`] (0, 0.2, 0.4, 0.6), the pair of least image error chosen together (ties: the
//!   smaller threshold, then the smaller factor), one pair per level and cell ("the image error
//!   is computed for multiple values of t and corresponding scaling coefficients for the
//!   ellipsoid area to compensate the area loss due to the alpha test"). Every other factor is
//!   measured with all thresholds (one image of noise values serves them all), then the two
//!   neighbours of the best pair's factor at its threshold.
//! - **Levels** (Clasen's Algorithm 1, made to nest): level 0 is the leaf ellipsoids; each next
//!   level clusters the previous level's `n` ellipsoids into `⌈n/4⌉` clusters, until one is left.
//!   [`Clustering::Em`] (the paper's method): EM on a Gaussian mixture over the ellipsoids'
//!   centres, each weighted by its leaves' area, with full covariances, started from k-means++
//!   starts at the elements' centres (`plus_plus_starts`: D² sampling by weight, [`SplitMix64`]
//!   seeded from [`EllipsoidConfig::seed`], the cell, the level and the try). Each element is a Gaussian
//!   itself (its leaves' surface), so the M-step adds its own covariance to the scatter of the
//!   centres, as when reducing a mixture (Vasconcelos and Lippman 1999), and the E-step its
//!   expected log-density `log N(μ_i | m_j, Σ_j) − ½ tr(Σ_j⁻¹ C_i)`: clusters of four flat leaves
//!   do not collapse to singular covariances. A regulariser of `(10⁻⁴·D)²` (D the diagonal of the
//!   centres' box) is added to each covariance. To stay `O(n)`, each element's responsibilities
//!   are taken over its [`CANDIDATES`] nearest cluster centres (a uniform grid of the centres).
//!   A cluster that is no element's likeliest (it would end up without members) is re-seeded
//!   after every M-step, for the whole run: it splits the cluster of most members, moving to
//!   that cluster's member worst explained by the mixture with the same covariance and half the
//!   prior each, so that levels keep close to `⌈n/4⌉` clusters.
//!   Iterations stop when the log-likelihood gains less than `10⁻⁴` per unit of weight and every
//!   cluster is some element's likeliest, or after [`EllipsoidConfig::iterations`].
//!   [`Clustering::KMeans`] is the baseline of the paper's comparison: Lloyd's k-means (hard,
//!   spherical) from the same starts, an empty cluster moved to the element farthest from its
//!   centre.
//! - **Membership and shape**: the hard membership (argmax of the fuzzy weight, ties: the lower
//!   cluster) says which ellipsoids of the previous level a cluster contains, so levels nest and
//!   every cluster's leaves are a contiguous run. The shape comes from the fuzzy weights (the
//!   responsibilities renormalised over the clusters that keep members): the weighted mean and
//!   the weighted covariance of the members' Gaussians (their centres' scatter plus their own
//!   covariances, i.e. the second moments of the leaves' surface samples, not the centres alone),
//!   turned into an ellipsoid as a leaf is. Clusters whose surface area is under 1 % of the
//!   level's largest are dropped (Clasen §3.1): their elements' fuzzy weights are renormalised
//!   over the kept clusters and an element whose candidates are all dropped goes to the kept
//!   cluster with the nearest centre; the shapes are then recomputed.
//! - **Tries**: each level is clustered [`EllipsoidConfig::tries`] times from different starts;
//!   each result is calibrated and the one of least image error against the rendered leaves is
//!   kept (ties: the first).
//! - **Noise**: `noise_mip = 0.5·(1 + log2 Σ_i w_ij)` (Clasen's `l_j`) with `Σ_i w_ij` the
//!   cluster's fuzzy count of leaves (0.5 for a leaf); `alpha_threshold` is the level's
//!   calibrated `t`.
//! - **Intervals** (Clasen §6): a level's error is `e_k = d̄_k / pixels`, `d̄_k` the mean over its
//!   ellipsoids of the diameter of the sphere of equal surface area (`2·sqrt(S/4π)`, also the
//!   diameter of the disc of the mean projected area `S/4` over all directions), metres, and
//!   `pixels` [`EllipsoidConfig::pixels`] (5): level `k` is drawn for `τ ∈ [e_{k−1}, e_k)` (`τ`
//!   metres per pixel), level 0 from 0 and the coarsest to `+∞`. A level whose error is not above
//!   the last written level's is skipped (not written; the next level nests over it all the
//!   same), so the intervals stay ordered. [`crate::spt::flatten`] turns the nesting into SPT
//!   order with these intervals and numbers each cell's leaves in hierarchy order.
//!
//! Cells are built in parallel and collected in order, tries and images in parallel inside a
//! cell; every sum runs in a fixed order, so the output does not depend on the thread count.

use glam::{DMat3, DQuat, DVec3, Vec2, Vec3, Vec4};
use rayon::prelude::*;
use treelod_format::{EllipsoidRecord, Setting, VertexRecord, pack};

use crate::error::BuildError;
use crate::impostor::symmetric_eigen;
use crate::prune::{MeshTriangle, PruneMesh, find_leaves};
use crate::raster::{
    AlphaMask, Mask, NOISE_SIZE, RasterTriangle, View, bounding_sphere, coverage_values, fill_ellipsoid_noise,
    multiscale_errors_of_grey, noise_cut, rasterize, view_directions,
};
use crate::rng::SplitMix64;
use crate::spt::flatten;
use crate::texture::linear_to_srgb;

/// The scale factors tried by the calibration (Clasen: "multiple scaling factors"), with every
/// threshold of [`THRESHOLDS`].
pub const SCALE_FACTORS: [f64; 12] = [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6];

/// The noise alpha-test thresholds tried by the calibration (Clasen's `t`, one per level).
pub const THRESHOLDS: [f32; 4] = [0.0, 0.2, 0.4, 0.6];

/// The renderer's noise texels per radian of the local hit direction at the cube's finest level
/// (`shaders/tree/ellipsoids.wgsl` `NOISE_TEXELS_PER_RADIAN`).
const NOISE_TEXELS_PER_RADIAN: f64 = 40.0;

/// Thinnest semi-axis of an ellipsoid as a share of its largest.
pub const MIN_THICKNESS: f64 = 0.05;

/// Clusters with less surface area than this share of the level's largest are dropped.
pub const DROP_AREA: f64 = 0.01;

/// Cluster centres each element's responsibilities are computed over.
pub const CANDIDATES: usize = 8;

/// Elements per cluster of the next level (Clasen: `n ← n · ¼`).
const BRANCHING: usize = 4;

/// How each level is clustered.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Clustering {
    /// Clasen's EM on a Gaussian mixture with full covariances: fuzzy, ellipsoidal clusters.
    #[default]
    Em,
    /// Lloyd's k-means: hard, spherical clusters (the baseline Clasen compares with).
    KMeans,
}

impl Clustering {
    /// Its name in settings and on the command line.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Em => "em",
            Self::KMeans => "kmeans",
        }
    }
}

/// Leaf-ellipsoid tunables (recorded in the container's settings as `ellipsoids.*`, spec §7.1).
#[derive(Clone, Debug, PartialEq)]
pub struct EllipsoidConfig {
    /// Target mean ellipsoid diameter on screen, pixels (Clasen §6: 5): a level is drawn while its
    /// mean ellipsoid is at least this many pixels across. `(0, 1000]`.
    pub pixels: f32,
    /// Clusterings tried per level, the one of least image error kept (Clasen: 4). `1 ..= 64`.
    pub tries: u32,
    /// EM (or k-means) iterations at most per clustering. `1 ..= 1000`. Default 50.
    pub iterations: u32,
    /// Views of the image error. `1 ..= 16`. Default 3.
    pub views: u32,
    /// Side of the image-error views, pixels, a power of two in `16 ..= 1024`. Default 128.
    pub resolution: u32,
    /// Surface samples per leaf. `4 ..= 4096`. Default 64.
    pub samples: u32,
    /// Seed of the clusterings' starts. Default 1.
    pub seed: u64,
    /// How levels are clustered. Default [`Clustering::Em`].
    pub clustering: Clustering,
}

impl Default for EllipsoidConfig {
    fn default() -> Self {
        Self {
            pixels: 5.0,
            tries: 4,
            iterations: 50,
            views: 3,
            resolution: 128,
            samples: 64,
            seed: 1,
            clustering: Clustering::Em,
        }
    }
}

impl EllipsoidConfig {
    /// Checks the ranges documented on the fields.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the field.
    pub fn validate(&self) -> Result<(), BuildError> {
        let bad = |what: String| Err(BuildError::Setting(what));
        if !(self.pixels > 0.0 && self.pixels <= 1000.0) {
            return bad(format!("ellipsoid pixels {}: must be in (0, 1000]", self.pixels));
        }
        if !(1..=64).contains(&self.tries) {
            return bad(format!("ellipsoid tries {}: must be in 1..=64", self.tries));
        }
        if !(1..=1000).contains(&self.iterations) {
            return bad(format!("ellipsoid iterations {}: must be in 1..=1000", self.iterations));
        }
        if !(1..=16).contains(&self.views) {
            return bad(format!("ellipsoid views {}: must be in 1..=16", self.views));
        }
        if !(16..=1024).contains(&self.resolution) || !self.resolution.is_power_of_two() {
            return bad(format!("ellipsoid resolution {}: must be a power of two in 16..=1024", self.resolution));
        }
        if !(4..=4096).contains(&self.samples) {
            return bad(format!("ellipsoid samples {}: must be in 4..=4096", self.samples));
        }
        Ok(())
    }

    /// The `ellipsoids.*` settings (spec §7.1), sorted by key.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        let setting = |key: &str, value: String| Setting { key: format!("ellipsoids.{key}"), value };
        vec![
            setting("clustering", self.clustering.name().into()),
            setting("iterations", self.iterations.to_string()),
            setting("pixels", self.pixels.to_string()),
            setting("resolution", self.resolution.to_string()),
            setting("samples", self.samples.to_string()),
            setting("seed", self.seed.to_string()),
            setting("tries", self.tries.to_string()),
            setting("views", self.views.to_string()),
        ]
    }
}

/// The leaves of a block as the ellipsoid build sees them.
///
/// Every vertex index must be in range; [`build_ellipsoids`] panics otherwise.
#[derive(Clone, Copy, Debug)]
pub struct EllipsoidMesh<'a> {
    /// Vertices (position and UV are read), metres, block space.
    pub vertices: &'a [VertexRecord],
    /// The leaf-class triangles, each with its alpha test (an index into `alphas` or
    /// [`crate::raster::NO_ALPHA`]).
    pub triangles: &'a [MeshTriangle],
    /// Alpha tests of the triangles' materials.
    pub alphas: &'a [AlphaMask],
    /// Per triangle: linear RGB of its opaque part and in `w` its opaque fraction
    /// ([`crate::texture::integrate`]); empty for white.
    pub colours: &'a [Vec4],
}

/// One level of one cell's hierarchy, for reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelReport {
    /// Ellipsoids built at this level.
    pub count: u32,
    /// Whether the level was written (a level whose error is not above the previous written
    /// level's is skipped).
    pub written: bool,
    /// Its calibrated scale factor.
    pub factor: f32,
    /// Its calibrated noise alpha-test threshold (Clasen's `t`).
    pub alpha_threshold: f32,
    /// Its image error against the cell's leaves (mean multi-scale RMSE of coverage).
    pub error: f64,
    /// Its error `e_k`, metres per pixel.
    pub threshold: f32,
}

/// The ellipsoids of one grid cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CellEllipsoids {
    /// In SPT order (spec §10).
    pub records: Vec<EllipsoidRecord>,
    /// Bounds of the ellipsoids (centres grown by their largest semi-axis), block space; `None`
    /// without records.
    pub bounds: Option<(Vec3, Vec3)>,
    /// Its levels, finest (the leaves) first.
    pub levels: Vec<LevelReport>,
    /// Per leaf id of the cell (the records' `leaf_first ..`, spec §6.8), the leaf's triangles as
    /// indices into [`EllipsoidMesh::triangles`]: what the ambient occlusion of a record averages
    /// over (spec §6.14).
    pub leaf_triangles: Vec<Vec<u32>>,
}

/// What [`build_ellipsoids`] returns.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Ellipsoids {
    /// Per grid cell, in cell order.
    pub cells: Vec<CellEllipsoids>,
    /// Leaves found.
    pub leaves: u32,
}

impl Ellipsoids {
    /// Ellipsoids written per level (level 0: the leaves), summed over the cells.
    #[must_use]
    pub fn per_level(&self) -> Vec<u32> {
        let mut counts: Vec<u32> = Vec::new();
        for cell in &self.cells {
            for (k, level) in cell.levels.iter().enumerate() {
                if counts.len() <= k {
                    counts.resize(k + 1, 0);
                }
                if level.written {
                    counts[k] += level.count;
                }
            }
        }
        counts
    }

    /// The image error of each level (level 0: the leaves), the mean over the cells that have it
    /// weighted by their leaves; a cell with fewer levels counts with its coarsest.
    #[must_use]
    pub fn error_per_level(&self) -> Vec<f64> {
        let depth = self.cells.iter().map(|c| c.levels.len()).max().unwrap_or(0);
        (0..depth)
            .map(|k| {
                let (mut sum, mut weight) = (0.0, 0.0);
                for cell in &self.cells {
                    let (Some(first), Some(level)) = (cell.levels.first(), cell.levels.get(k).or(cell.levels.last()))
                    else {
                        continue;
                    };
                    sum += level.error * f64::from(first.count);
                    weight += f64::from(first.count);
                }
                if weight > 0.0 { sum / weight } else { 0.0 }
            })
            .collect()
    }

    /// Records written, all cells.
    #[must_use]
    pub fn count(&self) -> usize {
        self.cells.iter().map(|c| c.records.len()).sum()
    }
}

/// A Gaussian element of a level: a leaf or a cluster, relative to its cell's origin.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Element {
    mean: DVec3,
    cov: DMat3,
    /// Area of its leaves, m² (fuzzy for clusters).
    weight: f64,
    /// Its leaves, counted fuzzily (1 for a leaf).
    leaves: f64,
    /// Linear RGB.
    colour: DVec3,
}

/// An ellipsoid at scale 1: unit axes (right-handed, largest first) and semi-axes, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Shape {
    axes: [DVec3; 3],
    radii: [f64; 3],
}

impl Shape {
    /// The ellipsoid of a Gaussian: PCA axes, semi-axes `2σ`, the thinnest at least
    /// [`MIN_THICKNESS`] of the largest; the disc of area `weight` if the Gaussian is a point.
    fn of(cov: &DMat3, weight: f64) -> Self {
        let (values, vectors) = symmetric_eigen(*cov);
        let mut radii = [values[2], values[1], values[0]].map(|v| 2.0 * v.max(0.0).sqrt());
        let (x, y) = (vectors[2], vectors[1]);
        let z = x.cross(y);
        if !(radii[0] > 0.0 && radii[0].is_finite()) {
            let r = (weight.max(0.0) / std::f64::consts::PI).sqrt();
            radii = [r, r, 0.0];
        }
        let thinnest = MIN_THICKNESS * radii[0];
        radii[1] = radii[1].max(thinnest);
        radii[2] = radii[2].max(thinnest);
        Self { axes: [x, y, z], radii }
    }

    /// Surface area at `factor` (Knud Thomsen's approximation, within 1.1 %).
    fn area(&self, factor: f64) -> f64 {
        const P: f64 = 1.6075;
        let [a, b, c] = self.radii.map(|r| (r * factor).powf(P));
        4.0 * std::f64::consts::PI * ((a * b + a * c + b * c) / 3.0).powf(1.0 / P)
    }

    /// The diameter of the sphere of equal surface area at `factor`.
    fn diameter(&self, factor: f64) -> f64 {
        2.0 * (self.area(factor) / (4.0 * std::f64::consts::PI)).sqrt()
    }
}

/// One built level of a cell.
#[derive(Clone, Debug)]
struct Level {
    elements: Vec<Element>,
    shapes: Vec<Shape>,
    /// Per element of the previous level, its cluster here (empty at level 0).
    parent_of_prev: Vec<u32>,
    factor: f64,
    /// Clasen's `t`, calibrated with `factor`.
    threshold: f32,
    error: f64,
}

/// What the image error of a cell is measured against.
struct Target {
    origin: DVec3,
    views: Vec<View>,
    /// Per view, the leaves' coverage as 0 and 1 ([`coverage_values`]).
    reference: Vec<Vec<i32>>,
}

impl Target {
    /// The image errors of `shapes` at `elements`' centres scaled by `factor`, drawn with the
    /// renderer's noise holes ([`fill_ellipsoid_noise`] at each one's noise level,
    /// [`runtime_noise_level`]), per threshold of [`THRESHOLDS`].
    fn errors(&self, elements: &[Element], shapes: &[Shape], levels: &[u32], factor: f64) -> [f64; THRESHOLDS.len()] {
        let mut total = [0.0; THRESHOLDS.len()];
        for (view, reference) in self.views.iter().zip(&self.reference) {
            let size = view.size as usize;
            let mut grey = vec![0u16; size * size];
            for ((e, s), &level) in elements.iter().zip(shapes).zip(levels) {
                let axes = [0, 1, 2].map(|i| (s.axes[i] * (s.radii[i] * factor)).as_vec3());
                fill_ellipsoid_noise(&mut grey, view, (self.origin + e.mean).as_vec3(), axes, level);
            }
            let cuts = THRESHOLDS.map(noise_cut);
            for (sum, e) in total.iter_mut().zip(multiscale_errors_of_grey(&grey, reference, &cuts)) {
                *sum += e;
            }
        }
        total.map(|t| t / self.views.len().max(1) as f64)
    }

    /// The pair of [`SCALE_FACTORS`] and [`THRESHOLDS`] of least error (ties: the smaller
    /// threshold, then the smaller factor) and that error (Clasen §3.1: "the image error is
    /// computed for multiple values of t and corresponding scaling coefficients"). Every other
    /// factor is measured first (each image serves every threshold), then the neighbours of the
    /// best pair's factor at its threshold.
    fn calibrate(&self, elements: &[Element], shapes: &[Shape], pixels: f32) -> (f64, f32, f64) {
        let levels = runtime_noise_levels(elements, shapes, pixels);
        let coarse: Vec<usize> = (0..SCALE_FACTORS.len()).step_by(2).collect();
        let errors: Vec<[f64; THRESHOLDS.len()]> =
            coarse.par_iter().map(|&i| self.errors(elements, shapes, &levels, SCALE_FACTORS[i])).collect();
        // (threshold index, factor index, error)
        let mut best = (0usize, 0usize, f64::INFINITY);
        for ti in 0..THRESHOLDS.len() {
            for (&fi, e) in coarse.iter().zip(&errors) {
                if e[ti] < best.2 {
                    best = (ti, fi, e[ti]);
                }
            }
        }
        let (ti, fi, _) = best;
        let fine: Vec<usize> =
            [fi.checked_sub(1), Some(fi + 1)].into_iter().flatten().filter(|&i| i < SCALE_FACTORS.len()).collect();
        let refined: Vec<f64> =
            fine.par_iter().map(|&i| self.errors(elements, shapes, &levels, SCALE_FACTORS[i])[ti]).collect();
        for (&i, &e) in fine.iter().zip(&refined) {
            if e < best.2 || (e == best.2 && i < best.1) {
                best = (ti, i, e);
            }
        }
        (SCALE_FACTORS[best.1], THRESHOLDS[best.0], best.2)
    }
}

/// Clasen's noise level of a cluster of `leaves` leaves (fuzzy count, spec §6.8 `noise_mip`):
/// `0.5·(1 + log2 Σ_i w_ij)`, the paper's level `l_j` of `2^l × 2^l` texels per face.
fn noise_mip(leaves: f64) -> f64 {
    0.5 * (1.0 + leaves.max(1.0).log2())
}

/// The mip of the noise cube the renderer samples on each ellipsoid of a level (`ellipsoid_hit`
/// in `shaders/tree/ellipsoids.wgsl`): `max(log2 NOISE_SIZE − noise_mip, log2 footprint)`, the nearest mip
/// (Vulkan's rounding, `⌈x + ½⌉ − 1`). The footprint is the noise texels per pixel at the middle
/// of the ellipsoid when the level is drawn: a level is drawn while its mean diameter is between
/// `pixels` and about twice that on screen, so the mean ellipsoid is taken `√2·pixels` across
/// and each other in proportion to its diameter; at the middle of a sphere `R` pixels in radius
/// the hit direction turns `1/R` radians per pixel. (Towards the rim it turns faster and the
/// renderer picks coarser mips; not modelled.)
fn runtime_noise_levels(elements: &[Element], shapes: &[Shape], pixels: f32) -> Vec<u32> {
    let top = f64::from(NOISE_SIZE.ilog2());
    let diameters: Vec<f64> = shapes.iter().map(|s| s.diameter(1.0)).collect();
    let mean = diameters.iter().sum::<f64>() / diameters.len().max(1) as f64;
    elements
        .iter()
        .zip(&diameters)
        .map(|(e, &d)| {
            let radius_px =
                0.5 * std::f64::consts::SQRT_2 * f64::from(pixels) * if mean > 0.0 { d / mean } else { 1.0 };
            let footprint = (NOISE_TEXELS_PER_RADIAN / radius_px.max(1e-6)).log2();
            let level = (top - noise_mip(e.leaves)).max(footprint).clamp(0.0, top);
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=6")]
            let mip = ((level + 0.5).ceil() - 1.0).clamp(0.0, top) as u32;
            mip
        })
        .collect()
}

/// Builds the ellipsoid hierarchies of every grid cell (see the module documentation): leaves go
/// to `cell_of(centre)`, which must be below `cell_count`.
///
/// # Errors
/// [`BuildError::Setting`] for a bad `config`, [`BuildError::Spt`] if an internal invariant breaks.
///
/// # Panics
/// If a vertex index of `mesh` is out of range, or `cell_of` returns `cell_count` or more.
pub fn build_ellipsoids(
    mesh: &EllipsoidMesh<'_>,
    cell_of: impl Fn(Vec3) -> usize + Sync,
    cell_count: usize,
    config: &EllipsoidConfig,
) -> Result<Ellipsoids, BuildError> {
    config.validate()?;
    let prune_mesh = PruneMesh { vertices: mesh.vertices, leaves: mesh.triangles, bark: &[], alphas: mesh.alphas };
    let leaves = find_leaves(&prune_mesh);
    let mut per_cell: Vec<Vec<u32>> = vec![Vec::new(); cell_count];
    for (i, leaf) in leaves.leaves.iter().enumerate() {
        #[expect(clippy::cast_possible_truncation, reason = "fewer leaves than triangles")]
        per_cell[cell_of(leaf.centre)].push(i as u32);
    }
    let position = |v: u32| Vec3::from_array(mesh.vertices[v as usize].position);
    let cells: Vec<CellEllipsoids> = per_cell
        .par_iter()
        .enumerate()
        .map(|(cell, ids)| {
            if ids.is_empty() {
                return Ok(CellEllipsoids::default());
            }
            let triangles: Vec<u32> =
                ids.iter().flat_map(|&l| leaves.triangles_of(&leaves.leaves[l as usize]).iter().copied()).collect();
            let (centre, radius) =
                bounding_sphere(triangles.iter().flat_map(|&t| mesh.triangles[t as usize].v.map(position)));
            let origin = centre.as_dvec3();
            let raster: Vec<RasterTriangle> = triangles
                .iter()
                .map(|&t| {
                    let tri = &mesh.triangles[t as usize];
                    RasterTriangle {
                        positions: tri.v.map(position),
                        uvs: tri.v.map(|v| Vec2::from_array(mesh.vertices[v as usize].uv)),
                        alpha: tri.alpha,
                    }
                })
                .collect();
            let views: Vec<View> = view_directions(config.views as usize)
                .into_iter()
                .map(|d| View::fit(d, centre, radius, config.resolution))
                .collect();
            let reference: Vec<Vec<i32>> = views
                .par_iter()
                .map(|view| {
                    let mut mask = Mask::new(view.size);
                    rasterize(&mut mask, view, &raster, mesh.alphas);
                    coverage_values(&mask)
                })
                .collect();
            drop(raster);
            let target = Target { origin, views, reference };
            let elements: Vec<Element> = ids
                .par_iter()
                .map(|&l| leaf_element(mesh, leaves.triangles_of(&leaves.leaves[l as usize]), origin, config.samples))
                .collect();
            let mut built = build_cell(elements, &target, cell as u64, config)?;
            // `leaf_triangles` holds, per leaf id, the element (an index into `ids`); now the
            // triangles of that element's leaf.
            for slot in &mut built.leaf_triangles {
                *slot = slot
                    .first()
                    .map_or_else(Vec::new, |&e| leaves.triangles_of(&leaves.leaves[ids[e as usize] as usize]).to_vec());
            }
            Ok(built)
        })
        .collect::<Result<_, BuildError>>()?;
    #[expect(clippy::cast_possible_truncation, reason = "fewer leaves than triangles")]
    let leaf_count = leaves.leaves.len() as u32;
    Ok(Ellipsoids { cells, leaves: leaf_count })
}

/// The Gaussian of one leaf (module documentation): its surface samples' mean and covariance,
/// its area and its colour. `triangles` index `mesh.triangles`.
fn leaf_element(mesh: &EllipsoidMesh<'_>, triangles: &[u32], origin: DVec3, samples: u32) -> Element {
    let corners = |t: u32| {
        mesh.triangles[t as usize].v.map(|v| Vec3::from_array(mesh.vertices[v as usize].position).as_dvec3() - origin)
    };
    let areas: Vec<f64> = triangles
        .iter()
        .map(|&t| {
            let [a, b, c] = corners(t);
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let total: f64 = areas.iter().sum();
    // Stage: stratified samples, alpha-tested.
    let golden = 0.5 * (5f64.sqrt() - 1.0);
    let (mut passed, mut all) = (Vec::new(), Vec::new());
    let (mut t, mut below) = (0usize, 0.0f64);
    for k in 0..samples {
        let u = (f64::from(k) + 0.5) / f64::from(samples) * total;
        while t + 1 < triangles.len() && below + areas[t] <= u {
            below += areas[t];
            t += 1;
        }
        let r1 = if areas[t] > 0.0 { ((u - below) / areas[t]).clamp(0.0, 1.0) } else { 0.5 };
        let r2 = (f64::from(k) * golden + 0.5).fract();
        let s = r1.sqrt();
        let w = [1.0 - s, s * (1.0 - r2), s * r2];
        let tri = &mesh.triangles[triangles[t] as usize];
        let [a, b, c] = corners(triangles[t]);
        let p = a * w[0] + b * w[1] + c * w[2];
        all.push(p);
        let passes = mesh.alphas.get(tri.alpha as usize).is_none_or(|mask| {
            let uv = tri.v.map(|v| Vec2::from_array(mesh.vertices[v as usize].uv).as_dvec2());
            mask.passes((uv[0] * w[0] + uv[1] * w[1] + uv[2] * w[2]).as_vec2())
        });
        if passes {
            passed.push(p);
        }
    }
    let points = if passed.is_empty() { &all } else { &passed };
    let n = points.len().max(1) as f64;
    let mean = points.iter().copied().sum::<DVec3>() / n;
    let mut cov = DMat3::ZERO;
    for &p in points {
        cov += outer(p - mean, p - mean);
    }
    cov *= 1.0 / n;
    // Stage: colour, weighted by opaque area.
    let (mut rgb, mut weight, mut plain) = (DVec3::ZERO, 0.0, DVec3::ZERO);
    for (&t, &area) in triangles.iter().zip(&areas) {
        let c = mesh.colours.get(t as usize).copied().unwrap_or(Vec4::ONE).as_dvec4();
        rgb += c.truncate() * (area * c.w);
        weight += area * c.w;
        plain += c.truncate() * area;
    }
    let colour = if weight > 0.0 {
        rgb / weight
    } else if total > 0.0 {
        plain / total
    } else {
        DVec3::ONE
    };
    Element { mean, cov, weight: total, leaves: 1.0, colour }
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The seed of one clustering.
fn seed(config: &EllipsoidConfig, cell: u64, level: usize, attempt: u32) -> u64 {
    let mut rng = SplitMix64(config.seed ^ cell.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let a = rng.next_u64();
    let mut rng = SplitMix64(a ^ (level as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    let b = rng.next_u64();
    SplitMix64(b ^ u64::from(attempt).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7)).next_u64()
}

/// The levels of one cell's leaves and their records (module documentation).
fn build_cell(
    leaves: Vec<Element>,
    target: &Target,
    cell: u64,
    config: &EllipsoidConfig,
) -> Result<CellEllipsoids, BuildError> {
    let levels = build_levels(leaves, target, cell, config);
    records(&levels, target.origin, config.pixels)
}

/// The levels of one cell, finest first: the leaves, then clusterings down to one ellipsoid.
fn build_levels(leaves: Vec<Element>, target: &Target, cell: u64, config: &EllipsoidConfig) -> Vec<Level> {
    let shapes: Vec<Shape> = leaves.iter().map(|e| Shape::of(&e.cov, e.weight)).collect();
    let (factor, threshold, error) = target.calibrate(&leaves, &shapes, config.pixels);
    let mut levels = vec![Level { elements: leaves, shapes, parent_of_prev: Vec::new(), factor, threshold, error }];
    while let Some(prev) = levels.last()
        && prev.elements.len() > 1
    {
        let k = prev.elements.len().div_ceil(BRANCHING);
        let depth = levels.len();
        let tries: Vec<Level> = (0..config.tries)
            .into_par_iter()
            .map(|attempt| {
                let mut rng = SplitMix64(seed(config, cell, depth, attempt));
                let fuzzy = match config.clustering {
                    Clustering::Em => em(&prev.elements, k, config.iterations, &mut rng),
                    Clustering::KMeans => kmeans(&prev.elements, k, config.iterations, &mut rng),
                };
                let (elements, shapes, parent_of_prev) = make_level(&prev.elements, fuzzy);
                let (factor, threshold, error) = target.calibrate(&elements, &shapes, config.pixels);
                Level { elements, shapes, parent_of_prev, factor, threshold, error }
            })
            .collect();
        let mut best = 0;
        for (i, t) in tries.iter().enumerate() {
            if t.error < tries[best].error {
                best = i;
            }
        }
        let Some(chosen) = tries.into_iter().nth(best) else { break };
        levels.push(chosen);
    }
    levels
}

/// Turns the levels into records in SPT order with their intervals (module documentation).
fn records(levels: &[Level], origin: DVec3, pixels: f32) -> Result<CellEllipsoids, BuildError> {
    let pixels = f64::from(pixels);
    let thresholds: Vec<f64> = levels
        .iter()
        .map(|l| {
            let sum: f64 = l.shapes.iter().map(|s| s.diameter(l.factor)).sum();
            sum / l.shapes.len().max(1) as f64 / pixels
        })
        .collect();
    // Which levels are written: the leaves, every level whose error is above the last written
    // one's, and the coarsest.
    let mut written = vec![false; levels.len()];
    written[0] = true;
    let mut last = thresholds[0];
    for k in 1..levels.len() {
        if k + 1 == levels.len() || thresholds[k] > last {
            written[k] = true;
            last = thresholds[k];
        }
    }
    // Nodes of the written levels, finest first; each level's parents in the next written one.
    let mut children: Vec<Vec<u32>> = Vec::new();
    let mut sizes: Vec<f32> = Vec::new();
    let mut node_of: Vec<(usize, usize)> = Vec::new();
    let mut first_node_of_level = vec![0usize; levels.len()];
    let mut previous: Option<usize> = None;
    for (k, level) in levels.iter().enumerate() {
        if !written[k] {
            continue;
        }
        first_node_of_level[k] = children.len();
        #[expect(clippy::cast_possible_truncation, reason = "metres")]
        let size = previous.map_or(0.0, |p| thresholds[p] as f32);
        for i in 0..level.elements.len() {
            children.push(Vec::new());
            sizes.push(size);
            node_of.push((k, i));
        }
        if let Some(p) = previous {
            // Each node of level p goes to its ancestor at level k.
            for i in 0..levels[p].elements.len() {
                let mut j = i as u32;
                for level in &levels[p + 1..=k] {
                    j = level.parent_of_prev[j as usize];
                }
                #[expect(clippy::cast_possible_truncation, reason = "fewer nodes than leaves")]
                children[first_node_of_level[k] + j as usize].push((first_node_of_level[p] + i) as u32);
            }
        }
        previous = Some(k);
    }
    let spt = flatten(&children, &sizes)?;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let mut out = Vec::with_capacity(node_of.len());
    // Per leaf id, the level-0 element it is (a leaf of the hierarchy: one leaf, its own id).
    let mut leaf_elements = vec![Vec::new(); levels[0].elements.len()];
    for &n in &spt.order {
        let (k, i) = node_of[n as usize];
        let (level, s) = (&levels[k], &spt.nodes[n as usize]);
        if k == 0
            && let Some(slot) = leaf_elements.get_mut(s.leaf_first as usize)
        {
            #[expect(clippy::cast_possible_truncation, reason = "fewer elements than leaves")]
            slot.push(i as u32);
        }
        let (e, shape) = (&level.elements[i], &level.shapes[i]);
        let centre = (origin + e.mean).as_vec3();
        let radii = shape.radii.map(|r| r * level.factor);
        #[expect(clippy::cast_possible_truncation, reason = "metres")]
        let reach = radii[0] as f32;
        lo = lo.min(centre - reach);
        hi = hi.max(centre + reach);
        let rgb = e.colour.as_vec3().to_array().map(linear_to_srgb);
        #[expect(clippy::cast_possible_truncation, reason = "a mip level")]
        let noise_mip = noise_mip(e.leaves) as f32;
        out.push(EllipsoidRecord {
            center: centre.to_array(),
            radii: radii.map(|r| r as f32),
            orientation: quaternion(&shape.axes),
            color: pack::rgba8([rgb[0], rgb[1], rgb[2], 1.0]),
            alpha_threshold: level.threshold,
            noise_mip,
            lo: s.lo,
            hi: s.hi,
            leaf_first: s.leaf_first,
            leaf_count: s.leaf_count,
            flags: 0,
        });
    }
    let reports = levels
        .iter()
        .zip(&thresholds)
        .zip(&written)
        .map(|((l, &t), &w)| {
            #[expect(clippy::cast_possible_truncation, reason = "counts, factors and metres")]
            let report = LevelReport {
                count: l.elements.len() as u32,
                written: w,
                factor: l.factor as f32,
                alpha_threshold: l.threshold,
                error: l.error,
                threshold: t as f32,
            };
            report
        })
        .collect();
    debug_assert!(leaf_elements.iter().all(|e| e.len() == 1), "each leaf id is one level-0 element");
    Ok(CellEllipsoids { records: out, bounds: Some((lo, hi)), levels: reports, leaf_triangles: leaf_elements })
}

/// The unit quaternion (x, y, z, w) of the rotation whose columns are `axes` (right-handed), as
/// snorm16 with `w ≥ 0`.
fn quaternion(axes: &[DVec3; 3]) -> [i16; 4] {
    let q = DQuat::from_mat3(&DMat3::from_cols(axes[0], axes[1], axes[2])).normalize();
    let q = if q.w < 0.0 { -q } else { q };
    #[expect(clippy::cast_possible_truncation, reason = "clamped to the snorm16 range")]
    let snorm = |v: f64| (v.clamp(-1.0, 1.0) * 32767.0).round() as i16;
    [snorm(q.x), snorm(q.y), snorm(q.z), snorm(q.w)]
}

/// Responsibilities of a clustering: per element, up to `slots` (cluster, weight) pairs.
struct Fuzzy {
    /// Clusters asked for.
    k: usize,
    slots: usize,
    cluster: Vec<u32>,
    weight: Vec<f64>,
}

/// A uniform grid over cluster centres, for the nearest ones to a point.
struct CentreGrid {
    lo: DVec3,
    cell: f64,
    dims: [i64; 3],
    /// Cluster ids by grid cell (CSR).
    start: Vec<u32>,
    ids: Vec<u32>,
}

impl CentreGrid {
    fn new(centres: &[DVec3], alive: &[bool]) -> Self {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        let mut count = 0usize;
        for (c, _) in centres.iter().zip(alive).filter(|(_, a)| **a) {
            lo = lo.min(*c);
            hi = hi.max(*c);
            count += 1;
        }
        if count == 0 {
            return Self { lo: DVec3::ZERO, cell: 1.0, dims: [1, 1, 1], start: vec![0, 0], ids: Vec::new() };
        }
        let extent = (hi - lo).max(DVec3::splat(1e-9));
        let floor = extent.max_element() * 1e-3;
        let volume = extent.max(DVec3::splat(floor)).element_product();
        let cell = (2.0 * volume / count as f64).cbrt().max(floor).max(1e-9);
        #[expect(clippy::cast_possible_truncation, reason = "clamped to 1..=128")]
        let dims = extent.to_array().map(|e| ((e / cell).floor() as i64 + 1).clamp(1, 128));
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let mut grid = Self { lo, cell, dims, start: vec![0; n + 1], ids: Vec::with_capacity(count) };
        let keys: Vec<usize> = centres.iter().map(|&c| grid.key(grid.coords(c))).collect();
        for (&k, _) in keys.iter().zip(alive).filter(|(_, a)| **a) {
            grid.start[k + 1] += 1;
        }
        for i in 0..n {
            grid.start[i + 1] += grid.start[i];
        }
        let mut next = grid.start.clone();
        grid.ids.resize(count, 0);
        for (j, (&k, _)) in keys.iter().zip(alive).enumerate().filter(|(_, (_, a))| **a) {
            #[expect(clippy::cast_possible_truncation, reason = "fewer clusters than leaves")]
            let j = j as u32;
            grid.ids[next[k] as usize] = j;
            next[k] += 1;
        }
        grid
    }

    fn coords(&self, p: DVec3) -> [i64; 3] {
        let r = (p - self.lo) / self.cell;
        #[expect(clippy::cast_possible_truncation, reason = "clamped into the grid")]
        let c = [0, 1, 2].map(|a| (r[a].floor().max(0.0) as i64).min(self.dims[a] - 1));
        c
    }

    fn key(&self, c: [i64; 3]) -> usize {
        #[expect(clippy::cast_sign_loss, clippy::cast_possible_truncation, reason = "inside the grid")]
        let k = (c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])) as usize;
        k
    }

    /// The `m` centres nearest to `p` (ties: lower id) as (squared distance, id), nearest first:
    /// rings of grid cells around `p`'s until the `m`-th nearest found is nearer than anything
    /// outside the rings can be. (Passing over a ring's cells whose box is farther than the
    /// `m`-th nearest so far was measured and not taken: with about two centres a cell the test
    /// costs what it saves, the maple's `--ellipsoids` stage 7.77–7.94 s without it and
    /// 8.09–8.23 s with it, two alternating runs each, the same bytes.)
    fn nearest(&self, centres: &[DVec3], p: DVec3, m: usize, out: &mut Vec<(f64, u32)>) {
        out.clear();
        if self.ids.is_empty() || m == 0 {
            return;
        }
        let c = self.coords(p);
        let reach = self.dims.iter().copied().max().unwrap_or(1);
        let visit = |out: &mut Vec<(f64, u32)>, x: i64, y: i64, z: i64| {
            let k = self.key([x, y, z]);
            for &j in &self.ids[self.start[k] as usize..self.start[k + 1] as usize] {
                let item = (centres[j as usize].distance_squared(p), j);
                let better = |a: &(f64, u32), b: &(f64, u32)| a.0 < b.0 || (a.0 == b.0 && a.1 < b.1);
                if out.len() == m {
                    if !better(&item, &out[m - 1]) {
                        continue;
                    }
                    out.pop();
                }
                let at = out.iter().position(|o| better(&item, o)).unwrap_or(out.len());
                out.insert(at, item);
            }
        };
        for r in 0..=reach {
            let (z0, z1) = ((c[2] - r).max(0), (c[2] + r).min(self.dims[2] - 1));
            let (y0, y1) = ((c[1] - r).max(0), (c[1] + r).min(self.dims[1] - 1));
            let (x0, x1) = ((c[0] - r).max(0), (c[0] + r).min(self.dims[0] - 1));
            for z in z0..=z1 {
                for y in y0..=y1 {
                    if (z - c[2]).abs() == r || (y - c[1]).abs() == r {
                        for x in x0..=x1 {
                            visit(out, x, y, z);
                        }
                    } else {
                        if c[0] - r >= 0 {
                            visit(out, c[0] - r, y, z);
                        }
                        if c[0] + r < self.dims[0] {
                            visit(out, c[0] + r, y, z);
                        }
                    }
                }
            }
            if out.len() == m {
                // Anything outside the block of rings is at least this far from `p`.
                let mut bound = f64::INFINITY;
                for a in 0..3 {
                    #[expect(clippy::cast_precision_loss, reason = "grid coordinates")]
                    let (lo, hi) = ((c[a] - r) as f64 * self.cell, (c[a] + r + 1) as f64 * self.cell);
                    let q = p[a] - self.lo[a];
                    if c[a] - r > 0 {
                        bound = bound.min(q - lo);
                    }
                    if c[a] + r < self.dims[a] - 1 {
                        bound = bound.min(hi - q);
                    }
                }
                if bound == f64::INFINITY || out[m - 1].0 <= bound * bound {
                    return;
                }
            }
        }
    }
}

/// Above this many element–centre distances, [`plus_plus_starts`] takes distinct random elements
/// instead of D² sampling.
const PLUS_PLUS_WORK: usize = 50_000_000;

/// `k` starting centres at elements' centres by k-means++ (Arthur and Vassilvitskii 2007): the
/// first an element drawn by weight, each next one drawn with probability proportional to its
/// weight times its squared distance to the nearest centre so far (an element drawn by weight if
/// all coincide with centres). Above [`PLUS_PLUS_WORK`] distances, `k` distinct elements drawn
/// uniformly. Deterministic from `rng`.
fn plus_plus_starts(elements: &[Element], k: usize, rng: &mut SplitMix64) -> Vec<DVec3> {
    let n = elements.len();
    let k = k.min(n);
    #[expect(clippy::cast_possible_truncation, reason = "an index below n")]
    let below = |rng: &mut SplitMix64, n: usize| rng.below(n as u64) as usize;
    if n.saturating_mul(k) > PLUS_PLUS_WORK {
        // A partial Fisher–Yates shuffle.
        let mut order: Vec<usize> = (0..n).collect();
        for i in 0..k {
            let j = i + below(rng, n - i);
            order.swap(i, j);
        }
        return order[..k].iter().map(|&i| elements[i].mean).collect();
    }
    // The element at `u` of the way along the cumulative `score`, in element order.
    let pick = |score: &[f64], u: f64| -> usize {
        let total: f64 = score.iter().sum();
        let target = u * total;
        let mut sum = 0.0;
        for (i, &s) in score.iter().enumerate() {
            sum += s;
            if sum > target {
                return i;
            }
        }
        score.iter().rposition(|&s| s > 0.0).unwrap_or(n - 1)
    };
    let weights: Vec<f64> = elements.iter().map(|e| e.weight.max(0.0)).collect();
    let first = if weights.iter().any(|&w| w > 0.0) { pick(&weights, rng.next_f64()) } else { below(rng, n) };
    let mut starts = vec![elements[first].mean];
    let mut nearest: Vec<f64> = elements.iter().map(|e| e.mean.distance_squared(starts[0])).collect();
    let mut score = vec![0.0f64; n];
    while starts.len() < k {
        for ((s, &w), &d) in score.iter_mut().zip(&weights).zip(&nearest) {
            *s = w * d;
        }
        let u = rng.next_f64();
        let i = if score.iter().any(|&s| s > 0.0) {
            pick(&score, u)
        } else if weights.iter().any(|&w| w > 0.0) {
            pick(&weights, u)
        } else {
            below(rng, n)
        };
        let c = elements[i].mean;
        starts.push(c);
        for (d, e) in nearest.iter_mut().zip(elements) {
            *d = d.min(e.mean.distance_squared(c));
        }
    }
    starts
}

/// The elements by how badly they are explained, worst first (ties: the lower index), `fit[i]`
/// higher for better explained.
fn worst_first(fit: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..fit.len()).collect();
    order.sort_by(|&a, &b| fit[a].total_cmp(&fit[b]).then(a.cmp(&b)));
    order
}

/// A Gaussian of the mixture with what its density needs.
#[derive(Clone, Copy)]
struct Component {
    mean: DVec3,
    inverse: DMat3,
    /// `log π_j − ½ log det Σ_j`.
    log_norm: f64,
}

impl Component {
    fn new(mean: DVec3, cov: DMat3, prior: f64) -> Self {
        let det = cov.determinant().max(1e-300);
        Self { mean, inverse: cov.inverse(), log_norm: prior.max(1e-300).ln() - 0.5 * det.ln() }
    }

    /// Expected log-density of the Gaussian `(mean, cov)` (up to a constant).
    fn log_density(&self, mean: DVec3, cov: &DMat3) -> f64 {
        let d = mean - self.mean;
        let product = self.inverse * *cov;
        let trace = product.x_axis.x + product.y_axis.y + product.z_axis.z;
        self.log_norm - 0.5 * (d.dot(self.inverse * d) + trace)
    }
}

/// Clasen's EM clustering into `k` Gaussians (module documentation): the responsibilities.
fn em(elements: &[Element], k: usize, iterations: u32, rng: &mut SplitMix64) -> Fuzzy {
    let n = elements.len();
    let k = k.clamp(1, n);
    let slots = CANDIDATES.min(k);
    let (lo, hi) =
        elements.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), e| (lo.min(e.mean), hi.max(e.mean)));
    let diagonal = (hi - lo).length().max(1e-6);
    let regulariser = DMat3::from_diagonal(DVec3::splat((1e-4 * diagonal).powi(2)));
    let spread = (hi - lo).max_element().max(1e-6) / (2.0 * (k as f64).cbrt());
    let start_cov = DMat3::from_diagonal(DVec3::splat(spread * spread)) + regulariser;
    let mut means = plus_plus_starts(elements, k, rng);
    let mut covs = vec![start_cov; k];
    let mut priors = vec![1.0 / k as f64; k];
    let total: f64 = elements.iter().map(|e| e.weight).sum::<f64>().max(1e-300);
    let mut fuzzy = Fuzzy { k, slots, cluster: vec![0; n * slots], weight: vec![0.0; n * slots] };
    let mut last_ll = f64::NEG_INFINITY;
    let alive = vec![true; k];
    for iteration in 0..iterations.max(1) {
        // E-step over each element's nearest centres.
        let components: Vec<Component> = (0..k).map(|j| Component::new(means[j], covs[j], priors[j])).collect();
        let grid = CentreGrid::new(&means, &alive);
        let fit: Vec<f64> = fuzzy
            .cluster
            .par_chunks_mut(slots)
            .zip(fuzzy.weight.par_chunks_mut(slots))
            .zip(elements.par_iter())
            .map_init(Vec::new, |near, ((cluster, weight), e)| {
                grid.nearest(&means, e.mean, slots, near);
                let mut logs = [0.0f64; CANDIDATES];
                for (l, &(_, j)) in logs.iter_mut().zip(near.iter()) {
                    *l = components[j as usize].log_density(e.mean, &e.cov);
                }
                let logs = &mut logs[..near.len()];
                let top = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let mut sum = 0.0;
                for l in logs.iter_mut() {
                    *l = (*l - top).exp();
                    sum += *l;
                }
                for (s, (&(_, j), l)) in near.iter().zip(logs.iter()).enumerate() {
                    cluster[s] = j;
                    weight[s] = l / sum;
                }
                weight[near.len()..].fill(0.0);
                top + sum.ln()
            })
            .collect();
        let ll: f64 = fit.iter().zip(elements).map(|(f, e)| e.weight * f).sum();
        // Clusters that are no element's likeliest: they would end up empty.
        let mut members = vec![0u32; k];
        let mut owner = vec![0u32; n];
        for ((cluster, weight), own) in
            fuzzy.cluster.chunks_exact(slots).zip(fuzzy.weight.chunks_exact(slots)).zip(owner.iter_mut())
        {
            let mut best = (0.0f64, u32::MAX);
            for (&j, &w) in cluster.iter().zip(weight) {
                if w > best.0 || (w == best.0 && w > 0.0 && j < best.1) {
                    best = (w, j);
                }
            }
            if best.1 != u32::MAX {
                members[best.1 as usize] += 1;
                *own = best.1;
            }
        }
        let empty: Vec<usize> = (0..k).filter(|&j| members[j] == 0).collect();
        let converged = (ll - last_ll).abs() < 1e-4 * total && empty.is_empty();
        last_ll = ll;
        if converged || iteration + 1 == iterations.max(1) {
            break;
        }
        // M-step, in element order.
        let mut sums = vec![(0.0f64, DVec3::ZERO, DMat3::ZERO); k];
        for (i, e) in elements.iter().enumerate() {
            for s in 0..slots {
                let r = fuzzy.weight[i * slots + s];
                if r > 0.0 {
                    let w = r * e.weight;
                    let sum = &mut sums[fuzzy.cluster[i * slots + s] as usize];
                    sum.0 += w;
                    sum.1 += e.mean * w;
                    sum.2 += (e.cov + outer(e.mean, e.mean)) * w;
                }
            }
        }
        for (j, &(w, first, second)) in sums.iter().enumerate() {
            if w > 0.0 {
                let m = first / w;
                means[j] = m;
                covs[j] = second * (1.0 / w) - outer(m, m) + regulariser;
                priors[j] = w / total;
            } else {
                priors[j] = 1e-12;
            }
        }
        // A cluster that no element prefers splits the cluster of most members (ties: the lower):
        // it moves to that cluster's member worst explained by the mixture, with the same
        // covariance and half its prior each, so the members on that side come along.
        if !empty.is_empty() {
            let mut worst: Vec<Option<(f64, usize)>> = vec![None; k];
            for (i, (&o, &f)) in owner.iter().zip(&fit).enumerate() {
                let slot = &mut worst[o as usize];
                if slot.is_none_or(|(w, _)| f < w) {
                    *slot = Some((f, i));
                }
            }
            let mut count: Vec<f64> = members.iter().map(|&m| f64::from(m)).collect();
            for &j in &empty {
                let mut split: Option<usize> = None;
                for o in 0..k {
                    if worst[o].is_some() && count[o] > 1.0 && split.is_none_or(|b| count[o] > count[b]) {
                        split = Some(o);
                    }
                }
                let Some(o) = split else { break };
                let Some((_, i)) = worst[o].take() else { break };
                means[j] = elements[i].mean;
                covs[j] = covs[o];
                priors[o] *= 0.5;
                priors[j] = priors[o];
                count[o] *= 0.5;
                count[j] = count[o];
            }
        }
    }
    fuzzy
}

/// Lloyd's k-means from the same random starts as [`em`]: hard, spherical clusters (one slot
/// per element, weight 1).
fn kmeans(elements: &[Element], k: usize, iterations: u32, rng: &mut SplitMix64) -> Fuzzy {
    let n = elements.len();
    let k = k.clamp(1, n);
    let mut means = plus_plus_starts(elements, k, rng);
    let alive = vec![true; k];
    let mut assign: Vec<u32> = Vec::new();
    for iteration in 0..iterations.max(1) {
        let grid = CentreGrid::new(&means, &alive);
        let next: Vec<u32> = elements
            .par_iter()
            .map_init(Vec::new, |near, e| {
                grid.nearest(&means, e.mean, 1, near);
                near.first().map_or(0, |&(_, j)| j)
            })
            .collect();
        if next == assign {
            break;
        }
        assign = next;
        let mut sums = vec![(0.0f64, DVec3::ZERO); k];
        for (e, &j) in elements.iter().zip(&assign) {
            sums[j as usize].0 += e.weight;
            sums[j as usize].1 += e.mean * e.weight;
        }
        // Empty clusters move to the elements farthest from their centres, farthest first.
        let fit: Vec<f64> =
            elements.iter().zip(&assign).map(|(e, &j)| -e.mean.distance_squared(means[j as usize])).collect();
        let empty: Vec<usize> = (0..k).filter(|&j| sums[j].0 <= 0.0).collect();
        for (j, &(w, first)) in sums.iter().enumerate() {
            if w > 0.0 {
                means[j] = first / w;
            }
        }
        if iteration + 1 < iterations.max(1) {
            for (&j, i) in empty.iter().zip(worst_first(&fit)) {
                means[j] = elements[i].mean;
            }
        }
    }
    Fuzzy { k, slots: 1, cluster: assign, weight: vec![1.0; n] }
}

/// The clusters of a level from the responsibilities (module documentation): their elements,
/// shapes, and each previous element's cluster.
fn make_level(prev: &[Element], mut fuzzy: Fuzzy) -> (Vec<Element>, Vec<Shape>, Vec<u32>) {
    let (n, slots) = (prev.len(), fuzzy.slots);
    let mut alive = vec![false; fuzzy.k];
    // Each element's cluster of greatest weight among `alive` ones (ties: the lower), u32::MAX
    // if none.
    let hard = |fuzzy: &Fuzzy, alive: &[bool]| -> Vec<u32> {
        (0..n)
            .map(|i| {
                let mut best: Option<(f64, u32)> = None;
                for s in 0..slots {
                    let (j, w) = (fuzzy.cluster[i * slots + s], fuzzy.weight[i * slots + s]);
                    if w > 0.0 && alive[j as usize] && best.is_none_or(|(bw, bj)| w > bw || (w == bw && j < bj)) {
                        best = Some((w, j));
                    }
                }
                best.map_or(u32::MAX, |b| b.1)
            })
            .collect()
    };
    let everyone = vec![true; fuzzy.k];
    let mut assign = hard(&fuzzy, &everyone);
    for (i, j) in assign.iter_mut().enumerate() {
        if *j == u32::MAX {
            // No weight anywhere (cannot happen with a non-empty mixture): its first candidate.
            *j = fuzzy.cluster[i * slots];
        }
        alive[*j as usize] = true;
    }
    let mut clusters = moments(prev, &mut fuzzy, &alive, &assign);
    // Drop the clusters of less than 1 % of the largest surface area.
    let areas: Vec<f64> = clusters.iter().map(|c| c.as_ref().map_or(0.0, |(_, s)| s.area(1.0))).collect();
    let largest = areas.iter().copied().fold(0.0, f64::max);
    let mut dropped = false;
    for (j, &a) in areas.iter().enumerate() {
        if alive[j] && a < DROP_AREA * largest {
            alive[j] = false;
            dropped = true;
        }
    }
    if dropped {
        assign = hard(&fuzzy, &alive);
        for i in 0..n {
            if assign[i] != u32::MAX {
                continue;
            }
            // All its candidates dropped: the kept cluster with the nearest centre.
            let mut best: Option<(f64, u32)> = None;
            for (j, c) in clusters.iter().enumerate() {
                if let (true, Some((e, _))) = (alive[j], c) {
                    let d = e.mean.distance_squared(prev[i].mean);
                    if best.is_none_or(|(bd, _)| d < bd) {
                        #[expect(clippy::cast_possible_truncation, reason = "fewer clusters than leaves")]
                        let j = j as u32;
                        best = Some((d, j));
                    }
                }
            }
            if let Some((_, j)) = best {
                // Its whole weight goes there.
                for s in 0..slots {
                    fuzzy.weight[i * slots + s] = 0.0;
                }
                fuzzy.cluster[i * slots] = j;
                fuzzy.weight[i * slots] = 1.0;
                assign[i] = j;
            }
        }
        alive.iter_mut().for_each(|a| *a = false);
        for &j in &assign {
            alive[j as usize] = true;
        }
        clusters = moments(prev, &mut fuzzy, &alive, &assign);
    }
    // Renumber the kept clusters densely in index order.
    let mut renumber = vec![u32::MAX; fuzzy.k];
    let (mut elements, mut shapes) = (Vec::new(), Vec::new());
    for (j, c) in clusters.into_iter().enumerate() {
        if let (true, Some((e, s))) = (alive[j], c) {
            #[expect(clippy::cast_possible_truncation, reason = "fewer clusters than leaves")]
            let id = elements.len() as u32;
            renumber[j] = id;
            elements.push(e);
            shapes.push(s);
        }
    }
    let parent = assign.iter().map(|&j| renumber[j as usize]).collect();
    (elements, shapes, parent)
}

/// Renormalises the responsibilities over the `alive` clusters (an element with none left keeps
/// its hard cluster `assign[i]` alone) and returns each alive cluster's fuzzy element and shape.
fn moments(prev: &[Element], fuzzy: &mut Fuzzy, alive: &[bool], assign: &[u32]) -> Vec<Option<(Element, Shape)>> {
    let slots = fuzzy.slots;
    let mut sums = vec![(0.0f64, 0.0f64, DVec3::ZERO, DMat3::ZERO, DVec3::ZERO); fuzzy.k];
    for (i, e) in prev.iter().enumerate() {
        let row = i * slots..(i + 1) * slots;
        let kept: f64 = row.clone().filter(|&s| alive[fuzzy.cluster[s] as usize]).map(|s| fuzzy.weight[s]).sum();
        if kept <= 0.0 {
            for s in row.clone() {
                fuzzy.weight[s] = 0.0;
            }
            fuzzy.cluster[i * slots] = assign[i];
            fuzzy.weight[i * slots] = 1.0;
        } else {
            for s in row.clone() {
                fuzzy.weight[s] = if alive[fuzzy.cluster[s] as usize] { fuzzy.weight[s] / kept } else { 0.0 };
            }
        }
        for s in row {
            let r = fuzzy.weight[s];
            if r > 0.0 {
                let sum = &mut sums[fuzzy.cluster[s] as usize];
                let w = r * e.weight;
                sum.0 += w;
                sum.1 += r * e.leaves;
                sum.2 += e.mean * w;
                sum.3 += (e.cov + outer(e.mean, e.mean)) * w;
                sum.4 += e.colour * w;
            }
        }
    }
    sums.iter()
        .zip(alive)
        .map(|(&(w, leaves, first, second, colour), &a)| {
            if !a || w <= 0.0 {
                return None;
            }
            let mean = first / w;
            let cov = second * (1.0 / w) - outer(mean, mean);
            let e = Element { mean, cov, weight: w, leaves, colour: colour / w };
            Some((e, Shape::of(&cov, w)))
        })
        .collect()
}

/// A cluster as [`cluster_points`] reports it: mean and covariance (columns).
pub type ClusterStats = (Vec3, [[f32; 3]; 3]);

/// One clustering of points, for tests: the EM (or k-means) clustering of points with unit
/// weights into `k` clusters, as each point's hard cluster (numbered densely) and each
/// cluster's mean and covariance.
#[doc(hidden)]
#[must_use]
pub fn cluster_points(points: &[Vec3], k: usize, clustering: Clustering, seed: u64) -> (Vec<u32>, Vec<ClusterStats>) {
    let elements: Vec<Element> = points
        .iter()
        .map(|p| Element { mean: p.as_dvec3(), cov: DMat3::ZERO, weight: 1.0, leaves: 1.0, colour: DVec3::ONE })
        .collect();
    let mut rng = SplitMix64(seed);
    let fuzzy = match clustering {
        Clustering::Em => em(&elements, k, 200, &mut rng),
        Clustering::KMeans => kmeans(&elements, k, 200, &mut rng),
    };
    let (clusters, _, parent) = make_level(&elements, fuzzy);
    let stats = clusters.iter().map(|c| (c.mean.as_vec3(), c.cov.as_mat3().to_cols_array_2d())).collect();
    (parent, stats)
}

/// The ellipsoid of a leaf given as triangles (`positions`, metres) with `samples` surface
/// samples and no alpha test, for tests: centre, unit axes (largest first) and semi-axes.
#[doc(hidden)]
#[must_use]
pub fn leaf_ellipsoid(positions: &[[Vec3; 3]], samples: u32) -> (Vec3, [Vec3; 3], [f32; 3]) {
    let vertices: Vec<VertexRecord> = positions
        .iter()
        .flatten()
        .map(|p| VertexRecord { position: p.to_array(), ..VertexRecord::default() })
        .collect();
    #[expect(clippy::cast_possible_truncation, reason = "a test's few triangles")]
    let triangles: Vec<MeshTriangle> = (0..positions.len() as u32)
        .map(|t| MeshTriangle { v: [3 * t, 3 * t + 1, 3 * t + 2], alpha: crate::raster::NO_ALPHA })
        .collect();
    let ids: Vec<u32> = (0..triangles.len() as u32).collect();
    let mesh = EllipsoidMesh { vertices: &vertices, triangles: &triangles, alphas: &[], colours: &[] };
    let e = leaf_element(&mesh, &ids, DVec3::ZERO, samples);
    let s = Shape::of(&e.cov, e.weight);
    #[expect(clippy::cast_possible_truncation, reason = "metres")]
    let radii = s.radii.map(|r| r as f32);
    (e.mean.as_vec3(), s.axes.map(|a| a.as_vec3()), radii)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_centre_grid_finds_the_nearest_centres_as_a_search_of_all_of_them_does() {
        // Centres spread through a box, clumped on a few points, strung along a line long
        // enough that the grid's cells are clamped (128 a side), and on the corners of a square,
        // some not alive; points inside and outside: the m nearest alive centres (ties by id)
        // are those a sort of every centre gives.
        let mut rng = SplitMix64(3);
        let mut at = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        for case in 0..12 {
            let n = [40, 400, 3000][case % 3];
            let centres: Vec<DVec3> = (0..n)
                .map(|i| match case / 3 {
                    0 => DVec3::new(at(-1.0, 1.0), at(0.0, 3.0), at(-1.0, 1.0)),
                    1 => DVec3::splat((i % 5) as f64) + 0.01 * DVec3::new(at(0.0, 1.0), 0.0, 0.0),
                    2 => DVec3::new(i as f64 * 0.37, at(0.0, 0.01), 0.0),
                    _ => DVec3::new(at(0.0, 1.0), 0.0, at(0.0, 1.0)).round(),
                })
                .collect();
            let alive: Vec<bool> = (0..n).map(|i| i % 7 != 3).collect();
            let grid = CentreGrid::new(&centres, &alive);
            let mut out = Vec::new();
            for _ in 0..200 {
                let scale = if case / 3 == 2 { 100.0 } else { 1.0 };
                let p = DVec3::new(at(-2.0, 4.0), at(-1.0, 4.0), at(-2.0, 2.0)) * scale;
                for m in [1, 8, 20] {
                    grid.nearest(&centres, p, m, &mut out);
                    #[expect(clippy::cast_possible_truncation, reason = "a few centres")]
                    let mut all: Vec<(f64, u32)> =
                        (0..n).filter(|&i| alive[i]).map(|i| (centres[i].distance_squared(p), i as u32)).collect();
                    all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    all.truncate(m);
                    assert_eq!(out, all, "case {case}, m {m}, p {p}");
                }
            }
        }
    }
}
