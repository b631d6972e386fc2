//! `treelod render`: draws a container or a scene file offscreen (wgpu on Vulkan; Mesa lavapipe on
//! machines without a GPU) and writes a PNG, optionally beside the full mesh for comparison.

use std::path::{Path, PathBuf};

use glam::Vec3;
use treelod_format::ErrorClass;
use treelod_render::offscreen::{Gpu, Image, render_prepared_scene};
use treelod_render::{
    Casters, DebugView, FrameStats, Ground, ImpostorBark, Primitive, Pruning, Renderer, Settings, Shadows, Technique,
};

use crate::report::{self, Failed};
use crate::scene;
pub use treelod_harness::offscreen::{clear_colour, encode_png, frame_camera, settle_streaming};

/// Arguments of `treelod render`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A `.treelod` container (drawn once at the origin) or a JSON scene file.
    #[arg(value_name = "FILE|SCENE")]
    pub input: PathBuf,
    /// Where to write the PNG.
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Image size in pixels, `WIDTHxHEIGHT`.
    #[arg(long, value_name = "WxH", default_value = "1024x768", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Eye position `x,y,z` (metres); default: framing the whole scene from the front right.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<Vec3>,
    /// Point looked at, `x,y,z` (metres); default: the centre of the scene's bounds.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub target: Option<Vec3>,
    /// Vertical field of view in degrees.
    #[arg(long, value_name = "DEGREES", default_value_t = 50.0, value_parser = parse_fov)]
    pub fov: f32,
    /// Write the level of detail (left) beside the full mesh (right), twice as wide.
    #[arg(long)]
    pub compare: bool,
    /// With shadows: render the image again with every tree casting its full mesh (the camera's
    /// trees drawn as before) and print the image's error against it, multi-scale RMSE and FLIP:
    /// what the shadow pass's choice of representations costs in the picture.
    #[arg(long)]
    pub shadow_error: bool,
    /// Colour by grid cell (`cells`), by kind (`kinds`: triangles red, points blue, pruned
    /// leaves green, impostor planes yellow, billboards magenta, octahedral impostors pink,
    /// ellipsoids cyan, lines brown), by level (`levels`: one colour per octave of each point's,
    /// plane's, ellipsoid's or line's interval, triangles light grey) or by the technique each
    /// tree is drawn with (`techniques`: what the policy chose; full grey, spt blue, prune-opt
    /// green, prune-cook dark green, impostors yellow, ellipsoids cyan, lod-chain red, billboard
    /// magenta, crossed violet, octahedral pink).
    #[arg(long, value_name = "VIEW", value_parser = ["cells", "kinds", "levels", "techniques"])]
    pub debug: Option<String>,
    /// MSAA samples, 1 or 4; with 4, alpha-tested leaves cover samples in proportion to their
    /// filtered alpha (alpha to coverage) instead of being tested against the cutoff.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = parse_msaa)]
    pub msaa: u32,
    #[command(flatten)]
    pub thresholds: ThresholdArgs,
    /// Background colour, `RRGGBB` (sRGB hex, an optional leading `#`).
    #[arg(long, value_name = "RRGGBB", default_value = "ffffff", value_parser = parse_colour)]
    pub background: [u8; 3],
    #[command(flatten)]
    pub technique: TechniqueArgs,
    #[command(flatten)]
    pub prune: PruneArgs,
    #[command(flatten)]
    pub light: LightArgs,
    #[command(flatten)]
    pub shadow: ShadowArgs,
    #[command(flatten)]
    pub impostor: ImpostorArgs,
    #[command(flatten)]
    pub ellipsoid: EllipsoidArgs,
    /// Select on the GPU (compute shaders write the indirect draws; every model is kept resident
    /// whole): every tree with `spt`, the trees drawn with the point tree with the policy (the
    /// CPU chooses and selects the others). Other forced techniques, shadows and the full mesh
    /// (`--compare`'s right half) select on the CPU.
    #[arg(long)]
    pub gpu_selection: bool,
}

/// The technique trees are drawn with: shared by `render` and `view`.
#[derive(Debug, clap::Args)]
pub struct TechniqueArgs {
    /// Draw every tree with one technique: `spt` (triangles and points, Gilet 2005), `prune-opt`
    /// and `prune-cook` (trees at least 64 pixels high with pruned leaves, Neubert 2011, scaled by
    /// the container's s_opt(λ) or by Cook's 1/λ; build with `--prune`), `impostors`
    /// (leaf-cluster planes, Garcia 2005; build with `--impostors`), `ellipsoids` (leaf
    /// ellipsoids and branch lines, Clasen 2011; build with `--ellipsoids --lines`), the
    /// baselines `lod-chain`, `billboard` and `crossed` (build with `--baselines`), or `full`
    /// (every triangle). Trees whose containers lack the technique's data are drawn with `spt`.
    /// Without it, the policy chooses per tree: the cheapest representation whose calibrated
    /// error at the tree's size on screen is within `--policy-target` of the least error there
    /// of the full mesh and every representation (the point tree for containers without
    /// calibration tables).
    #[arg(long, value_name = "TECHNIQUE", value_enum)]
    pub technique: Option<Technique>,
    /// The policy's target: image error (multi-scale RMSE, as the calibration measures it) allowed over the least
    /// error of the full mesh and every representation at each tree's projected size, for a tree up
    /// to 64 pixels high (a taller one `h` pixels high: `target · 64 / h`); 0 keeps the best image
    /// the tables know.
    #[arg(long, value_name = "ERROR", default_value_t = treelod_render::Policy::DEFAULT_TARGET, value_parser = parse_target, conflicts_with = "technique")]
    pub policy_target: f32,
}

