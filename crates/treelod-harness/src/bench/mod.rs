//! `treelod bench`: the fly-through benchmark, modelled on Clasen 2011 §7 — a forest of 10,000
//! trees in groups ([`forest`]) and a camera path that starts with an overview, descends to human
//! height inside the main forest, heads to a smaller separate group and turns back ([`path`]).
//! Every technique flies the same path; per frame it records the CPU time of the selection
//! (`Renderer::prepare`), the primitives drawn by kind, the bytes streamed, the instances in view,
//! the GPU time of the render pass (timestamp queries) and, with `--quality`, the P/R/Q,
//! multi-scale RMSE and mean FLIP error (`treelod_eval`'s metrics) against the full mesh at the
//! same frame, drawn as `treelod eval`'s reference is (supersampled, box-filtered, with the
//! stochastic alpha test) unless `--reference-1x` asks for the plain full mesh at the image size.
//!
//! The full mesh of 10^4 trees takes minutes a frame on a software rasteriser, so `full` is
//! counted, not drawn, unless `--quality` needs it as the reference: its primitives come from the
//! runtime's selection with both thresholds at zero (what `Technique::Full` draws), run over
//! the forest in chunks so that even 10^6 instances need little memory.
//!
//! The tables, CSV, JSON, plot and contact sheet are in [`output`].

pub mod forest;
pub mod output;
pub mod path;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use treelod_format::{Compression, Container};
use treelod_render::offscreen::{Gpu, render_image_timed, render_prepared_timed};
use treelod_render::{
    BudgetFrame, Camera, Instance, ModelId, PerTechnique, Policy, PreparePhases, Primitive, Pruning, Renderer,
    Settings, Technique,
};

use self::forest::{Forest, Shape};
use self::path::Frame;
use treelod_eval::MetricError;

use crate::Error;
use crate::eval::metrics::{Coverage, LinearImage, Mask, flip::mean_flip, multiscale_rmse, temporal_noise};
use crate::eval::{Adapter, Availability, SheetFrame, TechniqueName};
use crate::offscreen::{clear_colour, settle_streaming};
use crate::scene;

/// Instances per call of the full mesh's counting selection: its draw list holds a range per
/// non-empty cell of each (about 60 for the demo tree), so this bounds it to a few tens of MB.
const FULL_COUNT_CHUNK: usize = 8192;

/// The built-in forest's models: demo trees of different seeds, leaf counts and heights.
const DEMO_TREES: [(u64, u32, f32); 4] = [(1, 4000, 4.0), (2, 2500, 3.0), (3, 5000, 5.0), (4, 3000, 4.5)];

/// How `--quality`'s reference is drawn, asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// `treelod eval`'s reference: drawn this many times larger per side (1..=16) with the
    /// stochastic alpha test, box-filtered down.
    Supersampled(u32),
    /// The reference of earlier versions: the full mesh at the image size with the plain alpha
    /// test (aliased: thin leaves drop out of it).
    Plain1x,
}

/// What to fly and how: the options of `treelod bench`, as plain values.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Containers, or scene files whose models are used; the forest is made of these models.
    /// None: built-in demo trees of four shapes, built in memory.
    pub inputs: Vec<PathBuf>,
    /// Trees in the forest (at least 1).
    pub trees: u64,
    /// Frames along the path (at least 1).
    pub frames: u32,
    /// Image size in pixels.
    pub size: (u32, u32),
    /// Seed of the forest's layout.
    pub seed: u64,
    /// Vertical field of view, degrees.
    pub fov_degrees: f32,
    /// Techniques to fly, in order (a repeated one is flown once); those not available are
    /// reported, not skipped. `full` is counted from the selection (drawn only as `quality`'s
    /// reference); `full-1x` draws the full mesh at the image size; `policy` flies the renderer's
    /// default, [`Self::policy`].
    pub techniques: Vec<TechniqueName>,
    /// The policy `policy` flies with: its target, and with [`Policy::budget`] the primitives
    /// per frame its budget mode aims for.
    pub policy: Policy,
    /// Draw images (else select and stream only: no GPU time, no quality).
    pub render: bool,
    /// Select the point tree on the GPU (`Renderer::enable_gpu_selection`) for `spt` and
    /// `policy` (whose other techniques the CPU selects).
    pub gpu_selection: bool,
    /// Cast shadows (`Settings::shadows`, the defaults) with every technique the renderer flies.
    pub shadows: bool,
    /// Draw the full mesh as the reference at every frame and measure every technique against
    /// it (needs `render`).
    pub quality: Option<Quality>,
    /// Point threshold `s_min` of `spt` in pixels (`None`: the renderer's default).
    pub s_min: Option<f32>,
    /// Triangle threshold `s_max` of `spt` in pixels (`None`: the renderer's default).
    pub s_max: Option<f32>,
    /// Background, sRGB: with `quality`, pixels of it count as not covered.
    pub background: [u8; 3],
    /// Frames (indices along the path) whose images to keep for a contact sheet
    /// ([`Report::sheet`]): the reference's and each drawn technique's. Needs `quality`; at most
    /// [`SHEET_FRAMES_MAX`], each less than `frames`.
    pub sheet_frames: Vec<usize>,
}

/// Frames of a contact sheet at most ([`Options::sheet_frames`]).
pub const SHEET_FRAMES_MAX: usize = 8;

