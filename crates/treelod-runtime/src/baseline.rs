//! Baselines at run time (spec §6.12, §6.13): what a user would draw instead of treelod, chosen
//! by the same pixel threshold, so that tools can compare both on one file.
//!
//! A discrete level-of-detail chain switches per instance. Where the container holds the chain's
//! per-level calibration tables (`CHAIN_CALIBRATION`, spec §6.17), the level is chosen by image
//! error, as the policy chooses representations (spec §10.2): at the tree's projected height
//! `h`, the full mesh or the level of fewest primitives whose calibrated error is within the
//! policy's target of the policy's floor ([`Calibration::chain_level`]), looked up in a table per
//! model and policy ([`ChainChoices`]) with the policy's hysteresis on the camera's view (a tree
//! keeps last frame's level while that level is still the choice within
//! [`Policy::hysteresis`](crate::Policy::hysteresis) octaves of `h`). Below the calibrated range the smallest
//! height's level holds; above it the finer of the largest height's level and the geometric
//! rule's, so that near trees converge to the full mesh as the geometric rule makes them. This
//! holds whether the policy chose the chain for the tree or the chain was forced.
//!
//! Without those tables (files before 1.8, or built without calibration) [`LodChain::pick`]
//! returns the coarsest level whose geometric error projects below `s_min` pixels at the block
//! centre's distance (the `τ_p` of spec §10.1, the threshold that chooses treelod's own points),
//! or the full mesh when even the finest level's error is larger. meshoptimizer's error says
//! little about the image: it is one-sided (a removed leaf card counts for its own size, not for
//! the hole it leaves), and its scale is not the image's: the shared oak's finest level (3.1 m
//! of its 102 m) projects over a pixel on a tree more than about 33 pixels high, so the
//! geometric rule drew the full mesh there, and its coarsest (5.1 m) under a pixel below about
//! 20 pixels. Measured with `treelod eval --orbit
//! 2,8,32 --technique lod-chain` (640×480, means of 8 views; tables in shaded colour from 7
//! views): at 8 bounding radii the oak drew 22,566 triangles by geometric error and 11,113 by
//! image error (RMSE 0.0117 and 0.0119), the pine 19,384 and 9,677 (0.0056 and 0.0059), the
//! Quaternius tree 2,888 and 1,444 (0.0017 and 0.0027, FLIP 0.0007 and 0.0017: in its tables
//! level 0 reads 0.0140 at 64 pixels against the full mesh's 0.0098, within the default target
//! of 0.01); at 32 radii the oak 220 and 5,475 triangles (0.0069 and 0.0059), the pine 191 and
//! 4,723 (0.0056 and 0.0050).
//!
//! A block of several trees switches all of its trees together (at level `ℓ` it draws every
//! tree's level `ℓ`, the block's error being the largest of theirs): the container's `TRIANGLES`
//! are not split by tree, and the full mesh is the block's. Billboards need no choice: the
//! instance draws its billboard quads.
//!
//! [`select`] is the baselines' per-frame selection: the draws of the trees assigned to one of
//! them (see [`crate::draws`]).

use std::sync::{Arc, Mutex, PoisonError};

use glam::{Mat4, Vec3};
use treelod_format::{Container, LodLevelRecord, Range, billboard_kind};

#[cfg(doc)]
use crate::draws::Representations;
use crate::draws::{QuadDraw, Scene, TechniqueSettings, TreeDraws, TriangleDraw, TriangleSource, select_into_with};
use crate::frame::{Camera, Frustum, tau_per_metre, usable_scale};
#[cfg(doc)]
use crate::impostor::ImpostorBark;
use crate::policy::{
    Calibration, ChainChoices, ChainPick, Choices, Policy, TablesKey, TreeDither, projected_height_at,
};
use crate::technique::Technique;

/// One level of a block's chain: every tree's level of that number.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainLevel {
    /// The largest error of the trees' levels, metres, model space.
    pub error: f32,
    /// The trees' triangle ranges in `LOD_TRIANGLES`, in tree order.
    pub ranges: Vec<Range>,
}

/// A container's LoD chain, made once.
#[derive(Clone, Debug, PartialEq)]
pub struct LodChain {
    levels: Vec<ChainLevel>,
}

