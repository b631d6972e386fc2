//! `treelod eval`: the measuring instrument. Renders the full mesh as the reference (supersampled,
//! box-filtered down) and every chosen technique at the same cameras, and reports per frame and in
//! total what each drew and how close its image is to the reference (pixel Precision and Recall,
//! Neubert's `Q`, multi-scale RMSE, FLIP, temporal noise) and what it cost (wall time).
//!
//! The metrics themselves are `treelod_eval`'s ([`metrics`], defined there once), camera paths in
//! [`path`], the
//! table, CSV, JSON and contact sheet in [`output`].

pub use treelod_eval::metrics;
pub mod output;
pub mod path;
pub mod plot;

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use treelod_format::Container;
use treelod_render::offscreen::{Gpu, render_prepared_timed};
use treelod_render::{
    Camera, FrameStats, ImpostorBark, PerTechnique, Policy, Primitive, Pruning, Renderer, Settings, Technique,
};

use self::metrics::{Coverage, LinearImage, Mask, MultiScaleRmse, multiscale_rmse, temporal_noise};
use self::path::Pose;
use crate::Error;
use crate::offscreen::{FRAMING_DIRECTION, clear_colour, frame_camera, settle_streaming};
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

/// Where the cameras of a run stand.
#[derive(Clone, Debug, PartialEq)]
pub enum Cameras {
    /// N cameras on a circle around the scene (at the framing elevation), each at the distance
    /// that frames it (`--views N`).
    Views(u32),
    /// 8 cameras on a circle at each distance, in bounding radii of the scene (half the diagonal
    /// of its bounds; `--orbit D1,D2,…`).
    Orbit(Vec<f32>),
    /// N ≥ 2 cameras flying in along the framing direction towards the centre of the bounds, from
    /// 1 km (or 100 bounding radii, if farther) to 0.3 bounding radii, each frame the same
    /// fraction closer (`--approach N`).
    Approach(u32),
    /// The poses of a camera path file ([`path::load`]; `--path FILE`).
    Path(PathBuf),
}

impl Default for Cameras {
    fn default() -> Self {
        Self::Views(DEFAULT_VIEWS)
    }
}

/// What to measure and how: the options of `treelod eval`, as plain values.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// A `.treelod` container (drawn once at the origin) or a JSON scene file.
    pub input: PathBuf,
    /// Where the cameras stand.
    pub cameras: Cameras,
    /// Techniques to measure, in order (a repeated one is measured once); those whose data the
    /// input lacks are reported as absent.
    pub techniques: Vec<TechniqueName>,
    /// Image size in pixels.
    pub size: (u32, u32),
    /// The reference is drawn this many times larger per side and box-filtered down (1..=16).
    pub supersample: u32,
    /// Vertical field of view, degrees.
    pub fov_degrees: f32,
    /// Background, sRGB: pixels of exactly this colour count as not covered.
    pub background: [u8; 3],
    /// MSAA samples (1 or 4) of every technique but `full` (drawn as the reference is).
    pub msaa: u32,
    /// Point threshold `s_min` of `spt` in pixels (`None`: the renderer's default).
    pub s_min: Option<f32>,
    /// Triangle threshold `s_max` of `spt` in pixels (`None`: the renderer's default).
    pub s_max: Option<f32>,
    /// `impostors`: slide planes onto their parents' and cross-fade textures between levels.
    pub impostor_morph: bool,
    /// `impostors`: which bark is drawn beside the planes.
    pub impostor_bark: ImpostorBark,
    /// `ellipsoids`: the bark as branch lines where the container has them (else triangles).
    pub lines: bool,
    /// `ellipsoids`: octaves of metres per pixel over which levels blend (0: switch at once).
    pub level_blend: f32,
    /// `policy`: the policy the renderer chooses each tree's representation with (its target).
    pub policy: Policy,
    /// `prune-opt` and `prune-cook`: a fixed fraction `λ` of each cell's leaves, in (0, 1], on
    /// every tree at every distance instead of the container's `λ(h)` (`Pruning::lambda`), so
    /// that the two are compared at equal geometry or the `λ` each needs for a quality is found.
    pub prune_lambda: Option<f32>,
    /// Keep the images of up to 4 frames spread over the path for a contact sheet
    /// ([`Report::sheet`], [`output::contact_sheet`]).
    pub sheet: bool,
}

