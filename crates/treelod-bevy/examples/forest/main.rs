//! A fly camera over 3000 treelod trees in Bevy: the built-in demo tree (built in memory at
//! start), or a container you name, on a Bevy ground lit by a Bevy directional light.
//!
//! ```sh
//! cargo run --release -p treelod-bevy --ignore-rust-version --example forest    # the demo tree, a window (X11)
//! cargo run --release -p treelod-bevy --ignore-rust-version --example forest -- tree.treelod   # yours, memory-mapped
//! cargo run --release -p treelod-bevy --ignore-rust-version --example forest -- --headless forest.png  # no window
//! ```
//!
//! (`--ignore-rust-version`: Bevy 0.20 declares Rust 1.97.1; it builds with the workspace's 1.95.)
//!
//! `--screenshot PATH` (with a window) writes the window to a PNG once trees are drawn, and exits.
//!
//! Keys: W A S D to move, Q E down and up, Shift faster, the right mouse button held to look
//! around; K colours triangles red and points blue, F draws the full mesh, L toggles treelod's
//! shadows, B the sun's Bevy shadow maps (the trees cast into them, onto the ground and onto each
//! other), G selection on the GPU. The window title shows what the renderer drew.

mod scene;

use std::path::PathBuf;
use std::process::ExitCode;

use bevy_app::{App, AppExit, Startup, Update};
use bevy_asset::Assets;
use bevy_ecs::prelude::*;
use bevy_input::ButtonInput;
use bevy_input::keyboard::KeyCode;
use bevy_input::mouse::{AccumulatedMouseMotion, MouseButton};
use bevy_math::{EulerRot, Quat, Vec3};
use bevy_mesh::Mesh;
use bevy_pbr::StandardMaterial;
use bevy_render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy_time::Time;
use bevy_transform::components::Transform;
use bevy_window::Window;
use treelod_bevy::treelod_render::{DebugView, Policy, Primitive, Shadows, Technique};
use treelod_bevy::{TreelodContainer, TreelodSettings, TreelodStats};

use scene::Output;

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let mut headless: Option<PathBuf> = None;
    let mut window_shot: Option<PathBuf> = None;
    let mut input: Option<PathBuf> = None;
    while let Some(arg) = args.next() {
        if arg == "--headless" || arg == "--screenshot" {
            let Some(path) = args.next() else {
                eprintln!("error: {} needs the path of the PNG to write", arg.to_string_lossy());
                return ExitCode::from(2);
            };
            if arg == "--headless" { headless = Some(path.into()) } else { window_shot = Some(path.into()) }
        } else {
            input = Some(arg.into());
        }
    }
    // A container named on the command line is memory-mapped; the demo tree is built in memory.
    let container = match &input {
        Some(path) => TreelodContainer::open(path),
        None => TreelodContainer::from_bytes(&scene::demo_container_bytes()),
    };
    let container = match container {
        Ok(container) => container,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(1);
        }
    };
    match headless {
        Some(path) => screenshot(container, &path),
        None => window(container, window_shot),
    }
}

/// Opens the window and flies; with `shot`, captures the window once trees are drawn, writes it
/// there and exits.
fn window(container: TreelodContainer, shot: Option<PathBuf>) -> ExitCode {
    let mut app = App::new();
    scene::add_plugins(&mut app, &Output::Window, None);
    app.insert_resource(Tree(Some(container))).add_systems(Startup, setup).add_systems(Update, (fly, keys, title));
    if let Some(path) = shot {
        app.insert_resource(WindowShot(Some(path))).add_systems(Update, window_shot);
    }
    match app.run() {
        AppExit::Success => ExitCode::SUCCESS,
        AppExit::Error(code) => ExitCode::from(code.get()),
    }
}

