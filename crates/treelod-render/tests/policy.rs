//! The policy on the Vulkan backend (Mesa lavapipe in CI): trees of a calibrated container drawn
//! with the representation its tables choose at each one's size on screen, per tree in one frame,
//! and forced techniques still forceable.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, calibrated_demo, calibrated_demo_without_octahedral, demo_built, gpu};
use glam::{Mat4, Vec3, vec3};
use treelod_build::{BuildConfig, LodChainConfig};
use treelod_format::Container;
use treelod_render::offscreen::render_image;
use treelod_render::{Camera, DebugView, Instance, Policy, Renderer, Settings, Shadows, Technique};
use treelod_runtime::BudgetController;
use treelod_runtime::{
    Calibration, Choices, ModelLod, Representations, VISIBILITY_LEAD, elevation_class_after, in_view_share,
    projected_height, view_elevation,
};

/// What the runtime reads of a calibrated container: its tables, point tree and representations.
fn read_back(container: &Container) -> (Calibration, ModelLod, Representations) {
    let calibration = Calibration::from_container(container).expect("the build calibrated it");
    let (representations, _) = Representations::from_container(container);
    (calibration, ModelLod::from_container(container), representations)
}

/// A renderer drawing `container` at each of `positions`.
fn forest(
    gpu: &treelod_render::offscreen::Gpu,
    container: &Arc<Container>,
    settings: Settings,
    positions: &[Vec3],
) -> Renderer {
    let mut renderer = Renderer::new(&gpu.device, treelod_render::offscreen::Gpu::formats(), settings);
    let model = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).expect("model");
    let instances: Vec<Instance> =
        positions.iter().map(|&p| Instance { model, transform: Mat4::from_translation(p) }).collect();
    renderer.set_instances(&instances);
    renderer
}

#[test]
fn each_tree_is_drawn_with_what_the_tables_choose_at_its_size() {
    let gpu = gpu();
    let container = calibrated_demo();
    let (calibration, lod, representations) = read_back(&container);
    let policy = Policy::default();
    let choices = Choices::new(&calibration, &policy, &representations);
    // The choices differ somewhere over the calibrated range, or this test shows nothing.
    let first = choices.steps()[0];
    assert!(choices.steps().iter().any(|&t| t != first), "one choice everywhere: {:?}", choices.steps());

    // Trees along the view, from a few pixels to a large part of the screen.
    let (width, height) = (256, 256);
    let eye = vec3(0.0, 0.0, 0.0);
    let centre = lod.centre();
    let distances: Vec<f32> = (0..8).map(|i| 4.0 * 1.9f32.powi(i)).collect();
    // Spread sideways so that no tree hides another (the colours by technique are counted).
    let positions: Vec<Vec3> = distances
        .iter()
        .enumerate()
        .map(|(i, &d)| vec3(d * (0.3 - 0.085 * i as f32), -centre.y, -d) - vec3(centre.x, 0.0, centre.z))
        .collect();
    let camera = Camera::look_at(eye, vec3(0.0, 0.0, -1.0), 0.9, width, height);
    let runtime_camera = treelod_runtime::Camera::look_at(eye, vec3(0.0, 0.0, -1.0), 0.9, width, height);

    // Each tree's choice at its height, by the elevation class of its view, and (above the
    // calibrated range) the share of it in view (spec §10.2).
    let frustum = treelod_runtime::Frustum::from_view_proj(runtime_camera.view_proj);
    let mut expected = treelod_render::PerTechnique::<u32>::default();
    for &p in &positions {
        let transform = Mat4::from_translation(p);
        let h = projected_height(&lod, transform, &runtime_camera);
        let class = elevation_class_after(None, view_elevation(&lod, transform, eye), choices.elevations());
        let in_view = if choices.above_range(h) { in_view_share(&lod, transform, &frustum) } else { 1.0 };
        *expected.get_mut(choices.choose_framed(h, class, 1.0, in_view, None)) += 1;
    }
    assert!(expected.iter().filter(|&(_, n)| n > 0).count() >= 2, "the row spans two choices: {expected:?}");
    // The far trees are drawn with their octahedral impostor, one quad each (its rows are in the
    // sections of format 1.12, spec §6.18, which the runtime reads with the others).
    assert!(expected[Technique::Octahedral] > 0, "{expected:?}");

    let mut renderer = forest(&gpu, &container, Settings::default(), &positions);
    let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    assert_eq!(stats.instances_visible, 8, "{stats:?}");
    assert_eq!(stats.instances, expected, "each tree by the policy's choice at its height");
    assert!(common::covered(&image).iter().any(|&c| c), "something is drawn");
    // Every primitive is counted under the technique its tree is drawn with, and each chosen
    // technique submitted some.
    assert_eq!(stats.by_technique.total(), stats.primitives(), "{stats:?}");
    for (technique, n) in stats.by_technique.iter() {
        assert_eq!(n > 0, expected[technique] > 0, "{technique}: {n} primitives, {} trees", expected[technique]);
    }

    // Coloured by technique: each chosen technique's colour is on screen.
    let debug = Settings { debug: DebugView::Techniques, ..Settings::default() };
    let mut coloured = forest(&gpu, &container, debug, &positions);
    let (image, stats) = render_image(&gpu, &mut coloured, &camera, BACKGROUND).expect("renders");
    assert_eq!(stats.instances, expected);
    let encode = |c: f32| {
        let s = if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
        (s * 255.0).round() as i32
    };
    for (technique, n) in expected.iter() {
        let colour = DebugView::technique_colour(technique).map(encode);
        let pixels =
            image.rgba.chunks_exact(4).filter(|p| (0..3).all(|k| (i32::from(p[k]) - colour[k]).abs() <= 6)).count();
        assert_eq!(pixels > 0, n > 0, "{technique}: {n} trees, {pixels} pixels of {colour:?}");
    }

    // The same trees forced to one technique: every tree with it.
    let mut forced = forest(&gpu, &container, Settings::forced(Technique::Crossed), &positions);
    let (_, stats) = render_image(&gpu, &mut forced, &camera, BACKGROUND).expect("renders");
    assert_eq!(stats.instances.get(Technique::Crossed), 8, "{stats:?}");
}