/// Parses the policy's target: a number in `0..=1`.
pub fn parse_target(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("expected an error target, a number in 0..=1, got {s:?}")),
    }
}

impl TechniqueArgs {
    /// The technique trees are drawn with where the policy does not choose.
    #[must_use]
    pub fn technique(&self) -> Technique {
        self.technique.unwrap_or(Technique::FALLBACK)
    }

    /// Sets `settings` to the technique forced, or to the policy with its target.
    pub fn apply(&self, settings: &mut Settings) {
        settings.technique = self.technique();
        settings.policy = match self.technique {
            Some(_) => None,
            None => Some(treelod_render::Policy { target: self.policy_target, ..treelod_render::Policy::default() }),
        };
    }

    /// Warns about each model of `models` (its path and the container opened from it) that lacks
    /// the forced technique's data (its trees are drawn with the point tree instead).
    pub fn warn_without<'a>(&self, models: impl IntoIterator<Item = (&'a Path, &'a treelod_format::Container)>) {
        let Some(technique) = self.technique else { return };
        let Some(data) = technique.needs() else { return };
        for (path, container) in models {
            if !technique.held_by(container) {
                let message = format!(
                    "holds no {}; its trees are drawn with {} instead of {}",
                    data.description(),
                    Technique::FALLBACK,
                    technique
                );
                report::print_warning(path, &message);
            }
        }
    }
}

/// The trees drawn with each technique, for summaries: `3 spt, 12 crossed`.
#[must_use]
/// What a frame submitted, by kind (those it submitted any of: "1200 triangles, 40 planes"), and
/// the leaves pruned trees drew.
pub fn submitted(stats: &FrameStats) -> String {
    let mut parts: Vec<String> =
        stats.submitted.iter().filter(|&(_, n)| n > 0).map(|(kind, n)| format!("{n} {}", kind.name())).collect();
    if stats.leaves_pruned > 0 {
        parts.push(format!("{} pruned leaves", stats.leaves_pruned));
    }
    if parts.is_empty() { "nothing".to_owned() } else { parts.join(", ") }
}

/// Trees per technique, for a summary line ("3 spt, 5 impostors").
pub fn technique_counts(instances: &treelod_render::PerTechnique<u32>) -> String {
    let parts: Vec<String> = instances.iter().filter(|&(_, n)| n > 0).map(|(t, n)| format!("{n} {t}")).collect();
    if parts.is_empty() { "none".to_owned() } else { parts.join(", ") }
}

/// The point tree's thresholds in pixels: options shared by `render`, `eval` and `bench` (each
/// keeps the settings' default where not given).
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct ThresholdArgs {
    /// Point threshold `s_min` in pixels (Gilet 2005): points are drawn down to this size.
    #[arg(long, value_name = "PX", value_parser = parse_pixels)]
    pub s_min: Option<f32>,
    /// Triangle threshold `s_max` in pixels: triangles larger than this are drawn as triangles.
    #[arg(long, value_name = "PX", value_parser = parse_pixels)]
    pub s_max: Option<f32>,
}

impl ThresholdArgs {
    /// Sets the thresholds given in `settings`.
    pub fn apply(self, settings: &mut Settings) {
        if let Some(s_min) = self.s_min {
            settings.s_min = s_min;
        }
        if let Some(s_max) = self.s_max {
            settings.s_max = s_max;
        }
    }
}

/// How trees drawn with impostor planes change level and draw their bark: options shared by
/// `render`, `view` and `eval`.
#[derive(Debug, clap::Args)]
pub struct ImpostorArgs {
    /// With impostors: switch between levels of planes at once instead of sliding each plane onto
    /// its parent's over the last octave of its distances (Garcia's smooth level of detail) and
    /// cross-fading their textures over the last quarter (both on by default).
    #[arg(long)]
    pub no_impostor_morph: bool,
    /// With impostors: the bark beside the planes. `lines` (the default): the branch lines where
    /// the container has them (built with `--lines`), as ellipsoid trees draw them, else as
    /// `chain`; `chain`: where the container has a LoD chain (built with `--baselines`), the
    /// chain's bark at the coarsest level whose error projects below half of `--s-min` pixels
    /// among those keeping 90 % of the bark's area, else all bark; `all`: every bark triangle.
    #[arg(long, value_name = "BARK", default_value = "lines", value_parser = ["lines", "chain", "all"])]
    pub impostor_bark: String,
}

