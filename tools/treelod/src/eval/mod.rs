//! `treelod eval`: the measuring instrument. Renders the full mesh as the reference (supersampled,
//! box-filtered down) and every chosen technique at the same cameras, and reports per frame and in
//! total what each drew and how close its image is to the reference (pixel Precision and Recall,
//! Neubert's `Q`, multi-scale RMSE, FLIP, temporal noise) and what it cost (wall time).
//!
//! The metrics themselves are `treelod_eval`'s ([`metrics`], defined there once), camera paths in
//! [`path`], the
//! table, CSV, JSON and contact sheet in [`output`].

pub use treelod_eval::metrics;
pub(crate) mod output;
pub mod path;
pub(crate) mod plot;

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use treelod_format::{Container, ErrorClass};
use treelod_render::offscreen::{Gpu, render_prepared_timed};
use treelod_render::{Camera, FrameStats, PerTechnique, Pruning, Renderer, Settings, Technique};

use crate::render::ImpostorArgs;

use self::metrics::{Coverage, LinearImage, Mask, MultiScaleRmse, multiscale_rmse, temporal_noise};
use self::path::Pose;
use crate::render::{FRAMING_DIRECTION, clear_colour, frame_camera, parse_colour, parse_fov, parse_pixels, parse_size};
use crate::report::{self, Failed};
use crate::scene::{self, Scene};
use treelod_eval::MetricError;

/// Frames of the contact sheet at most.
const SHEET_FRAMES: usize = 4;
/// Views on each circle of `--orbit`.
const ORBIT_VIEWS: usize = 8;
/// `--approach` starts this many metres from the centre, or [`APPROACH_FAR_RADII`] bounding radii
/// if that is farther…
const APPROACH_FAR_METRES: f32 = 1000.0;
/// …(for models in units larger than metres)…
const APPROACH_FAR_RADII: f32 = 100.0;
/// …and ends this many bounding radii from the centre, inside the crown.
const APPROACH_NEAR_RADII: f32 = 0.3;
/// `--views` when no camera option is given.
const DEFAULT_VIEWS: u32 = 8;

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
    /// Point threshold `s_min` in pixels of the `spt` technique.
    #[arg(long, value_name = "PX", value_parser = parse_pixels)]
    pub s_min: Option<f32>,
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
    /// Triangle threshold `s_max` in pixels of the `spt` technique.
    #[arg(long, value_name = "PX", value_parser = parse_pixels)]
    pub s_max: Option<f32>,
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

/// What a row measures, by the name `--technique` takes: a technique of the one list
/// ([`Technique`], drawn at the image size; `full` is drawn as the reference is, supersampled and
/// box-filtered, the instrument's check), or `full-1x`, the full mesh drawn at the image size with no
/// supersampling: the aliasing floor of every technique drawn at the image size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TechniqueName {
    /// A technique of the one list.
    Technique(Technique),
    /// The full mesh at the image size.
    Full1x,
}

/// Every name `--technique` takes: the full mesh at the image size after the full mesh, then the
/// rest of [`Technique::ALL`].
const NAMES: [TechniqueName; Technique::COUNT + 1] = {
    let mut names = [TechniqueName::Full1x; Technique::COUNT + 1];
    let (mut i, mut k) = (0, 0);
    while i < Technique::COUNT {
        names[k] = TechniqueName::Technique(Technique::ALL[i]);
        k += 1;
        if matches!(Technique::ALL[i], Technique::Full) {
            k += 1;
        }
        i += 1;
    }
    names
};

impl TechniqueName {
    /// The full mesh drawn as the reference is.
    pub const FULL: Self = Self::Technique(Technique::Full);

    /// The name as `--technique` takes it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Technique(t) => t.name(),
            Self::Full1x => "full-1x",
        }
    }

    /// The technique drawn ([`Technique::Full`] for `full-1x`).
    #[must_use]
    pub fn technique(self) -> Technique {
        match self {
            Self::Technique(t) => t,
            Self::Full1x => Technique::Full,
        }
    }
}

