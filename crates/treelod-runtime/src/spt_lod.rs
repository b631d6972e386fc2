//! Per-cell selection of the kinds drawn as whole prefixes of a cell's sequential point tree
//! (spec §10): Clasen's ellipsoids and lines ([`crate::ellipsoid`]) and impostor planes
//! ([`crate::impostor`]).
//!
//! Each such kind is a flat array whose records carry an interval `[lo, hi)` and are sorted by
//! `hi`, largest first, within each cell, so for one `τ` a cell draws a prefix found by binary
//! search ([`SptLod::prefix`]) and the vertex shader drops the few records of it with `lo > τ`
//! ([`spt_drawn`]). [`SptLod`] holds what that needs of a container for one kind — the cells
//! holding records, their anchors (where `τ` is measured from) and a compact copy of the `hi`
//! values — and selects an instance's prefixes in one of two units: metres per pixel
//! ([`SptLod::select_per_pixel`]: ellipsoids, lines) or metres at a pixel threshold
//! ([`SptLod::select_at_pixels`]: planes).
//!
//! Ellipsoids and lines may blend their levels ([`PixelLevel::blend`]): an element then fades in
//! over `β` octaves of `τ` centred on its `lo` and out over `β` octaves centred on its `hi`, on
//! complementary dithered pixels ([`level_keep`]), so the prefix also holds the records still
//! fading out ([`SptLod::select_per_pixel_blended`]).

use glam::{Mat4, Vec3, Vec4};
use treelod_format::{CellRecord, Container, EllipsoidRecord, LineRecord, PlaneRecord, Range};

use crate::frame::{
    Camera, CellPrefix, Frustum, LodSettings, far_cut, leading_above, prefix_above, sort_key, tau_per_metre,
};

/// A record of a kind drawn by prefixes ([`SptLod`]).
pub trait SptRecord {
    /// The record's threshold interval `[lo, hi)` (spec §10).
    fn interval(&self) -> (f32, f32);

    /// A box, model space, holding everything the record draws beyond its reference positions
    /// (which its cell's bounds hold, spec §6.2), for culling: `None` if those suffice.
    fn reach(&self) -> Option<(Vec3, Vec3)> {
        None
    }
}

impl SptRecord for EllipsoidRecord {
    fn interval(&self) -> (f32, f32) {
        (self.lo, self.hi)
    }

    /// The centre's cube of half-side the largest radius.
    fn reach(&self) -> Option<(Vec3, Vec3)> {
        let (c, r) = (Vec3::from_array(self.center), Vec3::from_array(self.radii).max_element());
        (c.is_finite() && r.is_finite()).then(|| (c - r, c + r))
    }
}

impl SptRecord for LineRecord {
    fn interval(&self) -> (f32, f32) {
        (self.lo, self.hi)
    }

    /// The endpoints' box grown by the larger radius.
    fn reach(&self) -> Option<(Vec3, Vec3)> {
        let (a, b, r) = (Vec3::from_array(self.p0), Vec3::from_array(self.p1), self.r0.max(self.r1));
        (a.is_finite() && b.is_finite() && r.is_finite()).then(|| (a.min(b) - r, a.max(b) + r))
    }
}

impl SptRecord for PlaneRecord {
    fn interval(&self) -> (f32, f32) {
        (self.lo, self.hi)
    }
}

/// Whether a record is drawn at `τ` (spec §10): its interval holds `τ`.
#[must_use]
pub fn spt_drawn(record: &impl SptRecord, tau: f32) -> bool {
    let (lo, hi) = record.interval();
    lo <= tau && tau < hi
}

/// The most octaves of `τ` a level blend may span ([`PixelLevel::blend`] is clamped to it).
pub const MAX_LEVEL_BLEND: f32 = 2.0;

/// A renderer's default level blend `β`, octaves ([`PixelLevel::blend`]): half an octave, so
/// that one level gives way to the next over a quarter of an octave on each side of its switch.
/// The build's calibration draws ellipsoids and lines with it, as the renderer draws them.
pub const DEFAULT_LEVEL_BLEND: f32 = 0.5;

/// How a kind measured in metres per pixel (ellipsoids, lines) picks its levels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelLevel {
    /// The user's quality factor `q`: `τ = mpp / q` (non-positive or non-finite: 1).
    pub quality: f32,
    /// `β`, octaves of `τ` over which one level gives way to the next (Clasen 2011 §5: the steps
    /// are close enough for image-space blending). 0 switches levels at once; clamped to
    /// `[0, MAX_LEVEL_BLEND]`, non-finite: 0. See [`level_keep`].
    pub blend: f32,
}

