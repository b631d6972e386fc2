//! Ambient occlusion in the container (spec §6.14): the `VERTEX_AO`, `POINT_AO` and `PLANE_AO`
//! kinds (1.2), `ELLIPSOID_AO` (1.3), `LINE_AO` (1.4) and `FAR_LINE_AO` (1.9), the byte encoding,
//! the writer refusing arrays of the wrong length, the reader refusing such files at open, and
//! files with ambient occlusion round-tripping as format 1.2 (1.3 with `ELLIPSOID_AO`, 1.4 with
//! `LINE_AO`).

mod common;

use common::{assert_reads_back, resize_section};
use treelod_format::{
    AO_KINDS, CellRecord, Compression, Container, ContainerData, EllipsoidRecord, Error, MINOR, PlaneRecord, Range,
    SectionKind, decode_ao, encode_ao, pack, verify,
};

fn range(first: u32, count: u32) -> Range {
    Range { first, count }
}

/// One 1×1×1 cell holding one triangle under its leaf point, the block cell one impostor plane
/// with a 2×2 RGBA8 image, one ellipsoid over the leaf and one branch line; no ambient occlusion.
/// Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("ao-fixture");
    data.planes = vec![PlaneRecord {
        center: [0.5, 0.5, 0.5],
        axis_u: [0.25, 0.0, 0.0],
        axis_v: [0.0, 0.25, 0.0],
        image: 0,
        uv_min: pack::unorm16x2(0.0, 0.0),
        uv_max: pack::unorm16x2(1.0, 1.0),
        lo: 0.0,
        hi: f32::INFINITY,
        leaf_first: 0,
        leaf_count: 1,
    }];
    data.ellipsoids = vec![EllipsoidRecord {
        center: [0.5, 0.5, 0.5],
        radii: [0.2, 0.2, 0.05],
        orientation: [0, 0, 0, i16::MAX],
        color: 0xFF33_9933,
        alpha_threshold: 0.5,
        noise_mip: 0.0,
        lo: 0.0,
        hi: f32::INFINITY,
        leaf_first: 0,
        leaf_count: 1,
        flags: 0,
    }];
    data.lines = vec![common::branch_line([0.3, 0.3, 0.5], [0.7, 0.7, 0.5])];
    data.cells[1] = CellRecord {
        bounds_min: [0.25, 0.25, 0.5],
        bounds_max: [0.75, 0.75, 0.5],
        planes: range(0, 1),
        ellipsoids: range(0, 1),
        lines: range(0, 1),
        ..data.cells[1]
    };
    common::grey_image(&mut data);
    data
}

/// The fixture with a value for every vertex, point and plane (the 1.2 kinds).
fn with_ao() -> ContainerData {
    ContainerData { vertex_ao: vec![0, 128, 255], point_ao: vec![200], plane_ao: vec![77], ..fixture() }
}

/// [`with_ao`] and a value for the ellipsoid (`ELLIPSOID_AO`, 1.3) and the line (`LINE_AO`,
/// 1.4), too.
fn with_all_ao() -> ContainerData {
    ContainerData { ellipsoid_ao: vec![33], line_ao: vec![44], ..with_ao() }
}

/// [`with_all_ao`] with one far line (a copy of the block's one coarsest line, spec §6.9.1) and a
/// value for it (`FAR_LINE_AO`, 1.9).
fn with_far_ao() -> ContainerData {
    let data = with_all_ao();
    ContainerData { far_lines: data.lines.clone(), far_line_ao: vec![55], ..data }
}

