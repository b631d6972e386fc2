//! The per-frame selection of every representation, as plain draw lists a renderer turns into
//! GPU draws.
//!
//! A frame's trees are first assigned to techniques ([`Assignment`], one list of instance indices
//! per [`Technique`]); then [`select_techniques`] runs each technique's selection over its own
//! list, appending to one [`TreeDraws`]: [`prune::select`](crate::prune::select) (pruned trees),
//! [`impostor::select`](crate::impostor::select) (impostor planes and their bark),
//! [`ellipsoid::select`](crate::ellipsoid::select) (ellipsoids and lines, or bark triangles) and
//! [`baseline::select`](crate::baseline::select) (the LoD chain, billboards). The sequential point
//! tree and the full mesh are selected by [`select_frame`](crate::select_frame) over the
//! instances the assignment gives them and those a technique hands back this frame
//! ([`TreeDraws::point_tree`]).
//!
//! What these selections read of a model is a [`Representations`], made once from its container
//! beside its [`ModelLod`]; triangles drawn whole (pruned leaves, bark, LoD chain levels) are
//! addressed in the model's *whole-triangle list* ([`Representations::from_container`] returns
//! it), which a renderer uploads as it is.
//!
//! **Determinism and threads.** Each selection splits its list into chunks of [`CHUNK`]
//! instances, selects the chunks in parallel (rayon) and appends their draws in list order, so
//! the draw lists are the same whatever the thread count; lists of one chunk or less run on the
//! calling thread. Per-instance state a selection keeps between frames (the pruned trees' held
//! `λ`) is read during the parallel part and written afterwards.

use glam::{Mat4, Vec3};
use rayon::prelude::*;
use treelod_format::{Container, TriangleRecord, material_class};

use crate::baseline::{BillboardRanges, Billboards, ChainRanges, ChainState, ChoicesCache, LodChain};
use crate::ellipsoid::{EllipsoidLod, LineLod};
use crate::frame::{Camera, CellPrefix, Instance, LodSettings, ModelLod, ROOTS_CELL};
use crate::impostor::{BARK_AREA_KEPT, ImpostorBark, PlaneLod, area};
use crate::policy::{Calibration, ChainPick, Policy};
use crate::prune::{PruneLod, PruneState, Pruning};
use crate::spt_lod::PixelLevel;
use crate::technique::{PerTechnique, Technique};

/// What the selection of each representation reads of one model, made once from its container
/// ([`Self::from_container`]). A renderer that cannot draw a representation it holds (an atlas
/// that does not decode) sets its field to `None`: its trees then go to [`Technique::FALLBACK`]
/// ([`Self::holds`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Representations {
    /// The centre of the container's block: where `τ` is measured for baselines and impostors'
    /// bark.
    pub block_centre: Vec3,
    /// The bark (non-leaf) triangles in the whole-triangle list: first and count. Pruned trees,
    /// and trees drawn with impostors or ellipsoids without lines, draw them.
    pub bark: (u32, u32),
    /// The leaf priority lists (pruning), if the container has them; their triangles lead the
    /// whole-triangle list.
    pub prune: Option<PruneLod>,
    /// The impostor planes, if the container has them.
    pub planes: Option<PlaneLod>,
    /// Clasen's ellipsoids, if the container has them.
    pub ellipsoids: Option<EllipsoidLod>,
    /// Clasen's branch lines, if the container has them.
    pub lines: Option<LineLod>,
    /// The baseline LoD chain and where its levels lie in the whole-triangle list, if the
    /// container has one.
    pub chain: Option<ChainRanges>,
    /// The baseline billboards (the facing quads, then the crossed ones), if the container has
    /// them.
    pub billboards: Option<BillboardRanges>,
    /// The baseline octahedral impostors (spec §6.13.1), one per tree: their count, 0 without.
    pub octahedral: u32,
}