impl PixelLevel {
    /// [`Self::blend`] clamped to `[0, MAX_LEVEL_BLEND]`, 0 if not finite.
    #[must_use]
    pub fn clamped_blend(&self) -> f32 {
        if self.blend.is_finite() { self.blend.clamp(0.0, MAX_LEVEL_BLEND) } else { 0.0 }
    }
}

/// Where an element of interval `[lo, hi)` is drawn at `τ` with a level blend of `blend` (`β`,
/// octaves, clamped as [`PixelLevel::blend`]): `None` outside `lo · 2^(−β/2) ≤ τ < hi · 2^(β/2)`,
/// else `Some((from, to))`, the fragments whose per-pixel dither value `h ∈ [0, 1)` satisfies
/// `from ≤ h < to`. `from = 1 − w_in` with the fade-in `w_in = clamp(log2(τ/lo)/β + ½, 0, 1)` (0
/// for `lo = 0`), `to = w_out`, the fade-out `clamp(log2(hi/τ)/β + ½, 0, 1)` (2 for `hi = ∞`); so
/// the element covers `w_in · w_out` of its pixels where its fades do not overlap. At a level
/// boundary `e` the finer level's `to` and the coarser level's `from` are the same number
/// (computed as `½ ± (log2 e − log2 τ)/β`, exact negatives): with one `h` per pixel for both,
/// each pixel shows exactly one of them. With `β = 0`: `[lo, hi)` and `(0, 2)`, the hard switch
/// of [`spt_drawn`]. The WGSL twin is `level_keep` in `shaders/shared/records.wgsl`.
#[must_use]
pub fn level_keep(lo: f32, hi: f32, tau: f32, blend: f32) -> Option<(f32, f32)> {
    let blend = PixelLevel { quality: 1.0, blend }.clamped_blend();
    if blend == 0.0 {
        return (lo <= tau && tau < hi).then_some((0.0, 2.0));
    }
    let (shrink, reach) = ((-0.5 * blend).exp2(), (0.5 * blend).exp2());
    if !(lo * shrink <= tau && tau < hi * reach) {
        return None;
    }
    let from = if lo > 0.0 { (0.5 - (tau.log2() - lo.log2()) / blend).clamp(0.0, 1.0) } else { 0.0 };
    // As the WGSL twin tests it: an infinite `hi` (or one as large) has no fade-out.
    let to = if hi < 3.0e38 { (0.5 + (hi.log2() - tau.log2()) / blend).clamp(0.0, 1.0) } else { 2.0 };
    Some((from, to))
}

/// One cell holding records of the kind.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SptCell {
    /// Index of the cell in the container's `CELLS`.
    pub cell: u32,
    /// Its records in the kind's array.
    pub records: Range,
    /// Where `τ` is measured from, model space: the block centre for the block cell, else the
    /// centre of the cell's bounds.
    pub anchor: Vec3,
    /// Whether this is the block cell (`Z_i = 0` for the depth bias).
    pub block_cell: bool,
    /// Where the cell's `hi` values start in [`SptLod`]'s compact array.
    hi_at: u32,
}

/// What drawing one kind of a model's records by prefixes needs of its container, made once.
#[derive(Clone, Debug, PartialEq)]
pub struct SptLod {
    cells: Vec<SptCell>,
    hi: Vec<f32>,
    /// A sphere, model space, holding the block, every cell's bounds and every record's reach:
    /// culling.
    centre: Vec3,
    radius: f32,
    /// The block's centre and half diagonal, model space: `d_block` and `R` of Gilet's `Z_i`.
    block_centre: Vec3,
    block_radius: f32,
    /// The greatest distance of a cell's anchor from the block centre, model space:
    /// [`Self::least_tau_bound`].
    anchor_reach: f32,
    /// The cells' anchors by coordinate (x, y, z), padded with copies of the first to a whole
    /// number of [`LANES`]: [`Self::least_tau`]'s scan.
    anchors: [Vec<f32>; 3],
    /// The far list ([`Self::far_list`]): indices in the kind's array, by `hi` (largest first,
    /// ties by index).
    far: Vec<u32>,
    /// `hi` of each entry of `far`: its prefixes, as a cell's.
    far_hi: Vec<f32>,
    /// `far` holds every record with `hi > far_tau`.
    far_tau: f32,
    /// Where the copies of `far` start in the records as uploaded ([`Self::place_far_list`]);
    /// `None`: no far range is drawn.
    far_first: Option<u32>,
    /// The block cell's index in `CELLS`: the cell a far range names.
    block_cell: u32,
}

