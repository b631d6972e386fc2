//! Calibration per elevation in the container (spec §6.16): the `CALIBRATION_ELEVATIONS` kind (1.7)
//! round-trips and makes a file 1.7, a file without it reads as before (no records); `verify`
//! checks each record (elevations finite in `[0, 90]` and non-decreasing, defined techniques
//! non-decreasing within an elevation, heights finite, positive and strictly increasing within an
//! elevation and technique, errors in `[0, 1]`, primitive counts finite and `≥ 0`, every
//! `(technique, height)` a pair of `CALIBRATION`, every elevation all of `CALIBRATION`'s pairs);
//! each elevation restarts the techniques and heights. Each rule is broken once and refused with
//! an error naming `CALIBRATION_ELEVATIONS` and the record.

mod common;

use common::{bytes_of, check, expect_refused};
use treelod_format::{
    CalibrationRecord, Compression, Container, ContainerData, ElevationCalibrationRecord, MINOR, SectionKind,
    calibration_technique, verify,
};

const KIND: SectionKind = SectionKind::CALIBRATION_ELEVATIONS;

use calibration_technique::{FULL, SPT};

fn sample(elevation: f32, technique: u32, height: f32, error: f32, primitives: f32) -> ElevationCalibrationRecord {
    ElevationCalibrationRecord { elevation, technique, height, error, primitives }
}

/// The one-leaf cell of `common` with a calibration of `FULL` at 16 and 64 pixels and `SPT` at 8
/// and 32, and the same four pairs at 0, 30 and 90 degrees: records 0–3, 4–7 and 8–11. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("calibration-elevations-fixture");
    let pairs = [(FULL, 16.0, 0.0, 1.0), (FULL, 64.0, 0.0, 1.0), (SPT, 8.0, 0.5, 1.0), (SPT, 32.0, 0.25, 1.0)];
    data.calibration = pairs
        .iter()
        .map(|&(technique, height, error, primitives)| CalibrationRecord { technique, height, error, primitives })
        .collect();
    for (elevation, scale) in [(0.0, 1.5), (30.0, 1.0), (90.0, 0.5)] {
        data.calibration_elevations.extend(pairs.iter().map(|&(technique, height, error, primitives)| {
            sample(elevation, technique, height, error * scale, primitives)
        }));
    }
    data
}

/// The fixture with record `index` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut ElevationCalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.calibration_elevations[index]);
    data
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 7, "calibration per elevation is format 1.7") };
    let kind = SectionKind::CALIBRATION_ELEVATIONS;
    assert_eq!(
        (kind.0, kind.name(), kind.to_string().as_str()),
        (0x0072, Some("CALIBRATION_ELEVATIONS"), "CALIBRATION_ELEVATIONS")
    );
    assert_eq!(kind.record_size(), Some(20));
    assert_eq!(size_of::<ElevationCalibrationRecord>(), 20);
    assert_eq!(kind.since_minor(), 7);
    assert!(SectionKind::KNOWN.contains(&kind));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn a_valid_table_round_trips_as_a_1_7_file_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::Zstd { level: 19 }] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, 7, "CALIBRATION_ELEVATIONS is a kind of 1.7");
        assert_eq!(c.calibration_elevations(), data.calibration_elevations.as_slice());
        assert_eq!(ContainerData::from_container(&c), data);
        let report = verify(&c).expect("valid");
        assert_eq!((report.calibration, report.calibration_elevations), (4, 12));
    }
}

#[test]
fn without_the_kind_a_file_is_what_it_was_and_has_no_records() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 7);
    data.calibration_elevations.clear();
    assert_eq!(minor(&data), 5, "a calibration alone is 1.5");
    let report = check(&data).expect("no tables per elevation is valid");
    assert_eq!(report.calibration_elevations, 0);
    assert!(Container::from_bytes(&bytes_of(&data)).expect("opens").calibration_elevations().is_empty());
}

