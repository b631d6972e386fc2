//! `treelod view`: a window over a container, a JSON scene or a glTF file (built first, with
//! `treelod build`'s defaults), with a panel (egui) for what is drawn and how, live counts and a
//! graph of the last seconds, a fly or orbiting camera, a sky and a ground that receives the trees'
//! shadows (winit on X11, wgpu on Vulkan; Mesa lavapipe works). Files dropped on the window are
//! shown the same way. With `--screenshot` it renders `--frames` frames, writes the last (the
//! whole window, panel included) as a PNG and exits.

mod dropped;
mod gpu_timer;
mod heat;
mod panel;
mod rig;

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Vec3;
use treelod_format::{Container, ErrorClass};
use treelod_render::offscreen::{GpuError, Image, Readback};
use treelod_render::{
    Camera, DebugView, FrameStats, Ground, Policy, Primitive, Renderer, RendererFormats, Settings, Shadows, Sky,
    Technique,
};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, KeyEvent, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, OwnedDisplayHandle};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use self::dropped::DroppedBuild;
use self::gpu_timer::GpuTimer;
use self::panel::{Action, History, Holds};
use self::rig::{Mode, Rig};
use crate::render::{
    EllipsoidArgs, ImpostorArgs, LightArgs, PruneArgs, ShadowArgs, TechniqueArgs, frame_camera, parse_size, parse_vec3,
    scene_failed, shadow_summary, write_png,
};
use crate::report::{self, Failed};
use crate::scene::{self, Scene};

/// Gilet's self-shadowing `(L_m, L_M)` that key `L` turns on (unless `--self-shadow` gave one).
const SELF_SHADOW: (f32, f32) = (0.6, 1.0);

/// Degrees the sun turns per arrow key press: about the vertical (left, right) or up and down.
const SUN_STEP_DEGREES: f32 = 15.0;

/// The sun's azimuth about +y (from +z towards +x) and elevation, radians, of the direction
/// towards it (straight up if it has no length).
fn sun_angles(sun: Vec3) -> (f32, f32) {
    let sun = sun.normalize_or(Vec3::Y);
    (sun.x.atan2(sun.z), sun.y.clamp(-1.0, 1.0).asin())
}

/// The direction towards the sun at `azimuth` and `elevation` (radians, as [`sun_angles`]).
fn sun_from_angles(azimuth: f32, elevation: f32) -> Vec3 {
    Vec3::new(azimuth.sin() * elevation.cos(), elevation.sin(), azimuth.cos() * elevation.cos())
}

/// The direction towards the sun after arrow key `key`: azimuth about +y, or elevation, by
/// [`SUN_STEP_DEGREES`], the elevation kept within ±85° (lighting from below is allowed: leaves
/// are lit on both faces).
fn turn_sun(sun: Vec3, key: KeyCode) -> Vec3 {
    let (mut azimuth, mut elevation) = sun_angles(sun);
    let step = SUN_STEP_DEGREES.to_radians();
    match key {
        KeyCode::ArrowLeft => azimuth -= step,
        KeyCode::ArrowRight => azimuth += step,
        KeyCode::ArrowUp => elevation += step,
        KeyCode::ArrowDown => elevation -= step,
        _ => {}
    }
    sun_from_angles(azimuth, elevation.clamp(-85f32.to_radians(), 85f32.to_radians()))
}

/// Keys `F`, `P`, `I`, `C` and `B`: from a technique outside `group` to its first, through the
/// group in turn, and after its last back to the point tree.
fn toggle_technique(current: Technique, group: &[Technique]) -> Technique {
    match group.iter().position(|&t| t == current) {
        None => group.first().copied().unwrap_or(Technique::Spt),
        Some(i) => group.get(i + 1).copied().unwrap_or(Technique::Spt),
    }
}

/// Keys `F`, `P`, `I`, `C` and `B`: the policy off and every tree drawn with the technique
/// [`toggle_technique`] steps to.
fn force_technique(settings: &mut Settings, group: &[Technique]) {
    settings.technique = toggle_technique(settings.technique, group);
    settings.policy = None;
}

/// Key `T`: the policy off, keeping it in `last`, or back on with `last`.
fn toggle_policy(policy: &mut Option<Policy>, last: &mut Policy) {
    match policy.take() {
        Some(on) => *last = on,
        None => *policy = Some(*last),
    }
}

/// Key `H`: shadows off, keeping their settings in `last`, or back on with `last`.
fn toggle_shadows(shadows: &mut Option<Shadows>, last: &mut Shadows) {
    match shadows.take() {
        Some(on) => *last = on,
        None => *shadows = Some(*last),
    }
}

/// Vertical field of view (as `treelod render`'s default).
const FOVY_DEGREES: f32 = 50.0;
/// The depth attachment's format.
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Radians of turn per pixel of mouse drag.
const LOOK_PER_PIXEL: f32 = 0.004;
/// How often the title's statistics are refreshed.
const TITLE_PERIOD: Duration = Duration::from_millis(250);
/// With `--screenshot`, how long the window may stay undrawable before giving up.
const SCREENSHOT_PATIENCE: Duration = Duration::from_secs(30);
/// The viewer's ground spans this many times the ground under the instances
/// ([`Ground::under_instances`]), so that its edge lies near the horizon.
const GROUND_SCALE: f32 = 16.0;
/// MSAA sample counts offered (those every adapter has for the window's 8-bit formats and the
/// depth format; the panel offers those the adapter confirms).
const MSAA_COUNTS: [u32; 2] = [1, 4];

/// Arguments of `treelod view`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A `.treelod` container (drawn once at the origin), a JSON scene file, or a glTF file
    /// (`.glb`, `.gltf`: built with `treelod build`'s defaults into a temporary container first).
    #[arg(value_name = "FILE|SCENE")]
    pub input: PathBuf,
    /// Window size in pixels, `WIDTHxHEIGHT`.
    #[arg(long, value_name = "WxH", default_value = "1280x720", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Start eye position `x,y,z` (metres); default: framing the whole scene from the front right.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<Vec3>,
    /// Point looked at first, `x,y,z` (metres); default: the centre of the scene's bounds.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub target: Option<Vec3>,
    /// Start orbiting the scene's centre at this many bounding radii (the panel's distance).
    #[arg(long, value_name = "RADII", value_parser = parse_distance, conflicts_with = "eye")]
    pub distance: Option<f32>,
    /// Start coloured by grid cell (`cells`), by kind (`kinds`), by level (`levels`) or by the
    /// technique each tree is drawn with (`techniques`, key 6; as `render --debug`), or with the
    /// error view (`error`: the difference from the full mesh as a heat map; key 5).
    #[arg(long, value_name = "VIEW", value_parser = ["cells", "kinds", "levels", "techniques", "error"])]
    pub debug: Option<String>,
    /// Start without the panel (key Tab shows it). Windows narrower than twice the panel start
    /// without it anyway.
    #[arg(long)]
    pub no_panel: bool,
    /// MSAA samples per pixel, with alpha to coverage for leaves (the panel switches).
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = parse_msaa)]
    pub msaa: u32,
    /// Render `--frames` frames, write the last one (the whole window, panel included) to this
    /// PNG and exit. With a glTF input, the frames count from when its build is shown.
    #[arg(long, value_name = "PATH")]
    pub screenshot: Option<PathBuf>,
    /// Frames rendered before the screenshot (streaming refines the level of detail per frame).
    #[arg(long, value_name = "N", default_value_t = 10, requires = "screenshot",
          value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    // `--technique` starts with that technique (the panel chooses; keys F, P, I, C and B switch
    // to the full mesh, pruning, impostors, ellipsoids and the baselines and back to spt).
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
    // `--no-lines` starts ellipsoid trees with their bark as triangles instead of lines (key `N`).
    #[command(flatten)]
    pub ellipsoid: EllipsoidArgs,
}

