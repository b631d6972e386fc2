//! Level blending of Clasen's ellipsoids and branch lines (`Settings::level_blend`) on the Vulkan
//! backend (Mesa lavapipe in CI), from synthetic containers of two levels: a blue fine level
//! `[0, e)` partly outside a red coarse one `[e, ∞)`, drawn from distances that put `τ` at
//! `e · 2^{−1, −0.2, 0, 0.2, 1}`.
//!
//! Each level's exact silhouette at a distance is the image of that level alone (no blend, the
//! quality factor moving `τ` far to one side: the camera stays). With a blend of `β` octaves the
//! fine level's weight is `w = clamp(log2(e/τ)/β + ½, 0, 1)`: where only the fine level covers a
//! pixel it shows on `w` of them, where only the coarse one `1 − w`, and where both do every pixel
//! shows exactly one of them, the fine one on `w` (both drawn, the nearer fine level would win
//! the depth test nearly everywhere).

mod common;

use std::sync::Arc;

use common::{BACKGROUND, count, gpu, keep, light_taken};
use glam::{Mat4, Vec3, vec3};
use treelod_format::{CellRecord, Container, EllipsoidRecord, LineRecord, Range};
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, Image, render_image, render_prepared_scene};
use treelod_render::{Camera, DrawSource, Ground, Renderer, Settings, Shadows, Technique};
use treelod_runtime::{EllipsoidLod, Frustum, LodSettings};

const RED: u32 = 0xFF19_19CC;
const BLUE: u32 = 0xFFCC_3319;
const FOVY: f32 = 0.35;
const SIZE: u32 = 256;

/// Metres per pixel at `d` metres: `τ` of the block cell (anchored at the origin) seen from `d`.
fn mpp(d: f32) -> f32 {
    d * 2.0 * (0.5 * FOVY).tan() / SIZE as f32
}

/// The level boundary: the pixel size at 20 m.
fn boundary() -> f32 {
    mpp(20.0)
}

/// The octaves of `τ` from `e` the tests look from.
const OCTAVES: [f32; 5] = [-1.0, -0.2, 0.0, 0.2, 1.0];

/// A sphere-like ellipsoid of colour `color` over `[lo, hi)` standing for leaves `leaves`.
fn ellipsoid(center: Vec3, radii: Vec3, color: u32, (lo, hi): (f32, f32), leaves: (u32, u32)) -> EllipsoidRecord {
    EllipsoidRecord {
        center: center.to_array(),
        radii: radii.to_array(),
        orientation: [0, 0, 0, i16::MAX],
        color,
        alpha_threshold: 0.0,
        noise_mip: 4.0,
        lo,
        hi,
        leaf_first: leaves.0,
        leaf_count: leaves.1,
        flags: 0,
    }
}

/// Two levels of ellipsoids switching at `e`: a red coarse one about the origin, four blue
/// spheres sticking out of it (and in front of it, towards +z).
fn two_levels_of_ellipsoids(e: f32) -> Vec<EllipsoidRecord> {
    let mut records = vec![ellipsoid(Vec3::ZERO, vec3(2.0, 1.5, 1.0), RED, (e, f32::INFINITY), (0, 4))];
    for (k, (x, y)) in [(-1.4, -0.9), (1.4, -0.9), (-1.4, 0.9), (1.4, 0.9)].into_iter().enumerate() {
        records.push(ellipsoid(vec3(x, y, 0.6), Vec3::splat(0.8), BLUE, (0.0, e), (k as u32, 1)));
    }
    records
}

/// Two levels of lines switching at `e`: one red straight line, two blue ones bent up through
/// a point above it (and in front of it).
fn two_levels_of_lines(e: f32) -> Vec<LineRecord> {
    let line = |p0: Vec3, p1: Vec3, r: f32, color: u32, interval: (f32, f32), segments: (u32, u32)| {
        common::line_record(p0, r, p1, r, color, interval, segments)
    };
    let (a, m, b) = (vec3(-2.2, -0.6, 0.0), vec3(0.0, 0.7, 0.4), vec3(2.2, -0.3, 0.0));
    vec![
        line(a, b, 0.35, RED, (e, f32::INFINITY), (0, 2)),
        line(a, m, 0.3, BLUE, (0.0, e), (0, 1)),
        line(m, b, 0.3, BLUE, (0.0, e), (1, 1)),
    ]
}