impl Representations {
    /// What the selections need of `container`, and its whole-triangle list: `PRUNE_TRIANGLES`,
    /// then every bark triangle, then (with a LoD chain) the full mesh and each chain level with
    /// every tree's triangles, then (with a chain and impostor planes) the bark of the leading
    /// chain levels whose bark keeps [`BARK_AREA_KEPT`] of the full bark's area. Empty when the
    /// container has none of pruning, planes, ellipsoids or a chain.
    #[must_use]
    pub fn from_container(container: &Container) -> (Self, Vec<TriangleRecord>) {
        let block = container.block();
        let block_centre = 0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max));
        let prune = PruneLod::from_container(container);
        let planes = PlaneLod::from_container(container);
        let ellipsoids = EllipsoidLod::from_container(container);
        let lines = LineLod::from_container(container);
        let lod_chain = LodChain::from_container(container);
        let billboards = Billboards::from_container(container).as_ref().map(BillboardRanges::of);
        let octahedral = u32::try_from(container.octahedral().len()).unwrap_or(u32::MAX);
        let mut whole = Vec::new();
        let mut chain = None;
        let mut bark = (0, 0);
        if prune.is_some() || planes.is_some() || ellipsoids.is_some() || lod_chain.is_some() {
            let classes = container.materials();
            let is_bark =
                |t: &&TriangleRecord| classes.get(t.material as usize).is_none_or(|m| m.class != material_class::LEAF);
            whole.extend_from_slice(container.prune_triangles());
            let at = |whole: &Vec<TriangleRecord>| u32::try_from(whole.len()).unwrap_or(u32::MAX);
            let bark_first = at(&whole);
            whole.extend(container.triangles().iter().filter(is_bark));
            bark = (bark_first, at(&whole) - bark_first);
            if let Some(lod_chain) = lod_chain {
                let full_first = at(&whole);
                whole.extend_from_slice(container.triangles());
                let full = (full_first, at(&whole) - full_first);
                let mut levels = Vec::new();
                for level in lod_chain.levels() {
                    let first = at(&whole);
                    for range in &level.ranges {
                        whole.extend_from_slice(container.lod_triangles().get(range.as_usize()).unwrap_or_default());
                    }
                    levels.push((first, at(&whole) - first));
                }
                let mut bark_levels = Vec::new();
                if planes.is_some() || prune.is_some() {
                    let full_area = area(container.vertices(), &whole[bark.0 as usize..(bark.0 + bark.1) as usize]);
                    for level in lod_chain.levels() {
                        let first = at(&whole);
                        for range in &level.ranges {
                            let triangles = container.lod_triangles().get(range.as_usize()).unwrap_or_default();
                            whole.extend(triangles.iter().filter(is_bark));
                        }
                        // The levels that keep the bark's surface: a coarser one collapses
                        // branches that its error does not count.
                        let kept = area(container.vertices(), &whole[first as usize..]);
                        if kept < BARK_AREA_KEPT * full_area {
                            whole.truncate(first as usize);
                            break;
                        }
                        bark_levels.push((first, at(&whole) - first));
                    }
                }
                // The per-level tables, where the build measured them (spec §6.17).
                let calibration = Calibration::from_container(container).filter(|c| c.chain_levels() > 0);
                chain = Some(ChainRanges {
                    chain: lod_chain,
                    full,
                    levels,
                    bark_levels,
                    calibration,
                    choices: ChoicesCache::default(),
                });
            }
        }
        let representations =
            Self { block_centre, bark, prune, planes, ellipsoids, lines, chain, billboards, octahedral };
        (representations, whole)
    }

    /// Whether this model can be drawn with `technique` (else its trees go to
    /// [`Technique::FALLBACK`]): as [`Technique::held_by`] says of its container, less what the
    /// renderer dropped.
    #[must_use]
    pub fn holds(&self, technique: Technique) -> bool {
        match technique {
            Technique::Full | Technique::Spt => true,
            Technique::PruneOpt | Technique::PruneCook => self.prune.is_some(),
            Technique::Impostors => self.planes.is_some(),
            Technique::Ellipsoids => self.ellipsoids.is_some(),
            Technique::LodChain => self.chain.is_some(),
            Technique::Billboard => self.billboards.as_ref().is_some_and(|b| b.facing.1 > 0),
            Technique::Crossed => self.billboards.as_ref().is_some_and(|b| b.crossed.1 > 0),
            Technique::Octahedral => self.octahedral > 0,
        }
    }

    /// The draw of all this model's bark triangles for instance `instance` of model `model`
    /// (`lambda` is recorded with it), if it has any.
    #[must_use]
    pub fn bark_draw(&self, instance: u32, model: u32, lambda: f32) -> Option<TriangleDraw> {
        TriangleDraw::whole(instance, model, TriangleSource::Bark, self.bark, lambda, 1.0)
    }
}

