//! Calibration of the techniques added after 1.11 (spec §6.18): the kinds `CALIBRATION_ADDED` and
//! `CALIBRATION_ELEVATIONS_ADDED` (1.12) round-trip and make a file 1.12, a file without them keeps
//! its smaller minor; `verify` checks their records as `CALIBRATION`'s and
//! `CALIBRATION_ELEVATIONS`' (a technique from `FIRST_ADDED` on, heights finite, positive and
//! strictly increasing, errors in `[0, 1]`, primitive counts finite and `≥ 0`, the same order) and
//! the rules that tie them to the others (`CALIBRATION_ADDED` needs `CALIBRATION`; the tables per
//! elevation need `CALIBRATION_ELEVATIONS`, at its elevations, each with every pair of
//! `CALIBRATION_ADDED`; a file with `CALIBRATION_ELEVATIONS` and `CALIBRATION_ADDED` has them),
//! while `CALIBRATION` and `CALIBRATION_ELEVATIONS` hold only the codes below `FIRST_ADDED`. Each
//! rule is broken once and refused with an error naming the section and the record. A reader that
//! does not know the kinds (1.11 and before) skips them and reads the rest as before.

mod common;

use common::{assert_reads_back, bytes_of, check, expect_refused, relabel};
use treelod_format::{
    CalibrationRecord, Compression, Container, ContainerData, ElevationCalibrationRecord, MINOR, SectionKind,
    calibration_technique, verify,
};

use calibration_technique::{CROSSED, FIRST_ADDED, FULL, OCTAHEDRAL, SPT};

fn sample(technique: u32, height: f32, error: f32, primitives: f32) -> CalibrationRecord {
    CalibrationRecord { technique, height, error, primitives }
}

/// The samples at `elevation` of `records`, each error scaled by `scale`.
fn at(elevation: f32, scale: f32, records: &[CalibrationRecord]) -> Vec<ElevationCalibrationRecord> {
    records
        .iter()
        .map(|r| ElevationCalibrationRecord {
            elevation,
            technique: r.technique,
            height: r.height,
            error: r.error * scale,
            primitives: r.primitives,
        })
        .collect()
}

/// The elevations of the fixture's tables, degrees.
const ELEVATIONS: [(f32, f32); 3] = [(0.0, 1.5), (30.0, 1.0), (90.0, 0.5)];

/// The one-leaf cell of `common` with a calibration of `FULL` at 16 and 64 pixels and `SPT` at 8
/// and 32, the octahedral impostor's in `CALIBRATION_ADDED` at 8, 16 and 64 (records 0–2), and
/// both per elevation at 0, 30 and 90 degrees (`CALIBRATION_ELEVATIONS_ADDED` records 0–2, 3–5 and
/// 6–8). Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("calibration-added-fixture");
    data.calibration = vec![
        sample(FULL, 16.0, 0.0, 1.0),
        sample(FULL, 64.0, 0.0, 1.0),
        sample(SPT, 8.0, 0.5, 3.0),
        sample(SPT, 32.0, 0.25, 3.0),
    ];
    data.calibration_added = vec![
        sample(OCTAHEDRAL, 8.0, 0.5, 2.0),
        sample(OCTAHEDRAL, 16.0, 0.25, 2.0),
        sample(OCTAHEDRAL, 64.0, 0.125, 2.0),
    ];
    for (elevation, scale) in ELEVATIONS {
        data.calibration_elevations.extend(at(elevation, scale, &data.calibration));
        data.calibration_elevations_added.extend(at(elevation, scale, &data.calibration_added));
    }
    data
}

/// The fixture with record `index` of `CALIBRATION_ADDED` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut CalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.calibration_added[index]);
    data
}

/// The fixture with record `index` of `CALIBRATION_ELEVATIONS_ADDED` changed by `edit`.
fn edited_at(index: usize, edit: impl FnOnce(&mut ElevationCalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.calibration_elevations_added[index]);
    data
}

