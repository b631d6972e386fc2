//! `build --octahedral-views N --octahedral-texels T` (spec §6.13.1): each tree's octahedral
//! impostor baked from `N × N` views of `T` texels a side, recorded in the settings and shown by
//! `dump`; values out of range, or without `--baselines`, are usage errors.

mod common;

use common::{assert_build_usage_errors, model, run_on, scratch, succeeded};
use treelod_format::Container;

const AREA: &str = "treelod-octahedral-options";

#[test]
fn the_octahedral_impostor_has_the_views_and_texels_asked_for() {
    let dir = scratch(AREA, "views");
    let tree = model("quaternius-common-tree-1-3k.glb");
    let out_path = dir.join("q.treelod");
    let args = [
        "build",
        "--baselines",
        "--calibration-views",
        "0",
        "--octahedral-views",
        "6",
        "--octahedral-texels",
        "32",
        "-o",
    ];
    succeeded(&run_on(&args, &[&out_path, &tree]), "build");
    let c = Container::open(&out_path).expect("opens");
    treelod_format::verify(&c).expect("verifies");
    let [record] = c.octahedral() else { panic!("one octahedral impostor: {:?}", c.octahedral()) };
    assert_eq!(record.frames, 6);
    assert_eq!(c.octahedral_depth().len(), 36, "a depth plane per view");

    let dump = succeeded(&run_on(&["dump"], &[&out_path]), "dump");
    assert!(dump.contains("baselines.octahedral_views = \"6\""), "{dump}");
    assert!(dump.contains("baselines.octahedral_texels = \"32\""), "{dump}");
    assert!(dump.contains("octahedral tree 0: 6x6 views"), "{dump}");
    let json = succeeded(&run_on(&["dump", "--json"], &[&out_path]), "dump --json");
    let value: serde_json::Value = serde_json::from_str(&json).expect("JSON");
    // The rectangle of the views: 6 cells of 32 texels a side.
    assert_eq!(value["baselines"]["octahedral"][0]["texels"], 6 * 6 * 32 * 32, "{}", value["baselines"]);
}

#[test]
fn octahedral_options_out_of_range_or_without_baselines_are_usage_errors() {
    let dir = scratch(AREA, "usage");
    let cases: [(&[&str], &str); 6] = [
        (&["--baselines", "--octahedral-views", "1"], "--octahedral-views"),
        (&["--baselines", "--octahedral-views", "65"], "--octahedral-views"),
        (&["--baselines", "--octahedral-texels", "100"], "--octahedral-texels"),
        (&["--baselines", "--octahedral-texels", "16"], "--octahedral-texels"),
        // A multiple of 16 but not of 32: its normal cells, half the side, would leave the
        // atlas's alignment.
        (&["--baselines", "--octahedral-texels", "48"], "--octahedral-texels"),
        (&["--octahedral-views", "8"], "--baselines"),
    ];
    assert_build_usage_errors(&dir, &[], &cases);
}