/// Anchors measured at once by [`SptLod::least_tau`]: one [`Vec4`].
const LANES: usize = 4;

/// The most records per cell (with records) a far list holds ([`SptLod::far_list`]): a bound of
/// its copy's size, as [`crate::FAR_POINTS_PER_CELL`] is the points'. It stays at the 64 the
/// points' list had when the lines' was made: the lines' selection was not measured with longer
/// lists.
const FAR_RECORDS_PER_CELL: usize = 64;

/// `anchors` ([`SptLod::anchors`]) of `cells`.
fn anchor_lanes(cells: &[SptCell]) -> [Vec<f32>; 3] {
    let padded = cells.len().div_ceil(LANES) * LANES;
    let first = cells.first().map_or(Vec3::ZERO, |c| c.anchor);
    let at = |i: usize| cells.get(i).map_or(first, |c| c.anchor);
    [0, 1, 2].map(|axis| (0..padded).map(|i| at(i)[axis]).collect())
}

/// What every cell's `τ` of an instance is measured from ([`SptLod::cell_taus`]).
#[derive(Clone, Copy)]
struct TauBasis {
    /// Metres per pixel per metre of distance, model units (the transform's largest axis scale
    /// divided out).
    per_metre: f32,
    /// The quality factor, 1 where it is not a positive number.
    quality: f32,
    /// The transform's largest axis scale.
    scale: f32,
    /// The block centre's distance from the eye, world units.
    d_block: f32,
    /// One over the block's half diagonal in world units (0 without one): `Z_i` per unit of
    /// distance.
    inv_radius: f32,
}

/// Gilet's depth bias of a cell at depth `Z_i = z` as a factor of `τ`: `s_min_i / s_min` (1
/// without a positive `s_min`).
fn depth_bias(settings: &LodSettings, z: f32) -> f32 {
    if settings.s_min > 0.0 { settings.biased_pixels(z).0 / settings.s_min } else { 1.0 }
}

impl SptLod {
    /// The kind of `container` whose array is `records` and whose range in each cell `range`
    /// gives (`|cell| cell.lines` for `container.lines()`); `None` if the array is empty.
    #[must_use]
    pub fn from_container<T: SptRecord>(
        container: &Container,
        records: &[T],
        range: impl Fn(&CellRecord) -> Range,
    ) -> Option<Self> {
        if records.is_empty() {
            return None;
        }
        let block = container.block();
        let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        let block_cell = block.grid_cell_count();
        let (mut lo, mut hi) = (min, max);
        let mut lod = Self {
            cells: Vec::new(),
            hi: Vec::new(),
            centre: Vec3::ZERO,
            radius: 0.0,
            block_centre: 0.5 * (min + max),
            block_radius: 0.5 * (max - min).length(),
            anchor_reach: 0.0,
            anchors: [Vec::new(), Vec::new(), Vec::new()],
            far: Vec::new(),
            far_hi: Vec::new(),
            far_tau: f32::INFINITY,
            far_first: None,
            block_cell: u32::try_from(block_cell).unwrap_or(u32::MAX),
        };
        for (index, cell) in container.cells().iter().enumerate() {
            let cell_range = range(cell);
            // Ranges were checked when the container was opened (spec §9.1).
            let Some(cell_records) = records.get(cell_range.as_usize()).filter(|r| !r.is_empty()) else {
                continue;
            };
            let (Ok(index_u32), Ok(hi_at)) = (u32::try_from(index), u32::try_from(lod.hi.len())) else { break };
            let (cmin, cmax) = (Vec3::from_array(cell.bounds_min), Vec3::from_array(cell.bounds_max));
            if cmin.is_finite() && cmax.is_finite() {
                lo = lo.min(cmin);
                hi = hi.max(cmax);
            }
            for (a, b) in cell_records.iter().filter_map(SptRecord::reach) {
                lo = lo.min(a);
                hi = hi.max(b);
            }
            let is_block = index == block_cell;
            let anchor = if is_block { lod.block_centre } else { 0.5 * (cmin + cmax) };
            lod.anchor_reach = lod.anchor_reach.max(anchor.distance(lod.block_centre));
            lod.cells.push(SptCell { cell: index_u32, records: cell_range, anchor, block_cell: is_block, hi_at });
            lod.hi.extend(cell_records.iter().map(|r| r.interval().1));
        }
        lod.centre = 0.5 * (lo + hi);
        lod.radius = 0.5 * (hi - lo).length();
        lod.anchors = anchor_lanes(&lod.cells);
        lod.build_far_list(FAR_RECORDS_PER_CELL);
        Some(lod)
    }

