//! Helpers shared by the command-line tests (each test file uses some of them).
#![allow(dead_code, reason = "each test crate compiles this module and uses a part of it")]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh scratch directory for one test, under `area` (one per test file).
pub fn scratch(area: &str, test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(area).join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// Runs the binary with `args` (Mesa's device-select layer silenced).
pub fn run<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    Command::new(env!("CARGO_BIN_EXE_treelod")).args(args).env("NODEVICE_SELECT", "1").output().expect("runs")
}

/// Runs the binary with `args` then `paths`.
pub fn run_on(args: &[&str], paths: &[&Path]) -> Output {
    let mut all: Vec<std::ffi::OsString> = args.iter().map(Into::into).collect();
    all.extend(paths.iter().map(|p| p.as_os_str().to_owned()));
    run(&all)
}

/// A tree of the shared test models beside the repository (`../shared/assets/trees`, see its
/// `SOURCES.md`).
pub fn model(name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees").join(name);
    assert!(path.exists(), "the shared models sit in ../shared beside the repository: {}", path.display());
    path
}

/// Program output as text.
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8(bytes.to_vec()).expect("UTF-8")
}

/// A demo container (500 leaf quads) built once per test process by the binary, under `area`, and
/// shared by that process's tests (per process: nextest runs each test in its own, and a shared
/// directory would be removed by one test while another reads it).
pub fn demo(area: &str) -> &'static Path {
    static DEMO: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DEMO.get_or_init(|| {
        let path = scratch(area, &format!("shared-demo-{}", std::process::id())).join("demo.treelod");
        let out = run(["demo".as_ref(), "--leaf-count".as_ref(), "500".as_ref(), "-o".as_ref(), path.as_os_str()]);
        assert!(out.status.success(), "demo: {}", text(&out.stderr));
        path
    })
}

/// Decodes an 8-bit RGBA PNG: `(width, height, pixels)`.
pub fn read_png(path: &Path) -> (u32, u32, Vec<[u8; 4]>) {
    let file = std::io::BufReader::new(std::fs::File::open(path).expect("the PNG exists"));
    let mut reader = png::Decoder::new(file).read_info().expect("a PNG");
    let mut buffer = vec![0; reader.output_buffer_size().expect("fits in memory")];
    let info = reader.next_frame(&mut buffer).expect("decodes");
    assert_eq!((info.color_type, info.bit_depth), (png::ColorType::Rgba, png::BitDepth::Eight));
    let pixels = buffer[..info.buffer_size()].chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect();
    (info.width, info.height, pixels)
}

/// Asserts that `out` (of the command described by `what`) succeeded without a panic; returns its
/// stdout.
pub fn succeeded(out: &Output, what: &str) -> String {
    let err = text(&out.stderr);
    assert!(out.status.success(), "{what} failed (a Vulkan adapter is required: install mesa-vulkan-drivers): {err}");
    assert!(!err.contains("panicked"), "{err}");
    text(&out.stdout)
}

/// A CSV file as a header and rows of fields (every row as long as the header).
pub fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let csv = std::fs::read_to_string(path).expect("the CSV was written");
    let mut lines = csv.lines();
    let header: Vec<String> = lines.next().expect("a header").split(',').map(str::to_owned).collect();
    let rows: Vec<Vec<String>> = lines.map(|l| l.split(',').map(str::to_owned).collect()).collect();
    for row in &rows {
        assert_eq!(row.len(), header.len(), "{row:?}");
    }
    (header, rows)
}

/// The field `column` of `row`.
pub fn field<'a>(header: &[String], row: &'a [String], column: &str) -> &'a str {
    let i = header.iter().position(|h| h == column).unwrap_or_else(|| panic!("no column {column}"));
    &row[i]
}

/// The field `column` of `row` as a number.
pub fn number(header: &[String], row: &[String], column: &str) -> f64 {
    let value = field(header, row, column);
    value.parse().unwrap_or_else(|_| panic!("{column} = {value:?} is not a number"))
}

/// Runs `treelod build` on the small Quaternius tree with `before`, then each case's arguments,
/// writing to `dir/never.treelod`, and checks each is a usage error (exit 2) whose message names
/// the case's option and that nothing is written.
pub fn assert_build_usage_errors(dir: &Path, before: &[&str], cases: &[(&[&str], &str)]) {
    let out_path = dir.join("never.treelod");
    let tree = model("quaternius-common-tree-1-3k.glb");
    for &(bad, option) in cases {
        let mut args = vec!["build"];
        args.extend(before);
        args.extend(bad);
        args.push("-o");
        let out = run_on(&args, &[&out_path, &tree]);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{bad:?}: {stderr}");
        assert!(stderr.contains(option), "{bad:?}: {stderr}");
        assert!(!out_path.exists(), "{bad:?}: nothing written");
    }
}