const ADDED: SectionKind = SectionKind::CALIBRATION_ADDED;
const ADDED_AT: SectionKind = SectionKind::CALIBRATION_ELEVATIONS_ADDED;

// ----------------------------------------------------------------------------------------------
// The kinds, the codes, the round trip and the version.

#[test]
fn the_kinds_and_the_codes_are_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 12, "the added techniques' calibration is format 1.12") };
    for (kind, value, name, size) in
        [(ADDED, 0x0073, "CALIBRATION_ADDED", 16), (ADDED_AT, 0x0074, "CALIBRATION_ELEVATIONS_ADDED", 20)]
    {
        assert_eq!((kind.0, kind.name(), kind.to_string().as_str()), (value, Some(name), name));
        assert_eq!(kind.record_size(), Some(size));
        assert_eq!(kind.since_minor(), 12);
        assert!(SectionKind::KNOWN.contains(&kind));
    }
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    assert_eq!((OCTAHEDRAL, FIRST_ADDED, calibration_technique::COUNT), (9, 9, 10));
    assert_eq!(calibration_technique::name(OCTAHEDRAL), Some("octahedral"));
    assert_eq!(calibration_technique::name(calibration_technique::COUNT), None);
}

#[test]
fn valid_tables_round_trip_as_a_1_12_file_and_verify() {
    let data = fixture();
    for compression in [Compression::None, Compression::Zstd { level: 19 }] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, 12, "the added sections are kinds of 1.12");
        assert_eq!(c.calibration_added(), data.calibration_added.as_slice());
        assert_eq!(c.calibration_elevations_added(), data.calibration_elevations_added.as_slice());
        assert_eq!(c.calibration(), data.calibration.as_slice(), "CALIBRATION keeps its own codes");
        let section = c.section(ADDED).expect("present");
        assert_eq!((section.entry.record_size, section.entry.raw_length), (16, 48));
        let section = c.section(ADDED_AT).expect("present");
        assert_eq!((section.entry.record_size, section.entry.raw_length), (20, 180));
        let report = verify(&c).expect("valid");
        assert_eq!(
            (
                report.calibration,
                report.calibration_elevations,
                report.calibration_added,
                report.calibration_elevations_added
            ),
            (4, 12, 3, 9)
        );
        assert_reads_back(&c, &data, &bytes, compression);
    }
}

#[test]
fn without_the_kinds_a_file_keeps_its_smaller_minor() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 12);
    data.calibration_added.clear();
    data.calibration_elevations_added.clear();
    assert_eq!(minor(&data), 7, "the calibration per elevation is 1.7");
    let report = check(&data).expect("no added tables is valid");
    assert_eq!((report.calibration_added, report.calibration_elevations_added), (0, 0));
    let c = Container::from_bytes(&bytes_of(&data)).expect("opens");
    assert!(c.calibration_added().is_empty() && c.calibration_elevations_added().is_empty());
    assert!(c.section(ADDED).is_none() && c.section(ADDED_AT).is_none(), "no empty section is written");

    // Without the tables per elevation, CALIBRATION_ADDED alone makes a 1.5 file 1.12.
    data.calibration_elevations.clear();
    assert_eq!(minor(&data), 5);
    data.calibration_added = fixture().calibration_added;
    assert_eq!(minor(&data), 12);
    let report = check(&data).expect("the added means without tables per elevation are valid");
    assert_eq!((report.calibration_added, report.calibration_elevations_added), (3, 0));
}

#[test]
fn edge_values_pass() {
    let mut data = fixture();
    data.calibration_elevations.clear();
    data.calibration_elevations_added.clear();
    data.calibration_added =
        vec![sample(OCTAHEDRAL, f32::MIN_POSITIVE, 0.0, -0.0), sample(OCTAHEDRAL, f32::MAX, 1.0, f32::MAX)];
    check(&data).expect("the extremes each field allows");
    // The elevations need not be the build's, only CALIBRATION_ELEVATIONS'.
    let mut data = fixture();
    for r in data.calibration_elevations[4..8].iter_mut().chain(&mut data.calibration_elevations_added[3..6]) {
        r.elevation = 45.5;
    }
    check(&data).expect("any elevation of CALIBRATION_ELEVATIONS");
}

