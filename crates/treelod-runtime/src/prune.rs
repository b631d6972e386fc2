//! Pruning (Neubert et al. 2011, spec §6.11): how much of each cell's leaf priority list to draw
//! and how much to scale the survivors.
//!
//! A container built with pruning lists, per cell, its leaves most important first, each leaf a
//! run of `PRUNE_TRIANGLES`. Drawing a fraction `λ` of the leaves means drawing the first
//! `ceil(λ·count)` leaves of every cell: one contiguous run of triangles per cell, a range draw
//! with no per-frame sorting. The survivors are scaled about their own centres by `s(λ)` so the
//! tree keeps its pixel coverage: the optimal scale `s_opt(λ)` of the container's `PRUNE_SCALE`
//! curve, or Cook et al.'s area-preserving `1/λ` as the baseline.
//!
//! Per instance, `λ` comes from the container's `PRUNE_LAMBDA` curve at the block's projected
//! height in pixels (the smallest `λ` that keeps the build's minimum quality there), times
//! `max(f, 0.1)` where `f` is the fraction of the tree's sample points that were visible in the
//! previous frame; [`Hysteresis`] keeps it from flickering. Bark is never pruned.
//!
//! [`select`] is the per-frame selection of the pruned trees (see [`crate::draws`]), tuned by
//! [`Pruning`].

use glam::Vec3;
use treelod_format::{Container, CurveSample, PruneLeafRecord, Range, TriangleRecord};

use crate::draws::{
    Scene, TechniqueSettings, TreeDraws, TriangleDraw, TriangleSource, max_axis_scale, select_into_with,
};
use crate::frame::{Camera, Frustum};
use crate::impostor::{ImpostorBark, push_bark};
use crate::technique::Technique;

/// Lower bound of the occlusion factor: a hidden tree still draws a tenth of its `λ`, so it is
/// there when it comes into view (Neubert et al. §5).
pub const MIN_VISIBLE_FRACTION: f32 = 0.1;

/// How survivors are scaled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PruneScale {
    /// `s_opt(λ)` from the container's `PRUNE_SCALE` curve (Neubert et al.).
    #[default]
    Optimal,
    /// `1/λ`: each survivor grows by the area of the leaves it replaces (Cook et al. 2007), the
    /// baseline Neubert et al. improve on.
    Cook,
    /// No scaling.
    None,
}

impl PruneScale {
    /// How the survivors of a pruned tree are scaled with `technique`: `s_opt(λ)` for
    /// [`Technique::PruneOpt`], Cook's `1/λ` for [`Technique::PruneCook`]; `None` for techniques
    /// that do not prune.
    #[must_use]
    pub const fn of(technique: Technique) -> Option<Self> {
        match technique {
            Technique::PruneOpt => Some(Self::Optimal),
            Technique::PruneCook => Some(Self::Cook),
            _ => None,
        }
    }
}

/// The value of a piecewise-linear curve (spec §6.11: `x` strictly increasing, clamped outside the
/// sampled range) at `x`; `None` for a curve without samples.
#[must_use]
pub fn curve_at(curve: &[CurveSample], x: f32) -> Option<f32> {
    let (first, last) = (curve.first()?, curve.last()?);
    if x <= first.x || x.is_nan() {
        return Some(first.y);
    }
    if x >= last.x {
        return Some(last.y);
    }
    // The first sample with x above, and the one before it (x > first.x, so i ≥ 1).
    let i = curve.partition_point(|s| s.x <= x);
    let (a, b) = (curve[i - 1], curve[i]);
    let t = (x - a.x) / (b.x - a.x);
    Some(a.y + t * (b.y - a.y))
}

/// The scale `s` of survivors at `lambda ∈ (0, 1]`: a factor on each leaf's *area*, as the
/// papers write it (Cook's `s = 1/λ` keeps the total area); the size factor that the vertex
/// shader applies about each leaf's centre is [`size_factor`]`(s) = sqrt(s)`.
#[must_use]
pub fn leaf_scale(mode: PruneScale, scale_curve: &[CurveSample], lambda: f32) -> f32 {
    let lambda = lambda.clamp(f32::MIN_POSITIVE, 1.0);
    match mode {
        PruneScale::Optimal => curve_at(scale_curve, lambda).unwrap_or(1.0).max(1.0),
        PruneScale::Cook => lambda.recip(),
        PruneScale::None => 1.0,
    }
}

