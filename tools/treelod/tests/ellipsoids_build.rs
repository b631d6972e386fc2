//! Leaf ellipsoids through the command line (spec §6.8): `build --ellipsoids` writes `ELLIPSOIDS`
//! that `treelod verify` accepts and `dump` shows, with the `ellipsoids.*` settings; `demo` takes
//! the option too; bad values of its options are usage errors naming the option.

mod common;

use common::{assert_build_usage_errors, model, run_on, scratch, succeeded};
use treelod_format::Container;

const AREA: &str = "treelod-ellipsoids";

#[test]
fn build_ellipsoids_writes_records_that_verify_and_dump_shows() {
    let dir = scratch(AREA, "build");
    let out_path = dir.join("tree.treelod");
    let args = ["build", "--ellipsoids", "--ellipsoid-tries", "2", "--ao-rays", "0", "-o"];
    let out = run_on(&args, &[&out_path, &model("quaternius-common-tree-1-3k.glb")]);
    let stdout = succeeded(&out, "build --ellipsoids");
    assert!(stdout.contains("verify        ok") && stdout.contains("ellipsoids "), "{stdout}");

    let c = Container::open(&out_path).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    let ellipsoids = c.ellipsoids();
    assert!(!ellipsoids.is_empty());
    // The finest level: one ellipsoid per leaf of each cell; the roots drawn to +∞.
    assert!(ellipsoids.iter().any(|e| e.lo == 0.0 && e.leaf_count == 1));
    assert!(ellipsoids.iter().any(|e| e.hi == f32::INFINITY && e.leaf_count > 1));
    let line = stdout.lines().find(|l| l.trim_start().starts_with("ellipsoids")).expect("an ellipsoid line");
    assert!(line.contains(&ellipsoids.len().to_string()) && line.contains("per level"), "{line}");

    let dump = succeeded(&run_on(&["dump"], &[&out_path]), "dump");
    assert!(dump.lines().any(|l| l.trim_start().starts_with("ELLIPSOIDS")), "{dump}");
    assert!(dump.contains("ellipsoids.tries = \"2\"") && dump.contains("ellipsoids.clustering = \"em\""), "{dump}");
    let verified = succeeded(&run_on(&["verify"], &[&out_path]), "verify");
    assert!(verified.contains(": ok"), "{verified}");

    // JSON carries the counts.
    let json_path = dir.join("json.treelod");
    let args = ["build", "--ellipsoids", "--ellipsoid-clustering", "kmeans", "--json", "--ao-rays", "0", "-o"];
    let out = run_on(&args, &[&json_path, &model("quaternius-common-tree-1-3k.glb")]);
    let value: serde_json::Value = serde_json::from_str(&succeeded(&out, "build --json")).expect("JSON");
    let per_level: u64 =
        value["ellipsoids_per_level"].as_array().expect("levels").iter().filter_map(serde_json::Value::as_u64).sum();
    assert_eq!(Some(per_level), value["ellipsoids"].as_u64());
    let c = Container::open(&json_path).expect("opens");
    assert!(c.metadata().settings.iter().any(|s| s.key == "ellipsoids.clustering" && s.value == "kmeans"));
}

#[test]
fn demo_takes_the_option_and_without_it_nothing_is_written() {
    let dir = scratch(AREA, "demo");
    let with = dir.join("with.treelod");
    let out = run_on(&["demo", "--leaf-count", "300", "--ellipsoids", "--ao-rays", "0", "-o"], &[&with]);
    succeeded(&out, "demo --ellipsoids");
    let c = Container::open(&with).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    assert!(c.ellipsoids().len() > 300);
    let without = dir.join("without.treelod");
    succeeded(&run_on(&["demo", "--leaf-count", "300", "--ao-rays", "0", "-o"], &[&without]), "demo");
    let c = Container::open(&without).expect("opens");
    assert!(c.ellipsoids().is_empty());
    assert!(!c.metadata().settings.iter().any(|s| s.key.starts_with("ellipsoids.")));
}

#[test]
fn bad_ellipsoid_options_are_usage_errors_naming_the_option() {
    let dir = scratch(AREA, "usage");
    let cases: &[(&[&str], &str)] = &[
        (&["--ellipsoids", "--ellipsoid-pixels", "0"][..], "--ellipsoid-pixels"),
        (&["--ellipsoids", "--ellipsoid-pixels", "1001"], "--ellipsoid-pixels"),
        (&["--ellipsoids", "--ellipsoid-pixels", "big"], "--ellipsoid-pixels"),
        (&["--ellipsoids", "--ellipsoid-tries", "0"], "--ellipsoid-tries"),
        (&["--ellipsoids", "--ellipsoid-tries", "65"], "--ellipsoid-tries"),
        (&["--ellipsoids", "--ellipsoid-clustering", "fuzzy"], "--ellipsoid-clustering"),
        (&["--ellipsoids", "--ellipsoid-seed", "x"], "--ellipsoid-seed"),
        // The tunables need the option itself.
        (&["--ellipsoid-tries", "2"], "--ellipsoids"),
    ];
    assert_build_usage_errors(&dir, &[], cases);
}

#[test]
fn bad_line_options_are_usage_errors_naming_the_option() {
    let dir = scratch(AREA, "line-usage");
    let cases: &[(&[&str], &str)] = &[
        (&["--lines", "--line-pixels", "0"], "--line-pixels"),
        (&["--lines", "--line-pixels", "1001"], "--line-pixels"),
        (&["--lines", "--line-candidates", "0"], "--line-candidates"),
        (&["--lines", "--line-candidates", "257"], "--line-candidates"),
        (&["--lines", "--line-seed", "x"], "--line-seed"),
        // The tunables need the option itself.
        (&["--line-candidates", "4"], "--lines"),
    ];
    assert_build_usage_errors(&dir, &[], cases);
}