// ----------------------------------------------------------------------------------------------
// Verify: the codes of each section.

#[test]
fn an_added_section_refuses_the_codes_of_1_11() {
    expect_refused(
        &edited(0, |r| r.technique = CROSSED),
        ADDED,
        0,
        &["technique 8 is not defined here (9..): crossed belongs in CALIBRATION"],
    );
    expect_refused(&edited(2, |r| r.technique = FULL), ADDED, 2, &["technique 0 is not defined here (9..): full"]);
    expect_refused(
        &edited_at(4, |r| r.technique = CROSSED),
        ADDED_AT,
        4,
        &["technique 8 is not defined here (9..): crossed belongs in CALIBRATION_ELEVATIONS"],
    );
}

/// Codes past those this reader defines are techniques of a later minor: their records verify
/// (sorted and paired as every other) and a reader skips them, so a later file stays readable.
#[test]
fn an_added_section_accepts_the_codes_of_later_minors() {
    let later = calibration_technique::COUNT;
    let mut data = fixture();
    data.calibration_added.push(sample(later, 8.0, 0.5, 1.0));
    data.calibration_added.push(sample(u32::MAX, 8.0, 0.5, 1.0));
    data.calibration_elevations_added.clear();
    for (elevation, scale) in ELEVATIONS {
        data.calibration_elevations_added.extend(at(elevation, scale, &data.calibration_added));
    }
    check(&data).expect("codes of later minors verify");
    // Still sorted by code: a later code before the octahedral rows is refused.
    let mut unsorted = data.clone();
    unsorted.calibration_added.swap(0, 3);
    assert!(check(&unsorted).is_err());
    // And still paired per elevation.
    let mut unpaired = data;
    unpaired.calibration_elevations_added.retain(|r| !(r.elevation == 30.0 && r.technique == later));
    assert!(check(&unpaired).is_err());
}

#[test]
fn calibration_and_its_elevations_refuse_the_added_codes() {
    let mut data = fixture();
    data.calibration[3].technique = OCTAHEDRAL;
    expect_refused(
        &data,
        SectionKind::CALIBRATION,
        3,
        &["technique 9 is not defined here (0..9): octahedral belongs in CALIBRATION_ADDED"],
    );
    let mut data = fixture();
    data.calibration_elevations[7].technique = OCTAHEDRAL;
    expect_refused(
        &data,
        SectionKind::CALIBRATION_ELEVATIONS,
        7,
        &["technique 9 is not defined here (0..9): octahedral belongs in CALIBRATION_ELEVATIONS_ADDED"],
    );
    // Moved whole into CALIBRATION, the octahedral rows are still refused there.
    let mut data = fixture();
    data.calibration.append(&mut data.calibration_added);
    data.calibration_elevations.clear();
    data.calibration_elevations_added.clear();
    expect_refused(&data, SectionKind::CALIBRATION, 4, &["technique 9 is not defined here (0..9)"]);
}

// ----------------------------------------------------------------------------------------------
// Verify: the records' fields and order, as CALIBRATION's and CALIBRATION_ELEVATIONS'.

#[test]
fn unsorted_records_are_refused() {
    expect_refused(&edited(1, |r| r.height = 8.0), ADDED, 1, &["height 8 does not increase strictly after 8"]);
    let mut data = fixture();
    data.calibration_added.swap(1, 2);
    expect_refused(&data, ADDED, 2, &["height 16 does not increase strictly after 64"]);
    // Per elevation: a height out of order within the elevation 30, and an elevation that falls.
    let mut data = fixture();
    data.calibration_elevations_added.swap(3, 4);
    expect_refused(&data, ADDED_AT, 4, &["height 8 does not increase strictly after 16"]);
    let mut data = fixture();
    data.calibration_elevations_added[3..].rotate_left(3);
    expect_refused(&data, ADDED_AT, 6, &["elevation 30 follows elevation 90"]);
}

