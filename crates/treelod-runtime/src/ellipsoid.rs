//! Clasen's leaf ellipsoids at run time (Clasen and Prohaska 2011, §5; spec §6.8, §10): which
//! prefix of each cell's ellipsoids an instance draws.
//!
//! Every ellipsoid of one level of a cell shares the interval `[lo, hi) = [e_{k−1}, e_k)` of
//! *metres per pixel*, `e_k` being the size of a pixel at which level `k`'s mean ellipsoid is about
//! 5 px across (the build's business). Records are sorted by `hi`, largest first, per cell, so for
//! one `τ` the ellipsoids with `hi > τ` are a prefix found by binary search, and the vertex shader
//! drops the few of them with `lo > τ` ([`ellipsoid_drawn`]), exactly like impostor planes
//! ([`crate::impostor`]).
//!
//! `τ` is the metres per pixel at the cell's distance (spec §10.1), from the same camera maths that
//! gives the point threshold `τ_p = s_min · mpp` — so `mpp = τ_p / s_min`, Gilet's depth bias
//! included as for points (the block cell at the block centre's distance with `Z_i = 0`) — divided
//! by a quality factor: `τ = mpp / quality`, so a quality of 2 draws the level a camera twice as
//! near would draw.
//!
//! Clasen's branch lines (spec §6.9) are selected the same way with the same `τ` ([`LineLod`],
//! [`line_drawn`]); both are [`SptLod`]s, the per-cell prefix selector they share with impostor
//! planes.
//!
//! A switch of level can be blended ([`SptLod::select_per_pixel_blended`], [`level_keep`]): over
//! `β` octaves of `τ` about each boundary the finer level fades out and the coarser one fades in
//! on complementary dithered pixels, so the prefix then also holds the finer level a little past
//! its `hi`.
//!
//! [`select`] is the per-frame selection of the trees drawn with ellipsoids (see
//! [`crate::draws`]), their lines or bark triangles included.

use std::ops::Deref;

use glam::Mat4;
use treelod_format::{Container, EllipsoidRecord, LineRecord};

use crate::draws::{PrefixDraw, Scene, TreeDraws, select_into};
use crate::frame::{Camera, CellPrefix, Frustum, LodSettings};
#[cfg(doc)]
use crate::spt_lod::level_keep;
use crate::spt_lod::{PixelLevel, SptCell, SptLod, spt_drawn};
use crate::technique::Technique;

/// Whether an ellipsoid is drawn at `τ` (spec §10): its interval holds `τ`. `vs_ellipsoid` tests
/// [`level_keep`], which is this rule without a level blend.
#[must_use]
pub fn ellipsoid_drawn(ellipsoid: &EllipsoidRecord, tau: f32) -> bool {
    spt_drawn(ellipsoid, tau)
}

/// Whether a line is drawn at `τ` (spec §10): its interval holds `τ`. `vs_line` tests
/// [`level_keep`], which is this rule without a level blend.
#[must_use]
pub fn line_drawn(line: &LineRecord, tau: f32) -> bool {
    spt_drawn(line, tau)
}

/// One cell holding ellipsoids.
pub type EllipsoidCell = SptCell;

/// One cell holding lines.
pub type LineCell = SptCell;

/// One prefix of a cell's ellipsoids to draw.
pub type EllipsoidRange = CellPrefix;

/// One prefix of a cell's lines to draw.
pub type LineRange = CellPrefix;

/// What drawing a model's ellipsoids needs of its container, made once: its [`SptLod`] over
/// `ELLIPSOIDS` (through `Deref`), and its far ellipsoids where it has them.
///
/// **Far ellipsoids.** A tree far enough that every cell draws its coarsest level whole (level 0:
/// the records whose `hi` is infinite) draws the same ellipsoids as one range instead of a range
/// per cell: the runtime's copy of every cell's level 0 in cell order ([`far_ellipsoids`]),
/// uploaded after `ELLIPSOIDS` ([`Self::far_first`]). Nothing in the container changes: the
/// copies are the cells' own records, so the image is the one the cells' prefixes draw. The
/// switch is the `τ` at which the last cell's prefix shrinks to its level 0 (the next level's
/// `hi`) and its level 0 is drawn whole with the level blend (`lo · 2^(β/2)`), measured at the
/// nearest cell, whose `τ` is the least ([`Self::select_per_pixel_blended`]). A far tree's
/// cells each drew one or a few ellipsoids in a draw of their own: a forest of 10^4 trees drawn
/// with ellipsoids recorded and submitted about a hundred draws per tree (measured on the shared
/// orchid, see `docs/cli.md`). The one draw names the block cell (the debug view's cell tint).
#[derive(Clone, Debug, PartialEq)]
pub struct EllipsoidLod {
    cells: SptLod,
    far: Option<FarEllipsoids>,
}

/// A model's far ellipsoids as uploaded, and where an instance switches to them.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FarEllipsoids {
    /// The block cell's index in `CELLS`.
    cell: u32,
    /// The copies in the ellipsoids as uploaded (`ELLIPSOIDS` then the copies).
    records: treelod_format::Range,
    /// The least `τ · 2^(−β/2)` at which every cell draws its level 0 alone and whole.
    switch: f32,
}

/// The far ellipsoids of a container ([`EllipsoidLod`]): the indices in `ELLIPSOIDS` of every
/// cell's level 0 (its leading records with an infinite `hi`), in cell order, and the switch, the
/// greatest over the cells of their level 0's `lo` and of the `hi` of the record after it.
/// `None` where fewer than two cells hold ellipsoids (one range per tree already) or a cell's
/// coarsest level has a finite `hi` (it leaves the tree at some distance, which one range
/// measured at the nearest cell would not see).
#[must_use]
pub fn far_ellipsoids(container: &Container) -> Option<(Vec<u32>, f32)> {
    let records = container.ellipsoids();
    let (mut indices, mut switch, mut cells) = (Vec::new(), 0.0_f32, 0);
    for cell in container.cells() {
        let range = cell.ellipsoids;
        // Ranges were checked when the container was opened (spec §9.1).
        let Some(cell_records) = records.get(range.as_usize()).filter(|r| !r.is_empty()) else { continue };
        let level0 = cell_records.iter().take_while(|e| e.hi == f32::INFINITY).count();
        if level0 == 0 {
            return None;
        }
        cells += 1;
        for (k, e) in cell_records[..level0].iter().enumerate() {
            switch = switch.max(e.lo);
            indices.push(range.first.checked_add(u32::try_from(k).ok()?)?);
        }
        if let Some(next) = cell_records.get(level0) {
            switch = switch.max(next.hi);
        }
    }
    (cells >= 2 && switch.is_finite()).then_some((indices, switch))
}

