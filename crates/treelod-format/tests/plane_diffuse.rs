//! The planes' diffuse response in the container (spec §6.10.2): the `PLANE_DIFFUSE` kind (1.10)
//! round-trips and makes a file 1.10, a file without it keeps its smaller minor and reads as
//! `FLAT` planes (no records), the writer refuses and the reader refuses at open a section with
//! another count than `PLANES` (a typed error naming `PLANE_DIFFUSE`), `verify` refuses shares
//! that sum past 1, and [`PlaneDiffuseRecord::diffuse`] is the area-weighted mean `|n·l|` of the
//! mixture the record describes: the plane's own `|N·l|` for `FLAT`, and for each of the three
//! ways alone what normals spread that way give.

mod common;

use common::{assert_reads_back, resize_section};
use treelod_format::{
    AO_KINDS, CellRecord, Compression, Container, ContainerData, Error, ErrorClass, MINOR, PlaneDiffuseRecord,
    PlaneRecord, Range, SectionKind, pack, verify,
};

fn range(first: u32, count: u32) -> Range {
    Range { first, count }
}

fn plane(center: [f32; 3], axis_u: [f32; 3], axis_v: [f32; 3], lo: f32, hi: f32, leaf_first: u32) -> PlaneRecord {
    let leaf_count = if hi == f32::INFINITY { 2 } else { 1 };
    PlaneRecord {
        center,
        axis_u,
        axis_v,
        image: 0,
        uv_min: pack::unorm16x2(0.0, 0.0),
        uv_max: pack::unorm16x2(1.0, 1.0),
        lo,
        hi,
        leaf_first,
        leaf_count,
    }
}

/// Every leaf turned every way (`s = 1`).
const SCATTERED: PlaneDiffuseRecord = PlaneDiffuseRecord { flat: 0, scattered: u16::MAX };

/// Every leaf across the plane, every way about its normal (`r = 1`).
const ACROSS: PlaneDiffuseRecord = PlaneDiffuseRecord { flat: 0, scattered: 0 };

/// A mixture of the three: `f = 0.5`, `s ≈ 0.3`, `r ≈ 0.2`.
const MIXED: PlaneDiffuseRecord = PlaneDiffuseRecord { flat: 0x8000, scattered: 0x4CCC };

/// `common`'s leaf cell and, in the block cell, three impostor planes sampling a 2×2 RGBA8 image:
/// a root `[1, +∞)` over leaves 0 and 1 facing `+z`, and one plane per leaf `[0, 1)` facing `−y`
/// and `+x`. `PLANE_DIFFUSE` holds `FLAT`, [`SCATTERED`] and [`MIXED`]. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("plane-diffuse-fixture");
    let (u, v, w) = ([0.2, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.2]);
    data.planes = vec![
        plane([0.5, 0.5, 0.5], u, v, 1.0, f32::INFINITY, 0),
        plane([0.3, 0.4, 0.5], u, w, 0.0, 1.0, 0),
        plane([0.7, 0.6, 0.5], v, w, 0.0, 1.0, 1),
    ];
    data.plane_diffuse = vec![PlaneDiffuseRecord::FLAT, SCATTERED, MIXED];
    data.cells[1] =
        CellRecord { bounds_min: [0.3, 0.4, 0.5], bounds_max: [0.7, 0.6, 0.5], planes: range(0, 3), ..data.cells[1] };
    common::grey_image(&mut data);
    data
}

#[test]
fn the_kind_is_numbered_named_and_sized_as_the_spec_says() {
    const { assert!(MINOR >= 10, "PLANE_DIFFUSE is format 1.10") };
    let kind = SectionKind::PLANE_DIFFUSE;
    assert_eq!(kind.0, 0x0066);
    assert_eq!(kind.name(), Some("PLANE_DIFFUSE"));
    assert_eq!(kind.to_string(), "PLANE_DIFFUSE");
    assert_eq!(kind.record_size(), Some(4));
    assert_eq!(size_of::<PlaneDiffuseRecord>(), 4);
    assert_eq!(kind.since_minor(), 10);
    assert!(SectionKind::KNOWN.contains(&kind));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    // Not an ambient-occlusion kind: 4-byte records, though one per plane as PLANE_AO is.
    assert!(AO_KINDS.iter().all(|&(k, _)| k != kind));
    // `flat` in bytes 0–1, `scattered` in bytes 2–3, little endian.
    let record = PlaneDiffuseRecord { flat: 0x1234, scattered: 0xABCD };
    assert_eq!(bytemuck::bytes_of(&record), &[0x34, 0x12, 0xCD, 0xAB]);
    assert_eq!(PlaneDiffuseRecord::FLAT, PlaneDiffuseRecord { flat: 65535, scattered: 0 });
}

