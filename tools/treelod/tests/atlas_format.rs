//! `build --atlas-format` (spec §6.7): BC7 atlases by default, RGBA8 when asked, recorded in the
//! settings; `dump` prints the texture bytes of each representation and their formats; a bad
//! value is a usage error.

mod common;

use common::{assert_build_usage_errors, model, run_on, scratch, succeeded};
use treelod_format::{Container, image_format};

const AREA: &str = "treelod-atlas-format";

/// The bytes of the `textures` line of `representation` in `dump`'s text.
fn texture_line<'a>(dump: &'a str, representation: &str) -> &'a str {
    let start = dump.find("\ntextures").unwrap_or_else(|| panic!("no textures block:\n{dump}"));
    dump[start..]
        .lines()
        .find(|l| l.trim_start().starts_with(representation))
        .unwrap_or_else(|| panic!("no {representation} line:\n{}", &dump[start..]))
}

fn bytes_of(line: &str) -> u64 {
    line.split_whitespace().nth(1).and_then(|b| b.parse().ok()).unwrap_or_else(|| panic!("no bytes in {line:?}"))
}

#[test]
fn atlases_are_bc7_by_default_and_rgba8_when_asked_and_dump_counts_their_bytes() {
    let dir = scratch(AREA, "formats");
    let tree = model("quaternius-common-tree-1-3k.glb");
    let mut lines = Vec::new();
    for format in ["bc7", "rgba8"] {
        let out_path = dir.join(format!("{format}.treelod"));
        let mut args = vec!["build", "--baselines", "--calibration-views", "0"];
        if format == "rgba8" {
            args.extend(["--atlas-format", "rgba8"]);
        }
        args.push("-o");
        succeeded(&run_on(&args, &[&out_path, &tree]), "build");
        let c = Container::open(&out_path).expect("opens");
        treelod_format::verify(&c).expect("verifies");
        let expected = if format == "bc7" { image_format::BC7_SRGB } else { image_format::RGBA8_SRGB };
        assert_eq!(c.images()[c.planes()[0].image as usize].format, expected, "{format}");
        assert_eq!(c.images()[c.billboards()[0].image as usize].format, expected, "{format}");

        let dump = succeeded(&run_on(&["dump"], &[&out_path]), "dump");
        assert!(dump.contains(&format!("atlas.format = \"{format}\"")), "{dump}");
        let name = if format == "bc7" { "BC7_SRGB" } else { "RGBA8_SRGB" };
        let (planes, billboards) = (texture_line(&dump, "planes"), texture_line(&dump, "billboards"));
        assert!(planes.contains(name) && billboards.contains(name), "{planes}\n{billboards}");
        lines.push((bytes_of(planes), bytes_of(billboards)));

        let json = succeeded(&run_on(&["dump", "--json"], &[&out_path]), "dump --json");
        let value: serde_json::Value = serde_json::from_str(&json).expect("JSON");
        let textures = value["textures"].as_array().expect("a textures array");
        let planes_json = textures.iter().find(|t| t["representation"] == "planes").expect("planes");
        assert_eq!(planes_json["bytes"].as_u64(), Some(bytes_of(planes)));
        assert_eq!(planes_json["formats"][0], name);
    }
    let [(bc7_planes, bc7_billboards), (rgba8_planes, rgba8_billboards)] = lines[..] else { panic!("two builds") };
    // A quarter of the bytes, a little more where small levels round up to whole blocks.
    for (bc7, rgba8) in [(bc7_planes, rgba8_planes), (bc7_billboards, rgba8_billboards)] {
        let ratio = rgba8 as f64 / bc7 as f64;
        assert!((3.5..=4.0).contains(&ratio), "RGBA8 {rgba8} bytes, BC7 {bc7}");
    }
}

#[test]
fn a_bad_atlas_format_is_a_usage_error_naming_the_option() {
    let dir = scratch(AREA, "usage");
    assert_build_usage_errors(&dir, &["--impostors"], &[(&["--atlas-format", "bc1"][..], "--atlas-format")]);
}