impl Options {
    /// The defaults of `treelod eval` for `input`: 8 views, `full`, `full-1x` and `spt`,
    /// 640×480, the reference supersampled 4 times, a 50° field of view, a white background, no
    /// MSAA, the renderer's thresholds, impostors morphing with the chain's bark, ellipsoids with
    /// lines blending over half an octave, pruning by the containers' `λ(h)`, no contact sheet.
    #[must_use]
    pub fn new(input: impl Into<PathBuf>) -> Self {
        Self {
            input: input.into(),
            cameras: Cameras::default(),
            techniques: vec![TechniqueName::FULL, TechniqueName::Full1x, TechniqueName::Technique(Technique::Spt)],
            size: (640, 480),
            supersample: 4,
            fov_degrees: 50.0,
            background: [255; 3],
            msaa: 1,
            s_min: None,
            s_max: None,
            impostor_morph: true,
            impostor_bark: ImpostorBark::default(),
            lines: true,
            level_blend: 0.5,
            policy: Policy::default(),
            prune_lambda: None,
            sheet: false,
        }
    }

    /// The renderer settings `technique` is measured with (`full` is drawn as the reference).
    fn settings(&self, technique: Technique) -> Settings {
        let mut settings = Settings::forced(technique);
        settings.s_min = self.s_min.unwrap_or(settings.s_min);
        settings.s_max = self.s_max.unwrap_or(settings.s_max);
        // The pruning techniques prune every tree at every distance (no point tree for
        // small ones), with the container's λ(h) (or the fixed λ asked for), the occlusion
        // factor and hysteresis.
        settings.pruning = Pruning { spt_below_pixels: 0.0, lambda: self.prune_lambda, ..Pruning::default() };
        // Impostors: the leaves of every tree with planes as planes, its bark as the renderer's
        // default draws it (branch lines where the container has them) unless asked otherwise.
        settings.impostor_morph = self.impostor_morph;
        settings.impostor_bark = self.impostor_bark;
        // Ellipsoids: the leaves of every tree with ellipsoids as ellipsoids, its bark as
        // its branch lines where it has them (unless `lines` is off), else as triangles.
        settings.lines = self.lines;
        settings.level_blend = self.level_blend;
        settings
    }

    /// Refuses values no command line gives.
    fn check(&self) -> Result<(), Error> {
        let bad = |message: &str| Err(Error::Options { input: self.input.clone(), message: message.to_owned() });
        let (w, h) = self.size;
        if w == 0 || h == 0 {
            return bad("the image size must be at least 1x1");
        }
        if !(1..=16).contains(&self.supersample) {
            return bad("the supersampling factor must be 1 to 16");
        }
        if !matches!(self.msaa, 1 | 4) {
            return bad("MSAA samples must be 1 or 4");
        }
        if let Some(lambda) = self.prune_lambda {
            if !(lambda > 0.0 && lambda <= 1.0) {
                return bad("a fixed λ of pruning must be a fraction in (0, 1]");
            }
            if !self.techniques.iter().any(|t| t.prunes()) {
                return bad("a fixed λ of pruning needs prune-opt or prune-cook among the techniques");
            }
        }
        if !(self.fov_degrees > 0.0 && self.fov_degrees < 180.0) {
            return bad("the field of view must be between 0 and 180 degrees");
        }
        if matches!(&self.cameras, Cameras::Views(0) | Cameras::Approach(0 | 1)) {
            return bad("views need at least 1 camera, an approach 2");
        }
        if matches!(&self.cameras, Cameras::Orbit(d) if d.is_empty() || d.iter().any(|d| !(*d > 0.0 && d.is_finite())))
        {
            return bad("orbit distances must be positive");
        }
        Ok(())
    }
}

