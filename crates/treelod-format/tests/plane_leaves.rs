//! Indirect texturing in the container (spec §6.10.1): the `PLANE_LEAVES` kind and `LEAF_SLOTS`
//! images round-trip and make a file 1.3; `verify` checks the section's length, its records, the
//! images' format rules and every slot of each indirectly textured plane's rectangle.

mod common;

use treelod_format::{
    CellRecord, Compression, Container, ContainerData, Error, ImageRecord, MINOR, MaterialInfo, MaterialRecord,
    NO_IMAGE, PlaneLeafRecord, PlaneRecord, Range, SectionKind, SplitMix64, image_format, leaf_slots, pack,
    plane_leaf_bases, verify,
};

const INF: f32 = f32::INFINITY;

/// Texels across and down the fixture's `LEAF_SLOTS` image: 15 and 5 divide 65535, so texel
/// edges are exact `unorm16` values (`k · 4369` across, `k · 13107` down).
const W: u32 = 15;
const H: u32 = 5;

fn range(first: u32, count: u32) -> Range {
    Range { first, count }
}

/// The `unorm16x2` of the texel corner `(x, y)` of the fixture's slot image, exactly.
fn corner(x: u32, y: u32) -> u32 {
    (x * (65_535 / W)) | ((y * (65_535 / H)) << 16)
}

fn plane(leaf_first: u32, leaf_count: u32, lo: f32, hi: f32, texels: [u32; 2]) -> PlaneRecord {
    PlaneRecord {
        center: [0.5, 0.5, 0.5],
        axis_u: [0.25, 0.0, 0.0],
        axis_v: [0.0, 0.25, 0.0],
        image: 1,
        // Texel columns texels[0] ..= texels[1], rows 1 ..= 3.
        uv_min: corner(texels[0], 1),
        uv_max: corner(texels[1] + 1, 4),
        lo,
        hi,
        leaf_first,
        leaf_count,
    }
}

fn leaf(material: u32, k: f32) -> PlaneLeafRecord {
    PlaneLeafRecord {
        uv0: [0.5, 0.5 + k],
        du: [0.5, 0.0],
        dv: [0.0, -0.5],
        uv_min: pack::unorm16x2(0.0, 0.0),
        uv_max: pack::unorm16x2(1.0, 1.0),
        material,
        color: 0xFF80_C0FF,
    }
}

/// The slots of texel `(x, y)` of the fixture's slot image, as stored.
fn set_slots(data: &mut ContainerData, x: u32, y: u32, a: u16, b: u16) {
    let image = data.images[1];
    let at = image.data_offset as usize + ((y * W + x) * 4) as usize;
    data.image_data[at..at + 2].copy_from_slice(&a.to_le_bytes());
    data.image_data[at + 2..at + 4].copy_from_slice(&b.to_le_bytes());
}

