//! The `treelod` command-line tool.
fn main() {}