/// What a row measures, by the name `--technique` takes: a technique of the one list
/// ([`Technique`], drawn at the image size; `full` is drawn as the reference is, supersampled and
/// box-filtered, the instrument's check), or `full-1x`, the full mesh drawn at the image size with no
/// supersampling: the aliasing floor of every technique drawn at the image size; or `policy`,
/// the renderer's default: each tree drawn with the representation the policy chooses from its
/// container's calibration tables (the point tree where a container has none).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TechniqueName {
    /// A technique of the one list.
    Technique(Technique),
    /// The full mesh at the image size.
    Full1x,
    /// The policy's choice per tree.
    Policy,
}

/// Every name `--technique` takes: the full mesh at the image size after the full mesh, then the
/// rest of [`Technique::ALL`], then the policy.
const NAMES: [TechniqueName; Technique::COUNT + 2] = {
    let mut names = [TechniqueName::Policy; Technique::COUNT + 2];
    names[1] = TechniqueName::Full1x;
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
    /// Every name: `full`, `full-1x`, then the rest of [`Technique::ALL`], then `policy`.
    pub const ALL: [Self; Technique::COUNT + 2] = NAMES;

    /// The name as `--technique` takes it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Technique(t) => t.name(),
            Self::Full1x => "full-1x",
            Self::Policy => "policy",
        }
    }

    /// The technique drawn ([`Technique::Full`] for `full-1x`); `None` for the policy, which
    /// chooses per tree.
    #[must_use]
    pub fn technique(self) -> Option<Technique> {
        match self {
            Self::Technique(t) => Some(t),
            Self::Full1x => Some(Technique::Full),
            Self::Policy => None,
        }
    }

    /// Whether this name prunes leaves at run time ([`Technique::PruneOpt`],
    /// [`Technique::PruneCook`]): those a fixed λ ([`Options::prune_lambda`]) applies to.
    #[must_use]
    pub fn prunes(self) -> bool {
        matches!(self, Self::Technique(t) if treelod_render::prune_scale(t).is_some())
    }
}

