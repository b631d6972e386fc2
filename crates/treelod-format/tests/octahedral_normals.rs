//! Where the octahedral views' normals lie (spec §6.13.3): the `OCTAHEDRAL_NORMALS` kind (1.15)
//! round-trips and makes a file 1.15, a file without it keeps its smaller minor and reads no
//! normal grids (every view lit as a whole), the writer and the reader at open refuse a record
//! count other than `OCTAHEDRAL`'s (one per impostor, or none), `verify` refuses a normal grid that
//! leaves the image with an error naming the section and the record, and a reader that does not
//! know the kind (1.14 and before) skips it and reads everything else as it was.
//!
//! 1.16's `OCTAHEDRAL_NORMAL_GRIDS`, each grid with its own far corner, round-trips and makes a
//! file 1.16; [`Container::octahedral_normal_grid`] reads a grid of 1.16 and of 1.15 alike (none
//! where the file has neither); the writer, the reader at open and `verify` refuse another count
//! than the impostors', both kinds in one file, a grid whose `uv_max` is below its `uv_min` and an
//! empty grid (one table of cases); a reader of 1.15 skips the kind.

mod common;

use common::{assert_reads_back, bytes_of, check, expect_refused, relabel, resize_section};
use treelod_format::{
    Compression, Container, ContainerData, Error, ErrorClass, MINOR, OctahedralDepthRecord, OctahedralNormalGridRecord,
    OctahedralNormalRecord, OctahedralRecord, PlaneDiffuseRecord, SectionKind, pack, verify,
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
        let reason = format!(
            "the normal grid at ({u}, {v}) of the colour grid's size ({w}, {h}) leaves the image (unorm16 steps, \
             at most 65536)"
        );
        // The reason exactly, not only containing it.
        assert_eq!(expect_refused(&data, KIND, index, &[&reason]), reason);
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

// ----------------------------------------------------------------------------------------------
// 1.16: OCTAHEDRAL_NORMAL_GRIDS, grids of their own size.

const GRIDS: SectionKind = SectionKind::OCTAHEDRAL_NORMAL_GRIDS;

/// A normal grid from `(u0, v0)` to `(u1, v1)`, unorm16 steps.
fn grid(u0: u32, v0: u32, u1: u32, v1: u32) -> OctahedralNormalGridRecord {
    OctahedralNormalGridRecord { uv_min: steps(u0, v0), uv_max: steps(u1, v1) }
}

/// [`fixture`]'s impostors with 1.16's grids in place of 1.15's records, each from the same
/// corner at half its colour grid's size, as the `treelod` build stores them: tree 0's
/// `[32768, 0] .. [49152, 16384]`, tree 1's `[16384, 32768] .. [24576, 49151]`. Verifies.
fn grids_fixture() -> ContainerData {
    ContainerData {
        octahedral_normals: Vec::new(),
        octahedral_normal_grids: vec![grid(32768, 0, 49152, 16384), grid(16384, 32768, 24576, 49151)],
        ..fixture()
    }
}

#[test]
fn the_grids_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 16, "OCTAHEDRAL_NORMAL_GRIDS is format 1.16") };
    assert_eq!(GRIDS.0, 0x0056);
    assert_eq!(GRIDS.name(), Some("OCTAHEDRAL_NORMAL_GRIDS"));
    assert_eq!(GRIDS.to_string(), "OCTAHEDRAL_NORMAL_GRIDS");
    assert_eq!(GRIDS.record_size(), Some(8));
    assert_eq!(size_of::<OctahedralNormalGridRecord>(), 8);
    assert_eq!(GRIDS.since_minor(), 16);
    assert!(GRIDS.compressible());
    // Right after OCTAHEDRAL_NORMALS, which it replaces.
    let at = SectionKind::KNOWN.iter().position(|&k| k == GRIDS).expect("known");
    assert_eq!(SectionKind::KNOWN[at - 1], KIND);
    // Two corners of two unorm16 each, u in the low half, v in the high, little endian.
    let record = grid(0x8000, 0x4000, 0xC000, 0x8000);
    assert_eq!(bytemuck::bytes_of(&record), [0x00, 0x80, 0x00, 0x40, 0x00, 0xC0, 0x00, 0x80]);
}