#[test]
fn one_elevation_edge_values_and_restarts_pass() {
    // A single elevation, straight down, with the extreme values each field allows.
    let mut data = fixture();
    data.calibration_elevations.truncate(4);
    let edges = [(0.0, -0.0), (1.0, 0.0), (0.0, 1e30), (1.0, f32::MAX)];
    for (r, (error, primitives)) in data.calibration_elevations.iter_mut().zip(edges) {
        (r.elevation, r.error, r.primitives) = (90.0, error, primitives);
    }
    assert_eq!(check(&data).expect("valid").calibration_elevations, 4);
    // -0 and 0 are one elevation.
    let mut data = fixture();
    data.calibration_elevations[0].elevation = -0.0;
    data.calibration_elevations[1].elevation = -0.0;
    data.calibration_elevations[2].elevation = 0.0;
    check(&data).expect("-0 is the elevation 0");
    // The elevations need not be those the build measures.
    let mut data = fixture();
    for r in &mut data.calibration_elevations[4..8] {
        r.elevation = 45.5;
    }
    check(&data).expect("any elevation in [0, 90]");
}

// ----------------------------------------------------------------------------------------------
// Verify: one rule at a time.

#[test]
fn an_elevation_outside_0_90_is_refused() {
    for (elevation, text) in [
        (-1.0, "elevation -1 "),
        (90.5, "elevation 90.5 "),
        (f32::NAN, "elevation NaN"),
        (f32::INFINITY, "elevation inf"),
    ] {
        expect_refused(&edited(0, |r| r.elevation = elevation), KIND, 0, &[text, "outside [0, 90] degrees"]);
    }
    // The last elevation's records too.
    expect_refused(&edited(11, |r| r.elevation = 91.0), KIND, 11, &["elevation 91 ", "outside [0, 90]"]);
}

#[test]
fn a_decreasing_elevation_is_refused() {
    // An elevation-0 record after the elevation 90.
    let mut data = fixture();
    data.calibration_elevations.push(sample(0.0, FULL, 1.0e7, 0.0, 1.0));
    expect_refused(&data, KIND, 12, &["elevation 0 follows elevation 90"]);
    // The elevation 30 moved to the end.
    let mut data = fixture();
    data.calibration_elevations[4..].rotate_left(4);
    expect_refused(&data, KIND, 8, &["elevation 30 follows elevation 90"]);
    // Two elevations interleaved: 0, 30, 0.
    let mut data = fixture();
    data.calibration_elevations[5].elevation = 0.0;
    expect_refused(&data, KIND, 5, &["elevation 0 follows elevation 30"]);
}

#[test]
fn an_undefined_technique_is_refused() {
    let data = edited(3, |r| r.technique = calibration_technique::FIRST_ADDED);
    expect_refused(
        &data,
        KIND,
        3,
        &["technique 9 is not defined here (0..9): octahedral belongs in CALIBRATION_ELEVATIONS_ADDED"],
    );
    let data = edited(3, |r| r.technique = calibration_technique::COUNT);
    expect_refused(&data, KIND, 3, &["technique 10 is not defined here (0..9)"]);
    let data = edited(8, |r| r.technique = u32::MAX);
    expect_refused(&data, KIND, 8, &["technique 4294967295 is not defined"]);
}

#[test]
fn a_decreasing_technique_within_an_elevation_is_refused() {
    // FULL after SPT within the elevation 30.
    let mut data = fixture();
    data.calibration_elevations[4..8].rotate_left(2);
    expect_refused(&data, KIND, 6, &["technique 0 follows technique 1"]);
}

#[test]
fn a_height_that_does_not_increase_within_an_elevation_and_technique_is_refused() {
    let data = edited(1, |r| r.height = 16.0);
    expect_refused(&data, KIND, 1, &["height 16", "does not increase strictly after 16"]);
    let mut data = fixture();
    data.calibration_elevations.swap(6, 7);
    expect_refused(&data, KIND, 7, &["height 8", "after 32"]);
}

