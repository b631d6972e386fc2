//! The `META` section (spec §7.1): small structured data encoded with postcard.
//!
//! Postcard is not self-describing, so field order is part of the format: later minor versions may
//! only append fields to [`Metadata`], and readers ignore trailing bytes.

use serde::{Deserialize, Serialize};

/// Largest decoded `META` section a reader accepts (spec §12).
pub const MAX_META_BYTES: u64 = 16 << 20;

/// Block-level metadata: provenance, trees, material names and build settings.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metadata {
    /// Tool name and version, e.g. `"treelod 0.1.0"`.
    pub generator: String,
    /// Block name (the source file stem for one tree).
    pub name: String,
    /// Source files the block was built from.
    pub sources: Vec<Source>,
    /// The trees of the block, `BlockRecord::tree_count` entries.
    pub trees: Vec<Tree>,
    /// One entry per `MaterialRecord`, same order.
    pub materials: Vec<MaterialInfo>,
    /// Build settings as text, sorted by key, keys unique.
    pub settings: Vec<Setting>,
}

/// A source file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Source {
    /// Path as given to the build, `/` separators.
    pub path: String,
    /// `"<algorithm>:<lowercase hex>"`, empty if unknown.
    pub content_hash: String,
    /// Size of the source file in bytes.
    pub byte_length: u64,
    /// Metres per source unit applied on import.
    pub unit_scale: f32,
}

/// A tree of the block.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Tree {
    /// Tree name.
    pub name: String,
    /// Index into [`Metadata::sources`].
    pub source: u32,
    /// Placement in block space, metres.
    pub translation: [f32; 3],
    /// Bounds in block space, metres.
    pub bounds_min: [f32; 3],
    /// Upper corner.
    pub bounds_max: [f32; 3],
}

/// Name and classification provenance of a material.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MaterialInfo {
    /// Source material name, empty if none.
    pub name: String,
    /// How the class was decided: `name`, `mesh`, `node`, `geometry`, `override` or `default`.
    pub classified_by: String,
}

/// One build setting.
#[derive(Clone, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Setting {
    /// Setting name, e.g. `grid`.
    pub key: String,
    /// Its value as text.
    pub value: String,
}

impl Metadata {
    /// The value of build setting `key`, if present.
    #[must_use]
    pub fn setting(&self, key: &str) -> Option<&str> {
        self.settings.iter().find(|s| s.key == key).map(|s| s.value.as_str())
    }
}
