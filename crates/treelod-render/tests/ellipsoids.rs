//! Clasen's ellipsoids on the Vulkan backend (Mesa lavapipe in CI), from synthetic containers:
//! the ray-cast silhouette against the exact one (intersection over union with a CPU ray cast
//! through every pixel centre), the written depth against a triangle through the ellipsoid, the
//! level chosen per distance and quality, the noise's holes, and the shadow cast on the ground.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, count, covered, gpu, iou, keep};
use glam::{Mat3, Quat, Vec3, Vec4, vec3};
use treelod_format::{CellRecord, Container, EllipsoidRecord, Range};
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, Image, render_image, render_prepared_scene};
use treelod_render::{Camera, DrawSource, Ground, Renderer, Settings, Shadows, Technique};

/// An ellipsoid of colour `color` (RGBA8, sRGB) and interval `[lo, hi)`.
fn ellipsoid(center: Vec3, radii: Vec3, rotation: Quat, color: u32, (lo, hi): (f32, f32)) -> EllipsoidRecord {
    let q = rotation.normalize().to_array().map(|c| (c * 32767.0).round() as i16);
    EllipsoidRecord {
        center: center.to_array(),
        radii: radii.to_array(),
        orientation: q,
        color,
        alpha_threshold: 0.0,
        noise_mip: 4.0,
        lo,
        hi,
        leaf_first: 0,
        leaf_count: 1,
        flags: 0,
    }
}

/// A 1×1×1 block over `[-10, 10]³` whose block cell holds `ellipsoids` (with their leaf runs as
/// given), and whose grid cell holds `triangle` if any: one opaque bark triangle of colour
/// `[0.8, 0.1, 0.1]` (with its point, as the sequential point tree needs); verified.
fn container(ellipsoids: Vec<EllipsoidRecord>, triangle: Option<[Vec3; 3]>) -> Arc<Container> {
    let mut data = common::one_cell_block("ellipsoids", triangle);
    let n = ellipsoids.len() as u32;
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for e in &ellipsoids {
        lo = lo.min(Vec3::from_array(e.center));
        hi = hi.max(Vec3::from_array(e.center));
    }
    let triangles = data.triangles.len() as u32;
    let block_cell = CellRecord {
        bounds_min: lo.to_array(),
        bounds_max: hi.to_array(),
        triangles: Range { first: triangles, count: 0 },
        points: Range { first: triangles, count: 0 },
        ellipsoids: Range { first: 0, count: n },
        ..CellRecord::default()
    };
    data.cells.push(block_cell);
    data.ellipsoids = ellipsoids;
    common::open_verified(&data)
}

/// A renderer drawing ellipsoids (no shadows, default sun) with one instance of `container`.
fn renderer(gpu: &Gpu, container: &Arc<Container>, settings: Settings) -> Renderer {
    common::one_tree(gpu, container, Settings { technique: Technique::Ellipsoids, ..settings })
}

/// The world ray (origin, unit direction) through the centre of pixel `(x, y)` of `camera`.
fn pixel_ray(camera: &Camera, x: u32, y: u32) -> (Vec3, Vec3) {
    let inverse = camera.view_proj().inverse();
    let ndc_x = (x as f32 + 0.5) / camera.width as f32 * 2.0 - 1.0;
    let ndc_y = 1.0 - (y as f32 + 0.5) / camera.height as f32 * 2.0;
    let unproject = |z: f32| {
        let p = inverse * Vec4::new(ndc_x, ndc_y, z, 1.0);
        p.truncate() / p.w
    };
    let (near, far) = (unproject(0.0), unproject(0.5));
    (near, (far - near).normalize())
}

