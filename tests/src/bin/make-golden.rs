//! Writes the golden files of format versions 1.0 to 1.18 into `tests/data/v1_0` to
//! `tests/data/v1_18` (or the `v1_<minor>` directories of the directory given).
//!
//! Golden files are written once and kept forever (spec §11): an existing file is never replaced
//! unless `--force` is given. A file that exists and equals what would be written is reported as
//! unchanged; one that differs is reported and makes the program fail, which shows that the
//! generator or the writer changed (the golden file stays as it is).
//!
//! ```text
//! cargo run -p treelod-tests --bin make-golden [-- [--force] [DIR]]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use treelod_tests::{golden_files, golden_root, synthetic};

fn main() -> ExitCode {
    let mut force = false;
    let mut root = golden_root();
    for arg in std::env::args().skip(1) {
        match arg.as_str() {
            "--force" => force = true,
            "-h" | "--help" => {
                println!("usage: make-golden [--force] [DIR]   (default DIR: {})", golden_root().display());
                return ExitCode::SUCCESS;
            }
            other if other.starts_with('-') => {
                eprintln!("make-golden: unknown option {other}");
                return ExitCode::from(2);
            }
            other => root = PathBuf::from(other),
        }
    }
    let mut failed = false;
    for golden in golden_files() {
        let dir = root.join(format!("v1_{}", golden.minor));
        if let Err(e) = std::fs::create_dir_all(&dir) {
            eprintln!("make-golden: {}: {e}", dir.display());
            return ExitCode::FAILURE;
        }
        let path = dir.join(golden.name);
        let data = synthetic(golden.seed, &golden.options);
        let bytes = match data.to_bytes(golden.compression) {
            Ok(bytes) => bytes,
            Err(e) => {
                eprintln!("make-golden: {}: {e}", golden.name);
                failed = true;
                continue;
            }
        };
        if path.exists() && !force {
            match std::fs::read(&path) {
                Ok(existing) if existing == bytes => println!("unchanged {}", path.display()),
                Ok(_) => {
                    eprintln!(
                        "make-golden: {} exists and differs from what the generator makes now; golden files never \
                         change, so it is kept (--force overwrites)",
                        path.display()
                    );
                    failed = true;
                }
                Err(e) => {
                    eprintln!("make-golden: {}: {e}", path.display());
                    failed = true;
                }
            }
            continue;
        }
        match treelod_format::write_atomically(&path, &bytes) {
            Ok(()) => println!("wrote {} ({} bytes): {}", path.display(), bytes.len(), golden.description),
            Err(e) => {
                eprintln!("make-golden: {e}");
                failed = true;
            }
        }
    }
    if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS }
}
