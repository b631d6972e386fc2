//! Calibration (spec §6.15) through the whole build: every representation the demo tree is built
//! with gets a row at each height, the table verifies, is the same whatever the thread count, and
//! says what is known of the representations (the full mesh's cost is its triangle count, the point
//! tree converges to the full mesh up close and costs far less far away, a billboard is worse up
//! close than far away).

use glam::Vec3;
use treelod_build::calibrate::{
    CalibrationConfig, ELEVATIONS, HEIGHTS, calibrate, calibration_views, down_views_at, splat_seeds_at, views_at,
};
use treelod_build::{
    BuildConfig, DemoTreeConfig, EllipsoidConfig, ImpostorConfig, LineConfig, LodChainConfig, Placed, build_block,
    demo_tree,
};
use treelod_format::{CalibrationRecord, Compression, Container, calibration_technique as t, verify};
use treelod_runtime::{Calibration, Technique};

fn config() -> BuildConfig {
    BuildConfig {
        impostors: Some(ImpostorConfig::default()),
        ellipsoids: Some(EllipsoidConfig::default()),
        baselines: Some(LodChainConfig::default()),
        calibration: Some(CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() }),
        ..BuildConfig::default()
    }
}

fn row(records: &[CalibrationRecord], technique: u32) -> Vec<CalibrationRecord> {
    records.iter().filter(|r| r.technique == technique).copied().collect()
}

#[test]
fn the_demo_tree_is_calibrated_for_every_representation_it_holds() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let out = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let records = &out.data.calibration;
    for technique in [t::FULL, t::SPT, t::IMPOSTORS, t::ELLIPSOIDS, t::LOD_CHAIN, t::BILLBOARD, t::CROSSED] {
        let heights: Vec<f32> = row(records, technique).iter().map(|r| r.height).collect();
        assert_eq!(heights, HEIGHTS, "{:?}", t::name(technique));
    }
    assert!(row(records, t::PRUNE_OPT).is_empty(), "built without pruning: no pruning rows");

    // Written, it opens and verifies, and dump's reader returns the same records.
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    let container = Container::from_bytes(&bytes).expect("opens");
    assert_eq!(container.calibration(), records.as_slice());
    assert_eq!(container.calibration_elevations(), out.data.calibration_elevations.as_slice());
    assert_eq!(container.chain_calibration(), out.data.chain_calibration.as_slice());
    // CALIBRATION is a kind of 1.5, the impostors' BC7 atlas (the default) one of 1.6,
    // CALIBRATION_ELEVATIONS one of 1.7, the chain's per-level tables (CHAIN_CALIBRATION) one of
    // 1.8, the planes' diffuse response (PLANE_DIFFUSE) one of 1.10, the octahedral impostors of
    // the baselines (OCTAHEDRAL) one of 1.11, their calibration (CALIBRATION_ADDED) one of 1.12,
    // their views' depth planes (OCTAHEDRAL_DEPTH) one of 1.13, the points' facing (POINT_FACING)
    // one of 1.14, and the views' normals at half resolution (OCTAHEDRAL_NORMAL_GRIDS) make the
    // file 1.16.
    assert!(!container.chain_calibration().is_empty() && !container.plane_diffuse().is_empty());
    assert!(!container.octahedral().is_empty() && !container.octahedral_depth().is_empty());
    assert_eq!(container.octahedral_normal_grids().len(), container.octahedral().len());
    assert!(container.octahedral_normals().is_empty(), "one of the two kinds");
    assert_eq!(container.point_facing().len(), container.points().len());
    assert_eq!(container.calibration_added(), out.data.calibration_added.as_slice());
    // Built with FLIP (the `flip` feature, which the command line enables), the calibration's
    // FLIP error of every row of the four tables (CALIBRATION_FLIP, a kind of 1.17) and of every
    // record of the chain's per-level tables (CHAIN_CALIBRATION_FLIP) make it 1.18.
    let d = &out.data;
    let mut rows: Vec<(f32, u32, f32)> =
        d.calibration.iter().chain(&d.calibration_added).map(|r| (-1.0, r.technique, r.height)).collect();
    rows.extend(
        d.calibration_elevations
            .iter()
            .chain(&d.calibration_elevations_added)
            .map(|r| (r.elevation, r.technique, r.height)),
    );
    if cfg!(feature = "flip") {
        let flip: Vec<(f32, u32, f32)> =
            container.calibration_flip().iter().map(|r| (r.elevation, r.technique, r.height)).collect();
        assert!(flip.iter().all(|r| rows.contains(r)), "each FLIP row is a table's row");
        assert_eq!(flip.len(), rows.len(), "a FLIP error per row");
        assert!(container.calibration_flip().iter().all(|r| r.flip > 0.0 && r.flip < 1.0));
        let levels: Vec<(u32, f32)> = d.chain_calibration.iter().map(|r| (r.level, r.height)).collect();
        let level_flips: Vec<(u32, f32)> =
            container.chain_calibration_flip().iter().map(|r| (r.level, r.height)).collect();
        assert_eq!(level_flips, levels, "a FLIP error per level and height");
        assert!(container.chain_calibration_flip().iter().all(|r| r.flip > 0.0 && r.flip < 1.0));
        assert_eq!(container.header().minor, 18, "the chain levels' FLIP error is a kind of 1.18");
    } else {
        assert!(container.calibration_flip().is_empty() && container.chain_calibration_flip().is_empty());
        assert_eq!(container.header().minor, 16, "the views' normal grids are a kind of 1.16");
    }
    verify(&container).expect("verifies");

    // The full mesh draws every triangle at every height.
    let triangles = out.data.triangles.len() as f32;
    assert!(row(records, t::FULL).iter().all(|r| r.primitives == triangles));
    // The point tree draws fewer primitives the smaller the tree, far fewer than the mesh at 8
    // pixels, and at the largest height it is the full mesh's image.
    let spt = row(records, t::SPT);
    assert!(spt.windows(2).all(|w| w[0].primitives <= w[1].primitives), "{spt:?}");
    assert!(spt[0].primitives < 0.2 * triangles, "{spt:?}");
    let full_near = row(records, t::FULL)[HEIGHTS.len() - 1].error;
    assert!(spt[HEIGHTS.len() - 1].error <= full_near * 1.2 + 1e-3, "{spt:?} vs {full_near}");
    // One quad is the whole tree: a poorer image up close than at 8 pixels, and poorer than the
    // point tree up close.
    let billboard = row(records, t::BILLBOARD);
    assert!(billboard.iter().all(|r| r.primitives == 1.0));
    assert!(billboard[HEIGHTS.len() - 1].error > billboard[0].error, "{billboard:?}");
    assert!(billboard[HEIGHTS.len() - 1].error > 2.0 * spt[HEIGHTS.len() - 1].error, "{billboard:?} {spt:?}");
}

