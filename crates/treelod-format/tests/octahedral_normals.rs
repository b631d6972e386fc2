//! Where the octahedral views' normals lie (spec §6.13.3): the `OCTAHEDRAL_NORMALS` kind (1.15)
//! round-trips and makes a file 1.15, a file without it keeps its smaller minor and reads no
//! normal grids (every view lit as a whole), the writer and the reader at open refuse a record
//! count other than `OCTAHEDRAL`'s (one per impostor, or none), `verify` refuses a normal grid that
//! leaves the image with an error naming the section and the record, and a reader that does not
//! know the kind (1.14 and before) skips it and reads everything else as it was.

mod common;

use common::{assert_reads_back, bytes_of, check, relabel, resize_section};
use treelod_format::{
    Compression, Container, ContainerData, Error, ErrorClass, MINOR, OctahedralDepthRecord, OctahedralNormalRecord,
    OctahedralRecord, PlaneDiffuseRecord, SectionKind, pack, verify,
};

const KIND: SectionKind = SectionKind::OCTAHEDRAL_NORMALS;

/// A point of an image in unorm16 steps, `u` low and `v` high, as the records store it.
fn steps(u: u32, v: u32) -> u32 {
    (v << 16) | u
}

/// An octahedral impostor of `tree` with `frames × frames` views whose colour grid is
/// `uv_min .. uv_max` (unorm16 steps) of image 0.
fn impostor(tree: u32, frames: u32, uv_min: u32, uv_max: u32) -> OctahedralRecord {
    OctahedralRecord {
        center: [0.4, 0.5, 0.5],
        radius: 0.35,
        image: 0,
        uv_min,
        uv_max,
        frames,
        tree,
        occlusion: 0.25,
        diffuse: PlaneDiffuseRecord { flat: 30_000, scattered: 20_000 },
        reserved: 0,
    }
}

/// `common`'s leaf cell in a block of two trees, a 2×2 RGBA8 image (`IMAGES` 0) and an octahedral
/// impostor per tree, each with its normal grid right of its colour grid: tree 0's colours in the
/// top left quarter (`[0, 0] .. [32768, 32768]` steps) and its normals in the top right one, up to
/// the image's right edge (`32768 + 32768 = 65536`); tree 1's colours in `[0, 32768] .. [16384,
/// 65535]` and its normals from `[16384, 32768]`, down to the bottom edge. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("octahedral-normals-fixture");
    data.block.tree_count = 2;
    data.metadata.trees.push(treelod_format::Tree::default());
    common::grey_image(&mut data);
    data.octahedral =
        vec![impostor(0, 2, steps(0, 0), steps(32768, 32768)), impostor(1, 3, steps(0, 32768), steps(16384, 65535))];
    data.octahedral_normals = vec![
        OctahedralNormalRecord { uv_min: steps(32768, 0) },
        OctahedralNormalRecord { uv_min: steps(16384, 32768) },
    ];
    data
}

/// Asserts a `BadRecord` of `OCTAHEDRAL_NORMALS` at `index` from `verify` whose reason is `reason`,
/// and whose message names the kind and the record.
#[track_caller]
fn expect_refused(data: &ContainerData, index: usize, reason: &str) {
    match check(data) {
        Err(ref e @ Error::BadRecord { kind, index: i, reason: ref r })
            if kind == KIND && i == index && r == reason =>
        {
            let message = e.to_string();
            assert_eq!(message, format!("OCTAHEDRAL_NORMALS record {index}: {reason}"));
            assert_eq!(e.class(), ErrorClass::Invalid, "{message}");
        }
        other => panic!("expected BadRecord OCTAHEDRAL_NORMALS {index} ({reason}), got {other:?}"),
    }
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 15, "OCTAHEDRAL_NORMALS is format 1.15") };
    assert_eq!(KIND.0, 0x0055);
    assert_eq!(KIND.name(), Some("OCTAHEDRAL_NORMALS"));
    assert_eq!(KIND.to_string(), "OCTAHEDRAL_NORMALS");
    assert_eq!(KIND.record_size(), Some(4));
    assert_eq!(size_of::<OctahedralNormalRecord>(), 4);
    assert_eq!(KIND.since_minor(), 15);
    assert!(KIND.compressible());
    assert!(SectionKind::KNOWN.contains(&KIND));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    // Right after OCTAHEDRAL_DEPTH, after OCTAHEDRAL, whose views it describes.
    let at = SectionKind::KNOWN.iter().position(|&k| k == KIND).expect("known");
    assert_eq!(SectionKind::KNOWN[at - 2..at], [SectionKind::OCTAHEDRAL, SectionKind::OCTAHEDRAL_DEPTH]);
    // Two unorm16, u in the low half, v in the high, little endian (spec §6.13.3).
    let record = OctahedralNormalRecord { uv_min: pack::unorm16x2(0.5, 0.25) };
    assert_eq!(bytemuck::bytes_of(&record), [0x00, 0x80, 0x00, 0x40]);
    assert_eq!(pack::unpack_unorm16x2(record.uv_min), [32768.0 / 65535.0, 16384.0 / 65535.0]);
}

