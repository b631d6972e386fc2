//! Precomputed ambient occlusion (spec §6.14) on the Vulkan backend (Mesa lavapipe in CI): a leaf
//! quad inside a closed opaque box is fully occluded and the box's outer faces are open, in the
//! container's `VERTEX_AO` and `POINT_AO` (and `PLANE_AO`, `ELLIPSOID_AO` when built with
//! those); lit by ambient light alone and seen from inside the box, the quad is black with
//! `Settings::ambient_occlusion` and its albedo without, drawn as triangles, as points selected on
//! the CPU and on the GPU, as an impostor plane and as Clasen's ellipsoid, while the box's walls
//! keep their albedo either way. Reserved `flags` of points and ellipsoids are never read as
//! occlusion.

mod common;

use std::sync::Arc;

use common::{gpu, keep, one_tree, settled};
use glam::{Vec3, vec3};
use treelod_build::scene::{AlphaMode, Material, Part, Scene};
use treelod_build::{AoConfig, BuildConfig, EllipsoidConfig, ImpostorConfig, Placed, build_block};
use treelod_format::{Compression, Container, ContainerData, SectionKind, material_class};
use treelod_render::Primitive;
use treelod_render::offscreen::Image;
use treelod_render::{Camera, Settings, Technique};

/// Half the box's side, metres.
const BOX: f32 = 1.0;
/// Half the quad's side, metres.
const QUAD: f32 = 0.15;
/// Linear albedos of the quad (a leaf) and the box (bark).
const LEAF: [f32; 3] = [0.2, 0.6, 0.1];
const BARK: [f32; 3] = [0.4, 0.3, 0.2];
/// The image's side, pixels.
const SIZE: u32 = 64;

/// A closed box of half-side [`BOX`] about the origin (bark, single-sided, normals outwards,
/// counter-clockwise seen from outside) and inside it a two-sided leaf quad of half-side [`QUAD`]
/// at the origin, facing +z.
fn boxed_quad() -> Scene {
    let mut walls = Part { mesh_name: "bark box".into(), material: 1, ..Part::default() };
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let n = Vec3::from_array(std::array::from_fn(|i| if i == axis { sign } else { 0.0 }));
            let (t, b) = n.any_orthonormal_pair();
            let first = walls.positions.len() as u32;
            for (s, r) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                walls.positions.push((BOX * (n + s * t + r * b)).to_array());
                walls.normals.push(n.to_array());
            }
            // (t, b, n) is right-handed, so t then b turns counter-clockwise about n.
            assert!((t.cross(b) - n).length() < 1e-5);
            walls.triangles.extend([[first, first + 1, first + 2], [first, first + 2, first + 3]]);
        }
    }
    let mut quad = Part { mesh_name: "leaves".into(), material: 0, ..Part::default() };
    for (x, y) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        quad.positions.push([QUAD * x, QUAD * y, 0.0]);
        quad.normals.push([0.0, 0.0, 1.0]);
    }
    quad.triangles.extend([[0, 1, 2], [0, 2, 3]]);
    let [r, g, b] = LEAF;
    let [br, bg, bb] = BARK;
    Scene {
        name: "boxed-quad".into(),
        parts: vec![quad, walls],
        materials: vec![
            Material {
                name: "leaves".into(),
                base_color: [r, g, b, 1.0],
                alpha_mode: AlphaMode::Opaque,
                double_sided: true,
                ..Material::default()
            },
            Material { name: "bark".into(), base_color: [br, bg, bb, 1.0], ..Material::default() },
        ],
        ..Scene::default()
    }
}

/// The scene built with ambient occlusion (16 rays per vertex, the tools' default).
fn built() -> ContainerData {
    built_with(&BuildConfig { ao: Some(AoConfig::default()), ..BuildConfig::default() })
}

/// The scene built with `config`.
fn built_with(config: &BuildConfig) -> ContainerData {
    let scene = boxed_quad();
    let out = build_block("boxed-quad", &[Placed { scene: &scene, translation: Vec3::ZERO }], config, "test")
        .expect("builds");
    assert_eq!((out.stats.leaf_triangles, out.stats.bark_triangles), (2, 12));
    out.data
}

