//! Calibration tables in the container (spec §6.15): the `CALIBRATION` kind (1.5) round-trips and
//! makes a file 1.5; `verify` checks each record (a technique of 1.5 to 1.11, below
//! `FIRST_ADDED`, techniques in ascending
//! order, heights finite, positive and strictly increasing within a technique, errors in
//! `[0, 1]`, primitive counts finite and `≥ 0`). Each rule is broken once and refused with an
//! error naming `CALIBRATION` and the record.

mod common;

use treelod_format::{
    CalibrationRecord, Compression, Container, ContainerData, MINOR, SectionKind, calibration_technique, verify,
};

const KIND: SectionKind = SectionKind::CALIBRATION;

fn sample(technique: u32, height: f32, error: f32, primitives: f32) -> CalibrationRecord {
    CalibrationRecord { technique, height, error, primitives }
}

/// The one-leaf cell of `common` with a calibration of three techniques: `FULL` at three
/// heights, `SPT` at four, `CROSSED` (the last code of `CALIBRATION`) at one. Verifies.
fn fixture() -> ContainerData {
    use calibration_technique::{CROSSED, FULL, SPT};
    let mut data = common::one_leaf_cell("calibration-fixture");
    data.calibration = vec![
        sample(FULL, 16.0, 0.0, 1.0),
        sample(FULL, 64.0, 0.0, 1.0),
        sample(FULL, 256.0, 0.0, 1.0),
        sample(SPT, 4.0, 1.0, 0.0),
        sample(SPT, 8.0, 0.25, 1.0),
        sample(SPT, 32.0, 0.125, 1.0),
        sample(SPT, 1.0e6, 0.0, 1.0),
        sample(CROSSED, 0.5, 0.75, 2.0),
    ];
    data
}

use common::{bytes_of, check, expect_refused};

/// The fixture with record `index` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut CalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.calibration[index]);
    data
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_and_the_techniques_are_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 5, "calibration is format 1.5") };
    let kind = SectionKind::CALIBRATION;
    assert_eq!((kind.0, kind.name(), kind.to_string().as_str()), (0x0070, Some("CALIBRATION"), "CALIBRATION"));
    assert_eq!(kind.record_size(), Some(16));
    assert_eq!(size_of::<CalibrationRecord>(), 16);
    assert_eq!(kind.since_minor(), 5);
    assert!(SectionKind::KNOWN.contains(&kind));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    let names: Vec<&str> = (0..calibration_technique::COUNT).filter_map(calibration_technique::name).collect();
    assert_eq!(
        names,
        [
            "full",
            "spt",
            "prune-opt",
            "prune-cook",
            "impostors",
            "ellipsoids",
            "lod-chain",
            "billboard",
            "crossed",
            "octahedral"
        ]
    );
    assert_eq!(calibration_technique::name(calibration_technique::COUNT), None);
    // CALIBRATION holds the codes up to CROSSED; the octahedral impostor's are in CALIBRATION_ADDED.
    assert_eq!(calibration_technique::CROSSED + 1, calibration_technique::FIRST_ADDED);
    assert_eq!(calibration_technique::OCTAHEDRAL + 1, calibration_technique::COUNT);
}

#[test]
fn a_valid_table_round_trips_as_a_1_5_file_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::Zstd { level: 19 }] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, 5, "CALIBRATION is a kind of 1.5");
        assert_eq!(c.calibration(), data.calibration.as_slice());
        assert_eq!(ContainerData::from_container(&c), data);
        let report = verify(&c).expect("valid");
        assert_eq!(report.calibration, 8);
    }
}

#[test]
fn the_minor_is_5_exactly_when_a_calibration_is_present() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 5);
    data.calibration.clear();
    assert_eq!(minor(&data), 0);
    let report = check(&data).expect("no calibration is valid");
    assert_eq!(report.calibration, 0);
    assert!(Container::from_bytes(&bytes_of(&data)).expect("opens").calibration().is_empty());
}