impl Default for Options {
    /// The defaults of `treelod bench`: the built-in forest of 10,000 trees, 360 frames at
    /// 1536×864, layout seed 1, a 50° field of view, `full` and `spt`, drawn, no GPU selection,
    /// shadows or quality, the renderer's thresholds and policy, a white background, no contact
    /// sheet.
    fn default() -> Self {
        Self {
            inputs: Vec::new(),
            trees: 10_000,
            frames: 360,
            size: (1536, 864),
            seed: 1,
            fov_degrees: 50.0,
            techniques: vec![TechniqueName::FULL, TechniqueName::Technique(Technique::Spt)],
            policy: Policy::default(),
            render: true,
            gpu_selection: false,
            shadows: false,
            quality: None,
            s_min: None,
            s_max: None,
            background: [255; 3],
            sheet_frames: Vec::new(),
        }
    }
}

impl Options {
    /// What error lines name when no file is to blame: the first input, or `bench` for the
    /// built-in forest.
    #[must_use]
    pub fn input_label(&self) -> PathBuf {
        match self.inputs.first() {
            None => PathBuf::from("bench"),
            Some(first) => first.clone(),
        }
    }

    /// Refuses values no command line gives.
    fn check(&self) -> Result<(), Error> {
        let bad = |message: &str| Err(Error::Options { input: self.input_label(), message: message.to_owned() });
        if self.trees == 0 || self.frames == 0 {
            return bad("a forest needs at least 1 tree and a path 1 frame");
        }
        if self.size.0 == 0 || self.size.1 == 0 {
            return bad("the image size must be at least 1x1");
        }
        if !(self.fov_degrees > 0.0 && self.fov_degrees < 180.0) {
            return bad("the field of view must be between 0 and 180 degrees");
        }
        if self.policy.budget == Some(0) {
            return bad("a primitive budget must be at least 1");
        }
        if self.quality.is_some() && !self.render {
            return bad("quality needs images drawn");
        }
        if matches!(self.quality, Some(Quality::Supersampled(k)) if !(1..=16).contains(&k)) {
            return bad("the supersampling factor must be 1 to 16");
        }
        if !self.sheet_frames.is_empty() && self.quality.is_none() {
            return bad("a contact sheet needs --quality (its images are the reference and each technique's)");
        }
        if self.sheet_frames.len() > SHEET_FRAMES_MAX {
            return bad(&format!("a contact sheet holds {SHEET_FRAMES_MAX} frames at most"));
        }
        if let Some(&frame) = self.sheet_frames.iter().find(|&&f| f >= self.frames as usize) {
            return bad(&format!(
                "frame {frame} of the contact sheet is past the path, whose frames are 0 to {}",
                self.frames - 1
            ));
        }
        Ok(())
    }
}

/// What `technique` draws, for the JSON summary.
#[must_use]
pub fn description(technique: TechniqueName) -> &'static str {
    match technique {
        TechniqueName::FULL => "the full mesh: every triangle of every visible instance",
        t => crate::eval::output::description(t),
    }
}

/// Whether `technique` can be flown over models holding each technique's data as `held` counts
/// them.
fn availability(technique: TechniqueName, held: PerTechnique<usize>) -> Availability {
    crate::eval::availability(technique, held, "no model of the forest holds")
}

/// The renderer settings `technique` flies with; `None` for `full`, which is counted apart.
///
/// The pruning techniques fly the renderer's pruning policy ([`Pruning`]'s defaults: trees at
/// least 64 pixels high pruned to the container's `λ(h)` times their visible fraction, with
/// hysteresis; smaller ones by the point tree) with the optimal or Cook's scale. `ellipsoids` flies
/// with the bark as lines where a model has them, at the default quality and level blend;
/// `impostors` with the defaults of `render` (morphing levels, the chain's bark where a model has a
/// chain). Trees whose models lack a technique's data draw with the point tree. `full-1x` draws
/// every triangle at the image size; `policy` is the renderer's default with [`Options::policy`]
/// (the point tree for models without calibration tables).
pub fn settings(technique: TechniqueName, options: &Options) -> Option<Settings> {
    let mut settings = match technique {
        TechniqueName::FULL => return None,
        TechniqueName::Technique(t) => Settings::forced(t),
        TechniqueName::Full1x => Settings::forced(Technique::Full),
        TechniqueName::Policy => Settings { policy: Some(options.policy), ..Settings::forced(Technique::Spt) },
    };
    settings.s_min = options.s_min.unwrap_or(settings.s_min);
    settings.s_max = options.s_max.unwrap_or(settings.s_max);
    settings.pruning = Pruning::default();
    settings.shadows = options.shadows.then(treelod_render::Shadows::default);
    settings.lines = true;
    Some(settings)
}

