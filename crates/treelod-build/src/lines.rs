//! Branch lines (Clasen, Paar and Prohaska 2011 §3.2, §4, §6; spec §6.9, §10): a skeleton of
//! truncated-cone line segments read off the bark mesh, and per grid cell an agglomerative
//! hierarchy of straighten and combine merges above it, whose levels are each drawn in one interval
//! of `τ`.
//!
//! **Skeleton** (no node structure needed: it works for generators that make every branch a
//! separate tube, Sapling and ez-tree, and for merged meshes such as the jacaranda's trunk):
//!
//! - **Weld and components**: bark positions are welded on a grid of [`WELD`] (10⁻⁵) of the bark
//!   box's diagonal; triangles sharing a welded vertex form a component (union–find). Each
//!   component has its surface area `A`. Components are ranked by area, largest first (ties: the
//!   first met).
//! - **Roots**: the largest component starts at its lowest vertex (least `y`, glTF is Y-up) and
//!   has no parent: at the open end there (a tube's base), or else at every vertex within 1 % of
//!   its height of the lowest (a closed or flared base). Every other component is tried from each of its open boundary loops (the cut
//!   ends of a tube; a closed component: its vertex nearest to a larger component's), taking the
//!   one whose centroid lies deepest in the skeleton already built: for each loop, the vertex of a
//!   larger component nearest to its centroid (a uniform grid over the vertices, filled in rank
//!   order) gives a node, and the depth is the signed distance of the centroid to the surface of
//!   the segment (a cone with round ends) of that node, of a few of its ancestors or of their
//!   children, the least of them (ties: the lower node). So a branch tube starts at its end inside
//!   its parent, not where it crosses the parent's surface, and branches starting at one point of
//!   their parent's axis hang from the parent, not from each other. That node is the component's
//!   parent if the depth is at most `2h + r` (`h` the component's slice width, below; `r` the
//!   node's radius: generators put branch bases on or near the parent's surface, which the cone
//!   only approximates). Otherwise the component is a separate tree of the block or a floating
//!   piece, and no line may join it to its neighbour across the gap: it starts at its base as the largest does
//!   as a root of its own. Small pieces, under [`SMALL_PIECE`] (1 %) of the largest
//!   component's area (flowers, knots, caps, stray bark triangles: no tree of their own), are
//!   attached within twice the largest component's slice width instead, so that they merge into
//!   the tree's hierarchy rather than each staying a line of its own up to the coarsest level.
//! - **Geodesic slices**: Dijkstra distances over the welded edges (ties: lower vertex id) from
//!   the chosen loop, or from the lowest vertex's loop (the vertex alone when it is on no
//!   boundary), so that the slices of a tube are perpendicular to it instead of slanted from a
//!   point of its rim. With `L` the largest distance, `r_est` the median radius of the connected
//!   pieces of [`FINE_SLICES`] (96) slices of width `L/96` (each piece's mean distance of its
//!   vertices to their centroid: about a ring of the tube), the slice width is
//!   `h = max(2·r_est, L/24)`: slices no narrower than the branch is thick (finer ones add nothing
//!   visible and fragment at bends), and about [`MAX_SLICES`] (24) slices per component, so long
//!   thin branches do not flood the hierarchy. (The radius of an open cylinder of the component's
//!   area and length, `A/(2πL)`, is right for one tube but counts every limb of a merged mesh,
//!   such as the jacaranda's forked trunk, into one radius several times too large, whose wide
//!   slices join the stems of a fork into one fat node.)
//! - **Nodes**: vertices are binned by `⌊d/h⌋`; the connected pieces of a bin (edges inside it)
//!   are the skeleton nodes (numbered by component rank, bin, least vertex). A node's centroid is
//!   its vertices' mean; its radius the mean distance of its vertices to the axis through the
//!   centroid along the skeleton (towards its parent, or for a component's first node towards its
//!   first child; the plain distance to the centroid without either), at least 10⁻⁷ of the
//!   diagonal. Measuring to the axis, not the centroid, keeps a slice's length out of its radius.
//!   A node's parent is the node of the highest lower bin it shares an edge with (ties: the lower
//!   node).
//! - **Source segments**, one per node: from the parent node (centroid, radius) to the node. A
//!   component's first node attached to a foreign node starts at that node's centroid with its own
//!   radius (the branch leaves its parent's axis at its own thickness). A root component's first
//!   node starts at the centroid of the source loop (the trunk's base) with the loop's radius, so
//!   the base of the trunk is not lost. A segment's triangles are its node's (a triangle belongs
//!   to the node of its first corner); its colour is their area-weighted mean colour, and its
//!   weight its frustum volume `π·l·(r0² + r0·r1 + r1²)/3` (Clasen Fig. 7).
//!
//! **Cells**: a segment goes to the cell of its midpoint; within a cell the segments form a
//! forest (a segment's parent is the segment ending at its start node, when in the same cell).
//!
//! **Hierarchy** (Clasen §3.2), per cell:
//!
//! - *straighten* replaces a line `A` and its only child `B` by `A.p0, A.r0 → B.p1, B.r1`;
//!   *combine* replaces two siblings (the same parent line, or both roots of the cell under the
//!   same out-of-cell parent segment) by their weight-averaged line (endpoints and radii). Either
//!   merge then widens the result by the square root of the ratio of the pair's side areas
//!   (`(r0 + r1)·length` summed) to its own (at most to twice the pair's widest radius; see
//!   `merged_line`), so that coarse levels keep more of the crown's twigs than Clasen's plain
//!   average. The result's weight is the sum, its colour the weight-averaged colour, and the
//!   merged lines' children become its children. Roots without a parent, or under different out-of-cell parents,
//!   are never combined: merging ends with one line per connected tree of the cell.
//! - Each step samples [`LineConfig::candidates`] mergeable pairs uniformly ([`SplitMix64`] seeded
//!   from [`LineConfig::seed`] and the cell; all pairs when there are no more) and applies the one
//!   of least image error (ties: the smaller merged weight, then the first sampled).
//! - **Image error** (Clasen §4): the multi-scale RMSE ([`multiscale_rmse`]) between the coverage
//!   of the two old lines and of the new one, in [`LineConfig::views`] orthographic views
//!   ([`view_directions`]) at one pixel size for the whole block: the diameter of the bark's
//!   bounding sphere over [`LineConfig::resolution`], so errors of every cell and step compare.
//!   It is computed locally: only the power-of-two square around the three lines is drawn, and
//!   each level's sum of squares is normalised by the full `resolution²` view as if the rest of
//!   the image were unchanged (levels coarser than the square, up to the whole view, see the
//!   difference of the pixel counts in one block). Other lines are not drawn: the merge is measured on its own, as it changes the
//!   image where nothing else overlaps. Lines are drawn as the convex hull of their end discs
//!   (the outline of a cone with round caps seen from the side), each at least
//!   [`MIN_HALF_WIDTH`] (½) pixel wide, so that the shape of branches thinner than a pixel of
//!   these views still counts: a bend costs more than a straight continuation.
//! - **Levels and intervals** (Clasen §6): level 0 is the source segments; the line set is
//!   snapshot every time its count falls to `⌈n/2⌉` of the last snapshot's `n`, and at the end.
//!   Level `k`'s error `e_k` is the mean over its lines of the width `r0 + r1` divided by
//!   [`LineConfig::pixels`] (metres per pixel at which the mean line is `pixels` wide), made
//!   strictly increasing; level `k` is drawn for `τ ∈ [e_{k−1}, e_k)`, level 0 from 0 and the last
//!   to `+∞`. A line in several consecutive snapshots is one record spanning their intervals;
//!   lines made and merged again between snapshots are not written. [`crate::spt::flatten`]
//!   numbers the source segments (the leaves) depth-first in the merge forest, so every record's
//!   run of leaves is contiguous and each `τ` draws an exact cut (spec §10).
//!
//! **Far lines** (spec §6.9.1): a cell's hierarchy ends at one line per connected piece of the
//! cell, so a far tree drew the same lines whatever its size (the shared oak 149, from about 60
//! pixels of height down). After the cells, `far_switch` finds the `τ` from which the cells
//! draw no more than [`FAR_TAKEOVER`] times their coarsest lines' number, in the middle of a
//! stretch where no cell fades between levels under the reference blend ([`FAR_BLEND`]); the
//! lines each cell draws there become the far leaves, each hanging from the leaf that holds its
//! out-of-cell parent segment, and the merge loop merges them on across cells, down to one line per
//! tree. Their thresholds keep the ratios of the far levels' mean widths, scaled so that far
//! level 0 ends half an octave above the switch: a runtime switching there finds the far lines
//! drawing exactly the cells' lines.
//!
//! Cells are built in parallel and collected in order; every sum runs in a fixed order, so the
//! output does not depend on the thread count.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap, HashMap};

use glam::{DVec2, DVec3, Vec2, Vec3, Vec4};
use rayon::prelude::*;
use treelod_format::{LineRecord, Setting, VertexRecord, pack};

use crate::error::BuildError;
use crate::raster::{Mask, bounding_sphere, fill_ellipse, fill_triangle, multiscale_rmse, view_directions};
use crate::rng::SplitMix64;
use crate::spt::flatten;
use crate::texture::linear_to_srgb;
use crate::union_find::{find, singletons, union};

/// Welding tolerance, a share of the bark box's diagonal.
pub const WELD: f64 = 1e-5;

/// Most segments per component: the slice width is at least `1/MAX_SLICES` of its length.
pub const MAX_SLICES: f64 = 24.0;

/// Fine slices per component for estimating its branches' thickness: the slice width is twice
/// the median radius of the pieces of `FINE_SLICES` slices.
pub const FINE_SLICES: f64 = 96.0;

/// Least half-width of a line in the image-error views, pixels.
pub const MIN_HALF_WIDTH: f64 = 0.5;

/// Least node radius, a share of the bark box's diagonal.
const MIN_RADIUS: f64 = 1e-7;

/// Components with less area than this share of the largest one's are small pieces (flowers,
/// knots, caps, stray triangles), attached within a wider reach.
pub const SMALL_PIECE: f64 = 0.01;

/// Ancestors of the nearest foreign vertex's node searched for the attachment.
const ATTACH_ANCESTORS: usize = 4;

/// Branch-line tunables (recorded in the container's settings as `lines.*`, spec §7.1).
#[derive(Clone, Debug, PartialEq)]
pub struct LineConfig {
    /// Target mean line width on screen, pixels (Clasen §6: 1): a level is drawn while its mean
    /// line is at least this wide. `(0, 1000]`. Default 1.
    pub pixels: f32,
    /// Random mergeable pairs evaluated per merge step, the one of least image error applied.
    /// `1 ..= 256`. Default 16.
    pub candidates: u32,
    /// Side of the image-error views, pixels, a power of two in `16 ..= 1024`; the bark's
    /// bounding sphere spans it. Default 256.
    pub resolution: u32,
    /// Views of the image error. `1 ..= 16`. Default 3.
    pub views: u32,
    /// Seed of the candidate sampling. Default 1.
    pub seed: u64,
}

impl Default for LineConfig {
    fn default() -> Self {
        Self { pixels: 1.0, candidates: 16, resolution: 256, views: 3, seed: 1 }
    }
}

impl LineConfig {
    /// Checks the ranges documented on the fields.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the field.
    pub fn validate(&self) -> Result<(), BuildError> {
        let bad = |what: String| Err(BuildError::Setting(what));
        if !(self.pixels > 0.0 && self.pixels <= 1000.0) {
            return bad(format!("line pixels {}: must be in (0, 1000]", self.pixels));
        }
        if !(1..=256).contains(&self.candidates) {
            return bad(format!("line candidates {}: must be in 1..=256", self.candidates));
        }
        if !(16..=1024).contains(&self.resolution) || !self.resolution.is_power_of_two() {
            return bad(format!("line resolution {}: must be a power of two in 16..=1024", self.resolution));
        }
        if !(1..=16).contains(&self.views) {
            return bad(format!("line views {}: must be in 1..=16", self.views));
        }
        Ok(())
    }

    /// The `lines.*` settings (spec §7.1), sorted by key.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        let setting = |key: &str, value: String| Setting { key: format!("lines.{key}"), value };
        vec![
            setting("candidates", self.candidates.to_string()),
            setting("pixels", self.pixels.to_string()),
            setting("resolution", self.resolution.to_string()),
            setting("seed", self.seed.to_string()),
            setting("views", self.views.to_string()),
        ]
    }
}

