//! Bevy draws the forest example's 3000 trees with treelod, headless on Vulkan (Mesa lavapipe in
//! CI; no adapter is a failure): the container loads through Bevy's asset server, the frame is
//! captured from an image target, and the image must hold leaves below the horizon and sky above
//! it, a Bevy cube standing in front of the trees must hide them (Bevy's depth buffer is read with
//! its reverse-Z convention), and the trees must hide part of a Bevy cube behind them (they write
//! that depth buffer). A malformed `.treelod` asset fails to load with the container's error.
//! Trees behind a Bevy wall are chosen hidden, a tree casts its shadow onto Bevy's ground through
//! the cascades of a Bevy directional light and receives the shadow a Bevy mesh casts, and GPU
//! selection over the memory budget is refused (the camera selects on the CPU).

#[path = "../examples/forest/scene.rs"]
mod scene;

use std::time::Instant;

use bevy_app::{App, Startup, TaskPoolPlugin};
use bevy_asset::{AssetPlugin, AssetServer, Assets, LoadState};
use bevy_color::Color;
use bevy_ecs::prelude::*;
use bevy_math::Vec3;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_pbr::{MeshMaterial3d, StandardMaterial};
use bevy_render::renderer::RenderAdapterInfo;
use bevy_shape::Cuboid;
use bevy_transform::components::Transform;
use scene::{Frame, IMAGE_SIZE, Output};
use treelod_bevy::treelod_render::Primitive;
use treelod_bevy::{TreelodContainer, TreelodPlugin, TreelodStats};

/// Whether a pixel is a leaf: clearly greener than red and blue (the sky is blue, the ground
/// brown, the cubes red and blue).
fn leaf(p: [u8; 4]) -> bool {
    p[1] > p[0].saturating_add(8) && p[1] > p[2].saturating_add(8)
}

/// The HDR camera's image.
const SMALL: (u32, u32) = (160, 90);

/// The cube colours, unlit: exactly these in the image (sRGB).
const RED: [u8; 3] = [220, 30, 30];
const BLUE: [u8; 3] = [30, 30, 220];

fn is(p: [u8; 4], colour: [u8; 3]) -> bool {
    p.iter().zip(colour).all(|(a, b)| a.abs_diff(b) <= 6)
}

/// The pixel rectangle (x0, y0, x1, y1) that a world-space box projects to with the scene's camera
/// (Bevy's default perspective: 45° vertical field of view).
fn projected(centre: Vec3, half: Vec3) -> (u32, u32, u32, u32) {
    let (width, height) = IMAGE_SIZE;
    let view = glam::Mat4::from_cols_array(&scene::camera_transform().to_matrix().inverse().to_cols_array());
    let aspect = width as f32 / height as f32;
    let proj = glam::camera::rh::proj::directx::perspective_infinite_reverse(std::f32::consts::FRAC_PI_4, aspect, 0.1);
    let (mut x0, mut y0, mut x1, mut y1) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
    for corner in 0..8 {
        let sign = |bit: u32| if corner & bit == 0 { -1.0 } else { 1.0 };
        let p = centre + half * Vec3::new(sign(1), sign(2), sign(4));
        let ndc = (proj * view).project_point3(glam::Vec3::from_array(p.to_array()));
        let (x, y) = ((ndc.x + 1.0) * 0.5 * width as f32, (1.0 - ndc.y) * 0.5 * height as f32);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    let clamp = |v: f32, max: u32| v.clamp(0.0, (max - 1) as f32) as u32;
    (clamp(x0, width), clamp(y0, height), clamp(x1, width), clamp(y1, height))
}

/// The share of the pixels of `rect` for which `test` holds.
fn share(frame: &Frame, (x0, y0, x1, y1): (u32, u32, u32, u32), test: impl Fn([u8; 4]) -> bool) -> f64 {
    let (mut hits, mut all) = (0u32, 0u32);
    for y in y0..=y1 {
        for x in x0..=x1 {
            all += 1;
            hits += u32::from(test(frame.pixel(x, y)));
        }
    }
    f64::from(hits) / f64::from(all.max(1))
}

/// The right edge of the blue cube on screen.
fn blue_right((centre, half): (Vec3, Vec3)) -> u32 {
    projected(centre, half).2
}

/// Runs frames until `handle` has loaded (loading runs on the task pool; frames run meanwhile,
/// with no trees); panics if it fails or takes more than 500 frames.
fn wait_for_load(app: &mut App, handle: &bevy_asset::Handle<TreelodContainer>) {
    for _ in 0..500 {
        app.update();
        match app.world().resource::<AssetServer>().load_state(handle) {
            LoadState::Loaded => return,
            LoadState::Failed(e) => panic!("the container fails to load: {e}"),
            _ => std::thread::sleep(std::time::Duration::from_millis(10)),
        }
    }
    panic!("the container did not load in 500 frames");
}

/// An app with the plugins (headless), `settings`, and the demo tree's container loading from a
/// temporary asset folder: the app, the folder (kept while the app runs), the container's
/// handle and its block's bounds (min, max).
fn demo_app(
    settings: treelod_bevy::TreelodSettings,
) -> (App, tempfile::TempDir, bevy_asset::Handle<TreelodContainer>, (Vec3, Vec3)) {
    let assets = tempfile::tempdir().expect("a temporary directory");
    let bytes = scene::demo_container_bytes();
    std::fs::write(assets.path().join("demo.treelod"), &bytes).expect("writes the container");
    let block = *TreelodContainer::from_bytes(&bytes).expect("opens").container().block();
    let mut app = App::new();
    scene::add_plugins(&mut app, &Output::Headless, Some(assets.path().to_string_lossy().into_owned()));
    app.insert_resource(settings);
    let handle = app.world().resource::<AssetServer>().load::<TreelodContainer>("demo.treelod");
    (app, assets, handle, (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max)))
}

