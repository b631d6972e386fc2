//! The block's far lines in the container (spec §6.9.1): the `FAR_LINES` and `FAR_LINE_AO` kinds
//! (1.9) round-trip and make a file 1.9, a file without them reads as before (no records), and
//! `verify` checks their rules: far lines need lines, their endpoints lie inside the block bounds,
//! they form one hierarchy with the exact cut of §10 over as many leaves as `LINES` has records
//! drawn at the switch `τ_s = τ_far · 2^(−1/2)` (the cells' lines that far level 0 copies). Each
//! rule is broken once and
//! refused with a typed error naming `FAR_LINES` (or `FAR_LINE_AO`) and what is wrong.

mod common;

use common::{assert_reads_back, bytes_of, check, reseal};
use treelod_format::{
    BlockRecord, CellRecord, Compression, Container, ContainerData, Error, LineRecord, MINOR, Range, SectionKind,
    SptSummary, check_far_lines, far_switch, far_threshold, lines_drawn_at, verify,
};

const INF: f32 = f32::INFINITY;

fn range(first: u32, count: u32) -> Range {
    Range { first, count }
}

fn line(p0: [f32; 3], p1: [f32; 3], lo: f32, hi: f32, leaf_first: u32, leaf_count: u32) -> LineRecord {
    LineRecord { p0, r0: 0.02, p1, r1: 0.01, color: 0xFF20_4060, lo, hi, leaf_first, leaf_count, flags: 0 }
}

/// A 2×1×1 block (bounds `0..(2, 1, 1)`): cell 0 holds `common`'s leaf triangle and three lines,
/// two leaves `[0, 1)` under their merge `[1, +∞)`; cell 1 one line `[0, +∞)`. So two coarsest
/// lines, the largest `lo` among them 1. The far lines are copies of those two, `[0, 1.5)`, under
/// one merge across the cells, `[1.5, +∞)`: `τ_far = 1.5`. `FAR_LINE_AO` has a byte per far line.
/// Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("far-lines-fixture");
    data.block = BlockRecord { bounds_max: [2.0, 1.0, 1.0], grid: [2, 1, 1], ..data.block };
    let (a, m, b) = ([0.3, 0.1, 0.5], [0.5, 0.5, 0.5], [0.7, 0.9, 0.5]);
    let (c, d) = ([1.2, 0.1, 0.5], [1.4, 0.8, 0.5]);
    data.lines = vec![line(a, b, 1.0, INF, 0, 2), line(a, m, 0.0, 1.0, 0, 1), line(m, b, 0.0, 1.0, 1, 1)];
    data.lines.push(line(c, d, 0.0, INF, 0, 1));
    data.far_lines = vec![line(a, d, 1.5, INF, 0, 2), line(a, b, 0.0, 1.5, 0, 1), line(c, d, 0.0, 1.5, 1, 1)];
    data.far_line_ao = vec![10, 20, 30];
    let grid_cell = data.cells[0];
    data.cells = vec![
        CellRecord { bounds_min: [0.2, 0.1, 0.5], bounds_max: [0.7, 0.9, 0.5], lines: range(0, 3), ..grid_cell },
        CellRecord {
            bounds_min: c,
            bounds_max: d,
            triangles: range(1, 0),
            points: range(1, 0),
            lines: range(3, 1),
            ..CellRecord::default()
        },
        CellRecord { triangles: range(1, 0), points: range(1, 0), lines: range(4, 0), ..CellRecord::default() },
    ];
    data
}

/// The fixture with far line `index` changed by `edit`.
fn edited(index: usize, edit: impl FnOnce(&mut LineRecord)) -> ContainerData {
    let mut data = fixture();
    edit(&mut data.far_lines[index]);
    data
}

/// Asserts a `BadRecord` of `FAR_LINES` at `index` whose reason mentions every needle.
#[track_caller]
fn expect_record(data: &ContainerData, index: usize, needles: &[&str]) {
    match check(data) {
        Err(ref e @ Error::BadRecord { kind, index: i, ref reason })
            if kind == SectionKind::FAR_LINES && i == index && needles.iter().all(|n| reason.contains(n)) =>
        {
            let message = e.to_string();
            assert!(message.starts_with(&format!("FAR_LINES record {index}: ")), "{message}");
        }
        other => panic!("expected BadRecord FAR_LINES {index} ({needles:?}), got {other:?}"),
    }
}

