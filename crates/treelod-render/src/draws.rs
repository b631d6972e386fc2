//! The draw lists: what one view of a frame (the camera, or a shadow cascade) selected and draws,
//! the buckets (model × [`Bucket`], one pipeline each) its draws are recorded into, clamped to
//! what is resident, and the indirect draws of each bucket.

use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;
use treelod_runtime::{
    DrawList, DrawRange, Kind, PerPrimitive, PerTechnique, ROOTS_CELL, Technique, TreeDraws, TriangleSource,
};

use crate::renderer::{ModelId, Renderer, max_axis_scale};
use crate::stats::FrameStats;
use crate::streaming::Array;
use crate::technique::{Bucket, DrawSource, prefix_lists};

/// One draw's constants. WGSL twin: `DrawInfo` in `shaders/shared/draw.wgsl`. The instance's
/// transform is not repeated here: the shaders read it from [`InstanceTransform`]s at
/// `instance`, uploaded when the list of instances changes. (A range once carried its 64-byte
/// matrix and scale, 112 bytes in all: on 10^4 weeping willows a frame of 45,000 ranges wrote
/// 5 MB of them, each matrix once per cell of its tree.)
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct DrawInfo {
    pub(crate) tau_p: f32,
    pub(crate) tau_t: f32,
    pub(crate) cell: u32,
    pub(crate) shading: f32,
    /// Size factor of pruned leaves about their centres (1 for everything else).
    pub(crate) leaf_scale: f32,
    /// Index of the instance in [`Renderer::set_instances`]' list: its [`InstanceTransform`],
    /// and the seed of the level blend's dither (`level_dither`).
    pub(crate) instance: u32,
    /// The colour of [`DebugView::Techniques`](crate::DebugView) for the technique that made the
    /// draw ([`tint`]).
    pub(crate) tint: u32,
    /// The share of the transition dither the draw keeps ([`RecordedDraw::dither`]), as WGSL's
    /// `pack2x16unorm` packs it: `0xFFFF0000` (`[0, 1)`) outside a transition.
    pub(crate) fade: u32,
}

const _: () = assert!(size_of::<DrawInfo>() == 32);

/// One instance's transform as the tree shaders read it, in the order of
/// [`Renderer::set_instances`]' list. WGSL twin: `InstanceTransform` in
/// `shaders/shared/draw.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct InstanceTransform {
    /// Column-major world-from-model transform.
    pub(crate) model: [[f32; 4]; 4],
    /// Its largest axis scale ([`max_axis_scale`]), for splat and line radii.
    pub(crate) scale: f32,
    pub(crate) pad: [u32; 3],
}

const _: () = assert!(size_of::<InstanceTransform>() == 80);

impl InstanceTransform {
    pub(crate) fn new(transform: glam::Mat4) -> Self {
        Self { model: transform.to_cols_array_2d(), scale: max_axis_scale(transform), pad: [0; 3] }
    }
}

/// [`DrawInfo::fade`] of a dither range `[lo, hi)` (clamped to `[0, 1]`), as `pack2x16unorm`.
pub(crate) fn pack_fade([lo, hi]: [f32; 2]) -> u32 {
    // Every pixel, the share of all but a transition's draws, without the arithmetic.
    if lo == 0.0 && hi == 1.0 {
        return 0xFFFF_0000;
    }
    unorm(lo, 65535.0) | (unorm(hi, 65535.0) << 16)
}

/// `x` clamped to `[0, 1]`, times `max` (at most 2^23) and rounded half away from zero, as
/// `(x.clamp(0.0, 1.0) * max).round() as u32` gives, without `round` (a library call on the
/// baseline x86-64 target, five per draw record): the fraction below the truncation is exact
/// under 2^23. NaN gives 0.
#[inline]
fn unorm(x: f32, max: f32) -> u32 {
    let v = x.clamp(0.0, 1.0) * max;
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=max, below 2^23")]
    let whole = v as u32;
    #[expect(clippy::cast_precision_loss, reason = "below 2^23: exact")]
    let fraction = v - whole as f32;
    whole + u32::from(fraction >= 0.5)
}

/// [`DrawInfo::tint`] of `technique`: its debug colour ([`Technique::colour`], linear RGB) as
/// WGSL's `pack4x8unorm` packs it, red in the low byte (alpha 1).
pub(crate) fn tint(technique: Technique) -> u32 {
    let [r, g, b] = technique.colour().map(|c| unorm(c, 255.0));
    r | (g << 8) | (b << 16) | (255 << 24)
}

