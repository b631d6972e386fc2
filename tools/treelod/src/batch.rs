//! `treelod batch`: converts a library of glTF trees, in parallel, into a mirrored tree of
//! containers, skipping those that are up to date.
//!
//! Each input file has a *base*: the source directory it was found in, the literal directory
//! prefix of the glob that matched it, or, for a file named directly, its own directory. Its path
//! under the base (`/` separators) is its *relative path*: the output is `OUT_DIR/<relative path
//! with .treelod>`, the metadata records the relative path as the source path (so a container is
//! the same whatever directory the library is mounted at, and equals what `treelod build` writes
//! when run in the base on the relative path), and `--shard` hashes it.
//!
//! An output is up to date when it opens and records this tool's version, one source with the
//! input's relative path and content hash, and the settings these options record. Outputs are
//! written atomically by the format crate (temporary file beside the output, verified, then
//! renamed: a file that fails verification never replaces the old output); a run removes the
//! temporary files that a killed run left beside the outputs it is responsible for. A file whose
//! conversion panics is that file's failure, and the run goes on.

use std::ffi::OsString;
use std::io;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

use glam::Vec3;
use sha2::Digest as _;
use treelod_format::{Container, ErrorClass};

use crate::build::{self, BuildOptions};
use crate::report::{self, Failed};
use crate::workers;

/// Arguments of `treelod batch`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Source directories (walked recursively for `.glb` and `.gltf` files, any case, in sorted
    /// order), glTF files, or quoted glob patterns of files (`*` and `?` within a name, `**` for
    /// any number of directories, e.g. `'lib/**/oak*.glb'`).
    #[arg(value_name = "SOURCE", required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output directory: receives the sources' folder layout, one `.treelod` per glTF file
    /// (directories are created as needed).
    #[arg(short, long, value_name = "OUT_DIR")]
    pub output: PathBuf,
    /// Files converted at once (default: the available cores). Each file's build is itself
    /// parallel over grid cells within the same pool of N threads.
    #[arg(short, long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub jobs: Option<u32>,
    /// Rebuild every output, also those that are up to date.
    #[arg(long)]
    pub force: bool,
    /// Convert only shard I of N (0-based, I < N): the files whose relative path hashes to I
    /// (first 8 bytes of its SHA-256, big-endian, modulo N). The N shards of a library are
    /// disjoint and together hold every file.
    #[arg(long, value_name = "I/N", value_parser = parse_shard)]
    pub shard: Option<Shard>,
    /// Build settings, as for `treelod build`.
    #[command(flatten)]
    pub options: BuildOptions,
}

/// `--shard I/N`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// This shard, `0..count`.
    pub index: u64,
    /// Number of shards, at least 1.
    pub count: u64,
}

impl Shard {
    /// Whether the file with this relative path belongs to this shard.
    fn holds(self, relative: &str) -> bool {
        shard_of(relative, self.count) == self.index
    }
}

/// The shard of `relative` among `count`: the first 8 bytes of the SHA-256 of the path's UTF-8
/// bytes (`/` separators), read big-endian, modulo `count`. Fixed forever: shards must agree
/// across machines, runs and versions of this tool.
fn shard_of(relative: &str, count: u64) -> u64 {
    let digest = sha2::Sha256::digest(relative.as_bytes());
    let mut first = [0u8; 8];
    first.copy_from_slice(&digest[..8]);
    u64::from_be_bytes(first) % count.max(1)
}

fn parse_shard(s: &str) -> Result<Shard, String> {
    let usage = || format!("expected I/N with 0 <= I < N (e.g. 0/4), got {s:?}");
    let (i, n) = s.split_once('/').ok_or_else(usage)?;
    let index: u64 = i.trim().parse().map_err(|_| usage())?;
    let count: u64 = n.trim().parse().map_err(|_| usage())?;
    if count == 0 || index >= count {
        return Err(usage());
    }
    Ok(Shard { index, count })
}

/// One file to convert.
#[derive(Clone, Debug)]
struct Job {
    /// The glTF file, as found (base joined with the relative path).
    input: PathBuf,
    /// Its path under its base, `/` separators.
    relative: String,
    /// Where its container goes.
    output: PathBuf,
    /// `Some(earlier input)` when another input, earlier in the list, writes the same output.
    duplicate_of: Option<PathBuf>,
}