#[test]
fn the_kinds_are_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 2, "ambient occlusion is format 1.2") };
    let expected = [
        (SectionKind::VERTEX_AO, 0x0060, "VERTEX_AO", SectionKind::VERTICES),
        (SectionKind::POINT_AO, 0x0061, "POINT_AO", SectionKind::POINTS),
        (SectionKind::PLANE_AO, 0x0062, "PLANE_AO", SectionKind::PLANES),
        (SectionKind::ELLIPSOID_AO, 0x0063, "ELLIPSOID_AO", SectionKind::ELLIPSOIDS),
        (SectionKind::LINE_AO, 0x0064, "LINE_AO", SectionKind::LINES),
        (SectionKind::FAR_LINE_AO, 0x0065, "FAR_LINE_AO", SectionKind::FAR_LINES),
    ];
    assert_eq!(AO_KINDS.len(), expected.len());
    for (i, (kind, value, name, of)) in expected.into_iter().enumerate() {
        assert_eq!(kind.0, value);
        assert_eq!(kind.name(), Some(name));
        assert_eq!(kind.to_string(), name);
        assert_eq!(kind.record_size(), Some(1), "{name}: one byte per record");
        let since = match kind {
            SectionKind::ELLIPSOID_AO => 3,
            SectionKind::LINE_AO => 4,
            SectionKind::FAR_LINE_AO => 9,
            _ => 2,
        };
        assert_eq!(kind.since_minor(), since, "{name}");
        assert!(SectionKind::KNOWN.contains(&kind), "{name}");
        assert_eq!(AO_KINDS[i], (kind, of), "{name} parallels {of}");
    }
    // KNOWN stays in ascending order with the AO kinds together (before CALIBRATION, 1.5).
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    let first = SectionKind::KNOWN.iter().position(|&k| k == SectionKind::VERTEX_AO).expect("known");
    assert_eq!(SectionKind::KNOWN[first..first + AO_KINDS.len()], AO_KINDS.map(|(k, _)| k));
}

#[test]
fn encode_and_decode_round_trip_clamp_and_map_nan_to_zero() {
    // Every stored byte survives decode then encode.
    for b in 0..=255u8 {
        assert_eq!(encode_ao(decode_ao(b)), b, "byte {b}");
    }
    assert_eq!(decode_ao(0), 0.0);
    assert_eq!(decode_ao(255), 1.0);
    assert!((decode_ao(51) - 0.2).abs() < 1e-7);
    // Rounded to the nearest step; halves away from zero (0.5·255 = 127.5 exactly).
    assert_eq!(encode_ao(0.5), 128);
    assert_eq!(encode_ao(0.5 / 255.0 - 1e-4), 0);
    assert_eq!(encode_ao(1.0 / 255.0), 1);
    assert_eq!(encode_ao(254.4 / 255.0), 254);
    // Within half a step of the value over [0, 1], and monotone.
    let mut last = 0u8;
    for i in 0..=10_000 {
        let x = i as f32 / 10_000.0;
        let b = encode_ao(x);
        assert!((decode_ao(b) - x).abs() <= 0.5 / 255.0 + 1e-6, "{x} → {b}");
        assert!(b >= last, "monotone at {x}");
        last = b;
    }
    // Clamped to [0, 1]; NaN is 0 (no occlusion).
    for (x, b) in [
        (-0.0, 0),
        (-0.3, 0),
        (-1e30, 0),
        (f32::NEG_INFINITY, 0),
        (1.0, 255),
        (1.0001, 255),
        (7.5, 255),
        (f32::INFINITY, 255),
        (f32::NAN, 0),
        (-f32::NAN, 0),
        (f32::MIN_POSITIVE, 0),
    ] {
        assert_eq!(encode_ao(x), b, "{x}");
    }
}