/// One frame of one technique.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Frame index.
    pub frame: usize,
    /// The technique.
    pub technique: TechniqueName,
    /// Instances inside the view frustum.
    pub instances_visible: u32,
    /// Triangles submitted.
    pub triangles: u64,
    /// Points submitted (the prefixes; the vertex shader drops those outside the cut).
    pub points: u64,
    /// Of those, the points in the cut, which the shader keeps (`Renderer::points_in_cut`; 0 for
    /// the full mesh, `None` when the frame was selected on the GPU).
    pub points_in_cut: Option<u64>,
    /// Impostor planes and billboard quads submitted (one primitive each, as a splat is).
    pub quads: u64,
    /// Ellipsoids submitted (the prefixes; the vertex shader drops those outside the level).
    pub ellipsoids: u64,
    /// Branch lines submitted by ellipsoid trees (the prefixes, as for ellipsoids).
    pub lines: u64,
    /// Visible instances drawn with pruned leaves (`None` for the counted full mesh).
    pub instances_pruned: Option<u32>,
    /// Leaves drawn by pruned instances (their triangles count in `triangles`).
    pub leaves_pruned: Option<u64>,
    /// Ranges recorded, one per drawn range (`None` for the counted full mesh).
    pub ranges: Option<u32>,
    /// Indirect draw commands those ranges went to the GPU as (`FrameStats::draw_commands`;
    /// `None` for the counted full mesh).
    pub draw_commands: Option<u32>,
    /// Draws made coarser than the selection because their data was not resident yet.
    pub ranges_clamped: Option<u32>,
    /// Bytes of triangles and points streamed to the GPU by this frame.
    pub bytes_uploaded: Option<u64>,
    /// Bytes of model data resident on the GPU.
    pub bytes_resident: Option<u64>,
    /// Wall milliseconds of the selection: `Renderer::prepare`, or for the counted full mesh the
    /// runtime's selection with thresholds 0.
    pub selection_ms: f64,
    /// GPU milliseconds of the render pass (timestamp queries); `None` when not drawn or not
    /// measurable.
    pub gpu_ms: Option<f64>,
    /// With `--shadows`: triangles, points, quads, ellipsoids and lines the shadow pass
    /// submitted, all cascades together (`None` without, and for the counted full mesh).
    pub shadow_primitives: Option<u64>,
    /// Trees drawn with two techniques, in a transition from one to the other
    /// (`FrameStats::transitions`; `None` for the counted full mesh).
    pub transitions: Option<u32>,
    /// Primitives of the draws of the techniques those trees are leaving (`FrameStats::leaving`,
    /// counted in the row's primitives; `None` for the counted full mesh).
    pub leaving: Option<u64>,
    /// Coverage against the reference (with `--quality`, not for the reference itself).
    pub coverage: Option<Coverage>,
    /// Multi-scale RMSE summary against the reference.
    pub rmse: Option<f64>,
    /// Mean FLIP error against the reference.
    pub flip: Option<f64>,
    /// Temporal noise (with `--quality`, from the second frame): the multi-scale RMSE summary of
    /// this frame's image against this technique's previous frame's, as `treelod eval` measures
    /// it. The path moves the camera between frames, so it holds the image's own change too.
    pub noise: Option<f64>,
    /// The reference's temporal noise over the same two frames: the change the scene itself
    /// makes, which `noise` is compared with.
    pub reference_noise: Option<f64>,
    /// Visible trees by the technique each was drawn with (`FrameStats::instances`: the policy's
    /// choice, or the point tree for trees whose model lacks the technique's data; a tree in a
    /// transition under the one it goes to) and the primitives they submitted
    /// (`FrameStats::by_technique`: a transition's leaving draws under the technique left).
    /// `None` for the counted full mesh.
    pub drawn_with: Option<(PerTechnique<u32>, PerTechnique<u64>)>,
    /// Where `Renderer::prepare` spent `selection_ms`, phase by phase
    /// (`Renderer::prepare_phases`); `None` for the counted full mesh.
    pub phases: Option<PreparePhases>,
    /// The policy's budget mode: the steering the frame was selected with
    /// (`Renderer::budget_frame`); `None` outside it.
    pub budget: Option<BudgetFrame>,
}

impl Row {
    /// Triangles, points, quads, ellipsoids and lines.
    #[must_use]
    pub fn primitives(&self) -> u64 {
        self.triangles + self.points + self.quads + self.ellipsoids + self.lines
    }

    /// Triangles and the points in the cut: what is rasterised (the submitted count where the
    /// cut was not counted, and for quads, ellipsoids and lines, whose levels the vertex shader
    /// picks).
    #[must_use]
    pub fn primitives_in_cut(&self) -> u64 {
        self.triangles + self.points_in_cut.unwrap_or(self.points) + self.quads + self.ellipsoids + self.lines
    }
}

/// What the forest is made of, for the heading and the JSON.
pub struct Models {
    /// Where the models came from, in words.
    pub source: String,
    /// One label per model (its path, or the demo tree's settings).
    pub labels: Vec<String>,
    containers: Vec<Arc<Container>>,
    /// The built-in trees with stochastic priority lists, for `prune-cook` (Cook et al.'s uniform
    /// stochastic pruning); `None` for given models, whose own lists `prune-cook` then uses.
    stochastic: Option<Vec<Arc<Container>>>,
}

/// How `--quality`'s reference is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reference {
    /// Drawn this many times larger per side, then box-filtered down.
    pub supersample: u32,
    /// Whether with the stochastic alpha test (`treelod eval`'s reference) or the plain one
    /// (`--reference-1x`).
    pub stochastic_alpha: bool,
}

/// Everything a run measured, for the outputs.
pub struct Report {
    /// The models.
    pub models: Models,
    /// The forest.
    pub forest: Forest,
    /// The frames of the path.
    pub frames: Vec<Frame>,
    /// Image size.
    pub size: (u32, u32),
    /// Vertical field of view, degrees.
    pub fov_degrees: f32,
    /// Seed of the layout.
    pub seed: u64,
    /// Whether images were drawn.
    pub rendered: bool,
    /// Whether quality was measured, and how the reference was drawn.
    pub quality: Option<Reference>,
    /// The adapter, if one was opened.
    pub adapter: Option<Adapter>,
    /// Whether the device has timestamp queries.
    pub timestamps: bool,
    /// Every technique asked for, in order, and whether it was measured.
    pub techniques: Vec<(TechniqueName, Availability)>,
    /// One row per frame and measured technique, frame by frame.
    pub rows: Vec<Row>,
    /// The contact sheet's frames ([`Options::sheet_frames`], in path order, each once): the
    /// reference and every technique drawn (`full`, counted, is not).
    pub sheet: Vec<SheetFrame>,
    /// Seconds the whole run took (models, layout, warm-up and frames).
    pub seconds: f64,
    /// The primitives per frame the policy's budget mode aimed for ([`Options::policy`]'s
    /// [`Policy::budget`]), if it was on: the `policy` technique's summary says how its frames
    /// met it ([`output::BudgetSummary`]).
    pub budget: Option<u64>,
}