/// One draw of the last [`Renderer::prepare`], as the GPU will execute it, for tests and tools.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedDraw {
    /// Index of the instance in [`Renderer::set_instances`]'s list.
    pub instance: u32,
    /// The instance's model.
    pub model: ModelId,
    /// The container cell, or [`treelod_runtime::ROOTS_CELL`] for a prefix of the far list.
    pub cell: u32,
    /// What is drawn.
    pub source: DrawSource,
    /// Elements drawn: a prefix of the cell's range (or of the model's far list).
    pub count: u32,
    /// `τ_p` the shader tests points with, model units (raised above the selection's when the
    /// resident prefix is shorter than the selection asked for); for pruned leaves, `λ`.
    pub tau_points: f32,
    /// `τ_t`, model units, likewise; for pruned leaves, their size factor.
    pub tau_triangles: f32,
    /// Whether residency made this draw coarser than the selection.
    pub clamped: bool,
    /// The technique that made the draw: the one its tree is drawn with, or, for a tree in a
    /// transition ([`treelod_runtime::Policy::transition`]), also the one it is leaving.
    pub technique: Technique,
    /// The pixels the draw covers, `[lo, hi)` of the transition dither (`[0, 1)`: all of them):
    /// for a tree in a transition the new technique's draws keep `[0, shown)` and the old one's
    /// `[shown, 1)` ([`treelod_runtime::Transition`]).
    pub dither: [f32; 2],
}

/// [`RecordedDraw::dither`] outside a transition.
pub(crate) const EVERY_PIXEL: [f32; 2] = [0.0, 1.0];

/// What one view of a frame (the camera, or a shadow cascade) selected and draws.
#[derive(Default)]
pub(crate) struct View {
    pub(crate) selection: DrawList,
    /// The pieces of the renderer's recordings that hold the view's draws as recorded for the
    /// GPU, in order (its own, then those of the techniques trees in a transition leave): read in
    /// place ([`Renderer::recorded`]), not copied into one list each frame.
    pub(crate) recorded: std::ops::Range<usize>,
    /// Instances drawn with the sequential point tree when not every instance is (the
    /// assignment's full-mesh and point-tree lists and what techniques handed back), and their
    /// indices in `instances` (see `spt_remapped`).
    pub(crate) spt_instances: Vec<treelod_runtime::Instance>,
    pub(crate) spt_map: Vec<u32>,
    /// Whether the selection ran over `spt_instances`, so its instance indices go through
    /// `spt_map`.
    pub(crate) spt_remapped: bool,
    /// The draws of the other representations, as their runtime selections listed them.
    pub(crate) draws: TreeDraws,
    /// Per model, per bucket: the view's range of the indirect buffer.
    pub(crate) model_draws: Vec<[(u32, u32); Bucket::COUNT]>,
}

impl View {
    /// The index in the renderer's instances of an instance of this view's selection.
    pub(crate) fn instance_index(&self, selected: u32) -> u32 {
        if self.spt_remapped { self.spt_map.get(selected as usize).copied().unwrap_or(selected) } else { selected }
    }
}