/// Parses `--distance`: a positive number of bounding radii within the panel's range.
fn parse_distance(s: &str) -> Result<f32, String> {
    let (lo, hi) = rig::DISTANCE_RANGE;
    match s.trim().parse::<f32>() {
        Ok(v) if (lo..=hi).contains(&v) => Ok(v),
        _ => Err(format!("expected bounding radii from {lo} to {hi}, got {s:?}")),
    }
}

/// Parses `--msaa`: one of [`MSAA_COUNTS`].
fn parse_msaa(s: &str) -> Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(n) if MSAA_COUNTS.contains(&n) => Ok(n),
        _ => Err(format!("expected one of {MSAA_COUNTS:?}, got {s:?}")),
    }
}

/// Runs `treelod view`.
pub fn run(args: &Args) -> Result<(), Failed> {
    if let (Some(eye), Some(target)) = (args.eye, args.target)
        && eye.distance_squared(target) < 1e-12
    {
        clap::Error::raw(clap::error::ErrorKind::ValueValidation, "--eye and --target are the same point\n").exit();
    }
    // A glTF input is built once the window is up (the panel shows the progress); anything else
    // is checked before a window is needed (and opened again once the device exists).
    let scene = if scene::is_gltf_path(&args.input) {
        if let Err(e) = std::fs::metadata(&args.input) {
            return Err(report::io_error(&args.input, &e));
        }
        Scene { models: Vec::new(), instances: Vec::new() }
    } else {
        let scene = scene::load(&args.input).map_err(|e| scene_failed(&e))?;
        let opened = scene.models.iter().map(|model| report::open(model)).collect::<Result<Vec<_>, _>>()?;
        args.technique.warn_without(scene.models.iter().map(PathBuf::as_path).zip(&opened));
        scene
    };
    if let Some(path) = args.screenshot.as_deref().filter(|p| p.is_dir()) {
        report::message_error(path, "is a directory; name the file to write");
        return Err(Failed { class: ErrorClass::Io });
    }
    let event_loop = EventLoop::new().map_err(|e| {
        let message = e.to_string();
        let reason = winit_reason(&message);
        let hint = "treelod view needs an X11 display: set DISPLAY, or run it under xvfb-run";
        unsupported(&args.input, &format!("cannot open a window: {} ({hint})", reason.trim_end_matches('.')))
    })?;
    let mut app =
        App { args, scene: Some(scene), display: event_loop.owned_display_handle(), viewer: None, outcome: Ok(None) };
    if let Err(e) = event_loop.run_app(&mut app) {
        return Err(unsupported(&args.input, &format!("the window's event loop failed: {e}")));
    }
    let outcome = app.outcome?;
    let Some(path) = &args.screenshot else { return Ok(()) };
    let Some(shot) = outcome else {
        report::message_error(path, "the window was closed before the screenshot was taken; nothing written");
        return Err(Failed { class: ErrorClass::Io });
    };
    write_png(path, &shot.image)?;
    let stats = shot.stats;
    let mut line = format!(
        "{}: {}x{}, {} of {} instance(s) visible, {} triangles, {} points",
        path.display(),
        shot.image.width,
        shot.image.height,
        stats.instances_visible,
        shot.instances,
        stats.submitted[Primitive::Triangle],
        stats.submitted[Primitive::Point]
    );
    if shot.panel {
        line.push_str(", with the panel");
    }
    if stats.shadow.cascades > 0 {
        line.push_str("; ");
        line.push_str(&shadow_summary(&stats));
    }
    line.push('\n');
    report::write_stdout(&line)
}

/// A winit error message without the source location winit prefixes to operating-system errors
/// (`os error at FILE:LINE: reason`).
fn winit_reason(message: &str) -> &str {
    message.strip_prefix("os error at ").and_then(|rest| rest.split_once(": ")).map_or(message, |(_, reason)| reason)
}

/// Prints `error: PATH: message` and returns an [`ErrorClass::Unsupported`] failure (no display,
/// no adapter, a window the device cannot draw).
fn unsupported(path: &Path, message: &str) -> Failed {
    report::message_error(path, message);
    Failed { class: ErrorClass::Unsupported }
}

/// A screenshot taken: the image, its frame's statistics, the scene's instances and whether the
/// panel was shown.
struct Shot {
    image: Image,
    stats: FrameStats,
    instances: usize,
    panel: bool,
}

/// The winit application: creates the [`Viewer`] once the event loop runs.
struct App<'a> {
    args: &'a Args,
    /// The scene to show first, until the viewer takes it.
    scene: Option<Scene>,
    display: OwnedDisplayHandle,
    viewer: Option<Viewer>,
    /// The screenshot once taken, or the failure that ended the loop.
    outcome: Result<Option<Shot>, Failed>,
}

impl App<'_> {
    fn finish(&mut self, event_loop: &ActiveEventLoop, outcome: Result<Option<Shot>, Failed>) {
        self.outcome = outcome;
        self.viewer = None;
        event_loop.exit();
    }
}