/// The factor on a leaf's size (distances from its centre) that scales its area by `s`.
#[must_use]
pub fn size_factor(s: f32) -> f32 {
    s.max(0.0).sqrt()
}

pub use treelod_format::prune_leaves_drawn as leaves_drawn;

/// Hysteresis on `λ`: the shown value follows the target only when the target leaves a band of
/// relative width `band` around it, so an occlusion factor that wavers by a few sample points, or
/// a camera that hovers, does not add and remove the same leaves every frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hysteresis {
    /// Relative half-width of the band, e.g. 0.1 for ±10 %.
    pub band: f32,
}

impl Default for Hysteresis {
    fn default() -> Self {
        Self { band: 0.1 }
    }
}

impl Hysteresis {
    /// The `λ` to show this frame, given last frame's (`None` for an instance seen for the first
    /// time, which takes the target) and this frame's target. Reaching 1 (every leaf) is never
    /// held back.
    #[must_use]
    pub fn update(&self, shown: Option<f32>, target: f32) -> f32 {
        let target = target.clamp(0.0, 1.0);
        match shown {
            Some(shown) if (target - shown).abs() <= self.band * shown && target < 1.0 => shown,
            _ => target,
        }
    }
}

/// One cell's priority list: leaves and their triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PruneCell {
    /// Index of the cell in the container's `CELLS`.
    pub cell: u32,
    /// Its leaves, into `PRUNE_LEAVES`, most important first.
    pub leaves: Range,
}

/// The pruning view of a container: cells with leaves, the two curves, and the sample points of
/// the occlusion test.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PruneLod {
    cells: Vec<PruneCell>,
    /// Per leaf of `PRUNE_LEAVES`: its first triangle and one past its last (leaves tile the
    /// triangles in leaf order, so a prefix of a cell's leaves is one run of triangles).
    leaf_triangles: Vec<(u32, u32)>,
    scale: Vec<CurveSample>,
    lambda: Vec<CurveSample>,
    /// Block height, metres (the abscissa of `PRUNE_LAMBDA` is its projected height).
    height: f32,
    samples: Vec<Vec3>,
}

/// Sample points of the occlusion test per tree (Neubert et al. test a few dozen points on the
/// tree's hull).
pub const OCCLUSION_SAMPLES: usize = 64;

impl PruneLod {
    /// The pruning view of an open container; `None` if it has no pruned leaves.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        let block = container.block();
        let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        Self::from_records(
            container.cells().iter().map(|c| c.prune_leaves),
            container.prune_leaves(),
            container.prune_triangles(),
            container.prune_scale(),
            container.prune_lambda(),
            (min, max),
        )
    }

    /// The pruning view of raw records: each cell's `prune_leaves` range in cell order, the
    /// leaves, their triangles, the curves and the block bounds. Ranges or triangle runs outside
    /// their arrays count as empty; `None` if no leaf is left.
    #[must_use]
    pub fn from_records(
        cell_ranges: impl IntoIterator<Item = Range>,
        leaves: &[PruneLeafRecord],
        triangles: &[TriangleRecord],
        scale: &[CurveSample],
        lambda: &[CurveSample],
        bounds: (Vec3, Vec3),
    ) -> Option<Self> {
        let triangle_count = u32::try_from(triangles.len()).unwrap_or(u32::MAX);
        let leaf_triangles: Vec<(u32, u32)> = leaves
            .iter()
            .map(|l| {
                let end = l.first_triangle.saturating_add(l.triangle_count).min(triangle_count);
                (l.first_triangle.min(end), end)
            })
            .collect();
        let cells: Vec<PruneCell> = cell_ranges
            .into_iter()
            .enumerate()
            .filter(|(_, r)| r.count > 0 && r.as_usize().end <= leaves.len())
            .filter_map(|(i, leaves)| Some(PruneCell { cell: u32::try_from(i).ok()?, leaves }))
            .collect();
        if cells.is_empty() {
            return None;
        }
        let samples = hull_samples(cells.iter().flat_map(|c| &leaves[c.leaves.as_usize()]).map(|l| l.center));
        Some(Self {
            cells,
            leaf_triangles,
            scale: scale.to_vec(),
            lambda: lambda.to_vec(),
            height: (bounds.1.y - bounds.0.y).max(0.0),
            samples,
        })
    }

    /// The cells that have leaves, in cell order.
    #[must_use]
    pub fn cells(&self) -> &[PruneCell] {
        &self.cells
    }

    /// `PRUNE_SCALE`: `λ → s_opt`.
    #[must_use]
    pub fn scale_curve(&self) -> &[CurveSample] {
        &self.scale
    }

    /// `PRUNE_LAMBDA`: projected block height in pixels → `λ`.
    #[must_use]
    pub fn lambda_curve(&self) -> &[CurveSample] {
        &self.lambda
    }

    /// The block's height, metres, model space.
    #[must_use]
    pub fn height(&self) -> f32 {
        self.height
    }

    /// Points on the tree's hull, model space, for the occlusion test: per direction of a
    /// Fibonacci sphere of [`OCCLUSION_SAMPLES`] directions about the leaves' centroid, the
    /// centre of the outermost leaf (largest extent along it), without repeats.
    #[must_use]
    pub fn samples(&self) -> &[Vec3] {
        &self.samples
    }

    /// `λ` for a block that projects `pixels` high: the `PRUNE_LAMBDA` curve there, 1 (every
    /// leaf) without a curve.
    #[must_use]
    pub fn lambda_at(&self, pixels: f32) -> f32 {
        curve_at(&self.lambda, pixels).unwrap_or(1.0).clamp(0.0, 1.0)
    }

    /// The triangles of the first `leaves` leaves of `cell`: `(first, count)` into
    /// `PRUNE_TRIANGLES`.
    #[must_use]
    pub fn prefix_triangles(&self, cell: &PruneCell, leaves: u32) -> (u32, u32) {
        let leaves = leaves.min(cell.leaves.count);
        if leaves == 0 {
            return (0, 0);
        }
        let first = self.leaf_triangles.get(cell.leaves.first as usize).map_or(0, |t| t.0);
        let end = self.leaf_triangles.get((cell.leaves.first + leaves - 1) as usize).map_or(first, |t| t.1);
        (first, end.saturating_sub(first))
    }
}