#[cfg(feature = "clap")]
impl clap::ValueEnum for TechniqueName {
    fn value_variants<'a>() -> &'a [Self] {
        &NAMES
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let help = match self {
            Self::Technique(Technique::Full) => "the full mesh drawn as the reference is (supersampled)",
            Self::Technique(t) => t.label(),
            Self::Full1x => "the full mesh at the image size (the aliasing floor)",
            Self::Policy => "per tree, the cheapest representation the calibration finds within the target",
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
    let Some(technique) = technique.technique() else { return Availability::Measured };
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
    stats.submitted[Primitive::Triangle] * size_of::<treelod_format::TriangleRecord>() as u64
        + stats.submitted[Primitive::Point] * size_of::<treelod_format::PointRecord>() as u64
        + stats.submitted[Primitive::Plane] * size_of::<treelod_format::PlaneRecord>() as u64
        + stats.submitted[Primitive::Billboard] * size_of::<treelod_format::BillboardRecord>() as u64
        + stats.submitted[Primitive::Ellipsoid] * size_of::<treelod_format::EllipsoidRecord>() as u64
        + stats.submitted[Primitive::Line] * size_of::<treelod_format::LineRecord>() as u64
}

/// Quads submitted in a frame: impostor planes and billboard quads.
#[must_use]
pub fn quads(stats: &FrameStats) -> u64 {
    stats.submitted[Primitive::Plane] + stats.submitted[Primitive::Billboard]
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
    /// Per technique asked for (in [`Self::techniques`]' order), the texture bytes it samples.
    pub textures: Vec<TextureBytes>,
}

/// The container images a technique samples, bytes as stored (spec §6.7), over the scene's models
/// (each model once, not per instance).
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TextureBytes {
    /// The sources' images, which the materials name: every technique that draws triangles or
    /// points samples them.
    pub source_bytes: u64,
    /// The technique's own atlases: impostor planes' for `impostors`, the billboards' for
    /// `billboard` and `crossed`, both for the policy, none for the others.
    pub atlas_bytes: u64,
    /// The formats of those atlases (spec names, each once), empty without.
    pub atlas_formats: Vec<String>,
}

impl TextureBytes {
    /// Source and atlas bytes together.
    #[must_use]
    pub fn total(&self) -> u64 {
        self.source_bytes + self.atlas_bytes
    }

    /// What `technique` samples of `containers`.
    #[must_use]
    pub fn of(containers: &[Container], technique: TechniqueName) -> Self {
        let (planes, billboards) = match technique {
            TechniqueName::Technique(Technique::Impostors) => (true, false),
            TechniqueName::Technique(Technique::Billboard | Technique::Crossed) => (false, true),
            TechniqueName::Policy => (true, true),
            _ => (false, false),
        };
        let mut out = Self::default();
        for c in containers {
            let images = c.images();
            let named = |list: Vec<u32>| -> Vec<u32> {
                let mut list: Vec<u32> = list.into_iter().filter(|&i| (i as usize) < images.len()).collect();
                list.sort_unstable();
                list.dedup();
                list
            };
            let sources = named(c.materials().iter().map(|m| m.image).collect());
            let mut atlases = Vec::new();
            if planes {
                atlases.extend(c.planes().iter().map(|p| p.image));
            }
            if billboards {
                atlases.extend(c.billboards().iter().map(|b| b.image));
            }
            let atlases = named(atlases);
            out.source_bytes += sources.iter().map(|&i| images[i as usize].data_length).sum::<u64>();
            for &i in atlases.iter().filter(|i| !sources.contains(i)) {
                let record = &images[i as usize];
                out.atlas_bytes += record.data_length;
                let name = treelod_format::image_format::name(record.format)
                    .map_or_else(|| format!("format {}", record.format), str::to_owned);
                if !out.atlas_formats.contains(&name) {
                    out.atlas_formats.push(name);
                }
            }
        }
        out
    }
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

impl Report {
    /// The techniques measured, in the order asked for.
    pub fn measured(&self) -> impl Iterator<Item = TechniqueName> + '_ {
        self.techniques.iter().filter(|(_, a)| *a == Availability::Measured).map(|(n, _)| *n)
    }

    /// The report as text: the heading, the techniques not measured, the table, the summary by
    /// band and, last, `written`: the files written, as `treelod eval` prints it (in the order
    /// CSV, JSON, contact sheet, quality plot, frame plot, band plot).
    #[must_use]
    pub fn text(&self, written: [&Option<PathBuf>; 6]) -> String {
        output::text(self, written)
    }

    /// Writes one CSV row per frame and technique to `path`.
    ///
    /// # Errors
    /// [`Error::OutputIsDirectory`] or [`Error::Write`] naming `path`.
    pub fn write_csv(&self, path: &Path) -> Result<(), Error> {
        crate::write::atomically(path, output::csv(self).as_bytes())
    }

    /// Writes the JSON summary to `path`.
    ///
    /// # Errors
    /// As [`Report::write_csv`], or [`Error::Encode`].
    pub fn write_json(&self, path: &Path) -> Result<(), Error> {
        crate::write::json(path, output::json(self))
    }

    /// Writes the contact sheet (a PNG; empty unless [`Options::sheet`] was set) to `path`.
    ///
    /// # Errors
    /// As [`Report::write_json`].
    pub fn write_sheet(&self, path: &Path) -> Result<(), Error> {
        crate::write::png(path, &output::contact_sheet(self))
    }

    /// Writes the plot of Q against primitives drawn ([`plot::quality_vs_primitives`]) to `path`.
    ///
    /// # Errors
    /// As [`Report::write_json`].
    pub fn write_quality_plot(&self, path: &Path) -> Result<(), Error> {
        crate::write::png(path, &plot::quality_vs_primitives(self))
    }

    /// Writes the per-frame curves along the path ([`plot::per_frame`]) to `path`.
    ///
    /// # Errors
    /// As [`Report::write_json`].
    pub fn write_frame_plot(&self, path: &Path) -> Result<(), Error> {
        crate::write::png(path, &plot::per_frame(self))
    }

    /// Writes RMSE against primitives per band of projected height ([`plot::by_band`]) to `path`.
    ///
    /// # Errors
    /// As [`Report::write_json`].
    pub fn write_band_plot(&self, path: &Path) -> Result<(), Error> {
        crate::write::png(path, &plot::by_band(self))
    }
}

/// Measures `options.techniques` against the reference at every camera; see [`run_with_progress`].
///
/// # Errors
/// As [`run_with_progress`].
pub fn run(options: &Options) -> Result<Report, Error> {
    run_with_progress(options, &mut |_, _| {})
}

/// Measures `options.techniques` against the reference at every camera and returns what was
/// measured. Before the first frame every renderer draws once (shader compilation is not
/// timed), and before each frame streaming settles. `progress(frame, frames)` is called before
/// each frame is drawn.
///
/// # Errors
/// A bad scene, container or camera path ([`Error::Scene`], [`Error::Container`],
/// [`Error::CameraPath`], naming the file), bad options ([`Error::Options`]), no technique
/// measurable ([`Error::NoneMeasurable`]), no device or one too small ([`Error::NoDevice`],
/// [`Error::TooLarge`]), a frame that cannot be drawn ([`Error::Render`]).
pub fn run_with_progress(options: &Options, progress: &mut dyn FnMut(usize, usize)) -> Result<Report, Error> {
    options.check()?;
    let input = &options.input;
    let scene = scene::load(input)?;
    let path_poses = match &options.cameras {
        Cameras::Path(file) => {
            Some(path::load(file).map_err(|(io, message)| Error::CameraPath { path: file.clone(), message, io })?)
        }
        _ => None,
    };
    let containers = open_models(&scene)?;
    let held = PerTechnique::held_by(&containers);
    let mut techniques: Vec<(TechniqueName, Availability)> = Vec::new();
    for &name in &options.techniques {
        if !techniques.iter().any(|(n, _)| *n == name) {
            let holder =
                if scene::is_container_path(input) { "this container holds no" } else { "no model of the scene holds" };
            techniques.push((name, availability(name, held, holder)));
        }
    }
    if techniques.iter().all(|(_, a)| *a != Availability::Measured) {
        return Err(Error::NoneMeasurable { input: input.clone(), absent: output::unavailable(&techniques) });
    }
    let gpu = Gpu::new().map_err(|source| Error::NoDevice { input: input.clone(), source })?;
    let (width, height) = options.size;
    let k = options.supersample;
    let limit = gpu.device.limits().max_texture_dimension_2d;
    if u64::from(width) * u64::from(k) > u64::from(limit) || u64::from(height) * u64::from(k) > u64::from(limit) {
        return Err(Error::TooLarge {
            input: input.clone(),
            message: format!(
                "the reference, {width}x{height} supersampled {k} times, is larger than the device draws ({limit} pixels per side at most)"
            ),
        });
    }

    let add = |settings: Settings, samples: u32| -> Result<(Renderer, (Vec3, Vec3)), Error> {
        let mut renderer = Renderer::new(&gpu.device, Gpu::formats_msaa(samples), settings);
        let bounds = scene::add_to_renderer(&scene, &gpu.device, &gpu.queue, &mut renderer)?;
        Ok((renderer, bounds))
    };
    let full_settings = Settings::forced(Technique::Full);
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
            TechniqueName::Technique(technique) => (options.settings(*technique), 1),
            TechniqueName::Policy => (Settings { policy: Some(options.policy), ..options.settings(Technique::Spt) }, 1),
        };
        let samples = if *name == TechniqueName::FULL { 1 } else { options.msaa };
        measured.push(Measured { name: *name, renderer: add(settings, samples)?.0, supersample, previous: None });
    }

