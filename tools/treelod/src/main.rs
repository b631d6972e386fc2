//! The `treelod` command-line tool: build, inspect and check `.treelod` containers.
//!
//! This file only parses the command line, dispatches to one module per subcommand and turns the
//! outcome into an exit code ([`report::Failed::exit_code`]). Each subcommand prints its own
//! results to stdout and its errors to stderr, every error line as `error: PATH: reason`.

mod batch;
mod bench;
mod build;
mod dump;
mod eval;
mod prune_plot;
mod render;
mod report;
mod scatter;
mod scene;
mod table;
mod verify;
mod view;
mod workers;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// The exit codes, shown at the end of `--help` (and documented in `docs/cli.md`).
const EXIT_CODES: &str = "\
Exit codes:
  0  success
  2  usage error (unknown subcommand or option, missing argument)
  3  invalid input: not a valid .treelod container, a glTF file that does not parse or holds
     nothing drawable, a bad placement or scene file
  4  unsupported: a newer format version, a feature this build of treelod lacks (e.g. a glTF
     compression extension), a glTF input over a --max-* limit or with a URI outside its
     directory, no Vulkan adapter for render or view, no display for view
  5  I/O error: a file cannot be read or written (missing, a directory, not a regular file,
     no permission)
With several files every file is processed and the exit code is that of the first failure.
Errors go to stderr as `error: FILE: reason`, warnings as `warning: FILE: message`.";

/// Build, inspect and check .treelod level-of-detail containers for tree meshes.
#[derive(Debug, Parser)]
#[command(name = "treelod", version, after_help = EXIT_CODES)]
struct Cli {
    /// What to do.
    #[command(subcommand)]
    command: Command,
}

/// The subcommands, one module each.
#[derive(Debug, Subcommand)]
enum Command {
    /// Build containers from glTF trees (Gilet's triangle + point hierarchy per grid cell).
    #[command(after_help = EXIT_CODES)]
    Build(build::Args),
    /// Convert a library of glTF trees in parallel into a mirrored tree of containers, skipping
    /// those that are up to date.
    ///
    /// Each output is written atomically; a re-run (say after a kill) builds only what is missing
    /// or stale (tool version, source content hash or settings changed). --shard I/N takes a stable
    /// subset so a Kubernetes indexed Job or a Slurm array spreads a library over machines.
    #[command(after_help = EXIT_CODES)]
    Batch(batch::Args),
    /// Build the built-in procedural demo tree into a container (no input needed).
    #[command(after_help = EXIT_CODES)]
    Demo(build::DemoArgs),
    /// Print what a container holds: sections, block, metadata, per-cell counts, size histograms.
    #[command(after_help = EXIT_CODES)]
    Dump(dump::Args),
    /// Fully check containers (format spec §9.2): checksums, records, orderings, exact cuts.
    #[command(after_help = EXIT_CODES)]
    Verify(verify::Args),
    /// Write a scene file of N instances of containers scattered on the ground (deterministic).
    #[command(after_help = EXIT_CODES)]
    Scatter(scatter::Args),
    /// Render a container or scene file offscreen to a PNG (Vulkan; lavapipe without a GPU).
    #[command(after_help = EXIT_CODES)]
    Render(render::Args),
    /// Open a window with a fly camera over a container or scene file (X11, Vulkan).
    ///
    /// Drag with the left mouse button to look; W A S D move, E and Q rise and sink, Shift is
    /// faster. `[` `]` halve and double s_min, `-` `=` s_max, K and J raise and lower the depth
    /// bias k, F toggles the full mesh, 1 2 3 show shaded, cells, kinds; Esc quits. The title shows
    /// fps, visible instances, triangles, points and the thresholds.
    #[command(after_help = EXIT_CODES)]
    View(view::Args),
    /// Measure techniques against the full mesh: primitives, Precision/Recall/Q, multi-scale RMSE,
    /// temporal noise and wall time per frame along a camera path (Vulkan; lavapipe works).
    ///
    /// The reference is the full mesh drawn --supersample times larger and box-filtered down,
    /// minified alpha-tested leaves covering the share of pixels their filtered alpha gives.
    /// Techniques: full (the full mesh drawn as the reference is: reads perfect), full-1x (the
    /// full mesh at the image size), spt (triangles + points, the default renderer), ellipsoids
    /// (Clasen's ellipsoids and branch lines), impostors, prune-opt and prune-cook where the
    /// containers hold them (reported as absent otherwise); policy (per tree the representation the
    /// calibration tables choose).
    #[command(after_help = EXIT_CODES)]
    Eval(eval::Args),
    /// The fly-through benchmark (Clasen 2011 §7): a forest of 10,000 trees in groups and a camera
    /// path from an overview down into the forest, to a separate group and back; per frame and
    /// technique the selection time, primitives, streaming, GPU time and optionally quality.
    ///
    /// Without inputs the forest is made of built-in demo trees. full (the full mesh) is counted
    /// from the selection, not drawn, unless --quality draws it as the reference; spt is the
    /// default renderer; prune-cook and prune-opt fly the renderer's pruning policy with Cook's or
    /// the optimal scale where the models hold priority lists (reported as absent otherwise);
    /// policy flies the renderer's default choice per tree, with --budget its budget mode.
    #[command(after_help = EXIT_CODES)]
    Bench(bench::Args),
}

fn main() -> ExitCode {
    fixed_mmap_threshold();
    // Usage errors: clap prints `error: …` and the usage to stderr and exits with 2.
    let cli = Cli::parse();
    let outcome = match &cli.command {
        Command::Build(args) => build::run(args),
        Command::Batch(args) => batch::run(args),
        Command::Demo(args) => build::run_demo(args),
        Command::Dump(args) => dump::run(args),
        Command::Verify(args) => verify::run(args),
        Command::Scatter(args) => scatter::run(args),
        Command::Render(args) => render::run(args),
        Command::View(args) => view::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Bench(args) => bench::run(args),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(failed) => ExitCode::from(failed.exit_code()),
    }
}

/// Keeps glibc's mmap threshold at its initial 128 KiB. By default glibc raises it, up to
/// 32 MiB, each time a block above it is freed; a build then takes its multi-megabyte arrays, and
/// the per-cell work of its threads its scratch arrays, from heaps where they stay resident after
/// being freed and are seldom reused whole. On the 669k-triangle maple this fixed threshold keeps
/// the peak at 117 MB (4 MiB: 125 MB; glibc's default: more than 150 MB), in the same time.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn fixed_mmap_threshold() {
    unsafe extern "C" {
        fn mallopt(param: i32, value: i32) -> i32;
    }
    const M_MMAP_THRESHOLD: i32 = -3;
    // SAFETY: `mallopt` only sets a parameter of glibc's allocator; it is called first thing in
    // `main`, before any other thread exists.
    unsafe {
        mallopt(M_MMAP_THRESHOLD, 128 << 10);
    }
}

/// Other allocators need no tuning.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn fixed_mmap_threshold() {}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    #[test]
    fn the_command_line_definition_is_consistent() {
        super::Cli::command().debug_assert();
    }
}