#[test]
fn a_container_with_plane_diffuse_round_trips_as_format_1_10_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::default()] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!((c.header().major, c.header().minor), (1, 10), "{compression:?}");
        assert_eq!(c.plane_diffuse(), data.plane_diffuse.as_slice());
        assert_eq!(c.plane_diffuse().len(), c.planes().len());
        assert_eq!(c.section(SectionKind::PLANE_DIFFUSE).expect("present").entry.record_size, 4);
        assert_eq!(c.raw_bytes(SectionKind::PLANE_DIFFUSE), &[0xFF, 0xFF, 0, 0, 0, 0, 0xFF, 0xFF, 0, 0x80, 0xCC, 0x4C]);
        let report = verify(&c).expect("verifies");
        assert_eq!((report.planes, report.plane_diffuse, report.ao), (3, 3, 0));
        let text = report.to_string();
        assert!(text.contains("planes' diffuse response: 3 records"), "{text}");
        assert_reads_back(&c, &data, &bytes, compression);
    }
    // Any shares that sum to at most 1 verify.
    for (flat, scattered) in [(0, 0), (u16::MAX, 0), (0, u16::MAX), (1, 2), (40_000, 25_535)] {
        let mut data = fixture();
        data.plane_diffuse[2] = PlaneDiffuseRecord { flat, scattered };
        let bytes = data.to_bytes(Compression::None).expect("writes");
        verify(&Container::from_bytes(&bytes).expect("opens")).expect("verifies");
    }
}

#[test]
fn shares_that_sum_past_one_open_but_do_not_verify() {
    for (flat, scattered) in [(40_000, 25_536), (u16::MAX, 1), (u16::MAX, u16::MAX), (1, u16::MAX)] {
        let mut data = fixture();
        data.plane_diffuse[1] = PlaneDiffuseRecord { flat, scattered };
        let bytes = data.to_bytes(Compression::None).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens: verify checks the shares");
        let err = verify(&c).expect_err("the shares sum past 1");
        match &err {
            Error::BadRecord { kind, index, reason } => {
                assert_eq!((*kind, *index), (SectionKind::PLANE_DIFFUSE, 1), "{err}");
                assert!(reason.contains(&format!("flat {flat} + scattered {scattered}")), "{err}");
            }
            other => panic!("({flat}, {scattered}): expected BadRecord, got {other:?}"),
        }
        assert!(err.to_string().starts_with("PLANE_DIFFUSE record 1: "), "{err}");
        assert_eq!(err.class(), ErrorClass::Invalid);
        // A reader clamps them: `s` to `1 − f`.
        let (f, s, r) = c.plane_diffuse()[1].shares();
        assert!((f + s + r - 1.0).abs() <= 1e-6 && r == 0.0, "({flat}, {scattered}): {f} {s} {r}");
        assert_eq!(f, f32::from(flat) / 65535.0);
    }
}

#[test]
fn a_file_without_plane_diffuse_keeps_its_smaller_minor() {
    // Without the section: the planes' file of 1.0, read as FLAT planes (no records), as a 1.9
    // reader sees a 1.10 file.
    let older = ContainerData { plane_diffuse: Vec::new(), ..fixture() };
    let bytes = older.to_bytes(Compression::None).expect("writes");
    let c = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(c.header().minor, 0);
    assert!(c.plane_diffuse().is_empty());
    assert!(c.section(SectionKind::PLANE_DIFFUSE).is_none(), "no empty section is written");
    let report = verify(&c).expect("verifies");
    assert_eq!(report.plane_diffuse, 0);
    assert!(!report.to_string().contains("diffuse"), "{report}");

    // With the planes' occlusion: 1.2, and 1.10 once the diffuse records join it.
    let with_ao = ContainerData { plane_ao: vec![1, 2, 3], ..older.clone() };
    let c = Container::from_bytes(&with_ao.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 2);
    let both = ContainerData { plane_diffuse: fixture().plane_diffuse, ..with_ao };
    let c = Container::from_bytes(&both.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 10);

    // With far lines (1.9): 1.9 without the diffuse records, 1.10 with them.
    let line = common::branch_line([0.3, 0.3, 0.5], [0.7, 0.6, 0.5]);
    let mut lines = ContainerData { lines: vec![line], far_lines: vec![line], ..older };
    lines.cells[1] = CellRecord { bounds_min: [0.3, 0.3, 0.5], lines: range(0, 1), ..lines.cells[1] };
    let c = Container::from_bytes(&lines.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 9);
    verify(&c).expect("verifies");
    let both = ContainerData { plane_diffuse: fixture().plane_diffuse, ..lines };
    let c = Container::from_bytes(&both.to_bytes(Compression::None).expect("writes")).expect("opens");
    assert_eq!(c.header().minor, 10);
    verify(&c).expect("verifies");
}