/// A 1×1×1 block over `[-10, 10]³` whose block cell holds `ellipsoids` and `lines` (with no
/// ellipsoids, one of zero radii: a tree drawn with ellipsoids that shows no leaf); verified.
fn container(mut ellipsoids: Vec<EllipsoidRecord>, lines: Vec<LineRecord>) -> Arc<Container> {
    let mut data = common::one_cell_block("blend", None);
    let (mut lo, mut hi) = (Vec3::ZERO, Vec3::ZERO);
    for p in ellipsoids.iter().map(|e| e.center).chain(lines.iter().flat_map(|l| [l.p0, l.p1])) {
        lo = lo.min(Vec3::from_array(p));
        hi = hi.max(Vec3::from_array(p));
    }
    if ellipsoids.is_empty() {
        ellipsoids.push(ellipsoid(Vec3::ZERO, Vec3::ZERO, RED, (0.0, f32::INFINITY), (0, 1)));
    }
    data.cells.push(CellRecord {
        bounds_min: lo.to_array(),
        bounds_max: hi.to_array(),
        ellipsoids: Range { first: 0, count: ellipsoids.len() as u32 },
        lines: Range { first: 0, count: lines.len() as u32 },
        ..CellRecord::default()
    });
    data.ellipsoids = ellipsoids;
    data.lines = lines;
    common::open_verified(&data)
}

/// The camera on +z looking at the origin from `τ = e · 2^octaves`.
fn camera_at(octaves: f32) -> Camera {
    let distance = 20.0 * octaves.exp2();
    Camera::look_at(vec3(0.0, 0.0, distance), Vec3::ZERO, FOVY, SIZE, SIZE)
}

/// Per pixel: the level shown (`Some(true)` the blue fine one, `Some(false)` the red coarse one)
/// or `None` (background).
fn levels(image: &Image) -> Vec<Option<bool>> {
    image
        .rgba
        .chunks_exact(4)
        .map(|p| {
            if p[0] >= 250 && p[1] >= 250 && p[2] >= 250 {
                None
            } else if p[2] > p[0].saturating_add(20) {
                Some(true)
            } else if p[0] > p[2].saturating_add(20) {
                Some(false)
            } else {
                panic!("a pixel neither red nor blue: {p:?}")
            }
        })
        .collect()
}

/// The share of the pixels of `region` where `shown` holds.
fn share(region: &[bool], shown: impl Fn(usize) -> bool) -> f64 {
    let n = count(region);
    let hits = region.iter().enumerate().filter(|(i, r)| **r && shown(*i)).count();
    hits as f64 / n.max(1) as f64
}

/// The fine level's weight at `τ = e · 2^octaves` with a blend of `β` octaves.
fn fine_weight(octaves: f32, blend: f32) -> f64 {
    f64::from((-octaves / blend + 0.5).clamp(0.0, 1.0))
}