/// The full mesh's primitives, counted by the runtime's selection with both thresholds 0 (what
/// `Technique::Full` selects: every triangle of every non-culled cell of every visible
/// instance), over chunks of instances made from the trees as needed, with one reused draw list.
struct FullCounter {
    models: Vec<treelod_runtime::ModelLod>,
    chunk: Vec<treelod_runtime::Instance>,
    list: treelod_runtime::DrawList,
    settings: treelod_runtime::LodSettings,
}

impl FullCounter {
    fn new(containers: &[Arc<Container>]) -> Self {
        let models = containers.iter().map(|c| treelod_runtime::ModelLod::from_container(c)).collect();
        let settings =
            treelod_runtime::LodSettings { s_min: 0.0, s_max: 0.0, ..treelod_runtime::LodSettings::default() };
        Self { models, chunk: Vec::with_capacity(FULL_COUNT_CHUNK), list: treelod_runtime::DrawList::new(), settings }
    }

    /// Visible instances and triangles of `trees` for `camera`, and the milliseconds it took
    /// (making the instances' matrices included).
    fn count(&mut self, trees: &[forest::Tree], camera: &Camera) -> (u32, u64, f64) {
        let camera = treelod_runtime::Camera {
            position: camera.position,
            view_proj: camera.view_proj(),
            viewport_height: camera.height.max(1) as f32,
            fovy: camera.fovy,
        };
        let start = Instant::now();
        let (mut visible, mut triangles) = (0, 0);
        for trees in trees.chunks(FULL_COUNT_CHUNK) {
            self.chunk.clear();
            self.chunk
                .extend(trees.iter().map(|t| treelod_runtime::Instance { model: t.model, transform: t.transform() }));
            let stats =
                treelod_runtime::select_frame(&self.models, &self.chunk, &camera, &self.settings, &mut self.list);
            visible += stats.instances_visible;
            triangles += stats.triangles;
        }
        (visible, triangles, start.elapsed().as_secs_f64() * 1e3)
    }
}

/// A technique flown with a renderer.
struct Flown {
    technique: TechniqueName,
    renderer: Renderer,
}