impl clap::ValueEnum for TechniqueName {
    fn value_variants<'a>() -> &'a [Self] {
        &NAMES
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let help = match self {
            Self::Technique(Technique::Full) => "the full mesh drawn as the reference is (supersampled)",
            Self::Technique(t) => t.label(),
            Self::Full1x => "the full mesh at the image size (the aliasing floor)",
        };
        Some(clap::builder::PossibleValue::new(self.name()).help(help))
    }
}

/// Whether a technique can be measured on this input, and why not.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Availability {
    /// It is measured.
    Measured,
    /// The input holds none of the data it draws.
    Absent(String),
}

impl Availability {
    /// `measured` or `absent`.
    #[must_use]
    pub fn status(&self) -> &'static str {
        match self {
            Self::Measured => "measured",
            Self::Absent(_) => "absent",
        }
    }

    /// Why it is not measured; `None` if it is.
    #[must_use]
    pub fn reason(&self) -> Option<&str> {
        match self {
            Self::Measured => None,
            Self::Absent(r) => Some(r),
        }
    }
}

/// Whether `technique` can be measured on an input whose models hold each technique's data as
/// `held` counts them; `holder` begins the reason (`this container holds no`, `no model of the
/// scene holds`).
#[must_use]
pub fn availability(technique: TechniqueName, held: PerTechnique<usize>, holder: &str) -> Availability {
    let technique = technique.technique();
    match technique.needs() {
        Some(data) if held.get(technique) == 0 => Availability::Absent(format!("{holder} {}", data.description())),
        _ => Availability::Measured,
    }
}

/// A technique being measured: its renderer and how its images are made.
struct Measured {
    name: TechniqueName,
    renderer: Renderer,
    /// Drawn this many times larger per side, then box-filtered (the reference's factor for
    /// `full`, 1 for the rest).
    supersample: u32,
    /// The previous frame's image, for temporal noise.
    previous: Option<LinearImage>,
}

/// An image of a frame as the metrics take it.
struct Shot {
    image: LinearImage,
    mask: Mask,
    stats: FrameStats,
    prepare_ms: f64,
    gpu_ms: Option<f64>,
    wall_ms: f64,
}

/// One frame of one technique: what it drew, how close it came, what it cost.
#[derive(Clone, Debug)]
pub struct Row {
    /// Frame index along the path.
    pub frame: usize,
    /// The technique.
    pub technique: TechniqueName,
    /// What `prepare` selected and submitted.
    pub stats: FrameStats,
    /// Pixel classification against the reference.
    pub coverage: Coverage,
    /// Multi-scale RMSE against the reference.
    pub rmse: MultiScaleRmse,
    /// Mean FLIP error against the reference (both as 8-bit sRGB), 0 for identical images.
    pub flip: f64,
    /// Temporal noise: the multi-scale RMSE summary against this technique's previous frame
    /// (`None` for frame 0).
    pub noise: Option<f64>,
    /// The same for the reference.
    pub reference_noise: Option<f64>,
    /// Wall milliseconds of `prepare` alone (selection; streaming has settled).
    pub prepare_ms: f64,
    /// GPU milliseconds of the render pass from timestamp queries (`None` without them).
    pub gpu_ms: Option<f64>,
    /// Wall milliseconds of prepare + render + read-back.
    pub wall_ms: f64,
}

impl Row {
    /// Bytes of geometry records the frame reads: 24 per triangle, 48 per point and 64 per impostor
    /// plane or billboard quad submitted.
    #[must_use]
    pub fn geometry_bytes(&self) -> u64 {
        geometry_bytes(&self.stats)
    }

    /// Primitives the frame submitted: triangles, points, impostor planes and billboard quads
    /// (a splat, a plane and a billboard are each one quad).
    #[must_use]
    pub fn primitives(&self) -> u64 {
        primitives(&self.stats)
    }
}