/// The scene built with ambient occlusion and impostor planes (a fine atlas: the quad is 0.3 m).
fn built_with_planes() -> ContainerData {
    built_with(&BuildConfig {
        ao: Some(AoConfig::default()),
        impostors: Some(ImpostorConfig { texels_per_metre: 256.0, ..ImpostorConfig::default() }),
        ..BuildConfig::default()
    })
}

/// The scene built with ambient occlusion and leaf ellipsoids; their noise holes are closed
/// (`alpha_threshold` 0), so the quad's ellipsoid covers the image's centre alone.
fn built_with_ellipsoids() -> ContainerData {
    let mut data = built_with(&BuildConfig {
        ao: Some(AoConfig::default()),
        ellipsoids: Some(EllipsoidConfig::default()),
        ..BuildConfig::default()
    });
    for e in &mut data.ellipsoids {
        e.alpha_threshold = 0.0;
    }
    data
}

fn open(data: &ContainerData) -> Arc<Container> {
    Arc::new(Container::from_bytes(&data.to_bytes(Compression::None).expect("encodes")).expect("opens"))
}

/// Whether each triangle of `container` is a leaf (the quad) rather than bark (the box).
fn is_leaf(container: &Container, t: &treelod_format::TriangleRecord) -> bool {
    container.materials()[t.material as usize].class == material_class::LEAF
}

/// For each point of `container`: `Some(true)` if all its leaves are the quad's triangles,
/// `Some(false)` if all are the box's, `None` if mixed.
fn point_classes(container: &Container) -> Vec<Option<bool>> {
    let mut classes = vec![None; container.points().len()];
    for cell in container.cells() {
        let triangles = &container.triangles()[cell.triangles.as_usize()];
        let mut leaf_of = vec![false; triangles.len()];
        for t in triangles {
            leaf_of[t.leaf as usize] = is_leaf(container, t);
        }
        for i in cell.points.as_usize() {
            let p = container.points()[i];
            let leaves = &leaf_of[p.leaf_first as usize..(p.leaf_first + p.leaf_count) as usize];
            classes[i] = if leaves.iter().all(|&l| l) {
                Some(true)
            } else if leaves.iter().all(|&l| !l) {
                Some(false)
            } else {
                None
            };
        }
    }
    classes
}