impl Report {
    /// The report as text: the heading, the techniques not measured, the table of means per
    /// technique, the seconds the run took and, last, `written`: the files written, as
    /// `treelod bench` prints it (in the order CSV, JSON, plot, contact sheet).
    #[must_use]
    pub fn text(&self, written: [&Option<PathBuf>; 4]) -> String {
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

    /// Writes the plot along the path ([`output::plot`]) to `path`.
    ///
    /// # Errors
    /// As [`Report::write_json`].
    pub fn write_plot(&self, path: &Path) -> Result<(), Error> {
        crate::write::png(path, &output::plot(self))
    }

    /// Writes the contact sheet (a PNG: per kept frame the reference, then each technique drawn
    /// and its difference, as `treelod eval --sheet` lays it out; empty without
    /// [`Options::sheet_frames`]) to `path`.
    ///
    /// # Errors
    /// As [`Report::write_json`].
    pub fn write_sheet(&self, path: &Path) -> Result<(), Error> {
        crate::write::png(path, &crate::eval::output::sheet(self.size, &self.sheet))
    }
}

/// Flies the benchmark; see [`run_with_progress`].
///
/// # Errors
/// As [`run_with_progress`].
pub fn run(options: &Options) -> Result<Report, Error> {
    run_with_progress(options, &mut |_, _| {})
}

/// Flies every technique of `options` along the path over the forest and returns what was
/// measured. Before the first frame every renderer settles its streaming at the first camera and
/// draws once; neither is timed. `progress(frame, frames)` is called before each frame.
///
/// # Errors
/// A bad container or scene file ([`Error::Container`], [`Error::Scene`], naming the file), bad
/// options ([`Error::Options`]), no technique measurable ([`Error::NoneMeasurable`]), no device
/// or one too small ([`Error::NoDevice`], [`Error::TooLarge`]), a model or frame the device
/// refuses ([`Error::AddModel`], [`Error::GpuSelection`], [`Error::DeviceRefused`]), a frame that
/// cannot be drawn ([`Error::Render`]).
pub fn run_with_progress(options: &Options, progress: &mut dyn FnMut(usize, usize)) -> Result<Report, Error> {
    let started = Instant::now();
    options.check()?;
    let label = options.input_label();
    let models = load_models(&options.inputs, &options.techniques)?;
    let mut held = held_by_models(&models.containers);
    if let Some(stochastic) = &models.stochastic {
        *held.get_mut(Technique::PruneCook) += held_by_models(stochastic).get(Technique::PruneCook);
    }
    let mut techniques: Vec<(TechniqueName, Availability)> = Vec::new();
    for &technique in &options.techniques {
        if !techniques.iter().any(|(t, _)| *t == technique) {
            techniques.push((technique, availability(technique, held)));
        }
    }
    if techniques.iter().all(|(_, a)| *a != Availability::Measured) {
        return Err(Error::NoneMeasurable { input: label, absent: output::unavailable(&techniques) });
    }
    let measured: Vec<TechniqueName> =
        techniques.iter().filter(|(_, a)| *a == Availability::Measured).map(|(t, _)| *t).collect();

    let (width, height) = options.size;
    let fovy = options.fov_degrees.to_radians();
    let aspect = width as f32 / height as f32;
    let shapes: Vec<Shape> = models
        .containers
        .iter()
        .map(|c| Shape::from_bounds(Vec3::from_array(c.block().bounds_min), Vec3::from_array(c.block().bounds_max)))
        .collect();
    let trees = usize::try_from(options.trees).unwrap_or(usize::MAX);
    let mut forest = forest::layout(trees, options.seed, &shapes);
    // No trunk stands on the low part of the path (the clearance keeps the camera out of trunks,
    // not out of crowns).
    let clearance = 0.5 * forest.footprint;
    for track in path::ground_track(&forest, fovy, aspect, 1.5 * forest.tree_height) {
        forest::clear_track(&mut forest, &track, clearance);
    }
    let frames = path::fly_through(&forest, options.frames as usize, fovy, aspect);

    // A device only when something is drawn or prepared: the full mesh alone is counted on the CPU.
    let needs_gpu = options.quality.is_some() || measured.iter().any(|&t| settings(t, options).is_some());
    let gpu = if needs_gpu {
        Some(Gpu::new().map_err(|source| Error::NoDevice { input: label.clone(), source })?)
    } else {
        None
    };
    let k = match options.quality {
        Some(Quality::Supersampled(k)) => k,
        Some(Quality::Plain1x) | None => 1,
    };
    if let Some(gpu) = &gpu {
        let limit = gpu.device.limits().max_texture_dimension_2d;
        if u64::from(width) * u64::from(k) > u64::from(limit) || u64::from(height) * u64::from(k) > u64::from(limit) {
            return Err(Error::TooLarge {
                input: label,
                message: format!(
                    "{width}x{height} (times {k}) is larger than the device draws ({limit} pixels per side at most)"
                ),
            });
        }
    }

    // The renderers share one list of instances (the same model order in each).
    let instances: Vec<Instance> =
        forest.trees.iter().map(|t| Instance { model: ModelId(t.model), transform: t.transform() }).collect();
    let add = |gpu: &Gpu, settings: Settings, technique: Option<TechniqueName>| -> Result<Renderer, Error> {
        let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
        let containers = match (&models.stochastic, technique) {
            (Some(stochastic), Some(TechniqueName::Technique(Technique::PruneCook))) => stochastic,
            _ => &models.containers,
        };
        for (index, (container, label)) in containers.iter().zip(&models.labels).enumerate() {
            let id = renderer
                .add_model(&gpu.device, &gpu.queue, Arc::clone(container))
                .map_err(|source| Error::AddModel { label: label.clone(), source })?;
            // A fresh renderer numbers its models in order; the instances rely on it.
            if id.0 as usize != index {
                return Err(Error::Internal {
                    input: PathBuf::from(label),
                    message: format!("model {index} got id {}", id.0),
                });
            }
        }
        renderer.set_instances(&instances);
        // `spt` selects every tree on the GPU; the policy the trees it draws with the point tree.
        if options.gpu_selection
            && matches!(technique, Some(TechniqueName::Technique(Technique::Spt) | TechniqueName::Policy))
        {
            renderer
                .enable_gpu_selection(&gpu.device, &gpu.queue)
                .map_err(|source| Error::GpuSelection { input: options.input_label(), source })?;
        }
        Ok(renderer)
    };
    let mut flown = Vec::new();
    let mut reference = None;
    if let Some(gpu) = &gpu {
        for &technique in &measured {
            if let Some(settings) = settings(technique, options) {
                flown.push(Flown { technique, renderer: add(gpu, settings, Some(technique))? });
            }
        }
        if let Some(quality) = options.quality {
            let settings = if quality == Quality::Plain1x {
                Settings::forced(Technique::Full)
            } else {
                crate::eval::reference_settings()
            };
            reference = Some(add(gpu, settings, None)?);
        }
    }
    drop(instances);
    let mut full = measured.contains(&TechniqueName::FULL).then(|| FullCounter::new(&models.containers));

    let background = clear_colour(options.background);
    let camera =
        |frame: &Frame, k: u32| Camera::look_at(frame.pose.eye, frame.pose.target, fovy, width * k, height * k);
    let internal = |e: MetricError| Error::Internal { input: label.clone(), message: e.to_string() };
    let render_failed =
        |source: treelod_render::offscreen::GpuError| Error::Render { input: options.input_label(), source };
    // Warm-up at the first frame: streaming loads what it needs (a host's loading screen) and
    // the first draw compiles the shaders, so neither is timed as frame 0.
    if let (Some(gpu), Some(first)) = (&gpu, frames.first()) {
        guarded(gpu, &label, || {
            for f in &mut flown {
                let camera = camera(first, 1);
                settle_streaming(gpu, &mut f.renderer, &camera);
                if options.render {
                    render_image_timed(gpu, &mut f.renderer, &camera, background).map_err(render_failed)?;
                }
            }
            if let Some(reference) = &mut reference {
                let camera = camera(first, k);
                settle_streaming(gpu, reference, &camera);
                render_image_timed(gpu, reference, &camera, background).map_err(render_failed)?;
            }
            Ok(())
        })?;
    }
    if let (Some(counter), Some(first)) = (&mut full, frames.first()) {
        counter.count(&forest.trees, &camera(first, 1));
    }

    let mut rows = Vec::with_capacity(frames.len() * measured.len());
    // The last frame's measurable images, the reference's and each flown technique's (in
    // `flown`'s order), for temporal noise.
    let mut previous_reference: Option<LinearImage> = None;
    let mut previous: Vec<Option<LinearImage>> = vec![None; flown.len()];
    let mut sheet = Vec::new();
    for (index, frame) in frames.iter().enumerate() {
        progress(index, frames.len());
        let mut sheet_techniques = Vec::new();
        let view = camera(frame, 1);
        // The reference: the full mesh, streaming settled, drawn K times larger.
        let mut reference_shot: Option<((LinearImage, Mask), Option<f64>)> = None;
        if let (Some(gpu), Some(reference)) = (&gpu, &mut reference) {
            let camera = camera(frame, k);
            let (image, _, gpu_ms) = guarded(gpu, &label, || {
                settle_streaming(gpu, reference, &camera);
                render_image_timed(gpu, reference, &camera, background).map_err(render_failed)
            })?;
            reference_shot = Some((crate::eval::measurable(&image, k, options.background).map_err(internal)?, gpu_ms));
        }
        let reference_noise = match (&reference_shot, &previous_reference) {
            (Some(((image, _), _)), Some(previous)) => Some(temporal_noise(image, previous).map_err(internal)?),
            _ => None,
        };
        for &technique in &measured {
            if technique == TechniqueName::FULL {
                let Some(counter) = &mut full else { continue };
                let (visible, triangles, ms) = counter.count(&forest.trees, &view);
                rows.push(Row {
                    frame: index,
                    technique,
                    instances_visible: visible,
                    triangles,
                    points: 0,
                    quads: 0,
                    ellipsoids: 0,
                    lines: 0,
                    points_in_cut: Some(0),
                    instances_pruned: None,
                    leaves_pruned: None,
                    ranges: None,
                    draw_commands: None,
                    ranges_clamped: None,
                    bytes_uploaded: None,
                    bytes_resident: None,
                    selection_ms: ms,
                    phases: None,
                    gpu_ms: reference_shot.as_ref().and_then(|(_, ms)| *ms),
                    shadow_primitives: None,
                    transitions: None,
                    leaving: None,
                    coverage: None,
                    rmse: None,
                    flip: None,
                    noise: None,
                    reference_noise: None,
                    drawn_with: None,
                    budget: None,
                });
                continue;
            }
            let (Some(gpu), Some(slot)) = (&gpu, flown.iter().position(|f| f.technique == technique)) else { continue };
            let f = &mut flown[slot];
            // One prepare per frame, as a host makes it: streaming keeps up within its budget or
            // draws coarser stand-ins (counted in ranges_clamped).
            let (stats, selection_ms) = guarded(gpu, &label, || {
                let start = Instant::now();
                let stats = f.renderer.prepare(&gpu.device, &gpu.queue, &view);
                gpu.queue.submit([]);
                Ok((stats, start.elapsed().as_secs_f64() * 1e3))
            })?;
            let mut row = Row {
                frame: index,
                technique,
                instances_visible: stats.instances_visible,
                triangles: stats.submitted[Primitive::Triangle],
                points: stats.submitted[Primitive::Point],
                quads: crate::eval::quads(&stats),
                ellipsoids: stats.submitted[Primitive::Ellipsoid],
                lines: stats.submitted[Primitive::Line],
                // Counted on the CPU after the timed selection.
                points_in_cut: (!stats.gpu_selection).then(|| f.renderer.points_in_cut()),
                instances_pruned: Some(
                    stats.instances.get(Technique::PruneOpt) + stats.instances.get(Technique::PruneCook),
                ),
                leaves_pruned: Some(stats.leaves_pruned),
                ranges: Some(stats.ranges),
                draw_commands: Some(stats.draw_commands),
                ranges_clamped: Some(stats.ranges_clamped),
                bytes_uploaded: Some(stats.bytes_uploaded),
                bytes_resident: Some(stats.bytes_resident),
                selection_ms,
                phases: Some(f.renderer.prepare_phases()),
                gpu_ms: None,
                shadow_primitives: options.shadows.then(|| stats.shadow.primitives()),
                transitions: Some(stats.transitions),
                leaving: Some(stats.leaving),
                coverage: None,
                rmse: None,
                flip: None,
                noise: None,
                reference_noise: None,
                drawn_with: Some((stats.instances, stats.by_technique)),
                budget: f.renderer.budget_frame(),
            };
            if options.render {
                let (image, gpu_ms) = guarded(gpu, &label, || {
                    render_prepared_timed(gpu, &mut f.renderer, &view, background).map_err(render_failed)
                })?;
                row.gpu_ms = gpu_ms;
                if let Some(((reference_image, reference_mask), _)) = &reference_shot {
                    let (image, mask) = crate::eval::measurable(&image, 1, options.background).map_err(internal)?;
                    row.coverage = Some(Coverage::compare(reference_mask, &mask).map_err(internal)?);
                    row.rmse = Some(multiscale_rmse(&image, reference_image).map_err(internal)?.summary());
                    row.flip = Some(mean_flip(&image, reference_image).map_err(internal)?);
                    if let Some(last) = &previous[slot] {
                        row.noise = Some(temporal_noise(&image, last).map_err(internal)?);
                        row.reference_noise = reference_noise;
                    }
                    if options.sheet_frames.contains(&index) {
                        sheet_techniques.push((technique, image.clone(), mask));
                    }
                    previous[slot] = Some(image);
                }
            }
            rows.push(row);
        }
        if let Some(((image, mask), _)) = &reference_shot
            && options.sheet_frames.contains(&index)
        {
            sheet.push(SheetFrame {
                frame: index,
                reference: (image.clone(), mask.clone()),
                techniques: sheet_techniques,
            });
        }
        previous_reference = reference_shot.map(|((image, _), _)| image);
    }

    let report = Report {
        models,
        forest,
        frames,
        size: options.size,
        fov_degrees: options.fov_degrees,
        seed: options.seed,
        rendered: options.render,
        quality: options.quality.map(|q| Reference { supersample: k, stochastic_alpha: q != Quality::Plain1x }),
        adapter: gpu.as_ref().map(|g| Adapter::new(&g.info)),
        timestamps: gpu.as_ref().is_some_and(|g| g.device.features().contains(wgpu::Features::TIMESTAMP_QUERY)),
        techniques,
        rows,
        sheet,
        seconds: started.elapsed().as_secs_f64(),
        budget: options.policy.budget,
    };
    Ok(report)
}

/// Runs `f` inside a validation error scope of the device, so that a frame the device refuses
/// (the renderer's draw records of a huge forest outgrowing one storage binding, say) is an error
/// line and exit code 4 rather than wgpu's panic.
fn guarded<R>(gpu: &Gpu, label: &Path, f: impl FnOnce() -> Result<R, Error>) -> Result<R, Error> {
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let result = f();
    if let Some(error) = pollster::block_on(scope.pop()) {
        let text = error.to_string().split_whitespace().collect::<Vec<_>>().join(" ");
        return Err(Error::DeviceRefused { input: label.to_owned(), message: text });
    }
    result
}

/// Opens the models of the inputs (containers, or the models of scene files, each path once), or
/// builds the demo trees when there are none.
fn load_models(inputs: &[PathBuf], techniques: &[TechniqueName]) -> Result<Models, Error> {
    if inputs.is_empty() {
        return demo_models(techniques);
    }
    let mut paths: Vec<PathBuf> = Vec::new();
    for input in inputs {
        if scene::is_container_path(input) {
            if !paths.contains(input) {
                paths.push(input.clone());
            }
        } else {
            let scene = scene::load(input)?;
            for model in scene.models {
                if !paths.contains(&model) {
                    paths.push(model);
                }
            }
        }
    }
    let mut containers = Vec::with_capacity(paths.len());
    for path in &paths {
        if path.is_dir() {
            return Err(Error::ContainerIsDirectory { path: path.clone() });
        }
        let container = Container::open(path).map_err(|source| Error::Container { path: path.clone(), source })?;
        containers.push(Arc::new(container));
    }
    let labels: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    let source = format!("{} model(s): {}", labels.len(), labels.join(", "));
    Ok(Models { source, labels, containers, stochastic: None })
}

/// Pruning lists of the built-in trees: coarser measuring images than a build's default (128
/// pixels, 4 views) keep the benchmark's start short.
fn demo_prune(order: treelod_build::PruneOrder) -> treelod_build::PruneConfig {
    treelod_build::PruneConfig { order, resolution: 128, views: 4, ..treelod_build::PruneConfig::default() }
}

/// The built-in models: [`DEMO_TREES`] built in memory (no file written), in parallel. With
/// `prune-opt` asked for they hold density-ordered priority lists (the order that saved most
/// geometry on the shared models); with `prune-cook` a second set holds stochastic lists; with a
/// baseline (the octahedral impostor among them) or `impostors` asked for they hold baselines and impostors (the impostors set the
/// billboards' budget, and the chain gives the impostor trees' bark); with
/// `ellipsoids` they hold Clasen's ellipsoids and lines (the build's defaults: about a second per
/// tree on 2 cores, so only when asked for); with `policy`, baselines, impostors, ellipsoids and
/// lines and the calibration tables the policy chooses among them with (the build's default
/// calibration, as `treelod build` writes it; without tables the policy would draw every tree
/// with the point tree).
fn demo_models(names: &[TechniqueName]) -> Result<Models, Error> {
    use treelod_build::PruneOrder;
    let techniques: Vec<Technique> = names.iter().filter_map(|n| n.technique()).collect();
    let opt = techniques.contains(&Technique::PruneOpt).then(|| demo_prune(PruneOrder::Density));
    let containers = demo_containers(opt.as_ref(), Extras::for_techniques(names))?;
    let stochastic = match techniques.contains(&Technique::PruneCook) {
        true => Some(demo_containers(Some(&demo_prune(PruneOrder::Stochastic)), Extras::default())?),
        false => None,
    };
    let labels: Vec<String> = DEMO_TREES
        .iter()
        .map(|(seed, leaves, height)| format!("demo tree seed {seed}, {leaves} leaves, trunk {height} m"))
        .collect();
    let source = format!("{} built-in demo trees (seeds 1-{})", labels.len(), labels.len());
    Ok(Models { source, labels, containers, stochastic })
}

/// The optional representations a set of demo trees is built with, besides pruning lists.
#[derive(Clone, Copy, Debug, Default)]
struct Extras {
    /// Baselines and impostors (each needs the other: the impostors' texture budget sets the
    /// billboards', the chain gives the impostor trees' coarse bark).
    baselines: bool,
    /// Clasen's ellipsoids and lines.
    ellipsoids: bool,
    /// Calibration tables (the build's default [`treelod_build::CalibrationConfig`]).
    calibration: bool,
}

impl Extras {
    /// What the demo trees hold for the techniques `names` ([`demo_models`]).
    fn for_techniques(names: &[TechniqueName]) -> Self {
        let policy = names.contains(&TechniqueName::Policy);
        let techniques: Vec<Technique> = names.iter().filter_map(|n| n.technique()).collect();
        Self {
            baselines: policy
                || techniques.iter().any(|t| {
                    matches!(
                        t,
                        Technique::LodChain
                            | Technique::Billboard
                            | Technique::Crossed
                            | Technique::Octahedral
                            | Technique::Impostors
                    )
                }),
            ellipsoids: policy || techniques.contains(&Technique::Ellipsoids),
            calibration: policy,
        }
    }
}

/// [`DEMO_TREES`] built with `prune` and `extras`.
fn demo_containers(prune: Option<&treelod_build::PruneConfig>, extras: Extras) -> Result<Vec<Arc<Container>>, Error> {
    let build = treelod_build::BuildConfig {
        prune: prune.cloned(),
        impostors: extras.baselines.then(treelod_build::ImpostorConfig::default),
        baselines: extras.baselines.then(treelod_build::LodChainConfig::default),
        ellipsoids: extras.ellipsoids.then(treelod_build::EllipsoidConfig::default),
        lines: extras.ellipsoids.then(treelod_build::LineConfig::default),
        calibration: extras.calibration.then(treelod_build::CalibrationConfig::default),
        ..treelod_build::BuildConfig::default()
    };
    let built: Result<Vec<Container>, Error> = DEMO_TREES
        .par_iter()
        .map(|&(seed, leaves, height)| {
            let config =
                treelod_build::DemoTreeConfig { seed, leaves, height, ..treelod_build::DemoTreeConfig::default() };
            let tree = treelod_build::demo_tree(&config);
            let label = Path::new("bench");
            let placed = [treelod_build::Placed { scene: &tree, translation: Vec3::ZERO }];
            let output = treelod_build::build_block(&tree.name, &placed, &build, &generator())
                .map_err(|source| Error::Build { path: label.to_owned(), source })?;
            let container = |source| Error::Container { path: label.to_owned(), source };
            let bytes = output.data.to_bytes(Compression::None).map_err(container)?;
            Container::from_bytes(&bytes).map_err(container)
        })
        .collect();
    Ok(built?.into_iter().map(Arc::new).collect())
}

/// How many of the models hold each technique's data.
fn held_by_models(containers: &[Arc<Container>]) -> PerTechnique<usize> {
    PerTechnique::held_by(containers.iter().map(|c| &**c))
}

/// The generator the built-in trees' containers record: the `treelod` tool's, whose version is
/// the workspace's.
fn generator() -> String {
    format!("treelod {}", env!("CARGO_PKG_VERSION"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in trees hold what each technique draws, and with `policy` every
    /// representation and the calibration tables it chooses with.
    #[test]
    fn the_built_in_trees_hold_what_the_techniques_draw() {
        let name = TechniqueName::Technique;
        let of = |names: &[TechniqueName]| {
            let e = Extras::for_techniques(names);
            (e.baselines, e.ellipsoids, e.calibration)
        };
        assert_eq!(of(&[TechniqueName::Policy]), (true, true, true));
        assert_eq!(of(&[name(Technique::Spt), TechniqueName::FULL]), (false, false, false));
        assert_eq!(of(&[name(Technique::Ellipsoids)]), (false, true, false));
        assert_eq!(of(&[name(Technique::Octahedral)]), (true, false, false));
        assert_eq!(of(&[name(Technique::LodChain), name(Technique::Spt)]), (true, false, false));
    }

    #[test]
    fn pruning_needs_priority_lists() {
        let none = PerTechnique::<usize>::default();
        let name = TechniqueName::Technique;
        assert_eq!(availability(name(Technique::Spt), none), Availability::Measured);
        assert_eq!(availability(TechniqueName::FULL, none), Availability::Measured);
        assert_eq!(availability(TechniqueName::Policy, none), Availability::Measured);
        let cook = availability(name(Technique::PruneCook), none);
        assert_eq!(cook.status(), "absent");
        assert!(cook.reason().is_some_and(|r| r.contains("pruning priority lists")), "{cook:?}");
        let mut some = PerTechnique::<usize>::default();
        *some.get_mut(Technique::PruneOpt) = 4;
        assert_eq!(availability(name(Technique::PruneOpt), some), Availability::Measured);
    }

    #[test]
    fn every_technique_of_the_one_list_flies_with_itself() {
        let options = Options { techniques: TechniqueName::ALL.to_vec(), ..Options::default() };
        for t in Technique::ALL {
            let settings = settings(TechniqueName::Technique(t), &options);
            assert_eq!(settings.map(|s| s.technique), (t != Technique::Full).then_some(t), "{t}");
            assert!(settings.is_none_or(|s| s.policy.is_none()), "{t} is forced");
        }
        let full_1x = settings(TechniqueName::Full1x, &options).expect("drawn");
        assert_eq!((full_1x.technique, full_1x.policy), (Technique::Full, None));
        let none = PerTechnique::<usize>::default();
        let absent = availability(TechniqueName::Technique(Technique::Impostors), none);
        assert!(absent.reason().is_some_and(|r| r.contains("impostor planes")), "{absent:?}");
        assert!(settings(TechniqueName::Technique(Technique::Ellipsoids), &options).is_some_and(|s| s.lines));
    }

    #[test]
    fn the_policy_flies_with_its_target_and_budget() {
        let policy = Policy { target: 0.03, budget: Some(50_000), ..Policy::default() };
        let options = Options { policy, ..Options::default() };
        let flown = settings(TechniqueName::Policy, &options).expect("drawn");
        assert_eq!(flown.policy, Some(policy));
        assert_eq!(flown.technique, Technique::Spt, "models without tables draw the point tree");
        let none = Options { policy: Policy { budget: Some(0), ..Policy::default() }, ..Options::default() };
        assert!(matches!(none.check(), Err(Error::Options { .. })));
    }
}