/// Bytes of triangle, point, impostor plane, billboard, ellipsoid and line records submitted in a
/// frame.
#[must_use]
pub fn geometry_bytes(stats: &FrameStats) -> u64 {
    stats.triangles * size_of::<treelod_format::TriangleRecord>() as u64
        + stats.points * size_of::<treelod_format::PointRecord>() as u64
        + stats.planes * size_of::<treelod_format::PlaneRecord>() as u64
        + stats.billboards * size_of::<treelod_format::BillboardRecord>() as u64
        + stats.ellipsoids * size_of::<treelod_format::EllipsoidRecord>() as u64
        + stats.lines * size_of::<treelod_format::LineRecord>() as u64
}

/// Quads submitted in a frame: impostor planes and billboard quads.
#[must_use]
pub fn quads(stats: &FrameStats) -> u64 {
    stats.planes + stats.billboards
}

/// Primitives submitted in a frame, every kind ([`FrameStats::primitives`]): triangles, points,
/// [`quads`], ellipsoids and lines.
#[must_use]
pub fn primitives(stats: &FrameStats) -> u64 {
    stats.primitives()
}

/// Everything a run measured, for the outputs.
pub struct Report {
    /// The input as given.
    pub input: PathBuf,
    /// How the cameras were chosen, as the command line says it.
    pub camera_source: String,
    /// The cameras.
    pub poses: Vec<Pose>,
    /// Per camera: the scene's height on screen, pixels ([`projected_height`]).
    pub heights: Vec<f64>,
    /// Image size.
    pub size: (u32, u32),
    /// Supersampling factor of the reference.
    pub supersample: u32,
    /// MSAA samples of the techniques other than `full`.
    pub msaa: u32,
    /// Vertical field of view, degrees.
    pub fov_degrees: f32,
    /// Background, sRGB.
    pub background: [u8; 3],
    /// The adapter.
    pub adapter: Adapter,
    /// Whether the device writes timestamp queries (the `gpu_ms` figures).
    pub timestamps: bool,
    /// Every technique asked for, in order, with its availability.
    pub techniques: Vec<(TechniqueName, Availability)>,
    /// Rows, frame-major, techniques in order.
    pub rows: Vec<Row>,
    /// Contact-sheet frames: the frame, the reference, and per measured technique its image and
    /// mask, with the reference's mask.
    pub sheet: Vec<SheetFrame>,
}

/// What the adapter says of itself.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Adapter {
    /// Its name (e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`).
    pub name: String,
    /// Its backend (`Vulkan`).
    pub backend: String,
    /// Its kind (`Cpu`, `DiscreteGpu`, …).
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
}

impl Adapter {
    /// From wgpu's description.
    #[must_use]
    pub fn new(info: &wgpu::AdapterInfo) -> Self {
        Self {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_owned(),
        }
    }
}

/// One frame of the contact sheet.
pub struct SheetFrame {
    /// Frame index.
    pub frame: usize,
    /// The reference image and coverage.
    pub reference: (LinearImage, Mask),
    /// Per measured technique, its image and coverage.
    pub techniques: Vec<(TechniqueName, LinearImage, Mask)>,
}