/// What one level's image and the blended images measure at each of [`OCTAVES`]: returns the
/// fine level's share of the pixels both levels cover.
fn check_blend(gpu: &Gpu, name: &str, container: &Arc<Container>, source: DrawSource) -> Vec<f64> {
    let e = boundary();
    let mut renderer =
        common::one_tree(gpu, container, Settings { technique: Technique::Ellipsoids, ..Settings::default() });
    let mut render = |octaves: f32, blend: f32, quality: f32| {
        let settings = renderer.settings_mut();
        settings.level_blend = blend;
        settings.ellipsoid_quality = quality;
        let camera = camera_at(octaves);
        let (image, stats) = render_image(gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        let tau = renderer.draws().iter().find(|d| d.source == source).map(|d| d.tau_points).expect("a draw");
        assert!((tau * quality / (e * octaves.exp2()) - 1.0).abs() < 1e-3, "τ {tau} at {octaves} octaves");
        (image, stats)
    };
    let mut fine_shares = Vec::new();
    for octaves in OCTAVES {
        // The levels alone: τ two octaves from e either way.
        let fine = levels(&render(octaves, 0.0, 4.0 * octaves.exp2()).0);
        let coarse = levels(&render(octaves, 0.0, 0.25 * octaves.exp2()).0);
        assert!(fine.iter().all(|l| *l != Some(false)) && coarse.iter().all(|l| *l != Some(true)));
        let f: Vec<bool> = fine.iter().map(Option::is_some).collect();
        let c: Vec<bool> = coarse.iter().map(Option::is_some).collect();
        let only = |a: &[bool], b: &[bool]| a.iter().zip(b).map(|(x, y)| *x && !*y).collect::<Vec<_>>();
        let (fine_only, coarse_only) = (only(&f, &c), only(&c, &f));
        let both: Vec<bool> = f.iter().zip(&c).map(|(x, y)| *x && *y).collect();
        let neither: Vec<bool> = f.iter().zip(&c).map(|(x, y)| !*x && !*y).collect();
        let regions = [count(&fine_only), count(&coarse_only), count(&both)];
        assert!(regions.iter().all(|n| *n > 300), "{name}: regions {regions:?} at {octaves} octaves");

        // Blended.
        let (image, stats) = render(octaves, 0.5, 1.0);
        keep(&image, &format!("blend-{name}-{octaves}"));
        let shown = levels(&image);
        let w = fine_weight(octaves, 0.5);
        let fine_only_shown = share(&fine_only, |i| shown[i] == Some(true));
        let coarse_only_shown = share(&coarse_only, |i| shown[i] == Some(false));
        let both_covered = share(&both, |i| shown[i].is_some());
        let both_fine = share(&both, |i| shown[i] == Some(true));
        let stray = share(&neither, |i| shown[i].is_some());
        let wrong = share(&fine_only, |i| shown[i] == Some(false)) + share(&coarse_only, |i| shown[i] == Some(true));
        eprintln!(
            "{name} at e·2^{octaves}: w_fine {w:.2}, fine-only shown {fine_only_shown:.3}, coarse-only shown \
             {coarse_only_shown:.3}, both: covered {both_covered:.3}, fine {both_fine:.3}; regions {regions:?}; \
             {} submitted",
            stats.submitted[Primitive::Ellipsoid] + stats.submitted[Primitive::Line],
        );
        let tolerance = 0.06;
        assert!((fine_only_shown - w).abs() < tolerance, "{name} {octaves}: fine-only {fine_only_shown:.3}");
        assert!((coarse_only_shown - (1.0 - w)).abs() < tolerance, "{name} {octaves}: coarse-only");
        assert!(both_covered > 0.995, "{name} {octaves}: holes where both levels cover: {both_covered:.3}");
        assert!((both_fine - w).abs() < tolerance, "{name} {octaves}: fine where both cover {both_fine:.3}");
        assert!(stray < 0.002 && wrong < 0.002, "{name} {octaves}: {stray:.4} outside, {wrong:.4} wrong level");
        // Far from e the one level shows, as with no blend.
        if octaves.abs() >= 1.0 {
            let hard = levels(&render(octaves, 0.0, 1.0).0);
            let same = shown.iter().zip(&hard).filter(|(a, b)| a == b).count();
            assert!(same as f64 / shown.len() as f64 > 0.999, "{name} {octaves}: as without a blend");
        }
        // No blend: the hard switch either side of e.
        if octaves != 0.0 {
            let hard = levels(&render(octaves, 0.0, 1.0).0);
            let fine_level = octaves < 0.0;
            assert!(hard.iter().all(|l| l.is_none() || *l == Some(fine_level)), "{name} {octaves}: hard switch");
        }
        fine_shares.push(both_fine);
    }
    assert!(fine_shares.windows(2).all(|w| w[0] > w[1]), "{name}: the fine level gives way: {fine_shares:?}");
    fine_shares
}

#[test]
fn ellipsoid_levels_blend_on_complementary_pixels_across_their_boundary() {
    let gpu = gpu();
    let container = container(two_levels_of_ellipsoids(boundary()), Vec::new());
    let shares = check_blend(&gpu, "ellipsoids", &container, DrawSource::Ellipsoids);
    eprintln!("ellipsoids: the fine level's share where both cover: {shares:?}");
}

#[test]
fn line_levels_blend_on_complementary_pixels_across_their_boundary() {
    let gpu = gpu();
    let container = container(Vec::new(), two_levels_of_lines(boundary()));
    let shares = check_blend(&gpu, "lines", &container, DrawSource::Lines);
    eprintln!("lines: the fine level's share where both cover: {shares:?}");
}

#[test]
fn the_prefix_holds_the_level_fading_out_and_drops_it_past_the_band() {
    let gpu = gpu();
    let e = boundary();
    let container = container(two_levels_of_ellipsoids(e), two_levels_of_lines(e));
    let mut renderer =
        common::one_tree(&gpu, &container, Settings { technique: Technique::Ellipsoids, ..Settings::default() });
    // β = 0.5: the fine level is submitted up to a quarter octave past e.
    for (octaves, blend, submitted) in
        [(0.2, 0.5, (5, 3)), (0.2, 0.0, (1, 1)), (0.3, 0.5, (1, 1)), (-0.2, 0.0, (5, 3)), (0.2, 1.0, (5, 3))]
    {
        renderer.settings_mut().level_blend = blend;
        let (_, stats) = render_image(&gpu, &mut renderer, &camera_at(octaves), BACKGROUND).expect("renders");
        assert_eq!(
            (stats.submitted[Primitive::Ellipsoid], stats.submitted[Primitive::Line]),
            submitted,
            "e·2^{octaves}, β {blend}"
        );
    }
}

#[test]
fn with_msaa_a_blended_pixel_covers_its_share_of_the_samples() {
    let gpu = gpu();
    let e = boundary();
    let container = container(two_levels_of_ellipsoids(e), Vec::new());
    let settings = Settings { technique: Technique::Ellipsoids, ..Settings::default() };
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats_msaa(4), settings);
    let tree = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("uploads");
    renderer.set_instances(&[treelod_render::Instance { model: tree, transform: Mat4::IDENTITY }]);
    let camera = camera_at(0.0);
    // The fine level alone, single-sampled, gives its silhouette.
    let mut alone =
        common::one_tree(&gpu, &container, Settings { technique: Technique::Ellipsoids, ..Settings::default() });
    alone.settings_mut().level_blend = 0.0;
    alone.settings_mut().ellipsoid_quality = 4.0;
    let fine = levels(&render_image(&gpu, &mut alone, &camera, BACKGROUND).expect("renders").0);
    alone.settings_mut().ellipsoid_quality = 0.25;
    let coarse = levels(&render_image(&gpu, &mut alone, &camera, BACKGROUND).expect("renders").0);
    let (image, _) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    keep(&image, "blend-msaa");
    // At τ = e each level has half of every pixel's samples: inside the fine level's silhouette
    // (away from its edge) and outside the coarse one's, every pixel is blue half blended with
    // the white background, none fully blue and none white.
    let (mut inside, mut half) = (0, 0);
    for y in 1..SIZE - 1 {
        for x in 1..SIZE - 1 {
            let at = |dx: i32, dy: i32| ((y as i32 + dy) as u32 * SIZE + (x as i32 + dx) as u32) as usize;
            let interior = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .all(|&(dx, dy)| fine[at(dx, dy)].is_some() && coarse[at(dx, dy)].is_none());
            if !interior {
                continue;
            }
            inside += 1;
            let p = image.pixel(x, y);
            // Blue (about 51 in red) over white: a half-covered pixel's red is about 150.
            if (110..=200).contains(&p[0]) {
                half += 1;
            }
        }
    }
    let ratio = f64::from(half) / f64::from(inside.max(1));
    eprintln!("MSAA at τ = e: {half} of {inside} fine-only interior pixels half covered ({ratio:.3})");
    assert!(inside > 300 && ratio > 0.97, "{half} of {inside}");
}

