//! What the build benchmarks share: where the shared models are, which of them to measure, and
//! the source triangles a throughput counts.

use std::path::{Path, PathBuf};

use treelod_build::scene::Scene;

/// `../shared/assets/trees/`, or `TREELOD_TREES`.
fn trees_dir() -> PathBuf {
    std::env::var_os("TREELOD_TREES")
        .map_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees"), PathBuf::from)
}

/// `models`, and the 669k-triangle maple when `TREELOD_BENCH_LARGE` is set (seconds per
/// iteration), each with its path and bytes; a model that cannot be read is skipped with a line
/// on stderr.
pub fn read_models(models: &[&'static str]) -> Vec<(&'static str, PathBuf, Vec<u8>)> {
    let large = std::env::var_os("TREELOD_BENCH_LARGE").is_some().then_some("sapling-japanese-maple-669k.glb");
    models
        .iter()
        .copied()
        .chain(large)
        .filter_map(|model| {
            let path = trees_dir().join(model);
            match std::fs::read(&path) {
                Ok(bytes) => Some((model, path, bytes)),
                Err(e) => {
                    eprintln!("skipping {model}: {}: {e}", path.display());
                    None
                }
            }
        })
        .collect()
}

/// The source triangles of `scene`: what a build's throughput counts.
pub fn triangles(scene: &Scene) -> u64 {
    scene.parts.iter().map(|p| p.triangles.len() as u64).sum()
}