/// Runs `treelod eval`.
pub fn run(args: &Args) -> Result<(), Failed> {
    for output in [&args.csv, &args.json, &args.sheet, &args.quality_plot, &args.frame_plot, &args.band_plot]
        .into_iter()
        .flatten()
    {
        if output.is_dir() {
            report::message_error(output, "is a directory; name the file to write");
            return Err(Failed { class: ErrorClass::Io });
        }
    }
    let scene = scene::load(&args.input).map_err(|e| crate::render::scene_failed(&e))?;
    let path_poses = match &args.path {
        Some(file) => Some(path::load(file).map_err(|(io, message)| {
            report::message_error(file, &message);
            Failed { class: if io { ErrorClass::Io } else { ErrorClass::Invalid } }
        })?),
        None => None,
    };
    let held = held_by_models(&scene)?;
    let mut techniques: Vec<(TechniqueName, Availability)> = Vec::new();
    for &name in &args.technique {
        if !techniques.iter().any(|(n, _)| *n == name) {
            let holder = if scene::is_container_path(&args.input) {
                "this container holds no"
            } else {
                "no model of the scene holds"
            };
            techniques.push((name, availability(name, held, holder)));
        }
    }
    if techniques.iter().all(|(_, a)| *a != Availability::Measured) {
        report::write_stdout(&output::unavailable(&techniques))?;
        report::message_error(&args.input, "none of the techniques asked for can be measured");
        return Err(Failed { class: ErrorClass::Unsupported });
    }
    let gpu = Gpu::new().map_err(|e| {
        report::message_error(&args.input, &format!("cannot render: {e}"));
        Failed { class: ErrorClass::Unsupported }
    })?;
    let (width, height) = args.size;
    let k = args.supersample;
    let limit = gpu.device.limits().max_texture_dimension_2d;
    if u64::from(width) * u64::from(k) > u64::from(limit) || u64::from(height) * u64::from(k) > u64::from(limit) {
        report::message_error(
            &args.input,
            &format!(
                "the reference, {width}x{height} supersampled {k} times, is larger than the device draws ({limit} pixels per side at most)"
            ),
        );
        return Err(Failed { class: ErrorClass::Unsupported });
    }

    let add = |settings: Settings, samples: u32| -> Result<(Renderer, (Vec3, Vec3)), Failed> {
        let mut renderer = Renderer::new(&gpu.device, Gpu::formats_msaa(samples), settings);
        let bounds = scene::add_to_renderer(&scene, &gpu.device, &gpu.queue, &mut renderer)
            .map_err(|e| crate::render::scene_failed(&e))?;
        Ok((renderer, bounds))
    };
    let full_settings = Settings { technique: Technique::Full, ..Settings::default() };
    let reference_settings = reference_settings();
    let (mut reference, bounds) = add(reference_settings, 1)?;
    let mut measured = Vec::new();
    for (name, availability) in &techniques {
        if *availability != Availability::Measured {
            continue;
        }
        let (settings, supersample) = match name {
            &TechniqueName::FULL => (reference_settings, k),
            TechniqueName::Full1x => (full_settings, 1),
            TechniqueName::Technique(technique) => {
                let mut settings = Settings { technique: *technique, ..Settings::default() };
                settings.s_min = args.s_min.unwrap_or(settings.s_min);
                settings.s_max = args.s_max.unwrap_or(settings.s_max);
                // The pruning techniques prune every tree at every distance (no point tree for
                // small ones), with the container's λ(h), the occlusion factor and hysteresis.
                settings.pruning = Pruning { spt_below_pixels: 0.0, ..Pruning::default() };
                // Impostors: the leaves of every tree with planes as planes, its bark as triangles.
                args.impostor.apply(&mut settings);
                // Ellipsoids: the leaves of every tree with ellipsoids as ellipsoids, its bark as
                // its branch lines where it has them (unless `--no-lines`), else as triangles.
                settings.lines = !args.no_lines;
                settings.level_blend = args.level_blend;
                (settings, 1)
            }
        };
        let samples = if *name == TechniqueName::FULL { 1 } else { args.msaa };
        measured.push(Measured { name: *name, renderer: add(settings, samples)?.0, supersample, previous: None });
    }

    let fovy = args.fov.to_radians();
    let (poses, camera_source) = cameras(args, path_poses, bounds, fovy);
    let background = clear_colour(args.background);
    let camera = |pose: &Pose, k: u32| Camera::look_at(pose.eye, pose.target, fovy, width * k, height * k);
    // Images and masks of one run always match in size; a mismatch is a bug, reported as such.
    let internal = |e: MetricError| {
        report::message_error(&args.input, &format!("internal error: {e}"));
        Failed { class: ErrorClass::Io }
    };
    let shoot = |renderer: &mut Renderer, pose: &Pose, k: u32| -> Result<Shot, Failed> {
        let camera = camera(pose, k);
        crate::render::settle_streaming(&gpu, renderer, &camera);
        // One prepare per frame, as a host makes it; the wall clock runs over prepare, render and
        // read-back.
        let start = Instant::now();
        let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
        gpu.queue.submit([]);
        let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
        let (image, gpu_ms) = render_prepared_timed(&gpu, renderer, &camera, background).map_err(|e| {
            report::message_error(&args.input, &format!("cannot render: {e}"));
            Failed { class: ErrorClass::Io }
        })?;
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let (image, mask) = measurable(&image, k, args.background).map_err(internal)?;
        Ok(Shot { image, mask, stats, prepare_ms, gpu_ms, wall_ms })
    };

    // Warm up every renderer once (shader compilation happens at the first draw) so the first
    // frame's time is not the compiler's.
    if let Some(first) = poses.first() {
        shoot(&mut reference, first, k)?;
        for m in &mut measured {
            shoot(&mut m.renderer, first, m.supersample)?;
        }
    }
    let sheet_frames = sheet_frames(poses.len());
    let progress = progress_bar(poses.len() as u64);
    let mut rows = Vec::with_capacity(poses.len() * measured.len());
    let mut sheet = Vec::new();
    let mut previous_reference: Option<LinearImage> = None;
    for (frame, pose) in poses.iter().enumerate() {
        progress.set_position(frame as u64);
        let reference_shot = shoot(&mut reference, pose, k)?;
        let reference_noise = match &previous_reference {
            Some(previous) => Some(temporal_noise(&reference_shot.image, previous).map_err(internal)?),
            None => None,
        };
        let mut sheet_techniques = Vec::new();
        for m in &mut measured {
            let shot = shoot(&mut m.renderer, pose, m.supersample)?;
            let coverage = Coverage::compare(&reference_shot.mask, &shot.mask).map_err(internal)?;
            let rmse = multiscale_rmse(&shot.image, &reference_shot.image).map_err(internal)?;
            let flip = metrics::flip::mean_flip(&shot.image, &reference_shot.image).map_err(internal)?;
            let noise = match &m.previous {
                Some(previous) => Some(temporal_noise(&shot.image, previous).map_err(internal)?),
                None => None,
            };
            rows.push(Row {
                frame,
                technique: m.name,
                stats: shot.stats,
                coverage,
                rmse,
                flip,
                noise,
                reference_noise,
                prepare_ms: shot.prepare_ms,
                gpu_ms: shot.gpu_ms,
                wall_ms: shot.wall_ms,
            });
            if args.sheet.is_some() && sheet_frames.contains(&frame) {
                sheet_techniques.push((m.name, shot.image.clone(), shot.mask));
            }
            m.previous = Some(shot.image);
        }
        if args.sheet.is_some() && sheet_frames.contains(&frame) {
            sheet.push(SheetFrame {
                frame,
                reference: (reference_shot.image.clone(), reference_shot.mask),
                techniques: sheet_techniques,
            });
        }
        previous_reference = Some(reference_shot.image);
    }
    progress.finish_and_clear();

    let heights = poses.iter().map(|pose| projected_height(bounds, pose, fovy, height)).collect();
    let report = Report {
        input: args.input.clone(),
        camera_source,
        poses,
        heights,
        size: args.size,
        supersample: k,
        msaa: args.msaa,
        fov_degrees: args.fov,
        background: args.background,
        adapter: Adapter::new(&gpu.info),
        timestamps: gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY),
        techniques,
        rows,
        sheet,
    };
    if let Some(csv) = &args.csv {
        report::write_atomically(csv, output::csv(&report).as_bytes())?;
    }
    if let Some(json) = &args.json {
        crate::render::write_json(json, output::json(&report))?;
    }
    if let Some(sheet) = &args.sheet {
        crate::render::write_png(sheet, &output::contact_sheet(&report))?;
    }
    for (file, draw) in [
        (&args.quality_plot, plot::quality_vs_primitives as fn(&Report) -> treelod_render::offscreen::Image),
        (&args.frame_plot, plot::per_frame),
        (&args.band_plot, plot::by_band),
    ] {
        if let Some(file) = file {
            crate::render::write_png(file, &draw(&report))?;
        }
    }
    report::write_stdout(&output::text(
        &report,
        [&args.csv, &args.json, &args.sheet, &args.quality_plot, &args.frame_plot, &args.band_plot],
    ))
}

