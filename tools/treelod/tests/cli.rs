//! End-to-end tests of the `treelod` binary: output of `dump` and `verify`, exit codes, error
//! messages, robustness against files that are not containers, and the golden dumps of
//! `tests/data/v1_0/` and `tests/data/v1_1/`.

mod common;
use common::read_png;
use std::f64::consts::PI;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use treelod_format::pack::{oct_encode, rgba8, unorm16x2};
use treelod_format::{
    BillboardRecord, BlockRecord, CellRecord, Compression, ContainerData, EllipsoidRecord, ImageRecord, LineRecord,
    MaterialInfo, MaterialRecord, Metadata, NO_IMAGE, OctahedralNormalGridRecord, OctahedralNormalRecord,
    OctahedralRecord, PlaneDiffuseRecord, PointRecord, Range, Setting, Source, Tree, TriangleRecord, VertexRecord,
    billboard_kind, image_format, material_class,
};

/// Runs the binary with `args` in the current directory.
fn treelod(args: &[&str]) -> Output {
    treelod_in(Path::new("."), args)
}

/// Runs the binary with `args` in `dir`.
fn treelod_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_treelod")).args(args).current_dir(dir).output().expect("the binary runs")
}

fn stdout(out: &Output) -> String {
    String::from_utf8(out.stdout.clone()).expect("stdout is UTF-8")
}

fn stderr(out: &Output) -> String {
    String::from_utf8(out.stderr.clone()).expect("stderr is UTF-8")
}