    let fovy = options.fov_degrees.to_radians();
    let (poses, camera_source) = cameras(options, path_poses, bounds, fovy);
    let background = clear_colour(options.background);
    let camera = |pose: &Pose, k: u32| Camera::look_at(pose.eye, pose.target, fovy, width * k, height * k);
    // Images and masks of one run always match in size; a mismatch is a bug, reported as such.
    let internal = |e: MetricError| Error::Internal { input: input.clone(), message: e.to_string() };
    let shoot = |renderer: &mut Renderer, pose: &Pose, k: u32| -> Result<Shot, Error> {
        let camera = camera(pose, k);
        settle_streaming(&gpu, renderer, &camera);
        // One prepare per frame, as a host makes it; the wall clock runs over prepare, render and
        // read-back.
        let start = Instant::now();
        let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
        gpu.queue.submit([]);
        let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
        let (image, gpu_ms) = render_prepared_timed(&gpu, renderer, &camera, background)
            .map_err(|source| Error::Render { input: input.clone(), source })?;
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let (image, mask) = measurable(&image, k, options.background).map_err(internal)?;
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
    let mut rows = Vec::with_capacity(poses.len() * measured.len());
    let mut sheet = Vec::new();
    let mut previous_reference: Option<LinearImage> = None;
    for (frame, pose) in poses.iter().enumerate() {
        progress(frame, poses.len());
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
            if options.sheet && sheet_frames.contains(&frame) {
                sheet_techniques.push((m.name, shot.image.clone(), shot.mask));
            }
            m.previous = Some(shot.image);
        }
        if options.sheet && sheet_frames.contains(&frame) {
            sheet.push(SheetFrame {
                frame,
                reference: (reference_shot.image.clone(), reference_shot.mask),
                techniques: sheet_techniques,
            });
        }
        previous_reference = Some(reference_shot.image);
    }