#[test]
fn calibration_is_the_same_whatever_the_thread_count() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool");
        pool.install(|| {
            calibrate(
                &built.data,
                &CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() },
            )
        })
    };
    let one = with(1);
    assert!(!one.mean.is_empty() && !one.elevations.is_empty() && !one.chain_levels.is_empty());
    assert_eq!(one, with(3));
    assert_eq!(one.mean, built.data.calibration, "the build's table is the calibration of what it wrote");
    assert_eq!(one.elevations, built.data.calibration_elevations);
    assert!(!one.added.is_empty(), "the octahedral impostors' rows");
    assert_eq!(one.added, built.data.calibration_added);
    assert_eq!(one.elevations_added, built.data.calibration_elevations_added);
    assert_eq!(one.chain_levels, built.data.chain_calibration, "and so are the chain's levels");
}

#[test]
fn heights_under_64_pixels_take_more_views_and_the_metadata_records_them() {
    assert_eq!(HEIGHTS.map(|h| views_at(2, h)), [16, 16, 8, 4, 2, 2, 2]);
    assert_eq!(HEIGHTS.map(|h| views_at(1, h)), [8, 8, 4, 2, 1, 1, 1]);
    assert_eq!(views_at(2, 2.0), 16, "at most 8 times the views");
    let setting = |config: &CalibrationConfig| {
        config.settings().into_iter().find(|s| s.key == "calibration.views_by_height").map(|s| s.value)
    };
    assert_eq!(setting(&CalibrationConfig::default()).as_deref(), Some("16,16,8,4,2,2,2"));
    let fixed = CalibrationConfig { more_small_views: false, ..CalibrationConfig::default() };
    assert_eq!(setting(&fixed).as_deref(), Some("2,2,2,2,2,2,2"));
    assert_eq!(HEIGHTS.map(down_views_at), [8, 8, 4, 2, 1, 1, 1], "straight down too");
    let down = |config: &CalibrationConfig| {
        config.settings().into_iter().find(|s| s.key == "calibration.views_down_by_height").map(|s| s.value)
    };
    assert_eq!(down(&CalibrationConfig::default()).as_deref(), Some("8,8,4,2,1,1,1"));
    assert_eq!(down(&fixed).as_deref(), Some("1,1,1,1,1,1,1"));
    // So many draws of the point tree's splats per view, each kept by another hash.
    assert_eq!(HEIGHTS.map(splat_seeds_at), [8, 8, 4, 2, 1, 1, 1]);
    let seeds = |config: &CalibrationConfig| {
        config.settings().into_iter().find(|s| s.key == "calibration.splat_seeds_by_height").map(|s| s.value)
    };
    assert_eq!(seeds(&CalibrationConfig::default()).as_deref(), Some("8,8,4,2,1,1,1"));
    assert_eq!(seeds(&fixed).as_deref(), Some("1,1,1,1,1,1,1"));
    // The views straight down are one direction, each turned a step of a full turn further.
    let views = calibration_views(2, 4);
    let straight_down: Vec<_> = views.iter().filter(|v| ELEVATIONS[v.elevation] >= 90.0).collect();
    assert_eq!(views.len(), 3 * 2 + 4);
    assert!(straight_down.iter().all(|v| v.direction == Vec3::Y));
    let rolls: Vec<f32> = straight_down.iter().map(|v| v.roll.to_degrees().round()).collect();
    assert_eq!(rolls, [0.0, 90.0, 180.0, 270.0]);
    assert!(views.iter().filter(|v| ELEVATIONS[v.elevation] < 90.0).all(|v| v.roll == 0.0));

    // The same tree calibrated both ways: from 64 pixels up the same views and the same rows; below,
    // more views, and rows that are their mean (at least one differs).
    let scene = demo_tree(&DemoTreeConfig { leaves: 400, ..DemoTreeConfig::default() });
    let built = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let one = CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() };
    let (fixed, more) =
        (calibrate(&built.data, &one), calibrate(&built.data, &CalibrationConfig { more_small_views: true, ..one }));
    assert_eq!(fixed.mean.len(), more.mean.len());
    let mut differ = 0;
    for (a, b) in fixed.mean.iter().zip(&more.mean) {
        assert_eq!((a.technique, a.height), (b.technique, b.height));
        if a.height >= 64.0 {
            assert_eq!(a, b, "from 64 pixels up one view per elevation either way");
        } else {
            differ += usize::from(a.error != b.error);
        }
    }
    assert!(differ > 0, "the small heights' rows are measured from more views");

    // Over every view the views straight down weigh as one view, however many they are: each row
    // of `CALIBRATION` is the elevations' rows weighted by their views around the tree and one.
    for (h, &height) in HEIGHTS.iter().enumerate() {
        let n = one.views_at(height) as f32;
        let n_more = CalibrationConfig { more_small_views: true, ..one }.views_at(height) as f32;
        for (calibrated, n) in [(&fixed, n), (&more, n_more)] {
            for mean in calibrated.mean.iter().filter(|r| r.height == height) {
                let per_elevation: Vec<f32> = calibrated
                    .elevations
                    .iter()
                    .filter(|r| r.technique == mean.technique && r.height == height)
                    .map(|r| r.error)
                    .collect();
                assert_eq!(per_elevation.len(), ELEVATIONS.len());
                let sides: f32 = per_elevation[..3].iter().sum();
                let weighted = (n * sides + per_elevation[3]) / (3.0 * n + 1.0);
                assert!(
                    (weighted - mean.error).abs() <= 1e-5 * mean.error.max(1e-3),
                    "{} at {height} px (index {h}): {} over every view, {weighted} from the elevations",
                    t::name(mean.technique).unwrap_or("?"),
                    mean.error
                );
            }
        }
    }
}