    /// Fills the far list ([`Self::far_list`]): every record of every cell by `hi`, largest first
    /// (ties by index: the same list on every machine), up to `per_cell` per cell with records,
    /// ending where `hi` changes so that it holds every record with `hi > far_tau`. Empty with
    /// fewer than two cells: one range per tree already.
    pub(crate) fn build_far_list(&mut self, per_cell: usize) {
        (self.far, self.far_hi, self.far_tau) = (Vec::new(), Vec::new(), f32::INFINITY);
        if self.cells.len() < 2 {
            return;
        }
        let mut all: Vec<(f32, u32)> = Vec::with_capacity(self.hi.len());
        for cell in &self.cells {
            let his = self.hi.get(cell.hi_at as usize..).unwrap_or_default();
            all.extend(
                his.iter().zip(cell.records.first..).take(cell.records.count as usize).map(|(&h, i)| (sort_key(h), i)),
            );
        }
        // Where more records than the room share the first `hi` (+∞: more roots than room), the
        // list is empty and never drawn.
        let (far_tau, kept) = far_cut(all, per_cell * self.cells.len());
        self.far_tau = far_tau;
        (self.far_hi, self.far) = kept.into_iter().unzip();
    }

    /// A kind held as one hierarchy for the whole block rather than per cell (`FAR_LINES`,
    /// spec §6.9.1): `records` as the block cell's, numbered from `first` (where they follow
    /// another array in one buffer), `τ` measured from the block centre; `None` if empty or
    /// `first` plus their count overflows.
    #[must_use]
    pub fn whole<T: SptRecord>(container: &Container, records: &[T], first: u32) -> Option<Self> {
        let count = u32::try_from(records.len()).ok().filter(|&n| n > 0)?;
        first.checked_add(count)?;
        let block = container.block();
        let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        let (mut lo, mut hi) = (min, max);
        for (a, b) in records.iter().filter_map(SptRecord::reach) {
            lo = lo.min(a);
            hi = hi.max(b);
        }
        let block_centre = 0.5 * (min + max);
        let cell = SptCell {
            cell: u32::try_from(block.grid_cell_count()).ok()?,
            records: Range { first, count },
            anchor: block_centre,
            block_cell: true,
            hi_at: 0,
        };
        Some(Self {
            cells: vec![cell],
            hi: records.iter().map(|r| r.interval().1).collect(),
            centre: 0.5 * (lo + hi),
            radius: 0.5 * (hi - lo).length(),
            block_centre,
            block_radius: 0.5 * (max - min).length(),
            anchor_reach: 0.0,
            anchors: anchor_lanes(&[cell]),
            far: Vec::new(),
            far_hi: Vec::new(),
            far_tau: f32::INFINITY,
            far_first: None,
            block_cell: cell.cell,
        })
    }

    /// The cells holding records, in container order.
    #[must_use]
    pub fn cells(&self) -> &[SptCell] {
        &self.cells
    }

    /// A sphere, model space, holding the block bounds, every cell's bounds and every record's
    /// reach: `(centre, radius)`.
    #[must_use]
    pub fn sphere(&self) -> (Vec3, f32) {
        (self.centre, self.radius)
    }

    /// The far list: indices in the kind's array of every record with `hi >` [`Self::far_tau`]
    /// of every cell, by `hi` (largest first, ties by index), at most `FAR_RECORDS_PER_CELL` (64)
    /// per cell with records in all; empty with fewer than two cells (and for [`Self::whole`]).
    ///
    /// The kind's twin of the points' far list (`ModelLod::far_list`): a tree drawn cell by
    /// cell is at least one range per cell with records, however few each draws. The impostor
    /// trees of a forest of the shared Japanese maple drew about 45 ranges each, nearly all of
    /// them the branch lines of their bark, a line or two apiece (their planes are one hierarchy
    /// in the block cell, one range). Where the least `τ` of an instance's cells is at least
    /// [`Self::far_tau`], the list's prefix with `hi` above it is every record that any cell's
    /// prefix at that `τ` holds: one range ([`Self::far_prefix`]) draws each cell as the nearest
    /// one is drawn, never coarser than the cell's own `τ` would draw it. A renderer uploads
    /// copies of the listed records after the kind's own ([`Self::place_far_list`]), so the range
    /// is contiguous.
    ///
    /// The cost: the cells beyond the nearest draw finer than their own `τ` asks, at most the
    /// list's length in all. Measured on the shared oak's impostors (their bark lines, `eval
    /// --orbit 2,8,32`): 1,855 → 1,951 primitives a frame at 128–512 pixels high and 309 → 393 at
    /// 32–128, at the same error (RMSE .04300 → .04299 and .00564 → .00564), for one range in
    /// place of one per cell with records — a few records per range saved, where a range costs
    /// its draw record and the renderer's work for it.
    #[must_use]
    pub fn far_list(&self) -> &[u32] {
        &self.far
    }

