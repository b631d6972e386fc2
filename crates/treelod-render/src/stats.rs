//! The public statistics of a frame: what [`Renderer::prepare`] selected and submitted
//! ([`FrameStats`]), what its shadow pass draws ([`ShadowStats`]), and where its time went
//! ([`PreparePhases`]).

use std::time::{Duration, Instant};

use treelod_runtime::{PerPrimitive, PerTechnique};

#[cfg(doc)]
use crate::{Renderer, Settings, Technique};
#[cfg(doc)]
use treelod_runtime::Primitive;

/// What [`Renderer::prepare`] selected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// Instances inside the view frustum.
    pub instances_visible: u32,
    /// Instances inside the view frustum by the technique each was drawn with: the settings'
    /// [`Settings::technique`], or [`Technique::FALLBACK`] for trees whose containers lack its
    /// data. Sums to [`Self::instances_visible`].
    pub instances: PerTechnique<u32>,
    /// Ranges recorded (one per non-empty range, each with its `DrawInfo`).
    pub ranges: u32,
    /// Indirect draw commands the GPU executes for [`Self::ranges`]: consecutive ranges of a
    /// bucket that draw the same elements (every tree's octahedral or billboard quads of a
    /// model, far ellipsoids, equal prefixes) are one instanced draw. With GPU selection, one
    /// per range.
    pub draw_commands: u32,
    /// Draws made coarser than the selection because their prefix is not resident yet.
    pub ranges_clamped: u32,
    /// Primitives submitted, per kind ([`Primitive`]): triangles (bark, leaves, pruned leaves,
    /// LoD chain levels), points (the prefixes; the vertex shader drops those outside the cut),
    /// impostor planes, billboard quads, ellipsoids and branch lines (the prefixes; the vertex
    /// shader drops those outside the level).
    pub submitted: PerPrimitive<u64>,
    /// Primitives submitted, per technique the trees that submitted them are drawn with (a
    /// pruned tree below its pruning height counts under pruning though the point tree draws it).
    /// Sums to [`Self::primitives`].
    pub by_technique: PerTechnique<u64>,
    /// Trees drawn with two techniques this frame, in a transition from one to the other
    /// ([`Policy::transition`](crate::Policy)): each counts once in [`Self::instances`], under
    /// the technique it goes to; the draws of the one it leaves count in [`Self::submitted`] and,
    /// under that technique, in [`Self::by_technique`].
    pub transitions: u32,
    /// Primitives of the draws of the techniques the trees in a transition leave (counted in
    /// [`Self::submitted`] and [`Self::by_technique`] too): what the frame submits beyond its
    /// assignment, for the few frames a transition lasts.
    pub leaving: u64,
    /// Bytes of model data on the GPU: vertices, materials and images of every model, and the
    /// streamed prefixes and roots in use.
    pub bytes_resident: u64,
    /// Bytes of triangles and points uploaded by this frame.
    pub bytes_uploaded: u64,
    /// Leaves drawn by pruned instances (their triangles count in [`Self::submitted`]).
    pub leaves_pruned: u64,
    /// Whether this frame's point tree was selected on the GPU ([`Renderer::enable_gpu_selection`]).
    /// Then what the GPU selected — the visible instances it drew with their assigned technique
    /// (counted in [`Self::instances`] under the point tree, as the CPU path counts them), its
    /// ranges, triangles and points in [`Self::submitted`] and [`Self::by_technique`] (under the
    /// technique each tree is drawn with), the primitives of trees only leaving the point tree
    /// in a transition in [`Self::leaving`], and [`Self::ranges_dropped`] — are those of the
    /// latest earlier frame whose counters have been read back (without waiting: usually one or
    /// two frames old, zero before the first). In a policy frame the counts of the other
    /// techniques, selected on the CPU, are this frame's and are added to them, as are
    /// [`Self::transitions`] and [`Self::leaves_pruned`]; [`Self::bytes_resident`] is current;
    /// nothing is streamed ([`Self::bytes_uploaded`] and [`Self::ranges_clamped`] are zero). A
    /// tree both entering and leaving the point tree's selection in a transition is one GPU draw
    /// on every pixel, where the CPU path counts two draws and their primitives twice.
    pub gpu_selection: bool,
    /// GPU selection: ranges selected but not drawn because their bucket was full (the buckets
    /// grow for later frames once the counters are read back).
    pub ranges_dropped: u32,
    /// What the shadow pass draws, all cascades together ([`Settings::shadows`]; zero without).
    pub shadow: ShadowStats,
    /// What the host's shadow maps drew ([`Renderer::set_host_shadow_views`]; `cascades` is the
    /// number of maps, `per_cascade` their first [`crate::MAX_CASCADES`]).
    pub host_shadow: ShadowStats,
    /// Cascades of the host's shadow maps the trees receive in place of the renderer's own
    /// ([`Renderer::receive_host_shadows`]); zero while they receive the renderer's own cascades
    /// (or none).
    pub host_shadows_received: u32,
}

impl FrameStats {
    /// Primitives submitted, every kind counted once (a splat, a plane, a quad, an ellipsoid's
    /// and a line's bounding quad are each one primitive).
    #[must_use]
    pub fn primitives(&self) -> u64 {
        self.submitted.total()
    }
}