#[test]
fn a_container_with_grids_of_their_own_size_round_trips_as_format_1_16_and_verifies() {
    let data = grids_fixture();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 16), "{compression:?}");
        assert_eq!(c.octahedral_normal_grids(), data.octahedral_normal_grids.as_slice());
        assert!(c.octahedral_normals().is_empty() && c.section(KIND).is_none(), "one kind of the two");
        let section = c.section(GRIDS).expect("present");
        assert_eq!((section.entry.record_size, section.entry.raw_length), (8, 2 * 8));
        assert_eq!(c.raw_bytes(GRIDS), bytemuck::cast_slice::<_, u8>(&data.octahedral_normal_grids));
        let report = verify(&c).expect("verifies");
        assert_eq!((report.octahedral, report.octahedral_normals, report.octahedral_normal_grids), (2, 0, 2));
        let text = report.to_string();
        assert!(text.contains("2 octahedral impostors, 2 octahedral normal grids\n"), "{text}");
        assert_reads_back(&c, &data, &bytes, compression);
    }
    // With the views' depth planes (1.13) and the points' facing (1.14): still 1.16.
    let data = ContainerData {
        octahedral_depth: vec![OctahedralDepthRecord::default(); 4 + 9],
        point_facing: vec![128],
        ..grids_fixture()
    };
    let bytes = bytes_of(&data);
    let c = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(c.header().minor, 16);
    let report = verify(&c).expect("verifies");
    assert!(report.to_string().contains("13 octahedral depth planes, 2 octahedral normal grids\n"), "{report}");
    assert_reads_back(&c, &data, &bytes, Compression::None);
    // Without the grids: the 1.14 file; with 1.15's records instead: 1.15.
    let older = ContainerData { octahedral_normal_grids: Vec::new(), ..data.clone() };
    assert_eq!(Container::from_bytes(&bytes_of(&older)).expect("opens").header().minor, 14);
    let v1_15 = ContainerData { octahedral_normals: fixture().octahedral_normals, ..older };
    assert_eq!(Container::from_bytes(&bytes_of(&v1_15)).expect("opens").header().minor, 15);
}

#[test]
fn the_reader_gives_each_impostor_its_grid_of_1_16_or_of_1_15() {
    // 1.16: the records as stored.
    let c = Container::from_bytes(&bytes_of(&grids_fixture())).expect("opens");
    assert_eq!(c.octahedral_normal_grid(0), Some(grid(32768, 0, 49152, 16384)));
    assert_eq!(c.octahedral_normal_grid(1), Some(grid(16384, 32768, 24576, 49151)));
    assert_eq!(c.octahedral_normal_grid(2), None, "no third impostor");
    // 1.15: grids of the colour grids' size from the records' corners, the far corner held inside
    // the image (tree 0's at 32768 + 32768 = 65536 steps is 65535), the same as the record's own
    // `grid`; OCTAHEDRAL_NORMAL_GRIDS itself is empty.
    let c = Container::from_bytes(&bytes_of(&fixture())).expect("opens");
    assert!(c.octahedral_normal_grids().is_empty());
    assert_eq!(c.octahedral_normal_grid(0), Some(grid(32768, 0, 65535, 32768)));
    assert_eq!(c.octahedral_normal_grid(1), Some(grid(16384, 32768, 32768, 65535)));
    for (k, (n, o)) in c.octahedral_normals().iter().zip(c.octahedral()).enumerate() {
        assert_eq!(c.octahedral_normal_grid(k), Some(n.grid(o)), "impostor {k}");
    }
    assert_eq!(c.octahedral_normal_grid(2), None, "no third impostor");
    // Neither kind (1.14 and before): no grid, every view lit as a whole.
    let c = Container::from_bytes(&bytes_of(&ContainerData { octahedral_normals: Vec::new(), ..fixture() }))
        .expect("opens");
    assert_eq!((c.octahedral_normal_grid(0), c.octahedral_normal_grid(1)), (None, None));
    // No impostors: none either.
    let c = Container::from_bytes(&bytes_of(&common::one_leaf_cell("plain"))).expect("opens");
    assert_eq!(c.octahedral_normal_grid(0), None);
}

#[test]
fn grids_of_any_size_inside_the_image_verify() {
    // Larger than the colour grid, the whole image, one step per side, over the colour grid: a
    // grid needs only its two corners in order.
    type Edit = fn(&mut ContainerData);
    let cases: [(&str, Edit); 5] = [
        ("the fixture", |_| {}),
        ("larger than its colour grid", |d| d.octahedral_normal_grids[0] = grid(0, 0, 60000, 60000)),
        ("the whole image", |d| d.octahedral_normal_grids[1] = grid(0, 0, 65535, 65535)),
        ("one step per side", |d| d.octahedral_normal_grids[0] = grid(65534, 65534, 65535, 65535)),
        ("the colour grid itself", |d| d.octahedral_normal_grids[0] = grid(0, 0, 32768, 32768)),
    ];
    for (what, edit) in cases {
        let mut data = grids_fixture();
        edit(&mut data);
        let report = check(&data).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(report.octahedral_normal_grids, 2, "{what}");
    }
}

