//! The octahedral views' depth planes in the container (spec §6.13.2): the `OCTAHEDRAL_DEPTH` kind
//! (1.13) round-trips and makes a file 1.13, a file without it keeps its smaller minor and reads
//! no planes (every view the plane through the impostor's centre), opening does not read the
//! records (only their size), `verify` refuses a section without `OCTAHEDRAL`, a record count
//! other than the views' (`frames²` per impostor) and a value that is not finite or lies outside
//! `[−1, 1]`, each with an error naming the section and the record, and a reader that does not know
//! the kind (1.12 and before) skips it and reads everything else as it was.

mod common;

use common::{assert_reads_back, bytes_of, check, expect_refused, relabel, resize_section};
use treelod_format::{
    Compression, Container, ContainerData, Error, ErrorClass, MINOR, OctahedralDepthRecord, OctahedralRecord,
    PlaneDiffuseRecord, SectionKind, pack, verify,
};

const KIND: SectionKind = SectionKind::OCTAHEDRAL_DEPTH;

fn plane(offset: f32, slope_s: f32, slope_t: f32) -> OctahedralDepthRecord {
    OctahedralDepthRecord { offset, slope_s, slope_t }
}

/// An octahedral impostor of `tree` with `frames × frames` views over the whole of image 0.
fn impostor(tree: u32, frames: u32) -> OctahedralRecord {
    OctahedralRecord {
        center: [0.4, 0.5, 0.5],
        radius: 0.35,
        image: 0,
        uv_min: pack::unorm16x2(0.0, 0.0),
        uv_max: pack::unorm16x2(1.0, 1.0),
        frames,
        tree,
        occlusion: 0.25,
        diffuse: PlaneDiffuseRecord { flat: 30_000, scattered: 20_000 },
        reserved: 0,
    }
}

/// The depth planes of the fixture's first impostor (2 × 2 views, records 0–3): view `(0, 0)`,
/// `(1, 0)`, `(0, 1)` and `(1, 1)`; the third shows nothing (all zero), the fourth reaches the
/// bounds.
const FIRST: [OctahedralDepthRecord; 4] = [
    OctahedralDepthRecord { offset: 0.25, slope_s: -0.5, slope_t: 0.125 },
    OctahedralDepthRecord { offset: -0.75, slope_s: 0.5, slope_t: 0.375 },
    OctahedralDepthRecord { offset: 0.0, slope_s: 0.0, slope_t: 0.0 },
    OctahedralDepthRecord { offset: 1.0, slope_s: -1.0, slope_t: -0.25 },
];

/// View `(i, j)` of the fixture's second impostor (3 × 3 views, records 4–12).
fn second(i: u32, j: u32) -> OctahedralDepthRecord {
    let k = (j * 3 + i) as f32;
    plane(0.125 * k - 0.5, 0.0625 * k - 0.25, 0.5 - 0.0625 * k)
}

/// `common`'s leaf cell in a block of two trees, a 2×2 RGBA8 image (`IMAGES` 0), an octahedral
/// impostor per tree (tree 0 with 2 × 2 views, tree 1 with 3 × 3) and their 4 + 9 depth planes,
/// view `(i, j)` of each at `j·frames + i` after the other's. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("octahedral-depth-fixture");
    data.block.tree_count = 2;
    data.metadata.trees.push(treelod_format::Tree::default());
    common::grey_image(&mut data);
    data.octahedral =
        vec![impostor(0, 2), OctahedralRecord { center: [0.3, 0.45, 0.5], radius: 0.5, ..impostor(1, 3) }];
    data.octahedral_depth = FIRST.to_vec();
    data.octahedral_depth.extend((0..3).flat_map(|j| (0..3).map(move |i| second(i, j))));
    data
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 13, "OCTAHEDRAL_DEPTH is format 1.13") };
    assert_eq!(KIND.0, 0x0054);
    assert_eq!(KIND.name(), Some("OCTAHEDRAL_DEPTH"));
    assert_eq!(KIND.to_string(), "OCTAHEDRAL_DEPTH");
    assert_eq!(KIND.record_size(), Some(12));
    assert_eq!(size_of::<OctahedralDepthRecord>(), 12);
    assert_eq!(KIND.since_minor(), 13);
    assert!(KIND.compressible());
    assert!(SectionKind::KNOWN.contains(&KIND));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    // Right after OCTAHEDRAL, whose views it describes.
    let at = SectionKind::KNOWN.iter().position(|&k| k == KIND).expect("known");
    assert_eq!(SectionKind::KNOWN[at - 1], SectionKind::OCTAHEDRAL);
    // The field offsets of spec §6.13.2, little endian; all zero is the default.
    let bytes = bytemuck::bytes_of(&FIRST[1]);
    let float = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    assert_eq!([float(0), float(4), float(8)], [-0.75, 0.5, 0.375]);
    assert_eq!(OctahedralDepthRecord::default(), plane(0.0, 0.0, 0.0));
}