/// The bark of a block as the line build sees it.
///
/// Every vertex index must be in range; [`build_lines`] panics otherwise.
#[derive(Clone, Copy, Debug)]
pub struct LineMesh<'a> {
    /// Vertices (only the position is read), metres, block space.
    pub vertices: &'a [VertexRecord],
    /// The bark triangles, as indices into `vertices`.
    pub triangles: &'a [[u32; 3]],
    /// Per triangle, its linear RGBA colour (alpha ignored); white where missing.
    pub colours: &'a [Vec4],
}

/// One level of one cell's hierarchy, for reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineLevel {
    /// Lines in this snapshot.
    pub count: u32,
    /// Its error `e_k`, metres per pixel: the upper end of its interval.
    pub threshold: f32,
}

/// The lines of one grid cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CellLines {
    /// In SPT order (spec §6.9, §10): sorted by `hi`, largest first; leaf ids `0 .. n` are the
    /// cell's source segments.
    pub records: Vec<LineRecord>,
    /// Bounds of the lines (endpoints grown by their radii), block space; `None` without records.
    pub bounds: Option<(Vec3, Vec3)>,
    /// Per leaf id (the records' `leaf_first ..`), the source segment's triangles as indices into
    /// [`LineMesh::triangles`]: what the ambient occlusion of a record averages over (spec
    /// §6.14).
    pub segment_triangles: Vec<Vec<u32>>,
    /// Its levels (snapshots), finest (the source segments) first.
    pub levels: Vec<LineLevel>,
}

/// What [`build_lines`] returns.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lines {
    /// Per grid cell, in cell order.
    pub cells: Vec<CellLines>,
    /// The block's far lines (`FAR_LINES`, spec §6.9.1): the cells' coarsest lines merged across
    /// cells, one hierarchy; empty where nothing merges (one coarsest line in all).
    pub far: CellLines,
    /// Source segments of the skeleton, all cells.
    pub source_segments: u64,
    /// Connected components of the welded bark.
    pub components: u64,
}

impl Lines {
    /// Lines per level (level 0: the source segments), summed over the cells.
    #[must_use]
    pub fn per_level(&self) -> Vec<u32> {
        let mut counts: Vec<u32> = Vec::new();
        for cell in &self.cells {
            if counts.len() < cell.levels.len() {
                counts.resize(cell.levels.len(), 0);
            }
            for (k, level) in cell.levels.iter().enumerate() {
                counts[k] += level.count;
            }
        }
        counts
    }

    /// Records written, all cells.
    #[must_use]
    pub fn count(&self) -> usize {
        self.cells.iter().map(|c| c.records.len()).sum()
    }
}

/// Builds the skeleton of `mesh`'s bark and each cell's line hierarchy (module documentation).
/// `cell_of` maps a point to its grid cell, `0 .. cell_count`.
///
/// # Errors
/// [`BuildError::Setting`] for a bad `config`, [`BuildError::Spt`] if an internal invariant breaks.
///
/// # Panics
/// If a vertex index of `mesh` is out of range, or `cell_of` returns `cell_count` or more.
pub fn build_lines(
    mesh: &LineMesh<'_>,
    cell_of: impl Fn(Vec3) -> usize + Sync,
    cell_count: usize,
    config: &LineConfig,
) -> Result<Lines, BuildError> {
    config.validate()?;
    let skeleton = skeleton(mesh);
    let mut per_cell: Vec<Vec<u32>> = vec![Vec::new(); cell_count];
    for (i, s) in skeleton.segments.iter().enumerate() {
        #[expect(clippy::cast_possible_truncation, reason = "fewer segments than triangles")]
        per_cell[cell_of((0.5 * (s.p0 + s.p1)).as_vec3())].push(i as u32);
    }
    let context = ErrorViews::new(&skeleton.points, config);
    let built: Vec<(CellLines, Option<History>)> = per_cell
        .par_iter()
        .enumerate()
        .map(|(cell, ids)| build_cell(&skeleton.segments, ids, &context, config, cell as u64))
        .collect::<Result<_, BuildError>>()?;
    let (cells, histories): (Vec<CellLines>, Vec<Option<History>>) = built.into_iter().unzip();
    let far = far_lines(&skeleton.segments, &per_cell, &cells, &histories, &context, config)?;
    Ok(Lines { cells, far, source_segments: skeleton.segments.len() as u64, components: skeleton.components as u64 })
}

/// The level blend, octaves, whose fades the far lines' switch avoids: the reference blend of
/// spec §6.9.1, the renderer's default. A cell's level boundary `e` fades over
/// `[e·2^(−β/2), e·2^(β/2))`.
pub const FAR_BLEND: f32 = 0.5;

/// The far lines take over where the cells draw at most this many times the lines of their
/// coarsest levels (spec §6.9.1): where the cells have all but finished merging, so a tree drawn
/// near enough to be cut by the view or biased in depth per cell still draws the cells' lines.
pub const FAR_TAKEOVER: f32 = 1.125;

/// A far leaf: line `line` of a cell's merge forest `forest`, whose first `ids.len()` lines are
/// the cell's source segments `ids` (global), in order.
struct FarLeaf<'a> {
    forest: &'a [Line],
    ids: &'a [u32],
    line: u32,
}

/// The block's far lines (spec §6.9.1): the lines every cell draws at the switch `τ_s`
/// ([`far_switch`]) as source lines, each hanging from the one that holds its out-of-cell
/// parent segment, merged by the cells' rule (straighten, combine; module documentation) down
/// to one line per tree of the block. Their levels keep the ratios of their mean widths, level 0
/// ending half an octave above the switch (`τ_far = τ_s·√2`, spec §6.9.1): a runtime switches at
/// `τ_s` and finds them drawing exactly the cells' lines, level 1 not yet fading in. Empty where
/// no merge is possible; records that span several levels are split per level
/// (`split_by_level`).
fn far_lines(
    segments: &[Segment],
    per_cell: &[Vec<u32>],
    cells: &[CellLines],
    histories: &[Option<History>],
    views: &ErrorViews,
    config: &LineConfig,
) -> Result<CellLines, BuildError> {
    let Some(switch) = far_switch(cells) else { return Ok(CellLines::default()) };
    // The lines each cell draws at the switch, in cell order.
    let mut leaves: Vec<FarLeaf<'_>> = Vec::new();
    for ((lines, history), ids) in cells.iter().zip(histories).zip(per_cell) {
        let Some(history) = history else { continue };
        let k = lines.levels.iter().position(|l| switch < l.threshold).unwrap_or(lines.levels.len() - 1);
        let forest = &history.forest.lines[..];
        leaves.extend(history.snapshots[k].iter().map(|&line| FarLeaf { forest, ids, line }));
    }
    if leaves.len() < 2 {
        return Ok(CellLines::default());
    }
    // Each leaf's source segments (global ids), and the leaf of each segment.
    let sources: Vec<Vec<u32>> = leaves
        .iter()
        .map(|leaf| {
            let mut out = Vec::new();
            let mut stack = vec![leaf.line];
            while let Some(l) = stack.pop() {
                match leaf.forest[l as usize].merged {
                    Some([a, b]) => stack.extend([b, a]),
                    None => out.push(leaf.ids[l as usize]),
                }
            }
            out.sort_unstable();
            out
        })
        .collect();
    let mut leaf_of: HashMap<u32, u32> = HashMap::new();
    for (i, leaf_sources) in sources.iter().enumerate() {
        for &g in leaf_sources {
            leaf_of.insert(g, u32::try_from(i).unwrap_or(u32::MAX));
        }
    }
    let far: Vec<Segment> = leaves
        .iter()
        .zip(&sources)
        .enumerate()
        .map(|(i, (leaf, leaf_sources))| {
            let line = &leaf.forest[leaf.line as usize];
            // Its segments hang together, or (combined siblings) from one parent segment: the
            // parent of the first whose parent is not its own.
            let here = u32::try_from(i).unwrap_or(u32::MAX);
            let parent = leaf_sources
                .iter()
                .filter_map(|&g| segments[g as usize].parent)
                .filter_map(|p| leaf_of.get(&p).copied())
                .find(|&l| l != here);
            let mut triangles: Vec<u32> =
                leaf_sources.iter().flat_map(|&g| segments[g as usize].triangles.iter().copied()).collect();
            triangles.sort_unstable();
            Segment {
                p0: line.p0,
                r0: line.r0,
                p1: line.p1,
                r1: line.r1,
                weight: line.weight,
                colour: line.colour,
                parent,
                triangles,
            }
        })
        .collect();
    let ids: Vec<u32> = (0..u32::try_from(far.len()).unwrap_or(u32::MAX)).collect();
    let history = simplify(&far, &ids, views, config, per_cell.len() as u64);
    if history.snapshots.len() < 2 {
        return Ok(CellLines::default());
    }
    let mut lines = records(&far, &ids, &history, config.pixels, switch * treelod_format::FAR_SWITCH_OCTAVES.exp2())?;
    lines.records = split_by_level(&lines.records, &lines.levels);
    Ok(lines)
}

/// `records` (SPT order) with every record that spans several levels (a line unchanged from
/// level `j` to `k`, `[e_{j−1}, e_k)`) split into one record per level, then in SPT order again
/// (by `hi`, largest first; stable). The exact cut still holds (a leaf's chain of intervals is
/// the same, cut at the levels' boundaries), and now every level's records follow the coarser
/// levels' in the array, so a runtime can skip the head of coarser levels that a prefix holds
/// but does not draw (`LineLod`): just past the switch, far lines whose leaves persist over
/// several levels would otherwise submit every level.
fn split_by_level(records: &[LineRecord], levels: &[LineLevel]) -> Vec<LineRecord> {
    let mut out = Vec::with_capacity(records.len());
    for r in records {
        let mut lo = r.lo;
        for e in levels.iter().map(|l| l.threshold).filter(|&e| r.lo < e && e < r.hi) {
            out.push(LineRecord { lo, hi: e, ..*r });
            lo = e;
        }
        out.push(LineRecord { lo, ..*r });
    }
    out.sort_by(|a, b| b.hi.total_cmp(&a.hi));
    out
}

/// Where a runtime with the default level blend ([`FAR_BLEND`]) switches a tree from the cells'
/// lines to the far lines: from the least `τ` at which the cells draw no more than
/// [`FAR_TAKEOVER`] times the lines of their coarsest levels, the first stretch of `τ` where no
/// cell is fading between two levels (outside `[e·2^(−β/2), e·2^(β/2))` of every cell's level
/// boundary `e`), and within it the geometric middle (a quarter octave into it where it has no
/// end), so that cells a little nearer or farther than the one measured (a perspective view,
/// the depth bias) draw the same lines; `None` without a boundary.
fn far_switch(cells: &[CellLines]) -> Option<f32> {
    let records = || cells.iter().flat_map(|c| &c.records);
    let mut boundaries: Vec<f32> = records().map(|l| l.lo).filter(|&lo| lo > 0.0 && lo.is_finite()).collect();
    boundaries.sort_by(f32::total_cmp);
    boundaries.dedup();
    let coarsest = records().filter(|l| l.hi == f32::INFINITY).count();
    #[expect(clippy::cast_precision_loss, reason = "line counts")]
    let takeover =
        |tau: f32| records().filter(|l| l.lo <= tau && tau < l.hi).count() as f32 <= FAR_TAKEOVER * coarsest as f32;
    let half = (0.5 * FAR_BLEND).exp2();
    // Counts change only at boundaries: the first boundary from which the cells are few enough.
    let mut start = *boundaries.iter().find(|&&e| takeover(e))? * half;
    while let Some(&e) = boundaries.iter().find(|&&e| e / half <= start && start < e * half) {
        start = e * half;
    }
    Some(match boundaries.iter().map(|&e| e / half).find(|&fade| fade > start) {
        Some(end) => (start * end).sqrt(),
        None => start * half,
    })
}

// ---------------------------------------------------------------------------------------------
// Skeleton
// ---------------------------------------------------------------------------------------------

/// A source segment of the skeleton, block space.
#[derive(Clone, Debug, PartialEq)]
struct Segment {
    p0: DVec3,
    r0: f64,
    p1: DVec3,
    r1: f64,
    /// Frustum volume, m³.
    weight: f64,
    /// Linear RGB.
    colour: DVec3,
    /// The segment ending where this one starts.
    parent: Option<u32>,
    /// Indices into the mesh's triangles.
    triangles: Vec<u32>,
}

impl Segment {
    fn volume(p0: DVec3, r0: f64, p1: DVec3, r1: f64) -> f64 {
        std::f64::consts::PI * p0.distance(p1) * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0
    }
}

/// The skeleton of a mesh's bark.
#[derive(Clone, Debug, Default)]
struct Skeleton {
    segments: Vec<Segment>,
    components: usize,
    /// The welded positions (for the image-error views' bounding sphere).
    points: Vec<Vec3>,
}