#[test]
fn a_quad_inside_a_closed_box_is_fully_occluded_in_the_container() {
    let data = built();
    let container = open(&data);
    treelod_format::verify(&container).expect("verifies");
    // The ambient-occlusion kinds are of 1.2; the points' facing (POINT_FACING, which every build
    // writes) makes the file 1.14.
    assert_eq!(SectionKind::POINT_AO.since_minor(), 2);
    assert_eq!(container.header().minor, 14, "a built container is format 1.14");
    let (vertex_ao, point_ao) = (container.vertex_ao(), container.point_ao());
    assert_eq!(vertex_ao.len(), container.vertices().len());
    assert_eq!(point_ao.len(), container.points().len());
    assert!(container.plane_ao().is_empty(), "no impostors, no plane occlusion");
    let settings = &container.metadata().settings;
    let setting = |key: &str| settings.iter().find(|s| s.key == key).map(|s| s.value.as_str());
    assert_eq!((setting("ao.rays"), setting("ao.seed")), (Some("16"), Some("0")));

    // Per vertex: every ray from the quad (both faces) ends on a wall, every ray from a wall's
    // outer face leaves the block.
    let (mut quad, mut walls) = (Vec::new(), Vec::new());
    for t in container.triangles() {
        let target = if is_leaf(&container, t) { &mut quad } else { &mut walls };
        target.extend(t.indices.iter().map(|&v| (v, vertex_ao[v as usize])));
    }
    quad.sort_unstable();
    quad.dedup();
    walls.sort_unstable();
    walls.dedup();
    eprintln!("quad vertices (index, AO): {quad:?}");
    eprintln!("wall vertices' AO: {:?}", walls.iter().map(|w| w.1).collect::<Vec<_>>());
    assert!(quad.len() >= 4 && walls.len() >= 24, "{} quad and {} wall vertices", quad.len(), walls.len());
    for &(v, ao) in &quad {
        let p = container.vertices()[v as usize].position;
        assert!(p.iter().all(|c| c.abs() <= QUAD + 1e-3), "a quad vertex at {p:?}");
        assert_eq!(ao, 255, "quad vertex {v} at {p:?} is fully occluded");
    }
    for &(v, ao) in &walls {
        assert_eq!(ao, 0, "wall vertex {v} at {:?} sees only sky", container.vertices()[v as usize].position);
    }

    // Per point: the mean of its leaves', so the quad's points are occluded and the walls' open.
    let classes = point_classes(&container);
    let mut counts = [0usize; 3];
    for (i, (class, &ao)) in classes.iter().zip(point_ao).enumerate() {
        match class {
            Some(true) => {
                counts[0] += 1;
                assert_eq!(ao, 255, "quad point {i} at {:?}", container.points()[i].position);
            }
            Some(false) => {
                counts[1] += 1;
                assert_eq!(ao, 0, "wall point {i} at {:?}", container.points()[i].position);
            }
            None => counts[2] += 1,
        }
    }
    eprintln!("points: {} of the quad, {} of the walls, {} mixed", counts[0], counts[1], counts[2]);
    assert!(counts[0] >= 2, "the quad's two triangles have leaf points");
    assert_eq!(counts[2], 0, "the quad shares no cell with the walls: {counts:?}");

    // With impostors: the quad's planes are the mean of its triangles', fully occluded.
    let planes = open(&built_with_planes());
    eprintln!("planes: {}, their AO {:?}", planes.planes().len(), planes.plane_ao());
    assert!(!planes.planes().is_empty());
    assert_eq!(planes.plane_ao().len(), planes.planes().len());
    assert!(planes.plane_ao().iter().all(|&a| a == 255), "{:?}", planes.plane_ao());

    // With ellipsoids: the quad's (the only leaf) is the mean of its triangles', fully occluded;
    // the records' own reserved flags stay 0.
    let ellipsoids = open(&built_with_ellipsoids());
    eprintln!("ellipsoids: {}, their AO {:?}", ellipsoids.ellipsoids().len(), ellipsoids.ellipsoid_ao());
    assert!(!ellipsoids.ellipsoids().is_empty());
    assert_eq!(ellipsoids.header().minor, 14, "ELLIPSOID_AO is of 1.3, POINT_FACING of 1.14");
    assert_eq!(ellipsoids.ellipsoid_ao().len(), ellipsoids.ellipsoids().len());
    assert!(ellipsoids.ellipsoid_ao().iter().all(|&a| a == 255), "{:?}", ellipsoids.ellipsoid_ao());
    assert!(ellipsoids.ellipsoids().iter().all(|e| e.flags == 0));

    // Built without ambient occlusion: no sections, nothing of 1.2 to 1.13 (the points' facing,
    // which every build writes, is of 1.14).
    let scene = boxed_quad();
    let out = build_block("plain", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "t")
        .expect("builds");
    let plain = open(&out.data);
    assert!(plain.vertex_ao().is_empty() && plain.point_ao().is_empty());
    assert!(plain.sections().iter().all(|s| s.kind().since_minor() < 2 || s.kind() == SectionKind::POINT_FACING));
}

/// The mean RGB of the pixels within `radius` of the image's centre.
fn centre_mean(image: &Image, radius: u32) -> [f64; 3] {
    let c = image.width / 2;
    let mut sum = [0.0; 3];
    let mut n = 0.0;
    for y in c - radius..=c + radius {
        for x in c - radius..=c + radius {
            let p = image.pixel(x, y);
            for k in 0..3 {
                sum[k] += f64::from(p[k]);
            }
            n += 1.0;
        }
    }
    sum.map(|s| s / n)
}

/// The brightest channel of the pixels within `radius` of the image's centre.
fn centre_max(image: &Image, radius: u32) -> u8 {
    let c = image.width / 2;
    (c - radius..=c + radius)
        .flat_map(|y| (c - radius..=c + radius).map(move |x| (x, y)))
        .map(|(x, y)| image.pixel(x, y)[..3].iter().copied().max().unwrap_or(0))
        .max()
        .unwrap_or(0)
}

