//! Smallest round trip: a one-cell container with no geometry.
use treelod_format::{BlockRecord, CellRecord, Compression, Container, ContainerData, Metadata};

#[test]
fn empty_block_round_trips() {
    let data = ContainerData {
        metadata: Metadata { generator: "test".into(), name: "empty".into(), ..Metadata::default() },
        block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells: vec![CellRecord::default(); 2],
        ..ContainerData::default()
    };
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(ContainerData::from_container(&c), data);
        assert_eq!(bytes.len() as u64, c.header().file_size);
    }
}

#[test]
fn compressed_record_arrays_are_shuffled_and_round_trip() {
    use treelod_format::{FLAG_SHUFFLE, FLAG_ZSTD, SectionKind, VertexRecord};
    let vertices: Vec<VertexRecord> = (0..4000u32)
        .map(|i| VertexRecord { position: [i as f32 * 0.01, 1.0, 2.0], normal: i, uv: [0.5, 0.25], color: u32::MAX })
        .collect();
    let data = ContainerData {
        metadata: Metadata::default(),
        block: BlockRecord { bounds_max: [40.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells: vec![CellRecord::default(); 2],
        vertices,
        ..ContainerData::default()
    };
    let bytes = data.to_bytes(Compression::default()).expect("writes");
    let c = Container::from_bytes(&bytes).expect("opens");
    let section = c.section(SectionKind::VERTICES).expect("present");
    assert_eq!(section.entry.flags, FLAG_ZSTD | FLAG_SHUFFLE);
    assert!(section.entry.length * 4 < section.entry.raw_length, "shuffled vertices compress 4x");
    assert_eq!(c.vertices(), &data.vertices[..]);
}