#[test]
fn without_tables_the_policy_draws_the_settings_technique() {
    let gpu = gpu();
    let container = demo_built(&BuildConfig { baselines: Some(LodChainConfig::default()), ..BuildConfig::default() });
    assert!(Calibration::from_container(&container).is_none());
    let positions = [vec3(0.0, -5.0, -30.0)];
    let camera = Camera::look_at(Vec3::ZERO, vec3(0.0, 0.0, -1.0), 0.9, 128, 128);
    for technique in [Technique::Spt, Technique::LodChain] {
        let settings = Settings { technique, ..Settings::default() };
        assert!(settings.policy.is_some(), "the policy is the default");
        let mut renderer = forest(&gpu, &container, settings, &positions);
        let (_, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        assert_eq!(stats.instances.get(technique), stats.instances_visible, "{stats:?}");
    }
}

#[test]
fn a_shadow_cascade_chooses_at_the_coarser_of_the_light_s_and_the_camera_s_view() {
    let gpu = gpu();
    let container = calibrated_demo();
    let (calibration, lod, representations) = read_back(&container);
    let choices = Choices::new(&calibration, &Policy::default(), &representations);
    let (width, height) = (256, 256);
    let (eye, ahead) = (vec3(0.0, 0.0, 0.0), vec3(0.0, 0.0, -1.0));
    let runtime_camera = treelod_runtime::Camera::look_at(eye, ahead, 0.9, width, height);
    // One tree 200 px high on screen; one cascade whose selection pixel is so coarse that the tree
    // is a few of its pixels high.
    let distance = treelod_runtime::policy::distance_for_height(&lod, 200.0, &runtime_camera);
    let position = vec3(0.0, 0.0, -distance) - lod.centre();
    let transform = Mat4::from_translation(position);
    // The choice for a tree `height` px high seen from `eye` (by its elevation class, spec §10.2).
    let choice = |eye: Vec3, height: f32| {
        let class = elevation_class_after(None, view_elevation(&lod, transform, eye), choices.elevations());
        choices.choose_viewed(height, class, 1.0, None)
    };
    let drawn = choice(eye, projected_height(&lod, transform, &runtime_camera));
    let camera = Camera::look_at(eye, ahead, 0.9, width, height);
    // A coarse cascade (the tree a few of its selection pixels high) and a fine one (more pixels
    // than on screen): from the light's view alone, and at the coarser of both views.
    let mut differ = false;
    for (resolution, lod_texels) in [(256, 64.0), (4096, 0.1)] {
        for casters in [treelod_render::Casters::LightView, treelod_render::Casters::Coarser] {
            let shadows = Shadows { cascades: 1, resolution, lod_texels, casters, ..Shadows::default() };
            let settings = Settings { shadows: Some(shadows), ..Settings::default() };
            let mut renderer = forest(&gpu, &container, settings, &[position]);
            let (_, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
            let light = renderer.shadow_cascades()[0].selection_camera();
            let in_shadow = projected_height(&lod, transform, &light);
            let on_screen = projected_height(&lod, transform, &runtime_camera);
            let coarser = casters == treelod_render::Casters::Coarser && on_screen < in_shadow;
            let (at, seen_from) = if coarser { (on_screen, eye) } else { (in_shadow, light.position) };
            let cast = choice(seen_from, at);
            differ |= cast != drawn;
            assert_eq!(stats.instances[drawn], 1, "{stats:?}");
            assert_eq!(stats.shadow.instances[cast], 1, "{casters:?} at {at} px: {:?}", stats.shadow);
            assert_eq!(stats.shadow.instances.total(), stats.shadow.instances_visible);
            if lod_texels > 1.0 {
                assert!(in_shadow < on_screen, "the coarse cascade: {in_shadow} px against {on_screen}");
            } else {
                assert!(in_shadow > on_screen, "the fine cascade: {in_shadow} px against {on_screen}");
            }
        }
    }
    assert!(differ, "the test needs a cascade that casts another choice than is drawn");
    let shadows = Shadows { cascades: 1, resolution: 256, lod_texels: 64.0, ..Shadows::default() };
    // Forced settings force the cascades too.
    let forced = Settings { shadows: Some(shadows), ..Settings::forced(Technique::Impostors) };
    let mut renderer = forest(&gpu, &container, forced, &[position]);
    let (_, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    assert_eq!(stats.shadow.instances[Technique::Impostors], 1, "{:?}", stats.shadow);
    // Casters forced for the shadow pass alone.
    let casters = Shadows { casters: treelod_render::Casters::Forced(Technique::Crossed), ..shadows };
    let mut renderer =
        forest(&gpu, &container, Settings { shadows: Some(casters), ..Settings::default() }, &[position]);
    let (_, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    assert_eq!((stats.instances[drawn], stats.shadow.instances[Technique::Crossed]), (1, 1), "{stats:?}");
    // Or the camera's choice: the tree casts what it is drawn with.
    let casters = Shadows { casters: treelod_render::Casters::CameraView, ..shadows };
    let mut renderer =
        forest(&gpu, &container, Settings { shadows: Some(casters), ..Settings::default() }, &[position]);
    let (_, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    assert_eq!((stats.instances[drawn], stats.shadow.instances[drawn]), (1, 1), "{stats:?}");
}

#[test]
fn hysteresis_holds_a_tree_at_a_boundary_until_it_moves_past_it() {
    let container = calibrated_demo();
    let calibration = Calibration::from_container(&container).expect("calibrated");
    let (representations, _) = Representations::from_container(&container);
    let choices = Choices::new(&calibration, &Policy::default(), &representations);
    let steps = choices.steps();
    let Some(boundary) = steps.windows(2).position(|w| w[0] != w[1]) else {
        panic!("no boundary in {steps:?}");
    };
    let (below, above) = (steps[boundary], steps[boundary + 1]);
    let (min, _) = calibration.heights();
    let step_height = |i: f32| min * (i / treelod_runtime::policy::STEPS_PER_OCTAVE).exp2();
    // Just above the boundary, a tree that was drawn with the smaller side's technique keeps it.
    let h = step_height(boundary as f32 + 1.0);
    assert_eq!(choices.choose(h, None), above);
    assert_eq!(choices.choose(h, Some(below)), below, "held by hysteresis");
    // Past the hysteresis (0.25 octaves: 2 steps), where `below` is not the choice within 2
    // steps, it switches.
    let far = (boundary + 1..steps.len()).find(|&j| {
        steps[j.saturating_sub(2)..(j + 3).min(steps.len())].iter().all(|&t| t != below) && j + 2 < steps.len()
    });
    if let Some(j) = far {
        assert_eq!(choices.choose(step_height(j as f32), Some(below)), steps[j], "switched at step {j}");
    }
}

/// A field of 36 trees of `lod` from near to far in front of the camera, and the camera.
fn field_of_trees(lod: &ModelLod) -> (Vec<Vec3>, Camera) {
    let centre = lod.centre();
    let positions = (0..6)
        .flat_map(|row| (0..6).map(move |col| (row, col)))
        .map(|(row, col)| {
            vec3((col as f32 - 2.5) * 6.0, -centre.y, -8.0 - 9.0 * row as f32 * (1.0 + 0.3 * row as f32))
                - vec3(centre.x, 0.0, centre.z)
        })
        .collect();
    (positions, Camera::look_at(Vec3::ZERO, vec3(0.0, -0.1, -1.0), 0.9, 320, 240))
}

/// The field of demo trees the budget tests draw ([`field_of_trees`] of the demo tree without the
/// octahedral impostor), its camera, and the primitives its frame draws without a budget.
fn budget_field(gpu: &treelod_render::offscreen::Gpu) -> (Arc<Container>, Vec<Vec3>, Camera, u64) {
    let container = calibrated_demo_without_octahedral();
    let (positions, camera) = field_of_trees(&ModelLod::from_container(&container));
    let mut free = forest(gpu, &container, Settings::default(), &positions);
    let unbudgeted = free.prepare(&gpu.device, &gpu.queue, &camera).primitives();
    assert!(free.budget_steering().is_none(), "no budget, no steering");
    (container, positions, camera, unbudgeted)
}

/// [`budget_field`] drawn in budget mode at a quarter of what it draws without a budget.
struct QuarterBudget {
    /// The renderer, no frame drawn yet.
    renderer: Renderer,
    container: Arc<Container>,
    positions: Vec<Vec3>,
    camera: Camera,
    /// What the field draws without a budget.
    unbudgeted: u64,
    budget: u64,
    policy: Policy,
}

fn quarter_budget_field(gpu: &treelod_render::offscreen::Gpu) -> QuarterBudget {
    let (container, positions, camera, unbudgeted) = budget_field(gpu);
    let budget = unbudgeted / 4;
    let policy = Policy { budget: Some(budget), ..Policy::default() };
    let renderer = forest(gpu, &container, Settings { policy: Some(policy), ..Settings::default() }, &positions);
    QuarterBudget { renderer, container, positions, camera, unbudgeted, budget, policy }
}

#[test]
fn budget_mode_steers_the_frame_to_the_primitive_count() {
    let gpu = gpu();
    let (container, positions, camera, unbudgeted) = budget_field(&gpu);
    assert!(unbudgeted > 1000, "{unbudgeted}");

    for budget in [unbudgeted / 4, unbudgeted * 2] {
        let policy = Policy { budget: Some(budget), ..Policy::default() };
        let settings = Settings { policy: Some(policy), ..Settings::default() };
        let mut renderer = forest(&gpu, &container, settings, &positions);
        assert!(renderer.budget_frame().is_none(), "no frame yet");
        let counts: Vec<u64> = (0..80)
            .map(|i| {
                let next = renderer.budget_steering();
                let count = renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives();
                let drawn = renderer.budget_frame().expect("a budget frame");
                if i > 0 {
                    // The camera holds still: the frame is drawn with the steering its last one
                    // left (only the first frame, or one whose camera moved, is predicted first).
                    assert_eq!(next, Some((drawn.s_min, drawn.target)), "frame {i}");
                }
                if budget < unbudgeted {
                    assert!(!drawn.finest, "fewer primitives wanted than the default draws: frame {i}");
                }
                count
            })
            .collect();
        assert_eq!(renderer.settings().policy, Some(policy), "the settings are not changed");
        let (s_min, target) = renderer.budget_steering().expect("steering");
        let last: Vec<f64> = counts[60..].iter().map(|&c| c as f64 / budget as f64).collect();
        if budget < unbudgeted {
            // Fewer primitives wanted: both knobs up, and the count settles under the budget
            // (by at most the step its trees make switching together, here less than half).
            assert!(s_min > Settings::default().s_min && target > Policy::DEFAULT_TARGET, "{s_min} {target}");
            assert!(last.iter().all(|&r| (0.5..=1.05).contains(&r)), "budget {budget}: {counts:?}");
            assert!(counts[60..].windows(2).all(|w| w[0] == w[1]), "settled: {counts:?}");
        } else {
            // More allowed: both knobs down, and more drawn than without a budget.
            assert!(s_min < Settings::default().s_min && target < Policy::DEFAULT_TARGET, "{s_min} {target}");
            assert!(counts[79] > unbudgeted, "budget {budget}: {counts:?}");
            assert!(last.iter().all(|&r| r <= 1.1), "budget {budget}: {counts:?}");
        }
    }
}

/// A budget the forest cannot spend: the steering goes down to its finest (`s_min` and the
/// target at their floors), where the frame draws everything the policy would refine and stays
/// far under the budget, and `Renderer::budget_frame` says so, as `bench` counts such frames.
#[test]
fn a_budget_the_forest_cannot_spend_steers_to_the_finest_and_says_so() {
    let gpu = gpu();
    let (container, positions, camera, unbudgeted) = budget_field(&gpu);
    let budget = 1000 * unbudgeted;
    let policy = Policy { budget: Some(budget), ..Policy::default() };
    let mut renderer = forest(&gpu, &container, Settings { policy: Some(policy), ..Settings::default() }, &positions);
    let counts: Vec<u64> = (0..20).map(|_| renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives()).collect();
    let drawn = renderer.budget_frame().expect("a budget frame");
    let floors = BudgetController::new(budget, 1.0);
    assert!(drawn.finest, "{drawn:?}: {counts:?}");
    assert_eq!((drawn.s_min, drawn.target), (floors.s_min_floor, floors.target_floor));
    assert!(counts[19] > unbudgeted && 2 * counts[19] < budget, "{counts:?} against {budget}");
    // Without a budget, no budget frame.
    renderer.settings_mut().policy = Some(Policy::default());
    renderer.prepare(&gpu.device, &gpu.queue, &camera);
    assert!(renderer.budget_frame().is_none());
}

/// Budget mode predicts its first frame before drawing it (spec §10.2): a forest the default
/// target draws at four times the budget starts near the budget, not at four times it, and the
/// steering goes on from there: from the twentieth frame on, none over 1.25 times the budget and
/// at most 2 of 20 over 1.05 times it. (Not every frame: a step down predicted within 1.1 times
/// the budget is drawn, and the steering then steps back by a few percent a frame so near the
/// budget. In one CI run the count went from 41,700 to 48,500 at the ninth frame and was at
/// 50,200 at the twentieth, a raise's trees fading, then 46,500 and under; this machine's runs
/// draw 40,800 throughout.)
#[test]
fn budget_mode_predicts_its_first_frame_and_starts_within_the_budget() {
    let gpu = gpu();
    let QuarterBudget { mut renderer, camera, unbudgeted, budget, .. } = quarter_budget_field(&gpu);
    let first = renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives();
    assert!(first <= 2 * budget, "first frame {first} against a budget of {budget} ({unbudgeted} unbudgeted)");
    let counts: Vec<u64> = (0..40).map(|_| renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives()).collect();
    assert!(counts[20..].iter().all(|&c| 4 * c <= 5 * budget), "budget {budget}: {first}, {counts:?}");
    let over = counts[20..].iter().filter(|&&c| 20 * c > 21 * budget).count();
    assert!(over <= 2, "{over} frames over 1.05 times the budget {budget}: {first}, {counts:?}");
}

/// Budget mode started at the coarsest target, far under its budget, moves on down by
/// prediction (spec §10.2, `BudgetController::lower_within`): its second frame is within the
/// budget's band, where stepping down a largest step a frame took many frames to get there.
#[test]
fn budget_mode_lowers_a_frame_far_under_the_budget_by_prediction() {
    let gpu = gpu();
    let (container, positions, camera, budget) = budget_field(&gpu);
    let policy = Policy { target: 1.0, budget: Some(budget), ..Policy::default() };
    let mut renderer = forest(&gpu, &container, Settings { policy: Some(policy), ..Settings::default() }, &positions);
    let counts: Vec<u64> = (0..4).map(|_| renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives()).collect();
    assert!(2 * counts[0] < budget, "the coarsest target is far under the budget {budget}: {counts:?}");
    assert!(
        counts[1..].iter().all(|&c| 2 * c >= budget && 10 * c <= 11 * budget),
        "on down within the budget {budget} at once: {counts:?}"
    );
}

/// Budget mode looks before it steps the target down (spec §10.2): trees all at one size on
/// screen switch technique at one target, and where the steering would step down to a target at
/// which they switch to a representation of many more primitives, the step is refused undrawn.
#[test]
fn budget_mode_refuses_a_step_down_that_would_switch_every_tree_at_once() {
    let gpu = gpu();
    let container = calibrated_demo();
    let (calibration, lod, representations) = read_back(&container);
    let (width, height) = (320, 240);
    let runtime_camera = treelod_runtime::Camera::look_at(Vec3::ZERO, vec3(0.0, 0.0, -1.0), 0.9, width, height);
    // The tables' primitives of a tree `h` pixels high under `target`, drawn with what the
    // default target chooses before (hysteresis).
    let choose = |target: f32, h: f32, previous: Option<Technique>| {
        Choices::new(&calibration, &Policy { target, ..Policy::default() }, &representations).choose(h, previous)
    };
    let cost = |target: f32, h: f32| {
        let technique = choose(target, h, Some(choose(Policy::DEFAULT_TARGET, h, None)));
        calibration.at(technique, h).map_or(0.0, |(_, primitives)| primitives)
    };
    // A height where the default target draws a tree with a few primitives and the least target
    // the steering reaches with many: the cliff.
    let (min, _) = calibration.heights();
    let floor = BudgetController::new(1, 1.0).target_floor;
    let h = (0..24)
        .map(|i| min * (i as f32 / 8.0).exp2())
        .filter(|&h| h <= 48.0)
        .max_by(|&a, &b| {
            let rise = |h: f32| cost(floor, h) / cost(Policy::DEFAULT_TARGET, h).max(1.0);
            rise(a).total_cmp(&rise(b))
        })
        .expect("heights");
    let rise = cost(floor, h) / cost(Policy::DEFAULT_TARGET, h).max(1.0);
    assert!(rise > 40.0, "no cliff in the demo's tables: ×{rise} at {h} px");
    // Twelve trees along an arc at the distance that gives them that height.
    let d = treelod_runtime::policy::distance_for_height(&lod, h, &runtime_camera);
    let positions: Vec<Vec3> = (0..12)
        .map(|i| {
            let angle = (i as f32 / 11.0 - 0.5) * 0.9;
            vec3(angle.sin() * d, 0.0, -angle.cos() * d) - lod.centre()
        })
        .collect();
    let camera = Camera::look_at(Vec3::ZERO, vec3(0.0, 0.0, -1.0), 0.9, width, height);
    let mut free = forest(&gpu, &container, Settings::default(), &positions);
    let unbudgeted = free.prepare(&gpu.device, &gpu.queue, &camera).primitives();
    // A budget the default target leaves mostly unspent, and the cliff more than twice over.
    let budget = 4 * unbudgeted.max(12);
    let policy = Policy { budget: Some(budget), transition: 0, ..Policy::default() };
    let mut renderer = forest(&gpu, &container, Settings { policy: Some(policy), ..Settings::default() }, &positions);
    let counts: Vec<u64> = (0..40).map(|_| renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives()).collect();
    assert!(counts.iter().all(|&c| c <= 2 * budget), "budget {budget}: {counts:?}");
    let (_, target) = renderer.budget_steering().expect("steering");
    assert!(target < Policy::DEFAULT_TARGET, "stepped down towards the cliff: {target}");
    assert!(cost(target, h) * 12.0 <= 2.0 * budget as f32, "held above it: {target}, {counts:?}");
}

/// A tree that crosses a boundary of the tables is drawn with both techniques for the
/// transition's frames, on complementary pixels: every pixel of a frame in the transition is the
/// old technique's or the new one's (each drawn alone), the new one's share of the pixels where
/// they differ grows by a step per frame, and then the new one alone draws.
#[test]
fn a_tree_changing_technique_fades_over_the_transition_s_frames() {
    let gpu = gpu();
    let container = calibrated_demo_without_octahedral();
    let (calibration, lod, representations) = read_back(&container);
    let frames = 4;
    let policy = Policy { hysteresis: 0.0, transition: frames, ..Policy::default() };
    let choices = Choices::new(&calibration, &policy, &representations);
    let steps = choices.steps();
    let (min, _) = calibration.heights();
    let step_height = |i: usize| min * (i as f32 / treelod_runtime::policy::STEPS_PER_OCTAVE).exp2();
    // The largest boundary whose tree is a good size on a 128-pixel-high screen.
    let (width, height) = (128, 128);
    let boundary = (0..steps.len() - 1)
        .rev()
        .find(|&i| steps[i] != steps[i + 1] && step_height(i + 1) <= 100.0)
        .unwrap_or_else(|| panic!("no boundary under 100 px in {steps:?}"));
    let (old, new) = (steps[boundary], steps[boundary + 1]);
    let camera = Camera::look_at(Vec3::ZERO, vec3(0.0, 0.0, -1.0), 0.9, width, height);
    let runtime_camera = treelod_runtime::Camera::look_at(Vec3::ZERO, vec3(0.0, 0.0, -1.0), 0.9, width, height);
    let at = |h: f32| {
        let d = treelod_runtime::policy::distance_for_height(&lod, h, &runtime_camera);
        vec3(0.0, 0.0, -d) - lod.centre()
    };
    let (before, after) = (at(step_height(boundary)), at(step_height(boundary + 1)));
    let chosen = |p: Vec3| choices.choose(projected_height(&lod, Mat4::from_translation(p), &runtime_camera), None);
    assert_eq!((chosen(before), chosen(after)), (old, new), "the tree's choices either side");

    // Each technique alone at the new place.
    let alone = |technique: Technique| {
        let mut renderer = forest(&gpu, &container, Settings::forced(technique), &[after]);
        render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders").0
    };
    let (old_image, new_image) = (alone(old), alone(new));
    let differ: Vec<usize> = (0..old_image.rgba.len() / 4)
        .filter(|&p| old_image.rgba[4 * p..4 * p + 4] != new_image.rgba[4 * p..4 * p + 4])
        .collect();
    assert!(differ.len() > 200, "the two techniques differ on {} pixels only", differ.len());

    let settings = Settings { policy: Some(policy), ..Settings::default() };
    let mut renderer = Renderer::new(&gpu.device, treelod_render::offscreen::Gpu::formats(), settings);
    let model = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("model");
    renderer.set_instances(&[Instance { model, transform: Mat4::from_translation(before) }]);
    let (_, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
    assert_eq!((stats.instances[old], stats.transitions), (1, 0), "{stats:?}");
    renderer.set_instances(&[Instance { model, transform: Mat4::from_translation(after) }]);
    for frame in 1..=frames {
        let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        assert_eq!(stats.instances[new], 1, "frame {frame}: counted under the new technique: {stats:?}");
        let draws = renderer.draws();
        if frame == frames {
            assert_eq!(stats.transitions, 0, "the transition is over: {stats:?}");
            assert!(draws.iter().all(|d| d.technique == new && d.dither == [0.0, 1.0]), "{draws:?}");
            assert_eq!(image.rgba, new_image.rgba, "the new technique alone");
            continue;
        }
        let shown = frame as f32 / frames as f32;
        assert_eq!(stats.transitions, 1, "frame {frame}: {stats:?}");
        assert!(stats.by_technique[old] > 0 && stats.by_technique[new] > 0, "frame {frame}: {stats:?}");
        for d in draws {
            let expected = if d.technique == new { [0.0, shown] } else { [shown, 1.0] };
            assert!(d.technique == new || d.technique == old, "frame {frame}: {d:?}");
            assert_eq!(d.dither, expected, "frame {frame}: {d:?}");
        }
        // Every pixel is one technique's; the new one's share where they differ is `shown`.
        let pixel = |image: &treelod_render::offscreen::Image, p: usize| image.rgba[4 * p..4 * p + 4].to_vec();
        let mut taken_new = 0;
        for &p in &differ {
            let here = pixel(&image, p);
            assert!(here == pixel(&old_image, p) || here == pixel(&new_image, p), "frame {frame}, pixel {p}");
            taken_new += usize::from(here == pixel(&new_image, p));
        }
        let share = taken_new as f32 / differ.len() as f32;
        assert!((share - shown).abs() < 0.1, "frame {frame}: the new technique on {share} of the pixels, not {shown}");
        let same = (0..image.rgba.len() / 4).filter(|p| !differ.contains(p));
        assert!(same.into_iter().all(|p| pixel(&image, p) == pixel(&old_image, p)), "frame {frame}");
    }
}

/// Trees hidden behind a near one are measured (`Renderer::measure_occlusion` after each pass)
/// and chosen at their visible fraction: each drawn with the choice of its visibility class,
/// some of them with a cheaper technique than a visible tree of their size gets; without
/// `Policy::occlusion` nothing is measured.
#[test]
fn trees_hidden_behind_another_are_chosen_at_their_visible_fraction() {
    let gpu = gpu();
    let container = calibrated_demo_without_octahedral();
    let (calibration, lod, representations) = read_back(&container);
    let policy = Policy { hysteresis: 0.0, transition: 0, ..Policy::default() };
    assert!(policy.occlusion, "on by default");
    let choices = Choices::new(&calibration, &policy, &representations);
    let centre = lod.centre();
    // One tree 12 m in front of the camera, a row straight behind it.
    let eye = vec3(0.0, centre.y, 12.0);
    let distances = [0.0, 20.0, 30.0, 45.0, 65.0, 95.0, 140.0];
    let positions: Vec<Vec3> = distances.iter().map(|&d| vec3(-centre.x, 0.0, -d - centre.z)).collect();
    let (width, height) = (256, 256);
    let camera = Camera::look_at(eye, eye - Vec3::Z, 0.9, width, height);
    let runtime_camera = treelod_runtime::Camera::look_at(eye, eye - Vec3::Z, 0.9, width, height);

    let drawn_with = |renderer: &Renderer, i: u32| {
        let techniques: Vec<Technique> =
            renderer.draws().iter().filter(|d| d.instance == i).map(|d| d.technique).collect();
        assert!(techniques.windows(2).all(|w| w[0] == w[1]), "tree {i}: {techniques:?}");
        techniques.first().copied()
    };
    for occlusion in [true, false] {
        let settings = Settings { policy: Some(Policy { occlusion, ..policy }), ..Settings::default() };
        let mut renderer = forest(&gpu, &container, settings, &positions);
        // The first frame measures; a later one reads the measurement (mapped without waiting).
        for _ in 0..3 {
            render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        }
        // Frame after frame (the renderer lends its fractions to the choice and takes them back).
        for frame in 3..6 {
            render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
            let fractions = renderer.visible_fractions().to_vec();
            assert_eq!(fractions.len(), positions.len(), "frame {frame}");
            if !occlusion {
                assert!(fractions.iter().all(|&f| f == 1.0), "nothing measured: {fractions:?}");
                continue;
            }
            assert!(fractions[0] > 0.9, "frame {frame}: the front tree is visible: {fractions:?}");
            assert!(
                fractions[1..].iter().all(|&f| f < 0.7),
                "frame {frame}: the row behind it is hidden: {fractions:?}"
            );
            let mut cheaper = 0;
            for (i, &p) in positions.iter().enumerate() {
                let h = projected_height(&lod, Mat4::from_translation(p), &runtime_camera);
                // The class the tree moved to from fully visible (a quarter class of hysteresis).
                let class = treelod_runtime::policy::visibility_class_after(0, fractions[i]);
                let seen = choices.choose_seen(h, (-(class as f32)).exp2(), None);
                let i = i as u32;
                let f = fractions[i as usize];
                assert_eq!(drawn_with(&renderer, i), Some(seen), "frame {frame}: tree {i}, {h} px, {f} visible");
                let primitives = |t: Technique| calibration.at(t, h).map_or(0.0, |(_, p)| p);
                cheaper += usize::from(primitives(seen) < primitives(choices.choose(h, None)));
            }
            assert!(cheaper > 0, "some hidden tree is drawn cheaper than a visible one of its size");
        }
    }
}

/// A row of trees hidden behind a near one reaching out past the policy's uniform height
/// (`Choices::uniform_below_in` of the side views): the trees whose choice can follow their visible
/// fraction are measured hidden, while those under half that height (`VISIBILITY_LEAD`), drawn
/// alike whatever their fraction, are not measured and keep a fraction of 1; each is drawn with the
/// technique its measured fraction chooses.
#[test]
fn far_trees_drawn_alike_whatever_their_visibility_are_not_measured() {
    let gpu = gpu();
    let container = calibrated_demo();
    let (calibration, lod, representations) = read_back(&container);
    let policy = Policy { hysteresis: 0.0, transition: 0, ..Policy::default() };
    let choices = Choices::new(&calibration, &policy, &representations);
    // The trees are seen from the side (elevation class 0), whose smallest trees take one
    // technique.
    let (below, uniform) = choices.uniform_below_in(0).expect("one technique for the smallest trees");
    let centre = lod.centre();
    // The near tree fills most of the view.
    let eye = vec3(0.0, centre.y, 5.0);
    let (width, height) = (256, 256);
    let camera = Camera::look_at(eye, eye - Vec3::Z, 0.9, width, height);
    let runtime_camera = treelod_runtime::Camera::look_at(eye, eye - Vec3::Z, 0.9, width, height);
    // The near tree, then trees of 1.5, 0.8, 0.6, 0.4 and 0.2 times the uniform height.
    let shares = [1.5, 0.8, 0.6, 0.4, 0.2];
    let (lo, hi) = lod.bounds();
    let world_height = hi.y - lo.y;
    let mut positions = vec![vec3(-centre.x, 0.0, -centre.z)];
    positions.extend(shares.iter().map(|&share| {
        let distance = world_height / (share * below * runtime_camera.world_per_pixel());
        vec3(-centre.x, 0.0, eye.z - distance - centre.z)
    }));
    let unmeasured = positions
        .iter()
        .filter(|&&p| projected_height(&lod, Mat4::from_translation(p), &runtime_camera) < VISIBILITY_LEAD * below);
    assert_eq!(unmeasured.count(), 2, "the trees of 0.4 and 0.2 times the height");
    let settings = Settings { policy: Some(policy), ..Settings::default() };
    // On the CPU's selection and on the GPU's (which lists the trees it draws for the
    // measurement apart, `Renderer::draws` holding only the CPU's).
    for gpu_selection in [false, true] {
        let mut renderer = forest(&gpu, &container, settings, &positions);
        if gpu_selection {
            renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
        }
        for _ in 0..4 {
            render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
        }
        for frame in 4..6 {
            render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
            let fractions = renderer.visible_fractions().to_vec();
            for (i, (&p, &f)) in positions.iter().zip(&fractions).enumerate().skip(1) {
                let transform = Mat4::from_translation(p);
                let h = projected_height(&lod, transform, &runtime_camera);
                let visible = (-(treelod_runtime::policy::visibility_class_after(0, f) as f32)).exp2();
                let elevation = elevation_class_after(None, view_elevation(&lod, transform, eye), choices.elevations());
                let seen = choices.choose_framed(h, elevation, visible, 1.0, None);
                let drawn: Vec<Technique> =
                    renderer.draws().iter().filter(|d| d.instance == i as u32).map(|d| d.technique).collect();
                assert!(drawn.iter().all(|&t| t == seen), "frame {frame}, tree {i} at {h} px ({f}): {drawn:?}");
                let case = format!("GPU selection {gpu_selection}, frame {frame}, tree {i} at {h} px of {below}");
                if h < VISIBILITY_LEAD * below {
                    assert_eq!((f, seen), (1.0, uniform), "{case}");
                } else {
                    assert!(f < 0.7, "{case}: hidden, measured {f}");
                }
            }
        }
    }
}

/// A frame's draws are recorded in pieces, in parallel: a forest whose trees the policy draws
/// with several techniques, some of them in a transition, gives the same draws in the same
/// order, the same counts and the same image whether each entry of the views' lists is a piece
/// of its own, the lists are cut as by default, or all is one piece on the calling thread.
/// Also: `prepare` runs on rayon's pool, on the caller's thread when that is one of a pool's, so
/// frames prepared from inside pools of one and of three threads are the frames prepared from
/// outside (the global pool).
#[test]
fn a_frame_recorded_in_pieces_or_on_any_pool_is_the_frame_recorded_in_one_pass() {
    let gpu = gpu();
    let container = calibrated_demo_without_octahedral();
    let policy = Policy { hysteresis: 0.0, transition: 3, ..Policy::default() };
    let settings = Settings { policy: Some(policy), ..Settings::default() };
    let (width, height) = (480, 360);
    // Looking 50° down on the trees: the 50° tables choose the point tree, impostor planes and
    // the chain over the rows' heights (from the side, with short runs merged, spec §10.2, the
    // point tree and the chain alone).
    let down = vec3(0.0, -(50f32.to_radians().sin()), -(50f32.to_radians().cos()));
    let camera = Camera::look_at(Vec3::ZERO, down, 0.9, width, height);
    let runtime_camera = treelod_runtime::Camera::look_at(Vec3::ZERO, down, 0.9, width, height);
    let lod = ModelLod::from_container(&container);
    // Rows of 8 trees from 320 pixels high down to 10, then the same rows half as far again
    // (nearer): trees cross the policy's boundaries and fade from one technique to another.
    let rows = |scale: f32| -> Vec<Vec3> {
        (0..6)
            .flat_map(|row| {
                let h = scale * 320.0 / (1u32 << row) as f32;
                let d = treelod_runtime::policy::distance_for_height(&lod, h, &runtime_camera);
                (0..8).map(move |i| down * d + vec3((i as f32 - 3.5) * 0.15 * d, 0.0, 0.0))
            })
            .map(|p| p - lod.centre())
            .collect()
    };
    let frames = [rows(1.0), rows(1.5), rows(1.5), rows(1.5)];
    let run = |chunk: usize| {
        let mut renderer = Renderer::new(&gpu.device, treelod_render::offscreen::Gpu::formats(), settings);
        let model = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&container)).expect("model");
        renderer.set_record_chunk(chunk);
        frames
            .iter()
            .map(|positions| {
                let instances: Vec<Instance> =
                    positions.iter().map(|&p| Instance { model, transform: Mat4::from_translation(p) }).collect();
                renderer.set_instances(&instances);
                let (image, stats) = render_image(&gpu, &mut renderer, &camera, BACKGROUND).expect("renders");
                (image.rgba, stats, renderer.draws().to_vec())
            })
            .collect::<Vec<_>>()
    };
    let each = run(1);
    let techniques =
        |stats: &treelod_render::FrameStats| Technique::ALL.iter().filter(|&&t| stats.instances[t] > 0).count();
    // (Measured: the point tree, the impostor planes and the chain in every frame.)
    assert!(
        each.iter().all(|(_, stats, _)| techniques(stats) >= 2)
            && each.iter().any(|(_, stats, _)| techniques(stats) >= 3),
        "{:?}",
        each.iter().map(|f| f.1).collect::<Vec<_>>()
    );
    assert!(each.iter().any(|(_, stats, _)| stats.transitions > 0 && stats.leaving > 0), "no transition");
    assert!(
        each.iter().all(|(_, stats, _)| stats.ranges > 50),
        "{:?}",
        each.iter().map(|f| f.1.ranges).collect::<Vec<_>>()
    );
    let paired = |draws: &[treelod_render::RecordedDraw]| {
        draws.windows(2).any(|w| {
            w[0].source == treelod_render::DrawSource::Triangles
                && w[1].source == treelod_render::DrawSource::Points
                && (w[0].instance, w[0].cell) == (w[1].instance, w[1].cell)
        })
    };
    assert!(each.iter().any(|(_, _, draws)| paired(draws)), "no cell drew both triangles and points");
    for chunk in [usize::MAX, 512, 7] {
        let other = run(chunk);
        for (frame, (a, b)) in each.iter().zip(&other).enumerate() {
            assert_eq!(a.2, b.2, "chunk {chunk}, frame {frame}: the draws");
            assert_eq!(a.1, b.1, "chunk {chunk}, frame {frame}: the counts");
            assert!(a.0 == b.0, "chunk {chunk}, frame {frame}: the image");
        }
    }
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool");
        let other = pool.install(|| run(7));
        for (frame, (a, b)) in each.iter().zip(&other).enumerate() {
            assert_eq!(a.2, b.2, "{threads} threads, frame {frame}: the draws");
            assert_eq!(a.1, b.1, "{threads} threads, frame {frame}: the counts");
            assert!(a.0 == b.0, "{threads} threads, frame {frame}: the image");
        }
    }
}

/// Budget mode steers the frame's whole count, the draws of the representations trees in a
/// transition are leaving included (spec §10.2): walking into the field of demo trees, trees
/// change representation and fade for the transition's frames, and the frames, their leaving
/// draws counted, stay within 1.25 times the budget, all but a few within 1.1 times it. (Steered
/// without the leaving draws, 28 of the 60 frames drew over 1.1 times the budget, up to 1.40
/// times it.)
#[test]
fn budget_mode_counts_the_draws_of_trees_in_a_transition() {
    let gpu = gpu();
    let (container, positions, camera, unbudgeted) = budget_field(&gpu);
    let budget = unbudgeted / 2;
    let policy = Policy { budget: Some(budget), ..Policy::default() };
    let mut renderer = forest(&gpu, &container, Settings { policy: Some(policy), ..Settings::default() }, &positions);
    let ahead = vec3(0.0, -0.1, -1.0);
    let frames: Vec<(u64, u64)> = (0..60)
        .map(|k| {
            let eye = camera.position + ahead * (0.5 * k as f32);
            let walked = Camera::look_at(eye, eye + ahead, 0.9, camera.width, camera.height);
            let stats = renderer.prepare(&gpu.device, &gpu.queue, &walked);
            (stats.primitives(), stats.leaving)
        })
        .collect();
    assert!(frames.iter().filter(|(_, leaving)| *leaving > 0).count() >= 5, "few transitions: {frames:?}");
    assert!(frames.iter().all(|&(count, _)| 4 * count <= 5 * budget), "budget {budget}: {frames:?}");
    let over = frames.iter().filter(|&&(count, _)| 10 * count > 11 * budget).count();
    assert!(over <= 5, "{over} frames over 1.1 times the budget {budget}: {frames:?}");
}

/// Budget mode predicts a frame whose camera moved before drawing it (spec §10.2), and lowers
/// it where it is predicted far under the budget, as it raises one predicted over it: settled
/// on the field of demo trees at a quarter of what the default draws, the camera turns away
/// from most of the trees; the first frame of the new view is drawn within half to 1.1 times
/// the budget, where the steering it held draws that view (without a budget, at the held
/// target and `s_min`) under half of it. The same with the field's trees spread over a forest
/// of 17 chunks of `CHOOSE_CHUNK` (the others far behind both views), which budget mode's
/// predictions sample: such a forest was not lowered by prediction before its nearest trees
/// were chosen whole wherever they stand (`ChunkBounds::tallest_in_view`).
#[test]
fn budget_mode_lowers_a_moved_frame_predicted_far_under_before_drawing_it() {
    let gpu = gpu();
    let QuarterBudget { container, positions, camera, budget, policy, .. } = quarter_budget_field(&gpu);
    let n = 16 * treelod_runtime::CHOOSE_CHUNK + 1;
    let mut sampled = vec![vec3(0.0, 0.0, 5000.0); n];
    for (k, &p) in positions.iter().enumerate() {
        sampled[(k * 997) % n] = p;
    }
    for positions in [positions, sampled] {
        let settings = Settings { policy: Some(policy), ..Settings::default() };
        let mut renderer = forest(&gpu, &container, settings, &positions);
        let settled: Vec<u64> =
            (0..30).map(|_| renderer.prepare(&gpu.device, &gpu.queue, &camera).primitives()).collect();
        assert!(settled[20..].iter().all(|&c| 2 * c >= budget && 10 * c <= 11 * budget), "settled: {settled:?}");
        let (s_min, target) = renderer.budget_steering().expect("steering");
        let turned = Camera::look_at(Vec3::ZERO, vec3(3.0, -0.1, -1.0), 0.9, 320, 240);
        let defaults = Settings::default();
        let held = Settings {
            s_min,
            s_max: defaults.s_max * s_min / defaults.s_min,
            policy: Some(Policy { target, budget: None, ..policy }),
            ..defaults
        };
        let at_held = forest(&gpu, &container, held, &positions).prepare(&gpu.device, &gpu.queue, &turned).primitives();
        let trees = positions.len();
        assert!(
            2 * at_held < budget,
            "{trees} trees: the turned view at the held steering is far under {budget}: {at_held}"
        );
        let first = renderer.prepare(&gpu.device, &gpu.queue, &turned).primitives();
        assert!(
            2 * first >= budget && 10 * first <= 11 * budget,
            "{trees} trees: the first frame turned: {first} against {budget}"
        );
    }
}
