//! `Container::open` costs the same for a 1 MiB and a 1 GiB file: it reads the header, the section
//! table, `META`, `BLOCK` and `CELLS`, never the bulk arrays (spec §9.1).
//!
//! Run with `cargo bench -p treelod-format --bench open`. The two files are written once into a
//! temporary directory (the 1 GiB one takes a few seconds and 1 GiB of disk).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use treelod_format::{BlockRecord, CellRecord, Compression, Container, ContainerData, Metadata, VertexRecord};

/// An uncompressed container whose `VERTICES` section makes it about `bytes` long.
fn write_container(path: &Path, bytes: usize) {
    let count = bytes / size_of::<VertexRecord>();
    let vertices: Vec<VertexRecord> = (0..count)
        .map(|i| VertexRecord { position: [i as f32, 0.5, 0.25], normal: 0, uv: [0.0, 1.0], color: u32::MAX })
        .collect();
    let cells = vec![CellRecord::default(); 65];
    let data = ContainerData {
        metadata: Metadata { generator: "bench".into(), name: "open".into(), ..Metadata::default() },
        block: BlockRecord { bounds_max: [1.0; 3], grid: [4, 4, 4], tree_count: 1, ..BlockRecord::default() },
        cells,
        vertices,
        ..ContainerData::default()
    };
    data.write_to_path(path, Compression::None).expect("bench container writes");
}

fn open(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temporary directory");
    for (name, bytes) in [("1 MiB", 1usize << 20), ("1 GiB", 1usize << 30)] {
        let path = dir.path().join(format!("{}.treelod", bytes));
        write_container(&path, bytes);
        c.bench_function(&format!("open {name}"), |b| b.iter(|| black_box(Container::open(&path).expect("opens"))));
    }
}

criterion_group!(benches, open);
criterion_main!(benches);