impl ApplicationHandler for App<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.viewer.is_none()
            && self.outcome.is_ok()
            && let Some(scene) = self.scene.take()
        {
            match Viewer::new(event_loop, self.display.clone(), self.args, scene) {
                Ok(viewer) => self.viewer = Some(viewer),
                Err(failed) => self.finish(event_loop, Err(failed)),
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let Some(viewer) = &mut self.viewer else { return };
        // The panel sees every event first; what it takes (a click on a slider, keys while a
        // field has focus) does not also move the camera.
        let taken = viewer.egui_state.on_window_event(&viewer.window, &event).consumed;
        match event {
            WindowEvent::CloseRequested => self.finish(event_loop, Ok(None)),
            WindowEvent::Resized(size) => viewer.resize(size),
            WindowEvent::KeyboardInput { event, .. } => {
                // Releases always count, so that no key stays held.
                let used = !taken || event.state == ElementState::Released;
                if used && viewer.key(&event) == Some(KeyCode::Escape) {
                    self.finish(event_loop, Ok(None));
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                viewer.dragging = state == ElementState::Pressed && !taken && !viewer.egui.is_pointer_over_egui();
            }
            WindowEvent::CursorMoved { position, .. } => viewer.cursor_moved(position),
            WindowEvent::Focused(false) => viewer.keys.clear(),
            WindowEvent::DroppedFile(path) => viewer.open(path),
            WindowEvent::RedrawRequested => match viewer.frame(self.args.screenshot.as_deref(), self.args.frames) {
                Ok(None) => viewer.window.request_redraw(),
                Ok(Some(shot)) => self.finish(event_loop, Ok(Some(shot))),
                Err(failed) => self.finish(event_loop, Err(failed)),
            },
            _ => {}
        }
    }
}

/// What the window draws: the renderer with the scene, and the sky and ground around it.
struct Stage {
    renderer: Renderer,
    /// The ground under the scene's instances (it sizes itself from their bounds).
    ground: Ground,
    sky: Sky,
    /// Depth, and the multisampled colour target with MSAA, window-sized.
    depth: wgpu::TextureView,
    multisampled: Option<wgpu::TextureView>,
}

impl Stage {
    /// A renderer for `formats` and `settings` holding `scene`, whose `models` are opened
    /// ([`scene::open_models`]: once per scene, however many renderers draw it); the scene's
    /// bounds.
    fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        formats: RendererFormats,
        settings: Settings,
        (scene, models): (&Scene, &[Arc<Container>]),
        size: (u32, u32),
    ) -> Result<(Self, (Vec3, Vec3)), scene::SceneError> {
        let mut renderer = Renderer::new(device, formats, settings);
        let bounds = scene::add_opened(scene, models, device, queue, &mut renderer)?;
        let mut ground = Ground::under_instances(device, &renderer);
        // Out towards the horizon (the shadows reach `--shadow-distance`), its far part meeting
        // the sky's colour below the horizon.
        ground.half_size *= GROUND_SCALE;
        let mut sky = Sky::new(device, &renderer);
        sky.below = ground.colour * 0.8;
        let (depth, multisampled) = targets(device, formats, size);
        Ok((Self { renderer, ground, sky, depth, multisampled }, bounds))
    }

    fn resize(&mut self, device: &wgpu::Device, size: (u32, u32)) {
        (self.depth, self.multisampled) = targets(device, self.renderer.formats(), size);
    }
}

