//! Leaf-cluster impostors (Garcia, Sbert and Szirmay-Kalos 2005; spec §6.10): a few fixed,
//! textured, alpha-tested planes per tree that stand for its leaves, in nested levels (by
//! default 32 → 16 → 8 planes per tree).
//!
//! - **Leaves** are [`crate::prune::find_leaves`]' connected sets of leaf-class triangles of one
//!   part: centre `p_i` (area-weighted), unit normal `n_i` (area-weighted), area `w_i`.
//! - **Error** of leaf `i` against the plane `pᵀn + d = 0` (the paper's eq. 1):
//!   `E = (p_iᵀn + d)² + α·(1 − (n_iᵀn)²)`. `α` (m²) weighs orientation against distance; it is
//!   `(alpha_scale·R)²` with `R` the crown radius of the tree (half the diagonal of the box holding
//!   its leaf centres), so the clustering does not depend on the model's scale.
//! - **Refit** of a cluster (eqs. 3–5), area-weighted: `c = Σw_i p_i / Σw_i`, `d = −cᵀn`, `n` the
//!   eigenvector of the smallest eigenvalue of `A = Σw_i(p_i − c)(p_i − c)ᵀ − α Σw_i n_i n_iᵀ`.
//!   Weighting by area minimises `Σ w_i E_i`, the error per unit of leaf surface: a large leaf (or
//!   a twig card holding many) moves more pixels when it is moved off its plane than a small one.
//!   The eigenvector comes from cyclic Jacobi rotations in `f64` ([`symmetric_eigen`]), not the
//!   paper's inverse power iteration: `A` is indefinite (the `−α` term), so powers of `A⁻¹`
//!   converge to the eigenvalue nearest zero rather than the smallest, and they stall when the
//!   two smallest eigenvalues are close or `A` is singular (one leaf, a flat cluster); Jacobi
//!   returns the whole orthonormal eigenbasis of any symmetric matrix to rounding. A tie-break
//!   of `10⁻⁹ m²` is added to `α` so that among planes of equal distance (one leaf, `α = 0`) the
//!   one along the leaves' normals wins.
//! - **k-means** (Lloyd): k-means++ seeding on the plane error with [`SplitMix64`] (the first
//!   seed drawn by area, each next one by its error to the seeds so far; a seed is the plane
//!   fitted to one leaf); assignment to the plane of least error (ties: lowest index); refit; an
//!   empty cluster takes the leaf worst served by its plane among clusters that keep one; until
//!   no assignment changes or [`ImpostorConfig::iterations`].
//! - **Levels**: the first level clusters the leaves of each tree into `levels[0]` planes; each
//!   next level clusters the previous level's clusters as wholes (their moments summed, so a
//!   cluster's error is the sum of its leaves' errors, exactly), so levels nest and each plane
//!   covers a contiguous run of leaf ids. A cluster of one cluster is the same plane and is kept
//!   once. Planes are per tree (one hierarchy per tree of the block) in the block cell (§6.2).
//! - **Intervals** ([`crate::spt::flatten`] over the nesting): the size of a plane is its *error
//!   size*, the root-mean-square distance of its leaves' surface from the plane, metres (from the
//!   leaves' exact area moments). A coarser level is drawn from `τ` equal to its error size on, so
//!   under the rule `τ = s_min` pixels the leaves a plane moves stay within `s_min` pixels of
//!   where they are. (The planes' extents would be no use: a plane metres wide is below a pixel
//!   only when the whole tree is.)
//! - **Quads**: each leaf is first turned about its centre by the least rotation that makes it
//!   parallel to the plane (the paper's "moving and rotating the leaves a little toward their
//!   common planes"), so it keeps its shape and area instead of being foreshortened by the
//!   projection (a leaf that is not flat turns by the share `|Σ a_t n_t| / Σ a_t` of that
//!   rotation: a closed blob, 0, keeps its shape); each plane's quad is the smallest of 32 rectangles (rotated in 2.8° steps)
//!   holding the projections of its leaves' turned vertices.
//! - **Atlas**: each plane's leaves are drawn orthogonally onto its quad (texture × factor ×
//!   vertex colour, alpha-tested as the renderer tests them; 4 × 4 samples per texel, the leaf
//!   nearest to the plane wins a sample) at [`ImpostorConfig::texels_per_metre`]. A texel's alpha
//!   is the fraction of its samples covered, its colour their mean (linear). Regions get a
//!   4-texel transparent gutter, sizes and places aligned to 16 texels so that no texel of the 5
//!   mip levels (16 → 1 texel per aligned block) mixes two regions. Mips are a premultiplied box
//!   filter; each level's alpha is then scaled so that the renderer's test (`alpha ≥ ½` of the
//!   bilinearly filtered alpha) covers the fraction the leaves cover (`preserve_coverage`,
//!   Castaño's alpha mipmaps), or a distant canopy would thin out. Transparent texels within 2 of
//!   coverage take the nearest covered colour (so filtering does not darken edges), the rest stay
//!   zero (so they compress to nothing). Regions are shelf-packed (tallest first) into one RGBA8
//!   sRGB image; if it would exceed [`ImpostorConfig::max_atlas`] texels per side the density
//!   drops by 3/4 steps until it fits.
//! - **Indirect texturing** ([`Texturing::Indirect`], Garcia §2.3; spec §6.10.1), instead of the
//!   atlas: each plane's quad gets a low-resolution grid of *leaf slots* at
//!   [`ImpostorConfig::slots_per_leaf`] texels across the median leaf (`bake_slots`: 4 × 4
//!   samples per texel, each taking the leaf nearest to the plane that passes its alpha test; a
//!   texel keeps the two leaves of most samples), and each (plane, leaf) a
//!   [`PlaneLeafRecord`]: the weighted least-squares affine map from the plane's `(s, t)` to the
//!   leaf's texture coordinates over its turned vertices, each triangle weighted by its area as
//!   projected on the plane (`LeafFit`), and the leaf's texture rectangle, colour and
//!   material. The renderer draws the leaves from their own textures, so a plane close up shows
//!   the leaf texture's full detail. Garcia stores a corner and an angle per texel and keeps a
//!   set of pre-rotated leaf images; the affine map does the rotation (and any scale or shear)
//!   at draw time from the one image the triangles already use, and suits leaves of any size and
//!   any place in a texture atlas. It needs leaves whose outline is in their texture (`MASK` or
//!   `BLEND`, textured): otherwise the build writes the atlas and says why ([`Impostors::note`]).
//!
//! - **Diffuse response** (spec §6.10.2): a plane lit as one surface takes the sun by `|N·l|` of
//!   its own normal, its leaves by theirs, and a view sees each leaf by the area it shows, `|n·v|`:
//!   a cluster of leaves turned every way is as bright edge-on as face-on, where its plane would
//!   be dark. Each plane gets the shares of a mixture of leaves in the plane, turned every way and
//!   across the plane (every way about its normal), for which the renderer's diffuse factor has a
//!   closed form in `v` and `l`; the shares match the mean and mean square of the leaves' `|c|`
//!   (cosine to the plane's normal), each leaf triangle's shading normal (its vertices' normals
//!   summed) weighted as the plane's occlusion weighs it, area times `1 − occlusion` (the leaves a
//!   view from outside reaches) (`plane_diffuse`). Exact for each of the three alone.
//!
//! Everything is deterministic: fixed seeds, sums in a fixed order, rayon only over independent
//! items collected in order.

use glam::{DMat2, DMat3, DQuat, DVec2, DVec3, Vec3};
use rayon::prelude::*;
use treelod_format::{PlaneDiffuseRecord, PlaneLeafRecord, PlaneRecord, Setting, VertexRecord, image_format, pack};

use crate::error::BuildError;
use crate::prune::{MeshTriangle, PruneMesh, find_leaves};
use crate::raster::{NO_ALPHA, floor_f64};
use crate::rng::SplitMix64;
use crate::scene::{AlphaMode, Image, Material};
use crate::spt::flatten;
use crate::texture::{linear_to_srgb, srgb_to_linear_table};

/// Planes per tree of each level, finest first (the paper's 32 → 16 → 8).
pub const DEFAULT_LEVELS: [u32; 3] = [32, 16, 8];

/// Samples per texel side when baking.
pub(crate) const SAMPLES: usize = 4;

/// Texel rows baked at a time: 64 rows of a 2048-texel-wide quad hold 33 MB of samples.
/// (Baking a quad of at most 2^18 samples in one band, without finding each triangle's rows
/// first, was measured and not taken: the maple's octahedral views, two bands each, went over
/// their 118k–154k triangles once instead of three times, and the same texels took as long,
/// 15.7 and 16.0 s for the stage; the samples' shading, not the triangles' loop, is its cost.)
const BAND_ROWS: usize = 64;

/// Samples [`row_span`] adds on each side of a row's crossing with a triangle.
const SPAN_MARGIN: f64 = 2.0;

/// Transparent texels around each region's content.
pub(crate) const GUTTER: u32 = 4;

/// Region sizes and places are multiples of this, `2^(MIP_LEVELS − 1)`: every mip texel of a
/// region lies in that region.
pub(crate) const ALIGN: u32 = 16;

/// Mip levels of the atlas.
pub(crate) const MIP_LEVELS: u32 = 5;

/// Texels around coverage that get its colour, at every level.
const DILATION: u32 = 2;

/// Added to `α` in every refit, m²: the tie-break towards the leaves' normals.
const TIE_BREAK: f64 = 1e-9;

/// Orientations tried for each quad, over a quarter turn.
const QUAD_ANGLES: u32 = 32;

/// Impostor tunables (recorded in the container's settings as `impostors.*`, spec §7.1).
#[derive(Clone, Debug, PartialEq)]
pub struct ImpostorConfig {
    /// Planes per tree at each level, finest first, strictly decreasing, each `1 ..= 4096`.
    /// Default `[32, 16, 8]`. A tree with fewer leaves gets one plane per leaf at the levels
    /// that would not reduce it.
    pub levels: Vec<u32>,
    /// `α = (alpha_scale·R)²`, `R` the tree's crown radius: the distance from a plane, as a
    /// fraction of `R`, that costs as much as a leaf at right angles to it. Finite, `≥ 0`.
    /// Default 0.1.
    pub alpha_scale: f32,
    /// Atlas texels per metre of plane, `(0, 4096]`. Default 24: a 10 m tree's planes get about
    /// 64–160 texels per side.
    pub texels_per_metre: f32,
    /// Largest region side, texels, `4 ..= 2048`. Default 512.
    pub max_texels: u32,
    /// Largest atlas side, texels, `64 ..= 16384`: past it the density drops by 3/4 steps until
    /// the atlas fits. Default 2048 (16 MiB of level 0 at most, a few MiB compressed).
    pub max_atlas: u32,
    /// Lloyd iterations at most per clustering, `1 ..= 1000`. Default 30.
    pub iterations: u32,
    /// Seed of the k-means++ seeding. Default 1.
    pub seed: u64,
    /// How planes are textured. Default [`Texturing::Direct`].
    pub texturing: Texturing,
    /// With [`Texturing::Indirect`], leaf-slot texels across the square root of the median leaf
    /// area, `(0, 64]`. Default 2: a typical leaf spans about 2 × 2 slot texels.
    pub slots_per_leaf: f32,
}

/// How impostor planes are textured (spec §6.10, §6.10.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Texturing {
    /// An RGBA atlas of the leaves as seen on each plane, with coverage-preserving mips.
    #[default]
    Direct,
    /// Garcia's §2.3 indirect texturing: a low-resolution leaf-slot image naming the leaf at each
    /// texel, and per plane and leaf the affine map into the leaf's own texture
    /// ([`treelod_format::PlaneLeafRecord`]). Needs leaves whose outline is in their texture's
    /// alpha; otherwise the build falls back to [`Texturing::Direct`] and says why.
    Indirect,
}

impl Texturing {
    /// Its name in settings and on the command line.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Direct => "direct",
            Self::Indirect => "indirect",
        }
    }
}

impl Default for ImpostorConfig {
    fn default() -> Self {
        Self {
            levels: DEFAULT_LEVELS.to_vec(),
            alpha_scale: 0.1,
            texels_per_metre: 24.0,
            max_texels: 512,
            max_atlas: 2048,
            iterations: 30,
            seed: 1,
            texturing: Texturing::Direct,
            slots_per_leaf: 2.0,
        }
    }
}

impl ImpostorConfig {
    /// Checks the ranges documented on the fields.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the field.
    pub fn validate(&self) -> Result<(), BuildError> {
        let bad = |what: String| Err(BuildError::Setting(what));
        if self.levels.is_empty()
            || self.levels.iter().any(|&k| !(1..=4096).contains(&k))
            || self.levels.windows(2).any(|w| w[1] >= w[0])
        {
            return bad(format!("impostor levels {:?}: strictly decreasing, each in 1..=4096", self.levels));
        }
        if !(self.alpha_scale.is_finite() && self.alpha_scale >= 0.0) {
            return bad(format!("impostor alpha scale {}: must be finite and >= 0", self.alpha_scale));
        }
        if !(self.texels_per_metre > 0.0 && self.texels_per_metre <= 4096.0) {
            return bad(format!("impostor texels per metre {}: must be in (0, 4096]", self.texels_per_metre));
        }
        if !(4..=2048).contains(&self.max_texels) {
            return bad(format!("impostor max texels {}: must be in 4..=2048", self.max_texels));
        }
        if !(64..=16384).contains(&self.max_atlas) {
            return bad(format!("impostor max atlas {}: must be in 64..=16384", self.max_atlas));
        }
        if !(1..=1000).contains(&self.iterations) {
            return bad(format!("impostor iterations {}: must be in 1..=1000", self.iterations));
        }
        if !(self.slots_per_leaf > 0.0 && self.slots_per_leaf <= 64.0) {
            return bad(format!("impostor slots per leaf {}: must be in (0, 64]", self.slots_per_leaf));
        }
        Ok(())
    }

    /// The `impostors.*` settings (spec §7.1), sorted by key.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        let setting = |key: &str, value: String| Setting { key: format!("impostors.{key}"), value };
        let levels: Vec<String> = self.levels.iter().map(u32::to_string).collect();
        vec![
            setting("alpha_scale", self.alpha_scale.to_string()),
            setting("iterations", self.iterations.to_string()),
            setting("levels", levels.join(",")),
            setting("max_atlas", self.max_atlas.to_string()),
            setting("max_texels", self.max_texels.to_string()),
            setting("seed", self.seed.to_string()),
            setting("slots_per_leaf", self.slots_per_leaf.to_string()),
            setting("texels_per_metre", self.texels_per_metre.to_string()),
            setting("texturing", self.texturing.name().into()),
        ]
    }
}

/// A leaf-class triangle of the block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LeafTriangle {
    /// Indices into [`ImpostorMesh::vertices`].
    pub v: [u32; 3],
    /// Index into [`ImpostorMesh::surfaces`].
    pub material: u32,
    /// The tree of the block it belongs to (each tree gets its own planes).
    pub tree: u32,
}

/// How a material looks, for the bake.
#[derive(Clone, Copy, Debug)]
pub struct Surface<'a> {
    /// The material: factor, alpha mode and cutoff.
    pub material: &'a Material,
    /// Its base-colour image.
    pub image: Option<&'a Image>,
}

/// The leaves of a block as the impostor build sees them.
///
/// Every vertex and material index must be in range (the build checks this when it gathers
/// triangles); [`build_impostors`] panics otherwise.
#[derive(Clone, Copy, Debug)]
pub struct ImpostorMesh<'a> {
    /// Vertices (position, UV and colour are read), metres, block space.
    pub vertices: &'a [VertexRecord],
    /// The leaf-class triangles.
    pub triangles: &'a [LeafTriangle],
    /// Per material index of the triangles.
    pub surfaces: &'a [Surface<'a>],
    /// Ambient occlusion of each triangle ([`crate::ambient`]), or empty for none.
    pub occlusion: &'a [f32],
}

