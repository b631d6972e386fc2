//! The LoD chain levels' FLIP error (spec §6.20): the `CHAIN_CALIBRATION_FLIP` kind (1.18)
//! round-trips and makes a file 1.18, a file without it keeps its smaller minor and reads no
//! records; `verify` checks each record (levels non-decreasing, each a level every tree of
//! `LOD_LEVELS` has, so the section needs a chain, heights finite, positive and strictly increasing
//! within a level, FLIP errors in `[0, 1]`); each level restarts the heights, and the rows need no
//! other calibration section. Each rule is broken once and refused with an error naming
//! `CHAIN_CALIBRATION_FLIP` and the record. A reader that does not know the kind (1.17 and before)
//! skips it and reads the rest as before.

mod common;

use common::{bytes_of, check, expect_refused, relabel};
use treelod_format::{
    CalibrationRecord, ChainCalibrationRecord, ChainFlipCalibrationRecord, Compression, Container, ContainerData,
    LodLevelRecord, MINOR, Range, SectionKind, TriangleRecord, calibration_technique, verify,
};

use calibration_technique::{FULL, LOD_CHAIN};

const KIND: SectionKind = SectionKind::CHAIN_CALIBRATION_FLIP;

fn row(level: u32, height: f32, flip: f32) -> ChainFlipCalibrationRecord {
    ChainFlipCalibrationRecord { level, height, flip }
}

/// The one-leaf cell of `common` with a two-level chain of its one tree and FLIP rows of level 0
/// at 8 and 16 pixels (records 0–1) and of level 1 at 4, 8 and 32 (records 2–4). No RMSE table:
/// the rows need a chain, no other calibration section. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("chain-calibration-flip-fixture");
    data.lod_triangles = vec![TriangleRecord { indices: [0, 1, 2], size: 0.2, leaf: 0, material: 0 }; 2];
    data.lod_levels = vec![
        LodLevelRecord { tree: 0, level: 0, triangles: Range { first: 0, count: 1 }, error: 0.01, fraction: 0.5 },
        LodLevelRecord { tree: 0, level: 1, triangles: Range { first: 1, count: 1 }, error: 0.05, fraction: 0.25 },
    ];
    data.chain_calibration_flip =
        vec![row(0, 8.0, 0.2), row(0, 16.0, 0.1), row(1, 4.0, 0.5), row(1, 8.0, 0.3), row(1, 32.0, 0.25)];
    data
}

/// The fixture with the full mesh's and the chain's RMSE rows and the chain's per-level RMSE
/// tables at the FLIP rows' levels and heights: the file a build with FLIP writes. Verifies.
fn with_rmse_tables() -> ContainerData {
    let mut data = fixture();
    data.calibration = vec![
        CalibrationRecord { technique: FULL, height: 8.0, error: 0.1, primitives: 1.0 },
        CalibrationRecord { technique: LOD_CHAIN, height: 8.0, error: 0.1, primitives: 1.0 },
    ];
    data.chain_calibration = data
        .chain_calibration_flip
        .iter()
        .map(|r| ChainCalibrationRecord { level: r.level, height: r.height, error: r.flip / 2.0, primitives: 1.0 })
        .collect();
    data
}

/// The fixture with record `index` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut ChainFlipCalibrationRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.chain_calibration_flip[index]);
    data
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 18, "the chain levels' FLIP error is format 1.18") };
    assert_eq!(
        (KIND.0, KIND.name(), KIND.to_string().as_str()),
        (0x0076, Some("CHAIN_CALIBRATION_FLIP"), "CHAIN_CALIBRATION_FLIP")
    );
    assert_eq!(KIND.record_size(), Some(12));
    assert_eq!(size_of::<ChainFlipCalibrationRecord>(), 12);
    assert_eq!(KIND.since_minor(), 18);
    assert!(KIND.compressible());
    assert_eq!(SectionKind::KNOWN.len(), 40);
    assert!(SectionKind::KNOWN.contains(&KIND));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn a_valid_table_round_trips_as_a_1_18_file_and_verifies() {
    for data in [fixture(), with_rmse_tables()] {
        for compression in [Compression::None, Compression::Zstd { level: 19 }] {
            let bytes = data.to_bytes(compression).expect("writes");
            let c = Container::from_bytes(&bytes).expect("opens");
            assert_eq!(c.header().minor, 18, "CHAIN_CALIBRATION_FLIP is a kind of 1.18");
            assert_eq!(c.chain_calibration_flip(), data.chain_calibration_flip.as_slice());
            assert_eq!(ContainerData::from_container(&c), data);
            let entry = c.section(KIND).expect("written").entry;
            assert_eq!((entry.record_size, entry.raw_length), (12, 5 * 12));
            let report = verify(&c).expect("valid");
            assert_eq!(report.chain_calibration_flip, 5);
            assert_eq!(report.chain_calibration, data.chain_calibration.len() as u64);
            assert_eq!(report.calibration_flip, 0, "a kind of its own");
            // Written again, the same bytes.
            assert!(ContainerData::from_container(&c).to_bytes(compression).expect("writes") == bytes);
        }
    }
}

