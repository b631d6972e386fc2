//! Full verification (spec §9.2): a small valid container passes, then each rule is broken once and
//! the specific error is expected. The exact-cut sweep is also checked against a brute-force oracle.

mod common;

use common::reseal;
use treelod_format::{
    BillboardRecord, BlockRecord, CellRecord, Compression, Container, ContainerData, CurveSample, EllipsoidRecord,
    Error, ImageRecord, LineRecord, LodLevelRecord, MaterialInfo, MaterialRecord, Metadata, NO_IMAGE, PlaneRecord,
    PointRecord, PruneLeafRecord, Range, SectionKind, SptSummary, TriangleRecord, VerifyReport, VertexRecord,
    billboard_kind, check_point_cut, check_spt, image_format, pack, triangle_leaf_sizes, verify,
};

const INF: f32 = f32::INFINITY;

fn range(first: u32, count: u32) -> Range {
    Range { first, count }
}

fn point(position: [f32; 3], size: f32, lo: f32, hi: f32, leaf_first: u32, leaf_count: u32) -> PointRecord {
    PointRecord {
        position,
        radius: size / 2.0,
        normal: pack::oct_encode([0.0, 0.0, 1.0]),
        color: 0xFF33_6633,
        size,
        lo,
        hi,
        leaf_first,
        leaf_count,
        flags: 0,
    }
}

fn ellipsoid(lo: f32, hi: f32, leaf_first: u32, leaf_count: u32) -> EllipsoidRecord {
    EllipsoidRecord {
        center: [3.0, 1.0, 1.0],
        radii: [0.5, 0.4, 0.3],
        orientation: [0, 0, 0, i16::MAX],
        color: 0xFF00_FF00,
        alpha_threshold: 0.5,
        noise_mip: 1.0,
        lo,
        hi,
        leaf_first,
        leaf_count,
        flags: 0,
    }
}

