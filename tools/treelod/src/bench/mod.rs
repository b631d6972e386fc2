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
//! The tables, CSV, JSON and plot are in [`output`].

mod forest;
mod output;
mod path;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use treelod_format::{Compression, Container, ErrorClass};
use treelod_render::offscreen::{Gpu, render_image_timed, render_prepared_timed};
use treelod_render::{Camera, Instance, ModelId, PerTechnique, Pruning, Renderer, Settings, Technique};

use self::forest::{Forest, Shape};
use self::path::Frame;
use treelod_eval::MetricError;

use crate::eval::metrics::{Coverage, LinearImage, Mask, flip::mean_flip, multiscale_rmse};
use crate::eval::{Adapter, Availability};
use crate::render::{clear_colour, parse_colour, parse_fov, parse_pixels, parse_size};
use crate::report::{self, Failed};
use crate::scene;

/// Instances per call of the full mesh's counting selection: its draw list holds a range per
/// non-empty cell of each (about 60 for the demo tree), so this bounds it to a few tens of MB.
const FULL_COUNT_CHUNK: usize = 8192;

/// The built-in forest's models: demo trees of different seeds, leaf counts and heights.
const DEMO_TREES: [(u64, u32, f32); 4] = [(1, 4000, 4.0), (2, 2500, 3.0), (3, 5000, 5.0), (4, 3000, 4.5)];

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
    #[arg(long, value_name = "NAMES", value_enum, value_delimiter = ',', default_values = ["full", "spt"])]
    pub technique: Vec<Technique>,
    /// Select and stream only: no image is drawn, so there is no GPU time (the figure for large
    /// forests on a software rasteriser).
    #[arg(long, conflicts_with = "quality")]
    pub no_render: bool,
    /// Select `spt` on the GPU (compute shaders write the draws: `Renderer::enable_gpu_selection`,
    /// every model resident whole); its counts are then those of a frame read back one or two
    /// frames earlier, and its selection time is that of `prepare` submitting the compute work.
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
    /// image against it: P, R, Q, multi-scale RMSE and mean FLIP error (slow: the full mesh of
    /// every tree in view). The reference is `treelod eval`'s: supersampled, box-filtered, with
    /// the stochastic alpha test that keeps minified leaves' coverage.
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
    /// Point threshold `s_min` in pixels of `spt`.
    #[arg(long, value_name = "PX", value_parser = parse_pixels)]
    pub s_min: Option<f32>,
    /// Triangle threshold `s_max` in pixels of `spt`.
    #[arg(long, value_name = "PX", value_parser = parse_pixels)]
    pub s_max: Option<f32>,
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
}

/// What `technique` draws, for the JSON summary.
#[must_use]
pub fn description(technique: Technique) -> &'static str {
    match technique {
        Technique::Full => "the full mesh: every triangle of every visible instance",
        t => crate::eval::output::description(crate::eval::TechniqueName::Technique(t)),
    }
}

/// Whether `technique` can be flown over models holding each technique's data as `held` counts
/// them.
fn availability(technique: Technique, held: PerTechnique<usize>) -> Availability {
    crate::eval::availability(crate::eval::TechniqueName::Technique(technique), held, "no model of the forest holds")
}

/// The renderer settings `technique` flies with; `None` for `full`, which is counted apart.
///
/// The pruning techniques fly the renderer's pruning policy ([`Pruning`]'s defaults: trees at
/// least 64 pixels high pruned to the container's `λ(h)` times their visible fraction, with
/// hysteresis; smaller ones by the point tree) with the optimal or Cook's scale. `ellipsoids` flies
/// with the bark as lines where a model has them, at the default quality and level blend;
/// `impostors` with the defaults of `render` (morphing levels, the chain's bark where a model has a
/// chain). Trees whose models lack a technique's data draw with the point tree.
fn settings(technique: Technique, args: &Args) -> Option<Settings> {
    if technique == Technique::Full {
        return None;
    }
    let mut settings = Settings { technique, ..Settings::default() };
    settings.s_min = args.s_min.unwrap_or(settings.s_min);
    settings.s_max = args.s_max.unwrap_or(settings.s_max);
    settings.pruning = Pruning::default();
    settings.shadows = args.shadows.then(treelod_render::Shadows::default);
    settings.lines = true;
    Some(settings)
}