#[test]
fn a_build_without_calibration_writes_none() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig::default();
    let out = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").expect("builds");
    assert!(out.data.calibration.is_empty());
    assert!(out.data.chain_calibration.is_empty());
    assert!(!out.data.metadata.settings.iter().any(|s| s.key.starts_with("calibration.")));
}

#[test]
fn the_error_is_of_the_shaded_image_so_a_darker_representation_reads_worse() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let calibration = CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() };
    let before = row(&calibrate(&built.data, &calibration).mean, t::SPT);
    // The same points, same places and sizes, drawn black: the coverage is unchanged.
    let mut dark = built.data.clone();
    for point in &mut dark.points {
        point.color &= 0xFF00_0000;
    }
    let after = row(&calibrate(&dark, &calibration).mean, t::SPT);
    // Far away the point tree is mostly points: its error grows (measured 0.060 -> 0.072 at 8
    // pixels); near, it is triangles.
    assert!(after[0].error > before[0].error + 0.005, "{before:?} vs {after:?}");
    assert!(before.iter().zip(&after).take(4).all(|(b, a)| a.error > b.error), "{before:?} vs {after:?}");
    assert_eq!(
        before.iter().map(|r| r.primitives).collect::<Vec<_>>(),
        after.iter().map(|r| r.primitives).collect::<Vec<_>>()
    );
    // Ambient occlusion shades the image too: points fully occluded lose the ambient share.
    let mut occluded = built.data.clone();
    occluded.point_ao = vec![255; occluded.points.len()];
    let shaded = row(&calibrate(&occluded, &calibration).mean, t::SPT);
    assert!(shaded[0].error > before[0].error, "{before:?} vs {shaded:?}");
    assert!(built.data.metadata.settings.iter().any(|s| s.key == "calibration.error" && s.value == "colour"));
}