/// The planes' image: an RGBA8 atlas, RGB sRGB-encoded, alpha linear (spec §6.7 format 1), or
/// with indirect texturing a leaf-slot image (format 5, §6.10.1). The build then stores an RGBA8
/// atlas as BC7 (format 6) unless told otherwise ([`crate::atlas_format`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Atlas {
    /// Texels across (an RGBA atlas: a multiple of 16).
    pub width: u32,
    /// Texels down (an RGBA atlas: a multiple of 16).
    pub height: u32,
    /// [`treelod_format::image_format`]: `RGBA8_SRGB` or `LEAF_SLOTS` as baked; `BC7_SRGB` once
    /// stored as BC7.
    pub format: u32,
    /// Mip levels stored.
    pub mip_count: u32,
    /// The levels, largest first, rows top to bottom, tightly packed.
    pub texels: Vec<u8>,
}

/// What [`build_impostors`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct Impostors {
    /// The planes in SPT order (spec §10), `image` 0: the caller sets the atlas's index.
    pub planes: Vec<PlaneRecord>,
    /// The atlas every plane samples.
    pub atlas: Atlas,
    /// Bounds of the quads' corners, block space.
    pub bounds: (Vec3, Vec3),
    /// Planes at each level of [`ImpostorConfig::levels`], summed over the trees (a plane kept
    /// unchanged from one level to the next counts at both).
    pub planes_per_level: Vec<u32>,
    /// Leaves clustered.
    pub leaves: u32,
    /// The atlas density used, texels per metre (below the configured one if the atlas had to
    /// shrink to fit [`ImpostorConfig::max_atlas`]).
    pub texels_per_metre: f32,
    /// Atlas texels of each tree's planes: their regions (gutter and alignment included) at mip
    /// level 0, summed over the planes of every hierarchy level. Indexed by the triangles'
    /// `tree`, up to the largest tree with leaves; a tree without leaves used 0. The texture
    /// budget of the baseline billboards ([`crate::billboard`]).
    pub texels_per_tree: Vec<u64>,
    /// Ambient occlusion of each plane, in the order of [`Self::planes`]: the mean of its
    /// triangles' ([`ImpostorMesh::occlusion`]) weighted by area; empty if the mesh has none.
    pub plane_ao: Vec<f32>,
    /// How each plane's leaves take the sun (spec §6.10.2), in the order of [`Self::planes`].
    pub plane_diffuse: Vec<PlaneDiffuseRecord>,
    /// How the planes are textured: as configured, or [`Texturing::Direct`] where indirect
    /// texturing does not apply ([`Self::note`] says why).
    pub texturing: Texturing,
    /// With [`Texturing::Indirect`], each plane's leaves in the order of [`Self::planes`]
    /// (spec §6.10.1), their `material` the index of [`ImpostorMesh::surfaces`]; empty
    /// otherwise.
    pub plane_leaves: Vec<PlaneLeafRecord>,
    /// Why indirect texturing was asked for and not used.
    pub note: Option<String>,
}

/// A plane `pᵀn + d = 0` with a unit normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vec3,
    /// `d`, metres.
    pub offset: f32,
}

/// A leaf as [`cluster`] takes it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClusterLeaf {
    /// Centre, metres.
    pub centre: Vec3,
    /// Unit normal (its sign does not matter).
    pub normal: Vec3,
    /// Area, m², `> 0`.
    pub area: f32,
}

/// A plane in `f64` as the clustering fits it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct PlaneFit {
    /// Unit normal.
    pub(crate) normal: DVec3,
    /// `d` of `pᵀn + d = 0`, metres.
    pub(crate) offset: f64,
}

impl PlaneFit {
    fn plane(&self) -> Plane {
        Plane { normal: self.normal.as_vec3(), offset: self.offset as f32 }
    }
}

/// Area moments of a set of leaves: what the error of the set against any plane, its refit and
/// its error size need.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Moments {
    /// `Σ w_i`, m².
    weight: f64,
    /// `Σ w_i p_i`, which is also `∫ x dA` over the leaves' surface.
    first: DVec3,
    /// `Σ w_i p_i p_iᵀ` (leaf centres).
    centres: DMat3,
    /// `Σ w_i n_i n_iᵀ`.
    normals: DMat3,
    /// `∫ x xᵀ dA` over the leaves' surface.
    surface: DMat3,
}

impl Default for Moments {
    fn default() -> Self {
        Self { weight: 0.0, first: DVec3::ZERO, centres: DMat3::ZERO, normals: DMat3::ZERO, surface: DMat3::ZERO }
    }
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

impl Moments {
    /// One leaf whose surface is concentrated at its centre.
    fn point(centre: DVec3, normal: DVec3, area: f64) -> Self {
        let centres = outer(centre, centre) * area;
        Self { weight: area, first: centre * area, centres, normals: outer(normal, normal) * area, surface: centres }
    }

    fn add(&mut self, o: &Self) {
        self.weight += o.weight;
        self.first += o.first;
        self.centres += o.centres;
        self.normals += o.normals;
        self.surface += o.surface;
    }

    /// `Σ w_i E_i` against `plane` (the paper's eq. 1, area-weighted).
    fn error(&self, plane: &PlaneFit, alpha: f64) -> f64 {
        let (n, d) = (plane.normal, plane.offset);
        let distance = n.dot(self.centres * n) + 2.0 * d * n.dot(self.first) + d * d * self.weight;
        distance.max(0.0) + alpha * (self.weight - n.dot(self.normals * n)).max(0.0)
    }

    /// The plane minimising [`Self::error`] (the paper's eqs. 3–5).
    fn fit(&self, alpha: f64) -> PlaneFit {
        if self.weight <= 0.0 {
            return PlaneFit { normal: DVec3::Y, offset: 0.0 };
        }
        let c = self.first / self.weight;
        let a = self.centres - outer(c, c) * self.weight - self.normals * (alpha + TIE_BREAK);
        let (_, vectors) = symmetric_eigen(a);
        let n = canonical(vectors[0]);
        PlaneFit { normal: n, offset: -c.dot(n) }
    }

    /// Root-mean-square distance of the leaves' surface from `plane`, metres: the error size.
    fn rms_distance(&self, plane: &PlaneFit) -> f64 {
        if self.weight <= 0.0 {
            return 0.0;
        }
        let (n, d) = (plane.normal, plane.offset);
        let sq = n.dot(self.surface * n) + 2.0 * d * n.dot(self.first) + d * d * self.weight;
        (sq.max(0.0) / self.weight).sqrt()
    }
}

/// `v` with its largest component (the first of equals) positive: one sign per plane.
fn canonical(v: DVec3) -> DVec3 {
    let a = v.abs();
    let largest = if a.x >= a.y && a.x >= a.z {
        v.x
    } else if a.y >= a.z {
        v.y
    } else {
        v.z
    };
    let v = if largest < 0.0 { -v } else { v };
    v.normalize_or(DVec3::Y)
}

/// Eigenvalues (ascending) and unit eigenvectors of a symmetric 3×3 matrix, by cyclic Jacobi
/// rotations (Golub and Van Loan §8.5): each rotation zeroes one off-diagonal entry, and sweeps
/// repeat until the off-diagonal part is below `10⁻³⁰` of the matrix's norm (a few sweeps). Only
/// the lower triangle's symmetric part matters (the matrix is symmetrised first). The vectors
/// are orthonormal whatever the eigenvalues' multiplicities.
#[must_use]
pub fn symmetric_eigen(m: DMat3) -> ([f64; 3], [DVec3; 3]) {
    let mut a = [[0.0f64; 3]; 3];
    for (i, row) in a.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = 0.5 * (m.col(j)[i] + m.col(i)[j]);
        }
    }
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let norm: f64 = a.iter().flatten().map(|x| x * x).sum();
    for _ in 0..64 {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        if off <= 1e-30 * norm || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = if theta >= 0.0 { 1.0 } else { -1.0 } / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            let apq = a[p][q];
            a[p][p] -= t * apq;
            a[q][q] += t * apq;
            a[p][q] = 0.0;
            a[q][p] = 0.0;
            let r = 3 - p - q;
            let (arp, arq) = (a[r][p], a[r][q]);
            a[r][p] = c * arp - s * arq;
            a[p][r] = a[r][p];
            a[r][q] = s * arp + c * arq;
            a[q][r] = a[r][q];
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]).then(i.cmp(&j)));
    let values = order.map(|i| a[i][i]);
    let vectors = order.map(|i| DVec3::new(v[0][i], v[1][i], v[2][i]));
    (values, vectors)
}

/// Picks the index at which the running sum of `weights` first exceeds `r` (skipping zero
/// weights); the last positive weight if rounding leaves `r` past the end.
fn pick(weights: &[f64], r: f64) -> usize {
    let mut sum = 0.0;
    let mut last = 0;
    for (i, &w) in weights.iter().enumerate() {
        if w > 0.0 {
            sum += w;
            last = i;
            if sum > r {
                return i;
            }
        }
    }
    last
}

/// The plane of least error for an item (ties: lowest index).
fn nearest(error: impl Fn(&PlaneFit) -> f64, planes: &[PlaneFit]) -> u32 {
    let mut best = (f64::INFINITY, 0u32);
    for (j, plane) in planes.iter().enumerate() {
        let e = error(plane);
        if e < best.0 {
            #[expect(clippy::cast_possible_truncation, reason = "at most 4096 planes")]
            let j = j as u32;
            best = (e, j);
        }
    }
    best.1
}

/// k-means over items with the given moments and per-item error (module documentation);
/// returns each item's cluster, clusters numbered densely from 0 (an empty one is dropped).
fn kmeans<E: Fn(usize, &PlaneFit) -> f64 + Sync>(
    moments: &[Moments],
    error: E,
    k: usize,
    alpha: f64,
    iterations: u32,
    rng: &mut SplitMix64,
) -> Vec<u32> {
    let n = moments.len();
    if n == 0 {
        return Vec::new();
    }
    let k = k.clamp(1, n);
    // Stage: k-means++ seeding on the plane error.
    let weights: Vec<f64> = moments.iter().map(|m| m.weight).collect();
    let total: f64 = weights.iter().sum();
    let first = pick(&weights, rng.next_f64() * total);
    let mut planes = vec![moments[first].fit(alpha)];
    let mut best: Vec<f64> = (0..n).into_par_iter().map(|i| error(i, &planes[0])).collect();
    while planes.len() < k {
        let total: f64 = best.iter().sum();
        if total <= 0.0 {
            break;
        }
        let plane = moments[pick(&best, rng.next_f64() * total)].fit(alpha);
        planes.push(plane);
        best = best.par_iter().enumerate().map(|(i, &b)| b.min(error(i, &plane))).collect();
    }
    // Stage: Lloyd iterations.
    let mut assign: Vec<u32> = Vec::new();
    for _ in 0..iterations.max(1) {
        let next: Vec<u32> = (0..n).into_par_iter().map(|i| nearest(|p| error(i, p), &planes)).collect();
        if next == assign {
            break;
        }
        assign = next;
        let mut counts = vec![0usize; planes.len()];
        for &c in &assign {
            counts[c as usize] += 1;
        }
        for j in 0..planes.len() {
            if counts[j] > 0 {
                continue;
            }
            // Re-seed an empty cluster with the item its plane serves worst.
            let mut worst: Option<(f64, usize)> = None;
            for (i, &c) in assign.iter().enumerate() {
                if counts[c as usize] > 1 {
                    let e = error(i, &planes[c as usize]);
                    if worst.is_none_or(|(w, _)| e > w) {
                        worst = Some((e, i));
                    }
                }
            }
            if let Some((_, i)) = worst {
                counts[assign[i] as usize] -= 1;
                #[expect(clippy::cast_possible_truncation, reason = "at most 4096 planes")]
                let j32 = j as u32;
                assign[i] = j32;
                counts[j] = 1;
            }
        }
        let mut sums = vec![Moments::default(); planes.len()];
        for (i, &c) in assign.iter().enumerate() {
            sums[c as usize].add(&moments[i]);
        }
        for (plane, sum) in planes.iter_mut().zip(&sums) {
            if sum.weight > 0.0 {
                *plane = sum.fit(alpha);
            }
        }
    }
    // Clusters numbered densely in index order.
    let mut renumber = vec![u32::MAX; planes.len()];
    let mut used = 0u32;
    for (j, slot) in renumber.iter_mut().enumerate() {
        if assign.contains(&(j as u32)) {
            *slot = used;
            used += 1;
        }
    }
    assign.iter().map(|&c| renumber[c as usize]).collect()
}

/// Clusters `leaves` onto at most `k` planes with the paper's error at `alpha` (m²), as the
/// build's first level does (see the module documentation); returns each leaf's cluster
/// (numbered densely from 0) and each cluster's fitted plane. Deterministic for a `seed`.
#[must_use]
pub fn cluster(leaves: &[ClusterLeaf], k: usize, alpha: f32, iterations: u32, seed: u64) -> (Vec<u32>, Vec<Plane>) {
    let moments: Vec<Moments> = leaves
        .iter()
        .map(|l| Moments::point(l.centre.as_dvec3(), l.normal.normalize_or(Vec3::Y).as_dvec3(), f64::from(l.area)))
        .collect();
    let alpha = f64::from(alpha);
    let assign = kmeans(&moments, |i, p| moments[i].error(p, alpha), k, alpha, iterations, &mut SplitMix64(seed));
    let clusters = assign.iter().max().map_or(0, |&m| m as usize + 1);
    let mut sums = vec![Moments::default(); clusters];
    for (i, &c) in assign.iter().enumerate() {
        sums[c as usize].add(&moments[i]);
    }
    (assign, sums.iter().map(|s| s.fit(alpha).plane()).collect())
}

/// One leaf of the build: its moments (relative to the block's origin of work) and tree.
struct LeafData {
    centre: DVec3,
    normal: DVec3,
    /// `|Σ a_t n_t| / Σ a_t` over its triangles: 1 for a flat leaf, near 0 for a closed blob.
    flatness: f64,
    moments: Moments,
    tree: u32,
}

/// A node of the plane hierarchies.
struct Node {
    /// Nodes of the level below (empty at the first level).
    children: Vec<u32>,
    /// At the first level, the leaves (indices into the leaf list).
    leaves: Vec<u32>,
    moments: Moments,
    plane: PlaneFit,
    /// The error size, metres.
    size: f64,
}

impl Node {
    fn new(children: Vec<u32>, leaves: Vec<u32>, moments: Moments, alpha: f64) -> Self {
        let plane = moments.fit(alpha);
        let size = moments.rms_distance(&plane);
        Self { children, leaves, moments, plane, size }
    }
}

/// A plane's quad, relative to the origin of work.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Quad {
    pub(crate) centre: DVec3,
    /// Half-extent vectors: `u` along the texture's u, `v` along its v.
    pub(crate) u: DVec3,
    pub(crate) v: DVec3,
}

/// The diffuse response of leaves of `(unit normal, weight)` on a plane of unit `normal` (spec
/// §6.10.2): the mixture of leaves in the plane (share `f`), turned every way (`s`) and across it
/// (`r = 1 − f − s`) whose leaves' `|c|` (cosine to the plane's normal) has the same mean and
/// mean square as theirs, `f + s/2 = E|c|` and `f + s/3 = E c²`; where no mixture of the three
/// has both, the one of two of them with the same mean whose mean square is nearest. No leaves
/// read as lying in the plane; if every leaf has weight 0, each counts alike.
pub(crate) fn plane_diffuse(normal: DVec3, items: &[(DVec3, f64)]) -> PlaneDiffuseRecord {
    match diffuse_moments(normal, items) {
        Some((m1, m2)) => diffuse_mixture(m1, m2),
        None => PlaneDiffuseRecord::FLAT,
    }
}

/// The weighted mean and mean square of `|c|`, the cosine of each of `items`' unit normals to
/// `normal` ([`plane_diffuse`]); `None` without items. If every weight is 0, each counts alike.
pub(crate) fn diffuse_moments(normal: DVec3, items: &[(DVec3, f64)]) -> Option<(f64, f64)> {
    if items.is_empty() {
        return None;
    }
    let total: f64 = items.iter().map(|&(_, w)| w).sum();
    let weight = |w: f64| if total > 0.0 { w } else { 1.0 };
    let (mut m1, mut m2, mut sum) = (0.0, 0.0, 0.0);
    for &(n, w) in items {
        let c = n.dot(normal).abs().min(1.0);
        m1 += weight(w) * c;
        m2 += weight(w) * c * c;
        sum += weight(w);
    }
    Some((m1 / sum, m2 / sum))
}

