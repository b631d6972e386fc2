//! End-to-end tests of `treelod bench`: short fly-throughs over small forests, rendered with
//! Vulkan (Mesa's lavapipe on machines without a GPU: `mesa-vulkan-drivers`). Without an adapter
//! the rendering tests fail; they do not skip.

mod common;
use common::{field, number, read_csv, read_png, run, succeeded, text};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};

fn scratch(test: &str) -> PathBuf {
    common::scratch("treelod-bench", test)
}

fn demo() -> &'static Path {
    common::demo("treelod-bench")
}

/// Builds a 300-leaf demo tree with `flags` into `dir/name`, asserts success, returns its path.
fn demo_with(dir: &Path, name: &str, flags: &[&str]) -> PathBuf {
    let model = dir.join(name);
    let args = ["demo", "--leaf-count", "300"]
        .iter()
        .chain(flags)
        .map(OsStr::new)
        .chain([OsStr::new("-o"), model.as_os_str()]);
    let out = run(args);
    assert!(out.status.success(), "demo {flags:?}: {}", text(&out.stderr));
    model
}

/// Runs `treelod bench ARGS…`, asserts success and no panic, returns stdout.
fn bench_ok(args: &[&OsStr]) -> String {
    succeeded(&run(std::iter::once(OsStr::new("bench")).chain(args.iter().copied())), &format!("bench {args:?}"))
}

const COLUMNS: &str = "frame,phase,technique,eye_x,eye_y,eye_z,target_x,target_y,target_z,instances_visible,\
triangles,points,primitives,instances_pruned,leaves_pruned,ranges,ranges_clamped,bytes_uploaded,bytes_resident,selection_ms,gpu_ms,\
precision,recall,q,rmse,flip,points_in_cut,primitives_in_cut,quads,shadow_primitives,ellipsoids,lines,transitions,leaving,\
trees_full,trees_spt,trees_prune_opt,trees_prune_cook,trees_impostors,trees_ellipsoids,trees_lod_chain,trees_billboard,\
trees_crossed,trees_octahedral,primitives_full,primitives_spt,primitives_prune_opt,primitives_prune_cook,\
primitives_impostors,primitives_ellipsoids,primitives_lod_chain,primitives_billboard,primitives_crossed,\
primitives_octahedral,noise,ref_noise,draw_commands,setup_ms,assign_ms,select_ms,stream_ms,record_ms,upload_ms,\
budget_s_min,budget_target,budget_finest";

/// The CSV's phases of `Renderer::prepare`, in order.
const PHASES: [&str; 6] = ["setup_ms", "assign_ms", "select_ms", "stream_ms", "record_ms", "upload_ms"];

/// The techniques of the CSV's `trees_*` and `primitives_*` columns.
const DRAWN_WITH: [&str; 10] = [
    "full",
    "spt",
    "prune_opt",
    "prune_cook",
    "impostors",
    "ellipsoids",
    "lod_chain",
    "billboard",
    "crossed",
    "octahedral",
];

