//! Stage timings through the command line: `build --timings` prints to stderr a row for each
//! stage that ran (seconds and share of the total) and the total; `build --json` holds the same
//! stages as `stages`, named and in order, summing to at most the build's `seconds`.

mod common;

use common::{model, run_on, scratch, succeeded, text};

const AREA: &str = "treelod-timings";

/// The `--timings` table of `stderr`: (stage, seconds, share in per cent) per row after the
/// heading, the `total` row last.
fn table(stderr: &str) -> Vec<(String, f64, f64)> {
    let mut lines = stderr.lines().skip_while(|l| !l.starts_with("timings of "));
    assert!(lines.next().is_some(), "a timings table: {stderr}");
    let heading: Vec<&str> = lines.next().expect("a heading").split_whitespace().collect();
    assert_eq!(heading, ["stage", "seconds", "share"]);
    lines
        .take_while(|l| l.starts_with("  "))
        .map(|l| {
            let cells: Vec<&str> = l.split_whitespace().collect();
            let [name, seconds, share, "%"] = cells[..] else { panic!("a row: {l:?}") };
            (name.to_owned(), seconds.parse().expect("seconds"), share.parse().expect("a share"))
        })
        .collect()
}

/// The stages of a `build --json` object as (name, seconds), and its total seconds.
fn json_stages(stdout: &str) -> (Vec<(String, f64)>, f64) {
    let value: serde_json::Value = serde_json::from_str(stdout).expect("one JSON object");
    let stages = value["stages"]
        .as_array()
        .expect("stages")
        .iter()
        .map(|s| (s["name"].as_str().expect("a name").to_owned(), s["seconds"].as_f64().expect("seconds")));
    (stages.collect(), value["seconds"].as_f64().expect("seconds"))
}

#[test]
fn build_times_every_stage_that_ran_in_the_table_and_the_json() {
    let dir = scratch(AREA, "build");
    let tree = model("quaternius-common-tree-1-3k.glb");
    let out_path = dir.join("tree.treelod");
    let args = [
        "build",
        "--json",
        "--timings",
        "--prune",
        "density",
        "--prune-views",
        "1",
        "--prune-resolution",
        "32",
        "--lines",
        "--ao-rays",
        "4",
        "-o",
    ];
    let out = run_on(&args, &[&out_path, &tree]);
    let stdout = succeeded(&out, "build --json --timings");
    let (stages, total) = json_stages(&stdout);
    let names: Vec<&str> = stages.iter().map(|(name, _)| name.as_str()).collect();
    let ran = [
        "import",
        "gather",
        "grid",
        "prune",
        "lines",
        "ao",
        "cells",
        "records",
        "triangles",
        "images",
        "metadata",
        "precision",
        "calibration",
        "write",
        "verify",
    ];
    assert_eq!(names, ran, "every stage that ran, in order");
    let sum: f64 = stages.iter().map(|(_, seconds)| seconds).sum();
    assert!(stages.iter().all(|(_, seconds)| *seconds >= 0.0), "{stages:?}");
    assert!(sum <= total + 1e-9, "the stages ({sum} s) within the total ({total} s)");

    // The table on stderr: one row per stage as in the JSON, then the total; stdout is the JSON.
    let rows = table(&text(&out.stderr));
    let (last, rows) = rows.split_last().expect("rows");
    assert_eq!(rows.iter().map(|(name, _, _)| name.as_str()).collect::<Vec<_>>(), ran);
    assert_eq!(last.0, "total");
    assert!((last.1 - total).abs() < 0.001, "the table's total {} is the JSON's {total}", last.1);
    assert!((last.2 - 100.0).abs() < 1e-9);
    for ((name, seconds, share), (_, json_seconds)) in rows.iter().zip(&stages) {
        assert!((seconds - json_seconds).abs() < 0.001, "{name}: {seconds} s against {json_seconds} s");
        assert!((0.0..=100.0).contains(share), "{name}: {share} %");
    }
    let table_sum: f64 = rows.iter().map(|(_, seconds, _)| seconds).sum();
    assert!(table_sum <= last.1 + 0.0005 * rows.len() as f64, "rounded to milliseconds");

    // Without the optional stages and without `--timings`: those stages are not listed and
    // stderr has no table; `--no-verify` drops the verification.
    let args = ["build", "--json", "--ao-rays", "0", "--no-verify", "-o"];
    let out = run_on(&args, &[&out_path, &tree]);
    let stdout = succeeded(&out, "build --json");
    let (stages, total) = json_stages(&stdout);
    let names: Vec<&str> = stages.iter().map(|(name, _)| name.as_str()).collect();
    assert_eq!(names, ["import", "gather", "grid", "cells", "triangles", "images", "metadata", "precision", "write"]);
    assert!(stages.iter().map(|(_, seconds)| seconds).sum::<f64>() <= total + 1e-9);
    assert!(!text(&out.stderr).contains("timings of"), "{}", text(&out.stderr));
}