/// The mixture of [`plane_diffuse`] whose `|c|` has mean `m1` and mean square `m2`.
pub(crate) fn diffuse_mixture(m1: f64, m2: f64) -> PlaneDiffuseRecord {
    let (f, s) = (3.0 * m2 - 2.0 * m1, 6.0 * (m1 - m2));
    let (f, s) = if f >= 0.0 && s >= 0.0 && f + s <= 1.0 {
        (f, s)
    } else {
        // Two of the three with the same mean: in the plane and turned every way (E|c| ≥ 1/2),
        // turned every way and across (E|c| ≤ 1/2), in the plane and across (any).
        let mut pairs = vec![(m1, 0.0)];
        if m1 >= 0.5 {
            pairs.push((2.0 * m1 - 1.0, 2.0 * (1.0 - m1)));
        }
        if m1 <= 0.5 {
            pairs.push((0.0, 2.0 * m1));
        }
        let off = |&(f, s): &(f64, f64)| (f + s / 3.0 - m2).abs();
        pairs.into_iter().min_by(|a, b| off(a).total_cmp(&off(b))).unwrap_or((1.0, 0.0))
    };
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to [0, 1] first")]
    let unorm = |v: f64| (v.clamp(0.0, 1.0) * 65535.0).round() as u16;
    let flat = unorm(f);
    PlaneDiffuseRecord { flat, scattered: unorm(s).min(u16::MAX - flat) }
}

/// Triangle `t` of `mesh` (placed at `[a, b, c]`) as [`plane_diffuse`] counts it: its shading
/// normal (its vertex normals summed; its face's where they cancel) and its area times the share
/// of its rays that leave, `1 − occlusion` (a view from outside sees it as often).
pub(crate) fn diffuse_item(mesh: &ImpostorMesh<'_>, t: u32, [a, b, c]: [DVec3; 3]) -> (DVec3, f64) {
    let tri = &mesh.triangles[t as usize];
    let face = (b - a).cross(c - a);
    let summed: DVec3 =
        tri.v.iter().map(|&v| DVec3::from(pack::oct_decode(mesh.vertices[v as usize].normal).map(f64::from))).sum();
    let normal = summed.try_normalize().or_else(|| face.try_normalize()).unwrap_or(DVec3::Y);
    let open = 1.0 - f64::from(mesh.occlusion.get(t as usize).copied().unwrap_or(0.0).clamp(0.0, 1.0));
    (normal, 0.5 * face.length() * open)
}

/// The occlusion of `triangles` of `mesh` (index and placed corners) as a view from outside sees
/// them ([`crate::ambient::seen_occlusion`], each weighted by its area): a plane's leaves, an
/// octahedral impostor's tree.
pub(crate) fn seen_triangle_occlusion(
    mesh: &ImpostorMesh<'_>,
    triangles: impl Iterator<Item = (u32, [DVec3; 3])>,
) -> f32 {
    let items: Vec<(f32, f32)> = triangles
        .map(|(t, [a, b, c])| {
            #[expect(clippy::cast_possible_truncation, reason = "an area as a weight")]
            let area = (b - a).cross(c - a).length() as f32;
            (mesh.occlusion.get(t as usize).copied().unwrap_or(0.0), area)
        })
        .collect();
    crate::ambient::seen_occlusion(&items)
}

/// One region of the atlas: the content's texels and the region's place and size.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Region {
    /// Content texels across and down.
    pub(crate) tw: u32,
    pub(crate) th: u32,
    /// Region size (content, gutter, alignment).
    pub(crate) rw: u32,
    pub(crate) rh: u32,
    /// Region corner in the atlas.
    pub(crate) x: u32,
    pub(crate) y: u32,
}

impl Region {
    /// An unplaced region holding `tw × th` texels of content in its gutter, aligned.
    pub(crate) fn new(tw: u32, th: u32) -> Self {
        Self { tw, th, rw: align(tw + 2 * GUTTER), rh: align(th + 2 * GUTTER), x: 0, y: 0 }
    }

    /// Its texels (content, gutter and alignment), level 0.
    pub(crate) fn texels(&self) -> u64 {
        u64::from(self.rw) * u64::from(self.rh)
    }

    /// Its content rectangle as a record's `uv_min` and `uv_max` (spec §6.10) in a
    /// `width × height` atlas.
    pub(crate) fn uv(&self, width: u32, height: u32) -> (u32, u32) {
        self.uv_in(width, height, GUTTER)
    }

    /// [`Self::uv`] of a region whose content starts `border` texels in.
    pub(crate) fn uv_in(&self, width: u32, height: u32, border: u32) -> (u32, u32) {
        let (fw, fh) = (f64::from(width), f64::from(height));
        let (cx, cy) = (f64::from(self.x + border), f64::from(self.y + border));
        #[expect(clippy::cast_possible_truncation, reason = "uv in [0, 1]")]
        let uv = (
            pack::unorm16x2((cx / fw) as f32, (cy / fh) as f32),
            pack::unorm16x2(((cx + f64::from(self.tw)) / fw) as f32, ((cy + f64::from(self.th)) / fh) as f32),
        );
        uv
    }
}

pub(crate) fn align(v: u32) -> u32 {
    v.div_ceil(ALIGN) * ALIGN
}

/// Which sample [`bake`] keeps where triangles overlap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Winner {
    /// The one nearest to the plane (`|distance|` least): impostor planes, whose leaves lie on
    /// both sides.
    Nearest,
    /// The front-most seen from the side the plane's normal points to (signed distance along the
    /// normal greatest): billboards, which show the whole tree as seen from one side.
    Front,
}

/// Builds the impostor planes and their atlas for the leaves of `mesh` (see the module
/// documentation); `None` when there are no leaves.
///
/// # Errors
/// [`BuildError::Setting`] for a bad `config`, [`BuildError::Spt`] if an internal invariant breaks.
///
/// # Panics
/// If an index of `mesh` is out of range.
pub fn build_impostors(mesh: &ImpostorMesh<'_>, config: &ImpostorConfig) -> Result<Option<Impostors>, BuildError> {
    config.validate()?;
    if mesh.triangles.is_empty() {
        return Ok(None);
    }
    let position = |v: u32| Vec3::from_array(mesh.vertices[v as usize].position).as_dvec3();

    // Stage: leaves (connected leaf triangles of one part) and their moments, about the centre
    // of the leaves' bounds so that the moments keep their precision.
    let soup: Vec<MeshTriangle> = mesh.triangles.iter().map(|t| MeshTriangle { v: t.v, alpha: NO_ALPHA }).collect();
    let leaves = find_leaves(&PruneMesh { vertices: mesh.vertices, leaves: &soup, bark: &[], alphas: &[] });
    let (lo, hi) =
        leaves.leaves.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), l| {
            (lo.min(l.centre), hi.max(l.centre))
        });
    let origin = (0.5 * (lo + hi)).as_dvec3();
    let data: Vec<LeafData> = leaves
        .leaves
        .par_iter()
        .map(|leaf| {
            let mut moments = Moments::default();
            let mut normal_sum = DVec3::ZERO;
            for &t in leaves.triangles_of(leaf) {
                let [a, b, c] = mesh.triangles[t as usize].v.map(|v| position(v) - origin);
                let cross = (b - a).cross(c - a);
                normal_sum += 0.5 * cross;
                let area = 0.5 * cross.length();
                let s = a + b + c;
                moments.weight += area;
                moments.first += s * (area / 3.0);
                moments.surface += (outer(a, a) + outer(b, b) + outer(c, c) + outer(s, s)) * (area / 12.0);
            }
            let centre = leaf.centre.as_dvec3() - origin;
            let normal = leaf.normal.as_dvec3().normalize_or(DVec3::Y);
            let point = Moments::point(centre, normal, moments.weight);
            moments.centres = point.centres;
            moments.normals = point.normals;
            let tree = mesh.triangles[leaves.triangles_of(leaf)[0] as usize].tree;
            let flatness = if moments.weight > 0.0 { (normal_sum.length() / moments.weight).min(1.0) } else { 0.0 };
            LeafData { centre, normal, flatness, moments, tree }
        })
        .collect();

    // Stage: per tree, the levels of planes.
    let mut trees: Vec<u32> = data.iter().map(|d| d.tree).collect();
    trees.sort_unstable();
    trees.dedup();
    let mut nodes: Vec<Node> = Vec::new();
    // The tree of each node.
    let mut node_tree: Vec<u32> = Vec::new();
    let mut planes_per_level = vec![0u32; config.levels.len()];
    for &tree in &trees {
        #[expect(clippy::cast_possible_truncation, reason = "fewer leaves than triangles, which fit u32")]
        let ids: Vec<u32> = (0..data.len()).filter(|&i| data[i].tree == tree).map(|i| i as u32).collect();
        tree_levels(&data, &ids, tree, config, &mut nodes, &mut planes_per_level);
        node_tree.resize(nodes.len(), tree);
    }

    // Stage: SPT intervals over the nesting, sizes = error sizes.
    let children: Vec<Vec<u32>> = nodes.iter().map(|n| n.children.clone()).collect();
    #[expect(clippy::cast_possible_truncation, reason = "metres")]
    let sizes: Vec<f32> = nodes.iter().map(|n| n.size as f32).collect();
    let spt = flatten(&children, &sizes)?;
    // Source leaves numbered in the order of the first-level planes' ids.
    let mut by_id = vec![0u32; spt.leaf_id.iter().flatten().count()];
    for (node, id) in spt.leaf_id.iter().enumerate() {
        if let Some(id) = id {
            #[expect(clippy::cast_possible_truncation, reason = "node count fits u32 (flatten checked)")]
            let node = node as u32;
            by_id[*id as usize] = node;
        }
    }
    let ordered: Vec<u32> = by_id.iter().flat_map(|&n| nodes[n as usize].leaves.iter().copied()).collect();
    let mut start = vec![0u32; by_id.len() + 1];
    for (i, &n) in by_id.iter().enumerate() {
        #[expect(clippy::cast_possible_truncation, reason = "fewer leaves than triangles")]
        let count = nodes[n as usize].leaves.len() as u32;
        start[i + 1] = start[i] + count;
    }
    let run = |node: usize| {
        let s = &spt.nodes[node];
        let first = start[s.leaf_first as usize];
        (first, start[(s.leaf_first + s.leaf_count) as usize] - first)
    };
    // The triangles of a node's leaves, each leaf turned about its centre onto the node's plane
    // (the paper's "moving and rotating the leaves a little toward their common planes"): the
    // least rotation taking its normal (or the normal's opposite, whichever is nearer) to the
    // plane's, so a leaf keeps its shape and area on the plane instead of being foreshortened
    // by the projection; a leaf that is not flat turns only by its flatness's share of that
    // rotation. Positions relative to the origin of work.
    let (leaf_sets, leaf_data) = (&leaves, &data);
    // Each item is (the leaf's place in the node's run, the triangle, its placed corners).
    let placed_leaves = |node: usize| {
        let (first, count) = run(node);
        let n = nodes[node].plane.normal;
        ordered[first as usize..(first + count) as usize].iter().enumerate().flat_map(move |(k, &l)| {
            let leaf = &leaf_data[l as usize];
            let from = if leaf.normal.dot(n) < 0.0 { -leaf.normal } else { leaf.normal };
            // A leaf turns as far as it is flat: a closed blob has no plane of its own to turn.
            let turn = DQuat::IDENTITY.slerp(DQuat::from_rotation_arc(from, n), leaf.flatness);
            leaf_sets.triangles_of(&leaf_sets.leaves[l as usize]).iter().map(move |&t| {
                let corners =
                    mesh.triangles[t as usize].v.map(|v| leaf.centre + turn * (position(v) - origin - leaf.centre));
                (k, t, corners)
            })
        })
    };
    let placed_triangles = |node: usize| placed_leaves(node).map(|(_, t, corners)| (t, corners));

    // Stage: quads.
    let quads: Vec<Quad> = (0..nodes.len())
        .into_par_iter()
        .map(|i| quad(&nodes[i].plane, placed_triangles(i).flat_map(|(_, c)| c)))
        .collect();

    // Stage: atlas layout, shrinking the density until it fits. The RGBA layout also sets each
    // tree's texel budget, whichever texturing is used.
    let mut density = config.texels_per_metre;
    let (regions, width, height) = loop {
        let (regions, width, height) = layout(&quads, density, config.max_texels);
        if (width <= config.max_atlas && height <= config.max_atlas) || density < 1e-3 {
            break (regions, width, height);
        }
        density *= 0.75;
    };
    let mut texels_per_tree = vec![0u64; trees.last().map_or(0, |&t| t as usize + 1)];
    for (region, &tree) in regions.iter().zip(&node_tree) {
        texels_per_tree[tree as usize] += region.texels();
    }

    let (mut texturing, mut note) = (config.texturing, None);
    if texturing == Texturing::Indirect {
        let most = nodes.iter().enumerate().map(|(i, _)| run(i).1).max().unwrap_or(0);
        if let Err(why) = indirect_applies(mesh, most) {
            note = Some(format!("indirect impostor texturing not used: {why}; the planes get an RGBA atlas"));
            texturing = Texturing::Direct;
        }
    }
    let mut slot_layout: Option<Vec<Region>> = None;
    let atlas = match texturing {
        Texturing::Direct => {
            // Stage: bake each plane's leaves into its region, with mips, and compose the atlas.
            let baked: Vec<Vec<Vec<u8>>> = (0..nodes.len())
                .into_par_iter()
                .map(|i| {
                    bake(
                        mesh,
                        placed_triangles(i),
                        &nodes[i].plane,
                        Winner::Nearest,
                        &quads[i],
                        &regions[i],
                        SAMPLES,
                        false,
                    )
                    .levels
                })
                .collect();
            let texels = compose(&regions, &baked, width, height);
            Atlas { width, height, format: image_format::RGBA8_SRGB, mip_count: MIP_LEVELS, texels }
        }
        Texturing::Indirect => {
            // Stage: the leaf-slot image (spec §6.10.1) at `slots_per_leaf` texels across the
            // median leaf, shrunk until it fits.
            let mut areas: Vec<f64> = data.iter().map(|d| d.moments.weight).filter(|a| *a > 0.0).collect();
            areas.sort_by(f64::total_cmp);
            let median = areas.get(areas.len() / 2).copied().unwrap_or(1.0);
            #[expect(clippy::cast_possible_truncation, reason = "texels per metre")]
            let mut slot_density = (f64::from(config.slots_per_leaf) / median.sqrt()) as f32;
            let (slot_regions, sw, sh) = loop {
                let mut regions: Vec<Region> = quads
                    .iter()
                    .map(|q| {
                        let r = layout_side(q.u.length(), slot_density, config.max_texels);
                        let t = layout_side(q.v.length(), slot_density, config.max_texels);
                        Region { tw: r, th: t, rw: r + 2, rh: t + 2, x: 0, y: 0 }
                    })
                    .collect();
                let (w, h) = pack(&mut regions);
                if (w <= config.max_atlas && h <= config.max_atlas) || slot_density < 1e-3 {
                    break (regions, w, h);
                }
                slot_density *= 0.75;
            };
            let baked: Vec<Vec<[u16; 2]>> = (0..nodes.len())
                .into_par_iter()
                .map(|i| bake_slots(mesh, placed_leaves(i), &nodes[i].plane, &quads[i], &slot_regions[i]))
                .collect();
            let mut texels = vec![0u8; sw as usize * sh as usize * 4];
            for (region, slots) in slot_regions.iter().zip(&baked) {
                for (k, pair) in slots.iter().enumerate() {
                    let (x, y) = (
                        region.x as usize + 1 + k % region.tw as usize,
                        region.y as usize + 1 + k / region.tw as usize,
                    );
                    let o = (y * sw as usize + x) * 4;
                    texels[o..o + 2].copy_from_slice(&pair[0].to_le_bytes());
                    texels[o + 2..o + 4].copy_from_slice(&pair[1].to_le_bytes());
                }
            }
            slot_layout = Some(slot_regions);
            Atlas { width: sw, height: sh, format: image_format::LEAF_SLOTS, mip_count: 1, texels }
        }
    };

    // Stage: each plane's diffuse response, over its leaves' shading normals.
    let plane_diffuse: Vec<PlaneDiffuseRecord> = spt
        .order
        .par_iter()
        .map(|&i| {
            let q = &quads[i as usize];
            let items: Vec<(DVec3, f64)> =
                placed_triangles(i as usize).map(|(t, corners)| diffuse_item(mesh, t, corners)).collect();
            plane_diffuse(q.u.cross(q.v).normalize_or(DVec3::Y), &items)
        })
        .collect();

    // Stage: the records in SPT order, and the bounds of the quads.
    let (mut bmin, mut bmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let mut planes = Vec::with_capacity(nodes.len());
    let mut plane_ao = Vec::new();
    let mut plane_leaves = Vec::new();
    for &i in &spt.order {
        if !mesh.occlusion.is_empty() {
            plane_ao.push(seen_triangle_occlusion(mesh, placed_triangles(i as usize)));
        }
        let (q, r, s) = (&quads[i as usize], &regions[i as usize], &spt.nodes[i as usize]);
        let centre = q.centre + origin;
        for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let corner = (centre + q.u * su + q.v * sv).as_vec3();
            bmin = bmin.min(corner);
            bmax = bmax.max(corner);
        }
        let (leaf_first, leaf_count) = run(i as usize);
        let (uv_min, uv_max) = match &slot_layout {
            Some(slots) => {
                let q = &quads[i as usize];
                let mut fits = vec![LeafFit::default(); leaf_count as usize];
                for (k, t, corners) in placed_leaves(i as usize) {
                    fits[k].add(mesh, t, corners, q);
                }
                plane_leaves.extend(fits.iter().map(LeafFit::record));
                slots[i as usize].uv_in(atlas.width, atlas.height, 1)
            }
            None => r.uv(width, height),
        };
        planes.push(PlaneRecord {
            center: centre.as_vec3().to_array(),
            axis_u: q.u.as_vec3().to_array(),
            axis_v: q.v.as_vec3().to_array(),
            image: 0,
            uv_min,
            uv_max,
            lo: s.lo,
            hi: s.hi,
            leaf_first,
            leaf_count,
        });
    }
    #[expect(clippy::cast_possible_truncation, reason = "fewer leaves than triangles")]
    let leaf_count = data.len() as u32;
    Ok(Some(Impostors {
        planes,
        atlas,
        bounds: (bmin, bmax),
        planes_per_level,
        leaves: leaf_count,
        texels_per_metre: density,
        texels_per_tree,
        plane_ao,
        plane_diffuse,
        texturing,
        plane_leaves,
        note,
    }))
}

