//! `Container::open` costs the same for a 1 MiB and a 1 GiB file: it reads the header, the section
//! table, `META`, `BLOCK` and `CELLS`, never the bulk arrays (spec §9.1). A compressed section is
//! decoded at open: `open compressed 48 MB` times a byte-shuffled `VERTICES` section of 1.71 M
//! records (spec §8), as the build's verification and every load of a distributed container pay it.
//!
//! Run with `cargo bench -p treelod-format --bench open`. The files are written once into a
//! temporary directory (the 1 GiB one takes a few seconds and 1 GiB of disk).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use treelod_format::{BlockRecord, CellRecord, Compression, Container, ContainerData, Metadata, VertexRecord};

/// A container whose `VERTICES` section holds about `bytes` raw bytes, written with `compression`.
fn write_container(path: &Path, bytes: usize, compression: Compression) {
    let count = bytes / size_of::<VertexRecord>();
    #[expect(clippy::cast_precision_loss, clippy::cast_possible_truncation, reason = "bench values")]
    let vertices: Vec<VertexRecord> = (0..count)
        .map(|i| VertexRecord {
            position: [i as f32, (i % 1000) as f32 * 0.01, (i / 1000) as f32 * 0.25],
            normal: (i as u32).wrapping_mul(0x9E37_79B9) >> 8,
            uv: [(i % 64) as f32 / 64.0, 1.0],
            color: u32::MAX,
        })
        .collect();
    let cells = vec![CellRecord::default(); 65];
    let data = ContainerData {
        metadata: Metadata { generator: "bench".into(), name: "open".into(), ..Metadata::default() },
        block: BlockRecord { bounds_max: [1.0; 3], grid: [4, 4, 4], tree_count: 1, ..BlockRecord::default() },
        cells,
        vertices,
        ..ContainerData::default()
    };
    data.write_to_path(path, compression).expect("bench container writes");
}

fn open(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temporary directory");
    let cases = [
        ("1 MiB", 1usize << 20, Compression::None),
        ("1 GiB", 1 << 30, Compression::None),
        ("compressed 48 MB", 48_000_000, Compression::default()),
    ];
    for (name, bytes, compression) in cases {
        let path = dir.path().join(format!("{bytes}.treelod"));
        write_container(&path, bytes, compression);
        c.bench_function(&format!("open {name}"), |b| b.iter(|| black_box(Container::open(&path).expect("opens"))));
    }
}

criterion_group!(benches, open);
criterion_main!(benches);