#[test]
fn a_non_positive_or_non_finite_height_is_refused() {
    for (height, text) in [(0.0, "height 0 "), (-0.0, "height -0 "), (-4.0, "height -4 "), (f32::NAN, "height NaN")] {
        expect_refused(&edited(4, |r| r.height = height), KIND, 4, &[text, "not a positive number of pixels"]);
    }
    expect_refused(&edited(11, |r| r.height = f32::INFINITY), KIND, 11, &["height inf", "not a positive"]);
}

#[test]
fn an_error_outside_0_1_is_refused() {
    for (error, text) in
        [(-0.01, "error -0.01 "), (1.5, "error 1.5 "), (f32::NAN, "error NaN"), (f32::INFINITY, "error inf")]
    {
        expect_refused(&edited(5, |r| r.error = error), KIND, 5, &[text, "outside [0, 1]"]);
    }
}

#[test]
fn a_negative_or_non_finite_primitive_count_is_refused() {
    for (primitives, text) in [(-1.0, "count -1 "), (f32::NAN, "count NaN"), (f32::INFINITY, "count inf")] {
        expect_refused(&edited(9, |r| r.primitives = primitives), KIND, 9, &[text, "not a finite count"]);
    }
}

#[test]
fn a_pair_that_calibration_lacks_is_refused() {
    // A height between CALIBRATION's, in order.
    let data = edited(1, |r| r.height = 17.0);
    expect_refused(&data, KIND, 1, &["technique 0 at height 17 has no CALIBRATION record"]);
    // A technique CALIBRATION has no row for, after the others.
    let mut data = fixture();
    data.calibration_elevations.insert(8, sample(30.0, calibration_technique::CROSSED, 8.0, 0.5, 4.0));
    expect_refused(&data, KIND, 8, &["technique 8 at height 8 has no CALIBRATION record"]);
    // Heights equal as stored: one ulp off is another height.
    let data = edited(10, |r| r.height = f32::from_bits(8.0f32.to_bits() + 1));
    expect_refused(&data, KIND, 10, &["technique 1 at height 8.000001 has no CALIBRATION record"]);
}

#[test]
fn an_elevation_without_every_pair_of_calibration_is_refused() {
    // The elevation 30 lacks FULL at 64 (record 5): reported at its first record, 4.
    let mut data = fixture();
    data.calibration_elevations.remove(5);
    expect_refused(
        &data,
        KIND,
        4,
        &["elevation 30 holds 3 of the 4", "pairs of CALIBRATION", "not technique 0 at height 64"],
    );
    // The first elevation lacks its last pair.
    let mut data = fixture();
    data.calibration_elevations.remove(3);
    expect_refused(&data, KIND, 0, &["elevation 0 holds 3 of the 4", "not technique 1 at height 32"]);
    // The last elevation lacks its first pair.
    let mut data = fixture();
    data.calibration_elevations.remove(8);
    expect_refused(&data, KIND, 8, &["elevation 90 holds 3 of the 4", "not technique 0 at height 16"]);
    // A calibration row the elevations do not have.
    let mut data = fixture();
    data.calibration.push(CalibrationRecord { technique: calibration_technique::CROSSED, ..data.calibration[0] });
    expect_refused(&data, KIND, 0, &["elevation 0 holds 4 of the 5", "not technique 8 at height 16"]);
}

#[test]
fn records_without_calibration_are_refused() {
    let mut data = fixture();
    data.calibration.clear();
    expect_refused(&data, KIND, 0, &["no CALIBRATION"]);
}

#[test]
fn the_first_broken_record_is_reported() {
    let mut data = fixture();
    data.calibration_elevations[6].error = 2.0;
    data.calibration_elevations[11].technique = 0;
    data.calibration_elevations.remove(10);
    expect_refused(&data, KIND, 6, &["error 2"]);
}