/// Three cells on a 2×1×1 grid: cell 0 holds 4 triangles under a 7-point binary hierarchy (spec
/// §6.5), cell 1 is empty, the block cell holds an ellipsoid hierarchy over 3 leaves, a line, a
/// plane and two pruned leaves. Two images: raw RGBA8 with two mip levels, and a PNG.
fn valid() -> ContainerData {
    // Triangle i has vertices 3i..3i+3 in cell 0's box (x in 0..2).
    let mut vertices = Vec::new();
    for i in 0..4 {
        let x = 0.2 + 0.4 * i as f32;
        for p in [[x, 0.1, 0.5], [x + 0.2, 0.1, 0.5], [x, 0.3, 0.5]] {
            vertices.push(VertexRecord {
                position: p,
                normal: pack::oct_encode([0.0, 0.0, 1.0]),
                uv: [0.5, 0.5],
                color: u32::MAX,
            });
        }
    }
    // Sorted by size, largest first; leaf ids in depth-first order of the hierarchy below.
    let sizes = [0.4, 0.3, 0.2, 0.1];
    let leaves = [2, 0, 3, 1];
    let triangles: Vec<TriangleRecord> = (0..4)
        .map(|i| TriangleRecord {
            indices: [3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2],
            size: sizes[i],
            leaf: leaves[i],
            material: 0,
        })
        .collect();
    // Leaf sizes: leaf 0 = 0.3, 1 = 0.1, 2 = 0.4, 3 = 0.2. Inner A = {0, 1} size 0.5, B = {2, 3}
    // size 0.6, root size 1.0. Each node's hi is its parent's lo; sorted by hi, largest first.
    let c = [1.0, 1.0, 1.0];
    let points = vec![
        point(c, 1.0, 1.0, INF, 0, 4),
        point(c, 0.5, 0.5, 1.0, 0, 2),
        point(c, 0.6, 0.6, 1.0, 2, 2),
        point(c, 0.4, 0.0, 0.6, 2, 1),
        point(c, 0.2, 0.0, 0.6, 3, 1),
        point(c, 0.3, 0.0, 0.5, 0, 1),
        point(c, 0.1, 0.0, 0.5, 1, 1),
    ];
    // Root [2, inf) over leaves 0..3; X [1, 2) over 0..2; leaf ellipsoids; leaf 2 skips a level.
    let ellipsoids = vec![
        ellipsoid(2.0, INF, 0, 3),
        ellipsoid(1.0, 2.0, 0, 2),
        ellipsoid(0.0, 2.0, 2, 1),
        ellipsoid(0.0, 1.0, 0, 1),
        ellipsoid(0.0, 1.0, 1, 1),
    ];
    let lines = vec![LineRecord {
        p0: [2.5, 0.5, 0.5],
        r0: 0.1,
        p1: [3.0, 1.5, 1.0],
        r1: 0.05,
        color: 0xFF22_4466,
        lo: 0.0,
        hi: INF,
        leaf_first: 0,
        leaf_count: 1,
        flags: 0,
    }];
    let planes = vec![PlaneRecord {
        center: [3.0, 1.0, 1.0],
        axis_u: [0.5, 0.0, 0.0],
        axis_v: [0.0, 0.5, 0.0],
        image: 0,
        uv_min: pack::unorm16x2(0.0, 0.0),
        uv_max: pack::unorm16x2(1.0, 0.5),
        lo: 0.0,
        hi: INF,
        leaf_first: 0,
        leaf_count: 1,
    }];
    let prune_leaves = vec![
        PruneLeafRecord { center: [3.0, 1.0, 1.0], area: 0.02, first_triangle: 0, triangle_count: 1 },
        PruneLeafRecord { center: [3.5, 1.0, 1.0], area: 0.01, first_triangle: 1, triangle_count: 2 },
    ];
    let prune_triangles = vec![
        TriangleRecord { indices: [0, 1, 2], size: 0.1, leaf: 0, material: 0 },
        TriangleRecord { indices: [3, 4, 5], size: 0.1, leaf: 1, material: 0 },
        TriangleRecord { indices: [6, 7, 8], size: 0.1, leaf: 1, material: 0 },
    ];
    let mut image_data = vec![0x80; 20];
    image_data.resize(32, 0);
    image_data.extend_from_slice(&[0x89, 0x50, 0x4E, 0x47, 0x0D, 0x0A, 0x1A, 0x0A, 1, 2, 3, 4, 5, 6, 7, 8]);
    let images = vec![
        ImageRecord {
            width: 2,
            height: 2,
            mip_count: 2,
            format: image_format::RGBA8_SRGB,
            data_offset: 0,
            data_length: 20,
        },
        ImageRecord { width: 4, height: 4, mip_count: 1, format: image_format::PNG, data_offset: 32, data_length: 16 },
    ];
    let cells = vec![
        CellRecord {
            bounds_min: [0.0; 3],
            bounds_max: [2.0; 3],
            triangles: range(0, 4),
            points: range(0, 7),
            ..CellRecord::default()
        },
        CellRecord { triangles: range(4, 0), points: range(7, 0), ..CellRecord::default() },
        CellRecord {
            bounds_min: [2.0, 0.0, 0.0],
            bounds_max: [4.0, 2.0, 2.0],
            triangles: range(4, 0),
            points: range(7, 0),
            ellipsoids: range(0, 5),
            lines: range(0, 1),
            planes: range(0, 1),
            prune_leaves: range(0, 2),
            ..CellRecord::default()
        },
    ];
    ContainerData {
        metadata: Metadata {
            generator: "test".into(),
            name: "fixture".into(),
            materials: vec![MaterialInfo { name: "leaf".into(), classified_by: "name".into() }],
            sources: vec![treelod_format::Source::default()],
            trees: vec![treelod_format::Tree::default()],
            ..Metadata::default()
        },
        block: BlockRecord { bounds_max: [4.0, 2.0, 2.0], grid: [2, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells,
        vertices,
        triangles,
        points,
        materials: vec![MaterialRecord {
            base_color: [1.0; 4],
            image: 0,
            alpha_mode: 1,
            alpha_cutoff: 0.5,
            class: 1,
            flags: 1,
            _pad: 0,
        }],
        images,
        image_data,
        ellipsoids,
        lines,
        planes,
        prune_leaves,
        prune_triangles,
        prune_scale: vec![CurveSample { x: 0.1, y: 2.0 }, CurveSample { x: 1.0, y: 1.0 }],
        prune_lambda: vec![CurveSample { x: 10.0, y: 0.2 }, CurveSample { x: 100.0, y: 1.0 }],
        // A two-level chain over triangles 0..2 and 0..1, and a facing plus one crossed billboard.
        lod_levels: vec![
            LodLevelRecord { tree: 0, level: 0, triangles: range(0, 2), error: 0.01, fraction: 0.5 },
            LodLevelRecord { tree: 0, level: 1, triangles: range(2, 1), error: 0.05, fraction: 0.25 },
        ],
        lod_triangles: vec![
            TriangleRecord { indices: [0, 1, 2], size: 0.2, leaf: 0, material: 0 },
            TriangleRecord { indices: [3, 4, 5], size: 0.2, leaf: 0, material: 0 },
            TriangleRecord { indices: [0, 4, 2], size: 0.3, leaf: 0, material: 0 },
        ],
        billboards: [billboard_kind::FACING, billboard_kind::CROSSED]
            .map(|kind| BillboardRecord {
                center: [2.0, 1.0, 1.0],
                axis_u: [1.0, 0.0, 0.0],
                axis_v: [0.0, 1.0, 0.0],
                image: 0,
                uv_min: 0,
                uv_max: pack::unorm16x2(1.0, 1.0),
                tree: 0,
                kind,
                reserved: [0; 2],
            })
            .to_vec(),
        ..ContainerData::default()
    }
}

fn bytes_of(data: &ContainerData) -> Vec<u8> {
    data.to_bytes(Compression::None).expect("invalid content still writes")
}

fn verify_bytes(bytes: &[u8]) -> Result<VerifyReport, Error> {
    let c = Container::from_bytes(bytes).expect("opens: only verify checks content");
    verify(&c)
}

fn check(data: &ContainerData) -> Result<VerifyReport, Error> {
    verify_bytes(&bytes_of(data))
}

/// Asserts a `BadRecord` of `kind` at `index` whose reason mentions `needle`.
#[track_caller]
fn expect_record(data: &ContainerData, kind: SectionKind, index: usize, needle: &str) {
    match check(data) {
        Err(Error::BadRecord { kind: k, index: i, reason }) if k == kind && i == index && reason.contains(needle) => {}
        other => panic!("expected BadRecord {kind} {index} ({needle}), got {other:?}"),
    }
}

/// Asserts a `BadCell` for `cell` whose reason mentions `needle`.
#[track_caller]
fn expect_cell(data: &ContainerData, cell: usize, needle: &str) {
    match check(data) {
        Err(Error::BadCell { cell: c, reason }) if c == cell && reason.contains(needle) => {}
        other => panic!("expected BadCell {cell} ({needle}), got {other:?}"),
    }
}

/// Offset and length of the stored payload of `kind`.
fn section_span(bytes: &[u8], kind: SectionKind) -> (usize, usize) {
    let c = Container::from_bytes(bytes).expect("opens");
    let e = c.section(kind).expect("present").entry;
    (e.offset as usize, e.length as usize)
}

// ----------------------------------------------------------------------------------------------
// The valid fixture.

#[test]
fn the_fixture_verifies_with_full_counts() {
    let data = valid();
    let report = check(&data).expect("valid");
    assert_eq!(report.cells, 3);
    assert_eq!(report.empty_cells, 1);
    assert_eq!((report.vertices, report.triangles, report.points), (12, 4, 7));
    assert_eq!((report.materials, report.images, report.image_data_bytes), (1, 2, 48));
    assert_eq!((report.ellipsoids, report.lines, report.planes), (5, 1, 1));
    assert_eq!((report.prune_leaves, report.prune_triangles, report.curve_samples), (2, 3, 4));
    assert_eq!((report.lod_levels, report.lod_triangles, report.billboards), (2, 3, 2));
    // 4 point leaves + 3 ellipsoid leaves + 1 line leaf + 1 plane leaf.
    assert_eq!(report.cut_leaves, 9);
    assert_eq!(report.max_depth, 3);
    let bytes = bytes_of(&data);
    let c = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(report.sections, c.sections().len());
    assert_eq!(report.checksummed_bytes, c.sections().iter().map(|s| s.entry.length).sum::<u64>());
    assert!(report.padding_bytes > 0, "META's end is padded to 16 bytes");
    let text = report.to_string();
    assert!(text.contains("7 points") && text.contains("9 leaves"), "{text}");
    assert!(text.contains("2 LoD levels, 3 LoD triangles, 2 billboards"), "{text}");
}

#[test]
fn the_compressed_fixture_verifies() {
    let bytes = valid().to_bytes(Compression::default()).expect("writes");
    let c = Container::from_bytes(&bytes).expect("opens");
    assert!(c.sections().iter().any(|s| s.is_compressed()));
    verify(&c).expect("valid");
}

#[test]
fn nonzero_reserved_fields_are_ignored() {
    let mut data = valid();
    data.block.flags = 7;
    data.block._pad = 1;
    data.cells[0].flags = 1;
    data.cells[1]._pad = 9;
    data.points[0].flags = 3;
    data.ellipsoids[0].flags = 3;
    data.lines[0].flags = 3;
    data.materials[0].flags = u32::MAX;
    data.materials[0]._pad = 5;
    data.materials[0].alpha_mode = 77; // an enumeration value of a later version
    data.materials[0].class = 9;
    check(&data).expect("reserved values and unknown enumerations are kept, not refused");
}

#[test]
fn unknown_image_formats_are_checked_only_for_their_range() {
    let mut data = valid();
    data.images[1] =
        ImageRecord { width: 0, height: 99_999, mip_count: 0, format: 42, data_offset: 32, data_length: 16 };
    check(&data).expect("valid");
    data.images[1].data_length = 17;
    expect_record(&data, SectionKind::IMAGES, 1, "reaches past IMAGE_DATA");
}

// ----------------------------------------------------------------------------------------------
// File level.

#[test]
fn a_flipped_bit_in_an_uncompressed_section_is_a_checksum_mismatch() {
    let mut bytes = bytes_of(&valid());
    let (offset, _) = section_span(&bytes, SectionKind::VERTICES);
    bytes[offset + 5] ^= 0x10;
    match verify_bytes(&bytes) {
        Err(Error::ChecksumMismatch { what, stored, computed }) => {
            assert!(what.contains("VERTICES"), "{what}");
            assert_ne!(stored, computed);
        }
        other => panic!("expected ChecksumMismatch, got {other:?}"),
    }
}

#[test]
fn a_nonzero_padding_byte_is_refused() {
    let mut bytes = bytes_of(&valid());
    let c = Container::from_bytes(&bytes).expect("opens");
    // The first section whose end is not on a 16-byte boundary is followed by padding.
    let (index, entry) = c
        .sections()
        .iter()
        .map(|s| s.entry)
        .enumerate()
        .find(|(_, e)| (e.offset + e.length) % 16 != 0)
        .expect("some section is padded");
    let at = (entry.offset + entry.length) as usize;
    bytes[at] = 1;
    match verify_bytes(&bytes) {
        Err(Error::BadSection { index: i, reason, .. }) => {
            assert_eq!(i, index + 1, "reported against the section after the gap");
            assert!(reason.contains(&format!("offset {at}")), "{reason}");
        }
        other => panic!("expected BadSection, got {other:?}"),
    }
}

#[test]
fn the_file_ends_where_its_last_section_ends() {
    // Spec §1: file_size is the end of the last section, so even zero bytes after it (declared in
    // file_size, so open accepts them) are refused by verify.
    let mut bytes = bytes_of(&valid());
    let len = bytes.len();
    bytes.extend_from_slice(&[0; 16]);
    bytes[32..40].copy_from_slice(&(len as u64 + 16).to_le_bytes());
    reseal(&mut bytes);
    match verify_bytes(&bytes) {
        Err(Error::BadHeader { field: "file_size", value, .. }) => assert_eq!(value, len as u64 + 16),
        other => panic!("expected BadHeader file_size, got {other:?}"),
    }
}

#[test]
fn a_resealed_content_edit_reaches_the_record_checks() {
    // A NaN written into the points' bytes with the checksums recomputed: only the record rules can
    // catch it.
    let mut bytes = bytes_of(&valid());
    let (offset, _) = section_span(&bytes, SectionKind::POINTS);
    bytes[offset + 48..offset + 52].copy_from_slice(&f32::NAN.to_le_bytes());
    reseal(&mut bytes);
    match verify_bytes(&bytes) {
        Err(Error::BadRecord { kind, index: 1, .. }) if kind == SectionKind::POINTS => {}
        other => panic!("expected BadRecord POINTS 1, got {other:?}"),
    }
}

#[test]
fn byte_edits_never_panic() {
    // Payload edits are resealed so they reach the content checks; header and table edits are not
    // (open refuses most of them on the header checksum).
    let clean = bytes_of(&valid());
    let c = Container::from_bytes(&clean).expect("opens");
    let payloads = c.sections()[0].entry.offset as usize;
    let mut refused = 0;
    for at in 0..clean.len() {
        for pattern in [0x01u8, 0x80, 0xFF] {
            let mut bytes = clean.clone();
            bytes[at] ^= pattern;
            if at >= payloads {
                reseal(&mut bytes);
            }
            if let Ok(c) = Container::from_bytes(&bytes)
                && verify(&c).is_err()
            {
                refused += 1;
            }
        }
    }
    assert!(refused > 1000, "most content edits break a rule ({refused})");
}

// ----------------------------------------------------------------------------------------------
// Record rules (spec §6).

#[test]
fn vertex_rules() {
    let mut data = valid();
    data.vertices[4].position[1] = f32::NAN;
    expect_record(&data, SectionKind::VERTICES, 4, "position");
    let mut data = valid();
    data.vertices[2].uv[0] = INF;
    expect_record(&data, SectionKind::VERTICES, 2, "uv");
}

#[test]
fn triangle_rules() {
    let mut data = valid();
    data.triangles[1].indices[2] = 12;
    expect_record(&data, SectionKind::TRIANGLES, 1, "vertex index 12");
    let mut data = valid();
    data.triangles[3].material = 1;
    expect_record(&data, SectionKind::TRIANGLES, 3, "material 1");
    let mut data = valid();
    data.triangles[3].size = -0.1;
    expect_record(&data, SectionKind::TRIANGLES, 3, "size");
    let mut data = valid();
    data.triangles.swap(1, 2);
    expect_record(&data, SectionKind::TRIANGLES, 2, "sorts by size");
}

#[test]
fn triangle_leaf_ids_are_a_permutation() {
    // Leaf 4 instead of 1: out of range for 4 triangles, so leaf 1 is missing.
    let mut data = valid();
    data.triangles[3].leaf = 4;
    expect_record(&data, SectionKind::TRIANGLES, 3, "leaf 4 is out of range");
    let mut data = valid();
    data.triangles[3].leaf = 2;
    expect_record(&data, SectionKind::TRIANGLES, 3, "also the leaf of record 0");
}

#[test]
fn material_rules() {
    let mut data = valid();
    data.materials[0].image = 2;
    expect_record(&data, SectionKind::MATERIALS, 0, "image 2");
    let mut data = valid();
    data.materials[0].image = NO_IMAGE;
    check(&data).expect("no image is valid");
    data.materials[0].alpha_cutoff = 1.5;
    expect_record(&data, SectionKind::MATERIALS, 0, "alpha_cutoff");
    let mut data = valid();
    data.materials[0].base_color[3] = f32::NAN;
    expect_record(&data, SectionKind::MATERIALS, 0, "base_color");
}

#[test]
fn image_rules() {
    let mut data = valid();
    data.images[0].data_length = 16;
    expect_record(&data, SectionKind::IMAGES, 0, "needs Some(20)");
    let mut data = valid();
    data.images[0].mip_count = 3;
    expect_record(&data, SectionKind::IMAGES, 0, "mip_count 3");
    let mut data = valid();
    data.images[0].width = 0;
    expect_record(&data, SectionKind::IMAGES, 0, "width 0");
    let mut data = valid();
    data.images[1].data_offset = 8;
    expect_record(&data, SectionKind::IMAGES, 1, "multiple of 16");
    let mut data = valid();
    data.images[1].data_offset = 16; // 16..32 overlaps 0..20
    data.images[1].data_length = 16;
    data.image_data[16..24].copy_from_slice(&[0x89, 0x50, 0x4E, 0x47, 0x0D, 0x0A, 0x1A, 0x0A]);
    expect_record(&data, SectionKind::IMAGES, 1, "overlaps");
    let mut data = valid();
    data.image_data[32] = 0;
    expect_record(&data, SectionKind::IMAGES, 1, "PNG signature");
    let mut data = valid();
    data.images[1].format = image_format::JPEG;
    expect_record(&data, SectionKind::IMAGES, 1, "JPEG signature");
    let mut data = valid();
    data.images[1].mip_count = 2;
    expect_record(&data, SectionKind::IMAGES, 1, "mip_count 2");
}

#[test]
fn bc7_image_rules() {
    // Image 1 as one BC7 block of 4x4 texels: 16 bytes at 32.
    let bc7 = |data: &mut ContainerData| {
        data.images[1] = ImageRecord {
            width: 4,
            height: 4,
            mip_count: 1,
            format: image_format::BC7_SRGB,
            data_offset: 32,
            data_length: 16,
        };
    };
    let mut data = valid();
    bc7(&mut data);
    check(&data).expect("one 4x4 block verifies");
    // A file with a BC7 image is a 1.6 file; without, it keeps the minor of its kinds.
    assert_eq!(Container::from_bytes(&bytes_of(&data)).expect("opens").header().minor, 6);
    assert!(Container::from_bytes(&bytes_of(&valid())).expect("opens").header().minor < 6);
    // Its byte length must match its dimensions and levels.
    data.images[1].width = 8;
    expect_record(&data, SectionKind::IMAGES, 1, "needs Some(32)");
    let mut data = valid();
    bc7(&mut data);
    data.images[1].mip_count = 2; // 4x4 and 2x2: a block each
    expect_record(&data, SectionKind::IMAGES, 1, "needs Some(32)");
    let mut data = valid();
    bc7(&mut data);
    data.images[1].data_length = 8;
    expect_record(&data, SectionKind::IMAGES, 1, "data_length 8");
    // Sides are whole blocks.
    let mut data = valid();
    bc7(&mut data);
    data.images[1].height = 3;
    expect_record(&data, SectionKind::IMAGES, 1, "multiples of 4");
    // A level smaller than a block is one whole block: 8x8 with 4 levels is 4 + 1 + 1 + 1 blocks.
    let mut data = valid();
    data.image_data.resize(32 + 7 * 16, 0);
    data.images[1] = ImageRecord {
        width: 8,
        height: 8,
        mip_count: 4,
        format: image_format::BC7_LINEAR,
        data_offset: 32,
        data_length: 7 * 16,
    };
    check(&data).expect("partial blocks of small levels count whole");
}

#[test]
fn point_rules() {
    let mut data = valid();
    data.points[2].radius = -1.0;
    expect_record(&data, SectionKind::POINTS, 2, "radius");
    let mut data = valid();
    data.points[5].lo = INF;
    expect_record(&data, SectionKind::POINTS, 5, "lo inf");
    let mut data = valid();
    data.points[5].lo = 0.6;
    expect_record(&data, SectionKind::POINTS, 5, "below lo");
    let mut data = valid();
    data.points[6].hi = f32::NAN;
    expect_record(&data, SectionKind::POINTS, 6, "NaN");
    let mut data = valid();
    data.points[4].leaf_count = 0;
    expect_record(&data, SectionKind::POINTS, 4, "leaf_count is 0");
    let mut data = valid();
    data.points.swap(2, 3);
    expect_record(&data, SectionKind::POINTS, 3, "sorts by hi");
}

#[test]
fn ellipsoid_line_plane_rules() {
    let mut data = valid();
    data.ellipsoids[1].radii[2] = -0.5;
    expect_record(&data, SectionKind::ELLIPSOIDS, 1, "radii");
    let mut data = valid();
    data.ellipsoids[1].alpha_threshold = 2.0;
    expect_record(&data, SectionKind::ELLIPSOIDS, 1, "alpha_threshold");
    let mut data = valid();
    data.ellipsoids.swap(1, 3); // root inf, e0 1, e2 2, ...
    expect_record(&data, SectionKind::ELLIPSOIDS, 2, "sorts by hi");
    let mut data = valid();
    data.lines[0].r1 = f32::NAN;
    expect_record(&data, SectionKind::LINES, 0, "radii");
    let mut data = valid();
    data.lines[0].p1[0] = -INF;
    expect_record(&data, SectionKind::LINES, 0, "endpoints");
    let mut data = valid();
    data.planes[0].image = NO_IMAGE;
    expect_record(&data, SectionKind::PLANES, 0, "image 4294967295");
    let mut data = valid();
    data.planes[0].uv_max = pack::unorm16x2(1.0, 0.0);
    data.planes[0].uv_min = pack::unorm16x2(0.0, 0.1);
    expect_record(&data, SectionKind::PLANES, 0, "uv_min");
}

#[test]
fn prune_rules() {
    let mut data = valid();
    data.prune_triangles[2].leaf = 0;
    expect_record(&data, SectionKind::PRUNE_TRIANGLES, 2, "pruned leaf 1");
    let mut data = valid();
    data.prune_leaves[1].first_triangle = 2;
    data.prune_leaves[1].triangle_count = 1;
    expect_record(&data, SectionKind::PRUNE_LEAVES, 1, "expected 1");
    let mut data = valid();
    data.prune_leaves[1].triangle_count = 1;
    expect_record(&data, SectionKind::PRUNE_TRIANGLES, 2, "belongs to no pruned leaf");
    let mut data = valid();
    data.prune_leaves[1].triangle_count = 3;
    expect_record(&data, SectionKind::PRUNE_LEAVES, 1, "reach past");
    let mut data = valid();
    data.prune_leaves[0].triangle_count = 0;
    expect_record(&data, SectionKind::PRUNE_LEAVES, 0, "triangle_count is 0");
    let mut data = valid();
    data.prune_leaves[0].area = -1.0;
    expect_record(&data, SectionKind::PRUNE_LEAVES, 0, "area");
    let mut data = valid();
    data.prune_triangles[0].indices[0] = 99;
    expect_record(&data, SectionKind::PRUNE_TRIANGLES, 0, "vertex index 99");
}

#[test]
fn lod_chain_rules() {
    let mut data = valid();
    data.lod_levels[1].tree = 1;
    expect_record(&data, SectionKind::LOD_LEVELS, 1, "tree 1 is out of range");
    let mut data = valid();
    data.lod_levels[1].level = 2;
    expect_record(&data, SectionKind::LOD_LEVELS, 1, "level 2, expected 1");
    let mut data = valid();
    data.lod_levels[1].fraction = 0.5;
    expect_record(&data, SectionKind::LOD_LEVELS, 1, "not below the previous level");
    let mut data = valid();
    data.lod_levels[1].error = 0.001;
    expect_record(&data, SectionKind::LOD_LEVELS, 1, "below the previous level");
    let mut data = valid();
    data.lod_levels[0].error = f32::NAN;
    expect_record(&data, SectionKind::LOD_LEVELS, 0, "error NaN");
    let mut data = valid();
    data.lod_levels[0].fraction = 1.0;
    expect_record(&data, SectionKind::LOD_LEVELS, 0, "outside (0, 1)");
    let mut data = valid();
    data.lod_levels[1].triangles = range(1, 2);
    expect_record(&data, SectionKind::LOD_LEVELS, 1, "expected 2");
    let mut data = valid();
    data.lod_levels[1].triangles.count = 0;
    expect_record(&data, SectionKind::LOD_TRIANGLES, 0, "the levels cover 2");
    let mut data = valid();
    data.lod_triangles[2].indices[1] = 40;
    expect_record(&data, SectionKind::LOD_TRIANGLES, 2, "vertex index 40");
    let mut data = valid();
    data.lod_triangles[0].material = 3;
    expect_record(&data, SectionKind::LOD_TRIANGLES, 0, "material 3");
}

#[test]
fn billboard_rules() {
    let mut data = valid();
    data.billboards[0].image = 5;
    expect_record(&data, SectionKind::BILLBOARDS, 0, "image 5");
    let mut data = valid();
    data.billboards[1].kind = 2;
    expect_record(&data, SectionKind::BILLBOARDS, 1, "neither FACING");
    let mut data = valid();
    data.billboards.swap(0, 1);
    expect_record(&data, SectionKind::BILLBOARDS, 1, "not sorted");
    let mut data = valid();
    data.billboards[0].axis_u[2] = f32::INFINITY;
    expect_record(&data, SectionKind::BILLBOARDS, 0, "not all finite");
    let mut data = valid();
    data.billboards[1].tree = 4;
    expect_record(&data, SectionKind::BILLBOARDS, 1, "tree 4");
    let mut data = valid();
    data.billboards[0].uv_min = pack::unorm16x2(1.0, 0.0);
    data.billboards[0].uv_max = pack::unorm16x2(0.5, 1.0);
    expect_record(&data, SectionKind::BILLBOARDS, 0, "uv_min");
}

#[test]
fn curve_rules() {
    let mut data = valid();
    data.prune_scale[1].x = 0.1;
    expect_record(&data, SectionKind::PRUNE_SCALE, 1, "increase strictly");
    let mut data = valid();
    data.prune_lambda[0].y = f32::NAN;
    expect_record(&data, SectionKind::PRUNE_LAMBDA, 0, "not finite");
}

// ----------------------------------------------------------------------------------------------
// Cells: bounds (spec §6.2) and the exact cut (§10).

#[test]
fn cell_bounds_contain_every_reference_position() {
    let mut data = valid();
    data.vertices[7].position[0] = 2.5;
    expect_cell(&data, 0, "vertex 7");
    let mut data = valid();
    data.points[3].position = [1.0, 1.0, 2.0001];
    expect_cell(&data, 0, "POINTS record 3 position");
    let mut data = valid();
    data.lines[0].p0[0] = 1.9;
    expect_cell(&data, 2, "LINES record 0 p0");
    let mut data = valid();
    data.prune_leaves[1].center[1] = -0.5;
    expect_cell(&data, 2, "PRUNE_LEAVES record 1 center");
    let mut data = valid();
    data.cells[2].bounds_min[0] = 3.1;
    expect_cell(&data, 2, "ELLIPSOIDS record 0 center");
    let mut data = valid();
    data.cells[0].bounds_min[2] = 3.0;
    expect_cell(&data, 0, "not finite and ordered");
    let mut data = valid();
    data.cells[0].bounds_max[1] = INF;
    expect_cell(&data, 0, "not finite and ordered");
    let mut data = valid();
    data.cells[1].bounds_max[1] = 0.5;
    expect_cell(&data, 1, "all-zero bounds");
}

#[test]
fn overlapping_runs_break_rule_1() {
    let mut data = valid();
    // B covers leaves 1..3 instead of 2..4: it overlaps A (0..2) without nesting.
    data.points[2].leaf_first = 1;
    expect_cell(&data, 0, "overlap without nesting");
}

#[test]
fn a_gap_in_a_leaf_chain_breaks_rule_2() {
    let mut data = valid();
    data.points[6].hi = 0.4; // leaf 1: [0, 0.4) then A's [0.5, 1)
    expect_cell(&data, 0, "leaf 1: the intervals [0, 0.4) of record 6 and [0.5, 1) of record 1 leave a gap");
}

#[test]
fn an_overlap_in_a_leaf_chain_breaks_rule_2() {
    let mut data = valid();
    data.ellipsoids[1].lo = 0.5; // leaves 0, 1: [0, 1) and [0.5, 2)
    data.ellipsoids[1].hi = 2.0;
    expect_cell(&data, 2, "overlap (§10 rule 2)");
}

#[test]
fn a_chain_must_start_at_zero_and_end_at_infinity() {
    let mut data = valid();
    data.ellipsoids[0].hi = 1e9;
    expect_cell(&data, 2, "does not end at +inf");
    let mut data = valid();
    data.ellipsoids[2].lo = 0.5; // leaf 2: [0.5, 2) then [2, inf)
    expect_cell(&data, 2, "leaf 2: its first interval, [0.5, 2) of record 2, does not start at 0");
}

#[test]
fn every_leaf_below_n_is_covered() {
    let mut data = valid();
    // The line covers leaves 1..2 only: leaf 0 has no element.
    data.lines[0].leaf_first = 1;
    expect_cell(&data, 2, "leaf 0 is represented by no record");
}

#[test]
fn empty_intervals_are_not_part_of_a_chain() {
    // A node whose size equals its parent's gets an empty interval: valid.
    let mut data = valid();
    data.ellipsoids[1].lo = 2.0; // X [2, 2) is empty: leaves 0 and 1 have [0, 1), then [2, inf).
    expect_cell(&data, 2, "leave a gap");
    data.ellipsoids[3].hi = 2.0;
    data.ellipsoids[4].hi = 2.0;
    data.ellipsoids.sort_by(|a, b| b.hi.total_cmp(&a.hi));
    check(&data).expect("X is never drawn, its leaves go from [0, 2) to [2, inf)");
}

#[test]
fn a_leaf_point_must_have_its_triangles_size() {
    let mut data = valid();
    data.points[5].size = 0.31; // leaf 0's triangle has size 0.3
    expect_cell(&data, 0, "leaf 0 has triangle size 0.3");
}

#[test]
fn an_inner_point_must_not_be_smaller_than_its_leaves() {
    let mut data = valid();
    // B: size 0.6 > lo 0.35, so every leaf of B would need size 0.6.
    data.points[2].lo = 0.35;
    data.points[2].hi = 1.0;
    data.points[3].hi = 0.35;
    data.points[4].hi = 0.35;
    data.points.sort_by(|a, b| b.hi.total_cmp(&a.hi)); // B stays record 2
    expect_cell(&data, 0, "size 0.6, interval [0.35, 1)");
    // Size at or below lo with a leaf above lo: leaf 2 (size 0.4) under a point [0.35, 1) of size 0.35.
    data.points[2].size = 0.35;
    expect_cell(&data, 0, "leaf 2 has triangle size 0.4");
}

#[test]
fn points_cover_exactly_the_triangles_leaves() {
    let mut data = valid();
    data.points[0].leaf_count = 5;
    expect_cell(&data, 0, "leaves 0..5, the cell has 4 triangles");
    // A cell without triangles has no points.
    let mut data = valid();
    data.points.push(point([3.0, 1.0, 1.0], 1.0, 0.0, INF, 0, 1));
    data.cells[2].points = range(7, 1);
    expect_cell(&data, 2, "1 records but no triangles");
    // A cell with triangles has points.
    let mut data = valid();
    data.points.clear();
    for cell in &mut data.cells {
        cell.points = range(0, 0);
    }
    expect_cell(&data, 0, "leaves 0..0, the cell has 4 triangles");
}

// ----------------------------------------------------------------------------------------------
// The slice functions directly.

fn e(lo: f32, hi: f32, leaf_first: u32, leaf_count: u32) -> EllipsoidRecord {
    ellipsoid(lo, hi, leaf_first, leaf_count)
}

#[test]
fn check_spt_handles_huge_runs_without_walking_them() {
    let one = [e(0.0, INF, 0, u32::MAX)];
    assert_eq!(
        check_spt(SectionKind::ELLIPSOIDS, 0, 0, &one).expect("valid"),
        SptSummary { leaves: u64::from(u32::MAX), max_depth: 1 }
    );
    let far = [e(0.0, INF, u32::MAX, u32::MAX)];
    match check_spt(SectionKind::ELLIPSOIDS, 3, 10, &far) {
        Err(Error::BadCell { cell: 3, reason }) => {
            assert!(reason.contains("leaf 0 is represented by no record"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(check_spt::<EllipsoidRecord>(SectionKind::ELLIPSOIDS, 0, 0, &[]).expect("valid"), SptSummary::default());
}

#[test]
fn check_spt_reports_global_record_indices() {
    let runs = [e(1.0, INF, 0, 3), e(0.0, 1.0, 0, 2), e(0.0, 1.0, 1, 2)];
    match check_spt(SectionKind::PLANES, 7, 100, &runs) {
        Err(Error::BadCell { cell: 7, reason }) => {
            assert!(reason.starts_with("PLANES:"), "{reason}");
            assert!(reason.contains("records 101 (leaves 0..2) and 102 (leaves 1..3)"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_deep_chain_is_linear() {
    // A caterpillar: E_i covers leaves 0..m-i with [m-1-i, m-i) ([m-1, inf) for the root); the leaf
    // m-1-i hangs off E_i with [0, m-1-i). Depth m; a leaf-by-leaf check would be quadratic.
    let m = 200_000u32;
    let mut records = Vec::new();
    for i in 0..m {
        let hi = if i == 0 { INF } else { (m - i) as f32 };
        records.push(e((m - 1 - i) as f32, hi, 0, m - i));
        if i + 1 < m {
            records.push(e(0.0, (m - 1 - i) as f32, m - 1 - i, 1));
        }
    }
    records.sort_by(|a, b| b.hi.total_cmp(&a.hi));
    let s = check_spt(SectionKind::ELLIPSOIDS, 0, 0, &records).expect("valid");
    assert_eq!(s, SptSummary { leaves: u64::from(m), max_depth: m as usize });
}

#[test]
fn intervals_far_from_nesting_order_still_chain() {
    // Leaf 0 lies in k nested runs E_i (leaves 0..k-i) whose unit intervals are a scrambled
    // permutation of [0, k); every other leaf gets the intervals its open runs lack from single-leaf
    // records. Valid, with many unmatched interval ends open at once while the runs nest.
    let k = 40u32;
    let p = |i: u32| (i * 17) % k;
    let interval = |j: u32| (p(j) as f32, if p(j) == k - 1 { INF } else { (p(j) + 1) as f32 });
    let mut records = Vec::new();
    for i in 0..k {
        let (lo, hi) = interval(i);
        records.push(e(lo, hi, 0, k - i));
    }
    for leaf in 1..k {
        for j in k - leaf..k {
            let (lo, hi) = interval(j);
            records.push(e(lo, hi, leaf, 1));
        }
    }
    records.sort_by(|a, b| b.hi.total_cmp(&a.hi));
    let s = check_spt(SectionKind::ELLIPSOIDS, 0, 0, &records).expect("valid");
    assert_eq!(s, SptSummary { leaves: u64::from(k), max_depth: k as usize });
    // Without one of leaf 7's single-leaf records its chain has a gap.
    let gone = records.iter().position(|r| r.leaf_first == 7 && r.leaf_count == 1).expect("present");
    records.remove(gone);
    match check_spt(SectionKind::ELLIPSOIDS, 0, 0, &records) {
        Err(Error::BadCell { reason, .. }) => assert!(reason.contains("leaf 7"), "{reason}"),
        other => panic!("{other:?}"),
    }
}

/// The leaf sizes of a cell and a Gilet hierarchy over them: a balanced binary tree over leaves
/// `0..t`, inner sizes 1.25 × the larger child, intervals as spec §6.5 says. Triangles are sorted
/// by size with leaf ids scrambled.
fn gilet_cell(t: usize, seed: u64) -> (Vec<TriangleRecord>, Vec<PointRecord>) {
    let mut state = seed | 1;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let leaf_size: Vec<f32> = (0..t).map(|_| 0.01 + (rnd() % 1000) as f32 * 1e-4).collect();
    let mut triangles: Vec<TriangleRecord> = (0..t)
        .map(|l| TriangleRecord { indices: [0, 1, 2], size: leaf_size[l], leaf: l as u32, material: 0 })
        .collect();
    // Scramble the order, then sort by size: ties end up in any order.
    for i in (1..t).rev() {
        triangles.swap(i, (rnd() % (i as u64 + 1)) as usize);
    }
    triangles.sort_by(|a, b| b.size.total_cmp(&a.size));
    let mut points = Vec::with_capacity(2 * t);
    // Pushes the points of the node over leaves `first .. first + count` whose parent's lo is `hi`.
    fn node(first: usize, count: usize, hi: f32, leaf_size: &[f32], points: &mut Vec<PointRecord>) -> f32 {
        let c = [0.5, 0.5, 0.5];
        if count == 1 {
            let s = leaf_size[first];
            points.push(point(c, s, 0.0, hi, first as u32, 1));
            return s;
        }
        // Strictly above every child's size, so every interval is non-empty.
        let max = leaf_size[first..first + count].iter().fold(0.0f32, |m, &s| m.max(s));
        let size = max * 1.25f32.powi((count as f32).log2().ceil() as i32);
        points.push(point(c, size, size, hi, first as u32, count as u32));
        let half = count / 2;
        node(first, half, size, leaf_size, points);
        node(first + half, count - half, size, leaf_size, points);
        size
    }
    node(0, t, INF, &leaf_size, &mut points);
    points.sort_by(|a, b| b.hi.total_cmp(&a.hi));
    (triangles, points)
}

fn large_container(t: usize) -> ContainerData {
    let (triangles, points) = gilet_cell(t, 0x2545_F491_4F6C_DD1D);
    let vertex = |p| VertexRecord { position: p, normal: 0, uv: [0.0; 2], color: u32::MAX };
    ContainerData {
        metadata: Metadata {
            sources: vec![treelod_format::Source::default()],
            trees: vec![treelod_format::Tree::default()],
            materials: vec![MaterialInfo::default()],
            ..Metadata::default()
        },
        block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells: vec![
            CellRecord {
                bounds_min: [0.0; 3],
                bounds_max: [1.0; 3],
                triangles: range(0, t as u32),
                points: range(0, points.len() as u32),
                ..CellRecord::default()
            },
            CellRecord {
                triangles: range(t as u32, 0),
                points: range(points.len() as u32, 0),
                ..CellRecord::default()
            },
        ],
        vertices: vec![vertex([0.1, 0.1, 0.1]), vertex([0.9, 0.1, 0.1]), vertex([0.1, 0.9, 0.1])],
        materials: vec![MaterialRecord { image: NO_IMAGE, ..MaterialRecord::default() }],
        triangles,
        points,
        ..ContainerData::default()
    }
}

#[test]
fn a_generated_hierarchy_verifies() {
    for t in [1, 2, 3, 5, 17, 1000] {
        let (triangles, points) = gilet_cell(t, t as u64);
        let sizes = triangle_leaf_sizes(0, 0, &triangles).expect("valid");
        let s = check_point_cut(0, 0, &points, &sizes).expect("valid");
        assert_eq!(s.leaves, t as u64);
    }
    let report = check(&large_container(20_000)).expect("valid");
    assert_eq!(report.cut_leaves, 20_000);
    assert!(report.max_depth >= 15, "{report:?}");
}

/// `cargo test -p treelod-format --release --test verify -- --ignored --nocapture`
#[test]
#[ignore = "timing run: prints how long verify takes on a 500k-leaf cell"]
fn time_a_500k_leaf_cell() {
    let data = large_container(500_000);
    let bytes = bytes_of(&data);
    let c = Container::from_bytes(&bytes).expect("opens");
    let start = std::time::Instant::now();
    let report = verify(&c).expect("valid");
    let elapsed = start.elapsed();
    println!("verify: {elapsed:?} for {} bytes\n{report}", bytes.len());
}

// ----------------------------------------------------------------------------------------------
// The sweep against a brute-force reading of spec §10 on small random hierarchies.

/// Rules 1–3 leaf by leaf, as the spec words them. Records already pass their own field checks.
fn oracle(records: &[PointRecord], leaf_sizes: Option<&[f32]>) -> bool {
    let run = |r: &PointRecord| (u64::from(r.leaf_first), u64::from(r.leaf_first) + u64::from(r.leaf_count));
    for a in records {
        for b in records {
            let ((s1, e1), (s2, e2)) = (run(a), run(b));
            let disjoint = e1 <= s2 || e2 <= s1;
            let nested = (s1 <= s2 && e2 <= e1) || (s2 <= s1 && e1 <= e2);
            if !disjoint && !nested {
                return false;
            }
        }
    }
    let n = records.iter().map(|r| run(r).1).max().unwrap_or(0);
    if let Some(sizes) = leaf_sizes
        && n != sizes.len() as u64
    {
        return false; // with no triangles, n = 0 means no points
    }
    for leaf in 0..n {
        let mut chain: Vec<&PointRecord> =
            records.iter().filter(|r| run(r).0 <= leaf && leaf < run(r).1 && r.lo < r.hi).collect();
        chain.sort_by(|a, b| a.lo.total_cmp(&b.lo));
        if chain.is_empty() || chain[0].lo != 0.0 || chain[chain.len() - 1].hi != INF {
            return false;
        }
        if chain.windows(2).any(|w| w[0].hi != w[1].lo) {
            return false;
        }
        if let Some(sizes) = leaf_sizes {
            let s = sizes[leaf as usize];
            if chain.iter().any(|p| !(p.size == s || (p.size <= p.lo && s <= p.lo))) {
                return false;
            }
        }
    }
    true
}

#[test]
fn the_sweep_agrees_with_the_spec_on_random_hierarchies() {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut rnd = move |n: u64| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state % n
    };
    let values = [0.0, 1.0, 2.0, 3.0, INF];
    let (mut valid_seen, mut cut_seen) = (0, 0);
    for case in 0..200_000 {
        let m = 1 + rnd(6) as usize;
        let mut records: Vec<PointRecord> = (0..m)
            .map(|_| {
                let lo_i = rnd(4) as usize;
                let hi_i = lo_i + rnd((values.len() - lo_i) as u64) as usize;
                let size = values[rnd(4) as usize];
                point([0.0; 3], size, values[lo_i], values[hi_i], rnd(4) as u32, 1 + rnd(3) as u32)
            })
            .collect();
        // Often start from a valid two-level hierarchy so that both answers occur.
        if case % 2 == 0 {
            records = vec![
                point([0.0; 3], 1.0, 1.0, INF, 0, 2),
                point([0.0; 3], 1.0, 0.0, 1.0, 0, 1),
                point([0.0; 3], 1.0, 0.0, 1.0, 1, 1),
            ];
            let k = rnd(3) as usize;
            match rnd(4) {
                0 => records[k].lo = values[rnd(2) as usize],
                1 => records[k].hi = values[1 + rnd(4) as usize].max(records[k].lo),
                2 => records[k].leaf_first = rnd(3) as u32,
                _ => records[k].size = values[rnd(3) as usize],
            }
        }
        records.sort_by(|a, b| b.hi.total_cmp(&a.hi));
        let leaf_sizes: Vec<f32> = (0..rnd(4)).map(|_| values[rnd(3) as usize]).collect();
        let spt_expected = oracle(&records, None);
        let spt_got = check_spt(SectionKind::POINTS, 0, 0, &records).is_ok();
        assert_eq!(spt_got, spt_expected, "rules 1-2 on {records:?}");
        let cut_expected = oracle(&records, Some(&leaf_sizes));
        let cut_got = check_point_cut(0, 0, &records, &leaf_sizes).is_ok();
        assert_eq!(cut_got, cut_expected, "rules 1-3 on {records:?} with leaf sizes {leaf_sizes:?}");
        valid_seen += usize::from(spt_expected);
        cut_seen += usize::from(cut_expected);
    }
    assert!(valid_seen > 10_000 && cut_seen > 1_000, "both answers occur: {valid_seen} {cut_seen}");
}