/// A camera at `eye` looking at `at` into a new image target, once the scene is finished and
/// the container `handle` loaded: the camera and its target.
fn image_camera(
    app: &mut App,
    handle: &bevy_asset::Handle<TreelodContainer>,
    eye: Vec3,
    at: Vec3,
) -> (Entity, bevy_asset::Handle<bevy_image::Image>) {
    let target = app.world_mut().resource_mut::<Assets<bevy_image::Image>>().add(scene::target_image());
    scene::finish(app);
    let camera = app
        .world_mut()
        .spawn((scene::camera(), bevy_camera::RenderTarget::Image(target.clone().into())))
        .insert(Transform::from_translation(eye).looking_at(at, Vec3::Y))
        .id();
    wait_for_load(app, handle);
    (camera, target)
}

/// `camera`'s frame into `target` after `change` to the settings and six frames to settle, and
/// the camera's counts.
fn frame_after(
    app: &mut App,
    (camera, target): &(Entity, bevy_asset::Handle<bevy_image::Image>),
    change: impl FnOnce(&mut treelod_bevy::TreelodSettings),
) -> (Frame, treelod_render::FrameStats) {
    change(&mut app.world_mut().resource_mut::<treelod_bevy::TreelodSettings>());
    let frame = scene::render_frames(app, &[(*camera, target.clone())], 6).expect("a frame").remove(0);
    (frame, app.world().resource::<TreelodStats>().get(*camera).expect("the camera drew trees"))
}

/// Spawns at start-up the demo tree `forest` at the origin, a Bevy mesh (its material and
/// transform), and a directional light with shadow maps, placed by `sun`.
fn one_tree_in_the_sun(
    app: &mut App,
    forest: &bevy_asset::Handle<TreelodContainer>,
    (mesh, material, at): (Mesh, StandardMaterial, Transform),
    sun: Transform,
) {
    let forest = forest.clone();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<StandardMaterial>>| {
            commands.spawn(treelod_bevy::TreelodForest::new(forest.clone(), [Transform::IDENTITY]));
            commands.spawn((Mesh3d(meshes.add(mesh.clone())), MeshMaterial3d(materials.add(material.clone())), at));
            commands.spawn((bevy_light::DirectionalLight { shadow_maps_enabled: true, ..Default::default() }, sun));
        },
    );
}