/// A linear value as the sRGB target stores it.
fn srgb(linear: f32) -> f64 {
    let s = if linear <= 0.003_130_8 { 12.92 * linear } else { 1.055 * linear.powf(1.0 / 2.4) - 0.055 };
    f64::from(s) * 255.0
}

fn close(rgb: [f64; 3], expected: [f32; 3], tolerance: f64) -> bool {
    rgb.iter().zip(expected).all(|(&v, e)| (v - srgb(e)).abs() <= tolerance)
}

/// The image's corners: the box's inner walls (the camera is inside the box).
fn corners(image: &Image) -> Vec<[u8; 4]> {
    let m = image.width - 2;
    vec![image.pixel(1, 1), image.pixel(m, 1), image.pixel(1, m), image.pixel(m, m)]
}

#[test]
fn the_enclosed_quad_is_black_in_ambient_light_with_ao_and_lit_without() {
    let gpu = gpu();
    let container = open(&built());
    let with_planes = open(&built_with_planes());
    let with_ellipsoids = open(&built_with_ellipsoids());
    // Inside the box, in front of the quad, looking at it: the walls around it are drawn too (no
    // pipeline culls back faces: leaves are cards), the far wall behind it.
    let camera = Camera::look_at(vec3(0.0, 0.0, 0.8), Vec3::ZERO, 0.8, SIZE, SIZE);
    // Ambient light alone: the sun's share is (1 − ambient) = 0.
    let lit = Settings { ambient: 1.0, ..Settings::default() };
    let points = Settings { s_min: 1.0, s_max: 1e9, ..lit };
    let planes = Settings { technique: Technique::Impostors, ..lit };
    let ellipsoids = Settings { technique: Technique::Ellipsoids, ..lit };
    let cases = [
        ("triangles", &container, lit, false),
        ("points", &container, points, false),
        ("gpu-points", &container, points, true),
        ("planes", &with_planes, planes, false),
        ("ellipsoids", &with_ellipsoids, ellipsoids, false),
    ];
    let mut reference = None;
    for (name, container, settings, gpu_selection) in cases {
        let mut renderer = one_tree(&gpu, container, settings);
        if gpu_selection {
            renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
        }
        let mut frame = |ambient_occlusion: bool| {
            renderer.settings_mut().ambient_occlusion = ambient_occlusion;
            let (image, stats) = settled(&gpu, &mut renderer, &camera);
            keep(&image, &format!("ao-{name}-{}", if ambient_occlusion { "on" } else { "off" }));
            assert_eq!(stats.gpu_selection, gpu_selection);
            (image, stats)
        };
        let (on, stats) = frame(true);
        let (off, _) = frame(false);
        match name {
            "triangles" => assert!(
                stats.submitted[Primitive::Triangle] >= 14 && renderer.points_in_cut() == 0,
                "{name}: {stats:?}"
            ),
            "planes" => {
                assert!(
                    stats.instances.get(Technique::Impostors) == 1 && stats.submitted[Primitive::Plane] >= 1,
                    "{name}: {stats:?}"
                );
            }
            "ellipsoids" => {
                assert!(
                    stats.instances.get(Technique::Ellipsoids) == 1 && stats.submitted[Primitive::Ellipsoid] >= 1,
                    "{name}: {stats:?}"
                );
            }
            _ => {
                assert!(
                    stats.submitted[Primitive::Triangle] == 0,
                    "{name}: every triangle is drawn as points: {stats:?}"
                );
                if !gpu_selection {
                    assert!(
                        stats.submitted[Primitive::Point] >= 2 && renderer.points_in_cut() >= 2,
                        "{name}: {stats:?}"
                    );
                }
            }
        }
        let (mean_on, mean_off, max_on) = (centre_mean(&on, 2), centre_mean(&off, 2), centre_max(&on, 2));
        eprintln!(
            "{name}: centre mean with AO {mean_on:.1?} (brightest channel {max_on}), without {mean_off:.1?}; \
             corners with AO {:?}, without {:?}; expected leaf {:.1?}, bark {:.1?}",
            corners(&on),
            corners(&off),
            LEAF.map(srgb),
            BARK.map(srgb),
        );
        assert!(max_on <= 8, "{name}: the enclosed quad is black with ambient occlusion: {mean_on:?}, max {max_on}");
        assert!(close(mean_off, LEAF, 6.0), "{name}: without, it has its albedo: {mean_off:?}");
        // The walls are open outwards: the same with and without, bark-coloured (as points, a
        // corner may fall between the walls' splats, on the background).
        for (a, b) in corners(&on).into_iter().zip(corners(&off)) {
            assert_eq!(a, b, "{name}: the walls do not change");
            let bark = close([a[0], a[1], a[2]].map(f64::from), BARK, 6.0);
            assert!(bark || (name != "triangles" && a == [255; 4]), "{name}: a wall pixel {a:?}");
        }
        // Every representation shows the quad alike.
        match reference {
            None => reference = Some((mean_on, mean_off)),
            Some((ref_on, ref_off)) => {
                for k in 0..3 {
                    assert!((mean_on[k] - ref_on[k]).abs() <= 8.0, "{name}: {mean_on:?} vs {ref_on:?}");
                    assert!((mean_off[k] - ref_off[k]).abs() <= 8.0, "{name}: {mean_off:?} vs {ref_off:?}");
                }
            }
        }
    }
}