    /// The far list holds every record with `hi` above this (0 where it holds every record;
    /// `+∞` where it holds none).
    #[must_use]
    pub fn far_tau(&self) -> f32 {
        self.far_tau
    }

    /// Says that copies of [`Self::far_list`]'s records, in its order, follow the kind's records
    /// as uploaded from index `first` on: from then on [`Self::far_prefix`] draws them. A kind
    /// whose copies are not uploaded keeps drawing cell by cell.
    pub fn place_far_list(&mut self, first: u32) {
        let len = u32::try_from(self.far.len()).ok();
        self.far_first = len.filter(|&n| n > 0 && first.checked_add(n).is_some()).map(|_| first);
    }

    /// Where the copies of [`Self::far_list`] start in the records as uploaded; `None` where
    /// they are not placed ([`Self::place_far_list`]) or the list is empty.
    #[must_use]
    pub fn far_first(&self) -> Option<u32> {
        self.far_first
    }

    /// The one range of the far list that draws an instance whose cells' least `τ` is `least`
    /// (`CellPrefix::tau`), each cell's prefix being its leading records with `hi > least ·
    /// widen` (`widen` 1, or `2^(−β/2)` for a level blend): `Some` where the list is placed, `least
    /// · widen` is finite and at least [`Self::far_tau`] (a `count` of 0 then draws nothing),
    /// else `None` (draw cell by cell). The range names the block cell.
    #[must_use]
    pub fn far_prefix(&self, least: f32, widen: f32) -> Option<CellPrefix> {
        let first = self.far_first?;
        let tau = least * widen;
        (tau.is_finite() && tau >= self.far_tau).then(|| CellPrefix {
            cell: self.block_cell,
            first,
            count: leading_above(&self.far_hi, tau),
            tau: least,
        })
    }

    /// Number of leading records of `cell` with `hi > τ` (spec §10).
    #[must_use]
    pub fn prefix(&self, cell: &SptCell, tau: f32) -> u32 {
        prefix_above(&self.hi, cell.hi_at, cell.records.count, tau)
    }

    /// The prefixes an instance with world-from-model `transform` draws for `camera` with `τ` in
    /// metres per pixel, appended to `out`: per cell, `τ = mpp / quality` with `mpp = d · 2·tan
    /// (fovy/2) / H` (spec §10.1; `d` the distance to the cell's anchor, divided by the
    /// transform's largest axis scale) times Gilet's depth bias `s_min_i / s_min` of `settings`
    /// (the point threshold's, so `mpp = τ_p / s_min`; `Z_i = clamp((d_cell − d_block) / R, −1,
    /// 1)`, 0 for the block cell), and the leading records with `hi > τ`. Returns `false`,
    /// appending nothing, if the instance's sphere lies outside `frustum` or the transform is
    /// degenerate.
    pub fn select_per_pixel(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        quality: f32,
        out: &mut Vec<CellPrefix>,
    ) -> bool {
        self.select_per_pixel_blended(transform, camera, frustum, settings, PixelLevel { quality, blend: 0.0 }, out)
    }

    /// [`Self::select_per_pixel`] with `level.quality` and a level blend of `β = level.blend`
    /// octaves ([`level_keep`]): each cell's prefix also holds the records still fading out, the
    /// leading ones with `hi > τ · 2^(−β/2)`. `CellPrefix::tau` is `τ` itself. Where the far list
    /// is placed and the cells' least `τ` reaches it, its one range at that `τ` instead
    /// ([`Self::far_prefix`]).
    pub fn select_per_pixel_blended(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        level: PixelLevel,
        out: &mut Vec<CellPrefix>,
    ) -> bool {
        // The cells' least τ, the nearest cell's: the far list where it reaches the list's `τ`.
        if self.far_first.is_some() {
            let Some(least) = self.least_tau(transform, camera, frustum, settings, level.quality) else {
                return false;
            };
            if self.push_far(least, level, out) {
                return true;
            }
        }
        self.select_cells_blended(transform, camera, frustum, settings, level, out)
    }