#[test]
fn non_finite_or_out_of_range_values_are_refused() {
    for (height, text) in
        [(0.0, "height 0 "), (-4.0, "height -4 "), (f32::NAN, "height NaN"), (f32::INFINITY, "height inf")]
    {
        expect_refused(&edited(2, |r| r.height = height), ADDED, 2, &[text, "not a positive number of pixels"]);
        expect_refused(&edited_at(5, |r| r.height = height), ADDED_AT, 5, &[text, "not a positive number of pixels"]);
    }
    for (error, text) in
        [(-0.01, "error -0.01 "), (1.5, "error 1.5 "), (f32::NAN, "error NaN"), (f32::INFINITY, "error inf")]
    {
        expect_refused(&edited(0, |r| r.error = error), ADDED, 0, &[text, "outside [0, 1]"]);
        expect_refused(&edited_at(1, |r| r.error = error), ADDED_AT, 1, &[text, "outside [0, 1]"]);
    }
    for (primitives, text) in [(-1.0, "count -1 "), (f32::NAN, "count NaN"), (f32::INFINITY, "count inf")] {
        expect_refused(&edited(1, |r| r.primitives = primitives), ADDED, 1, &[text, "not a finite count"]);
        expect_refused(&edited_at(7, |r| r.primitives = primitives), ADDED_AT, 7, &[text, "not a finite count"]);
    }
    for (elevation, text) in [(-1.0, "elevation -1 "), (90.5, "elevation 90.5 "), (f32::NAN, "elevation NaN")] {
        expect_refused(&edited_at(0, |r| r.elevation = elevation), ADDED_AT, 0, &[text, "outside [0, 90] degrees"]);
    }
}

// ----------------------------------------------------------------------------------------------
// Verify: the rules that tie the added tables to the others.

#[test]
fn added_tables_without_calibration_are_refused() {
    let mut data = fixture();
    data.calibration.clear();
    data.calibration_elevations.clear();
    data.calibration_elevations_added.clear();
    expect_refused(&data, ADDED, 0, &["no CALIBRATION,"]);
}

#[test]
fn added_means_beside_tables_per_elevation_need_their_own_per_elevation() {
    let mut data = fixture();
    data.calibration_elevations_added.clear();
    expect_refused(&data, ADDED, 0, &["has CALIBRATION_ELEVATIONS but no CALIBRATION_ELEVATIONS_ADDED"]);
}

#[test]
fn added_tables_per_elevation_need_both_others() {
    // Without CALIBRATION_ADDED, whose pairs each elevation holds.
    let mut data = fixture();
    data.calibration_added.clear();
    expect_refused(&data, ADDED_AT, 0, &["no CALIBRATION_ADDED, whose (technique, height) pairs each elevation holds"]);
    // Without CALIBRATION_ELEVATIONS, whose elevations they complete.
    let mut data = fixture();
    data.calibration_elevations.clear();
    expect_refused(&data, ADDED_AT, 0, &["no CALIBRATION_ELEVATIONS, whose elevations these complete"]);
}

#[test]
fn an_elevation_set_other_than_calibration_elevations_is_refused() {
    // An elevation CALIBRATION_ELEVATIONS lacks: 30 moved to 45.
    let mut data = fixture();
    for r in &mut data.calibration_elevations_added[3..6] {
        r.elevation = 45.0;
    }
    expect_refused(&data, ADDED_AT, 3, &["elevation 45 is not an elevation of CALIBRATION_ELEVATIONS"]);
    // An elevation of CALIBRATION_ELEVATIONS missing: 30, reported where its records would be.
    let mut data = fixture();
    data.calibration_elevations_added.drain(3..6);
    expect_refused(&data, ADDED_AT, 3, &["has no records at elevation 30, an elevation of CALIBRATION_ELEVATIONS"]);
    // The last one missing: reported at the last record.
    let mut data = fixture();
    data.calibration_elevations_added.truncate(6);
    expect_refused(&data, ADDED_AT, 5, &["has no records at elevation 90"]);
    // Equal as stored: -0 is not the 0 of CALIBRATION_ELEVATIONS.
    let mut data = fixture();
    for r in &mut data.calibration_elevations_added[0..3] {
        r.elevation = -0.0;
    }
    expect_refused(&data, ADDED_AT, 0, &["elevation -0 is not an elevation of CALIBRATION_ELEVATIONS"]);
}

