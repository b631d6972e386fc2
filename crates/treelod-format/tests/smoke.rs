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

#[test]
fn verify_checks_metadata_against_the_records() {
    use treelod_format::{MaterialInfo, MaterialRecord, Setting, Tree, verify};
    let good = ContainerData {
        metadata: Metadata {
            trees: vec![Tree::default()],
            sources: vec![treelod_format::Source::default()],
            materials: vec![MaterialInfo::default()],
            settings: vec![
                Setting { key: "a".into(), value: "1".into() },
                Setting { key: "b".into(), value: "2".into() },
            ],
            ..Metadata::default()
        },
        block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells: vec![CellRecord::default(); 2],
        materials: vec![MaterialRecord { image: treelod_format::NO_IMAGE, ..MaterialRecord::default() }],
        ..ContainerData::default()
    };
    let check = |data: &ContainerData| {
        let bytes = data.to_bytes(Compression::None).expect("writes");
        verify(&Container::from_bytes(&bytes).expect("opens")).map(|_| ()).map_err(|e| e.to_string())
    };
    check(&good).expect("consistent metadata verifies");
    let mut two_trees = good.clone();
    two_trees.block.tree_count = 2;
    assert!(check(&two_trees).unwrap_err().contains("1 trees listed, BLOCK says tree_count = 2"));
    let mut no_material_names = good.clone();
    no_material_names.metadata.materials.clear();
    assert!(check(&no_material_names).unwrap_err().contains("0 material entries for 1 MATERIALS records"));
    let mut unsorted = good.clone();
    unsorted.metadata.settings.reverse();
    assert!(check(&unsorted).unwrap_err().contains("not sorted"));
    let mut dangling = good;
    dangling.metadata.trees[0].source = 5;
    assert!(check(&dangling).unwrap_err().contains("names source 5"));
}