/// The levels of one tree (module documentation): appends its nodes and counts its planes.
fn tree_levels(
    data: &[LeafData],
    ids: &[u32],
    tree: u32,
    config: &ImpostorConfig,
    nodes: &mut Vec<Node>,
    planes_per_level: &mut [u32],
) {
    let (lo, hi) = ids.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), &i| {
        (lo.min(data[i as usize].centre), hi.max(data[i as usize].centre))
    });
    let radius = 0.5 * (hi - lo).length();
    let alpha = (f64::from(config.alpha_scale) * radius).powi(2);
    let mut rng = SplitMix64(config.seed ^ u64::from(tree).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let (iterations, count) = (config.iterations, |v: usize| u32::try_from(v).unwrap_or(u32::MAX));

    // First level: the leaves.
    let moments: Vec<Moments> = ids.iter().map(|&i| data[i as usize].moments).collect();
    let leaf_error = |i: usize, p: &PlaneFit| {
        let d = &data[ids[i] as usize];
        let distance = d.centre.dot(p.normal) + p.offset;
        let cos = d.normal.dot(p.normal);
        d.moments.weight * (distance * distance + alpha * (1.0 - cos * cos).max(0.0))
    };
    let assign = kmeans(&moments, leaf_error, config.levels[0] as usize, alpha, iterations, &mut rng);
    let clusters = assign.iter().max().map_or(0, |&m| m as usize + 1);
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); clusters];
    for (&leaf, &c) in ids.iter().zip(&assign) {
        members[c as usize].push(leaf);
    }
    let mut current: Vec<u32> = Vec::with_capacity(clusters);
    for leaves in members {
        let mut sum = Moments::default();
        for &l in &leaves {
            sum.add(&data[l as usize].moments);
        }
        current.push(count(nodes.len()));
        nodes.push(Node::new(Vec::new(), leaves, sum, alpha));
    }
    planes_per_level[0] += count(current.len());

    // Each next level: the previous level's clusters as wholes.
    for (level, &k) in config.levels.iter().enumerate().skip(1) {
        if k as usize >= current.len() {
            planes_per_level[level] += count(current.len());
            continue;
        }
        let groups: Vec<Moments> = current.iter().map(|&n| nodes[n as usize].moments).collect();
        let assign = kmeans(&groups, |i, p| groups[i].error(p, alpha), k as usize, alpha, iterations, &mut rng);
        let clusters = assign.iter().max().map_or(0, |&m| m as usize + 1);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); clusters];
        for (&node, &c) in current.iter().zip(&assign) {
            members[c as usize].push(node);
        }
        current = members
            .into_iter()
            .map(|children| {
                if let [only] = children[..] {
                    return only;
                }
                let mut sum = Moments::default();
                for &c in &children {
                    sum.add(&nodes[c as usize].moments);
                }
                nodes.push(Node::new(children, Vec::new(), sum, alpha));
                count(nodes.len() - 1)
            })
            .collect();
        planes_per_level[level] += count(current.len());
    }
}

/// The smallest of [`QUAD_ANGLES`] rectangles in `plane` holding the projections of `points`.
fn quad(plane: &PlaneFit, points: impl Iterator<Item = DVec3>) -> Quad {
    let n = plane.normal;
    let (t1, t2) = n.any_orthonormal_pair();
    let flat: Vec<DVec2> = points.map(|p| DVec2::new(p.dot(t1), p.dot(t2))).collect();
    let extent = |axis: DVec2| {
        flat.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), q| {
            let t = q.dot(axis);
            (lo.min(t), hi.max(t))
        })
    };
    let mut best = (f64::INFINITY, DVec2::X);
    for k in 0..QUAD_ANGLES {
        let angle = std::f64::consts::FRAC_PI_2 * f64::from(k) / f64::from(QUAD_ANGLES);
        let axis = DVec2::from_angle(angle);
        let (a, b) = (extent(axis), extent(axis.perp()));
        let area = (a.1 - a.0) * (b.1 - b.0);
        if area < best.0 {
            best = (area, axis);
        }
    }
    let u = t1 * best.1.x + t2 * best.1.y;
    let v = n.cross(u);
    let extent3 = |axis: DVec3| {
        flat.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), q| {
            let t = (t1 * q.x + t2 * q.y).dot(axis);
            (lo.min(t), hi.max(t))
        })
    };
    let ((u0, u1), (v0, v1)) = (extent3(u), extent3(v));
    if !(u0 <= u1 && v0 <= v1) {
        return Quad { centre: -n * plane.offset, u: u * 1e-3, v: v * 1e-3 };
    }
    // At least a millimetre across, so the quad is never degenerate.
    let (hu, hv) = ((0.5 * (u1 - u0)).max(5e-4), (0.5 * (v1 - v0)).max(5e-4));
    Quad { centre: -n * plane.offset + u * (0.5 * (u0 + u1)) + v * (0.5 * (v0 + v1)), u: u * hu, v: v * hv }
}

/// Region sizes at `density` texels per metre and their shelf packing (tallest first): the
/// regions, in node order, and the atlas size.
fn layout(quads: &[Quad], density: f32, max_texels: u32) -> (Vec<Region>, u32, u32) {
    let texels = |half: f64| layout_side(half, density, max_texels);
    let mut regions: Vec<Region> =
        quads.iter().map(|q| Region::new(texels(q.u.length()), texels(q.v.length()))).collect();
    let (width, height) = pack(&mut regions);
    (regions, width, height)
}

/// Texels across a quad side of half-length `half` metres at `density` texels per metre,
/// `1 ..= max_texels`.
fn layout_side(half: f64, density: f32, max_texels: u32) -> u32 {
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 1..=max_texels")]
    let t = (2.0 * half * f64::from(density)).ceil().clamp(1.0, f64::from(max_texels)) as u32;
    t
}

/// Shelf-packs `regions` ([`shelf_pack`]) into an atlas a power of two wide (at least the
/// widest region) and returns its size.
fn pack(regions: &mut [Region]) -> (u32, u32) {
    let area: u64 = regions.iter().map(|r| u64::from(r.rw) * u64::from(r.rh)).sum();
    let widest = regions.iter().map(|r| r.rw).max().unwrap_or(ALIGN);
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a square root of a u64 area")]
    let side = (area as f64).sqrt().ceil() as u32;
    let width = side.next_power_of_two().max(widest).max(ALIGN);
    (width, shelf_pack(regions, width))
}

/// Shelf-packs `regions` (tallest first, then widest, then in order) into an atlas `width`
/// texels wide (a multiple of [`ALIGN`], at least the widest region), sets each region's place
/// and returns the atlas's height.
pub(crate) fn shelf_pack(regions: &mut [Region], width: u32) -> u32 {
    let mut order: Vec<usize> = (0..regions.len()).collect();
    order.sort_by(|&a, &b| regions[b].rh.cmp(&regions[a].rh).then(regions[b].rw.cmp(&regions[a].rw)).then(a.cmp(&b)));
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    for i in order {
        let r = &mut regions[i];
        if x + r.rw > width {
            y += shelf;
            x = 0;
            shelf = 0;
        }
        r.x = x;
        r.y = y;
        x += r.rw;
        shelf = shelf.max(r.rh);
    }
    align((y + shelf).max(1))
}

/// The atlas texels of all [`MIP_LEVELS`] levels, largest first, of a `width × height` atlas
/// holding each region's levels from [`bake`] at its place; zero elsewhere.
pub(crate) fn compose(regions: &[Region], baked: &[Vec<Vec<u8>>], width: u32, height: u32) -> Vec<u8> {
    let mut texels = Vec::new();
    for level in 0..MIP_LEVELS {
        let (w, h) = ((width >> level) as usize, (height >> level) as usize);
        let at = texels.len();
        texels.resize(at + w * h * 4, 0);
        let image = &mut texels[at..];
        for (region, chain) in regions.iter().zip(baked) {
            let (rx, ry, rw) =
                ((region.x >> level) as usize, (region.y >> level) as usize, (region.rw >> level) as usize);
            for (row, line) in chain[level as usize].chunks_exact(rw * 4).enumerate() {
                let o = ((ry + row) * w + rx) * 4;
                image[o..o + rw * 4].copy_from_slice(line);
            }
        }
    }
    texels
}

/// Draws the triangles `triangles` (index into `mesh.triangles` and placed corners, relative to
/// the origin of work) onto `quad` (module documentation; `winner` keeps a sample where they
/// overlap, by the distance from `plane`) and returns the region's levels, RGBA8 sRGB, each
/// `(rw >> l) × (rh >> l)`, each texel the mean of `samples × samples` samples ([`SAMPLES`] for
/// planes and billboards). The sample at `quad.centre + s·u + t·v` lands at `((s + 1)/2,
/// (t + 1)/2)` of the content rectangle, rows top to bottom (spec §6.10's texture coordinates).
/// With `view` (an octahedral impostor's view, spec §6.13.2–§6.13.3), also the sums that fit a
/// plane to the covered samples' depths ([`DepthMoments`]) and the region's normal levels
/// ([`Baked::normals`]); both empty without.
#[expect(clippy::too_many_arguments, reason = "the triangles, the quad, its sampling and what else to measure")]
pub(crate) fn bake(
    mesh: &ImpostorMesh<'_>,
    triangles: impl Iterator<Item = (u32, [DVec3; 3])> + Clone + Sync,
    plane: &PlaneFit,
    winner: Winner,
    quad: &Quad,
    region: &Region,
    samples: usize,
    view: bool,
) -> Baked {
    let lut = srgb_to_linear_table();
    let mut moments = DepthMoments::default();
    let (sw, sh) = (region.tw as usize * samples, region.th as usize * samples);
    let (hu, hv) = (quad.u.length(), quad.v.length());
    // Metres along the quad's u (v) of sample column (row) `x` (`y`), from its centre; a
    // sample's depth: its signed distance to `plane` (only `Front` keeps its sign).
    let along_u = |x: usize| ((x as f64 + 0.5) / sw as f64 * 2.0 - 1.0) * hu;
    let along_v = |y: usize| ((y as f64 + 0.5) / sh as f64 * 2.0 - 1.0) * hv;
    let signed_depth = |key: f32| match winner {
        Winner::Nearest => f64::from(key),
        Winner::Front => -f64::from(key),
    };
    let (rw, rh) = (region.rw as usize, region.rh as usize);
    let mut texels = vec![[0.0f32; 4]; rw * rh];
    // With `view`: per texel the covered samples' mean normal (turned towards the viewer, the
    // side of `plane.normal`) and mean ambient occlusion.
    let mut normal_texels = vec![[0.0f32; 4]; if view { rw * rh } else { 0 }];
    let g = GUTTER as usize;
    // The samples of `BAND_ROWS` texel rows at a time, each band going over every triangle: a
    // sample sees the same triangles in the same order as in one pass, so the result is the
    // same, and the samples of a large quad (a whole-tree billboard of millions of texels) need
    // a band's memory per thread baking one, not the quad's.
    let band_samples = BAND_ROWS * samples;
    let rows = covered_rows(triangles.clone().map(|(_, local)| local), quad, (sw, sh));
    // Alpha planes of the images, where a quad has more samples than the image has texels.
    let planes: Vec<Option<Vec<u8>>> = mesh
        .surfaces
        .iter()
        .map(|surface| surface.image.filter(|img| sw * sh >= img.rgba.len() / 4).map(alpha_plane))
        .collect();
    // Band `b` of texel rows into `out`, its rows of the region (full width), with `scratch`'s
    // buffers; the texels' normals into `normals_out` and the covered samples' depths to
    // `moments` where given.
    let band = |b: usize,
                out: &mut [[f32; 4]],
                mut normals_out: Option<&mut [[f32; 4]]>,
                scratch: &mut BandScratch,
                mut moments: Option<&mut DepthMoments>| {
        let BandScratch { depth, colour, normal, pending, located, alphas } = scratch;
        let band_start = b * band_samples;
        let band_end = (band_start + band_samples).min(sh);
        depth.clear();
        depth.resize(sw * band_samples.min(sh), f32::INFINITY);
        colour.resize(sw * band_samples.min(sh), [0.0; 3]);
        if normals_out.is_some() {
            normal.resize(sw * band_samples.min(sh), [0.0; 4]);
        }
        for ((t, local), &(y0, y1)) in triangles.clone().zip(&rows) {
            if y1 as usize <= band_start || y0 as usize >= band_end {
                continue;
            }
            // The samples that pass the depth test, then their texels, then their shading: a
            // triangle covers each sample once, so this is the order of shading each in turn,
            // and the texel loads, with no branch between them, overlap their cache misses.
            pending.clear();
            raster_band(&local, quad, plane, (sw, sh), (band_start, band_end), |i, w, signed| {
                // The sample's key: the least wins (ties: the first triangle).
                #[expect(clippy::cast_possible_truncation, reason = "a distance in metres")]
                let z = match winner {
                    Winner::Nearest => signed.abs() as f32,
                    Winner::Front => -signed as f32,
                };
                if z < depth[i] {
                    pending.push((i, z, weights(w)));
                }
            });
            // Most triangles of a large tree on a small view cover no sample, or only hidden
            // ones: their corners are not loaded.
            if pending.is_empty() {
                continue;
            }
            let tri = &mesh.triangles[t as usize];
            let shading = Shading::new(
                &mesh.surfaces[tri.material as usize],
                planes[tri.material as usize].as_deref(),
                tri.v.map(|v| &mesh.vertices[v as usize]),
                lut,
            );
            located.clear();
            located.extend(pending.iter().map(|&(_, _, w)| shading.locate(w)));
            alphas.clear();
            alphas.extend(located.iter().map(|&n| shading.alpha(n)));
            // The triangle's normal at a sample, towards the viewer, and its occlusion.
            let occlusion = mesh.occlusion.get(t as usize).copied().unwrap_or(0.0).clamp(0.0, 1.0);
            for ((&(i, z, w), &n), &alpha) in pending.iter().zip(located.iter()).zip(alphas.iter()) {
                if shading.passes(w, alpha) {
                    depth[i] = z;
                    colour[i] = shading.colour(w, shading.texel(n), lut);
                    if normals_out.is_some() {
                        let [nx, ny, nz] = shading.normal(w, &local, plane.normal);
                        normal[i] = [nx, ny, nz, occlusion];
                    }
                }
            }
        }

        // Resolve the band's samples into the region's content.
        for ty in band_start / samples..band_end / samples {
            for tx in 0..region.tw as usize {
                let (mut sum, mut normal_sum, mut covered) = ([0.0f32; 3], [0.0f32; 4], 0u32);
                for sy in 0..samples {
                    let row = (ty * samples + sy - band_start) * sw + tx * samples;
                    for (sx, i) in (row..row + samples).enumerate() {
                        if depth[i].is_finite() {
                            if let Some(moments) = moments.as_deref_mut() {
                                let (x, y) = (along_u(tx * samples + sx), along_v(ty * samples + sy));
                                moments.add(x, y, signed_depth(depth[i]), (x * x + y * y) / (hu * hv));
                            }
                            covered += 1;
                            for c in 0..3 {
                                sum[c] += colour[i][c];
                            }
                            if normals_out.is_some() {
                                for c in 0..4 {
                                    normal_sum[c] += normal[i][c];
                                }
                            }
                        }
                    }
                }
                if covered > 0 {
                    let n = covered as f32;
                    let at = (ty - band_start / samples) * rw + tx + g;
                    out[at] = [sum[0] / n, sum[1] / n, sum[2] / n, n / (samples * samples) as f32];
                    if let Some(normals_out) = normals_out.as_deref_mut() {
                        normals_out[at] = normal_sum.map(|v| v / n);
                    }
                }
            }
        }
    };
    // The bands write disjoint rows, so they are baked in parallel, each sample as in one pass;
    // but the depth fit's sums are taken in the rows' order, one band after another.
    let content = &mut texels[g * rw..(g + region.th as usize) * rw];
    if view {
        let mut scratch = BandScratch::default();
        let normal_content = &mut normal_texels[g * rw..(g + region.th as usize) * rw];
        for (b, (out, normals_out)) in
            content.chunks_mut(BAND_ROWS * rw).zip(normal_content.chunks_mut(BAND_ROWS * rw)).enumerate()
        {
            band(b, out, Some(normals_out), &mut scratch, Some(&mut moments));
        }
    } else {
        content
            .par_chunks_mut(BAND_ROWS * rw)
            .enumerate()
            .for_each_init(BandScratch::default, |scratch, (b, out)| band(b, out, None, scratch, None));
    }
    // Each mip texel the mean of its four, weighted by their coverage, the normals by the same
    // weights (the colour's alpha before coverage preservation); then each level dilated into
    // its transparent texels. A view's normals are kept at half the colour's resolution (spec
    // §6.13.3: its levels 1 to `MIP_LEVELS`), so a view computes one level more, which only its
    // normals keep.
    let mut levels = vec![texels];
    let mut normal_levels = vec![normal_texels];
    let (mut w, mut h) = (rw, rh);
    for _ in 1..MIP_LEVELS + u32::from(view) {
        let (Some(prev), Some(prev_normals)) = (levels.last(), normal_levels.last()) else { break };
        let (nw, nh) = (w / 2, h / 2);
        let mut next = Vec::with_capacity(nw * nh);
        let mut next_normals = Vec::with_capacity(if view { nw * nh } else { 0 });
        for y in 0..nh {
            for x in 0..nw {
                let four =
                    [2 * y * w + 2 * x, 2 * y * w + 2 * x + 1, (2 * y + 1) * w + 2 * x, (2 * y + 1) * w + 2 * x + 1];
                let alpha: f32 = four.iter().map(|&i| prev[i][3]).sum();
                let mean = |texels: &[[f32; 4]], c: usize| {
                    if alpha > 0.0 { four.iter().map(|&i| texels[i][c] * prev[i][3]).sum::<f32>() / alpha } else { 0.0 }
                };
                next.push([mean(prev, 0), mean(prev, 1), mean(prev, 2), alpha / 4.0]);
                if view {
                    next_normals.push(std::array::from_fn(|c| mean(prev_normals, c)));
                }
            }
        }
        levels.push(next);
        normal_levels.push(next_normals);
        (w, h) = (nw, nh);
    }
    for (l, (level, normals)) in levels.iter_mut().zip(&mut normal_levels).enumerate() {
        let covered: Vec<bool> = level.iter().map(|t| t[3] > 0.0).collect();
        if view {
            dilate(normals, rw >> l, rh >> l, covered.clone(), false);
        }
        dilate(level, rw >> l, rh >> l, covered, true);
    }
    levels.truncate(MIP_LEVELS as usize);
    preserve_coverage(&mut levels, rw, rh);
    let byte = |v: f32| {
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=255")]
        let b = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        b
    };
    let srgb = |v: f32| byte(linear_to_srgb(v));
    let bytes = levels
        .iter()
        .map(|level| level.iter().flat_map(|t| [srgb(t[0]), srgb(t[1]), srgb(t[2]), byte(t[3])]).collect())
        .collect();
    // A normal texel's RGB is `(n + 1)/2`, sRGB-encoded as the colour is (spec §6.13.3).
    let unit = |v: f32| srgb(0.5 * v + 0.5);
    let normals = if view {
        normal_levels
            .iter()
            .skip(1)
            .map(|level| level.iter().flat_map(|t| [unit(t[0]), unit(t[1]), unit(t[2]), byte(t[3])]).collect())
            .collect()
    } else {
        Vec::new()
    };
    Baked { levels: bytes, normals, moments }
}