/// The outermost of `centres` (model space) in [`OCCLUSION_SAMPLES`] directions of a Fibonacci
/// sphere about their centroid, without repeats: the hull samples of the occlusion test, of the
/// leaves' centres for pruned trees ([`PruneLod::samples`]), of the point tree's points for the
/// policy's trees (`Renderer::measure_occlusion`).
#[must_use]
pub fn hull_samples(centres: impl Iterator<Item = [f32; 3]> + Clone) -> Vec<Vec3> {
    let (sum, n) = centres.clone().fold((Vec3::ZERO, 0u32), |(s, n), c| (s + Vec3::from_array(c), n + 1));
    if n == 0 {
        return Vec::new();
    }
    #[expect(clippy::cast_precision_loss, reason = "leaf counts are far below 2^24")]
    let centroid = sum / n as f32;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut chosen: Vec<(usize, Vec3)> = Vec::with_capacity(OCCLUSION_SAMPLES);
    #[expect(clippy::cast_precision_loss, reason = "small counts")]
    for i in 0..OCCLUSION_SAMPLES {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / OCCLUSION_SAMPLES as f32;
        let r = (1.0 - y * y).max(0.0).sqrt();
        let phi = golden * i as f32;
        let direction = Vec3::new(r * phi.cos(), y, r * phi.sin());
        let best = centres
            .clone()
            .enumerate()
            .map(|(j, c)| (j, Vec3::from_array(c)))
            .max_by(|a, b| (a.1 - centroid).dot(direction).total_cmp(&(b.1 - centroid).dot(direction)));
        if let Some(best) = best
            && !chosen.iter().any(|c| c.0 == best.0)
        {
            chosen.push(best);
        }
    }
    chosen.into_iter().map(|c| c.1).collect()
}

/// The projected height in pixels of a block `height` metres high (model space) scaled by
/// `scale`, seen from `distance` metres with `world_per_pixel` metres per pixel at one metre
/// ([`crate::Camera::world_per_pixel`]).
#[must_use]
pub fn projected_height(height: f32, scale: f32, distance: f32, world_per_pixel: f32) -> f32 {
    height * scale / (distance.max(1e-6) * world_per_pixel.max(1e-12))
}

