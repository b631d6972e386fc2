//! `eval` and `bench` called as library functions, without the `treelod` binary: on a tiny
//! container built here, through lavapipe (a machine without a Vulkan adapter fails these).

use std::path::{Path, PathBuf};

use glam::Vec3;
use treelod_format::{Compression, ErrorClass};
use treelod_harness::eval::{self, Availability, Cameras, TechniqueName};
use treelod_harness::{Error, Technique, bench};

/// A small demo tree written as a container in `dir`.
fn tiny_container(dir: &Path) -> PathBuf {
    let config = treelod_build::DemoTreeConfig { seed: 7, leaves: 300, ..treelod_build::DemoTreeConfig::default() };
    let tree = treelod_build::demo_tree(&config);
    let placed = [treelod_build::Placed { scene: &tree, translation: Vec3::ZERO }];
    let build = treelod_build::BuildConfig::default();
    let output = treelod_build::build_block(&tree.name, &placed, &build, "treelod harness test").expect("builds");
    let path = dir.join("tiny.treelod");
    std::fs::write(&path, output.data.to_bytes(Compression::None).expect("encodes")).expect("writes");
    path
}

#[test]
fn eval_measures_a_container_through_the_library() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let input = tiny_container(dir.path());
    let options = eval::Options {
        cameras: Cameras::Views(2),
        techniques: vec![TechniqueName::FULL, TechniqueName::Full1x, TechniqueName::Technique(Technique::Spt)],
        size: (64, 48),
        supersample: 2,
        sheet: true,
        ..eval::Options::new(&input)
    };
    let mut frames = Vec::new();
    let report = eval::run_with_progress(&options, &mut |frame, of| frames.push((frame, of))).expect("measures");
    assert_eq!(frames, [(0, 2), (1, 2)]);
    assert_eq!(report.poses.len(), 2);
    assert_eq!(report.rows.len(), 2 * 3, "a row per frame and technique");
    assert_eq!(report.measured().count(), 3);
    for row in &report.rows {
        assert!(row.primitives() > 0, "{row:?}");
        if row.technique == TechniqueName::FULL {
            // The instrument's self-check: the reference against itself.
            assert_eq!(row.coverage.quality(), 1.0);
            assert_eq!(row.rmse.summary(), 0.0);
        }
    }
    let summary = eval::output::summarise(&report.rows, TechniqueName::Technique(Technique::Spt));
    assert_eq!(summary.frames, 2);
    // At 64×48 the points of a small tree read a modest Q; the figure is only checked to be one.
    assert!(summary.mean.q > 0.0 && summary.mean.q <= 1.0, "{}", summary.mean.q);
    // The outputs, written by the report's own functions.
    let (csv, json, sheet, plot) =
        (dir.path().join("e.csv"), dir.path().join("e.json"), dir.path().join("s.png"), dir.path().join("q.png"));
    report.write_csv(&csv).expect("csv");
    report.write_json(&json).expect("json");
    report.write_sheet(&sheet).expect("sheet");
    report.write_quality_plot(&plot).expect("plot");
    assert_eq!(std::fs::read_to_string(&csv).expect("reads").lines().count(), 1 + 6);
    let text = report.text([&Some(csv), &Some(json), &Some(sheet), &Some(plot), &None, &None]);
    assert!(text.contains("spt") && text.contains("csv: "), "{text}");
    // A file to write that is a directory is a typed error naming it.
    let refused = report.write_csv(dir.path()).expect_err("a directory");
    assert!(matches!(&refused, Error::OutputIsDirectory { path } if path == dir.path()), "{refused}");
}