/// One 1×1×1 cell holding one triangle under its leaf point; the block cell holds two leaves'
/// impostor planes under a root plane, textured indirectly from a 15×5 `LEAF_SLOTS` image: the
/// root's rectangle is texels 1..=3 × 1..=3, its children's 6..=8 and 11..=13 (each with empty
/// texels around it), slots naming the planes' leaves; `PLANE_LEAVES` holds 2 + 1 + 1 records
/// over two materials. Image 0 is a 2×2 RGBA8 texture of material 1. Verifies.
fn fixture() -> ContainerData {
    let mut data = common::one_leaf_cell("indirect-fixture");
    data.planes = vec![plane(0, 2, 1.0, INF, [1, 3]), plane(0, 1, 0.0, 1.0, [6, 8]), plane(1, 1, 0.0, 1.0, [11, 13])];
    data.plane_leaves = vec![leaf(0, 0.0), leaf(1, 0.1), leaf(1, 0.2), leaf(0, 0.3)];
    data.cells[1] = CellRecord { bounds_min: [0.5; 3], bounds_max: [0.5; 3], planes: range(0, 3), ..data.cells[1] };
    // Material 0 is bark (the cell's triangle's), material 1 the textured leaf the planes' leaves use.
    data.metadata.materials.insert(0, MaterialInfo { name: "bark".into(), classified_by: "name".into() });
    data.materials.insert(
        0,
        MaterialRecord {
            base_color: [0.4, 0.3, 0.2, 1.0],
            image: NO_IMAGE,
            alpha_mode: 0,
            alpha_cutoff: 0.5,
            class: 0,
            flags: 0,
            _pad: 0,
        },
    );
    data.materials[1].image = 0;
    data.materials[1].alpha_mode = 1;
    let slots_length = u64::from(W * H * 4);
    data.images = vec![
        ImageRecord {
            width: 2,
            height: 2,
            mip_count: 1,
            format: image_format::RGBA8_SRGB,
            data_offset: 0,
            data_length: 16,
        },
        ImageRecord {
            width: W,
            height: H,
            mip_count: 1,
            format: image_format::LEAF_SLOTS,
            data_offset: 16,
            data_length: slots_length,
        },
    ];
    data.image_data = vec![0x80; 16 + slots_length as usize];
    data.image_data[16..].fill(0);
    for y in 1..=3 {
        for x in 1..=3 {
            // The root: both leaves, in either order, some texels with one.
            let (a, b) = [(1, 2), (2, 1), (2, 0)][((x + y) % 3) as usize];
            set_slots(&mut data, x, y, a, b);
        }
        for x in 6..=8 {
            set_slots(&mut data, x, y, 1, 0);
        }
        set_slots(&mut data, 11, y, 1, 0);
        set_slots(&mut data, 13, y, 0, 0);
    }
    data
}

use common::{bytes_of, check};

/// Asserts a `BadRecord` of `kind` at `index` whose reason mentions every needle.
#[track_caller]
fn expect_record(data: &ContainerData, kind: SectionKind, index: usize, needles: &[&str]) {
    match check(data) {
        Err(Error::BadRecord { kind: k, index: i, reason })
            if k == kind && i == index && needles.iter().all(|n| reason.contains(n)) => {}
        other => panic!("expected BadRecord {kind} {index} ({needles:?}), got {other:?}"),
    }
}

// ----------------------------------------------------------------------------------------------
// The kind, the round trip and the version.

