//! Ambient occlusion through the command line (spec §6.14): `build` and `demo` write `VERTEX_AO`
//! and `POINT_AO` by default (format 1.2), `--ao-rays 0` writes none, out-of-range ray counts are
//! usage errors, and `render --no-ao` lights the tree brighter than the default.

mod common;

use std::path::{Path, PathBuf};

use common::{read_png, run, scratch, succeeded, text};
use treelod_format::{Container, SectionKind};

const AREA: &str = "treelod-ambient";

/// The small glTF tree every checkout has beside the repository.
fn model() -> PathBuf {
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees/quaternius-common-tree-1-3k.glb");
    assert!(model.exists(), "the shared models sit in ../shared beside the repository");
    model
}

/// Runs `treelod` with `args` then `paths`; asserts success and returns stdout.
fn ok(args: &[&str], paths: &[&Path]) -> String {
    let mut all: Vec<std::ffi::OsString> = args.iter().map(Into::into).collect();
    all.extend(paths.iter().map(|p| p.as_os_str().to_owned()));
    succeeded(&run(&all), &format!("treelod {args:?}"))
}

fn setting<'a>(c: &'a Container, key: &str) -> Option<&'a str> {
    c.metadata().settings.iter().find(|s| s.key == key).map(|s| s.value.as_str())
}

/// Asserts that `path` holds ambient occlusion for every vertex and point (kinds of format 1.2)
/// with `rays` recorded, and returns its vertices' mean occlusion byte.
fn assert_has_ao(path: &Path, rays: &str) -> f64 {
    let c = Container::open(path).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    // Ambient occlusion is of 1.2; the points' facing (POINT_FACING), which every build writes,
    // of 1.14.
    assert_eq!((c.header().major, c.header().minor), (1, 14), "{}", path.display());
    assert_eq!(c.vertex_ao().len(), c.vertices().len());
    assert_eq!(c.point_ao().len(), c.points().len());
    assert!(c.section(SectionKind::VERTEX_AO).is_some() && c.section(SectionKind::POINT_AO).is_some());
    assert!(c.plane_ao().is_empty(), "no impostors, no PLANE_AO");
    assert_eq!((setting(&c, "ao.rays"), setting(&c, "ao.seed")), (Some(rays), Some("0")));
    assert!(matches!(setting(&c, "ao.method"), Some("parallel" | "traced")), "{:?}", setting(&c, "ao.method"));
    // A tree shades itself somewhere, and no vertex of it is in a closed box.
    let max = c.vertex_ao().iter().copied().max().unwrap_or(0);
    let mean = c.vertex_ao().iter().map(|&a| f64::from(a)).sum::<f64>() / c.vertex_ao().len() as f64;
    let points = c.point_ao().iter().map(|&a| f64::from(a)).sum::<f64>() / c.point_ao().len() as f64;
    eprintln!("{}: vertex AO mean {mean:.1}, max {max}; point AO mean {points:.1}", path.display());
    assert!(max > 0 && mean > 0.0 && mean < 200.0, "mean {mean}, max {max}");
    mean
}

/// Asserts that `path` holds no ambient occlusion: no kind of format 1.2 or later but the points'
/// facing (`POINT_FACING`, 1.14, which every build writes).
fn assert_has_no_ao(path: &Path) {
    let c = Container::open(path).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    assert_eq!(c.header().minor, 14, "{}", path.display());
    assert!(c.vertex_ao().is_empty() && c.point_ao().is_empty() && c.plane_ao().is_empty());
    assert!(c.sections().iter().all(|s| s.kind().since_minor() < 2 || s.kind() == SectionKind::POINT_FACING));
    assert_eq!(setting(&c, "ao.rays"), None);
}

