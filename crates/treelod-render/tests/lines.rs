//! Clasen's branch lines (spec §6.9) on the Vulkan backend (Mesa lavapipe in CI), from synthetic
//! containers: the ray-cast round cones' silhouettes against a CPU ray cast through every pixel
//! centre, the written depth against a triangle the line crosses, the level chosen per distance
//! and quality, the coverage of lines thinner than a pixel, `LINE_AO`, the shadow cast on the
//! ground, and the bark triangles drawn instead with `Settings::lines` off.
//!
//! The CPU reference treats a round cone as what it is, the union of the balls of centre
//! `p0 + s·(p1 − p0)` and radius `r0 + s·(r1 − r0)` for `s ∈ [0, 1]`: a ray meets it where its
//! distance to some centre is at most that ball's radius, a convex function of `s` minimised by
//! ternary search — independent of the shader's closed-form intersection.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, count, covered, gpu, iou, keep, line_record as line};
use glam::{DVec3, Mat4, Vec3, Vec4, vec3};
use treelod_format::{CellRecord, Container, EllipsoidRecord, LineRecord, Range};
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, Image, render_image, render_prepared_scene};
use treelod_render::{Camera, DrawSource, Ground, Instance, Renderer, Settings, Shadows, Technique};

const GREEN: u32 = 0xFF30_A040;
const RED: u32 = 0xFF19_19CC;
const BLUE: u32 = 0xFFCC_3319;
const WHITE: u32 = 0xFFFF_FFFF;

/// A line drawn at every `τ`, standing for segment `segment`.
fn solid(p0: Vec3, r0: f32, p1: Vec3, r1: f32, color: u32, segment: u32) -> LineRecord {
    line(p0, r0, p1, r1, color, (0.0, f32::INFINITY), (segment, 1))
}

/// A 1×1×1 block over `[-10, 10]³`. With lines, its block cell holds them (with `LINE_AO` `ao`,
/// empty for none) and one ellipsoid of zero radii, which makes it a tree drawn with ellipsoids
/// that shows no leaf. Its grid cell holds `triangle` if any: one opaque bark triangle of colour
/// `[0.8, 0.1, 0.1]` (with its point, as the sequential point tree needs). Verified.
fn container(lines: Vec<LineRecord>, ao: Vec<u8>, triangle: Option<[Vec3; 3]>) -> Arc<Container> {
    let mut data = common::one_cell_block("lines", triangle);
    let triangles = data.triangles.len() as u32;
    let mut block_cell = CellRecord {
        triangles: Range { first: triangles, count: 0 },
        points: Range { first: triangles, count: 0 },
        ..CellRecord::default()
    };
    if !lines.is_empty() {
        let (mut lo, mut hi) = (Vec3::ZERO, Vec3::ZERO);
        for l in &lines {
            for p in [l.p0, l.p1] {
                lo = lo.min(Vec3::from_array(p));
                hi = hi.max(Vec3::from_array(p));
            }
        }
        block_cell.bounds_min = lo.to_array();
        block_cell.bounds_max = hi.to_array();
        block_cell.ellipsoids = Range { first: 0, count: 1 };
        block_cell.lines = Range { first: 0, count: lines.len() as u32 };
        data.ellipsoids = vec![EllipsoidRecord {
            orientation: [0, 0, 0, i16::MAX],
            hi: f32::INFINITY,
            leaf_count: 1,
            ..EllipsoidRecord::default()
        }];
    }
    data.cells.push(block_cell);
    data.lines = lines;
    data.line_ao = ao;
    common::open_verified(&data)
}

/// A renderer drawing ellipsoid trees (no shadows, default sun) with one instance of each of
/// `containers` at the origin.
fn renderer(gpu: &Gpu, containers: &[&Arc<Container>], settings: Settings) -> Renderer {
    let mut renderer =
        Renderer::new(&gpu.device, Gpu::formats(), Settings { technique: Technique::Ellipsoids, ..settings });
    let instances: Vec<Instance> = containers
        .iter()
        .map(|c| Instance {
            model: renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(c)).expect("uploads"),
            transform: Mat4::IDENTITY,
        })
        .collect();
    renderer.set_instances(&instances);
    renderer
}

