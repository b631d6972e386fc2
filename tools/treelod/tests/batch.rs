//! End-to-end tests of `treelod batch`: layout, up-to-date skipping, byte-identical outputs,
//! shards, and resuming after a SIGKILL.
//!
//! nextest runs every test in its own process, so every test builds its own scratch library under
//! a directory named after the test and the process.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, SystemTime};

/// The shared test models (outside the repository, see `../shared/assets/trees/SOURCES.md`).
fn model(name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees").join(name);
    assert!(path.exists(), "the shared models sit in ../shared beside the repository: {}", path.display());
    path
}

const SMALL: &str = "quaternius-common-tree-1-3k.glb";
const PINE: &str = "ez-tree-pine-large-19k.glb";

/// A fresh scratch directory for one test in this process.
fn scratch(test: &str) -> PathBuf {
    let dir =
        Path::new(env!("CARGO_TARGET_TMPDIR")).join("treelod-batch").join(format!("{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// Copies `files` (relative path in the library, shared model name) into `dir/lib`, writes a garbage
/// `bad/garbage.glb` if `garbage`, and a `notes.txt` that is not a glTF file. Returns the library.
fn library(dir: &Path, files: &[(&str, &str)], garbage: bool) -> PathBuf {
    let lib = dir.join("lib");
    for (relative, name) in files {
        let path = lib.join(relative);
        std::fs::create_dir_all(path.parent().expect("has a parent")).expect("creates");
        std::fs::copy(model(name), &path).expect("copies the model");
        // The shared models are read-only; the tests rewrite some copies.
        std::fs::set_permissions(&path, std::os::unix::fs::PermissionsExt::from_mode(0o644)).expect("makes writable");
    }
    if garbage {
        std::fs::create_dir_all(lib.join("bad")).expect("creates");
        std::fs::write(lib.join("bad/garbage.glb"), b"glTF but not really").expect("writes");
    }
    std::fs::write(lib.join("notes.txt"), b"not a tree").expect("writes");
    lib
}

/// Runs the binary with `args` in `dir`.
fn treelod_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_treelod")).args(args).current_dir(dir).output().expect("the binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8(bytes.to_vec()).expect("UTF-8")
}

/// Runs a batch in `dir`; asserts it did not panic; returns stdout, stderr and the exit code.
fn batch(dir: &Path, args: &[&str]) -> (String, String, Option<i32>) {
    let mut all = vec!["batch"];
    all.extend_from_slice(args);
    let out = treelod_in(dir, &all);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(!stderr.contains("panicked"), "{stderr}");
    (stdout, stderr, out.status.code())
}

/// Every file under `root` (relative path → bytes), hidden ones included.
fn files(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("lists") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let relative = path.strip_prefix(root).expect("under root").to_string_lossy().replace('\\', "/");
                out.insert(relative, std::fs::read(&path).expect("reads"));
            }
        }
    }
    out
}

fn mtimes(root: &Path, names: &[&str]) -> Vec<SystemTime> {
    names.iter().map(|n| std::fs::metadata(root.join(n)).expect("exists").modified().expect("mtime")).collect()
}