#[test]
fn demo_writes_ambient_occlusion_by_default_and_none_with_zero_rays() {
    let dir = scratch(AREA, "demo");
    let (default, none, few) = (dir.join("default.treelod"), dir.join("none.treelod"), dir.join("few.treelod"));
    let stdout = ok(&["demo", "--leaf-count", "200", "-o"], &[&default]);
    assert!(stdout.contains("verify        ok"), "{stdout}");
    assert_has_ao(&default, "16");
    ok(&["demo", "--leaf-count", "200", "--ao-rays", "0", "-o"], &[&none]);
    assert_has_no_ao(&none);
    ok(&["demo", "--leaf-count", "200", "--ao-rays", "4", "-o"], &[&few]);
    assert_has_ao(&few, "4");
    // Ambient occlusion changes nothing else: the same records either way.
    let (a, b) = (Container::open(&default).expect("opens"), Container::open(&none).expect("opens"));
    assert_eq!(a.vertices(), b.vertices());
    assert_eq!(a.triangles(), b.triangles());
    assert_eq!(a.points(), b.points());
    // The ray count is used: 4 rays give other values than 16.
    assert_ne!(a.vertex_ao(), Container::open(&few).expect("opens").vertex_ao());

    // `dump` shows the sections and the version (1.14 for the points' facing), in text and JSON.
    let dump = ok(&["dump"], &[&default]);
    assert!(dump.contains("version    1.14"), "{dump}");
    assert!(dump.contains("VERTEX_AO") && dump.contains("POINT_AO") && !dump.contains("PLANE_AO"), "{dump}");
    let json: serde_json::Value = serde_json::from_str(&ok(&["dump", "--json"], &[&default])).expect("JSON");
    assert_eq!(json["version"], "1.14");
    let sections = json["sections"].as_array().expect("sections");
    let vertices = a.vertices().len() as u64;
    let points = a.points().len() as u64;
    for (kind, count) in [(SectionKind::VERTEX_AO, vertices), (SectionKind::POINT_AO, points)] {
        let name = kind.to_string();
        let s = sections.iter().find(|s| s["name"] == name.as_str()).unwrap_or_else(|| panic!("{name} listed"));
        assert_eq!(s["kind"].as_u64(), Some(u64::from(kind.0)), "{name}");
        assert_eq!((s["record_size"].as_u64(), s["record_count"].as_u64()), (Some(1), Some(count)), "{name}");
    }
    let json: serde_json::Value = serde_json::from_str(&ok(&["dump", "--json"], &[&none])).expect("JSON");
    assert_eq!(json["version"].as_str(), Some("1.14"), "the points' facing, without occlusion");
    assert!(
        json["sections"]
            .as_array()
            .expect("sections")
            .iter()
            .all(|s| !s["name"].as_str().unwrap_or("").ends_with("_AO"))
    );
}

#[test]
fn build_writes_ambient_occlusion_by_default_and_none_with_zero_rays() {
    let dir = scratch(AREA, "build");
    let model = model();
    let (default, none) = (dir.join("default.treelod"), dir.join("none.treelod"));
    let stdout = ok(&["build"], &[&model, Path::new("-o"), &default]);
    assert!(stdout.contains("verify        ok"), "{stdout}");
    assert_has_ao(&default, "16");
    ok(&["build", "--ao-rays", "0"], &[&model, Path::new("-o"), &none]);
    assert_has_no_ao(&none);
    assert_eq!(setting(&Container::open(&default).expect("opens"), "ao.method"), Some("parallel"));

    // `--ao-method traced`: the other method, recorded, with values near the default's.
    let traced = dir.join("traced.treelod");
    ok(&["build", "--ao-method", "traced"], &[&model, Path::new("-o"), &traced]);
    assert_has_ao(&traced, "16");
    let (a, b) = (Container::open(&default).expect("opens"), Container::open(&traced).expect("opens"));
    assert_eq!(setting(&b, "ao.method"), Some("traced"));
    assert_ne!(a.vertex_ao(), b.vertex_ao(), "the method is used");
    let mean_abs = a.vertex_ao().iter().zip(b.vertex_ao()).map(|(&x, &y)| f64::from(x.abs_diff(y))).sum::<f64>()
        / a.vertex_ao().len() as f64;
    // Each is about 0.02 from a 256-ray reference on this tree (benches/ao.rs): well within 0.08.
    assert!(mean_abs < 0.08 * 255.0, "mean |Δ| {mean_abs} of 255");
    let out = common::run_on(&["build", "--ao-method", "bvh"], &[&model]);
    assert_eq!(out.status.code(), Some(2), "an unknown method is a usage error");
    assert!(text(&out.stderr).contains("--ao-method"), "{}", text(&out.stderr));
}