impl LodChain {
    /// The chain of an open container; `None` if it has none.
    ///
    /// A level number missing for some tree (verified files have none) ends the chain there, so
    /// every level covers every tree that has a chain.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        Self::from_records(container.lod_levels())
    }

    /// The chain of `records` (a container's `LOD_LEVELS`), as [`Self::from_container`] makes it.
    #[must_use]
    pub fn from_records(records: &[LodLevelRecord]) -> Option<Self> {
        let depth = records.iter().map(|l| l.level.saturating_add(1)).max()?;
        let trees = {
            let mut trees: Vec<u32> = records.iter().map(|l| l.tree).collect();
            trees.dedup();
            trees.len()
        };
        let mut levels = Vec::new();
        for level in 0..depth {
            let of_level: Vec<_> = records.iter().filter(|l| l.level == level).collect();
            if of_level.len() != trees {
                break;
            }
            let error = of_level.iter().map(|l| l.error).fold(0.0f32, f32::max);
            levels.push(ChainLevel { error, ranges: of_level.iter().map(|l| l.triangles).collect() });
        }
        // Errors are non-decreasing per tree (spec §6.12), so their maximum is too; keep it so
        // even for a file that breaks the rule, so `pick` can search.
        let mut running = 0.0f32;
        for level in &mut levels {
            running = running.max(level.error);
            level.error = running;
        }
        (!levels.is_empty()).then_some(Self { levels })
    }

    /// The levels, finest first.
    #[must_use]
    pub fn levels(&self) -> &[ChainLevel] {
        &self.levels
    }

    /// The level drawn at the world-size threshold `tau` (metres, model space): the coarsest whose
    /// error is at most `tau`, or `None` for the full mesh.
    #[must_use]
    pub fn pick(&self, tau: f32) -> Option<u32> {
        let usable = self.levels.partition_point(|l| l.error <= tau);
        usable.checked_sub(1).and_then(|l| u32::try_from(l).ok())
    }
}

/// `τ` (metres, model space) of an instance for `camera` at `s_min` pixels, measured at the
/// model-space point `anchor` (spec §10.1), and whether its sphere `(centre, radius)` (model
/// space) meets `frustum`. `None` if it does not, or if the transform is degenerate.
#[must_use]
pub fn instance_tau(
    transform: Mat4,
    camera: &Camera,
    frustum: &Frustum,
    s_min: f32,
    (centre, radius): (Vec3, f32),
    anchor: Vec3,
) -> Option<f32> {
    let per_metre = tau_per_metre(transform, camera, frustum, s_min, (centre, radius))?;
    Some(transform.transform_point3(anchor).distance(camera.position) * per_metre)
}

/// Which billboard a baseline draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BillboardKind {
    /// One quad per tree turned towards the camera about the vertical.
    Facing,
    /// Fixed quads crossing on the tree's vertical axis.
    Crossed,
}

impl BillboardKind {
    /// The record value of spec §6.13.
    #[must_use]
    pub fn record_kind(self) -> u32 {
        match self {
            Self::Facing => billboard_kind::FACING,
            Self::Crossed => billboard_kind::CROSSED,
        }
    }
}

/// A container's billboards, by kind: the record indices of each kind, in file order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Billboards {
    /// Indices into `BILLBOARDS` of the facing quads.
    pub facing: Vec<u32>,
    /// Indices of the crossed quads.
    pub crossed: Vec<u32>,
}

impl Billboards {
    /// The billboards of an open container; `None` if it has none.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        let records = container.billboards();
        if records.is_empty() {
            return None;
        }
        let mut out = Self::default();
        for (i, b) in records.iter().enumerate() {
            let Ok(i) = u32::try_from(i) else { break };
            match b.kind {
                billboard_kind::FACING => out.facing.push(i),
                billboard_kind::CROSSED => out.crossed.push(i),
                _ => {}
            }
        }
        Some(out)
    }

    /// The record indices of one kind.
    #[must_use]
    pub fn of(&self, kind: BillboardKind) -> &[u32] {
        match kind {
            BillboardKind::Facing => &self.facing,
            BillboardKind::Crossed => &self.crossed,
        }
    }
}

/// Where a model's LoD chain lies in its whole-triangle list
/// ([`Representations::from_container`]), with the chain itself.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainRanges {
    /// The chain's levels and errors.
    pub chain: LodChain,
    /// Every triangle of the container (the full mesh): first and count.
    pub full: (u32, u32),
    /// Per level, every tree's triangles of that level, contiguous: first and count.
    pub levels: Vec<(u32, u32)>,
    /// Per level, the bark (non-leaf) triangles of `levels`, for trees drawn with impostor
    /// planes or pruned ([`ImpostorBark::Chain`]): the leading levels whose bark keeps
    /// [`BARK_AREA_KEPT`](crate::impostor::BARK_AREA_KEPT) of the full bark's area; empty
    /// without planes and priority lists.
    pub bark_levels: Vec<(u32, u32)>,
    /// The model's calibration tables where they hold the chain's per-level tables
    /// (`CHAIN_CALIBRATION`, spec §6.17): the chain's level is then chosen by image error
    /// ([`select`]); `None`: by geometric error ([`LodChain::pick`]). Set it before the chain
    /// is selected with: [`Self::choices`] keeps what it made from it.
    pub calibration: Option<Calibration>,
    /// The last levels by image error made from `calibration` ([`Self::choices`]).
    pub(crate) choices: ChoicesCache,
}