/// Asserts a `BadHierarchy` of `FAR_LINES` whose reason mentions every needle.
#[track_caller]
fn expect_hierarchy(data: &ContainerData, needles: &[&str]) {
    match check(data) {
        Err(ref e @ Error::BadHierarchy { kind, ref reason })
            if kind == SectionKind::FAR_LINES && needles.iter().all(|n| reason.contains(n)) =>
        {
            assert!(e.to_string().starts_with("FAR_LINES: "), "{e}");
            assert_eq!(e.class(), treelod_format::ErrorClass::Invalid);
        }
        other => panic!("expected BadHierarchy FAR_LINES ({needles:?}), got {other:?}"),
    }
}

#[test]
fn the_kinds_are_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 9, "FAR_LINES is format 1.9") };
    for (kind, value, name, size) in
        [(SectionKind::FAR_LINES, 0x0022, "FAR_LINES", 56), (SectionKind::FAR_LINE_AO, 0x0065, "FAR_LINE_AO", 1)]
    {
        assert_eq!(kind.0, value);
        assert_eq!(kind.name(), Some(name));
        assert_eq!(kind.record_size(), Some(size), "{name}");
        assert_eq!(kind.since_minor(), 9, "{name}");
        assert!(SectionKind::KNOWN.contains(&kind), "{name}");
    }
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn a_container_with_far_lines_round_trips_as_format_1_9_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 9), "{compression:?}");
        assert_eq!(c.far_lines(), data.far_lines.as_slice());
        assert_eq!(c.far_line_ao(), &[10, 20, 30]);
        let report = verify(&c).expect("verifies");
        assert_eq!((report.lines, report.far_lines, report.far_line_leaves), (4, 3, 2));
        // 1 point leaf, 2 + 1 line leaves and 2 far leaves.
        assert_eq!(report.cut_leaves, 6);
        assert_eq!(report.ao, 3);
        let text = report.to_string();
        assert!(text.contains("far lines: 3 records over 2 leaves"), "{text}");
        assert_reads_back(&c, &data, &bytes, compression);
    }
    assert_eq!(far_threshold(&data.far_lines), 1.5);
    let switch = far_switch(&data.far_lines);
    assert!((switch - 1.5 * 2f32.powf(-0.5)).abs() < 1e-6, "{switch}");
    assert_eq!(lines_drawn_at(&data.lines, switch), 2, "cell 0's merge and cell 1's line");

    // Far lines without their occlusion: still 1.9. Without either: the lines' file of 1.0, with
    // nothing to read for them, as a 1.8 reader sees a 1.9 file.
    let bytes = ContainerData { far_line_ao: Vec::new(), ..fixture() }.to_bytes(Compression::None).expect("writes");
    let c = Container::from_bytes(&bytes).expect("opens");
    assert_eq!((c.header().minor, c.far_lines().len(), c.far_line_ao().len()), (9, 3, 0));
    verify(&c).expect("verifies");
    let older = ContainerData { far_lines: Vec::new(), far_line_ao: Vec::new(), ..fixture() };
    let bytes = older.to_bytes(Compression::None).expect("writes");
    let c = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(c.header().minor, 0);
    assert!(c.far_lines().is_empty() && c.far_line_ao().is_empty());
    assert!(c.section(SectionKind::FAR_LINES).is_none(), "no empty section is written");
    assert_eq!(verify(&c).expect("verifies").far_lines, 0);
}

#[test]
fn far_lines_that_never_merge_and_equal_thresholds_verify() {
    // Each coarsest line copied as a far leaf [0, +∞): τ_far = +∞, above any lo.
    let mut data = fixture();
    let (cell_0, cell_1) = (data.lines[0], data.lines[3]);
    data.far_lines =
        vec![LineRecord { lo: 0.0, leaf_first: 0, leaf_count: 1, ..cell_0 }, LineRecord { leaf_first: 1, ..cell_1 }];
    data.far_line_ao.truncate(2);
    assert_eq!(far_threshold(&data.far_lines), INF);
    check(&data).expect("verifies");
    // Far level 0 may copy finer lines than the cells' coarsest: with τ_far = 1 the switch is at
    // 0.71, where cell 0 still draws its two leaves, so far level 0 holds three lines.
    let mut data = fixture();
    let (c0, c1, c3) = (data.lines[1], data.lines[2], data.lines[3]);
    data.far_lines = vec![
        LineRecord { lo: 1.0, leaf_count: 3, ..data.far_lines[0] },
        LineRecord { hi: 1.0, leaf_first: 0, ..c0 },
        LineRecord { hi: 1.0, leaf_first: 1, ..c1 },
        LineRecord { hi: 1.0, leaf_first: 2, ..c3 },
    ];
    data.far_line_ao = vec![10, 20, 30, 40];
    check(&data).expect("τ_far = 1 over the lines drawn at 0.71 verifies");
}