/// Where the ray `(origin, direction)` first meets `e` (distance along the ray), if it does.
fn ray_hit(e: &EllipsoidRecord, origin: Vec3, direction: Vec3) -> Option<f32> {
    let q = Quat::from_array(e.orientation.map(|c| f32::from(c) / 32767.0)).normalize();
    let to_local = Mat3::from_diagonal(Vec3::from_array(e.radii).recip()) * Mat3::from_quat(q).transpose();
    let o = to_local * (origin - Vec3::from_array(e.center));
    let d = to_local * direction;
    let (a, b, c) = (d.dot(d), o.dot(d), o.dot(o) - 1.0);
    let disc = b * b - a * c;
    (disc >= 0.0).then(|| (-b - disc.sqrt()) / a)
}

/// The pixels of `camera` whose centre's ray meets `e`.
fn exact_silhouette(camera: &Camera, e: &EllipsoidRecord) -> Vec<bool> {
    let mut mask = Vec::new();
    for y in 0..camera.height {
        for x in 0..camera.width {
            let (origin, direction) = pixel_ray(camera, x, y);
            mask.push(ray_hit(e, origin, direction).is_some());
        }
    }
    mask
}

/// A turned, stretched ellipsoid near the origin.
fn tilted(color: u32) -> EllipsoidRecord {
    let rotation = Quat::from_axis_angle(vec3(1.0, 2.0, 3.0).normalize(), 0.7);
    ellipsoid(vec3(0.1, -0.2, 0.05), vec3(1.2, 0.7, 0.3), rotation, color, (0.0, f32::INFINITY))
}

#[test]
fn an_ellipsoid_covers_the_pixels_of_its_exact_silhouette() {
    let gpu = gpu();
    let e = tilted(0xFF30_A040);
    let container = container(vec![e], None);
    let mut renderer = renderer(&gpu, &container, Settings::default());
    // Head-on, from the side, from above, near, and off the view's axis (the quad is widened for
    // the perspective).
    let views = [
        ("front", Camera::look_at(vec3(0.0, 0.0, 10.0), Vec3::ZERO, 0.35, 256, 256)),
        ("side", Camera::look_at(vec3(9.0, 1.0, 0.5), Vec3::ZERO, 0.35, 256, 256)),
        ("above", Camera::look_at(vec3(0.5, 9.0, 2.0), Vec3::ZERO, 0.35, 256, 256)),
        ("near", Camera::look_at(vec3(1.0, 1.5, 2.5), Vec3::ZERO, 1.2, 256, 256)),
        ("off-axis", Camera::look_at(vec3(2.0, 0.5, 3.0), vec3(-1.5, -1.0, 0.0), 1.4, 256, 200)),
    ];
    for (name, camera) in views {
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("ellipsoid-{name}"));
        assert_eq!(
            (stats.instances.get(Technique::Ellipsoids), stats.submitted[Primitive::Ellipsoid]),
            (1, 1),
            "{name}: {stats:?}"
        );
        let drawn = covered(&image);
        let exact = exact_silhouette(&camera, &e);
        let overlap = iou(&drawn, &exact);
        eprintln!("{name}: {} pixels drawn, {} exact, IoU {overlap:.4}", count(&drawn), count(&exact));
        assert!(count(&exact) > 2000, "{name}: the ellipsoid is in view");
        assert!(overlap >= 0.95, "{name}: IoU {overlap:.4}");
    }
}

