//! Builds `.treelod` containers: hierarchies of level-of-detail representations of tree meshes,
//! flattened into the size-sorted arrays of `format-spec/treelod.md`.
//!
//! Stages so far: [`spt`] turns any per-cell hierarchy (Gilet's point clustering, Clasen's
//! ellipsoid levels, Garcia's nested planes) into sequential-point-tree order with each element's
//! threshold interval, so that every threshold draws an exact cut (spec §10).

pub mod ambient;
pub mod assemble;
pub mod atlas_format;
pub mod billboard;
pub mod calibrate;
pub mod classify;
pub mod demo;
pub mod ellipsoid;
mod error;
pub mod gilet;
pub mod import;
pub mod impostor;
pub mod lines;
pub mod lod_chain;
pub mod parallel_rays;
pub mod precision;
pub mod prune;
pub mod raster;
pub mod rng;
pub mod scene;
pub mod shade;
pub mod spt;
pub mod texture;
mod union_find;

pub use ambient::{AoConfig, AoMethod};
pub use assemble::{
    BuildConfig, BuildOutput, BuildStats, Placed, Progress, StageTime, auto_grid, build_block, build_scenes,
    ellipsoid_report, prune_report, recorded_settings,
};
pub use atlas_format::AtlasFormat;
pub use billboard::OctahedralConfig;
pub use calibrate::CalibrationConfig;
pub use demo::{DemoTreeConfig, cards_on_planes, demo_tree, leaf_material};
pub use ellipsoid::{Clustering, EllipsoidConfig, Ellipsoids};
pub use error::BuildError;
pub use import::{
    ImportLimits, content_hash, import_gltf, import_gltf_bytes, import_gltf_bytes_with, import_gltf_with, read_source,
    scene_name,
};
pub use impostor::{ImpostorConfig, Impostors, Texturing};
pub use lines::{LineConfig, Lines};
pub use lod_chain::LodChainConfig;
pub use prune::{PruneConfig, PruneOrder, PruneReport};
pub use rng::SplitMix64;
pub use spt::{FlattenError, Spt, SptNode, flatten};