/// One frame of one technique.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Frame index.
    pub frame: usize,
    /// The technique.
    pub technique: Technique,
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
    /// Indirect draws recorded (`None` for the counted full mesh).
    pub ranges: Option<u32>,
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
    /// Coverage against the reference (with `--quality`, not for the reference itself).
    pub coverage: Option<Coverage>,
    /// Multi-scale RMSE summary against the reference.
    pub rmse: Option<f64>,
    /// Mean FLIP error against the reference.
    pub flip: Option<f64>,
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
    pub techniques: Vec<(Technique, Availability)>,
    /// One row per frame and measured technique, frame by frame.
    pub rows: Vec<Row>,
    /// Seconds the whole run took (models, layout, warm-up and frames).
    pub seconds: f64,
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
    technique: Technique,
    renderer: Renderer,
}

/// Runs `treelod bench`.
pub fn run(args: &Args) -> Result<(), Failed> {
    let started = Instant::now();
    for output in [&args.csv, &args.json, &args.plot].into_iter().flatten() {
        if output.is_dir() {
            report::message_error(output, "is a directory; name the file to write");
            return Err(Failed { class: ErrorClass::Io });
        }
    }
    let models = load_models(&args.inputs, &args.technique)?;
    let mut held = held_by_models(&models.containers);
    if let Some(stochastic) = &models.stochastic {
        *held.get_mut(Technique::PruneCook) += held_by_models(stochastic).get(Technique::PruneCook);
    }
    let mut techniques: Vec<(Technique, Availability)> = Vec::new();
    for &technique in &args.technique {
        if !techniques.iter().any(|(t, _)| *t == technique) {
            techniques.push((technique, availability(technique, held)));
        }
    }
    if techniques.iter().all(|(_, a)| *a != Availability::Measured) {
        report::write_stdout(&output::unavailable(&techniques))?;
        report::message_error(&input_label(args), "none of the techniques asked for can be measured");
        return Err(Failed { class: ErrorClass::Unsupported });
    }
    let measured: Vec<Technique> =
        techniques.iter().filter(|(_, a)| *a == Availability::Measured).map(|(t, _)| *t).collect();

    let (width, height) = args.size;
    let fovy = args.fov.to_radians();
    let aspect = width as f32 / height as f32;
    let shapes: Vec<Shape> = models
        .containers
        .iter()
        .map(|c| Shape::from_bounds(Vec3::from_array(c.block().bounds_min), Vec3::from_array(c.block().bounds_max)))
        .collect();
    let trees = usize::try_from(args.trees).unwrap_or(usize::MAX);
    let mut forest = forest::layout(trees, args.seed, &shapes);
    // No trunk stands on the low part of the path (the clearance keeps the camera out of trunks,
    // not out of crowns).
    let clearance = 0.5 * forest.footprint;
    for track in path::ground_track(&forest, fovy, aspect, 1.5 * forest.tree_height) {
        forest::clear_track(&mut forest, &track, clearance);
    }
    let frames = path::fly_through(&forest, args.frames as usize, fovy, aspect);

    // A device only when something is drawn or prepared: the full mesh alone is counted on the CPU.
    let needs_gpu = args.quality || measured.iter().any(|&t| settings(t, args).is_some());
    let gpu = if needs_gpu {
        Some(Gpu::new().map_err(|e| {
            report::message_error(&input_label(args), &format!("cannot render: {e}"));
            Failed { class: ErrorClass::Unsupported }
        })?)
    } else {
        None
    };
    let k = if args.quality && !args.reference_1x { args.supersample } else { 1 };
    if let Some(gpu) = &gpu {
        let limit = gpu.device.limits().max_texture_dimension_2d;
        if u64::from(width) * u64::from(k) > u64::from(limit) || u64::from(height) * u64::from(k) > u64::from(limit) {
            report::message_error(
                &input_label(args),
                &format!(
                    "{width}x{height} (times {k}) is larger than the device draws ({limit} pixels per side at most)"
                ),
            );
            return Err(Failed { class: ErrorClass::Unsupported });
        }
    }

    // The renderers share one list of instances (the same model order in each).
    let instances: Vec<Instance> =
        forest.trees.iter().map(|t| Instance { model: ModelId(t.model), transform: t.transform() }).collect();
    let add = |gpu: &Gpu, settings: Settings, technique: Option<Technique>| -> Result<Renderer, Failed> {
        let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
        let containers = match (&models.stochastic, technique) {
            (Some(stochastic), Some(Technique::PruneCook)) => stochastic,
            _ => &models.containers,
        };
        for (index, (container, label)) in containers.iter().zip(&models.labels).enumerate() {
            let id = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).map_err(|e| {
                report::print_error(&format!("{label}: {e}"));
                Failed { class: ErrorClass::Unsupported }
            })?;
            // A fresh renderer numbers its models in order; the instances rely on it.
            if id.0 as usize != index {
                report::print_error(&format!("{label}: internal error: model {index} got id {}", id.0));
                return Err(Failed { class: ErrorClass::Io });
            }
        }
        renderer.set_instances(&instances);
        if args.gpu_selection && technique == Some(Technique::Spt) {
            renderer.enable_gpu_selection(&gpu.device, &gpu.queue).map_err(|e| {
                report::message_error(&input_label(args), &format!("cannot select on the GPU: {e}"));
                Failed { class: ErrorClass::Unsupported }
            })?;
        }
        Ok(renderer)
    };
    let mut flown = Vec::new();
    let mut reference = None;
    if let Some(gpu) = &gpu {
        for &technique in &measured {
            if let Some(settings) = settings(technique, args) {
                flown.push(Flown { technique, renderer: add(gpu, settings, Some(technique))? });
            }
        }
        if args.quality {
            let settings = if args.reference_1x {
                Settings { technique: Technique::Full, ..Settings::default() }
            } else {
                crate::eval::reference_settings()
            };
            reference = Some(add(gpu, settings, None)?);
        }
    }
    drop(instances);
    let mut full = measured.contains(&Technique::Full).then(|| FullCounter::new(&models.containers));

    let background = clear_colour(args.background);
    let camera =
        |frame: &Frame, k: u32| Camera::look_at(frame.pose.eye, frame.pose.target, fovy, width * k, height * k);
    let internal = |e: MetricError| {
        report::message_error(&input_label(args), &format!("internal error: {e}"));
        Failed { class: ErrorClass::Io }
    };
    let render_failed = |e: treelod_render::offscreen::GpuError| {
        report::message_error(&input_label(args), &format!("cannot render: {e}"));
        Failed { class: ErrorClass::Io }
    };
    // Warm-up at the first frame: streaming loads what it needs (a host's loading screen) and
    // the first draw compiles the shaders, so neither is timed as frame 0.
    if let (Some(gpu), Some(first)) = (&gpu, frames.first()) {
        guarded(gpu, &input_label(args), || {
            for f in &mut flown {
                let camera = camera(first, 1);
                crate::render::settle_streaming(gpu, &mut f.renderer, &camera);
                if !args.no_render {
                    render_image_timed(gpu, &mut f.renderer, &camera, background).map_err(render_failed)?;
                }
            }
            if let Some(reference) = &mut reference {
                let camera = camera(first, k);
                crate::render::settle_streaming(gpu, reference, &camera);
                render_image_timed(gpu, reference, &camera, background).map_err(render_failed)?;
            }
            Ok(())
        })?;
    }
    if let (Some(counter), Some(first)) = (&mut full, frames.first()) {
        counter.count(&forest.trees, &camera(first, 1));
    }

    let progress = progress_bar(frames.len() as u64);
    report::set_progress_bar(Some(progress.clone()));
    let mut rows = Vec::with_capacity(frames.len() * measured.len());
    for (index, frame) in frames.iter().enumerate() {
        progress.set_position(index as u64);
        let view = camera(frame, 1);
        // The reference: the full mesh, streaming settled, drawn K times larger.
        let mut reference_shot: Option<((LinearImage, Mask), Option<f64>)> = None;
        if let (Some(gpu), Some(reference)) = (&gpu, &mut reference) {
            let camera = camera(frame, k);
            let (image, _, gpu_ms) = guarded(gpu, &input_label(args), || {
                crate::render::settle_streaming(gpu, reference, &camera);
                render_image_timed(gpu, reference, &camera, background).map_err(render_failed)
            })?;
            reference_shot = Some((crate::eval::measurable(&image, k, args.background).map_err(internal)?, gpu_ms));
        }
        for &technique in &measured {
            if technique == Technique::Full {
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
                    ranges_clamped: None,
                    bytes_uploaded: None,
                    bytes_resident: None,
                    selection_ms: ms,
                    gpu_ms: reference_shot.as_ref().and_then(|(_, ms)| *ms),
                    shadow_primitives: None,
                    coverage: None,
                    rmse: None,
                    flip: None,
                });
                continue;
            }
            let (Some(gpu), Some(f)) = (&gpu, flown.iter_mut().find(|f| f.technique == technique)) else { continue };
            // One prepare per frame, as a host makes it: streaming keeps up within its budget or
            // draws coarser stand-ins (counted in ranges_clamped).
            let (stats, selection_ms) = guarded(gpu, &input_label(args), || {
                let start = Instant::now();
                let stats = f.renderer.prepare(&gpu.device, &gpu.queue, &view);
                gpu.queue.submit([]);
                Ok((stats, start.elapsed().as_secs_f64() * 1e3))
            })?;
            let mut row = Row {
                frame: index,
                technique,
                instances_visible: stats.instances_visible,
                triangles: stats.triangles,
                points: stats.points,
                quads: crate::eval::quads(&stats),
                ellipsoids: stats.ellipsoids,
                lines: stats.lines,
                // Counted on the CPU after the timed selection.
                points_in_cut: (!stats.gpu_selection).then(|| f.renderer.points_in_cut()),
                instances_pruned: Some(
                    stats.instances.get(Technique::PruneOpt) + stats.instances.get(Technique::PruneCook),
                ),
                leaves_pruned: Some(stats.leaves_pruned),
                ranges: Some(stats.ranges),
                ranges_clamped: Some(stats.ranges_clamped),
                bytes_uploaded: Some(stats.bytes_uploaded),
                bytes_resident: Some(stats.bytes_resident),
                selection_ms,
                gpu_ms: None,
                shadow_primitives: args.shadows.then(|| stats.shadow.primitives()),
                coverage: None,
                rmse: None,
                flip: None,
            };
            if !args.no_render {
                let (image, gpu_ms) = guarded(gpu, &input_label(args), || {
                    render_prepared_timed(gpu, &mut f.renderer, &view, background).map_err(render_failed)
                })?;
                row.gpu_ms = gpu_ms;
                if let Some(((reference_image, reference_mask), _)) = &reference_shot {
                    let (image, mask) = crate::eval::measurable(&image, 1, args.background).map_err(internal)?;
                    row.coverage = Some(Coverage::compare(reference_mask, &mask).map_err(internal)?);
                    row.rmse = Some(multiscale_rmse(&image, reference_image).map_err(internal)?.summary());
                    row.flip = Some(mean_flip(&image, reference_image).map_err(internal)?);
                }
            }
            rows.push(row);
        }
    }
    progress.finish_and_clear();
    report::set_progress_bar(None);

    let report = Report {
        models,
        forest,
        frames,
        size: args.size,
        fov_degrees: args.fov,
        seed: args.seed,
        rendered: !args.no_render,
        quality: args.quality.then_some(Reference { supersample: k, stochastic_alpha: !args.reference_1x }),
        adapter: gpu.as_ref().map(|g| Adapter::new(&g.info)),
        timestamps: gpu.as_ref().is_some_and(|g| g.device.features().contains(wgpu::Features::TIMESTAMP_QUERY)),
        techniques,
        rows,
        seconds: started.elapsed().as_secs_f64(),
    };
    if let Some(csv) = &args.csv {
        report::write_atomically(csv, output::csv(&report).as_bytes())?;
    }
    if let Some(json) = &args.json {
        crate::render::write_json(json, output::json(&report))?;
    }
    if let Some(plot) = &args.plot {
        crate::render::write_png(plot, &output::plot(&report))?;
    }
    report::write_stdout(&output::text(&report, [&args.csv, &args.json, &args.plot]))
}

