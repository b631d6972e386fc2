//! Indirect impostor texturing through the command line (spec §6.10.1): `build --impostors
//! --impostor-texturing indirect` writes `PLANE_LEAVES` and a leaf-slot image (format 1.3) for a
//! tree of alpha-tested leaf cards, falls back to the RGBA atlas with a warning for untextured
//! leaves, refuses bad values of its options as usage errors, and `render --impostors` draws the
//! result.

mod common;

use std::path::Path;

use common::{assert_build_usage_errors, model, read_png, run_on, scratch, succeeded, text};
use treelod_format::{Container, image_format};

const AREA: &str = "treelod-indirect";

/// Pixels of a render that are not its white background: (all, green ones).
fn drawn(path: &Path) -> (usize, usize) {
    let (_, _, pixels) = read_png(path);
    let covered: Vec<&[u8; 4]> = pixels.iter().filter(|p| p[..3].iter().any(|&c| c < 250)).collect();
    (covered.len(), covered.iter().filter(|p| p[1] > p[0] && p[1] > p[2]).count())
}

#[test]
fn an_oak_of_leaf_cards_builds_indirect_planes_that_verify_dump_and_render() {
    let dir = scratch(AREA, "oak");
    let out_path = dir.join("oak.treelod");
    // No calibration (CALIBRATION is of 1.5): the version is what the planes make it.
    let args = ["build", "--impostors", "--impostor-texturing", "indirect", "--calibration-views", "0", "-o"];
    let out = run_on(&args, &[&out_path, &model("ez-tree-oak-large-23k.glb")]);
    let stdout = succeeded(&out, "build --impostor-texturing indirect");
    assert!(!text(&out.stderr).contains("warning"), "{}", text(&out.stderr));
    assert!(stdout.contains("verify        ok") && stdout.contains("plane leaves"), "{stdout}");

    let c = Container::open(&out_path).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    let leaves: u64 = c.planes().iter().map(|p| u64::from(p.leaf_count)).sum();
    assert!(leaves > 0 && c.plane_leaves().len() as u64 == leaves, "{leaves} vs {}", c.plane_leaves().len());
    let slots = c.images()[c.planes()[0].image as usize];
    assert_eq!((slots.format, slots.mip_count), (image_format::LEAF_SLOTS, 1));

    let dump = succeeded(&run_on(&["dump"], &[&out_path]), "dump");
    // PLANE_LEAVES is of 1.3, PLANE_DIFFUSE of 1.10, the points' facing (POINT_FACING) of 1.14.
    assert!(dump.lines().any(|l| l.starts_with("version") && l.trim_end().ends_with("1.14")), "{dump}");
    assert!(dump.lines().any(|l| l.trim_start().starts_with("PLANE_LEAVES")), "{dump}");
    assert!(dump.contains("impostors.texturing = \"indirect\""), "{dump}");
    let verified = succeeded(&run_on(&["verify"], &[&out_path]), "verify");
    assert!(verified.contains(": ok"), "{verified}");

    // Drawn as impostors: the planes are submitted and show about the leaves the points do
    // (measured on lavapipe at 160 × 160: 2609 pixels covered, 2243 of them green, against
    // 2427 and 1722 with the points).
    let (planes_png, points_png) = (dir.join("planes.png"), dir.join("points.png"));
    let stdout = succeeded(
        &run_on(&["render", "--technique", "impostors", "--size", "160x160", "-o"], &[&planes_png, &out_path]),
        "render --technique impostors",
    );
    assert!(stdout.contains("1 tree(s) drawn with impostors submitting"), "{stdout}");
    succeeded(&run_on(&["render", "--size", "160x160", "-o"], &[&points_png, &out_path]), "render");
    let ((planes, planes_green), (points, points_green)) = (drawn(&planes_png), drawn(&points_png));
    eprintln!("covered pixels: planes {planes} ({planes_green} green), points {points} ({points_green} green)");
    let share = planes as f64 / points as f64;
    assert!((0.85..1.25).contains(&share), "planes cover {planes} pixels, points {points}");
    assert!(planes_green as f64 > 0.8 * points_green as f64, "leaves drawn: {planes_green} vs {points_green}");
}

#[test]
fn untextured_leaves_get_the_rgba_atlas_and_a_warning() {
    let dir = scratch(AREA, "untextured");
    let out_path = dir.join("tree.treelod");
    // No calibration (CALIBRATION is of 1.5): the version is what the planes make it.
    // RGBA8 atlases: the file is then of the minor of its kinds (a BC7 atlas would make it 1.6).
    let args = [
        "build",
        "--impostors",
        "--impostor-texturing",
        "indirect",
        "--atlas-format",
        "rgba8",
        "--calibration-views",
        "0",
        "-o",
    ];
    let out = run_on(&args, &[&out_path, &model("quaternius-common-tree-1-3k.glb")]);
    let stdout = succeeded(&out, "build --impostor-texturing indirect");
    let stderr = text(&out.stderr);
    assert!(stderr.contains("warning:") && stderr.contains("indirect impostor texturing not used"), "{stderr}");
    assert!(stderr.contains("has no texture") && stderr.contains("RGBA atlas"), "{stderr}");
    assert!(stdout.contains("atlas") && !stdout.contains("plane leaves"), "{stdout}");
    let c = Container::open(&out_path).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    assert!(c.plane_leaves().is_empty() && !c.planes().is_empty());
    let atlas = c.images()[c.planes()[0].image as usize];
    assert_eq!((atlas.format, atlas.mip_count), (image_format::RGBA8_SRGB, 5));
    // Nothing of 1.3 (no leaf-slot image, checked above); the planes' diffuse response is 1.10,
    // the points' facing (POINT_FACING) 1.14.
    assert!(c.images().iter().all(|i| i.format != image_format::LEAF_SLOTS));
    assert_eq!(c.header().minor, 14, "POINT_FACING makes the file 1.14");
}

#[test]
fn bad_indirect_texturing_options_are_usage_errors_naming_the_option() {
    let dir = scratch(AREA, "usage");
    let cases: &[(&[&str], &str)] = &[
        (&["--impostor-slots-per-leaf", "0"][..], "--impostor-slots-per-leaf"),
        (&["--impostor-slots-per-leaf", "65"], "--impostor-slots-per-leaf"),
        (&["--impostor-slots-per-leaf", "many"], "--impostor-slots-per-leaf"),
        (&["--impostor-texturing", "sideways"], "--impostor-texturing"),
    ];
    assert_build_usage_errors(&dir, &["--impostors"], cases);
}
