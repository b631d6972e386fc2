//! Octahedral impostors in the container (spec §6.13.1): the `OCTAHEDRAL` kind (1.11) round-trips
//! and makes a file 1.11, a file without it keeps its smaller minor, opening does not read the
//! records (only their size), `verify` refuses every broken rule with an error naming the section
//! and the record, and a reader that does not know the kind (1.10 and before) skips it and reads
//! everything else as it was.

mod common;

use common::{assert_reads_back, relabel, resize_section};
use treelod_format::{
    CellRecord, Compression, Container, ContainerData, Error, ErrorClass, ImageRecord, MINOR, OctahedralRecord,
    PlaneDiffuseRecord, Range, SectionKind, image_format, pack, verify,
};

fn range(first: u32, count: u32) -> Range {
    Range { first, count }
}

/// An octahedral impostor of `tree` over the whole of image 0, centred in the block.
fn impostor(tree: u32, frames: u32, occlusion: f32) -> OctahedralRecord {
    OctahedralRecord {
        center: [0.4, 0.5, 0.5],
        radius: 0.35,
        image: 0,
        uv_min: pack::unorm16x2(0.0, 0.0),
        uv_max: pack::unorm16x2(1.0, 1.0),
        frames,
        tree,
        occlusion,
        diffuse: PlaneDiffuseRecord { flat: 30_000, scattered: 20_000 },
        reserved: 0,
    }
}

/// `common`'s leaf cell in a block of two trees, a 2×2 RGBA8 image (`IMAGES` 0) and one
/// octahedral impostor per tree: tree 0 with 8 × 8 views, tree 1 with 5 × 5 views over the
/// image's right half. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("octahedral-fixture");
    data.block.tree_count = 2;
    data.metadata.trees.push(treelod_format::Tree::default());
    common::grey_image(&mut data);
    data.octahedral = vec![
        impostor(0, 8, 0.25),
        OctahedralRecord {
            center: [0.3, 0.45, 0.5],
            radius: 0.5,
            uv_min: pack::unorm16x2(0.5, 0.0),
            ..impostor(1, 5, 0.0)
        },
    ];
    data
}

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 11, "OCTAHEDRAL is format 1.11") };
    let kind = SectionKind::OCTAHEDRAL;
    assert_eq!(kind.0, 0x0053);
    assert_eq!(kind.name(), Some("OCTAHEDRAL"));
    assert_eq!(kind.to_string(), "OCTAHEDRAL");
    assert_eq!(kind.record_size(), Some(48));
    assert_eq!(size_of::<OctahedralRecord>(), 48);
    assert_eq!(kind.since_minor(), 11);
    assert!(SectionKind::KNOWN.contains(&kind));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    // The field offsets of spec §6.13.1, little endian.
    let record = OctahedralRecord {
        center: [1.0, 2.0, 3.0],
        radius: 4.0,
        image: 0x0506_0708,
        uv_min: 0x1112_1314,
        uv_max: 0x2122_2324,
        frames: 0x3132_3334,
        tree: 0x4142_4344,
        occlusion: 0.5,
        diffuse: PlaneDiffuseRecord { flat: 0x5152, scattered: 0x5354 },
        reserved: 0x6162_6364,
    };
    let bytes = bytemuck::bytes_of(&record);
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let float = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    assert_eq!([float(0), float(4), float(8), float(12)], [1.0, 2.0, 3.0, 4.0]);
    assert_eq!(
        [word(16), word(20), word(24), word(28), word(32)],
        [0x0506_0708, 0x1112_1314, 0x2122_2324, 0x3132_3334, 0x4142_4344]
    );
    assert_eq!(float(36), 0.5);
    assert_eq!([word(40), word(44)], [0x5354_5152, 0x6162_6364]);
}