/// Runs `f` inside a validation error scope of the device, so that a frame the device refuses
/// (the renderer's draw records of a huge forest outgrowing one storage binding, say) is an error
/// line and exit code 4 rather than wgpu's panic.
fn guarded<R>(gpu: &Gpu, label: &Path, f: impl FnOnce() -> Result<R, Failed>) -> Result<R, Failed> {
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let result = f();
    if let Some(error) = pollster::block_on(scope.pop()) {
        let text = error.to_string().split_whitespace().collect::<Vec<_>>().join(" ");
        report::message_error(
            label,
            &format!(
                "the device refused a frame: {text} (a frame of this forest may need more draws than the device \
                 binds in one buffer: try fewer --trees)"
            ),
        );
        return Err(Failed { class: ErrorClass::Unsupported });
    }
    result
}

/// What error lines name when no file is to blame: the inputs, or `bench` for the built-in forest.
fn input_label(args: &Args) -> PathBuf {
    match args.inputs.as_slice() {
        [] => PathBuf::from("bench"),
        [one] => one.clone(),
        [first, ..] => first.clone(),
    }
}

/// Opens the models of the inputs (containers, or the models of scene files, each path once), or
/// builds the demo trees when there are none.
fn load_models(inputs: &[PathBuf], techniques: &[Technique]) -> Result<Models, Failed> {
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
            let scene = scene::load(input).map_err(|e| crate::render::scene_failed(&e))?;
            for model in scene.models {
                if !paths.contains(&model) {
                    paths.push(model);
                }
            }
        }
    }
    let mut containers = Vec::with_capacity(paths.len());
    for path in &paths {
        containers.push(Arc::new(report::open(path)?));
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
/// baseline or `impostors` asked for they hold baselines and impostors (the impostors set the
/// billboards' budget, and the chain gives the impostor trees' bark); with
/// `ellipsoids` they hold Clasen's ellipsoids and lines (the build's defaults: about a second per
/// tree on 2 cores, so only when asked for).
fn demo_models(techniques: &[Technique]) -> Result<Models, Failed> {
    use treelod_build::PruneOrder;
    let opt = techniques.contains(&Technique::PruneOpt).then(|| demo_prune(PruneOrder::Density));
    let extras = Extras {
        baselines: techniques.iter().any(|t| {
            matches!(t, Technique::LodChain | Technique::Billboard | Technique::Crossed | Technique::Impostors)
        }),
        ellipsoids: techniques.contains(&Technique::Ellipsoids),
    };
    let containers = demo_containers(opt.as_ref(), extras)?;
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
}

/// [`DEMO_TREES`] built with `prune` and `extras`.
fn demo_containers(prune: Option<&treelod_build::PruneConfig>, extras: Extras) -> Result<Vec<Arc<Container>>, Failed> {
    let build = treelod_build::BuildConfig {
        prune: prune.cloned(),
        impostors: extras.baselines.then(treelod_build::ImpostorConfig::default),
        baselines: extras.baselines.then(treelod_build::LodChainConfig::default),
        ellipsoids: extras.ellipsoids.then(treelod_build::EllipsoidConfig::default),
        lines: extras.ellipsoids.then(treelod_build::LineConfig::default),
        ..treelod_build::BuildConfig::default()
    };
    let built: Result<Vec<Container>, Failed> = DEMO_TREES
        .par_iter()
        .map(|&(seed, leaves, height)| {
            let config =
                treelod_build::DemoTreeConfig { seed, leaves, height, ..treelod_build::DemoTreeConfig::default() };
            let tree = treelod_build::demo_tree(&config);
            let label = Path::new("bench");
            let placed = [treelod_build::Placed { scene: &tree, translation: Vec3::ZERO }];
            let output = treelod_build::build_block(&tree.name, &placed, &build, &crate::build::generator())
                .map_err(|e| report::build_error(label, &e))?;
            let bytes = output.data.to_bytes(Compression::None).map_err(|e| report::file_error(label, &e))?;
            Container::from_bytes(&bytes).map_err(|e| report::file_error(label, &e))
        })
        .collect();
    Ok(built?.into_iter().map(Arc::new).collect())
}

/// How many of the models hold each technique's data.
fn held_by_models(containers: &[Arc<Container>]) -> PerTechnique<usize> {
    PerTechnique::held_by(containers.iter().map(|c| &**c))
}

/// A progress bar on stderr (drawn only on a terminal).
fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} bench [frame {pos}/{len}] {elapsed}") {
        bar.set_style(style);
    }
    bar
}

