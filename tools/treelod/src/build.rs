//! `treelod build` and `treelod demo`: trees in, verified containers out, with a summary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use treelod_build::scene::Scene;
use treelod_build::{BuildConfig, BuildOutput, BuildStats, Placed, build_block};
use treelod_format::{Compression, Container, ErrorClass, Setting};

use crate::report::{self, Failed};

/// Options shared by `build` and `demo`.
#[derive(clap::Args, Debug, Clone)]
pub struct BuildOptions {
    /// Grid cells along x,y,z (e.g. `4,4,4`); default: 4 along the shortest axis, proportionally
    /// more along the others, each axis 4..=16.
    #[arg(long, value_parser = parse_grid)]
    pub grid: Option<[u32; 3]>,
    /// Glob (case-insensitive, `*` and `?`) of material, mesh or node names that are leaves;
    /// repeatable.
    #[arg(long = "leaves", value_name = "PATTERN")]
    pub leaves: Vec<String>,
    /// Glob of material, mesh or node names that are bark; repeatable.
    #[arg(long = "bark", value_name = "PATTERN")]
    pub bark: Vec<String>,
    /// Largest point cluster left unsplit by the PCA clustering (Gilet: about 5).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(2..=64))]
    pub cluster_max: u32,
    /// Section compression: `zstd` (smaller files, decoded on open) or `none` (used in place
    /// from a memory map).
    #[arg(long, default_value = "zstd", value_parser = ["zstd", "none"])]
    pub compression: String,
    /// zstd level, 1..=22.
    #[arg(long, default_value_t = 9, value_parser = clap::value_parser!(i32).range(1..=22))]
    pub level: i32,
    /// Skip the full verification of each written file.
    #[arg(long)]
    pub no_verify: bool,
    /// Print one JSON object per container instead of the text summary.
    #[arg(long)]
    pub json: bool,
}

impl BuildOptions {
    /// The build crate's configuration of these options.
    pub(crate) fn config(&self) -> BuildConfig {
        BuildConfig {
            grid: self.grid,
            gilet: treelod_build::gilet::GiletConfig { cluster_max: self.cluster_max as usize },
            classify: treelod_build::classify::ClassifyOptions { leaves: self.leaves.clone(), bark: self.bark.clone() },
        }
    }

    /// How sections are stored.
    pub(crate) fn compression(&self) -> Compression {
        if self.compression == "none" { Compression::None } else { Compression::Zstd { level: self.level } }
    }

    /// The `compression` setting recorded in the metadata: `zstd:LEVEL` or `none`.
    fn compression_setting(&self) -> Setting {
        let value = match self.compression() {
            Compression::None => "none".to_owned(),
            Compression::Zstd { level } => format!("zstd:{level}"),
        };
        Setting { key: "compression".into(), value }
    }

    /// Every setting a container built with these options records (spec §7.1), sorted by key: the
    /// build crate's ([`treelod_build::recorded_settings`]) and `compression`. `grid` is the grid
    /// the block was built with.
    pub(crate) fn recorded_settings(&self, grid: [u32; 3]) -> Vec<Setting> {
        let mut settings = treelod_build::recorded_settings(&self.config(), grid);
        settings.push(self.compression_setting());
        settings.sort();
        settings
    }
}

/// The `generator` recorded in the metadata of every container this tool writes.
pub(crate) fn generator() -> String {
    format!("treelod {}", env!("CARGO_PKG_VERSION"))
}

/// Parses `X,Y,Z`, each in 1..=256 (the `--grid` option and the recorded `grid` setting).
pub(crate) fn parse_grid(s: &str) -> Result<[u32; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("expected X,Y,Z (three numbers), got {s:?}"));
    };
    let n = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (1..=256).contains(n))
            .ok_or_else(|| format!("{v:?} is not a number in 1..=256"))
    };
    Ok([n(x)?, n(y)?, n(z)?])
}

