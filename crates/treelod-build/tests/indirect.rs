//! Indirect texturing of impostor planes (spec §6.10.1) on a scene made in code: alpha-tested,
//! textured, two-sided leaf quads lying on three known planes, so every plane's affine maps are
//! exact and its leaf-slot image can be checked texel by texel; determinism across thread
//! counts, the fallback to the RGBA atlas for leaves whose outline is geometry, and setting
//! errors.

use glam::{Vec2, Vec3};
use treelod_build::scene::{AlphaMode, Image, ImageEncoding, Material, Part, Scene};
use treelod_build::{
    BuildConfig, BuildError, BuildOutput, ImpostorConfig, Placed, Texturing, build_block, cards_on_planes,
    leaf_material,
};
use treelod_format::{Compression, Container, PlaneRecord, SectionKind, image_format, material_class, pack};

/// A leaf texture: opaque inside a disc of radius 0.45 about the centre, transparent outside,
/// in two greens.
fn leaf_texture() -> Image {
    let size = 16u32;
    let mut rgba = Vec::with_capacity((size * size * 4) as usize);
    for y in 0..size {
        for x in 0..size {
            let p = Vec2::new((x as f32 + 0.5) / size as f32 - 0.5, (y as f32 + 0.5) / size as f32 - 0.5);
            let rgb = if (x / 4 + y / 4) % 2 == 0 { [60, 140, 40] } else { [120, 190, 60] };
            rgba.extend(rgb);
            rgba.push(if p.length() < 0.45 { 255 } else { 0 });
        }
    }
    Image { width: size, height: size, rgba, encoded: Vec::new(), encoding: ImageEncoding::Raw }
}

/// The three planes of [`scene`]: a point on each and its normal.
const PLANES: [(Vec3, Vec3); 3] =
    [(Vec3::new(0.0, 3.0, 0.0), Vec3::Z), (Vec3::new(6.0, 3.0, 3.0), Vec3::X), (Vec3::new(0.0, 8.0, 4.0), Vec3::Y)];

/// One leaf quad: its four corners and their texture coordinates.
struct Leaf {
    corners: [Vec3; 4],
    uvs: [[f32; 2]; 4],
}

/// 27 square leaves 0.2 m across, 9 on each of [`PLANES`] in a 3 × 3 grid 0.5 m apart (so
/// 0.3 m lie between neighbours), each turned in its plane by its own angle, every other one
/// facing the other way, and the texture coordinates of some turned by a quarter: their UVs
/// cover `[0, 1]²`.
fn leaves() -> Vec<Leaf> {
    cards_on_planes(&PLANES, 3, 0.5, 0.1, 0.35)
        .into_iter()
        .enumerate()
        .map(|(k, corners)| {
            let mut uvs = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
            if k % 3 == 0 {
                uvs.rotate_left(1);
            }
            Leaf { corners, uvs }
        })
        .collect()
}

/// The leaves of [`leaves`] as one part; with `colours`, each leaf's own vertex colour (so that
/// its `PlaneLeafRecord` can be told by it).
fn scene(material: Material, image: bool, colours: bool) -> Scene {
    let mut part = Part { mesh_name: "leaves".into(), material: 0, ..Part::default() };
    for (k, leaf) in leaves().iter().enumerate() {
        let base = part.positions.len() as u32;
        let normal = (leaf.corners[1] - leaf.corners[0]).cross(leaf.corners[2] - leaf.corners[0]).normalize();
        for (corner, uv) in leaf.corners.iter().zip(leaf.uvs) {
            part.positions.push(corner.to_array());
            part.normals.push(normal.to_array());
            part.uvs.push(uv);
            if colours {
                part.colors.push([0.3 + 0.025 * k as f32, 1.0, 0.9, 1.0]);
            }
        }
        part.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
    }
    Scene {
        name: "planes".into(),
        parts: vec![part],
        materials: vec![Material { image: image.then_some(0), ..material }],
        images: if image { vec![leaf_texture()] } else { Vec::new() },
        ..Scene::default()
    }
}

