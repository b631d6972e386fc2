//! Build throughput: the built-in demo tree and the shared models, from glTF bytes in memory to an
//! encoded container (import, classification, grid, point hierarchies, ambient occlusion, zstd at the
//! default level), each reported as source triangles per second (criterion's throughput).
//!
//! Run with `cargo bench -p treelod-build --bench build`. The shared models are read from
//! `../shared/assets/trees/` (set `TREELOD_TREES` to another directory); the 669k-triangle maple is
//! only measured when `TREELOD_BENCH_LARGE=1`, as it takes seconds per iteration. Peak memory is
//! not measured here: `/usr/bin/time -v treelod build …` reports it (see `docs/cli.md`).

mod common;

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, build_block, demo_tree, import_gltf_bytes};
use treelod_format::Compression;

fn build(c: &mut Criterion) {
    let mut group = c.benchmark_group("build");
    group.sample_size(10);
    let demo = demo_tree(&DemoTreeConfig::default());
    group.throughput(Throughput::Elements(common::triangles(&demo)));
    group.bench_function("demo tree", |b| {
        b.iter(|| {
            let placed = [Placed { scene: &demo, translation: glam::Vec3::ZERO }];
            let out = build_block("demo", &placed, &BuildConfig::default(), "bench").expect("demo builds");
            black_box(out.data.to_bytes(Compression::default()).expect("encodes"))
        });
    });
    let models = [
        "quaternius-common-tree-1-3k.glb",
        "ez-tree-oak-large-23k.glb",
        "plantcatalog-hk-orchid-tree-31k.glb",
        "polyhaven-jacaranda-tree-55k.glb",
    ];
    for (model, path, bytes) in common::read_models(&models) {
        let scene = import_gltf_bytes(&bytes, &path, path.parent()).expect("shared model imports");
        group.throughput(Throughput::Elements(common::triangles(&scene)));
        drop(scene);
        group.bench_function(model, |b| {
            b.iter(|| {
                let scene = import_gltf_bytes(&bytes, &path, path.parent()).expect("shared model imports");
                let placed = [Placed { scene: &scene, translation: glam::Vec3::ZERO }];
                let out = build_block(&scene.name, &placed, &BuildConfig::default(), "bench").expect("builds");
                black_box(out.data.to_bytes(Compression::default()).expect("encodes"))
            });
        });
    }
    group.finish();
}

criterion_group!(benches, build);
criterion_main!(benches);