#[test]
fn the_kind_and_the_image_format_are_numbered_and_named_as_the_spec_says() {
    const { assert!(MINOR >= 3, "indirect texturing is format 1.3") };
    let kind = SectionKind::PLANE_LEAVES;
    assert_eq!((kind.0, kind.name(), kind.to_string().as_str()), (0x0031, Some("PLANE_LEAVES"), "PLANE_LEAVES"));
    assert_eq!(kind.record_size(), Some(size_of::<PlaneLeafRecord>() as u32));
    assert_eq!(kind.since_minor(), 3);
    assert!(SectionKind::KNOWN.contains(&kind));
    assert!(SectionKind::KNOWN.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(image_format::LEAF_SLOTS, 5);
    // Slots are two little-endian u16; bases are running sums of leaf_count, then the total.
    assert_eq!(leaf_slots([0x02, 0x01, 0xFF, 0x00]), (0x0102, 0x00FF));
    assert_eq!(plane_leaf_bases(&fixture().planes), [0, 2, 3, 4]);
    assert_eq!(plane_leaf_bases(&[]), [0]);
}

#[test]
fn the_fixture_round_trips_as_a_1_3_file_and_verifies() {
    let data = fixture();
    for compression in [Compression::None, Compression::Zstd { level: 19 }] {
        let bytes = data.to_bytes(compression).expect("writes");
        let c = Container::from_bytes(&bytes).expect("opens");
        assert_eq!(c.header().minor, 3, "PLANE_LEAVES is a kind of 1.3");
        assert_eq!(c.plane_leaves(), data.plane_leaves.as_slice());
        assert_eq!(c.images()[1].format, image_format::LEAF_SLOTS);
        assert_eq!(ContainerData::from_container(&c), data);
        let report = verify(&c).expect("valid");
        assert_eq!((report.plane_leaves, report.indirect_planes, report.planes), (4, 3, 3));
        assert!(report.to_string().contains("indirect texturing: 3 planes, 4 plane leaves"), "{report}");
    }
}

#[test]
fn the_minor_is_3_exactly_when_plane_leaves_are_present() {
    let minor = |data: &ContainerData| Container::from_bytes(&bytes_of(data)).expect("opens").header().minor;
    let mut data = fixture();
    assert_eq!(minor(&data), 3);
    data.plane_ao = vec![1, 2, 3];
    assert_eq!(minor(&data), 3, "1.3 whatever else of 1.2 it holds");
    // Without PLANE_LEAVES the minor is what the other kinds need; the LEAF_SLOTS image alone does
    // not raise it (it is not a kind; such a file fails verify, below).
    data.plane_leaves.clear();
    assert_eq!(minor(&data), 2);
    data.plane_ao.clear();
    assert_eq!(minor(&data), 0);
    // Directly textured planes with PLANE_LEAVES (unused records, spec §6.10.1): 1.3 and valid.
    let mut direct = fixture();
    for p in &mut direct.planes {
        p.image = 0;
    }
    assert_eq!(minor(&direct), 3);
    let report = check(&direct).expect("records of directly textured planes are unused, not invalid");
    assert_eq!((report.plane_leaves, report.indirect_planes), (4, 0));
    // The same planes without PLANE_LEAVES make the 1.0 file they always did.
    direct.plane_leaves.clear();
    assert_eq!(minor(&direct), 0);
    let report = check(&direct).expect("valid");
    assert_eq!((report.plane_leaves, report.indirect_planes), (0, 0));
    assert!(!report.to_string().contains("indirect"), "{report}");
}

// ----------------------------------------------------------------------------------------------
// Verify: PLANE_LEAVES.

#[test]
fn plane_leaves_of_the_wrong_length_are_refused_naming_both_lengths() {
    let mut short = fixture();
    short.plane_leaves.pop();
    expect_record(&short, SectionKind::PLANE_LEAVES, 0, &["PLANE_LEAVES", "3 records", "sum to 4"]);
    let mut long = fixture();
    long.plane_leaves.push(leaf(0, 0.0));
    expect_record(&long, SectionKind::PLANE_LEAVES, 0, &["5 records", "sum to 4"]);
    // A plane's leaf_count changes the length the section needs.
    let mut grown = fixture();
    grown.planes[2].leaf_count = 2;
    grown.planes[0].leaf_count = 3;
    expect_record(&grown, SectionKind::PLANE_LEAVES, 0, &["4 records", "sum to 6"]);
}

#[test]
fn a_leaf_slots_plane_needs_plane_leaves() {
    let mut data = fixture();
    data.plane_leaves.clear();
    expect_record(&data, SectionKind::PLANES, 0, &["LEAF_SLOTS", "PLANE_LEAVES is empty"]);
    // The first indirectly textured plane is named.
    data.planes[0].image = 0;
    expect_record(&data, SectionKind::PLANES, 1, &["image 1 is LEAF_SLOTS"]);
}

#[test]
fn plane_leaf_records_name_existing_materials_and_have_finite_maps() {
    let mut data = fixture();
    data.plane_leaves[2].material = 2;
    expect_record(&data, SectionKind::PLANE_LEAVES, 2, &["material 2", "2 materials", "leaf 0 of plane 1"]);
    data.plane_leaves[2].material = u32::MAX;
    expect_record(&data, SectionKind::PLANE_LEAVES, 2, &["material 4294967295"]);
    let mut data = fixture();
    data.plane_leaves[1].uv0[0] = f32::NAN;
    expect_record(&data, SectionKind::PLANE_LEAVES, 1, &["uv0", "leaf 1 of plane 0"]);
    let mut data = fixture();
    data.plane_leaves[3].uv0[1] = INF;
    expect_record(&data, SectionKind::PLANE_LEAVES, 3, &["uv0", "leaf 0 of plane 2"]);
    let mut data = fixture();
    data.plane_leaves[0].du[1] = -INF;
    expect_record(&data, SectionKind::PLANE_LEAVES, 0, &["du"]);
    let mut data = fixture();
    data.plane_leaves[0].dv[0] = f32::NAN;
    expect_record(&data, SectionKind::PLANE_LEAVES, 0, &["dv"]);
    let mut data = fixture();
    data.plane_leaves[3].uv_min = pack::unorm16x2(0.5, 0.0);
    data.plane_leaves[3].uv_max = pack::unorm16x2(0.25, 1.0);
    expect_record(&data, SectionKind::PLANE_LEAVES, 3, &["uv_min", "uv_max"]);
    // Colours may be any value, and a leaf's material may have no texture.
    let mut data = fixture();
    for (i, leaf) in data.plane_leaves.iter_mut().enumerate() {
        leaf.color = [0, u32::MAX, 0x1234_5678, 7][i];
        leaf.material = 0;
    }
    check(&data).expect("valid");
}

// ----------------------------------------------------------------------------------------------
// Verify: LEAF_SLOTS images.

#[test]
fn leaf_slots_images_have_one_level_of_four_bytes_per_texel() {
    let mut data = fixture();
    data.images[1].mip_count = 2;
    expect_record(&data, SectionKind::IMAGES, 1, &["mip_count 2", "LEAF_SLOTS"]);
    let mut data = fixture();
    data.images[1].mip_count = 0;
    expect_record(&data, SectionKind::IMAGES, 1, &["mip_count 0"]);
    let mut data = fixture();
    data.images[1].data_length -= 4;
    expect_record(&data, SectionKind::IMAGES, 1, &["data_length 296", "15x5 LEAF_SLOTS", "needs 300 bytes"]);
    let mut data = fixture();
    data.images[1].height = 4;
    expect_record(&data, SectionKind::IMAGES, 1, &["data_length 300", "15x4", "needs 240"]);
    let mut data = fixture();
    data.images[1].width = 0;
    expect_record(&data, SectionKind::IMAGES, 1, &["width 0"]);
    let mut data = fixture();
    data.images[1].height = 16_385;
    expect_record(&data, SectionKind::IMAGES, 1, &["height 16385"]);
    // Data longer than the texels need is refused as well.
    let mut data = fixture();
    data.images[1].data_length += 16;
    data.image_data.extend_from_slice(&[0; 16]);
    expect_record(&data, SectionKind::IMAGES, 1, &["data_length 316"]);
}

#[test]
fn every_slot_inside_a_planes_rectangle_is_at_most_its_leaf_count() {
    // Plane 1 (texels 6..=8, leaf_count 1): slot a = 2 at its last column.
    let mut data = fixture();
    set_slots(&mut data, 8, 2, 2, 0);
    expect_record(&data, SectionKind::PLANES, 1, &["texel (8, 2)", "slots (2, 0)", "leaf_count 1", "image 1"]);
    // Slot b counts as well.
    let mut data = fixture();
    set_slots(&mut data, 12, 3, 1, 2);
    expect_record(&data, SectionKind::PLANES, 2, &["texel (12, 3)", "slots (1, 2)", "leaf_count 1"]);
    // The root allows its two leaves, not a third.
    let mut data = fixture();
    set_slots(&mut data, 1, 1, 3, 0);
    expect_record(&data, SectionKind::PLANES, 0, &["texel (1, 1)", "leaf_count 2"]);
    let mut data = fixture();
    set_slots(&mut data, 3, 3, 0, u16::MAX);
    expect_record(&data, SectionKind::PLANES, 0, &["texel (3, 3)", "65535"]);
}

#[test]
fn texels_outside_every_rectangle_hold_anything() {
    // Texels that touch a rectangle only along its edge (the rectangles' corners are exact texel
    // corners here) are outside it: texel columns 0, 4, 5, 9, 10 and 14, rows 0 and 4.
    let mut data = fixture();
    for (x, y) in [(0, 2), (4, 1), (5, 2), (9, 3), (10, 1), (14, 2), (2, 0), (7, 4), (12, 0)] {
        set_slots(&mut data, x, y, 999, 999);
    }
    check(&data).expect("slots outside every rectangle are not checked");
    // A rectangle one unorm16 step wider reaches into the next texel column, and checks it.
    data.planes[1].uv_max += 1;
    expect_record(&data, SectionKind::PLANES, 1, &["texel (9, 3)", "slots (999, 999)"]);
}

#[test]
fn a_rectangle_of_no_area_checks_the_texel_it_lies_in() {
    let mut data = fixture();
    // Plane 2's rectangle shrunk to its top-left corner, the corner of texel (11, 1).
    data.planes[2].uv_max = data.planes[2].uv_min;
    check(&data).expect("texel (11, 1) holds leaf 1");
    set_slots(&mut data, 11, 1, 2, 0);
    expect_record(&data, SectionKind::PLANES, 2, &["texel (11, 1)"]);
    // On the image's far edge: the last texel.
    let mut data = fixture();
    data.planes[2].uv_min = u32::MAX;
    data.planes[2].uv_max = u32::MAX;
    set_slots(&mut data, 14, 4, 2, 0);
    expect_record(&data, SectionKind::PLANES, 2, &["texel (14, 4)"]);
}

#[test]
fn slots_of_images_that_planes_do_not_sample_indirectly_are_not_read() {
    // An image with huge slots that no plane samples, and an RGBA plane over the RGBA texture.
    let mut data = fixture();
    data.image_data[16..].fill(0xFF);
    for p in &mut data.planes {
        p.image = 0;
    }
    check(&data).expect("valid");
}

/// Uniform in `0..n` for the randomised comparison below.
fn below(rng: &mut SplitMix64, n: u32) -> u32 {
    u32::try_from(rng.below(u64::from(n))).expect("below a u32")
}

#[test]
fn the_slot_check_agrees_with_reading_every_texel_of_every_rectangle() {
    // Random images (up to 70×40, so the pyramid of 4×4 blocks has a few levels) and random
    // overlapping rectangles, each plane a root of its own leaves: verify's answer equals a
    // brute-force scan of every rectangle's texels (the texels whose area meets the rectangle).
    let mut rng = SplitMix64(0x5107_5107);
    let mut refused = 0;
    for case in 0..300 {
        let mut data = fixture();
        let (w, h) = (1 + below(&mut rng, 70), 1 + below(&mut rng, 40));
        let mut texels = vec![0u8; (w * h * 4) as usize];
        let high = 1 + below(&mut rng, 6);
        for t in texels.chunks_exact_mut(4) {
            // Mostly slots 0 and 1, which every plane allows; rarely one up to 6.
            let pick =
                |rng: &mut SplitMix64| (if below(rng, 400) == 0 { 1 + below(rng, high) } else { below(rng, 2) }) as u16;
            let (a, b) = (pick(&mut rng), pick(&mut rng));
            t.copy_from_slice(&[a.to_le_bytes(), b.to_le_bytes()].concat());
        }
        data.images[1] = ImageRecord {
            width: w,
            height: h,
            mip_count: 1,
            format: image_format::LEAF_SLOTS,
            data_offset: 16,
            data_length: u64::from(w * h * 4),
        };
        data.image_data.truncate(16);
        data.image_data.extend_from_slice(&texels);
        let count = 1 + below(&mut rng, 6);
        data.planes.clear();
        data.plane_leaves.clear();
        let mut first = 0;
        for _ in 0..count {
            let leaves = 1 + below(&mut rng, 4);
            let (u0, u1) = (below(&mut rng, 65_536), below(&mut rng, 65_536));
            let (v0, v1) = (below(&mut rng, 65_536), below(&mut rng, 65_536));
            let (u0, u1) = (u0.min(u1), u0.max(u1));
            let (v0, v1) = (v0.min(v1), v0.max(v1));
            data.planes.push(PlaneRecord {
                uv_min: u0 | (v0 << 16),
                uv_max: u1 | (v1 << 16),
                ..plane(first, leaves, 0.0, INF, [0, 0])
            });
            data.plane_leaves.extend((0..leaves).map(|_| leaf(1, 0.0)));
            first += leaves;
        }
        data.cells[1].planes = range(0, count);
        // Brute force: the first plane with a texel above its leaf_count.
        let span = |min: u32, max: u32, side: u32| {
            // floor(min·side/65535) ..= ceil(max·side/65535) − 1, at least one texel, in the image.
            let (lo, hi) = (u64::from(min) * u64::from(side), u64::from(max) * u64::from(side));
            let first = (lo / 65_535) as u32;
            let last = (hi.div_ceil(65_535) as u32).saturating_sub(1).max(first);
            first.min(side - 1)..=last.min(side - 1)
        };
        let slots_at = |x: u32, y: u32| {
            let at = ((y * w + x) * 4) as usize;
            leaf_slots([texels[at], texels[at + 1], texels[at + 2], texels[at + 3]])
        };
        let expected = data.planes.iter().position(|p| {
            span(p.uv_min >> 16, p.uv_max >> 16, h).any(|y| {
                span(p.uv_min & 0xFFFF, p.uv_max & 0xFFFF, w).any(|x| {
                    let (a, b) = slots_at(x, y);
                    u32::from(a.max(b)) > p.leaf_count
                })
            })
        });
        match (check(&data), expected) {
            (Ok(_), None) => {}
            (Err(Error::BadRecord { kind: SectionKind::PLANES, index, reason }), Some(p)) if index == p => {
                // The texel named is one of the plane's and holds a slot above its leaf_count.
                let plane = data.planes[p];
                let named: Vec<u32> = reason
                    .split_once("texel (")
                    .and_then(|(_, rest)| rest.split_once(')'))
                    .map(|(xy, _)| xy.split(", ").map(|v| v.parse().expect("a number")).collect())
                    .expect("a texel");
                let (x, y) = (named[0], named[1]);
                assert!(span(plane.uv_min & 0xFFFF, plane.uv_max & 0xFFFF, w).contains(&x), "case {case}: {reason}");
                assert!(span(plane.uv_min >> 16, plane.uv_max >> 16, h).contains(&y), "case {case}: {reason}");
                let (a, b) = slots_at(x, y);
                assert!(u32::from(a.max(b)) > plane.leaf_count, "case {case}: {reason}");
                refused += 1;
            }
            (other, expected) => panic!("case {case}: verify said {other:?}, expected a refusal of plane {expected:?}"),
        }
    }
    assert!((50..250).contains(&refused), "both outcomes are exercised ({refused} of 300 refused)");
}

#[cfg(feature = "images")]
#[test]
fn a_leaf_slots_image_does_not_decode_as_colour() {
    let data = fixture();
    let image = data.images[1];
    let bytes = &data.image_data[16..16 + image.data_length as usize];
    let err = treelod_format::image::decode(&image, bytes).expect_err("not a colour image");
    assert!(err.contains("LEAF_SLOTS") && err.contains("not a colour image"), "{err}");
    // The texture beside it still decodes.
    let texture = treelod_format::image::decode(&data.images[0], &data.image_data[..16]).expect("decodes");
    assert_eq!((texture.width, texture.height, texture.texels.len()), (2, 2, 16));
}

#[test]
fn a_material_naming_a_leaf_slots_image_is_refused() {
    let mut data = fixture();
    // Image 1 holds the planes' leaf slots: no colour for a material to sample.
    data.materials[1].image = 1;
    expect_record(&data, SectionKind::MATERIALS, 1, &["image 1", "LEAF_SLOTS", "not a colour image"]);
}