/// Which instances each technique draws this frame: per technique, indices into the frame's
/// instance list, ascending, each instance in exactly one list.
///
/// This is where a choice of technique per tree plugs in: [`Self::assign`] asks a function for
/// each instance's technique and checks that its model holds the data. Today the renderer fills
/// it with its settings' one technique for every tree.
pub type Assignment = PerTechnique<Vec<u32>>;

impl PerTechnique<Vec<u32>> {
    /// Refills the assignment: instance `i` goes to `choose(i, instance)` if its model
    /// (`models[instance.model]`) holds that technique ([`Representations::holds`]), else to
    /// [`Technique::FALLBACK`]; instances of unknown models go nowhere.
    pub fn assign(
        &mut self,
        instances: &[Instance],
        models: &[Representations],
        mut choose: impl FnMut(usize, &Instance) -> Technique,
    ) {
        self.assign_listed(
            instances,
            models,
            instances
                .iter()
                .enumerate()
                .map(|(i, instance)| (u32::try_from(i).unwrap_or(u32::MAX), choose(i, instance))),
        );
    }

    /// Refills the assignment with only the `listed` instances, each `(index, technique)`: to
    /// that technique if its model holds it, else to [`Technique::FALLBACK`]; unknown instances
    /// and models go nowhere. Ascending indices give ascending lists (the renderer lists the
    /// techniques trees in a transition are leaving this way).
    pub fn assign_listed(
        &mut self,
        instances: &[Instance],
        models: &[Representations],
        listed: impl IntoIterator<Item = (u32, Technique)>,
    ) {
        self.list(|i| instances.get(i as usize).map(|instance| instance.model), models, listed);
    }

    /// [`Self::assign_listed`] with each instance's model given by `model_of` (`None`: an unknown
    /// instance).
    fn list(
        &mut self,
        model_of: impl Fn(u32) -> Option<u32>,
        models: &[Representations],
        listed: impl IntoIterator<Item = (u32, Technique)>,
    ) {
        for list in &mut self.0 {
            list.clear();
        }
        for (i, chosen) in listed {
            let Some(model) = model_of(i).and_then(|model| models.get(model as usize)) else {
                continue;
            };
            let technique = if model.holds(chosen) { chosen } else { Technique::FALLBACK };
            self[technique].push(i);
        }
    }

    /// [`Self::assign_listed`] of the instances whose `chosen[i]` is a technique (a chooser's
    /// output, [`crate::choose_instances_in_chunks`]; `None` goes nowhere), the same lists, made
    /// by chunks of instances on rayon's pool and joined in order: at 10^6 trees the listing
    /// was a fifth of the renderer's assignment, on one thread. `instance_models[i]` is
    /// instance `i`'s model ([`Instance::model`]): 4 bytes a tree read where an [`Instance`]
    /// takes 80, a cache line for each of up to 887k trees a frame of 10^6 willows
    /// (`docs/cli.md`).
    pub fn assign_chosen(&mut self, instance_models: &[u32], models: &[Representations], chosen: &[Option<Technique>]) {
        /// Instances per chunk: a few tens of microseconds of work.
        const CHUNK: usize = 1 << 14;
        let list = |first: usize, part: &[Option<Technique>], lists: &mut Self| {
            let listed = part.iter().enumerate().filter_map(|(k, t)| Some((u32::try_from(first + k).ok()?, (*t)?)));
            lists.list(|i| instance_models.get(i as usize).copied(), models, listed);
        };
        if chosen.len() <= CHUNK {
            list(0, chosen, self);
            return;
        }
        let parts: Vec<Self> = chosen
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(c, part)| {
                let mut lists = Self::default();
                list(c * CHUNK, part, &mut lists);
                lists
            })
            .collect();
        for technique in Technique::ALL {
            let list = &mut self[technique];
            list.clear();
            list.reserve(parts.iter().map(|p| p[technique].len()).sum());
            for part in &parts {
                list.extend_from_slice(&part[technique]);
            }
        }
    }

    /// The assignment of every instance to one technique (or, where its model lacks it, to
    /// [`Technique::FALLBACK`]).
    #[must_use]
    pub fn forced(technique: Technique, instances: &[Instance], models: &[Representations]) -> Self {
        let mut assignment = Self::default();
        assignment.assign(instances, models, |_, _| technique);
        assignment
    }
}