/// The reference's renderer settings, for `eval` and `bench --quality`: the full mesh, keeping
/// the leaves' coverage where their textures are minified. The plain alpha test drops every texel
/// less than half covered, so thin leaves vanish from a distant crown even at 4× (the maple at 32
/// bounding radii kept 60 % of the darkening that alpha to coverage keeps). Each of its pixels is
/// still leaf or background (a stochastic test), so the box filter of [`measurable`] averages the
/// coverage and the majority mask stays binary.
pub(crate) fn reference_settings() -> Settings {
    Settings { technique: Technique::Full, stochastic_alpha: true, ..Settings::default() }
}

/// A read-back image as the metrics take it: linear colour box-filtered over `k`×`k` blocks, and
/// coverage (pixels not exactly `background`) by the majority of each block.
///
/// # Errors
/// [`MetricError`] if the image's pixels do not match its size or `k` does not divide it.
pub(crate) fn measurable(
    image: &treelod_render::offscreen::Image,
    k: u32,
    background: [u8; 3],
) -> Result<(LinearImage, Mask), MetricError> {
    let linear = LinearImage::from_srgba8(image.width, image.height, &image.rgba)?;
    let mask = Mask::from_srgba8(image.width, image.height, &image.rgba, background)?;
    Ok((linear.box_filter(k)?, mask.reduce_majority(k)?))
}