#[test]
fn a_container_with_octahedral_impostors_round_trips_as_format_1_11_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 11), "{compression:?}");
        assert_eq!(c.octahedral(), data.octahedral.as_slice());
        let section = c.section(SectionKind::OCTAHEDRAL).expect("present");
        assert_eq!((section.entry.record_size, section.entry.raw_length), (48, 96));
        assert_eq!(c.raw_bytes(SectionKind::OCTAHEDRAL), bytemuck::cast_slice::<_, u8>(&data.octahedral));
        let report = verify(&c).expect("verifies");
        assert_eq!((report.octahedral, report.billboards, report.lod_levels), (2, 0, 0));
        let text = report.to_string();
        assert!(
            text.contains("baselines: 0 LoD levels, 0 LoD triangles, 0 billboards, 2 octahedral impostors\n"),
            "{text}"
        );
        assert_reads_back(&c, &data, &bytes, compression);
    }
}

#[test]
fn a_file_without_octahedral_impostors_keeps_its_smaller_minor() {
    // Without the section: the leaf cell and its image are a 1.0 file.
    let older = ContainerData { octahedral: Vec::new(), ..fixture() };
    let c = Container::from_bytes(&older.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 0);
    assert!(c.octahedral().is_empty());
    assert!(c.section(SectionKind::OCTAHEDRAL).is_none(), "no empty section is written");
    let report = verify(&c).expect("verifies");
    assert_eq!(report.octahedral, 0);
    assert!(!report.to_string().contains("baselines"), "{report}");

    // One impostor is enough for 1.11.
    let one = ContainerData { octahedral: vec![impostor(1, 2, 1.0)], ..older.clone() };
    let c = Container::from_bytes(&one.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 11);
    assert_eq!(verify(&c).expect("verifies").octahedral, 1);

    // With far lines (1.9): 1.9 without the impostors, 1.11 with them.
    let line = common::branch_line([0.3, 0.3, 0.5], [0.7, 0.6, 0.5]);
    let mut lines = ContainerData { lines: vec![line], far_lines: vec![line], ..older };
    lines.cells[1] =
        CellRecord { bounds_min: [0.3, 0.3, 0.5], bounds_max: [0.7, 0.6, 0.5], lines: range(0, 1), ..lines.cells[1] };
    let c = Container::from_bytes(&lines.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 9);
    verify(&c).expect("verifies");
    let both = ContainerData { octahedral: fixture().octahedral, ..lines };
    let c = Container::from_bytes(&both.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 11);
    verify(&c).expect("verifies");
}

#[test]
fn the_bounds_of_every_rule_verify() {
    type Edit = fn(&mut OctahedralRecord);
    let cases: [(&str, Edit); 9] = [
        ("2 views per side", |o| o.frames = 2),
        ("64 views per side", |o| o.frames = 64),
        ("a tiny radius", |o| o.radius = f32::MIN_POSITIVE),
        ("no occlusion", |o| o.occlusion = 0.0),
        ("negative zero occlusion", |o| o.occlusion = -0.0),
        ("full occlusion", |o| o.occlusion = 1.0),
        ("an empty rectangle", |o| o.uv_max = o.uv_min),
        ("a rectangle of one row", |o| o.uv_max = pack::unorm16x2(1.0, 0.0)),
        ("a centre outside the block", |o| o.center = [-100.0, 50.0, 1e6]),
    ];
    for (what, edit) in cases {
        let mut data = fixture();
        edit(&mut data.octahedral[1]);
        common::check(&data).unwrap_or_else(|e| panic!("{what}: {e}"));
    }
    // A tree may have none: impostors of tree 1 only, or of tree 0 only.
    for keep in [0, 1] {
        let mut data = fixture();
        data.octahedral.remove(1 - keep);
        common::check(&data).unwrap_or_else(|e| panic!("only tree {keep}: {e}"));
    }
}

/// A 1×1 `LEAF_SLOTS` image appended to `data`'s images (`IMAGES` 1).
fn with_slots_image(data: &mut ContainerData) {
    data.image_data.extend_from_slice(&[0; 4]);
    data.images.push(ImageRecord {
        width: 1,
        height: 1,
        mip_count: 1,
        format: image_format::LEAF_SLOTS,
        data_offset: 16,
        data_length: 4,
    });
}