#[test]
fn a_container_with_ao_round_trips_as_format_1_2() {
    let plain = fixture();
    for compression in [Compression::None, Compression::default()] {
        // Without ambient occlusion the file stays 1.0 (no section of a later minor).
        let bytes = plain.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        verify(&c).expect("the fixture verifies");
        assert_eq!((c.header().major, c.header().minor), (1, 0));
        assert!(c.vertex_ao().is_empty() && c.point_ao().is_empty() && c.plane_ao().is_empty());
        assert!(c.ellipsoid_ao().is_empty());
        assert!(AO_KINDS.iter().all(|(kind, _)| c.section(*kind).is_none()), "no empty AO section is written");

        let data = with_ao();
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 2), "{compression:?}");
        assert_eq!(c.vertex_ao(), &[0, 128, 255]);
        assert_eq!(c.point_ao(), &[200]);
        assert_eq!(c.plane_ao(), &[77]);
        assert!(c.ellipsoid_ao().is_empty() && c.section(SectionKind::ELLIPSOID_AO).is_none());
        assert!(c.line_ao().is_empty() && c.section(SectionKind::LINE_AO).is_none());
        for (kind, _) in AO_KINDS.into_iter().filter(|&(k, _)| k.since_minor() == 2) {
            assert_eq!(c.section(kind).expect("present").entry.record_size, 1, "{kind}");
        }
        let report = verify(&c).expect("verifies");
        assert_eq!(report.ao, 5);
        assert!(report.to_string().contains("ambient occlusion: 5 values"), "{report}");
        // Read back into data and written again: the same bytes.
        assert_reads_back(&c, &data, &bytes, compression);
    }

    // Any one of the first three kinds makes a 1.2 file, `ELLIPSOID_AO` a 1.3 file, `LINE_AO` a 1.4
    // file, `FAR_LINE_AO` (with the far lines it needs, also 1.9) a 1.9 file; the others read as
    // empty.
    for (i, (kind, _)) in AO_KINDS.into_iter().enumerate() {
        let mut data = fixture();
        let mut sections = 1;
        match i {
            0 => data.vertex_ao = vec![1, 2, 3],
            1 => data.point_ao = vec![4],
            2 => data.plane_ao = vec![5],
            3 => data.ellipsoid_ao = vec![6],
            4 => data.line_ao = vec![7],
            _ => {
                // One far line: a copy of the block's one coarsest line.
                data.far_lines = data.lines.clone();
                data.far_line_ao = vec![8];
                sections = 2;
            }
        }
        let bytes = data.to_bytes(Compression::None).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, [2, 2, 2, 3, 4, 9][i], "{kind} alone");
        assert_eq!(c.sections().iter().filter(|s| s.kind().since_minor() >= 2).count(), sections, "{kind} alone");
        let lengths = c.vertex_ao().len()
            + c.point_ao().len()
            + c.plane_ao().len()
            + c.ellipsoid_ao().len()
            + c.line_ao().len()
            + c.far_line_ao().len();
        assert_eq!(lengths, if i == 0 { 3 } else { 1 });
        assert_eq!(c.raw_bytes(kind).len(), lengths, "{kind}");
        verify(&c).expect("verifies");
    }

    // Through a file on disk, too.
    let dir = std::env::temp_dir().join(format!("treelod-format-ao-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("creates");
    let path = dir.join("ao.treelod");
    with_ao().write_to_path(&path, Compression::default()).expect("writes");
    let c = Container::open(&path).expect("opens");
    assert_eq!(
        (c.header().minor, c.vertex_ao(), c.point_ao(), c.plane_ao()),
        (2, &[0u8, 128, 255][..], &[200u8][..], &[77u8][..])
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_container_with_ellipsoid_ao_round_trips_as_format_1_3() {
    const { assert!(MINOR >= 3, "ELLIPSOID_AO is format 1.3") };
    let data = ContainerData { line_ao: Vec::new(), ..with_all_ao() };
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 3), "{compression:?}");
        assert_eq!(c.ellipsoid_ao(), &[33]);
        assert_eq!(c.ellipsoid_ao().len(), c.ellipsoids().len());
        assert_eq!((c.vertex_ao(), c.point_ao(), c.plane_ao()), (&[0u8, 128, 255][..], &[200u8][..], &[77u8][..]));
        assert_eq!(c.section(SectionKind::ELLIPSOID_AO).expect("present").entry.record_size, 1);
        // The file's own reserved `flags` stay 0: the occlusion lives only in its section.
        assert_eq!(c.ellipsoids()[0].flags, 0);
        let report = verify(&c).expect("verifies");
        assert_eq!(report.ao, 6);
        assert!(report.to_string().contains("ambient occlusion: 6 values"), "{report}");
        assert_reads_back(&c, &data, &bytes, compression);
    }
}