#[test]
fn the_writer_refuses_another_count_than_planes() {
    for wrong in [1usize, 2, 4, 9] {
        let mut data = fixture();
        data.plane_diffuse.resize(wrong, SCATTERED);
        for compression in [Compression::None, Compression::default()] {
            match data.to_bytes(compression) {
                Err(Error::Write(message)) => {
                    assert!(message.contains("PLANE_DIFFUSE"), "{wrong}: {message}");
                    assert!(message.contains(&format!("{wrong} records, PLANES has 3")), "{wrong}: {message}");
                }
                other => panic!("PLANE_DIFFUSE of {wrong}: expected Error::Write, got {other:?}"),
            }
        }
    }
    // Diffuse records without planes are refused too.
    let data = ContainerData { planes: Vec::new(), ..fixture() };
    let data =
        ContainerData { cells: data.cells.iter().map(|c| CellRecord { planes: range(0, 0), ..*c }).collect(), ..data };
    match data.to_bytes(Compression::None) {
        Err(Error::Write(message)) => {
            assert!(message.contains("PLANE_DIFFUSE") && message.contains("PLANES has 0"), "{message}")
        }
        other => panic!("expected Error::Write, got {other:?}"),
    }
}

#[test]
fn a_file_whose_plane_diffuse_is_shorter_or_longer_than_planes_is_refused_at_open() {
    let bytes = fixture().to_bytes(Compression::None).expect("writes");
    Container::from_bytes(&resize_section(&bytes, SectionKind::PLANE_DIFFUSE, 0)).expect("the untouched file opens");
    for (delta, needle) in
        [(-8, "1 records, PLANES has 3"), (-4, "2 records, PLANES has 3"), (4, "4 records, PLANES has 3")]
    {
        let edited = resize_section(&bytes, SectionKind::PLANE_DIFFUSE, delta);
        let err = match Container::from_bytes(&edited) {
            Ok(c) => panic!("{delta:+}: opened with {} diffuse records", c.plane_diffuse().len()),
            Err(err) => err,
        };
        match &err {
            Error::BadRecord { kind, reason, .. } => {
                assert_eq!(*kind, SectionKind::PLANE_DIFFUSE, "{err}");
                assert!(reason.contains(needle), "{delta:+}: {err}");
            }
            other => panic!("{delta:+}: expected BadRecord, got {other:?}"),
        }
        assert!(err.to_string().starts_with("PLANE_DIFFUSE"), "the message names the kind: {err}");
        assert_eq!(err.class(), ErrorClass::Invalid);
    }
    // A length that is not a whole number of records is refused as well.
    let edited = resize_section(&bytes, SectionKind::PLANE_DIFFUSE, -2);
    let err = Container::from_bytes(&edited).expect_err("a partial record");
    assert_eq!(err.class(), ErrorClass::Invalid, "{err}");
    assert!(err.to_string().contains("PLANE_DIFFUSE"), "{err}");
    // A zero-length section is the same as an absent one: FLAT planes.
    let emptied = resize_section(&bytes, SectionKind::PLANE_DIFFUSE, -12);
    let c = Container::from_bytes(&emptied).expect("an empty PLANE_DIFFUSE section opens");
    assert!(c.plane_diffuse().is_empty() && c.planes().len() == 3);
}

/// `a·b`.
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `v` scaled to unit length.
fn unit(v: [f32; 3]) -> [f32; 3] {
    let n = dot(v, v).sqrt();
    v.map(|x| x / n)
}

/// Normals spread evenly over the sphere: a Fibonacci lattice of `n` points.
fn sphere(n: usize) -> Vec<[f32; 3]> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let (s, phi) = ((1.0 - z * z).sqrt(), golden * i as f64);
            [(s * phi.cos()) as f32, (s * phi.sin()) as f32, z as f32]
        })
        .collect()
}

/// Normals spread evenly about `+z`, at right angles to it: `n` points on the equator.
fn circle(n: usize) -> Vec<[f32; 3]> {
    (0..n)
        .map(|i| {
            let t = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
            [t.cos() as f32, t.sin() as f32, 0.0]
        })
        .collect()
}