/// What [`bake`] returns.
pub(crate) struct Baked {
    /// The region's levels, RGBA8 (RGB sRGB-encoded), largest first.
    pub levels: Vec<Vec<u8>>,
    /// With `view`, the region's normal levels, as `levels` (spec §6.13.3): RGB `(n + 1)/2` of the
    /// covered samples' mean normal turned towards the viewer, sRGB-encoded; alpha their mean
    /// ambient occlusion; each mip level the mean of its four texels weighted by their coverage,
    /// the uncovered texels dilated as the colour's are; at half the colour's resolution (its
    /// levels 1 to [`MIP_LEVELS`], `(rw >> (l + 1)) × (rh >> (l + 1))`). Empty without.
    pub normals: Vec<Vec<u8>>,
    /// With `view`, the sums that fit the view's depth plane ([`DepthMoments`]).
    pub moments: DepthMoments,
}

/// A band's buffers in [`bake`]: per sample of the band its key, colour and (an octahedral
/// view's) normal and occlusion; one triangle's samples (index in the band, key, weights), their
/// texels and alphas.
#[derive(Default)]
struct BandScratch {
    depth: Vec<f32>,
    colour: Vec<[f32; 3]>,
    normal: Vec<[f32; 4]>,
    pending: Vec<(usize, f32, [f32; 3])>,
    located: Vec<Option<usize>>,
    alphas: Vec<u8>,
}

/// The sums of a weighted least-squares fit of a plane `z = a + b·x + c·y` to the depths `z`
/// of a quad's covered samples at `(x, y)` in its plane (metres from its centre, along its u and
/// v; `z` along its normal, towards the side baked from): what an octahedral view's depth plane
/// is fitted from (spec §6.13.2). Each sample weighs `x² + y²` (over the quad's `|u|·|v|`): a
/// surface `ρ` from the view's centre drawn `Δz` off its depth moves on screen by about
/// `ρ·Δz/D` seen in perspective from `D`, so the fit keeps the silhouette, where the samples
/// are far from the centre, rather than the middle of the crown, which a wrong depth barely
/// moves. (Measured with `eval --orbit 2,8,32`, octahedral RMSE at 128–512, 32–128 and 8–32 px:
/// the Quaternius tree, whose dense round crown fits a plane badly, .0909, .00705 and .00118
/// against .1138, .00826 and .00129 with every sample weighing alike, and .0994, .00746 and
/// .00123 with weights `x² + y²` plus a quarter; the oak and the pine within 2 % of either.)
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct DepthMoments {
    /// Samples added.
    count: u64,
    /// Their weights' sum; the other fields are the weighted sums their names say.
    weight: f64,
    x: f64,
    y: f64,
    z: f64,
    xx: f64,
    xy: f64,
    yy: f64,
    xz: f64,
    yz: f64,
}

impl DepthMoments {
    /// A sample at `(x, y)` of depth `z` and weight `w`.
    fn add(&mut self, x: f64, y: f64, z: f64, w: f64) {
        self.count += 1;
        self.weight += w;
        self.x += w * x;
        self.y += w * y;
        self.z += w * z;
        self.xx += w * x * x;
        self.xy += w * x * y;
        self.yy += w * y * y;
        self.xz += w * x * z;
        self.yz += w * y * z;
    }

    /// `[a, b, c]` of the plane of least squares (`a` in metres, the slopes `b`, `c` without
    /// unit); `None` without samples. Where the samples do not span two directions (fewer
    /// than 3, or on a line), the plane of their mean depth.
    pub(crate) fn plane(&self) -> Option<[f64; 3]> {
        if self.count == 0 || self.weight <= 0.0 {
            return None;
        }
        let (mx, my, mz) = (self.x / self.weight, self.y / self.weight, self.z / self.weight);
        // Centred second moments.
        let (sxx, sxy, syy) =
            (self.xx / self.weight - mx * mx, self.xy / self.weight - mx * my, self.yy / self.weight - my * my);
        let (sxz, syz) = (self.xz / self.weight - mx * mz, self.yz / self.weight - my * mz);
        let det = sxx * syy - sxy * sxy;
        // (`det` is never negative, up to rounding; NaN falls through to the mean too.)
        if self.count < 3 || det.is_nan() || det <= 1e-12 * (sxx + syy).powi(2) {
            return Some([mz, 0.0, 0.0]);
        }
        let b = (sxz * syy - syz * sxy) / det;
        let c = (syz * sxx - sxz * sxy) / det;
        Some([mz - b * mx - c * my, b, c])
    }
}

/// A triangle projected onto a quad's sample grid: its corners in sample coordinates, twice its
/// signed area, and the samples its bounding box holds (`x0..x1`, `y0..y1`).
struct Projected {
    xy: [DVec2; 3],
    area: f64,
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

/// `local` projected onto `quad`'s `sw × sh` samples; `None` if it is degenerate.
fn project(local: &[DVec3; 3], quad: &Quad, (sw, sh): (usize, usize)) -> Option<Projected> {
    let (hu2, hv2) = (quad.u.length_squared(), quad.v.length_squared());
    // Sample coordinates: s = −1 ↦ 0, s = +1 ↦ sw (likewise t and sh).
    let at = |p: DVec3| {
        let d = p - quad.centre;
        DVec2::new((d.dot(quad.u) / hu2 + 1.0) * 0.5 * sw as f64, (d.dot(quad.v) / hv2 + 1.0) * 0.5 * sh as f64)
    };
    // Written out: `local.map(at)` was a call per corner (its closure not inlined), on the path
    // every triangle takes once per view.
    let xy = [at(local[0]), at(local[1]), at(local[2])];
    let area = (xy[1] - xy[0]).perp_dot(xy[2] - xy[0]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return None;
    }
    let (min, max) = (xy[0].min(xy[1]).min(xy[2]), xy[0].max(xy[1]).max(xy[2]));
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped into the grid")]
    let (x0, x1, y0, y1) = (
        (min.x - 0.5).ceil().max(0.0) as usize,
        ((max.x - 0.5).floor() + 1.0).clamp(0.0, sw as f64) as usize,
        (min.y - 0.5).ceil().max(0.0) as usize,
        ((max.y - 0.5).floor() + 1.0).clamp(0.0, sh as f64) as usize,
    );
    Some(Projected { xy, area, x0, x1, y0, y1 })
}

/// Whether a triangle may cover a sample of a quad's grid: the bounding box of its corners
/// projected onto `quad`'s `samples` (columns, rows), widened by [`MayCover::MARGIN`], holds a
/// sample centre. It says `true` of every triangle whose box [`project`] finds holding one (the
/// others draw nothing there, and [`bake`] skips them), with one product and sum per axis and
/// corner where `project` divides: a view of many samples tests every triangle of its tree, and
/// bakes only the few that may cover a sample.
pub(crate) struct MayCover {
    /// Per axis, the sample coordinate of a corner `p` (relative to the origin of work) is
    /// `p · scale + offset`.
    scale: [DVec3; 2],
    offset: [f64; 2],
    /// The last sample column and row.
    last: [f64; 2],
}

impl MayCover {
    /// How far past a triangle's box, in samples, a centre is still taken as in it: far more than
    /// the rounding by which these products and sums differ from [`project`]'s quotients (about
    /// 10⁻¹¹ samples for a tree 100 metres across in a grid of 8,192 samples).
    const MARGIN: f64 = 1e-6;

    pub(crate) fn new(quad: &Quad, (sw, sh): (usize, usize)) -> Self {
        #[expect(clippy::cast_precision_loss, reason = "sample counts")]
        let (sw, sh) = (sw as f64, sh as f64);
        // (d·u/|u|² + 1)·sw/2 with d = p − centre.
        let scale = [quad.u * (0.5 * sw / quad.u.length_squared()), quad.v * (0.5 * sh / quad.v.length_squared())];
        let offset = [0.5 * sw - quad.centre.dot(scale[0]), 0.5 * sh - quad.centre.dot(scale[1])];
        Self { scale, offset, last: [sw - 1.0, sh - 1.0] }
    }

    /// Whether `local` may cover a sample (the documentation of [`MayCover`]).
    pub(crate) fn test(&self, local: &[DVec3; 3]) -> bool {
        (0..2).all(|axis| {
            let at = |p: DVec3| p.dot(self.scale[axis]) + self.offset[axis];
            let (a, b, c) = (at(local[0]), at(local[1]), at(local[2]));
            let (lo, hi) = (a.min(b).min(c) - 0.5 - Self::MARGIN, a.max(b).max(c) - 0.5 + Self::MARGIN);
            // Some whole k with max(lo, 0) ≤ k ≤ min(hi, last): the largest whole number up to
            // the upper end is not below the lower end. (`max` and `min` pass over a NaN; a
            // corner that is not finite gives `project` no box.)
            let (lo, hi) = (lo.max(0.0), hi.min(self.last[axis]));
            #[expect(clippy::cast_precision_loss, reason = "at most the last sample; far below 0, it stays below")]
            let last_whole = floor_f64(hi) as f64;
            last_whole >= lo
        })
    }
}

/// The sample rows `y0..y1` of the bounding box of `local` projected onto `quad`'s `samples`,
/// where that box holds a sample centre.
fn boxed_rows(local: &[DVec3; 3], quad: &Quad, samples: (usize, usize)) -> Option<(usize, usize)> {
    project(local, quad, samples).filter(|p| p.x0 < p.x1 && p.y0 < p.y1).map(|p| (p.y0, p.y1))
}

/// The sample rows `y0..y1` each triangle of `triangles` covers on `quad` (an empty range for
/// one that covers none), found once so that a band skips the triangles outside it without
/// projecting them again: a quad of many bands (a whole-tree billboard) otherwise projects every
/// triangle once per band.
fn covered_rows(triangles: impl Iterator<Item = [DVec3; 3]>, quad: &Quad, samples: (usize, usize)) -> Vec<(u32, u32)> {
    triangles
        .map(|local| match boxed_rows(&local, quad, samples) {
            #[expect(clippy::cast_possible_truncation, reason = "sample rows of a region fit u32")]
            Some((y0, y1)) => (y0 as u32, y1 as u32),
            None => (0, 0),
        })
        .collect()
}

/// Calls `f(sample index in the band, barycentric weights, signed distance from plane)` for
/// every sample centre of rows `band_start .. band_end` of a `sw × sh` grid over `quad` that the
/// triangle `local` (relative to the origin of work) covers. The sample at `quad.centre + s·u +
/// t·v` has grid coordinates `((s + 1)/2·sw, (t + 1)/2·sh)`.
fn raster_band(
    local: &[DVec3; 3],
    quad: &Quad,
    plane: &PlaneFit,
    (sw, sh): (usize, usize),
    (band_start, band_end): (usize, usize),
    mut f: impl FnMut(usize, [f64; 3], f64),
) {
    let Some(Projected { xy, area, x0, x1, y0, y1 }) = project(local, quad, (sw, sh)) else {
        return;
    };
    let (y0, y1) = (y0.max(band_start), y1.min(band_end));
    if y0 >= y1 || x0 >= x1 {
        return;
    }
    let dist = local.map(|p| p.dot(plane.normal) + plane.offset);
    for sy in y0..y1 {
        let (x0, x1) = row_span(&xy, area, sy as f64 + 0.5, (x0, x1));
        for sx in x0..x1 {
            let p = DVec2::new(sx as f64 + 0.5, sy as f64 + 0.5);
            let w1 = (p - xy[0]).perp_dot(xy[2] - xy[0]) / area;
            let w2 = (xy[1] - xy[0]).perp_dot(p - xy[0]) / area;
            let w0 = 1.0 - w1 - w2;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            f((sy - band_start) * sw + sx, [w0, w1, w2], w0 * dist[0] + w1 * dist[1] + w2 * dist[2]);
        }
    }
}

/// The samples `x0..x1` of a row, of centre height `y` on the sample grid, that can lie in the
/// triangle `xy` (twice its signed area `area`): the row's crossing with each edge's inner side,
/// widened by [`SPAN_MARGIN`] samples, within `x0..x1`. [`raster_band`] still tests each sample of
/// the span as it tests every sample of the bounding box, so it takes the same ones; the margin
/// covers the rounding of that test and of this crossing many times over. An edge too near to
/// horizontal for its crossing to be found to much better than a sample bounds nothing.
fn row_span(xy: &[DVec2; 3], area: f64, y: f64, (x0, x1): (usize, usize)) -> (usize, usize) {
    let scale = xy.iter().map(|p| p.abs().max_element()).fold(1.0f64, f64::max);
    let flat = 1e-12 * scale * scale;
    #[expect(clippy::cast_precision_loss, reason = "sample counts of a region")]
    let (mut lo, mut hi) = (x0 as f64, x1 as f64);
    for (a, b) in [(xy[0], xy[1]), (xy[1], xy[2]), (xy[2], xy[0])] {
        let dy = b.y - a.y;
        if dy.abs() <= flat {
            continue;
        }
        // Where the edge's line meets the row; the triangle lies left of it if the edge rises
        // in a counter-clockwise triangle (positive area) or falls in a clockwise one.
        let cross = a.x + (y - a.y) * (b.x - a.x) / dy;
        if (dy > 0.0) == (area > 0.0) {
            hi = hi.min(cross + SPAN_MARGIN);
        } else {
            lo = lo.max(cross - SPAN_MARGIN - 1.0);
        }
    }
    if lo >= hi {
        return (x0, x0);
    }
    // Sample `sx` has its centre at `sx + 0.5`.
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "within x0..=x1")]
    let span = (lo.floor().max(x0 as f64) as usize, (hi.ceil() as usize).min(x1));
    span
}