#[test]
fn impostor_rows_count_the_branch_lines_their_trees_draw_in_place_of_the_bark() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig { lines: Some(LineConfig::default()), ..config() };
    let built = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").expect("builds");
    let calibration = CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() };
    let with_lines = row(&built.data.calibration, t::IMPOSTORS);
    // The same container without lines: its impostor trees draw the chain's bark (`ImpostorBark`).
    let mut without = built.data.clone();
    without.lines.clear();
    without.line_ao.clear();
    let bark = row(&calibrate(&without, &calibration).mean, t::IMPOSTORS);
    let lines = (built.data.lines.len() + built.data.far_lines.len() + built.data.planes.len()) as f32;
    for (l, b) in with_lines.iter().zip(&bark) {
        // At most every plane and every line (the runtime's counts are checked below).
        assert!(l.primitives <= lines, "{l:?} vs {} planes and lines", lines);
        eprintln!("{} px: lines {:.4} ({}), bark {:.4} ({})", l.height, l.error, l.primitives, b.error, b.primitives);
        // The image barely changes: measured 0.0554 against 0.0598 at 8 pixels (71 primitives
        // against 928), 0.0428 against 0.0413 at 64 (136 against 3744), 0.0548 against 0.0538
        // at 256.
        assert!(l.error <= 1.1 * b.error, "{l:?} vs {b:?}");
    }
    assert!(with_lines[0].primitives < bark[0].primitives, "{with_lines:?} vs {bark:?}");
}

#[test]
fn the_tables_per_elevation_split_the_mean_and_billboards_read_worse_from_above() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let out = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    let (mean, per_elevation) = (&out.data.calibration, &out.data.calibration_elevations);
    assert_eq!(per_elevation.len(), ELEVATIONS.len() * mean.len(), "every row at every elevation");
    for (e, &elevation) in ELEVATIONS.iter().enumerate() {
        let rows = &per_elevation[e * mean.len()..(e + 1) * mean.len()];
        assert!(rows.iter().all(|r| r.elevation == elevation));
        let keys = |r: (u32, f32)| r;
        assert!(rows.iter().zip(mean).all(|(r, m)| keys((r.technique, r.height)) == (m.technique, m.height)));
    }
    // One view per elevation (the tests' configuration): the mean is the mean of the elevations.
    for (i, m) in mean.iter().enumerate() {
        let of_elevations: f32 =
            (0..ELEVATIONS.len()).map(|e| per_elevation[e * mean.len() + i].error).sum::<f32>() / 4.0;
        assert!((m.error - of_elevations).abs() < 1e-5, "{m:?}: {of_elevations}");
    }
    // Crossed quads are three lines from straight above: worse there than from the side at every
    // height; the point tree differs far less.
    let at = |elevation: f32, technique: u32| -> Vec<f32> {
        per_elevation.iter().filter(|r| r.elevation == elevation && r.technique == technique).map(|r| r.error).collect()
    };
    let (side, top) = (at(0.0, t::CROSSED), at(90.0, t::CROSSED));
    assert!(side.iter().zip(&top).all(|(s, t)| t > s), "crossed from the side {side:?}, from above {top:?}");
    eprintln!("crossed from the side {side:?}, from above {top:?}; spt {:?} {:?}", at(0.0, t::SPT), at(90.0, t::SPT));
    assert!(
        out.data.metadata.settings.iter().any(|s| s.key == "calibration.elevations" && s.value == "0,30,60,90"),
        "the elevations are recorded"
    );
}