    /// Appends the far list's range ([`Self::far_prefix`]) of an instance whose cells' least `τ`
    /// is `least` under the level blend of `level`, if it draws the instance; `true` if so.
    pub(crate) fn push_far(&self, least: f32, level: PixelLevel, out: &mut Vec<CellPrefix>) -> bool {
        let widen = (-0.5 * level.clamped_blend()).exp2();
        let Some(far) = self.far_prefix(least, widen) else {
            return false;
        };
        out.extend((far.count > 0).then_some(far));
        true
    }

    /// [`Self::select_per_pixel_blended`] cell by cell, the far list aside.
    pub(crate) fn select_cells_blended(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        level: PixelLevel,
        out: &mut Vec<CellPrefix>,
    ) -> bool {
        // 1 exactly for no blend: the prefix of `hi > τ`.
        let widen = (-0.5 * level.clamped_blend()).exp2();
        let Some(taus) = self.cell_taus(transform, camera, frustum, settings, level.quality) else {
            return false;
        };
        for (cell, tau) in taus {
            let count = self.prefix(cell, tau * widen);
            if count > 0 {
                out.push(CellPrefix { cell: cell.cell, first: cell.records.first, count, tau });
            }
        }
        true
    }

    /// A lower bound of every cell's `τ` ([`Self::cell_taus`]) in `O(1)`: no anchor is nearer
    /// than the block centre's distance less the farthest anchor's distance from it (times the
    /// transform's largest axis scale), and the depth bias, monotone in `Z_i`, is least at one
    /// end of the range of `Z_i` that reach allows (or at 0, the block cell's). `None` as
    /// [`Self::cell_taus`].
    pub fn least_tau_bound(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        quality: f32,
    ) -> Option<f32> {
        let TauBasis { per_metre, quality, scale, d_block, .. } =
            self.tau_basis(transform, camera, frustum, quality)?;
        let nearest = (d_block - self.anchor_reach * scale).max(0.0);
        let z = if self.block_radius > 0.0 { (self.anchor_reach / self.block_radius).min(1.0) } else { 0.0 };
        let bias = [-z, 0.0, z].map(|z| depth_bias(settings, z)).into_iter().fold(f32::INFINITY, f32::min);
        Some(nearest * per_metre * bias / quality)
    }

    /// The least of every cell's `τ` ([`Self::cell_taus`]), the nearest cell's: `τ_near`. With a
    /// depth bias that does not fall with depth (`LodSettings::depth_bias_k ≥ 0`, the default 0),
    /// a cell's `τ` never falls as its anchor's distance grows, so only the nearest anchor's `τ`
    /// is measured (the anchors' squared distances compared, one square root and one depth bias
    /// in all: the same number as the least of [`Self::cell_taus`], every step of it rounding
    /// monotonically); else every cell's. `None` as [`Self::cell_taus`].
    pub fn least_tau(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        quality: f32,
    ) -> Option<f32> {
        if settings.depth_bias_k.is_nan() || settings.depth_bias_k < 0.0 {
            let taus = self.cell_taus(transform, camera, frustum, settings, quality)?;
            return Some(taus.map(|(_, tau)| tau).fold(f32::INFINITY, f32::min));
        }
        let basis = self.tau_basis(transform, camera, frustum, quality)?;
        if self.cells.is_empty() {
            return Some(f32::INFINITY);
        }
        let nearest = self.nearest_anchor(transform, camera);
        Some(self.tau_at(&basis, settings, nearest, nearest == basis.d_block))
    }