impl Renderer {
    /// Records `view`'s draws, clamped to what is resident, after the draw infos and indirect
    /// draws of the views before it; counts them into `stats`. `leaving`: the draws, for the
    /// same view, of the techniques the trees in a transition are leaving (the camera's view
    /// only), recorded into the same buckets on their share of the pixels.
    ///
    /// The draws are recorded in pieces of at most [`Renderer::record_chunk`] of the selection's
    /// lists, in parallel, each piece into buckets of its own ([`Recording`]); the buckets are
    /// then read piece after piece, in the order of the lists, so the draw infos, indirect draws
    /// and recorded draws are those one pass over the lists gives, whatever the pieces and the
    /// thread count.
    pub(crate) fn record_view(
        &mut self,
        view: &mut View,
        leaving: Option<&View>,
        full_mesh: bool,
        stats: &mut FrameStats,
    ) {
        let mut recordings = std::mem::take(&mut self.recordings);
        let buckets = Bucket::COUNT * self.models.len();
        let first = self.recordings_used;
        // The view's pieces, then those of the techniques trees in transition are leaving.
        let (used, leaving_from) = {
            let mut pieces = pieces_of(view, false, self.record_chunk);
            let leaving_from = first + pieces.len();
            if let Some(leaving) = leaving {
                pieces.extend(pieces_of(leaving, true, self.record_chunk));
            }
            if recordings.len() < first + pieces.len() {
                recordings.resize_with(first + pieces.len(), Recording::default);
            }
            let this = &*self;
            let record = |(piece, out): (&Piece<'_>, &mut Recording)| {
                out.clear(buckets);
                this.record_piece(piece, full_mesh, out);
            };
            let outs = &mut recordings[first..first + pieces.len()];
            if pieces.len() > 1 {
                pieces.par_iter().zip(outs.par_iter_mut()).for_each(record);
            } else {
                pieces.iter().zip(outs.iter_mut()).for_each(record);
            }
            (first..first + pieces.len(), leaving_from)
        };
        self.recordings_used = used.end;
        view.recorded = used.clone();
        stats.leaving = 0;
        for r in used.clone() {
            let out = &recordings[r];
            stats.ranges_clamped += out.clamped;
            // What each kind of primitive and each technique submitted.
            stats.submitted += out.submitted;
            stats.by_technique += out.by_technique;
            if r >= leaving_from {
                stats.leaving += out.elements;
            }
        }
        // The view's draw infos, bucket after bucket, each bucket's pieces in turn; their copy
        // into the draw buffer waits for `upload_draws`. Here only their indirect draws.
        view.model_draws.clear();
        let (before, infos_before) = (self.indirect.len(), self.info_count);
        let mut written: Vec<(usize, usize)> =
            used.clone().flat_map(|r| recordings[r].written.iter().map(move |&b| (b, r))).collect();
        written.sort_unstable();
        let mut written = written.into_iter().peekable();
        for m in 0..self.models.len() {
            let mut draws = [(0, 0); Bucket::COUNT];
            for (kind, draw) in draws.iter_mut().enumerate() {
                let start = self.indirect.len();
                let bucket = m * Bucket::COUNT + kind;
                while let Some((_, r)) = written.next_if(|&(b, _)| b == bucket) {
                    let runs = &recordings[r].buckets[bucket].runs;
                    self.info_segments.push((r, bucket));
                    for &[first_vertex, vertex_count, draws] in runs {
                        let index = u32::try_from(self.info_count).unwrap_or(u32::MAX);
                        self.info_count += draws as usize;
                        // Ranges that draw the same elements as the bucket's last draw (each
                        // tree's octahedral or billboard quads, far ellipsoids, equal prefixes)
                        // join it as its next instances: the shaders read a range's `DrawInfo`
                        // at the instance index, which runs on from the draw's first. One
                        // indirect draw then stands for a run of trees, where the GPU would
                        // otherwise walk a command per tree. (A piece's run of such ranges is
                        // one entry here: each of them after its first would join the draw the
                        // one before it made or joined.)
                        if let Some(last) = self.indirect[start..].last_mut()
                            && (last.first_vertex, last.vertex_count) == (first_vertex, vertex_count)
                            && last.first_instance.checked_add(last.instance_count) == Some(index)
                        {
                            last.instance_count += draws;
                            continue;
                        }
                        self.indirect.push(wgpu::util::DrawIndirectArgs {
                            vertex_count,
                            instance_count: draws,
                            first_vertex,
                            first_instance: index,
                        });
                    }
                }
                let [start, end] = [start, self.indirect.len()].map(|n| u32::try_from(n).unwrap_or(u32::MAX));
                *draw = (start, end - start);
            }
            view.model_draws.push(draws);
        }
        stats.ranges += u32::try_from(self.info_count - infos_before).unwrap_or(u32::MAX);
        stats.draw_commands += u32::try_from(self.indirect.len() - before).unwrap_or(u32::MAX);
        self.recordings = recordings;
    }

    /// Starts a frame's draws: no draw info, indirect draw or piece recorded yet.
    pub(crate) fn begin_draws(&mut self) {
        self.recordings_used = 0;
        self.info_segments.clear();
        self.info_count = 0;
        self.indirect.clear();
    }

