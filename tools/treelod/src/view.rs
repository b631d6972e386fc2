//! `treelod view`: a window with a fly camera over a container or scene file (winit on X11, wgpu on
//! Vulkan; Mesa lavapipe works), keys for the level-of-detail settings and the frame's statistics
//! in the title. With `--screenshot` it renders `--frames` frames, writes the last as a PNG and
//! exits.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Vec3;
use treelod_format::ErrorClass;
use treelod_render::offscreen::{GpuError, Image, Readback};
use treelod_render::{Camera, DebugView, FrameStats, Ground, Pruning, Renderer, RendererFormats, Settings, Shadows};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, KeyEvent, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, OwnedDisplayHandle};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use crate::render::{
    BASELINES, EllipsoidArgs, ImpostorArgs, LightArgs, PruneArgs, ShadowArgs, baseline_name, frame_camera, parse_size,
    parse_vec3, scene_failed, shadow_primitives, shadow_summary, write_png,
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
    let elevation = elevation.clamp(-85f32.to_radians(), 85f32.to_radians());
    Vec3::new(azimuth.sin() * elevation.cos(), elevation.sin(), azimuth.cos() * elevation.cos())
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

/// Arguments of `treelod view`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A `.treelod` container (drawn once at the origin) or a JSON scene file.
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
    /// Render `--frames` frames, write the last one (window-sized) to this PNG and exit.
    #[arg(long, value_name = "PATH")]
    pub screenshot: Option<PathBuf>,
    /// Frames rendered before the screenshot (streaming refines the level of detail per frame).
    #[arg(long, value_name = "N", default_value_t = 10, requires = "screenshot",
          value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    #[command(flatten)]
    pub prune: PruneArgs,
    #[command(flatten)]
    pub light: LightArgs,
    #[command(flatten)]
    pub shadow: ShadowArgs,
    #[command(flatten)]
    pub impostor: ImpostorArgs,
    /// Start with impostor planes on (key `I`) for trees whose containers have them.
    #[arg(long)]
    pub impostors: bool,
    // `--ellipsoids` starts with Clasen's ellipsoids on (key `C`) for trees whose containers
    // have them; `--no-lines` with their bark as triangles instead of lines (key `N`).
    #[command(flatten)]
    pub ellipsoid: EllipsoidArgs,
    /// Start with a baseline on (key `B` cycles none, lod-chain, billboard, crossed) for trees
    /// whose containers have baselines (build with `--baselines`).
    #[arg(long, value_name = "BASELINE", value_parser = ["lod-chain", "billboard", "crossed"])]
    pub baseline: Option<String>,
}

/// Runs `treelod view`.
pub fn run(args: &Args) -> Result<(), Failed> {
    if let (Some(eye), Some(target)) = (args.eye, args.target)
        && eye.distance_squared(target) < 1e-12
    {
        clap::Error::raw(clap::error::ErrorKind::ValueValidation, "--eye and --target are the same point\n").exit();
    }
    let scene = scene::load(&args.input).map_err(|e| scene_failed(&e))?;
    // Bad files fail before a window is needed (they are opened again once the device exists).
    for model in &scene.models {
        report::open(model)?;
    }
    args.ellipsoid.warn_without(&scene.models);
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
        App { args, scene: &scene, display: event_loop.owned_display_handle(), viewer: None, outcome: Ok(None) };
    if let Err(e) = event_loop.run_app(&mut app) {
        return Err(unsupported(&args.input, &format!("the window's event loop failed: {e}")));
    }
    let outcome = app.outcome?;
    let Some(path) = &args.screenshot else { return Ok(()) };
    let Some((image, stats)) = outcome else {
        report::message_error(path, "the window was closed before the screenshot was taken; nothing written");
        return Err(Failed { class: ErrorClass::Io });
    };
    write_png(path, &image)?;
    let mut line = format!(
        "{}: {}x{}, {} of {} instance(s) visible, {} triangles, {} points",
        path.display(),
        image.width,
        image.height,
        stats.instances_visible,
        scene.instances.len(),
        stats.triangles,
        stats.points
    );
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

/// The winit application: creates the [`Viewer`] once the event loop runs.
struct App<'a> {
    args: &'a Args,
    scene: &'a Scene,
    display: OwnedDisplayHandle,
    viewer: Option<Viewer>,
    /// The screenshot and its frame's statistics once taken, or the failure that ended the loop.
    outcome: Result<Option<(Image, FrameStats)>, Failed>,
}

