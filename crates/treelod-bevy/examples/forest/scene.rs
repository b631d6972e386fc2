//! The forest of the `forest` example, shared with the headless test (`tests/headless.rs`):
//! Bevy's plugins, the built-in demo tree, a few thousand instances of it on a jittered grid, a
//! ground, the sun, the camera, and one frame rendered to an image with no window.

#![allow(dead_code, reason = "the example and the test each use part of it")]

use std::sync::{Arc, Mutex};

use bevy_app::{App, TaskPoolPlugin};
use bevy_asset::{AssetPlugin, Assets, Handle, RenderAssetUsages};
use bevy_camera::{Camera3d, ClearColor};
use bevy_color::Color;
use bevy_core_pipeline::CorePipelinePlugin;
use bevy_core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy_ecs::prelude::*;
use bevy_image::Image;
use bevy_light::{DirectionalLight, GlobalAmbientLight};
use bevy_math::{Quat, Vec3};
use bevy_mesh::{Mesh, Mesh3d, MeshBuilder, Meshable};
use bevy_pbr::{MeshMaterial3d, StandardMaterial};
use bevy_render::RenderPlugin;
use bevy_render::settings::{Backends, RenderCreation, WgpuSettings};
use bevy_render::view::Msaa;
use bevy_render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy_shape::Plane3d;
use bevy_transform::components::Transform;
use bevy_window::{ExitCondition, Window, WindowPlugin};
use treelod_bevy::{TreelodContainer, TreelodForest, TreelodPlugin};

/// Trees across (x) and deep (−z): 3000 trees.
pub const COLUMNS: u32 = 60;
/// Rows of trees.
pub const ROWS: u32 = 50;
/// Distance between neighbouring trees before jitter, metres.
pub const SPACING: f32 = 7.0;
/// The headless image (and the screenshot in `docs/images/bevy-forest.png`).
pub const IMAGE_SIZE: (u32, u32) = (640, 360);
/// The sky: what the camera clears to (sRGB).
pub const SKY: [u8; 3] = [150, 190, 230];
/// The ground's albedo (sRGB): a dry brown, so that green pixels are leaves.
pub const GROUND: [u8; 3] = [100, 80, 60];

/// Where trees are drawn.
pub enum Output {
    /// A window (X11), with input.
    Window,
    /// No window: frames go to an image ([`render_frame`]); Vulkan only, so that a machine
    /// without a Vulkan driver fails instead of falling back to another backend.
    Headless,
}

/// Bevy's plugins the example uses (Bevy's own crates, as the plugin depends on them), then
/// [`TreelodPlugin`]. `assets` is the asset folder (Bevy's default `assets` without).
pub fn add_plugins(app: &mut App, output: &Output, assets: Option<String>) {
    let window = match output {
        Output::Window => WindowPlugin {
            primary_window: Some(Window {
                title: "treelod in Bevy".into(),
                resolution: (1280, 720).into(),
                ..Window::default()
            }),
            ..WindowPlugin::default()
        },
        Output::Headless => {
            WindowPlugin { primary_window: None, exit_condition: ExitCondition::DontExit, ..WindowPlugin::default() }
        }
    };
    let mut wgpu = WgpuSettings::default();
    if matches!(output, Output::Headless) {
        wgpu.backends = Some(Backends::VULKAN);
    }
    let mut asset = AssetPlugin::default();
    if let Some(assets) = assets {
        asset.file_path = assets;
    }
    app.add_plugins((
        // Warnings and errors (treelod's included) on stderr.
        bevy_log::LogPlugin::default(),
        TaskPoolPlugin::default(),
        bevy_diagnostic::FrameCountPlugin,
        bevy_time::TimePlugin,
        bevy_transform::TransformPlugin,
        bevy_input::InputPlugin,
        window,
        bevy_a11y::AccessibilityPlugin,
        asset,
    ));
    if matches!(output, Output::Window) {
        app.add_plugins(bevy_winit::WinitPlugin::default());
    }
    app.add_plugins((
        RenderPlugin {
            render_creation: RenderCreation::Automatic(Box::new(wgpu)),
            // Every pipeline ready for the first frame: the headless image shows everything.
            synchronous_pipeline_compilation: matches!(output, Output::Headless),
            ..RenderPlugin::default()
        },
        bevy_image::ImagePlugin::default(),
        bevy_mesh::MeshPlugin,
        bevy_camera::CameraPlugin,
        bevy_light::LightPlugin,
        CorePipelinePlugin,
        bevy_pbr::PbrPlugin::default(),
        TreelodPlugin,
    ));
}