    /// The least distance of a cell's anchor from the eye, world units: the same number as
    /// `transform.transform_point3(anchor).distance(camera.position)` of the nearest anchor (∞
    /// without cells).
    ///
    /// Every anchor is measured. Skipping those out of reach was measured and not taken: the
    /// anchors in chunks of eight along a Morton curve, each chunk bounded (by its box seen
    /// along the direction to it, or by a sphere compared in squared distances), the chunk of
    /// the nearest bound scanned first and then only the chunks that could hold a nearer anchor
    /// (the same number to the bit, tested against the full scan on random anchors, transforms
    /// and eyes). From afar a 6 × 4 × 6 grid's tree scanned a quarter to a half of its chunks,
    /// but a chunk's bound costs about as much as scanning its eight anchors four lanes at a
    /// time: the orchid's 10^6 trees with every representation (`bench --gpu-selection
    /// --technique policy --no-render --frames 12`, whose impostor trees' lines measure it per
    /// tree) selected in 148–168 ms with boxes and 106–112 ms with spheres, against 96–117 ms
    /// scanning every anchor (alternating runs). Nor was measuring in model space where the
    /// transform is a similarity (the eye brought into the model once, each anchor's squared
    /// distance then three differences and three products, and only the anchors within a margin
    /// of the least of those measured as here, the same number to the bit over 30,000 random
    /// cases): the same flight's `select` took 95–104 ms against 83–86 ms (the orchid's 72
    /// anchors a tree; the check, the margin and the second pass cost more than the
    /// transforms they saved).
    fn nearest_anchor(&self, transform: Mat4, camera: &Camera) -> f32 {
        // `transform.transform_point3(anchor) - camera.position` and its `length_squared`, four
        // anchors at a time in glam's SIMD vectors, each product and sum in glam's order
        // (`w + (z·a_z + (y·a_y + x·a_x))`, then `(x² + y²) + z²`; no fused multiply-add): the
        // same numbers as `cell_taus` measures. The least is kept by comparison (a NaN distance,
        // of a degenerate transform, never replaces it, as `f32::min` has it). Written with
        // arrays of eight anchors instead, the compiler's vectors shuffled and spilled: the
        // scan took about a tenth of the orchid's 10^6-tree flight (`docs/cli.md`).
        let [mx, my, mz, mw] = [transform.x_axis, transform.y_axis, transform.z_axis, transform.w_axis];
        let eye = camera.position;
        let s = Vec4::splat;
        let (xx, xy, xz) = (s(mx.x), s(my.x), s(mz.x));
        let (yx, yy, yz) = (s(mx.y), s(my.y), s(mz.y));
        let (zx, zy, zz) = (s(mx.z), s(my.z), s(mz.z));
        let (wx, wy, wz) = (s(mw.x), s(mw.y), s(mw.z));
        let (ex, ey, ez) = (s(eye.x), s(eye.y), s(eye.z));
        let mut least = Vec4::INFINITY;
        let [xs, ys, zs] = &self.anchors;
        for ((x, y), z) in xs.chunks_exact(LANES).zip(ys.chunks_exact(LANES)).zip(zs.chunks_exact(LANES)) {
            let (ax, ay, az) = (Vec4::from_slice(x), Vec4::from_slice(y), Vec4::from_slice(z));
            let dx = (((xx * ax) + (xy * ay)) + (xz * az)) + wx - ex;
            let dy = (((yx * ax) + (yy * ay)) + (yz * az)) + wy - ey;
            let dz = (((zx * ax) + (zy * ay)) + (zz * az)) + wz - ez;
            let d = (dx * dx + dy * dy) + dz * dz;
            least = Vec4::select(d.cmplt(least), d, least);
        }
        least.to_array().into_iter().fold(f32::INFINITY, f32::min).sqrt()
    }

    /// A cell's `τ` from its anchor's distance `d_cell` ([`Self::cell_taus`]); `block_cell` gives
    /// it `Z_i = 0`.
    #[inline]
    fn tau_at(&self, basis: &TauBasis, settings: &LodSettings, d_cell: f32, block_cell: bool) -> f32 {
        let TauBasis { per_metre, quality, d_block, inv_radius, .. } = *basis;
        let z = if block_cell { 0.0 } else { ((d_cell - d_block) * inv_radius).clamp(-1.0, 1.0) };
        d_cell * per_metre * depth_bias(settings, z) / quality
    }

    /// What every cell's `τ` is measured from ([`Self::cell_taus`], [`Self::least_tau_bound`]);
    /// `None` if the instance's sphere lies outside `frustum` or the transform is degenerate.
    fn tau_basis(&self, transform: Mat4, camera: &Camera, frustum: &Frustum, quality: f32) -> Option<TauBasis> {
        let per_metre = tau_per_metre(transform, camera, frustum, 1.0, (self.centre, self.radius))?;
        let scale = camera.world_per_pixel() / per_metre;
        Some(TauBasis {
            per_metre,
            quality: if quality > 0.0 && quality.is_finite() { quality } else { 1.0 },
            scale,
            d_block: transform.transform_point3(self.block_centre).distance(camera.position),
            inv_radius: if self.block_radius > 0.0 { (self.block_radius * scale).recip() } else { 0.0 },
        })
    }