/// Pruning settings of [`Technique::PruneOpt`] and [`Technique::PruneCook`]: which trees are
/// pruned and by how much; the technique says how survivors are scaled ([`PruneScale`]).
///
/// A pruned tree draws its bark as [`Self::bark`] says (by default, where the container has a
/// LoD chain, the chain's bark level for `s_min` as impostor trees do; else every bark triangle)
/// and, of each cell's leaf priority list, the first `ceil(λ·count)` leaves, scaled about their centres (spec §6.11). `λ` is the
/// container's `λ(h)` at the tree's projected height `h` (or [`Self::lambda`]), times
/// `max(f, 0.1)` with `f` the visible fraction of the tree's hull samples measured by the
/// renderer's occlusion test on an earlier frame, then held by [`Self::hysteresis`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pruning {
    /// A fixed `λ` for every pruned tree instead of the container's `λ(h)` (for comparisons).
    pub lambda: Option<f32>,
    /// Multiply `λ` by the trees' measured visible fraction (needs the renderer's occlusion
    /// measurement each frame; without measurements every tree counts as visible).
    pub occlusion: bool,
    /// Hold `λ` while its target stays within a band, so it does not flicker.
    pub hysteresis: Hysteresis,
    /// Trees projecting fewer pixels high than this are drawn with the sequential point tree
    /// instead (pruning is the near-to-mid-field representation); 0 prunes every tree.
    pub spt_below_pixels: f32,
    /// The bark of pruned trees (issue: pruning alone never reduced bark, most of the
    /// primitives of a tree whose triangles are mostly bark): [`ImpostorBark::Chain`] by default.
    pub bark: ImpostorBark,
}

impl Default for Pruning {
    /// `λ(h)` from the container, occlusion on, ±10 % hysteresis, trees below 64 pixels high by
    /// the sequential point tree, the chain's bark where the container has a chain.
    fn default() -> Self {
        Self {
            lambda: None,
            occlusion: true,
            hysteresis: Hysteresis::default(),
            spt_below_pixels: 64.0,
            bark: ImpostorBark::Chain,
        }
    }
}

/// What pruning keeps per instance between the frames of the camera's view: the `λ` each
/// instance was drawn with last frame (hysteresis; `None` if it was not pruned) and the visible
/// fraction of its hull samples last measured (1 if never), both indexed like the instances.
#[derive(Debug)]
pub struct PruneState<'a> {
    /// Per instance: the held `λ`, updated by [`select`].
    pub shown: &'a mut [Option<f32>],
    /// Per instance: the measured visible fraction.
    pub visible_fraction: &'a [f32],
}