/// How many of the scene's models hold each technique's data (each opened and checked as every
/// reader does).
fn held_by_models(scene: &Scene) -> Result<PerTechnique<usize>, Failed> {
    let containers = scene
        .models
        .iter()
        .map(|model| Container::open(model).map_err(|e| report::file_error(model, &e)))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(PerTechnique::held_by(&containers))
}

/// The height on screen, pixels, of the scene's bounds seen from `pose` in an image `image_height`
/// pixels high with a vertical field of view of `fovy` radians: the bounds' vertical extent over
/// the distance from the eye to their centre, times the focal length in pixels. For one tree this
/// is the tree's projected height, the size the bands of eval's summary (and a level-of-detail
/// policy) are measured in.
#[must_use]
pub fn projected_height(bounds: (Vec3, Vec3), pose: &Pose, fovy: f32, image_height: u32) -> f64 {
    let focal = f64::from(image_height) / (2.0 * f64::from((0.5 * fovy).tan()).max(1e-9));
    let distance = f64::from(pose.eye.distance(0.5 * (bounds.0 + bounds.1))).max(1e-6);
    f64::from(bounds.1.y - bounds.0.y) * focal / distance
}

/// The cameras the arguments ask for, and how to say where they came from.
fn cameras(args: &Args, path_poses: Option<Vec<Pose>>, bounds: (Vec3, Vec3), fovy: f32) -> (Vec<Pose>, String) {
    let (width, height) = args.size;
    let framing = frame_camera(bounds, None, None, fovy, width, height);
    let target = 0.5 * (bounds.0 + bounds.1);
    if let Some(poses) = path_poses {
        let source = args.path.as_ref().map(|p| format!("--path {}", p.display())).unwrap_or_default();
        return (poses, source);
    }
    // The bounding radius as `render` frames it: the half diagonal of the bounds.
    let radius = (0.5 * (bounds.1 - bounds.0)).length().max(0.1);
    if let Some(count) = args.approach {
        let (far, near) = (APPROACH_FAR_METRES.max(APPROACH_FAR_RADII * radius), APPROACH_NEAR_RADII * radius);
        let poses = path::approach(target, FRAMING_DIRECTION, far, near, count as usize);
        return (poses, format!("--approach {count}: {far:.0} to {near:.2} from the centre"));
    }
    if let Some(Distances(distances)) = &args.orbit {
        let poses =
            distances.iter().flat_map(|d| path::circle(target, FRAMING_DIRECTION, d * radius, ORBIT_VIEWS)).collect();
        let list: Vec<String> = distances.iter().map(f32::to_string).collect();
        return (poses, format!("--orbit {}", list.join(",")));
    }
    let views = args.views.unwrap_or(DEFAULT_VIEWS);
    let distance = framing.position.distance(target);
    (path::circle(target, FRAMING_DIRECTION, distance, views as usize), format!("--views {views}"))
}