impl ImpostorArgs {
    /// Sets the renderer's impostor morph and bark from these options.
    pub fn apply(&self, settings: &mut Settings) {
        settings.impostor_morph = !self.no_impostor_morph;
        settings.impostor_bark = match self.impostor_bark.as_str() {
            "all" => ImpostorBark::All,
            "lines" => ImpostorBark::Lines,
            _ => ImpostorBark::Chain,
        };
    }
}

/// Clasen's ellipsoids: options shared by `render` and `view`.
#[derive(Debug, clap::Args)]
pub struct EllipsoidArgs {
    /// With ellipsoids (leaves ray-cast per pixel with their noise, per cell the level whose
    /// interval holds the metres per pixel at the cell's distance divided by this factor, bark as
    /// the containers' branch lines where they have them): the quality factor `q`; the level drawn is the one for pixels `q` times
    /// smaller (2: finer, 0.5: coarser).
    #[arg(long, value_name = "Q", default_value_t = 1.0, value_parser = parse_quality)]
    pub ellipsoid_quality: f32,
    /// With ellipsoids: blend ellipsoids and lines from one level to the next over this many
    /// octaves of the metres per pixel (on complementary dithered pixels) instead of switching
    /// at once; 0 switches at once, at most 2.
    #[arg(long, value_name = "OCTAVES", default_value_t = 0.5, value_parser = parse_level_blend)]
    pub level_blend: f32,
    /// With ellipsoids: draw the bark as triangles even where the container has branch lines.
    #[arg(long)]
    pub no_lines: bool,
}

impl EllipsoidArgs {
    /// Sets the renderer's ellipsoid options from these.
    pub fn apply(&self, settings: &mut Settings) {
        settings.ellipsoid_quality = self.ellipsoid_quality;
        settings.level_blend = self.level_blend;
        settings.lines = !self.no_lines;
    }
}

/// A quality factor: finite and > 0.
pub fn parse_quality(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("expected a quality factor, a finite number > 0, got {s:?}")),
    }
}

/// A level blend in octaves: finite, in `0..=2`.
pub fn parse_level_blend(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if (0.0..=2.0).contains(&v) => Ok(v),
        _ => Err(format!("expected a level blend in octaves, a number in 0..=2, got {s:?}")),
    }
}

/// Lighting options shared by `render` and `view`.
#[derive(Debug, clap::Args)]
pub struct LightArgs {
    /// Direction towards the sun, `x,y,z` (any length but zero) [default: 0.4,0.8,0.45].
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_direction, allow_hyphen_values = true)]
    pub sun: Option<Vec3>,
    /// Colour of the sunlight, `RRGGBB` in sRGB hex (e.g. `fff2d9` for a warm afternoon)
    /// [default: ffffff].
    #[arg(long, value_name = "RRGGBB", value_parser = parse_colour)]
    pub sun_colour: Option<[u8; 3]>,
    /// Ambient share of the light, 0..=1: a surface receives `ambient + (1 − ambient)·|n·l|` of
    /// the sun [default: 0.35].
    #[arg(long, value_name = "SHARE", value_parser = parse_share)]
    pub ambient: Option<f32>,
    /// Gilet's self-shadowing estimate (2005 §5.3) instead of none: each cell's brightness from
    /// `L_m` at the front of its tree to `L_M` at the back, `L_m,L_M` each in 0..=1 (e.g. `0.6,1`).
    #[arg(long, value_name = "L_m,L_M", value_parser = parse_self_shadow)]
    pub self_shadow: Option<(f32, f32)>,
    /// Ignore the containers' precomputed ambient occlusion (spec §6.14; `build --ao-rays`):
    /// the ambient share reaches every surface whole.
    #[arg(long)]
    pub no_ao: bool,
}

impl LightArgs {
    /// Sets the renderer's light from these options; those not given keep `settings`' values.
    pub fn apply(&self, settings: &mut Settings) {
        if let Some(sun) = self.sun {
            settings.sun = sun;
        }
        if let Some(colour) = self.sun_colour {
            let linear = clear_colour(colour);
            #[expect(clippy::cast_possible_truncation, reason = "colour components in [0, 1]")]
            let rgb = Vec3::new(linear.r as f32, linear.g as f32, linear.b as f32);
            settings.sun_colour = rgb;
        }
        if let Some(ambient) = self.ambient {
            settings.ambient = ambient;
        }
        if self.self_shadow.is_some() {
            settings.shading = self.self_shadow;
        }
        settings.ambient_occlusion = !self.no_ao;
    }
}