/// What drawing a model's branch lines (spec §6.9) needs of its container, made once: its
/// [`SptLod`] over `LINES` (through `Deref`), and over `FAR_LINES` where the container has them.
/// Lines share the ellipsoids' unit of `τ` (metres per pixel; their build targets one pixel of
/// width), so one `τ` per cell serves both.
///
/// Far lines (spec §6.9.1): each grid cell's hierarchy ends at one line per connected piece of
/// the cell (the shared oak: 149 lines in all, drawn by every tree under about 60 pixels high).
/// `FAR_LINES` merges the lines the cells draw once they have nearly finished merging across
/// cells, down to one line per tree. An instance whose nearest cell's `τ` is at least the
/// switch `τ_s = τ_far · 2^(−1/2)` ([`Self::far_from`]) draws the far lines' prefix of that `τ`
/// instead of the cells' prefixes: there the far lines' level 0, copies of what the cells draw
/// at `τ_s` (the build puts it where no cell is fading between levels), is drawn whole and level
/// 1 not yet faded in (with a level blend up to an octave), so the switch does not show. Their
/// draws index the lines as uploaded: `LINES` then `FAR_LINES` ([`Self::far_first`]), then the
/// copies of the cells' far list ([`SptLod::far_list`]), which a tree short of the switch draws
/// as one range where its nearest cell's `τ` reaches it.
#[derive(Clone, Debug, PartialEq)]
pub struct LineLod {
    cells: SptLod,
    far: Option<FarLines>,
}

/// A model's far lines: their one hierarchy, and where an instance switches to them.
#[derive(Clone, Debug, PartialEq)]
struct FarLines {
    lod: SptLod,
    /// The switch `τ_s` (spec §6.9.1, [`treelod_format::far_switch`]).
    switch: f32,
    /// Per record, the least `lo` of it and the records before it (non-increasing): the records
    /// before the first whose entry is at most `τ` all start above `τ`.
    lo_before: Vec<f32>,
}

impl EllipsoidLod {
    /// The ellipsoids of an open container, with its far ellipsoids where it has them
    /// ([`far_ellipsoids`]); `None` if it has none.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        let cells = SptLod::from_container(container, container.ellipsoids(), |cell| cell.ellipsoids)?;
        let far = far_ellipsoids(container).and_then(|(indices, switch)| {
            let first = u32::try_from(container.ellipsoids().len()).ok()?;
            let count = u32::try_from(indices.len()).ok()?;
            first.checked_add(count)?;
            let cell = u32::try_from(container.block().grid_cell_count()).ok()?;
            Some(FarEllipsoids { cell, records: treelod_format::Range { first, count }, switch })
        });
        Some(Self { cells, far })
    }

    /// Where the far ellipsoids start in the ellipsoids as uploaded (`ELLIPSOIDS` then the
    /// copies [`far_ellipsoids`] lists): the count of `ELLIPSOIDS`; `None` without far
    /// ellipsoids.
    #[must_use]
    pub fn far_first(&self) -> Option<u32> {
        self.far.map(|f| f.records.first)
    }

    /// The ellipsoid prefixes an instance draws ([`SptLod::select_per_pixel_blended`]): each
    /// cell's or, where the least of the cells' `τ` (`τ_near`, the nearest cell's, depth bias
    /// included) times `2^(−β/2)` is at least the far switch, one range of the far ellipsoids,
    /// every cell's level 0: what the cells' prefixes draw there. The range's `τ` is `τ_near`,
    /// or the bound of it [`SptLod::least_tau_bound`] gives where that bound already reaches the
    /// switch (every `τ` past the switch draws the range whole: the same image).
    pub fn select_per_pixel_blended(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        level: PixelLevel,
        out: &mut Vec<CellPrefix>,
    ) -> bool {
        if let Some(far) = &self.far {
            let widen = (-0.5 * level.clamped_blend()).exp2();
            let reaches = |tau: f32| tau.is_finite() && tau * widen >= far.switch;
            // An O(1) bound of the cells' least τ first: a far tree need not measure every
            // cell's.
            let Some(bound) = self.cells.least_tau_bound(transform, camera, frustum, settings, level.quality) else {
                return false;
            };
            let tau = if reaches(bound) {
                Some(bound)
            } else {
                let Some(tau_near) = self.cells.least_tau(transform, camera, frustum, settings, level.quality) else {
                    return false;
                };
                Some(tau_near).filter(|&t| reaches(t))
            };
            if let Some(tau) = tau {
                out.push(CellPrefix { cell: far.cell, first: far.records.first, count: far.records.count, tau });
                return true;
            }
        }
        self.cells.select_per_pixel_blended(transform, camera, frustum, settings, level, out)
    }

    /// [`Self::select_per_pixel_blended`] without a level blend.
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
}

impl Deref for EllipsoidLod {
    type Target = SptLod;

    /// The cells' ellipsoids (`ELLIPSOIDS`).
    fn deref(&self) -> &SptLod {
        &self.cells
    }
}