/// A fresh scratch directory for one test.
fn scratch(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("treelod-cli").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// The size of a triangle (spec §2): the diameter of the disc of equal area.
fn triangle_size(p: [[f32; 3]; 3]) -> f32 {
    let d = |a: [f32; 3], b: [f32; 3]| [f64::from(b[0] - a[0]), f64::from(b[1] - a[1]), f64::from(b[2] - a[2])];
    let (u, v) = (d(p[0], p[1]), d(p[0], p[2]));
    let c = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    let area = 0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    (2.0 * (area / PI).sqrt()) as f32
}

fn centroid(p: [[f32; 3]; 3]) -> [f32; 3] {
    std::array::from_fn(|i| (p[0][i] + p[1][i] + p[2][i]) / 3.0)
}

/// A leaf point of a triangle (spec §6.5): `lo = 0`, `size` = the triangle's size.
fn leaf_point(tri: [[f32; 3]; 3], leaf: u32, hi: f32) -> PointRecord {
    let size = triangle_size(tri);
    PointRecord {
        position: centroid(tri),
        radius: size / 2.0,
        normal: oct_encode([0.0, 0.0, 1.0]),
        color: rgba8([0.2, 0.6, 0.1, 1.0]),
        size,
        lo: 0.0,
        hi,
        leaf_first: leaf,
        leaf_count: 1,
        flags: 0,
    }
}

/// A 2x1x1 grid over `[0,0,0]..[2,1,1]`: cell 0 holds two triangles under a root point, cell 1 one
/// triangle whose leaf point is the root, the block cell one ellipsoid and one line. Every cut
/// invariant of spec §10 holds.
fn tiny() -> ContainerData {
    let big = [[0.1, 0.1, 0.5], [0.9, 0.1, 0.5], [0.1, 0.9, 0.5]];
    let small = [[0.2, 0.2, 0.6], [0.4, 0.2, 0.6], [0.2, 0.4, 0.6]];
    let right = [[1.2, 0.2, 0.2], [1.8, 0.2, 0.2], [1.2, 0.8, 0.2]];
    let vertices = [big, small, right]
        .iter()
        .flatten()
        .map(|&position| VertexRecord {
            position,
            normal: oct_encode([0.0, 0.0, 1.0]),
            uv: [0.5, 0.5],
            color: u32::MAX,
        })
        .collect();
    let tri = |first: u32, corners, leaf, material| TriangleRecord {
        indices: [first, first + 1, first + 2],
        size: triangle_size(corners),
        leaf,
        material,
    };
    let root_size = 0.8;
    let root = PointRecord {
        position: [0.5, 0.5, 0.55],
        radius: root_size / 2.0,
        normal: oct_encode([0.0, 0.0, 1.0]),
        color: rgba8([0.2, 0.6, 0.1, 1.0]),
        size: root_size,
        lo: root_size,
        hi: f32::INFINITY,
        leaf_first: 0,
        leaf_count: 2,
        flags: 0,
    };
    let range = |first, count| Range { first, count };
    let cells = vec![
        CellRecord {
            bounds_min: [0.1, 0.1, 0.5],
            bounds_max: [0.9, 0.9, 0.6],
            triangles: range(0, 2),
            points: range(0, 3),
            ..CellRecord::default()
        },
        CellRecord {
            bounds_min: [1.2, 0.2, 0.2],
            bounds_max: [1.8, 0.8, 0.2],
            triangles: range(2, 1),
            points: range(3, 1),
            ..CellRecord::default()
        },
        CellRecord {
            bounds_min: [0.5, 0.0, 0.2],
            bounds_max: [1.5, 1.0, 0.8],
            triangles: range(3, 0),
            points: range(4, 0),
            ellipsoids: range(0, 1),
            lines: range(0, 1),
            ..CellRecord::default()
        },
    ];
    let material = |class, alpha_mode| MaterialRecord {
        base_color: [1.0; 4],
        image: NO_IMAGE,
        alpha_mode,
        alpha_cutoff: 0.5,
        class,
        flags: 0,
        _pad: 0,
    };
    let bounds_max = [2.0, 1.0, 1.0];
    ContainerData {
        metadata: Metadata {
            generator: "treelod cli test".into(),
            name: "tiny".into(),
            sources: vec![Source {
                path: "trees/tiny.glb".into(),
                content_hash: String::new(),
                byte_length: 1234,
                unit_scale: 1.0,
            }],
            trees: vec![Tree {
                name: "tiny".into(),
                source: 0,
                translation: [0.0; 3],
                bounds_min: [0.0; 3],
                bounds_max,
            }],
            materials: vec![
                MaterialInfo { name: "Bark".into(), classified_by: "name".into() },
                MaterialInfo { name: "Leaves".into(), classified_by: "override".into() },
            ],
            settings: vec![
                Setting { key: "grid".into(), value: "2x1x1".into() },
                Setting { key: "points".into(), value: "gilet".into() },
            ],
        },
        block: BlockRecord { bounds_max, grid: [2, 1, 1], tree_count: 1, ..BlockRecord::default() },
        cells,
        vertices,
        triangles: vec![tri(0, big, 0, 1), tri(3, small, 1, 1), tri(6, right, 0, 0)],
        points: vec![
            root,
            leaf_point(big, 0, root_size),
            leaf_point(small, 1, root_size),
            leaf_point(right, 0, f32::INFINITY),
        ],
        materials: vec![material(material_class::BARK, 0), material(material_class::LEAF, 1)],
        ellipsoids: vec![EllipsoidRecord {
            center: [1.0, 0.5, 0.5],
            radii: [0.5, 0.3, 0.3],
            orientation: [0, 0, 0, 32767],
            color: rgba8([0.2, 0.6, 0.1, 1.0]),
            alpha_threshold: 0.5,
            noise_mip: 0.0,
            lo: 0.0,
            hi: f32::INFINITY,
            leaf_first: 0,
            leaf_count: 1,
            flags: 0,
        }],
        lines: vec![LineRecord {
            p0: [1.0, 0.0, 0.5],
            r0: 0.05,
            p1: [1.0, 0.8, 0.5],
            r1: 0.02,
            color: rgba8([0.3, 0.2, 0.1, 1.0]),
            lo: 0.0,
            hi: f32::INFINITY,
            leaf_first: 0,
            leaf_count: 1,
            flags: 0,
        }],
        ..ContainerData::default()
    }
}

/// Writes [`tiny`] uncompressed to `dir/tiny.treelod` and returns its path.
fn write_tiny(dir: &Path) -> PathBuf {
    let path = dir.join("tiny.treelod");
    tiny().write_to_path(&path, Compression::None).expect("the test container is valid");
    path
}

/// Asserts that the run failed with `code` and one error line naming `path` exactly once.
fn assert_fails(out: &Output, code: i32, path: &Path) {
    let err = stderr(out);
    let shown = path.display().to_string();
    assert_eq!(out.status.code(), Some(code), "stderr: {err}");
    assert!(err.starts_with(&format!("error: {shown}: ")), "stderr: {err}");
    assert_eq!(err.matches(&shown).count(), 1, "the path is named once: {err}");
    assert!(!err.contains("panicked"), "stderr: {err}");
}

#[test]
fn dump_text_shows_every_part() {
    let dir = scratch("dump_text");
    write_tiny(&dir);
    let out = treelod_in(&dir, &["dump", "tiny.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    let len = std::fs::metadata(dir.join("tiny.treelod")).expect("written").len();
    for expected in [
        "file       tiny.treelod\n".to_owned(),
        "version    1.0\n".to_owned(),
        format!("file size  {len} bytes (header 64, section table at 64)\n"),
        "\nsections (9)\n".to_owned(),
        "  bounds  [0, 0, 0] .. [2, 1, 1]\n".to_owned(),
        "  grid    2 x 1 x 1 = 2 cells + block cell\n".to_owned(),
        "  generator  \"treelod cli test\"\n".to_owned(),
        "    grid = \"2x1x1\"\n".to_owned(),
        "\ncells (3 of 3 non-empty: 2 grid cells + block cell)\n".to_owned(),
    ] {
        assert!(text.contains(&expected), "missing {expected:?} in\n{text}");
    }
    // Section rows: kind, flags, offset, stored, raw, ratio, record size, records, checksum.
    let row = |kind: &str| {
        text.lines()
            .find(|l| l.split_whitespace().next() == Some(kind))
            .unwrap_or_else(|| panic!("no {kind} row in\n{text}"))
            .split_whitespace()
            .collect::<Vec<_>>()
    };
    let triangles = row("TRIANGLES");
    assert_eq!(triangles[1], "-");
    assert_eq!(&triangles[3..8], ["72", "72", "1.00", "24", "3"]);
    assert!(triangles[8].starts_with("0x") && triangles[8].len() == 10);
    assert_eq!(&row("POINTS")[6..8], ["48", "4"]);
    // Materials: index, class from the record, classified_by and name from the metadata.
    assert!(text.contains("    0  bark   \"name\"         \"Bark\"\n"), "{text}");
    assert!(text.contains("    1  leaf   \"override\"     \"Leaves\"\n"), "{text}");
    // Per-cell counts.
    let cell_rows: Vec<Vec<&str>> = text
        .lines()
        .skip_while(|l| !l.starts_with("cells ("))
        .skip(2)
        .take(4)
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(cell_rows[0], ["0", "(0,0,0)", "2", "3", "0", "0", "0", "0"]);
    assert_eq!(cell_rows[1], ["1", "(1,0,0)", "1", "1", "0", "0", "0", "0"]);
    assert_eq!(cell_rows[2], ["block", "0", "0", "1", "1", "0", "0"]);
    assert_eq!(cell_rows[3], ["total", "3", "4", "1", "1", "0", "0"]);
    // Histograms: documented measure, one block per non-empty hierarchical kind.
    assert!(text.contains("\nhistograms: log2 buckets [2^k, 2^(k+1)) of element sizes in metres\n"), "{text}");
    assert!(text.contains("line: |p1 - p0|"), "the measures are documented: {text}");
    assert!(text.contains("  triangles: size (3 elements)\n"), "{text}");
    assert!(text.contains("  ellipsoids: 2*max(radii) (1 element)\n    2^0  [1, 2)  1"), "{text}");
    assert!(!text.contains("  planes:"), "{text}");
    // Deterministic: a second run prints the same bytes.
    assert_eq!(treelod_in(&dir, &["dump", "tiny.treelod"]).stdout, out.stdout);
}

#[test]
fn dump_json_has_the_same_content_in_a_stable_order() {
    let dir = scratch("dump_json");
    let path = write_tiny(&dir);
    let out = treelod_in(&dir, &["dump", "--json", "tiny.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    let json: serde_json::Value = serde_json::from_str(&text).expect("one JSON object");
    // `serde_json::Value` sorts its keys: the printed order is read from the text.
    let mut in_text_order: Vec<&str> = json.as_object().expect("an object").keys().map(String::as_str).collect();
    in_text_order.sort_by_key(|k| text.find(&format!("\n  \"{k}\":")));
    assert_eq!(
        in_text_order,
        [
            "file",
            "version",
            "file_size",
            "header_size",
            "table_offset",
            "sections",
            "block",
            "metadata",
            "cells",
            "histograms"
        ]
    );
    assert_eq!(json["file"], "tiny.treelod");
    assert_eq!(json["version"], "1.0");
    assert_eq!(json["file_size"], std::fs::metadata(&path).expect("written").len());
    let sections = json["sections"].as_array().expect("sections");
    let names: Vec<&str> = sections.iter().map(|s| s["name"].as_str().expect("name")).collect();
    assert_eq!(
        names,
        ["META", "BLOCK", "CELLS", "VERTICES", "TRIANGLES", "POINTS", "MATERIALS", "ELLIPSOIDS", "LINES"]
    );
    assert_eq!(sections[4]["record_count"], 3);
    assert_eq!(sections[4]["ratio"], 1.0);
    assert_eq!(json["block"]["grid"], serde_json::json!([2, 1, 1]));
    assert_eq!(json["metadata"]["materials"][1]["class_name"], "leaf");
    assert_eq!(json["metadata"]["materials"][1]["classified_by"], "override");
    assert_eq!(json["metadata"]["settings"][0]["key"], "grid");
    assert_eq!(json["cells"]["non_empty"], 3);
    assert_eq!(json["cells"]["list"][2]["block"], true);
    assert_eq!(json["cells"]["list"][2]["xyz"], serde_json::Value::Null);
    assert_eq!(json["cells"]["list"][1]["xyz"], serde_json::json!([1, 0, 0]));
    assert_eq!(json["cells"]["totals"]["points"], 4);
    let points = &json["histograms"]["points"];
    let bucketed: u64 =
        points["buckets"].as_array().expect("buckets").iter().map(|b| b["count"].as_u64().unwrap_or(0)).sum();
    assert_eq!((points["count"].as_u64(), bucketed), (Some(4), 4));
    assert_eq!(json["histograms"]["planes"]["buckets"], serde_json::json!([]));
}

#[test]
fn verify_accepts_a_valid_file() {
    let dir = scratch("verify_ok");
    let path = write_tiny(&dir);
    let out = treelod(&["verify", path.to_str().expect("UTF-8 path")]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(stdout(&out).starts_with(&format!("{}: ok", path.display())), "{}", stdout(&out));
    assert_eq!(stdout(&out).lines().count(), 1);
    assert!(out.stderr.is_empty());
}

#[test]
fn a_corrupted_header_is_invalid_input() {
    let dir = scratch("corrupt_header");
    let path = write_tiny(&dir);
    let mut bytes = std::fs::read(&path).expect("written");
    bytes[20] ^= 0x01; // section_count: caught by the header checksum
    std::fs::write(&path, bytes).expect("rewritten");
    for command in ["dump", "verify"] {
        let out = treelod(&[command, path.to_str().expect("UTF-8 path")]);
        assert_fails(&out, 3, &path);
        assert!(stdout(&out).is_empty());
    }
}

#[test]
fn a_corrupted_payload_is_found_by_verify_only() {
    // Checksums of uncompressed sections are not read at open (spec §9.1), so dump still works.
    let dir = scratch("corrupt_payload");
    let path = write_tiny(&dir);
    let mut bytes = std::fs::read(&path).expect("written");
    let (offset, _) = section(&bytes, 0x0011).expect("TRIANGLES");
    bytes[offset + 12] ^= 0x40; // the first triangle's size
    std::fs::write(&path, bytes).expect("rewritten");
    let arg = path.to_str().expect("UTF-8 path");
    assert_eq!(treelod(&["dump", arg]).status.code(), Some(0));
    let out = treelod(&["verify", arg]);
    assert_fails(&out, 3, &path);
    assert!(stderr(&out).contains("checksum"), "{}", stderr(&out));
}

/// Payload offset and table index of section `kind` in a file with a 64-byte header.
fn section(bytes: &[u8], kind: u32) -> Option<(usize, usize)> {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    (0..u32_at(20) as usize).find_map(|index| {
        let entry = 64 + 48 * index;
        (u32_at(entry) == kind).then(|| (u32_at(entry + 8) as usize, index))
    })
}

/// CRC-32/ISO-HDLC (spec §8), bit by bit: enough for a test that re-signs a header.
fn crc32(bytes: &[u8]) -> u32 {
    !bytes.iter().fold(!0u32, |crc, &byte| {
        (0..8).fold(crc ^ u32::from(byte), |c, _| if c & 1 == 1 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 })
    })
}

#[test]
fn an_unknown_flag_on_a_known_section_is_unsupported() {
    let dir = scratch("unsupported_flag");
    let path = write_tiny(&dir);
    let mut bytes = std::fs::read(&path).expect("written");
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    let (_, index) = section(&bytes, 0x0012).expect("POINTS");
    bytes[64 + 48 * index + 4] |= 0x04; // flags bit 2: a feature of a later version
    let table_end = 64 + 48 * u32::from_le_bytes(bytes[20..24].try_into().expect("4 bytes")) as usize;
    let mut signed = bytes[..table_end].to_vec();
    signed[60..64].fill(0);
    let checksum = crc32(&signed);
    bytes[60..64].copy_from_slice(&checksum.to_le_bytes());
    std::fs::write(&path, bytes).expect("rewritten");
    for command in ["dump", "verify"] {
        assert_fails(&treelod(&[command, path.to_str().expect("UTF-8 path")]), 4, &path);
    }
}

#[test]
fn a_future_major_version_is_unsupported() {
    let dir = scratch("future_major");
    let path = write_tiny(&dir);
    let mut bytes = std::fs::read(&path).expect("written");
    bytes[12..14].copy_from_slice(&2u16.to_le_bytes()); // nothing else fixed: the version comes first
    std::fs::write(&path, bytes).expect("rewritten");
    for command in ["dump", "verify"] {
        let out = treelod(&[command, path.to_str().expect("UTF-8 path")]);
        assert_fails(&out, 4, &path);
        assert!(stderr(&out).contains("2.0"), "names the file's version: {}", stderr(&out));
    }
}

#[test]
fn a_missing_file_is_an_io_error() {
    let dir = scratch("missing");
    let path = dir.join("no-such.treelod");
    for command in ["dump", "verify"] {
        assert_fails(&treelod(&[command, path.to_str().expect("UTF-8 path")]), 5, &path);
    }
}

#[test]
fn files_that_are_not_containers_never_panic() {
    let dir = scratch("garbage");
    let garbage = dir.join("garbage.treelod");
    std::fs::write(&garbage, (0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect::<Vec<_>>())
        .expect("written");
    let empty = dir.join("empty.treelod");
    std::fs::write(&empty, b"").expect("written");
    let magic_only = dir.join("magic.treelod");
    std::fs::write(&magic_only, b"\x89TREELOD\r\n\x1a\n\x01\x00").expect("written");
    let truncated = dir.join("truncated.treelod");
    let full = std::fs::read(write_tiny(&dir)).expect("written");
    std::fs::write(&truncated, &full[..full.len() / 2]).expect("written");
    let cases = [
        (&garbage, 3),
        (&empty, 3),
        (&magic_only, 3),
        (&truncated, 3),
        (&dir.join("nonexistent.treelod"), 5),
        (&dir, 5),
    ];
    for (path, code) in cases {
        for args in [&["dump"][..], &["dump", "--json"], &["verify"]] {
            let mut args = args.to_vec();
            args.push(path.to_str().expect("UTF-8 path"));
            let out = treelod(&args);
            assert_fails(&out, code, path);
            assert!(stdout(&out).is_empty(), "{args:?}: {}", stdout(&out));
            assert_eq!(stderr(&out).lines().count(), 1, "{args:?}: {}", stderr(&out));
        }
    }
}

#[test]
fn dump_shows_records_that_only_verify_would_refuse() {
    // `open` does not look inside the bulk arrays (spec §9.1): dump must cope with any values.
    let dir = scratch("hostile_records");
    let mut data = tiny();
    data.triangles[0].size = f32::NAN;
    data.triangles[1].size = -1.0;
    data.triangles[2].size = 0.0;
    data.points[0].size = f32::from_bits(1); // the smallest subnormal
    data.points[1].size = f32::MAX;
    data.ellipsoids[0].radii = [f32::INFINITY, 0.0, f32::NAN];
    data.lines[0].p1 = [f32::MAX, -f32::MAX, 0.0];
    data.materials[1].class = 99;
    data.materials.push(data.materials[0]); // three records, two names
    data.metadata.name = "line\nbreak \u{1b}[31m".into();
    data.extra_sections = vec![(0x0_0004, Vec::new()), (0x1_0000, b"private".to_vec())];
    let path = dir.join("hostile.treelod");
    data.write_to_path(&path, Compression::default()).expect("open-level valid");
    let out = treelod_in(&dir, &["dump", "hostile.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    // Compared with the runs of spaces of the column alignment squeezed to one.
    let squeezed: String = text.lines().map(|l| l.split_whitespace().collect::<Vec<_>>().join(" ") + "\n").collect();
    for expected in [
        "name \"line\\nbreak \\u{1b}[31m\"\n",
        "\n1 unknown(99) \"override\" \"Leaves\"\n",
        "\n2 bark - -\n",
        "triangles: size (3 elements)\nzero 1\nnegative 1\nnon-finite 1\n",
        "\npoints: size (4 elements)\n2^-149 [1.401298464324817e-45, 2.802596928649634e-45) 1 #",
        "\n... (145 empty buckets)\n2^-3 [0.125, 0.25) 1 #",
        "\n... (128 empty buckets)\n2^127 [",
        "\n2^127 [1.7014118346046923e38, 3.402823669209385e38) 1 #",
        "ellipsoids: 2*max(radii) (1 element)\nnon-finite 1\n",
    ] {
        assert!(squeezed.contains(expected), "missing {expected:?} in\n{text}");
    }
    let kinds: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix("  0x")).collect();
    assert_eq!(kinds.len(), 2, "unknown kinds are listed in hex: {text}");
    assert!(text.lines().any(|l| l.starts_with("  VERTICES    zstd+shuffle")), "{text}");

    let out = treelod_in(&dir, &["dump", "--json", "hostile.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let json: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("valid JSON");
    assert_eq!(json["histograms"]["triangles"]["non_finite"], 1);
    assert_eq!(json["histograms"]["triangles"]["negative"], 1);
    assert_eq!(json["histograms"]["triangles"]["zero"], 1);
    assert_eq!(json["metadata"]["materials"][2]["name"], serde_json::Value::Null);
    assert_eq!(json["sections"][3]["name"], "0x0004");
    assert_eq!(json["sections"][3]["ratio"], serde_json::Value::Null);

    assert_fails(&treelod_in(&dir, &["verify", "hostile.treelod"]), 3, Path::new("hostile.treelod"));
}

#[test]
fn dump_and_verify_show_the_octahedral_impostors() {
    // [`tiny`] with a 4x4 RGBA8 atlas and the tree's octahedral impostor on its left half
    // (spec §6.13.1, format 1.11).
    let dir = scratch("octahedral");
    let mut data = tiny();
    data.images = vec![ImageRecord {
        width: 4,
        height: 4,
        mip_count: 1,
        format: image_format::RGBA8_SRGB,
        data_offset: 0,
        data_length: 64,
    }];
    data.image_data = vec![0x80; 64];
    data.octahedral = vec![OctahedralRecord {
        center: [1.0, 0.5, 0.5],
        radius: 0.75,
        image: 0,
        uv_min: unorm16x2(0.0, 0.0),
        uv_max: unorm16x2(0.5, 1.0),
        frames: 8,
        tree: 0,
        occlusion: 0.25,
        diffuse: PlaneDiffuseRecord { flat: 16384, scattered: 32768 },
        reserved: 0,
    }];
    data.write_to_path(dir.join("octahedral.treelod"), Compression::None).expect("valid");

    let out = treelod_in(&dir, &["dump", "octahedral.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    assert!(text.lines().any(|l| l.starts_with("version") && l.ends_with("1.11")), "{text}");
    assert!(text.contains("\n  OCTAHEDRAL "), "the section is listed: {text}");
    assert!(
        text.contains(
            "\nbaselines\n  octahedral tree 0: 8x8 views, radius 0.75 m at [1, 0.5, 0.5], image 0 rectangle [0, 0] \
             .. [0.5000076, 1] (8 texels), occlusion 0.25, diffuse flat 0.2500 scattered 0.5000\n"
        ),
        "{text}"
    );
    // No billboard samples its image: its bytes are the octahedral impostors'.
    assert!(text.contains("\n  octahedral           64 bytes, 1 image(s), RGBA8_SRGB\n"), "{text}");
    let json = |name: &str| -> serde_json::Value {
        let out = treelod_in(&dir, &["dump", "--json", name]);
        assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
        serde_json::from_str(&stdout(&out)).expect("valid JSON")
    };
    let j = json("octahedral.treelod");
    let o = &j["baselines"]["octahedral"][0];
    assert_eq!((&o["tree"], &o["frames"], &o["image"], &o["texels"]), (&0.into(), &8.into(), &0.into(), &8.into()));
    assert_eq!((o["radius"].as_f64(), o["occlusion"].as_f64()), (Some(0.75), Some(0.25)));
    assert_eq!(o["diffuse"][0].as_f64().map(|f| (f * 1e4).round()), Some(2500.0));
    assert_eq!(o["center"], serde_json::json!([1.0, 0.5, 0.5]));
    assert_eq!((o["uv_min"][1].as_f64(), o["uv_max"][1].as_f64()), (Some(0.0), Some(1.0)));
    assert_eq!(j["baselines"]["billboards"], serde_json::json!([]));
    assert_eq!(j["textures"][0]["representation"], "octahedral");
    let out = treelod_in(&dir, &["verify", "octahedral.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(stdout(&out).contains(", 1 octahedral impostor;"), "{}", stdout(&out));
    // Without OCTAHEDRAL_NORMALS or OCTAHEDRAL_NORMAL_GRIDS (files before 1.15) there are no
    // `normals_uv_min` and `normals_uv_max` keys and no normals in the text.
    assert!(o.get("normals_uv_min").is_none() && o.get("normals_uv_max").is_none(), "{o}");
    assert!(!text.contains("normals"), "{text}");

    // With its views' normal grid on the atlas's right half (spec §6.13.3, format 1.15): the
    // grid's corners on the impostor's line and in the JSON (the far one from the colour grid's
    // size in unorm16 steps, 32768 from 32768, held inside the image at 65535), and the count in
    // verify's line.
    data.octahedral_normals = vec![OctahedralNormalRecord { uv_min: unorm16x2(0.5, 0.0) }];
    data.write_to_path(dir.join("normals.treelod"), Compression::None).expect("valid");
    let out = treelod_in(&dir, &["dump", "normals.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    assert!(text.lines().any(|l| l.starts_with("version") && l.ends_with("1.15")), "{text}");
    assert!(text.contains("\n  OCTAHEDRAL_NORMALS "), "the section is listed: {text}");
    assert!(
        text.contains(
            "\nbaselines\n  octahedral tree 0: 8x8 views, radius 0.75 m at [1, 0.5, 0.5], image 0 rectangle [0, 0] \
             .. [0.5000076, 1] (8 texels), occlusion 0.25, diffuse flat 0.2500 scattered 0.5000, normals \
             [0.5000076, 0] .. [1, 1]\n"
        ),
        "{text}"
    );
    let steps = |o: &serde_json::Value, key: &str| -> Vec<f64> {
        o[key].as_array().expect("[u, v]").iter().filter_map(|x| x.as_f64()).map(|x| (x * 65535.0).round()).collect()
    };
    let j = json("normals.treelod");
    let o = &j["baselines"]["octahedral"][0];
    assert_eq!(steps(o, "normals_uv_min"), [32768.0, 0.0], "{o}");
    assert_eq!(steps(o, "normals_uv_max"), [65535.0, 65535.0], "{o}");
    let out = treelod_in(&dir, &["verify", "normals.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(stdout(&out).contains(", 1 octahedral impostor, 1 octahedral normal grid;"), "{}", stdout(&out));
    data.octahedral_normals.clear();

    // With a grid of its own size instead, half the colour grid's, on the right half's top left
    // quarter (spec §6.13.3, format 1.16): its corners as stored, in the text and the JSON, and
    // the same count in verify's line.
    let at = |u: u32, v: u32| (v << 16) | u;
    data.octahedral_normal_grids = vec![OctahedralNormalGridRecord { uv_min: at(32768, 0), uv_max: at(49152, 32768) }];
    data.write_to_path(dir.join("grids.treelod"), Compression::None).expect("valid");
    let out = treelod_in(&dir, &["dump", "grids.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    assert!(text.lines().any(|l| l.starts_with("version") && l.ends_with("1.16")), "{text}");
    assert!(text.contains("\n  OCTAHEDRAL_NORMAL_GRIDS "), "the section is listed: {text}");
    assert!(!text.contains("\n  OCTAHEDRAL_NORMALS "), "{text}");
    assert!(
        text.contains(
            "(8 texels), occlusion 0.25, diffuse flat 0.2500 scattered 0.5000, normals [0.5000076, 0] .. [0.75001144, \
             0.5000076]\n"
        ),
        "{text}"
    );
    let j = json("grids.treelod");
    let o = &j["baselines"]["octahedral"][0];
    assert_eq!(steps(o, "normals_uv_min"), [32768.0, 0.0], "{o}");
    assert_eq!(steps(o, "normals_uv_max"), [49152.0, 32768.0], "{o}");
    let out = treelod_in(&dir, &["verify", "grids.treelod"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(stdout(&out).contains(", 1 octahedral impostor, 1 octahedral normal grid;"), "{}", stdout(&out));
    // An empty grid does not verify: the record and the reason are named.
    data.octahedral_normal_grids[0].uv_max = at(32768, 32768);
    data.write_to_path(dir.join("empty-grid.treelod"), Compression::None).expect("only verify checks the grid");
    let out = treelod_in(&dir, &["verify", "empty-grid.treelod"]);
    assert_eq!(out.status.code(), Some(3), "stdout: {}", stdout(&out));
    assert!(stderr(&out).contains("OCTAHEDRAL_NORMAL_GRIDS record 0: the normal grid"), "{}", stderr(&out));
    data.octahedral_normal_grids.clear();

    // With a billboard on the same image, the views share the billboards' atlas and its bytes
    // count as the billboards'.
    data.billboards = vec![BillboardRecord {
        center: [1.0, 0.5, 0.5],
        axis_u: [0.75, 0.0, 0.0],
        axis_v: [0.0, 0.5, 0.0],
        image: 0,
        uv_min: unorm16x2(0.5, 0.0),
        uv_max: unorm16x2(1.0, 1.0),
        tree: 0,
        kind: billboard_kind::FACING,
        reserved: [0; 2],
    }];
    data.write_to_path(dir.join("shared.treelod"), Compression::None).expect("valid");
    let j = json("shared.treelod");
    let uses: Vec<&str> =
        j["textures"].as_array().unwrap().iter().map(|u| u["representation"].as_str().unwrap()).collect();
    assert_eq!(uses, ["billboards"]);
    assert_eq!(j["baselines"]["octahedral"][0]["texels"], 8);
    // Without the impostor there is no `octahedral` key, as in the files of 1.10 and before.
    data.octahedral.clear();
    data.write_to_path(dir.join("without.treelod"), Compression::None).expect("valid");
    let j = json("without.treelod");
    assert!(j["baselines"].get("octahedral").is_none(), "{}", j["baselines"]);
    assert!(!stdout(&treelod_in(&dir, &["dump", "without.treelod"])).contains("octahedral"));
}

#[test]
fn verify_checks_every_file_and_exits_with_the_first_failure() {
    let dir = scratch("several");
    let good = write_tiny(&dir);
    let missing = dir.join("missing.treelod");
    let bad = dir.join("bad.treelod");
    std::fs::write(&bad, b"not a container").expect("written");
    let arg = |p: &Path| p.to_str().expect("UTF-8 path").to_owned();
    let out = treelod(&["verify", &arg(&good), &arg(&missing), &arg(&bad), &arg(&good)]);
    assert_eq!(out.status.code(), Some(5), "the first failure is the missing file");
    assert_eq!(stdout(&out).lines().count(), 2, "both copies of the good file are reported ok");
    let err = stderr(&out);
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 2, "{err}");
    assert!(lines[0].starts_with(&format!("error: {}: ", missing.display())));
    assert!(lines[1].starts_with(&format!("error: {}: ", bad.display())));

    let out = treelod(&["verify", &arg(&bad), &arg(&missing)]);
    assert_eq!(out.status.code(), Some(3), "the first failure is the invalid file");

    // Files checked side by side are still reported in the order given, whatever the jobs.
    let other = dir.join("other.treelod");
    std::fs::copy(&good, &other).expect("copied");
    let files = [&bad, &good, &missing, &other, &dir, &good, &bad];
    let mut args = vec!["verify".to_owned(), "--jobs".to_owned(), String::new()];
    args.extend(files.iter().map(|p| arg(p)));
    let mut seen = Vec::new();
    for jobs in ["1", "2", "3", "7", "64"] {
        args[2] = jobs.to_owned();
        let out = treelod(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert_eq!(out.status.code(), Some(3), "--jobs {jobs}: the first failure is the invalid file");
        let ok: Vec<String> = stdout(&out).lines().map(|l| l.split(": ok").next().unwrap_or("").to_owned()).collect();
        assert_eq!(ok, [arg(&good), arg(&other), arg(&good)], "--jobs {jobs}");
        let err = stderr(&out);
        let failed: Vec<&str> = err.lines().map(|l| l.split(": ").nth(1).unwrap_or("")).collect();
        assert_eq!(failed, [arg(&bad), arg(&missing), arg(&dir), arg(&bad)], "--jobs {jobs}: {err}");
        seen.push((stdout(&out), err));
    }
    assert!(seen.windows(2).all(|w| w[0] == w[1]), "the same lines whatever the jobs");
    let out = treelod(&["verify", "--jobs", "0", &arg(&good)]);
    assert_eq!(out.status.code(), Some(2), "no jobs is a usage error");
}

#[test]
fn usage_errors_exit_with_2_and_help_documents_exit_codes() {
    for args in [&[][..], &["dump"], &["verify"], &["dump", "--bogus", "x"], &["frobnicate"]] {
        let out = treelod(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(stdout(&out).is_empty(), "{args:?}");
    }
    for args in [&["--help"][..], &["dump", "--help"], &["verify", "--help"]] {
        let out = treelod(args);
        assert_eq!(out.status.code(), Some(0));
        let help = stdout(&out);
        for code in ["0  success", "2  usage error", "3  invalid input", "4  unsupported", "5  I/O error"] {
            assert!(help.contains(code), "{args:?} help lacks {code:?}:\n{help}");
        }
    }
}

/// The calibration's FLIP error (`CALIBRATION_FLIP`, spec §6.19, format 1.17) of the golden 1.17
/// file: `dump` prints its table over every view after the RMSE tables, laid out as they are
/// (a row per technique, a column per height, four decimals, no primitive counts), then one per
/// elevation, and the JSON holds one object per record; `verify` accepts the file and counts the
/// records. The 1.16 file, without the section, prints no FLIP table and has no JSON key.
#[test]
fn dump_and_verify_show_the_calibration_flip_of_the_1_17_golden_file() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/v1_17");
    let name = "every-kind-zstd.treelod";
    let out = treelod_in(&dir, &["dump", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    assert!(text.lines().any(|l| l.starts_with("version") && l.ends_with("1.17")), "{text}");
    assert!(text.contains("\n  CALIBRATION_FLIP "), "the section is listed: {text}");
    let every_view = "\ncalibration FLIP (mean LDR-FLIP of the shaded colour against the supersampled full mesh, by \
                      the block's projected height)\n  technique ";
    let (rmse, flip) = (text.find("\ncalibration at 90° elevation").expect("RMSE tables"), text.find(every_view));
    assert!(flip.is_some_and(|flip| flip > rmse), "after the RMSE tables: {text}");
    let table = &text[flip.unwrap_or(0)..];
    for heading in ["calibration FLIP at 30° elevation", "calibration FLIP at 90° elevation"] {
        assert!(table.contains(&format!("\n{heading} (the same, from the views at that elevation)\n")), "{text}");
    }
    // Rows named as the RMSE tables name them, each value with four decimals and no count.
    let rows: Vec<&str> =
        table.lines().filter(|l| l.starts_with("  full ") || l.starts_with("  octahedral ")).collect();
    assert_eq!(rows.len(), 2 * 3, "two techniques in each of three tables: {table}");
    for row in rows {
        let values: Vec<&str> = row.split_whitespace().skip(1).collect();
        assert_eq!(values.len(), 3, "{row}");
        assert!(values.iter().all(|v| v.len() == 6 && v.starts_with("0.") && !v.contains('(')), "{row}");
    }
    let out = treelod_in(&dir, &["dump", "--json", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let records = j["calibration_flip"].as_array().expect("an array of records");
    assert_eq!(records.len(), 18);
    assert_eq!(records[0]["elevation"], -1.0);
    assert_eq!(records[0]["technique"], "full");
    assert_eq!(records[17]["elevation"], 90.0);
    assert_eq!(records[17]["technique"], "octahedral");
    assert!(records.iter().all(|r| r["height"].as_f64().is_some_and(|h| h > 0.0)));
    assert!(records.iter().all(|r| r["flip"].as_f64().is_some_and(|f| (0.0..=1.0).contains(&f))));
    let out = treelod_in(&dir, &["verify", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(stdout(&out).contains("per elevation, 18 FLIP calibration records, "), "{}", stdout(&out));

    let dir = dir.join("../v1_16");
    let out = treelod_in(&dir, &["dump", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(!stdout(&out).contains("FLIP"), "{}", stdout(&out));
    let out = treelod_in(&dir, &["dump", "--json", name]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert!(j.get("calibration_flip").is_none(), "no key without the section");
}

/// The LoD chain levels' FLIP error (`CHAIN_CALIBRATION_FLIP`, spec §6.20, format 1.18) of the
/// golden 1.18 file: `dump` prints a row per level (`lod-chain level N`) in the FLIP table over
/// every view, after the representations' rows, as the RMSE table over every view has the levels'
/// rows (four decimals, no primitive counts; not in the tables per elevation), and the JSON holds
/// one object per record; `verify` accepts the file and counts the records. The 1.17 file, without
/// the section, prints no level rows in its FLIP table and has no JSON key.
#[test]
fn dump_and_verify_show_the_chain_calibration_flip_of_the_1_18_golden_file() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/v1_18");
    let name = "every-kind-zstd.treelod";
    let out = treelod_in(&dir, &["dump", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    assert!(text.lines().any(|l| l.starts_with("version") && l.ends_with("1.18")), "{text}");
    assert!(text.contains("\n  CHAIN_CALIBRATION_FLIP "), "the section is listed: {text}");
    let every_view = "\ncalibration FLIP (mean LDR-FLIP of the shaded colour against the supersampled full mesh, by \
                      the block's projected height)\n  technique ";
    let flip = text.find(every_view).expect("the FLIP table over every view");
    let per_elevation = text.find("\ncalibration FLIP at 30° elevation").expect("the FLIP tables per elevation");
    assert!(flip < per_elevation, "{text}");
    // The levels' rows close the table over every view, each with a value at its three heights
    // (four decimals, no count), and no table per elevation has them.
    let table = &text[flip..per_elevation];
    let rows: Vec<&str> = table.lines().filter(|l| l.starts_with("  lod-chain level ")).collect();
    assert_eq!(rows.len(), 3, "three levels: {table}");
    for (level, row) in rows.iter().enumerate() {
        assert!(row.starts_with(&format!("  lod-chain level {level} ")), "{row}");
        let values: Vec<&str> = row.split_whitespace().skip(3).collect();
        assert_eq!(values.len(), 3, "{row}");
        assert!(values.iter().all(|v| v.len() == 6 && v.starts_with("0.") && !v.contains('(')), "{row}");
    }
    let last_technique = table.find("\n  octahedral ").expect("the representations' rows");
    assert!(table.find("\n  lod-chain level 0 ").is_some_and(|l| l > last_technique), "{table}");
    assert!(!text[per_elevation..].contains("lod-chain level"), "{text}");

    let out = treelod_in(&dir, &["dump", "--json", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let records = j["chain_calibration_flip"].as_array().expect("an array of records");
    assert_eq!(records.len(), 9);
    let levels: Vec<u64> = records.iter().map(|r| r["level"].as_u64().expect("a level")).collect();
    assert_eq!(levels, [0, 0, 0, 1, 1, 1, 2, 2, 2]);
    // At the heights of the chain's RMSE table, record for record.
    let chain = j["calibration"]["chain_levels"].as_array().expect("the chain's RMSE table");
    let heights = chain.iter().flat_map(|l| l["samples"].as_array().expect("samples").iter().map(|s| &s[0]));
    assert!(records.iter().map(|r| &r["height"]).eq(heights), "{records:?}");
    assert!(records.iter().all(|r| r["flip"].as_f64().is_some_and(|f| (0.0..=1.0).contains(&f))));
    assert_eq!(j["calibration_flip"].as_array().map(Vec::len), Some(18), "the calibration's FLIP error too");
    let out = treelod_in(&dir, &["verify", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let line = stdout(&out);
    assert!(line.contains(", 18 FLIP calibration records, 9 chain FLIP calibration records, "), "{line}");

    let dir = dir.join("../v1_17");
    let out = treelod_in(&dir, &["dump", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    let flip = text.find("\ncalibration FLIP (").expect("1.17's FLIP tables");
    assert!(!text[flip..].contains("lod-chain level"), "{text}");
    let out = treelod_in(&dir, &["dump", "--json", name]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert!(j.get("chain_calibration_flip").is_none(), "no key without the section");
    let out = treelod_in(&dir, &["verify", name]);
    assert!(!stdout(&out).contains("chain FLIP"), "{}", stdout(&out));
}

/// What the renderer's policy draws by default (`dump`'s `policy` part, from the calibration): on
/// the golden 1.18 file a line per elevation class, 0° to 90° every 10°, after the FLIP tables, each
/// from the tables' smallest height with heights ascending and techniques of the file's tables; the
/// JSON holds the same classes. The 1.5 file, whose tables are over every view only, has one class
/// without an elevation; the 1.0 file, without tables, none.
#[test]
fn dump_shows_what_the_policy_draws_by_elevation_and_height() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/v1_18");
    let name = "every-kind-zstd.treelod";
    let out = treelod_in(&dir, &["dump", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    let text = stdout(&out);
    let heading = "\npolicy (what the renderer draws a tree with by default, target 0.01: from each projected height up, \
                   by the elevation it is seen from; fully visible, wholly in view, chosen afresh)\n";
    let at = text.find(heading).expect("the policy part");
    assert!(text.find("\ncalibration FLIP (").is_some_and(|flip| flip < at), "after the FLIP tables: {text}");
    let lines: Vec<&str> = text[at + heading.len()..].lines().take_while(|l| !l.is_empty()).collect();
    let elevations: Vec<&str> = lines.iter().filter_map(|l| l.split_whitespace().next()).collect();
    assert_eq!(elevations, ["0°", "10°", "20°", "30°", "40°", "50°", "60°", "70°", "80°", "90°"], "{text}");

    let out = treelod_in(&dir, &["dump", "--json", name]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    // The smallest height of the representations' tables, the added ones' included.
    let c = &j["calibration"];
    let smallest = ["techniques", "added_techniques"]
        .iter()
        .flat_map(|key| c[key].as_array().into_iter().flatten())
        .flat_map(|t| t["samples"].as_array().expect("samples").iter().map(|s| s[0].as_f64().expect("a height")))
        .fold(f64::INFINITY, f64::min);
    // The techniques with tables: the chain's by its levels' where it has them.
    let mut held: Vec<&str> = ["techniques", "added_techniques"]
        .iter()
        .flat_map(|key| c[key].as_array().into_iter().flatten())
        .map(|t| t["technique"].as_str().expect("a name"))
        .collect();
    if c["chain_levels"].as_array().is_some_and(|levels| !levels.is_empty()) {
        held.push("lod-chain");
    }
    assert_eq!(j["policy"]["target"], 0.01);
    let classes = j["policy"]["classes"].as_array().expect("the classes");
    assert_eq!(classes.len(), 10);
    for (k, (class, line)) in classes.iter().zip(&lines).enumerate() {
        assert_eq!(class["elevation"].as_f64(), Some(10.0 * k as f64));
        let runs = class["runs"].as_array().expect("runs");
        let heights: Vec<f64> = runs.iter().map(|r| r[0].as_f64().expect("a height")).collect();
        assert!((heights[0] - smallest).abs() < 1e-3 * smallest, "from the smallest height: {heights:?}");
        assert!(heights.windows(2).all(|w| w[0] < w[1]), "{heights:?}");
        for run in runs {
            let technique = run[1].as_str().expect("a technique");
            assert!(held.contains(&technique), "{technique} has tables: {held:?}");
            assert!(line.contains(&format!(" px: {technique}")), "{line}");
        }
        if let Some(uniform) = class.get("uniform_below") {
            assert_eq!(uniform[1], runs[0][1], "the smallest trees' technique");
            assert!(line.contains("(every tree under "), "{line}");
        }
    }

    let out = treelod_in(&dir.join("../v1_5"), &["dump", "--json", name]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let classes = j["policy"]["classes"].as_array().expect("the classes");
    assert_eq!(classes.len(), 1);
    assert!(classes[0]["elevation"].is_null(), "over every view");
    let out = treelod_in(&dir.join("../v1_5"), &["dump", name]);
    assert!(stdout(&out).contains("\n  every view  "), "{}", stdout(&out));
    let out = treelod_in(&dir.join("../v1_0"), &["dump", "--json", name]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert!(j.get("policy").is_none(), "no tables, no policy");

    // A file that does not verify (one byte of its vertices' occlusion changed, its checksum no
    // longer matching) dumps its tables but no policy: the renderer would not read it.
    let out = treelod_in(&dir, &["dump", "--json", name]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let section = j["sections"].as_array().expect("sections").iter().find(|s| s["name"] == "VERTEX_AO");
    let offset = section.and_then(|s| s["offset"].as_u64()).expect("the occlusion section");
    let mut bytes = std::fs::read(dir.join(name)).expect("the golden file");
    let at = usize::try_from(offset).expect("an offset");
    bytes[at] ^= 0x01;
    let broken = scratch("dump_policy_unverified");
    std::fs::write(broken.join(name), &bytes).expect("the copy");
    let out = treelod_in(&broken, &["verify", name]);
    assert_ne!(out.status.code(), Some(0), "the copy does not verify");
    let out = treelod_in(&broken, &["dump", name]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", stderr(&out));
    assert!(stdout(&out).contains("\ncalibration at 90° elevation"), "{}", stdout(&out));
    assert!(!stdout(&out).contains("\npolicy ("), "{}", stdout(&out));
}

/// Golden files: every `tests/data/v1_*/NAME.treelod` has `NAME.dump.txt` and `NAME.dump.json`
/// beside it, the exact output of `treelod dump NAME.treelod` and `treelod dump --json
/// NAME.treelod` run in that directory. With no `.treelod` there yet, the test passes; a
/// `.treelod` without its expected output fails it.
///
/// To (re)write the expected files after a deliberate change of the dump output, run
/// `TREELOD_BLESS=1 cargo test -p treelod --test cli golden` and review the diff.
#[test]
fn golden_dumps_match() {
    for version in [
        "v1_0", "v1_1", "v1_2", "v1_3", "v1_4", "v1_5", "v1_6", "v1_7", "v1_8", "v1_9", "v1_10", "v1_11", "v1_12",
        "v1_13", "v1_14", "v1_15", "v1_16", "v1_17", "v1_18",
    ] {
        golden_dumps_match_in(version);
    }
}

fn golden_dumps_match_in(version: &str) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data").join(version);
    let bless = std::env::var_os("TREELOD_BLESS").is_some_and(|v| v == "1");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return; // no golden directory yet
    };
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|name| name.ends_with(".treelod"))
        .collect();
    names.sort();
    let mut failures = Vec::new();
    for name in &names {
        let stem = name.trim_end_matches(".treelod");
        for (args, expected_name) in [
            (vec!["dump", name.as_str()], format!("{stem}.dump.txt")),
            (vec!["dump", "--json", name.as_str()], format!("{stem}.dump.json")),
        ] {
            let out = treelod_in(&dir, &args);
            assert_eq!(out.status.code(), Some(0), "treelod {args:?}: {}", stderr(&out));
            let expected_path = dir.join(&expected_name);
            if bless {
                std::fs::write(&expected_path, &out.stdout).expect("expected output written");
                continue;
            }
            match std::fs::read(&expected_path) {
                Ok(expected) if expected == out.stdout => {}
                Ok(expected) => failures.push(format!(
                    "{expected_name}: `treelod {}` differs:\n{}",
                    args.join(" "),
                    first_difference(&String::from_utf8_lossy(&expected), &stdout(&out))
                )),
                Err(e) => failures.push(format!("{expected_name}: cannot read the expected output ({e})")),
            }
        }
    }
    assert!(
        failures.is_empty(),
        "golden dumps in {} (rewrite with TREELOD_BLESS=1 if the change is deliberate):\n{}",
        dir.display(),
        failures.join("\n")
    );
}

/// The first differing line of two texts, for a readable failure.
fn first_difference(expected: &str, actual: &str) -> String {
    let expected: Vec<&str> = expected.lines().collect();
    let actual: Vec<&str> = actual.lines().collect();
    for i in 0..expected.len().max(actual.len()) {
        if expected.get(i) != actual.get(i) {
            return format!("line {}:\n  expected: {:?}\n  actual:   {:?}", i + 1, expected.get(i), actual.get(i));
        }
    }
    "only line endings differ".into()
}

#[test]
fn demo_builds_a_verified_container_with_no_input() {
    let dir = tempfile_dir("demo");
    let out = dir.join("demo.treelod");
    let run = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .args(["demo", "--leaf-count", "500", "-o"])
        .arg(&out)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "stderr: {}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("built from the built-in demo tree"), "{stdout}");
    assert!(stdout.contains("(leaf 1000, bark"), "500 leaf quads are 1000 leaf triangles: {stdout}");
    assert!(stdout.contains("verify        ok"), "{stdout}");
    let container = treelod_format::Container::open(&out).expect("opens");
    treelod_format::verify(&container).expect("verifies");
    assert_eq!(container.metadata().name, "demo-tree");
    // Same seed, same bytes.
    let again = dir.join("again.treelod");
    let status = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .args(["demo", "--leaf-count", "500", "--json", "-o"])
        .arg(&again)
        .output()
        .expect("runs");
    assert!(status.status.success());
    let json: serde_json::Value = serde_json::from_slice(&status.stdout).expect("one JSON object");
    assert_eq!(json["leaf_triangles"], 1000);
    assert_eq!(std::fs::read(&out).expect("reads"), std::fs::read(&again).expect("reads"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fresh directory under the system temporary directory for one test.
fn tempfile_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("treelod-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("creates a temporary directory");
    dir
}

#[test]
fn build_writes_one_verified_container_per_input_and_reports_bad_gltf() {
    let dir = tempfile_dir("build");
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees/quaternius-common-tree-1-3k.glb");
    assert!(model.exists(), "the shared models sit in ../shared beside the repository");
    let run = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .arg("build")
        .arg(&model)
        .arg("-o")
        .arg(&dir)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "stderr: {}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("(leaf 528, bark 2360; dropped 0)"), "{stdout}");
    let out = dir.join("quaternius-common-tree-1-3k.treelod");
    treelod_format::verify(&treelod_format::Container::open(&out).expect("opens")).expect("verifies");
    let dump = Command::new(env!("CARGO_BIN_EXE_treelod")).arg("dump").arg(&out).output().expect("runs");
    let dump = String::from_utf8_lossy(&dump.stdout);
    assert!(
        dump.contains("leaf   \"geometry\"") || dump.contains("\"geometry\""),
        "dump shows how classes were decided: {dump}"
    );

    let bad = dir.join("bad.glb");
    std::fs::write(&bad, b"glTF garbage").expect("writes");
    let run = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .arg("build")
        .arg(&bad)
        .arg("-o")
        .arg(dir.join("bad.treelod"))
        .output()
        .expect("runs");
    assert_eq!(run.status.code(), Some(3));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.starts_with(&format!("error: {}: ", bad.display())), "{stderr}");
    assert!(!dir.join("bad.treelod").exists(), "nothing written for a failed build");

    // In a batch, a bad file is reported and the others are still built.
    let batch = dir.join("batch");
    let run = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .arg("build")
        .arg(&bad)
        .arg(&model)
        .arg("-o")
        .arg(&batch)
        .output()
        .expect("runs");
    assert_eq!(run.status.code(), Some(3), "the batch exits with the first failure");
    assert!(String::from_utf8_lossy(&run.stderr).contains(&bad.display().to_string()));
    treelod_format::verify(
        &treelod_format::Container::open(batch.join("quaternius-common-tree-1-3k.treelod")).expect("opens"),
    )
    .expect("the good input is built despite the bad one before it");
    assert!(!batch.join("bad.treelod").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn build_with_pruning_writes_the_lists_dump_shows_them_and_the_report_compares_orders() {
    let dir = tempfile_dir("prune");
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees/quaternius-common-tree-1-3k.glb");
    let out = dir.join("pruned.treelod");
    let small = ["--prune-resolution", "64", "--prune-views", "3"];
    let run = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .arg("build")
        .arg(&model)
        .arg("-o")
        .arg(&out)
        .args(["--prune", "density", "--prune-quality", "0.8", "--prune-report", "--prune-plot"])
        .arg(&dir)
        .args(small)
        .output()
        .expect("runs");
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "stderr: {}", String::from_utf8_lossy(&run.stderr));
    // The report: every order against Cook, then the build's summary with the curves.
    assert!(text.contains("pruning orders compared on"), "{text}");
    for line in ["Q stochastic + s_Cook", "s_opt density", "Q combined + s_opt", "stochastic + s_Cook  "] {
        assert!(text.contains(line), "{line:?} in {text}");
    }
    assert!(text.contains("  prune         ") && text.contains("  s_opt(λ)      0.05:"), "{text}");
    let container = treelod_format::Container::open(&out).expect("opens");
    treelod_format::verify(&container).expect("verifies");
    assert!(!container.prune_leaves().is_empty());
    let setting = |key: &str| container.metadata().setting(key).map(str::to_owned);
    assert_eq!(setting("prune.order").as_deref(), Some("density"));
    assert_eq!(setting("prune.min_quality").as_deref(), Some("0.8"));
    let dump = treelod(&["dump", out.to_str().expect("UTF-8 path")]);
    let dump = stdout(&dump);
    assert!(dump.contains("\npruning\n  leaves     "), "{dump}");
    assert!(dump.contains("PRUNE_SCALE s_opt(λ) (14 samples)") && dump.contains("(20 samples)"), "{dump}");
    let json = treelod(&["dump", "--json", out.to_str().expect("UTF-8 path")]);
    let json: serde_json::Value = serde_json::from_slice(&json.stdout).expect("JSON");
    assert_eq!(json["pruning"]["scale"].as_array().map(Vec::len), Some(14));
    // The plot of s_opt and Q against λ.
    let (width, height, pixels) = read_png(&dir.join("pruned.prune.png"));
    assert_eq!((width, height), (720, 24 + 2 * (200 + 48)));
    assert!(pixels.iter().filter(|p| p[..3] != [255, 255, 255]).count() > 1000);
    // Drawn pruned: near trees draw a fraction of their leaves.
    let png = dir.join("pruned.png");
    let out_str = out.to_str().expect("UTF-8 path");
    let png_str = png.to_str().expect("UTF-8 path");
    let drawn = treelod(&["render", out_str, "-o", png_str, "--size", "200x200", "--technique", "prune-opt"]);
    let line = stdout(&drawn);
    assert!(line.contains(", 1 tree(s) drawn with prune-opt submitting ") && line.contains(" pruned leaves"), "{line}");
    let all = treelod(&[
        "render",
        out_str,
        "-o",
        png_str,
        "--size",
        "200x200",
        "--technique",
        "prune-cook",
        "--prune-lambda",
        "1",
    ]);
    let leaves = |line: &str| -> u64 {
        let before = line.split(" pruned leaves").next().unwrap_or_default();
        before.rsplit(' ').next().and_then(|n| n.parse().ok()).expect("a count")
    };
    assert_eq!(leaves(&stdout(&all)), container.prune_leaves().len() as u64, "λ = 1 draws every leaf");
    assert!(leaves(&line) < container.prune_leaves().len() as u64, "{line}");
    // eval with a fixed λ: a quarter of the leaves draws fewer primitives than all of them, and
    // a fixed λ without a pruning technique to apply it to is refused.
    let eval_primitives = |lambda: &str| -> u64 {
        let csv = dir.join(format!("eval-{lambda}.csv"));
        let csv_str = csv.to_str().expect("UTF-8 path");
        let args = ["eval", out_str, "--views", "1", "--size", "96x72", "--supersample", "1"];
        let run =
            treelod(&[&args[..], &["--technique", "prune-opt", "--prune-lambda", lambda, "--csv", csv_str]].concat());
        assert!(run.status.success(), "stderr: {}", String::from_utf8_lossy(&run.stderr));
        let text = std::fs::read_to_string(&csv).expect("the CSV");
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
        let column = header.iter().position(|&c| c == "primitives").expect("a primitives column");
        let row = lines.find(|l| l.contains(",prune-opt,")).expect("a prune-opt row");
        row.split(',').nth(column).and_then(|n| n.parse().ok()).expect("a count")
    };
    let (quarter, every) = (eval_primitives("0.25"), eval_primitives("1"));
    assert!(quarter < every, "λ 0.25: {quarter} primitives, λ 1: {every}");
    let refused = treelod(&["eval", out_str, "--views", "1", "--technique", "spt", "--prune-lambda", "0.5"]);
    assert_eq!(refused.status.code(), Some(2), "a usage error");
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(message.contains("--prune-lambda needs prune-opt or prune-cook among --technique"), "{message}");
    // Without --prune nothing is pruned, and a quality outside [0, 1] is a usage error.
    let plain = dir.join("plain.treelod");
    let run = Command::new(env!("CARGO_BIN_EXE_treelod")).arg("build").arg(&model).arg("-o").arg(&plain).output();
    assert!(run.expect("runs").status.success());
    let plain = treelod_format::Container::open(&plain).expect("opens");
    assert!(plain.prune_leaves().is_empty() && plain.metadata().setting("prune.order").is_none());
    let bad = Command::new(env!("CARGO_BIN_EXE_treelod"))
        .arg("build")
        .arg(&model)
        .arg("-o")
        .arg(dir.join("bad.treelod"))
        .args(["--prune", "combined", "--prune-quality", "1.5"])
        .output()
        .expect("runs");
    assert_eq!(bad.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------------
// Untrusted input: resource limits, files that are not regular, outputs that fail verification,
// stale temporary files (issue 28). The import's own refusals are tested in the build crate; these
// check that the command maps them to its exit codes and one `error: FILE: reason` line.

/// The small shared tree (2888 triangles, 158 kB).
fn small_tree() -> PathBuf {
    common::model("quaternius-common-tree-1-3k.glb")
}

/// Asserts that `out` failed with `code` and printed exactly one line to stderr, an error naming
/// `path` first; returns that line.
fn one_error_line(out: &Output, code: i32, path: &Path) -> String {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(code), "stderr: {err}");
    assert_eq!(err.lines().count(), 1, "one line: {err}");
    assert!(err.starts_with(&format!("error: {}: ", path.display())), "stderr: {err}");
    assert!(!err.contains("panicked"), "stderr: {err}");
    err
}

/// A GLB of one triangle with texture coordinates, textured with `png` (embedded in the binary
/// chunk) when given.
fn triangle_glb(png: Option<&[u8]>) -> Vec<u8> {
    let (json, bin) = triangle(png);
    glb_of(&json, &bin)
}

/// A GLB of `json` with `bin` as its binary chunk (padded to 4 bytes, as its buffer declares).
fn glb_of(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(json).expect("serialises");
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut glb = Vec::with_capacity(total);
    let u32_le = |n: usize| u32::try_from(n).expect("small").to_le_bytes();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&u32_le(total));
    glb.extend_from_slice(&u32_le(text.len()));
    glb.extend_from_slice(b"JSON");
    glb.extend_from_slice(&text);
    glb.extend_from_slice(&u32_le(bin.len()));
    glb.extend_from_slice(b"BIN\0");
    glb.extend_from_slice(bin);
    glb
}

/// The glTF JSON and binary buffer of [`triangle_glb`] (the buffer without a URI).
fn triangle(png: Option<&[u8]>) -> (serde_json::Value, Vec<u8>) {
    let mut bin: Vec<u8> = Vec::new();
    for v in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        bin.extend(v.iter().flat_map(|c| c.to_le_bytes()));
    }
    for uv in [[0.0f32, 1.0], [1.0, 1.0], [0.0, 0.0]] {
        bin.extend(uv.iter().flat_map(|c| c.to_le_bytes()));
    }
    let mut json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "leaf"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
        "materials": [{"name": "leaves", "pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.6, 0.1, 1.0]}}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}
        ],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 24}],
    });
    if let Some(png) = png {
        let offset = bin.len();
        bin.extend_from_slice(png);
        json["bufferViews"].as_array_mut().expect("an array").push(serde_json::json!(
            {"buffer": 0, "byteOffset": offset, "byteLength": png.len()}
        ));
        json["images"] = serde_json::json!([{"bufferView": 2, "mimeType": "image/png"}]);
        json["textures"] = serde_json::json!([{"source": 0}]);
        json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = serde_json::json!({"index": 0});
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    json["buffers"] = serde_json::json!([{"byteLength": bin.len()}]);
    (json, bin)
}

/// An opaque green RGBA PNG of `width` × `height` pixels.
fn png_image(width: u32, height: u32) -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().expect("a header");
    let pixels: Vec<u8> = (0..width * height).flat_map(|_| [40u8, 160, 30, 255]).collect();
    writer.write_image_data(&pixels).expect("encodes");
    writer.finish().expect("finishes");
    bytes
}

/// The names of the files in `dir`, sorted.
fn dir_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("lists")
        .map(|e| e.expect("an entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn an_input_over_a_limit_is_unsupported_and_names_the_option() {
    let dir = scratch("over_a_limit");
    let tree = small_tree();
    let out_path = dir.join("tree.treelod");
    // The file itself is over the decoded-bytes limit (the build and batch read it within it).
    let out = run_os(
        [OsStr::new("build"), tree.as_os_str(), OsStr::new("-o"), out_path.as_os_str()]
            .into_iter()
            .chain(["--max-decoded-bytes", "64K"].map(OsStr::new)),
    );
    let line = one_error_line(&out, 4, &tree);
    assert!(line.contains("--max-decoded-bytes"), "{line}");
    assert!(!out_path.exists(), "nothing written");
    // Its 2888 triangles are over a triangle limit of 1000.
    let out = run_os(
        [OsStr::new("build"), tree.as_os_str(), OsStr::new("-o"), out_path.as_os_str()]
            .into_iter()
            .chain(["--max-triangles", "1000"].map(OsStr::new)),
    );
    let line = one_error_line(&out, 4, &tree);
    assert!(line.contains("--max-triangles"), "{line}");
    assert!(!out_path.exists(), "nothing written");
    // Within the limits the options change nothing: they are not recorded settings.
    let plain = dir.join("plain.treelod");
    let out = run_os([OsStr::new("build"), tree.as_os_str(), OsStr::new("-o"), plain.as_os_str()]);
    assert!(out.status.success(), "{}", stderr(&out));
    let limited = ["--max-decoded-bytes", "4M", "--max-triangles", "3000", "--max-instances", "1000"];
    let limited = limited.iter().chain(&["--max-image-pixels", "1", "--allow-external-uris"]).map(OsStr::new);
    let out = run_os(
        [OsStr::new("build"), tree.as_os_str(), OsStr::new("-o"), out_path.as_os_str()].into_iter().chain(limited),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(std::fs::read(&plain).expect("reads") == std::fs::read(&out_path).expect("reads"), "same bytes");

    // In a batch: the file's failed line, the summary, exit 4.
    let lib = dir.join("lib");
    std::fs::create_dir_all(&lib).expect("creates");
    std::fs::copy(&tree, lib.join("tree.glb")).expect("copies");
    let out = treelod_in(&dir, &["batch", "lib", "-o", "converted", "--max-decoded-bytes", "64K", "--jobs", "1"]);
    let line = one_error_line(&out, 4, Path::new("lib/tree.glb"));
    assert!(line.contains("--max-decoded-bytes"), "{line}");
    let text = stdout(&out);
    assert!(text.contains("failed      converted/tree.treelod from lib/tree.glb"), "{text}");
    assert!(text.contains("1 file(s) in ") && text.contains(": 0 built, 0 up to date, 1 failed"), "{text}");
}

#[cfg(unix)]
#[test]
fn a_fifo_as_input_fails_at_once_as_not_a_regular_file() {
    let dir = scratch("fifo_input");
    let fifo = dir.join("tree.glb");
    let made = Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
    assert!(made.success());
    // Nothing ever writes to the FIFO: opening it to read would block forever.
    let start = std::time::Instant::now();
    let out = run_os([OsStr::new("build"), fifo.as_os_str(), OsStr::new("-o"), dir.join("out.treelod").as_os_str()]);
    let line = one_error_line(&out, 5, &fifo);
    assert!(line.contains("not a regular file"), "{line}");
    let out = treelod_in(&dir, &["batch", "tree.glb", "-o", "converted"]);
    let line = one_error_line(&out, 5, Path::new("tree.glb"));
    assert!(line.contains("not a regular file"), "{line}");
    assert!(stdout(&out).contains(": 0 built, 0 up to date, 1 failed"), "{}", stdout(&out));
    assert!(start.elapsed().as_secs() < 30, "no wait for a writer");
}

#[test]
fn uris_outside_the_models_directory_are_unsupported_unless_allowed() {
    let dir = scratch("external_uris");
    let models = dir.join("models");
    std::fs::create_dir_all(&models).expect("creates");
    let (mut json, bin) = triangle(None);
    std::fs::write(dir.join("outside.bin"), &bin).expect("writes");
    std::fs::write(models.join("inside.bin"), &bin).expect("writes");
    let cases = [("inside", "inside.bin".to_owned()), ("up", "../outside.bin".to_owned())];
    let absolute = ("absolute", dir.join("outside.bin").to_str().expect("UTF-8").to_owned());
    for (name, uri) in cases.into_iter().chain([absolute]) {
        json["buffers"][0]["uri"] = serde_json::json!(uri);
        let model = models.join(format!("{name}.gltf"));
        std::fs::write(&model, serde_json::to_vec(&json).expect("serialises")).expect("writes");
        let out_path = dir.join(format!("{name}.treelod"));
        let out = run_os([OsStr::new("build"), model.as_os_str(), OsStr::new("-o"), out_path.as_os_str()]);
        if name == "inside" {
            assert!(out.status.success(), "{uri}: {}", stderr(&out));
            continue;
        }
        let line = one_error_line(&out, 4, &model);
        assert!(line.contains("outside the model's directory") && line.contains("--allow-external-uris"), "{line}");
        assert!(!out_path.exists(), "{uri}: nothing written");
        let allowed = [OsStr::new("--allow-external-uris")];
        let out = run_os(
            [OsStr::new("build"), model.as_os_str(), OsStr::new("-o"), out_path.as_os_str()].into_iter().chain(allowed),
        );
        assert!(out.status.success(), "{uri} allowed: {}", stderr(&out));
    }
    // In a batch too: the model's line fails with exit 4, the others are built.
    let out = treelod_in(&dir, &["batch", "models", "-o", "converted", "--jobs", "1"]);
    assert_eq!(out.status.code(), Some(4), "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.contains(": 1 built, 0 up to date, 2 failed"), "{text}");
}

#[test]
fn unsupported_required_extensions_exit_4_and_read_ones_build() {
    let dir = scratch("required_extensions");
    let cases: [(&[&str], bool); 4] = [
        (&["KHR_texture_transform", "KHR_mesh_quantization"], true),
        (&["KHR_draco_mesh_compression"], false),
        (&["EXT_meshopt_compression"], false),
        (&["VENDOR_unknown_extension"], false),
    ];
    for (i, (required, builds)) in cases.into_iter().enumerate() {
        let (mut json, bin) = triangle(None);
        json["extensionsUsed"] = serde_json::json!(required);
        json["extensionsRequired"] = serde_json::json!(required);
        let model = dir.join(format!("model{i}.glb"));
        std::fs::write(&model, glb_of(&json, &bin)).expect("writes");
        let out_path = dir.join(format!("model{i}.treelod"));
        let out = run_os([OsStr::new("build"), model.as_os_str(), OsStr::new("-o"), out_path.as_os_str()]);
        if builds {
            assert!(out.status.success(), "{required:?}: {}", stderr(&out));
        } else {
            let line = one_error_line(&out, 4, &model);
            assert!(line.contains(required[0]), "{line}");
            assert!(!out_path.exists());
        }
    }
}

#[test]
fn a_failed_build_keeps_the_valid_output_of_the_same_name() {
    let dir = scratch("keeps_output");
    let out_path = dir.join("tree.treelod");
    let out = run_os([OsStr::new("build"), small_tree().as_os_str(), OsStr::new("-o"), out_path.as_os_str()]);
    assert!(out.status.success(), "{}", stderr(&out));
    let valid = std::fs::read(&out_path).expect("reads");
    // An image wider than the container allows (16384): refused by the import, or written and
    // failing verification; either way the valid file stays and no temporary file is left.
    let wide = dir.join("wide.glb");
    std::fs::write(&wide, triangle_glb(Some(&png_image(20_000, 1)))).expect("writes");
    // And an input that is not glTF at all.
    let garbage = dir.join("garbage.glb");
    std::fs::write(&garbage, b"glTF garbage").expect("writes");
    for input in [&wide, &garbage] {
        for batch in [false, true] {
            let out = if batch {
                let lib = dir.join("lib");
                let _ = std::fs::remove_dir_all(&lib);
                std::fs::create_dir_all(&lib).expect("creates");
                std::fs::copy(input, lib.join("tree.glb")).expect("copies");
                run_os([OsStr::new("batch"), lib.as_os_str(), OsStr::new("-o"), dir.as_os_str(), OsStr::new("--force")])
            } else {
                run_os([OsStr::new("build"), input.as_os_str(), OsStr::new("-o"), out_path.as_os_str()])
            };
            let err = stderr(&out);
            assert!(matches!(out.status.code(), Some(3 | 4)), "{}: {err}", input.display());
            assert_eq!(err.lines().filter(|l| l.starts_with("error: ")).count(), 1, "{err}");
            assert!(!err.contains("panicked"), "{err}");
            if err.starts_with(&format!("error: {}: ", out_path.display())) {
                assert!(err.contains("the old file is kept"), "{err}");
            }
            assert!(std::fs::read(&out_path).expect("reads") == valid, "{}: the valid output is kept", input.display());
            let names: Vec<String> = dir_names(&dir).into_iter().filter(|n| n.ends_with(".tmp")).collect();
            assert!(names.is_empty(), "no temporary file left: {names:?}");
        }
    }
}

#[test]
fn build_removes_stale_temporary_files_beside_its_outputs() {
    let dir = scratch("stale_temporaries");
    // Left by killed runs: two of tree.treelod's, and others that are not its.
    let theirs = [".tree.treelod.Ab12Cd.tmp", ".tree.treelod.x9Y8z7.tmp"];
    let others = [".other.treelod.Ab12Cd.tmp", ".tree.treelod.tmp", "tree.treelod.Ab12Cd.tmp"];
    for name in theirs.iter().chain(&others) {
        std::fs::write(dir.join(name), b"partial").expect("writes");
    }
    let out_path = dir.join("tree.treelod");
    let out = run_os([OsStr::new("build"), small_tree().as_os_str(), OsStr::new("-o"), out_path.as_os_str()]);
    let text = stdout(&out);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(text.starts_with("removed 2 temporary file(s) left beside outputs by an interrupted run\n"), "{text}");
    let mut expected: Vec<String> = others.iter().map(|n| (*n).to_owned()).collect();
    expected.push("tree.treelod".to_owned());
    expected.sort();
    assert_eq!(dir_names(&dir), expected);
    // Into a directory, with --json: removed too, and stdout stays JSON.
    std::fs::write(dir.join(".quaternius-common-tree-1-3k.treelod.Ab12Cd.tmp"), b"partial").expect("writes");
    let out = run_os([
        OsStr::new("build"),
        small_tree().as_os_str(),
        OsStr::new("-o"),
        dir.as_os_str(),
        OsStr::new("--json"),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let _: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert!(!dir.join(".quaternius-common-tree-1-3k.treelod.Ab12Cd.tmp").exists());
    assert!(dir.join("quaternius-common-tree-1-3k.treelod").exists());
}

#[test]
fn bad_limit_options_are_usage_errors() {
    let dir = scratch("bad_limits");
    common::assert_build_usage_errors(
        &dir,
        &[],
        &[
            (&["--max-decoded-bytes", "0"], "--max-decoded-bytes"),
            (&["--max-decoded-bytes", "12X"], "--max-decoded-bytes"),
            (&["--max-decoded-bytes=-1"], "--max-decoded-bytes"),
            (&["--max-decoded-bytes", "99999999999G"], "--max-decoded-bytes"),
            (&["--max-decoded-bytes", "G"], "--max-decoded-bytes"),
            (&["--max-image-pixels", "0"], "--max-image-pixels"),
            (&["--max-image-pixels", "8192x8192"], "--max-image-pixels"),
            (&["--max-instances", "0"], "--max-instances"),
            (&["--max-triangles", "1.5"], "--max-triangles"),
            (&["--allow-external-uris=yes"], "--allow-external-uris"),
        ],
    );
    let help = stdout(&treelod(&["build", "--help"]));
    for default in ["[default: 2G]", "[default: 67108864]", "[default: 1048576]", "[default: 16777216]"] {
        assert!(help.contains(default), "{default} in {help}");
    }
}

// ---------------------------------------------------------------------------------------------
// Scene files, `scatter` and `render`.

/// A demo container (500 leaf quads) built once per test process by the binary and shared by the
/// tests below. The directory is per process: nextest runs every test in its own process, and a
/// shared one would be removed by one test while another reads it.
fn shared_demo() -> &'static Path {
    static DEMO: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DEMO.get_or_init(|| {
        let dir = scratch(&format!("shared-demo-{}", std::process::id()));
        let path = dir.join("demo.treelod");
        let out = Command::new(env!("CARGO_BIN_EXE_treelod"))
            .args(["demo", "--leaf-count", "500", "--no-verify", "-o"])
            .arg(&path)
            .output()
            .expect("runs");
        assert!(out.status.success(), "demo: {}", stderr(&out));
        path
    })
}

/// Runs the binary with `args` (paths as `OsStr`s) in the current directory.
fn run_os<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    Command::new(env!("CARGO_BIN_EXE_treelod")).args(args).output().expect("the binary runs")
}

fn close_to(p: [u8; 4], rgb: [u8; 3]) -> bool {
    (0..3).all(|i| p[i].abs_diff(rgb[i]) <= 1)
}

/// Renders `input` to `output` with `extra` options; asserts success and returns stdout.
fn render_ok(input: &Path, output: &Path, extra: &[&str]) -> String {
    let mut args: Vec<std::ffi::OsString> = vec!["render".into(), input.into(), "-o".into(), output.into()];
    args.extend(extra.iter().map(Into::into));
    let out = run_os(&args);
    assert!(
        out.status.success(),
        "render {extra:?} failed (a Vulkan adapter is required: install mesa-vulkan-drivers): {}",
        stderr(&out)
    );
    assert!(!stderr(&out).contains("panicked"), "{}", stderr(&out));
    stdout(&out)
}

#[test]
fn scatter_is_deterministic_and_writes_a_scene_the_loader_reads() {
    let demo = shared_demo();
    let dir = scratch("scatter");
    std::fs::create_dir_all(dir.join("scenes")).expect("creates");
    let write = |name: &str, seed: &str| {
        let path = dir.join("scenes").join(name);
        let out = run_os([
            "scatter".as_ref(),
            "-o".as_ref(),
            path.as_os_str(),
            "--count".as_ref(),
            "12".as_ref(),
            "--seed".as_ref(),
            seed.as_ref(),
            demo.as_os_str(),
            demo.as_os_str(),
        ]);
        assert!(out.status.success(), "scatter: {}", stderr(&out));
        assert!(stdout(&out).contains("12 instances of 2 model(s)"), "{}", stdout(&out));
        (path.clone(), std::fs::read(&path).expect("written"))
    };
    let (first, bytes) = write("a.json", "5");
    let (_, again) = write("b.json", "5");
    let (_, other) = write("c.json", "6");
    assert_eq!(bytes, again, "the same arguments give the same bytes");
    assert_ne!(bytes, other, "another seed, another forest");

    let json: serde_json::Value = serde_json::from_slice(&bytes).expect("valid JSON");
    assert_eq!(json["version"], 1);
    let demo_dir = demo.parent().and_then(Path::file_name).expect("a directory").to_string_lossy();
    let relative = format!("../../{demo_dir}/demo.treelod");
    assert_eq!(json["models"], serde_json::json!([relative, relative]), "paths relative to the scene file");
    let instances = json["instances"].as_array().expect("instances");
    assert_eq!(instances.len(), 12);
    // Default area: one tree per 25 m², a square of side 5·sqrt(12) ≈ 17.3 m around the origin.
    for instance in instances {
        let t = &instance["translation"];
        assert_eq!(t[1], 0.0);
        assert!(t[0].as_f64().expect("x").abs() <= 8.7 && t[2].as_f64().expect("z").abs() <= 8.7, "{t}");
        let scale = instance["scale"].as_f64().expect("scale");
        assert!((0.8..=1.2).contains(&scale), "{scale}");
    }
    // The loader reads it back: rendering the scene loads every instance.
    let stdout = render_ok(&first, &dir.join("forest.png"), &["--size", "64x48"]);
    assert!(stdout.contains("of 12 instance(s) visible"), "{stdout}");
    assert!(
        !std::fs::read_dir(dir.join("scenes"))
            .expect("lists")
            .any(|e| { e.expect("entry").file_name().to_string_lossy().ends_with(".tmp") }),
        "no temporary file is left behind"
    );

    // A model that is not a container is refused before anything is written.
    let bad = dir.join("bad.treelod");
    std::fs::write(&bad, b"nope").expect("writes");
    let out = run_os([
        "scatter".as_ref(),
        "-o".as_ref(),
        dir.join("x.json").as_os_str(),
        "--count".as_ref(),
        "3".as_ref(),
        bad.as_os_str(),
    ]);
    assert_fails(&out, 3, &bad);
    assert!(!dir.join("x.json").exists());
}

#[test]
fn bad_scene_files_fail_with_a_message_naming_the_file() {
    let demo = shared_demo();
    let dir = scratch("bad-scenes");
    std::fs::copy(demo, dir.join("demo.treelod")).expect("copies");
    let cases: [(&str, &str, i32, &str); 6] = [
        ("syntax.json", "{\"version\": 1,\n \"models\": [\"demo.treelod\",]\n}", 3, "line 2, column"),
        (
            "index.json",
            r#"{"version": 1, "models": ["demo.treelod"], "instances": [{"model": 1, "translation": [0,0,0]}]}"#,
            3,
            "instance 0: model 1 is out of range",
        ),
        ("missing.json", r#"{"version": 1, "models": ["nowhere.treelod"], "instances": []}"#, 5, "model 0: "),
        (
            "scale.json",
            r#"{"version": 1, "models": ["demo.treelod"], "instances": [{"model": 0, "translation": [0,0,0], "scale": 0}]}"#,
            3,
            "`scale` must be positive",
        ),
        (
            "unknown.json",
            r#"{"version": 1, "models": ["demo.treelod"], "instances": [], "camera": 1}"#,
            3,
            "unknown field `camera`",
        ),
        ("future.json", r#"{"version": 2, "models": ["demo.treelod"], "instances": []}"#, 4, "unknown scene version 2"),
    ];
    for (name, text, code, reason) in cases {
        let scene = dir.join(name);
        std::fs::write(&scene, text).expect("writes");
        let png = dir.join(format!("{name}.png"));
        let out = run_os([
            "render".as_ref(),
            scene.as_os_str(),
            "-o".as_ref(),
            png.as_os_str(),
            "--size".as_ref(),
            "32x32".as_ref(),
        ]);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(code), "{name}: {err}");
        assert!(err.contains(&format!("error: {}: ", scene.display())), "{name}: the message names the file: {err}");
        assert!(err.contains(reason), "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(stdout(&out).is_empty());
        assert!(!png.exists(), "{name}: nothing written");
    }
    // A missing scene file or container is an I/O error naming it.
    for missing in [dir.join("absent.json"), dir.join("absent.treelod")] {
        let out = run_os(["render".as_ref(), missing.as_os_str(), "-o".as_ref(), dir.join("x.png").as_os_str()]);
        assert_fails(&out, 5, &missing);
    }
    // A scene whose model is not a container names the model.
    let garbage = dir.join("garbage.treelod");
    std::fs::write(&garbage, b"not a container at all").expect("writes");
    let scene = dir.join("garbage.json");
    std::fs::write(&scene, r#"{"version": 1, "models": ["garbage.treelod"], "instances": []}"#).expect("writes");
    let out = run_os([
        "render".as_ref(),
        scene.as_os_str(),
        "-o".as_ref(),
        dir.join("x.png").as_os_str(),
        "--size".as_ref(),
        "32x32".as_ref(),
    ]);
    // Mesa's lavapipe may print its own lines once the device is open; ours is the last line.
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(3), "{err}");
    let last = err.lines().last().unwrap_or_default();
    assert!(last.starts_with(&format!("error: {}: not a .treelod file", garbage.display())), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn render_lights_the_tree_as_its_light_options_say_and_refuses_bad_ones() {
    let demo = shared_demo();
    let dir = scratch("render-light");
    let png = dir.join("red.png");
    // A red sun, no ambient light: the tree has red and nothing else.
    render_ok(demo, &png, &["--size", "96x72", "--sun-colour", "ff0000", "--ambient", "0", "--sun", "0,1,1"]);
    let (_, _, pixels) = read_png(&png);
    let drawn: Vec<&[u8; 4]> = pixels.iter().filter(|p| !close_to(**p, [255, 255, 255])).collect();
    assert!(drawn.len() > 100, "the tree is drawn: {}", drawn.len());
    assert!(drawn.iter().all(|p| p[1] == 0 && p[2] == 0), "red light only");
    // Gilet's self-shadowing darkens the tree.
    let plain = dir.join("plain.png");
    let shadowed = dir.join("shadowed.png");
    render_ok(demo, &plain, &["--size", "96x72"]);
    render_ok(demo, &shadowed, &["--size", "96x72", "--self-shadow", "0.2,0.6"]);
    let sum = |path: &Path| read_png(path).2.iter().map(|p| u64::from(p[0]) + u64::from(p[1])).sum::<u64>();
    assert!(sum(&shadowed) < sum(&plain), "darker with self-shadowing");
    let bad: [&[&str]; 5] = [
        &["--sun", "0,0,0"],
        &["--sun", "1,nan,0"],
        &["--sun-colour", "red"],
        &["--ambient", "1.5"],
        &["--self-shadow", "0.5"],
    ];
    for extra in bad {
        let mut args = vec!["render", demo.to_str().expect("UTF-8"), "-o", "x.png"];
        args.extend_from_slice(extra);
        let out = treelod(&args);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {}", stderr(&out));
        assert!(stderr(&out).contains("expected"), "{extra:?}: the message says what is expected: {}", stderr(&out));
    }
}

#[test]
fn render_writes_a_png_of_the_requested_size_showing_the_tree() {
    let demo = shared_demo();
    let dir = scratch("render");
    let png = dir.join("tree.png");
    let stdout = render_ok(demo, &png, &["--size", "256x192", "--background", "336699"]);
    assert!(stdout.starts_with(&format!("{}: 256x192, 1 of 1 instance(s) visible, ", png.display())), "{stdout}");
    // A default build holds no calibration tables: the line says why the policy chose the point tree.
    assert!(
        stdout.contains(", policy: 1 spt (1 of 1 container(s) without calibration tables, their trees drawn with spt)"),
        "{stdout}"
    );
    // A container with tables has the policy's choice alone.
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/v1_18/every-kind-zstd.treelod");
    let calibrated = render_ok(&golden, &dir.join("golden.png"), &["--size", "64x48"]);
    assert!(calibrated.contains(", policy: 1 ") && !calibrated.contains("calibration tables"), "{calibrated}");
    let (width, height, pixels) = read_png(&png);
    assert_eq!((width, height), (256, 192));
    assert!(pixels.iter().all(|p| p[3] == 255), "opaque");
    assert!(close_to(pixels[0], [0x33, 0x66, 0x99]), "the corner is background: {:?}", pixels[0]);
    let drawn = pixels.iter().filter(|p| !close_to(**p, [0x33, 0x66, 0x99])).count();
    assert!(drawn > 500, "the tree covers pixels: {drawn}");
    // The tree is framed: nothing drawn on the image border.
    let border = |i: usize| {
        let (x, y) = (i % width as usize, i / width as usize);
        x == 0 || y == 0 || x + 1 == width as usize || y + 1 == height as usize
    };
    assert!(pixels.iter().enumerate().all(|(i, p)| !border(i) || close_to(*p, [0x33, 0x66, 0x99])), "framed");

    // A technique the container lacks: a warning naming the file, the trees drawn with spt.
    let args: Vec<std::ffi::OsString> = vec![
        "render".into(),
        demo.into(),
        "-o".into(),
        dir.join("planes.png").into(),
        "--technique".into(),
        "impostors".into(),
    ];
    let out = run_os(&args);
    assert!(out.status.success(), "{}", stderr(&out));
    let warning = format!(
        "{}: holds no impostor planes (build with --impostors); its trees are drawn with spt instead of impostors",
        demo.display()
    );
    assert!(stderr(&out).contains(&warning), "{}", stderr(&out));
    let line = String::from_utf8_lossy(&out.stdout);
    assert!(line.contains(", 0 tree(s) drawn with impostors, 1 spt in their stead, submitting "), "{line}");

    // An explicit camera looking away from the tree sees only background.
    let away = dir.join("away.png");
    let stdout = render_ok(demo, &away, &["--size", "64x48", "--eye", "0,2,-10", "--target", "0,2,-20"]);
    assert!(stdout.contains("0 of 1 instance(s) visible, 0 triangles, 0 points"), "{stdout}");
    let (_, _, pixels) = read_png(&away);
    assert!(pixels.iter().all(|p| close_to(*p, [255, 255, 255])), "white background by default");
}

#[test]
fn render_compare_writes_lod_and_full_mesh_side_by_side() {
    let demo = shared_demo();
    let dir = scratch("render-compare");
    let png = dir.join("compare.png");
    let stdout = render_ok(demo, &png, &["--size", "128x96", "--compare"]);
    assert!(stdout.contains("; full mesh ") && stdout.contains("LoD/full "), "{stdout}");
    let (width, height, pixels) = read_png(&png);
    assert_eq!((width, height), (256, 96));
    let drawn = |from: usize, to: usize| {
        pixels.chunks_exact(256).flat_map(|row| &row[from..to]).filter(|p| !close_to(**p, [255, 255, 255])).count()
    };
    assert!(drawn(0, 128) > 100 && drawn(128, 256) > 100, "both halves show the tree");
}

#[test]
fn render_debug_kinds_colours_triangles_red_and_points_blue() {
    let demo = shared_demo();
    let dir = scratch("render-debug");
    let png = dir.join("kinds.png");
    // Thresholds low enough that both triangles and points are drawn at this size.
    let stdout = render_ok(demo, &png, &["--size", "128x96", "--debug", "kinds", "--s-min", "0.5", "--s-max", "1"]);
    assert!(!stdout.contains(" 0 triangles") && !stdout.contains(" 0 points"), "{stdout}");
    let (width, height, pixels) = read_png(&png);
    assert_eq!((width, height), (128, 96));
    // Triangles are drawn (0.9, 0.3, 0.2) and points (0.2, 0.5, 0.95), linear: in sRGB about
    // (243, 149, 124) and (124, 188, 250).
    let rgb = |p: &[u8; 4]| (i32::from(p[0]), i32::from(p[1]), i32::from(p[2]));
    let red = pixels.iter().map(rgb).filter(|&(r, g, b)| r > 200 && r > g + 60 && r > b + 60).count();
    let blue = pixels.iter().map(rgb).filter(|&(r, g, b)| b > 200 && b > r + 60 && b > g + 30).count();
    assert!(red > 0 && blue > 0, "red triangles {red}, blue points {blue}");
    let cells = dir.join("cells.png");
    render_ok(demo, &cells, &["--size", "64x48", "--debug", "cells"]);
    assert_eq!(read_png(&cells).0, 64);
}

#[test]
fn render_debug_levels_colours_points_by_the_octave_of_their_interval() {
    let demo = shared_demo();
    let dir = scratch("render-levels");
    let png = dir.join("levels.png");
    let stdout = render_ok(demo, &png, &["--size", "128x96", "--debug", "levels", "--s-min", "0.5", "--s-max", "1"]);
    assert!(!stdout.contains(" 0 points"), "{stdout}");
    let (_, _, pixels) = read_png(&png);
    // The palette of shaders/tree/common.wgsl (`LEVEL_PALETTE`) in sRGB, and triangles' light grey.
    let palette: [[u8; 3]; 6] =
        [[243, 137, 124], [250, 225, 109], [149, 231, 149], [124, 225, 237], [149, 160, 250], [231, 160, 237]];
    let near = |p: &[u8; 4], c: [u8; 3]| (0..3).all(|i| p[i].abs_diff(c[i]) <= 2);
    let levels: Vec<usize> = palette.iter().map(|&c| pixels.iter().filter(|p| near(p, c)).count()).collect();
    assert!(levels.iter().filter(|&&n| n > 5).count() >= 2, "points of several octaves: {levels:?}");
    let grey = pixels.iter().filter(|p| near(p, [243, 243, 243])).count();
    assert!(grey > 0, "triangles are light grey");
}

/// The number after `prefix` in `text` (e.g. `shadow pass: ` → the cascades).
fn count_after(text: &str, prefix: &str) -> Option<u64> {
    let rest = &text[text.find(prefix)? + prefix.len()..];
    rest.split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
}

#[test]
fn render_shadows_draws_a_shadowed_ground_and_reports_the_shadow_pass() {
    let demo = shared_demo();
    let dir = scratch("render-shadows");
    let plain = dir.join("plain.png");
    let shadowed = dir.join("shadows.png");
    render_ok(demo, &plain, &["--size", "128x96"]);
    let stdout = render_ok(demo, &shadowed, &["--size", "128x96", "--shadows"]);
    let line = stdout.lines().last().unwrap_or_default();
    assert!(line.starts_with(&format!("{}: 128x96, 1 of 1 instance(s) visible, ", shadowed.display())), "{stdout}");
    let shadow = &line[line.find("; shadow pass: ").unwrap_or_else(|| panic!("a shadow pass: {line}"))..];
    assert_eq!(count_after(shadow, "shadow pass: "), Some(3), "the default cascades: {line}");
    let primitives: u64 = ["cascade(s), ", "triangles, ", "points, ", "planes, "]
        .iter()
        .map(|before| count_after(shadow, before).unwrap_or_else(|| panic!("{before:?}: {line}")))
        .sum();
    assert!(primitives > 0, "the shadow pass draws the tree: {line}");
    assert!(line.contains("× the main pass's primitives)"), "{line}");

    // The ground under the tree covers much of the image, and somewhere it is in the tree's shadow.
    let (width, height, pixels) = read_png(&shadowed);
    assert_eq!((width, height), (128, 96));
    let (_, _, plain_pixels) = read_png(&plain);
    assert_ne!(pixels, plain_pixels, "shadows and a ground change the image");
    let drawn = |pixels: &[[u8; 4]]| pixels.iter().filter(|p| !close_to(**p, [255, 255, 255])).count();
    assert!(drawn(&pixels) > drawn(&plain_pixels) + 1000, "the ground is drawn");
    // The sunlit ground is flat and of one colour, the most common one; shadowed ground is the
    // same colour darker (the same fraction of each linear channel).
    let mut counts = std::collections::HashMap::new();
    for p in pixels.iter().filter(|p| !close_to(**p, [255, 255, 255])) {
        *counts.entry(*p).or_insert(0usize) += 1;
    }
    let lit = counts.iter().max_by_key(|&(_, n)| *n).map(|(p, _)| *p).expect("pixels drawn");
    let linear = |c: u8| {
        let c = f64::from(c) / 255.0;
        if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
    };
    let shade = |p: &[u8; 4]| -> Option<f64> {
        let k: Vec<f64> = (0..3).map(|i| linear(p[i]) / linear(lit[i]).max(1e-6)).collect();
        let (lo, hi) = (k.iter().copied().fold(f64::MAX, f64::min), k.iter().copied().fold(0.0, f64::max));
        (hi - lo < 0.08).then_some((lo + hi) / 2.0)
    };
    let in_shadow = pixels.iter().filter(|p| shade(p).is_some_and(|k| k < 0.75)).count();
    assert!(in_shadow > 30, "the tree shadows the ground: {in_shadow} pixels (lit ground {lit:?})");

    // A value option implies --shadows; the cascades are as asked.
    let one = dir.join("one.png");
    let stdout = render_ok(demo, &one, &["--size", "64x48", "--shadow-cascades", "1", "--shadow-resolution", "256"]);
    assert_eq!(count_after(&stdout, "; shadow pass: "), Some(1), "{stdout}");
    // Without shadows the line has no shadow pass.
    assert!(!render_ok(demo, &plain, &["--size", "64x48"]).contains("shadow pass"));
}

/// The RMSE and FLIP of render's `--shadow-error`.
fn shadow_error(line: &str) -> (f64, f64) {
    let rest = &line[line.find("; shadow error against full-mesh casters").unwrap_or_else(|| panic!("{line}"))..];
    let number = |key: &str| -> f64 {
        let at = rest.find(key).unwrap_or_else(|| panic!("{key}: {rest}")) + key.len();
        rest[at..]
            .split(|c: char| c != '.' && !c.is_ascii_digit())
            .next()
            .and_then(|n| n.parse().ok())
            .expect("a number")
    };
    (number("RMSE "), number("FLIP "))
}

#[test]
fn render_shadow_error_measures_the_casters_against_the_full_mesh() {
    let demo = shared_demo();
    let dir = scratch("render-shadow-error");
    let png = dir.join("error.png");
    // The point tree casts its shadow: a small error against the full mesh's.
    let stdout = render_ok(demo, &png, &["--size", "160x120", "--shadows", "--shadow-error"]);
    let (rmse, flip) = shadow_error(&stdout);
    assert!(rmse > 0.0 && rmse < 0.05 && flip > 0.0 && flip < 0.05, "{stdout}");
    // Trees drawn and cast with the full mesh: the very same image.
    let stdout = render_ok(demo, &png, &["--size", "160x120", "--shadows", "--shadow-error", "--technique", "full"]);
    assert_eq!(shadow_error(&stdout), (0.0, 0.0), "{stdout}");
    // Without shadows there is nothing to measure.
    let stdout = render_ok(demo, &png, &["--size", "64x48", "--shadow-error"]);
    assert!(stdout.contains("no shadow error (no shadows)"), "{stdout}");
}

#[test]
fn render_refuses_bad_shadow_options_naming_them() {
    let demo = shared_demo();
    let bad: [&[&str]; 6] = [
        &["--shadow-cascades", "0"],
        &["--shadow-cascades", "5"],
        &["--shadow-resolution", "0"],
        &["--shadow-resolution", "8193"],
        &["--shadow-distance", "-1"],
        &["--shadow-distance", "nan"],
    ];
    for extra in bad {
        let mut args = vec!["render", demo.to_str().expect("UTF-8"), "-o", "x.png", "--shadows"];
        args.extend_from_slice(extra);
        let out = treelod(&args);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(&format!("invalid value '{}' for '{}", extra[1], extra[0])), "{extra:?}: {err}");
        assert!(!err.contains("panicked"), "{extra:?}: {err}");
    }
}

// ---------------------------------------------------------------------------------------------
// `view`: a window, under Xvfb (xvfb-run and xauth are required: .ci/run installs them).

/// `treelod view INPUT --screenshot PNG --frames 3 EXTRA...` under Xvfb, with `--size 160x120`
/// unless `extra` gives a size.
fn view_screenshot(input: &Path, png: &Path, extra: &[&str]) -> Output {
    let size: &[&str] = if extra.contains(&"--size") { &[] } else { &["--size", "160x120"] };
    Command::new("xvfb-run")
        .args(["-a", env!("CARGO_BIN_EXE_treelod"), "view"])
        .arg(input)
        .arg("--screenshot")
        .arg(png)
        .args(["--frames", "3"])
        .args(size)
        .args(extra)
        .output()
        .expect("xvfb-run runs (install xvfb and xauth, as .ci/run does)")
}

/// A pixel of the viewer's sky: bluer than it is green or red.
fn sky_like(p: [u8; 4]) -> bool {
    p[2] > p[0].saturating_add(20) && p[2] >= p[1]
}

/// A pixel of a leaf: green above blue and red, and darker than the lit ground.
fn leaf_like(p: [u8; 4]) -> bool {
    p[1] > p[2].saturating_add(20) && p[1] > p[0] && p[0] < 150
}

/// A pixel of the panel (egui's dark theme): dark and grey.
fn panel_like(p: [u8; 4]) -> bool {
    p[0].max(p[1]).max(p[2]) < 80 && p[0].abs_diff(p[2]) < 12 && p[0].abs_diff(p[1]) < 12
}

/// Pixels of `pixels` (`width` wide) in columns `columns` that satisfy `test`.
fn count_in(pixels: &[[u8; 4]], width: u32, columns: std::ops::Range<u32>, test: fn([u8; 4]) -> bool) -> usize {
    pixels.iter().enumerate().filter(|(i, p)| columns.contains(&((*i as u32) % width)) && test(**p)).count()
}

#[test]
fn view_screenshot_under_xvfb_is_window_sized_and_shows_the_tree_under_a_sky() {
    let demo = shared_demo();
    let dir = scratch("view");
    let png = dir.join("view.png");
    let out = view_screenshot(demo, &png, &[]);
    let err = stderr(&out);
    assert!(out.status.success(), "view failed (needs Xvfb and a Vulkan adapter, e.g. mesa-vulkan-drivers): {err}");
    assert!(!err.contains("panicked"), "{err}");
    let stdout = stdout(&out);
    assert!(stdout.starts_with(&format!("{}: 160x120, 1 of 1 instance(s) visible, ", png.display())), "{stdout}");
    // 160 pixels is less than twice the panel's width: it starts hidden.
    assert!(!stdout.contains("with the panel"), "{stdout}");
    let (width, height, pixels) = read_png(&png);
    assert_eq!((width, height), (160, 120));
    assert!(pixels.iter().all(|p| p[3] == 255), "opaque");
    assert!(sky_like(pixels[0]), "the top corner is sky: {:?}", pixels[0]);
    let leaves = count_in(&pixels, width, 0..width, leaf_like);
    assert!(leaves > 100, "the tree covers pixels: {leaves}");

    // With MSAA (a multisampled target resolved into the window).
    let out = view_screenshot(demo, &png, &["--msaa", "4"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let (_, _, pixels) = read_png(&png);
    let leaves = count_in(&pixels, width, 0..width, leaf_like);
    assert!(leaves > 100, "the tree covers pixels with MSAA: {leaves}");
}

#[test]
fn view_screenshot_with_shadows_shades_the_ground_and_reports_the_shadow_pass() {
    let demo = shared_demo();
    let dir = scratch("view-shadows");
    let (lit, shadowed) = (dir.join("lit.png"), dir.join("shadowed.png"));
    let out = view_screenshot(demo, &lit, &[]);
    assert!(out.status.success(), "{}", stderr(&out));
    let out = view_screenshot(demo, &shadowed, &["--shadows", "--shadow-cascades", "2"]);
    let err = stderr(&out);
    assert!(out.status.success(), "view failed (needs Xvfb and a Vulkan adapter, e.g. mesa-vulkan-drivers): {err}");
    assert!(!err.contains("panicked"), "{err}");
    let stdout = stdout(&out);
    assert_eq!(count_after(&stdout, "; shadow pass: "), Some(2), "{stdout}");
    // The ground is drawn either way; with shadows some of it is darker.
    let (_, _, lit) = read_png(&lit);
    let (_, _, shadowed) = read_png(&shadowed);
    let brightness = |p: &[u8; 4]| u32::from(p[0]) + u32::from(p[1]) + u32::from(p[2]);
    let ground = lit.iter().filter(|p| !sky_like(**p) && brightness(p) > 450).count();
    assert!(ground > lit.len() / 4, "the ground covers much of the window: {ground} of {}", lit.len());
    let darker = lit.iter().zip(&shadowed).filter(|(a, b)| brightness(b) + 60 < brightness(a)).count();
    assert!(darker > 100, "the trees shadow the ground: {darker} pixels darker");
}

#[test]
fn view_shows_the_panel_beside_the_tree_and_hides_it_on_request() {
    let demo = shared_demo();
    let dir = scratch("view-panel");
    let (with, without) = (dir.join("panel.png"), dir.join("no-panel.png"));
    let out = view_screenshot(demo, &with, &["--size", "640x400"]);
    let err = stderr(&out);
    assert!(out.status.success(), "view failed (needs Xvfb and a Vulkan adapter, e.g. mesa-vulkan-drivers): {err}");
    assert!(stdout(&out).contains(", with the panel"), "{}", stdout(&out));
    let (width, height, pixels) = read_png(&with);
    assert_eq!((width, height), (640, 400));
    // The panel fills the right 300 pixels (its text and widgets aside); the tree is left of it.
    let panel_area = (300 * height) as usize;
    let panel = count_in(&pixels, width, 340..640, panel_like);
    assert!(panel > panel_area / 2, "the panel is drawn: {panel} of {panel_area} pixels");
    assert!(count_in(&pixels, width, 0..330, panel_like) < 200, "and only on the right");
    let leaves = count_in(&pixels, width, 0..330, leaf_like);
    assert!(leaves > 1000, "the tree is drawn beside it: {leaves}");

    let out = view_screenshot(demo, &without, &["--size", "640x400", "--no-panel"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(!stdout(&out).contains("with the panel"));
    let (_, _, pixels) = read_png(&without);
    let panel = count_in(&pixels, width, 340..640, panel_like);
    assert!(panel < panel_area / 20, "no panel: {panel} dark grey pixels");
}

#[test]
fn view_error_view_darkens_what_matches_the_full_mesh_and_colours_what_does_not() {
    // No error: the reference's luminance, dimmed, grey; an error: the ramp's colours.
    fn coloured(p: [u8; 4]) -> bool {
        p[0].max(p[1]).max(p[2]) - p[0].min(p[1]).min(p[2]) > 30
    }
    let demo = shared_demo();
    let dir = scratch("view-error");
    let png = dir.join("error.png");
    let out = view_screenshot(demo, &png, &["--debug", "error"]);
    let err = stderr(&out);
    assert!(out.status.success(), "view failed (needs Xvfb and a Vulkan adapter, e.g. mesa-vulkan-drivers): {err}");
    let (width, _, pixels) = read_png(&png);
    // The sky is the same in both frames: dark grey.
    assert!(!coloured(pixels[0]) && pixels[0][0] < 80, "no error in the sky: {:?}", pixels[0]);
    // The point tree differs from the full mesh somewhere in the canopy.
    let differ = count_in(&pixels, width, 0..width, coloured);
    assert!(differ > 10, "differences are coloured: {differ} pixels");
    // The full mesh against itself shows no error at all.
    let out = view_screenshot(demo, &png, &["--debug", "error", "--technique", "full"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let (_, _, pixels) = read_png(&png);
    assert_eq!(count_in(&pixels, width, 0..width, coloured), 0, "the full mesh matches itself");
}

#[test]
fn view_builds_a_gltf_input_first_and_reports_a_bad_one() {
    let dir = scratch("view-gltf");
    let png = dir.join("built.png");
    let out = view_screenshot(&small_tree(), &png, &["--distance", "2"]);
    let err = stderr(&out);
    assert!(out.status.success(), "view failed (needs Xvfb and a Vulkan adapter, e.g. mesa-vulkan-drivers): {err}");
    assert!(stdout(&out).contains(": 160x120, 1 of 1 instance(s) visible, "), "{}", stdout(&out));
    let (width, _, pixels) = read_png(&png);
    let leaves = count_in(&pixels, width, 0..width, leaf_like);
    assert!(leaves > 100, "the built tree is drawn: {leaves}");

    let broken = dir.join("broken.glb");
    std::fs::write(&broken, b"glTF, but only the magic").expect("writes");
    let shot = dir.join("never.png");
    let out = view_screenshot(&broken, &shot, &[]);
    assert_eq!(out.status.code(), Some(3), "{}", stderr(&out));
    assert!(stderr(&out).contains(&format!("error: {}", broken.display())), "{}", stderr(&out));
    assert!(!stderr(&out).contains("panicked"));
    assert!(!shot.exists(), "no screenshot of a build that failed");
}

#[test]
fn view_fails_with_a_message_without_a_display_or_with_a_bad_file() {
    let dir = scratch("view-errors");
    let no_display = |args: &[&OsStr]| {
        Command::new(env!("CARGO_BIN_EXE_treelod"))
            .arg("view")
            .args(args)
            .env_remove("DISPLAY")
            .env_remove("WAYLAND_DISPLAY")
            .output()
            .expect("the binary runs")
    };
    let demo = shared_demo();
    let out = no_display(&[demo.as_os_str()]);
    assert_fails(&out, 4, demo);
    assert!(stderr(&out).contains("cannot open a window") && stderr(&out).contains("DISPLAY"), "{}", stderr(&out));

    // A bad file is reported as such before any window is needed.
    let garbage = dir.join("garbage.treelod");
    std::fs::write(&garbage, b"not a container").expect("writes");
    assert_fails(&no_display(&[garbage.as_os_str()]), 3, &garbage);
    let missing = dir.join("missing.treelod");
    assert_fails(&no_display(&[missing.as_os_str()]), 5, &missing);
    // --frames only goes with --screenshot.
    assert_eq!(no_display(&[demo.as_os_str(), "--frames".as_ref(), "3".as_ref()]).status.code(), Some(2));
}
