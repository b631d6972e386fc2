//! The calibration's FLIP error (spec §6.19): the `CALIBRATION_FLIP` kind (1.17) round-trips and
//! makes a file 1.17, a file without it keeps its smaller minor and reads no records; `verify`
//! checks each record (elevations exactly −1, a row over every view, or finite in `[0, 90]`, and
//! non-decreasing, techniques of any code non-decreasing within an elevation, heights finite,
//! positive and strictly increasing within an elevation and technique, FLIP errors in `[0, 1]`);
//! each elevation restarts the techniques and heights, and the rows need no other section. Each
//! rule is broken once and refused with an error naming `CALIBRATION_FLIP` and the record. A reader
//! that does not know the kind (1.16 and before) skips it and reads the rest as before.

mod common;

use common::{bytes_of, check, expect_refused, relabel};
use treelod_format::{
    CalibrationRecord, Compression, Container, ContainerData, FlipCalibrationRecord, MINOR, SectionKind,
    calibration_technique, verify,
};

use calibration_technique::{FULL, OCTAHEDRAL, SPT};

const KIND: SectionKind = SectionKind::CALIBRATION_FLIP;
const EVERY_VIEW: f32 = FlipCalibrationRecord::EVERY_VIEW;

fn row(elevation: f32, technique: u32, height: f32, flip: f32) -> FlipCalibrationRecord {
    FlipCalibrationRecord { elevation, technique, height, flip }
}

/// The one-leaf cell of `common` with FLIP rows of `FULL` at 16 and 64 pixels, `SPT` at 8 and 32
/// and `OCTAHEDRAL` (an added code) at 8, over every view and at 0 and 90 degrees: records 0–4,
/// 5–9 and 10–14. No RMSE table: the rows are self-describing. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("calibration-flip-fixture");
    let rows = [(FULL, 16.0, 0.0), (FULL, 64.0, 0.0), (SPT, 8.0, 0.5), (SPT, 32.0, 0.25), (OCTAHEDRAL, 8.0, 0.75)];
    for (elevation, scale) in [(EVERY_VIEW, 1.0), (0.0, 1.25), (90.0, 0.5)] {
        data.calibration_flip
            .extend(rows.iter().map(|&(technique, height, flip)| row(elevation, technique, height, flip * scale)));
    }
    data
}

/// The fixture with record `index` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut FlipCalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.calibration_flip[index]);
    data
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 17, "the calibration's FLIP error is format 1.17") };
    assert_eq!(
        (KIND.0, KIND.name(), KIND.to_string().as_str()),
        (0x0075, Some("CALIBRATION_FLIP"), "CALIBRATION_FLIP")
    );
    assert_eq!(KIND.record_size(), Some(16));
    assert_eq!(size_of::<FlipCalibrationRecord>(), 16);
    assert_eq!(KIND.since_minor(), 17);
    assert!(KIND.compressible());
    assert_eq!(SectionKind::KNOWN.len(), 40);
    assert!(SectionKind::KNOWN.contains(&KIND));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(EVERY_VIEW, -1.0);
}

#[test]
fn a_valid_table_round_trips_as_a_1_17_file_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::Zstd { level: 19 }] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, 17, "CALIBRATION_FLIP is a kind of 1.17");
        assert_eq!(c.calibration_flip(), data.calibration_flip.as_slice());
        assert_eq!(ContainerData::from_container(&c), data);
        let entry = c.section(KIND).expect("written").entry;
        assert_eq!((entry.record_size, entry.raw_length), (16, 15 * 16));
        let report = verify(&c).expect("valid");
        assert_eq!((report.calibration, report.calibration_flip), (0, 15));
        // Written again, the same bytes.
        assert!(ContainerData::from_container(&c).to_bytes(compression).expect("writes") == bytes);
    }
}

#[test]
fn without_the_kind_a_file_is_what_it_was_and_has_no_records() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 17);
    data.calibration_flip.clear();
    assert_eq!(minor(&data), 0, "the fixture without the rows is a 1.0 file");
    let report = check(&data).expect("no FLIP rows is valid");
    assert_eq!(report.calibration_flip, 0);
    let c = Container::from_bytes(&bytes_of(&data)).expect("opens");
    assert!(c.calibration_flip().is_empty() && c.section(KIND).is_none());
    // Beside the RMSE tables, the rows still mark the file 1.17, and without them it is 1.5.
    let mut data = fixture();
    data.calibration = vec![CalibrationRecord { technique: FULL, height: 16.0, error: 0.0, primitives: 1.0 }];
    assert_eq!(minor(&data), 17);
    data.calibration_flip.clear();
    assert_eq!(minor(&data), 5);
}