/// A chain's levels by image error under the last [`CACHED_POLICIES`] policies they were made
/// for, the most recent last: [`select`] runs every frame and for every shadow cascade, and the
/// table (a few dozen steps of [`Calibration::chain_level`]) changes only with the policy; budget
/// mode's predictions ask for the targets next to the one drawn, and back. A cache, not state:
/// two chains compare equal whatever it holds.
#[derive(Default)]
pub(crate) struct ChoicesCache(Mutex<Vec<(TablesKey, Option<Arc<ChainChoices>>)>>);

/// How many policies' tables of choices a chain keeps ([`ChainRanges::choices`]; the renderer's
/// tables of representations keep as many).
pub const CACHED_POLICIES: usize = 8;

impl ChoicesCache {
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<(TablesKey, Option<Arc<ChainChoices>>)>> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Clone for ChoicesCache {
    /// An empty cache: the clone's calibration may be changed before it is read.
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl PartialEq for ChoicesCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for ChoicesCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ChoicesCache")
    }
}

impl ChainRanges {
    /// The error of level `level`, metres (0 past the chain).
    #[must_use]
    pub fn level_error(&self, level: usize) -> f32 {
        self.chain.levels().get(level).map_or(0.0, |l| l.error)
    }

    /// The chain's levels by image error under `policy` ([`ChainChoices::new`] over the
    /// techniques `usable` accepts, which must not change between calls: the model's), made on
    /// the first call with that policy and kept while it is among the last [`CACHED_POLICIES`]
    /// asked for (in budget mode, every target within one cell of the lattice of targets shares
    /// them, [`Choices::tables_key`]); `None` without per-level tables.
    pub fn choices(&self, policy: &Policy, usable: impl Fn(Technique) -> bool) -> Option<Arc<ChainChoices>> {
        let calibration = self.calibration.as_ref()?;
        let key = Choices::tables_key(policy);
        let mut cache = self.choices.lock();
        if let Some(at) = cache.iter().rposition(|(made_for, _)| *made_for == key) {
            let entry = cache.remove(at);
            let choices = entry.1.clone();
            cache.push(entry);
            return choices;
        }
        let choices = ChainChoices::new(calibration, policy, usable).map(Arc::new);
        if cache.len() >= CACHED_POLICIES {
            cache.remove(0);
        }
        cache.push((key, choices.clone()));
        choices
    }
}

/// Where a model's billboards lie in its billboard list: the facing quads ([`Billboards::facing`]
/// in file order), then the crossed ones; first and count each.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BillboardRanges {
    /// The facing quads.
    pub facing: (u32, u32),
    /// The crossed quads.
    pub crossed: (u32, u32),
}

impl BillboardRanges {
    /// The ranges of `billboards` in the list facing-then-crossed.
    #[must_use]
    pub fn of(billboards: &Billboards) -> Self {
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        Self {
            facing: (0, count(billboards.facing.len())),
            crossed: (count(billboards.facing.len()), count(billboards.crossed.len())),
        }
    }
}

/// Per instance, the LoD chain's level it was drawn with last frame on the camera's view
/// (`None`: not drawn with the chain by image error), for the hysteresis of [`select`].
pub struct ChainState<'a> {
    /// Per instance: last frame's level, updated by [`select`] (unless [`Self::hold`]).
    pub previous: &'a mut [Option<ChainPick>],
    /// The trees draw the level [`Self::previous`] holds for them, where it holds one, and
    /// nothing is written: trees leaving the chain in a transition (`Policy::transition`),
    /// which fade out as they were drawn. Picked again, a near tree above the calibration
    /// tables' heights takes its level by geometric error at the frame's `s_min`, and where
    /// budget mode lowered `s_min` the fading tree drew its full mesh (the shared maple, 1,000
    /// trees, `bench --budget 100000`: 324,000 triangles of trees leaving the chain in a frame).
    pub hold: bool,
}

/// Whether a tree the policy's chooser found in the camera's view (`TechniqueSettings::culled`)
/// is in view for its quads' selection ([`select`]) without testing it again: the chooser's
/// sphere test is the selection's for any transform whose largest axis scale is at least the
/// floor the chooser's scale takes (`1e-12`); a tree of a smaller or unusable scale is tested
/// again. A renderer that hands such trees' quads to the GPU without selecting them on the CPU
/// asks this to draw the same trees.
#[must_use]
pub fn chosen_in_view(transform: Mat4) -> bool {
    usable_scale(transform).is_some_and(|scale| scale >= 1e-12)
}

