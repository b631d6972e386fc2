//! treelod's measuring instrument: one definition of every image metric the project reports or
//! calibrates with, used by the build's calibrations (`treelod-build`), `treelod eval`,
//! `treelod bench --quality` and the rendering tests.
//!
//! - [`metrics`]: coverage masks and their pixel classification with Precision, Recall and
//!   Neubert's quality `Q`; the multi-scale RMSE of Clasen et al. (for coverage and for linear
//!   colour alike); temporal noise; FLIP (feature `flip`).
//!
//! The crate is free of GPU types: its default features pull no GPU crate and no C++ (the build
//! crate depends on it). The `flip` feature adds NVIDIA's FLIP through `nv-flip`, which compiles
//! C++; the command-line tool enables it.

pub mod metrics;

mod error;

pub use error::MetricError;