impl App<'_> {
    fn finish(&mut self, event_loop: &ActiveEventLoop, outcome: Result<Option<(Image, FrameStats)>, Failed>) {
        self.outcome = outcome;
        self.viewer = None;
        event_loop.exit();
    }
}

impl ApplicationHandler for App<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.viewer.is_none() && self.outcome.is_ok() {
            match Viewer::new(event_loop, self.display.clone(), self.args, self.scene) {
                Ok(viewer) => self.viewer = Some(viewer),
                Err(failed) => self.finish(event_loop, Err(failed)),
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let Some(viewer) = &mut self.viewer else { return };
        match event {
            WindowEvent::CloseRequested => self.finish(event_loop, Ok(None)),
            WindowEvent::Resized(size) => viewer.resize(size),
            WindowEvent::KeyboardInput { event, .. } => {
                let pressed = viewer.key(&event);
                if pressed == Some(KeyCode::Escape) {
                    self.finish(event_loop, Ok(None));
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                viewer.dragging = state == ElementState::Pressed;
            }
            WindowEvent::CursorMoved { position, .. } => viewer.cursor_moved(position),
            WindowEvent::Focused(false) => viewer.keys.clear(),
            WindowEvent::RedrawRequested => match viewer.frame(self.args.screenshot.as_deref(), self.args.frames) {
                Ok(None) => viewer.window.request_redraw(),
                Ok(Some(shot)) => self.finish(event_loop, Ok(Some(shot))),
                Err(failed) => self.finish(event_loop, Err(failed)),
            },
            _ => {}
        }
    }
}

/// The window, its surface and device, the renderer and the fly camera.
struct Viewer {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    depth: wgpu::TextureView,
    renderer: Renderer,
    /// The ground under the scene's instances, drawn while shadows are on (made once the
    /// instances are set: it sizes itself from their bounds).
    ground: Ground,
    /// The shadow settings key `H` turns back on (the last ones on).
    last_shadows: Shadows,
    input: PathBuf,
    instances: usize,
    /// Eye position, metres.
    position: Vec3,
    /// Turn about +y, radians; 0 looks down −z.
    yaw: f32,
    /// Elevation, radians.
    pitch: f32,
    /// Metres per second, from the scene's size.
    speed: f32,
    /// Keys held down (movement).
    keys: HashSet<KeyCode>,
    dragging: bool,
    cursor: Option<PhysicalPosition<f64>>,
    last_frame: Instant,
    /// Frames presented.
    frames: u32,
    /// Statistics of the last frame, and frames since the title was last set.
    stats: FrameStats,
    title_frames: u32,
    title_since: Instant,
    /// Set the title at the next frame (a setting changed).
    title_now: bool,
    /// Since when no frame could be drawn (surface timeouts, occlusion).
    stalled_since: Option<Instant>,
}

impl Viewer {
    fn new(
        event_loop: &ActiveEventLoop,
        display: OwnedDisplayHandle,
        args: &Args,
        scene: &Scene,
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
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("treelod view"),
            required_features: Renderer::required_features(),
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
        let depth = depth_view(&device, config.width, config.height);

        let formats = RendererFormats { color: format, depth: DEPTH_FORMAT, sample_count: 1 };
        let mut settings = Settings {
            pruning: args.prune.settings(),
            impostors: args.impostors,
            baseline: crate::render::parse_baseline(args.baseline.as_deref()),
            ..Settings::default()
        };
        args.light.apply(&mut settings);
        args.shadow.apply(&mut settings);
        args.impostor.apply(&mut settings);
        args.ellipsoid.apply(&mut settings);
        let last_shadows = settings.shadows.unwrap_or_default();
        let mut renderer = Renderer::new(&device, formats, settings);
        let bounds = scene::add_to_renderer(scene, &device, &queue, &mut renderer).map_err(|e| scene_failed(&e))?;
        let ground = Ground::under_instances(&device, &renderer);

        let fovy = FOVY_DEGREES.to_radians();
        let start = frame_camera(bounds, args.eye, args.target, fovy, config.width, config.height);
        let forward = -start.view.inverse().z_axis.truncate().normalize_or(Vec3::NEG_Z);
        let now = Instant::now();
        window.request_redraw();
        Ok(Self {
            window,
            surface,
            device,
            queue,
            config,
            depth,
            renderer,
            ground,
            last_shadows,
            input: args.input.clone(),
            instances: scene.instances.len(),
            position: start.position,
            yaw: forward.x.atan2(-forward.z),
            pitch: forward.y.clamp(-1.0, 1.0).asin(),
            speed: 0.25 * (bounds.1 - bounds.0).length().max(4.0),
            keys: HashSet::new(),
            dragging: false,
            cursor: None,
            last_frame: now,
            frames: 0,
            stats: FrameStats::default(),
            title_frames: 0,
            title_since: now,
            title_now: false,
            stalled_since: None,
        })
    }