#[test]
fn without_the_kind_a_file_is_what_it_was_and_has_no_records() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 18);
    data.chain_calibration_flip.clear();
    assert_eq!(minor(&data), 1, "the fixture without the rows is a 1.1 file (a chain)");
    let report = check(&data).expect("no FLIP rows is valid");
    assert_eq!(report.chain_calibration_flip, 0);
    let c = Container::from_bytes(&bytes_of(&data)).expect("opens");
    assert!(c.chain_calibration_flip().is_empty() && c.section(KIND).is_none());
    // Beside the RMSE tables, the rows still mark the file 1.18, and without them it is 1.8.
    let mut data = with_rmse_tables();
    assert_eq!(minor(&data), 18);
    data.chain_calibration_flip.clear();
    assert_eq!(minor(&data), 8);
    check(&data).expect("the RMSE tables alone are valid");
}

#[test]
fn edge_values_restarts_and_unpaired_rows_pass() {
    // One level alone, and the coarser level alone.
    let mut data = fixture();
    data.chain_calibration_flip.truncate(2);
    assert_eq!(check(&data).expect("level 0 alone").chain_calibration_flip, 2);
    let mut data = fixture();
    data.chain_calibration_flip.drain(..2);
    assert_eq!(check(&data).expect("level 1 alone").chain_calibration_flip, 3);
    // The extreme values each field allows.
    let mut data = fixture();
    data.chain_calibration_flip[0].flip = 0.0;
    data.chain_calibration_flip[1].flip = 1.0;
    data.chain_calibration_flip[2].flip = -0.0;
    data.chain_calibration_flip[2].height = f32::MIN_POSITIVE / 2.0;
    data.chain_calibration_flip[4].height = f32::MAX;
    check(&data).expect("flip 0, -0 and 1, any positive height up to f32::MAX");
    // A new level restarts the heights.
    let mut data = fixture();
    data.chain_calibration_flip[2].height = 1.0;
    check(&data).expect("heights restart with each level");
    // The rows need not pair with the RMSE tables' records: other heights, a level they lack.
    let mut data = with_rmse_tables();
    data.chain_calibration.retain(|r| r.level == 0);
    data.chain_calibration_flip[1].height = 24.0;
    check(&data).expect("rows of their own");
}

// ----------------------------------------------------------------------------------------------
// Verify: one rule at a time.

#[test]
fn refusals() {
    // (record edited, its edit, record reported, what the reason says), one rule broken each.
    type Edit = fn(&mut ChainFlipCalibrationRecord);
    let table: [(usize, Edit, usize, &[&str]); 14] = [
        (0, |r| r.flip = f32::NAN, 0, &["FLIP error NaN lies outside [0, 1]"]),
        (1, |r| r.flip = 1.5, 1, &["FLIP error 1.5 lies outside [0, 1]"]),
        (2, |r| r.flip = -0.01, 2, &["FLIP error -0.01 lies outside [0, 1]"]),
        (3, |r| r.flip = f32::INFINITY, 3, &["FLIP error inf lies outside [0, 1]"]),
        (0, |r| r.height = 0.0, 0, &["height 0 is not a positive number of pixels"]),
        (2, |r| r.height = -4.0, 2, &["height -4 is not a positive number of pixels"]),
        (3, |r| r.height = f32::NAN, 3, &["height NaN is not a positive number of pixels"]),
        (4, |r| r.height = f32::INFINITY, 4, &["height inf is not a positive number of pixels"]),
        // A level the chain does not have.
        (0, |r| r.level = 2, 0, &["level 2 is not a level of every tree's LoD chain (0..2)"]),
        (4, |r| r.level = u32::MAX, 4, &["level 4294967295 is not a level of every tree's LoD chain (0..2)"]),
        // Level 1's last row made level 0's: the level decreases after it.
        (2, |r| r.level = 0, 2, &["height 4 does not increase strictly after 16"]),
        (4, |r| r.level = 0, 4, &["level 0 follows level 1"]),
        // Level 0's second height made its first.
        (1, |r| r.height = 8.0, 1, &["height 8 does not increase strictly after 8"]),
        (3, |r| r.height = 2.0, 3, &["height 2 does not increase strictly after 4"]),
    ];
    for (index, edit, reported, needles) in table {
        expect_refused(&edited(index, edit), KIND, reported, needles);
    }
}