/// Shadow-map options shared by `render` and `view`.
#[derive(Debug, clap::Args)]
pub struct ShadowArgs {
    /// Cascaded shadow maps of the sun, and a ground under the trees receiving them: each cascade
    /// is one more depth-only pass with its own level-of-detail selection from the sun's view
    /// (sizes in shadow-map texels). Any `--shadow-*` option below implies it.
    #[arg(long)]
    pub shadows: bool,
    /// Texels per side of each cascade's shadow map, 16..=8192 (implies `--shadows`)
    /// [default: 2048].
    #[arg(long, value_name = "N", allow_negative_numbers = true,
          value_parser = clap::value_parser!(u32).range(16..=8192))]
    pub shadow_resolution: Option<u32>,
    /// Shadow cascades, 1..=4, splitting the distance up to `--shadow-distance` (implies
    /// `--shadows`) [default: 3].
    #[arg(long, value_name = "N", allow_negative_numbers = true,
          value_parser = clap::value_parser!(u32).range(1..=4))]
    pub shadow_cascades: Option<u32>,
    /// Distance from the eye up to which surfaces receive shadows, metres, > 0 (implies
    /// `--shadows`) [default: 150].
    #[arg(long, value_name = "METRES", value_parser = parse_distance, allow_negative_numbers = true)]
    pub shadow_distance: Option<f32>,
    /// What the cascades cast each tree with, chosen as the camera's trees are: `coarser`, at the
    /// smaller of the tree's heights on screen and in the cascade's selection pixels; `light`, at
    /// its height in the cascade alone; `camera`, what the camera draws it with (implies
    /// `--shadows`) [default: coarser].
    #[arg(long, value_name = "FROM", value_parser = ["coarser", "light", "camera"])]
    pub shadow_casters: Option<String>,
}

impl ShadowArgs {
    /// Whether these options turn shadows on: `--shadows` or any `--shadow-*` value.
    pub fn enabled(&self) -> bool {
        self.shadows
            || self.shadow_resolution.is_some()
            || self.shadow_cascades.is_some()
            || self.shadow_distance.is_some()
            || self.shadow_casters.is_some()
    }

    /// `base` with the values these options give.
    pub fn shadows(&self, base: Shadows) -> Shadows {
        Shadows {
            resolution: self.shadow_resolution.unwrap_or(base.resolution),
            cascades: self.shadow_cascades.unwrap_or(base.cascades),
            distance: self.shadow_distance.unwrap_or(base.distance),
            casters: match self.shadow_casters.as_deref() {
                Some("camera") => Casters::CameraView,
                Some("light") => Casters::LightView,
                Some(_) => Casters::Coarser,
                None => base.casters,
            },
            ..base
        }
    }

    /// Turns the renderer's shadows on with these options' values (the others kept from
    /// `settings`' shadows, or the defaults), if [`Self::enabled`]; otherwise leaves them.
    pub fn apply(&self, settings: &mut Settings) {
        if self.enabled() {
            settings.shadows = Some(self.shadows(settings.shadows.unwrap_or_default()));
        }
    }
}

/// Pruning options shared by `render` and `view`.
#[derive(Debug, clap::Args)]
pub struct PruneArgs {
    /// With `--technique prune-opt` or `prune-cook` (a fraction λ of each cell's leaves, most
    /// important first, scaled; bark whole; λ the container's λ(h) for the tree's projected
    /// height, times the visible fraction of the tree measured on the previous frame): a fixed
    /// fraction of leaves in (0, 1] instead of λ(h).
    #[arg(long, value_name = "LAMBDA", value_parser = parse_fraction)]
    pub prune_lambda: Option<f32>,
}

impl PruneArgs {
    /// The renderer's pruning settings these options ask for; exits with a usage error if they
    /// are given with a technique that does not prune.
    pub fn settings(&self, technique: Technique) -> Pruning {
        if self.prune_lambda.is_some() && treelod_render::prune_scale(technique).is_none() {
            clap::Error::raw(
                clap::error::ErrorKind::ArgumentConflict,
                format!("--prune-lambda needs --technique prune-opt or prune-cook, not {technique}\n"),
            )
            .exit();
        }
        Pruning { lambda: self.prune_lambda, ..Pruning::default() }
    }
}

/// The renderer's debug view for a `--debug` value (checked by clap; anything else, `view`'s
/// `error` among them, is the shaded view).
pub fn parse_debug(name: Option<&str>) -> DebugView {
    match name {
        Some("cells") => DebugView::Cells,
        Some("kinds") => DebugView::Kinds,
        Some("levels") => DebugView::Levels,
        Some("techniques") => DebugView::Techniques,
        _ => DebugView::Shaded,
    }
}

/// Parses a fraction in (0, 1].
pub fn parse_fraction(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v > 0.0 && v <= 1.0 => Ok(v),
        _ => Err(format!("expected a fraction in (0, 1], got {s:?}")),
    }
}

pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let err = || format!("expected WIDTHxHEIGHT, each 1..=16384 pixels (e.g. 1024x768), got {s:?}");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(err)?;
    let n = |v: &str| v.trim().parse::<u32>().ok().filter(|n| (1..=16384).contains(n)).ok_or_else(err);
    Ok((n(w)?, n(h)?))
}

pub fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let values: Vec<Option<f32>> =
        s.split(',').map(|v| v.trim().parse::<f32>().ok().filter(|v| v.is_finite())).collect();
    match values.as_slice() {
        [Some(x), Some(y), Some(z)] => Ok(Vec3::new(*x, *y, *z)),
        _ => Err(format!("expected X,Y,Z (three finite numbers), got {s:?}")),
    }
}

/// A direction: three finite numbers, not all zero.
pub fn parse_direction(s: &str) -> Result<Vec3, String> {
    let v = parse_vec3(s)?;
    if v.length_squared() > 0.0 && v.length_squared().is_finite() {
        Ok(v)
    } else {
        Err(format!("expected a direction X,Y,Z (three finite numbers, not all zero), got {s:?}"))
    }
}

/// A share in [0, 1].
pub fn parse_share(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("expected a share in [0, 1], got {s:?}")),
    }
}

/// Gilet's `L_m,L_M`: two brightnesses in [0, 1].
pub fn parse_self_shadow(s: &str) -> Result<(f32, f32), String> {
    let err = || format!("expected L_m,L_M (two brightnesses in [0, 1], e.g. 0.6,1), got {s:?}");
    let (a, b) = s.split_once(',').ok_or_else(err)?;
    Ok((parse_share(a).map_err(|_| err())?, parse_share(b).map_err(|_| err())?))
}

pub fn parse_fov(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if (1.0..=170.0).contains(&v) => Ok(v),
        _ => Err(format!("expected a field of view in degrees, 1..=170, got {s:?}")),
    }
}

pub fn parse_pixels(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("expected a size in pixels, a number ≥ 0, got {s:?}")),
    }
}

/// Parses an MSAA sample count: 1 or 4, the counts every adapter offers for the offscreen formats.
pub fn parse_msaa(s: &str) -> Result<u32, String> {
    match s.trim() {
        "1" => Ok(1),
        "4" => Ok(4),
        _ => Err(format!("expected 1 or 4 MSAA samples, got {s:?}")),
    }
}

pub fn parse_colour(s: &str) -> Result<[u8; 3], String> {
    let hex = s.trim().trim_start_matches('#');
    let err = || format!("expected a colour RRGGBB in hex (e.g. ffffff), got {s:?}");
    if hex.len() != 6 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(err());
    }
    let byte = |i: usize| u8::from_str_radix(&hex[i..i + 2], 16).map_err(|_| err());
    Ok([byte(0)?, byte(2)?, byte(4)?])
}