#[test]
fn a_short_fly_through_of_the_built_in_forest_writes_csv_json_and_plot() {
    let dir = scratch("short");
    let (csv, json, plot) = (dir.join("bench.csv"), dir.join("bench.json"), dir.join("bench.png"));
    let stdout = bench_ok(&[
        "--trees".as_ref(),
        "200".as_ref(),
        "--frames".as_ref(),
        "6".as_ref(),
        "--size".as_ref(),
        "320x180".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
        "--plot".as_ref(),
        plot.as_os_str(),
    ]);
    assert!(stdout.contains("forest: 200 trees (layout seed 1) of 4 built-in demo trees"), "{stdout}");
    assert!(stdout.contains("path: 6 frame(s) at 320x180"), "{stdout}");
    assert!(stdout.contains("(Vulkan, "), "rendered with Vulkan: {stdout}");
    assert!(
        stdout.lines().any(|l| l.starts_with("full ")) && stdout.lines().any(|l| l.starts_with("spt ")),
        "{stdout}"
    );

    let (header, rows) = read_csv(&csv);
    assert_eq!(header.join(","), COLUMNS);
    assert_eq!(rows.len(), 6 * 2, "one row per frame and technique");
    for frame in 0..6 {
        let of = |technique: &str| {
            rows.iter()
                .find(|r| {
                    field(&header, r, "frame") == frame.to_string() && field(&header, r, "technique") == technique
                })
                .unwrap_or_else(|| panic!("frame {frame} {technique}"))
        };
        let (full, spt) = (of("full"), of("spt"));
        // Both select the same instances; spt's triangles are prefixes of the full mesh's.
        assert_eq!(number(&header, full, "instances_visible"), number(&header, spt, "instances_visible"));
        assert!(number(&header, full, "triangles") >= number(&header, spt, "triangles"), "frame {frame}");
        // At this size and distance spt draws far fewer primitives (in close-ups it can submit
        // more: whole point prefixes, of which the shader draws only the cut).
        assert!(number(&header, full, "primitives") >= number(&header, spt, "primitives"), "frame {frame}");
        assert_eq!(number(&header, full, "points"), 0.0);
        assert!(number(&header, spt, "selection_ms") > 0.0 && number(&header, full, "selection_ms") > 0.0);
        // spt is drawn (lavapipe has timestamp queries), the full mesh only counted.
        assert!(number(&header, spt, "gpu_ms") > 0.0, "{spt:?}");
        assert_eq!(field(&header, full, "gpu_ms"), "");
        assert!(number(&header, spt, "bytes_resident") > 0.0);
        assert_eq!(field(&header, spt, "q"), "", "no quality without --quality");
        assert_eq!(field(&header, spt, "noise"), "", "no temporal noise without --quality");
        assert_eq!(field(&header, spt, "shadow_primitives"), "", "no shadow pass without --shadows");
        // Ranges drawing the same elements (a far tree's roots) share an indirect draw.
        let (commands, ranges) = (number(&header, spt, "draw_commands"), number(&header, spt, "ranges"));
        assert!(commands > 0.0 && commands <= ranges, "{commands} draw commands for {ranges} ranges");
        assert_eq!(field(&header, full, "draw_commands"), "");
        // `prepare`'s phases follow one another within the timed call; the point tree's frame
        // selects and records ranges, and the counted full mesh has none.
        let phases = PHASES.map(|p| number(&header, spt, p));
        assert!(phases.iter().all(|&ms| ms >= 0.0), "{phases:?}");
        let selection = number(&header, spt, "selection_ms");
        assert!(phases.iter().sum::<f64>() <= selection + 1e-3, "{phases:?} within {selection} ms");
        assert!(phases[2] > 0.0 && phases[4] > 0.0, "select and record take time: {phases:?}");
        assert!(PHASES.iter().all(|p| field(&header, full, p).is_empty()), "{full:?}");
        // A forced technique changes no tree's technique; the counted full mesh has no draws.
        assert_eq!((field(&header, spt, "transitions"), field(&header, full, "transitions")), ("0", ""));
        // Every tree is drawn with the point tree, and the counted full mesh draws nothing.
        for technique in DRAWN_WITH {
            let (trees, primitives) = (format!("trees_{technique}"), format!("primitives_{technique}"));
            assert_eq!((field(&header, full, &trees), field(&header, full, &primitives)), ("", ""));
            let expected = if technique == "spt" {
                (number(&header, spt, "instances_visible"), number(&header, spt, "primitives"))
            } else {
                (0.0, 0.0)
            };
            assert_eq!((number(&header, spt, &trees), number(&header, spt, &primitives)), expected, "{technique}");
        }
    }
    assert!(stdout.lines().any(|l| l.starts_with("spt prepare ms: setup ")), "{stdout}");
    assert!(!stdout.contains("full prepare ms"), "{stdout}");
    let phases: Vec<&str> = rows.iter().step_by(2).map(|r| field(&header, r, "phase")).collect();
    assert_eq!(phases.first(), Some(&"overview"));
    assert_eq!(phases.last(), Some(&"back"));

    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).expect("json")).expect("parses");
    assert_eq!(json["forest"]["trees"], 200);
    assert_eq!(json["path"]["frames"], 6);
    assert_eq!(json["adapter"]["backend"], "Vulkan");
    let spt = json["techniques"].as_array().expect("techniques").iter().find(|t| t["name"] == "spt").expect("spt");
    assert_eq!(spt["status"], "measured");
    assert!(spt["summary"]["full_ratio"].as_f64().is_some_and(|r| r > 1.0), "{spt}");
    assert!(spt["summary"]["selection_ms"]["p95"].as_f64().is_some_and(|ms| ms > 0.0), "{spt}");

    let (width, height, pixels) = read_png(&plot);
    assert_eq!((width, height), (960, 24 + 4 * (170 + 44)), "primitives submitted and in the cut, selection, GPU");
    assert!(
        spt["summary"]["full_ratio_in_cut"]
            .as_f64()
            .is_some_and(|r| r > spt["summary"]["full_ratio"].as_f64().unwrap()),
        "{spt}"
    );
    assert!(pixels.iter().any(|p| p[..3] != [255, 255, 255]));
}