#[test]
fn every_broken_rule_is_refused_by_verify_naming_the_section_and_record() {
    type Edit = fn(&mut ContainerData);
    // (what, record index, the reason's words, the edit)
    let cases: [(&str, usize, &str, Edit); 22] = [
        ("one view per side", 1, "frames 1 is outside 2 ..= 64", |d| d.octahedral[1].frames = 1),
        ("no views", 0, "frames 0 is outside", |d| d.octahedral[0].frames = 0),
        ("65 views per side", 1, "frames 65 is outside", |d| d.octahedral[1].frames = 65),
        ("a huge grid", 0, "frames 4294967295", |d| d.octahedral[0].frames = u32::MAX),
        ("a NaN centre", 1, "center [NaN", |d| d.octahedral[1].center[0] = f32::NAN),
        ("an infinite centre", 0, "is not finite", |d| d.octahedral[0].center[2] = f32::INFINITY),
        ("a zero radius", 1, "radius 0 is not finite and > 0", |d| d.octahedral[1].radius = 0.0),
        ("a negative radius", 0, "radius -0.5", |d| d.octahedral[0].radius = -0.5),
        ("a NaN radius", 1, "radius NaN", |d| d.octahedral[1].radius = f32::NAN),
        ("an infinite radius", 0, "radius inf", |d| d.octahedral[0].radius = f32::INFINITY),
        ("an image out of range", 1, "image 1 is out of range (1 images)", |d| d.octahedral[1].image = 1),
        ("no image", 0, "image 4294967295 is out of range", |d| d.octahedral[0].image = u32::MAX),
        ("a LEAF_SLOTS image", 1, "image 1 is a LEAF_SLOTS image, not a colour image", |d| {
            with_slots_image(d);
            d.octahedral[1].image = 1;
        }),
        ("u reversed", 0, "uv_min (65535, 0) is not <= uv_max", |d| {
            d.octahedral[0].uv_min = pack::unorm16x2(1.0, 0.0);
            d.octahedral[0].uv_max = pack::unorm16x2(0.5, 1.0);
        }),
        ("v reversed", 1, "uv_min (32768, 49151) is not <= uv_max (65535, 32768)", |d| {
            d.octahedral[1].uv_min = pack::unorm16x2(0.5, 0.75);
            d.octahedral[1].uv_max = pack::unorm16x2(1.0, 0.5);
        }),
        ("a tree out of range", 1, "tree 2 is out of range (2 trees)", |d| d.octahedral[1].tree = 2),
        ("negative occlusion", 0, "occlusion -0.01 is not in [0, 1]", |d| d.octahedral[0].occlusion = -0.01),
        ("occlusion above 1", 1, "occlusion 1.5", |d| d.octahedral[1].occlusion = 1.5),
        ("NaN occlusion", 0, "occlusion NaN", |d| d.octahedral[0].occlusion = f32::NAN),
        ("diffuse shares over 1", 1, "diffuse shares flat 40000 + scattered 30000 exceed 65535", |d| {
            d.octahedral[1].diffuse = PlaneDiffuseRecord { flat: 40_000, scattered: 30_000 }
        }),
        ("not sorted", 1, "tree 0 after tree 1: not sorted by tree", |d| d.octahedral.swap(0, 1)),
        ("two of one tree", 1, "tree 0 after tree 0: a second impostor of the tree", |d| d.octahedral[1].tree = 0),
    ];
    for (what, index, needle, edit) in cases {
        let mut data = fixture();
        edit(&mut data);
        let bytes = data.to_bytes(Compression::None).expect("invalid content still writes");
        let c = Container::from_bytes(&bytes).unwrap_or_else(|e| panic!("{what}: opening checks no content: {e}"));
        let err = verify(&c).expect_err(what);
        match &err {
            Error::BadRecord { kind, index: i, reason } => {
                assert_eq!((*kind, *i), (SectionKind::OCTAHEDRAL, index), "{what}: {err}");
                assert!(reason.contains(needle), "{what}: {err}");
            }
            other => panic!("{what}: expected BadRecord, got {other:?}"),
        }
        assert!(err.to_string().starts_with(&format!("OCTAHEDRAL record {index}: ")), "{what}: {err}");
        assert_eq!(err.class(), ErrorClass::Invalid, "{what}");
    }
    // Three impostors with the third's tree out of order (a block of three trees).
    let mut data = fixture();
    data.block.tree_count = 3;
    data.metadata.trees.push(treelod_format::Tree::default());
    data.octahedral[1].tree = 2;
    data.octahedral.push(impostor(1, 4, 0.5));
    match common::check(&data) {
        Err(Error::BadRecord { kind: SectionKind::OCTAHEDRAL, index: 2, reason }) => {
            assert!(reason.contains("tree 1 after tree 2"), "{reason}")
        }
        other => panic!("expected BadRecord OCTAHEDRAL 2, got {other:?}"),
    }
    data.octahedral.swap(1, 2);
    common::check(&data).expect("sorted again");
}