#[test]
fn a_container_with_line_ao_round_trips_as_format_1_4() {
    const { assert!(MINOR >= 4, "LINE_AO is format 1.4") };
    let data = with_all_ao();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 4), "{compression:?}");
        assert_eq!((c.line_ao(), c.ellipsoid_ao()), (&[44u8][..], &[33u8][..]));
        assert_eq!(c.line_ao().len(), c.lines().len());
        assert_eq!(c.section(SectionKind::LINE_AO).expect("present").entry.record_size, 1);
        // The file's own reserved `flags` stay 0: the occlusion lives only in its section.
        assert_eq!(c.lines()[0].flags, 0);
        let report = verify(&c).expect("verifies");
        assert_eq!(report.ao, 7);
        assert!(report.to_string().contains("ambient occlusion: 7 values"), "{report}");
        assert_reads_back(&c, &data, &bytes, compression);
    }
}

#[test]
fn the_writer_refuses_ao_arrays_of_another_length_than_their_array() {
    type Field = fn(&mut ContainerData) -> &mut Vec<u8>;
    let fields: [(SectionKind, &str, Field); 6] = [
        (SectionKind::VERTEX_AO, "VERTICES has 3", |d| &mut d.vertex_ao),
        (SectionKind::POINT_AO, "POINTS has 1", |d| &mut d.point_ao),
        (SectionKind::PLANE_AO, "PLANES has 1", |d| &mut d.plane_ao),
        (SectionKind::ELLIPSOID_AO, "ELLIPSOIDS has 1", |d| &mut d.ellipsoid_ao),
        (SectionKind::LINE_AO, "LINES has 1", |d| &mut d.line_ao),
        (SectionKind::FAR_LINE_AO, "FAR_LINES has 1", |d| &mut d.far_line_ao),
    ];
    let dir = std::env::temp_dir().join(format!("treelod-format-ao-refused-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("creates");
    for (kind, array, field) in fields {
        for wrong in [1usize, 2, 4, 9] {
            let mut data = with_far_ao();
            let ao = field(&mut data);
            if ao.len() == wrong {
                continue;
            }
            ao.resize(wrong, 9);
            for compression in [Compression::None, Compression::default()] {
                match data.to_bytes(compression) {
                    Err(Error::Write(message)) => {
                        assert!(message.contains(kind.name().expect("known")), "{kind} × {wrong}: {message}");
                        assert!(message.contains(&format!("{wrong} records")), "{kind} × {wrong}: {message}");
                        assert!(message.contains(array), "{kind} × {wrong}: {message}");
                    }
                    other => panic!("{kind} with {wrong} values: expected Error::Write, got {other:?}"),
                }
            }
            // Nor is a file written.
            let path = dir.join(format!("{kind}-{wrong}.treelod"));
            assert!(matches!(data.write_to_path(&path, Compression::default()), Err(Error::Write(_))));
            assert!(matches!(data.clone().into_path(&path, Compression::default()), Err(Error::Write(_))));
            assert!(!path.exists(), "{kind} × {wrong}: nothing written");
        }
        // Empty is always allowed: no ambient occlusion for that array.
        let mut data = with_far_ao();
        field(&mut data).clear();
        let bytes = data.to_bytes(Compression::None).expect("writes");
        assert!(Container::from_bytes(&bytes).expect("opens").section(kind).is_none());
    }
    // An AO array for an array that is empty is refused too.
    let data = ContainerData { plane_ao: vec![1], planes: Vec::new(), ..fixture() };
    let data =
        ContainerData { cells: data.cells.iter().map(|c| CellRecord { planes: range(0, 0), ..*c }).collect(), ..data };
    match data.to_bytes(Compression::None) {
        Err(Error::Write(message)) => {
            assert!(message.contains("PLANE_AO") && message.contains("PLANES has 0"), "{message}")
        }
        other => panic!("expected Error::Write, got {other:?}"),
    }
    // So is an ellipsoid AO array without ellipsoids.
    let data = ContainerData { ellipsoid_ao: vec![1], ellipsoids: Vec::new(), ..fixture() };
    let data = ContainerData {
        cells: data.cells.iter().map(|c| CellRecord { ellipsoids: range(0, 0), ..*c }).collect(),
        ..data
    };
    match data.to_bytes(Compression::None) {
        Err(Error::Write(message)) => {
            assert!(message.contains("ELLIPSOID_AO") && message.contains("ELLIPSOIDS has 0"), "{message}")
        }
        other => panic!("expected Error::Write, got {other:?}"),
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_file_whose_ao_section_is_shorter_or_longer_than_its_array_is_refused_at_open() {
    let bytes = with_far_ao().to_bytes(Compression::None).expect("writes");
    Container::from_bytes(&resize_section(&bytes, SectionKind::VERTEX_AO, 0)).expect("the untouched file opens");
    let cases = [
        (SectionKind::VERTEX_AO, -1, "2 records, VERTICES has 3"),
        (SectionKind::VERTEX_AO, 1, "4 records, VERTICES has 3"),
        (SectionKind::POINT_AO, 1, "2 records, POINTS has 1"),
        (SectionKind::PLANE_AO, 5, "6 records, PLANES has 1"),
        (SectionKind::ELLIPSOID_AO, 2, "3 records, ELLIPSOIDS has 1"),
        (SectionKind::ELLIPSOID_AO, 15, "16 records, ELLIPSOIDS has 1"),
        (SectionKind::LINE_AO, 1, "2 records, LINES has 1"),
        (SectionKind::FAR_LINE_AO, 1, "2 records, FAR_LINES has 1"),
        (SectionKind::FAR_LINE_AO, 7, "8 records, FAR_LINES has 1"),
    ];
    for (kind, delta, needle) in cases {
        let edited = resize_section(&bytes, kind, delta);
        let err = match Container::from_bytes(&edited) {
            Ok(c) => panic!("{kind} {delta:+}: opened with {} AO bytes", c.raw_bytes(kind).len()),
            Err(err) => err,
        };
        match &err {
            Error::BadRecord { kind: k, reason, .. } => {
                assert_eq!(*k, kind, "{err}");
                assert!(reason.contains(needle), "{kind} {delta:+}: {err}");
            }
            other => panic!("{kind} {delta:+}: expected BadRecord, got {other:?}"),
        }
        let message = err.to_string();
        assert!(message.starts_with(kind.name().expect("known")), "the message names the kind: {message}");
        assert_eq!(err.class(), treelod_format::ErrorClass::Invalid);
    }
    // A zero-length AO section is the same as an absent one.
    let emptied = resize_section(&bytes, SectionKind::POINT_AO, -1);
    let c = Container::from_bytes(&emptied).expect("an empty AO section opens");
    assert!(c.point_ao().is_empty());
    assert_eq!(c.vertex_ao(), &[0, 128, 255]);
    let emptied = resize_section(&bytes, SectionKind::ELLIPSOID_AO, -1);
    let c = Container::from_bytes(&emptied).expect("an empty ELLIPSOID_AO section opens");
    assert!(c.ellipsoid_ao().is_empty());
    assert_eq!(c.ellipsoid_ao().len() + 1, c.ellipsoids().len());
    let emptied = resize_section(&bytes, SectionKind::FAR_LINE_AO, -1);
    let c = Container::from_bytes(&emptied).expect("an empty FAR_LINE_AO section opens");
    assert!(c.far_line_ao().is_empty() && c.far_lines().len() == 1);
}