#[test]
fn the_rows_need_a_chain() {
    // No chain at all: level 0 is not a level of it.
    let mut data = fixture();
    data.lod_levels.clear();
    data.lod_triangles.clear();
    expect_refused(&data, KIND, 0, &["level 0 is not a level of every tree's LoD chain (0..0)"]);
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
    expect_refused(&data, KIND, 2, &["level 1 is not a level of every tree's LoD chain (0..1)"]);
    // Without level 1's rows the file verifies.
    data.chain_calibration_flip.truncate(2);
    check(&data).expect("level 0 is every tree's");
}

#[test]
fn a_decreasing_level_is_refused() {
    // Level 0's rows after level 1's.
    let mut data = fixture();
    data.chain_calibration_flip.rotate_left(2);
    expect_refused(&data, KIND, 3, &["level 0 follows level 1"]);
}

#[test]
fn a_height_that_does_not_increase_within_a_level_is_refused() {
    // Equal.
    let data = edited(3, |r| r.height = 4.0);
    expect_refused(&data, KIND, 3, &["height 4 does not increase strictly after 4"]);
    // Decreasing.
    let mut data = fixture();
    data.chain_calibration_flip.swap(3, 4);
    expect_refused(&data, KIND, 4, &["height 8 does not increase strictly after 32"]);
}

#[test]
fn the_first_broken_record_is_reported() {
    let mut data = fixture();
    data.chain_calibration_flip[1].flip = 2.0;
    data.chain_calibration_flip[3].level = 5;
    data.chain_calibration_flip[4].height = -1.0;
    expect_refused(&data, KIND, 1, &["FLIP error 2 "]);
}

// ----------------------------------------------------------------------------------------------
// A reader of 1.17 and before.

#[test]
fn a_reader_that_does_not_know_the_kind_skips_it_and_reads_the_rest_as_before() {
    // A reader of 1.17 or before sees kind 0x0076 as one it does not know. Relabelled as a kind
    // this version does not know either (a private extension), the section is skipped the same
    // way: the rest of the file reads record for record, and verifies, with the RMSE tables.
    let data = with_rmse_tables();
    let bytes = data.to_bytes(Compression::None).expect("writes");
    let unknown = 0x0001_0076;
    assert_eq!(SectionKind(unknown).record_size(), None);
    let c = Container::from_bytes(&relabel(&bytes, KIND, unknown)).expect("opens");
    assert!(c.chain_calibration_flip().is_empty() && c.section(KIND).is_none(), "skipped");
    assert_eq!(c.header().minor, 18, "the header keeps the file's minor; a reader accepts any minor");
    assert_eq!(c.chain_calibration(), data.chain_calibration.as_slice());
    assert_eq!(c.calibration(), data.calibration.as_slice());
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        chain_calibration_flip: Vec::new(),
        extra_sections: vec![(unknown, bytemuck::cast_slice::<_, u8>(&data.chain_calibration_flip).to_vec())],
        ..data.clone()
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("unknown kinds are only checksummed");
    assert_eq!((report.chain_calibration, report.chain_calibration_flip), (5, 0));
    // Written back without it, it is the file of the smaller minor.
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    let c = Container::from_bytes(&without.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 8);
    verify(&c).expect("verifies");
}