/// Arguments of `treelod build`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Source trees: glTF 2.0 files (`.glb` or `.gltf`).
    #[arg(value_name = "INPUT", required_unless_present = "placement")]
    pub inputs: Vec<PathBuf>,
    /// Output: a `.treelod` file for one input or `--block`, otherwise a directory that receives
    /// `<input stem>.treelod` per input (created if missing).
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Put all inputs into one block (Gilet's compact group of trees), side by side along x, so
    /// one grid spans the group.
    #[arg(long)]
    pub block: bool,
    /// With `--block`: a placement file instead of side by side. One tree per line, `PATH X Y Z`
    /// (metres; PATH relative to the placement file; `#` starts a comment). Trees listed here are
    /// added after any INPUTs.
    #[arg(long, value_name = "FILE", requires = "block")]
    pub placement: Option<PathBuf>,
    /// Build settings.
    #[command(flatten)]
    pub options: BuildOptions,
}

/// Arguments of `treelod demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Where to write the container.
    #[arg(short, long, value_name = "PATH", default_value = "demo.treelod")]
    pub output: PathBuf,
    /// Seed of the procedural tree.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of leaf quads.
    #[arg(long, default_value_t = treelod_build::DemoTreeConfig::default().leaves, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub leaf_count: u32,
    /// Build settings.
    #[command(flatten)]
    pub options: BuildOptions,
}

/// Runs `treelod build`.
pub fn run(args: &Args) -> Result<(), Failed> {
    if args.block {
        return run_block(args);
    }
    let to_directory =
        args.inputs.len() > 1 || args.output.is_dir() || args.output.as_os_str().to_string_lossy().ends_with('/');
    if to_directory {
        std::fs::create_dir_all(&args.output).map_err(|e| report::io_error(&args.output, &e))?;
    }
    // One input at a time: import, build, write, then drop it before the next, so a batch takes the
    // memory of its largest tree, and one bad file does not stop the others.
    let mut first_failure = None;
    let mut seen: Vec<PathBuf> = Vec::new();
    for input in &args.inputs {
        let output = if to_directory {
            args.output.join(format!("{}.treelod", treelod_build::scene_name(input)))
        } else {
            args.output.clone()
        };
        if seen.contains(&output) {
            report::message_error(
                input,
                &format!("another input also writes {}; rename one or use --block", output.display()),
            );
            first_failure.get_or_insert(Failed { class: ErrorClass::Invalid });
            continue;
        }
        seen.push(output.clone());
        let result = import(input).and_then(|scene| {
            let name = scene.name.clone();
            build_one(&name, vec![(scene, Vec3::ZERO)], &[input.as_path()], &output, &args.options)
        });
        if let Err(failed) = result {
            first_failure.get_or_insert(failed);
        }
    }
    first_failure.map_or(Ok(()), Err)
}

/// `--block`: every input (and every tree of the placement file) in one block.
fn run_block(args: &Args) -> Result<(), Failed> {
    let mut paths: Vec<PathBuf> = Vec::new();
    let mut x = 0.0f32;
    let mut scenes: Vec<(Scene, Vec3)> = Vec::new();
    let progress = progress_bar(args.inputs.len() as u64);
    for input in &args.inputs {
        progress.set_message(format!("importing {}", input.display()));
        let scene = import(input)?;
        // Side by side along x with a 10 % gap, each tree's own x extent apart.
        let (lo, hi) = scene_x_range(&scene);
        let offset = x - lo;
        x = offset + hi + 0.1 * (hi - lo).max(0.0);
        paths.push(input.clone());
        scenes.push((scene, Vec3::new(offset, 0.0, 0.0)));
        progress.inc(1);
    }
    if let Some(placement) = &args.placement {
        for (path, at) in read_placement(placement)? {
            progress.set_message(format!("importing {}", path.display()));
            scenes.push((import(&path)?, at));
            paths.push(path);
        }
    }
    progress.finish_and_clear();
    let name = args.output.file_stem().map_or_else(|| "block".to_owned(), |s| s.to_string_lossy().into_owned());
    let sources: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
    build_one(&name, scenes, &sources, &args.output, &args.options)
}

