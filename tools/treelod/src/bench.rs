//! `treelod bench`: the command line of the fly-through benchmark, [`treelod_harness::bench`].
//! This module turns the arguments into [`bench::Options`], shows a progress bar, prints the
//! report and writes the files asked for; the forest, the path, the measuring and the outputs are
//! the harness's.

use std::path::PathBuf;

use treelod_harness::bench::{self, Options, Quality, Report};
use treelod_harness::eval::TechniqueName;
use treelod_render::Policy;

use crate::eval::{failed, none_measurable};
use crate::render::{parse_colour, parse_fov, parse_size};
use crate::report::{self, Failed};

/// Arguments of `treelod bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Containers, or scene files whose models are used; the forest is made of these models.
    /// None: built-in demo trees of four shapes, built in memory.
    #[arg(value_name = "FILE|SCENE")]
    pub inputs: Vec<PathBuf>,
    /// Trees in the forest (the paper: 10,000; 1,000,000 measures selection at scale, best with
    /// --no-render).
    #[arg(long, value_name = "N", default_value_t = 10_000,
          value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub trees: u64,
    /// Frames along the path (the paper: 1440).
    #[arg(long, value_name = "N", default_value_t = 360,
          value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// Image size in pixels, `WIDTHxHEIGHT`.
    #[arg(long, value_name = "WxH", default_value = "1536x864", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Seed of the forest's layout.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
    /// Vertical field of view in degrees.
    #[arg(long, value_name = "DEGREES", default_value_t = 50.0, value_parser = parse_fov)]
    pub fov: f32,
    /// Techniques to fly, separated by commas; those not available are reported, not skipped.
    /// full is counted, not drawn; full-1x draws the full mesh at the image size; policy flies
    /// the renderer's default (per tree the cheapest representation within --policy-target,
    /// from the containers' calibration tables).
    #[arg(long, value_name = "NAMES", value_enum, value_delimiter = ',', default_values = ["full", "spt"])]
    pub technique: Vec<TechniqueName>,
    /// The policy's target: image error (multi-scale RMSE, as the calibration measures it) allowed over the full
    /// mesh's at each tree's projected height (up to 64 pixels; a taller tree `h` pixels high:
    /// `target · 64 / h`), 0 to 1; with --budget, where the steering starts.
    #[arg(long, value_name = "ERROR", default_value_t = Policy::DEFAULT_TARGET, value_parser = crate::render::parse_target)]
    pub policy_target: f32,
    /// The policy's budget mode: primitives per frame to aim for (the camera's view). The
    /// target and s_min are steered together from frame to frame to meet it (the same error
    /// allowance over the floor on every tree); applies to `policy` only.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub budget: Option<u64>,
    /// Frames over which a tree that changes technique fades from the old one to the new one
    /// on complementary dithered pixels (drawn with both meanwhile: CSV column `transitions`);
    /// 0 or 1: switch at once. Default: the renderer's 15 frames scaled by --frames / 1440, the
    /// same share of the path as a quarter of a second of the paper's one-minute 1440-frame
    /// flight (4 frames at the default 360, 15 at 1440; below 144 trees switch at once), since fewer frames sample the same
    /// path more coarsely. Applies to `policy` only.
    #[arg(long, value_name = "FRAMES",
          value_parser = clap::value_parser!(u32).range(0..=i64::from(Policy::MAX_TRANSITION)))]
    pub transition: Option<u32>,
    /// The policy chooses every tree as fully visible: no occlusion measurement (by default each
    /// drawn tree's visible fraction is measured from the frame's depth and a partly hidden tree
    /// is chosen with the target over the square root of it). Applies to `policy` only.
    #[arg(long)]
    pub no_occlusion: bool,
    /// Select and stream only: no image is drawn, so there is no GPU time (the figure for large
    /// forests on a software rasteriser).
    #[arg(long, conflicts_with = "quality")]
    pub no_render: bool,
    /// Select the point tree on the GPU for `spt` and `policy` (compute shaders write the draws:
    /// `Renderer::enable_gpu_selection`, every model resident whole; with `policy` the CPU still
    /// chooses every tree's technique and selects the other techniques' trees); the GPU's counts
    /// are then those of a frame read back one or two frames earlier, and the selection time is
    /// that of `prepare`'s CPU work and submitting the compute work.
    #[arg(long)]
    pub gpu_selection: bool,
    /// Cast shadows: every technique the renderer flies also selects and draws three 2048²
    /// shadow cascades of the sun over the first 150 m (`Settings::shadows`, the defaults), and
    /// each frame records the primitives of that shadow pass (CSV column `shadow_primitives`).
    /// The full mesh is counted, not drawn, so it has none; `--gpu-selection` frames are then
    /// selected on the CPU.
    #[arg(long)]
    pub shadows: bool,
    /// Also draw the full mesh as the reference at every frame and measure each technique's
    /// image against it: P, R, Q, multi-scale RMSE and mean FLIP error, and from the second frame
    /// the temporal noise of each image and of the reference (slow: the full mesh of every tree
    /// in view). The reference is `treelod eval`'s: supersampled, box-filtered, with the
    /// stochastic alpha test that keeps minified leaves' coverage.
    #[arg(long)]
    pub quality: bool,
    /// With --quality, the reference is drawn K times larger per side and box-filtered down.
    #[arg(long, value_name = "K", default_value_t = 4, requires = "quality",
          value_parser = clap::value_parser!(u32).range(1..=16))]
    pub supersample: u32,
    /// With --quality, the reference of earlier versions instead: the full mesh drawn at the image
    /// size with the plain alpha test (aliased: thin leaves drop out of it).
    #[arg(long, requires = "quality", conflicts_with = "supersample")]
    pub reference_1x: bool,
    #[command(flatten)]
    pub thresholds: crate::render::ThresholdArgs,
    /// Background colour, `RRGGBB` (sRGB hex): with --quality, pixels of it count as not covered.
    #[arg(long, value_name = "RRGGBB", default_value = "ffffff", value_parser = parse_colour)]
    pub background: [u8; 3],
    /// Write one CSV row per frame and technique.
    #[arg(long, value_name = "PATH")]
    pub csv: Option<PathBuf>,
    /// Write a JSON summary.
    #[arg(long, value_name = "PATH")]
    pub json: Option<PathBuf>,
    /// Write a PNG plot: primitives per frame per technique (log scale), selection and GPU
    /// milliseconds, and Q with --quality, along the path.
    #[arg(long, value_name = "PATH")]
    pub plot: Option<PathBuf>,
    /// With --quality, write a PNG contact sheet: per frame of --sheet-frames a row of the
    /// reference, then each technique drawn and its difference (red: false positive pixels,
    /// blue: false negatives, grey: colour error ×4), as `treelod eval --sheet` lays it out.
    #[arg(long, value_name = "PATH", requires = "quality")]
    pub sheet: Option<PathBuf>,
    /// The contact sheet's frames, indices along the path separated by commas (the CSV's
    /// `frame`), at most 8; default: 4 spread over the path, first and last included.
    #[arg(long, value_name = "FRAMES", value_delimiter = ',', requires = "sheet")]
    pub sheet_frames: Vec<usize>,
}

