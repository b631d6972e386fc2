//! The build per stage: the import, the core build (classification, grid, point hierarchies),
//! each representation and ambient occlusion on top of the core, and the encoding at each
//! compression, each reported as source triangles per second.
//!
//! Run with `cargo bench -p treelod-build --bench stages`. A representation's own cost is its
//! row's time less the core's. The models are the shared oak (23k triangles) and, when
//! `TREELOD_BENCH_LARGE=1`, the 669k-triangle maple (seconds per iteration), read from
//! `../shared/assets/trees/` (or `TREELOD_TREES`); without them, the built-in demo tree. One
//! build's stage times are also printed by `treelod build --timings`.

mod common;

use std::hint::black_box;
use std::path::Path;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use treelod_build::scene::Scene;
use treelod_build::{
    AoConfig, BuildConfig, DemoTreeConfig, EllipsoidConfig, ImpostorConfig, LineConfig, LodChainConfig, Placed,
    PruneConfig, build_block, demo_tree, import_gltf_bytes,
};
use treelod_format::Compression;

/// The core build: every stage that always runs, nothing optional.
fn core() -> BuildConfig {
    BuildConfig { ao: None, ..BuildConfig::default() }
}

/// The stages measured on top of [`core`].
fn stages() -> Vec<(&'static str, BuildConfig)> {
    vec![
        ("core", core()),
        ("core + ambient occlusion (default)", BuildConfig { ao: Some(AoConfig::default()), ..core() }),
        ("core + ellipsoids", BuildConfig { ellipsoids: Some(EllipsoidConfig::default()), ..core() }),
        ("core + lines", BuildConfig { lines: Some(LineConfig::default()), ..core() }),
        ("core + impostors", BuildConfig { impostors: Some(ImpostorConfig::default()), ..core() }),
        ("core + prune", BuildConfig { prune: Some(PruneConfig::default()), ..core() }),
        ("core + lod chain", BuildConfig { baselines: Some(LodChainConfig::default()), ..core() }),
    ]
}

fn bench_model(c: &mut Criterion, name: &str, bytes: Option<(&[u8], &Path)>, scene: &Scene) {
    let mut group = c.benchmark_group(format!("stages/{name}"));
    group.sample_size(10);
    group.throughput(Throughput::Elements(common::triangles(scene)));
    if let Some((bytes, path)) = bytes {
        group.bench_function("import", |b| {
            b.iter(|| black_box(import_gltf_bytes(bytes, path, path.parent()).expect("the model imports")));
        });
    }
    let placed = [Placed { scene, translation: glam::Vec3::ZERO }];
    for (stage, config) in stages() {
        group.bench_function(stage, |b| {
            b.iter(|| black_box(build_block(name, &placed, &config, "bench").expect("builds")));
        });
    }
    let built = build_block(name, &placed, &BuildConfig::default(), "bench").expect("builds");
    for compression in [Compression::None, Compression::default()] {
        let label = match compression {
            Compression::None => "none".to_owned(),
            Compression::Zstd { level } => format!("zstd {level}"),
        };
        group.bench_function(BenchmarkId::new("encode", label), |b| {
            b.iter(|| black_box(built.data.to_bytes(compression).expect("encodes")));
        });
    }
    group.finish();
}

fn stages_bench(c: &mut Criterion) {
    let mut measured = false;
    for (model, path, bytes) in common::read_models(&["ez-tree-oak-large-23k.glb"]) {
        let scene = import_gltf_bytes(&bytes, &path, path.parent()).expect("the shared model imports");
        bench_model(c, model, Some((&bytes, &path)), &scene);
        measured = true;
    }
    if !measured {
        let demo = demo_tree(&DemoTreeConfig::default());
        bench_model(c, "demo tree", None, &demo);
    }
}

criterion_group!(benches, stages_bench);
criterion_main!(benches);