/// The trees of `list` drawn pruned (`technique`, [`Technique::PruneOpt`] or
/// [`Technique::PruneCook`], survivors scaled as [`PruneScale::of`] it says; every model of `list` has priority
/// lists): appends to `out` each visible tree's leaf prefixes and bark, and counts it and its
/// leaves; trees below [`Pruning::spt_below_pixels`] go to [`TreeDraws::point_tree`]. With
/// `state` (the camera's view) `λ` is multiplied by the visible fraction and held between frames,
/// and trees to measure are listed in [`TreeDraws::occlusion`]; a shadow cascade (no `state`)
/// prunes by the tree's height in texels, with no hysteresis and no occlusion: what the camera
/// cannot see may still cast.
pub fn select(
    scene: &Scene<'_>,
    list: &[u32],
    technique: Technique,
    settings: &TechniqueSettings,
    camera: &Camera,
    state: Option<PruneState<'_>>,
    out: &mut TreeDraws,
) {
    let pruning = &settings.pruning;
    let frustum = Frustum::from_view_proj(camera.view_proj);
    let world_per_pixel = camera.world_per_pixel();
    let scale = PruneScale::of(technique).unwrap_or_default();
    let main = state.is_some();
    let (shown, visible_fraction) = match &state {
        Some(s) => (&*s.shown, s.visible_fraction),
        None => (&[][..], &[][..]),
    };
    // The held `λ` of the camera's view's instances, written once every chunk has read them.
    let mut held: Vec<(u32, Option<f32>)> = Vec::new();
    select_into_with(list, out, &mut held, |chunk, draws, held| {
        let mut bark_ranges = Vec::new();
        for &index in chunk {
            let i = index as usize;
            let Some((instance, lod, model)) = scene.get(index) else { continue };
            let scale_of = max_axis_scale(instance.transform);
            let (centre, radius) = lod.cull_sphere();
            let world_centre = instance.transform.transform_point3(centre);
            let height = model.prune.as_ref().map_or(0.0, |p| {
                projected_height(p.height(), scale_of, world_centre.distance(camera.position), world_per_pixel)
            });
            let Some(prune) = model.prune.as_ref().filter(|_| height >= pruning.spt_below_pixels) else {
                if main {
                    held.push((index, None));
                }
                draws.point_tree.push(index);
                continue;
            };
            if !frustum.intersects_sphere(world_centre, radius * scale_of) {
                if main {
                    held.push((index, None));
                }
                continue;
            }
            *draws.visible.get_mut(technique) += 1;
            if main && pruning.occlusion && !prune.samples().is_empty() {
                draws.occlusion.push(index);
            }
            let target = pruning.lambda.unwrap_or_else(|| prune.lambda_at(height));
            let lambda = if main {
                let seen = if pruning.occlusion {
                    visible_fraction.get(i).copied().unwrap_or(1.0).max(MIN_VISIBLE_FRACTION)
                } else {
                    1.0
                };
                let lambda = pruning.hysteresis.update(shown.get(i).copied().flatten(), target * seen);
                held.push((index, Some(lambda)));
                lambda
            } else {
                target
            };
            let factor = size_factor(leaf_scale(scale, prune.scale_curve(), lambda));
            for cell in prune.cells() {
                let drawn = leaves_drawn(cell.leaves.count, lambda);
                let (first, count) = prune.prefix_triangles(cell, drawn);
                draws.leaves_pruned += u64::from(drawn);
                if count > 0 {
                    draws.triangles.push(TriangleDraw {
                        instance: index,
                        model: instance.model,
                        cell: cell.cell,
                        source: TriangleSource::PrunedLeaves,
                        first,
                        count,
                        lambda,
                        leaf_scale: factor,
                        tau_triangles: factor,
                    });
                }
            }
            let tree = (index, instance, lod, model);
            push_bark(tree, camera, &frustum, settings, pruning.bark, lambda, &mut bark_ranges, draws);
        }
    });
    if let Some(state) = state {
        for (index, lambda) in held {
            if let Some(slot) = state.shown.get_mut(index as usize) {
                *slot = lambda;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve(points: &[(f32, f32)]) -> Vec<CurveSample> {
        points.iter().map(|&(x, y)| CurveSample { x, y }).collect()
    }

    #[test]
    fn curves_interpolate_linearly_and_clamp_outside() {
        let c = curve(&[(0.1, 2.0), (0.5, 1.2), (1.0, 1.0)]);
        assert_eq!(curve_at(&c, 0.0), Some(2.0));
        assert_eq!(curve_at(&c, 0.1), Some(2.0));
        assert!((curve_at(&c, 0.3).unwrap() - 1.6).abs() < 1e-6);
        assert_eq!(curve_at(&c, 0.5), Some(1.2));
        assert!((curve_at(&c, 0.75).unwrap() - 1.1).abs() < 1e-6);
        assert_eq!(curve_at(&c, 7.0), Some(1.0));
        assert_eq!(curve_at(&c, f32::NAN), Some(2.0));
        assert_eq!(curve_at(&[], 0.5), None);
    }

    #[test]
    fn scales_follow_the_chosen_rule() {
        let c = curve(&[(0.25, 1.4), (1.0, 1.0)]);
        assert!((leaf_scale(PruneScale::Optimal, &c, 0.25) - 1.4).abs() < 1e-6);
        assert!((leaf_scale(PruneScale::Cook, &c, 0.25) - 4.0).abs() < 1e-6);
        assert!((size_factor(4.0) - 2.0).abs() < 1e-6);
        assert_eq!(leaf_scale(PruneScale::None, &c, 0.25), 1.0);
        // Never shrinks, and no curve means no scaling.
        assert_eq!(leaf_scale(PruneScale::Optimal, &curve(&[(0.5, 0.8)]), 0.5), 1.0);
        assert_eq!(leaf_scale(PruneScale::Optimal, &[], 0.5), 1.0);
    }

    #[test]
    fn leaves_drawn_rounds_up_and_keeps_one() {
        assert_eq!(leaves_drawn(10, 0.25), 3);
        assert_eq!(leaves_drawn(10, 0.0), 1);
        assert_eq!(leaves_drawn(10, 1.0), 10);
        assert_eq!(leaves_drawn(10, 2.0), 10);
        assert_eq!(leaves_drawn(0, 0.5), 0);
        assert_eq!(leaves_drawn(4, 0.5), 2);
    }

    #[test]
    fn hysteresis_holds_small_changes_and_follows_large_ones() {
        let h = Hysteresis { band: 0.1 };
        assert_eq!(h.update(None, 0.5), 0.5);
        // Wavering by ±8 % keeps the shown value.
        let mut shown = 0.5;
        for target in [0.54, 0.46, 0.53, 0.47, 0.5] {
            shown = h.update(Some(shown), target);
            assert_eq!(shown, 0.5);
        }
        // A 20 % change is followed at once.
        assert_eq!(h.update(Some(0.5), 0.6), 0.6);
        assert_eq!(h.update(Some(0.5), 0.4), 0.4);
        // Every leaf is never held back, and targets are clamped.
        assert_eq!(h.update(Some(0.95), 1.0), 1.0);
        assert_eq!(h.update(Some(0.5), 7.0), 1.0);
    }

    fn leaf(center: [f32; 3], first_triangle: u32, triangle_count: u32) -> PruneLeafRecord {
        PruneLeafRecord { center, area: 1.0, first_triangle, triangle_count }
    }

    #[test]
    fn a_prefix_of_leaves_is_one_run_of_triangles() {
        // Cell 0: leaves 0..3 with 2, 1, 3 triangles; cell 1 empty; cell 2: leaves 3..5.
        let leaves = [
            leaf([0.0; 3], 0, 2),
            leaf([1.0, 0.0, 0.0], 2, 1),
            leaf([0.0; 3], 3, 3),
            leaf([0.0; 3], 6, 1),
            leaf([0.0; 3], 7, 2),
        ];
        let triangles = vec![TriangleRecord::default(); 9];
        let ranges = [Range { first: 0, count: 3 }, Range { first: 3, count: 0 }, Range { first: 3, count: 2 }];
        let lod =
            PruneLod::from_records(ranges, &leaves, &triangles, &[], &[], (Vec3::ZERO, Vec3::splat(2.0))).unwrap();
        assert_eq!(lod.cells().len(), 2);
        assert_eq!(lod.cells()[1].cell, 2);
        let (c0, c2) = (lod.cells()[0], lod.cells()[1]);
        assert_eq!(lod.prefix_triangles(&c0, 0), (0, 0));
        assert_eq!(lod.prefix_triangles(&c0, 1), (0, 2));
        assert_eq!(lod.prefix_triangles(&c0, 2), (0, 3));
        assert_eq!(lod.prefix_triangles(&c0, 3), (0, 6));
        assert_eq!(lod.prefix_triangles(&c0, 99), (0, 6));
        assert_eq!(lod.prefix_triangles(&c2, 1), (6, 1));
        assert_eq!(lod.prefix_triangles(&c2, 2), (6, 3));
        assert_eq!(lod.height(), 2.0);
        // Without a curve every leaf is drawn.
        assert_eq!(lod.lambda_at(10.0), 1.0);
        // Samples are leaf centres, no repeats.
        assert!(!lod.samples().is_empty() && lod.samples().len() <= 5);
    }

    #[test]
    fn hull_samples_are_the_outermost_leaves() {
        // A ball of leaves on a sphere of radius 1 and an inner cluster: samples lie on the shell.
        let mut centres = Vec::new();
        for i in 0..400 {
            let t = i as f32 * 0.37;
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / 400.0;
            let r = (1.0 - y * y).sqrt();
            centres.push([r * (t * 7.0).cos(), y, r * (t * 7.0).sin()]);
            centres.push([0.3 * r * t.cos(), 0.3 * y, 0.3 * r * t.sin()]);
        }
        let samples = hull_samples(centres.iter().copied());
        assert!(samples.len() > 40, "{} samples", samples.len());
        assert!(samples.iter().all(|s| (s.length() - 1.0).abs() < 0.05));
    }

    #[test]
    fn projected_height_matches_the_pinhole_rule() {
        // 10 m at 100 m with 1 mm per pixel at one metre: 100 pixels.
        assert!((projected_height(10.0, 1.0, 100.0, 0.001) - 100.0).abs() < 1e-3);
        assert!((projected_height(10.0, 2.0, 100.0, 0.001) - 200.0).abs() < 1e-3);
    }
}