/// The depth target and, with MSAA, the multisampled colour target of `size`.
fn targets(
    device: &wgpu::Device,
    formats: RendererFormats,
    (width, height): (u32, u32),
) -> (wgpu::TextureView, Option<wgpu::TextureView>) {
    let samples = formats.sample_count.max(1);
    let texture = |label, format, usage| {
        device
            .create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: samples,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
            .create_view(&wgpu::TextureViewDescriptor::default())
    };
    // Sampled by the occlusion measurement of pruned trees.
    let depth = texture(
        "treelod view depth",
        DEPTH_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let multisampled = (samples > 1)
        .then(|| texture("treelod view multisampled", formats.color, wgpu::TextureUsages::RENDER_ATTACHMENT));
    (depth, multisampled)
}

/// The window, its surface and device, what it draws, the panel and the camera.
struct Viewer {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    stage: Stage,
    scene: Scene,
    /// The scene's models, opened once for the renderers that draw them.
    models: Vec<Arc<Container>>,
    /// What the scene's containers hold, for the panel.
    holds: Holds,
    /// The shadow settings turned back on (the last ones on).
    last_shadows: Shadows,
    /// The policy last on (key `T` turns it back on with these settings).
    last_policy: Policy,
    /// The shown input's path (a dropped file's once one is shown).
    input: PathBuf,
    rig: Rig,
    /// Keys held down (movement).
    keys: HashSet<KeyCode>,
    dragging: bool,
    cursor: Option<PhysicalPosition<f64>>,
    started: Instant,
    last_frame: Instant,
    /// Frames presented since the scene was shown.
    frames: u32,
    /// Statistics of the last frame, and its selection's CPU milliseconds.
    stats: FrameStats,
    select_ms: f64,
    history: History,
    gpu_timer: Option<GpuTimer>,
    msaa_choices: Vec<u32>,
    egui: egui::Context,
    egui_state: egui_winit::State,
    egui_renderer: egui_wgpu::Renderer,
    panel_shown: bool,
    /// The error view (key 5): on, and its reference renderer and targets once made.
    heat_on: bool,
    heat: Option<heat::Heat>,
    /// A glTF file being built, the directory builds are written to, and how many were started.
    build: Option<DroppedBuild>,
    build_dir: Option<tempfile::TempDir>,
    builds: u32,
    /// The failure of the last build, if it failed.
    build_failed: Option<Failed>,
    /// Errors and warnings of the last file opened or built, for the panel.
    messages: Vec<String>,
    title_frames: u32,
    title_since: Instant,
    /// Set the title at the next frame (a setting changed).
    title_now: bool,
    /// Since when no frame could be drawn (surface timeouts, occlusion).
    stalled_since: Option<Instant>,
    /// Where the first view was asked for: `--eye`, `--target`, `--distance`.
    start_view: (Option<Vec3>, Option<Vec3>, Option<f32>),
}

impl Viewer {
    fn new(
        event_loop: &ActiveEventLoop,
        display: OwnedDisplayHandle,
        args: &Args,
        scene: Scene,
    ) -> Result<Self, Failed> {
        let input = args.input.as_path();
        let (width, height) = args.size;
        let attributes = Window::default_attributes()
            .with_title(format!("treelod view {}", input.display()))
            .with_inner_size(PhysicalSize::new(width, height));
        let window = Arc::new(
            event_loop
                .create_window(attributes)
                .map_err(|e| unsupported(input, &format!("cannot open a window: {}", winit_reason(&e.to_string()))))?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(display)));
        let surface = instance.create_surface(window.clone()).map_err(|e| {
            let hint = "no Vulkan driver? On a machine without a GPU, install Mesa's lavapipe: mesa-vulkan-drivers";
            unsupported(input, &format!("cannot draw into the window: {e} ({hint})"))
        })?;
        let gpu_error = |e: GpuError| unsupported(input, &format!("cannot render: {e}"));
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            compatible_surface: Some(&surface),
            ..wgpu::RequestAdapterOptions::default()
        }))
        .map_err(|e| gpu_error(GpuError::NoAdapter(e.to_string())))?;
        let missing = Renderer::required_features() - adapter.features();
        if !missing.is_empty() {
            return Err(gpu_error(GpuError::MissingFeatures { adapter: adapter.get_info().name, missing }));
        }
        // Timestamps for the panel's GPU time, GPU selection's counted draws, and BC textures
        // (BC7 atlases uploaded as stored), where offered.
        let optional = adapter.features()
            & (wgpu::Features::TIMESTAMP_QUERY
                | wgpu::Features::TEXTURE_COMPRESSION_BC
                | Renderer::gpu_selection_features());
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("treelod view"),
            required_features: Renderer::required_features() | optional,
            required_limits: adapter.limits(),
            ..wgpu::DeviceDescriptor::default()
        }))
        .map_err(|e| gpu_error(GpuError::Device(e.to_string())))?;
        let limit = device.limits().max_texture_dimension_2d;
        if width > limit || height > limit {
            let message = format!("{width}x{height} is larger than the device draws ({limit} pixels per side at most)");
            return Err(unsupported(input, &message));
        }

        let caps = surface.get_capabilities(&adapter);
        // sRGB (the renderer writes linear colours); with --screenshot, one whose pixels read back.
        let usable = |f: &&wgpu::TextureFormat| args.screenshot.is_none() || bgra(**f).is_some();
        let format = caps
            .formats
            .iter()
            .filter(usable)
            .find(|f| f.is_srgb())
            .or_else(|| caps.formats.iter().find(usable))
            .copied()
            .ok_or_else(|| unsupported(input, &format!("the window offers no usable format ({:?})", caps.formats)))?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| unsupported(input, "the adapter cannot present to this window"))?;
        config.format = format;
        // No vsync wait when rendering a screenshot.
        config.present_mode =
            if args.screenshot.is_some() { wgpu::PresentMode::AutoNoVsync } else { wgpu::PresentMode::AutoVsync };
        surface.configure(&device, &config);
        let msaa_choices: Vec<u32> = MSAA_COUNTS
            .into_iter()
            .filter(|&n| {
                let ok = |f| adapter.get_texture_format_features(f).flags.sample_count_supported(n);
                ok(format) && ok(DEPTH_FORMAT)
            })
            .collect();
        if !msaa_choices.contains(&args.msaa) {
            return Err(unsupported(
                input,
                &format!("--msaa {}: the adapter offers {msaa_choices:?} for this window", args.msaa),
            ));
        }

        let formats = RendererFormats { color: format, depth: DEPTH_FORMAT, sample_count: args.msaa };
        let technique = args.technique.technique();
        let mut settings = Settings {
            technique,
            policy: None,
            pruning: args.prune.settings(technique),
            // `error` is the shaded view compared with the full mesh (`heat_on`).
            debug: crate::render::parse_debug(args.debug.as_deref()),
            ..Settings::default()
        };
        args.technique.apply(&mut settings);
        args.light.apply(&mut settings);
        args.shadow.apply(&mut settings);
        args.impostor.apply(&mut settings);
        args.ellipsoid.apply(&mut settings);
        let last_shadows = settings.shadows.unwrap_or_default();
        let last_policy = settings.policy.unwrap_or_default();
        let models = scene::open_models(&scene).map_err(|e| scene_failed(&e))?;
        let (stage, bounds) =
            Stage::new(&device, &queue, formats, settings, (&scene, &models), (config.width, config.height))
                .map_err(|e| scene_failed(&e))?;

        let egui = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(limit as usize),
        );
        let egui_renderer = egui_wgpu::Renderer::new(&device, format, egui_wgpu::RendererOptions::default());
        // The panel takes WIDTH points: windows less than twice that wide start without it.
        let panel_shown = !args.no_panel && config.width as f32 >= 2.0 * panel::WIDTH * window.scale_factor() as f32;
        let gpu_timer = GpuTimer::new(&device, &queue);
        let now = Instant::now();
        window.request_redraw();
        let mut viewer = Self {
            window,
            surface,
            device,
            queue,
            config,
            stage,
            holds: Holds::default(),
            scene,
            models,
            last_shadows,
            last_policy,
            input: args.input.clone(),
            rig: Rig::new((Vec3::splat(-1.0), Vec3::splat(1.0)), Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO),
            keys: HashSet::new(),
            dragging: false,
            cursor: None,
            started: now,
            last_frame: now,
            frames: 0,
            stats: FrameStats::default(),
            select_ms: 0.0,
            history: History::default(),
            gpu_timer,
            msaa_choices,
            egui,
            egui_state,
            egui_renderer,
            panel_shown,
            heat_on: args.debug.as_deref() == Some("error"),
            heat: None,
            build: None,
            build_dir: None,
            builds: 0,
            build_failed: None,
            messages: Vec::new(),
            title_frames: 0,
            title_since: now,
            title_now: false,
            stalled_since: None,
            start_view: (args.eye, args.target, args.distance),
        };
        viewer.shown(bounds);
        if scene::is_gltf_path(input) {
            viewer.open(args.input.clone());
        }
        Ok(viewer)
    }

    /// After a scene is added: counts what its containers hold, frames it (as asked at the start,
    /// the first time) and restarts the frame count.
    fn shown(&mut self, bounds: (Vec3, Vec3)) {
        self.holds = Holds::of(self.models.iter().map(|m| &**m));
        // The view asked for at the start is for the first scene with trees (a glTF input's
        // once built).
        let asked =
            if self.scene.instances.is_empty() { (None, None, None) } else { std::mem::take(&mut self.start_view) };
        let (eye, target, distance) = asked;
        let fovy = FOVY_DEGREES.to_radians();
        let start = frame_camera(bounds, eye, target, fovy, self.view_width(), self.config.height);
        let target = target.unwrap_or(0.5 * (bounds.0 + bounds.1));
        self.rig = Rig::new(bounds, start.position, target);
        if let Some(distance) = distance {
            self.rig.set_mode(Mode::Orbit);
            self.rig.distance = distance;
        }
        self.frames = 0;
        self.title_now = true;
    }

    /// Shows a container or scene file, or starts building a glTF file (one at a time).
    fn open(&mut self, path: PathBuf) {
        self.messages.clear();
        if scene::is_gltf_path(&path) {
            if let Some(build) = &self.build {
                let line = format!(
                    "error: {}: {} is still being built; drop it again after",
                    path.display(),
                    build.source.display()
                );
                self.messages.push(line);
                return;
            }
            let directory = match &self.build_dir {
                Some(dir) => dir.path().to_owned(),
                None => match tempfile::Builder::new().prefix("treelod-view-").tempdir() {
                    Ok(dir) => self.build_dir.insert(dir).path().to_owned(),
                    Err(e) => {
                        self.messages.push(format!(
                            "error: cannot make a temporary directory to build {} in: {e}",
                            path.display()
                        ));
                        return;
                    }
                },
            };
            self.builds += 1;
            self.build_failed = None;
            let output = dropped::output_path(&directory, &path, self.builds);
            self.build = Some(DroppedBuild::start(path, output));
            return;
        }
        let loaded = scene::load(&path).map_err(|e| e.to_string()).and_then(|scene| self.show_scene(scene, &path));
        if let Err(message) = loaded {
            report::print_error(&message);
            self.messages.push(format!("error: {message}"));
        }
    }

    /// Replaces what is drawn by `scene` (from `path`), keeping the settings.
    fn show_scene(&mut self, scene: Scene, path: &Path) -> Result<(), String> {
        let settings = *self.stage.renderer.settings();
        let formats = self.stage.renderer.formats();
        let size = (self.config.width, self.config.height);
        let models = scene::open_models(&scene).map_err(|e| e.to_string())?;
        let (stage, bounds) = Stage::new(&self.device, &self.queue, formats, settings, (&scene, &models), size)
            .map_err(|e| e.to_string())?;
        self.stage = stage;
        self.heat = None;
        self.scene = scene;
        self.models = models;
        path.clone_into(&mut self.input);
        self.window.set_title(&format!("treelod view {}", path.display()));
        self.shown(bounds);
        Ok(())
    }

    /// Shows a finished build's container, or its errors.
    fn poll_build(&mut self) {
        let Some(outcome) = self.build.as_mut().and_then(DroppedBuild::finished) else { return };
        let source = self.build.take().map(|b| b.source).unwrap_or_default();
        match outcome {
            Ok((container, warnings)) => {
                self.messages = warnings;
                let scene = Scene::single(&container);
                if let Err(message) = self.show_scene(scene, &source) {
                    report::print_error(&message);
                    self.messages.push(format!("error: {message}"));
                }
            }
            Err((failed, lines)) => {
                self.messages = lines;
                self.build_failed = Some(failed);
            }
        }
    }

    /// Rebuilds the renderer with `samples` MSAA samples, keeping the scene and settings.
    fn set_msaa(&mut self, samples: u32) {
        let mut formats = self.stage.renderer.formats();
        formats.sample_count = samples;
        let settings = *self.stage.renderer.settings();
        let size = (self.config.width, self.config.height);
        match Stage::new(&self.device, &self.queue, formats, settings, (&self.scene, &self.models), size) {
            Ok((stage, _)) => {
                self.stage = stage;
                self.heat = None;
            }
            Err(e) => self.messages.push(format!("error: {e}")),
        }
    }

    /// Pixels across of the 3D view: the window less the panel.
    fn view_width(&self) -> u32 {
        if self.panel_shown {
            let panel = (panel::WIDTH * self.window.scale_factor() as f32).ceil() as u32;
            self.config.width.saturating_sub(panel).max(1)
        } else {
            self.config.width
        }
    }

    fn resize(&mut self, size: PhysicalSize<u32>) {
        let limit = self.device.limits().max_texture_dimension_2d;
        if size.width > 0 && size.height > 0 {
            (self.config.width, self.config.height) = (size.width.min(limit), size.height.min(limit));
            self.surface.configure(&self.device, &self.config);
            self.stage.resize(&self.device, (self.config.width, self.config.height));
            self.heat = None;
        }
    }

    fn toggle_gpu_selection(&mut self) {
        let renderer = &mut self.stage.renderer;
        // GPU selection: every model resident whole; refused (and left off) over the budget.
        if renderer.gpu_selection_enabled() {
            renderer.disable_gpu_selection();
        } else if let Err(e) = renderer.enable_gpu_selection(&self.device, &self.queue) {
            let message = format!("{}: cannot select on the GPU: {e}", self.input.display());
            report::print_error(&message);
            self.messages.push(format!("error: {message}"));
        }
        self.title_now = true;
    }

    /// Applies a key press to the settings and tracks held keys; returns the key pressed, if any.
    fn key(&mut self, event: &KeyEvent) -> Option<KeyCode> {
        let PhysicalKey::Code(code) = event.physical_key else { return None };
        if event.state == ElementState::Released {
            self.keys.remove(&code);
            return None;
        }
        self.keys.insert(code);
        if event.repeat {
            return Some(code);
        }
        match code {
            KeyCode::KeyG => {
                self.toggle_gpu_selection();
                return Some(code);
            }
            KeyCode::Tab => {
                self.panel_shown = !self.panel_shown;
                return Some(code);
            }
            KeyCode::Digit5 => {
                self.heat_on = !self.heat_on;
                self.stage.renderer.settings_mut().debug = DebugView::Shaded;
                return Some(code);
            }
            _ => {}
        }
        let settings = self.stage.renderer.settings_mut();
        match code {
            KeyCode::BracketLeft => settings.s_min = (settings.s_min * 0.5).max(1.0 / 64.0),
            KeyCode::BracketRight => settings.s_min = (settings.s_min * 2.0).min(1024.0),
            KeyCode::Minus => settings.s_max = (settings.s_max * 0.5).max(1.0 / 64.0),
            KeyCode::Equal => settings.s_max = (settings.s_max * 2.0).min(1024.0),
            KeyCode::KeyK => settings.depth_bias_k += 0.5,
            KeyCode::KeyJ => settings.depth_bias_k = (settings.depth_bias_k - 0.5).max(0.0),
            KeyCode::KeyF => force_technique(settings, &[Technique::Full]),
            KeyCode::KeyP => force_technique(settings, &[Technique::PruneOpt, Technique::PruneCook]),
            KeyCode::KeyI => force_technique(settings, &[Technique::Impostors]),
            KeyCode::KeyC => force_technique(settings, &[Technique::Ellipsoids]),
            KeyCode::KeyT => toggle_policy(&mut settings.policy, &mut self.last_policy),
            KeyCode::KeyN => settings.lines = !settings.lines,
            KeyCode::KeyM => settings.impostor_morph = !settings.impostor_morph,
            KeyCode::KeyH => toggle_shadows(&mut settings.shadows, &mut self.last_shadows),
            KeyCode::KeyY => settings.ambient_occlusion = !settings.ambient_occlusion,
            KeyCode::ArrowLeft | KeyCode::ArrowRight | KeyCode::ArrowUp | KeyCode::ArrowDown => {
                settings.sun = turn_sun(settings.sun, code);
            }
            KeyCode::KeyL => {
                settings.shading = match settings.shading {
                    Some(_) => None,
                    None => Some(SELF_SHADOW),
                };
            }
            KeyCode::KeyB => {
                let baselines = [Technique::LodChain, Technique::Billboard, Technique::Crossed, Technique::Octahedral];
                force_technique(settings, &baselines)
            }
            KeyCode::KeyO => settings.pruning.occlusion = !settings.pruning.occlusion,
            KeyCode::Digit1 | KeyCode::Digit2 | KeyCode::Digit3 | KeyCode::Digit4 | KeyCode::Digit6 => {
                settings.debug = match code {
                    KeyCode::Digit1 => DebugView::Shaded,
                    KeyCode::Digit2 => DebugView::Cells,
                    KeyCode::Digit3 => DebugView::Kinds,
                    KeyCode::Digit4 => DebugView::Levels,
                    _ => DebugView::Techniques,
                };
                self.heat_on = false;
            }
            _ => return Some(code),
        }
        // Keep s_min ≤ s_max (selection would raise s_max anyway): the title shows what is used.
        match code {
            KeyCode::BracketRight => settings.s_max = settings.s_max.max(settings.s_min),
            KeyCode::Minus => settings.s_min = settings.s_min.min(settings.s_max),
            _ => {}
        }
        self.title_now = true;
        Some(code)
    }

    fn cursor_moved(&mut self, position: PhysicalPosition<f64>) {
        if let (true, Some(last)) = (self.dragging, self.cursor) {
            let dx = (position.x - last.x) as f32 * LOOK_PER_PIXEL;
            let dy = (position.y - last.y) as f32 * LOOK_PER_PIXEL;
            self.rig.drag(dx, dy);
        }
        self.cursor = Some(position);
    }

    /// Moves the camera by the keys held, or its animation, over `dt` seconds.
    fn fly(&mut self, dt: f32) {
        let held = |a: KeyCode| f32::from(u8::from(self.keys.contains(&a)));
        let axis = |plus: KeyCode, minus: KeyCode| held(plus) - held(minus);
        let movement = Vec3::new(
            axis(KeyCode::KeyW, KeyCode::KeyS),
            axis(KeyCode::KeyD, KeyCode::KeyA),
            axis(KeyCode::KeyE, KeyCode::KeyQ),
        );
        let boost = 1.0 + 4.0 * held(KeyCode::ShiftLeft).max(held(KeyCode::ShiftRight));
        self.rig.advance(dt, movement, boost);
    }

    /// Runs the panel for this frame; returns egui's output to draw and what it asks for.
    fn run_panel(&mut self) -> (egui::FullOutput, Vec<Action>) {
        let raw = self.egui_state.take_egui_input(&self.window);
        let mut actions = Vec::new();
        let ctx = self.egui.clone();
        let name = self.input.file_name().map_or_else(|| self.input.display().to_string(), |n| n.display().to_string());
        let status = self.build.as_ref().map(|b| (b.status(), b.source.display().to_string(), b.started.elapsed()));
        let gpu_selection = self.stage.renderer.gpu_selection_enabled();
        let msaa = self.stage.renderer.formats().sample_count.max(1);
        let output = ctx.run_ui(raw, |ui| {
            if !self.panel_shown {
                return;
            }
            let build = status.as_ref().map(|(status, source, elapsed)| panel::BuildView {
                source,
                stage: &status.stage,
                fraction: status.fraction,
                seconds: elapsed.as_secs_f32(),
            });
            let inputs = panel::Inputs {
                name: &name,
                settings: self.stage.renderer.settings_mut(),
                last_shadows: &mut self.last_shadows,
                rig: &mut self.rig,
                stats: &self.stats,
                holds: self.holds,
                instances: self.scene.instances.len(),
                history: &self.history,
                select_ms: self.select_ms,
                gpu_ms: self.gpu_timer.as_ref().and_then(|t| t.last_ms),
                gpu_selection,
                heat: &mut self.heat_on,
                msaa_choices: &self.msaa_choices,
                msaa,
                build,
                messages: &self.messages,
            };
            egui::Panel::right("treelod view panel")
                .resizable(false)
                .exact_size(panel::WIDTH)
                .show(ui, |ui| actions = panel::show(ui, inputs));
        });
        (output, actions)
    }

    /// Draws and presents one frame. With a screenshot path, the `frames`-th frame since the
    /// scene was shown is also drawn into a texture and read back, and returned.
    fn frame(&mut self, screenshot: Option<&Path>, frames: u32) -> Result<Option<Shot>, Failed> {
        let now = Instant::now();
        let dt = now.duration_since(self.last_frame).as_secs_f32().min(0.1);
        self.last_frame = now;
        self.poll_build();
        if let (Some(failed), Some(_)) = (self.build_failed, screenshot) {
            // The build's errors are printed; there is nothing to take a picture of.
            return Err(failed);
        }
        self.fly(dt);
        let (mut output, actions) = self.run_panel();
        for action in actions {
            match action {
                Action::ToggleGpuSelection => self.toggle_gpu_selection(),
                Action::Msaa(samples) => self.set_msaa(samples),
            }
        }
        self.egui_state.handle_platform_output(&self.window, output.platform_output);
        let pixels_per_point = output.pixels_per_point;
        let jobs = self.egui.tessellate(output.shapes, pixels_per_point);
        // New and changed textures before painting; those to free after (or now, if no frame
        // is drawn).
        for (id, deltas) in output.textures_delta.set.drain() {
            for delta in &deltas {
                self.egui_renderer.update_texture(&self.device, &self.queue, id, delta);
            }
        }
        let free: Vec<egui::TextureId> = output.textures_delta.free.drain().collect();
        let free_textures = |renderer: &mut egui_wgpu::Renderer| free.iter().for_each(|id| renderer.free_texture(id));

        let texture = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                free_textures(&mut self.egui_renderer);
                self.surface.configure(&self.device, &self.config);
                return self.stalled(screenshot);
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                free_textures(&mut self.egui_renderer);
                return self.stalled(screenshot);
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                return Err(unsupported(&self.input, "the window's surface failed validation"));
            }
        };
        self.stalled_since = None;

        let (width, height) = (self.config.width, self.config.height);
        let view_width = self.view_width();
        let (eye, target) = self.rig.eye_and_target();
        let camera = Camera::look_at(eye, target, FOVY_DEGREES.to_radians(), view_width, height);
        let select = Instant::now();
        self.stats = self.stage.renderer.prepare(&self.device, &self.queue, &camera);
        self.select_ms = select.elapsed().as_secs_f64() * 1e3;
        if let Some(timer) = &mut self.gpu_timer {
            timer.begin_frame(&self.device);
        }
        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        let view = texture.texture.create_view(&wgpu::TextureViewDescriptor::default());
        // The shadow maps, drawn before (and sampled by) the passes below.
        self.stage.renderer.render_shadows(&mut encoder);
        let timestamps = self.gpu_timer.as_ref().and_then(GpuTimer::writes);
        if self.heat_on && self.heat.is_none() {
            let formats = self.stage.renderer.formats();
            let settings = self.stage.renderer.settings();
            let scene = (&self.scene, self.models.as_slice());
            match heat::Heat::new(&self.device, &self.queue, formats, settings, scene, (width, height)) {
                Ok(heat) => self.heat = Some(heat),
                Err(e) => {
                    self.heat_on = false;
                    self.messages.push(format!("error: cannot draw the error view: {e}"));
                }
            }
        }
        match self.heat.as_mut().filter(|_| self.heat_on) {
            Some(heat) => {
                let settings = *self.stage.renderer.settings();
                heat.record(&self.device, &self.queue, &mut encoder, &self.stage, &settings, &camera, timestamps);
                heat.draw(&mut encoder, &view, &camera);
            }
            None => draw_scene(&mut encoder, &view, &self.stage, &self.queue, &camera, timestamps),
        }
        if let Some(timer) = &self.gpu_timer {
            timer.resolve(&mut encoder);
        }
        self.stage.renderer.measure_occlusion(&self.device, &mut encoder, &self.stage.depth);
        let screen = egui_wgpu::ScreenDescriptor { size_in_pixels: [width, height], pixels_per_point };
        let mut commands = self.egui_renderer.update_buffers(&self.device, &self.queue, &mut encoder, &jobs, &screen);
        draw_panel(&mut encoder, &view, &self.egui_renderer, &jobs, &screen);
        // A glTF input is shown once built: the screenshot's frames count from then.
        let shown = self.build.is_none() && !(self.scene.models.is_empty() && scene::is_gltf_path(&self.input));
        let capture = match screenshot {
            Some(_) if shown && self.frames + 1 >= frames => {
                Some(Capture::record(self, &mut encoder, &camera, &jobs, &screen))
            }
            _ => None,
        };
        commands.push(encoder.finish());
        self.queue.submit(commands);
        if let Some(timer) = &mut self.gpu_timer {
            timer.after_submit();
        }
        self.window.pre_present_notify();
        self.queue.present(texture);
        free_textures(&mut self.egui_renderer);
        if shown {
            self.frames += 1;
        }
        self.history.push(self.started.elapsed().as_secs_f64(), dt * 1e3, self.stats.primitives());
        self.update_title();

        match (capture, screenshot) {
            (Some(capture), Some(path)) => match capture.read(&self.device) {
                Ok(image) => Ok(Some(Shot {
                    image,
                    stats: self.stats,
                    instances: self.scene.instances.len(),
                    panel: self.panel_shown,
                })),
                Err(e) => {
                    report::message_error(path, &format!("cannot read the frame back: {e}"));
                    Err(Failed { class: ErrorClass::Io })
                }
            },
            _ => Ok(None),
        }
    }

    /// A frame that could not be drawn: try again, unless a screenshot has waited too long.
    fn stalled(&mut self, screenshot: Option<&Path>) -> Result<Option<Shot>, Failed> {
        let since = *self.stalled_since.get_or_insert_with(Instant::now);
        if screenshot.is_some() && since.elapsed() > SCREENSHOT_PATIENCE {
            let message = format!("the window could not be drawn for {} s", SCREENSHOT_PATIENCE.as_secs());
            return Err(unsupported(&self.input, &message));
        }
        Ok(None)
    }

    /// Sets the window title to the statistics, at most every [`TITLE_PERIOD`] (the panel shows
    /// more; the title serves with the panel hidden).
    fn update_title(&mut self) {
        self.title_frames += 1;
        let elapsed = self.title_since.elapsed();
        if elapsed < TITLE_PERIOD && !self.title_now {
            return;
        }
        let fps = f64::from(self.title_frames) / elapsed.as_secs_f64();
        let renderer = &self.stage.renderer;
        let settings = renderer.settings();
        let stats = &self.stats;
        let full_mesh = settings.technique == Technique::Full;
        let mut mode = match (full_mesh, settings.debug) {
            (true, _) => " | full mesh",
            (false, DebugView::Shaded) => "",
            (false, DebugView::Cells) => " | cells",
            (false, DebugView::Kinds) => " | kinds",
            (false, DebugView::Levels) => " | levels",
            (false, DebugView::Techniques) => " | techniques",
        }
        .to_owned();
        if renderer.gpu_selection_enabled() {
            mode.push_str(" | GPU selection");
        }
        let technique = settings.technique;
        let drawn = stats.instances.get(technique);
        if let Some(policy) = settings.policy {
            let target = match (policy.budget, renderer.budget_steering()) {
                (Some(budget), Some((s_min, target))) => {
                    format!("budget {budget}: target {target:.4}, s_min {s_min:.2}")
                }
                _ => format!("target {}", policy.target),
            };
            mode.push_str(&format!(" | policy ({target}): {}", crate::render::technique_counts(&stats.instances)));
        }
        if settings.policy.is_none() && !matches!(technique, Technique::Full | Technique::Spt) {
            mode.push_str(&format!(" | {technique}: {drawn} trees, {}", crate::render::submitted(stats)));
        }
        let (azimuth, elevation) = sun_angles(settings.sun);
        mode.push_str(&format!(" | sun az {:.0} el {:.0}", azimuth.to_degrees(), elevation.to_degrees()));
        if let Some((l_min, l_max)) = settings.shading {
            mode.push_str(&format!(" | self-shadow {l_min}..{l_max}"));
        }
        mode.push_str(if settings.ambient_occlusion { " | AO on" } else { " | AO off" });
        match settings.shadows {
            Some(shadows) => mode.push_str(&format!(
                " | shadows on: {}x{}² to {} m, {} primitives",
                stats.shadow.cascades,
                shadows.resolution,
                shadows.distance,
                stats.shadow.primitives()
            )),
            None => mode.push_str(" | shadows off"),
        }
        let name = self.input.file_name().map_or_else(|| self.input.display().to_string(), |n| n.display().to_string());
        self.window.set_title(&format!(
            "{name} | {fps:.1} fps | {} of {} instances | {} triangles | {} points | s_min {} s_max {} k {}{mode}",
            stats.instances_visible,
            self.scene.instances.len(),
            stats.submitted[Primitive::Triangle],
            stats.submitted[Primitive::Point],
            settings.s_min,
            settings.s_max,
            settings.depth_bias_k,
        ));
        self.title_frames = 0;
        self.title_since = Instant::now();
        self.title_now = false;
    }
}