#[test]
fn a_single_record_of_each_technique_and_edge_values_pass() {
    let mut data = common::one_leaf_cell("edges");
    data.calibration = (0..calibration_technique::FIRST_ADDED)
        .map(|t| sample(t, f32::MIN_POSITIVE, if t % 2 == 0 { 0.0 } else { 1.0 }, -0.0))
        .collect();
    assert_eq!(check(&data).expect("valid").calibration, u64::from(calibration_technique::FIRST_ADDED));
    // Heights may fall from one technique to the next.
    data.calibration = vec![sample(0, 100.0, 0.5, 3.0), sample(1, 1.0, 0.5, 3.0)];
    check(&data).expect("heights restart with each technique");
}

// ----------------------------------------------------------------------------------------------
// Verify: one rule at a time.

#[test]
fn an_undefined_technique_is_refused() {
    // The octahedral impostor's code is defined, but only in CALIBRATION_ADDED (spec §6.18).
    let data = edited(7, |r| r.technique = calibration_technique::OCTAHEDRAL);
    expect_refused(
        &data,
        KIND,
        7,
        &["technique 9 is not defined here (0..9): octahedral belongs in CALIBRATION_ADDED"],
    );
    let data = edited(7, |r| r.technique = calibration_technique::COUNT);
    expect_refused(&data, KIND, 7, &["technique 10 is not defined here (0..9)"]);
    let data = edited(0, |r| r.technique = u32::MAX);
    expect_refused(&data, KIND, 0, &["technique 4294967295 is not defined"]);
}

#[test]
fn a_decreasing_technique_is_refused() {
    // FULL (0) after CROSSED (8): a record appended to the end goes back to the first technique.
    let mut data = fixture();
    data.calibration.push(sample(calibration_technique::FULL, 1.0e7, 0.0, 1.0));
    expect_refused(&data, KIND, 8, &["technique 0 follows technique 8"]);
    // The FULL table moved to the end.
    let mut data = fixture();
    data.calibration.rotate_left(3);
    expect_refused(&data, KIND, 5, &["technique 0 follows technique 8"]);
    // SPT and FULL interleaved.
    let mut data = fixture();
    data.calibration.swap(2, 3);
    expect_refused(&data, KIND, 3, &["technique 0 follows technique 1"]);
}

#[test]
fn a_height_that_does_not_increase_within_a_technique_is_refused() {
    let data = edited(1, |r| r.height = 16.0);
    expect_refused(&data, KIND, 1, &["height 16", "does not increase strictly after 16"]);
    let data = edited(5, |r| r.height = 7.5);
    expect_refused(&data, KIND, 5, &["height 7.5", "after 8"]);
}

#[test]
fn a_non_positive_or_non_finite_height_is_refused() {
    for (height, text) in [(0.0, "height 0 "), (-0.0, "height -0 "), (-4.0, "height -4 "), (f32::NAN, "height NaN")] {
        expect_refused(&edited(0, |r| r.height = height), KIND, 0, &[text, "not a positive number of pixels"]);
    }
    expect_refused(&edited(6, |r| r.height = f32::INFINITY), KIND, 6, &["height inf", "not a positive"]);
}

#[test]
fn an_error_outside_0_1_is_refused() {
    for (error, text) in
        [(-0.01, "error -0.01 "), (1.5, "error 1.5 "), (f32::NAN, "error NaN"), (f32::INFINITY, "error inf")]
    {
        expect_refused(&edited(4, |r| r.error = error), KIND, 4, &[text, "outside [0, 1]"]);
    }
}

#[test]
fn a_negative_or_non_finite_primitive_count_is_refused() {
    for (primitives, text) in [(-1.0, "count -1 "), (f32::NAN, "count NaN"), (f32::INFINITY, "count inf")] {
        expect_refused(&edited(2, |r| r.primitives = primitives), KIND, 2, &[text, "not a finite count"]);
    }
}

#[test]
fn the_first_broken_record_is_reported() {
    let mut data = fixture();
    data.calibration[3].error = 2.0;
    data.calibration[6].technique = 0;
    expect_refused(&data, KIND, 3, &["error 2"]);
}