#[test]
fn with_shadows_each_frame_records_its_shadow_pass() {
    let dir = scratch("shadows");
    let (csv, json) = (dir.join("shadows.csv"), dir.join("shadows.json"));
    let stdout = bench_ok(&[
        "--shadows".as_ref(),
        "--no-render".as_ref(),
        "--trees".as_ref(),
        "200".as_ref(),
        "--frames".as_ref(),
        "4".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
    ]);
    assert!(stdout.contains("shadow/this"), "{stdout}");
    let (header, rows) = read_csv(&csv);
    for row in &rows {
        match field(&header, row, "technique") {
            // Counted, not drawn: no shadow pass.
            "full" => assert_eq!(field(&header, row, "shadow_primitives"), ""),
            _ => assert!(number(&header, row, "shadow_primitives") > 0.0, "{row:?}"),
        }
    }
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).expect("json")).expect("parses");
    let spt = json["techniques"].as_array().expect("techniques").iter().find(|t| t["name"] == "spt").expect("spt");
    assert!(spt["summary"]["shadow_ratio"].as_f64().is_some_and(|r| r > 0.0), "{spt}");
}

#[test]
fn quality_is_measured_against_the_full_mesh_and_missing_techniques_are_reported() {
    let dir = scratch("quality");
    let csv = dir.join("q.csv");
    let stdout = bench_ok(&[
        demo().as_os_str(),
        "--trees".as_ref(),
        "40".as_ref(),
        "--frames".as_ref(),
        "3".as_ref(),
        "--size".as_ref(),
        "160x90".as_ref(),
        "--quality".as_ref(),
        "--technique".as_ref(),
        "full,spt,prune-cook".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
    ]);
    assert!(
        stdout.contains("technique prune-cook: absent: no model of the forest holds pruning priority lists"),
        "{stdout}"
    );
    assert!(
        stdout
            .contains("the full mesh as the reference at 640x360 (supersample 4, box-filtered, stochastic alpha test)"),
        "{stdout}"
    );
    let (header, rows) = read_csv(&csv);
    assert_eq!(rows.len(), 3 * 2, "prune-cook has no rows");
    for row in &rows {
        match field(&header, row, "technique") {
            "spt" => {
                for column in ["precision", "recall", "q"] {
                    let v = number(&header, row, column);
                    assert!((0.0..=1.0).contains(&v), "{column} {v}");
                }
                assert!(number(&header, row, "rmse") >= 0.0);
                let flip = number(&header, row, "flip");
                assert!(flip > 0.0 && flip <= 1.0, "spt's image differs from the full mesh's: {flip}");
                // Temporal noise from the second frame on, the technique's and the reference's:
                // the camera moves between frames, so both images change.
                if field(&header, row, "frame") == "0" {
                    assert_eq!(field(&header, row, "noise"), "", "no previous frame");
                    assert_eq!(field(&header, row, "ref_noise"), "");
                } else {
                    assert!(number(&header, row, "noise") > 0.0, "spt's frame did not change");
                    assert!(number(&header, row, "ref_noise") > 0.0, "the reference did not change");
                }
            }
            "full" => {
                assert_eq!(field(&header, row, "q"), "", "the reference is not measured against itself");
                assert_eq!(field(&header, row, "flip"), "");
                assert_eq!(field(&header, row, "noise"), "");
                assert!(number(&header, row, "gpu_ms") > 0.0, "the reference's pass is timed");
            }
            other => panic!("unexpected technique {other}"),
        }
    }
}

