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

/// A branch line from `p0` (radius 0.02) to `p1` (radius 0.01), drawn at every `τ`, standing for
/// the cell's leaf 0.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn branch_line(p0: [f32; 3], p1: [f32; 3]) -> treelod_format::LineRecord {
    treelod_format::LineRecord {
        p0,
        r0: 0.02,
        p1,
        r1: 0.01,
        color: 0xFF20_4060,
        lo: 0.0,
        hi: f32::INFINITY,
        leaf_first: 0,
        leaf_count: 1,
        flags: 0,
    }
}

/// A 2×2 mid-grey RGBA8 sRGB image, the only image of `data` (`IMAGES` index 0), for planes to
/// sample.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn grey_image(data: &mut ContainerData) {
    data.images = vec![treelod_format::ImageRecord {
        width: 2,
        height: 2,
        mip_count: 1,
        format: treelod_format::image_format::RGBA8_SRGB,
        data_offset: 0,
        data_length: 16,
    }];
    data.image_data = vec![0x80; 16];
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

/// Where the section-table entry of `kind` starts in the container `bytes` (spec §4).
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn entry_offset(bytes: &[u8], kind: treelod_format::SectionKind) -> usize {
    let count = u32::from_le_bytes(bytes[20..24].try_into().expect("4 bytes")) as usize;
    let table = u64::from_le_bytes(bytes[24..32].try_into().expect("8 bytes")) as usize;
    (0..count)
        .map(|i| table + 48 * i)
        .find(|&at| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) == kind.0)
        .expect("the section is present")
}

/// `bytes` with the section-table entry of `from` relabelled `to` (a kind a reader may not know),
/// resealed.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn relabel(bytes: &[u8], from: treelod_format::SectionKind, to: u32) -> Vec<u8> {
    let mut bytes = bytes.to_vec();
    let at = entry_offset(&bytes, from);
    bytes[at..at + 4].copy_from_slice(&to.to_le_bytes());
    reseal(&mut bytes);
    bytes
}

/// Changes the stored and decoded length of the (uncompressed) section `kind` by `delta` bytes,
/// zeroing the bytes that leave or join it (growing the file past its last section), and reseals
/// the file.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn resize_section(bytes: &[u8], kind: treelod_format::SectionKind, delta: i64) -> Vec<u8> {
    let mut bytes = bytes.to_vec();
    let at = entry_offset(&bytes, kind);
    assert_eq!(u32::from_le_bytes(bytes[at + 4..at + 8].try_into().expect("4 bytes")), 0, "stored uncompressed");
    let offset = u64::from_le_bytes(bytes[at + 8..at + 16].try_into().expect("8 bytes"));
    let length = u64::from_le_bytes(bytes[at + 16..at + 24].try_into().expect("8 bytes"));
    let new_length = length.checked_add_signed(delta).expect("a length");
    assert!(new_length <= length.next_multiple_of(16), "stays within the section's padding");
    let changed = (offset + length.min(new_length)) as usize..(offset + length.max(new_length)) as usize;
    if changed.end > bytes.len() {
        // The file's last section: the file grows with it.
        bytes.resize(changed.end, 0);
        let file_size = bytes.len() as u64;
        bytes[32..40].copy_from_slice(&file_size.to_le_bytes());
    }
    bytes[changed].fill(0);
    bytes[at + 16..at + 24].copy_from_slice(&new_length.to_le_bytes());
    bytes[at + 24..at + 32].copy_from_slice(&new_length.to_le_bytes());
    reseal(&mut bytes);
    bytes
}

/// That `data`, written with `compression` as `bytes` and opened as `c`, reads back as itself and
/// writes the same bytes again.
#[allow(dead_code, reason = "not every test binary uses every helper")]
pub fn assert_reads_back(
    c: &treelod_format::Container,
    data: &ContainerData,
    bytes: &[u8],
    compression: treelod_format::Compression,
) {
    let back = ContainerData::from_container(c);
    assert_eq!(&back, data);
    assert_eq!(back.to_bytes(compression).expect("writes"), bytes, "{compression:?}");
}

/// Asserts that `verify` refuses `data` (written and opened, [`check`]) with a `BadRecord` of
/// `kind` at `index` whose reason mentions every needle, whose message is the kind, the record and
/// the reason, and whose class is `Invalid`. Returns the reason, for a test that expects it
/// exactly.
#[allow(dead_code, reason = "not every test binary uses every helper")]
#[track_caller]
pub fn expect_refused(
    data: &ContainerData,
    kind: treelod_format::SectionKind,
    index: usize,
    needles: &[&str],
) -> String {
    match check(data) {
        Err(ref e @ treelod_format::Error::BadRecord { kind: k, index: i, ref reason })
            if k == kind && i == index && needles.iter().all(|n| reason.contains(n)) =>
        {
            let message = e.to_string();
            assert_eq!(message, format!("{kind} record {index}: {reason}"));
            assert_eq!(e.class(), treelod_format::ErrorClass::Invalid, "{message}");
            reason.clone()
        }
        other => panic!("expected BadRecord {kind} {index} ({needles:?}), got {other:?}"),
    }
}