/// The models and instances a view's selections read.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'a> {
    /// Per model: its point tree (culling spheres).
    pub lods: &'a [ModelLod],
    /// Per model: its representations.
    pub models: &'a [Representations],
    /// The frame's instances; assignments index them.
    pub instances: &'a [Instance],
}

impl Scene<'_> {
    /// Instance `index` with its model's point tree and representations, if the model exists.
    #[must_use]
    pub fn get(&self, index: u32) -> Option<(&Instance, &ModelLod, &Representations)> {
        let instance = self.instances.get(index as usize)?;
        let m = instance.model as usize;
        Some((instance, self.lods.get(m)?, self.models.get(m)?))
    }
}

/// What a draw of whole-tree triangles holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TriangleSource {
    /// A prefix of one cell's pruned leaves.
    PrunedLeaves,
    /// All bark triangles of the model (or those of a LoD chain level).
    Bark,
    /// A LoD chain level (or the full mesh) of the whole block.
    LodLevel,
}

/// One draw of triangles of a model's whole-triangle list: one cell's pruned leaves, the bark,
/// or a LoD chain level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleDraw {
    /// Index of the instance.
    pub instance: u32,
    /// Its model.
    pub model: u32,
    /// Container cell, or [`ROOTS_CELL`] for the whole tree.
    pub cell: u32,
    /// What is drawn.
    pub source: TriangleSource,
    /// Into the whole-triangle list.
    pub first: u32,
    /// Triangles drawn.
    pub count: u32,
    /// The pruned tree's `λ` (1 for the rest).
    pub lambda: f32,
    /// Size factor of pruned leaves about their centres (1 for the rest).
    pub leaf_scale: f32,
    /// What a renderer reports as the draw's triangle threshold: `leaf_scale`, or a chain
    /// level's error (metres, model space).
    pub tau_triangles: f32,
}

impl TriangleDraw {
    /// A draw of the triangles `first, count` for the whole tree (cell [`ROOTS_CELL`]), if
    /// there are any; `lambda` and `tau_triangles` are recorded with it.
    #[must_use]
    pub fn whole(
        instance: u32,
        model: u32,
        source: TriangleSource,
        (first, count): (u32, u32),
        lambda: f32,
        tau_triangles: f32,
    ) -> Option<Self> {
        (count > 0).then_some(Self {
            instance,
            model,
            cell: ROOTS_CELL,
            source,
            first,
            count,
            lambda,
            leaf_scale: 1.0,
            tau_triangles,
        })
    }
}

/// One draw of impostor planes, ellipsoids or lines: a prefix of one cell's elements for one
/// instance, and the `τ` the vertex stage tests them with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrefixDraw {
    /// Index of the instance.
    pub instance: u32,
    /// Its model.
    pub model: u32,
    /// The cell's prefix.
    pub range: CellPrefix,
}

/// One draw of billboard quads: `count` quads from `first` of the model's billboard list
/// ([`BillboardRanges`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QuadDraw {
    /// Index of the instance.
    pub instance: u32,
    /// Its model.
    pub model: u32,
    /// First quad.
    pub first: u32,
    /// Quads drawn.
    pub count: u32,
}

/// The draw lists of one view's representations other than the point tree, and what their
/// selections counted. Each list is in the order of the assignment's techniques, each
/// technique's draws in instance order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TreeDraws {
    /// Whole-tree triangles: pruned leaves, bark, LoD chain levels.
    pub triangles: Vec<TriangleDraw>,
    /// Impostor planes.
    pub planes: Vec<PrefixDraw>,
    /// Ellipsoids.
    pub ellipsoids: Vec<PrefixDraw>,
    /// Branch lines.
    pub lines: Vec<PrefixDraw>,
    /// Billboard quads.
    pub billboards: Vec<QuadDraw>,
    /// Octahedral impostors' quads.
    pub octahedral: Vec<QuadDraw>,
    /// Instances a technique hands to the point tree this frame, ascending (pruned trees below
    /// their projected height).
    pub point_tree: Vec<u32>,
    /// Pruned instances whose hull samples the occlusion test should measure (the camera's view
    /// only, with occlusion on), ascending.
    pub occlusion: Vec<u32>,
    /// Instances inside the view frustum per technique.
    pub visible: PerTechnique<u32>,
    /// Leaves drawn by pruned instances.
    pub leaves_pruned: u64,
}