/// Runs `treelod render`.
pub fn run(args: &Args) -> Result<(), Failed> {
    if let (Some(eye), Some(target)) = (args.eye, args.target)
        && eye.distance_squared(target) < 1e-12
    {
        clap::Error::raw(clap::error::ErrorKind::ValueValidation, "--eye and --target are the same point\n").exit();
    }
    let scene = scene::load(&args.input).map_err(|e| scene_failed(&e))?;
    let gpu = Gpu::new().map_err(|e| {
        report::message_error(&args.output, &format!("cannot render: {e}"));
        Failed { class: ErrorClass::Unsupported }
    })?;
    let (width, height) = args.size;
    let limit = gpu.device.limits().max_texture_dimension_2d;
    if width > limit || height > limit {
        report::message_error(
            &args.output,
            &format!("{width}x{height} is larger than the device draws ({limit} pixels per side at most)"),
        );
        return Err(Failed { class: ErrorClass::Unsupported });
    }
    let mut settings = Settings::default();
    args.thresholds.apply(&mut settings);
    settings.debug = parse_debug(args.debug.as_deref());
    args.technique.apply(&mut settings);
    settings.pruning = args.prune.settings(settings.technique);
    args.light.apply(&mut settings);
    args.shadow.apply(&mut settings);
    args.impostor.apply(&mut settings);
    args.ellipsoid.apply(&mut settings);
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats_msaa(args.msaa), settings);
    let models = scene::open_models(&scene).map_err(|e| scene_failed(&e))?;
    let bounds =
        scene::add_opened(&scene, &models, &gpu.device, &gpu.queue, &mut renderer).map_err(|e| scene_failed(&e))?;
    args.technique.warn_without(scene.models.iter().map(PathBuf::as_path).zip(models.iter().map(|m| &**m)));
    // With shadows, a ground under the trees receives them.
    let ground = renderer.settings().shadows.is_some().then(|| Ground::under_instances(&gpu.device, &renderer));
    if args.gpu_selection {
        renderer.enable_gpu_selection(&gpu.device, &gpu.queue).map_err(|e| {
            report::message_error(&args.input, &format!("cannot select on the GPU: {e}"));
            Failed { class: ErrorClass::Unsupported }
        })?;
    }
    let camera = frame_camera(bounds, args.eye, args.target, args.fov.to_radians(), width, height);
    let background = clear_colour(args.background);
    let render = |renderer: &mut Renderer| -> Result<(Image, FrameStats), Failed> {
        settle_streaming(&gpu, renderer, &camera);
        if renderer.gpu_selection_enabled() {
            // GPU selection reports the counts of a frame read back earlier: let the settling
            // frame (same camera) finish, so the image's frame reports its counts.
            let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
        }
        let frame = |renderer: &mut Renderer| {
            let stats = renderer.prepare(&gpu.device, &gpu.queue, &camera);
            render_prepared_scene(&gpu, renderer, &camera, background, ground.as_ref(), true)
                .map(|(image, _)| (image, stats))
                .map_err(|e| {
                    report::message_error(&args.output, &format!("cannot render: {e}"));
                    Failed { class: ErrorClass::Io }
                })
        };
        if treelod_render::prune_scale(renderer.settings().technique).is_some() {
            // The occlusion factor of pruned trees is measured on the frame before.
            frame(renderer)?;
        }
        frame(renderer)
    };
    let (lod, stats) = render(&mut renderer)?;
    let mut line = format!(
        "{}: {width}x{height}, {} of {} instance(s) visible, {} triangles, {} points",
        args.output.display(),
        stats.instances_visible,
        scene.instances.len(),
        stats.submitted[Primitive::Triangle],
        stats.submitted[Primitive::Point]
    );
    let technique = renderer.settings().technique;
    let drawn = stats.instances.get(technique);
    if renderer.settings().policy.is_some() {
        line.push_str(&format!(", policy: {}", technique_counts(&stats.instances)));
        // A default build holds the point tree alone, and so no tables to choose by: say so.
        let without = models.iter().filter(|c| c.calibration().is_empty()).count();
        if without > 0 {
            line.push_str(&format!(
                " ({without} of {} container(s) without calibration tables, their trees drawn with {technique})",
                models.len()
            ));
        }
    }
    if renderer.settings().policy.is_none() && !matches!(technique, Technique::Full | Technique::Spt) {
        // Trees whose containers lack the technique's data (warned about above) are drawn with
        // the point tree: counted apart, so the line does not credit the technique with them.
        let mut stead = stats.instances;
        stead[technique] = 0;
        let stead = if stead.iter().any(|(_, n)| n > 0) {
            format!(", {} in their stead,", technique_counts(&stead))
        } else {
            String::new()
        };
        line.push_str(&format!(", {drawn} tree(s) drawn with {technique}{stead} submitting {}", submitted(&stats)));
    }
    if renderer.settings().shadows.is_some() {
        line.push_str("; ");
        line.push_str(&shadow_summary(&stats));
    }
    if args.shadow_error {
        line.push_str(&shadow_error(&mut renderer, &lod, render, &args.output)?);
    }
    let image = if args.compare {
        renderer.settings_mut().technique = Technique::Full;
        renderer.settings_mut().policy = None;
        let (full, full_stats) = render(&mut renderer)?;
        let ratio = stats.primitives() as f64 / full_stats.submitted[Primitive::Triangle].max(1) as f64;
        line.push_str(&format!(
            "; full mesh {} triangles; LoD/full {ratio:.3} (left LoD, right full mesh)",
            full_stats.submitted[Primitive::Triangle]
        ));
        side_by_side(&lod, &full)
    } else {
        lod
    };
    line.push('\n');
    write_png(&args.output, &image)?;
    report::write_stdout(&line)
}

/// A distance in metres: finite and > 0.
pub fn parse_distance(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("expected a distance in metres, a finite number > 0, got {s:?}")),
    }
}

/// What the shadow pass of a frame drew, and its primitives over the main pass's.
pub fn shadow_summary(stats: &FrameStats) -> String {
    let shadow = &stats.shadow;
    let main = stats.primitives();
    let ratio = if main == 0 {
        "(the main pass draws nothing)".to_owned()
    } else {
        format!("({:.2}× the main pass's primitives)", shadow.primitives() as f64 / main as f64)
    };
    let cascades = shadow.cascades as usize;
    let per_cascade: Vec<String> = shadow.per_cascade.iter().take(cascades).map(u64::to_string).collect();
    format!(
        "shadow pass: {} cascade(s), {} triangles, {} points, {} planes, {} billboards, {} ellipsoids, {} lines, \
         per cascade {} {ratio}",
        shadow.cascades,
        shadow.submitted[Primitive::Triangle],
        shadow.submitted[Primitive::Point],
        shadow.submitted[Primitive::Plane],
        shadow.submitted[Primitive::Billboard],
        shadow.submitted[Primitive::Ellipsoid],
        shadow.submitted[Primitive::Line],
        per_cascade.join(" / ")
    )
}