    let heights = poses.iter().map(|pose| projected_height(bounds, pose, fovy, height)).collect();
    Ok(Report {
        input: input.clone(),
        camera_source,
        poses,
        heights,
        size: options.size,
        supersample: k,
        msaa: options.msaa,
        fov_degrees: options.fov_degrees,
        background: options.background,
        adapter: Adapter::new(&gpu.info),
        timestamps: gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY),
        textures: techniques.iter().map(|&(name, _)| TextureBytes::of(&containers, name)).collect(),
        techniques,
        rows,
        sheet,
    })
}

/// The reference's renderer settings, for `eval` and `bench --quality`: the full mesh, keeping
/// the leaves' coverage where their textures are minified. The plain alpha test drops every texel
/// less than half covered, so thin leaves vanish from a distant crown even at 4× (the maple at 32
/// bounding radii kept 60 % of the darkening that alpha to coverage keeps). Each of its pixels is
/// still leaf or background (a stochastic test), so the box filter of [`measurable`] averages the
/// coverage and the majority mask stays binary.
#[must_use]
pub fn reference_settings() -> Settings {
    Settings { stochastic_alpha: true, ..Settings::forced(Technique::Full) }
}

/// A read-back image as the metrics take it: linear colour box-filtered over `k`×`k` blocks, and
/// coverage (pixels not exactly `background`) by the majority of each block.
///
/// # Errors
/// [`MetricError`] if the image's pixels do not match its size or `k` does not divide it.
pub fn measurable(
    image: &treelod_render::offscreen::Image,
    k: u32,
    background: [u8; 3],
) -> Result<(LinearImage, Mask), MetricError> {
    let linear = LinearImage::from_srgba8(image.width, image.height, &image.rgba)?;
    let mask = Mask::from_srgba8(image.width, image.height, &image.rgba, background)?;
    Ok((linear.box_filter(k)?, mask.reduce_majority(k)?))
}