impl Args {
    /// The harness's options for these arguments.
    #[must_use]
    pub fn options(&self) -> Options {
        let quality = match (self.quality, self.reference_1x) {
            (false, _) => None,
            (true, true) => Some(Quality::Plain1x),
            (true, false) => Some(Quality::Supersampled(self.supersample)),
        };
        Options {
            inputs: self.inputs.clone(),
            trees: self.trees,
            frames: self.frames,
            size: self.size,
            seed: self.seed,
            fov_degrees: self.fov,
            techniques: self.technique.clone(),
            policy: Policy {
                target: self.policy_target,
                budget: self.budget,
                transition: self.transition.unwrap_or_else(|| path_transition(self.frames)),
                occlusion: !self.no_occlusion,
                ..Policy::default()
            },
            render: !self.no_render,
            gpu_selection: self.gpu_selection,
            shadows: self.shadows,
            quality,
            s_min: self.thresholds.s_min,
            s_max: self.thresholds.s_max,
            background: self.background,
            sheet_frames: match (&self.sheet, self.sheet_frames.is_empty()) {
                (None, _) => Vec::new(),
                (Some(_), true) => treelod_harness::eval::spread_frames(self.frames as usize, 4),
                (Some(_), false) => self.sheet_frames.clone(),
            },
        }
    }
}