#[test]
fn eval_errors_are_typed_and_name_the_file() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let missing = dir.path().join("missing.treelod");
    let Err(error) = eval::run(&eval::Options::new(&missing)) else { panic!("no such file") };
    assert!(matches!(error, Error::Scene(_)), "{error:?}");
    assert_eq!(error.class(), ErrorClass::Io);
    assert!(error.to_string().starts_with(&missing.display().to_string()), "{error}");

    // Nothing to measure is found before any device is opened.
    let input = tiny_container(dir.path());
    let options = eval::Options {
        techniques: vec![TechniqueName::Technique(Technique::Ellipsoids)],
        ..eval::Options::new(&input)
    };
    let Err(error) = eval::run(&options) else { panic!("no ellipsoids") };
    let Error::NoneMeasurable { absent, .. } = &error else { panic!("{error:?}") };
    assert!(absent.starts_with("technique ellipsoids: absent: this container holds no ellipsoids"), "{absent}");
    assert_eq!(error.class(), ErrorClass::Unsupported);

    let bad = eval::Options { supersample: 0, ..eval::Options::new(&input) };
    assert!(matches!(eval::run(&bad), Err(Error::Options { .. })));
    let path = dir.path().join("path.json");
    std::fs::write(&path, "[]").expect("writes");
    let Err(error) = eval::run(&eval::Options { cameras: Cameras::Path(path.clone()), ..eval::Options::new(&input) })
    else {
        panic!("an empty path")
    };
    assert!(matches!(&error, Error::CameraPath { path: p, io: false, .. } if *p == path), "{error:?}");
}

#[test]
fn bench_flies_a_tiny_forest_through_the_library() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let input = tiny_container(dir.path());
    let options = bench::Options {
        inputs: vec![input],
        trees: 30,
        frames: 3,
        size: (96, 54),
        techniques: vec![
            TechniqueName::FULL,
            TechniqueName::Technique(Technique::Spt),
            TechniqueName::Technique(Technique::Impostors),
        ],
        quality: Some(bench::Quality::Supersampled(2)),
        sheet_frames: vec![2, 0],
        ..bench::Options::default()
    };
    let past = bench::Options { sheet_frames: vec![3], ..options.clone() };
    let error = bench::run(&past).err().expect("a sheet frame past the path");
    assert!(error.to_string().contains("frame 3 of the contact sheet is past the path"), "{error}");
    let report = bench::run(&options).expect("flies");
    assert_eq!(report.frames.len(), 3);
    assert_eq!(report.forest.trees.len(), 30);
    assert_eq!(report.techniques[2].1.status(), "absent", "the container holds no impostors");
    assert_eq!(report.techniques[1].1, Availability::Measured);
    assert_eq!(report.rows.len(), 3 * 2, "a row per frame and measured technique");
    for row in report.rows.iter().filter(|r| r.technique == TechniqueName::Technique(Technique::Spt)) {
        assert!(row.rmse.is_some() && row.coverage.is_some(), "{row:?}");
    }
    let csv = dir.path().join("b.csv");
    report.write_csv(&csv).expect("csv");
    report.write_plot(&dir.path().join("b.png")).expect("plot");
    // The contact sheet keeps its frames in path order, each with the reference and spt (the
    // full mesh is counted, not drawn): 2 rows of 3 panels.
    let frames: Vec<usize> = report.sheet.iter().map(|f| f.frame).collect();
    assert_eq!(frames, [0, 2]);
    for frame in &report.sheet {
        let drawn: Vec<TechniqueName> = frame.techniques.iter().map(|t| t.0).collect();
        assert_eq!(drawn, [TechniqueName::Technique(Technique::Spt)]);
        assert_eq!((frame.reference.0.width, frame.reference.0.height), (96, 54));
    }
    let image = eval::output::sheet(report.size, &report.sheet);
    assert_eq!((image.width, image.height), (3 * 96 + 2 * 2, 2 * 54 + 2));
    let sheet = dir.path().join("sheet.png");
    report.write_sheet(&sheet).expect("sheet");
    let text = report.text([&Some(csv), &None, &None, &Some(sheet)]);
    assert!(text.contains("technique impostors: absent"), "{text}");
    assert!(text.contains("(frames 0, 2; columns: reference, then each technique drawn"), "{text}");
}