#[test]
fn far_lines_without_lines_are_refused() {
    let mut data = fixture();
    data.lines.clear();
    for cell in &mut data.cells {
        cell.lines = range(0, 0);
    }
    data.cells[0].bounds_max = [0.6, 0.6, 0.5];
    data.cells[0].bounds_min = [0.2, 0.2, 0.5];
    data.cells[1] = CellRecord { triangles: range(1, 0), points: range(1, 0), ..CellRecord::default() };
    expect_record(&data, 0, &["3 records but LINES is empty"]);
    // Without far lines that file verifies.
    check(&ContainerData { far_lines: Vec::new(), far_line_ao: Vec::new(), ..data }).expect("verifies");
}

#[test]
fn a_leaf_count_other_than_the_lines_drawn_at_the_switch_is_refused() {
    // One far leaf too many: the merge covers three leaves, LINES draws two at the switch.
    let mut data = edited(0, |l| l.leaf_count = 3);
    data.far_lines.push(line([1.0, 0.5, 0.5], [1.1, 0.5, 0.5], 0.0, 1.5, 2, 1));
    data.far_line_ao.push(40);
    expect_hierarchy(&data, &["leaves 0..3", "LINES has 2 records drawn at the switch"]);
    // One too few: a single leaf under the merge.
    let mut data = edited(0, |l| l.leaf_count = 1);
    data.far_lines.pop();
    data.far_line_ao.pop();
    expect_hierarchy(&data, &["leaves 0..1", "LINES has 2 records"]);
    // A coarsest line more: cell 1 gets a second root (a valid forest for LINES), so three
    // coarsest lines for two far leaves.
    let mut data = fixture();
    data.lines.push(line([1.25, 0.2, 0.5], [1.35, 0.7, 0.5], 0.0, INF, 1, 1));
    data.cells[1].lines = range(3, 2);
    data.cells[2].lines = range(5, 0);
    expect_hierarchy(&data, &["leaves 0..2", "LINES has 3 records drawn at the switch"]);
}

#[test]
fn a_broken_exact_cut_is_refused() {
    // A gap in leaf 1's chain: [0, 1.2) then [1.5, +∞).
    expect_hierarchy(&edited(2, |l| l.hi = 1.2), &["leaf 1", "leave a gap", "§10 rule 2"]);
    // An overlap: leaf 0's own line, [0, 2), reaches into the merge's [1.5, +∞).
    expect_hierarchy(&edited(1, |l| l.hi = 2.0), &["leaf 0", "overlap", "§10 rule 2"]);
    // Leaf runs that overlap without nesting: leaf 1's line covers leaves 1..3, the merge 0..2.
    expect_hierarchy(&edited(2, |l| l.leaf_count = 2), &["overlap without nesting", "§10 rule 1"]);
    // A chain that does not start at 0.
    expect_hierarchy(&edited(2, |l| l.lo = 0.5), &["leaf 1", "does not start at 0"]);
    // The root's interval ends below +∞.
    let data = edited(0, |l| l.hi = 3.0);
    expect_hierarchy(&data, &["does not end at +inf"]);
    // Not sorted by hi: a record's own order.
    let mut data = fixture();
    data.far_lines.swap(0, 1);
    expect_record(&data, 1, &["hi inf is larger than 1.5", "the section sorts by hi"]);
    // A record's own interval and run.
    expect_record(&edited(1, |l| l.lo = -1.0), 1, &["lo -1 is not finite and >= 0"]);
    expect_record(&edited(1, |l| l.lo = f32::NAN), 1, &["is not finite and >= 0"]);
    expect_record(&edited(0, |l| l.hi = 1.0), 0, &["hi 1 is below lo 1.5"]);
    expect_record(&edited(2, |l| l.leaf_count = 0), 2, &["leaf_count is 0"]);
}