/// The sums `(Σ w·|n·v||n·l|, Σ w·|n·v|)` over `normals`, each of weight `w = share / count`.
fn sums(normals: &[[f32; 3]], share: f32, v: [f32; 3], l: [f32; 3]) -> (f64, f64) {
    let w = f64::from(share) / normals.len() as f64;
    normals.iter().fold((0.0, 0.0), |(num, den), &n| {
        let (nv, nl) = (f64::from(dot(n, v).abs()), f64::from(dot(n, l).abs()));
        (num + w * nv * nl, den + w * nv)
    })
}

/// Directions of view and light, none at right angles to `+z` nor along it.
const DIRECTIONS: [[f32; 3]; 6] =
    [[0.3, 0.2, 0.9], [-0.8, 0.1, 0.5], [0.1, -0.9, -0.4], [0.6, 0.6, 0.2], [-0.2, -0.3, -0.9], [0.7, -0.1, 0.3]];

#[test]
fn flat_planes_take_the_sun_by_their_own_normal() {
    let normal = [0.0, 0.0, 1.0];
    for v in DIRECTIONS.map(unit) {
        for l in DIRECTIONS.map(unit) {
            let d = PlaneDiffuseRecord::FLAT.diffuse(normal, v, l);
            assert!((d - dot(normal, l).abs()).abs() <= 1e-6, "v {v:?}, l {l:?}: {d}");
            // The sign of the view does not matter.
            assert_eq!(d, PlaneDiffuseRecord::FLAT.diffuse(normal, v.map(|x| -x), l));
        }
        // Seen edge-on too (the area it shows vanishes): still its own |N·l|.
        let edge_on = unit([v[0], v[1], 0.0]);
        let d = PlaneDiffuseRecord::FLAT.diffuse(normal, edge_on, unit([0.3, 0.2, 0.9]));
        assert!((d - unit([0.3, 0.2, 0.9])[2]).abs() <= 1e-6, "{d}");
    }
    assert_eq!(PlaneDiffuseRecord::FLAT.shares(), (1.0, 0.0, 0.0));
    assert_eq!(ACROSS.shares(), (0.0, 0.0, 1.0));
    assert_eq!(SCATTERED.shares(), (0.0, 1.0, 0.0));
    assert_eq!(PlaneDiffuseRecord::default(), ACROSS);
}

#[test]
fn leaves_turned_every_way_take_the_sun_alike_from_any_plane() {
    // Lit from where it is seen: E[(n·l)²] / E|n·l| = (1/3) / (1/2) = 2/3; at right angles, 4/(3π).
    for normal in [[0.0, 0.0, 1.0], unit([0.3, -0.5, 0.8]), [1.0, 0.0, 0.0]] {
        for l in DIRECTIONS.map(unit) {
            let along = SCATTERED.diffuse(normal, l, l);
            assert!((along - 2.0 / 3.0).abs() <= 1e-5, "{along}");
            let across = SCATTERED.diffuse(normal, unit([l[1], -l[0], 0.0]), unit([l[0], l[1], 0.0]));
            assert!((across - 4.0 / (3.0 * std::f32::consts::PI)).abs() <= 1e-5, "{across}");
        }
    }
}

#[test]
fn diffuse_is_the_area_weighted_mean_of_the_mixture_it_describes() {
    // Each way of the three sampled apart, then mixed by the record's shares: the leaves' mean
    // |n·l| weighted by the area each shows, |n·v| (spec §6.10.2), against the closed form.
    let normal = [0.0, 0.0, 1.0];
    let (flat, spread, ring) = (vec![normal], sphere(20_000), circle(20_000));
    for record in
        [PlaneDiffuseRecord::FLAT, SCATTERED, ACROSS, MIXED, PlaneDiffuseRecord { flat: 0x2000, scattered: 0x9000 }]
    {
        let (f, s, r) = record.shares();
        for v in DIRECTIONS.map(unit) {
            for l in DIRECTIONS.map(unit) {
                let parts = [sums(&flat, f, v, l), sums(&spread, s, v, l), sums(&ring, r, v, l)];
                let (num, den) = parts.iter().fold((0.0, 0.0), |(a, b), &(n, d)| (a + n, b + d));
                let expected = (num / den) as f32;
                let d = record.diffuse(normal, v, l);
                assert!((d - expected).abs() <= 2e-3, "{record:?}, v {v:?}, l {l:?}: {d} against {expected}");
            }
        }
    }
}