/// Records the scene's pass into `target`: the sky, the ground (lit and shadowed as the trees
/// are) and the renderer's draws, in the left `camera.width` pixels (the rest is the panel's),
/// through the stage's multisampled target with MSAA.
fn draw_scene(
    encoder: &mut wgpu::CommandEncoder,
    target: &wgpu::TextureView,
    stage: &Stage,
    queue: &wgpu::Queue,
    camera: &Camera,
    timestamps: Option<wgpu::RenderPassTimestampWrites<'_>>,
) {
    let (view, resolve_target) = match &stage.multisampled {
        Some(multisampled) => (multisampled, Some(target)),
        None => (target, None),
    };
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("treelod view"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target,
            ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::BLACK), store: wgpu::StoreOp::Store },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: &stage.depth,
            depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
            stencil_ops: None,
        }),
        timestamp_writes: timestamps,
        ..wgpu::RenderPassDescriptor::default()
    });
    // At the origin, so that the view's pixels are the depth target's (the occlusion measurement
    // reads it by the camera's pixel coordinates).
    pass.set_viewport(0.0, 0.0, camera.width as f32, camera.height as f32, 0.0, 1.0);
    stage.sky.render(queue, &mut pass, &stage.renderer, camera);
    stage.ground.render(queue, &mut pass, &stage.renderer, camera);
    stage.renderer.render(&mut pass);
}