#[test]
fn a_switch_where_the_cells_draw_other_lines_is_refused() {
    // Far level 0 ends at 0.8, so the switch is at 0.57, where cell 0 draws its two leaves, not
    // the merge that far level 0 copies.
    let mut data = edited(0, |l| l.lo = 0.8);
    data.far_lines[1].hi = 0.8;
    data.far_lines[2].hi = 0.8;
    expect_hierarchy(&data, &["leaves 0..2", "LINES has 3 records drawn at the switch", "τ_far 0.8", "§6.9.1"]);
}

#[test]
fn far_lines_outside_the_block_or_not_finite_are_refused() {
    expect_record(&edited(0, |l| l.p1 = [2.5, 0.8, 0.5]), 0, &["p1 [2.5, 0.8, 0.5] lies outside the block bounds"]);
    expect_record(&edited(2, |l| l.p0 = [1.2, -0.1, 0.5]), 2, &["p0", "outside the block bounds"]);
    expect_record(&edited(1, |l| l.p0[2] = f32::NAN), 1, &["endpoints", "are not finite"]);
    expect_record(&edited(1, |l| l.p1[0] = INF), 1, &["are not finite"]);
    expect_record(&edited(2, |l| l.r1 = -0.01), 2, &["radii 0.02, -0.01 are not finite and >= 0"]);
    // On the bounds is inside.
    check(&edited(0, |l| l.p1 = [2.0, 1.0, 1.0])).expect("a corner of the block is inside");
}

#[test]
fn far_line_ao_of_another_length_is_refused_by_the_writer() {
    for wrong in [1usize, 2, 4] {
        let mut data = fixture();
        data.far_line_ao.resize(wrong, 7);
        match data.to_bytes(Compression::None) {
            Err(Error::Write(message)) => {
                assert!(message.contains("FAR_LINE_AO"), "{message}");
                assert!(message.contains(&format!("{wrong} records, FAR_LINES has 3")), "{message}");
            }
            other => panic!("FAR_LINE_AO of {wrong}: expected Error::Write, got {other:?}"),
        }
    }
    // Occlusion for far lines there are none of, too (open refuses such a file: see ambient.rs).
    let data = ContainerData { far_lines: Vec::new(), ..fixture() };
    match data.to_bytes(Compression::None) {
        Err(Error::Write(message)) => assert!(message.contains("FAR_LINES has 0"), "{message}"),
        other => panic!("expected Error::Write, got {other:?}"),
    }
}

#[test]
fn check_far_lines_works_on_slices() {
    let data = fixture();
    let summary = check_far_lines(&data.far_lines, &data.lines, &data.block).expect("valid");
    assert_eq!(summary, SptSummary { leaves: 2, max_depth: 2 });
    assert_eq!(check_far_lines(&[], &[], &data.block).expect("empty is valid"), SptSummary::default());
    assert_eq!(check_far_lines(&[], &data.lines, &data.block).expect("empty is valid"), SptSummary::default());
    assert!(matches!(
        check_far_lines(&data.far_lines, &[], &data.block),
        Err(Error::BadRecord { kind: SectionKind::FAR_LINES, index: 0, .. })
    ));
}

#[test]
fn byte_edits_of_the_far_lines_never_panic() {
    // Every byte of both sections flipped three ways, resealed so the edit reaches verify.
    let clean = bytes_of(&fixture());
    let c = Container::from_bytes(&clean).expect("opens");
    let spans: Vec<(usize, usize)> = [SectionKind::FAR_LINES, SectionKind::FAR_LINE_AO]
        .iter()
        .map(|&kind| {
            let e = c.section(kind).expect("present").entry;
            (e.offset as usize, e.length as usize)
        })
        .collect();
    let mut refused = 0;
    for (offset, length) in spans {
        for at in offset..offset + length {
            for pattern in [0x01u8, 0x80, 0xFF] {
                let mut bytes = clean.clone();
                bytes[at] ^= pattern;
                reseal(&mut bytes);
                let c = Container::from_bytes(&bytes).expect("a content edit still opens");
                if let Err(e) = verify(&c) {
                    let message = e.to_string();
                    assert!(message.starts_with("FAR_LINES"), "{message}");
                    refused += 1;
                }
            }
        }
    }
    assert!(refused > 100, "most edits of the far lines break a rule ({refused})");
}