/// The welded bark: positions, triangles and a CSR adjacency with edge lengths and boundary flags.
struct Graph {
    positions: Vec<DVec3>,
    /// Per welded vertex, a third of the area of the triangles around it.
    vertex_area: Vec<f64>,
    /// Per welded vertex, its neighbours `start[v] .. start[v + 1]` in `neighbours`.
    start: Vec<usize>,
    neighbours: Vec<(u32, f64, bool)>,
}

impl Graph {
    /// Whether `v` is on an open boundary.
    fn on_boundary(&self, v: u32) -> bool {
        self.edges(v).iter().any(|e| e.2)
    }

    fn edges(&self, v: u32) -> &[(u32, f64, bool)] {
        &self.neighbours[self.start[v as usize]..self.start[v as usize + 1]]
    }
}

/// A skeleton node: a connected piece of one geodesic slice of one component.
#[derive(Clone, Debug)]
struct Node {
    bin: u32,
    vertices: Vec<u32>,
    centroid: DVec3,
    radius: f64,
    parent: Option<u32>,
    /// Start of its segment: point and radius.
    start: (DVec3, f64),
}

/// What one component's slicing gives.
struct Slicing {
    /// Slice width, metres.
    h: f64,
    /// The nodes, by bin then least vertex.
    nodes: Vec<Node>,
    /// Centroid and radius of the source vertices.
    base: (DVec3, f64),
}

/// The skeleton of `mesh`'s bark (module documentation).
#[expect(clippy::too_many_lines, reason = "one pass of named steps")]
fn skeleton(mesh: &LineMesh<'_>) -> Skeleton {
    let position = |v: u32| DVec3::from(Vec3::from_array(mesh.vertices[v as usize].position));
    // Triangles with a non-finite corner are left out.
    let triangles: Vec<u32> = (0..mesh.triangles.len())
        .filter(|&t| mesh.triangles[t].iter().all(|&v| position(v).is_finite()))
        .map(|t| u32::try_from(t).unwrap_or(u32::MAX))
        .collect();
    if triangles.is_empty() {
        return Skeleton::default();
    }
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &t in &triangles {
        for v in mesh.triangles[t as usize] {
            lo = lo.min(position(v));
            hi = hi.max(position(v));
        }
    }
    let diag = (hi - lo).length();
    let quantum = if diag > 0.0 { WELD * diag } else { 1.0 };
    let min_radius = (MIN_RADIUS * diag).max(1e-12);

    // Step: weld.
    let mut welded: HashMap<[i64; 3], u32> = HashMap::new();
    let mut positions: Vec<DVec3> = Vec::new();
    #[expect(clippy::cast_possible_truncation, reason = "quantised coordinates of finite positions")]
    let welded_tris: Vec<[u32; 3]> = triangles
        .iter()
        .map(|&t| {
            mesh.triangles[t as usize].map(|v| {
                let p = position(v);
                let key = ((p - lo) / quantum).round().to_array().map(|c| c as i64);
                *welded.entry(key).or_insert_with(|| {
                    positions.push(p);
                    u32::try_from(positions.len() - 1).unwrap_or(u32::MAX)
                })
            })
        })
        .collect();
    drop(welded);
    let n = positions.len();

    // Step: components (union–find over the triangles' corners) and their areas.
    let mut uf = singletons(n);
    for t in &welded_tris {
        union(&mut uf, t[0], t[1]);
        union(&mut uf, t[0], t[2]);
    }
    let mut component_of = vec![u32::MAX; n];
    let mut component_vertices: Vec<Vec<u32>> = Vec::new();
    #[expect(clippy::cast_possible_truncation, reason = "fewer welded vertices than 2^32")]
    for v in 0..n as u32 {
        let root = find(&mut uf, v) as usize;
        if component_of[root] == u32::MAX {
            component_of[root] = component_vertices.len() as u32;
            component_vertices.push(Vec::new());
        }
        let c = component_of[root];
        component_of[v as usize] = c;
        component_vertices[c as usize].push(v);
    }
    let components = component_vertices.len();
    let mut area = vec![0.0f64; components];
    let tri_area = |t: u32| {
        let [a, b, c] = mesh.triangles[t as usize].map(position);
        0.5 * (b - a).cross(c - a).length()
    };
    let mut vertex_area = vec![0.0f64; n];
    for (&t, w) in triangles.iter().zip(&welded_tris) {
        let a = tri_area(t);
        area[component_of[w[0] as usize] as usize] += a;
        for &v in w {
            vertex_area[v as usize] += a / 3.0;
        }
    }

    // Step: the welded edges with lengths and boundary flags (used by one triangle).
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(3 * welded_tris.len());
    for t in &welded_tris {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            if a != b {
                edges.push((a.min(b), a.max(b)));
            }
        }
    }
    edges.sort_unstable();
    let mut unique: Vec<(u32, u32, bool)> = Vec::new();
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        unique.push((edges[i].0, edges[i].1, j - i == 1));
        i = j;
    }
    drop(edges);
    let mut degree = vec![0usize; n + 1];
    for &(a, b, _) in &unique {
        degree[a as usize] += 1;
        degree[b as usize] += 1;
    }
    let mut start = vec![0usize; n + 1];
    for v in 0..n {
        start[v + 1] = start[v] + degree[v];
    }
    let mut fill = start.clone();
    let mut neighbours = vec![(0u32, 0.0f64, false); start[n]];
    for &(a, b, boundary) in &unique {
        let len = positions[a as usize].distance(positions[b as usize]);
        neighbours[fill[a as usize]] = (b, len, boundary);
        fill[a as usize] += 1;
        neighbours[fill[b as usize]] = (a, len, boundary);
        fill[b as usize] += 1;
    }
    // Sorted neighbours make every traversal's order independent of the edge list's.
    for v in 0..n {
        neighbours[start[v]..start[v + 1]].sort_by_key(|x| x.0);
    }
    let graph = Graph { positions, vertex_area, start, neighbours };

    // Step: rank components by area, largest first.
    let mut rank: Vec<usize> = (0..components).collect();
    rank.sort_by(|&a, &b| area[b].total_cmp(&area[a]).then(a.cmp(&b)));

    // Step: per component in rank order, its root, slices and nodes.
    let mut grid = VertexGrid::new(&graph.positions, lo, hi);
    let mut dist = vec![f64::INFINITY; n];
    let mut node_of = vec![u32::MAX; n];
    let mut nodes: Vec<Node> = Vec::new();
    // Per node: its children (for the attachment search).
    let mut node_children: Vec<Vec<u32>> = Vec::new();
    // The largest component's slice width: the reach within which small pieces are attached.
    let mut trunk_slice = 0.0;
    let lowest = |vertices: &[u32]| {
        let mut best = vertices[0];
        for &v in vertices {
            if graph.positions[v as usize].y < graph.positions[best as usize].y {
                best = v;
            }
        }
        best
    };
    for (r, &c) in rank.iter().enumerate() {
        let vertices = &component_vertices[c];
        // A branch tube starts at the open end that lies deepest in the larger components'
        // skeleton (usually inside its parent), not where it crosses the parent's surface; a
        // closed component at its vertex nearest to a larger component.
        let mut chosen = None;
        if r > 0 {
            // A loop holding half the component's vertices is the outline of a flat piece (a
            // strip, a card), not the cut end of a tube.
            let mut starts = boundary_loops(&graph, vertices);
            starts.retain(|l| 2 * l.len() <= vertices.len());
            if starts.is_empty()
                && let Some((own, _, _)) = grid.nearest(vertices.iter().map(|&v| (v, graph.positions[v as usize])))
            {
                starts.push(vec![own]);
            }
            let mut best: Option<(f64, u32, usize)> = None;
            for (i, start) in starts.iter().enumerate() {
                let centre = centroid(&graph, start);
                let Some((_, foreign, _)) = grid.nearest(std::iter::once((0, centre))) else { continue };
                let (node, depth) = deepest(&nodes, &node_children, node_of[foreign as usize], centre);
                if best.is_none_or(|b| depth < b.0) {
                    best = Some((depth, node, i));
                }
            }
            if let Some((depth, node, i)) = best {
                let s = slice(&graph, vertices, &starts[i], area[c], min_radius, &mut dist);
                let close = depth <= 2.0 * s.h + nodes[node as usize].radius;
                let debris = area[c] < SMALL_PIECE * area[rank[0]] && depth <= 2.0 * trunk_slice;
                if close || debris {
                    chosen = Some((s, node));
                }
            }
        }
        let (slicing, attach) = match chosen {
            Some((s, node)) => (s, Some(node)),
            None => {
                // The open end at the lowest vertex (a tube's base); without one (a closed or
                // flared base: the jacaranda's roots), every vertex within 1 % of the component's
                // height of its lowest, so that the first slices lie level instead of climbing
                // from one root tip.
                let mut sources = boundary_loop(&graph, lowest(vertices));
                if sources.len() == 1 || 2 * sources.len() > vertices.len() {
                    let y = |v: u32| graph.positions[v as usize].y;
                    let (y0, y1) = vertices
                        .iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(y(v)), b.max(y(v))));
                    sources = vertices.iter().copied().filter(|&v| y(v) <= y0 + 0.01 * (y1 - y0)).collect();
                }
                (slice(&graph, vertices, &sources, area[c], min_radius, &mut dist), None)
            }
        };
        if r == 0 {
            trunk_slice = slicing.h;
        }
        let first = u32::try_from(nodes.len()).unwrap_or(u32::MAX);
        for (k, mut node) in slicing.nodes.into_iter().enumerate() {
            let id = first + u32::try_from(k).unwrap_or(u32::MAX);
            node.start = match (node.parent.as_mut(), attach) {
                (Some(p), _) => {
                    *p += first;
                    (nodes[*p as usize].centroid, nodes[*p as usize].radius)
                }
                (None, Some(a)) => {
                    node.parent = Some(a);
                    (nodes[a as usize].centroid, node.radius)
                }
                (None, None) => slicing.base,
            };
            if let Some(p) = node.parent {
                node_children[p as usize].push(id);
            }
            for &v in &node.vertices {
                node_of[v as usize] = id;
            }
            nodes.push(node);
            node_children.push(Vec::new());
        }
        for &v in vertices {
            grid.insert(v, graph.positions[v as usize]);
        }
    }

    // Step: segments, one per node, with their triangles, colours and weights.
    let mut node_triangles: Vec<Vec<u32>> = vec![Vec::new(); nodes.len()];
    for (&t, w) in triangles.iter().zip(&welded_tris) {
        node_triangles[node_of[w[0] as usize] as usize].push(t);
    }
    let colour_of = |t: u32| mesh.colours.get(t as usize).map_or(DVec3::ONE, |c| c.truncate().as_dvec3());
    let mut mean_colour = DVec3::ZERO;
    for &t in &triangles {
        mean_colour += colour_of(t);
    }
    mean_colour /= triangles.len() as f64;
    let mut segments: Vec<Segment> = Vec::with_capacity(nodes.len());
    for (i, node) in nodes.iter().enumerate() {
        let (p0, r0) = node.start;
        let (p1, r1) = (node.centroid, node.radius);
        let tris = std::mem::take(&mut node_triangles[i]);
        let (mut sum, mut weight, mut plain) = (DVec3::ZERO, 0.0, DVec3::ZERO);
        for &t in &tris {
            let a = tri_area(t);
            sum += a * colour_of(t);
            weight += a;
            plain += colour_of(t);
        }
        let colour = if weight > 0.0 {
            sum / weight
        } else if !tris.is_empty() {
            plain / tris.len() as f64
        } else {
            node.parent.map_or(mean_colour, |p| segments[p as usize].colour)
        };
        segments.push(Segment {
            p0,
            r0,
            p1,
            r1,
            weight: Segment::volume(p0, r0, p1, r1),
            colour,
            parent: node.parent,
            triangles: tris,
        });
    }
    let points = graph.positions.iter().map(|p| p.as_vec3()).collect();
    Skeleton { segments, components, points }
}