/// Runs `treelod bench`.
pub fn run(args: &Args) -> Result<(), Failed> {
    let outputs = [&args.csv, &args.json, &args.plot, &args.sheet];
    treelod_harness::write::check_outputs(outputs.into_iter().flatten().map(PathBuf::as_path))
        .map_err(|e| failed(&e))?;
    let progress = progress_bar();
    report::set_progress_bar(Some(progress.clone()));
    let result = bench::run_with_progress(&args.options(), &mut |frame, frames| {
        progress.set_length(frames as u64);
        progress.set_position(frame as u64);
    });
    progress.finish_and_clear();
    report::set_progress_bar(None);
    let report = match result {
        Ok(report) => report,
        Err(e) => {
            none_measurable(&e)?;
            return Err(failed(&e));
        }
    };
    let written: [(&Option<PathBuf>, Writer); 4] = [
        (&args.csv, Report::write_csv),
        (&args.json, Report::write_json),
        (&args.plot, Report::write_plot),
        (&args.sheet, Report::write_sheet),
    ];
    for (file, write) in written {
        if let Some(file) = file {
            write(&report, file).map_err(|e| failed(&e))?;
        }
    }
    report::write_stdout(&report.text(outputs))
}

/// Writes one of the report's files.
type Writer = fn(&Report, &std::path::Path) -> Result<(), treelod_harness::Error>;

/// A progress bar on stderr (drawn only on a terminal).
fn progress_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(0);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} bench [frame {pos}/{len}] {elapsed}") {
        bar.set_style(style);
    }
    bar
}

/// The default `--transition` of a path flown in `frames` frames: the renderer's
/// [`Policy::DEFAULT_TRANSITION`] frames scaled to the paper's 1440-frame path, rounded.
fn path_transition(frames: u32) -> u32 {
    let scaled = (u64::from(Policy::DEFAULT_TRANSITION) * u64::from(frames) + 720) / 1440;
    u32::try_from(scaled).unwrap_or(u32::MAX).min(Policy::MAX_TRANSITION)
}

#[cfg(test)]
mod tests {
    use clap::Parser as _;

    use super::*;

    #[derive(Debug, clap::Parser)]
    struct BenchCli {
        #[command(flatten)]
        args: Args,
    }

    #[test]
    fn every_technique_of_the_one_list_is_a_name_and_the_options_follow_the_arguments() {
        let names: Vec<&str> = TechniqueName::ALL.iter().map(|t| t.name()).collect();
        let args = BenchCli::try_parse_from(["bench", "--technique", &names.join(",")]).expect("parses").args;
        assert_eq!(args.technique, TechniqueName::ALL);
        // The renderer's transition scaled to the path: 4 frames of the default 360.
        let policy = Policy { transition: 4, ..Policy::default() };
        assert_eq!(args.options(), Options { techniques: TechniqueName::ALL.to_vec(), policy, ..Options::default() });
        assert_eq!([143, 144, 360, 1440, 100_000].map(path_transition), [1, 2, 4, 15, 600]);
        let args = BenchCli::try_parse_from(["bench", "--transition", "0"]).expect("parses").args;
        assert_eq!(args.options().policy.transition, 0);
        let args =
            BenchCli::try_parse_from(["bench", "--technique", "policy", "--policy-target", "0.02", "--budget", "9000"])
                .expect("parses")
                .args;
        let policy = Policy { target: 0.02, budget: Some(9000), transition: 4, ..Policy::default() };
        assert_eq!(args.options().policy, policy);
        assert!(BenchCli::try_parse_from(["bench", "--budget", "0"]).is_err(), "a budget of 0 primitives");
        let args = BenchCli::try_parse_from(["bench", "--quality", "--reference-1x", "--no-render"]);
        assert!(args.is_err(), "--no-render conflicts with --quality");
        let args = BenchCli::try_parse_from(["bench", "--quality", "--supersample", "2"]).expect("parses").args;
        assert_eq!(args.options().quality, Some(Quality::Supersampled(2)));
        // The contact sheet: 4 frames spread over the path unless named; it needs --quality.
        let args = BenchCli::try_parse_from(["bench", "--frames", "30", "--quality", "--sheet", "s.png"]);
        assert_eq!(args.expect("parses").args.options().sheet_frames, [0, 10, 19, 29]);
        let args = ["bench", "--quality", "--sheet", "s.png", "--sheet-frames", "13,19"];
        assert_eq!(BenchCli::try_parse_from(args).expect("parses").args.options().sheet_frames, [13, 19]);
        assert!(BenchCli::try_parse_from(["bench", "--sheet", "s.png"]).is_err(), "--sheet without --quality");
        assert!(BenchCli::try_parse_from(["bench", "--quality", "--sheet-frames", "1"]).is_err(), "no --sheet");
    }
}
