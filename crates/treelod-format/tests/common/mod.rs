//! Helpers shared by the format crate's integration tests.

use treelod_format::{
    BlockRecord, CellRecord, ContainerData, MaterialInfo, MaterialRecord, Metadata, NO_IMAGE, PointRecord, Range,
    TriangleRecord, VertexRecord, pack,
};

/// A 1×1×1 block whose one cell holds one leaf triangle (area 0.08) under its leaf point, and an
/// empty block cell; one untextured, opaque, two-sided leaf material. Fixtures add to it.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn one_leaf_cell(name: &str) -> ContainerData {
    let corners = [[0.2, 0.2, 0.5], [0.6, 0.2, 0.5], [0.2, 0.6, 0.5]];
    let vertices: Vec<VertexRecord> = corners
        .iter()
        .map(|&position| VertexRecord {
            position,
            normal: pack::oct_encode([0.0, 0.0, 1.0]),
            uv: [0.5, 0.5],
            color: u32::MAX,
        })
        .collect();
    // Area 0.08: size = 2·sqrt(0.08/π).
    let size = 2.0 * (0.08f32 / std::f32::consts::PI).sqrt();
    let range = |first, count| Range { first, count };
    ContainerData {
        metadata: Metadata {
            generator: "test".into(),
            name: name.into(),
            materials: vec![MaterialInfo { name: "leaf".into(), classified_by: "name".into() }],
            sources: vec![treelod_format::Source::default()],
            trees: vec![treelod_format::Tree::default()],
            ..Metadata::default()
        },
        block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells: vec![
            CellRecord {
                bounds_min: [0.2, 0.2, 0.5],
                bounds_max: [0.6, 0.6, 0.5],
                triangles: range(0, 1),
                points: range(0, 1),
                ..CellRecord::default()
            },
            CellRecord { triangles: range(1, 0), points: range(1, 0), ..CellRecord::default() },
        ],
        vertices,
        triangles: vec![TriangleRecord { indices: [0, 1, 2], size, leaf: 0, material: 0 }],
        points: vec![PointRecord {
            position: [0.2 + 0.4 / 3.0, 0.2 + 0.4 / 3.0, 0.5],
            radius: size / 2.0,
            normal: pack::oct_encode([0.0, 0.0, 1.0]),
            color: 0xFF33_9933,
            size,
            lo: 0.0,
            hi: f32::INFINITY,
            leaf_first: 0,
            leaf_count: 1,
            flags: 0,
        }],
        materials: vec![MaterialRecord {
            base_color: [0.2, 0.6, 0.1, 1.0],
            image: NO_IMAGE,
            alpha_mode: 0,
            alpha_cutoff: 0.5,
            class: 1,
            flags: 1,
            _pad: 0,
        }],
        ..ContainerData::default()
    }
}

#[allow(dead_code, reason = "not every test binary uses every helper")]
/// Recomputes every section checksum and the header checksum after a byte-level edit.
pub fn reseal(bytes: &mut [u8]) {
    let count = u32::from_le_bytes(bytes[20..24].try_into().expect("8 or 4 bytes")) as usize;
    let table = u64::from_le_bytes(bytes[24..32].try_into().expect("8 or 4 bytes")) as usize;
    for i in 0..count {
        let at = table + 48 * i;
        let offset = u64::from_le_bytes(bytes[at + 8..at + 16].try_into().expect("8 or 4 bytes")) as usize;
        let length = u64::from_le_bytes(bytes[at + 16..at + 24].try_into().expect("8 or 4 bytes")) as usize;
        let crc = crc32fast::hash(&bytes[offset..offset + length]);
        bytes[at + 36..at + 40].copy_from_slice(&crc.to_le_bytes());
    }
    let mut crc = crc32fast::Hasher::new();
    crc.update(&bytes[..60]);
    crc.update(&[0; 4]);
    crc.update(&bytes[table..table + 48 * count]);
    let sum = crc.finalize();
    bytes[60..64].copy_from_slice(&sum.to_le_bytes());
}

/// `data` written uncompressed; content that `verify` refuses still writes.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn bytes_of(data: &ContainerData) -> Vec<u8> {
    data.to_bytes(treelod_format::Compression::None).expect("invalid content still writes")
}

/// `verify` of `data` written and opened (opening checks only structure, not content).
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn check(data: &ContainerData) -> Result<treelod_format::VerifyReport, treelod_format::Error> {
    let bytes = bytes_of(data);
    let c = treelod_format::Container::from_bytes(&bytes).expect("opens: only verify checks content");
    treelod_format::verify(&c)
}