#[test]
fn bevy_draws_the_forest_in_its_main_pass() {
    let started = Instant::now();
    let (mut app, _assets, handle, (min, max)) = demo_app(treelod_bevy::TreelodSettings::default());

    // The camera and the forest as in the example; a red cube in front of the first trees; a blue
    // cube behind the tree nearest the camera's view axis in the first row.
    let camera = scene::camera_transform();
    let red =
        (camera.translation + camera.forward() * 4.0 + camera.left() * 2.0 + camera.down() * 0.9, Vec3::splat(0.7));
    let trees = scene::forest_instances();
    // Nothing of any tree reaches the red cube: it stands wholly in front of the forest.
    let reach = min.abs().max(max.abs()).with_y(0.0).length();
    let forest_front = trees.iter().map(|t| t.translation.z + reach * t.scale.x).fold(f32::MIN, f32::max);
    assert!(
        red.0.z - red.1.z > forest_front,
        "the red cube ({red:?}) is in front of the forest (z up to {forest_front})"
    );
    let axis_x = camera.translation.x;
    let front = trees
        .iter()
        .take(scene::COLUMNS as usize)
        .min_by(|a, b| (a.translation.x - axis_x).abs().total_cmp(&(b.translation.x - axis_x).abs()))
        .expect("a first row");
    let away = (front.translation - camera.translation).with_y(0.0).normalize();
    // A little behind the tree, over the middle half of its height.
    let (low, high) = (min.y * front.scale.y, max.y * front.scale.y);
    let blue = (
        front.translation + away * 3.0 + Vec3::Y * 0.5 * (low + high),
        Vec3::new(0.25 * (high - low), 0.25 * (high - low), 0.5),
    );
    let forest = handle.clone();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<StandardMaterial>>| {
            scene::spawn_world(&mut commands, &mut meshes, &mut materials, forest.clone());
            for ((centre, half), [r, g, b]) in [(red, RED), (blue, BLUE)] {
                commands.spawn((
                    Mesh3d(meshes.add(Cuboid::from_size(half * 2.0))),
                    MeshMaterial3d(materials.add(StandardMaterial {
                        base_color: Color::srgb_u8(r, g, b),
                        unlit: true,
                        ..StandardMaterial::default()
                    })),
                    Transform::from_translation(centre),
                ));
            }
        },
    );
    let target = app.world_mut().resource_mut::<Assets<bevy_image::Image>>().add(scene::target_image());
    // A second camera, HDR (an `Rgba16Float` main texture) without MSAA, in the forest's first
    // rows looking out of it: a renderer of its own for other formats, and only a few trees.
    let mut small = bevy_image::Image::new_target_texture(
        SMALL.0,
        SMALL.1,
        bevy_render::render_resource::TextureFormat::Rgba8UnormSrgb,
        None,
    );
    small.asset_usage = bevy_asset::RenderAssetUsages::RENDER_WORLD;
    let small = app.world_mut().resource_mut::<Assets<bevy_image::Image>>().add(small);
    scene::finish(&mut app);
    let adapter =
        app.world().get_resource::<RenderAdapterInfo>().expect("a render adapter (install mesa-vulkan-drivers)");
    assert_eq!(adapter.backend, wgpu::Backend::Vulkan, "the test renders on Vulkan, got {:?}", **adapter);
    let camera_entity =
        app.world_mut().spawn((scene::camera(), bevy_camera::RenderTarget::Image(target.clone().into()))).id();
    let hdr_entity = app
        .world_mut()
        .spawn((
            bevy_camera::Camera3d::default(),
            bevy_camera::Hdr,
            bevy_core_pipeline::tonemapping::Tonemapping::None,
            bevy_core_pipeline::tonemapping::DebandDither::Disabled,
            bevy_render::view::Msaa::Off,
            Transform::from_xyz(3.0 * scene::SPACING, 3.0, -2.0 * scene::SPACING)
                .looking_at(Vec3::new(3.0 * scene::SPACING, 3.0, 30.0), Vec3::Y),
            bevy_camera::RenderTarget::Image(small.clone().into()),
        ))
        .id();
    wait_for_load(&mut app, &handle);
    let loaded = started.elapsed();
    // One frame with the trees before the captured one: their upload completes in the first
    // (`Settings::upload_budget` exceeds the container).
    let frames = scene::render_frames(&mut app, &[(camera_entity, target), (hdr_entity, small)], 1)
        .expect("the frames are captured");
    let (frame, hdr_frame) = (&frames[0], &frames[1]);
    eprintln!("container built and loaded in {loaded:.1?}, frame captured at {:.1?}", started.elapsed());
    if let Some(path) = std::env::var_os("TREELOD_BEVY_IMAGE") {
        let path = std::path::Path::new(&path);
        frame.write_png(path).expect("writes the image");
        hdr_frame.write_png(&path.with_extension("hdr.png")).expect("writes the image");
    }

    let stats = app.world().resource::<TreelodStats>().get(camera_entity).expect("the camera drew trees");
    eprintln!("{stats:?}");
    assert!(
        (300..3000).contains(&stats.instances_visible),
        "{} of 3000 trees in view (the camera looks into the forest from its edge)",
        stats.instances_visible
    );
    assert!(
        stats.submitted[Primitive::Triangle] > 0 && stats.submitted[Primitive::Point] > 0,
        "near trees are triangles, far ones points: {stats:?}"
    );
    assert_eq!(stats.ranges_clamped, 0, "every range is drawn at the detail selected (all of it resident)");
    let hdr_stats = app.world().resource::<TreelodStats>().get(hdr_entity).expect("the HDR camera drew trees");
    let hdr_leaves = share(hdr_frame, (0, 0, SMALL.0 - 1, SMALL.1 - 1), leaf);
    eprintln!("HDR camera: {} trees in view, leaves {hdr_leaves:.3} of its image", hdr_stats.instances_visible);
    assert!((1..60).contains(&hdr_stats.instances_visible), "the HDR camera sees a few trees: {hdr_stats:?}");
    assert!(hdr_leaves > 0.05, "the HDR camera's image shows leaves: {hdr_leaves:.3}");

    let (width, height) = IMAGE_SIZE;
    // Sky above the forest; the far rows of the forest (200 m on, 2–5 m up: the crowns) a band
    // of leaves beside the cubes; the near trees below it.
    let sky = share(frame, (0, 0, width - 1, height / 10), |p| is(p, [scene::SKY[0], scene::SKY[1], scene::SKY[2]]));
    let depth = scene::ROWS as f32 * scene::SPACING;
    let far_rows = projected(
        Vec3::new(camera.translation.x, 3.5, -0.5 * (200.0 + depth)),
        Vec3::new(1.0, 1.5, 0.5 * (depth - 200.0)),
    );
    let far_band = (blue_right(blue) + 2, far_rows.1, width - 1, far_rows.3);
    let far_leaves = share(frame, far_band, leaf);
    let near_leaves = share(frame, (0, height / 2, width - 1, height - 1), leaf);
    // The red cube, in front of the trees, is not drawn over: the rectangle a box of half its
    // size projects to lies inside its silhouette.
    let red_rect = projected(red.0, red.1 * 0.5);
    let red_share = share(frame, red_rect, |p| is(p, RED));
    // The blue cube, behind the first tree, is partly hidden by it.
    let blue_rect = projected(blue.0, blue.1 * 0.5);
    let blue_share = share(frame, blue_rect, |p| is(p, BLUE));
    let blue_hidden = share(frame, blue_rect, |p| !is(p, BLUE));
    eprintln!(
        "sky {sky:.3} of the top tenth; leaves {far_leaves:.3} of the far rows {far_band:?}, {near_leaves:.3} of the \
         lower half; red cube {red_rect:?}: {red_share:.3} red; blue cube {blue_rect:?}: {blue_share:.3} blue, \
         {blue_hidden:.3} hidden"
    );
    assert!(sky > 0.95, "the top of the image is sky: {sky:.3}");
    assert!(far_leaves > 0.6, "the far rows are a band of leaves: {far_leaves:.3} of {far_band:?}");
    assert!(near_leaves > 0.12, "the lower half shows the near trees' leaves: {near_leaves:.3}");
    assert!(red_share > 0.97, "the red cube hides the trees behind it: {red_share:.3} of {red_rect:?} is red");
    assert!(blue_share > 0.1, "the blue cube shows beside the tree: {blue_share:.3} of {blue_rect:?}");
    assert!(blue_hidden > 0.2, "the tree in front hides part of the blue cube: {blue_hidden:.3} of {blue_rect:?}");
}