fn mask_leaves() -> Material {
    leaf_material()
}

/// One level of three planes: one per known plane.
fn indirect() -> BuildConfig {
    BuildConfig {
        impostors: Some(ImpostorConfig {
            levels: vec![3],
            texturing: Texturing::Indirect,
            ..ImpostorConfig::default()
        }),
        ..BuildConfig::default()
    }
}

fn build(scene: &Scene, config: &BuildConfig) -> BuildOutput {
    build_block("planes", &[Placed { scene, translation: Vec3::ZERO }], config, "t").expect("builds")
}

fn open(out: &BuildOutput) -> Container {
    Container::from_bytes(&out.data.to_bytes(Compression::default()).expect("writes")).expect("opens")
}

/// A point's plane coordinates `(s, t)`: `p = center + s·axis_u + t·axis_v` (spec §6.10).
fn plane_st(plane: &PlaneRecord, p: Vec3) -> Vec2 {
    let (u, v) = (Vec3::from_array(plane.axis_u), Vec3::from_array(plane.axis_v));
    let d = p - Vec3::from_array(plane.center);
    Vec2::new(d.dot(u) / u.length_squared(), d.dot(v) / v.length_squared())
}

/// Where `(s, t)` falls in a `width × height` image, in texels, through the plane's rectangle.
fn texel_xy(plane: &PlaneRecord, st: Vec2, width: u32, height: u32) -> Vec2 {
    let (lo, hi) = (Vec2::from(pack::unpack_unorm16x2(plane.uv_min)), Vec2::from(pack::unpack_unorm16x2(plane.uv_max)));
    (lo + (st + 1.0) * 0.5 * (hi - lo)) * Vec2::new(width as f32, height as f32)
}