/// What became of one job.
#[derive(Clone, Copy, Debug)]
enum Status {
    Built { file_bytes: u64, verified: bool },
    UpToDate { file_bytes: u64 },
    Failed(Failed),
}

/// A job's status with its time and source size.
#[derive(Clone, Copy, Debug)]
struct Outcome {
    status: Status,
    seconds: f64,
    /// Size of the input, if it could be read.
    source_bytes: Option<u64>,
}

/// Runs `treelod batch`.
pub fn run(args: &Args) -> Result<(), Failed> {
    let start = Instant::now();
    let mut plan_failures: Vec<Failed> = Vec::new();
    let mut jobs = plan(&args.inputs, &args.output, &mut plan_failures);
    if let Some(shard) = args.shard {
        jobs.retain(|job| shard.holds(&job.relative));
    }
    std::fs::create_dir_all(&args.output).map_err(|e| report::io_error(&args.output, &e))?;
    let json = args.options.json;
    let stdout_failed = AtomicBool::new(false);
    let print = |text: String| {
        if report::write_stdout(&text).is_err() {
            stdout_failed.store(true, Ordering::Relaxed);
        }
    };
    let removed = build::remove_leftovers(jobs.iter().map(|job| job.output.as_path()));
    if let Some(text) = build::leftovers_line(removed).filter(|_| !json) {
        print(text);
    }
    quiet_caught_panics();

    let outcomes: Vec<Mutex<Option<Outcome>>> = jobs.iter().map(|_| Mutex::new(None)).collect();
    for (job, slot) in jobs.iter().zip(&outcomes) {
        if let Some(earlier) = &job.duplicate_of {
            report::message_error(
                &job.input,
                &format!("{} also writes {}; rename one of them", earlier.display(), job.output.display()),
            );
            let outcome = Outcome {
                status: Status::Failed(Failed { class: ErrorClass::Invalid }),
                seconds: 0.0,
                source_bytes: None,
            };
            print(line(job, &outcome, json));
            *slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(outcome);
        }
    }
    let todo: Vec<usize> = (0..jobs.len()).filter(|&i| jobs[i].duplicate_of.is_none()).collect();
    if !todo.is_empty() {
        let bar = progress_bar(todo.len() as u64);
        report::set_progress_bar(Some(bar.clone()));
        // At most `--jobs` trees are in memory; the pool keeps all its threads for the builds'
        // cells when fewer files than threads are left.
        let done = workers::on_workers(args.jobs, todo.len(), |k| {
            let index = todo[k];
            let job = &jobs[index];
            bar.set_message(job.relative.clone());
            let outcome = convert(job, &args.options, args.force);
            print(line(job, &outcome, json));
            *outcomes[index].lock().unwrap_or_else(PoisonError::into_inner) = Some(outcome);
            bar.inc(1);
        });
        bar.finish_and_clear();
        report::set_progress_bar(None);
        done?;
    }

    let outcomes: Vec<Outcome> =
        outcomes.into_iter().filter_map(|slot| slot.into_inner().unwrap_or_else(PoisonError::into_inner)).collect();
    let count = |f: fn(&Status) -> bool| outcomes.iter().filter(|o| f(&o.status)).count();
    let built = count(|s| matches!(s, Status::Built { .. }));
    let up_to_date = count(|s| matches!(s, Status::UpToDate { .. }));
    let failed = count(|s| matches!(s, Status::Failed(_))) + plan_failures.len();
    let seconds = start.elapsed().as_secs_f64();
    let files = built + up_to_date + failed;
    let per_minute = files as f64 * 60.0 / seconds.max(1e-6);
    print(if json {
        let value = serde_json::json!({ "summary": {
            "files": files,
            "built": built,
            "up_to_date": up_to_date,
            "failed": failed,
            "seconds": seconds,
            "files_per_minute": per_minute,
            "temporaries_removed": removed,
        }});
        format!("{value}\n")
    } else {
        format!(
            "{files} file(s) in {seconds:.2} s: {built} built, {up_to_date} up to date, {failed} failed ({per_minute:.1} files/min)\n"
        )
    });

    let mut failures = plan_failures.into_iter().chain(outcomes.iter().filter_map(|o| match o.status {
        Status::Failed(f) => Some(f),
        _ => None,
    }));
    match failures.next() {
        Some(failed) => Err(failed),
        None if stdout_failed.load(Ordering::Relaxed) => Err(Failed { class: ErrorClass::Io }),
        None => Ok(()),
    }
}