#[test]
fn a_container_with_normal_grids_round_trips_as_format_1_15_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 15), "{compression:?}");
        assert_eq!(c.octahedral_normals(), data.octahedral_normals.as_slice());
        assert_eq!(c.octahedral(), data.octahedral.as_slice());
        let section = c.section(KIND).expect("present");
        assert_eq!((section.entry.record_size, section.entry.raw_length), (4, 2 * 4));
        assert_eq!(c.raw_bytes(KIND), bytemuck::cast_slice::<_, u8>(&data.octahedral_normals));
        let report = verify(&c).expect("verifies");
        assert_eq!((report.octahedral, report.octahedral_depth, report.octahedral_normals), (2, 0, 2));
        let text = report.to_string();
        assert!(
            text.contains(
                "baselines: 0 LoD levels, 0 LoD triangles, 0 billboards, 2 octahedral impostors, 2 octahedral normal \
                 grids\n"
            ),
            "{text}"
        );
        assert_reads_back(&c, &data, &bytes, compression);
    }
    // With the views' depth planes too (1.13): still 1.15, both sections read back.
    let mut data = fixture();
    data.octahedral_depth = vec![OctahedralDepthRecord::default(); 4 + 9];
    let bytes = bytes_of(&data);
    let c = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(c.header().minor, 15);
    let report = verify(&c).expect("verifies");
    assert_eq!((report.octahedral_depth, report.octahedral_normals), (13, 2));
    assert!(report.to_string().contains("13 octahedral depth planes, 2 octahedral normal grids\n"), "{report}");
    assert_reads_back(&c, &data, &bytes, Compression::None);
}

#[test]
fn a_file_without_normal_grids_is_not_marked_1_15_and_reads_none() {
    // Without the section: the impostors alone are a 1.11 file, whose views are lit as a whole.
    let older = ContainerData { octahedral_normals: Vec::new(), ..fixture() };
    let c = Container::from_bytes(&bytes_of(&older)).expect("opens");
    assert_eq!(c.header().minor, 11);
    assert_eq!(c.octahedral_normals(), &[] as &[OctahedralNormalRecord]);
    assert!(c.section(KIND).is_none(), "no empty section is written");
    let report = verify(&c).expect("verifies");
    assert_eq!((report.octahedral, report.octahedral_normals), (2, 0));
    assert!(!report.to_string().contains("normal"), "{report}");

    // With the views' depth planes (1.13) and the points' facing (1.14): 1.14 without the
    // normals, 1.15 with them.
    let mut data = ContainerData {
        octahedral_depth: vec![OctahedralDepthRecord::default(); 4 + 9],
        point_facing: vec![128],
        ..older
    };
    let c = Container::from_bytes(&bytes_of(&data)).expect("opens");
    assert_eq!(c.header().minor, 14);
    assert!(c.octahedral_normals().is_empty());
    check(&data).expect("verifies");
    data.octahedral_normals = fixture().octahedral_normals;
    assert_eq!(Container::from_bytes(&bytes_of(&data)).expect("opens").header().minor, 15);
    assert_eq!(check(&data).expect("verifies").octahedral_normals, 2);

    // Without any impostor: a 1.0 file, no normal grids either.
    let plain = ContainerData { octahedral: Vec::new(), octahedral_normals: Vec::new(), ..fixture() };
    let c = Container::from_bytes(&bytes_of(&plain)).expect("opens");
    assert_eq!(c.header().minor, 0);
    assert!(c.octahedral().is_empty() && c.octahedral_normals().is_empty());
}