#[test]
fn reserved_point_flags_are_not_read_as_occlusion_without_point_ao() {
    // Spec §6.5: a point's `flags` are reserved (readers ignore them), and §6.14: without
    // `POINT_AO` every point's occlusion is 0. A file of another writer may set them.
    let gpu = gpu();
    let mut data = built();
    data.vertex_ao.clear();
    data.point_ao.clear();
    for p in &mut data.points {
        p.flags = 0xFF;
    }
    let container = open(&data);
    assert!(container.point_ao().is_empty() && container.points().iter().all(|p| p.flags == 0xFF));
    let camera = Camera::look_at(vec3(0.0, 0.0, 0.8), Vec3::ZERO, 0.8, SIZE, SIZE);
    let points = Settings { ambient: 1.0, s_min: 1.0, s_max: 1e9, ..Settings::default() };
    for gpu_selection in [false, true] {
        let mut renderer = one_tree(&gpu, &container, points);
        if gpu_selection {
            renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
        }
        let (image, stats) = settled(&gpu, &mut renderer, &camera);
        assert!(stats.submitted[Primitive::Triangle] == 0 && stats.gpu_selection == gpu_selection, "{stats:?}");
        let mean = centre_mean(&image, 2);
        eprintln!("reserved flags 0xFF, GPU selection {gpu_selection}: centre {mean:.1?}");
        assert!(close(mean, LEAF, 6.0), "GPU selection {gpu_selection}: lit as without occlusion: {mean:?}");
    }
}

#[test]
fn reserved_ellipsoid_flags_are_not_read_as_occlusion_without_ellipsoid_ao() {
    // Spec §6.8: an ellipsoid's `flags` are reserved (readers ignore them), and §6.14: without
    // `ELLIPSOID_AO` every ellipsoid's occlusion is 0. A file of another writer may set them.
    let gpu = gpu();
    let mut data = built_with_ellipsoids();
    data.ellipsoid_ao.clear();
    for e in &mut data.ellipsoids {
        e.flags = 0xFF;
    }
    let container = open(&data);
    assert!(container.ellipsoid_ao().is_empty() && container.ellipsoids().iter().all(|e| e.flags == 0xFF));
    let camera = Camera::look_at(vec3(0.0, 0.0, 0.8), Vec3::ZERO, 0.8, SIZE, SIZE);
    let settings = Settings { ambient: 1.0, technique: Technique::Ellipsoids, ..Settings::default() };
    let mut renderer = one_tree(&gpu, &container, settings);
    let (image, stats) = settled(&gpu, &mut renderer, &camera);
    assert!(stats.instances.get(Technique::Ellipsoids) == 1 && stats.submitted[Primitive::Ellipsoid] >= 1, "{stats:?}");
    let mean = centre_mean(&image, 2);
    eprintln!("reserved ellipsoid flags 0xFF, no ELLIPSOID_AO: centre {mean:.1?}");
    assert!(close(mean, LEAF, 6.0), "lit as without occlusion: {mean:?}");
}