impl TreeDraws {
    /// Empties every list and count (keeping their allocations).
    pub fn clear(&mut self) {
        self.triangles.clear();
        self.planes.clear();
        self.ellipsoids.clear();
        self.lines.clear();
        self.billboards.clear();
        self.octahedral.clear();
        self.point_tree.clear();
        self.occlusion.clear();
        self.visible = PerTechnique::default();
        self.leaves_pruned = 0;
    }

    /// Appends `other`'s lists and adds its counts.
    pub fn append(&mut self, other: &mut Self) {
        self.triangles.append(&mut other.triangles);
        self.planes.append(&mut other.planes);
        self.ellipsoids.append(&mut other.ellipsoids);
        self.lines.append(&mut other.lines);
        self.billboards.append(&mut other.billboards);
        self.octahedral.append(&mut other.octahedral);
        self.point_tree.append(&mut other.point_tree);
        self.occlusion.append(&mut other.occlusion);
        self.visible += other.visible;
        self.leaves_pruned += other.leaves_pruned;
    }
}

/// Instances per parallel task of a selection: a tree costs these selections from a fraction of
/// a microsecond (a baseline's one `τ`) to a few (a pruned tree's cells), so a task of a few
/// hundred trees outweighs rayon's cost of a task, and a scene of a few hundred trees stays on
/// the calling thread. Not tuned by measurement yet.
pub const CHUNK: usize = 512;

/// The draw lists of [`select_into`]'s chunks between selections, emptied, their allocations
/// kept: one pool for the process (a selection takes it once and gives it back once).
static CHUNK_POOL: std::sync::Mutex<Vec<TreeDraws>> = std::sync::Mutex::new(Vec::new());

/// Runs `select` over `list` in chunks of [`CHUNK`] instances, in parallel when there is more
/// than one, appending each chunk's draws to `out` in list order: a list of one chunk is
/// selected into `out` itself, and the chunks' lists of a longer one come
/// from (and go back to) a pool kept between selections, so a frame's chunks push into memory
/// earlier frames grew instead of fresh pages the kernel must zero. Measured on the orchid's
/// 10^6 trees with every representation (`bench --trees 1000000 --frames 30 --technique policy
/// --no-render`, 2 cores, four runs each, alternating; 348,000 trees a frame drawn with planes
/// and branch lines, selected here): the `select` phase 34.66–35.05 → 29.36–30.90 ms, `prepare`
/// (mean) 64.65–65.98 → 59.50–62.39 ms, system time 0.81–0.94 → 0.68–0.75 s, peak memory
/// 918 → 930–977 MB (the pool's lists), the same draws.
pub(crate) fn select_into(list: &[u32], out: &mut TreeDraws, select: impl Fn(&[u32], &mut TreeDraws) + Sync) {
    // `Vec<()>` never allocates.
    select_into_with(list, out, &mut Vec::<()>::new(), |chunk, draws, _| select(chunk, draws));
}

/// [`select_into`] for a selection whose chunks also push per-instance records of their own
/// (the state a selection holds between frames: a chain's levels, a pruned tree's `λ`), appended
/// to `extra` in list order. Those records are far smaller than the draws: each chunk's list of
/// them is its own, allocated only when it pushes one. The baseline (chain, billboards,
/// octahedral) and pruned selections pool their draws so too: on the same orchid flight
/// (170,000 octahedral and 28,000 billboard trees a frame; four runs each, alternating) `select`
/// 29.29–30.66 → 28.49–28.84 ms, peak memory 930 → 948–950 MB, the same draws.
pub(crate) fn select_into_with<X: Send>(
    list: &[u32],
    out: &mut TreeDraws,
    extra: &mut Vec<X>,
    select: impl Fn(&[u32], &mut TreeDraws, &mut Vec<X>) + Sync,
) {
    if list.len() <= CHUNK {
        select(list, out, extra);
        return;
    }
    let count = list.len().div_ceil(CHUNK);
    // The pool holds emptied lists only: one a panicking selection left is still usable.
    let lock = || CHUNK_POOL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let mut chunks = {
        let mut pool = lock();
        let keep = pool.len().saturating_sub(count);
        pool.split_off(keep)
    };
    chunks.resize_with(count, TreeDraws::default);
    let mut extras: Vec<Vec<X>> = Vec::new();
    extras.resize_with(count, Vec::new);
    list.par_chunks(CHUNK)
        .zip(chunks.par_iter_mut())
        .zip(extras.par_iter_mut())
        .for_each(|((chunk, draws), extra)| select(chunk, draws, extra));
    for (chunk, mut records) in chunks.iter_mut().zip(extras) {
        out.append(chunk);
        chunk.clear();
        extra.append(&mut records);
    }
    lock().append(&mut chunks);
}