/// The scene's models, each opened and checked as every reader does.
fn open_models(scene: &Scene) -> Result<Vec<Container>, Error> {
    scene
        .models
        .iter()
        .map(|model| Container::open(model).map_err(|source| Error::Container { path: model.clone(), source }))
        .collect()
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

/// The cameras the options ask for, and how to say where they came from (as the command line
/// says it).
fn cameras(options: &Options, path_poses: Option<Vec<Pose>>, bounds: (Vec3, Vec3), fovy: f32) -> (Vec<Pose>, String) {
    let (width, height) = options.size;
    let framing = frame_camera(bounds, None, None, fovy, width, height);
    let target = 0.5 * (bounds.0 + bounds.1);
    if let Some(poses) = path_poses {
        let source = match &options.cameras {
            Cameras::Path(p) => format!("--path {}", p.display()),
            _ => String::new(),
        };
        return (poses, source);
    }
    // The bounding radius as `render` frames it: the half diagonal of the bounds.
    let radius = (0.5 * (bounds.1 - bounds.0)).length().max(0.1);
    match &options.cameras {
        Cameras::Approach(count) => {
            let (far, near) = (APPROACH_FAR_METRES.max(APPROACH_FAR_RADII * radius), APPROACH_NEAR_RADII * radius);
            let poses = path::approach(target, FRAMING_DIRECTION, far, near, *count as usize);
            (poses, format!("--approach {count}: {far:.0} to {near:.2} from the centre"))
        }
        Cameras::Orbit(distances) => {
            let poses = distances
                .iter()
                .flat_map(|d| path::circle(target, FRAMING_DIRECTION, d * radius, ORBIT_VIEWS))
                .collect();
            let list: Vec<String> = distances.iter().map(f32::to_string).collect();
            (poses, format!("--orbit {}", list.join(",")))
        }
        Cameras::Views(_) | Cameras::Path(_) => {
            let views = match &options.cameras {
                Cameras::Views(views) => *views,
                _ => DEFAULT_VIEWS,
            };
            let distance = framing.position.distance(target);
            (path::circle(target, FRAMING_DIRECTION, distance, views as usize), format!("--views {views}"))
        }
    }
}

/// Up to [`SHEET_FRAMES`] frames spread evenly over `count`, first and last included.
fn sheet_frames(count: usize) -> Vec<usize> {
    spread_frames(count, SHEET_FRAMES)
}

/// Up to `n` frames spread evenly over `count`, first and last included where `n` ≥ 2 (one
/// frame: the first): the contact sheets' default frames (`treelod eval --sheet`, `treelod bench
/// --sheet`).
#[must_use]
pub fn spread_frames(count: usize, n: usize) -> Vec<usize> {
    if count <= n || n < 2 {
        return (0..count.min(n)).collect();
    }
    // round(i · (count − 1) / (n − 1))
    let steps = n - 1;
    let mut frames: Vec<usize> = (0..=steps).map(|i| (2 * i * (count - 1) + steps) / (2 * steps)).collect();
    frames.dedup();
    frames
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
    fn a_fixed_lambda_applies_to_the_names_that_prune_and_needs_one_of_them() {
        let pruning: Vec<&str> = TechniqueName::ALL.iter().filter(|t| t.prunes()).map(|t| t.name()).collect();
        assert_eq!(pruning, ["prune-opt", "prune-cook"]);
        let options = |techniques: Vec<TechniqueName>| Options {
            techniques,
            prune_lambda: Some(0.5),
            ..Options::new("forest.treelod")
        };
        assert!(options(vec![TechniqueName::Technique(Technique::PruneCook)]).check().is_ok());
        assert!(options(vec![TechniqueName::Technique(Technique::Spt), TechniqueName::Policy]).check().is_err());
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
        assert_eq!(spread_frames(30, 4), [0, 10, 19, 29]);
        assert_eq!(spread_frames(30, 1), [0]);
        assert_eq!(spread_frames(30, 0), Vec::<usize>::new());
    }
}