#[test]
fn a_section_of_partial_records_is_refused_at_open() {
    let bytes = fixture().to_bytes(Compression::None).expect("writes");
    Container::from_bytes(&resize_section(&bytes, SectionKind::OCTAHEDRAL, 0)).expect("the untouched file opens");
    for delta in [-4, -20, -47] {
        let edited = resize_section(&bytes, SectionKind::OCTAHEDRAL, delta);
        let err = Container::from_bytes(&edited).expect_err("a partial record");
        assert_eq!(err.class(), ErrorClass::Invalid, "{delta:+}: {err}");
        assert!(err.to_string().contains("OCTAHEDRAL"), "{delta:+}: {err}");
    }
    // One record fewer is a whole number of records: it opens with one impostor. (`verify` would
    // refuse the file, which no longer ends where its last section ends.)
    let shorter = resize_section(&bytes, SectionKind::OCTAHEDRAL, -48);
    let c = Container::from_bytes(&shorter).expect("one record");
    assert_eq!(c.octahedral(), &fixture().octahedral[..1]);
    // A zero-length section is the same as an absent one.
    let emptied = resize_section(&bytes, SectionKind::OCTAHEDRAL, -96);
    let c = Container::from_bytes(&emptied).expect("an empty OCTAHEDRAL section opens");
    assert!(c.octahedral().is_empty());
}

#[test]
fn a_reader_that_does_not_know_the_kind_skips_it_and_reads_the_rest_as_before() {
    // A reader of 1.10 or before sees kind 0x0053 as one it does not know. Relabelled as a kind
    // this version does not know either (a private extension), the section is skipped the same
    // way: the rest of the file reads record for record as with the impostors, and verifies.
    let data = fixture();
    let bytes = data.to_bytes(Compression::None).expect("writes");
    let unknown = 0x0001_0053;
    assert_eq!(SectionKind(unknown).record_size(), None, "a kind this version does not know");
    let skipped = relabel(&bytes, SectionKind::OCTAHEDRAL, unknown);
    let c = Container::from_bytes(&skipped).expect("opens");
    assert!(c.octahedral().is_empty(), "the impostors are skipped");
    assert!(c.section(SectionKind::OCTAHEDRAL).is_none());
    assert_eq!(c.header().minor, 11, "the header keeps the file's minor; a reader accepts any minor");
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        octahedral: Vec::new(),
        extra_sections: vec![(unknown, bytemuck::cast_slice::<_, u8>(&data.octahedral).to_vec())],
        ..data.clone()
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("an unknown kind is only checksummed");
    assert_eq!(report.octahedral, 0);
    assert_eq!(report.sections, Container::from_bytes(&bytes).expect("opens").sections().len());
    // Written back without the impostors, it is the file of the smaller minor.
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    let c = Container::from_bytes(&without.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 0);
}