/// The leaf slots (spec §6.10.1) of one plane's region: `leaves` are (the leaf's place in the
/// plane's run, triangle, placed corners). Each of 4 × 4 samples per texel takes the leaf nearest
/// to the plane that passes its alpha test there ([`shade`]); a texel's slot `a` is the leaf of
/// most of its samples, `b` the next (ties: the lower slot). Returns the `tw × th` content texels,
/// rows top to bottom.
fn bake_slots(
    mesh: &ImpostorMesh<'_>,
    leaves: impl Iterator<Item = (usize, u32, [DVec3; 3])> + Clone,
    plane: &PlaneFit,
    quad: &Quad,
    region: &Region,
) -> Vec<[u16; 2]> {
    let lut = srgb_to_linear_table();
    let (tw, th) = (region.tw as usize, region.th as usize);
    let (sw, sh) = (tw * SAMPLES, th * SAMPLES);
    let mut texels = vec![[0u16; 2]; tw * th];
    let band_samples = BAND_ROWS * SAMPLES;
    let mut depth = vec![f32::INFINITY; sw * band_samples.min(sh)];
    let mut slot = vec![0u16; sw * band_samples.min(sh)];
    let rows = covered_rows(leaves.clone().map(|(_, _, local)| local), quad, (sw, sh));
    for band_start in (0..sh).step_by(band_samples.max(1)) {
        let band_end = (band_start + band_samples).min(sh);
        depth.fill(f32::INFINITY);
        slot.fill(0);
        for ((k, t, local), &(y0, y1)) in leaves.clone().zip(&rows) {
            if y1 as usize <= band_start || y0 as usize >= band_end {
                continue;
            }
            let tri = &mesh.triangles[t as usize];
            let shading = Shading::new(
                &mesh.surfaces[tri.material as usize],
                None,
                tri.v.map(|v| &mesh.vertices[v as usize]),
                lut,
            );
            #[expect(clippy::cast_possible_truncation, reason = "indirect_applies checked the leaf count")]
            let k = k as u16 + 1;
            raster_band(&local, quad, plane, (sw, sh), (band_start, band_end), |i, w, signed| {
                #[expect(clippy::cast_possible_truncation, reason = "a distance in metres")]
                let z = signed.abs() as f32;
                if z < depth[i] && shade(&shading, w, lut).is_some() {
                    depth[i] = z;
                    slot[i] = k;
                }
            });
        }
        for ty in band_start / SAMPLES..band_end / SAMPLES {
            for tx in 0..tw {
                // (slot, samples), at most 16 entries.
                let mut counts: Vec<(u16, u32)> = Vec::with_capacity(SAMPLES * SAMPLES);
                for sy in 0..SAMPLES {
                    let row = (ty * SAMPLES + sy - band_start) * sw + tx * SAMPLES;
                    for &k in &slot[row..row + SAMPLES] {
                        if k == 0 {
                            continue;
                        }
                        match counts.iter_mut().find(|c| c.0 == k) {
                            Some(c) => c.1 += 1,
                            None => counts.push((k, 1)),
                        }
                    }
                }
                counts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
                let pick = |n: usize| counts.get(n).map_or(0, |c| c.0);
                texels[ty * tw + tx] = [pick(0), pick(1)];
            }
        }
    }
    texels
}

/// Whether indirect texturing can stand for a mesh's leaves (spec §6.10.1): every leaf
/// material has an image and alpha mode `MASK` or `BLEND` (so a leaf's outline is in its
/// texture, not in its geometry), and no plane holds more leaves than a slot can name.
fn indirect_applies(mesh: &ImpostorMesh<'_>, most_leaves: u32) -> Result<(), String> {
    let mut used = vec![false; mesh.surfaces.len()];
    for t in mesh.triangles {
        used[t.material as usize] = true;
    }
    for (surface, _) in mesh.surfaces.iter().zip(&used).filter(|(_, u)| **u) {
        let name = &surface.material.name;
        if surface.image.is_none() {
            return Err(format!("leaf material '{name}' has no texture, so its leaves' outline is geometry"));
        }
        if surface.material.alpha_mode == AlphaMode::Opaque {
            return Err(format!("leaf material '{name}' is OPAQUE, so its leaves' outline is geometry, not alpha"));
        }
    }
    if most_leaves > u32::from(u16::MAX) {
        return Err(format!("a plane holds {most_leaves} leaves, more than the 65535 a slot can name"));
    }
    Ok(())
}

/// The weighted least-squares fit of one leaf's affine map from plane coordinates `(s, t)` to
/// texture coordinates (spec §6.10.1), each triangle's corners weighted by its area as
/// projected on the plane, and its colour and material.
#[derive(Clone, Copy, Debug)]
struct LeafFit {
    /// `Σ w`.
    weight: f64,
    /// `Σ w st`, `Σ w uv`.
    st: DVec2,
    uv: DVec2,
    /// `Σ w st stᵀ`, `Σ w uv stᵀ`.
    st_st: DMat2,
    uv_st: DMat2,
    /// `Σ w colour` (bytes as stored, RGBA).
    colour: [f64; 4],
    /// Bounds of the vertices' texture coordinates.
    uv_min: DVec2,
    uv_max: DVec2,
    /// The material of the heaviest triangle, and its weight.
    material: (u32, f64),
}

impl Default for LeafFit {
    // Not derived: glam's matrices default to the identity.
    fn default() -> Self {
        Self {
            weight: 0.0,
            st: DVec2::ZERO,
            uv: DVec2::ZERO,
            st_st: DMat2::ZERO,
            uv_st: DMat2::ZERO,
            colour: [0.0; 4],
            uv_min: DVec2::ZERO,
            uv_max: DVec2::ZERO,
            material: (0, 0.0),
        }
    }
}

fn outer2(a: DVec2, b: DVec2) -> DMat2 {
    DMat2::from_cols(a * b.x, a * b.y)
}

impl LeafFit {
    fn add(&mut self, mesh: &ImpostorMesh<'_>, t: u32, corners: [DVec3; 3], quad: &Quad) {
        let tri = &mesh.triangles[t as usize];
        let (hu2, hv2) = (quad.u.length_squared(), quad.v.length_squared());
        let st = corners.map(|p| {
            let d = p - quad.centre;
            DVec2::new(d.dot(quad.u) / hu2, d.dot(quad.v) / hv2)
        });
        // Area in (s, t) units; the plane's metres would only scale every weight alike.
        let w = 0.5 * (st[1] - st[0]).perp_dot(st[2] - st[0]).abs();
        if !(w > 0.0 && w.is_finite()) {
            return;
        }
        if w > self.material.1 {
            self.material = (tri.material, w);
        }
        for (k, &v) in tri.v.iter().enumerate() {
            let vertex = &mesh.vertices[v as usize];
            let uv = DVec2::new(f64::from(vertex.uv[0]), f64::from(vertex.uv[1]));
            if self.weight == 0.0 {
                (self.uv_min, self.uv_max) = (uv, uv);
            }
            self.uv_min = self.uv_min.min(uv);
            self.uv_max = self.uv_max.max(uv);
            self.weight += w;
            self.st += st[k] * w;
            self.uv += uv * w;
            self.st_st += outer2(st[k], st[k]) * w;
            self.uv_st += outer2(uv, st[k]) * w;
            for (c, byte) in self.colour.iter_mut().zip(vertex.color.to_le_bytes()) {
                *c += w * f64::from(byte);
            }
        }
    }

    /// The record: `uv = ū + J (st − m)` with `J = Cov(uv, st) Cov(st)⁻¹` about the weighted
    /// means; a leaf whose projection has no area (or is a line) gets its mean texture
    /// coordinates and `J = 0`.
    #[expect(clippy::cast_possible_truncation, reason = "texture coordinates and colour bytes")]
    fn record(&self) -> PlaneLeafRecord {
        if self.weight <= 0.0 || self.weight.is_nan() {
            return PlaneLeafRecord { color: u32::MAX, ..PlaneLeafRecord::default() };
        }
        let (m, mean_uv) = (self.st / self.weight, self.uv / self.weight);
        let cov = self.st_st * (1.0 / self.weight) - outer2(m, m);
        let cross = self.uv_st * (1.0 / self.weight) - outer2(mean_uv, m);
        let det = cov.determinant();
        let trace = cov.x_axis.x + cov.y_axis.y;
        // A flat 2D spread has det ≈ trace²/4; an edge-on leaf (a line) has det ≈ 0.
        let j = if det > 1e-9 * trace * trace && det.is_finite() { cross * cov.inverse() } else { DMat2::ZERO };
        let uv0 = mean_uv - j * m;
        let colour = self.colour.map(|c| (c / self.weight).round().clamp(0.0, 255.0) as u8);
        // A rectangle inside the image (a card); texture coordinates that leave it repeat the
        // texture across the leaf, and the leaf is not clipped (spec §6.10.1).
        let slack = 1e-3;
        let unit = self.uv_min.min_element() >= -slack && self.uv_max.max_element() <= 1.0 + slack;
        PlaneLeafRecord {
            uv0: [uv0.x as f32, uv0.y as f32],
            du: [j.x_axis.x as f32, j.x_axis.y as f32],
            dv: [j.y_axis.x as f32, j.y_axis.y as f32],
            uv_min: if unit { pack::unorm16x2(self.uv_min.x as f32, self.uv_min.y as f32) } else { 0 },
            uv_max: if unit { pack::unorm16x2(self.uv_max.x as f32, self.uv_max.y as f32) } else { 0 },
            material: self.material.0,
            color: u32::from_le_bytes(colour),
        }
    }
}