/// Records the panel's pass over `target` (already drawn).
fn draw_panel(
    encoder: &mut wgpu::CommandEncoder,
    target: &wgpu::TextureView,
    renderer: &egui_wgpu::Renderer,
    jobs: &[egui::ClippedPrimitive],
    screen: &egui_wgpu::ScreenDescriptor,
) {
    let pass = overlay_pass(encoder, target, "treelod view panel");
    renderer.render(&mut pass.forget_lifetime(), jobs, screen);
}

/// A pass drawing over what `target` holds, without depth: the panel, the error view.
fn overlay_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    target: &wgpu::TextureView,
    label: &str,
) -> wgpu::RenderPass<'e> {
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: target,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
        })],
        ..wgpu::RenderPassDescriptor::default()
    })
}

/// Whether pixels of `format` are stored blue first (`Some(true)`) or red first (`Some(false)`);
/// `None` for formats a screenshot cannot read back.
fn bgra(format: wgpu::TextureFormat) -> Option<bool> {
    use wgpu::TextureFormat as F;
    match format {
        F::Bgra8Unorm | F::Bgra8UnormSrgb => Some(true),
        F::Rgba8Unorm | F::Rgba8UnormSrgb => Some(false),
        _ => None,
    }
}

/// The screenshot frame drawn a second time, scene and panel, into a texture of the window's
/// size and format, and copied to a buffer to read back.
struct Capture {
    readback: Readback,
    bgra: bool,
}

