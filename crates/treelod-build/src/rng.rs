//! The project's one random generator, [`SplitMix64`], kept by `treelod-format` so that every
//! crate draws the same sequences; re-exported here, where the build's procedural trees, forests
//! and sampling use it.

pub use treelod_format::SplitMix64;