#[test]
fn a_malformed_container_fails_to_load_with_its_error() {
    let assets = tempfile::tempdir().expect("a temporary directory");
    let bytes = scene::demo_container_bytes();
    // Truncated in its section table.
    std::fs::write(assets.path().join("broken.treelod"), &bytes[..100]).expect("writes");
    std::fs::write(assets.path().join("text.treelod"), b"not a container").expect("writes");
    let mut app = App::new();
    app.add_plugins((
        TaskPoolPlugin::default(),
        AssetPlugin { file_path: assets.path().to_string_lossy().into_owned(), ..AssetPlugin::default() },
        TreelodPlugin,
    ));
    scene::finish(&mut app);
    let server = app.world().resource::<AssetServer>().clone();
    for (name, expected) in [("broken.treelod", "truncated"), ("text.treelod", "not a .treelod file")] {
        let handle = server.load::<TreelodContainer>(name);
        let mut state = LoadState::Loading;
        for _ in 0..500 {
            app.update();
            state = server.load_state(&handle);
            if !matches!(state, LoadState::Loading | LoadState::NotLoaded) {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        let LoadState::Failed(error) = state else { panic!("{name}: expected a failure, got {state:?}") };
        let message = error.to_string();
        assert!(
            message.contains("not a valid .treelod container") && message.contains(expected) && message.contains(name),
            "{name}: {message}"
        );
    }
}

/// Trees hidden behind a Bevy mesh are measured in Bevy's depth buffer after the trees' pass and
/// chosen at their visible fraction (the policy's occlusion, on by default): a wall in front of a
/// row of trees makes them cheaper, and without it the measurement changes nothing (each tree is
/// seen whole, so Bevy's reverse-Z depth is read the right way round).
#[test]
fn trees_behind_a_bevy_wall_are_chosen_hidden() {
    use treelod_bevy::TreelodSettings;
    use treelod_bevy::treelod_render::{Policy, Technique};

    // The demo tree with impostor planes and the build's calibration tables: the policy draws a
    // tree of about 60 pixels with the point tree when it is seen, with planes when hidden.
    let tree = treelod_build::demo_tree(&treelod_build::DemoTreeConfig::default());
    let placed = [treelod_build::Placed { scene: &tree, translation: glam::Vec3::ZERO }];
    let config = treelod_build::BuildConfig {
        impostors: Some(treelod_build::ImpostorConfig::default()),
        calibration: Some(treelod_build::CalibrationConfig { views: 1, supersample: 2, more_small_views: false }),
        ..treelod_build::BuildConfig::default()
    };
    let built = treelod_build::build_block("demo", &placed, &config, "treelod-bevy occlusion test").expect("builds");
    let bytes = built.data.to_bytes(treelod_format::Compression::None).expect("encodes");
    let assets = tempfile::tempdir().expect("a temporary directory");
    std::fs::write(assets.path().join("calibrated.treelod"), &bytes).expect("writes the container");
    let block = *TreelodContainer::from_bytes(&bytes).expect("opens").container().block();
    let height = block.bounds_max[1] - block.bounds_min[1];

    let mut app = App::new();
    scene::add_plugins(&mut app, &Output::Headless, Some(assets.path().to_string_lossy().into_owned()));
    let policy = Policy { hysteresis: 0.0, transition: 0, ..Policy::default() };
    assert!(policy.occlusion, "on by default");
    let mut settings = TreelodSettings::default();
    settings.render.policy = Some(policy);
    app.insert_resource(settings);
    // Side by side, none in front of another: at 25, 35 and 50 m, left to right.
    let trees = [Vec3::new(-10.0, 0.0, -25.0), Vec3::new(0.0, 0.0, -35.0), Vec3::new(10.0, 0.0, -50.0)];
    let handle = app.world().resource::<AssetServer>().load::<TreelodContainer>("calibrated.treelod");
    let forest = handle.clone();
    let wall = app
        .world_mut()
        .spawn((Transform::from_xyz(0.0, 0.5 * height, -10.0), bevy_camera::visibility::Visibility::Hidden))
        .id();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<StandardMaterial>>| {
            commands.spawn(treelod_bevy::TreelodForest::new(forest.clone(), trees.map(Transform::from_translation)));
            // Wider and taller than the view 10 m away: everything behind it is hidden.
            commands.entity(wall).insert((
                Mesh3d(meshes.add(Cuboid::new(60.0, 40.0, 0.5))),
                MeshMaterial3d(materials.add(StandardMaterial {
                    base_color: Color::srgb_u8(RED[0], RED[1], RED[2]),
                    unlit: true,
                    ..StandardMaterial::default()
                })),
            ));
        },
    );
    let target = app.world_mut().resource_mut::<Assets<bevy_image::Image>>().add(scene::target_image());
    scene::finish(&mut app);
    let eye = Vec3::new(0.0, 0.5 * height, 0.0);
    let camera = app
        .world_mut()
        .spawn((scene::camera(), bevy_camera::RenderTarget::Image(target.clone().into())))
        .insert(Transform::from_translation(eye).looking_at(eye - Vec3::Z, Vec3::Y))
        .id();
    wait_for_load(&mut app, &handle);
    // A few frames with the settings: the first ones make the depth buffer samplable, measure,
    // and read the measurement back (mapped without waiting).
    let run = |app: &mut App, occlusion: bool, wall_shown: bool| {
        app.world_mut().resource_mut::<TreelodSettings>().render.policy = Some(Policy { occlusion, ..policy });
        *app.world_mut().get_mut::<bevy_camera::visibility::Visibility>(wall).expect("the wall") = if wall_shown {
            bevy_camera::visibility::Visibility::Visible
        } else {
            bevy_camera::visibility::Visibility::Hidden
        };
        for _ in 0..8 {
            app.update();
        }
        app.world().resource::<TreelodStats>().get(camera).expect("the camera drew trees")
    };
    let seen = run(&mut app, true, false);
    let seen_unmeasured = run(&mut app, false, false);
    let hidden_unmeasured = run(&mut app, false, true);
    let hidden = run(&mut app, true, true);
    for (name, stats) in [
        ("seen", &seen),
        ("seen, not measured", &seen_unmeasured),
        ("hidden, not measured", &hidden_unmeasured),
        ("hidden", &hidden),
    ] {
        eprintln!("{name}: {:?}, {} primitives", stats.instances, stats.primitives());
        assert_eq!(stats.instances_visible, 3, "{name}: every tree is in view");
    }
    assert!(seen.instances[Technique::Spt] > 0, "a tree seen whole is drawn with the point tree: {:?}", seen.instances);
    assert_eq!(seen.instances, seen_unmeasured.instances, "trees seen whole measure visible");
    assert_eq!(seen.primitives(), seen_unmeasured.primitives());
    assert_eq!(hidden_unmeasured.instances, seen_unmeasured.instances, "unmeasured, the wall changes no choice");
    assert!(
        hidden.instances[Technique::Impostors] > seen.instances[Technique::Impostors],
        "hidden trees take planes: {:?} against {:?}",
        hidden.instances,
        seen.instances
    );
    assert!(
        2 * hidden.primitives() < seen.primitives(),
        "hidden trees cost less: {} against {} primitives",
        hidden.primitives(),
        seen.primitives()
    );

    // Selected on the GPU (`TreelodSettings::gpu_selection`): the same choices, measured the same
    // way; the GPU's counts are read back a frame or two late, the same for a still camera.
    app.world_mut().resource_mut::<TreelodSettings>().gpu_selection = true;
    let seen_gpu = run(&mut app, true, false);
    let hidden_gpu = run(&mut app, true, true);
    for (name, gpu, cpu) in [("seen", &seen_gpu, &seen), ("hidden", &hidden_gpu, &hidden)] {
        eprintln!("{name}, GPU selection: {:?}, {} primitives", gpu.instances, gpu.primitives());
        assert!(gpu.gpu_selection, "{name}: selected on the GPU");
        assert_eq!(gpu.instances, cpu.instances, "{name}: the CPU's choices");
        let (g, c) = (gpu.primitives() as f64, cpu.primitives() as f64);
        assert!((g - c).abs() <= 0.01 * c, "{name}: {g} primitives on the GPU path, {c} on the CPU's");
    }
}

#[test]
fn trees_cast_into_the_shadow_maps_of_bevy_lights() {
    use bevy_mesh::{MeshBuilder, Meshable};
    use bevy_shape::Plane3d;
    use treelod_bevy::TreelodSettings;

    let (mut app, _assets, handle, (min, max)) = demo_app(TreelodSettings::default());
    let height = max.y - min.y;
    // A low sun from the west: the tree's shadow falls east of it, about 1.4 heights long.
    let sun = Vec3::new(0.7, -0.5, -0.2).normalize();
    let [r, g, b] = scene::GROUND;
    let ground = StandardMaterial {
        base_color: Color::srgb_u8(r, g, b),
        perceptual_roughness: 1.0,
        ..StandardMaterial::default()
    };
    let plane = Plane3d::default().mesh().size(200.0, 200.0).build();
    one_tree_in_the_sun(
        &mut app,
        &handle,
        (plane, ground, Transform::IDENTITY),
        Transform::default().looking_to(sun, Vec3::Y),
    );
    // Above the ground east of the tree, looking down on where its shadow falls.
    let (eye, at) = (Vec3::new(1.2 * height, 1.6 * height, 1.0 * height), Vec3::new(1.2 * height, 0.0, -0.3 * height));
    let view = image_camera(&mut app, &handle, eye, at);
    let (lit, lit_stats) = frame_after(&mut app, &view, |s| s.cast_bevy_shadows = false);
    let (shaded, stats) = frame_after(&mut app, &view, |s| s.cast_bevy_shadows = true);
    if let Some(dir) = std::env::var_os("TREELOD_TEST_IMAGES") {
        lit.write_png(&std::path::Path::new(&dir).join("bevy-shadow-off.png")).expect("writes");
        shaded.write_png(&std::path::Path::new(&dir).join("bevy-shadow-on.png")).expect("writes");
    }
    eprintln!("cast: {:?}", stats.host_shadow);
    assert_eq!(lit_stats.host_shadow.cascades, 0, "not cast: no host maps");
    assert!(stats.host_shadow.cascades >= 1, "Bevy's cascades are taken: {:?}", stats.host_shadow);
    assert!(stats.host_shadow.instances_visible >= 1 && stats.host_shadow.primitives() > 0);
    // The ground the trees' shadow darkens: pixels of the lit frame's ground at least a third
    // darker; the trees' own pixels and the rest of the ground are the same in both frames.
    let (width, height_px) = IMAGE_SIZE;
    let (mut darker, mut lighter, mut ground) = (0u32, 0u32, 0u32);
    for y in 0..height_px {
        for x in 0..width {
            let (a, b) = (lit.pixel(x, y), shaded.pixel(x, y));
            let luma = |p: [u8; 4]| u32::from(p[0]) + u32::from(p[1]) + u32::from(p[2]);
            ground += u32::from(!leaf(a));
            darker += u32::from(!leaf(a) && 3 * luma(b) < 2 * luma(a));
            lighter += u32::from(3 * luma(a) < 2 * luma(b));
        }
    }
    eprintln!("{darker} of {ground} ground pixels darker with the trees' shadow, {lighter} lighter");
    assert!(darker * 20 > ground, "the trees' shadow falls on Bevy's ground: {darker} of {ground} pixels");
    assert_eq!(lighter, 0, "a shadow only darkens");
}

#[test]
fn trees_receive_the_shadows_of_bevy_meshes() {
    use treelod_bevy::TreelodSettings;

    // Only Bevy's board casts: what the trees receive is Bevy's meshes' shadow alone.
    let (mut app, _assets, handle, (min, max)) =
        demo_app(TreelodSettings { cast_bevy_shadows: false, ..TreelodSettings::default() });
    let (height, width) = (max.y - min.y, max.x - min.x);
    // The sun nearly overhead; a board above the tree's west half (x below the trunk).
    let sun = Vec3::new(0.05, -1.0, 0.03).normalize();
    let board_centre = Vec3::new(min.x - 0.5 * width, max.y + 0.5 * height, 0.5 * (min.z + max.z));
    let board = Mesh::from(Cuboid::new(2.0 * width, 0.05 * height, 4.0 * (max.z - min.z)));
    let grey = StandardMaterial::from(Color::srgb(0.4, 0.4, 0.4));
    one_tree_in_the_sun(
        &mut app,
        &handle,
        (board, grey, Transform::from_translation(board_centre)),
        Transform::default().looking_to(sun, Vec3::Z),
    );
    // In front of the tree (south), level with its crown: west is the image's left.
    let at = 0.5 * (min + max);
    let view = image_camera(&mut app, &handle, at + Vec3::new(0.0, 0.1 * height, 1.6 * height), at);
    let (lit, off) = frame_after(&mut app, &view, |s| s.receive_bevy_shadows = false);
    let (shaded, on) = frame_after(&mut app, &view, |s| s.receive_bevy_shadows = true);
    let (off, on) = (off.host_shadows_received, on.host_shadows_received);
    assert_eq!(off, 0, "not received");
    assert_eq!(on, 4, "Bevy's four cascades of the sun are received");
    if let Some(dir) = std::env::var_os("TREELOD_TEST_IMAGES") {
        lit.write_png(&std::path::Path::new(&dir).join("bevy-receive-off.png")).expect("writes");
        shaded.write_png(&std::path::Path::new(&dir).join("bevy-receive-on.png")).expect("writes");
    }
    // The leaves' brightness with Bevy's shadows over that without, in the image's left and
    // right halves (the tree's west and east halves), over pixels that are leaves in both frames.
    let (image_width, image_height) = IMAGE_SIZE;
    let luma = |p: [u8; 4]| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2]);
    let mut sums = [[0.0f64; 2]; 2];
    let mut leaves = [0u32; 2];
    for y in 0..image_height {
        for x in 0..image_width {
            let (a, b) = (lit.pixel(x, y), shaded.pixel(x, y));
            if leaf(a) && leaf(b) {
                let side = usize::from(2 * x >= image_width);
                sums[side][0] += luma(a);
                sums[side][1] += luma(b);
                leaves[side] += 1;
            }
        }
    }
    let [west, east] = sums.map(|[a, b]| b / a.max(1.0));
    eprintln!("leaf pixels {leaves:?}: with Bevy's shadows west {west:.3}, east {east:.3} of the light without");
    assert!(leaves.iter().all(|n| *n > 500), "the tree fills both halves: {leaves:?}");
    assert!(west < 0.8, "the board's shadow darkens the tree's west half: {west:.3}");
    assert!((east - 1.0).abs() < 0.05, "the east half stays lit: {east:.3}");
}