#[test]
fn the_written_depth_meets_a_triangle_through_the_centre_where_the_surfaces_cross() {
    let gpu = gpu();
    let e = tilted(0xFF30_C040);
    let centre = Vec3::from_array(e.center);
    // A large red triangle in the plane x = centre.x, seen obliquely from +x: the ellipsoid's half
    // with x > centre.x lies in front of it, the other half behind.
    let plane = |dx: f32| {
        let x = centre.x + dx;
        [vec3(x, -8.0, -8.0), vec3(x, 8.0, -8.0), vec3(x, 0.0, 9.0)]
    };
    let camera = Camera::look_at(vec3(6.0, 2.0, 7.0), centre, 0.4, 256, 256);
    let classify = |image: &Image| -> Vec<Option<bool>> {
        // Some(true): the ellipsoid (green), Some(false): the triangle (red), None: background.
        image
            .rgba
            .chunks_exact(4)
            .map(|p| if p[0] >= 250 && p[1] >= 250 && p[2] >= 250 { None } else { Some(p[1] > p[0]) })
            .collect()
    };
    let mut results = Vec::new();
    for (name, dx) in [("through", 0.0), ("behind", -3.0), ("in-front", 3.0)] {
        let container = container(vec![e], Some(plane(dx)));
        let mut renderer = renderer(&gpu, &container, Settings::default());
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("ellipsoid-depth-{name}"));
        assert_eq!(stats.submitted[Primitive::Triangle], 1, "the bark triangle: {stats:?}");
        results.push((name, dx, classify(&image)));
    }
    for (name, dx, shown) in &results {
        let (mut inside, mut wrong) = (0, 0);
        for y in 0..camera.height {
            for x in 0..camera.width {
                let (origin, direction) = pixel_ray(&camera, x, y);
                let Some(t) = ray_hit(&e, origin, direction) else { continue };
                inside += 1;
                // The plane's hit along the ray, if in front.
                let t_plane = (centre.x + dx - origin.x) / direction.x;
                let expected = !(t_plane > 0.0 && t_plane < t);
                if shown[(y * camera.width + x) as usize] != Some(expected) {
                    wrong += 1;
                }
            }
        }
        let share = f64::from(wrong) / f64::from(inside);
        eprintln!("triangle {name}: {wrong} of {inside} silhouette pixels differ from the exact depth order");
        assert!(share < 0.02, "{name}: {share:.4} of the pixels in the wrong order");
    }
    // Through the centre, both show; behind, only the ellipsoid; in front, only the triangle.
    let ellipsoid_pixels = |shown: &[Option<bool>]| shown.iter().filter(|s| **s == Some(true)).count();
    let through = ellipsoid_pixels(&results[0].2);
    let behind = ellipsoid_pixels(&results[1].2);
    eprintln!("ellipsoid pixels: {through} with the triangle through its centre, {behind} with it behind");
    assert!(through > behind / 4 && through < behind * 3 / 4, "the near half shows: {through} of {behind}");
    assert_eq!(ellipsoid_pixels(&results[2].2), 0);
}

#[test]
fn near_draws_the_fine_level_far_the_coarse_one_and_quality_refines() {
    let gpu = gpu();
    let (fovy, height) = (0.35f32, 256u32);
    let mpp = |d: f32| d * 2.0 * (0.5 * fovy).tan() / height as f32;
    // The switch at the pixel size of 20 m.
    let e1 = mpp(20.0);
    let blue = 0xFFCC_3319;
    let red = 0xFF19_19CC;
    let fine = |x: f32, leaf: u32| {
        let mut e = ellipsoid(vec3(x, 0.0, 0.0), vec3(0.5, 0.5, 0.5), Quat::IDENTITY, blue, (0.0, e1));
        e.leaf_first = leaf;
        e
    };
    let (a, b) = (fine(-0.6, 0), fine(0.6, 1));
    let mut coarse = ellipsoid(Vec3::ZERO, vec3(1.1, 0.6, 0.6), Quat::IDENTITY, red, (e1, f32::INFINITY));
    coarse.leaf_count = 2;
    let container = container(vec![coarse, a, b], None);
    let mut renderer = renderer(&gpu, &container, Settings::default());
    common::check_level_switch(
        &gpu,
        &mut renderer,
        (fovy, height),
        DrawSource::Ellipsoids,
        |s| s.submitted[Primitive::Ellipsoid],
        20,
        "ellipsoid",
    );
}