#[test]
fn a_container_with_depth_planes_round_trips_as_format_1_13_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 13), "{compression:?}");
        assert_eq!(c.octahedral_depth(), data.octahedral_depth.as_slice());
        assert_eq!(c.octahedral(), data.octahedral.as_slice());
        let section = c.section(KIND).expect("present");
        assert_eq!((section.entry.record_size, section.entry.raw_length), (12, 13 * 12));
        assert_eq!(c.raw_bytes(KIND), bytemuck::cast_slice::<_, u8>(&data.octahedral_depth));
        let report = verify(&c).expect("verifies");
        assert_eq!((report.octahedral, report.octahedral_depth), (2, 13));
        let text = report.to_string();
        assert!(
            text.contains(
                "baselines: 0 LoD levels, 0 LoD triangles, 0 billboards, 2 octahedral impostors, 13 octahedral depth \
                 planes\n"
            ),
            "{text}"
        );
        assert_reads_back(&c, &data, &bytes, compression);
    }
}

#[test]
fn view_i_j_of_each_impostor_is_record_j_frames_plus_i_after_the_earlier_impostors() {
    let c = Container::from_bytes(&bytes_of(&fixture())).expect("opens");
    let (impostors, planes) = (c.octahedral(), c.octahedral_depth());
    let mut first = 0;
    for (k, o) in impostors.iter().enumerate() {
        let n = o.frames as usize;
        let views = &planes[first..first + n * n];
        for (i, j) in (0..o.frames).flat_map(|j| (0..o.frames).map(move |i| (i, j))) {
            let expected = if k == 0 { FIRST[(2 * j + i) as usize] } else { second(i, j) };
            assert_eq!(views[j as usize * n + i as usize], expected, "impostor {k}, view ({i}, {j})");
        }
        first += n * n;
    }
    assert_eq!(first, planes.len(), "the views' planes and nothing else");
}