#[test]
fn pruning_techniques_fly_where_the_models_hold_priority_lists() {
    let dir = scratch("prune");
    let flags = ["--prune", "stochastic", "--prune-views", "2", "--prune-resolution", "64"];
    let pruned = demo_with(&dir, "pruned.treelod", &flags);
    let csv = dir.join("p.csv");
    let stdout = bench_ok(&[
        pruned.as_os_str(),
        "--trees".as_ref(),
        "300".as_ref(),
        "--frames".as_ref(),
        "8".as_ref(),
        "--size".as_ref(),
        "320x180".as_ref(),
        "--technique".as_ref(),
        "spt,prune-cook,prune-opt".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
    ]);
    assert!(!stdout.contains("absent"), "{stdout}");
    let (header, rows) = read_csv(&csv);
    assert_eq!(rows.len(), 8 * 3);
    for technique in ["prune-cook", "prune-opt"] {
        let of: Vec<&Vec<String>> = rows.iter().filter(|r| field(&header, r, "technique") == technique).collect();
        assert_eq!(of.len(), 8);
        // Near trees (inside the forest) are pruned; the overview's small trees are not.
        assert_eq!(number(&header, of[0], "instances_pruned"), 0.0, "{technique}");
        assert!(of.iter().any(|r| number(&header, r, "leaves_pruned") > 0.0), "{technique}: no frame pruned");
    }
    assert!(rows.iter().filter(|r| field(&header, r, "technique") == "spt").all(|r| number(
        &header,
        r,
        "instances_pruned"
    ) == 0.0));
}

#[test]
fn ellipsoids_fly_where_the_models_hold_them_and_are_absent_elsewhere() {
    let dir = scratch("ellipsoids");
    let flags = ["--ellipsoids", "--ellipsoid-tries", "1", "--lines", "--ao-rays", "0"];
    let model = demo_with(&dir, "ellipsoids.treelod", &flags);
    let (csv, json) = (dir.join("e.csv"), dir.join("e.json"));
    let stdout = bench_ok(&[
        model.as_os_str(),
        "--trees".as_ref(),
        "100".as_ref(),
        "--frames".as_ref(),
        "4".as_ref(),
        "--size".as_ref(),
        "160x90".as_ref(),
        "--technique".as_ref(),
        "spt,ellipsoids".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
    ]);
    assert!(!stdout.contains("absent"), "{stdout}");
    assert!(stdout.lines().any(|l| l.contains(" ellipsoids ") && l.contains(" lines ")), "table columns: {stdout}");
    let (header, rows) = read_csv(&csv);
    assert_eq!(rows.len(), 4 * 2);
    let of = |technique: &str| -> Vec<&Vec<String>> {
        rows.iter().filter(|r| field(&header, r, "technique") == technique).collect()
    };
    for row in of("ellipsoids") {
        let count = |column: &str| number(&header, row, column);
        // Leaves as ellipsoids, bark as lines: no triangles or points where every tree has both.
        assert!(count("ellipsoids") > 0.0 && count("lines") > 0.0, "{row:?}");
        assert_eq!((count("triangles"), count("points")), (0.0, 0.0), "{row:?}");
        assert_eq!(count("primitives"), count("ellipsoids") + count("lines"), "{row:?}");
        assert!(count("selection_ms") > 0.0 && count("gpu_ms") > 0.0, "{row:?}");
    }
    for row in of("spt") {
        assert_eq!((number(&header, row, "ellipsoids"), number(&header, row, "lines")), (0.0, 0.0), "{row:?}");
    }
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).expect("json")).expect("parses");
    let technique =
        json["techniques"].as_array().expect("techniques").iter().find(|t| t["name"] == "ellipsoids").expect("listed");
    assert_eq!(technique["status"], "measured");
    let summary = &technique["summary"];
    assert!(summary["ellipsoids"].as_f64().is_some_and(|n| n > 0.0), "{summary}");
    assert!(summary["lines"].as_f64().is_some_and(|n| n > 0.0), "{summary}");
    assert!(summary["selection_ms"]["mean"].as_f64().is_some_and(|ms| ms > 0.0), "{summary}");
    let total = summary["primitives"].as_f64().expect("primitives");
    assert!((total - summary["ellipsoids"].as_f64().unwrap() - summary["lines"].as_f64().unwrap()).abs() < 1e-6);

    // Models without ellipsoids: reported absent, and alone nothing can be measured (exit 4).
    let csv = dir.join("absent.csv");
    let args = ["--trees", "20", "--frames", "1", "--no-render", "--technique"];
    let stdout = bench_ok(
        &[demo().as_os_str()]
            .into_iter()
            .chain(args.iter().map(OsStr::new))
            .chain(["spt,ellipsoids".as_ref(), "--csv".as_ref(), csv.as_os_str()])
            .collect::<Vec<_>>(),
    );
    assert!(stdout.contains("technique ellipsoids: absent: no model of the forest holds ellipsoids"), "{stdout}");
    let (header, rows) = read_csv(&csv);
    assert!(rows.iter().all(|r| field(&header, r, "technique") == "spt"), "ellipsoids has no rows");
    let out = run(["bench".as_ref(), demo().as_os_str()]
        .into_iter()
        .chain(args.iter().map(OsStr::new))
        .chain(["ellipsoids".as_ref()]));
    assert_eq!(out.status.code(), Some(4), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("technique ellipsoids: absent"), "{}", text(&out.stdout));
}