/// Where a refusal comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    /// The writer, [`ContainerData::to_bytes`] (`Error::Write`).
    Write,
    /// [`Container::from_bytes`].
    Open,
    /// [`verify`].
    Verify,
}

/// What a refusal case starts from: data to write, or the bytes of a file.
enum Input {
    Data(Box<ContainerData>),
    Bytes(Vec<u8>),
}

/// The first refusal of `input` on its way through the writer, the reader's open and `verify`.
fn first_refusal(input: Input) -> Option<(Stage, Error)> {
    let bytes = match input {
        Input::Data(data) => match data.to_bytes(Compression::None) {
            Ok(bytes) => bytes,
            Err(e) => return Some((Stage::Write, e)),
        },
        Input::Bytes(bytes) => bytes,
    };
    let c = match Container::from_bytes(&bytes) {
        Ok(c) => c,
        Err(e) => return Some((Stage::Open, e)),
    };
    verify(&c).err().map(|e| (Stage::Verify, e))
}

/// [`grids_fixture`] changed by `edit`, to write.
fn edited(edit: impl FnOnce(&mut ContainerData)) -> Input {
    let mut data = grids_fixture();
    edit(&mut data);
    Input::Data(Box::new(data))
}

/// The grids' file with a section of 1.15's records at the grids' corners added: written as a
/// kind this version does not know, then relabelled `OCTAHEDRAL_NORMALS` with its record size
/// (the writer refuses to write both kinds).
fn both_kinds_in_a_file() -> Vec<u8> {
    let private = 0x0001_0055;
    let normals: Vec<OctahedralNormalRecord> =
        grids_fixture().octahedral_normal_grids.iter().map(|g| OctahedralNormalRecord { uv_min: g.uv_min }).collect();
    let data = ContainerData {
        extra_sections: vec![(private, bytemuck::cast_slice::<_, u8>(&normals).to_vec())],
        ..grids_fixture()
    };
    let mut bytes = bytes_of(&data);
    Container::from_bytes(&bytes).expect("the private kind is skipped");
    // A private kind's records are bytes; 1.15's are 4 (spec §4: the entry's record size).
    let at = common::entry_offset(&bytes, SectionKind(private));
    bytes[at + 32..at + 36].copy_from_slice(&4u32.to_le_bytes());
    relabel(&bytes, SectionKind(private), KIND.0)
}