#[test]
fn the_noise_removes_the_share_of_the_surface_its_threshold_asks_for() {
    let gpu = gpu();
    let camera = Camera::look_at(vec3(0.0, 0.0, 10.0), Vec3::ZERO, 0.35, 256, 256);
    let mut pixels = Vec::new();
    for threshold in [0.0, 0.25, 0.5, 0.75] {
        let mut e = tilted(0xFF30_A040);
        e.alpha_threshold = threshold;
        let container = container(vec![e], None);
        let mut renderer = renderer(&gpu, &container, Settings::default());
        let (image, _) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("ellipsoid-noise-{threshold}"));
        let drawn = covered(&image);
        if threshold == 0.0 {
            let exact = exact_silhouette(&camera, &e);
            assert!(iou(&drawn, &exact) >= 0.95, "no holes at threshold 0");
        }
        pixels.push((threshold, count(&drawn)));
    }
    let all = pixels[0].1 as f64;
    for &(threshold, n) in &pixels[1..] {
        let threshold = f64::from(threshold);
        let removed = 1.0 - n as f64 / all;
        eprintln!("threshold {threshold}: {n} of {all} pixels kept, {removed:.3} removed");
        // A hole shows the ellipsoid's far side where the ray goes on: the front surface's holes
        // alone remove `t`, and the back shows through some of them (`t·(1 − t)` of the surface
        // behind a hole is solid), so the share of pixels removed lies between t² and t.
        assert!(
            removed > 0.8 * threshold * threshold - 0.03 && removed < threshold + 0.05,
            "threshold {threshold}: {removed:.3} removed"
        );
    }
}

#[test]
fn an_ellipsoid_casts_the_shadow_of_its_shape_on_the_ground() {
    let gpu = gpu();
    // Above the ground (the block's floor is at y = -10; the ellipsoid floats at y = -7).
    let rotation = Quat::from_axis_angle(vec3(0.3, 1.0, 0.2).normalize(), 0.9);
    let e = ellipsoid(vec3(0.0, -7.0, 0.0), vec3(1.6, 0.5, 0.8), rotation, 0xFF30_A040, (0.0, f32::INFINITY));
    let container = container(vec![e], None);
    let sun = vec3(0.3, 0.9, 0.2).normalize();
    let shadows = Shadows { resolution: 2048, cascades: 1, distance: 40.0, ..Shadows::default() };
    let settings = Settings { sun, shadows: Some(shadows), ..Settings::default() };
    let mut renderer = renderer(&gpu, &container, settings);
    let ground = Ground::new(&gpu.device, &renderer, vec3(0.0, -10.0, 0.0), 12.0);
    // Looking down at where the shadow falls.
    let ground_y = -10.0;
    let shadow_centre = vec3(0.0, -7.0, 0.0) - sun * (3.0 / sun.y);
    let camera = Camera::look_at(shadow_centre + vec3(0.0, 12.0, 0.1), shadow_centre, 0.6, 256, 256);
    let frame = |renderer: &mut Renderer, on: bool| {
        renderer.settings_mut().shadows = on.then_some(shadows);
        let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
        let (image, _) =
            render_prepared_scene(&gpu, renderer, &camera, BACKGROUND, Some(&ground), true).expect("renders");
        (image, stats)
    };
    let (lit, _) = frame(&mut renderer, false);
    let (shadowed, stats) = frame(&mut renderer, true);
    keep(&lit, "ellipsoid-shadow-lit");
    keep(&shadowed, "ellipsoid-shadow");
    assert_eq!(stats.shadow.cascades, 1);
    assert!(stats.shadow.submitted[Primitive::Ellipsoid] > 0, "{:?}", stats.shadow);
    // The exact shadow: ground points whose ray towards the sun meets the ellipsoid, over the
    // pixels that see the ground (not the ellipsoid itself).
    let (mut exact, mut drawn) = (Vec::new(), Vec::new());
    for y in 0..camera.height {
        for x in 0..camera.width {
            let (origin, direction) = pixel_ray(&camera, x, y);
            if ray_hit(&e, origin, direction).is_some() {
                continue;
            }
            let t = (ground_y - origin.y) / direction.y;
            let on_ground = origin + t * direction;
            exact.push(ray_hit(&e, on_ground, sun).is_some_and(|s| s > 0.0));
            let (s, l) = (shadowed.pixel(x, y), lit.pixel(x, y));
            drawn.push(f32::from(s[1]) < 0.85 * f32::from(l[1]));
        }
    }
    let overlap = iou(&drawn, &exact);
    eprintln!("shadow: {} pixels drawn, {} exact, IoU {overlap:.4}", count(&drawn), count(&exact));
    assert!(count(&exact) > 1000, "the shadow is in view");
    assert!(overlap >= 0.9, "IoU {overlap:.4}");
}