/// Runs `treelod demo`: builds the built-in procedural tree (no input needed).
pub fn run_demo(args: &DemoArgs) -> Result<(), Failed> {
    let config = treelod_build::DemoTreeConfig {
        seed: args.seed,
        leaves: args.leaf_count,
        ..treelod_build::DemoTreeConfig::default()
    };
    let scene = treelod_build::demo_tree(&config);
    let name = scene.name.clone();
    build_one(&name, vec![(scene, Vec3::ZERO)], &[], &args.output, &args.options)?;
    if !args.options.json {
        report::write_stdout(&format!("next: treelod dump {}\n", args.output.display()))?;
    }
    Ok(())
}

/// Builds, writes atomically, reopens and verifies one container, then prints its summary.
fn build_one(
    name: &str,
    scenes: Vec<(Scene, Vec3)>,
    sources: &[&Path],
    output: &Path,
    options: &BuildOptions,
) -> Result<(), Failed> {
    let built = build_container(name, scenes, sources, output, options)?;
    let summary = Summary { output, sources, built: &built };
    report::write_stdout(&if options.json { summary.to_json() } else { summary.to_text() })
}

/// What [`build_container`] built.
pub(crate) struct Built {
    /// Counts of the build.
    pub stats: BuildStats,
    /// Warnings of the import and the build (already printed to stderr).
    pub warnings: Vec<String>,
    /// Materials written.
    pub materials: usize,
    /// Images written.
    pub images: usize,
    /// Size of the written file.
    pub file_bytes: u64,
    /// Total size of the source files.
    pub source_bytes: u64,
    /// Wall-clock seconds from build to verification.
    pub seconds: f64,
    /// Whether the written file was fully verified (not with `--no-verify`).
    pub verified: bool,
}

/// Builds one container, writes it atomically (temporary file, then rename), reopens and verifies
/// it unless `--no-verify`, and returns what was built; prints warnings and errors (naming the
/// first source, or `output` without one) to stderr, nothing to stdout. The metadata records the
/// tool as generator and [`BuildOptions::recorded_settings`].
///
/// The scenes are dropped once built and the built arrays once written, before verification reads
/// the file back, so the stages do not hold each other's memory.
pub(crate) fn build_container(
    name: &str,
    scenes: Vec<(Scene, Vec3)>,
    sources: &[&Path],
    output: &Path,
    options: &BuildOptions,
) -> Result<Built, Failed> {
    let start = Instant::now();
    let source_label = sources.first().copied().unwrap_or(output);
    let placed: Vec<Placed<'_>> =
        scenes.iter().map(|(scene, translation)| Placed { scene, translation: *translation }).collect();
    let built =
        build_block(name, &placed, &options.config(), &generator()).map_err(|e| report::build_error(source_label, &e));
    drop(placed);
    drop(scenes);
    let BuildOutput { mut data, stats, warnings } = built?;
    for warning in &warnings {
        report::print_warning(source_label, warning);
    }
    data.metadata.settings.push(options.compression_setting());
    data.metadata.settings.sort();
    let file_bytes = data.write_to_path(output, options.compression()).map_err(|e| report::file_error(output, &e))?;
    let (materials, images) = (data.materials.len(), data.images.len());
    drop(data);
    let verified = if options.no_verify {
        false
    } else {
        let container = Container::open(output).map_err(|e| report::file_error(output, &e))?;
        treelod_format::verify(&container).map_err(|e| report::file_error(output, &e))?;
        true
    };
    let seconds = start.elapsed().as_secs_f64();
    let source_bytes: u64 = sources.iter().filter_map(|p| std::fs::metadata(p).ok()).map(|m| m.len()).sum();
    Ok(Built { stats, warnings, materials, images, file_bytes, source_bytes, seconds, verified })
}