#[test]
fn impostors_fly_where_the_models_hold_planes_and_count_them_as_primitives() {
    let dir = scratch("impostors");
    let model = demo_with(&dir, "planes.treelod", &["--impostors", "--ao-rays", "0"]);
    let csv = dir.join("i.csv");
    let stdout = bench_ok(&[
        model.as_os_str(),
        "--trees".as_ref(),
        "100".as_ref(),
        "--frames".as_ref(),
        "4".as_ref(),
        "--size".as_ref(),
        "160x90".as_ref(),
        "--technique".as_ref(),
        "spt,impostors".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
    ]);
    assert!(!stdout.contains("absent"), "{stdout}");
    let (header, rows) = read_csv(&csv);
    assert_eq!(rows.len(), 4 * 2);
    let impostors: Vec<&Vec<String>> = rows.iter().filter(|r| field(&header, r, "technique") == "impostors").collect();
    assert_eq!(impostors.len(), 4);
    for row in impostors {
        let count = |column: &str| number(&header, row, column);
        // Leaves as planes (quads), bark as triangles; no points where every tree has planes.
        assert!(count("quads") > 0.0 && count("triangles") > 0.0, "{row:?}");
        assert_eq!(count("points"), 0.0, "{row:?}");
        assert_eq!(count("primitives"), count("triangles") + count("quads"), "{row:?}");
        assert!(count("gpu_ms") > 0.0, "{row:?}");
    }
    // The demo tree without planes: impostors absent, named as such.
    let args = ["--trees", "20", "--frames", "1", "--no-render", "--technique", "spt,impostors"];
    let stdout = bench_ok(&[demo().as_os_str()].into_iter().chain(args.iter().map(OsStr::new)).collect::<Vec<_>>());
    assert!(stdout.contains("technique impostors: absent: no model of the forest holds impostor planes"), "{stdout}");
}

#[test]
fn each_tree_counts_under_the_technique_it_was_drawn_with() {
    let dir = scratch("drawn-with");
    let planes = demo_with(&dir, "planes.treelod", &["--impostors", "--ao-rays", "0"]);
    let csv = dir.join("d.csv");
    // Impostors forced over a forest of a model with planes and one without: the latter's trees
    // are drawn with the point tree.
    let stdout = bench_ok(&[
        planes.as_os_str(),
        demo().as_os_str(),
        "--trees".as_ref(),
        "60".as_ref(),
        "--frames".as_ref(),
        "3".as_ref(),
        "--no-render".as_ref(),
        "--technique".as_ref(),
        "impostors".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
    ]);
    let (header, rows) = read_csv(&csv);
    assert_eq!(rows.len(), 3);
    let sum = |row: &Vec<String>, prefix: &str| -> f64 {
        DRAWN_WITH.iter().map(|t| number(&header, row, &format!("{prefix}_{t}"))).sum()
    };
    for row in &rows {
        assert_eq!(sum(row, "trees"), number(&header, row, "instances_visible"), "{row:?}");
        assert_eq!(sum(row, "primitives"), number(&header, row, "primitives"), "{row:?}");
        for technique in ["full", "prune_opt", "prune_cook", "ellipsoids", "lod_chain", "billboard", "crossed"] {
            assert_eq!(number(&header, row, &format!("trees_{technique}")), 0.0, "{technique}: {row:?}");
        }
        // Planes are the impostor trees' only quads; the point tree's trees draw none.
        assert!(number(&header, row, "primitives_impostors") >= number(&header, row, "quads"), "{row:?}");
    }
    let (spt, impostors) = ("trees_spt", "trees_impostors");
    assert!(rows.iter().any(|r| number(&header, r, spt) > 0.0 && number(&header, r, impostors) > 0.0), "{rows:?}");
    let line = stdout.lines().find(|l| l.starts_with("impostors drew its trees with: spt ")).expect(&stdout);
    assert!(line.contains(" trees, ") && line.contains("; impostors "), "{line}");
}