#[test]
fn an_elevation_without_exactly_the_pairs_of_calibration_added_is_refused() {
    // A height CALIBRATION_ADDED lacks.
    expect_refused(
        &edited_at(4, |r| r.height = 17.0),
        ADDED_AT,
        4,
        &["technique 9 at height 17 has no CALIBRATION_ADDED record"],
    );
    // A pair missing from the elevation 30, reported at its first record.
    let mut data = fixture();
    data.calibration_elevations_added.remove(4);
    expect_refused(
        &data,
        ADDED_AT,
        3,
        &["elevation 30 holds 2 of the 3 (technique, height) pairs of CALIBRATION_ADDED, not technique 9 at height 16"],
    );
    // A CALIBRATION_ADDED row no elevation has.
    let mut data = fixture();
    data.calibration_added.push(sample(OCTAHEDRAL, 128.0, 0.0, 2.0));
    expect_refused(&data, ADDED_AT, 0, &["elevation 0 holds 3 of the 4", "not technique 9 at height 128"]);
}

// ----------------------------------------------------------------------------------------------
// A reader of 1.11 and before.

#[test]
fn a_reader_that_does_not_know_the_kinds_skips_them_and_reads_the_rest_as_before() {
    // A reader of 1.11 or before sees kinds 0x0073 and 0x0074 as ones it does not know.
    // Relabelled as kinds this version does not know either (private extensions), the sections are
    // skipped the same way: the rest of the file reads record for record, and verifies, the
    // calibration and its tables per elevation without the octahedral impostor's rows.
    let data = fixture();
    let bytes = data.to_bytes(Compression::None).expect("writes");
    let (unknown, unknown_at) = (0x0001_0073, 0x0001_0074);
    assert_eq!((SectionKind(unknown).record_size(), SectionKind(unknown_at).record_size()), (None, None));
    let skipped = relabel(&relabel(&bytes, ADDED, unknown), ADDED_AT, unknown_at);
    let c = Container::from_bytes(&skipped).expect("opens");
    assert!(c.calibration_added().is_empty() && c.calibration_elevations_added().is_empty(), "skipped");
    assert!(c.section(ADDED).is_none() && c.section(ADDED_AT).is_none());
    assert_eq!(c.header().minor, 12, "the header keeps the file's minor; a reader accepts any minor");
    assert_eq!(c.calibration(), data.calibration.as_slice());
    assert_eq!(c.calibration_elevations(), data.calibration_elevations.as_slice());
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        calibration_added: Vec::new(),
        calibration_elevations_added: Vec::new(),
        extra_sections: vec![
            (unknown, bytemuck::cast_slice::<_, u8>(&data.calibration_added).to_vec()),
            (unknown_at, bytemuck::cast_slice::<_, u8>(&data.calibration_elevations_added).to_vec()),
        ],
        ..data.clone()
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("unknown kinds are only checksummed");
    assert_eq!((report.calibration, report.calibration_elevations), (4, 12));
    assert_eq!((report.calibration_added, report.calibration_elevations_added), (0, 0));
    assert_eq!(report.sections, Container::from_bytes(&bytes).expect("opens").sections().len());
    // Written back without them, it is the file of the smaller minor.
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    let c = Container::from_bytes(&without.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 7);
    verify(&c).expect("verifies");
}