/// The node whose segment (a cone with round ends) `point` lies deepest in, and that depth as a
/// signed distance to its surface (negative inside), among `near` (the node of the nearest foreign
/// vertex), [`ATTACH_ANCESTORS`] of its ancestors and their children (ties: the lower node).
fn deepest(nodes: &[Node], children: &[Vec<u32>], near: u32, point: DVec3) -> (u32, f64) {
    let mut chain = vec![near];
    while chain.len() <= ATTACH_ANCESTORS
        && let Some(p) = chain.last().and_then(|&n| nodes[n as usize].parent)
    {
        chain.push(p);
    }
    let mut candidates: Vec<u32> = chain.iter().flat_map(|&n| children[n as usize].iter().copied()).collect();
    candidates.extend(chain);
    candidates.sort_unstable();
    candidates.dedup();
    let depth = |n: u32| {
        let node = &nodes[n as usize];
        let ((a, r0), (b, r1)) = (node.start, (node.centroid, node.radius));
        let d = b - a;
        let t = if d.length_squared() > 0.0 { ((point - a).dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
        point.distance(a + t * d) - (r0 + t * (r1 - r0))
    };
    let mut best = (near, depth(near));
    for n in candidates {
        let d = depth(n);
        if d < best.1 || (d == best.1 && n < best.0) {
            best = (n, d);
        }
    }
    best
}

/// The open boundary loop through `root` (its connected boundary edges), ascending; `root` alone
/// if it is on no boundary.
fn boundary_loop(graph: &Graph, root: u32) -> Vec<u32> {
    let mut sources = vec![root];
    let mut seen: HashMap<u32, ()> = HashMap::from([(root, ())]);
    let mut next = 0;
    while next < sources.len() {
        let v = sources[next];
        next += 1;
        for &(w, _, boundary) in graph.edges(v) {
            if boundary && seen.insert(w, ()).is_none() {
                sources.push(w);
            }
        }
    }
    sources.sort_unstable();
    sources
}

/// Every open boundary loop of a component, each ascending, ordered by least vertex.
fn boundary_loops(graph: &Graph, vertices: &[u32]) -> Vec<Vec<u32>> {
    let mut done: HashMap<u32, ()> = HashMap::new();
    let mut loops = Vec::new();
    for &v in vertices {
        if graph.on_boundary(v) && !done.contains_key(&v) {
            let l = boundary_loop(graph, v);
            done.extend(l.iter().map(|&w| (w, ())));
            loops.push(l);
        }
    }
    loops.sort_by_key(|l| l[0]);
    loops
}

/// The mean position of `vertices` (not empty).
fn centroid(graph: &Graph, vertices: &[u32]) -> DVec3 {
    vertices.iter().map(|&v| graph.positions[v as usize]).sum::<DVec3>() / vertices.len() as f64
}

/// Slices one component from `sources` (module documentation): Dijkstra from them, bins of width `h`, their connected pieces as nodes with
/// parents inside the component (bin-0 nodes have none), centroids and radii. `dist` is scratch
/// space, `+∞` outside the component's vertices on return.
fn slice(graph: &Graph, vertices: &[u32], sources: &[u32], area: f64, min_radius: f64, dist: &mut [f64]) -> Slicing {
    let centroid_of = |vs: &[u32]| centroid(graph, vs);
    let base_centre = centroid_of(sources);
    let base_radius =
        sources.iter().map(|&v| graph.positions[v as usize].distance(base_centre)).sum::<f64>() / sources.len() as f64;

    // Dijkstra; the heap key is (distance bits, vertex): non-negative floats order as their bits.
    let mut heap = BinaryHeap::new();
    for &s in sources {
        dist[s as usize] = 0.0;
        heap.push(Reverse((0u64, s)));
    }
    while let Some(Reverse((bits, v))) = heap.pop() {
        let d = f64::from_bits(bits);
        if d > dist[v as usize] {
            continue;
        }
        for &(w, len, _) in graph.edges(v) {
            let nd = d + len;
            if nd < dist[w as usize] {
                dist[w as usize] = nd;
                heap.push(Reverse((nd.to_bits(), w)));
            }
        }
    }
    let length = vertices.iter().map(|&v| dist[v as usize]).fold(0.0, f64::max);
    let local: HashMap<u32, u32> =
        vertices.iter().enumerate().map(|(i, &v)| (v, u32::try_from(i).unwrap_or(u32::MAX))).collect();
    // No narrower than the mesh's long edges either (the 90th percentile of its edge lengths),
    // or a coarse mesh's rings fall apart into single vertices, each a spike of a node.
    let mut edges: Vec<f64> = vertices.iter().flat_map(|&v| graph.edges(v).iter().map(|&(_, len, _)| len)).collect();
    let long_edge = if edges.is_empty() {
        0.0
    } else {
        let k = (edges.len() * 9 / 10).min(edges.len() - 1);
        *edges.select_nth_unstable_by(k, f64::total_cmp).1
    };
    // The branches' thickness: the median radius (largest distance of a piece's vertices to its
    // centroid: a ring's radius, a little more for a ring and a half, where a mean would shrink
    // for a piece that is an arc of a ring) of the pieces of fine slices. A component's area over its length, the radius of
    // a cylinder, is right for one tube but counts every branch of a merged mesh (a trunk with
    // its forks and limbs) into one radius several times too large, whose slices then join the
    // stems of a fork into one fat node.
    let fine = (length / FINE_SLICES).max(min_radius);
    let fine_pieces = pieces(graph, vertices, &local, |v| bin(dist[v as usize], fine));
    let mut radii: Vec<f64> = fine_pieces
        .values()
        .map(|vs| {
            let c = centroid_of(vs);
            vs.iter().map(|&v| graph.positions[v as usize].distance(c)).fold(0.0, f64::max)
        })
        .collect();
    radii.sort_unstable_by(f64::total_cmp);
    let r_est = match radii.get(radii.len() / 2) {
        Some(&r) => r,
        None if length > 0.0 => area / (std::f64::consts::TAU * length),
        None => 0.0,
    };
    let h = (2.0 * r_est).max(long_edge).max(length / MAX_SLICES).max(min_radius);
    let bin_of = |v: u32| bin(dist[v as usize], h);
    let pieces = pieces(graph, vertices, &local, bin_of);
    let mut piece_of: HashMap<u32, u32> = HashMap::new();
    let mut nodes: Vec<Node> = Vec::with_capacity(pieces.len());
    for ((bin, _), mut vs) in pieces {
        vs.sort_unstable();
        let id = u32::try_from(nodes.len()).unwrap_or(u32::MAX);
        for &v in &vs {
            piece_of.insert(v, id);
        }
        let centroid = centroid_of(&vs);
        nodes.push(Node { bin, vertices: vs, centroid, radius: 0.0, parent: None, start: (centroid, 0.0) });
    }
    // Parents: the node of the highest lower bin sharing an edge (ties: the lower node).
    for node in &mut nodes {
        let bin = node.bin;
        let mut best: Option<(u32, u32)> = None;
        for &v in &node.vertices {
            for &(w, _, _) in graph.edges(v) {
                let b = bin_of(w);
                if b < bin {
                    let candidate = (b, piece_of[&w]);
                    best = Some(match best {
                        Some(old) if (old.0, Reverse(old.1)) >= (candidate.0, Reverse(candidate.1)) => old,
                        _ => candidate,
                    });
                }
            }
        }
        node.parent = best.map(|b| b.1);
    }
    // Tip crumbs: a piece of fewer than 3 vertices with a parent and no children (the last few
    // vertices of a tube's end, cut off by the last bin) joins its parent instead of becoming a
    // node: its segment would point anywhere, with no thickness.
    let mut has_child = vec![false; nodes.len()];
    for node in &nodes {
        if let Some(p) = node.parent {
            has_child[p as usize] = true;
        }
    }
    let crumb = |i: usize, node: &Node| node.vertices.len() < 3 && node.parent.is_some() && !has_child[i];
    if nodes.iter().enumerate().any(|(i, n)| crumb(i, n)) {
        let mut new_id = vec![u32::MAX; nodes.len()];
        let mut kept: Vec<Node> = Vec::with_capacity(nodes.len());
        let mut folded: Vec<(u32, Vec<u32>)> = Vec::new();
        for (i, node) in nodes.into_iter().enumerate() {
            if crumb(i, &node) {
                folded.push((node.parent.unwrap_or(0), node.vertices));
            } else {
                new_id[i] = u32::try_from(kept.len()).unwrap_or(u32::MAX);
                kept.push(node);
            }
        }
        for node in &mut kept {
            // A crumb has no children, so every parent is kept.
            node.parent = node.parent.map(|p| new_id[p as usize]);
        }
        for (parent, vs) in folded {
            let target = &mut kept[new_id[parent as usize] as usize];
            target.vertices.extend(vs);
            target.vertices.sort_unstable();
        }
        nodes = kept;
    }
    // Radii: mean distance to the axis through the centroid.
    let mut first_child = vec![None::<u32>; nodes.len()];
    for i in (0..nodes.len()).rev() {
        if let Some(p) = nodes[i].parent {
            first_child[p as usize] = Some(u32::try_from(i).unwrap_or(u32::MAX));
        }
    }
    for i in 0..nodes.len() {
        let c = nodes[i].centroid;
        let axis = match (nodes[i].parent, first_child[i]) {
            (Some(p), _) => c - nodes[p as usize].centroid,
            (None, Some(k)) => nodes[k as usize].centroid - c,
            (None, None) => DVec3::ZERO,
        }
        .normalize_or_zero();
        let sum: f64 = nodes[i]
            .vertices
            .iter()
            .map(|&v| {
                let d = graph.positions[v as usize] - c;
                (d - d.dot(axis) * axis).length()
            })
            .sum();
        // No more than a tube of the piece's area and geodesic length would have: a piece that
        // is not a ring (a whole twig in one slice of a coarse mesh, a flat strip, the stems of
        // a fork) has no single axis, and its distances from one overstate its thickness.
        let (d0, d1) = nodes[i]
            .vertices
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(dist[v as usize]), b.max(dist[v as usize])));
        let piece_area: f64 = nodes[i].vertices.iter().map(|&v| graph.vertex_area[v as usize]).sum();
        let mut radius = sum / nodes[i].vertices.len() as f64;
        if d1 > d0 && piece_area > 0.0 {
            radius = radius.min(piece_area / (std::f64::consts::TAU * (d1 - d0)));
        }
        nodes[i].radius = radius.max(min_radius);
    }
    for &v in vertices {
        dist[v as usize] = f64::INFINITY;
    }
    // The base's radius: the sources' spread about their centroid (a tube's open end), but no
    // more than the first node's (a flared base's sources spread over its roots).
    let base_radius =
        if sources.len() > 1 { base_radius.min(nodes[0].radius).max(min_radius) } else { nodes[0].radius };
    Slicing { h, nodes, base: (base_centre, base_radius) }
}

/// The bin of distance `d` in slices of width `h`.
fn bin(d: f64, h: f64) -> u32 {
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to u32")]
    let b = (d / h).floor().clamp(0.0, f64::from(u32::MAX)) as u32;
    b
}

/// The connected pieces of each bin of `vertices` (union–find over the edges inside a bin, on the
/// component's own indices `local`), keyed and ordered by (bin, least vertex).
fn pieces(
    graph: &Graph,
    vertices: &[u32],
    local: &HashMap<u32, u32>,
    bin_of: impl Fn(u32) -> u32,
) -> BTreeMap<(u32, u32), Vec<u32>> {
    let mut uf = singletons(vertices.len());
    for &v in vertices {
        for &(w, _, _) in graph.edges(v) {
            if bin_of(v) == bin_of(w) {
                union(&mut uf, local[&v], local[&w]);
            }
        }
    }
    let mut pieces: BTreeMap<(u32, u32), Vec<u32>> = BTreeMap::new();
    let mut least: HashMap<u32, u32> = HashMap::new();
    for &v in vertices {
        let root = find(&mut uf, local[&v]);
        let entry = least.entry(root).or_insert(v);
        *entry = (*entry).min(v);
    }
    for &v in vertices {
        let root = find(&mut uf, local[&v]);
        pieces.entry((bin_of(v), least[&root])).or_default().push(v);
    }
    pieces
}

/// A uniform grid over the welded vertices for nearest-vertex queries, filled as components are
/// processed.
struct VertexGrid<'a> {
    positions: &'a [DVec3],
    lo: DVec3,
    cell: f64,
    dims: [i64; 3],
    cells: Vec<Vec<u32>>,
}

impl<'a> VertexGrid<'a> {
    fn new(positions: &'a [DVec3], lo: DVec3, hi: DVec3) -> Self {
        let extent = (hi - lo).max(DVec3::splat((hi - lo).length() * 1e-3)).max(DVec3::splat(1e-9));
        // About one vertex per cell, at most 2^21 cells.
        let target = (positions.len() as f64).clamp(1.0, 2_097_152.0);
        let cell = (extent.x * extent.y * extent.z / target).cbrt();
        #[expect(clippy::cast_possible_truncation, reason = "bounded by the cell count")]
        let dims = (extent / cell).ceil().max(DVec3::ONE).to_array().map(|d| (d as i64).clamp(1, 4096));
        #[expect(clippy::cast_sign_loss, reason = "dims are positive")]
        let count = (dims[0] * dims[1] * dims[2]) as usize;
        Self { positions, lo, cell, dims, cells: vec![Vec::new(); count] }
    }