    /// The draws of `view` as recorded for the GPU, in order: those of its pieces of
    /// `recordings` ([`View::recorded`]).
    pub(crate) fn recorded<'a>(
        recordings: &'a [Recording],
        view: &View,
    ) -> impl Iterator<Item = &'a RecordedDraw> + 'a {
        Self::recorded_pieces(recordings, view).iter().flat_map(Recording::draws)
    }

    /// The pieces of `recordings` that hold [`Self::recorded`], in order ([`Recording::draws`]
    /// each), for a reader that takes them side by side.
    pub(crate) fn recorded_pieces<'a>(recordings: &'a [Recording], view: &View) -> &'a [Recording] {
        recordings.get(view.recorded.clone()).unwrap_or_default()
    }

    /// Copies the frame's draw infos, in the order [`Self::record_view`] gave them their
    /// indices, into `out` (their bytes, `info_count` of them: the queue's staging memory, so
    /// that each info is copied once more after its piece wrote it). (`WriteOnly` of bytes is
    /// not `Send`: the runs are copied one after another.)
    pub(crate) fn write_draw_infos(&self, out: wgpu::WriteOnly<'_, [u8]>) {
        let mut rest = out;
        for &(r, bucket) in &self.info_segments {
            let infos: &[u8] = bytemuck::cast_slice(&self.recordings[r].buckets[bucket].infos);
            if infos.len() > rest.len() {
                break;
            }
            let (mut head, tail) = rest.split_at(infos.len());
            head.copy_from_slice(infos);
            rest = tail;
        }
    }

    /// The technique a draw of instance `instance` in a view's (`leaving` false) or in its
    /// leaving draws' selection was made by, and the share of the transition dither it keeps.
    pub(crate) fn drawn_by(&self, instance: u32, leaving: bool) -> (Technique, [f32; 2]) {
        let technique = self.technique_of(instance);
        match self.transition(instance) {
            Some(t) if leaving => (t.from, [t.shown, 1.0]),
            Some(t) => (technique, [0.0, t.shown]),
            None => (technique, EVERY_PIXEL),
        }
    }

    /// Records the draws of `piece` (of a view's selections or, `piece.leaving`, of those of the
    /// techniques trees in a transition leave) into `out`.
    fn record_piece(&self, piece: &Piece<'_>, full_mesh: bool, out: &mut Recording) {
        let Piece { view, leaving, part } = *piece;
        let tints = Technique::ALL.map(tint);
        // A tree's draws come one after another in each list (a far tree's branch lines, a
        // pruned tree's leaves and bark): its technique and dither are looked up once.
        let mut last: Option<(u32, (Technique, [f32; 2]))> = None;
        let mut drawn_by = |instance: u32| match last {
            Some((i, by)) if i == instance => by,
            _ => {
                let by = self.drawn_by(instance, leaving);
                last = Some((instance, by));
                by
            }
        };
        match part {
            Part::Ranges(ranges) => {
                let mut i = 0;
                while i < ranges.len() {
                    let range = ranges[i];
                    // A cell's triangle range is followed by its point range, if any.
                    let points = ranges.get(i + 1).filter(|next| pairs(&range, next)).copied();
                    i += 1 + usize::from(points.is_some());
                    let (triangles, points) = match range.kind {
                        Kind::Triangles => (Some(range), points),
                        Kind::Points | Kind::Roots => (None, Some(range)),
                    };
                    let instance = view.instance_index(range.instance);
                    let (technique, dither) = drawn_by(instance);
                    for draw in self.clamp(instance, range, triangles, points, full_mesh) {
                        let Some(draw) = draw else { continue };
                        let draw = RecordedDraw { technique, dither, ..draw };
                        out.clamped += u32::from(draw.clamped);
                        let (bucket, first_vertex, corners) = self.gpu_first(&draw);
                        let info = DrawInfo {
                            tau_p: draw.tau_points,
                            tau_t: draw.tau_triangles,
                            cell: draw.cell,
                            shading: range.shading,
                            leaf_scale: 1.0,
                            instance: draw.instance,
                            tint: tints[technique.index()],
                            fade: pack_fade(dither),
                        };
                        out.push(bucket, info, first_vertex, draw.count * corners);
                        out.keep(draw);
                    }
                }
            }
            // Pruned trees: leaves and bark from each model's extra triangles, unshaded by
            // Gilet's per-cell estimate (it is a property of the point hierarchy's cells).
            Part::Triangles(draws) => {
                for draw in draws {
                    let (technique, dither) = drawn_by(draw.instance);
                    let record = RecordedDraw {
                        instance: draw.instance,
                        model: ModelId(draw.model),
                        cell: draw.cell,
                        source: match draw.source {
                            TriangleSource::PrunedLeaves => DrawSource::PrunedLeaves,
                            TriangleSource::Bark => DrawSource::Bark,
                            TriangleSource::LodLevel => DrawSource::LodLevel,
                        },
                        count: draw.count,
                        tau_points: draw.lambda,
                        tau_triangles: draw.tau_triangles,
                        clamped: false,
                        technique,
                        dither,
                    };
                    record_direct(out, record, draw.first, draw.leaf_scale, &tints);
                }
            }
            // Prefixes of one cell's elements uploaded whole (impostor planes, ellipsoids,
            // lines), each in its bucket, the level chosen in the shader by `τ`.
            Part::Prefixes(draws, source) => {
                for draw in draws {
                    let range = draw.range;
                    let (technique, dither) = drawn_by(draw.instance);
                    let record = RecordedDraw {
                        instance: draw.instance,
                        model: ModelId(draw.model),
                        cell: range.cell,
                        source,
                        count: range.count,
                        tau_points: range.tau,
                        tau_triangles: range.tau,
                        clamped: false,
                        technique,
                        dither,
                    };
                    record_direct(out, record, range.first, 1.0, &tints);
                }
            }
            // Baseline billboards: every quad of the chosen kind; and octahedral impostors.
            Part::Quads(draws, source) => {
                for &treelod_runtime::QuadDraw { instance, model, first, count } in draws {
                    let (technique, dither) = drawn_by(instance);
                    let record = RecordedDraw {
                        instance,
                        model: ModelId(model),
                        cell: ROOTS_CELL,
                        source,
                        count,
                        tau_points: 0.0,
                        tau_triangles: 0.0,
                        clamped: false,
                        technique,
                        dither,
                    };
                    record_direct(out, record, first, 1.0, &tints);
                }
            }
        }
    }

    /// The draws of one selected cell (or one roots range), clamped to what is resident so that
    /// a missing prefix shows coarser data, never a hole:
    ///
    /// - **The far list** (a [`Kind::Roots`] range): if only its first `r` entries are pinned
    ///   (a small memory budget, `Model::far_pinned`), `τ_p` rises to the `hi` of the first entry
    ///   not pinned.
    /// - **Points**: if only `r` leading points are resident, `τ_p` rises to the `hi` of the first
    ///   missing one, so every point the cut needs lies in the resident prefix; with nothing (or
    ///   less than the roots) resident, the cell draws its roots from the pinned copy.
    /// - **Triangles**: `τ_t` rises to at least `τ_p` (the rule needs `τ_p ≤ τ_t`) and, if only `r`
    ///   leading triangles are resident, to the size of the first missing one; the smaller
    ///   triangles are then drawn through their points (the cell's own, also where the far list
    ///   draws the tree's points at the selection's `τ_t`).
    ///
    /// For any `τ_p ≤ τ_t` the drawn elements are an exact cut (spec §10), so a clamped cell is a
    /// valid coarser level of detail.
    fn clamp(
        &self,
        instance: u32,
        range: DrawRange,
        triangles: Option<DrawRange>,
        points: Option<DrawRange>,
        full_mesh: bool,
    ) -> [Option<RecordedDraw>; 2] {
        let base = RecordedDraw {
            instance,
            model: ModelId(range.model),
            cell: range.cell,
            source: DrawSource::Roots,
            count: 0,
            tau_points: range.tau_points,
            tau_triangles: range.tau_triangles,
            clamped: false,
            technique: Technique::FALLBACK,
            dither: EVERY_PIXEL,
        };
        let (m, c) = (range.model as usize, range.cell as usize);
        let (Some(model), Some(lod)) = (self.models.get(m), self.lods.get(m)) else { return [None, None] };
        if range.kind == Kind::Roots {
            let pinned = model.far_pinned as usize;
            let Some(&first_missing) = lod.far_hi().get(pinned).filter(|_| range.count as usize > pinned) else {
                return [None, Some(RecordedDraw { count: range.count, ..base })];
            };
            // More than is pinned: `τ_p` rises to the first entry not pinned, as for a cell.
            let tau_p = range.tau_points.max(first_missing);
            let count = lod.far_above(tau_p);
            let tau_t = range.tau_triangles.max(tau_p);
            return [
                None,
                Some(RecordedDraw { count, tau_points: tau_p, tau_triangles: tau_t, clamped: true, ..base }),
            ];
        }
        let Some(cell) = model.cell_lod.get(c).and_then(|&i| lod.cells().get(i as usize)) else {
            return [None, None];
        };
        let (sizes, his) = (lod.triangle_sizes(cell), lod.point_hi(cell));
        let (mut tau_p, mut tau_t) = (range.tau_points, range.tau_triangles);
        let resident_t = self.residency.slot(m, c, Array::Triangles).resident as usize;
        let resident_p = self.residency.slot(m, c, Array::Points).resident as usize;
        let roots = model.cell_roots.get(c).map_or(0, |r| r.1) as usize;
        let triangles_complete = triangles.is_none_or(|t| resident_t >= t.count as usize);
        // A cell whose points the far list draws (a triangle range alone, `select_frame`'s far
        // list) draws its own points too when its triangles are clamped: the far list's `τ_t`
        // leaves out the points of the triangles now left out (the far list draws the points
        // below it a second time, never a hole).
        let points = points.or_else(|| {
            (!triangles_complete && !his.is_empty()).then(|| DrawRange {
                kind: Kind::Points,
                count: lod.points_above(cell, tau_p),
                ..range
            })
        });
        let mut point_draw = None;
        let mut clamped = false;
        if let Some(p) = points.filter(|_| !(full_mesh && triangles_complete)) {
            let wanted = p.count as usize;
            let (source, count) = if resident_p >= wanted {
                (DrawSource::Points, wanted)
            } else if resident_p >= roots.max(1) {
                tau_p = tau_p.max(his[resident_p]);
                (DrawSource::Points, lod.points_above(cell, tau_p) as usize)
            } else {
                tau_p = tau_p.max(his.get(roots).copied().unwrap_or(tau_p));
                (DrawSource::Roots, roots)
            };
            clamped |= count < wanted || source == DrawSource::Roots;
            if count > 0 {
                point_draw = Some((source, count));
            }
        }
        tau_t = tau_t.max(tau_p);
        // At the selection's `τ_t`, its own count (no range: none), without searching again.
        let mut count_t = if tau_t.to_bits() == range.tau_triangles.to_bits() {
            triangles.map_or(0, |t| t.count as usize)
        } else {
            lod.triangles_above(cell, tau_t) as usize
        };
        if count_t > resident_t {
            tau_t = tau_t.max(sizes[resident_t]);
            count_t = lod.triangles_above(cell, tau_t) as usize;
        }
        clamped |= triangles.is_some_and(|t| count_t < t.count as usize);
        let base = RecordedDraw { tau_points: tau_p, tau_triangles: tau_t, clamped, ..base };
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        [
            (count_t > 0).then(|| RecordedDraw { source: DrawSource::Triangles, count: count(count_t), ..base }),
            point_draw.map(|(source, n)| RecordedDraw { source, count: count(n), ..base }),
        ]
    }

    /// The bucket (model × [`Bucket`], [`Bucket::of_model`]), first vertex and vertices per element
    /// of a recorded draw.
    fn gpu_first(&self, draw: &RecordedDraw) -> (usize, u32, u32) {
        let m = draw.model.0 as usize;
        let model = &self.models[m];
        match draw.source {
            DrawSource::Triangles => {
                let slot = self.residency.slot(m, draw.cell as usize, Array::Triangles);
                (Bucket::Triangles.of_model(m), 2 * slot.start * 3, 3)
            }
            DrawSource::Points => {
                let slot = self.residency.slot(m, draw.cell as usize, Array::Points);
                (Bucket::Points.of_model(m), slot.start * 6, 6)
            }
            DrawSource::Roots => {
                let at = if draw.cell == ROOTS_CELL {
                    0
                } else {
                    model.cell_roots.get(draw.cell as usize).map_or(0, |r| r.0)
                };
                (Bucket::Points.of_model(m), (model.roots_start + at) * 6, 6)
            }
            // Recorded directly (`record_direct`), never clamped.
            source => (source.bucket().of_model(m), 0, source.corners()),
        }
    }

    /// Draws `view`'s buckets with `pipelines` (in bucket order) into `pass`, whose frame bind
    /// group is set.
    pub(crate) fn draw_view(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        view: &View,
        pipelines: &[wgpu::RenderPipeline; Bucket::COUNT],
    ) {
        let stride = size_of::<wgpu::util::DrawIndirectArgs>() as u64;
        for (bucket, pipeline) in Bucket::ALL.into_iter().zip(pipelines) {
            pass.set_pipeline(pipeline);
            for (model, draws) in self.models.iter().zip(&view.model_draws) {
                let (first, count) = draws[bucket as usize];
                if count == 0 {
                    continue;
                }
                pass.set_bind_group(1, &model.bind_group, &[]);
                if bucket.group_entries().is_some() {
                    // A bucket with draws has its group: the model's upload made it.
                    let Some(group) = &model.groups[bucket as usize] else { continue };
                    pass.set_bind_group(3, group, &[]);
                }
                pass.multi_draw_indirect(&self.indirect_buffer, u64::from(first) * stride, count);
            }
        }
    }
}