/// Spec §6.13.2: the point a view shows at `(s, t)`, `center + radius·(s·right + t·up + depth·d)`
/// with `depth = offset + slope_s·s + slope_t·t`, lies on the plane `n·(p − center) =
/// offset·radius`, `n = d − slope_s·right − slope_t·up`; the same `(s, t)` are its `right` and `up`
/// components over `radius`.
#[test]
fn each_views_points_lie_on_its_plane() {
    let data = fixture();
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut planes = data.octahedral_depth.iter();
    for o in &data.octahedral {
        for (i, j) in (0..o.frames).flat_map(|j| (0..o.frames).map(move |i| (i, j))) {
            let p = planes.next().expect("a plane per view");
            let d = OctahedralRecord::view_direction(o.frames, i, j);
            let (right, up) = OctahedralRecord::view_basis(d);
            let n = p.normal(right, up, d);
            for (s, t) in [(0.0, 0.0), (1.0, 0.0), (0.0, -1.0), (-0.5, 0.75), (1.0, 1.0)] {
                let depth = p.depth(s, t);
                assert_eq!(depth, p.offset + p.slope_s * s + p.slope_t * t);
                let offset: [f32; 3] = core::array::from_fn(|k| o.radius * (s * right[k] + t * up[k] + depth * d[k]));
                let point: [f32; 3] = core::array::from_fn(|k| o.center[k] + offset[k]);
                let relative: [f32; 3] = core::array::from_fn(|k| point[k] - o.center[k]);
                assert!((dot(n, relative) - p.offset * o.radius).abs() < 1e-5, "({i}, {j}) at ({s}, {t})");
                assert!(
                    (dot(relative, right) / o.radius - s).abs() < 1e-5
                        && (dot(relative, up) / o.radius - t).abs() < 1e-5
                );
            }
        }
    }
    assert!(planes.next().is_none());
    // All zero: the plane through the centre across the view's direction.
    let flat = OctahedralDepthRecord::default();
    assert_eq!(flat.normal([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0]);
    assert_eq!(flat.depth(0.75, -1.0), 0.0);
}

#[test]
fn a_file_without_depth_planes_keeps_its_smaller_minor_and_reads_none() {
    // Without the section: the impostors alone are a 1.11 file, whose views are the planes
    // through their centres.
    let older = ContainerData { octahedral_depth: Vec::new(), ..fixture() };
    let c = Container::from_bytes(&bytes_of(&older)).expect("opens");
    assert_eq!(c.header().minor, 11);
    assert_eq!(c.octahedral_depth(), &[] as &[OctahedralDepthRecord]);
    assert!(c.section(KIND).is_none(), "no empty section is written");
    let report = verify(&c).expect("verifies");
    assert_eq!((report.octahedral, report.octahedral_depth), (2, 0));
    assert!(!report.to_string().contains("depth"), "{report}");

    // Without any impostor: a 1.0 file, no planes either.
    let plain = ContainerData { octahedral: Vec::new(), ..older.clone() };
    let c = Container::from_bytes(&bytes_of(&plain)).expect("opens");
    assert_eq!(c.header().minor, 0);
    assert!(c.octahedral().is_empty() && c.octahedral_depth().is_empty());

    // With the added techniques' calibration (1.12): 1.12 without the planes, 1.13 with them.
    let calibration = treelod_format::CalibrationRecord { technique: 0, height: 16.0, error: 0.0, primitives: 1.0 };
    let added = treelod_format::CalibrationRecord { technique: 9, ..calibration };
    let mut calibrated = ContainerData { calibration: vec![calibration], calibration_added: vec![added], ..older };
    assert_eq!(Container::from_bytes(&bytes_of(&calibrated)).expect("opens").header().minor, 12);
    check(&calibrated).expect("verifies");
    calibrated.octahedral_depth = fixture().octahedral_depth;
    assert_eq!(Container::from_bytes(&bytes_of(&calibrated)).expect("opens").header().minor, 13);
    assert_eq!(check(&calibrated).expect("verifies").octahedral_depth, 13);
}

// ----------------------------------------------------------------------------------------------
// Verify.

#[test]
fn the_bounds_of_every_value_verify() {
    for value in [-1.0, 1.0, 0.0, -0.0, f32::MIN_POSITIVE, -f32::MIN_POSITIVE, 1e-40, 0.999_999_94] {
        for field in 0..3 {
            let mut data = fixture();
            let r = &mut data.octahedral_depth[7];
            *[&mut r.offset, &mut r.slope_s, &mut r.slope_t][field] = value;
            check(&data).unwrap_or_else(|e| panic!("field {field} = {value}: {e}"));
        }
    }
    // Every view flat: what a file without the section means.
    let mut data = fixture();
    data.octahedral_depth.fill(OctahedralDepthRecord::default());
    check(&data).expect("all zero");
}

#[test]
fn depth_planes_without_octahedral_impostors_are_refused() {
    let mut data = fixture();
    data.octahedral.clear();
    expect_refused(&data, KIND, 0, &["the file has no OCTAHEDRAL"]);
    // Whatever their count.
    data.octahedral_depth.truncate(1);
    expect_refused(&data, KIND, 0, &["no OCTAHEDRAL"]);
}

#[test]
fn a_count_other_than_the_views_is_refused() {
    type Edit = fn(&mut ContainerData);
    let cases: [(&str, &str, Edit); 6] = [
        ("one plane more", "14 records, the 2 OCTAHEDRAL records have 13 views (frames² each)", |d| {
            d.octahedral_depth.push(OctahedralDepthRecord::default())
        }),
        ("one plane fewer", "12 records, the 2 OCTAHEDRAL records have 13 views", |d| {
            d.octahedral_depth.pop();
        }),
        ("the planes of the first impostor only", "4 records, the 2 OCTAHEDRAL records have 13 views", |d| {
            d.octahedral_depth.truncate(4)
        }),
        ("a grid of 2 × 2 for 3 × 3 planes", "13 records, the 2 OCTAHEDRAL records have 8 views", |d| {
            d.octahedral[1].frames = 2
        }),
        ("a grid of 4 × 4 for 2 × 2 planes", "13 records, the 2 OCTAHEDRAL records have 25 views", |d| {
            d.octahedral[0].frames = 4
        }),
        ("a third impostor without planes", "13 records, the 3 OCTAHEDRAL records have 17 views", |d| {
            d.block.tree_count = 3;
            d.metadata.trees.push(treelod_format::Tree::default());
            d.octahedral.push(impostor(2, 2));
        }),
    ];
    for (what, needle, edit) in cases {
        let mut data = fixture();
        edit(&mut data);
        match check(&data) {
            Err(Error::BadRecord { kind: SectionKind::OCTAHEDRAL_DEPTH, index: 0, reason }) => {
                assert!(reason.contains(needle), "{what}: {reason}")
            }
            other => panic!("{what}: expected BadRecord OCTAHEDRAL_DEPTH 0, got {other:?}"),
        }
    }
    // The count as a sum over the impostors: the first's 4 and the second's 9 swapped over
    // (frames 3 then 2) still count 13, so it verifies, the views read in the other order.
    let mut data = fixture();
    data.octahedral[0].frames = 3;
    data.octahedral[1].frames = 2;
    check(&data).expect("9 + 4 views, 13 planes");
}

#[test]
fn values_that_are_not_finite_or_outside_minus_one_to_one_are_refused() {
    // (record, its view and impostor as the reason names them)
    let places = [(0, "view (0, 0) of OCTAHEDRAL record 0"), (3, "view (1, 1) of OCTAHEDRAL record 0")]
        .into_iter()
        .chain([(4, "view (0, 0) of OCTAHEDRAL record 1"), (9, "view (2, 1) of OCTAHEDRAL record 1")])
        .chain([(12, "view (2, 2) of OCTAHEDRAL record 1")]);
    let values = [
        (f32::NAN, "NaN"),
        (f32::INFINITY, "inf"),
        (f32::NEG_INFINITY, "-inf"),
        (1.000_000_1, "1.0000001"),
        (-1.5, "-1.5"),
        (f32::MAX, "340282350000000000000000000000000000000"),
    ];
    for (index, view) in places {
        for (field, name) in ["offset", "slope_s", "slope_t"].into_iter().enumerate() {
            for (value, text) in values {
                let mut data = fixture();
                let r = &mut data.octahedral_depth[index];
                *[&mut r.offset, &mut r.slope_s, &mut r.slope_t][field] = value;
                expect_refused(&data, KIND, index, &[&format!("{name} {text} is not finite and in [-1, 1] ({view})")]);
            }
        }
    }
    // The first value out of range is reported: the record's first, then the first record.
    let mut data = fixture();
    data.octahedral_depth[5].slope_t = 2.0;
    data.octahedral_depth[5].slope_s = -2.0;
    data.octahedral_depth[6].offset = f32::NAN;
    expect_refused(&data, KIND, 5, &["slope_s -2 is not finite"]);
}

// ----------------------------------------------------------------------------------------------
// Open, and a reader of 1.12 and before.

#[test]
fn a_section_of_partial_records_is_refused_at_open() {
    let bytes = bytes_of(&fixture());
    Container::from_bytes(&resize_section(&bytes, KIND, 0)).expect("the untouched file opens");
    for delta in [-4, -8, -11] {
        let edited = resize_section(&bytes, KIND, delta);
        let err = Container::from_bytes(&edited).expect_err("a partial record");
        assert_eq!(err.class(), ErrorClass::Invalid, "{delta:+}: {err}");
        assert!(err.to_string().contains("OCTAHEDRAL_DEPTH"), "{delta:+}: {err}");
    }
    // One record fewer is a whole number of records: it opens (its count is checked by verify,
    // not at open).
    let shorter = resize_section(&bytes, KIND, -12);
    let c = Container::from_bytes(&shorter).expect("one record fewer");
    assert_eq!(c.octahedral_depth(), &fixture().octahedral_depth[..12]);
    // A zero-length section is the same as an absent one.
    let emptied = resize_section(&bytes, KIND, -13 * 12);
    let c = Container::from_bytes(&emptied).expect("an empty OCTAHEDRAL_DEPTH section opens");
    assert!(c.octahedral_depth().is_empty());
}

#[test]
fn a_reader_that_does_not_know_the_kind_skips_it_and_reads_the_rest_as_before() {
    // A reader of 1.12 or before sees kind 0x0054 as one it does not know. Relabelled as a kind
    // this version does not know either (a private extension), the section is skipped the same
    // way: the rest of the file reads record for record, the impostors drawn as flat views, and
    // verifies.
    let data = fixture();
    let bytes = bytes_of(&data);
    let unknown = 0x0001_0054;
    assert_eq!(SectionKind(unknown).record_size(), None, "a kind this version does not know");
    let skipped = relabel(&bytes, KIND, unknown);
    let c = Container::from_bytes(&skipped).expect("opens");
    assert!(c.octahedral_depth().is_empty(), "the depth planes are skipped");
    assert!(c.section(KIND).is_none());
    assert_eq!(c.octahedral(), data.octahedral.as_slice(), "the impostors stay");
    assert_eq!(c.header().minor, 13, "the header keeps the file's minor; a reader accepts any minor");
    let back = ContainerData::from_container(&c);
    let expected = ContainerData {
        octahedral_depth: Vec::new(),
        extra_sections: vec![(unknown, bytemuck::cast_slice::<_, u8>(&data.octahedral_depth).to_vec())],
        ..data.clone()
    };
    assert_eq!(back, expected, "nothing else is skipped");
    let report = verify(&c).expect("an unknown kind is only checksummed");
    assert_eq!((report.octahedral, report.octahedral_depth), (2, 0));
    assert_eq!(report.sections, Container::from_bytes(&bytes).expect("opens").sections().len());
    // Written back without the planes, it is the file of the smaller minor.
    let without = ContainerData { extra_sections: Vec::new(), ..back };
    let c = Container::from_bytes(&bytes_of(&without)).expect("opens");
    assert_eq!(c.header().minor, 11);
    verify(&c).expect("verifies");
}