#[test]
fn the_shadow_pass_blends_the_levels_alike() {
    let gpu = gpu();
    let sun = vec3(0.3, 0.9, 0.2).normalize();
    let shadows = Shadows { resolution: 1024, cascades: 1, distance: 40.0, ..Shadows::default() };
    let settings = Settings { technique: Technique::Ellipsoids, sun, shadows: Some(shadows), ..Settings::default() };
    // The trees float above the ground (the block's floor is at y = −10): lifted by 5 m.
    let lift = Mat4::from_translation(vec3(0.0, -5.0, 0.0));
    let centre = vec3(0.0, -5.0, 0.0) - sun * (5.0 / sun.y);
    let camera = Camera::look_at(centre + vec3(0.0, 14.0, 0.1), centre, 0.7, SIZE, SIZE);
    // The light the trees of `models` (each a list of ellipsoids) take from the ground, the τ
    // of the first one's block cell in the cascade, and the ellipsoids submitted to the shadow.
    let shadow = |models: Vec<Vec<EllipsoidRecord>>, blend: f32| {
        let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings { level_blend: blend, ..settings });
        let containers: Vec<_> = models.into_iter().map(|m| container(m, Vec::new())).collect();
        let trees: Vec<_> = containers
            .iter()
            .map(|c| treelod_render::Instance {
                model: renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(c)).expect("uploads"),
                transform: lift,
            })
            .collect();
        renderer.set_instances(&trees);
        let container = &containers[0];
        let ground = Ground::new(&gpu.device, &renderer, vec3(0.0, -10.0, 0.0), 14.0);
        let mut frame = |on: bool| {
            renderer.settings_mut().shadows = on.then_some(shadows);
            let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
            let (image, _) =
                render_prepared_scene(&gpu, &mut renderer, &camera, BACKGROUND, Some(&ground), true).expect("renders");
            (image, stats)
        };
        let (lit, _) = frame(false);
        let (shadowed, stats) = frame(true);
        // The cascade's τ at the block cell, as the renderer selects it.
        let light = renderer.shadow_cascades()[0].selection_camera();
        let lod = EllipsoidLod::from_container(container).expect("ellipsoids");
        let mut ranges = Vec::new();
        let frustum = Frustum::from_view_proj(light.view_proj);
        assert!(lod.select_per_pixel(lift, &light, &frustum, &LodSettings::default(), 1.0, &mut ranges));
        (light_taken(&shadowed, &lit), ranges[0].tau, stats.shadow.submitted[Primitive::Ellipsoid], shadowed)
    };
    // The shadow's τ does not depend on the levels' intervals: find it, then put the boundary on it.
    let (_, tau, _, _) = shadow(vec![two_levels_of_ellipsoids(1.0)], 0.0);
    let (fine, _, _, _) = shadow(vec![two_levels_of_ellipsoids(4.0 * tau)], 0.5);
    let (coarse, _, _, _) = shadow(vec![two_levels_of_ellipsoids(0.25 * tau)], 0.5);
    let (hard, _, hard_submitted, _) = shadow(vec![two_levels_of_ellipsoids(tau * 1.001)], 0.0);
    let (blended, _, submitted, image) = shadow(vec![two_levels_of_ellipsoids(tau)], 0.5);
    keep(&image, "blend-shadow");
    // Both levels drawn whole, as two trees (what a blend that did not split the texels between
    // them would approach).
    let levels = two_levels_of_ellipsoids(1.0);
    let (coarse_level, fine_level) = levels.split_at(1);
    let whole = |level: &[EllipsoidRecord]| {
        let mut level = level.to_vec();
        level.iter_mut().for_each(|e| (e.lo, e.hi) = (0.0, f32::INFINITY));
        level
    };
    let (union, _, _, _) = shadow(vec![whole(coarse_level), whole(fine_level)], 0.0);
    let mean = 0.5 * (fine + coarse);
    eprintln!(
        "shadow (τ {tau:.5}): light taken fine {fine:.0}, coarse {coarse:.0}, blended at τ = e {blended:.0} \
         (mean {mean:.0}), both levels whole {union:.0}, no blend {hard:.0}; {submitted} ellipsoids submitted \
         ({hard_submitted} without blend)"
    );
    assert_eq!((submitted, hard_submitted), (5, 5));
    assert!(union - mean > 0.08 * mean, "the test tells the two apart: union {union:.0}, mean {mean:.0}");
    assert!((blended - mean).abs() < 0.04 * mean, "blended {blended:.0}, mean {mean:.0}");
    assert!((hard - fine).abs() < 0.02 * fine, "no blend just below e: the fine level, {hard:.0} vs {fine:.0}");
}