/// Waits until every plugin is ready (the render device is made on a task), then finishes the
/// app's setup, as `App::run` does: for apps driven by [`App::update`].
pub fn finish(app: &mut App) {
    while app.plugins_state() == bevy_app::PluginsState::Adding {
        bevy_tasks::tick_global_task_pools_on_main_thread();
    }
    app.finish();
    app.cleanup();
}

/// The built-in demo tree (`treelod demo` builds the same), as the bytes of a container.
///
/// # Panics
/// If the build fails, which it does not for the built-in tree.
#[must_use]
pub fn demo_container_bytes() -> Vec<u8> {
    use treelod_build::{BuildConfig, DemoTreeConfig, Placed, build_block, demo_tree};
    let tree = demo_tree(&DemoTreeConfig::default());
    let placed = [Placed { scene: &tree, translation: glam::Vec3::ZERO }];
    let built = build_block("demo", &placed, &BuildConfig::default(), "treelod-bevy forest example")
        .expect("the built-in demo tree builds");
    built.data.to_bytes(treelod_format::Compression::None).expect("the demo container encodes")
}

/// A number in `[0, 1)` from `i` and `salt` (a hash, so the forest is the same every run).
fn unit(i: u32, salt: u32) -> f32 {
    let mut h = i.wrapping_mul(0x9E37_79B9) ^ salt.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

/// [`COLUMNS`] × [`ROWS`] trees from x = 0, z = 0 towards +x and −z, each moved by up to a third
/// of the spacing, turned about y and scaled by 0.8–1.2.
#[must_use]
pub fn forest_instances() -> Vec<Transform> {
    (0..COLUMNS * ROWS)
        .map(|i| {
            let (column, row) = (i % COLUMNS, i / COLUMNS);
            let jitter = SPACING / 3.0;
            let x = column as f32 * SPACING + (unit(i, 1) - 0.5) * 2.0 * jitter;
            let z = -(row as f32 * SPACING + (unit(i, 2) - 0.5) * 2.0 * jitter);
            Transform::from_xyz(x, 0.0, z)
                .with_rotation(Quat::from_rotation_y(unit(i, 3) * std::f32::consts::TAU))
                .with_scale(Vec3::splat(0.8 + 0.4 * unit(i, 4)))
        })
        .collect()
}

/// The camera's start: at the forest's near edge, at the height of the crowns, looking in.
#[must_use]
pub fn camera_transform() -> Transform {
    let width = COLUMNS as f32 * SPACING;
    Transform::from_xyz(0.45 * width, 7.0, 14.0).looking_at(Vec3::new(0.5 * width, 2.0, -150.0), Vec3::Y)
}

/// The forest of `container`, its ground, the sun and the sky.
pub fn spawn_world(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    container: Handle<TreelodContainer>,
) {
    commands.spawn(TreelodForest::new(container, forest_instances()));
    let (width, depth) = (COLUMNS as f32 * SPACING, ROWS as f32 * SPACING);
    let [r, g, b] = GROUND;
    commands.spawn((
        Mesh3d(meshes.add(Plane3d::default().mesh().size(width + 400.0, depth + 400.0).build())),
        MeshMaterial3d(materials.add(StandardMaterial {
            base_color: Color::srgb_u8(r, g, b),
            perceptual_roughness: 1.0,
            ..StandardMaterial::default()
        })),
        Transform::from_xyz(0.5 * width, 0.0, -0.5 * depth),
    ));
    // The sun, high in the south-west: treelod shades the trees from its direction and colour.
    commands.spawn((
        DirectionalLight { color: Color::srgb(1.0, 0.97, 0.9), ..DirectionalLight::default() },
        Transform::from_xyz(0.0, 0.0, 0.0).looking_at(Vec3::new(0.4, -0.8, -0.45), Vec3::Y),
    ));
    commands.insert_resource(GlobalAmbientLight { brightness: 300.0, ..GlobalAmbientLight::default() });
    let [r, g, b] = SKY;
    commands.insert_resource(ClearColor(Color::srgb_u8(r, g, b)));
}

/// The components of the scene's camera: a 3D camera without tonemapping (the trees' colours as
/// treelod shades them; so without debanding, which happens in tonemapping), 4× MSAA, at
/// [`camera_transform`].
pub fn camera() -> impl Bundle {
    (Camera3d::default(), Tonemapping::None, DebandDither::Disabled, Msaa::Sample4, camera_transform())
}

/// An RGBA8 image read back from the GPU.
pub struct Frame {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// `width · height · 4` bytes (sRGB, alpha), rows top to bottom.
    pub rgba: Vec<u8>,
}

impl Frame {
    /// The pixel at `(x, y)`.
    #[must_use]
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        [self.rgba[i], self.rgba[i + 1], self.rgba[i + 2], self.rgba[i + 3]]
    }

    /// Writes the frame as an 8-bit RGB PNG.
    ///
    /// # Errors
    /// If the file cannot be written.
    pub fn write_png(&self, path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
        let file = std::io::BufWriter::new(std::fs::File::create(path)?);
        let mut encoder = png::Encoder::new(file, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::High);
        let rgb: Vec<u8> = self.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
        encoder.write_header()?.write_image_data(&rgb)?;
        Ok(())
    }
}