/// The stdout line of a finished job.
fn line(job: &Job, outcome: &Outcome, json: bool) -> String {
    let (status, file_bytes, verified) = match outcome.status {
        Status::Built { file_bytes, verified } => ("built", Some(file_bytes), Some(verified)),
        Status::UpToDate { file_bytes } => ("up to date", Some(file_bytes), None),
        Status::Failed(_) => ("failed", None, None),
    };
    if json {
        let value = serde_json::json!({
            "status": status,
            "input": job.input.display().to_string(),
            "output": job.output.display().to_string(),
            "seconds": outcome.seconds,
            "source_bytes": outcome.source_bytes,
            "file_bytes": file_bytes,
            "verified": verified,
        });
        return format!("{value}\n");
    }
    let sizes = match (outcome.source_bytes, file_bytes) {
        (Some(source), Some(file)) => format!(" ({source} -> {file} bytes)"),
        (Some(source), None) => format!(" ({source} bytes; the error is on stderr)"),
        (None, _) => " (the error is on stderr)".to_owned(),
    };
    format!("{status:<10}  {} from {} in {:.2} s{sizes}\n", job.output.display(), job.input.display(), outcome.seconds)
}

/// Converts one file, or finds its output up to date. Errors are printed to stderr; a panic is
/// this file's failure ([`unless_panic`]).
fn convert(job: &Job, options: &BuildOptions, force: bool) -> Outcome {
    let start = Instant::now();
    let mut source_bytes = None;
    let status = match unless_panic(&job.input, || convert_file(job, options, force, &mut source_bytes)) {
        Ok(status) => status,
        Err(failed) => Status::Failed(failed),
    };
    Outcome { status, seconds: start.elapsed().as_secs_f64(), source_bytes }
}

/// Conversions running inside [`unless_panic`] now; while there are any, the panic hook that
/// [`quiet_caught_panics`] installs prints nothing.
static CONVERTING: AtomicUsize = AtomicUsize::new(0);

/// Runs `convert` (one file's conversion), turning a panic into that file's failure: `error: FILE:
/// internal error: MESSAGE (please report this file)`, class [`ErrorClass::Invalid`]. A last
/// resort, so that one file that trips a bug costs that file and not the run: inputs are meant to
/// be refused with a reason before anything can panic. What the conversion held is dropped while
/// unwinding (a temporary output file is removed).
fn unless_panic<T>(input: &Path, convert: impl FnOnce() -> Result<T, Failed>) -> Result<T, Failed> {
    CONVERTING.fetch_add(1, Ordering::SeqCst);
    let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(convert));
    CONVERTING.fetch_sub(1, Ordering::SeqCst);
    caught.unwrap_or_else(|payload| {
        let message = panic_message(payload.as_ref());
        report::message_error(input, &format!("internal error: {message} (please report this file)"));
        Err(Failed { class: ErrorClass::Invalid })
    })
}

/// A panic's message on one line (as every error line), from its payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    let message = payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("a panic without a message");
    message.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Installs (once) a panic hook that prints nothing for a panic while a conversion runs, which
/// [`unless_panic`] reports as one error line, and defers to the previous hook otherwise and when
/// `RUST_BACKTRACE` is set (to see where it happened).
fn quiet_caught_panics() {
    static INSTALLED: std::sync::Once = std::sync::Once::new();
    INSTALLED.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if CONVERTING.load(Ordering::SeqCst) == 0 || std::env::var_os("RUST_BACKTRACE").is_some() {
                previous(info);
            }
        }));
    });
}

