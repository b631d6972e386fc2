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
