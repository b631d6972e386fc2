//! Scene files: the harness's loader ([`treelod_harness::scene`]), which `render`, `view`,
//! `scatter`, `eval` and `bench` share.

pub use treelod_harness::scene::*;
