//! `treelod eval`: the command line of the measuring instrument, [`treelod_harness::eval`]. This
//! module turns the arguments into [`Options`], shows a progress bar, prints the report and
//! writes the files asked for; the measuring, the report and its outputs are the harness's.

use std::path::PathBuf;

pub use treelod_harness::eval::*;

use crate::render::ImpostorArgs;
use crate::render::{parse_colour, parse_fov, parse_size};
use crate::report::{self, Failed};

/// Arguments of `treelod eval`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A `.treelod` container (drawn once at the origin) or a JSON scene file.
    #[arg(value_name = "FILE|SCENE")]
    pub input: PathBuf,
    /// N directions around the model on a circle (at the framing elevation), each at the distance
    /// that frames it [default: 8 when no camera option is given].
    #[arg(long, value_name = "N", conflicts_with_all = ["orbit", "path"],
          value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub views: Option<u32>,
    /// 8 views on a circle at each distance, in bounding radii of the scene (e.g. `2,6,20`).
    #[arg(long, value_name = "D1,D2,…", conflicts_with = "path", value_parser = parse_orbit)]
    pub orbit: Option<Distances>,
    /// N cameras flying in from afar to inside the crown: along the framing direction towards the
    /// centre of the bounds, from 1 km (or 100 bounding radii, if farther) to 0.3 bounding radii,
    /// each frame the same fraction closer. Temporal noise along it shows pops.
    #[arg(long, value_name = "N", conflicts_with_all = ["views", "orbit", "path"],
          value_parser = clap::value_parser!(u32).range(2..=100_000))]
    pub approach: Option<u32>,
    /// A camera path file: a JSON array of `{"eye": [x, y, z], "target": [x, y, z]}`.
    #[arg(long, value_name = "FILE")]
    pub path: Option<PathBuf>,
    /// Techniques to measure, separated by commas. Those not available are reported as absent.
    #[arg(long, value_name = "NAMES", value_enum, value_delimiter = ',', default_values = ["full", "full-1x", "spt"])]
    pub technique: Vec<TechniqueName>,
    /// Image size in pixels, `WIDTHxHEIGHT`.
    #[arg(long, value_name = "WxH", default_value = "640x480", value_parser = parse_size)]
    pub size: (u32, u32),
    /// The reference is drawn K times larger per side and box-filtered down.
    #[arg(long, value_name = "K", default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub supersample: u32,
    /// Vertical field of view in degrees.
    #[arg(long, value_name = "DEGREES", default_value_t = 50.0, value_parser = parse_fov)]
    pub fov: f32,
    /// Background colour, `RRGGBB` (sRGB hex): pixels of this colour count as not covered.
    #[arg(long, value_name = "RRGGBB", default_value = "ffffff", value_parser = parse_colour)]
    pub background: [u8; 3],
    /// MSAA samples (1 or 4) of every technique but `full` (drawn as the reference is); with 4,
    /// alpha-tested leaves cover samples in proportion to their filtered alpha (alpha to coverage).
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = crate::render::parse_msaa)]
    pub msaa: u32,
    #[command(flatten)]
    pub thresholds: crate::render::ThresholdArgs,
    // How the `impostors` technique changes level and draws its bark, as `render`'s options.
    #[command(flatten)]
    pub impostor: ImpostorArgs,
    /// The `ellipsoids` technique draws the bark as triangles even where the container has
    /// branch lines (by default as those lines).
    #[arg(long)]
    pub no_lines: bool,
    /// The `ellipsoids` technique blends ellipsoids and lines from one level to the next over
    /// this many octaves of the metres per pixel, as `render`'s option; 0 switches at once.
    #[arg(long, value_name = "OCTAVES", default_value_t = 0.5, value_parser = crate::render::parse_level_blend)]
    pub level_blend: f32,
    /// The `policy` technique's target: the image error (multi-scale RMSE, as the calibration measures it) it allows
    /// over the floor (the least error of the full mesh and every representation) at each tree's
    /// projected size (up to 64 pixels; a taller tree `h` pixels high: `target · 64 / h`), as the
    /// containers' calibration tables measured it; 0 keeps the best image the tables know.
    #[arg(long, value_name = "ERROR", default_value_t = treelod_render::Policy::DEFAULT_TARGET, value_parser = crate::render::parse_target)]
    pub policy_target: f32,
    /// The `prune-opt` and `prune-cook` techniques keep this fixed fraction λ of each cell's
    /// leaves (most important first, scaled by s_opt or 1/λ) on every tree at every distance,
    /// instead of the container's λ(h): both at equal geometry, or, over several runs, the λ
    /// each needs to reach a quality (Neubert et al.'s comparison).
    #[arg(long, value_name = "LAMBDA", value_parser = crate::render::parse_fraction)]
    pub prune_lambda: Option<f32>,
    /// Write one CSV row per frame and technique.
    #[arg(long, value_name = "PATH")]
    pub csv: Option<PathBuf>,
    /// Write a JSON summary.
    #[arg(long, value_name = "PATH")]
    pub json: Option<PathBuf>,
    /// Write a PNG contact sheet: per frame (up to 4), the reference, then each technique and its
    /// difference.
    #[arg(long, value_name = "PATH")]
    pub sheet: Option<PathBuf>,
    /// Write a PNG plot of quality Q against primitives drawn: a dot per frame and technique, a
    /// large one at each technique's mean.
    #[arg(long, value_name = "PATH")]
    pub quality_plot: Option<PathBuf>,
    /// Write a PNG plot of per-frame curves along the path: Q, multi-scale RMSE, primitives drawn
    /// and temporal noise (the reference's beside it).
    #[arg(long, value_name = "PATH")]
    pub frame_plot: Option<PathBuf>,
    /// Write a PNG plot of multi-scale RMSE against primitives drawn, one panel per band of the
    /// scene's projected height in pixels (as the table's summary by band): the picture a
    /// representation is chosen from at each size on screen.
    #[arg(long, value_name = "PATH")]
    pub band_plot: Option<PathBuf>,
}