#[test]
fn gpu_selection_over_the_memory_budget_selects_on_the_cpu() {
    use treelod_bevy::TreelodSettings;

    // A budget far below the demo tree's triangles and points: GPU selection, which keeps them
    // whole on the GPU, is refused; the CPU's selection streams what fits.
    let mut settings = TreelodSettings { gpu_selection: true, ..TreelodSettings::default() };
    settings.render.memory_budget = 64 * 1024;
    let (mut app, _assets, handle, _) = demo_app(settings);
    let forest = handle.clone();
    app.add_systems(Startup, move |mut commands: Commands| {
        let trees = [Vec3::new(-6.0, 0.0, -20.0), Vec3::new(6.0, 0.0, -30.0)];
        commands.spawn(treelod_bevy::TreelodForest::new(forest.clone(), trees.map(Transform::from_translation)));
    });
    let target = app.world_mut().resource_mut::<Assets<bevy_image::Image>>().add(scene::target_image());
    scene::finish(&mut app);
    let camera = app
        .world_mut()
        .spawn((scene::camera(), bevy_camera::RenderTarget::Image(target.clone().into())))
        .insert(Transform::from_xyz(0.0, 4.0, 0.0).looking_at(Vec3::new(0.0, 4.0, -25.0), Vec3::Y))
        .id();
    wait_for_load(&mut app, &handle);
    for _ in 0..6 {
        app.update();
    }
    let refused = app.world().resource::<TreelodStats>().get(camera).expect("the camera drew trees");
    eprintln!("over the budget: {refused:?}");
    assert!(!refused.gpu_selection, "GPU selection is refused over the memory budget");
    assert_eq!(refused.instances_visible, 2, "the CPU selects and draws every tree");
    assert!(refused.primitives() > 0);
    assert!(refused.ranges_clamped > 0, "the budget holds coarser draws than selected: {refused:?}");

    // Within the budget, a new camera (whose renderer reads the budget when it is made) selects
    // on the GPU.
    app.world_mut().resource_mut::<TreelodSettings>().render.memory_budget = 1 << 30;
    app.world_mut().despawn(camera);
    let second = app
        .world_mut()
        .spawn((scene::camera(), bevy_camera::RenderTarget::Image(target.into())))
        .insert(Transform::from_xyz(0.0, 4.0, 0.0).looking_at(Vec3::new(0.0, 4.0, -25.0), Vec3::Y))
        .id();
    for _ in 0..6 {
        app.update();
    }
    let taken = app.world().resource::<TreelodStats>().get(second).expect("the new camera drew trees");
    eprintln!("within the budget: {taken:?}");
    assert!(taken.gpu_selection, "GPU selection is taken within the budget");
    assert_eq!(taken.instances_visible, 2);
}