/// Scales each level's alpha so that the alpha test at one half, of the bilinearly filtered
/// alpha as a GPU samples it, covers the fraction of the region that the leaves cover (the mean
/// alpha, which the box filter keeps at every level). This is Castaño's "Computing alpha
/// mipmaps" (2010), measured through the filter: averaged coverage of scattered leaves falls
/// below one half, and bilinear filtering shrinks an isolated passing texel to about 0.6 of its
/// area, so a plain test would thin a distant canopy to a fraction of itself. The scale is the
/// smallest that a bisection over `[1/64, 64]` (16 steps, in `log s`) finds to cover at least
/// that fraction, measured at 2 × 2 points per texel; alpha is clamped to 1.
fn preserve_coverage(levels: &mut [Vec<[f32; 4]>], width: usize, height: usize) {
    for (l, level) in levels.iter_mut().enumerate() {
        let (w, h) = ((width >> l).max(1), (height >> l).max(1));
        let target = level.iter().map(|t| f64::from(t[3])).sum::<f64>() / (w * h) as f64;
        if target <= 0.0 {
            continue;
        }
        // The 4 samples of a texel, at (¼, ¼) … (¾, ¾) of it, read the alpha bilinearly between
        // texel centres with edges clamped: a sample at ¼ lies ¾ of the way from the centre
        // before to its own (weights ¼, ¾), one at ¾ ¼ of the way to the next (¾, ¼). Sample
        // `k` of the texel at `(x, y)`, `k = ox + 2·oy`, whether it passes at `scale`.
        let passes = |x: usize, y: usize, k: usize, scale: f32| {
            // (first texel, second texel, weight of the second) along each axis.
            let (xa, xb, fx) =
                if k & 1 == 0 { (x.saturating_sub(1), x, 0.75f32) } else { (x, (x + 1).min(w - 1), 0.25f32) };
            let (ya, yb, fy) =
                if k & 2 == 0 { (y.saturating_sub(1), y, 0.75f32) } else { (y, (y + 1).min(h - 1), 0.25f32) };
            let alpha = |x: usize, y: usize| (level[y * w + x][3] * scale).min(1.0);
            let top = alpha(xa, ya) * (1.0 - fx) + alpha(xb, ya) * fx;
            let bottom = alpha(xa, yb) * (1.0 - fx) + alpha(xb, yb) * fx;
            top * (1.0 - fy) + bottom * fy >= 0.5
        };
        // The samples of `mask` (bit `k`: sample `k`) of the texel `i` that pass at `scale`.
        let passing = |i: usize, mask: u8, scale: f32| {
            let (x, y) = (i % w, i / w);
            (0..4).filter(|&k| mask & (1 << k) != 0 && passes(x, y, k, scale)).fold(0u8, |m, k| m | 1 << k)
        };
        let count = |samples: &[(u32, u8)]| samples.iter().map(|&(_, mask)| mask.count_ones() as usize).sum::<usize>();
        let fraction = |kept: usize| kept as f64 / (4 * w * h) as f64;
        // Every operation of `passes` is monotone in `scale` (products by non-negative numbers,
        // `min`, sums), rounding included: a sample that passes at one scale passes at every
        // larger one. So of the samples the bisection counts at each scale it tries, only those
        // that passed at the least scale found too large (`hi`) and failed at the largest found
        // too small (`lo`) can change, and only they are tested again: the counts, hence the
        // scale, are those of testing every sample each time. A texel whose neighbours and
        // itself have alpha 0 never passes.
        let (mut lo, mut hi) = ((1.0f32 / 64.0).ln(), 64.0f32.ln());
        let (mut lo_scale, mut hi_scale) = (0.0f32, hi.exp());
        // The texels (index, samples) that pass at `hi_scale` but not at `lo_scale`, and the
        // samples that pass at `lo_scale`.
        #[expect(clippy::cast_possible_truncation, reason = "a region's texels fit u32")]
        let mut open: Vec<(u32, u8)> =
            (0..w * h).map(|i| (i as u32, passing(i, 0b1111, hi_scale))).filter(|&(_, mask)| mask != 0).collect();
        let mut kept = 0usize;
        // False once `exp` is found not monotone (never seen): then every sample is counted.
        let mut sets = true;
        if fraction(count(&open)) < target {
            lo = hi;
        } else {
            for _ in 0..16 {
                let mid = 0.5 * (lo + hi);
                let scale = mid.exp();
                sets &= (lo_scale..=hi_scale).contains(&scale);
                if sets {
                    let tested: Vec<(u32, u8, u8)> =
                        open.iter().map(|&(i, mask)| (i, mask, passing(i as usize, mask, scale))).collect();
                    let pass = tested.iter().map(|&(_, _, p)| p.count_ones() as usize).sum::<usize>();
                    let keep = |f: fn(u8, u8) -> u8| {
                        tested.iter().map(|&(i, mask, p)| (i, f(mask, p))).filter(|&(_, m)| m != 0).collect()
                    };
                    if fraction(kept + pass) >= target {
                        (hi, hi_scale, open) = (mid, scale, keep(|_, p| p));
                    } else {
                        kept += pass;
                        (lo, lo_scale, open) = (mid, scale, keep(|mask, p| mask & !p));
                    }
                } else if fraction((0..w * h).map(|i| passing(i, 0b1111, scale).count_ones() as usize).sum()) >= target
                {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
        }
        let scale = hi.max(lo).exp();
        for t in level.iter_mut() {
            t[3] = (t[3] * scale).min(1.0);
        }
    }
}

/// One triangle's inputs to [`shade`], looked up once per triangle rather than once per sample:
/// its surface, its image's alpha plane if the caller made one ([`alpha_plane`]), and its
/// corners' vertex colours (RGB linear through the table, alpha in `[0, 1]`), texture
/// coordinates and normals (octahedral, as stored).
struct Shading<'a> {
    surface: &'a Surface<'a>,
    alpha: Option<&'a [u8]>,
    colour: [[f32; 4]; 3],
    uv: [[f32; 2]; 3],
    normals: [u32; 3],
}

impl<'a> Shading<'a> {
    fn new(surface: &'a Surface<'a>, alpha: Option<&'a [u8]>, corners: [&VertexRecord; 3], lut: &[f32; 256]) -> Self {
        let colour = corners.map(|corner| {
            let bytes = corner.color.to_le_bytes();
            std::array::from_fn(|i| if i < 3 { lut[bytes[i] as usize] } else { f32::from(bytes[3]) / 255.0 })
        });
        Self {
            surface,
            alpha,
            colour,
            uv: corners.map(|corner| corner.uv),
            normals: corners.map(|corner| corner.normal),
        }
    }

    /// The unit shading normal at weights `w` of the triangle placed at `corners` (its vertex
    /// normals interpolated; its face's where they cancel), turned to the side of `towards`.
    fn normal(&self, w: [f32; 3], corners: &[DVec3; 3], towards: DVec3) -> [f32; 3] {
        let mut n = Vec3::ZERO;
        for (k, &packed) in self.normals.iter().enumerate() {
            n += w[k] * Vec3::from_array(pack::oct_decode(packed));
        }
        let face = (corners[1] - corners[0]).cross(corners[2] - corners[0]).as_vec3();
        let n = n.try_normalize().or_else(|| face.try_normalize()).unwrap_or(Vec3::Y);
        let n = if f64::from(n.dot(towards.as_vec3())) < 0.0 { -n } else { n };
        n.to_array()
    }
}

/// The alpha bytes of `img`'s texels, a quarter of its bytes: the alpha test, which most samples
/// of a dense canopy fail or are hidden behind, reads only these, and they stay in cache where
/// the texels do not.
fn alpha_plane(img: &Image) -> Vec<u8> {
    img.rgba.chunks_exact(4).map(|t| t[3]).collect()
}

/// `x.floor() as i64`, without a call to `floorf` (which the baseline x86-64 target makes of
/// `floor`): the truncation, less one where it rounded up. Equal for every `f32`, NaN and the
/// infinities included (`as` saturates).
fn floor_i64(x: f32) -> i64 {
    #[expect(clippy::cast_possible_truncation, reason = "saturating, as floor() as i64 is")]
    let i = x as i64;
    #[expect(clippy::cast_precision_loss, reason = "exact where it decides: |x| < 2^23 or x integral")]
    let above = i as f32 > x;
    if above { i.saturating_sub(1) } else { i }
}

/// The number of the texel [`Image::texel`] reads at `(x, y)` (wrapped), if `img.rgba` holds it
/// (else that reads `[255; 4]`); without its integer divisions where the coordinates are at most
/// one image size outside it (a tiled bark texture).
fn texel_number(img: &Image, x: i64, y: i64) -> Option<usize> {
    let wrap = |c: i64, size: u32| {
        let size = i64::from(size.max(1));
        if (0..size).contains(&c) {
            c
        } else if (size..2 * size).contains(&c) {
            c - size
        } else if (-size..0).contains(&c) {
            c + size
        } else {
            c.rem_euclid(size)
        }
    };
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "rem_euclid is in 0..w·h")]
    let n = (wrap(y, img.height) * i64::from(img.width.max(1)) + wrap(x, img.width)) as usize;
    (n < img.rgba.len() / 4).then_some(n)
}

/// The linear colour of a leaf at barycentric `w`, if it passes the alpha test as the renderer
/// applies it: texture × factor × vertex colour; `MASK` against the cutoff, `BLEND` at 0.5.
fn shade(shading: &Shading<'_>, w: [f64; 3], lut: &[f32; 256]) -> Option<[f32; 3]> {
    let w = weights(w);
    let texel = shading.locate(w);
    shading.passes(w, shading.alpha(texel)).then(|| shading.colour(w, shading.texel(texel), lut))
}

/// Barycentric weights as [`shade`] interpolates with them.
fn weights(w: [f64; 3]) -> [f32; 3] {
    #[expect(clippy::cast_possible_truncation, reason = "barycentric weights")]
    let w = w.map(|w| w as f32);
    w
}

/// [`shade`] in steps, so that a caller can look up many samples' texels before it tests them.
impl Shading<'_> {
    /// The texel number ([`texel_number`]) of the image at weights `w`; `None` without an image.
    fn locate(&self, w: [f32; 3]) -> Option<usize> {
        let img = self.surface.image?;
        let (mut u, mut v) = (0.0f32, 0.0f32);
        for (k, uv) in self.uv.iter().enumerate() {
            u += w[k] * uv[0];
            v += w[k] * uv[1];
        }
        texel_number(img, floor_i64(u * img.width as f32), floor_i64(v * img.height as f32))
    }

    /// The texel's bytes as stored: `[255; 4]` outside the image's texels (as [`Image::texel`]
    /// reads), unused without an image.
    fn texel(&self, n: Option<usize>) -> [u8; 4] {
        match (self.surface.image, n) {
            (Some(img), Some(n)) => {
                let t = &img.rgba[n * 4..n * 4 + 4];
                [t[0], t[1], t[2], t[3]]
            }
            _ => [255; 4],
        }
    }

    /// The texel's alpha byte, from the alpha plane if there is one.
    fn alpha(&self, n: Option<usize>) -> u8 {
        match (self.alpha, n) {
            (Some(plane), Some(n)) => plane[n],
            _ => self.texel(n)[3],
        }
    }

    /// Whether the sample at weights `w`, where the texel's alpha is `alpha`, passes the alpha
    /// test.
    fn passes(&self, w: [f32; 3], alpha: u8) -> bool {
        let mut c = 0.0f32;
        for (k, colour) in self.colour.iter().enumerate() {
            c += w[k] * colour[3];
        }
        let surface = self.surface;
        let texel = if surface.image.is_some() { f32::from(alpha) / 255.0 } else { 1.0 };
        let a = c * texel * surface.material.base_color[3];
        match surface.material.alpha_mode {
            AlphaMode::Opaque => true,
            AlphaMode::Mask => a >= surface.material.alpha_cutoff,
            AlphaMode::Blend => a >= 0.5,
        }
    }

    /// The linear colour at weights `w`, where the texel is `t`.
    fn colour(&self, w: [f32; 3], t: [u8; 4], lut: &[f32; 256]) -> [f32; 3] {
        let mut c = [0.0f32; 3];
        for (k, colour) in self.colour.iter().enumerate() {
            for (slot, value) in c.iter_mut().zip(colour) {
                *slot += w[k] * value;
            }
        }
        let surface = self.surface;
        let factor = surface.material.base_color;
        std::array::from_fn(|i| {
            let texel = if surface.image.is_some() { lut[t[i] as usize] } else { 1.0 };
            c[i] * texel * factor[i]
        })
    }
}