fn verify(path: &Path) {
    let container = treelod_format::Container::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    treelod_format::verify(&container).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// The number of stdout lines starting with `status`.
fn count(stdout: &str, status: &str) -> usize {
    stdout.lines().filter(|l| l.starts_with(status)).count()
}

#[test]
fn batch_mirrors_the_layout_verifies_outputs_and_reports_bad_input() {
    let dir = scratch("layout");
    library(&dir, &[("a/b/oak.glb", SMALL), ("a/Upper.GLB", SMALL), ("c.glb", SMALL)], true);
    let (stdout, stderr, code) = batch(&dir, &["lib", "-o", "out", "--level", "1", "--jobs", "2"]);
    assert_eq!(code, Some(3), "a bad input makes the batch fail with its class (invalid): {stdout}{stderr}");
    assert!(stderr.starts_with("error: lib/bad/garbage.glb: "), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    let outputs: Vec<String> = files(&dir.join("out")).into_keys().collect();
    assert_eq!(outputs, ["a/Upper.treelod", "a/b/oak.treelod", "c.treelod"], "the layout is mirrored");
    for output in &outputs {
        verify(&dir.join("out").join(output));
    }
    assert_eq!(count(&stdout, "built       "), 3, "{stdout}");
    assert!(
        stdout.contains("failed      out/bad/garbage.treelod from lib/bad/garbage.glb in "),
        "one line per file, failures too: {stdout}"
    );
    assert!(stdout.contains("built       out/a/b/oak.treelod from lib/a/b/oak.glb in "), "{stdout}");
    assert!(stdout.contains(" (158708 -> "), "sizes are shown: {stdout}");
    let summary = stdout.lines().last().expect("a summary line");
    assert!(
        summary.starts_with("4 file(s) in ") && summary.contains(": 3 built, 0 up to date, 1 failed ("),
        "{summary}"
    );
    assert!(summary.ends_with(" files/min)"), "{summary}");
    // The metadata records the path under the source directory, with `/` separators.
    let container = treelod_format::Container::open(dir.join("out/a/b/oak.treelod")).expect("opens");
    assert_eq!(container.metadata().sources[0].path, "a/b/oak.glb");
    assert_eq!(container.metadata().setting("compression"), Some("zstd:1"));

    // Globs (quoted) and files named directly; a glob matching nothing is an error (exit 5).
    let (stdout, stderr, code) =
        batch(&dir, &["lib/a/**/*.glb", "lib/c.glb", "lib/*.none", "-o", "globbed", "--no-verify", "--level", "1"]);
    assert_eq!(code, Some(5), "{stdout}{stderr}");
    assert!(stderr.contains("error: lib/*.none: matches no .glb or .gltf file"), "{stderr}");
    let outputs: Vec<String> = files(&dir.join("globbed")).into_keys().collect();
    assert_eq!(outputs, ["b/oak.treelod", "c.treelod"], "globs are case-sensitive and mirror below their base");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_second_run_rewrites_nothing_and_changes_rebuild_only_what_changed() {
    let dir = scratch("up-to-date");
    let lib = library(&dir, &[("a/one.glb", SMALL), ("a/two.glb", SMALL), ("b/three.glb", SMALL)], false);
    let names = ["a/one.treelod", "a/two.treelod", "b/three.treelod"];
    let out = dir.join("out");
    let run = |extra: &[&str]| {
        let mut args = vec!["lib", "-o", "out", "--no-verify"];
        args.extend_from_slice(if extra.is_empty() { &["--level", "1"] } else { extra });
        let (stdout, stderr, code) = batch(&dir, &args);
        assert_eq!(code, Some(0), "{stdout}{stderr}");
        stdout
    };
    let first = run(&[]);
    assert_eq!(count(&first, "built"), 3, "{first}");
    let before = mtimes(&out, &names);
    let bytes = files(&out);

    std::thread::sleep(Duration::from_millis(20));
    let second = run(&[]);
    assert_eq!(count(&second, "up to date  "), 3, "{second}");
    assert!(second.lines().last().expect("summary").contains(": 0 built, 3 up to date, 0 failed"), "{second}");
    assert_eq!(mtimes(&out, &names), before, "nothing is rewritten");
    assert_eq!(files(&out), bytes);

    // The same bytes written again (a new mtime) are still up to date: the check is by content.
    std::fs::write(lib.join("a/one.glb"), std::fs::read(lib.join("a/one.glb")).expect("reads")).expect("writes");
    assert_eq!(count(&run(&[]), "up to date"), 3);

    // New content (one byte of the glTF JSON's generator) rebuilds that file only.
    let mut glb = std::fs::read(lib.join("a/two.glb")).expect("reads");
    let at = glb.windows(8).position(|w| w == b"FBX2glTF").expect("the generator string");
    glb[at + 7] = b'X';
    std::fs::write(lib.join("a/two.glb"), &glb).expect("writes");
    let third = run(&[]);
    assert!(third.contains("built       out/a/two.treelod"), "{third}");
    assert_eq!((count(&third, "built"), count(&third, "up to date")), (1, 2), "{third}");
    let after = mtimes(&out, &names);
    assert_eq!((after[0], after[2]), (before[0], before[2]), "the others are not rewritten");
    assert_ne!(after[1], before[1]);

    // A setting, the compression level included, makes every output stale once.
    let changes: [&[&str]; 3] =
        [&["--level", "2"], &["--level", "1", "--cluster-max", "4"], &["--compression", "none", "--level", "5"]];
    for extra in changes {
        let rebuilt = run(extra);
        assert_eq!(count(&rebuilt, "built"), 3, "{extra:?}: {rebuilt}");
        assert_eq!(count(&run(extra), "up to date"), 3, "{extra:?}");
    }
    // Without compression the level does not matter.
    assert_eq!(count(&run(&["--compression", "none", "--level", "7"]), "up to date"), 3);
    let container = treelod_format::Container::open(out.join("b/three.treelod")).expect("opens");
    assert_eq!(container.metadata().setting("compression"), Some("none"));
    // --force rebuilds what is up to date.
    let forced = run(&["--compression", "none", "--force"]);
    assert_eq!(count(&forced, "built"), 3, "{forced}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn outputs_equal_treelod_build_whatever_the_number_of_jobs() {
    let dir = scratch("identical");
    let lib = library(&dir, &[("x/pine.glb", PINE), ("x/y/small.glb", SMALL), ("small.glb", SMALL)], false);
    for (jobs, out) in [("1", "jobs1"), ("2", "jobs2")] {
        let (stdout, stderr, code) = batch(&dir, &["lib", "-o", out, "--jobs", jobs, "--no-verify", "--level", "3"]);
        assert_eq!(code, Some(0), "{stdout}{stderr}");
    }
    let one = files(&dir.join("jobs1"));
    assert_eq!(one.len(), 3);
    assert!(one == files(&dir.join("jobs2")), "--jobs 1 and --jobs 2 write the same bytes");
    // `treelod build` run in the source directory on the relative path writes the same bytes.
    for relative in ["x/pine.glb", "x/y/small.glb", "small.glb"] {
        let target = dir.join("built.treelod");
        let out = treelod_in(
            &lib,
            &["build", relative, "--no-verify", "--level", "3", "-o", target.to_str().expect("UTF-8 path")],
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        let batch_output = &one[&relative.replace(".glb", ".treelod")];
        assert!(&std::fs::read(&target).expect("reads") == batch_output, "{relative}: batch and build differ");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The inputs named on the stdout lines (every status).
fn inputs_of(stdout: &str) -> Vec<String> {
    stdout
        .lines()
        .filter(|l| ["built", "up to date", "failed"].iter().any(|s| l.starts_with(s)))
        .filter_map(|l| l.split(" from ").nth(1)?.split(" in ").next().map(str::to_owned))
        .collect()
}

#[test]
fn two_shards_hold_every_file_exactly_once() {
    let dir = scratch("shards");
    let lib = library(&dir, &[("a/one.glb", SMALL), ("b/two.glb", SMALL)], false);
    // Garbage inputs cost nothing to "convert" (they fail at once) and spread over the shards.
    for i in 0..24 {
        let path = lib.join(format!("g/{}/{i}.glb", i % 3));
        std::fs::create_dir_all(path.parent().expect("has a parent")).expect("creates");
        std::fs::write(path, b"junk").expect("writes");
    }
    let (all, _, _) = batch(&dir, &["lib", "-o", "all", "--no-verify", "--level", "1"]);
    let mut all = inputs_of(&all);
    all.sort();
    assert_eq!(all.len(), 26);
    // Both shards at once, into the same directory (as machines sharing an output volume).
    let spawn = |shard: &str| {
        Command::new(env!("CARGO_BIN_EXE_treelod"))
            .args(["batch", "lib", "-o", "out", "--no-verify", "--level", "1", "--shard", shard])
            .current_dir(&dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starts")
    };
    let (zero, one) = (spawn("0/2"), spawn("1/2"));
    // Lines come in the order files finish.
    let mut zero = inputs_of(&text(&zero.wait_with_output().expect("runs").stdout));
    let one = inputs_of(&text(&one.wait_with_output().expect("runs").stdout));
    zero.sort();
    assert!(!zero.is_empty() && !one.is_empty(), "{zero:?} {one:?}");
    assert!(zero.iter().all(|f| !one.contains(f)), "disjoint: {zero:?} {one:?}");
    let mut union: Vec<String> = zero.iter().chain(&one).cloned().collect();
    union.sort();
    assert_eq!(union, all, "together every file");
    assert!(files(&dir.join("out")) == files(&dir.join("all")), "the shards' outputs are the whole batch's");
    // The same split again: shards are stable.
    let (again, _, _) = batch(&dir, &["lib", "-o", "again", "--no-verify", "--level", "1", "--shard", "0/2"]);
    let mut again = inputs_of(&again);
    again.sort();
    assert_eq!(again, zero);
    let (_, stderr, code) = batch(&dir, &["lib", "-o", "x", "--shard", "2/2"]);
    assert_eq!(code, Some(2), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_batch_killed_at_any_moment_resumes_to_a_clean_runs_bytes() {
    let dir = scratch("kill");
    library(
        &dir,
        &[
            ("a/one.glb", SMALL),
            ("a/pine.glb", PINE),
            ("b/two.glb", SMALL),
            ("b/c/three.glb", SMALL),
            ("four.glb", SMALL),
        ],
        false,
    );
    let args = ["batch", "lib", "--jobs", "2", "--no-verify", "-o"];
    let started = std::time::Instant::now();
    let (stdout, stderr, code) = batch(&dir, &[&args[1..], &["clean"]].concat());
    let clean_run = started.elapsed();
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    let clean = files(&dir.join("clean"));
    assert_eq!(clean.len(), 5);

    // SIGKILL (`Child::kill` on Unix) at fixed fractions of a clean run's time (so the points fall
    // inside the run on fast and slow machines alike), each into its own directory, then resume.
    let (mut interrupted, mut temporaries) = (0, 0);
    for percent in [3, 10, 25, 45, 70, 90] {
        let killed = dir.join(format!("killed-{percent}"));
        let mut child = Command::new(env!("CARGO_BIN_EXE_treelod"))
            .args(args)
            .arg(&killed)
            .current_dir(&dir)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("starts");
        std::thread::sleep(clean_run * percent / 100);
        if child.try_wait().expect("polls").is_none() {
            interrupted += 1;
        }
        let _ = child.kill();
        let _ = child.wait();
        // Whatever is there under an output's name is a whole file: never a partial one.
        if killed.exists() {
            for (name, bytes) in files(&killed) {
                if name.ends_with(".tmp") {
                    temporaries += 1;
                } else {
                    assert!(bytes == clean[&name], "after a kill at {percent} %, {name} is not a whole output");
                }
            }
        }
        let resumed = treelod_in(&dir, &[&args[..], &[killed.to_str().expect("UTF-8 path")]].concat());
        assert!(resumed.status.success(), "{}", text(&resumed.stderr));
        let built = count(&text(&resumed.stdout), "built");
        let resumed_files = files(&killed);
        assert_eq!(
            resumed_files.keys().collect::<Vec<_>>(),
            clean.keys().collect::<Vec<_>>(),
            "after a kill at {percent} % and a re-run ({built} built): no temporary file is left"
        );
        for (name, bytes) in &resumed_files {
            assert!(*bytes == clean[name], "after a kill at {percent} %: {name} differs from the clean run's");
            verify(&killed.join(name));
        }
    }
    eprintln!("{interrupted} of 6 kills landed inside a run of {clean_run:?}, leaving {temporaries} temporary file(s)");
    assert!(interrupted > 0, "no kill landed inside a run");

    // A leftover temporary file of an output (as a kill while writing leaves) is removed by the next
    // run; a temporary file of another name is left alone.
    let killed = dir.join("killed-3");
    std::fs::write(killed.join("a/.one.treelod.Ab12Cd.tmp"), b"half a file").expect("writes");
    std::fs::write(killed.join("a/.unrelated.treelod.Xy34Zw.tmp"), b"someone else's").expect("writes");
    let again = treelod_in(&dir, &[&args[..], &[killed.to_str().expect("UTF-8 path")]].concat());
    let stdout = text(&again.stdout);
    assert!(stdout.starts_with("removed 1 temporary file(s) left beside outputs by an interrupted run\n"), "{stdout}");
    assert_eq!(count(&stdout, "up to date"), 5, "{stdout}");
    assert!(!killed.join("a/.one.treelod.Ab12Cd.tmp").exists());
    assert!(killed.join("a/.unrelated.treelod.Xy34Zw.tmp").exists(), "not ours: kept");
    let _ = std::fs::remove_dir_all(&dir);
}