    fn resize(&mut self, size: PhysicalSize<u32>) {
        let limit = self.device.limits().max_texture_dimension_2d;
        if size.width > 0 && size.height > 0 {
            (self.config.width, self.config.height) = (size.width.min(limit), size.height.min(limit));
            self.surface.configure(&self.device, &self.config);
            self.depth = depth_view(&self.device, self.config.width, self.config.height);
        }
    }

    /// The unit view direction.
    fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(cp * sy, sp, -cp * cy)
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
        if code == KeyCode::KeyG {
            // GPU selection: every model resident whole; refused (and left off) over the budget.
            if self.renderer.gpu_selection_enabled() {
                self.renderer.disable_gpu_selection();
            } else if let Err(e) = self.renderer.enable_gpu_selection(&self.device, &self.queue) {
                report::message_error(&self.input, &format!("cannot select on the GPU: {e}"));
            }
            self.title_now = true;
            return Some(code);
        }
        let settings = self.renderer.settings_mut();
        match code {
            KeyCode::BracketLeft => settings.s_min = (settings.s_min * 0.5).max(1.0 / 64.0),
            KeyCode::BracketRight => settings.s_min = (settings.s_min * 2.0).min(1024.0),
            KeyCode::Minus => settings.s_max = (settings.s_max * 0.5).max(1.0 / 64.0),
            KeyCode::Equal => settings.s_max = (settings.s_max * 2.0).min(1024.0),
            KeyCode::KeyK => settings.depth_bias_k += 0.5,
            KeyCode::KeyJ => settings.depth_bias_k = (settings.depth_bias_k - 0.5).max(0.0),
            KeyCode::KeyF => settings.full_mesh = !settings.full_mesh,
            KeyCode::KeyP => settings.pruning = settings.pruning.is_none().then(Pruning::default),
            KeyCode::KeyI => settings.impostors = !settings.impostors,
            KeyCode::KeyC => settings.ellipsoids = !settings.ellipsoids,
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
                // None, then each of `BASELINES` in turn, then none again.
                let at = settings.baseline.and_then(|b| BASELINES.iter().position(|&(_, x)| x == b));
                let next = at.map_or(0, |i| i + 1);
                settings.baseline = BASELINES.get(next).map(|&(_, b)| b);
            }
            KeyCode::KeyO => {
                if let Some(pruning) = &mut settings.pruning {
                    pruning.occlusion = !pruning.occlusion;
                }
            }
            KeyCode::Digit1 => settings.debug = DebugView::Shaded,
            KeyCode::Digit2 => settings.debug = DebugView::Cells,
            KeyCode::Digit3 => settings.debug = DebugView::Kinds,
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
            self.yaw += (position.x - last.x) as f32 * LOOK_PER_PIXEL;
            self.pitch = (self.pitch - (position.y - last.y) as f32 * LOOK_PER_PIXEL).clamp(-1.55, 1.55);
        }
        self.cursor = Some(position);
    }

    /// Moves the camera by the keys held over `dt` seconds.
    fn fly(&mut self, dt: f32) {
        let forward = self.forward();
        let right = forward.cross(Vec3::Y).normalize_or(Vec3::X);
        let held = |a: KeyCode, b: KeyCode| f32::from(u8::from(self.keys.contains(&a) || self.keys.contains(&b)));
        let axis = |plus: KeyCode, minus: KeyCode| {
            f32::from(u8::from(self.keys.contains(&plus))) - f32::from(u8::from(self.keys.contains(&minus)))
        };
        let direction = forward * axis(KeyCode::KeyW, KeyCode::KeyS)
            + right * axis(KeyCode::KeyD, KeyCode::KeyA)
            + Vec3::Y * axis(KeyCode::KeyE, KeyCode::KeyQ);
        let boost = 1.0 + 4.0 * held(KeyCode::ShiftLeft, KeyCode::ShiftRight);
        self.position += direction.normalize_or_zero() * self.speed * boost * dt;
    }

    /// Draws and presents one frame. With a screenshot path, the `frames`-th frame is also drawn
    /// into a texture and read back, and returned with its statistics.
    fn frame(&mut self, screenshot: Option<&Path>, frames: u32) -> Result<Option<(Image, FrameStats)>, Failed> {
        let now = Instant::now();
        let dt = now.duration_since(self.last_frame).as_secs_f32().min(0.1);
        self.last_frame = now;
        self.fly(dt);

        let texture = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.device, &self.config);
                return self.stalled(screenshot);
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                return self.stalled(screenshot);
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                return Err(unsupported(&self.input, "the window's surface failed validation"));
            }
        };
        self.stalled_since = None;

        let (width, height) = (self.config.width, self.config.height);
        let camera =
            Camera::look_at(self.position, self.position + self.forward(), FOVY_DEGREES.to_radians(), width, height);
        self.stats = self.renderer.prepare(&self.device, &self.queue, &camera);
        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        let view = texture.texture.create_view(&wgpu::TextureViewDescriptor::default());
        // The shadow maps, drawn before (and sampled by) the passes below.
        self.renderer.render_shadows(&mut encoder);
        let ground = self.renderer.settings().shadows.is_some().then_some((&self.ground, &self.queue, &camera));
        draw_pass(&mut encoder, &view, &self.depth, &self.renderer, ground);
        self.renderer.measure_occlusion(&self.device, &mut encoder, &self.depth);
        let capture = match screenshot {
            Some(_) if self.frames + 1 >= frames => Some(Capture::record(self, &mut encoder, &camera)),
            _ => None,
        };
        self.queue.submit([encoder.finish()]);
        self.window.pre_present_notify();
        self.queue.present(texture);
        self.frames += 1;
        self.update_title();

        match (capture, screenshot) {
            (Some(capture), Some(path)) => match capture.read(&self.device) {
                Ok(image) => Ok(Some((image, self.stats))),
                Err(e) => {
                    report::message_error(path, &format!("cannot read the frame back: {e}"));
                    Err(Failed { class: ErrorClass::Io })
                }
            },
            _ => Ok(None),
        }
    }

    /// A frame that could not be drawn: try again, unless a screenshot has waited too long.
    fn stalled(&mut self, screenshot: Option<&Path>) -> Result<Option<(Image, FrameStats)>, Failed> {
        let since = *self.stalled_since.get_or_insert_with(Instant::now);
        if screenshot.is_some() && since.elapsed() > SCREENSHOT_PATIENCE {
            let message = format!("the window could not be drawn for {} s", SCREENSHOT_PATIENCE.as_secs());
            return Err(unsupported(&self.input, &message));
        }
        Ok(None)
    }

    /// Sets the window title to the statistics, at most every [`TITLE_PERIOD`].
    fn update_title(&mut self) {
        self.title_frames += 1;
        let elapsed = self.title_since.elapsed();
        if elapsed < TITLE_PERIOD && !self.title_now {
            return;
        }
        let fps = f64::from(self.title_frames) / elapsed.as_secs_f64();
        let settings = self.renderer.settings();
        let mut mode = match (settings.full_mesh, settings.debug) {
            (true, _) => " | full mesh",
            (false, DebugView::Shaded) => "",
            (false, DebugView::Cells) => " | cells",
            (false, DebugView::Kinds) => " | kinds",
        }
        .to_owned();
        if self.renderer.gpu_selection_enabled() {
            mode.push_str(" | GPU selection");
        }
        if let Some(baseline) = settings.baseline.filter(|_| !settings.full_mesh) {
            let name = baseline_name(baseline);
            mode.push_str(&format!(
                " | baseline {name}: {} trees, {} triangles, {} quads",
                self.stats.instances_baseline, self.stats.triangles, self.stats.billboards
            ));
        } else if settings.ellipsoids && !settings.full_mesh {
            mode.push_str(&format!(
                " | ellipsoids (quality {}, blend {}): {} trees, {} ellipsoids, {}",
                settings.ellipsoid_quality,
                settings.level_blend,
                self.stats.instances_ellipsoids,
                self.stats.ellipsoids,
                if settings.lines { format!("{} lines", self.stats.lines) } else { "bark triangles".to_owned() }
            ));
            if settings.impostors {
                mode.push_str(&format!(
                    ", impostors: {} trees, {} planes",
                    self.stats.instances_impostors, self.stats.planes
                ));
            }
        } else if settings.impostors && !settings.full_mesh {
            mode.push_str(&format!(
                " | impostors: {} trees, {} planes",
                self.stats.instances_impostors, self.stats.planes
            ));
        } else if let Some(pruning) = settings.pruning.filter(|_| !settings.full_mesh) {
            let occlusion = if pruning.occlusion { ", occlusion" } else { "" };
            mode.push_str(&format!(
                " | pruning{occlusion}: {} trees, {} leaves",
                self.stats.instances_pruned, self.stats.leaves_pruned
            ));
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
                self.stats.shadow.cascades,
                shadows.resolution,
                shadows.distance,
                shadow_primitives(&self.stats.shadow)
            )),
            None => mode.push_str(" | shadows off"),
        }
        let name = self.input.file_name().map_or_else(|| self.input.display().to_string(), |n| n.display().to_string());
        self.window.set_title(&format!(
            "{name} | {fps:.1} fps | {} of {} instances | {} triangles | {} points | s_min {} s_max {} k {}{mode}",
            self.stats.instances_visible,
            self.instances,
            self.stats.triangles,
            self.stats.points,
            settings.s_min,
            settings.s_max,
            settings.depth_bias_k,
        ));
        self.title_frames = 0;
        self.title_since = Instant::now();
        self.title_now = false;
    }
}