/// The largest axis scale of an affine transform (what selection converts sizes with).
#[must_use]
pub fn max_axis_scale(m: Mat4) -> f32 {
    let (x, y, z) = (m.x_axis.truncate(), m.y_axis.truncate(), m.z_axis.truncate());
    x.length_squared().max(y.length_squared()).max(z.length_squared()).sqrt().max(1e-12)
}

/// Merges ascending lists of distinct instance indices into `out` (cleared first), ascending.
pub fn merge_ascending(lists: &[&[u32]], out: &mut Vec<u32>) {
    out.clear();
    for list in lists {
        out.extend_from_slice(list);
    }
    if lists.iter().filter(|l| !l.is_empty()).count() > 1 {
        out.sort_unstable();
    }
}

/// What the representations' selections read of a renderer's settings, per view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TechniqueSettings {
    /// The pixel threshold of impostor planes and baselines.
    pub s_min: f32,
    /// The point tree's settings, which ellipsoids and lines select with (their `τ` and depth
    /// bias).
    pub lod: LodSettings,
    /// Which trees are pruned and by how much.
    pub pruning: Pruning,
    /// The bark of trees drawn with impostor planes.
    pub impostor_bark: ImpostorBark,
    /// How ellipsoids and lines pick their levels.
    pub pixel_level: PixelLevel,
    /// Whether ellipsoid trees draw their bark as lines (where their models have lines).
    pub lines: bool,
    /// The policy whose target and hysteresis choose the LoD chain's level by image error where
    /// a model has per-level tables ([`crate::baseline::select`]); the renderer's policy, else
    /// [`Policy::default`].
    pub chain_policy: Policy,
    /// Whether the assignment's lists hold only trees whose culling sphere meets the camera's
    /// frustum, as the policy's chooser leaves them for the camera it chose with
    /// ([`crate::choose_instances`]): the billboards' and octahedral impostors' selections then
    /// take each tree without testing it again ([`crate::baseline::select`]).
    pub culled: bool,
}