#[test]
fn edge_values_restarts_and_any_technique_pass() {
    // Rows over every view alone, and rows of one elevation alone.
    let mut data = fixture();
    data.calibration_flip.truncate(5);
    assert_eq!(check(&data).expect("rows over every view alone").calibration_flip, 5);
    let mut data = fixture();
    data.calibration_flip.drain(..5);
    assert_eq!(check(&data).expect("rows per elevation alone").calibration_flip, 10);
    // The extreme values each field allows.
    let mut data = fixture();
    for (r, (elevation, flip)) in data.calibration_flip[5..10].iter_mut().zip([(0.0, 0.0), (0.0, 1.0)].repeat(3)) {
        (r.elevation, r.flip) = (elevation, flip);
    }
    data.calibration_flip[4].height = f32::MAX;
    data.calibration_flip[9].flip = -0.0;
    check(&data).expect("flip 0, -0 and 1, height up to f32::MAX");
    let mut data = fixture();
    data.calibration_flip[5].height = f32::MIN_POSITIVE / 2.0;
    check(&data).expect("any positive height");
    // -0 and 0 are one elevation.
    let mut data = fixture();
    data.calibration_flip[5].elevation = -0.0;
    data.calibration_flip[6].elevation = -0.0;
    check(&data).expect("-0 is the elevation 0");
    // Any elevation in [0, 90], not only those the build measures.
    let mut data = fixture();
    for r in &mut data.calibration_flip[10..] {
        r.elevation = 45.5;
    }
    check(&data).expect("any elevation in [0, 90]");
    // Any technique code: the base ones, the added ones and codes no minor defines yet (a reader
    // skips the rows of a code it does not define, as in CALIBRATION_ELEVATIONS_ADDED).
    let mut data = fixture();
    data.calibration_flip[4].technique = calibration_technique::COUNT;
    data.calibration_flip[14].technique = u32::MAX;
    check(&data).expect("codes a later minor may define");
}

// ----------------------------------------------------------------------------------------------
// Verify: one rule at a time.

#[test]
fn refusals() {
    // (record edited, its edit, record reported, what the reason says), one rule broken each.
    type Edit = fn(&mut FlipCalibrationRecord);
    let table: [(usize, Edit, usize, &[&str]); 15] = [
        (1, |r| r.flip = f32::NAN, 1, &["FLIP error NaN lies outside [0, 1]"]),
        (6, |r| r.flip = 1.5, 6, &["FLIP error 1.5 lies outside [0, 1]"]),
        (7, |r| r.flip = -0.01, 7, &["FLIP error -0.01 lies outside [0, 1]"]),
        (8, |r| r.flip = f32::INFINITY, 8, &["FLIP error inf lies outside [0, 1]"]),
        (2, |r| r.height = 0.0, 2, &["height 0 is not a positive number of pixels"]),
        (3, |r| r.height = -4.0, 3, &["height -4 is not a positive number of pixels"]),
        (4, |r| r.height = f32::NAN, 4, &["height NaN is not a positive number of pixels"]),
        (14, |r| r.height = f32::INFINITY, 14, &["height inf is not a positive number of pixels"]),
        (10, |r| r.elevation = 95.0, 10, &["elevation 95 is neither -1 (every view) nor in [0, 90] degrees"]),
        (0, |r| r.elevation = -0.5, 0, &["elevation -0.5 is neither -1"]),
        (5, |r| r.elevation = f32::NAN, 5, &["elevation NaN is neither -1"]),
        (12, |r| r.elevation = f32::NEG_INFINITY, 12, &["elevation -inf is neither -1"]),
        // The first row at 0 degrees moved to 90: the next row's 0 follows it.
        (5, |r| r.elevation = 90.0, 6, &["elevation 0 follows elevation 90"]),
        // The first row over every view made SPT's: FULL follows it.
        (0, |r| r.technique = SPT, 1, &["technique 0 follows technique 1"]),
        // FULL's second height made its first.
        (1, |r| r.height = 16.0, 1, &["height 16 does not increase strictly after 16"]),
    ];
    for (index, edit, reported, needles) in table {
        expect_refused(&edited(index, edit), KIND, reported, needles);
    }
}