#[test]
fn ao_rays_out_of_range_are_refused_naming_the_option() {
    let dir = scratch(AREA, "refused");
    let model = model();
    for rays in ["5000", "4097", "many"] {
        for command in ["build", "demo"] {
            let out_path = dir.join(format!("{command}-{rays}.treelod"));
            let mut args: Vec<std::ffi::OsString> = vec![command.into(), "--ao-rays".into(), rays.into()];
            if command == "build" {
                args.push(model.clone().into());
            }
            args.extend(["-o".into(), out_path.clone().into()]);
            let out = run(&args);
            let err = text(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{command} --ao-rays {rays}: a usage error: {err}");
            assert!(err.contains("--ao-rays"), "{command} --ao-rays {rays}: the message names the option: {err}");
            assert!(err.contains(rays), "{command} --ao-rays {rays}: and the value: {err}");
            if rays != "many" {
                assert!(err.contains("0..=4096"), "{command} --ao-rays {rays}: and the range: {err}");
            }
            assert!(!err.contains("panicked"), "{err}");
            assert!(!out_path.exists(), "{command} --ao-rays {rays}: nothing written");
        }
    }
}

/// The RGB of every pixel of a rendered PNG.
fn pixels(path: &Path) -> Vec<[u8; 3]> {
    read_png(path).2.into_iter().map(|p| [p[0], p[1], p[2]]).collect()
}

#[test]
fn render_no_ao_lights_the_tree_brighter_than_the_default() {
    let dir = scratch(AREA, "render");
    let (with_ao, without_ao) = (dir.join("with.treelod"), dir.join("without.treelod"));
    ok(&["demo", "--leaf-count", "300", "--no-verify", "-o"], &[&with_ao]);
    ok(&["demo", "--leaf-count", "300", "--no-verify", "--ao-rays", "0", "-o"], &[&without_ao]);
    let render = |input: &Path, name: &str, extra: &[&str]| {
        let png = dir.join(name);
        let mut args = vec!["render"];
        args.extend_from_slice(extra);
        args.extend(["--size", "160x120", "-o"]);
        ok(&args, &[&png, input]);
        pixels(&png)
    };
    let occluded = render(&with_ao, "ao.png", &[]);
    let open = render(&with_ao, "no-ao.png", &["--no-ao"]);
    // The tree's pixels (off the white background): every one at least as bright without
    // ambient occlusion, the tree as a whole clearly brighter.
    let tree: Vec<usize> = (0..occluded.len()).filter(|&i| occluded[i] != [255; 3] || open[i] != [255; 3]).collect();
    assert!(tree.len() > 300, "the tree is drawn: {} pixels", tree.len());
    let darker = tree.iter().filter(|&&i| (0..3).any(|k| open[i][k] + 1 < occluded[i][k])).count();
    let brightness = |image: &[[u8; 3]]| {
        tree.iter().map(|&i| image[i].iter().map(|&c| f64::from(c)).sum::<f64>()).sum::<f64>() / tree.len() as f64 / 3.0
    };
    let (dim, bright) = (brightness(&occluded), brightness(&open));
    let changed = tree.iter().filter(|&&i| occluded[i] != open[i]).count();
    eprintln!(
        "{} tree pixels: mean level {dim:.2} with ambient occlusion, {bright:.2} with --no-ao; {changed} differ, \
         {darker} darker without",
        tree.len()
    );
    assert_eq!(darker, 0, "no pixel is darker without ambient occlusion");
    assert!(changed * 4 > tree.len(), "most of the tree changes: {changed} of {}", tree.len());
    assert!(bright > dim + 2.0, "brighter without ambient occlusion: {bright:.2} vs {dim:.2}");

    // A container without ambient occlusion looks the same either way, and like --no-ao.
    let plain = render(&without_ao, "plain.png", &[]);
    assert_eq!(plain, render(&without_ao, "plain-no-ao.png", &["--no-ao"]));
    assert_eq!(plain, open, "--no-ao draws the tree as if it had no ambient occlusion");
}