    /// Each cell's `τ` in metres per pixel as [`Self::select_per_pixel_blended`] measures it (the
    /// anchor's distance, Gilet's depth bias, over `quality`); `None` if the instance's sphere
    /// lies outside `frustum` or the transform is degenerate.
    pub fn cell_taus<'a>(
        &'a self,
        transform: Mat4,
        camera: &'a Camera,
        frustum: &Frustum,
        settings: &'a LodSettings,
        quality: f32,
    ) -> Option<impl Iterator<Item = (&'a SptCell, f32)> + 'a> {
        let basis = self.tau_basis(transform, camera, frustum, quality)?;
        Some(self.cells.iter().map(move |cell| {
            let d_cell = transform.transform_point3(cell.anchor).distance(camera.position);
            (cell, self.tau_at(&basis, settings, d_cell, cell.block_cell))
        }))
    }

    /// The prefixes an instance with world-from-model `transform` draws for `camera` with `τ` in
    /// metres at `s_min` pixels (spec §10.1: `τ = s_min · d · 2·tan(fovy/2) / H`, divided by the
    /// transform's largest axis scale, `d` the distance to each cell's anchor; no depth bias),
    /// appended to `out`, cell by cell: the far list is not read (the planes, drawn this way, are
    /// one hierarchy in the block cell and place none). Returns `false`, appending nothing, if
    /// the instance's sphere lies outside `frustum` or the transform is degenerate.
    pub fn select_at_pixels(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        s_min: f32,
        out: &mut Vec<CellPrefix>,
    ) -> bool {
        let Some(per_metre) = tau_per_metre(transform, camera, frustum, s_min, (self.centre, self.radius)) else {
            return false;
        };
        for cell in &self.cells {
            let distance = transform.transform_point3(cell.anchor).distance(camera.position);
            let tau = distance * per_metre;
            let count = self.prefix(cell, tau);
            if count > 0 {
                out.push(CellPrefix { cell: cell.cell, first: cell.records.first, count, tau });
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use glam::Quat;
    use proptest::prelude::*;

    use super::*;

    /// An `SptLod` whose cells have `anchors` (one record each), for the anchors' scan alone.
    fn with_anchors(anchors: &[Vec3]) -> SptLod {
        let cells: Vec<SptCell> = (0u32..)
            .zip(anchors)
            .map(|(i, &anchor)| SptCell {
                cell: i,
                records: Range { first: i, count: 1 },
                anchor,
                block_cell: false,
                hi_at: i,
            })
            .collect();
        SptLod {
            anchors: anchor_lanes(&cells),
            hi: vec![1.0; cells.len()],
            cells,
            centre: Vec3::ZERO,
            radius: 1.0,
            block_centre: Vec3::ZERO,
            block_radius: 1.0,
            anchor_reach: 0.0,
            far: Vec::new(),
            far_hi: Vec::new(),
            far_tau: f32::INFINITY,
            far_first: None,
            block_cell: 0,
        }
    }

    fn vec3(range: std::ops::Range<f32>) -> impl Strategy<Value = Vec3> {
        (range.clone(), range.clone(), range).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// The scan four anchors at a time gives the nearest anchor's distance to the bit, as
        /// `transform_point3` and `distance` measure each anchor (what `cell_taus` measures),
        /// whatever the number of anchors (the last lanes padded) and the transform.
        #[test]
        fn the_nearest_anchor_is_the_least_distance_to_the_bit(
            anchors in prop::collection::vec(vec3(-20.0..20.0), 1..40),
            scale in vec3(0.05..8.0),
            axis in vec3(-1.0..1.0),
            angle in -3.2f32..3.2,
            translation in vec3(-500.0..500.0),
            eye in vec3(-2000.0..2000.0),
        ) {
            let rotation = Quat::from_axis_angle(axis.try_normalize().unwrap_or(Vec3::Y), angle);
            let transform = Mat4::from_scale_rotation_translation(scale, rotation, translation);
            let camera = Camera::look_at(eye, translation, 0.8, 480, 270);
            let lod = with_anchors(&anchors);
            let expected = anchors
                .iter()
                .map(|&a| transform.transform_point3(a).distance(eye))
                .fold(f32::INFINITY, f32::min);
            prop_assert_eq!(lod.nearest_anchor(transform, &camera).to_bits(), expected.to_bits());
        }
    }
}