#[test]
fn indirect_planes_map_each_leaf_onto_its_texture_and_name_it_in_the_slot_image() {
    let scene = scene(mask_leaves(), true, true);
    let out = build(&scene, &indirect());
    assert!(out.warnings.is_empty(), "{:?}", out.warnings);
    let c = open(&out);
    treelod_format::verify(&c).expect("verifies");
    // PLANE_LEAVES and LEAF_SLOTS are 1.3, the planes' diffuse response (PLANE_DIFFUSE) 1.10,
    // the points' facing (POINT_FACING) 1.14.
    assert_eq!(SectionKind::PLANE_LEAVES.since_minor(), 3);
    assert_eq!((c.header().major, c.header().minor), (1, 14), "POINT_FACING is 1.14");
    assert_eq!(c.plane_diffuse().len(), c.planes().len());
    let planes = c.planes();
    assert_eq!(planes.len(), 3);
    let total: u64 = planes.iter().map(|p| u64::from(p.leaf_count)).sum();
    assert_eq!((total, c.plane_leaves().len() as u64, out.stats.plane_leaves), (27, 27, 27));
    let setting = |key: &str| c.metadata().settings.iter().find(|s| s.key == key).map(|s| s.value.clone());
    assert_eq!(setting("impostors.texturing").as_deref(), Some("indirect"));

    // The slot image: the last image, format 5 with one level, every plane's.
    let index = c.images().len() - 1;
    let image = c.images()[index];
    assert_eq!((image.format, image.mip_count), (image_format::LEAF_SLOTS, 1));
    assert_eq!([image.width, image.height], out.stats.atlas);
    assert!(planes.iter().all(|p| p.image as usize == index));
    let data = &c.image_data()[image.data_offset as usize..][..image.data_length as usize];
    assert_eq!(data.len(), image.width as usize * image.height as usize * 4);
    let slots = |x: i64, y: i64| -> [u16; 2] {
        assert!((0..i64::from(image.width)).contains(&x) && (0..i64::from(image.height)).contains(&y));
        let o = (y as usize * image.width as usize + x as usize) * 4;
        [u16::from_le_bytes([data[o], data[o + 1]]), u16::from_le_bytes([data[o + 2], data[o + 3]])]
    };

    // Each leaf's vertices, told by their colour.
    let mut by_colour: std::collections::BTreeMap<u32, Vec<(Vec3, Vec2)>> = Default::default();
    for v in c.vertices() {
        by_colour.entry(v.color).or_default().push((Vec3::from_array(v.position), Vec2::from(v.uv)));
    }
    assert_eq!(by_colour.len(), 27, "each leaf its own colour");
    let leaf_material = c.materials().iter().position(|m| m.class == material_class::LEAF).expect("a leaf material");

    let bases = treelod_format::plane_leaf_bases(planes);
    let mut seen = std::collections::BTreeSet::new();
    let (mut worst, mut empty_texels, mut hits) = (0.0f32, 0usize, 0usize);
    let mut content = vec![false; image.width as usize * image.height as usize];
    for (p, plane) in planes.iter().enumerate() {
        // The clustering found the known plane: the plane's normal is one of them and its leaves'
        // vertices lie on it.
        let normal = Vec3::from_array(plane.axis_u).cross(Vec3::from_array(plane.axis_v)).normalize();
        assert!(PLANES.iter().any(|(_, n)| n.dot(normal).abs() > 0.9999), "plane {p}: normal {normal}");
        let records = &c.plane_leaves()[bases[p] as usize..][..plane.leaf_count as usize];
        let mut footprints = Vec::new();
        for (j, record) in records.iter().enumerate() {
            assert!(seen.insert(record.color), "plane {p} leaf {j}: one record per leaf");
            let vertices = by_colour.get(&record.color).unwrap_or_else(|| panic!("plane {p} leaf {j}: no leaf"));
            assert_eq!(record.material as usize, leaf_material);
            // UVs in [0, 1]²: the rectangle is the whole texture.
            assert_eq!((record.uv_min, record.uv_max), (0, u32::MAX), "plane {p} leaf {j}");
            // (a) The affine map takes each vertex's plane coordinates to its texture coordinates.
            let (uv0, du, dv) = (Vec2::from(record.uv0), Vec2::from(record.du), Vec2::from(record.dv));
            let mut centre = Vec3::ZERO;
            let (mut lo, mut hi) = (Vec2::INFINITY, Vec2::NEG_INFINITY);
            for &(position, uv) in vertices {
                assert!((position - Vec3::from_array(plane.center)).dot(normal).abs() < 1e-3, "on the plane");
                let st = plane_st(plane, position);
                let error = (uv0 + st.x * du + st.y * dv - uv).abs().max_element();
                worst = worst.max(error);
                assert!(error < 1e-3, "plane {p} leaf {j}: vertex at {st} maps {error} off its uv {uv}");
                centre += position / vertices.len() as f32;
                let xy = texel_xy(plane, st, image.width, image.height);
                (lo, hi) = (lo.min(xy), hi.max(xy));
            }
            footprints.push((lo, hi));
            // (b) The texel under the leaf's centre names it: slot j + 1 of the plane's run.
            let xy = texel_xy(plane, plane_st(plane, centre), image.width, image.height).floor();
            let pair = slots(xy.x as i64, xy.y as i64);
            assert_eq!(pair[0] as usize, j + 1, "plane {p} leaf {j}: texel {xy} holds {pair:?}");
            hits += 1;
        }
        // (c) Every slot of the plane's rectangle names one of its leaves or none; (b) a texel
        // clear of every leaf's footprint (by a quarter texel) names none.
        let (lo, hi) = (
            texel_xy(plane, Vec2::NEG_ONE, image.width, image.height),
            texel_xy(plane, Vec2::ONE, image.width, image.height),
        );
        for y in lo.y.round() as i64..hi.y.round() as i64 {
            for x in lo.x.round() as i64..hi.x.round() as i64 {
                content[y as usize * image.width as usize + x as usize] = true;
                let pair = slots(x, y);
                assert!(pair.iter().all(|&k| u32::from(k) <= plane.leaf_count), "plane {p} texel ({x}, {y}): {pair:?}");
                let (a, b) = (Vec2::new(x as f32, y as f32), Vec2::new(x as f32 + 1.0, y as f32 + 1.0));
                let clear = footprints
                    .iter()
                    .all(|&(l, h)| b.x < l.x - 0.25 || a.x > h.x + 0.25 || b.y < l.y - 0.25 || a.y > h.y + 0.25);
                if clear {
                    assert_eq!(pair, [0, 0], "plane {p} texel ({x}, {y}) lies off every leaf");
                    empty_texels += 1;
                }
            }
        }
    }
    assert_eq!((seen.len(), hits), (27, 27));
    // Borders and space between regions name no leaf.
    for y in 0..image.height {
        for x in 0..image.width {
            if !content[(y * image.width + x) as usize] {
                assert_eq!(slots(i64::from(x), i64::from(y)), [0, 0], "texel ({x}, {y}) outside every plane");
            }
        }
    }
    eprintln!(
        "slot image {}x{}; worst uv error {worst:.2e}; {empty_texels} texels off every leaf name none",
        image.width, image.height
    );
    assert!(empty_texels > 20, "the leaves leave gaps: {empty_texels} clear texels");
}