#[test]
fn impostor_and_ellipsoid_rows_count_what_the_runtime_submits_with_its_level_blend() {
    use treelod_runtime::{
        Camera, CellPrefix, DEFAULT_LEVEL_BLEND, EllipsoidLod, Frustum, LineLod, LodSettings, PixelLevel, PlaneLod,
    };
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig { lines: Some(LineConfig::default()), ..config() };
    let built = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").expect("builds");
    let container = Container::from_bytes(&built.data.to_bytes(Compression::None).expect("writes")).expect("opens");
    let (planes, lines) = (PlaneLod::from_container(&container).expect("planes"), LineLod::from_container(&container));
    let (ellipsoids, lines) = (EllipsoidLod::from_container(&container).expect("ellipsoids"), lines.expect("lines"));
    let block = container.block();
    let (lo, hi) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
    let (centre, height, radius) = (0.5 * (lo + hi), hi.y - lo.y, 0.5 * (hi - lo).length());
    let level = PixelLevel { quality: 1.0, blend: DEFAULT_LEVEL_BLEND };
    let settings = LodSettings::default();
    let mut blended_lines = 0;
    for (h, (impostors, ellipsoid_row)) in HEIGHTS
        .iter()
        .zip(row(&built.data.calibration, t::IMPOSTORS).iter().zip(&row(&built.data.calibration, t::ELLIPSOIDS)))
    {
        // Far enough that every cell's τ is the block centre's to a twentieth of a percent (the
        // runtime draws a far tree's lines at its nearest cell's τ, `SptLod::far_list`), with
        // the field of view that makes the block `h` pixels high (τ = p = H/h; with one view per
        // elevation every view measures at `h` itself).
        let distance = 2000.0 * radius;
        let fovy = 2.0 * (height * 1000.0 / (2.0 * h * distance)).atan();
        let eye = centre + Vec3::new(0.6, 0.3, 0.8).normalize() * distance;
        let camera = Camera::look_at(eye, centre, fovy, 1000, 1000);
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let model = glam::Mat4::IDENTITY;
        // The primitives of the prefixes a selection appends (it must see the tree).
        let submitted = |select: &dyn Fn(&mut Vec<CellPrefix>) -> bool| {
            let mut out = Vec::new();
            assert!(select(&mut out), "in view");
            out.iter().map(|r| r.count).sum::<u32>() as f32
        };
        let p = submitted(&|out| planes.select(model, &camera, &frustum, 1.0, out));
        let l = submitted(&|out| lines.select_per_pixel_blended(model, &camera, &frustum, &settings, level, out));
        let e = submitted(&|out| ellipsoids.select_per_pixel_blended(model, &camera, &frustum, &settings, level, out));
        let unblended = submitted(&|out| lines.select_per_pixel(model, &camera, &frustum, &settings, 1.0, out));
        blended_lines += u32::from(l > unblended);
        let close = |table: f32, runtime: f32| (table - runtime).abs() <= 0.02 * runtime + 1.0;
        assert!(close(impostors.primitives, p + l), "{h} px: impostors {impostors:?}, runtime {p} planes + {l} lines");
        assert!(
            close(ellipsoid_row.primitives, e + l),
            "{h} px: ellipsoids {ellipsoid_row:?}, runtime {e} ellipsoids + {l} lines"
        );
    }
    // The blend's fading level is what the tables counted too little before.
    assert!(blended_lines >= 2, "the level blend submits more lines at some heights");
}