/// The world ray (origin, unit direction) through the centre of pixel `(x, y)` of `camera`.
fn pixel_ray(camera: &Camera, x: u32, y: u32) -> (DVec3, DVec3) {
    let inverse = camera.view_proj().inverse();
    let ndc_x = (x as f32 + 0.5) / camera.width as f32 * 2.0 - 1.0;
    let ndc_y = 1.0 - (y as f32 + 0.5) / camera.height as f32 * 2.0;
    let unproject = |z: f32| {
        let p = inverse * Vec4::new(ndc_x, ndc_y, z, 1.0);
        (p.truncate() / p.w).as_dvec3()
    };
    let (near, far) = (unproject(0.0), unproject(0.5));
    (near, (far - near).normalize())
}

/// The pixel (x right, y down) `p` projects to.
fn project(camera: &Camera, p: Vec3) -> (f32, f32) {
    let clip = camera.view_proj() * p.extend(1.0);
    let ndc = clip.truncate() / clip.w;
    ((ndc.x + 1.0) * 0.5 * camera.width as f32, (1.0 - ndc.y) * 0.5 * camera.height as f32)
}

/// The minimum of a convex function over `[0, 1]` (ternary search): `(argument, value)`.
fn minimise(f: impl Fn(f64) -> f64) -> (f64, f64) {
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..60 {
        let (a, b) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        if f(a) <= f(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    let s = 0.5 * (lo + hi);
    (s, f(s))
}

/// A round cone, the CPU reference.
struct Cone {
    a: DVec3,
    b: DVec3,
    ra: f64,
    rb: f64,
}

impl Cone {
    fn new(l: &LineRecord) -> Self {
        let v = |p: [f32; 3]| Vec3::from_array(p).as_dvec3();
        Self { a: v(l.p0), b: v(l.p1), ra: f64::from(l.r0), rb: f64::from(l.r1) }
    }

    fn centre(&self, s: f64) -> DVec3 {
        self.a + s * (self.b - self.a)
    }

    fn radius(&self, s: f64) -> f64 {
        self.ra + s * (self.rb - self.ra)
    }

    /// Whether `x` lies inside: within some ball.
    fn contains(&self, x: DVec3) -> bool {
        minimise(|s| x.distance(self.centre(s)) - self.radius(s)).1 <= 0.0
    }

    /// Where the line `o + t·d` (`d` unit) enters the cone, if it meets it: the smallest `t`
    /// inside, by bisection from the point nearest a ball's centre.
    fn entry(&self, o: DVec3, d: DVec3) -> Option<f64> {
        let from_line = |s: f64| {
            let oc = self.centre(s) - o;
            (oc - oc.dot(d) * d).length() - self.radius(s)
        };
        // A quick rejection: the distance to the segment exceeds the larger radius.
        let reach = self.ra.max(self.rb);
        if from_line(0.5) > 0.5 * self.a.distance(self.b) + reach {
            return None;
        }
        let (s, gap) = minimise(from_line);
        if gap > 0.0 {
            return None;
        }
        let mut inside = (self.centre(s) - o).dot(d);
        let mut outside = inside - (self.a.distance(self.b) + 2.0 * reach + 1.0);
        for _ in 0..50 {
            let mid = 0.5 * (inside + outside);
            if self.contains(o + mid * d) {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        Some(inside)
    }
}

/// The pixels of `camera` whose centre's ray meets one of `lines`.
fn exact_silhouette(camera: &Camera, lines: &[LineRecord]) -> Vec<bool> {
    let cones: Vec<Cone> = lines.iter().map(Cone::new).collect();
    let mut mask = Vec::new();
    for y in 0..camera.height {
        for x in 0..camera.width {
            let (o, d) = pixel_ray(camera, x, y);
            mask.push(cones.iter().any(|c| c.entry(o, d).is_some()));
        }
    }
    mask
}

/// A straight, a tapered and an oblique line about the origin.
fn three_lines() -> Vec<LineRecord> {
    vec![
        solid(vec3(-2.0, -1.2, 0.0), 0.3, vec3(2.0, -1.2, 0.0), 0.3, GREEN, 0),
        solid(vec3(-2.0, 0.4, 0.2), 0.45, vec3(1.5, 1.6, -0.3), 0.1, GREEN, 1),
        solid(vec3(-1.0, -2.0, -1.5), 0.2, vec3(1.5, 2.0, 2.0), 0.28, GREEN, 2),
    ]
}

#[test]
fn lines_cover_the_pixels_of_their_exact_round_cones() {
    let gpu = gpu();
    let lines = three_lines();
    let container = container(lines.clone(), Vec::new(), None);
    let mut renderer = renderer(&gpu, &[&container], Settings::default());
    // Head-on, from the side, from above, near, and off the view's axis.
    let views = [
        ("front", Camera::look_at(vec3(0.0, 0.0, 10.0), Vec3::ZERO, 0.5, 256, 256)),
        ("side", Camera::look_at(vec3(9.0, 1.0, 0.5), Vec3::ZERO, 0.5, 256, 256)),
        ("above", Camera::look_at(vec3(0.5, 9.0, 2.0), Vec3::ZERO, 0.5, 256, 256)),
        ("near", Camera::look_at(vec3(1.0, 1.5, 3.5), Vec3::ZERO, 1.2, 256, 256)),
        ("off-axis", Camera::look_at(vec3(2.0, 0.5, 4.0), vec3(-1.5, -1.0, 0.0), 1.4, 256, 200)),
        ("along", Camera::look_at(vec3(-6.0, -1.2, 0.3), vec3(2.0, -1.2, 0.0), 0.6, 256, 256)),
    ];
    for (name, camera) in views {
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("line-{name}"));
        assert_eq!(
            (
                stats.instances.get(Technique::Ellipsoids),
                stats.submitted[Primitive::Line],
                stats.submitted[Primitive::Triangle]
            ),
            (1, 3, 0),
            "{name}: {stats:?}"
        );
        let drawn = covered(&image);
        let exact = exact_silhouette(&camera, &lines);
        let overlap = iou(&drawn, &exact);
        eprintln!("{name}: {} pixels drawn, {} exact, IoU {overlap:.4}", count(&drawn), count(&exact));
        assert!(count(&exact) > 1500, "{name}: the lines are in view");
        assert!(overlap >= 0.97, "{name}: IoU {overlap:.4}");
    }
}

#[test]
fn a_line_crossing_a_triangle_is_hidden_where_it_lies_behind_it() {
    let gpu = gpu();
    // A green line through the plane x = 0, which a large red triangle (another model, drawn by
    // the sequential point tree) fills; seen obliquely from +x.
    let l = solid(vec3(-2.5, -1.0, -1.0), 0.35, vec3(2.5, 1.0, 1.5), 0.2, GREEN, 0);
    let lines = container(vec![l], Vec::new(), None);
    let wall =
        container(Vec::new(), Vec::new(), Some([vec3(0.0, -8.0, -8.0), vec3(0.0, 8.0, -8.0), vec3(0.0, 0.0, 9.0)]));
    let mut renderer = renderer(&gpu, &[&lines, &wall], Settings::default());
    let camera = Camera::look_at(vec3(6.0, 2.0, 7.0), Vec3::ZERO, 0.5, 256, 256);
    let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    keep(&image, "line-depth");
    assert_eq!((stats.submitted[Primitive::Line], stats.submitted[Primitive::Triangle]), (1, 1), "{stats:?}");
    let cone = Cone::new(&l);
    let (mut inside, mut wrong, mut shown) = (0, 0, 0);
    for y in 0..camera.height {
        for x in 0..camera.width {
            let (o, d) = pixel_ray(&camera, x, y);
            let Some(t) = cone.entry(o, d) else { continue };
            inside += 1;
            let t_plane = -o.x / d.x;
            let expected = !(t_plane > 0.0 && t_plane < t);
            let p = image.pixel(x, y);
            let green = p[1] > p[0];
            wrong += usize::from(green != expected);
            shown += usize::from(expected);
        }
    }
    let share = wrong as f64 / inside as f64;
    eprintln!("{wrong} of {inside} line pixels differ from the exact depth order ({shown} in front)");
    assert!(shown > 300 && shown + 300 < inside, "the line is partly in front, partly behind");
    assert!(share < 0.01, "{share:.4} of the pixels in the wrong order");
}

#[test]
fn near_draws_the_fine_lines_far_the_coarse_one_and_quality_refines() {
    let gpu = gpu();
    let (fovy, height) = (0.35f32, 256u32);
    let mpp = |d: f32| d * 2.0 * (0.5 * fovy).tan() / height as f32;
    // The switch at the pixel size of 20 m: one red line for two blue segments.
    let e1 = mpp(20.0);
    let (a, m, b) = (vec3(-1.5, -0.5, 0.0), vec3(0.0, 0.6, 0.0), vec3(1.5, -0.2, 0.0));
    let lines = vec![
        line(a, 0.3, b, 0.3, RED, (e1, f32::INFINITY), (0, 2)),
        line(a, 0.3, m, 0.25, BLUE, (0.0, e1), (0, 1)),
        line(m, 0.25, b, 0.3, BLUE, (0.0, e1), (1, 1)),
    ];
    let container = container(lines, Vec::new(), None);
    let mut renderer = renderer(&gpu, &[&container], Settings::default());
    common::check_level_switch(
        &gpu,
        &mut renderer,
        (fovy, height),
        DrawSource::Lines,
        |s| s.submitted[Primitive::Line],
        50,
        "line",
    );
}

#[test]
fn lines_thinner_than_a_pixel_cover_their_width_and_one_pixel_lines_leave_no_gaps() {
    let gpu = gpu();
    let camera = Camera::look_at(vec3(0.0, 0.0, 10.0), Vec3::ZERO, 0.35, 256, 256);
    // The lines lie in the plane z = 0, parallel to the image: a pixel is `mpp` metres there.
    let mpp = 10.0 * 2.0 * (0.5f32 * 0.35).tan() / 256.0;
    for (width, slope) in [(0.3, 0.13), (0.3, 0.9), (1.0, 0.13), (1.0, 0.9)] {
        // Nine parallel lines 1.6 m wide (about 116 px), `width` pixels wide, all in view.
        let r = 0.5 * width * mpp * if width >= 1.0 { 1.01 } else { 1.0 };
        let lines: Vec<LineRecord> = (0..9)
            .map(|k| {
                let y = -0.9 + 0.225 * k as f32;
                let p0 = vec3(-0.8, y - 0.8 * slope, 0.0);
                let p1 = vec3(0.8, y + 0.8 * slope, 0.0);
                solid(p0, r, p1, r, GREEN, k)
            })
            .collect();
        let container = container(lines.clone(), Vec::new(), None);
        let mut renderer = renderer(&gpu, &[&container], Settings::default());
        let (image, _) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("line-thin-{width}-{slope}"));
        let drawn = covered(&image);
        let at = |x: i64, y: i64| {
            (0..camera.width as i64).contains(&x)
                && (0..camera.height as i64).contains(&y)
                && drawn[(y * camera.width as i64 + x) as usize]
        };
        let (mut pixels, mut length, mut longest_gap) = (0usize, 0.0f64, 0usize);
        for l in &lines {
            let (x0, y0) = project(&camera, Vec3::from_array(l.p0));
            let (x1, y1) = project(&camera, Vec3::from_array(l.p1));
            length += f64::from((x1 - x0).hypot(y1 - y0));
            // Columns along the line (x-major: |slope| < 1), away from its ends: is any pixel
            // within two rows of the axis covered?
            let mut gap = 0;
            for x in (x0.ceil() as i64 + 2)..(x1.floor() as i64 - 2) {
                let y = y0 + (x as f32 + 0.5 - x0) * (y1 - y0) / (x1 - x0) - 0.5;
                let hit = (-2..=2).any(|dy| at(x, y.round() as i64 + dy));
                gap = if hit { 0 } else { gap + 1 };
                longest_gap = longest_gap.max(gap);
            }
        }
        pixels += count(&drawn);
        let coverage = pixels as f64 / length;
        eprintln!(
            "{width} px wide, slope {slope}: {pixels} pixels over {length:.0} px of length: {coverage:.3} per pixel \
             of length; longest gap {longest_gap} columns"
        );
        if width < 1.0 {
            assert!((coverage - f64::from(width)).abs() < 0.06, "{width} px: covers {coverage:.3}");
        } else {
            assert!(longest_gap <= 1, "{width} px: a gap of {longest_gap} columns");
            assert!((coverage - 1.0).abs() < 0.12, "{width} px: covers {coverage:.3}");
        }
    }
}

#[test]
fn line_ao_darkens_ambient_light_and_reserved_flags_are_not_read() {
    let gpu = gpu();
    let camera = Camera::look_at(vec3(0.0, 0.0, 10.0), Vec3::ZERO, 0.5, 256, 256);
    // Two white lines whose file flags are set (reserved: never read as occlusion).
    let mut lines = vec![
        solid(vec3(-2.0, 0.8, 0.0), 0.4, vec3(2.0, 0.8, 0.0), 0.4, WHITE, 0),
        solid(vec3(-2.0, -0.8, 0.0), 0.4, vec3(2.0, -0.8, 0.0), 0.4, WHITE, 1),
    ];
    for l in &mut lines {
        l.flags = 0xFF;
    }
    // The line's centre pixels: a 5×5 patch about each line's middle.
    let brightness = |image: &Image, y: f32| {
        let (cx, cy) = project(&camera, vec3(0.0, y, 0.0));
        let mut sum = [0.0f64; 3];
        for dy in -2..=2 {
            for dx in -2..=2 {
                let p = image.pixel((cx as i64 + dx) as u32, (cy as i64 + dy) as u32);
                for k in 0..3 {
                    sum[k] += f64::from(p[k]) / 25.0;
                }
            }
        }
        sum
    };
    // Ambient light alone: the sun's share is (1 − ambient) = 0.
    let ambient = Settings { ambient: 1.0, ..Settings::default() };
    let mut results = Vec::new();
    for (name, ao, occlusion) in
        [("ao", vec![0u8, 200], true), ("ao-off", vec![0, 200], false), ("no-line-ao", Vec::new(), true)]
    {
        let container = container(lines.clone(), ao, None);
        assert!(container.lines().iter().all(|l| l.flags == 0xFF));
        let mut renderer = renderer(&gpu, &[&container], Settings { ambient_occlusion: occlusion, ..ambient });
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("line-{name}"));
        assert_eq!(stats.submitted[Primitive::Line], 2);
        let (open, occluded) = (brightness(&image, 0.8), brightness(&image, -0.8));
        eprintln!("{name}: the open line {open:.1?}, the occluded one {occluded:.1?}");
        results.push((name, open, occluded));
    }
    // The open line keeps its white albedo (its flags 0xFF are not occlusion); 200/255 of the
    // ambient light gone is linear 0.216, sRGB about 128.
    for (name, open, occluded) in &results {
        assert!(open.iter().all(|&c| c > 250.0), "{name}: the open line is white: {open:?}");
        let expected = if *name == "ao" { 128.0 } else { 255.0 };
        assert!(occluded.iter().all(|&c| (c - expected).abs() < 6.0), "{name}: {occluded:?}, expected {expected}");
    }
}

#[test]
fn a_line_casts_the_shadow_of_its_round_cone_on_the_ground() {
    let gpu = gpu();
    // Above the ground (the block's floor is at y = -10; the line floats about y = -7).
    let l = solid(vec3(-1.5, -7.0, -0.5), 0.4, vec3(1.6, -6.5, 0.9), 0.2, GREEN, 0);
    let container = container(vec![l], Vec::new(), None);
    let sun = vec3(0.3, 0.9, 0.2).normalize();
    let shadows = Shadows { resolution: 2048, cascades: 1, distance: 40.0, ..Shadows::default() };
    let settings = Settings { sun, shadows: Some(shadows), ..Settings::default() };
    let mut renderer = renderer(&gpu, &[&container], settings);
    let ground = Ground::new(&gpu.device, &renderer, vec3(0.0, -10.0, 0.0), 12.0);
    let ground_y = -10.0;
    let shadow_centre = vec3(0.0, -6.8, 0.2) - sun * (3.2 / sun.y);
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
    keep(&lit, "line-shadow-lit");
    keep(&shadowed, "line-shadow");
    assert_eq!(stats.shadow.cascades, 1);
    assert_eq!(stats.shadow.submitted[Primitive::Line], 1, "{:?}", stats.shadow);
    // The exact shadow: ground points whose ray towards the sun meets the line, over the pixels
    // that see the ground (not the line itself).
    let cone = Cone::new(&l);
    let sun = sun.as_dvec3();
    let (mut exact, mut drawn) = (Vec::new(), Vec::new());
    for y in 0..camera.height {
        for x in 0..camera.width {
            let (o, d) = pixel_ray(&camera, x, y);
            if cone.entry(o, d).is_some() {
                continue;
            }
            let on_ground = o + ((ground_y - o.y) / d.y) * d;
            exact.push(cone.entry(on_ground, sun).is_some_and(|t| t > 0.0));
            let (s, l) = (shadowed.pixel(x, y), lit.pixel(x, y));
            drawn.push(f32::from(s[1]) < 0.85 * f32::from(l[1]));
        }
    }
    let overlap = iou(&drawn, &exact);
    eprintln!("shadow: {} pixels drawn, {} exact, IoU {overlap:.4}", count(&drawn), count(&exact));
    assert!(count(&exact) > 1000, "the shadow is in view");
    assert!(overlap >= 0.9, "IoU {overlap:.4}");
}

#[test]
fn without_lines_the_bark_is_drawn_as_its_triangles() {
    let gpu = gpu();
    // A red bark triangle beside a green line, both of one tree.
    let l = solid(vec3(-2.0, 1.0, 0.0), 0.3, vec3(2.0, 1.5, 0.0), 0.3, GREEN, 0);
    let triangle = [vec3(-1.5, -2.0, 0.0), vec3(1.5, -2.0, 0.0), vec3(0.0, -0.5, 0.0)];
    let container = container(vec![l], Vec::new(), Some(triangle));
    let camera = Camera::look_at(vec3(0.0, 0.0, 10.0), Vec3::ZERO, 0.6, 256, 256);
    let exact = exact_silhouette(&camera, &[l]);
    for lines in [true, false] {
        let mut renderer = renderer(&gpu, &[&container], Settings { lines, ..Settings::default() });
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        keep(&image, &format!("line-bark-{lines}"));
        let greens = image.rgba.chunks_exact(4).filter(|p| p[1] > p[0].saturating_add(20)).count();
        let reds = image.rgba.chunks_exact(4).filter(|p| p[0] > p[1].saturating_add(20)).count();
        eprintln!("lines {lines}: {stats:?}; {greens} green, {reds} red pixels");
        assert_eq!(stats.instances.get(Technique::Ellipsoids), 1);
        let bark = renderer.draws().iter().filter(|d| d.source == DrawSource::Bark).count();
        if lines {
            assert_eq!(
                (stats.submitted[Primitive::Line], stats.submitted[Primitive::Triangle], bark),
                (1, 0, 0),
                "the line, not the bark triangles"
            );
            assert!(reds == 0 && greens.abs_diff(count(&exact)) < count(&exact) / 20, "{greens} of {}", count(&exact));
        } else {
            assert_eq!(
                (stats.submitted[Primitive::Line], stats.submitted[Primitive::Triangle], bark),
                (0, 1, 1),
                "the bark triangles, not the line"
            );
            assert!(greens == 0 && reds > 1000, "{reds} red");
        }
    }
}

/// The demo tree's far lines (spec §6.9.1), its leaves hidden (every ellipsoid of zero radii), as
/// drawn through the renderer: just past the switch the far lines draw what the cells' lines
/// draw (the file without `FAR_LINES` draws the cells' lines at every distance), so the images
/// agree; farther away they submit fewer lines than the cells and still cover the bark's pixels
/// as the cells' lines do. A far draw indexing the wrong records (the lines are uploaded `LINES`
/// then `FAR_LINES`) would draw other lines.
#[test]
fn far_trees_draw_the_far_lines_where_they_match_the_cells_lines() {
    use treelod_format::ContainerData;
    let gpu = gpu();
    let built = common::demo_built(&treelod_build::BuildConfig {
        lines: Some(treelod_build::LineConfig::default()),
        ellipsoids: Some(treelod_build::EllipsoidConfig::default()),
        ..treelod_build::BuildConfig::default()
    });
    let mut data = ContainerData::from_container(&built);
    for e in &mut data.ellipsoids {
        e.radii = [0.0; 3];
    }
    assert!(!data.far_lines.is_empty(), "the demo tree has far lines");
    let with_far = common::open_verified(&data);
    let cells_only =
        common::open_verified(&ContainerData { far_lines: Vec::new(), far_line_ao: Vec::new(), ..data.clone() });
    let lod = treelod_runtime::LineLod::from_container(&with_far).expect("lines");
    // Quality 1/8: τ is 8 times the metres per pixel, so at the same τ the tree is 8 times larger
    // on screen than with quality 1 (at the switch the demo tree is about 10 pixels high).
    let settings = Settings { ellipsoid_quality: 0.125, ..Settings::default() };
    let from = lod.far_from().expect("far lines");
    let (min, max) = (Vec3::from_array(data.block.bounds_min), Vec3::from_array(data.block.bounds_max));
    let (centre, radius) = (0.5 * (min + max), 0.5 * (max - min).length());
    // A narrow view from afar, so every cell is at about one τ: the nearest cell's τ at `tau`.
    let (fovy, size) = (0.05_f32, 160);
    let per_metre = 2.0 * (0.5 * fovy).tan() / size as f32;
    let draw = |container: &Arc<Container>, tau: f32| {
        let mut renderer = renderer(&gpu, &[container], settings);
        let eye = centre + Vec3::Z * (tau * settings.ellipsoid_quality / per_metre + radius);
        let camera = Camera::look_at(eye, centre, fovy, size, size);
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        (image, stats.submitted[Primitive::Line])
    };
    // (Just past the switch the far prefix also holds the coarser far levels, culled by the
    // vertex shader, as every prefix holds its coarser levels: it submits more than it draws.)
    let (far, _) = draw(&with_far, from * 1.02);
    let (cells, _) = draw(&cells_only, from * 1.02);
    let (diff, any) = common::differing(&far, &cells);
    assert!(any > 50, "the bark shows: {any} pixels");
    assert!(diff * 20 <= any, "just past the switch {diff} of {any} pixels differ");
    let (far, far_lines) = draw(&with_far, from * 3.0);
    let (cells, cell_lines) = draw(&cells_only, from * 3.0);
    assert!(2 * far_lines <= cell_lines, "{far_lines} far lines submitted against the cells' {cell_lines}");
    let (p, r) = common::precision_recall(&far, &cells);
    assert!(p > 0.5 && r > 0.5, "farther, the far lines cover the cells' lines' pixels: P {p:.2} R {r:.2}");
    keep(&far, "far-lines");
}