/// Up to [`SHEET_FRAMES`] frames spread evenly over `count`, first and last included.
fn sheet_frames(count: usize) -> Vec<usize> {
    if count <= SHEET_FRAMES {
        return (0..count).collect();
    }
    // round(i · (count − 1) / (SHEET_FRAMES − 1))
    let steps = SHEET_FRAMES - 1;
    let mut frames: Vec<usize> = (0..SHEET_FRAMES).map(|i| (2 * i * (count - 1) + steps) / (2 * steps)).collect();
    frames.dedup();
    frames
}

/// A progress bar on stderr (drawn only on a terminal).
fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} eval [frame {pos}/{len}] {elapsed}") {
        bar.set_style(style);
    }
    bar
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONTAINER: &str = "this container holds no";
    const SCENE: &str = "no model of the scene holds";

    #[test]
    fn techniques_whose_data_is_missing_are_reported_not_skipped() {
        let none = PerTechnique::<usize>::default();
        assert_eq!(availability(TechniqueName::Technique(Technique::Spt), none, CONTAINER), Availability::Measured);
        assert_eq!(availability(TechniqueName::Full1x, none, CONTAINER), Availability::Measured);
        assert_eq!(
            availability(TechniqueName::Technique(Technique::Ellipsoids), none, CONTAINER),
            Availability::Absent(
                "this container holds no ellipsoids (build with --ellipsoids, and --lines for the bark)".to_owned()
            )
        );
        assert_eq!(
            availability(TechniqueName::Technique(Technique::Impostors), none, SCENE).reason(),
            Some("no model of the scene holds impostor planes (build with --impostors)")
        );
        assert_eq!(
            availability(TechniqueName::Technique(Technique::Crossed), none, CONTAINER).reason(),
            Some("this container holds no baseline billboards (build with --baselines)")
        );
        let some = PerTechnique([1; Technique::COUNT]);
        for t in Technique::ALL {
            assert_eq!(availability(TechniqueName::Technique(t), some, CONTAINER), Availability::Measured);
            let expected = if t.needs().is_some() { "absent" } else { "measured" };
            assert_eq!(availability(TechniqueName::Technique(t), none, CONTAINER).status(), expected);
        }
    }

    #[test]
    fn every_technique_of_the_one_list_is_a_name_and_full_1x_follows_full() {
        use clap::ValueEnum as _;
        let names: Vec<&str> = TechniqueName::value_variants().iter().map(|n| n.name()).collect();
        assert_eq!(names.len(), Technique::COUNT + 1);
        assert_eq!(&names[..3], ["full", "full-1x", "spt"]);
        for t in Technique::ALL {
            assert!(names.contains(&t.name()), "{t}");
            assert_eq!(TechniqueName::from_str(t.name(), false), Ok(TechniqueName::Technique(t)));
        }
        assert_eq!(TechniqueName::from_str("full-1x", false), Ok(TechniqueName::Full1x));
        assert!(TechniqueName::from_str("policy", false).is_err());
    }

    #[test]
    fn the_projected_height_halves_with_twice_the_distance() {
        let bounds = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 10.0, 1.0));
        let at = |d: f32| Pose { eye: Vec3::new(0.0, 5.0, d), target: Vec3::new(0.0, 5.0, 0.0) };
        // 90° field of view: the focal length is half the image height, 240 px for 480.
        let fovy = std::f32::consts::FRAC_PI_2;
        let h = projected_height(bounds, &at(20.0), fovy, 480);
        assert!((h - 10.0 * 240.0 / 20.0).abs() < 1e-3, "{h}");
        assert!((projected_height(bounds, &at(40.0), fovy, 480) - h / 2.0).abs() < 1e-3);
    }

    #[test]
    fn the_sheet_spreads_its_frames_over_the_path() {
        assert_eq!(sheet_frames(0), Vec::<usize>::new());
        assert_eq!(sheet_frames(3), [0, 1, 2]);
        assert_eq!(sheet_frames(24), [0, 8, 15, 23]);
        assert_eq!(sheet_frames(5), [0, 1, 3, 4]);
    }
}
