//! Prints the annotated hex dump of `tests/data/v1_0/minimal.treelod` for spec §13.1: the text
//! between the markers `<!-- spec-example:begin -->` and `<!-- spec-example:end -->`.
//!
//! ```text
//! cargo run -p treelod-tests --bin spec-example
//! ```

use std::process::ExitCode;

use treelod_tests::{golden_dir, spec_hex_dump};

fn main() -> ExitCode {
    let path = golden_dir().join("minimal.treelod");
    let bytes = match std::fs::read(&path) {
        Ok(bytes) => bytes,
        Err(e) => {
            eprintln!("spec-example: {}: {e}", path.display());
            return ExitCode::FAILURE;
        }
    };
    match spec_hex_dump(&bytes) {
        Ok(text) => {
            print!("{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("spec-example: {}: {e}", path.display());
            ExitCode::FAILURE
        }
    }
}