#[test]
fn an_indirect_build_does_not_depend_on_the_thread_count() {
    let scene = scene(mask_leaves(), true, false);
    let bytes_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| build(&scene, &indirect()).data.to_bytes(Compression::default()).expect("writes"))
    };
    let one = bytes_with(1);
    assert_eq!(one, bytes_with(4));
    assert!(!Container::from_bytes(&one).expect("opens").plane_leaves().is_empty());
}

#[test]
fn leaves_whose_outline_is_geometry_get_the_rgba_atlas_and_a_warning() {
    let opaque = Material { name: "opaque-leaves".into(), alpha_mode: AlphaMode::Opaque, ..mask_leaves() };
    let plain = Material { name: "plain-leaves".into(), ..mask_leaves() };
    for (scene, name) in [(scene(opaque, true, false), "opaque-leaves"), (scene(plain, false, false), "plain-leaves")] {
        // RGBA8 atlases, so that the file is of the minor of its kinds (BC7 would make it 1.6).
        let out = build(&scene, &BuildConfig { atlas_format: treelod_build::AtlasFormat::Rgba8, ..indirect() });
        let note: Vec<&String> = out.warnings.iter().filter(|w| w.contains("indirect")).collect();
        assert_eq!(note.len(), 1, "{:?}", out.warnings);
        assert!(note[0].contains(&format!("'{name}'")) && note[0].contains("RGBA atlas"), "{}", note[0]);
        let c = open(&out);
        treelod_format::verify(&c).expect("verifies");
        assert!(c.plane_leaves().is_empty() && out.stats.plane_leaves == 0, "{name}");
        let atlas = c.images().last().expect("an atlas");
        assert_eq!((atlas.format, atlas.mip_count), (image_format::RGBA8_SRGB, 5), "{name}");
        assert!(c.planes().iter().all(|p| p.image as usize == c.images().len() - 1));
        // Nothing of 1.3 (no leaf-slot image); the planes' diffuse response is 1.10, and the
        // points' facing (POINT_FACING, which every build writes) makes the file 1.14.
        assert!(c.images().iter().all(|i| i.format != image_format::LEAF_SLOTS), "{name}");
        assert_eq!(SectionKind::PLANE_DIFFUSE.since_minor(), 10);
        assert_eq!(c.header().minor, 14, "{name}: POINT_FACING is 1.14");
    }
}

#[test]
fn slots_per_leaf_out_of_range_is_a_setting_error() {
    let scene = scene(mask_leaves(), true, false);
    for bad in [0.0, -1.0, 64.5, f32::NAN, f32::INFINITY] {
        let config = BuildConfig {
            impostors: Some(ImpostorConfig {
                texturing: Texturing::Indirect,
                slots_per_leaf: bad,
                ..ImpostorConfig::default()
            }),
            ..BuildConfig::default()
        };
        let err = build_block("x", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").unwrap_err();
        assert!(matches!(err, BuildError::Setting(_)), "{bad}: {err}");
        assert!(err.to_string().contains("slots per leaf"), "{err}");
    }
}