impl LineLod {
    /// The lines of an open container, with its far lines where it has them; `None` if it has
    /// no lines.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        let mut cells = SptLod::from_container(container, container.lines(), |cell| cell.lines)?;
        let records = container.far_lines();
        // A renderer uploads the cells' far list after `LINES` and `FAR_LINES`.
        cells.place_far_list(u32::try_from(container.lines().len().checked_add(records.len())?).ok()?);
        let switch = treelod_format::far_switch(records);
        let far = u32::try_from(container.lines().len())
            .ok()
            .filter(|_| switch.is_finite())
            .and_then(|first| SptLod::whole(container, records, first))
            .map(|lod| {
                let lo_before = records
                    .iter()
                    .scan(f32::INFINITY, |least, l| {
                        *least = least.min(l.lo);
                        Some(*least)
                    })
                    .collect();
                FarLines { lod, switch, lo_before }
            });
        Some(Self { cells, far })
    }

    /// Where the far lines start in the lines as uploaded (`LINES` then `FAR_LINES`): the count
    /// of `LINES`; `None` without far lines.
    #[must_use]
    pub fn far_first(&self) -> Option<u32> {
        self.far.as_ref().map(|f| f.lod.cells()[0].records.first)
    }

    /// The switch `τ_s` (spec §6.9.1): the least `τ` of an instance's nearest cell from which it
    /// draws the far lines, half an octave below `τ_far`; `None` without far lines.
    #[must_use]
    pub fn far_from(&self) -> Option<f32> {
        self.far.as_ref().map(|f| f.switch)
    }

    /// The line prefixes an instance draws ([`SptLod::select_per_pixel_blended`]): each cell's,
    /// or, where the least of the cells' `τ` (`τ_near`, the nearest cell's, depth bias
    /// included) is at least [`Self::far_from`], the far lines' prefix of `τ_near` instead, less
    /// its leading records that start above `τ_near` even faded in (the coarser levels). At
    /// that `τ` every cell draws the far lines' level 0 or (farther cells, under a wide view
    /// of a near tree) a level the far lines' level 0 refines; measured at the nearest cell, the
    /// far lines are never coarser than any cell was.
    pub fn select_per_pixel_blended(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        level: PixelLevel,
        out: &mut Vec<CellPrefix>,
    ) -> bool {
        if let Some(far) = &self.far {
            // The nearest cell's τ alone first: a far tree need not select its cells' prefixes.
            let Some(tau_near) = self.cells.least_tau(transform, camera, frustum, settings, level.quality) else {
                return false;
            };
            if tau_near >= far.switch && tau_near.is_finite() {
                let cell = far.lod.cells()[0];
                let blend = level.clamped_blend();
                let count = far.lod.prefix(&cell, tau_near * (-0.5 * blend).exp2());
                // The prefix's head of coarser levels, which start above `τ` even faded in: the
                // far lines just past the switch would submit all their levels (about twice what
                // they draw), where the cells submitted about what they drew.
                let reach = tau_near * (0.5 * blend).exp2();
                let head =
                    u32::try_from(far.lo_before.partition_point(|&lo| lo > reach)).unwrap_or(u32::MAX).min(count);
                if count > head {
                    out.push(CellPrefix {
                        cell: cell.cell,
                        first: cell.records.first + head,
                        count: count - head,
                        tau: tau_near,
                    });
                }
                return true;
            }
            // Short of the switch: the cells' far list, or cell by cell, from the same `τ_near`.
            if self.cells.push_far(tau_near, level, out) {
                return true;
            }
            return self.cells.select_cells_blended(transform, camera, frustum, settings, level, out);
        }
        self.cells.select_per_pixel_blended(transform, camera, frustum, settings, level, out)
    }

    /// [`Self::select_per_pixel_blended`] without a level blend.
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
}

impl Deref for LineLod {
    type Target = SptLod;

    /// The cells' lines (`LINES`).
    fn deref(&self) -> &SptLod {
        &self.cells
    }
}