#[test]
fn a_decreasing_elevation_is_refused() {
    // A row over every view after the elevation 90.
    let mut data = fixture();
    data.calibration_flip.push(row(EVERY_VIEW, FULL, 1.0e7, 0.0));
    expect_refused(&data, KIND, 15, &["elevation -1 follows elevation 90"]);
    // The elevation 0 moved to the end.
    let mut data = fixture();
    data.calibration_flip[5..].rotate_left(5);
    expect_refused(&data, KIND, 10, &["elevation 0 follows elevation 90"]);
    // Two elevations interleaved: 0, 90, 0.
    let mut data = fixture();
    data.calibration_flip[6].elevation = 90.0;
    expect_refused(&data, KIND, 7, &["elevation 0 follows elevation 90"]);
}

#[test]
fn a_decreasing_technique_within_an_elevation_is_refused() {
    // FULL after SPT over every view.
    let mut data = fixture();
    data.calibration_flip[0..4].rotate_left(2);
    expect_refused(&data, KIND, 2, &["technique 0 follows technique 1"]);
    // OCTAHEDRAL before SPT at 90 degrees.
    let mut data = fixture();
    data.calibration_flip.swap(12, 14);
    expect_refused(&data, KIND, 13, &["technique 1 follows technique 9"]);
}

#[test]
fn a_height_that_does_not_increase_within_an_elevation_and_technique_is_refused() {
    // Equal.
    let data = edited(1, |r| r.height = 16.0);
    expect_refused(&data, KIND, 1, &["height 16 does not increase strictly after 16"]);
    // Decreasing.
    let mut data = fixture();
    data.calibration_flip.swap(7, 8);
    expect_refused(&data, KIND, 8, &["height 8 does not increase strictly after 32"]);
    // A new technique or elevation restarts the heights.
    let mut data = fixture();
    data.calibration_flip[2].height = 1.0;
    data.calibration_flip[5].height = 1.0;
    check(&data).expect("heights restart with each technique and elevation");
}

#[test]
fn the_first_broken_record_is_reported() {
    let mut data = fixture();
    data.calibration_flip[6].flip = 2.0;
    data.calibration_flip[11].technique = 0;
    data.calibration_flip[13].elevation = 91.0;
    expect_refused(&data, KIND, 6, &["FLIP error 2 "]);
}

// ----------------------------------------------------------------------------------------------
// A reader of 1.16 and before.

#[test]
fn a_reader_that_does_not_know_the_kind_skips_it_and_reads_the_rest_as_before() {
    // A reader of 1.16 or before sees kind 0x0075 as one it does not know. Relabelled as a kind
    // this version does not know either (a private extension), the section is skipped the same
    // way: the rest of the file reads record for record, and verifies, with the RMSE table.
    let mut data = fixture();
    data.calibration = vec![CalibrationRecord { technique: FULL, height: 16.0, error: 0.0, primitives: 1.0 }];
    let bytes = data.to_bytes(Compression::None).expect("writes");
    let unknown = 0x0001_0075;
    assert_eq!(SectionKind(unknown).record_size(), None);
    let c = Container::from_bytes(&relabel(&bytes, KIND, unknown)).expect("opens");
    assert!(c.calibration_flip().is_empty() && c.section(KIND).is_none(), "skipped");
    assert_eq!(c.header().minor, 17, "the header keeps the file's minor; a reader accepts any minor");
    assert_eq!(c.calibration(), data.calibration.as_slice());
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        calibration_flip: Vec::new(),
        extra_sections: vec![(unknown, bytemuck::cast_slice::<_, u8>(&data.calibration_flip).to_vec())],
        ..data.clone()
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("unknown kinds are only checksummed");
    assert_eq!((report.calibration, report.calibration_flip), (1, 0));
    // Written back without it, it is the file of the smaller minor.
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    let c = Container::from_bytes(&without.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 5);
    verify(&c).expect("verifies");
}
