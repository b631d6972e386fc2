//! treelod's measuring harness: `eval` and `bench` as library functions.
//!
//! - [`eval`]: renders the full mesh as the reference (supersampled, box-filtered down) and every
//!   chosen technique at the same cameras, and measures per frame what each drew, how close its
//!   image came to the reference (`treelod_eval`'s metrics: P/R/Q, multi-scale RMSE, FLIP,
//!   temporal noise) and what it cost. [`eval::run`] takes an [`eval::Options`] and returns an
//!   [`eval::Report`]; [`eval::output`] and [`eval::plot`] turn a report into the table, CSV,
//!   JSON, contact sheet and plots, and [`eval::Report`]'s `write_*` methods write them.
//! - [`bench`](mod@bench): the fly-through benchmark (Clasen 2011 §7), [`bench::run`] with a
//!   [`bench::Options`], returning a [`bench::Report`] (per frame and technique the selection
//!   time, primitives, streaming, GPU time and optionally quality).
//! - [`scene`]: scene files (which containers to draw and where), shared with `treelod render`
//!   and `treelod view`; [`offscreen`]: the framing camera, the clear colour, settled streaming
//!   and PNG encoding that the harness and `treelod render` share.
//!
//! Nothing here prints or exits: failures are [`Error`]s naming the file concerned (or the input
//! the run was about), each with the class (`treelod_format::ErrorClass`) a command line turns into
//! its exit code; progress goes to an optional callback. The `treelod` command wraps these
//! functions (`treelod eval`, `treelod bench`) and prints their reports.
//!
//! Measuring a container from Rust (a Vulkan adapter is needed; lavapipe works):
//!
//! ```no_run
//! use treelod_harness::eval::{self, Cameras, TechniqueName};
//! use treelod_harness::Technique;
//!
//! let options = eval::Options {
//!     cameras: Cameras::Orbit(vec![2.0, 8.0, 32.0]),
//!     techniques: vec![TechniqueName::Full1x, TechniqueName::Technique(Technique::Spt)],
//!     size: (320, 240),
//!     ..eval::Options::new("tree.treelod")
//! };
//! let report = eval::run(&options)?;
//! for technique in report.measured() {
//!     let summary = eval::output::summarise(&report.rows, technique);
//!     println!("{}: Q {:.3}, RMSE {:.5}", technique.name(), summary.mean.q, summary.mean.rmse);
//! }
//! report.write_csv("eval.csv".as_ref())?;
//! # Ok::<(), treelod_harness::Error>(())
//! ```

pub mod bench;
mod error;
pub mod eval;
pub mod offscreen;
pub mod scene;
pub mod table;
pub mod write;

pub use error::Error;
pub use treelod_format::ErrorClass;
pub use treelod_render::Technique;
