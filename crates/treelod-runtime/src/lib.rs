//! The treelod runtime: maps containers and selects what to draw of every cell.
//!
//! Selection is plain Rust over the container's slices (no GPU types), so it is unit-tested and
//! benchmarked on the CPU. [`select`] holds the per-cell rule of `format-spec/treelod.md` §10:
//! pixel thresholds become world-size thresholds, a binary search of the size-sorted arrays gives
//! the prefix to draw, and [`select::point_drawn`] is the per-element test the vertex shader makes.
//! [`frame`] applies it to a whole frame: frustum culling of instances and cells, Gilet's depth
//! bias per cell, a reusable draw list, and a controller that keeps the primitive count on budget.
//! [`impostor`] selects the level of impostor planes of an instance the same way, [`ellipsoid`] the
//! level of Clasen's leaf ellipsoids and branch lines (all three through one per-cell prefix
//! selector, [`spt_lod`]), and [`baseline`] the level of a baseline LoD chain. [`technique`] is the one
//! list of the ways a tree can be drawn, by the names every layer uses, and [`policy`] chooses
//! among them per tree from the calibration tables the build measured.
//!
//! Each representation's module also owns its per-frame selection over the trees assigned to it
//! ([`prune::select`], [`impostor::select`], [`ellipsoid::select`], [`baseline::select`]); [`draws`]
//! holds what they share: the assignment of a frame's trees to techniques ([`Assignment`]), what
//! they read of a model ([`Representations`]) and the plain draw lists they produce
//! ([`TreeDraws`]), which a renderer turns into GPU draws. An engine embedding the runtime alone
//! selects every representation so.

pub mod baseline;
pub mod draws;
pub mod ellipsoid;
pub mod frame;
pub mod impostor;
pub mod light;
pub mod policy;
pub mod prune;
pub mod select;
pub mod spt_lod;
pub mod technique;
pub mod texels;

pub use baseline::{
    BillboardKind, BillboardRanges, Billboards, CACHED_POLICIES, ChainLevel, ChainRanges, ChainState, LodChain,
    chosen_in_view, instance_tau,
};
pub use draws::{
    Assignment, PrefixDraw, QuadDraw, Representations, Scene, TechniqueSettings, TreeDraws, TriangleDraw,
    TriangleSource, max_axis_scale, merge_ascending, select_techniques,
};
pub use ellipsoid::{
    EllipsoidCell, EllipsoidLod, EllipsoidRange, LineCell, LineLod, LineRange, ellipsoid_drawn, far_ellipsoids,
    line_drawn,
};
pub use frame::{
    BudgetController, Camera, CellLod, CellPrefix, DrawList, DrawRange, FAR_LIST_EXTRA, FAR_POINTS_PER_CELL, FAR_UNDER,
    FrameStats, Frustum, Instance, Kind, LodSettings, ModelError, ModelLod, ROOTS_CELL, look_at_matrices, select_frame,
};
pub use impostor::{
    CROSSFADE, ImpostorBark, NO_PARENT, PlaneCell, PlaneLod, PlaneRange, crossfade, morph_corner, morph_share,
    plane_drawn, plane_parents,
};
pub use light::Light;
pub use policy::{
    CHOOSE_CHUNK, Calibration, ChainChoices, ChainPick, ChoiceBasis, Choices, ChunkBounds, Policy, PolicyState,
    TablesKey, Transition, TreeDither, VISIBILITY_CLASSES, VISIBILITY_LEAD, choose_instances,
    choose_instances_coarsest, choose_instances_in_chunks, chunk_range, elevation_class_after, in_view_share,
    projected_height, view_elevation, visibility_class, visibility_class_after,
};
pub use prune::{Hysteresis, PruneCell, PruneLod, PruneScale, PruneState, Pruning, hull_samples};
pub use select::{CellSelection, Thresholds, pixels_to_world, point_drawn, select_cell, triangle_drawn};
pub use spt_lod::{DEFAULT_LEVEL_BLEND, PixelLevel, SptCell, SptLod, SptRecord, level_keep, spt_drawn};
pub use technique::{Data, PerPrimitive, PerTechnique, Primitive, Technique};