/// The trees of `list` drawn with the baseline `baseline` ([`Technique::LodChain`],
/// [`Technique::Billboard`], [`Technique::Crossed`] or [`Technique::Octahedral`]; every model of
/// `list` holds it, see
/// [`Representations::holds`]): appends to `out` a LoD chain draw (module docs: the level by image
/// error where the model has per-level tables, with `settings.chain_policy`'s target and
/// hysteresis (in budget mode each tree at its own height factor and lattice target,
/// [`TreeDither`], as its technique was chosen) and `state`'s last levels, else the coarsest
/// level whose error projects below
/// `settings.s_min` pixels at the block centre, [`LodChain::pick`], or the full mesh), the
/// billboard quads or the octahedral impostors of each instance inside the frustum, and counts
/// them visible. `state`: the
/// camera's view's levels (`None` for shadow cascades: no hysteresis).
pub fn select(
    scene: &Scene<'_>,
    list: &[u32],
    baseline: Technique,
    camera: &Camera,
    settings: &TechniqueSettings,
    state: Option<ChainState<'_>>,
    out: &mut TreeDraws,
) {
    let s_min = settings.s_min;
    let frustum = Frustum::from_view_proj(camera.view_proj);
    let world_per_pixel = camera.world_per_pixel();
    // Per model, its levels by image error under the policy (made once per policy).
    // In budget mode each tree's level is chosen at its own height factor and target class,
    // as its technique was ([`TreeDither`]).
    let dither = TreeDither::of(&settings.chain_policy);
    let choices: Vec<Option<Arc<ChainChoices>>> = if baseline == Technique::LodChain {
        scene.models.iter().map(|m| m.chain.as_ref()?.choices(&settings.chain_policy, |t| m.holds(t))).collect()
    } else {
        Vec::new()
    };
    let hold = state.as_ref().is_some_and(|s| s.hold);
    let main = state.is_some() && !hold;
    let previous: &[Option<ChainPick>] = state.as_ref().map_or(&[], |s| &*s.previous);
    // Quads need no `τ`; where the chooser culled the list with this camera, only the
    // transforms it could not have tested as this selection does are tested again.
    let trusted = settings.culled && baseline != Technique::LodChain;
    // The chain levels of the camera's view's instances, written once every chunk has read them.
    let mut levels: Vec<(u32, Option<ChainPick>)> = Vec::new();
    select_into_with(list, out, &mut levels, |chunk, draws, levels| {
        for &index in chunk {
            let Some((instance, lod, model)) = scene.get(index) else { continue };
            // The chooser's sphere test is this one for a scale of at least its floor
            // (`max_axis_scale`'s 1e-12): such a tree is in view.
            let tau = if trusted && chosen_in_view(instance.transform) {
                0.0
            } else {
                let Some(tau) =
                    instance_tau(instance.transform, camera, &frustum, s_min, lod.cull_sphere(), model.block_centre)
                else {
                    continue;
                };
                tau
            };
            *draws.visible.get_mut(baseline) += 1;
            match (baseline, &model.chain, &model.billboards) {
                (Technique::LodChain, Some(chain), _) => {
                    let by_image = choices.get(instance.model as usize).and_then(Option::as_deref);
                    let pick = match by_image {
                        Some(choices) => {
                            let height = projected_height_at(lod, instance.transform, camera.position, world_per_pixel);
                            let (height, class) = dither.apply(height, &instance.transform);
                            let last = previous.get(index as usize).copied().flatten();
                            let pick = match last {
                                Some(last) if hold => last,
                                _ => choices.choose_in(height, class, last, || chain.chain.pick(tau)),
                            };
                            if main {
                                levels.push((index, Some(pick)));
                            }
                            pick
                        }
                        None => {
                            if main {
                                levels.push((index, None));
                            }
                            chain.chain.pick(tau)
                        }
                    };
                    let (range, error) = match pick {
                        Some(level) => (
                            chain.levels.get(level as usize).copied().unwrap_or(chain.full),
                            chain.level_error(level as usize),
                        ),
                        None => (chain.full, 0.0),
                    };
                    draws.triangles.extend(TriangleDraw::whole(
                        index,
                        instance.model,
                        TriangleSource::LodLevel,
                        range,
                        tau,
                        error,
                    ));
                }
                (Technique::Octahedral, _, _) if model.octahedral > 0 => {
                    draws.octahedral.push(QuadDraw {
                        instance: index,
                        model: instance.model,
                        first: 0,
                        count: model.octahedral,
                    });
                }
                (Technique::Billboard | Technique::Crossed, _, Some(billboards)) => {
                    let (first, count) =
                        if baseline == Technique::Crossed { billboards.crossed } else { billboards.facing };
                    if count > 0 {
                        draws.billboards.push(QuadDraw { instance: index, model: instance.model, first, count });
                    }
                }
                _ => {}
            }
        }
    });
    if let Some(state) = state.filter(|s| !s.hold) {
        for (index, level) in levels {
            if let Some(slot) = state.previous.get_mut(index as usize) {
                *slot = level;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::draws::Representations;
    use crate::impostor::ImpostorBark;
    use crate::policy::Calibration;
    use treelod_format::{ContainerData, LodLevelRecord};

    fn chain(errors: &[&[f32]]) -> LodChain {
        let mut data = ContainerData::default();
        let mut first = 0;
        for (tree, errors) in errors.iter().enumerate() {
            for (level, &error) in errors.iter().enumerate() {
                data.lod_levels.push(LodLevelRecord {
                    tree: tree as u32,
                    level: level as u32,
                    triangles: Range { first, count: 1 },
                    error,
                    fraction: 0.5 / (level + 1) as f32,
                });
                first += 1;
            }
        }
        let container = Container::from_bytes(&minimal_with(data)).unwrap();
        LodChain::from_container(&container).unwrap()
    }

    /// A file holding only the given chain (and the required sections).
    fn minimal_with(mut data: ContainerData) -> Vec<u8> {
        data.block =
            treelod_format::BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 2, ..Default::default() };
        data.cells = vec![treelod_format::CellRecord::default(); 2];
        data.metadata.trees = vec![treelod_format::Tree::default(); 2];
        data.metadata.sources = vec![treelod_format::Source::default()];
        data.to_bytes(treelod_format::Compression::None).unwrap()
    }

    #[test]
    fn the_coarsest_level_within_tau_is_picked_and_below_the_finest_the_full_mesh() {
        let chain = chain(&[&[0.01, 0.05, 0.2]]);
        assert_eq!(chain.levels().len(), 3);
        assert_eq!(chain.pick(0.001), None, "full mesh");
        assert_eq!(chain.pick(0.01), Some(0));
        assert_eq!(chain.pick(0.049), Some(0));
        assert_eq!(chain.pick(0.05), Some(1));
        assert_eq!(chain.pick(10.0), Some(2));
    }

    #[test]
    fn a_block_switches_its_trees_together_at_the_largest_error() {
        let chain = chain(&[&[0.01, 0.05], &[0.02, 0.03]]);
        let errors: Vec<f32> = chain.levels().iter().map(|l| l.error).collect();
        assert_eq!(errors, [0.02, 0.05]);
        assert_eq!(chain.levels()[1].ranges, [Range { first: 1, count: 1 }, Range { first: 3, count: 1 }]);
        assert_eq!(chain.pick(0.015), None);
        assert_eq!(chain.pick(0.02), Some(0));
    }

    /// Selection settings of one pixel, the default policy, nothing culled beforehand.
    fn test_settings() -> TechniqueSettings {
        TechniqueSettings {
            s_min: 1.0,
            lod: crate::frame::LodSettings::default(),
            pruning: crate::prune::Pruning::default(),
            impostor_bark: ImpostorBark::default(),
            pixel_level: crate::spt_lod::PixelLevel { quality: 1.0, blend: 0.5 },
            lines: true,
            chain_policy: Policy::default(),
            culled: false,
        }
    }

    /// Trees the policy's chooser culled with the camera (`TechniqueSettings::culled`) give the
    /// billboards and octahedral impostors that testing every tree here gives, transforms scaled
    /// to nothing, to under the chooser's floor, and to infinity among them.
    #[test]
    fn quads_of_trees_the_chooser_culled_are_the_quads_culled_here() {
        use treelod_build::{BuildConfig, ImpostorConfig, LodChainConfig, Placed, SplitMix64, build_block};
        let tree = treelod_build::demo_tree(&treelod_build::DemoTreeConfig { leaves: 300, ..Default::default() });
        // Billboards and octahedral impostors are baked with the impostors' atlas.
        let config = BuildConfig {
            baselines: Some(LodChainConfig::default()),
            impostors: Some(ImpostorConfig::default()),
            ..BuildConfig::default()
        };
        let built =
            build_block("t", &[Placed { scene: &tree, translation: Vec3::ZERO }], &config, "t").expect("builds");
        let container =
            Container::from_bytes(&built.data.to_bytes(treelod_format::Compression::None).unwrap()).expect("opens");
        let models = [Representations::from_container(&container).0];
        let lods = [crate::frame::ModelLod::from_container(&container)];
        assert!(models[0].octahedral > 0 && models[0].billboards.is_some(), "quads built");
        let mut rng = SplitMix64(4);
        let mut instances: Vec<crate::frame::Instance> = (0..600)
            .map(|_| {
                let at = Vec3::new(rng.range(-80.0, 80.0), 0.0, rng.range(-120.0, 10.0));
                crate::frame::Instance {
                    model: 0,
                    transform: Mat4::from_scale_rotation_translation(
                        Vec3::splat(rng.range(0.5, 2.0)),
                        glam::Quat::from_rotation_y(rng.range(0.0, 6.0)),
                        at,
                    ),
                }
            })
            .collect();
        for (k, scale) in [0.0, 1e-13, 1e-30, f32::INFINITY, f32::NAN].into_iter().enumerate() {
            instances[k].transform = Mat4::from_scale_rotation_translation(
                Vec3::splat(scale),
                glam::Quat::IDENTITY,
                Vec3::new(0.0, 0.0, -30.0),
            );
        }
        let camera = Camera::look_at(Vec3::new(0.0, 3.0, 20.0), Vec3::new(0.0, 3.0, 0.0), 0.9, 640, 480);
        let frustum = Frustum::from_view_proj(camera.view_proj);
        // The chooser's cull (`choose_instances`): the culling sphere scaled by `max_axis_scale`.
        let every: Vec<u32> = (0..instances.len() as u32).collect();
        let culled: Vec<u32> = every
            .iter()
            .copied()
            .filter(|&i| {
                let t = instances[i as usize].transform;
                let (centre, radius) = lods[0].cull_sphere();
                frustum.intersects_sphere(t.transform_point3(centre), radius * crate::max_axis_scale(t))
            })
            .collect();
        assert!(culled.len() > 50 && culled.len() < 550, "{} of {} in view", culled.len(), every.len());
        let scene = Scene { lods: &lods, models: &models, instances: &instances };
        let settings = |culled: bool| TechniqueSettings { culled, ..test_settings() };
        for baseline in [Technique::Octahedral, Technique::Billboard, Technique::Crossed] {
            let (mut tested, mut trusted) = (TreeDraws::default(), TreeDraws::default());
            select(&scene, &every, baseline, &camera, &settings(false), None, &mut tested);
            select(&scene, &culled, baseline, &camera, &settings(true), None, &mut trusted);
            assert_eq!(trusted, tested, "{baseline:?}");
            assert!(tested.visible[baseline] > 50, "{baseline:?}");
        }
    }

    /// `scene` built with a LoD chain and calibration (two views), its selection inputs.
    fn built_chain(scene: &treelod_build::scene::Scene) -> (Container, Representations, crate::frame::ModelLod) {
        use treelod_build::{BuildConfig, CalibrationConfig, LodChainConfig, Placed, build_block};
        let config = BuildConfig {
            baselines: Some(LodChainConfig::default()),
            calibration: Some(CalibrationConfig { views: 2, more_small_views: false, ..CalibrationConfig::default() }),
            ..BuildConfig::default()
        };
        let built = build_block("t", &[Placed { scene, translation: Vec3::ZERO }], &config, "t").expect("builds");
        let container =
            Container::from_bytes(&built.data.to_bytes(treelod_format::Compression::None).unwrap()).expect("opens");
        let models = Representations::from_container(&container).0;
        let lod = crate::frame::ModelLod::from_container(&container);
        (container, models, lod)
    }

    /// The triangles the chain draws for one tree `height` pixels high (the camera's view, no
    /// previous level) with `models`' per-level tables, or (`geometric`) without them.
    fn chain_draw(models: &Representations, lod: &crate::frame::ModelLod, height: f32, geometric: bool) -> u32 {
        let mut previous = vec![None];
        let count = chain_draw_with(models, lod, height, geometric, (&mut previous, false));
        assert_eq!(previous[0].is_some(), !geometric, "the level by image error is held for the next frame");
        count
    }

    /// [`chain_draw`] with the tree's level last frame and whether it holds it
    /// ([`ChainState`]).
    fn chain_draw_with(
        models: &Representations,
        lod: &crate::frame::ModelLod,
        height: f32,
        geometric: bool,
        (previous, hold): (&mut Vec<Option<ChainPick>>, bool),
    ) -> u32 {
        let mut models = models.clone();
        if geometric {
            models.chain.as_mut().expect("a chain").calibration = None;
        }
        let probe = Camera::look_at(Vec3::new(0.0, 0.0, 10.0), Vec3::ZERO, 0.8, 640, 480);
        let centre = lod.centre();
        let distance = crate::policy::distance_for_height(lod, height, &probe);
        let camera = Camera::look_at(centre + Vec3::new(0.0, 0.0, distance), centre, 0.8, 640, 480);
        let instances = [crate::frame::Instance { model: 0, transform: Mat4::IDENTITY }];
        let (lods, reps) = (std::slice::from_ref(lod), std::slice::from_ref(&models));
        let scene = Scene { lods, models: reps, instances: &instances };
        let settings = test_settings();
        let mut out = TreeDraws::default();
        let state = ChainState { previous, hold };
        select(&scene, &[0], Technique::LodChain, &camera, &settings, Some(state), &mut out);
        assert_eq!(out.triangles.len(), 1, "one draw of the tree");
        out.triangles[0].count
    }

    /// A tree leaving the chain in a transition draws the level it drew, where picked again
    /// a near tree takes the full mesh, and its level is not written.
    #[test]
    fn a_tree_leaving_the_chain_holds_the_level_it_drew() {
        let scene = treelod_build::demo_tree(&treelod_build::DemoTreeConfig::default());
        let (container, models, lod) = built_chain(&scene);
        let chain = LodChain::from_container(&container).unwrap();
        let coarse = u32::try_from(chain.levels().len() - 1).unwrap();
        let level_triangles = models.chain.as_ref().unwrap().levels[coarse as usize].1;
        let full = container.triangles().len() as u32;
        assert!(level_triangles < full / 4, "{level_triangles} of {full}");
        // Above the tables' heights, picked again: the full mesh.
        let mut previous = vec![Some(Some(coarse))];
        assert_eq!(chain_draw_with(&models, &lod, 4096.0, false, (&mut previous, false)), full);
        assert_eq!(previous, [Some(None)], "the camera's view writes its level");
        // Held: the coarse level it drew, nothing written.
        let mut previous = vec![Some(Some(coarse))];
        assert_eq!(chain_draw_with(&models, &lod, 4096.0, false, (&mut previous, true)), level_triangles);
        assert_eq!(previous, [Some(Some(coarse))]);
        // A tree without a level to hold picks one, and nothing is written.
        let mut previous = vec![None];
        assert_eq!(chain_draw_with(&models, &lod, 4096.0, false, (&mut previous, true)), full);
        assert_eq!(previous, [None]);
    }

    /// At `height` pixels: the triangles the chain draws by image error and by geometric error,
    /// after checking that the former are those of the level the tables pick, whose calibrated
    /// error is within the default target's allowance at that height of the floor (or of the
    /// chain's least error, where that is above the floor).
    fn by_image_and_by_geometry(models: &Representations, lod: &crate::frame::ModelLod, height: f32) -> (u32, u32) {
        let calibration = models.chain.as_ref().and_then(|c| c.calibration.clone()).expect("per-level tables");
        let allowed = crate::policy::target_at(Policy::DEFAULT_TARGET, height);
        let pick = calibration.chain_level(height, allowed, |_| true).expect("tables");
        let (error, primitives) = match pick {
            Some(level) => calibration.level_at(level, height).expect("level"),
            None => calibration.at(Technique::Full, height).expect("full"),
        };
        // Within the target of the floor, or where nothing is, of the least error the chain has.
        let floor = calibration.floor(None, height, |_| true);
        let levels = (0..calibration.chain_levels() as u32).filter_map(|l| calibration.level_at(l, height));
        let best = levels.chain(calibration.at(Technique::Full, height)).map(|(e, _)| e).fold(f32::INFINITY, f32::min);
        assert!(error <= floor.max(best) + allowed, "{height} px: {error} over {floor}, {best}");
        let by_image = chain_draw(models, lod, height, false);
        assert_eq!(by_image as f32, primitives, "{height} px: the tables count what is drawn");
        (by_image, chain_draw(models, lod, height, true))
    }

    /// The demo tree's coarse chain levels lose its canopy (their image errors are two to three
    /// times the floor at 8 pixels) although their geometric errors project under a pixel there:
    /// by image error the chain keeps a finer level.
    #[test]
    fn the_chain_draws_the_level_its_tables_allow_on_the_demo_tree() {
        let scene = treelod_build::demo_tree(&treelod_build::DemoTreeConfig::default());
        let (container, models, lod) = built_chain(&scene);
        let levels = models.chain.as_ref().and_then(|c| c.calibration.as_ref()).map(Calibration::chain_levels);
        assert_eq!(levels, Some(LodChain::from_container(&container).unwrap().levels().len()));
        let (by_image, by_geometry) = by_image_and_by_geometry(&models, &lod, 8.0);
        assert!(by_image > by_geometry, "8 px: {by_image} triangles by image error, {by_geometry} by geometry");
        // Near, above the tables, the chain converges to the full mesh as the geometric rule does.
        assert_eq!(chain_draw(&models, &lod, 4096.0, false), container.triangles().len() as u32);
        assert_eq!(chain_draw(&models, &lod, 4096.0, true), container.triangles().len() as u32);
    }

    /// The chain's levels by image error are made once per policy and kept: the next frame
    /// (and each shadow cascade) reads the same table, another policy makes its own, and the
    /// last `CACHED_POLICIES` policies' tables are kept.
    #[test]
    fn the_chain_s_levels_by_image_error_are_made_once_per_policy() {
        let scene = treelod_build::demo_tree(&treelod_build::DemoTreeConfig::default());
        let (_, models, _) = built_chain(&scene);
        let chain = models.chain.as_ref().expect("a chain");
        let calibration = chain.calibration.as_ref().expect("per-level tables");
        let all = |_: Technique| true;
        let policy = Policy::default();
        let first = chain.choices(&policy, all).expect("levels");
        assert_eq!(*first, ChainChoices::new(calibration, &policy, all).expect("levels"));
        assert!(Arc::ptr_eq(&first, &chain.choices(&policy, all).expect("levels")), "kept");
        let loose = Policy { target: 0.05, ..policy };
        let other = chain.choices(&loose, all).expect("levels");
        assert!(!Arc::ptr_eq(&first, &other), "made again for another policy");
        assert_eq!(*other, ChainChoices::new(calibration, &loose, all).expect("levels"));
        assert_ne!(other.steps(), first.steps(), "a looser target picks coarser levels somewhere");
        assert!(chain.clone().choices(&loose, all).is_some_and(|c| !Arc::ptr_eq(&c, &other)), "a clone makes its own");
        // The first policy's table is still kept, until `CACHED_POLICIES` others were asked for
        // after it (budget mode's steering goes back and forth between a few targets).
        assert!(Arc::ptr_eq(&first, &chain.choices(&policy, all).expect("levels")), "kept beside another");
        for i in 1..CACHED_POLICIES {
            chain.choices(&Policy { target: 0.1 + 0.01 * i as f32, ..policy }, all);
        }
        assert!(Arc::ptr_eq(&first, &chain.choices(&policy, all).expect("levels")), "kept beside 7 others");
        for i in 1..=CACHED_POLICIES {
            chain.choices(&Policy { target: 0.011 * i as f32, ..policy }, all);
        }
        assert!(!Arc::ptr_eq(&first, &chain.choices(&policy, all).expect("levels")), "dropped after 8 others");
        // In budget mode the targets within one cell of the lattice of targets share the tables.
        let budget = Policy { target: 0.0123, budget: Some(100_000), ..policy };
        let moved = Policy { target: 0.0127, ..budget };
        assert_eq!(Choices::tables_key(&budget), Choices::tables_key(&moved), "one cell");
        let first = chain.choices(&budget, all).expect("levels");
        assert!(Arc::ptr_eq(&first, &chain.choices(&moved, all).expect("levels")), "shared within the cell");
        assert_eq!(*first, ChainChoices::new(calibration, &moved, all).expect("levels"));
    }

    /// The shared oak (about 76 pixels high at 8 bounding radii in `eval`'s default 640×480
    /// view, 50° field of view). At 32 and 64 pixels the chain by image error draws fewer
    /// triangles than by geometric error: the coarser levels whose leaves collapse are within the
    /// target of the best image the chain has there (nothing in it reaches the point tree's
    /// floor), where the geometric rule (levels' errors of 0.1 to 5 m) draws a finer level.
    /// At 128 and 256 pixels the chain's own level 0 reads about 0.039 and 0.027 in shaded colour
    /// against a floor of 0.031 and 0.016, out of the allowance there (`target_at`: 0.005 and
    /// 0.0025), so before bark-first levels both rules drew the full mesh; now both draw a
    /// bark-first level, every leaf triangle with part of the bark (a quarter by image error):
    /// fewer than half the bark's triangles.
    #[test]
    fn far_away_the_oak_chain_by_image_error_draws_fewer_triangles_than_by_geometric_error() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/assets/trees/ez-tree-oak-large-23k.glb");
        assert!(path.exists(), "{} is missing: the repository is checked out with ../shared beside it", path.display());
        let scene = treelod_build::import_gltf(&path).expect("imports");
        let (container, models, lod) = built_chain(&scene);
        let full = container.triangles().len() as u32;
        let leaf = container
            .triangles()
            .iter()
            .filter(|t| container.materials()[t.material as usize].class == treelod_format::material_class::LEAF)
            .count() as u32;
        for height in [32.0, 64.0, 128.0, 256.0] {
            let (by_image, by_geometry) = by_image_and_by_geometry(&models, &lod, height);
            if height < 128.0 {
                assert!(
                    by_image < by_geometry,
                    "{height} px: {by_image} triangles by image error, {by_geometry} by geometry"
                );
                continue;
            }
            for (rule, drawn) in [("image", by_image), ("geometry", by_geometry)] {
                assert!(
                    drawn > leaf && 2 * drawn < full + leaf,
                    "{height} px by {rule}: {drawn} of {full} ({leaf} leaves)"
                );
            }
            let level = container.lod_levels().iter().find(|l| l.triangles.count == by_image).expect("a level");
            assert!(
                !treelod_build::lod_chain::DEFAULT_FRACTIONS.contains(&level.fraction),
                "a bark-first level: {level:?}"
            );
        }
    }

    #[test]
    fn tau_grows_with_distance_and_culled_instances_have_none() {
        let sphere = (Vec3::ZERO, 1.0);
        let at = |z: f32| {
            let camera = Camera::look_at(Vec3::new(0.0, 0.0, z), Vec3::ZERO, 0.8, 512, 512);
            instance_tau(Mat4::IDENTITY, &camera, &Frustum::from_view_proj(camera.view_proj), 1.0, sphere, Vec3::ZERO)
        };
        let (near, far) = (at(10.0).unwrap(), at(100.0).unwrap());
        assert!((far / near - 10.0).abs() < 1e-3, "{near} {far}");
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 10.0), Vec3::new(0.0, 0.0, 20.0), 0.8, 512, 512);
        let frustum = Frustum::from_view_proj(camera.view_proj);
        assert_eq!(instance_tau(Mat4::IDENTITY, &camera, &frustum, 1.0, sphere, Vec3::ZERO), None, "behind");
        assert_eq!(instance_tau(Mat4::ZERO, &camera, &frustum, 1.0, sphere, Vec3::ZERO), None, "degenerate");
    }
}