fn convert_file(
    job: &Job,
    options: &BuildOptions,
    force: bool,
    source_bytes: &mut Option<u64>,
) -> Result<Status, Failed> {
    let input = job.input.as_path();
    let limits = options.import_limits();
    let bytes = treelod_build::read_source(input, &limits).map_err(|e| report::build_error(input, &e))?;
    *source_bytes = Some(bytes.len() as u64);
    if !force {
        let hash = treelod_build::content_hash(&bytes);
        if let Some(file_bytes) = up_to_date(&job.output, &job.relative, &hash, options) {
            return Ok(Status::UpToDate { file_bytes });
        }
    }
    // The same import as `treelod build INPUT` (the glTF's relative URIs resolve beside it), with the
    // relative path recorded as the source path.
    let mut scene = treelod_build::import_gltf_bytes_with(&bytes, input, input.parent(), &limits)
        .map_err(|e| report::build_error(input, &e))?;
    drop(bytes);
    scene.source.path.clone_from(&job.relative);
    if let Some(dir) = job.output.parent() {
        std::fs::create_dir_all(dir).map_err(|e| report::io_error(dir, &e))?;
    }
    let name = scene.name.clone();
    // Verified before the rename (unless --no-verify): a file that fails verification is never
    // written, and the old output, which is not up to date (or --force), stays as it was.
    let built = build::build_container(&name, vec![(scene, Vec3::ZERO)], &[input], &job.output, options)?;
    Ok(Status::Built { file_bytes: built.file_bytes, verified: built.verified })
}

/// The size of `output` if it is up to date: it opens (spec §9.1) and its metadata records this
/// tool as generator, exactly one source with this relative path and content hash, and the settings
/// these options record (with the recorded grid when the grid is automatic: it follows from the
/// source, which the hash pins).
fn up_to_date(output: &Path, relative: &str, content_hash: &str, options: &BuildOptions) -> Option<u64> {
    let container = Container::open(output).ok()?;
    let meta = container.metadata();
    let [source] = meta.sources.as_slice() else {
        return None;
    };
    let grid = match options.grid {
        Some(grid) => grid,
        None => build::parse_grid(meta.setting("grid")?).ok()?,
    };
    let same = meta.generator == build::generator()
        && source.path == relative
        && source.content_hash == content_hash
        && meta.settings == options.recorded_settings(grid);
    same.then(|| container.header().file_size)
}

/// The jobs of `inputs` in order, each directory's files in sorted order. Errors (an unreadable
/// directory, a glob that matches nothing) are printed and pushed to `failures`. A file listed
/// twice is converted once; a later input writing the output of an earlier one is marked
/// [`Job::duplicate_of`].
fn plan(inputs: &[PathBuf], output: &Path, failures: &mut Vec<Failed>) -> Vec<Job> {
    let mut jobs: Vec<Job> = Vec::new();
    let mut writers: std::collections::HashMap<PathBuf, PathBuf> = std::collections::HashMap::new();
    let mut add = |base: &Path, relative: &Path, jobs: &mut Vec<Job>| {
        let input = base.join(relative);
        let output = output.join(relative).with_extension("treelod");
        let duplicate_of = match writers.get(&output) {
            Some(earlier) if *earlier == input => return,
            Some(earlier) => Some(earlier.clone()),
            None => {
                writers.insert(output.clone(), input.clone());
                None
            }
        };
        jobs.push(Job { input, relative: slash_path(relative), output, duplicate_of });
    };
    for input in inputs {
        let mut errors = Vec::new();
        if let Some((base, pattern)) = glob_pattern(input) {
            let mut found = Vec::new();
            walk(&base, Path::new(""), &mut found, &mut errors);
            let before = jobs.len();
            for relative in found.iter().filter(|r| matches_glob(&pattern, r)) {
                add(&base, relative, &mut jobs);
            }
            // An unreadable base directory is reported as such below.
            if jobs.len() == before && errors.is_empty() {
                report::message_error(input, "matches no .glb or .gltf file");
                failures.push(Failed { class: ErrorClass::Io });
            }
        } else if input.is_dir() {
            let mut found = Vec::new();
            walk(input, Path::new(""), &mut found, &mut errors);
            if found.is_empty() && errors.is_empty() {
                report::print_warning(input, "holds no .glb or .gltf file");
            }
            for relative in &found {
                add(input, relative, &mut jobs);
            }
        } else {
            // A file named directly (or a missing path, reported when it is read).
            match input.file_name() {
                Some(name) => add(input.parent().unwrap_or(Path::new("")), Path::new(name), &mut jobs),
                None => {
                    report::message_error(input, "is neither a file nor a directory");
                    failures.push(Failed { class: ErrorClass::Io });
                }
            }
        }
        for (path, error) in errors {
            failures.push(report::io_error(&path, &error));
        }
    }
    jobs
}