// ----------------------------------------------------------------------------------------------
// One record per impostor: the writer and the reader at open.

#[test]
fn the_writer_refuses_another_count_than_the_impostors() {
    type Edit = fn(&mut ContainerData);
    let cases: [(&str, &str, Edit); 3] = [
        ("one grid fewer", "1 records, OCTAHEDRAL has 2", |d| {
            d.octahedral_normals.pop();
        }),
        ("one grid more", "3 records, OCTAHEDRAL has 2", |d| {
            d.octahedral_normals.push(OctahedralNormalRecord::default())
        }),
        ("grids without impostors", "2 records, OCTAHEDRAL has 0", |d| d.octahedral.clear()),
    ];
    for (what, needle, edit) in cases {
        let mut data = fixture();
        edit(&mut data);
        for compression in [Compression::None, Compression::default()] {
            match data.to_bytes(compression) {
                Err(Error::Write(message)) => {
                    assert!(message.contains("OCTAHEDRAL_NORMALS") && message.contains(needle), "{what}: {message}");
                }
                other => panic!("{what}: expected Error::Write, got {other:?}"),
            }
        }
    }
}

#[test]
fn a_file_whose_normal_grids_are_fewer_or_more_than_the_impostors_is_refused_at_open() {
    let bytes = bytes_of(&fixture());
    Container::from_bytes(&resize_section(&bytes, KIND, 0)).expect("the untouched file opens");
    for (delta, needle) in [(-4, "1 records, OCTAHEDRAL has 2"), (4, "3 records, OCTAHEDRAL has 2")] {
        let edited = resize_section(&bytes, KIND, delta);
        let err = match Container::from_bytes(&edited) {
            Ok(c) => panic!("{delta:+}: opened with {} normal grids", c.octahedral_normals().len()),
            Err(err) => err,
        };
        match &err {
            Error::BadRecord { kind, index, reason } => {
                assert_eq!((*kind, *index), (KIND, 0), "{err}");
                assert!(reason.contains(needle), "{delta:+}: {err}");
            }
            other => panic!("{delta:+}: expected BadRecord, got {other:?}"),
        }
        assert!(err.to_string().starts_with("OCTAHEDRAL_NORMALS record 0: "), "the message names the kind: {err}");
        assert_eq!(err.class(), ErrorClass::Invalid);
    }
    // Normal grids of impostors the file does not have (OCTAHEDRAL relabelled as a kind this
    // version does not know): refused too.
    let edited = relabel(&bytes, SectionKind::OCTAHEDRAL, 0x0001_0053);
    let err = Container::from_bytes(&edited).expect_err("normals without impostors");
    assert!(err.to_string().starts_with("OCTAHEDRAL_NORMALS"), "{err}");
    assert!(err.to_string().contains("2 records, OCTAHEDRAL has 0"), "{err}");
    // A length that is not a whole number of records is refused as well.
    for delta in [-1, -2, -3, -6] {
        let err = Container::from_bytes(&resize_section(&bytes, KIND, delta)).expect_err("a partial record");
        assert_eq!(err.class(), ErrorClass::Invalid, "{delta:+}: {err}");
        assert!(err.to_string().contains("OCTAHEDRAL_NORMALS"), "{delta:+}: {err}");
    }
    // A zero-length section is the same as an absent one: every view lit as a whole.
    let c = Container::from_bytes(&resize_section(&bytes, KIND, -8)).expect("an empty section opens");
    assert!(c.octahedral_normals().is_empty() && c.octahedral().len() == 2);
}

// ----------------------------------------------------------------------------------------------
// Verify: every grid inside the image.