#[test]
fn budget_mode_records_its_steering_and_the_frames_with_nothing_left_to_spend() {
    let dir = scratch("budget");
    let run_with = |budget: &str, name: &str| {
        let csv = dir.join(name);
        let stdout = bench_ok(&[
            demo().as_os_str(),
            "--trees".as_ref(),
            "60".as_ref(),
            "--frames".as_ref(),
            "6".as_ref(),
            "--no-render".as_ref(),
            "--technique".as_ref(),
            "policy,spt".as_ref(),
            "--budget".as_ref(),
            budget.as_ref(),
            "--csv".as_ref(),
            csv.as_os_str(),
        ]);
        let (header, rows) = read_csv(&csv);
        assert_eq!(rows.len(), 12, "{rows:?}");
        let line = stdout.lines().find(|l| l.starts_with("policy budget ")).expect(&stdout).to_owned();
        (header, rows, line)
    };
    // A budget no frame of the forest comes near: every frame is drawn at the finest steering
    // (`s_min` 0.5 pixels, the target 1/1024), under half the budget with nothing left to spend.
    let (header, rows, line) = run_with("1000000000", "finest.csv");
    for row in &rows {
        if field(&header, row, "technique") == "policy" {
            assert_eq!(number(&header, row, "budget_finest"), 1.0, "{row:?}");
            assert_eq!(number(&header, row, "budget_s_min"), 0.5, "{row:?}");
            assert_eq!(number(&header, row, "budget_target"), 1.0 / 1024.0, "{row:?}");
        } else {
            // Budget mode is the policy's alone.
            for column in ["budget_s_min", "budget_target", "budget_finest"] {
                assert_eq!(field(&header, row, column), "", "{column}: {row:?}");
            }
        }
    }
    assert!(line.ends_with("6 under half of it (the draws of trees in a transition counted; 6 of them at the finest steering, nothing left to spend)"), "{line}");
    // A budget under what the default target draws: the steering coarsens, never at its finest.
    let (header, rows, line) = run_with("2000", "coarse.csv");
    for row in rows.iter().filter(|r| field(&header, r, "technique") == "policy") {
        assert_eq!(number(&header, row, "budget_finest"), 0.0, "{row:?}");
        assert!(number(&header, row, "budget_s_min") > 0.5, "{row:?}");
    }
    assert!(line.ends_with("; 0 of them at the finest steering, nothing left to spend)"), "{line}");
}