#[test]
fn octahedral_impostors_are_calibrated_in_the_added_sections_and_hold_up_from_above() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let out = build_block("t", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config(), "t").expect("builds");
    // Codes a reader of 1.5 to 1.11 refuses stay out of CALIBRATION (spec §6.18).
    assert!(out.data.calibration.iter().all(|r| r.technique < t::FIRST_ADDED));
    assert!(out.data.calibration_elevations.iter().all(|r| r.technique < t::FIRST_ADDED));
    let octahedral = row(&out.data.calibration_added, t::OCTAHEDRAL);
    assert_eq!(octahedral.iter().map(|r| r.height).collect::<Vec<_>>(), HEIGHTS);
    assert_eq!(octahedral.len(), out.data.calibration_added.len(), "nothing else is added");
    // One quad per tree.
    assert!(octahedral.iter().all(|r| r.primitives == 1.0), "{octahedral:?}");
    assert_eq!(out.data.calibration_elevations_added.len(), ELEVATIONS.len() * octahedral.len());

    // From straight above the crossed quads are three lines and the facing billboard a card seen
    // edge on, while the octahedral impostor shows the crown as baked from there: it reads better
    // than both at every height; from the side it reads within reach of the crossed quads.
    let at = |elevation: f32, technique: u32| -> Vec<f32> {
        let rows = if technique >= t::FIRST_ADDED {
            &out.data.calibration_elevations_added
        } else {
            &out.data.calibration_elevations
        };
        rows.iter().filter(|r| r.elevation == elevation && r.technique == technique).map(|r| r.error).collect()
    };
    let (top, crossed, facing) = (at(90.0, t::OCTAHEDRAL), at(90.0, t::CROSSED), at(90.0, t::BILLBOARD));
    eprintln!("from above: octahedral {top:?}, crossed {crossed:?}, billboard {facing:?}");
    assert!(top.iter().zip(&crossed).all(|(o, c)| o < c), "{top:?} vs crossed {crossed:?}");
    assert!(top.iter().zip(&facing).all(|(o, f)| o < f), "{top:?} vs billboard {facing:?}");
    let (side, crossed_side) = (at(0.0, t::OCTAHEDRAL), at(0.0, t::CROSSED));
    eprintln!("from the side: octahedral {side:?}, crossed {crossed_side:?}");
    assert!(side.iter().zip(&crossed_side).all(|(o, c)| *o < 1.5 * c), "{side:?} vs crossed {crossed_side:?}");

    // The runtime reads the added rows with the others, per elevation too.
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    let container = Container::from_bytes(&bytes).expect("opens");
    verify(&container).expect("verifies");
    let tables = Calibration::from_container(&container).expect("tables");
    assert!(tables.holds(Technique::Octahedral));
    assert_eq!(tables.elevations(), ELEVATIONS);
    for (e, &elevation) in ELEVATIONS.iter().enumerate() {
        let errors: Vec<f32> =
            HEIGHTS.iter().map(|&h| tables.at_elevation(Some(e), Technique::Octahedral, h).expect("a row").0).collect();
        assert_eq!(errors, at(elevation, t::OCTAHEDRAL), "elevation {elevation}");
        let crossed: Vec<f32> =
            HEIGHTS.iter().map(|&h| tables.at_elevation(Some(e), Technique::Crossed, h).expect("a row").0).collect();
        assert_eq!(crossed, at(elevation, t::CROSSED), "elevation {elevation}");
    }
}

#[test]
fn a_block_far_wider_than_high_is_calibrated_in_the_middle_of_its_views_and_the_build_says_so() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 200, ..DemoTreeConfig::default() });
    let config = BuildConfig {
        calibration: Some(CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() }),
        ..BuildConfig::default()
    };
    let placed = |x: f32| Placed { scene: &scene, translation: Vec3::new(x, 0.0, 0.0) };
    let one = build_block("t", &[placed(0.0)], &config, "t").expect("builds");
    let said = |warnings: &[String]| warnings.iter().any(|w| w.contains("calibration measures the middle"));
    assert!(!said(&one.warnings), "{:?}", one.warnings);
    // The same tree and another 30 of its heights away: one block about 30 heights wide.
    let height = one.data.block.bounds_max[1] - one.data.block.bounds_min[1];
    let two = build_block("t", &[placed(0.0), placed(30.0 * height)], &config, "t").expect("builds");
    assert!(said(&two.warnings), "{:?}", two.warnings);
    // Calibrated all the same: a row per technique and height, every number finite.
    assert_eq!(row(&two.data.calibration, t::SPT).len(), HEIGHTS.len());
    assert!(two.data.calibration.iter().all(|r| r.error.is_finite() && r.primitives.is_finite()));
}