/// The views' directions as spec §6.13.1 maps them: unit, above the horizon, the grid's corners
/// at −X, +Z, −Z and +X and its centre (odd `N`) straight above; each view's basis orthonormal
/// with `right` horizontal and `d = right × up`.
#[test]
fn view_directions_and_bases_are_those_of_the_spec() {
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6);
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    for n in [2, 3, 12, 16, 64] {
        let last = n - 1;
        assert!(close(OctahedralRecord::view_direction(n, 0, 0), [-1.0, 0.0, 0.0]), "{n}");
        assert!(close(OctahedralRecord::view_direction(n, last, 0), [0.0, 0.0, 1.0]), "{n}");
        assert!(close(OctahedralRecord::view_direction(n, 0, last), [0.0, 0.0, -1.0]), "{n}");
        assert!(close(OctahedralRecord::view_direction(n, last, last), [1.0, 0.0, 0.0]), "{n}");
        if n % 2 == 1 {
            assert!(close(OctahedralRecord::view_direction(n, last / 2, last / 2), [0.0, 1.0, 0.0]), "{n}");
        }
        for (i, j) in (0..n).flat_map(|j| (0..n).map(move |i| (i, j))) {
            let d = OctahedralRecord::view_direction(n, i, j);
            assert!((dot(d, d) - 1.0).abs() < 1e-5 && d[1] >= 0.0, "{n}: ({i}, {j}) {d:?}");
            let (right, up) = OctahedralRecord::view_basis(d);
            assert!((dot(right, right) - 1.0).abs() < 1e-5 && (dot(up, up) - 1.0).abs() < 1e-5, "{d:?}");
            assert!(dot(right, up).abs() < 1e-5 && dot(right, d).abs() < 1e-5 && dot(up, d).abs() < 1e-5);
            assert!(right[1] == 0.0 && up[1] >= 0.0, "right horizontal, up not down: {right:?} {up:?}");
            let cross = [
                right[1] * up[2] - right[2] * up[1],
                right[2] * up[0] - right[0] * up[2],
                right[0] * up[1] - right[1] * up[0],
            ];
            assert!(close(cross, d) || dot(cross, d) > 1.0 - 1e-5, "right × up is d: {cross:?} {d:?}");
        }
    }
    // Straight above: right +X, up −Z.
    assert_eq!(OctahedralRecord::view_basis([0.0, 1.0, 0.0]), ([1.0, 0.0, 0.0], [0.0, 0.0, -1.0]));
}

proptest::proptest! {
    /// The three views a reader blends surround the direction: barycentric weights, at least 0,
    /// summing to 1, of views inside the grid, reproducing the direction's point on the map; a
    /// view's own direction gets it alone; below the horizon, the horizon's views.
    #[test]
    fn the_blend_weighs_the_three_views_around_the_direction(
        n in 2u32..=64,
        x in -1.0f32..1.0,
        y in -1.0f32..1.0,
        z in -1.0f32..1.0,
    ) {
        proptest::prop_assume!(x.abs() + y.abs() + z.abs() > 1e-3);
        let views = OctahedralRecord::blend(n, [x, y, z]);
        let total: f32 = views.iter().map(|v| v.2).sum();
        proptest::prop_assert!((total - 1.0).abs() < 1e-5, "{views:?}");
        proptest::prop_assert!(views.iter().all(|v| v.0 < n && v.1 < n && v.2 >= -1e-6), "{views:?}");
        // The map's point (grid units) is the weighted mean of the views' grid points.
        let yp = y.max(0.0);
        let sum = x.abs() + yp + z.abs();
        let last = (n - 1) as f32;
        let (gx, gy) = (((x + z) / sum + 1.0) * 0.5 * last, ((x - z) / sum + 1.0) * 0.5 * last);
        let mx: f32 = views.iter().map(|v| v.0 as f32 * v.2).sum();
        let my: f32 = views.iter().map(|v| v.1 as f32 * v.2).sum();
        proptest::prop_assert!((mx - gx).abs() < 1e-3 * last.max(1.0) && (my - gy).abs() < 1e-3 * last.max(1.0));
        // A view's own direction: that view alone.
        let (i, j) = (((x + 1.0) * 0.5 * last).round() as u32, ((z + 1.0) * 0.5 * last).round() as u32);
        let own = OctahedralRecord::blend(n, OctahedralRecord::view_direction(n, i, j));
        let weight: f32 = own.iter().filter(|v| (v.0, v.1) == (i, j)).map(|v| v.2).sum();
        proptest::prop_assert!(weight > 1.0 - 1e-4, "({i}, {j}): {own:?}");
    }
}