/// How the policy's budget mode steered the latest frame ([`Renderer::budget_frame`]): the
/// `s_min` and the policy target it was selected with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BudgetFrame {
    /// `s_min`, pixels.
    pub s_min: f32,
    /// The policy's error target.
    pub target: f32,
    /// Whether both were at their floors ([`BudgetController::at_finest`]): no steering draws
    /// more detail, so a frame far under the budget had nothing left to spend it on.
    ///
    /// [`BudgetController::at_finest`]: treelod_runtime::BudgetController::at_finest
    pub finest: bool,
}

/// What the shadow pass of a frame draws, summed over its cascades (a tree in two cascades
/// counts twice).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadowStats {
    /// Cascades drawn.
    pub cascades: u32,
    /// Instances inside a cascade's frustum, per cascade.
    pub instances_visible: u32,
    /// Instances inside a cascade's frustum by the technique the cascade drew each with (chosen
    /// from the light's view, [`Settings::policy`]), per cascade; sums to
    /// [`Self::instances_visible`].
    pub instances: PerTechnique<u32>,
    /// Ranges recorded (as [`FrameStats::ranges`]).
    pub ranges: u32,
    /// Indirect draw commands (as [`FrameStats::draw_commands`]).
    pub draw_commands: u32,
    /// Draws made coarser than the cascades' selections because their prefixes are not resident
    /// yet (0 once the cascades' data has streamed in).
    pub ranges_clamped: u32,
    /// Primitives submitted, per kind (as [`FrameStats::submitted`]).
    pub submitted: PerPrimitive<u64>,
    /// Primitives submitted per cascade, finest first (zero past [`Self::cascades`]).
    pub per_cascade: [u64; crate::MAX_CASCADES],
}

impl ShadowStats {
    /// Primitives submitted, every kind counted once (as [`FrameStats::primitives`]).
    #[must_use]
    pub fn primitives(&self) -> u64 {
        self.submitted.total()
    }

    /// Adds what cascade `k`'s view drew (counted as a frame's) to the pass's sums.
    pub(crate) fn add_view(&mut self, k: usize, view: &FrameStats) {
        if let Some(slot) = self.per_cascade.get_mut(k) {
            *slot = view.primitives();
        }
        self.ranges += view.ranges;
        self.draw_commands += view.draw_commands;
        self.ranges_clamped += view.ranges_clamped;
        self.submitted += view.submitted;
    }
}

/// Where the latest [`Renderer::prepare`] spent its time on the CPU, phase by phase
/// ([`Renderer::prepare_phases`]): what a host tuning its forest (the trees' count, the budgets,
/// shadows) needs to see beside the frame's total. Wall clock, read with [`Instant`] at each
/// phase's end; the phases follow one another, so they sum to the call's time but for the
/// budget mode's steering around it.
///
/// With GPU selection the point tree's selection is the GPU's: `select` is then the CPU's
/// selection of the other techniques' trees and the compute work's recording and submission,
/// and `stream` is zero (every model is resident whole).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PreparePhases {
    /// Before the trees: the occlusion queries' read-back, the shadow cascades' fitting and maps,
    /// the instances' transforms when they changed.
    pub setup: Duration,
    /// The camera's assignment: the policy's choice of each tree's technique, its transitions;
    /// in budget mode, the look-ahead before a step down of the target.
    pub assign: Duration,
    /// Every view's selection: the camera's, that of the techniques trees in a transition leave,
    /// and each shadow cascade's (its assignment from the light included).
    pub select: Duration,
    /// Streaming: what each cell needs, the residency's choice within the upload budget, the
    /// pool's growth and the uploads of triangles and points.
    pub stream: Duration,
    /// The draw records of every view: prefixes clamped to what is resident, each range's draw
    /// record in its bucket, the indirect draws.
    pub record: Duration,
    /// The frame's uniforms, draw records and indirect draws written to the GPU's queue.
    pub upload: Duration,
}

impl PreparePhases {
    /// The phases in the order `prepare` runs them, each with its name (the field's), e.g. for a
    /// host's or a tool's table: `[("setup", …), ("assign", …), …, ("upload", …)]`.
    #[must_use]
    pub fn named(&self) -> [(&'static str, Duration); 6] {
        [
            ("setup", self.setup),
            ("assign", self.assign),
            ("select", self.select),
            ("stream", self.stream),
            ("record", self.record),
            ("upload", self.upload),
        ]
    }

    /// The phases' sum.
    #[must_use]
    pub fn total(&self) -> Duration {
        self.named().iter().map(|&(_, d)| d).sum()
    }
}

/// Charges the time since its last lap to one phase of [`PreparePhases`].
pub(crate) struct Laps(Instant);

impl Laps {
    pub(crate) fn start() -> Self {
        Self(Instant::now())
    }

    /// Adds the time since the last lap (or the start) to `phase`.
    pub(crate) fn lap(&mut self, phase: &mut Duration) {
        let now = Instant::now();
        *phase += now.saturating_duration_since(self.0);
        self.0 = now;
    }
}