/// Clears `color` to white and `depth` to far, and records the renderer's draws, after the
/// `ground` (seen by the camera; its uniform written with the queue) if given.
fn draw_pass(
    encoder: &mut wgpu::CommandEncoder,
    color: &wgpu::TextureView,
    depth: &wgpu::TextureView,
    renderer: &Renderer,
    ground: Option<(&Ground, &wgpu::Queue, &Camera)>,
) {
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("treelod view"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: color,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::WHITE), store: wgpu::StoreOp::Store },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
            stencil_ops: None,
        }),
        ..wgpu::RenderPassDescriptor::default()
    });
    if let Some((ground, queue, camera)) = ground {
        ground.render(queue, &mut pass, renderer, camera);
    }
    renderer.render(&mut pass);
}

fn depth_view(device: &wgpu::Device, width: u32, height: u32) -> wgpu::TextureView {
    device
        .create_texture(&wgpu::TextureDescriptor {
            label: Some("treelod view depth"),
            size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            // Sampled by the occlusion measurement of pruned trees.
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        })
        .create_view(&wgpu::TextureViewDescriptor::default())
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

/// The screenshot frame drawn a second time, into a texture of the window's size and format,
/// and copied to a buffer to read back.
struct Capture {
    readback: Readback,
    bgra: bool,
}

impl Capture {
    fn record(viewer: &Viewer, encoder: &mut wgpu::CommandEncoder, camera: &Camera) -> Self {
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
        let ground = viewer.renderer.settings().shadows.is_some().then_some((&viewer.ground, &viewer.queue, camera));
        draw_pass(encoder, &view, &viewer.depth, &viewer.renderer, ground);
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