/// Selects one view of every technique but the point tree and the full mesh: appends to `out`
/// (not cleared) the draws of each technique's selection over its list of `assignment`, in
/// [`Technique::ALL`] order. `prune_state`: the camera's view's pruning state (see
/// [`prune::select`](crate::prune::select)); `chain_state`: the camera's view's LoD chain levels
/// (see [`baseline::select`](crate::baseline::select)), or those the trees leaving the chain in a
/// transition hold ([`ChainState::hold`]); `None` for other views (shadow cascades).
///
/// The point tree's trees are then `assignment`'s [`Technique::Full`] and [`Technique::Spt`]
/// lists and `out`'s [`TreeDraws::point_tree`] ([`merge_ascending`]), for
/// [`select_frame`](crate::select_frame).
pub fn select_techniques(
    scene: &Scene<'_>,
    assignment: &Assignment,
    camera: &Camera,
    settings: &TechniqueSettings,
    mut prune_state: Option<PruneState<'_>>,
    mut chain_state: Option<ChainState<'_>>,
    out: &mut TreeDraws,
) {
    // A tree not drawn with the chain this frame forgets its level (`ChainState`: `None`), so
    // one that comes back picks afresh rather than holding a level from frames ago.
    if let Some(state) = chain_state.as_mut().filter(|s| !s.hold) {
        let kept: Vec<(usize, Option<ChainPick>)> = assignment[Technique::LodChain]
            .iter()
            .map(|&i| (i as usize, state.previous.get(i as usize).copied().flatten()))
            .collect();
        state.previous.fill(None);
        for (i, level) in kept {
            if let Some(slot) = state.previous.get_mut(i) {
                *slot = level;
            }
        }
    }
    for technique in Technique::ALL {
        let list = &assignment[technique];
        if list.is_empty() {
            continue;
        }
        match technique {
            Technique::Full | Technique::Spt => {}
            Technique::PruneOpt | Technique::PruneCook => {
                let state = prune_state
                    .as_mut()
                    .map(|s| PruneState { shown: &mut *s.shown, visible_fraction: s.visible_fraction });
                crate::prune::select(scene, list, technique, settings, camera, state, out);
            }
            Technique::Impostors => {
                crate::impostor::select(scene, list, camera, settings, out);
            }
            Technique::Ellipsoids => {
                let (level, lines) = (settings.pixel_level, settings.lines);
                crate::ellipsoid::select(scene, list, camera, &settings.lod, level, lines, out);
            }
            Technique::LodChain | Technique::Billboard | Technique::Crossed | Technique::Octahedral => {
                let state = chain_state.as_mut().map(|s| ChainState { previous: &mut *s.previous, hold: s.hold });
                crate::baseline::select(scene, list, technique, camera, settings, state, out);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use treelod_build::{
        BuildConfig, DemoTreeConfig, EllipsoidConfig, ImpostorConfig, LineConfig, LodChainConfig, Placed, PruneConfig,
        build_block, demo_tree,
    };
    use treelod_format::Compression;

    fn demo(config: &BuildConfig) -> Container {
        let scene = demo_tree(&DemoTreeConfig { leaves: 300, ..DemoTreeConfig::default() });
        let built = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], config, "t").unwrap();
        Container::from_bytes(&built.data.to_bytes(Compression::None).unwrap()).unwrap()
    }

    /// A chooser's output listed by chunks in parallel gives the lists one pass gives, in
    /// order: techniques a model lacks to the fallback, unknown models and unchosen trees
    /// nowhere, over more instances than a chunk holds.
    #[test]
    fn chosen_trees_listed_by_chunks_are_listed_as_in_one_pass() {
        let container = demo(&BuildConfig { baselines: Some(LodChainConfig::default()), ..BuildConfig::default() });
        let models = [Representations::default(), Representations::from_container(&container).0];
        let instances: Vec<Instance> =
            (0..40_000u32).map(|i| Instance { model: i % 3, transform: Mat4::IDENTITY }).collect();
        let mut rng = 7u64;
        let chosen: Vec<Option<Technique>> = (0..instances.len())
            .map(|_| {
                rng = rng.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                let pick = (rng >> 33) as usize % (Technique::COUNT + 1);
                Technique::ALL.get(pick).copied()
            })
            .collect();
        let mut one_pass = Assignment::default();
        let listed = chosen.iter().enumerate().filter_map(|(i, t)| Some((u32::try_from(i).ok()?, (*t)?)));
        one_pass.assign_listed(&instances, &models, listed);
        let mut by_chunks = Assignment::default();
        by_chunks[Technique::Spt].push(3);
        let instance_models: Vec<u32> = instances.iter().map(|i| i.model).collect();
        by_chunks.assign_chosen(&instance_models, &models, &chosen);
        assert_eq!(by_chunks, one_pass);
        assert!(one_pass[Technique::LodChain].len() > 1000 && one_pass[Technique::FALLBACK].len() > 1000);
        assert!(one_pass[Technique::Ellipsoids].is_empty(), "no model holds ellipsoids");
    }

    /// The camera's view keeps a LoD chain level only for the trees drawn with the chain: one
    /// drawn with another technique forgets its level, so coming back it picks afresh instead of
    /// holding, by hysteresis, a level from frames ago.
    #[test]
    fn a_tree_not_drawn_with_the_chain_forgets_its_level() {
        let container = demo(&BuildConfig { baselines: Some(LodChainConfig::default()), ..BuildConfig::default() });
        let models = [Representations::from_container(&container).0];
        let lods = [ModelLod::from_container(&container)];
        let instances: Vec<Instance> = (0..2)
            .map(|i| Instance { model: 0, transform: Mat4::from_translation(Vec3::new(i as f32 * 10.0, 0.0, -30.0)) })
            .collect();
        let camera = Camera::look_at(Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0), 1.0, 640, 480);
        let scene = Scene { lods: &lods, models: &models, instances: &instances };
        let settings = TechniqueSettings {
            s_min: 1.0,
            lod: LodSettings::default(),
            pruning: Pruning::default(),
            impostor_bark: ImpostorBark::default(),
            pixel_level: PixelLevel { quality: 1.0, blend: 0.5 },
            lines: true,
            chain_policy: Policy::default(),
            culled: false,
        };
        let mut assignment = Assignment::default();
        assignment.assign(&instances, &models, |i, _| if i == 0 { Technique::LodChain } else { Technique::Spt });
        let mut previous = vec![Some(Some(1)), Some(Some(1))];
        let state = ChainState { previous: &mut previous, hold: false };
        select_techniques(&scene, &assignment, &camera, &settings, None, Some(state), &mut TreeDraws::default());
        assert_eq!(previous[1], None, "tree 1 went to the point tree: its level is forgotten");
        assert_eq!(previous[0].is_some(), models[0].chain.as_ref().is_some_and(|c| c.calibration.is_some()));
    }

    /// Every technique over a forest of three chunks, a seventh of its trees of a model with no
    /// optional data: the assignment sends those to the point tree, and the draw lists and the
    /// held `λ` are the same on one thread and on four.
    #[test]
    fn every_technique_selects_the_same_draws_whatever_the_thread_count() {
        let config = BuildConfig {
            prune: Some(PruneConfig { resolution: 64, views: 2, ..PruneConfig::default() }),
            impostors: Some(ImpostorConfig::default()),
            ellipsoids: Some(EllipsoidConfig::default()),
            lines: Some(LineConfig::default()),
            baselines: Some(LodChainConfig::default()),
            ..BuildConfig::default()
        };
        let containers = [demo(&config), demo(&BuildConfig::default())];
        let models: Vec<Representations> = containers.iter().map(|c| Representations::from_container(c).0).collect();
        let lods: Vec<ModelLod> = containers.iter().map(ModelLod::from_container).collect();
        let instances: Vec<Instance> = (0..3 * CHUNK)
            .map(|i| Instance {
                model: u32::from(i % 7 == 0),
                transform: Mat4::from_translation(Vec3::new(
                    (i % 48) as f32 * 10.0 - 240.0,
                    0.0,
                    -((i / 48) as f32) * 10.0,
                )),
            })
            .collect();
        let camera = Camera::look_at(Vec3::new(5.0, 2.0, -15.0), Vec3::new(5.0, 2.0, -200.0), 1.0, 640, 480);
        let scene = Scene { lods: &lods, models: &models, instances: &instances };
        let settings = TechniqueSettings {
            s_min: 1.0,
            lod: LodSettings::default(),
            // The far trees go to the point tree.
            pruning: Pruning { spt_below_pixels: 16.0, ..Pruning::default() },
            impostor_bark: ImpostorBark::default(),
            pixel_level: PixelLevel { quality: 1.0, blend: 0.5 },
            lines: true,
            chain_policy: Policy::default(),
            culled: false,
        };
        for technique in Technique::ALL {
            let assignment = Assignment::forced(technique, &instances, &models);
            assert_eq!(assignment.0.iter().map(Vec::len).sum::<usize>(), instances.len(), "{technique}");
            if technique.needs().is_some() {
                let bare = instances.iter().filter(|i| i.model == 1).count();
                assert!(assignment[Technique::FALLBACK].len() >= bare, "{technique}");
            }
            let select = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                pool.install(|| {
                    let mut shown = vec![None; instances.len()];
                    let visible_fraction = vec![1.0; instances.len()];
                    let state = PruneState { shown: &mut shown, visible_fraction: &visible_fraction };
                    let mut levels = vec![None; instances.len()];
                    let chain = ChainState { previous: &mut levels, hold: false };
                    let mut out = TreeDraws::default();
                    select_techniques(&scene, &assignment, &camera, &settings, Some(state), Some(chain), &mut out);
                    (out, shown, levels)
                })
            };
            let (one, four) = (select(1), select(4));
            assert_eq!(one, four, "{technique}");
            if models[0].holds(technique) && technique.needs().is_some() {
                assert!(one.0.visible.get(technique) > 0, "{technique}: {:?}", one.0.visible);
            }
        }
    }
}