/// What a finished build prints.
struct Summary<'a> {
    output: &'a Path,
    sources: &'a [&'a Path],
    built: &'a Built,
}

impl Summary<'_> {
    fn to_text(&self) -> String {
        let s = &self.built.stats;
        let from = if self.sources.is_empty() {
            "the built-in demo tree".to_owned()
        } else {
            self.sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        };
        let ratio = if self.built.source_bytes > 0 {
            format!(" ({:.2}x the source)", self.built.file_bytes as f64 / self.built.source_bytes as f64)
        } else {
            String::new()
        };
        format!(
            "{}: built from {from} in {:.2} s\n  triangles in  {} (leaf {}, bark {}; dropped {})\n  written       {} vertices, {} triangles, {} points, {} material(s), {} image(s)\n  grid          {}x{}x{}, {} of {} cells non-empty\n  file          {} bytes{ratio}\n  verify        {}\n",
            self.output.display(),
            self.built.seconds,
            s.triangles_in,
            s.leaf_triangles,
            s.bark_triangles,
            s.triangles_dropped,
            s.vertices,
            s.triangles,
            s.points,
            self.built.materials,
            self.built.images,
            s.grid[0],
            s.grid[1],
            s.grid[2],
            s.nonempty_cells,
            s.grid.iter().product::<u32>(),
            self.built.file_bytes,
            if self.built.verified { "ok" } else { "skipped" },
        )
    }

    fn to_json(&self) -> String {
        let (b, s) = (self.built, &self.built.stats);
        let value = serde_json::json!({
            "output": self.output.display().to_string(),
            "sources": self.sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
            "seconds": b.seconds,
            "triangles_in": s.triangles_in,
            "triangles_dropped": s.triangles_dropped,
            "leaf_triangles": s.leaf_triangles,
            "bark_triangles": s.bark_triangles,
            "vertices": s.vertices,
            "triangles": s.triangles,
            "points": s.points,
            "materials": b.materials,
            "images": b.images,
            "grid": s.grid,
            "nonempty_cells": s.nonempty_cells,
            "file_bytes": b.file_bytes,
            "source_bytes": b.source_bytes,
            "verified": b.verified,
            "warnings": b.warnings,
        });
        format!("{value}\n")
    }
}

fn import(path: &Path) -> Result<Scene, Failed> {
    treelod_build::import_gltf(path).map_err(|e| report::build_error(path, &e))
}

fn scene_x_range(scene: &Scene) -> (f32, f32) {
    let xs = scene.parts.iter().flat_map(|p| &p.positions).map(|p| p[0]).filter(|x| x.is_finite());
    let (lo, hi) = xs.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
    if lo <= hi { (lo, hi) } else { (0.0, 0.0) }
}

/// Reads a placement file: `PATH X Y Z` per line, `#` comments, blank lines ignored.
fn read_placement(path: &Path) -> Result<Vec<(PathBuf, Vec3)>, Failed> {
    let text = std::fs::read_to_string(path).map_err(|e| report::io_error(path, &e))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split_whitespace().collect();
        let parsed = match fields.as_slice() {
            [p, x, y, z] => match (x.parse::<f32>(), y.parse::<f32>(), z.parse::<f32>()) {
                (Ok(x), Ok(y), Ok(z)) if x.is_finite() && y.is_finite() && z.is_finite() => {
                    Some((base.join(p), Vec3::new(x, y, z)))
                }
                _ => None,
            },
            _ => None,
        };
        match parsed {
            Some(entry) => out.push(entry),
            None => {
                report::message_error(
                    path,
                    &format!("line {}: expected `PATH X Y Z` with finite numbers, got {line:?}", n + 1),
                );
                return Err(Failed { class: ErrorClass::Invalid });
            }
        }
    }
    if out.is_empty() {
        report::message_error(path, "lists no trees");
        return Err(Failed { class: ErrorClass::Invalid });
    }
    Ok(out)
}

fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} [{pos}/{len}] {msg}") {
        bar.set_style(style);
    }
    bar
}