    fn coords(&self, p: DVec3) -> [i64; 3] {
        #[expect(clippy::cast_possible_truncation, reason = "clamped to the grid")]
        let c = ((p - self.lo) / self.cell).floor().to_array().map(|c| c.clamp(-1.0, 1e9) as i64);
        [0, 1, 2].map(|i| c[i].clamp(0, self.dims[i] - 1))
    }

    fn index(&self, c: [i64; 3]) -> usize {
        #[expect(clippy::cast_sign_loss, reason = "coordinates inside the grid")]
        let i = ((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]) as usize;
        i
    }

    fn insert(&mut self, v: u32, p: DVec3) {
        let i = self.index(self.coords(p));
        self.cells[i].push(v);
    }

    /// The pair (query id, grid vertex) of least distance between the `queries` (id and point)
    /// and the vertices in the grid, and that distance (ties: the first query, then the lower
    /// grid vertex); `None` for an empty grid.
    fn nearest(&self, queries: impl Iterator<Item = (u32, DVec3)>) -> Option<(u32, u32, f64)> {
        let mut best: Option<(f64, u32, u32)> = None;
        let max_shell = self.dims.iter().copied().max().unwrap_or(1);
        for (v, p) in queries {
            let c = self.coords(p);
            for k in 0..=max_shell {
                // Vertices in shell k are at least (k − 1) cells away.
                #[expect(clippy::cast_precision_loss, reason = "small shell numbers")]
                let floor = (k - 1).max(0) as f64 * self.cell;
                if best.is_some_and(|b| b.0 < floor * floor) {
                    break;
                }
                self.shell(c, k, |w| {
                    let d2 = self.positions[w as usize].distance_squared(p);
                    if best.is_none_or(|(bd, bv, bw)| d2 < bd || (d2 == bd && bv == v && w < bw)) {
                        best = Some((d2, v, w));
                    }
                });
            }
        }
        best.map(|(d2, v, w)| (v, w, d2.sqrt()))
    }