#[test]
fn grids_up_to_the_image_edges_verify() {
    // The fixture's grids end at the right edge (tree 0, 65536 steps) and at the bottom edge
    // (tree 1, 32768 + 32767 = 65535 steps); one step further down still lies inside (65536).
    let mut data = fixture();
    check(&data).expect("verifies");
    data.octahedral_normals[1].uv_min = steps(16384, 32769);
    check(&data).expect("65536 steps: one step of rounding");
    // Over the colour grid, or at the image's origin: inside the image, so valid.
    data.octahedral_normals = vec![OctahedralNormalRecord { uv_min: steps(0, 0) }; 2];
    check(&data).expect("at the origin");
    // A colour grid of the whole image: its normal grid can only start at the origin or one
    // step from it.
    let mut data = fixture();
    data.octahedral[0].uv_max = steps(65535, 65535);
    data.octahedral_normals[0].uv_min = steps(1, 1);
    check(&data).expect("one step");
}

#[test]
fn a_normal_grid_leaving_the_image_is_refused() {
    // What changes, the change, the record reported, its grid's corner, the colour grid's size.
    type Case = (&'static str, fn(&mut ContainerData), usize, (u32, u32), (u32, u32));
    let cases: [Case; 5] = [
        (
            "tree 0's grid one step right of the right edge",
            |d| d.octahedral_normals[0].uv_min = steps(32769, 0),
            0,
            (32769, 0),
            (32768, 32768),
        ),
        (
            "tree 1's grid two steps below the bottom edge",
            |d| d.octahedral_normals[1].uv_min = steps(16384, 32770),
            1,
            (16384, 32770),
            (16384, 32767),
        ),
        (
            "at the far corner of the image",
            |d| d.octahedral_normals[1].uv_min = steps(65535, 65535),
            1,
            (65535, 65535),
            (16384, 32767),
        ),
        (
            "a larger colour grid moves the far corner out, the record unchanged",
            |d| d.octahedral[0].uv_max = steps(32769, 32768),
            0,
            (32768, 0),
            (32769, 32768),
        ),
        (
            "the first record that leaves is reported",
            |d| d.octahedral_normals = vec![OctahedralNormalRecord { uv_min: steps(40000, 40000) }; 2],
            0,
            (40000, 40000),
            (32768, 32768),
        ),
    ];
    for (what, change, index, (u, v), (w, h)) in cases {
        let mut data = fixture();
        change(&mut data);
        eprintln!("{what}");
        expect_refused(
            &data,
            index,
            &format!(
                "the normal grid at ({u}, {v}) of the colour grid's size ({w}, {h}) leaves the image (unorm16 steps, \
                 at most 65536)"
            ),
        );
    }
}

// ----------------------------------------------------------------------------------------------
// A reader of 1.14 and before.

#[test]
fn a_reader_that_does_not_know_the_kind_skips_it_and_reads_the_rest_as_before() {
    // A reader of 1.14 or before sees kind 0x0055 as one it does not know. Relabelled as a kind
    // this version does not know either (a private extension), the section is skipped the same
    // way: the rest of the file reads record for record, the views lit as a whole, and verifies.
    let data = fixture();
    let bytes = bytes_of(&data);
    let unknown = 0x0001_0055;
    assert_eq!(SectionKind(unknown).record_size(), None, "a kind this version does not know");
    let skipped = relabel(&bytes, KIND, unknown);
    let c = Container::from_bytes(&skipped).expect("opens");
    assert!(c.octahedral_normals().is_empty(), "the normal grids are skipped");
    assert!(c.section(KIND).is_none());
    assert_eq!(c.octahedral(), data.octahedral.as_slice(), "the impostors stay");
    assert_eq!(c.header().minor, 15, "the header keeps the file's minor; a reader accepts any minor");
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        octahedral_normals: Vec::new(),
        extra_sections: vec![(unknown, bytemuck::cast_slice::<_, u8>(&data.octahedral_normals).to_vec())],
        ..data.clone()
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("an unknown kind is only checksummed");
    assert_eq!((report.octahedral, report.octahedral_normals), (2, 0));
    // Written back without the normal grids, it is the file of the smaller minor.
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    let c = Container::from_bytes(&bytes_of(&without)).expect("opens");
    assert_eq!(c.header().minor, 11);
    verify(&c).expect("verifies");
}
