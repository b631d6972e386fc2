//! `treelod demo` (and the shared build path): a tree in, a verified container out, with a summary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use treelod_build::{BuildConfig, BuildOutput, Placed, build_block};
use treelod_format::{Compression, Container};

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
    fn config(&self) -> BuildConfig {
        BuildConfig {
            grid: self.grid,
            gilet: treelod_build::gilet::GiletConfig { cluster_max: self.cluster_max as usize },
            classify: treelod_build::classify::ClassifyOptions { leaves: self.leaves.clone(), bark: self.bark.clone() },
        }
    }

    fn compression(&self) -> Compression {
        if self.compression == "none" { Compression::None } else { Compression::Zstd { level: self.level } }
    }
}

fn parse_grid(s: &str) -> Result<[u32; 3], String> {
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

/// Runs `treelod demo`: builds the built-in procedural tree (no input needed).
pub fn run_demo(args: &DemoArgs) -> Result<(), Failed> {
    let config = treelod_build::DemoTreeConfig {
        seed: args.seed,
        leaves: args.leaf_count,
        ..treelod_build::DemoTreeConfig::default()
    };
    let scene = treelod_build::demo_tree(&config);
    build_one(&scene.name, &[Placed { scene: &scene, translation: Vec3::ZERO }], &[], &args.output, &args.options)?;
    if !args.options.json {
        report::write_stdout(&format!("next: treelod dump {}\n", args.output.display()))?;
    }
    Ok(())
}

/// Builds, writes atomically, reopens and verifies one container, then prints its summary.
fn build_one(
    name: &str,
    placed: &[Placed<'_>],
    sources: &[&Path],
    output: &Path,
    options: &BuildOptions,
) -> Result<(), Failed> {
    let start = Instant::now();
    let source_label = sources.first().copied().unwrap_or(output);
    let built: BuildOutput =
        build_block(name, placed, &options.config(), &format!("treelod {}", env!("CARGO_PKG_VERSION")))
            .map_err(|e| report::build_error(source_label, &e))?;
    for warning in &built.warnings {
        report::print_warning(source_label, warning);
    }
    let bytes = built.data.to_bytes(options.compression()).map_err(|e| report::file_error(output, &e))?;
    treelod_format::write_atomically(output, &bytes).map_err(|e| report::file_error(output, &e))?;
    let verified = if options.no_verify {
        None
    } else {
        let container = Container::open(output).map_err(|e| report::file_error(output, &e))?;
        Some(treelod_format::verify(&container).map_err(|e| report::file_error(output, &e))?)
    };
    let seconds = start.elapsed().as_secs_f64();
    let source_bytes: u64 = sources.iter().filter_map(|p| std::fs::metadata(p).ok()).map(|m| m.len()).sum();
    let summary = Summary {
        output,
        sources,
        built: &built,
        file_bytes: bytes.len() as u64,
        source_bytes,
        seconds,
        verified: verified.is_some(),
    };
    report::write_stdout(&if options.json { summary.to_json() } else { summary.to_text() })
}

/// What a finished build prints.
struct Summary<'a> {
    output: &'a Path,
    sources: &'a [&'a Path],
    built: &'a BuildOutput,
    file_bytes: u64,
    source_bytes: u64,
    seconds: f64,
    verified: bool,
}

impl Summary<'_> {
    fn to_text(&self) -> String {
        let s = &self.built.stats;
        let from = if self.sources.is_empty() {
            "the built-in demo tree".to_owned()
        } else {
            self.sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        };
        let ratio = if self.source_bytes > 0 {
            format!(" ({:.2}x the source)", self.file_bytes as f64 / self.source_bytes as f64)
        } else {
            String::new()
        };
        format!(
            "{}: built from {from} in {:.2} s\n  triangles in  {} (leaf {}, bark {}; dropped {})\n  written       {} vertices, {} triangles, {} points, {} material(s), {} image(s)\n  grid          {}x{}x{}, {} of {} cells non-empty\n  file          {} bytes{ratio}\n  verify        {}\n",
            self.output.display(),
            self.seconds,
            s.triangles_in,
            s.leaf_triangles,
            s.bark_triangles,
            s.triangles_dropped,
            s.vertices,
            s.triangles,
            s.points,
            self.built.data.materials.len(),
            self.built.data.images.len(),
            s.grid[0],
            s.grid[1],
            s.grid[2],
            s.nonempty_cells,
            s.grid.iter().product::<u32>(),
            self.file_bytes,
            if self.verified { "ok" } else { "skipped" },
        )
    }

    fn to_json(&self) -> String {
        let s = &self.built.stats;
        let value = serde_json::json!({
            "output": self.output.display().to_string(),
            "sources": self.sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
            "seconds": self.seconds,
            "triangles_in": s.triangles_in,
            "triangles_dropped": s.triangles_dropped,
            "leaf_triangles": s.leaf_triangles,
            "bark_triangles": s.bark_triangles,
            "vertices": s.vertices,
            "triangles": s.triangles,
            "points": s.points,
            "materials": self.built.data.materials.len(),
            "images": self.built.data.images.len(),
            "grid": s.grid,
            "nonempty_cells": s.nonempty_cells,
            "file_bytes": self.file_bytes,
            "source_bytes": self.source_bytes,
            "verified": self.verified,
            "warnings": self.built.warnings,
        });
        format!("{value}\n")
    }
}