/// A render target image of [`IMAGE_SIZE`] for a headless camera.
#[must_use]
pub fn target_image() -> Image {
    let (width, height) = IMAGE_SIZE;
    let mut image =
        Image::new_target_texture(width, height, bevy_render::render_resource::TextureFormat::Rgba8UnormSrgb, None);
    image.asset_usage = RenderAssetUsages::RENDER_WORLD;
    image
}

/// Runs `app` (set up with [`Output::Headless`]) for `warm_up` frames, then one frame whose
/// images of `views` (cameras and the images they render to) are captured; the cameras are then
/// switched off while further frames wait for the captures to arrive (at most 30), and on again
/// after. The frames come in the order of `views`.
///
/// # Errors
/// If a capture does not arrive, or is not an 8-bit RGBA or BGRA image.
pub fn render_frames(app: &mut App, views: &[(Entity, Handle<Image>)], warm_up: u32) -> Result<Vec<Frame>, String> {
    for _ in 0..warm_up {
        app.update();
    }
    let captured: Vec<Arc<Mutex<Option<Image>>>> = views.iter().map(|_| Arc::default()).collect();
    for ((_, target), slot) in views.iter().zip(&captured) {
        let slot = Arc::clone(slot);
        app.world_mut().spawn(Screenshot::image(target.clone())).observe(move |capture: On<ScreenshotCaptured>| {
            *slot.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some(capture.image.clone());
        });
    }
    app.update();
    for (camera, _) in views {
        set_active(app, *camera, false);
    }
    let arrived = |captured: &[Arc<Mutex<Option<Image>>>]| {
        captured.iter().all(|slot| slot.lock().unwrap_or_else(std::sync::PoisonError::into_inner).is_some())
    };
    for _ in 0..30 {
        if arrived(&captured) {
            break;
        }
        app.update();
    }
    for (camera, _) in views {
        set_active(app, *camera, true);
    }
    captured
        .iter()
        .map(|slot| {
            let image = slot.lock().unwrap_or_else(std::sync::PoisonError::into_inner).take();
            frame_of(&image.ok_or("no screenshot arrived in 30 frames")?)
        })
        .collect()
}

/// Switches `camera` on or off.
fn set_active(app: &mut App, camera: Entity, active: bool) {
    if let Some(mut camera) = app.world_mut().get_mut::<bevy_camera::Camera>(camera) {
        camera.is_active = active;
    }
}

/// The pixels of a captured image as RGBA8.
pub fn frame_of(image: &Image) -> Result<Frame, String> {
    use bevy_render::render_resource::TextureFormat;
    let (width, height) = (image.width(), image.height());
    let data = image.data.as_ref().ok_or("the screenshot holds no data")?;
    let bgra = match image.texture_descriptor.format {
        TextureFormat::Rgba8UnormSrgb | TextureFormat::Rgba8Unorm => false,
        TextureFormat::Bgra8UnormSrgb | TextureFormat::Bgra8Unorm => true,
        other => return Err(format!("the screenshot is {other:?}, not 8-bit RGBA")),
    };
    if data.len() != width as usize * height as usize * 4 {
        return Err(format!("{} bytes for {width}×{height} pixels", data.len()));
    }
    let rgba = if bgra { data.chunks_exact(4).flat_map(|p| [p[2], p[1], p[0], p[3]]).collect() } else { data.clone() };
    Ok(Frame { width, height, rgba })
}