/// `; shadow error against full-mesh casters: RMSE …, FLIP …`: `image` (drawn by `renderer`)
/// against the same frame with every tree casting its full mesh (`Shadows::casters`), measured
/// with eval's metrics; the renderer's casters are restored. Without shadows, says so.
fn shadow_error(
    renderer: &mut Renderer,
    image: &Image,
    render: impl Fn(&mut Renderer) -> Result<(Image, FrameStats), Failed>,
    output: &Path,
) -> Result<String, Failed> {
    let Some(shadows) = renderer.settings().shadows else {
        return Ok("; no shadow error (no shadows)".to_owned());
    };
    renderer.settings_mut().shadows = Some(Shadows { casters: Casters::Forced(Technique::Full), ..shadows });
    let (reference, full) = render(renderer)?;
    renderer.settings_mut().shadows = Some(shadows);
    let failed = |e: treelod_eval::MetricError| {
        report::message_error(output, &format!("cannot measure the shadow error: {e}"));
        Failed { class: ErrorClass::Io }
    };
    let linear =
        |i: &Image| treelod_eval::metrics::LinearImage::from_srgba8(i.width, i.height, &i.rgba).map_err(failed);
    let (sample, reference) = (linear(image)?, linear(&reference)?);
    let rmse = treelod_eval::metrics::multiscale_rmse(&sample, &reference).map_err(failed)?.summary();
    let flip = treelod_eval::metrics::flip::mean_flip(&sample, &reference).map_err(failed)?;
    Ok(format!(
        "; shadow error against full-mesh casters ({} shadow primitives): RMSE {rmse:.5}, FLIP {flip:.5}",
        full.shadow.primitives()
    ))
}

/// Prints a scene error (its message starts with the file) and returns its class.
pub fn scene_failed(error: &scene::SceneError) -> Failed {
    report::print_error(&error.to_string());
    Failed { class: error.class() }
}

/// `left` and `right` (the same size) side by side.
fn side_by_side(left: &Image, right: &Image) -> Image {
    let (width, height) = (left.width + right.width, left.height.max(right.height));
    let mut rgba = Vec::with_capacity(width as usize * height as usize * 4);
    for y in 0..height as usize {
        for image in [left, right] {
            let row = image.width as usize * 4;
            match image.rgba.get(y * row..(y + 1) * row) {
                Some(pixels) => rgba.extend_from_slice(pixels),
                None => rgba.extend(std::iter::repeat_n(0, row)),
            }
        }
    }
    Image { width, height, rgba }
}