/// Gives the texels within [`DILATION`] texels of a `covered` one the value of the nearest
/// (breadth first, eight neighbours, in raster order): all that bilinear filtering at that level
/// reads next to coverage. A `colour` level's filled texels keep their alpha 0 (their coverage);
/// a normal level's take all four channels. Farther texels stay `(0, 0, 0, 0)`, which compresses
/// to almost nothing.
fn dilate(texels: &mut [[f32; 4]], w: usize, h: usize, covered: Vec<bool>, colour: bool) {
    let mut done = covered;
    let mut queue: std::collections::VecDeque<(usize, u32)> =
        (0..texels.len()).filter(|&i| done[i]).map(|i| (i, 0)).collect();
    while let Some((i, steps)) = queue.pop_front() {
        if steps == DILATION {
            continue;
        }
        let (x, y) = (i % w, i / w);
        for (dx, dy) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                continue;
            }
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "inside the region")]
            let j = ny as usize * w + nx as usize;
            if !done[j] {
                done[j] = true;
                texels[j] = [texels[i][0], texels[i][1], texels[i][2], if colour { 0.0 } else { texels[i][3] }];
                queue.push_back((j, steps + 1));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn may_cover_keeps_every_triangle_whose_box_holds_a_sample() {
        // Tilted quads over grids of a few to thousands of samples, and triangles from a
        // sample's width to far under it, near sample centres and the grid's edges: every one
        // whose projected box holds a centre (as `bake` finds it) is kept, and most of the tiny
        // ones are not.
        let mut rng = SplitMix64(5);
        let mut next = || rng.next_f64();
        let (mut kept, mut boxed, mut tiny_kept, mut tiny) = (0, 0, 0, 0);
        for i in 0..40_000 {
            let samples = [(8, 8), (176, 176), (3000, 1700), (8192, 64)][i % 4];
            let turn = DQuat::from_rotation_y(next() * 6.0) * DQuat::from_rotation_x(next() - 0.5);
            let quad = Quad {
                centre: DVec3::new(next() - 0.5, next() * 3.0, next() - 0.5),
                u: turn * DVec3::X * (1.0 + 9.0 * next()),
                v: turn * DVec3::Y * (1.0 + 9.0 * next()),
            };
            let may_cover = MayCover::new(&quad, samples);
            // A point of the quad at sample coordinates (x, y), and off it along its normal.
            let point = |x: f64, y: f64, off: f64| {
                quad.centre
                    + quad.u * (2.0 * x / samples.0 as f64 - 1.0)
                    + quad.v * (2.0 * y / samples.1 as f64 - 1.0)
                    + quad.u.cross(quad.v).normalize() * off
            };
            let size = [1.0, 0.1, 0.01, 1e-4][(i / 4) % 4];
            let (x, y) = (next() * (samples.0 as f64 + 2.0) - 1.0, next() * (samples.1 as f64 + 2.0) - 1.0);
            // Half of them with a corner on a centre or an edge of the samples.
            let (x, y) =
                if i % 2 == 0 { ((x.floor() + 0.5 * f64::from(i as u32 % 3)), y.floor() + 0.5) } else { (x, y) };
            let local = [point(x, y, 0.0), point(x + size * next(), y, next()), point(x, y + size * next(), -next())];
            let exact = boxed_rows(&local, &quad, samples).is_some();
            let test = may_cover.test(&local);
            assert!(test || !exact, "{local:?} on {samples:?}: its box holds a sample, but it was not kept");
            (kept, boxed) = (kept + usize::from(test), boxed + usize::from(exact));
            if size < 0.05 && i % 2 == 1 {
                (tiny, tiny_kept) = (tiny + 1, tiny_kept + usize::from(test));
            }
        }
        assert!(boxed > 1000 && kept >= boxed, "{kept} kept, {boxed} boxed");
        assert!(tiny_kept * 4 < tiny, "{tiny_kept} of {tiny} tiny triangles kept");
    }
    use crate::raster::{
        AlphaMask, Mask, RasterTriangle, View, bounding_sphere, coverage, render_views, view_directions,
    };
    use crate::scene::ImageEncoding;
    use glam::Vec2;

    /// What a view along `v` sees of leaves of weighted unit normals lit from `l`: their mean
    /// `|n·l|` weighted by the area each shows, `|n·v|`.
    fn seen_diffuse(items: &[(DVec3, f64)], v: DVec3, l: DVec3) -> f64 {
        let shown: f64 = items.iter().map(|&(n, w)| w * n.dot(v).abs()).sum();
        items.iter().map(|&(n, w)| w * n.dot(v).abs() * n.dot(l).abs()).sum::<f64>() / shown
    }

    /// Unit directions spread over the sphere, from `rng`.
    fn directions(rng: &mut SplitMix64, n: usize) -> Vec<DVec3> {
        (0..n)
            .map(|_| {
                let z = rng.range(-1.0, 1.0);
                let phi = rng.range(0.0, 2.0 * std::f32::consts::PI);
                let r = (1.0 - z * z).max(0.0).sqrt();
                DVec3::new(f64::from(r * phi.cos()), f64::from(z), f64::from(r * phi.sin()))
            })
            .collect()
    }

    /// Leaves whose normals lie `tilt` (degrees, drawn from `tilts`) off `normal`, every way round.
    fn tilted(rng: &mut SplitMix64, normal: DVec3, tilts: (f32, f32), n: usize) -> Vec<(DVec3, f64)> {
        let (t1, t2) = normal.any_orthonormal_pair();
        (0..n)
            .map(|_| {
                let tilt = f64::from(rng.range(tilts.0, tilts.1)).to_radians();
                let turn = f64::from(rng.range(0.0, 360.0)).to_radians();
                let n = normal * tilt.cos() + (t1 * turn.cos() + t2 * turn.sin()) * tilt.sin();
                (n, f64::from(rng.range(0.5, 2.0)))
            })
            .collect()
    }

    /// The mean error of the record's diffuse factor and of the plane's own `|N·l|` against what
    /// a view sees of `items`, over random views and lights.
    fn diffuse_errors(rng: &mut SplitMix64, normal: DVec3, items: &[(DVec3, f64)]) -> (f64, f64) {
        let record = plane_diffuse(normal, items);
        let (mut fitted, mut own) = (0.0, 0.0);
        let pairs = directions(rng, 400);
        for vl in pairs.chunks_exact(2) {
            let (v, l) = (vl[0], vl[1]);
            let seen = seen_diffuse(items, v, l);
            let f = record.diffuse(normal.as_vec3().to_array(), v.as_vec3().to_array(), l.as_vec3().to_array());
            fitted += (f64::from(f) - seen).abs() / 200.0;
            own += (normal.dot(l).abs() - seen).abs() / 200.0;
        }
        (fitted, own)
    }

    #[test]
    fn a_planes_diffuse_response_is_exact_for_flat_scattered_and_crossing_leaves_and_close_between() {
        let normal = DVec3::new(0.3, 0.9, -0.2).normalize();
        let mut rng = SplitMix64(11);
        // Leaves in the plane, either face up: the plane's own |N·l|.
        let flat: Vec<(DVec3, f64)> =
            (0..9).map(|k| (if k % 2 == 0 { normal } else { -normal }, 1.0 + f64::from(k))).collect();
        assert_eq!(plane_diffuse(normal, &flat), PlaneDiffuseRecord::FLAT);
        // Leaves turned every way, and leaves across the plane, every way about its normal.
        let scattered: Vec<(DVec3, f64)> = directions(&mut rng, 4000).into_iter().map(|n| (n, 1.0)).collect();
        let across = tilted(&mut rng, normal, (90.0, 90.0), 4000);
        for (name, items, share) in [("scattered", &scattered, 1), ("across", &across, 2)] {
            let record = plane_diffuse(normal, items);
            let shares = record.shares();
            assert!([shares.0, shares.1, shares.2][share] > 0.97, "{name}: {shares:?}");
            let (fitted, own) = diffuse_errors(&mut rng, normal, items);
            assert!(fitted < 0.01 && own > 0.2, "{name}: off by {fitted:.3} on average, the plane's own by {own:.3}");
        }
        // Leaves tilted up to 50° or 80° off the plane's normal, or all at 60°: within about half
        // the plane's own error.
        for tilts in [(0.0, 50.0), (0.0, 80.0), (60.0, 60.0)] {
            let items = tilted(&mut rng, normal, tilts, 3000);
            let (fitted, own) = diffuse_errors(&mut rng, normal, &items);
            assert!(fitted < 0.6 * own, "tilted {tilts:?}: off by {fitted:.3} on average, the plane's own by {own:.3}");
        }
        // No leaves, or none of any weight.
        assert_eq!(plane_diffuse(normal, &[]), PlaneDiffuseRecord::FLAT);
        let weightless: Vec<(DVec3, f64)> = scattered.iter().map(|&(n, _)| (n, 0.0)).collect();
        assert_eq!(plane_diffuse(normal, &weightless), plane_diffuse(normal, &scattered));
    }

    fn random_matrix(rng: &mut SplitMix64) -> DMat3 {
        let v = |rng: &mut SplitMix64| rng.next_f64() * 2.0 - 1.0;
        let (a, b, c, d, e, f) = (v(rng), v(rng), v(rng), v(rng), v(rng), v(rng));
        DMat3::from_cols(DVec3::new(a, b, c), DVec3::new(b, d, e), DVec3::new(c, e, f))
    }

    #[test]
    fn jacobi_finds_orthonormal_eigenvectors_also_for_repeated_and_negative_eigenvalues() {
        let mut rng = SplitMix64(7);
        let mut cases: Vec<DMat3> = (0..200).map(|_| random_matrix(&mut rng)).collect();
        // Repeated eigenvalues, a diagonal, a zero matrix and a rank-one negative one.
        cases.push(DMat3::IDENTITY * 2.0);
        cases.push(DMat3::from_diagonal(DVec3::new(3.0, -1.0, 3.0)));
        cases.push(DMat3::ZERO);
        cases.push(-outer(DVec3::new(1.0, 2.0, 2.0), DVec3::new(1.0, 2.0, 2.0)));
        for m in cases {
            let (values, vectors) = symmetric_eigen(m);
            assert!(values[0] <= values[1] && values[1] <= values[2], "{values:?}");
            for (i, (&l, &v)) in values.iter().zip(&vectors).enumerate() {
                assert!((v.length() - 1.0).abs() < 1e-12, "{m:?}: vector {i} not unit");
                assert!((m * v - v * l).length() < 1e-10 * (1.0 + l.abs()), "{m:?}: A v ≠ λ v for {i}");
                for w in &vectors[i + 1..] {
                    assert!(v.dot(*w).abs() < 1e-10, "not orthogonal");
                }
            }
        }
    }

    /// Leaves scattered on three known planes, slightly tilted and displaced.
    fn three_planes() -> (Vec<ClusterLeaf>, [Plane; 3]) {
        let planes = [
            Plane { normal: Vec3::new(1.0, 0.2, 0.1).normalize(), offset: -2.0 },
            Plane { normal: Vec3::new(-0.3, 1.0, 0.2).normalize(), offset: -3.0 },
            Plane { normal: Vec3::new(0.1, -0.4, 1.0).normalize(), offset: 1.5 },
        ];
        let mut rng = SplitMix64(11);
        let mut leaves = Vec::new();
        for plane in &planes {
            let (t1, t2) = plane.normal.any_orthonormal_pair();
            let foot = -plane.normal * plane.offset;
            for _ in 0..300 {
                let p = foot + t1 * rng.range(-2.0, 2.0) + t2 * rng.range(-2.0, 2.0);
                let jitter = plane.normal * rng.range(-0.01, 0.01);
                let tilt = (t1 * rng.range(-0.02, 0.02) + t2 * rng.range(-0.02, 0.02)) + plane.normal;
                let sign = if rng.unit() < 0.5 { -1.0 } else { 1.0 };
                leaves.push(ClusterLeaf {
                    centre: p + jitter,
                    normal: tilt.normalize() * sign,
                    area: rng.range(0.005, 0.02),
                });
            }
        }
        (leaves, planes)
    }

    #[test]
    fn leaves_on_three_known_planes_are_recovered() {
        let (leaves, truth) = three_planes();
        let (assign, planes) = cluster(&leaves, 3, 0.25, 30, 1);
        assert_eq!(planes.len(), 3);
        for (k, t) in truth.iter().enumerate() {
            // The cluster holding most of plane k's leaves.
            let mut votes = [0usize; 3];
            for &c in &assign[k * 300..(k + 1) * 300] {
                votes[c as usize] += 1;
            }
            let c = (0..3).max_by_key(|&c| votes[c]).unwrap_or(0);
            assert!(votes[c] >= 295, "plane {k}: leaves split {votes:?}");
            let p = planes[c];
            let sign = p.normal.dot(t.normal).signum();
            let angle = (p.normal.dot(t.normal) * sign).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(angle < 1.0, "plane {k}: normal off by {angle}°");
            let offset = p.offset * sign;
            assert!((offset - t.offset).abs() < 0.01 * t.offset.abs(), "plane {k}: offset {offset}, want {}", t.offset);
        }
        // Deterministic.
        assert_eq!(cluster(&leaves, 3, 0.25, 30, 1).0, assign);
    }

    #[test]
    fn clusters_are_never_empty_even_when_k_exceeds_the_distinct_leaves() {
        let leaf = ClusterLeaf { centre: Vec3::ZERO, normal: Vec3::Y, area: 1.0 };
        let (assign, planes) = cluster(&[leaf; 5], 4, 0.0, 10, 3);
        assert_eq!(assign.len(), 5);
        let used = assign.iter().max().map_or(0, |&m| m as usize + 1);
        assert_eq!(used, planes.len());
        for c in 0..used as u32 {
            assert!(assign.contains(&c), "cluster {c} is empty");
        }
        // A single leaf's plane is its own plane (α = 0: the tie-break picks its normal).
        assert!((planes[0].normal.dot(Vec3::Y).abs() - 1.0).abs() < 1e-6);
    }

    fn leaf_image() -> Image {
        // 8×8: an opaque green disc on transparent texels.
        let rgba = (0..64)
            .flat_map(|i| {
                let (x, y) = (i % 8, i / 8);
                let inside = (x as f32 - 3.5).powi(2) + (y as f32 - 3.5).powi(2) < 12.0;
                if inside { [40, 160, 40, 255] } else { [0, 0, 0, 0] }
            })
            .collect();
        Image { width: 8, height: 8, rgba, encoded: Vec::new(), encoding: ImageEncoding::Raw }
    }

    /// A leaf quad: two triangles with their own four vertices.
    fn push_quad(vertices: &mut Vec<VertexRecord>, triangles: &mut Vec<LeafTriangle>, c: Vec3, a: Vec3, b: Vec3) {
        #[expect(clippy::cast_possible_truncation, reason = "a test mesh")]
        let base = vertices.len() as u32;
        for (s, t, uv) in
            [(-1.0, -1.0, [0.0, 1.0]), (1.0, -1.0, [1.0, 1.0]), (1.0, 1.0, [1.0, 0.0]), (-1.0, 1.0, [0.0, 0.0])]
        {
            let normal = pack::oct_encode(a.cross(b).normalize().to_array());
            vertices.push(VertexRecord { position: (c + a * s + b * t).to_array(), normal, uv, color: u32::MAX });
        }
        triangles.push(LeafTriangle { v: [base, base + 1, base + 2], material: 0, tree: 0 });
        triangles.push(LeafTriangle { v: [base, base + 2, base + 3], material: 0, tree: 0 });
    }

    #[test]
    fn one_flat_leaf_bakes_into_its_region_with_its_colour_and_coverage() {
        let image = leaf_image();
        let material = Material {
            base_color: [1.0; 4],
            image: Some(0),
            alpha_mode: AlphaMode::Mask,
            alpha_cutoff: 0.5,
            ..Material::default()
        };
        let surfaces = [Surface { material: &material, image: Some(&image) }];
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        push_quad(&mut vertices, &mut triangles, Vec3::new(0.0, 2.0, 0.0), Vec3::X * 0.5, Vec3::Z * 0.5);
        let mesh = ImpostorMesh { vertices: &vertices, triangles: &triangles, surfaces: &surfaces, occlusion: &[] };
        let config = ImpostorConfig { texels_per_metre: 32.0, ..ImpostorConfig::default() };
        let out = build_impostors(&mesh, &config).unwrap().unwrap();
        assert_eq!(out.planes.len(), 1);
        assert_eq!(out.planes_per_level, [1, 1, 1]);
        let p = &out.planes[0];
        assert_eq!((p.lo, p.hi, p.leaf_first, p.leaf_count), (0.0, f32::INFINITY, 0, 1));
        // The plane is the leaf's: y = 2, quad 1 m × 1 m.
        assert!((p.center[1] - 2.0).abs() < 1e-5, "{p:?}");
        let (u, v) = (Vec3::from_array(p.axis_u), Vec3::from_array(p.axis_v));
        assert!((u.length() - 0.5).abs() < 1e-4 && (v.length() - 0.5).abs() < 1e-4 && u.dot(v).abs() < 1e-5, "{p:?}");
        // 32 texels of content, 4 of gutter each side: a 48 × 48 region, aligned.
        let atlas = &out.atlas;
        assert_eq!((atlas.width % 16, atlas.height % 16, atlas.mip_count), (0, 0, 5));
        let level0 = &atlas.texels[..(atlas.width * atlas.height * 4) as usize];
        let [u0, v0] = pack::unpack_unorm16x2(p.uv_min);
        let [u1, v1] = pack::unpack_unorm16x2(p.uv_max);
        let (x0, y0) = ((u0 * atlas.width as f32).round() as usize, (v0 * atlas.height as f32).round() as usize);
        let (x1, y1) = ((u1 * atlas.width as f32).round() as usize, (v1 * atlas.height as f32).round() as usize);
        assert_eq!((x1 - x0, y1 - y0), (32, 32));
        // That region is the tree's texel budget.
        assert_eq!(out.texels_per_tree, [48 * 48]);
        let texel = |x: usize, y: usize| &level0[(y * atlas.width as usize + x) * 4..][..4];
        // The disc's middle is the texture's green, opaque (alpha scaled a little below 1 so the
        // filtered test covers the disc's area, not more); the corners transparent; the gutter
        // transparent but dilated (not black).
        assert_eq!(texel(x0 + 16, y0 + 16)[..3], [40, 160, 40]);
        assert!(texel(x0 + 16, y0 + 16)[3] > 200);
        assert_eq!(texel(x0, y0)[3], 0);
        let edge = (x0..x1).find(|&x| texel(x, y0 + 16)[3] > 0).unwrap();
        assert_eq!(texel(edge - 2, y0 + 16), [40, 160, 40, 0]);
        assert_eq!(texel(edge - 3, y0 + 16), [0, 0, 0, 0]);
        // Coverage: the disc's 32 texels of 64 pass the leaf's test, half of its 32 × 32 texels,
        // and so does the atlas's test at one half.
        let passing =
            (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| texel(x, y)[3] >= 128).count();
        let want = 0.5 * 32.0 * 32.0;
        assert!((passing as f32 - want).abs() < 0.03 * want, "{passing} texels pass, want about {want}");
        // Deterministic.
        assert_eq!(build_impostors(&mesh, &config).unwrap().unwrap(), out);
    }

    /// Triangles of the impostor quads, textured from the atlas's first level, for the CPU
    /// rasteriser; `tau` picks the level.
    fn impostor_triangles(out: &Impostors, tau: f32) -> (Vec<RasterTriangle>, AlphaMask) {
        let atlas = &out.atlas;
        let image = Image {
            width: atlas.width,
            height: atlas.height,
            rgba: atlas.texels[..(atlas.width * atlas.height * 4) as usize].to_vec(),
            encoded: Vec::new(),
            encoding: ImageEncoding::Raw,
        };
        let mask = AlphaMask::from_image(&image, 1.0, 0.5);
        let mut triangles = Vec::new();
        for p in out.planes.iter().filter(|p| p.lo <= tau && tau < p.hi) {
            let (c, u, v) = (Vec3::from_array(p.center), Vec3::from_array(p.axis_u), Vec3::from_array(p.axis_v));
            let ([u0, v0], [u1, v1]) = (pack::unpack_unorm16x2(p.uv_min), pack::unpack_unorm16x2(p.uv_max));
            let corner = |s: f32, t: f32| {
                (c + u * s + v * t, Vec2::new(u0 + (u1 - u0) * 0.5 * (s + 1.0), v0 + (v1 - v0) * 0.5 * (t + 1.0)))
            };
            let q = [corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0)];
            for [a, b, d] in [[0, 1, 2], [0, 2, 3]] {
                triangles.push(RasterTriangle {
                    positions: [q[a].0, q[b].0, q[d].0],
                    uvs: [q[a].1, q[b].1, q[d].1],
                    alpha: 0,
                });
            }
        }
        (triangles, mask)
    }

    #[test]
    fn the_demo_tree_impostors_cover_its_leaves_from_every_direction() {
        let scene = crate::demo_tree(&crate::DemoTreeConfig::default());
        let leaf_part = scene.parts.iter().find(|p| p.mesh_name != "bark").unwrap();
        let material = &scene.materials[leaf_part.material];
        let image = material.image.map(|i| &scene.images[i]);
        let vertices: Vec<VertexRecord> = leaf_part
            .positions
            .iter()
            .zip(&leaf_part.uvs)
            .map(|(p, uv)| VertexRecord { position: *p, normal: 0, uv: *uv, color: u32::MAX })
            .collect();
        let triangles: Vec<LeafTriangle> =
            leaf_part.triangles.iter().map(|&v| LeafTriangle { v, material: 0, tree: 0 }).collect();
        let surfaces = [Surface { material, image }];
        let mesh = ImpostorMesh { vertices: &vertices, triangles: &triangles, surfaces: &surfaces, occlusion: &[] };
        let out = build_impostors(&mesh, &ImpostorConfig::default()).unwrap().unwrap();
        assert_eq!(out.leaves, 4000);
        assert_eq!(out.planes_per_level, [32, 16, 8]);
        // The SPT rule draws one level at every τ, each leaf once (verify's rule 2, simply).
        for tau in [0.0, 0.05, 0.2, 1.0, 100.0] {
            let mut leaves: Vec<u32> = out
                .planes
                .iter()
                .filter(|p| p.lo <= tau && tau < p.hi)
                .flat_map(|p| p.leaf_first..p.leaf_first + p.leaf_count)
                .collect();
            leaves.sort_unstable();
            assert_eq!(leaves, (0..4000).collect::<Vec<_>>(), "τ = {tau}");
        }
        // Coverage of the finest and the coarsest level against the leaves, 8 views, 128 px.
        let mesh_triangles: Vec<RasterTriangle> = triangles
            .iter()
            .map(|t| RasterTriangle {
                positions: t.v.map(|v| Vec3::from_array(vertices[v as usize].position)),
                uvs: t.v.map(|v| Vec2::from_array(vertices[v as usize].uv)),
                alpha: 0,
            })
            .collect();
        let leaf_mask = AlphaMask::for_material(material, image).unwrap();
        let (centre, radius) = bounding_sphere(vertices.iter().map(|v| Vec3::from_array(v.position)));
        let views: Vec<View> = view_directions(8).iter().map(|&d| View::fit(d, centre, radius, 128)).collect();
        let reference: Vec<Mask> = render_views(&views, &mesh_triangles, &[leaf_mask]);
        // Measured (α scale 0.1, 24 texels/m): the 32 planes reach P 0.74–0.80 and R 0.69–0.80
        // over the views, the 8 planes P 0.62–0.70 and R 0.51–0.62. Pixel coverage at 128 px is
        // strict: the levels' leaves lie 0.25–0.3 m (RMS) off their planes, 4–5 px here, so the
        // parallax costs these points. The thresholds sit a few points below the measured
        // minima: a wrong plane, quad or atlas region, or coverage lost in the bake, fails.
        for (tau, min_p, min_r) in [(0.0, 0.70, 0.65), (f32::MAX, 0.58, 0.47)] {
            let (quads, atlas_mask) = impostor_triangles(&out, tau);
            let test = render_views(&views, &quads, &[atlas_mask]);
            for (v, (t, r)) in test.iter().zip(&reference).enumerate() {
                let (p, rec) = coverage(t, r).precision_recall();
                assert!(p >= min_p && rec >= min_r, "τ {tau}, view {v}: precision {p:.3}, recall {rec:.3}");
            }
        }
    }
}