#[test]
fn the_grids_are_refused_where_the_spec_says() {
    // What changes, where the refusal comes from, the record named (the writer's message names
    // the kind in its text) and a part of the reason.
    type Case = (&'static str, fn() -> Input, Stage, usize, &'static str);
    let cases: [Case; 13] = [
        // One record per impostor, or none (§9.1).
        (
            "one grid fewer",
            || edited(|d| d.octahedral_normal_grids.truncate(1)),
            Stage::Write,
            0,
            "1 records, OCTAHEDRAL has 2",
        ),
        (
            "one grid more",
            || edited(|d| d.octahedral_normal_grids.push(grid(0, 0, 1, 1))),
            Stage::Write,
            0,
            "3 records, OCTAHEDRAL has 2",
        ),
        (
            "grids without impostors",
            || Input::Data(Box::new(ContainerData { octahedral: Vec::new(), ..grids_fixture() })),
            Stage::Write,
            0,
            "2 records, OCTAHEDRAL has 0",
        ),
        (
            "a file with one grid fewer",
            || Input::Bytes(resize_section(&bytes_of(&grids_fixture()), GRIDS, -8)),
            Stage::Open,
            0,
            "1 records, OCTAHEDRAL has 2",
        ),
        (
            "a file whose impostors are of a kind this version does not know",
            || Input::Bytes(relabel(&bytes_of(&grids_fixture()), SectionKind::OCTAHEDRAL, 0x0001_0053)),
            Stage::Open,
            0,
            "2 records, OCTAHEDRAL has 0",
        ),
        // One kind of the two (§6.13.3, §9.1).
        (
            "both kinds written",
            || {
                Input::Data(Box::new(ContainerData {
                    octahedral_normals: fixture().octahedral_normals,
                    ..grids_fixture()
                }))
            },
            Stage::Write,
            0,
            "the file also holds OCTAHEDRAL_NORMALS",
        ),
        (
            "both kinds in a file",
            || Input::Bytes(both_kinds_in_a_file()),
            Stage::Open,
            0,
            "also holds OCTAHEDRAL_NORMALS",
        ),
        // Corners in order, the grid not empty (§9.2).
        (
            "uv_max left of uv_min",
            || edited(|d| d.octahedral_normal_grids[0] = grid(32768, 0, 32767, 16384)),
            Stage::Verify,
            0,
            "uv_min (32768, 0) is not <= uv_max (32767, 16384) per component",
        ),
        (
            "uv_max above uv_min",
            || edited(|d| d.octahedral_normal_grids[1] = grid(16384, 32768, 24576, 32767)),
            Stage::Verify,
            1,
            "uv_min (16384, 32768) is not <= uv_max (24576, 32767) per component",
        ),
        (
            "the corners swapped",
            || edited(|d| d.octahedral_normal_grids[1] = grid(24576, 49151, 16384, 32768)),
            Stage::Verify,
            1,
            "uv_min (24576, 49151) is not <= uv_max (16384, 32768) per component",
        ),
        (
            "no width",
            || edited(|d| d.octahedral_normal_grids[0] = grid(32768, 0, 32768, 16384)),
            Stage::Verify,
            0,
            "the normal grid (32768, 0) .. (32768, 16384) is empty (uv_min < uv_max per component)",
        ),
        (
            "a point",
            || edited(|d| d.octahedral_normal_grids[1] = grid(0, 0, 0, 0)),
            Stage::Verify,
            1,
            "the normal grid (0, 0) .. (0, 0) is empty (uv_min < uv_max per component)",
        ),
        (
            "the first record refused is reported",
            || edited(|d| d.octahedral_normal_grids = vec![grid(100, 200, 100, 300), grid(5, 5, 4, 4)]),
            Stage::Verify,
            0,
            "the normal grid (100, 200) .. (100, 300) is empty",
        ),
    ];
    for (what, input, stage, index, needle) in cases {
        let Some((at, err)) = first_refusal(input()) else { panic!("{what}: accepted") };
        assert_eq!(at, stage, "{what}: {err}");
        assert_eq!(err.class(), ErrorClass::Invalid, "{what}: {err}");
        let message = err.to_string();
        match (&err, stage) {
            (Error::Write(text), Stage::Write) => {
                assert!(text.contains(&format!("OCTAHEDRAL_NORMAL_GRIDS record {index}: ")), "{what}: {message}");
                assert!(text.contains(needle), "{what}: {message}");
            }
            (Error::BadRecord { kind, index: i, reason }, Stage::Open | Stage::Verify) => {
                assert_eq!((*kind, *i), (GRIDS, index), "{what}: {message}");
                assert!(reason.contains(needle), "{what}: {message}");
                assert!(message.starts_with(&format!("OCTAHEDRAL_NORMAL_GRIDS record {index}: ")), "{what}: {message}");
            }
            _ => panic!("{what}: unexpected {err:?}"),
        }
    }
    // A length that is not a whole number of records is refused at open as well, and an empty
    // section is an absent one.
    let bytes = bytes_of(&grids_fixture());
    for delta in [-1, -4, -7, -9] {
        let err = Container::from_bytes(&resize_section(&bytes, GRIDS, delta)).expect_err("a partial record");
        assert_eq!(err.class(), ErrorClass::Invalid, "{delta:+}: {err}");
        assert!(err.to_string().contains("OCTAHEDRAL_NORMAL_GRIDS"), "{delta:+}: {err}");
    }
    let c = Container::from_bytes(&resize_section(&bytes, GRIDS, -16)).expect("an empty section opens");
    assert!(c.octahedral_normal_grids().is_empty() && c.octahedral_normal_grid(0).is_none());
}

#[test]
fn a_reader_of_1_15_skips_the_grids_and_reads_the_rest_as_before() {
    // Relabelled as a kind this version does not know, as a 1.15 reader sees 0x0056: skipped,
    // the impostors read, no grid, and written back without it, the file of the smaller minor.
    let data = grids_fixture();
    let unknown = 0x0001_0056;
    let c = Container::from_bytes(&relabel(&bytes_of(&data), GRIDS, unknown)).expect("opens");
    assert!(c.octahedral_normal_grids().is_empty() && c.octahedral_normal_grid(0).is_none());
    assert_eq!(c.octahedral(), data.octahedral.as_slice());
    assert_eq!(c.header().minor, 16, "the header keeps the file's minor");
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        octahedral_normal_grids: Vec::new(),
        extra_sections: vec![(unknown, bytemuck::cast_slice::<_, u8>(&data.octahedral_normal_grids).to_vec())],
        ..data
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("an unknown kind is only checksummed");
    assert_eq!((report.octahedral, report.octahedral_normal_grids), (2, 0));
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    assert_eq!(Container::from_bytes(&bytes_of(&without)).expect("opens").header().minor, 11);
}
