//! Aligned plain-text tables: the harness's ([`treelod_harness::table`]), which the reports of
//! `eval` and `bench` use too.

pub use treelod_harness::table::*;