/// The trees of `list` drawn with ellipsoids ([`Technique::Ellipsoids`]; every model of `list`
/// has ellipsoids): appends to `out` each visible instance's ellipsoid prefixes
/// ([`SptLod::select_per_pixel_blended`] at `level`) and, with `lines` and where its model has
/// them, its line prefixes (their sphere holds their radii: they may be in view where the leaves
/// are not), else all its bark triangles; counts it visible.
pub fn select(
    scene: &Scene<'_>,
    list: &[u32],
    camera: &Camera,
    settings: &LodSettings,
    level: PixelLevel,
    lines: bool,
    out: &mut TreeDraws,
) {
    let frustum = Frustum::from_view_proj(camera.view_proj);
    select_into(list, out, |chunk, out| {
        let (mut ellipsoid_ranges, mut line_ranges) = (Vec::new(), Vec::new());
        for &index in chunk {
            let Some((instance, _, model)) = scene.get(index) else { continue };
            let Some(ellipsoids) = &model.ellipsoids else { continue };
            ellipsoid_ranges.clear();
            let leaves_seen = ellipsoids.select_per_pixel_blended(
                instance.transform,
                camera,
                &frustum,
                settings,
                level,
                &mut ellipsoid_ranges,
            );
            let model_lines = model.lines.as_ref().filter(|_| lines);
            line_ranges.clear();
            let lines_seen = model_lines.is_some_and(|l| {
                l.select_per_pixel_blended(instance.transform, camera, &frustum, settings, level, &mut line_ranges)
            });
            if !(leaves_seen || lines_seen) {
                continue;
            }
            *out.visible.get_mut(Technique::Ellipsoids) += 1;
            for range in &ellipsoid_ranges {
                out.ellipsoids.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            for range in &line_ranges {
                out.lines.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            if model_lines.is_none() {
                out.triangles.extend(model.bark_draw(index, instance.model, 1.0));
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{Camera, Frustum, LodSettings};
    use crate::spt_lod::{PixelLevel, level_keep};
    use glam::{Mat4, Vec3};
    use treelod_format::{BlockRecord, CellRecord, Compression, ContainerData, Metadata, Range, Source, Tree};

    /// An ellipsoid at `center` of level interval `[lo, hi)` with leaves `leaves`.
    fn ellipsoid(center: [f32; 3], lo: f32, hi: f32, leaves: (u32, u32)) -> EllipsoidRecord {
        EllipsoidRecord {
            center,
            radii: [0.5, 0.3, 0.2],
            orientation: [0, 0, 0, i16::MAX],
            color: 0xff20_8040,
            alpha_threshold: 0.0,
            noise_mip: 2.0,
            lo,
            hi,
            leaf_first: leaves.0,
            leaf_count: leaves.1,
            flags: 0,
        }
    }

    /// A line from `p0` to `p1` of level interval `[lo, hi)` with segments `segments`.
    fn line(p0: [f32; 3], p1: [f32; 3], lo: f32, hi: f32, segments: (u32, u32)) -> LineRecord {
        LineRecord {
            p0,
            r0: 0.05,
            p1,
            r1: 0.02,
            color: 0xff20_4060,
            lo,
            hi,
            leaf_first: segments.0,
            leaf_count: segments.1,
            flags: 0,
        }
    }

    /// A 2×1×1 grid: cell 0 holds two levels of a 4-leaf hierarchy (4 ellipsoids below
    /// `e1 = 0.01`, 1 above), cell 1 none, the block cell one level of 2 ellipsoids below `0.02`
    /// and 1 above; of lines, cell 0 none, cell 1 two levels of a 2-segment branch (2 lines below
    /// `0.005`, 1 above) reaching 1 m past the block; verified.
    fn container() -> Container {
        let (e1, e2) = (0.01, 0.005);
        let cell0 = vec![
            ellipsoid([1.0, 1.0, 1.0], e1, f32::INFINITY, (0, 4)),
            ellipsoid([0.5, 1.0, 1.0], 0.0, e1, (0, 1)),
            ellipsoid([1.5, 1.0, 1.0], 0.0, e1, (1, 1)),
            ellipsoid([1.0, 0.5, 1.0], 0.0, e1, (2, 1)),
            ellipsoid([1.0, 1.5, 1.0], 0.0, e1, (3, 1)),
        ];
        let block = vec![
            ellipsoid([2.0, 1.0, 1.0], 0.02, f32::INFINITY, (0, 2)),
            ellipsoid([1.8, 1.0, 1.0], 0.0, 0.02, (0, 1)),
            ellipsoid([2.2, 1.0, 1.0], 0.0, 0.02, (1, 1)),
        ];
        let cell = |first: u32, n: u32, min: [f32; 3], max: [f32; 3]| CellRecord {
            bounds_min: if n == 0 { [0.0; 3] } else { min },
            bounds_max: if n == 0 { [0.0; 3] } else { max },
            ellipsoids: Range { first, count: n },
            ..CellRecord::default()
        };
        let data = ContainerData {
            metadata: Metadata {
                generator: "test".into(),
                sources: vec![Source::default()],
                trees: vec![Tree::default()],
                ..Metadata::default()
            },
            block: BlockRecord {
                bounds_min: [0.0; 3],
                bounds_max: [4.0, 2.0, 2.0],
                grid: [2, 1, 1],
                tree_count: 1,
                ..BlockRecord::default()
            },
            cells: vec![
                CellRecord { lines: Range { first: 0, count: 0 }, ..cell(0, 5, [0.5, 0.5, 1.0], [1.5, 1.5, 1.0]) },
                CellRecord {
                    bounds_min: [2.5, 0.5, 0.5],
                    bounds_max: [5.0, 1.5, 1.5],
                    lines: Range { first: 0, count: 3 },
                    ..cell(5, 0, [0.0; 3], [0.0; 3])
                },
                CellRecord { lines: Range { first: 3, count: 0 }, ..cell(5, 3, [1.8, 1.0, 1.0], [2.2, 1.0, 1.0]) },
            ],
            ellipsoids: [cell0, block].concat(),
            lines: vec![
                line([2.5, 1.0, 1.0], [5.0, 1.0, 1.0], e2, f32::INFINITY, (0, 2)),
                line([2.5, 1.0, 1.0], [3.5, 1.5, 1.0], 0.0, e2, (0, 1)),
                line([3.5, 1.5, 1.0], [5.0, 1.0, 1.0], 0.0, e2, (1, 1)),
            ],
            ..ContainerData::default()
        };
        let container = Container::from_bytes(&data.to_bytes(Compression::None).unwrap()).unwrap();
        treelod_format::verify(&container).expect("a valid container");
        container
    }

    /// The leaves each cell's drawn ellipsoids cover at `τ`.
    fn covered(container: &Container, ranges: &[EllipsoidRange]) -> Vec<(u32, Vec<u32>, usize)> {
        ranges
            .iter()
            .map(|r| {
                let records = &container.ellipsoids()[r.first as usize..(r.first + r.count) as usize];
                let drawn: Vec<&EllipsoidRecord> = records.iter().filter(|e| ellipsoid_drawn(e, r.tau)).collect();
                let mut leaves: Vec<u32> =
                    drawn.iter().flat_map(|e| e.leaf_first..e.leaf_first + e.leaf_count).collect();
                leaves.sort_unstable();
                (r.cell, leaves, drawn.len())
            })
            .collect()
    }

    /// The cells' prefixes (`SptLod`'s selection, without the far ellipsoids, which
    /// `far_trees_draw_every_cells_coarsest_level_as_one_range` tests) from `distance` in front
    /// of the block centre.
    fn select_at(lod: &EllipsoidLod, distance: f32, settings: &LodSettings, quality: f32) -> Vec<EllipsoidRange> {
        let camera = Camera::look_at(Vec3::new(2.0, 1.0, 1.0 + distance), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
        let mut out = Vec::new();
        assert!(SptLod::select_per_pixel(
            lod,
            Mat4::IDENTITY,
            &camera,
            &Frustum::from_view_proj(camera.view_proj),
            settings,
            quality,
            &mut out
        ));
        out
    }

    /// A tree whose nearest cell's `τ · 2^(−β/2)` reaches the far switch draws one range, the
    /// copies of every cell's level 0 after `ELLIPSOIDS`, at that `τ`: the ellipsoids the cells'
    /// prefixes draw there, each whole. Short of it, the cells' prefixes.
    #[test]
    fn far_trees_draw_every_cells_coarsest_level_as_one_range() {
        let container = container();
        // Cell 0's level 0 (record 0, from e1 = 0.01) and the block cell's (record 5, from
        // 0.02): the switch is the block cell's.
        assert_eq!(far_ellipsoids(&container), Some((vec![0, 5], 0.02)));
        let lod = EllipsoidLod::from_container(&container).unwrap();
        assert_eq!(lod.far_first(), Some(8));
        let uploaded: Vec<EllipsoidRecord> = container
            .ellipsoids()
            .iter()
            .chain([&container.ellipsoids()[0], &container.ellipsoids()[5]])
            .copied()
            .collect();
        let settings = LodSettings::default();
        // mpp at 512 px and fovy 0.8: 0.00165 per metre; the block cell is the nearest (its τ
        // the least: no depth bias), at 0.02 from about 12.1 m.
        for blend in [0.0, 0.5] {
            let level = PixelLevel { quality: 1.0, blend };
            let switch_distance = 0.02 * (0.5 * blend).exp2() / (2.0 * 0.4f32.tan() / 512.0);
            let select = |distance: f32, cells_only: bool| {
                let camera =
                    Camera::look_at(Vec3::new(2.0, 1.0, 1.0 + distance), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
                let frustum = Frustum::from_view_proj(camera.view_proj);
                let mut out = Vec::new();
                let seen = if cells_only {
                    SptLod::select_per_pixel_blended(
                        &lod,
                        Mat4::IDENTITY,
                        &camera,
                        &frustum,
                        &settings,
                        level,
                        &mut out,
                    )
                } else {
                    lod.select_per_pixel_blended(Mat4::IDENTITY, &camera, &frustum, &settings, level, &mut out)
                };
                assert!(seen);
                out
            };
            let short = select(0.97 * switch_distance, false);
            assert_eq!(short, select(0.97 * switch_distance, true), "β {blend}: the cells' prefixes short of it");
            assert!(short.len() == 2 && short.iter().all(|p| p.first + p.count <= 8), "{short:?}");
            for factor in [1.03, 3.0] {
                let far = select(factor * switch_distance, false);
                let cells = select(factor * switch_distance, true);
                assert_eq!(far.len(), 1, "β {blend}: {far:?}");
                assert_eq!((far[0].cell, far[0].first, far[0].count), (2, 8, 2));
                let tau_near = cells.iter().map(|p| p.tau).fold(f32::INFINITY, f32::min);
                let widen = (-0.5 * blend).exp2();
                assert!(far[0].tau <= tau_near && far[0].tau * widen >= 0.02, "{far:?}, τ_near {tau_near}");
                // What each draws, whole (every dither value kept).
                let whole = |prefixes: &[CellPrefix]| {
                    let mut drawn: Vec<[u32; 3]> = prefixes
                        .iter()
                        .flat_map(|p| {
                            uploaded[p.first as usize..(p.first + p.count) as usize].iter().filter_map(move |e| {
                                let (from, to) = level_keep(e.lo, e.hi, p.tau, blend)?;
                                assert!(from <= 0.0 && to >= 1.0, "drawn whole: {from} {to}");
                                Some(e.center.map(f32::to_bits))
                            })
                        })
                        .collect();
                    drawn.sort_unstable();
                    drawn
                };
                assert_eq!(whole(&far), whole(&cells), "β {blend}, {factor}× the switch's distance");
                assert_eq!(whole(&far).len(), 2);
            }
        }
        // One cell holding ellipsoids: no far ellipsoids (one range per tree already).
        let mut data = ContainerData::from_container(&container);
        data.cells[0].ellipsoids = Range { first: 0, count: 0 };
        data.cells[0].bounds_min = [0.0; 3];
        data.cells[0].bounds_max = [0.0; 3];
        data.ellipsoids.drain(..5);
        data.cells[1].ellipsoids.first = 0;
        data.cells[2].ellipsoids.first = 0;
        let one = Container::from_bytes(&data.to_bytes(Compression::None).unwrap()).unwrap();
        assert_eq!(far_ellipsoids(&one), None);
        assert_eq!(EllipsoidLod::from_container(&one).unwrap().far_first(), None);
    }

    /// The bound of the cells' least `τ` is at most every cell's, from near and far, turned,
    /// scaled and with a strong depth bias, and close to it far away with the default bias.
    #[test]
    fn the_least_tau_bound_is_below_every_cells_tau_and_the_least_tau_is_the_least() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        let cells: &SptLod = &lod;
        let target = Vec3::new(2.0, 1.0, 1.0);
        let biased = |k: f32| LodSettings { depth_bias_k: k, ..LodSettings::default() };
        for settings in [LodSettings::default(), biased(0.8), biased(-0.6)] {
            for (i, distance) in [0.5, 3.0, 40.0, 900.0].into_iter().enumerate() {
                let direction = Vec3::new(0.3 * i as f32 - 0.4, 0.5, 1.0).normalize();
                let camera = Camera::look_at(target + direction * distance, target, 0.8, 512, 512);
                let frustum = Frustum::from_view_proj(camera.view_proj);
                for transform in [
                    Mat4::IDENTITY,
                    Mat4::from_scale_rotation_translation(
                        Vec3::new(1.5, 0.7, 1.2),
                        glam::Quat::from_rotation_y(0.9),
                        Vec3::new(0.2, 0.0, -0.3),
                    ),
                ] {
                    let Some(bound) = cells.least_tau_bound(transform, &camera, &frustum, &settings, 1.5) else {
                        continue;
                    };
                    let taus = cells.cell_taus(transform, &camera, &frustum, &settings, 1.5).expect("in view");
                    let least = taus.map(|(_, t)| t).fold(f32::INFINITY, f32::min);
                    assert!(bound <= least, "{distance} m: bound {bound} over the least τ {least}");
                    // The nearest anchor's τ alone is the least, to the bit.
                    let tau_near = cells.least_tau(transform, &camera, &frustum, &settings, 1.5).expect("in view");
                    assert_eq!(tau_near.to_bits(), least.to_bits(), "{distance} m, k {}", settings.depth_bias_k);
                    if distance > 100.0 && settings.depth_bias_k == LodSettings::default().depth_bias_k {
                        assert!(bound > 0.9 * least, "{distance} m: bound {bound}, least τ {least}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_prefix_holds_the_level_whose_interval_holds_tau_and_covers_each_leaf_once() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        assert_eq!(lod.cells().iter().map(|c| c.cell).collect::<Vec<_>>(), [0, 2]);
        let (c0, block) = (lod.cells()[0], lod.cells()[1]);
        assert!(block.block_cell && !c0.block_cell);
        // Prefix by hi alone: everything below e1, the root alone from e1 on.
        assert_eq!(lod.prefix(&c0, 0.0), 5);
        assert_eq!(lod.prefix(&c0, 0.009), 5);
        assert_eq!(lod.prefix(&c0, 0.01), 1);
        assert_eq!(lod.prefix(&c0, 1e9), 1);
        assert_eq!(lod.prefix(&block, 0.019), 3);
        assert_eq!(lod.prefix(&block, 0.02), 1);

        let settings = LodSettings::default();
        // mpp at 512 px and fovy 0.8: 0.00165 per metre. 2 m: fine levels everywhere.
        let near = select_at(&lod, 2.0, &settings, 1.0);
        let got = covered(&container, &near);
        assert_eq!(got[0], (0, vec![0, 1, 2, 3], 4), "{near:?}");
        assert_eq!(got[1], (2, vec![0, 1], 2), "{near:?}");
        // 8 m: cell 0 (τ ≈ 0.0137) coarse, the block cell (τ ≈ 0.0132) still fine.
        let mid = select_at(&lod, 8.0, &settings, 1.0);
        let got = covered(&container, &mid);
        assert_eq!(got[0], (0, vec![0, 1, 2, 3], 1), "{mid:?}");
        assert_eq!(got[1], (2, vec![0, 1], 2), "{mid:?}");
        // With quality 2, τ halves: cell 0 is fine again.
        let fine = select_at(&lod, 8.0, &settings, 2.0);
        assert!((fine[0].tau - 0.5 * mid[0].tau).abs() < 1e-7);
        assert_eq!(covered(&container, &fine)[0].2, 4);
        // 20 m: both coarse.
        let far = select_at(&lod, 20.0, &settings, 1.0);
        assert_eq!(covered(&container, &far).iter().map(|c| c.2).collect::<Vec<_>>(), [1, 1]);
        // τ is metres per pixel at the anchor: 2·tan(0.4)/512 per metre.
        let per_metre = 2.0 * 0.4f32.tan() / 512.0;
        let d_block = Vec3::new(2.0, 1.0, 21.0).distance(Vec3::new(2.0, 1.0, 1.0));
        assert!((far[1].tau - d_block * per_metre).abs() < 1e-6 * far[1].tau.max(1.0), "{far:?}");
    }

    /// The demo tree built with branch lines (and far lines).
    fn demo_with_lines() -> Container {
        use treelod_build::{BuildConfig, LineConfig, Placed, build_block};
        let scene = treelod_build::demo_tree(&treelod_build::DemoTreeConfig::default());
        let config = BuildConfig { lines: Some(LineConfig::default()), ..BuildConfig::default() };
        let built =
            build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").expect("builds");
        Container::from_bytes(&built.data.to_bytes(Compression::None).unwrap()).expect("opens")
    }

    /// A tree whose nearest cell's `τ` is at least `τ_far · 2^(−β/2)` draws one prefix of the far
    /// lines (numbered after the cells' lines, as uploaded), a nearer one the cells'; where it
    /// switches, seen from afar through a narrow view (every cell at about one `τ`), the far
    /// prefix draws whole exactly the cells' lines of just before.
    #[test]
    fn far_trees_draw_the_far_lines_and_near_trees_the_cells() {
        let container = demo_with_lines();
        let lines = LineLod::from_container(&container).expect("lines");
        let far_first = lines.far_first().expect("far lines");
        assert_eq!(far_first as usize, container.lines().len());
        let blend = 0.5;
        let from = lines.far_from().expect("far lines");
        let level = PixelLevel { quality: 1.0, blend };
        let (min, max) =
            (Vec3::from_array(container.block().bounds_min), Vec3::from_array(container.block().bounds_max));
        let centre = 0.5 * (min + max);
        let at_fov = |tau: f32, fovy: f32| {
            let probe = Camera::look_at(Vec3::Z, Vec3::ZERO, fovy, 512, 512);
            let camera = Camera::look_at(centre + Vec3::Z * (tau / probe.world_per_pixel()), centre, fovy, 512, 512);
            let mut out = Vec::new();
            let frustum = Frustum::from_view_proj(camera.view_proj);
            assert!(lines.select_per_pixel_blended(
                Mat4::IDENTITY,
                &camera,
                &frustum,
                &LodSettings::default(),
                level,
                &mut out
            ));
            out
        };
        let at = |tau: f32| at_fov(tau, 0.02);
        // Just short of the switch the cells' prefixes, or the one range of their far list
        // (`SptLod::far_list`, uploaded after `FAR_LINES`) that stands for them.
        let list_first = lines.cells.far_first().expect("a far list");
        assert_eq!(list_first as usize, container.lines().len() + container.far_lines().len());
        let cells = at(from * 0.99);
        assert!(cells.iter().all(|p| p.first + p.count <= far_first || p.first >= list_first), "{cells:?}");
        let far = at(from * 1.01);
        assert_eq!(far.len(), 1, "{far:?}");
        assert!(far[0].tau >= from && far[0].tau < from * 1.01, "the nearest cell's τ: {far:?}");
        assert_eq!(far[0].cell as usize, container.block().grid_cell_count());
        let far_end = far_first as usize + container.far_lines().len();
        assert!(far[0].first >= far_first && (far[0].first + far[0].count) as usize <= far_end, "{far:?}");
        // Its head of coarser levels, which start above τ even faded in, is not submitted: just
        // past the switch the far prefix submits about what it draws, as the cells' did.
        let skipped = &container.far_lines()[..(far[0].first - far_first) as usize];
        assert!(!skipped.is_empty() && skipped.iter().all(|l| l.lo > far[0].tau * (0.5 * blend).exp2()));
        let submitted = |prefixes: &[CellPrefix]| prefixes.iter().map(|p| p.count).sum::<u32>();
        assert!(
            submitted(&far) <= submitted(&cells),
            "{} far lines submitted, {} cells'",
            submitted(&far),
            submitted(&cells)
        );
        // What each draws whole at `τ` (level_keep's range covering every dither value; `None`:
        // the prefix's own).
        let copies = lines.far_list().iter().map(|&i| container.lines()[i as usize]);
        let all: Vec<LineRecord> =
            container.lines().iter().chain(container.far_lines()).copied().chain(copies).collect();
        let whole = |prefixes: &[CellPrefix], tau: Option<f32>| {
            let mut v: Vec<[u32; 4]> = prefixes
                .iter()
                .flat_map(|p| {
                    all[p.first as usize..(p.first + p.count) as usize]
                        .iter()
                        .filter(|l| {
                            level_keep(l.lo, l.hi, tau.unwrap_or(p.tau), blend)
                                .is_some_and(|(a, b)| a < 1e-4 && b > 0.9999)
                        })
                        .map(|l| [l.p0[0].to_bits(), l.p1[0].to_bits(), l.r0.to_bits(), l.color])
                        .collect::<Vec<_>>()
                })
                .collect();
            v.sort_unstable();
            v
        };
        // The far prefix holds what it draws whole at the switch: the cells' lines of just before.
        assert_eq!(whole(&cells, None), whole(&far, Some(from)), "the switch does not show");
        // Far away, fewer lines than the cells' coarsest.
        let coarsest = container.lines().iter().filter(|l| l.hi == f32::INFINITY).count() as u32;
        let distant = at_fov(from * 64.0, 0.8);
        assert_eq!(distant.len(), 1);
        assert!(distant[0].count < coarsest, "{} far lines against {coarsest}", distant[0].count);
    }

    /// The far list of a kind drawn by prefixes (`SptLod::far_list`), on the demo tree's lines
    /// with room for 2 records a cell (so that near trees fall short of it): it holds every
    /// record with `hi > far_tau` by `hi`; a tree whose cells' least `τ` reaches it draws one
    /// range that holds exactly the records the cells' prefixes at that `τ` hold, each cell's own
    /// `τ` being no less (never coarser); a nearer tree draws cell by cell.
    #[test]
    fn the_far_list_draws_in_one_range_what_the_cells_draw_at_their_least_tau() {
        let container = demo_with_lines();
        let records = container.lines();
        let mut lod = LineLod::from_container(&container).expect("lines").cells;
        let placed = u32::try_from(records.len() + container.far_lines().len()).unwrap();
        assert_eq!(lod.far_first(), Some(placed), "placed after LINES and FAR_LINES");
        lod.build_far_list(2);
        lod.place_far_list(placed);
        let (list, tau) = (lod.far_list().to_vec(), lod.far_tau());
        assert!(lod.cells().len() > 2 && !list.is_empty() && list.len() <= 2 * lod.cells().len());
        assert!(tau > 0.0 && tau.is_finite(), "{tau}");
        let hi = |i: u32| records[i as usize].hi;
        assert!(list.windows(2).all(|w| hi(w[0]) > hi(w[1]) || (hi(w[0]) == hi(w[1]) && w[0] < w[1])));
        let mut above: Vec<u32> = lod
            .cells()
            .iter()
            .flat_map(|c| c.records.first..c.records.first + c.records.count)
            .filter(|&i| hi(i) > tau)
            .collect();
        above.sort_unstable();
        let mut held = list.clone();
        held.sort_unstable();
        assert_eq!(held, above, "every record above far_tau, nothing else");

        let (min, max) =
            (Vec3::from_array(container.block().bounds_min), Vec3::from_array(container.block().bounds_max));
        let (centre, radius) = (0.5 * (min + max), 0.5 * (max - min).length());
        let settings = LodSettings::default();
        let widen = (-0.25f32).exp2();
        let (mut far_trees, mut near_trees) = (0, 0);
        for distance in [1.5, 3.0, 6.0, 12.0, 25.0, 50.0, 100.0, 200.0, 400.0].map(|k| k * radius) {
            // Coarser qualities stand for larger point sizes: τ up to 64× the pixel's.
            for (fovy, quality) in [(0.3, 1.0), (0.9, 1.0), (0.9, 1.0 / 3.0), (0.9, 1.0 / 64.0)] {
                let level = PixelLevel { quality, blend: 0.5 };
                let eye = centre + Vec3::new(0.5, 0.3, 0.8).normalize() * distance;
                let camera = Camera::look_at(eye, centre, fovy, 640, 480);
                let frustum = Frustum::from_view_proj(camera.view_proj);
                let taus: Vec<(SptCell, f32)> = lod
                    .cell_taus(Mat4::IDENTITY, &camera, &frustum, &settings, quality)
                    .expect("in view")
                    .map(|(c, t)| (*c, t))
                    .collect();
                let cases = [(taus.iter().map(|&(_, t)| t).collect::<Vec<f32>>(), widen, {
                    let mut out = Vec::new();
                    assert!(lod.select_per_pixel_blended(
                        Mat4::IDENTITY,
                        &camera,
                        &frustum,
                        &settings,
                        level,
                        &mut out
                    ));
                    out
                })];
                for (cell_taus, widen, out) in cases {
                    let least = cell_taus.iter().copied().fold(f32::INFINITY, f32::min);
                    if least * widen < tau {
                        near_trees += 1;
                        assert!(out.len() > 1 && out.iter().all(|p| p.first < placed), "{distance}: {out:?}");
                        continue;
                    }
                    far_trees += 1;
                    let [range] = out[..] else { panic!("{distance} m: one range, not {out:?}") };
                    assert_eq!(range.cell as usize, container.block().grid_cell_count());
                    assert!((range.tau - least).abs() <= 1e-5 * least, "{distance}: {} {least}", range.tau);
                    assert!(cell_taus.iter().all(|&t| t >= range.tau * (1.0 - 1e-6)), "never coarser");
                    let mut drawn: Vec<u32> = list[(range.first - placed) as usize..][..range.count as usize].to_vec();
                    drawn.sort_unstable();
                    let mut cells: Vec<u32> = lod
                        .cells()
                        .iter()
                        .flat_map(|c| {
                            let n = lod.prefix(c, range.tau * widen);
                            c.records.first..c.records.first + n
                        })
                        .collect();
                    cells.sort_unstable();
                    assert_eq!(drawn, cells, "{distance} m: the cells' prefixes at the least τ");
                }
            }
        }
        assert!(far_trees >= 4 && near_trees >= 4, "{far_trees} far, {near_trees} near");
    }

    #[test]
    fn the_depth_bias_of_points_shifts_the_cells_but_not_the_block_cell() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        let plain = select_at(&lod, 8.0, &LodSettings::default(), 1.0);
        let biased = select_at(&lod, 8.0, &LodSettings { depth_bias_k: 0.5, ..LodSettings::default() }, 1.0);
        // Cell 0 (centre (1, 1, 1)) is as far as the block centre (2, 1, 1) to within its
        // lateral offset: Z_i > 0 slightly, so its τ grows; the block cell's is unchanged.
        assert!(biased[0].tau > plain[0].tau, "{plain:?} {biased:?}");
        assert_eq!(biased[1].tau, plain[1].tau);
        // With the bias, τ = τ_p / s_min: the point threshold's metres per pixel.
        let s = LodSettings { s_min: 2.0, depth_bias_k: 1.0, ..LodSettings::default() };
        let camera = Camera::look_at(Vec3::new(2.0, 1.0, 9.0), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
        let mut out = Vec::new();
        assert!(lod.select_per_pixel(
            Mat4::IDENTITY,
            &camera,
            &Frustum::from_view_proj(camera.view_proj),
            &s,
            1.0,
            &mut out
        ));
        let d_cell = Vec3::new(1.0, 1.0, 1.0).distance(camera.position);
        let d_block = Vec3::new(2.0, 1.0, 1.0).distance(camera.position);
        let z = ((d_cell - d_block) / (0.5 * Vec3::new(4.0, 2.0, 2.0).length())).clamp(-1.0, 1.0);
        let tau_p = s.biased_pixels(z).0 * d_cell * camera.world_per_pixel();
        assert!((out[0].tau - tau_p / s.s_min).abs() < 1e-6, "{out:?} {tau_p}");
    }

    #[test]
    fn scaled_instances_measure_tau_in_model_units_and_culled_ones_draw_nothing() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        let camera = Camera::look_at(Vec3::new(2.0, 1.0, 21.0), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let settings = LodSettings::default();
        let (mut one, mut two) = (Vec::new(), Vec::new());
        // The cells' prefixes (at 20 m the tree draws the far ellipsoids, one range).
        let cells: &SptLod = &lod;
        assert!(cells.select_per_pixel(Mat4::IDENTITY, &camera, &frustum, &settings, 1.0, &mut one));
        // Twice as large about the block centre: same distance, half the τ in model units.
        let about = Vec3::new(2.0, 1.0, 1.0);
        let scaled =
            Mat4::from_translation(about) * Mat4::from_scale(Vec3::splat(2.0)) * Mat4::from_translation(-about);
        assert!(cells.select_per_pixel(scaled, &camera, &frustum, &settings, 1.0, &mut two));
        assert!((two[1].tau - 0.5 * one[1].tau).abs() < 1e-6, "{one:?} {two:?}");
        // Behind the camera.
        let mut out = Vec::new();
        let away = Mat4::from_translation(Vec3::new(0.0, 0.0, 100.0));
        assert!(!lod.select_per_pixel(away, &camera, &frustum, &settings, 1.0, &mut out));
        assert!(out.is_empty());
        // No ellipsoids: no lod.
        let empty = ContainerData {
            block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
            cells: vec![CellRecord::default(); 2],
            ..ContainerData::default()
        };
        let empty = Container::from_bytes(&empty.to_bytes(Compression::None).unwrap()).unwrap();
        assert!(EllipsoidLod::from_container(&empty).is_none());
    }

    #[test]
    fn lines_take_the_ellipsoids_tau_per_cell_and_their_own_levels() {
        let container = container();
        let lines = LineLod::from_container(&container).unwrap();
        let ellipsoids = EllipsoidLod::from_container(&container).unwrap();
        assert_eq!(lines.cells().iter().map(|c| c.cell).collect::<Vec<_>>(), [1]);
        let c1 = lines.cells()[0];
        assert!(!c1.block_cell);
        assert_eq!(c1.records, Range { first: 0, count: 3 });
        assert_eq!(c1.anchor, Vec3::new(3.75, 1.0, 1.0));
        assert_eq!((lines.prefix(&c1, 0.0049), lines.prefix(&c1, 0.005)), (3, 1));
        // The sphere holds the lines' radii past the block's bounds (x up to 5.05).
        let (centre, radius) = lines.sphere();
        assert!(centre.x + radius >= 5.05 && centre.x - radius <= 0.0, "{centre} {radius}");
        assert!(ellipsoids.sphere().1 < radius, "the ellipsoids stay inside the block");

        let select = |lod: &SptLod, distance: f32, quality: f32| {
            let target = Vec3::new(2.0, 1.0, 1.0);
            let camera = Camera::look_at(target + Vec3::new(0.0, 0.0, distance), target, 0.8, 512, 512);
            let mut out = Vec::new();
            let frustum = Frustum::from_view_proj(camera.view_proj);
            assert!(lod.select_per_pixel(
                Mat4::IDENTITY,
                &camera,
                &frustum,
                &LodSettings::default(),
                quality,
                &mut out
            ));
            out
        };
        let drawn = |range: &LineRange| {
            container.lines()[range.first as usize..(range.first + range.count) as usize]
                .iter()
                .filter(|l| line_drawn(l, range.tau))
                .count()
        };
        // 2 m: τ ≈ 0.0044 at cell 1's anchor (2.7 m away): both fine lines. 4 m: the coarse one.
        let near = select(&lines, 2.0, 1.0);
        assert_eq!((near.len(), near[0].cell, drawn(&near[0])), (1, 1, 2), "{near:?}");
        let far = select(&lines, 4.0, 1.0);
        assert_eq!((far[0].count, drawn(&far[0])), (1, 1), "{far:?}");
        assert_eq!(drawn(&select(&lines, 4.0, 2.0)[0]), 2, "quality 2 halves τ");
        // Both kinds' τ: the metres per pixel at the cell's anchor (spec §10.1).
        let per_metre = 2.0 * 0.4f32.tan() / 512.0;
        let d = Vec3::new(3.75, 1.0, 1.0).distance(Vec3::new(2.0, 1.0, 5.0));
        assert!((far[0].tau - d * per_metre).abs() < 1e-6, "{far:?}");
        let e = select(&ellipsoids, 4.0, 1.0);
        let d0 = Vec3::new(1.0, 1.0, 1.0).distance(Vec3::new(2.0, 1.0, 5.0));
        assert!((e[0].tau - d0 * per_metre).abs() < 1e-6, "{e:?}");
        // The records' own interval tests.
        let l = container.lines()[1];
        assert!(line_drawn(&l, 0.0) && line_drawn(&l, 0.0049) && !line_drawn(&l, 0.005));
        assert!(ellipsoid_drawn(&container.ellipsoids()[0], 0.01));
    }

    #[test]
    fn a_level_blend_widens_the_prefix_to_the_records_fading_out_and_their_dithers_complement() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        let settings = LodSettings::default();
        let camera = |distance: f32| {
            Camera::look_at(Vec3::new(2.0, 1.0, 1.0 + distance), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512)
        };
        let select = |distance: f32, blend: f32| {
            let camera = camera(distance);
            let mut out = Vec::new();
            let frustum = Frustum::from_view_proj(camera.view_proj);
            let level = PixelLevel { quality: 1.0, blend };
            // The cells' prefixes (from 20 m the tree draws the far ellipsoids).
            let cells: &SptLod = &lod;
            assert!(cells.select_per_pixel_blended(Mat4::IDENTITY, &camera, &frustum, &settings, level, &mut out));
            out
        };
        // No blend is the hard switch, exactly.
        for distance in [2.0, 6.5, 8.0, 20.0] {
            assert_eq!(select(distance, 0.0), select_at(&lod, distance, &settings, 1.0));
        }
        // 6.5 m: cell 0's τ ≈ 0.0109, just past e1 = 0.01: without a blend the root alone, with
        // β = 0.5 also the 4 fine ones (hi = 0.01 > τ · 2^(−1/4) ≈ 0.0092), at the same τ.
        let (hard, soft) = (select(6.5, 0.0), select(6.5, 0.5));
        let tau = hard[0].tau;
        assert!(tau > 0.01 && tau * (-0.25f32).exp2() < 0.01, "{hard:?}");
        assert_eq!((hard[0].count, soft[0].count, soft[0].tau), (1, 5, tau), "{soft:?}");
        // Far past the band (τ ≈ 0.033 at 20 m): the root alone either way; near: all five.
        assert_eq!(select(20.0, 0.5)[0].count, 1);
        assert_eq!(select(2.0, 0.5)[0].count, 5);
        // A blend beyond 2 octaves is clamped, a non-finite one is none.
        assert_eq!(select(6.5, 9.0), select(6.5, 2.0));
        assert_eq!(select(6.5, f32::NAN), hard);

        // The dither ranges at τ: the fine level keeps [0, w), the coarse one [w, 1), the same w
        // (0.5 − log2(τ / e1) / β ≈ 0.26 here): every pixel shows exactly one of them.
        let records = &container.ellipsoids()[..5];
        let keep: Vec<_> = records.iter().map(|e| level_keep(e.lo, e.hi, tau, 0.5)).collect();
        let w = 0.5 - (tau.log2() - 0.01f32.log2()) / 0.5;
        assert_eq!(keep[0], Some((w, 2.0)), "{keep:?}");
        assert!(keep[1..].iter().all(|k| *k == Some((0.0, w))), "{keep:?}");
        assert!(w > 0.2 && w < 0.3, "{w}");
        // Centred on the boundary: half each; a quarter octave away (the band's edge): one level.
        assert_eq!(level_keep(0.0, 0.01, 0.01, 0.5), Some((0.0, 0.5)));
        assert_eq!(level_keep(0.01, f32::INFINITY, 0.01, 0.5), Some((0.5, 2.0)));
        assert_eq!(level_keep(0.0, 0.01, 0.01 * 0.25f32.exp2(), 0.5), None);
        let (from, to) = level_keep(0.01, f32::INFINITY, 0.01 * (-0.25f32).exp2(), 0.5).unwrap();
        assert!((from - 1.0).abs() < 1e-5 && to == 2.0, "{from} {to}");
        // A level between two boundaries a quarter octave from each: fades on both sides.
        let (from, to) = level_keep(0.01, 0.02, 0.01 * 0.5f32.exp2(), 0.5).unwrap();
        assert!((from - 0.0).abs() < 1e-6 && (to - 1.0).abs() < 1e-6, "{from} {to}");
        let (from, to) = level_keep(0.01, 0.012, 0.011, 1.0).unwrap();
        assert!(from > 0.0 && to < 1.0 && from < to, "{from} {to}");
        // No blend: the interval itself.
        assert_eq!(level_keep(0.01, 0.02, 0.01, 0.0), Some((0.0, 2.0)));
        assert_eq!(level_keep(0.01, 0.02, 0.02, 0.0), None);
        assert_eq!(level_keep(0.01, 0.02, 0.0099, 0.0), None);
    }
}