/// Appends the glTF files under `base/dir` to `found` as paths relative to `base`, depth first,
/// each directory's entries in sorted order (by name, bytewise). Symbolic links to files are
/// taken; symbolic links to directories are not followed (no cycles). Directories that cannot be
/// read are pushed to `errors`.
fn walk(base: &Path, dir: &Path, found: &mut Vec<PathBuf>, errors: &mut Vec<(PathBuf, io::Error)>) {
    let shown = base.join(dir);
    let listed = if shown.as_os_str().is_empty() { Path::new(".") } else { shown.as_path() };
    let entries = match std::fs::read_dir(listed) {
        Ok(entries) => entries,
        Err(e) => {
            errors.push((shown, e));
            return;
        }
    };
    let mut names: Vec<(OsString, bool)> = Vec::new();
    for entry in entries {
        let entry = match entry {
            Ok(entry) => entry,
            Err(e) => {
                errors.push((shown.clone(), e));
                continue;
            }
        };
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        let is_file = kind.is_file() || (kind.is_symlink() && entry.path().is_file());
        if kind.is_dir() || is_file {
            names.push((entry.file_name(), kind.is_dir()));
        }
    }
    names.sort();
    for (name, is_dir) in names {
        let relative = dir.join(&name);
        if is_dir {
            walk(base, &relative, found, errors);
        } else if crate::scene::is_gltf_path(&relative) {
            found.push(relative);
        }
    }
}

/// `relative` with `/` between its components.
fn slash_path(relative: &Path) -> String {
    relative.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/")
}

/// If `input` is a glob (it holds `*` or `?` and names no existing file): its base (the components
/// before the first one with a wildcard) and the remaining components.
fn glob_pattern(input: &Path) -> Option<(PathBuf, Vec<String>)> {
    let text = input.to_str()?;
    if !text.contains(['*', '?']) || input.exists() {
        return None;
    }
    let mut base = PathBuf::new();
    let mut pattern = Vec::new();
    for component in input.components() {
        let part = component.as_os_str().to_string_lossy();
        if pattern.is_empty() && !part.contains(['*', '?']) {
            base.push(component);
        } else if !matches!(component, Component::CurDir) {
            pattern.push(part.into_owned());
        }
    }
    Some((base, pattern))
}

/// Whether the relative path matches the glob's components (`**` matches any number of them).
fn matches_glob(pattern: &[String], relative: &Path) -> bool {
    let parts: Vec<String> = relative.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    let parts: Vec<&str> = parts.iter().map(String::as_str).collect();
    let pattern: Vec<&str> = pattern.iter().map(String::as_str).collect();
    match_components(&pattern, &parts)
}

fn match_components(pattern: &[&str], parts: &[&str]) -> bool {
    match pattern.split_first() {
        None => parts.is_empty(),
        Some((&"**", rest)) => (0..=parts.len()).any(|skip| match_components(rest, &parts[skip..])),
        Some((first, rest)) => parts.split_first().is_some_and(|(part, parts)| {
            match_name(first.as_bytes(), part.as_bytes()) && match_components(rest, parts)
        }),
    }
}

/// `*` (any run of characters) and `?` (one character) within one name, case-sensitive. Works on
/// bytes: `?` matches one byte, which is one character for ASCII names.
fn match_name(pattern: &[u8], name: &[u8]) -> bool {
    // Iterative matching with one backtrack point (the last `*`): linear in practice.
    let (mut p, mut n) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while n < name.len() {
        match pattern.get(p) {
            Some(b'*') => {
                star = Some((p, n));
                p += 1;
            }
            Some(&c) if c == b'?' || c == name[n] => {
                p += 1;
                n += 1;
            }
            _ => match star {
                Some((sp, sn)) => {
                    p = sp + 1;
                    n = sn + 1;
                    star = Some((sp, sn + 1));
                }
                None => return false,
            },
        }
    }
    pattern[p.min(pattern.len())..].iter().all(|&c| c == b'*')
}

fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} [{bar:30}] {pos}/{len} {elapsed} {wide_msg}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    if !bar.is_hidden() {
        bar.enable_steady_tick(Duration::from_millis(250));
    }
    bar
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::{Shard, glob_pattern, match_name, matches_glob, parse_shard, shard_of, slash_path, unless_panic};
    use crate::report::Failed;
    use treelod_format::ErrorClass;

    #[test]
    fn a_panic_is_the_files_failure() {
        let input = Path::new("lib/tree.glb");
        assert_eq!(unless_panic(input, || Ok::<_, Failed>(7)), Ok(7));
        let failed = Failed { class: ErrorClass::Io };
        assert_eq!(unless_panic(input, || Err::<u8, _>(failed)), Err(failed));
        let invalid = Err(Failed { class: ErrorClass::Invalid });
        assert_eq!(unless_panic(input, || -> Result<u8, Failed> { panic!("index out of bounds") }), invalid);
        let owned = String::from("a formatted\nmessage");
        assert_eq!(unless_panic(input, || -> Result<u8, Failed> { panic!("{owned}") }), invalid);
        let message = |f: fn()| super::panic_message(std::panic::catch_unwind(f).unwrap_err().as_ref());
        assert_eq!(message(|| panic!("plain")), "plain");
        assert_eq!(message(|| panic!("left: {}\n right: {}", 1, 2)), "left: 1 right: 2");
        assert_eq!(message(|| std::panic::panic_any(7u8)), "a panic without a message");
        // Nothing is left counted as converting, and the run goes on with the next file.
        assert_eq!(super::CONVERTING.load(std::sync::atomic::Ordering::SeqCst), 0);
        assert_eq!(unless_panic(input, || Ok::<_, Failed>("next")), Ok("next"));
    }

    #[test]
    fn shards_are_fixed_and_cover_every_path_once() {
        // Pinned values: machines, runs and versions must agree on them.
        assert_eq!(shard_of("a/b/tree.glb", 1), 0);
        let spread: Vec<u64> =
            ["oak.glb", "pine.glb", "a/oak.glb", "b/c/maple.gltf"].iter().map(|p| shard_of(p, 7)).collect();
        assert_eq!(spread, spread_expected());
        for path in ["x.glb", "y/z.glb", "ü/ß.gltf"] {
            let holders = (0..5).filter(|&i| Shard { index: i, count: 5 }.holds(path)).count();
            assert_eq!(holders, 1, "{path}");
        }
    }

    fn spread_expected() -> Vec<u64> {
        use sha2::Digest as _;
        ["oak.glb", "pine.glb", "a/oak.glb", "b/c/maple.gltf"]
            .iter()
            .map(|p| {
                let d = sha2::Sha256::digest(p.as_bytes());
                u64::from_be_bytes([d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]]) % 7
            })
            .collect()
    }

    #[test]
    fn shard_arguments_are_checked() {
        assert_eq!(parse_shard("1/4"), Ok(Shard { index: 1, count: 4 }));
        assert_eq!(parse_shard("0/1"), Ok(Shard { index: 0, count: 1 }));
        for bad in ["4/4", "0/0", "1", "a/2", "-1/2", "1/2/3", ""] {
            assert!(parse_shard(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn globs_match_names_and_directories() {
        assert!(match_name(b"*.glb", b"oak.glb"));
        assert!(match_name(b"o?k*", b"oak.glb"));
        assert!(match_name(b"*", b""));
        assert!(!match_name(b"*.glb", b"oak.gltf"));
        assert!(!match_name(b"?", b""));
        assert!(match_name(b"a*b*c", b"axxbyyc"));
        assert!(!match_name(b"a*b*c", b"axxbyy"));
        let (base, pattern) = glob_pattern(Path::new("lib/trees/**/o*.glb")).expect("a glob");
        assert_eq!(base, Path::new("lib/trees"));
        assert_eq!(pattern, ["**", "o*.glb"]);
        assert!(matches_glob(&pattern, Path::new("oak.glb")));
        assert!(matches_glob(&pattern, Path::new("a/b/oak.glb")));
        assert!(!matches_glob(&pattern, Path::new("a/pine.glb")));
        let (base, pattern) = glob_pattern(Path::new("*/*.glb")).expect("a glob");
        assert_eq!(base, Path::new(""));
        assert!(matches_glob(&pattern, Path::new("a/oak.glb")));
        assert!(!matches_glob(&pattern, Path::new("oak.glb")));
        assert!(glob_pattern(Path::new("lib/oak.glb")).is_none());
        assert_eq!(slash_path(Path::new("a/b/c.glb")), "a/b/c.glb");
    }
}