#[test]
fn without_rendering_only_selection_is_measured() {
    let dir = scratch("no-render");
    let csv = dir.join("n.csv");
    let stdout = bench_ok(&[
        demo().as_os_str(),
        demo().as_os_str(),
        "--trees".as_ref(),
        "3000".as_ref(),
        "--frames".as_ref(),
        "4".as_ref(),
        "--no-render".as_ref(),
        "--csv".as_ref(),
        csv.as_os_str(),
    ]);
    assert!(stdout.contains("of 1 model(s)"), "the same container twice is one model: {stdout}");
    assert!(stdout.contains("nothing drawn (--no-render)"), "{stdout}");
    let (header, rows) = read_csv(&csv);
    assert_eq!(rows.len(), 4 * 2);
    assert!(rows.iter().all(|r| field(&header, r, "gpu_ms").is_empty()));
    // The full mesh alone needs no device at all.
    let stdout = bench_ok(&[
        demo().as_os_str(),
        "--trees".as_ref(),
        "100".as_ref(),
        "--frames".as_ref(),
        "2".as_ref(),
        "--technique".as_ref(),
        "full".as_ref(),
    ]);
    assert!(stdout.contains("adapter: none opened"), "{stdout}");
    // Without `full`, the full mesh drawn at 1× gives the ratios: the same triangles.
    let json = dir.join("n.json");
    let counted = |techniques: &str| {
        bench_ok(&[
            demo().as_os_str(),
            "--trees".as_ref(),
            "100".as_ref(),
            "--frames".as_ref(),
            "2".as_ref(),
            "--no-render".as_ref(),
            "--technique".as_ref(),
            techniques.as_ref(),
            "--json".as_ref(),
            json.as_os_str(),
        ]);
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).expect("json")).expect("parses");
        let summary = |name: &str| {
            json["techniques"]
                .as_array()
                .expect("techniques")
                .iter()
                .find(|t| t["name"] == name)
                .map(|t| t["summary"].clone())
        };
        (summary("full"), summary("full-1x").expect("full-1x"), summary("spt").expect("spt"))
    };
    let (no_full, full_1x, spt) = counted("full-1x,spt");
    assert!(no_full.is_none(), "full was not asked for");
    let ratio = full_1x["primitives"].as_f64().unwrap() / spt["primitives"].as_f64().unwrap();
    assert!(ratio > 1.0, "{full_1x} {spt}");
    assert_eq!(spt["full_ratio"].as_f64(), Some(ratio), "{spt}");
    assert_eq!(full_1x["full_ratio"].as_f64(), Some(1.0), "{full_1x}");
    let (full, full_1x_flown, spt_with_full) = counted("full,full-1x,spt");
    let full = full.expect("full");
    assert_eq!(
        full["primitives"], full_1x_flown["primitives"],
        "the counted full mesh and the drawn one: {full} {full_1x_flown}"
    );
    assert_eq!(full_1x_flown["primitives"], full_1x["primitives"], "the same flight twice");
    assert_eq!(spt_with_full["full_ratio"], spt["full_ratio"], "{spt_with_full}");
}

#[test]
fn bad_arguments_and_inputs_are_clear_errors() {
    let dir = scratch("errors");
    let usage = [
        vec!["--trees", "0"],
        vec!["--trees", "ten"],
        vec!["--frames", "0"],
        vec!["--size", "0x10"],
        vec!["--technique", "bogus"],
        vec!["--no-render", "--quality"],
        vec!["--supersample", "2"],
        vec!["--reference-1x"],
        vec!["--quality", "--reference-1x", "--supersample", "2"],
        vec!["--fov", "200"],
    ];
    for args in usage {
        let out = run(std::iter::once("bench").chain(args.iter().copied()));
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.starts_with("error: ") && !err.contains("panicked"), "{args:?}: {err}");
    }
    let missing = dir.join("missing.treelod");
    let out = run(["bench".as_ref(), missing.as_os_str()]);
    assert_eq!(out.status.code(), Some(5), "{}", text(&out.stderr));
    assert!(text(&out.stderr).starts_with(&format!("error: {}: ", missing.display())), "{}", text(&out.stderr));
    let scene = dir.join("forest.json");
    std::fs::write(&scene, "{\"version\": 1, \"models\": [], \"instances\": []}").expect("write");
    let out = run(["bench".as_ref(), scene.as_os_str()]);
    assert_eq!(out.status.code(), Some(3), "{}", text(&out.stderr));
    let garbage = dir.join("garbage.treelod");
    std::fs::write(&garbage, b"not a container").expect("write");
    let out = run(["bench".as_ref(), garbage.as_os_str()]);
    assert_eq!(out.status.code(), Some(3), "{}", text(&out.stderr));
    let out = run([
        "bench".as_ref(),
        demo().as_os_str(),
        "--technique".as_ref(),
        "prune-opt".as_ref(),
        "--trees".as_ref(),
        "10".as_ref(),
        "--frames".as_ref(),
        "1".as_ref(),
    ]);
    assert_eq!(out.status.code(), Some(4), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("technique prune-opt: absent"), "{}", text(&out.stdout));
    assert!(text(&out.stderr).contains("none of the techniques asked for can be measured"));
    let out = run(["bench".as_ref(), demo().as_os_str(), "--csv".as_ref(), dir.as_os_str()]);
    assert_eq!(out.status.code(), Some(5), "{}", text(&out.stderr));
    assert!(text(&out.stderr).contains("is a directory"), "{}", text(&out.stderr));
}