#[cfg(test)]
mod tests {
    use clap::Parser as _;

    use super::*;

    #[test]
    fn pruning_needs_priority_lists() {
        let none = PerTechnique::<usize>::default();
        assert_eq!(availability(Technique::Spt, none), Availability::Measured);
        assert_eq!(availability(Technique::Full, none), Availability::Measured);
        let cook = availability(Technique::PruneCook, none);
        assert_eq!(cook.status(), "absent");
        assert!(cook.reason().is_some_and(|r| r.contains("pruning priority lists")), "{cook:?}");
        let mut some = PerTechnique::<usize>::default();
        *some.get_mut(Technique::PruneOpt) = 4;
        assert_eq!(availability(Technique::PruneOpt, some), Availability::Measured);
    }

    #[derive(Debug, clap::Parser)]
    struct BenchCli {
        #[command(flatten)]
        args: Args,
    }

    #[test]
    fn every_technique_of_the_one_list_flies_with_itself() {
        let names: Vec<&str> = Technique::ALL.iter().map(|t| t.name()).collect();
        let args = BenchCli::try_parse_from(["bench", "--technique", &names.join(",")]).expect("parses").args;
        assert_eq!(args.technique, Technique::ALL);
        for t in Technique::ALL {
            let settings = settings(t, &args);
            assert_eq!(settings.map(|s| s.technique), (t != Technique::Full).then_some(t), "{t}");
        }
        let none = PerTechnique::<usize>::default();
        let absent = availability(Technique::Impostors, none);
        assert!(absent.reason().is_some_and(|r| r.contains("impostor planes")), "{absent:?}");
        assert!(settings(Technique::Ellipsoids, &args).is_some_and(|s| s.lines));
    }
}