/// A far tree drawn with ellipsoids draws every cell's coarsest level as one range of the far
/// ellipsoids (`EllipsoidLod::far_first`) where each cell drew its own: the same image from far
/// fewer draws. The other path is the same tree with its coarsest levels' `hi` made finite
/// (`f32::MAX`, which the shaders read as unbounded), which has no far ellipsoids (and which
/// verify refuses: the tree's last intervals must be unbounded).
#[test]
fn a_far_tree_draws_its_cells_coarsest_ellipsoids_as_one_range_with_the_same_image() {
    use treelod_build::{BuildConfig, DemoTreeConfig, EllipsoidConfig, Placed, build_block, demo_tree};
    use treelod_runtime::{EllipsoidLod, far_ellipsoids};
    let gpu = gpu();
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig { ellipsoids: Some(EllipsoidConfig::default()), ..BuildConfig::default() };
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "test").expect("builds");
    let with_far = common::open_verified(&built.data);
    let mut data = built.data.clone();
    for e in &mut data.ellipsoids {
        if e.hi == f32::INFINITY {
            e.hi = f32::MAX;
        }
    }
    // Not a valid container (§10 rule 2 wants the last interval unbounded): opened unverified.
    let bytes = data.to_bytes(treelod_format::Compression::None).expect("encodes");
    let without = Arc::new(Container::from_bytes(&bytes).expect("opens"));
    let (_, switch) = far_ellipsoids(&with_far).expect("far ellipsoids");
    assert!(far_ellipsoids(&without).is_none());
    let lod = EllipsoidLod::from_container(&with_far).expect("ellipsoids");
    assert_eq!(lod.far_first(), Some(with_far.ellipsoids().len() as u32));
    // A camera whose nearest cell's τ is a fifth past the switch (with the default level blend).
    let block = with_far.block();
    let (lo, hi) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let centre = 0.5 * (lo + hi);
    let (fovy, size) = (0.5_f32, 256);
    let world_per_pixel = 2.0 * (0.5 * fovy).tan() / size as f32;
    let tau = 1.2 * switch * (0.5 * treelod_runtime::DEFAULT_LEVEL_BLEND).exp2();
    let distance = tau / world_per_pixel + 0.5 * (hi - lo).length();
    let camera = Camera::look_at(centre + Vec3::new(0.6, 0.3, 0.75).normalize() * distance, centre, fovy, size, size);
    let draw = |container: &Arc<Container>| {
        let mut renderer = renderer(&gpu, container, Settings::default());
        let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
        let (image, _) = render_prepared_scene(&gpu, &mut renderer, &camera, BACKGROUND, None, true).expect("renders");
        (image, stats)
    };
    let (far, far_stats) = draw(&with_far);
    let (cells, cell_stats) = draw(&without);
    keep(&far, "ellipsoids-far");
    let submitted = |s: &treelod_render::FrameStats| s.submitted[Primitive::Ellipsoid];
    assert_eq!(submitted(&far_stats), submitted(&cell_stats), "the same ellipsoids");
    assert!(submitted(&far_stats) > 0);
    let cell_ranges = cell_stats.ranges - far_stats.ranges + 1;
    assert!(cell_ranges >= 4, "one range where the cells drew {cell_ranges}");
    assert!(count(&covered(&far)) > 100, "the tree is drawn");
    let differing = far.rgba.chunks(4).zip(cells.rgba.chunks(4)).filter(|(a, b)| a != b).count();
    assert_eq!(differing, 0, "pixels differing between the far range and the cells' ranges");
}
