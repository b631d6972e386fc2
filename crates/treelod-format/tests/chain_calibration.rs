//! The LoD chain's per-level calibration in the container (spec §6.17): the `CHAIN_CALIBRATION`
//! kind (1.8) round-trips and makes a file 1.8, a file without it reads as before (no records);
//! `verify` checks each record (a level every tree's chain has, levels in ascending order, heights
//! finite, positive and strictly increasing within a level, errors in `[0, 1]`, primitive counts
//! finite and `≥ 0`). Each rule is broken once and refused with an error naming
//! `CHAIN_CALIBRATION` and the record.

mod common;

use common::{bytes_of, check, expect_refused};
use treelod_format::{
    CalibrationRecord, ChainCalibrationRecord, Compression, Container, ContainerData, LodLevelRecord, MINOR, Range,
    SectionKind, TriangleRecord, calibration_technique,
};

const KIND: SectionKind = SectionKind::CHAIN_CALIBRATION;

fn sample(level: u32, height: f32, error: f32, primitives: f32) -> ChainCalibrationRecord {
    ChainCalibrationRecord { level, height, error, primitives }
}

/// The one-leaf cell of `common` with a two-level chain of its one tree, the full mesh's and the
/// chain's calibration rows, and per-level tables: level 0 at two heights, level 1 at three.
/// Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("chain-calibration-fixture");
    data.lod_triangles = vec![TriangleRecord { indices: [0, 1, 2], size: 0.2, leaf: 0, material: 0 }; 2];
    data.lod_levels = vec![
        LodLevelRecord { tree: 0, level: 0, triangles: Range { first: 0, count: 1 }, error: 0.01, fraction: 0.5 },
        LodLevelRecord { tree: 0, level: 1, triangles: Range { first: 1, count: 1 }, error: 0.05, fraction: 0.25 },
    ];
    use calibration_technique::{FULL, LOD_CHAIN};
    data.calibration = vec![
        CalibrationRecord { technique: FULL, height: 8.0, error: 0.1, primitives: 1.0 },
        CalibrationRecord { technique: LOD_CHAIN, height: 8.0, error: 0.1, primitives: 1.0 },
    ];
    data.chain_calibration =
        vec![sample(0, 8.0, 0.1, 1.0), sample(0, 16.0, 0.05, 1.0), sample(1, 4.0, 0.2, 1.0), sample(1, 8.0, 0.1, 1.0)];
    data.chain_calibration.push(sample(1, 1.0e6, 0.0, 0.0));
    data
}

/// The fixture with record `index` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut ChainCalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.chain_calibration[index]);
    data
}

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 8, "the chain's per-level calibration is format 1.8") };
    let kind = SectionKind::CHAIN_CALIBRATION;
    assert_eq!(
        (kind.0, kind.name(), kind.to_string().as_str()),
        (0x0071, Some("CHAIN_CALIBRATION"), "CHAIN_CALIBRATION")
    );
    assert_eq!(kind.record_size(), Some(16));
    assert_eq!(size_of::<ChainCalibrationRecord>(), 16);
    assert_eq!(kind.since_minor(), 8);
    assert!(SectionKind::KNOWN.contains(&kind));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn a_valid_table_round_trips_as_a_1_8_file_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::Zstd { level: 19 }] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, 8, "CHAIN_CALIBRATION is a kind of 1.8");
        assert_eq!(c.chain_calibration(), data.chain_calibration.as_slice());
        assert_eq!(ContainerData::from_container(&c), data);
        let report = treelod_format::verify(&c).expect("valid");
        assert_eq!((report.calibration, report.chain_calibration), (2, 5));
    }
}

#[test]
fn without_the_kind_a_file_is_what_it_was_and_has_no_records() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 8);
    data.chain_calibration.clear();
    assert_eq!(minor(&data), 5, "a calibration alone is 1.5");
    let report = check(&data).expect("no per-level tables is valid");
    assert_eq!(report.chain_calibration, 0);
    assert!(Container::from_bytes(&bytes_of(&data)).expect("opens").chain_calibration().is_empty());
}

#[test]
fn each_rule_is_refused_on_its_own() {
    expect_refused(&edited(0, |r| r.level = 2), KIND, 0, &["level 2", "0..2"]);
    expect_refused(&edited(2, |r| r.level = 0), KIND, 2, &["height 4", "16"]);
    expect_refused(&edited(4, |r| r.level = 0), KIND, 4, &["level 0 follows level 1"]);
    expect_refused(&edited(1, |r| r.height = 8.0), KIND, 1, &["height 8", "8"]);
    expect_refused(&edited(0, |r| r.height = 0.0), KIND, 0, &["height 0"]);
    expect_refused(&edited(0, |r| r.height = f32::INFINITY), KIND, 0, &["height inf"]);
    expect_refused(&edited(1, |r| r.error = 1.5), KIND, 1, &["error 1.5"]);
    expect_refused(&edited(1, |r| r.error = f32::NAN), KIND, 1, &["error NaN"]);
    expect_refused(&edited(3, |r| r.primitives = -1.0), KIND, 3, &["primitive count -1"]);
    expect_refused(&edited(3, |r| r.primitives = f32::INFINITY), KIND, 3, &["primitive count inf"]);
    // Per-level tables need a chain.
    let mut data = fixture();
    data.lod_levels.clear();
    data.lod_triangles.clear();
    expect_refused(&data, KIND, 0, &["level 0", "0..0"]);
}

#[test]
fn a_level_that_one_tree_lacks_is_refused() {
    let mut data = fixture();
    // A second tree whose chain has level 0 only: level 1 is not a level of every tree's chain.
    data.block.tree_count = 2;
    data.metadata.trees.push(treelod_format::Tree::default());
    data.lod_triangles.push(data.lod_triangles[0]);
    data.lod_levels.push(LodLevelRecord {
        tree: 1,
        level: 0,
        triangles: Range { first: 2, count: 1 },
        error: 0.01,
        fraction: 0.5,
    });
    expect_refused(&data, KIND, 2, &["level 1", "0..1"]);
}