impl Capture {
    fn record(
        viewer: &Viewer,
        encoder: &mut wgpu::CommandEncoder,
        camera: &Camera,
        jobs: &[egui::ClippedPrimitive],
        screen: &egui_wgpu::ScreenDescriptor,
    ) -> Self {
        let (width, height) = (viewer.config.width, viewer.config.height);
        let texture = viewer.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("treelod view screenshot"),
            size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: viewer.config.format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        match viewer.heat.as_ref().filter(|_| viewer.heat_on) {
            // The frames compared were drawn for the window already.
            Some(heat) => heat.draw(encoder, &view, camera),
            None => draw_scene(encoder, &view, &viewer.stage, &viewer.queue, camera, None),
        }
        draw_panel(encoder, &view, &viewer.egui_renderer, jobs, screen);
        let readback = Readback::record(&viewer.device, encoder, &texture);
        // The format was chosen readable when a screenshot is asked for.
        Self { readback, bgra: bgra(viewer.config.format).unwrap_or(false) }
    }

    /// Waits for the copy (submitted since [`Self::record`]) and returns the RGBA pixels.
    fn read(self, device: &wgpu::Device) -> Result<Image, String> {
        let mut image = self.readback.read(device).map_err(|e| e.to_string())?;
        if self.bgra {
            image.rgba.chunks_exact_mut(4).for_each(|pixel| pixel.swap(0, 2));
        }
        Ok(image)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn technique_keys_step_through_their_group_and_back_to_the_point_tree() {
        let baselines = [Technique::LodChain, Technique::Billboard, Technique::Crossed, Technique::Octahedral];
        let mut t = Technique::Impostors;
        let mut seen = Vec::new();
        for _ in 0..5 {
            t = toggle_technique(t, &baselines);
            seen.push(t);
        }
        assert_eq!(
            seen,
            [Technique::LodChain, Technique::Billboard, Technique::Crossed, Technique::Octahedral, Technique::Spt]
        );
        assert_eq!(toggle_technique(Technique::Full, &[Technique::Full]), Technique::Spt);
        assert_eq!(toggle_technique(Technique::Spt, &[Technique::Full]), Technique::Full);
    }

    #[test]
    fn winit_messages_lose_their_source_location() {
        let message = "os error at /src/winit/linux/mod.rs:765: DISPLAY is not set.";
        assert_eq!(winit_reason(message), "DISPLAY is not set.");
        assert_eq!(winit_reason("the event loop was already run"), "the event loop was already run");
    }

    #[test]
    fn arrow_keys_turn_the_sun_about_the_vertical_and_up_and_down() {
        let start = Vec3::new(0.0, 0.5f32.sqrt(), 0.5f32.sqrt());
        let right = turn_sun(start, KeyCode::ArrowRight);
        assert!((right.y - start.y).abs() < 1e-6, "the elevation is kept");
        assert!((right.x.atan2(right.z).to_degrees() - SUN_STEP_DEGREES).abs() < 1e-3);
        let back = turn_sun(right, KeyCode::ArrowLeft);
        assert!((back - start).length() < 1e-5, "left undoes right: {back}");
        let mut up = start;
        for _ in 0..20 {
            up = turn_sun(up, KeyCode::ArrowUp);
        }
        assert!((up.y.asin().to_degrees() - 85.0).abs() < 1e-3, "the elevation stops at 85°: {up}");
        assert!((up.length() - 1.0).abs() < 1e-6);
        let down = turn_sun(start, KeyCode::ArrowDown);
        assert!((down.y.asin().to_degrees() - 30.0).abs() < 1e-3, "45° − 15°: {down}");
    }

    #[test]
    fn key_h_turns_shadows_off_and_back_on_with_the_same_settings() {
        let custom = Shadows { resolution: 512, cascades: 2, distance: 40.0, ..Shadows::default() };
        let (mut shadows, mut last) = (Some(custom), Shadows::default());
        toggle_shadows(&mut shadows, &mut last);
        assert_eq!((shadows, last), (None, custom));
        toggle_shadows(&mut shadows, &mut last);
        assert_eq!(shadows, Some(custom));
    }

    #[test]
    fn screenshots_read_back_8_bit_formats_only() {
        assert_eq!(bgra(wgpu::TextureFormat::Bgra8UnormSrgb), Some(true));
        assert_eq!(bgra(wgpu::TextureFormat::Rgba8Unorm), Some(false));
        assert_eq!(bgra(wgpu::TextureFormat::Rgba16Float), None);
    }
}