    /// Calls `visit` with every vertex of the cells at Chebyshev distance `k` from `c`.
    fn shell(&self, c: [i64; 3], k: i64, mut visit: impl FnMut(u32)) {
        let inside = |i: usize, x: i64| x >= 0 && x < self.dims[i];
        for dz in -k..=k {
            let z = c[2] + dz;
            if !inside(2, z) {
                continue;
            }
            for dy in -k..=k {
                let y = c[1] + dy;
                if !inside(1, y) {
                    continue;
                }
                let face = dz.abs() == k || dy.abs() == k;
                let step = if face || k == 0 { 1 } else { 2 * k };
                let mut dx = -k;
                while dx <= k {
                    let x = c[0] + dx;
                    if inside(0, x) {
                        for &w in &self.cells[self.index([x, y, z])] {
                            visit(w);
                        }
                    }
                    dx += step.max(1);
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Image error
// ---------------------------------------------------------------------------------------------

/// The image-error views: fixed directions, one pixel size for the block.
struct ErrorViews {
    /// Per view: image right and up axes.
    axes: Vec<(DVec3, DVec3)>,
    /// The model-space point at pixel (0, 0) of every view's frame.
    origin: DVec3,
    /// Pixels per metre.
    scale: f64,
    /// Side of the full view, pixels.
    resolution: u32,
}

impl ErrorViews {
    fn new(points: &[Vec3], config: &LineConfig) -> Self {
        let (centre, radius) = bounding_sphere(points.iter().copied());
        let radius = if radius > 0.0 && radius.is_finite() { f64::from(radius) } else { 1e-3 };
        let axes = view_directions(config.views as usize)
            .into_iter()
            .map(|d| {
                let view = crate::raster::View::fit(d, centre, 1.0, 2);
                (view.right.as_dvec3(), view.up.as_dvec3())
            })
            .collect();
        Self {
            axes,
            origin: centre.as_dvec3(),
            scale: f64::from(config.resolution) / (2.0 * radius),
            resolution: config.resolution,
        }
    }

    /// Pixel coordinates (x right, y down) of `p` in view `v`, relative to the block centre.
    fn project(&self, v: usize, p: DVec3) -> DVec2 {
        let (right, up) = self.axes[v];
        let d = p - self.origin;
        DVec2::new(d.dot(right), -d.dot(up)) * self.scale
    }

    /// The image error of replacing `old` by `new` (module documentation): the mean over views
    /// and over the `log2 resolution + 1` levels of the RMSE, computed on the square around the
    /// lines.
    fn error(&self, old: [&Line; 2], new: &Line) -> f64 {
        let bands = self.resolution.trailing_zeros() as usize + 1;
        let mut total = 0.0;
        for v in 0..self.axes.len() {
            let disc = |p: DVec3, r: f64| (self.project(v, p), (r * self.scale).max(MIN_HALF_WIDTH));
            let shapes: [[(DVec2, f64); 2]; 3] = [old[0], old[1], new].map(|l| [disc(l.p0, l.r0), disc(l.p1, l.r1)]);
            let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
            for &(c, r) in shapes.iter().flatten() {
                lo = lo.min(c - r);
                hi = hi.max(c + r);
            }
            let origin = lo.floor() - 1.0;
            let span = (hi - origin).max_element().ceil() + 1.0;
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to the mask limit")]
            let side = (span.clamp(2.0, 4096.0) as u32).next_power_of_two();
            let (mut reference, mut test) = (Mask::new(side), Mask::new(side));
            for (mask, lines) in [(&mut reference, &shapes[..2]), (&mut test, &shapes[2..])] {
                for [(a, ra), (b, rb)] in lines {
                    fill_line(mask, (*a - origin).as_vec2(), *ra, (*b - origin).as_vec2(), *rb);
                }
            }
            let local = multiscale_rmse(&test, &reference).levels;
            #[expect(clippy::cast_precision_loss, reason = "pixel counts")]
            let difference = test.count() as f64 - reference.count() as f64;
            let mut sum = 0.0;
            for b in 0..bands {
                let squares = match local.get(b) {
                    Some(rmse) => rmse * rmse * f64::from(side >> b) * f64::from(side >> b),
                    None => (difference / 4f64.powi(i32::try_from(b).unwrap_or(i32::MAX))).powi(2),
                };
                sum += squares.sqrt() / f64::from(self.resolution >> b);
            }
            total += sum / bands as f64;
        }
        total / self.axes.len() as f64
    }
}

/// Covers the convex hull of the discs `(a, ra)` and `(b, rb)` (pixels): the outline of a cone
/// with round caps seen from the side.
fn fill_line(mask: &mut Mask, a: Vec2, ra: f64, b: Vec2, rb: f64) {
    fill_ellipse(mask, a, [ra * ra, 0.0, ra * ra]);
    fill_ellipse(mask, b, [rb * rb, 0.0, rb * rb]);
    let d = (b - a).as_dvec2();
    let len = d.length();
    if len <= (ra - rb).abs() || len == 0.0 {
        return;
    }
    let u = d / len;
    let n = DVec2::new(-u.y, u.x);
    let s = (ra - rb) / len;
    let c = (1.0 - s * s).max(0.0).sqrt();
    let (plus, minus) = (u * s + n * c, u * s - n * c);
    let (a, b) = (a.as_dvec2(), b.as_dvec2());
    let quad = [a + plus * ra, b + plus * rb, b + minus * rb, a + minus * ra].map(|p| p.as_vec2());
    let uv = [Vec2::ZERO; 3];
    fill_triangle(mask, [quad[0], quad[1], quad[2]], uv, None);
    fill_triangle(mask, [quad[0], quad[2], quad[3]], uv, None);
}

// ---------------------------------------------------------------------------------------------
// Hierarchy
// ---------------------------------------------------------------------------------------------

/// Where a line hangs in its cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Parent {
    /// A line of the cell.
    Line(u32),
    /// Out of the cell: the global id of the parent segment. Roots under the same one combine.
    External(u32),
    /// No parent: a tree's root, never combined.
    Alone,
}

/// A line of a cell's merge forest.
#[derive(Clone, Debug, PartialEq)]
struct Line {
    p0: DVec3,
    r0: f64,
    p1: DVec3,
    r1: f64,
    weight: f64,
    /// Linear RGB.
    colour: DVec3,
    parent: Parent,
    /// Its live children, ascending.
    children: Vec<u32>,
    alive: bool,
    /// The two lines it was made of; `None` for a source segment.
    merged: Option<[u32; 2]>,
}

/// A merge of two lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Merge {
    /// A line and its only child.
    Straighten { parent: u32, child: u32 },
    /// Two siblings, `a < b`.
    Combine { a: u32, b: u32 },
}

/// `a` and `b` averaged by the weights `wa`, `wb` (equally when both are 0).
fn mix<T: std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>>(a: T, wa: f64, b: T, wb: f64) -> T {
    let t = if wa + wb > 0.0 { wb / (wa + wb) } else { 0.5 };
    a * (1.0 - t) + b * t
}

/// The line a merge makes (without its links).
fn merged_line(lines: &[Line], merge: Merge) -> Line {
    let (a, b) = match merge {
        Merge::Straighten { parent, child } => (&lines[parent as usize], &lines[child as usize]),
        Merge::Combine { a, b } => (&lines[a as usize], &lines[b as usize]),
    };
    let (wa, wb) = (a.weight, b.weight);
    let (p0, r0, p1, r1) = match merge {
        Merge::Straighten { .. } => (a.p0, a.r0, b.p1, b.r1),
        Merge::Combine { .. } => {
            (mix(a.p0, wa, b.p0, wb), mix(a.r0, wa, b.r0, wb), mix(a.p1, wa, b.p1, wb), mix(a.r1, wa, b.r1, wb))
        }
    };
    // Keep part of the pair's silhouette: with `S = (r0 + r1)·length`, the area a line shows from
    // the side, the radii grow by `√((S_a + S_b) / S_merged)`, half-way (in log) between
    // Clasen's plain average, which halves the area of two equal siblings at each combine (coarse
    // levels lose the crown's twigs and a tree its density with distance), and keeping the sum,
    // which overstates it where siblings overlap near their joint. Measured against the full mesh
    // (mean of 24 views), the square root gave the least RMSE of the three on the willow (0.0250
    // against 0.0253 averaged and 0.0278 summed) and the maple (0.0252, 0.0259, 0.0274), and more
    // recall than averaging (maple at 20 radii 0.73 against 0.64). Never more than twice the
    // widest of the pair's radii, so that two siblings averaging to a short line do not become a
    // ball.
    let side = |l: &Line| (l.r0 + l.r1) * l.p0.distance(l.p1);
    let widest = a.r0.max(a.r1).max(b.r0).max(b.r1);
    let own = (r0 + r1) * p0.distance(p1);
    let k = if own > 0.0 { ((side(a) + side(b)) / own).max(1.0).sqrt() } else { 1.0 };
    let k = k.min(2.0 * widest / r0.max(r1).max(f64::MIN_POSITIVE)).max(1.0);
    let (r0, r1) = (k * r0, k * r1);
    Line {
        p0,
        r0,
        p1,
        r1,
        weight: wa + wb,
        colour: mix(a.colour, wa, b.colour, wb),
        parent: a.parent,
        children: Vec::new(),
        alive: true,
        merged: None,
    }
}

/// A cell's merge forest as it is simplified.
struct Forest {
    lines: Vec<Line>,
    /// Live roots under each out-of-cell parent, ascending.
    external: BTreeMap<u32, Vec<u32>>,
    alive: usize,
}

impl Forest {
    /// The source segments `ids` (global) as lines.
    fn new(segments: &[Segment], ids: &[u32]) -> Self {
        let local: HashMap<u32, u32> =
            ids.iter().enumerate().map(|(i, &g)| (g, u32::try_from(i).unwrap_or(u32::MAX))).collect();
        let mut lines: Vec<Line> = ids
            .iter()
            .map(|&g| {
                let s = &segments[g as usize];
                let parent = match s.parent {
                    Some(p) => local.get(&p).map_or(Parent::External(p), |&l| Parent::Line(l)),
                    None => Parent::Alone,
                };
                Line {
                    p0: s.p0,
                    r0: s.r0,
                    p1: s.p1,
                    r1: s.r1,
                    weight: s.weight,
                    colour: s.colour,
                    parent,
                    children: Vec::new(),
                    alive: true,
                    merged: None,
                }
            })
            .collect();
        let mut external: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for i in 0..lines.len() {
            let id = u32::try_from(i).unwrap_or(u32::MAX);
            match lines[i].parent {
                Parent::Line(p) => lines[p as usize].children.push(id),
                Parent::External(g) => external.entry(g).or_default().push(id),
                Parent::Alone => {}
            }
        }
        let alive = lines.len();
        Self { lines, external, alive }
    }

    /// The sibling list a line with parent `parent` is in.
    fn siblings(&mut self, parent: Parent) -> Option<&mut Vec<u32>> {
        match parent {
            Parent::Line(p) => Some(&mut self.lines[p as usize].children),
            Parent::External(g) => self.external.get_mut(&g),
            Parent::Alone => None,
        }
    }

    /// Every mergeable pair's site: straighten pairs, and sibling lists of two or more with their
    /// pair counts.
    fn sites(&self) -> Vec<(Site, u64)> {
        let mut sites = Vec::new();
        for (i, line) in self.lines.iter().enumerate() {
            let id = u32::try_from(i).unwrap_or(u32::MAX);
            if !line.alive {
                continue;
            }
            match line.children.len() {
                0 => {}
                1 => sites.push((Site::Straighten(id, line.children[0]), 1)),
                k => sites.push((Site::Children(id), pairs(k))),
            }
        }
        for (&g, roots) in &self.external {
            if roots.len() >= 2 {
                sites.push((Site::Roots(g), pairs(roots.len())));
            }
        }
        sites
    }

    /// The `index`-th pair of a site.
    fn pair(&self, site: Site, index: u64) -> Merge {
        let list = match site {
            Site::Straighten(parent, child) => return Merge::Straighten { parent, child },
            Site::Children(p) => &self.lines[p as usize].children,
            Site::Roots(g) => &self.external[&g],
        };
        let (mut i, mut rest) = (0usize, index);
        loop {
            let row = (list.len() - 1 - i) as u64;
            if rest < row {
                #[expect(clippy::cast_possible_truncation, reason = "below the list length")]
                let j = i + 1 + rest as usize;
                return Merge::Combine { a: list[i], b: list[j] };
            }
            rest -= row;
            i += 1;
        }
    }

    /// Applies `merge`; returns the new line's id.
    fn apply(&mut self, merge: Merge) -> u32 {
        let id = u32::try_from(self.lines.len()).unwrap_or(u32::MAX);
        let mut line = merged_line(&self.lines, merge);
        let (a, b) = match merge {
            Merge::Straighten { parent, child } => (parent, child),
            Merge::Combine { a, b } => (a, b),
        };
        let mut children: Vec<u32> = match merge {
            Merge::Straighten { child, .. } => std::mem::take(&mut self.lines[child as usize].children),
            Merge::Combine { a, b } => {
                let mut c = std::mem::take(&mut self.lines[a as usize].children);
                c.append(&mut self.lines[b as usize].children);
                c.sort_unstable();
                c
            }
        };
        for &c in &children {
            self.lines[c as usize].parent = Parent::Line(id);
        }
        line.children = std::mem::take(&mut children);
        line.merged = Some([a, b]);
        let parent = line.parent;
        self.lines[a as usize].alive = false;
        self.lines[b as usize].alive = false;
        self.lines.push(line);
        if let Some(siblings) = self.siblings(parent) {
            siblings.retain(|&s| s != a && s != b);
            siblings.push(id);
        }
        self.alive -= 1;
        id
    }

    fn alive_ids(&self) -> Vec<u32> {
        (0..self.lines.len()).filter(|&i| self.lines[i].alive).map(|i| u32::try_from(i).unwrap_or(u32::MAX)).collect()
    }
}

/// Where mergeable pairs are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Site {
    /// A line and its only child.
    Straighten(u32, u32),
    /// The children of a line (two or more).
    Children(u32),
    /// The roots under an out-of-cell parent (two or more).
    Roots(u32),
}

fn pairs(k: usize) -> u64 {
    (k as u64) * (k as u64 - 1) / 2
}

/// The merge history of one cell: its forest after all merges, and the snapshots.
struct History {
    forest: Forest,
    /// Line ids alive in each snapshot, finest first.
    snapshots: Vec<Vec<u32>>,
    /// The merges in order.
    #[cfg_attr(not(test), expect(dead_code, reason = "read by the tests"))]
    merges: Vec<Merge>,
}

/// Merges one cell's lines down to one per tree (module documentation).
fn simplify(segments: &[Segment], ids: &[u32], views: &ErrorViews, config: &LineConfig, cell: u64) -> History {
    let mut forest = Forest::new(segments, ids);
    let mut rng = SplitMix64(SplitMix64(config.seed ^ cell.wrapping_mul(0x9E37_79B9_7F4A_7C15)).next_u64());
    let mut snapshots = vec![forest.alive_ids()];
    let mut merges = Vec::new();
    loop {
        let sites = forest.sites();
        let total: u64 = sites.iter().map(|s| s.1).sum();
        if total == 0 {
            break;
        }
        // The pair indices to evaluate: all, or a uniform sample.
        let mut picks: Vec<u64> = if total <= u64::from(config.candidates) {
            (0..total).collect()
        } else {
            (0..config.candidates).map(|_| rng.below(total)).collect()
        };
        picks.sort_unstable();
        picks.dedup();
        let mut candidates = Vec::with_capacity(picks.len());
        let (mut site, mut offset) = (0usize, 0u64);
        for pick in picks {
            while pick >= offset + sites[site].1 {
                offset += sites[site].1;
                site += 1;
            }
            candidates.push(forest.pair(sites[site].0, pick - offset));
        }
        let scored: Vec<(f64, f64)> = candidates
            .par_iter()
            .map(|&m| {
                let new = merged_line(&forest.lines, m);
                let (a, b) = match m {
                    Merge::Straighten { parent, child } => (parent, child),
                    Merge::Combine { a, b } => (a, b),
                };
                (views.error([&forest.lines[a as usize], &forest.lines[b as usize]], &new), new.weight)
            })
            .collect();
        let mut best = 0;
        for (i, s) in scored.iter().enumerate() {
            if s.0.total_cmp(&scored[best].0).then(s.1.total_cmp(&scored[best].1)).is_lt() {
                best = i;
            }
        }
        forest.apply(candidates[best]);
        merges.push(candidates[best]);
        let last = snapshots.last().map_or(0, Vec::len);
        if forest.alive <= last.div_ceil(2) {
            snapshots.push(forest.alive_ids());
        }
    }
    if snapshots.last().map_or(0, Vec::len) != forest.alive {
        snapshots.push(forest.alive_ids());
    }
    History { forest, snapshots, merges }
}

/// One cell's lines: the hierarchy and its records in SPT order (module documentation), and its
/// merge history (`None` for an empty cell), which the far lines start from.
fn build_cell(
    segments: &[Segment],
    ids: &[u32],
    views: &ErrorViews,
    config: &LineConfig,
    cell: u64,
) -> Result<(CellLines, Option<History>), BuildError> {
    if ids.is_empty() {
        return Ok((CellLines::default(), None));
    }
    let history = simplify(segments, ids, views, config, cell);
    Ok((records(segments, ids, &history, config.pixels, 0.0)?, Some(history)))
}

/// Turns a cell's history into records with their intervals; with `first > 0` (the far lines)
/// the levels' thresholds are scaled together so that level 0 ends at `first` (0: as they are).
fn records(
    segments: &[Segment],
    ids: &[u32],
    history: &History,
    pixels: f32,
    first: f32,
) -> Result<CellLines, BuildError> {
    let lines = &history.forest.lines;
    // Thresholds: each level's mean width over `pixels`, scaled, then strictly increasing.
    let widths: Vec<f32> = history
        .snapshots
        .iter()
        .map(|snapshot| {
            let width: f64 = snapshot.iter().map(|&l| lines[l as usize].r0 + lines[l as usize].r1).sum();
            #[expect(clippy::cast_possible_truncation, reason = "metres per pixel")]
            let e = (width / snapshot.len().max(1) as f64 / f64::from(pixels)) as f32;
            e
        })
        .collect();
    let scale = match widths.first() {
        Some(&e0) if e0 > 0.0 && first > 0.0 => first / e0,
        _ => 1.0,
    };
    let mut thresholds: Vec<f32> = Vec::with_capacity(widths.len());
    for (k, &w) in widths.iter().enumerate() {
        let mut e = if k == 0 && first > 0.0 { first } else { w * scale };
        if let Some(&prev) = thresholds.last() {
            e = e.max(prev.next_up());
        }
        thresholds.push(e);
    }
    // Written lines: those in some snapshot, with the first snapshot they are in.
    let mut first_level = vec![None::<usize>; lines.len()];
    for (k, snapshot) in history.snapshots.iter().enumerate() {
        for &l in snapshot {
            first_level[l as usize].get_or_insert(k);
        }
    }
    let mut node_of = vec![u32::MAX; lines.len()];
    let mut written: Vec<u32> = Vec::new();
    for (l, level) in first_level.iter().enumerate() {
        if level.is_some() {
            node_of[l] = u32::try_from(written.len()).unwrap_or(u32::MAX);
            written.push(u32::try_from(l).unwrap_or(u32::MAX));
        }
    }
    // Each written line's children: its nearest written descendants in the merge forest.
    let mut children: Vec<Vec<u32>> = vec![Vec::new(); written.len()];
    let mut sizes: Vec<f32> = Vec::with_capacity(written.len());
    for (n, &l) in written.iter().enumerate() {
        let level = first_level[l as usize].unwrap_or(0);
        sizes.push(if level == 0 { 0.0 } else { thresholds[level - 1] });
        let mut stack: Vec<u32> = lines[l as usize].merged.map_or_else(Vec::new, |m| vec![m[1], m[0]]);
        while let Some(d) = stack.pop() {
            if node_of[d as usize] != u32::MAX {
                children[n].push(node_of[d as usize]);
            } else if let Some(m) = lines[d as usize].merged {
                stack.push(m[1]);
                stack.push(m[0]);
            }
        }
    }
    let spt = flatten(&children, &sizes)?;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let mut out = Vec::with_capacity(written.len());
    let mut segment_triangles = vec![Vec::new(); ids.len()];
    for &n in &spt.order {
        let line = &lines[written[n as usize] as usize];
        let s = &spt.nodes[n as usize];
        if let Some(leaf) = spt.leaf_id[n as usize] {
            // Source lines are the first `ids.len()` of the forest, in `ids` order.
            let segment = &segments[ids[written[n as usize] as usize] as usize];
            segment_triangles[leaf as usize].clone_from(&segment.triangles);
        }
        let (p0, p1) = (line.p0.as_vec3(), line.p1.as_vec3());
        #[expect(clippy::cast_possible_truncation, reason = "metres")]
        let (r0, r1) = (line.r0 as f32, line.r1 as f32);
        lo = lo.min(p0 - r0).min(p1 - r1);
        hi = hi.max(p0 + r0).max(p1 + r1);
        let rgb = line.colour.as_vec3().to_array().map(linear_to_srgb);
        out.push(LineRecord {
            p0: p0.to_array(),
            r0,
            p1: p1.to_array(),
            r1,
            color: pack::rgba8([rgb[0], rgb[1], rgb[2], 1.0]),
            lo: s.lo,
            hi: s.hi,
            leaf_first: s.leaf_first,
            leaf_count: s.leaf_count,
            flags: 0,
        });
    }
    let levels = history
        .snapshots
        .iter()
        .zip(&thresholds)
        .map(|(s, &t)| LineLevel { count: u32::try_from(s.len()).unwrap_or(u32::MAX), threshold: t })
        .collect();
    Ok(CellLines { records: out, bounds: Some((lo, hi)), segment_triangles, levels })
}

#[cfg(test)]
mod tests {
    use super::*;
    use treelod_format::{SectionKind, check_spt};

    /// A tube of `rings` rings of `sides` vertices along `path` (rings spread by arc length,
    /// frames by parallel transport), open at both ends, radius `radius`; vertex ids from
    /// `first`.
    fn tube(path: &[Vec3], radius: f32, rings: usize, sides: usize, first: u32) -> (Vec<VertexRecord>, Vec<[u32; 3]>) {
        let lengths: Vec<f32> = path.windows(2).map(|w| w[0].distance(w[1])).collect();
        let total: f32 = lengths.iter().sum();
        let at = |s: f32| {
            let mut s = s;
            for (i, &l) in lengths.iter().enumerate() {
                if s <= l || i + 1 == lengths.len() {
                    let t = (s / l).clamp(0.0, 1.0);
                    let tangent = (path[i + 1] - path[i]).normalize();
                    // At a corner the ring is perpendicular to the mean of the two directions.
                    let tangent = if t >= 1.0 - 1e-4 && i + 2 < path.len() {
                        (tangent + (path[i + 2] - path[i + 1]).normalize()).normalize()
                    } else {
                        tangent
                    };
                    return (path[i].lerp(path[i + 1], t), tangent);
                }
                s -= l;
            }
            unreachable!()
        };
        let mut vertices = Vec::new();
        let mut normal = Vec3::X;
        for k in 0..rings {
            let (centre, tangent) = at(total * k as f32 / (rings - 1) as f32);
            if (normal - normal.dot(tangent) * tangent).length() < 1e-3 {
                normal = tangent.any_orthonormal_vector();
            }
            normal = (normal - normal.dot(tangent) * tangent).normalize();
            let binormal = tangent.cross(normal);
            for j in 0..sides {
                let a = std::f32::consts::TAU * j as f32 / sides as f32;
                let p = centre + radius * (a.cos() * normal + a.sin() * binormal);
                vertices.push(VertexRecord { position: p.to_array(), ..VertexRecord::default() });
            }
        }
        let mut triangles = Vec::new();
        let id = |k: usize, j: usize| first + (k * sides + j % sides) as u32;
        for k in 0..rings - 1 {
            for j in 0..sides {
                triangles.push([id(k, j), id(k, j + 1), id(k + 1, j + 1)]);
                triangles.push([id(k, j), id(k + 1, j + 1), id(k + 1, j)]);
            }
        }
        (vertices, triangles)
    }

    /// Several tubes as one mesh.
    fn tubes(specs: &[(&[Vec3], f32, usize, usize)]) -> (Vec<VertexRecord>, Vec<[u32; 3]>) {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        for &(path, radius, rings, sides) in specs {
            let (v, t) = tube(path, radius, rings, sides, vertices.len() as u32);
            vertices.extend(v);
            triangles.extend(t);
        }
        (vertices, triangles)
    }

    fn skeleton_of(vertices: &[VertexRecord], triangles: &[[u32; 3]]) -> Skeleton {
        skeleton(&LineMesh { vertices, triangles, colours: &[] })
    }

    /// A trunk with two branches starting on its axis at the same height, to both sides.
    fn trunk_and_branches() -> (Vec<VertexRecord>, Vec<[u32; 3]>) {
        let trunk = [Vec3::ZERO, Vec3::new(0.0, 2.0, 0.0)];
        let right = [Vec3::new(0.0, 1.05, 0.0), Vec3::new(0.8, 1.5, 0.1)];
        let left = [Vec3::new(0.0, 1.05, 0.0), Vec3::new(-0.8, 1.6, -0.1)];
        tubes(&[(&trunk, 0.1, 41, 12), (&right, 0.03, 21, 8), (&left, 0.03, 21, 8)])
    }

    #[test]
    fn a_straight_tube_gives_a_collinear_skeleton_of_its_radius_and_length() {
        let (v, t) = tube(&[Vec3::ZERO, Vec3::new(0.0, 1.0, 0.0)], 0.05, 41, 12, 0);
        let s = skeleton_of(&v, &t);
        assert_eq!(s.components, 1);
        assert!(s.segments.len() >= 8 && s.segments.len() <= 25, "{} segments", s.segments.len());
        let mut length = 0.0;
        for (i, seg) in s.segments.iter().enumerate() {
            for p in [seg.p0, seg.p1] {
                assert!(p.x.abs() < 1e-3 && p.z.abs() < 1e-3, "segment {i} off the axis: {p}");
            }
            for r in [seg.r0, seg.r1] {
                assert!((r / 0.05 - 1.0).abs() < 0.1, "segment {i} radius {r}");
            }
            assert!(seg.p1.y >= seg.p0.y, "segment {i} points down");
            assert_eq!(seg.parent.is_none(), i == 0, "segment {i}: {:?}", seg.parent);
            length += seg.p0.distance(seg.p1);
        }
        assert!((length - 1.0).abs() < 0.1, "length {length}");
        // The base starts at the bottom ring's centre.
        assert!(s.segments[0].p0.length() < 1e-6);
        // Every triangle in exactly one segment.
        let mut all: Vec<u32> = s.segments.iter().flat_map(|s| s.triangles.iter().copied()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..t.len() as u32).collect::<Vec<_>>());
    }

    #[test]
    fn coarse_twigs_and_flat_strips_are_no_thicker_than_they_are() {
        // A trunk with a twig of three rings (edges longer than the slices), hanging from it.
        let trunk = [Vec3::ZERO, Vec3::new(0.0, 2.0, 0.0)];
        let twig = [Vec3::new(0.0, 1.5, 0.0), Vec3::new(0.9, 1.2, 0.0), Vec3::new(1.0, 0.4, 0.0)];
        let (v, t) = tubes(&[(&trunk, 0.1, 41, 12), (&twig, 0.01, 3, 6)]);
        let s = skeleton_of(&v, &t);
        let thickest = |segments: &[Segment]| segments.iter().map(|g| g.r0.max(g.r1)).fold(0.0, f64::max);
        let twig_segments: Vec<Segment> = s.segments.iter().filter(|g| g.p1.x > 0.2).cloned().collect();
        assert!(!twig_segments.is_empty());
        assert!(thickest(&twig_segments) < 0.02, "twig radius {}", thickest(&twig_segments));
        // A flat strip 0.1 wide and 1 long, standing: its outline is one boundary loop, which
        // is no tube's end; sliced from its lower edge, its line is as wide as the strip.
        let mut strip = Vec::new();
        for i in 0..=10 {
            let y = i as f32 / 10.0;
            for x in [0.0, 0.1] {
                strip.push(VertexRecord { position: [x, y, 0.0], ..VertexRecord::default() });
            }
        }
        let quads: Vec<[u32; 3]> =
            (0..10u32).flat_map(|i| [[2 * i, 2 * i + 1, 2 * i + 3], [2 * i, 2 * i + 3, 2 * i + 2]]).collect();
        let s = skeleton_of(&strip, &quads);
        let r = thickest(&s.segments);
        assert!(r <= 0.0505, "strip radius {r}");
        assert!(s.segments.iter().all(|g| g.p0.y.min(g.p1.y) > -1e-6 && (g.p1 - g.p0).y.abs() >= 0.0));
        let top = s.segments.iter().map(|g| g.p1.y.max(g.p0.y)).fold(0.0, f64::max);
        assert!(top > 0.85, "the strip's line reaches its top: {top}");
    }

    #[test]
    fn a_bent_tube_gets_a_joint_near_the_bend() {
        let corner = Vec3::new(0.0, 1.0, 0.0);
        let (v, t) = tube(&[Vec3::ZERO, corner, Vec3::new(1.0, 1.0, 0.0)], 0.05, 81, 12, 0);
        let s = skeleton_of(&v, &t);
        assert_eq!(s.components, 1);
        let joint = s.segments.iter().map(|seg| seg.p1.distance(corner.as_dvec3())).fold(f64::INFINITY, f64::min);
        assert!(joint < 0.1, "nearest joint {joint} from the bend");
        let first = (s.segments[1].p1 - s.segments[1].p0).normalize();
        let last = s.segments.last().map(|seg| (seg.p1 - seg.p0).normalize()).unwrap_or_default();
        assert!(first.y > 0.95, "first direction {first}");
        assert!(last.x > 0.95, "last direction {last}");
        // A chain: every segment but the base hangs from the one before.
        for (i, seg) in s.segments.iter().enumerate().skip(1) {
            assert!(seg.parent.is_some_and(|p| (p as usize) < i), "segment {i}");
        }
    }

    #[test]
    fn branch_tubes_touching_the_trunk_attach_to_it() {
        let (v, t) = trunk_and_branches();
        let s = skeleton_of(&v, &t);
        assert_eq!(s.components, 3);
        // The branches' first segments: their parents are trunk segments (the trunk's come first).
        let trunk_segments = s.segments.iter().take_while(|seg| seg.p1.x.abs() < 1e-3).count();
        let firsts: Vec<usize> = (trunk_segments..s.segments.len())
            .filter(|&i| s.segments[i].parent.is_some_and(|p| (p as usize) < trunk_segments))
            .collect();
        assert_eq!(firsts.len(), 2, "{firsts:?}");
        let parents: Vec<u32> = firsts.iter().filter_map(|&i| s.segments[i].parent).collect();
        // Both on the trunk node at the branching height, so they can be combined.
        assert_eq!(parents[0], parents[1]);
        for &i in &firsts {
            let seg = &s.segments[i];
            assert!((seg.p0.y - 1.05).abs() < 0.15 && seg.p0.x.abs() < 1e-3, "starts at {}", seg.p0);
            assert!((seg.r0 / 0.03 - 1.0).abs() < 0.15, "r0 {}", seg.r0);
        }
        let forest = Forest::new(&s.segments, &(0..s.segments.len() as u32).collect::<Vec<_>>());
        let children = &forest.lines[parents[0] as usize].children;
        assert!(firsts.iter().all(|&i| children.contains(&(i as u32))), "{children:?}");
        assert!(forest.sites().iter().any(|&(site, n)| site == Site::Children(parents[0]) && n == 3));
    }

    #[test]
    fn two_trees_side_by_side_stay_apart() {
        let trunk = |x: f32| [Vec3::new(x, 0.0, 0.0), Vec3::new(x, 2.0, 0.0)];
        let branch = |x: f32| [Vec3::new(x, 1.05, 0.0), Vec3::new(x + 0.8, 1.5, 0.0)];
        let (a, b, c, d) = (trunk(0.0), trunk(3.0), branch(0.0), branch(3.0));
        let (v, t) = tubes(&[(&a, 0.1, 41, 12), (&b, 0.1, 41, 12), (&c, 0.03, 21, 8), (&d, 0.03, 21, 8)]);
        let s = skeleton_of(&v, &t);
        assert_eq!(s.components, 4);
        let roots: Vec<&Segment> = s.segments.iter().filter(|seg| seg.parent.is_none()).collect();
        assert_eq!(roots.len(), 2);
        for (root, x) in roots.iter().zip([0.0, 3.0]) {
            assert!(root.p0.distance(DVec3::new(x, 0.0, 0.0)) < 1e-6, "root at {}", root.p0);
        }
        // No segment spans the gap.
        assert!(s.segments.iter().all(|seg| seg.p0.distance(seg.p1) < 1.0));
    }

    fn segment(p0: [f64; 3], r0: f64, p1: [f64; 3], r1: f64, weight: f64, parent: Option<u32>) -> Segment {
        Segment {
            p0: DVec3::from_array(p0),
            r0,
            p1: DVec3::from_array(p1),
            r1,
            weight,
            colour: DVec3::splat(0.5),
            parent,
            triangles: Vec::new(),
        }
    }

    #[test]
    fn straighten_and_combine_make_the_documented_lines() {
        let segments = [
            segment([0.0, 0.0, 0.0], 0.2, [0.0, 1.0, 0.0], 0.15, 2.0, None),
            segment([0.0, 1.0, 0.0], 0.15, [0.0, 2.0, 0.0], 0.1, 1.0, Some(0)),
            segment([0.0, 2.0, 0.0], 0.1, [1.0, 3.0, 0.0], 0.05, 1.0, Some(1)),
            segment([0.0, 2.0, 0.0], 0.1, [-1.0, 3.0, 0.0], 0.09, 3.0, Some(1)),
            segment([1.0, 3.0, 0.0], 0.05, [1.0, 4.0, 0.0], 0.01, 0.5, Some(2)),
        ];
        let mut forest = Forest::new(&segments, &[0, 1, 2, 3, 4]);
        // Straighten 0 and its only child 1 (a straight taper: the side area stays as it is).
        let s = forest.apply(Merge::Straighten { parent: 0, child: 1 });
        let line = &forest.lines[s as usize];
        assert_eq!((line.p0, line.r0, line.p1, line.r1), (DVec3::ZERO, 0.2, DVec3::new(0.0, 2.0, 0.0), 0.1));
        assert_eq!(line.weight, 3.0);
        assert_eq!(line.children, [2, 3]);
        assert_eq!(line.parent, Parent::Alone);
        assert!(!forest.lines[0].alive && !forest.lines[1].alive);
        // Combine siblings 2 (weight 1) and 3 (weight 3): weight-averaged, weights summed, and
        // the averaged radii (0.1, 0.08) grown by the square root of the side areas' ratio.
        let c = forest.apply(Merge::Combine { a: 2, b: 3 });
        let line = &forest.lines[c as usize];
        assert!(line.p0.distance(DVec3::new(0.0, 2.0, 0.0)) < 1e-12);
        assert!(line.p1.distance(DVec3::new(-0.5, 3.0, 0.0)) < 1e-12, "{}", line.p1);
        let sides = (0.1 + 0.05) * 2f64.sqrt() + (0.1 + 0.09) * 2f64.sqrt();
        let k = (sides / ((0.1 + 0.08) * 1.25f64.sqrt())).sqrt();
        assert!((k - 1.5457).abs() < 1e-4, "{k}");
        assert!((line.r0 - 0.1 * k).abs() < 1e-12 && (line.r1 - 0.08 * k).abs() < 1e-12, "{} {}", line.r0, line.r1);
        assert_eq!(line.weight, 4.0);
        assert_eq!(line.children, [4]);
        assert_eq!(line.parent, Parent::Line(s));
        assert_eq!(forest.lines[4].parent, Parent::Line(c));
        assert_eq!(forest.lines[s as usize].children, [c]);
        assert_eq!(forest.alive, 3);
        // Now two straighten sites remain and nothing else.
        assert_eq!(forest.sites(), vec![(Site::Straighten(s, c), 1), (Site::Straighten(c, 4), 1)]);
    }

    #[test]
    fn roots_under_the_same_outside_parent_combine_and_parentless_roots_do_not() {
        // Segments 0 and 1 are out of the cell; 2 and 3 hang from 0, 4 from 1, 5 from nothing.
        let segments = [
            segment([0.0; 3], 0.1, [0.0, 1.0, 0.0], 0.1, 1.0, None),
            segment([0.0; 3], 0.1, [0.0, 1.0, 0.0], 0.1, 1.0, None),
            segment([0.0, 1.0, 0.0], 0.1, [1.0, 2.0, 0.0], 0.1, 1.0, Some(0)),
            segment([0.0, 1.0, 0.0], 0.1, [-1.0, 2.0, 0.0], 0.1, 1.0, Some(0)),
            segment([0.0, 1.0, 0.0], 0.1, [0.0, 2.0, 1.0], 0.1, 1.0, Some(1)),
            segment([5.0, 0.0, 0.0], 0.1, [5.0, 1.0, 0.0], 0.1, 1.0, None),
        ];
        let forest = Forest::new(&segments, &[2, 3, 4, 5]);
        assert_eq!(forest.sites(), vec![(Site::Roots(0), 1)]);
        assert_eq!(forest.pair(Site::Roots(0), 0), Merge::Combine { a: 0, b: 1 });
    }

    #[test]
    fn merges_prefer_the_pair_of_lower_image_error() {
        // Two chains, each a root: one nearly straight, one bent at a right angle.
        let segments = [
            segment([0.0, 0.0, 0.0], 0.05, [0.0, 1.0, 0.0], 0.05, 1.0, None),
            segment([0.0, 1.0, 0.0], 0.05, [0.05, 2.0, 0.0], 0.05, 1.0, Some(0)),
            segment([3.0, 0.0, 0.0], 0.05, [3.0, 1.0, 0.0], 0.05, 1.0, None),
            segment([3.0, 1.0, 0.0], 0.05, [4.0, 1.0, 0.0], 0.05, 1.0, Some(2)),
        ];
        let points: Vec<Vec3> = segments.iter().flat_map(|s| [s.p0.as_vec3(), s.p1.as_vec3()]).collect();
        let config = LineConfig::default();
        let views = ErrorViews::new(&points, &config);
        let [a, b, c, d] = [0, 1, 2, 3].map(|i| {
            let forest = Forest::new(&segments, &[0, 1, 2, 3]);
            forest.lines[i].clone()
        });
        let forest = Forest::new(&segments, &[0, 1, 2, 3]);
        let straight = views.error([&a, &b], &merged_line(&forest.lines, Merge::Straighten { parent: 0, child: 1 }));
        let bent = views.error([&c, &d], &merged_line(&forest.lines, Merge::Straighten { parent: 2, child: 3 }));
        assert!(straight < 0.5 * bent, "straight {straight}, bent {bent}");
        let history = simplify(&segments, &[0, 1, 2, 3], &views, &config, 0);
        assert_eq!(
            history.merges,
            [Merge::Straighten { parent: 0, child: 1 }, Merge::Straighten { parent: 2, child: 3 }]
        );
        assert_eq!(history.snapshots, [vec![0, 1, 2, 3], vec![4, 5]]);
    }

    /// The leaf runs drawn at `tau` partition `0 .. n`.
    fn assert_exact_cut(records: &[LineRecord], n: usize, tau: f32) {
        let mut cover = vec![0u32; n];
        for r in records.iter().filter(|r| r.lo <= tau && tau < r.hi) {
            for leaf in r.leaf_first..r.leaf_first + r.leaf_count {
                cover[leaf as usize] += 1;
            }
        }
        assert!(cover.iter().all(|&c| c == 1), "tau {tau}: cover {cover:?}");
    }

    fn build(vertices: &[VertexRecord], triangles: &[[u32; 3]], cells: usize) -> Lines {
        let colours = vec![Vec4::new(0.3, 0.2, 0.1, 1.0); triangles.len()];
        let mesh = LineMesh { vertices, triangles, colours: &colours };
        let cell_of = move |p: Vec3| if cells > 1 && p.x > 0.0 { 1 } else { 0 };
        build_lines(&mesh, cell_of, cells, &LineConfig::default()).unwrap()
    }

    #[test]
    fn every_cell_is_an_exact_cut_that_verify_accepts() {
        let (v, t) = trunk_and_branches();
        for cells in [1, 2] {
            let lines = build(&v, &t, cells);
            assert_eq!(lines.components, 3);
            let mut leaves = 0;
            for (i, cell) in lines.cells.iter().enumerate() {
                let n = cell.segment_triangles.len();
                leaves += n;
                let summary = check_spt(SectionKind::LINES, i, 0, &cell.records).unwrap();
                assert_eq!(summary.leaves as usize, n);
                assert!(cell.records.windows(2).all(|w| w[0].hi >= w[1].hi));
                assert!(cell.levels.windows(2).all(|w| w[0].threshold < w[1].threshold && w[0].count > w[1].count));
                assert_eq!(cell.levels.first().map(|l| l.count as usize), Some(n));
                let mut taus = vec![0.0, 1e-6, 1e9, f32::MAX];
                for level in &cell.levels {
                    taus.extend([level.threshold, level.threshold * 0.999, level.threshold * 1.001]);
                }
                for tau in taus {
                    assert_exact_cut(&cell.records, n, tau);
                }
                let (lo, hi) = cell.bounds.unwrap();
                for r in &cell.records {
                    let p = Vec3::from_array(r.p0);
                    assert!(p.cmpge(lo).all() && p.cmple(hi).all());
                    assert_eq!(r.color & 0xFF00_0000, 0xFF00_0000, "opaque");
                }
            }
            assert_eq!(leaves as u64, lines.source_segments);
            // Every bark triangle belongs to one segment.
            let mut all: Vec<u32> =
                lines.cells.iter().flat_map(|c| c.segment_triangles.iter().flatten().copied()).collect();
            all.sort_unstable();
            assert_eq!(all, (0..t.len() as u32).collect::<Vec<_>>());
            let per_level = lines.per_level();
            assert_eq!(per_level[0] as u64, lines.source_segments);
            if cells == 1 {
                // One tree: the last level is one line.
                assert_eq!(per_level.last(), Some(&1), "{per_level:?}");
            }
        }
    }

    #[test]
    fn the_output_does_not_depend_on_the_thread_count() {
        let (v, t) = trunk_and_branches();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| build(&v, &t, 2))
        };
        assert_eq!(run(1), run(4));
    }

    #[test]
    fn degenerate_input_does_not_panic() {
        // No bark.
        let lines = build(&[], &[], 3);
        assert_eq!(lines.cells, vec![CellLines::default(); 3]);
        assert_eq!((lines.source_segments, lines.components), (0, 0));
        let vertex = |p: [f32; 3]| VertexRecord { position: p, ..VertexRecord::default() };
        // One triangle; one collapsed to a point; two coincident triangles.
        let cases: [(Vec<VertexRecord>, Vec<[u32; 3]>); 3] = [
            (vec![vertex([0.0; 3]), vertex([1.0, 0.0, 0.0]), vertex([0.0, 1.0, 0.0])], vec![[0, 1, 2]]),
            (vec![vertex([0.5; 3]); 3], vec![[0, 1, 2]]),
            (
                vec![vertex([0.0; 3]), vertex([1.0, 0.0, 0.0]), vertex([0.0, 1.0, 0.0]), vertex([0.0; 3])],
                vec![[0, 1, 2], [3, 1, 2], [0, 0, 0]],
            ),
        ];
        for (v, t) in &cases {
            let lines = build(v, t, 2);
            assert!(lines.source_segments >= 1);
            for (i, cell) in lines.cells.iter().enumerate() {
                check_spt(SectionKind::LINES, i, 0, &cell.records).unwrap();
                assert!(cell.records.iter().all(|r| r.p0.iter().chain(&r.p1).all(|c| c.is_finite())));
            }
        }
    }

    #[test]
    fn settings_are_checked_and_recorded() {
        let ok = LineConfig::default();
        ok.validate().unwrap();
        let keys: Vec<String> = ok.settings().into_iter().map(|s| s.key).collect();
        assert_eq!(keys, ["lines.candidates", "lines.pixels", "lines.resolution", "lines.seed", "lines.views"]);
        for (bad, field) in [
            (LineConfig { pixels: 0.0, ..ok.clone() }, "pixels"),
            (LineConfig { candidates: 0, ..ok.clone() }, "candidates"),
            (LineConfig { resolution: 100, ..ok.clone() }, "resolution"),
            (LineConfig { views: 17, ..ok.clone() }, "views"),
        ] {
            let message = bad.validate().unwrap_err().to_string();
            assert!(message.contains(field), "{message}");
        }
    }

    /// Every shared model's bark (`cargo test -p treelod-build --lib lines -- --ignored
    /// --nocapture`; `LINES_MODEL=jacaranda` picks models by name): timing and level counts, every cell an exact cut, and nearly every bark
    /// component attached to the tree.
    #[test]
    #[ignore = "reads the shared models and takes a while"]
    fn the_shared_models_build() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees");
        let mut paths: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "glb"))
            .collect();
        paths.sort();
        if let Ok(only) = std::env::var("LINES_MODEL") {
            paths.retain(|p| p.to_string_lossy().contains(&only));
        }
        assert!(!paths.is_empty());
        for path in paths {
            model_builds(&path);
        }
    }

    fn model_builds(path: &std::path::Path) {
        use crate::classify::{ClassifyOptions, classify};
        use crate::scene::Class;
        let scene = crate::import::import_gltf(path).unwrap();
        let classes = classify(&scene, &ClassifyOptions::default());
        let (mut vertices, mut triangles, mut colours) = (Vec::new(), Vec::new(), Vec::new());
        for (part, class) in scene.parts.iter().zip(&classes) {
            if class.class == Class::Leaf {
                continue;
            }
            let base = vertices.len() as u32;
            vertices.extend(part.positions.iter().map(|&p| VertexRecord { position: p, ..VertexRecord::default() }));
            let c = scene.materials.get(part.material).map_or([1.0; 4], |m| m.base_color);
            for t in &part.triangles {
                triangles.push(t.map(|v| v + base));
                colours.push(Vec4::from_array(c));
            }
        }
        let (lo, hi) = vertices.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(Vec3::from_array(v.position)), hi.max(Vec3::from_array(v.position)))
        });
        // A 2 × 2 × 2 grid over the bark's box.
        let cell_of = |p: Vec3| {
            let c = ((p - lo) / (hi - lo).max(Vec3::splat(1e-6)) * 2.0).floor().clamp(Vec3::ZERO, Vec3::ONE);
            (c.x + 2.0 * c.y + 4.0 * c.z) as usize
        };
        let mesh = LineMesh { vertices: &vertices, triangles: &triangles, colours: &colours };
        let start = std::time::Instant::now();
        let lines = build_lines(&mesh, cell_of, 8, &LineConfig::default()).unwrap();
        println!(
            "{}: {} bark triangles, {} components, {} segments, {} records, per level {:?}, {:.2} s",
            path.display(),
            triangles.len(),
            lines.components,
            lines.source_segments,
            lines.count(),
            lines.per_level(),
            start.elapsed().as_secs_f64()
        );
        for (i, cell) in lines.cells.iter().enumerate() {
            check_spt(SectionKind::LINES, i, 0, &cell.records).unwrap();
        }
        assert!(lines.source_segments > 0);
        // Trees without a parent: the trunk, and any component left unattached.
        let skeleton = skeleton(&mesh);
        let roots = skeleton.segments.iter().filter(|s| s.parent.is_none()).count();
        let long = skeleton.segments.iter().map(|s| s.p0.distance(s.p1)).fold(0.0, f64::max);
        println!("{roots} roots, longest segment {long:.3} m");
        // Generated tube trees attach nearly every branch; other models may hold bark pieces that
        // are not tubes (the orchid tree's small flat pieces), left as roots of their own.
        if path.to_string_lossy().contains("ez-tree") {
            assert!(roots * 20 <= skeleton.components, "{roots} of {} components unattached", skeleton.components);
        }
    }
}
