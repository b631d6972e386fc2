//! The `.treelod` container: record types, a zero-copy reader and a deterministic writer.
//!
//! The normative description is `format-spec/treelod.md`; every type here cites its section.
//! This crate depends on no GPU or thread-pool crate, so tools, builders and runtimes can all use it.
//!
//! ```no_run
//! # fn main() -> Result<(), treelod_format::Error> {
//! let container = treelod_format::Container::open("tree.treelod")?;
//! let block = container.block();
//! for (index, cell) in container.cells().iter().enumerate() {
//!     let points = &container.points()[cell.points.as_usize()];
//!     println!("cell {index}: {} points, grid {:?}", points.len(), block.grid);
//! }
//! # Ok(()) }
//! ```

mod error;
#[cfg(feature = "images")]
pub mod image;
mod metadata;
pub mod pack;
mod reader;
mod records;
mod rng;
mod verify;
mod writer;

pub use error::{Error, ErrorClass, Result};
pub use metadata::{MAX_META_BYTES, MaterialInfo, Metadata, Setting, Source, Tree};
pub use reader::{
    Container, DEFAULT_DECODE_BUDGET, MAX_COMPRESSION_RATIO, MAX_GRID_AXIS, MAX_GRID_CELLS, MAX_HEADER_SIZE,
    MAX_SECTIONS, OpenOptions, Section,
};
pub use records::*;
pub use rng::SplitMix64;
pub use verify::{SptSummary, VerifyReport, check_far_lines, check_point_cut, check_spt, triangle_leaf_sizes, verify};
pub use writer::{
    Compression, ContainerData, DEFAULT_LEVEL, SMALL_SECTION, section_level, temporary_target, verify_written,
    write_atomically,
};