/// Renders one frame with no window and writes it to `path`.
fn screenshot(container: TreelodContainer, path: &std::path::Path) -> ExitCode {
    let mut app = App::new();
    scene::add_plugins(&mut app, &Output::Headless, None);
    let target = app.world_mut().resource_mut::<Assets<bevy_image::Image>>().add(scene::target_image());
    app.insert_resource(Tree(Some(container))).add_systems(Startup, setup);
    scene::finish(&mut app);
    let camera = app.world_mut().spawn((scene::camera(), bevy_camera::RenderTarget::Image(target.clone().into()))).id();
    // The first frames load Bevy's shaders and upload the trees.
    let written = scene::render_frames(&mut app, &[(camera, target)], 3).and_then(|frames| {
        frames.first().ok_or_else(|| "no frame".to_owned())?.write_png(path).map_err(|e| e.to_string())
    });
    match written {
        Ok(()) => {
            println!("wrote {}", path.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {}: {e}", path.display());
            ExitCode::from(1)
        }
    }
}

/// Where `--screenshot` writes the window, taken when the capture is requested.
#[derive(Resource)]
struct WindowShot(Option<PathBuf>);

/// Frames drawn with trees before `--screenshot` captures the window.
const SHOT_AFTER_FRAMES: u32 = 5;

/// Captures the window once the camera has drawn trees for a few frames, writes the PNG and
/// exits (with an error if it cannot be written).
fn window_shot(
    mut commands: Commands,
    mut shot: ResMut<WindowShot>,
    stats: Res<TreelodStats>,
    cameras: Query<Entity, With<Fly>>,
    mut frames: Local<u32>,
) {
    let drawn = cameras.single().ok().and_then(|camera| stats.get(camera)).is_some_and(|s| s.instances_visible > 0);
    *frames += u32::from(drawn);
    if *frames < SHOT_AFTER_FRAMES {
        return;
    }
    let Some(path) = shot.0.take() else { return };
    commands.spawn(Screenshot::primary_window()).observe(
        move |capture: On<ScreenshotCaptured>, mut exit: MessageWriter<AppExit>| {
            let written = scene::frame_of(&capture.image).and_then(|f| f.write_png(&path).map_err(|e| e.to_string()));
            exit.write(match written {
                Ok(()) => {
                    println!("wrote {}", path.display());
                    AppExit::Success
                }
                Err(e) => {
                    eprintln!("error: {}: {e}", path.display());
                    AppExit::error()
                }
            });
        },
    );
}

/// The container to plant, taken by [`setup`].
#[derive(Resource)]
struct Tree(Option<TreelodContainer>);

/// How the camera flies: yaw and pitch, radians.
#[derive(Component, Default)]
struct Fly {
    yaw: f32,
    pitch: f32,
}

fn setup(
    mut commands: Commands,
    mut tree: ResMut<Tree>,
    mut containers: ResMut<Assets<TreelodContainer>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    windows: Query<(), With<Window>>,
) {
    let Some(container) = tree.0.take() else { return };
    let handle = containers.add(container);
    scene::spawn_world(&mut commands, &mut meshes, &mut materials, handle);
    if !windows.is_empty() {
        let (yaw, pitch, _) = scene::camera_transform().rotation.to_euler(EulerRot::YXZ);
        commands.spawn((scene::camera(), Fly { yaw, pitch }));
    }
}

/// Turn of the view per pixel the mouse moves, radians.
const LOOK_PER_PIXEL: f32 = 0.003;
/// Flying speed, metres per second, and with Shift held.
const SPEED: f32 = 20.0;
const FAST: f32 = 100.0;

/// W A S D Q E to move (Shift: faster), the right mouse button held to look around.
fn fly(
    time: Res<Time>,
    keys: Res<ButtonInput<KeyCode>>,
    buttons: Res<ButtonInput<MouseButton>>,
    motion: Res<AccumulatedMouseMotion>,
    mut cameras: Query<(&mut Transform, &mut Fly)>,
) {
    for (mut transform, mut fly) in &mut cameras {
        if buttons.pressed(MouseButton::Right) {
            fly.yaw -= motion.delta.x * LOOK_PER_PIXEL;
            // Short of straight up or down, where yaw would lose its meaning.
            fly.pitch = (fly.pitch - motion.delta.y * LOOK_PER_PIXEL).clamp(-1.5, 1.5);
            transform.rotation = Quat::from_euler(EulerRot::YXZ, fly.yaw, fly.pitch, 0.0);
        }
        let axis = |plus: KeyCode, minus: KeyCode| {
            f32::from(u8::from(keys.pressed(plus))) - f32::from(u8::from(keys.pressed(minus)))
        };
        let local = Vec3::new(
            axis(KeyCode::KeyD, KeyCode::KeyA),
            axis(KeyCode::KeyE, KeyCode::KeyQ),
            axis(KeyCode::KeyS, KeyCode::KeyW),
        );
        let speed = if keys.pressed(KeyCode::ShiftLeft) { FAST } else { SPEED };
        let step = transform.rotation * local * speed * time.delta_secs();
        transform.translation += step;
    }
}

/// K: triangles red, points blue; F: the full mesh; L: treelod's shadow cascades; B: the sun's
/// Bevy shadow maps; G: selection on the GPU.
fn keys(
    keys: Res<ButtonInput<KeyCode>>,
    mut settings: ResMut<TreelodSettings>,
    mut suns: Query<&mut bevy_light::DirectionalLight>,
) {
    if keys.just_pressed(KeyCode::KeyB) {
        for mut sun in &mut suns {
            sun.shadow_maps_enabled = !sun.shadow_maps_enabled;
        }
    }
    let render = &mut settings.render;
    if keys.just_pressed(KeyCode::KeyK) {
        render.debug = if render.debug == DebugView::Kinds { DebugView::Shaded } else { DebugView::Kinds };
    }
    if keys.just_pressed(KeyCode::KeyF) {
        // Every tree the full mesh (the policy off), and back to the policy.
        let full = render.technique == Technique::Full;
        render.technique = if full { Technique::Spt } else { Technique::Full };
        render.policy = if full { Some(Policy::default()) } else { None };
    }
    if keys.just_pressed(KeyCode::KeyL) {
        render.shadows = if render.shadows.is_some() { None } else { Some(Shadows::default()) };
    }
    if keys.just_pressed(KeyCode::KeyG) {
        settings.gpu_selection = !settings.gpu_selection;
    }
}

/// The window title: trees in view, triangles and points drawn.
fn title(stats: Res<TreelodStats>, cameras: Query<Entity, With<Fly>>, mut windows: Query<&mut Window>) {
    let (Ok(camera), Ok(mut window)) = (cameras.single(), windows.single_mut()) else { return };
    if let Some(frame) = stats.get(camera) {
        let title = format!(
            "treelod in Bevy: {} trees in view, {} triangles, {} points{}{}{}",
            frame.instances_visible,
            frame.submitted[Primitive::Triangle],
            frame.submitted[Primitive::Point],
            if frame.host_shadow.cascades > 0 {
                format!(", {} cast into Bevy's {} cascades", frame.host_shadow.primitives(), frame.host_shadow.cascades)
            } else {
                String::new()
            },
            if frame.host_shadows_received > 0 {
                format!(", receiving {} of Bevy's cascades", frame.host_shadows_received)
            } else {
                String::new()
            },
            if frame.gpu_selection { " (GPU selection)" } else { "" }
        );
        // Only on a change: a changed `Window` is sent to the windowing system.
        if window.title != title {
            window.title = title;
        }
    }
}