/// Whether `next` is the point range of the cell whose triangle range is `range`: the two are
/// recorded together ([`Renderer::clamp`]).
fn pairs(range: &DrawRange, next: &DrawRange) -> bool {
    range.kind == Kind::Triangles
        && next.kind == Kind::Points
        && (next.instance, next.cell) == (range.instance, range.cell)
}

/// The most entries of a view's lists one piece records by default ([`Renderer::record_view`]):
/// pieces of a few microseconds' work, so that a forest's tens of thousands of draws spread over
/// the threads while a small scene stays in one piece.
pub(crate) const RECORD_CHUNK: usize = 512;

/// A piece of a view's draws, recorded as one task of [`Renderer::record_view`].
#[derive(Clone, Copy)]
struct Piece<'a> {
    view: &'a View,
    /// Whether these are the draws of the techniques trees in a transition leave.
    leaving: bool,
    part: Part<'a>,
}

/// Consecutive entries of one of a view's lists.
#[derive(Clone, Copy)]
enum Part<'a> {
    /// The point tree's ranges (a cell's triangle range beside its point range).
    Ranges(&'a [DrawRange]),
    /// Pruned leaves, bark and LoD chain levels.
    Triangles(&'a [treelod_runtime::TriangleDraw]),
    /// Prefixes of one cell's elements uploaded whole.
    Prefixes(&'a [treelod_runtime::PrefixDraw], DrawSource),
    /// Billboards' and octahedral impostors' quads.
    Quads(&'a [treelod_runtime::QuadDraw], DrawSource),
}

/// `view`'s lists in the order they are recorded, in pieces of at most `chunk` entries (at least
/// 1); a cell's triangle range and its point range stay in one piece.
fn pieces_of(view: &View, leaving: bool, chunk: usize) -> Vec<Piece<'_>> {
    let chunk = chunk.max(1);
    let mut parts = Vec::new();
    let mut ranges = view.selection.ranges();
    while !ranges.is_empty() {
        let mut end = chunk.min(ranges.len());
        if end < ranges.len() && pairs(&ranges[end - 1], &ranges[end]) {
            end += 1;
        }
        let (head, rest) = ranges.split_at(end);
        parts.push(Part::Ranges(head));
        ranges = rest;
    }
    parts.extend(view.draws.triangles.chunks(chunk).map(Part::Triangles));
    for (list, source) in prefix_lists(&view.draws) {
        parts.extend(list.chunks(chunk).map(|c| Part::Prefixes(c, source)));
    }
    parts.extend(view.draws.billboards.chunks(chunk).map(|c| Part::Quads(c, DrawSource::Billboards)));
    parts.extend(view.draws.octahedral.chunks(chunk).map(|c| Part::Quads(c, DrawSource::Octahedral)));
    parts.into_iter().map(|part| Piece { view, leaving, part }).collect()
}

/// What one piece recorded: per bucket (model × [`Bucket`]) its draw infos with their first
/// vertex and vertex count, and the buckets it wrote, in the order it first wrote them (a piece
/// writes a few of a scene's buckets, however many models it has); its draws, and how many of
/// them streaming clamped. (Keeping only the point tree's draws here, the others made again
/// from the view's lists when asked, was measured and not taken: the orchid's 10^6-tree frames
/// recorded in the same time, `docs/cli.md`.)
#[derive(Default)]
pub(crate) struct Recording {
    buckets: Vec<Bucketed>,
    written: Vec<usize>,
    recorded: Vec<RecordedDraw>,
    clamped: u32,
    /// The elements of `recorded`, per primitive they are submitted as, per technique that
    /// made them, and in all: counted as each draw is kept, so the frame's statistics add up
    /// the pieces' sums instead of reading every draw again.
    submitted: PerPrimitive<u64>,
    by_technique: PerTechnique<u64>,
    elements: u64,
}

impl Recording {
    /// The piece's draws as recorded for the GPU, in order.
    pub(crate) fn draws(&self) -> &[RecordedDraw] {
        &self.recorded
    }

    /// Empty, with `buckets` buckets (their storage kept for the next frame).
    fn clear(&mut self, buckets: usize) {
        for b in self.written.drain(..) {
            if let Some(bucket) = self.buckets.get_mut(b) {
                bucket.infos.clear();
                bucket.runs.clear();
            }
        }
        self.buckets.resize_with(buckets, Bucketed::default);
        self.recorded.clear();
        self.clamped = 0;
        self.submitted = PerPrimitive::default();
        self.by_technique = PerTechnique::default();
        self.elements = 0;
    }

    /// Keeps `draw` in [`Self::recorded`] and counts its elements.
    fn keep(&mut self, draw: RecordedDraw) {
        let count = u64::from(draw.count);
        self.submitted[draw.source.primitive()] += count;
        self.by_technique[draw.technique] += count;
        self.elements += count;
        self.recorded.push(draw);
    }

    /// Adds a draw info to bucket `b`, drawing `vertex_count` vertices from `first_vertex`.
    fn push(&mut self, b: usize, info: DrawInfo, first_vertex: u32, vertex_count: u32) {
        let bucket = &mut self.buckets[b];
        if bucket.infos.is_empty() {
            self.written.push(b);
        }
        bucket.infos.push(info);
        match bucket.runs.last_mut() {
            Some([first, count, draws]) if (*first, *count) == (first_vertex, vertex_count) => *draws += 1,
            _ => bucket.runs.push([first_vertex, vertex_count, 1]),
        }
    }
}

/// A piece's draws of one bucket: their draw infos, and, apart (so that the indirect draws are
/// made without reading the infos), runs of consecutive draws of the same vertices: the first
/// vertex, the vertex count and the draws in the run. A frame's far trees draw the same ranges
/// (the orchid's 10^6 trees: up to 1.63 million draws a frame), which the frame's one pass over
/// the pieces then takes a run at a time (`docs/cli.md`).
#[derive(Default)]
struct Bucketed {
    infos: Vec<DrawInfo>,
    runs: Vec<[u32; 3]>,
}

/// Records a draw that streaming does not clamp (pruned leaves, bark, impostor planes: uploaded
/// whole): its `DrawInfo` (thresholds, technique and dither from `record`, unshaded) into the
/// model's bucket of its source, drawing `record.count` elements from element `first`, and
/// `record` itself. `tints`: each technique's [`tint`] by [`Technique::index`].
fn record_direct(
    out: &mut Recording,
    record: RecordedDraw,
    first: u32,
    leaf_scale: f32,
    tints: &[u32; Technique::COUNT],
) {
    let corners = record.source.corners();
    let info = DrawInfo {
        tau_p: record.tau_points,
        tau_t: record.tau_triangles,
        cell: record.cell,
        shading: 1.0,
        leaf_scale,
        instance: record.instance,
        tint: tints[record.technique.index()],
        fade: pack_fade(record.dither),
    };
    let bucket = record.source.bucket().of_model(record.model.0 as usize);
    out.push(bucket, info, corners * first, corners * record.count);
    out.keep(record);
}

#[cfg(test)]
mod tests {
    use super::{EVERY_PIXEL, pack_fade, unorm};

    #[test]
    fn every_pixel_packs_as_its_shares_do() {
        let packed = |[lo, hi]: [f32; 2]| unorm(lo, 65535.0) | (unorm(hi, 65535.0) << 16);
        assert_eq!(pack_fade(EVERY_PIXEL), packed(EVERY_PIXEL));
        assert_eq!(pack_fade(EVERY_PIXEL), 0xFFFF_0000);
        assert_eq!(pack_fade([-0.0, 1.0]), 0xFFFF_0000);
        for shares in [[0.0, 0.25], [0.25, 1.0], [0.0, 0.999_999], [1e-7, 1.0], [0.5, 0.5]] {
            assert_eq!(pack_fade(shares), packed(shares), "{shares:?}");
        }
    }

    #[test]
    fn unorm_rounds_as_round_does() {
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped first, as unorm")]
        let reference = |x: f32, max: f32| (x.clamp(0.0, 1.0) * max).round() as u32;
        let mut checked = 0;
        for max in [255.0, 65535.0] {
            // Every tie and its neighbours, and a dense sweep with values just under a half.
            for k in 0..=(max as u32) {
                let tie = (k as f32 + 0.5) / max;
                for x in [tie, f32::from_bits(tie.to_bits() - 1), f32::from_bits(tie.to_bits() + 1), k as f32 / max] {
                    assert_eq!(unorm(x, max), reference(x, max), "{x} × {max}");
                    checked += 1;
                }
            }
            for x in [-1.0, -0.0, 0.0, 0.499_999_97, 0.5, 1.0, 1.5, f32::INFINITY, f32::NEG_INFINITY, f32::NAN] {
                assert_eq!(unorm(x, max), reference(x, max), "{x} × {max}");
            }
        }
        assert!(checked > 4 * 65536);
    }
}