/// Writes `image` as a PNG to `path`, atomically; errors are printed naming the file.
pub fn write_png(path: &Path, image: &Image) -> Result<(), Failed> {
    let png = encode_png(image).map_err(|e| {
        report::message_error(path, &format!("cannot encode the PNG: {e}"));
        Failed { class: ErrorClass::Io }
    })?;
    report::write_atomically(path, &png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_parse_and_refuse_nonsense() {
        assert_eq!(parse_size("256x192"), Ok((256, 192)));
        assert_eq!(parse_size("8X8"), Ok((8, 8)));
        for bad in ["0x10", "10", "10x", "x10", "-1x5", "99999x1"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_vec3("1,-2.5, 3"), Ok(Vec3::new(1.0, -2.5, 3.0)));
        assert!(parse_vec3("1,2").is_err() && parse_vec3("1,2,nan").is_err() && parse_vec3("1,2,3,4").is_err());
        assert_eq!(parse_colour("#ff8000"), Ok([255, 128, 0]));
        assert!(parse_colour("fff").is_err() && parse_colour("gggggg").is_err() && parse_colour("ffé00").is_err());
        assert!(parse_fov("0").is_err() && parse_fov("180").is_err() && parse_fov("50").is_ok());
        assert!(parse_pixels("-1").is_err() && parse_pixels("inf").is_err() && parse_pixels("0.5").is_ok());
    }

    #[derive(Debug, clap::Parser)]
    struct ShadowCli {
        #[command(flatten)]
        shadow: ShadowArgs,
    }

    fn shadow_settings(args: &[&str]) -> Result<Option<Shadows>, clap::Error> {
        use clap::Parser;
        let cli = ShadowCli::try_parse_from(std::iter::once("shadows").chain(args.iter().copied()))?;
        let mut settings = Settings::default();
        cli.shadow.apply(&mut settings);
        Ok(settings.shadows)
    }

    #[test]
    fn shadow_options_turn_shadows_on_with_their_values_and_refuse_nonsense() {
        assert_eq!(shadow_settings(&[]).ok(), Some(None), "off unless asked for");
        assert_eq!(shadow_settings(&["--shadows"]).ok(), Some(Some(Shadows::default())));
        // A value option alone implies --shadows; the others keep their defaults.
        let two = shadow_settings(&["--shadow-cascades", "2"]).ok().flatten();
        assert_eq!(two, Some(Shadows { cascades: 2, ..Shadows::default() }));
        let all = ["--shadows", "--shadow-resolution", "512", "--shadow-cascades", "4", "--shadow-distance", "40.5"];
        let custom = Shadows { resolution: 512, cascades: 4, distance: 40.5, ..Shadows::default() };
        assert_eq!(shadow_settings(&all).ok(), Some(Some(custom)));
        let camera = shadow_settings(&["--shadow-casters", "camera"]).ok().flatten();
        assert_eq!(camera, Some(Shadows { casters: Casters::CameraView, ..Shadows::default() }));
        let light = shadow_settings(&["--shadow-casters", "light"]).ok().flatten();
        assert_eq!(light, Some(Shadows { casters: Casters::LightView, ..Shadows::default() }));
        let coarser = shadow_settings(&["--shadow-casters", "coarser"]).ok().flatten();
        assert_eq!(coarser, Some(Shadows::default()));
        let error = shadow_settings(&["--shadow-casters", "sun"]).expect_err("refused");
        assert_eq!(error.kind(), clap::error::ErrorKind::InvalidValue);
        assert!(error.to_string().contains("--shadow-casters"), "{error}");
        let bad: [&[&str]; 9] = [
            &["--shadow-cascades", "0"],
            &["--shadow-cascades", "5"],
            &["--shadow-resolution", "0"],
            &["--shadow-resolution", "15"],
            &["--shadow-resolution", "8193"],
            &["--shadow-distance", "-1"],
            &["--shadow-distance", "0"],
            &["--shadow-distance", "inf"],
            &["--shadow-distance", "nan"],
        ];
        for args in bad {
            let error = shadow_settings(args).expect_err("refused");
            assert_eq!(error.kind(), clap::error::ErrorKind::ValueValidation, "{args:?}");
            assert!(error.to_string().contains(args[0]), "{args:?}: the message names the option: {error}");
        }
    }

    #[test]
    fn the_shadow_summary_compares_the_shadow_pass_with_the_main_pass() {
        // Lines count as primitives on both sides.
        // Triangles, points, planes, billboards, ellipsoids, lines.
        let mut stats =
            FrameStats { submitted: treelod_render::PerPrimitive([100, 200, 50, 50, 0, 100]), ..FrameStats::default() };
        stats.shadow = treelod_render::ShadowStats {
            cascades: 3,
            submitted: treelod_render::PerPrimitive([300, 400, 100, 0, 0, 100]),
            per_cascade: [500, 250, 150, 0],
            ..treelod_render::ShadowStats::default()
        };
        assert_eq!(
            shadow_summary(&stats),
            "shadow pass: 3 cascade(s), 300 triangles, 400 points, 100 planes, 0 billboards, 0 ellipsoids, 100 lines, \
             per cascade 500 / 250 / 150 (1.80× the main pass's primitives)"
        );
        let nothing = FrameStats { shadow: stats.shadow, ..FrameStats::default() };
        assert!(shadow_summary(&nothing).ends_with("(the main pass draws nothing)"));
    }

    #[test]
    fn the_framing_camera_sees_every_corner() {
        let bounds = (Vec3::new(-10.0, 0.0, -4.0), Vec3::new(30.0, 12.0, 6.0));
        for (w, h) in [(1024, 768), (200, 800)] {
            let camera = frame_camera(bounds, None, None, 50f32.to_radians(), w, h);
            for corner in 0..8 {
                let p = Vec3::select(
                    glam::BVec3::new(corner & 1 == 0, corner & 2 == 0, corner & 4 == 0),
                    bounds.0,
                    bounds.1,
                );
                let clip = camera.view_proj() * p.extend(1.0);
                let ndc = clip.truncate() / clip.w;
                assert!(clip.w > 0.0 && ndc.x.abs() <= 1.0 && ndc.y.abs() <= 1.0, "{w}x{h}: corner {p} at {ndc}");
            }
        }
    }

    #[test]
    fn the_background_comes_out_as_given() {
        let c = clear_colour([255, 128, 0]);
        assert!((c.r - 1.0).abs() < 1e-9 && c.b == 0.0 && (c.g - 0.2158605).abs() < 1e-4, "{c:?}");
    }

    #[test]
    fn side_by_side_doubles_the_width() {
        let a = Image { width: 2, height: 1, rgba: vec![1; 8] };
        let b = Image { width: 2, height: 1, rgba: vec![2; 8] };
        let both = side_by_side(&a, &b);
        assert_eq!((both.width, both.height), (4, 1));
        assert_eq!(both.rgba, [1, 1, 1, 1, 1, 1, 1, 1, 2, 2, 2, 2, 2, 2, 2, 2]);
    }
}