/// `--orbit`'s distances, in bounding radii.
#[derive(Clone, Debug, PartialEq)]
pub struct Distances(pub Vec<f32>);

fn parse_orbit(s: &str) -> Result<Distances, String> {
    path::parse_distances(s).map(Distances)
}

impl Args {
    /// The harness's options for these arguments.
    #[must_use]
    pub fn options(&self) -> Options {
        let cameras = if let Some(file) = &self.path {
            Cameras::Path(file.clone())
        } else if let Some(count) = self.approach {
            Cameras::Approach(count)
        } else if let Some(Distances(distances)) = &self.orbit {
            Cameras::Orbit(distances.clone())
        } else {
            Cameras::Views(self.views.unwrap_or(8))
        };
        let mut settings = treelod_render::Settings::default();
        self.impostor.apply(&mut settings);
        Options {
            input: self.input.clone(),
            cameras,
            techniques: self.technique.clone(),
            size: self.size,
            supersample: self.supersample,
            fov_degrees: self.fov,
            background: self.background,
            msaa: self.msaa,
            s_min: self.thresholds.s_min,
            s_max: self.thresholds.s_max,
            impostor_morph: settings.impostor_morph,
            impostor_bark: settings.impostor_bark,
            lines: !self.no_lines,
            level_blend: self.level_blend,
            policy: treelod_render::Policy { target: self.policy_target, ..treelod_render::Policy::default() },
            prune_lambda: self.prune_lambda,
            sheet: self.sheet.is_some(),
        }
    }

    /// The files to write, in the order the report lists them.
    fn outputs(&self) -> [&Option<PathBuf>; 6] {
        [&self.csv, &self.json, &self.sheet, &self.quality_plot, &self.frame_plot, &self.band_plot]
    }
}

/// Runs `treelod eval`.
pub fn run(args: &Args) -> Result<(), Failed> {
    if args.prune_lambda.is_some() && !args.technique.iter().any(|t| t.prunes()) {
        clap::Error::raw(
            clap::error::ErrorKind::ArgumentConflict,
            "--prune-lambda needs prune-opt or prune-cook among --technique\n",
        )
        .exit();
    }
    treelod_harness::write::check_outputs(args.outputs().into_iter().flatten().map(PathBuf::as_path))
        .map_err(|e| failed(&e))?;
    let progress = progress_bar();
    let result = run_with_progress(&args.options(), &mut |frame, frames| {
        progress.set_length(frames as u64);
        progress.set_position(frame as u64);
    });
    progress.finish_and_clear();
    let report = match result {
        Ok(report) => report,
        Err(e) => {
            none_measurable(&e)?;
            return Err(failed(&e));
        }
    };
    let written: [(&Option<PathBuf>, Writer); 6] = [
        (&args.csv, Report::write_csv),
        (&args.json, Report::write_json),
        (&args.sheet, Report::write_sheet),
        (&args.quality_plot, Report::write_quality_plot),
        (&args.frame_plot, Report::write_frame_plot),
        (&args.band_plot, Report::write_band_plot),
    ];
    for (file, write) in written {
        if let Some(file) = file {
            write(&report, file).map_err(|e| failed(&e))?;
        }
    }
    report::write_stdout(&report.text(args.outputs()))
}

/// Prints a harness error as `error: PATH: reason` and returns its class.
pub fn failed(error: &treelod_harness::Error) -> Failed {
    use treelod_harness::Error;
    match error {
        Error::Container { path, source } | Error::Write { path, source } => report::file_error(path, source),
        Error::Build { path, source } => report::build_error(path, source),
        other => {
            report::print_error(&other.to_string());
            Failed { class: other.class() }
        }
    }
}

/// Writes one of the report's files.
type Writer = fn(&Report, &std::path::Path) -> Result<(), treelod_harness::Error>;

/// A progress bar on stderr (drawn only on a terminal).
fn progress_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(0);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} eval [frame {pos}/{len}] {elapsed}") {
        bar.set_style(style);
    }
    bar
}

/// Before the error of a run that could measure nothing, the techniques asked for and why each
/// is absent, on stdout.
pub fn none_measurable(error: &treelod_harness::Error) -> Result<(), Failed> {
    if let treelod_harness::Error::NoneMeasurable { absent, .. } = error {
        report::write_stdout(absent)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use treelod_harness::Technique;

    #[test]
    fn every_technique_of_the_one_list_is_a_name_and_full_1x_follows_full() {
        use clap::ValueEnum as _;
        let names: Vec<&str> = TechniqueName::value_variants().iter().map(|n| n.name()).collect();
        assert_eq!(names.len(), Technique::COUNT + 2);
        assert_eq!(&names[..3], ["full", "full-1x", "spt"]);
        for t in Technique::ALL {
            assert!(names.contains(&t.name()), "{t}");
            assert_eq!(TechniqueName::from_str(t.name(), false), Ok(TechniqueName::Technique(t)));
        }
        assert_eq!(TechniqueName::from_str("full-1x", false), Ok(TechniqueName::Full1x));
        assert_eq!(TechniqueName::from_str("policy", false), Ok(TechniqueName::Policy));
    }
}
