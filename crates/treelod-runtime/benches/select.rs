//! Frame selection throughput: a forest of 10,000 instances of the built-in demo tree scattered on a
//! 2 km × 2 km plane (random Y rotation, scale 0.8–1.2), along a fly-through of 60 camera poses:
//! an overview from 1 km up looking down, a descent, then a flight at 2 m height through the trees.
//!
//! Run with `cargo bench -p treelod-runtime --bench select`. Before the criterion runs, a table of
//! every pose is printed once: what it selects and its median time over a few repeats.
//!
//! The same fly-through is then selected with the policy (spec §10.2), as the renderer does it on
//! the CPU every frame: the demo tree built with every representation the policy chooses among and
//! its calibration tables, each tree's choice with its hysteresis, the assignment, each technique's
//! selection ([`select_techniques`]) and the point tree's ([`select_frame`]) over its trees; and
//! the making of the demo tree's choices under a policy ([`Choices::new`]), which budget mode
//! repeats each frame its target moves.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{Mat4, Quat, Vec3};
use treelod_build::{
    BuildConfig, CalibrationConfig, DemoTreeConfig, EllipsoidConfig, ImpostorConfig, LineConfig, LodChainConfig,
    Placed, PruneConfig, SplitMix64, build_block, demo_tree,
};
use treelod_format::{Compression, Container};
use treelod_runtime::{
    Assignment, Calibration, Camera, Choices, DrawList, FrameStats, ImpostorBark, Instance, LodSettings, ModelLod,
    PerTechnique, PixelLevel, Policy, PolicyState, PruneState, Pruning, Representations, Scene, Technique,
    TechniqueSettings, TreeDraws, choose_instances, merge_ascending, select_frame, select_techniques,
};

const INSTANCES: usize = 10_000;
const HALF_SIDE: f32 = 1000.0;
const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
const FOVY: f32 = 1.0;

fn demo_model() -> ModelLod {
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "bench")
            .expect("the demo tree builds");
    let container = Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens");
    ModelLod::from_container(&container)
}

/// The demo tree with every representation the policy chooses among (pruning, impostor planes,
/// ellipsoids with lines, the LoD chain and billboards) and its calibration tables, as
/// `treelod build --prune density --impostors --ellipsoids --lines --baselines --ao-rays 0` makes
/// it, with fewer measuring views so the bench starts in seconds: pruning's curves from 4 views at
/// 128 pixels (the tool's 8 at 256) and the calibration from 2 views (the tool's 4). The views
/// change the tables' values, not the work a frame does with them.
fn policy_model() -> (ModelLod, Representations, Calibration) {
    let scene = demo_tree(&DemoTreeConfig::default());
    let config = BuildConfig {
        prune: Some(PruneConfig { resolution: 128, views: 4, ..PruneConfig::default() }),
        impostors: Some(ImpostorConfig::default()),
        ellipsoids: Some(EllipsoidConfig::default()),
        lines: Some(LineConfig::default()),
        baselines: Some(LodChainConfig::default()),
        calibration: Some(CalibrationConfig { views: 1, more_small_views: false, ..CalibrationConfig::default() }),
        ..BuildConfig::default()
    };
    let built = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "bench")
        .expect("the demo tree builds");
    let container = Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens");
    let calibration = Calibration::from_container(&container).expect("the build calibrated");
    (ModelLod::from_container(&container), Representations::from_container(&container).0, calibration)
}

fn forest() -> Vec<Instance> {
    let mut rng = SplitMix64(2005);
    (0..INSTANCES)
        .map(|_| {
            let position = Vec3::new(rng.range(-HALF_SIDE, HALF_SIDE), 0.0, rng.range(-HALF_SIDE, HALF_SIDE));
            let rotation = Quat::from_rotation_y(rng.range(0.0, std::f32::consts::TAU));
            let scale = Vec3::splat(rng.range(0.8, 1.2));
            Instance { model: 0, transform: Mat4::from_scale_rotation_translation(scale, rotation, position) }
        })
        .collect()
}

/// 60 poses: 15 overview (1 km up, looking down, drifting), 15 descent, 30 at 2 m height.
fn fly_through() -> Vec<(&'static str, Camera)> {
    let mut poses = Vec::new();
    for i in 0..15 {
        let t = i as f32 / 14.0;
        let eye = Vec3::new(-200.0 + 200.0 * t, 1000.0, 300.0 - 100.0 * t);
        let target = Vec3::new(eye.x + 150.0, 0.0, eye.z - 250.0);
        poses.push(("overview", Camera::look_at(eye, target, FOVY, WIDTH, HEIGHT)));
    }
    for i in 0..15 {
        let t = (i + 1) as f32 / 15.0;
        // Height falls geometrically from 1 km to 2 m while the camera glides towards the forest's
        // centre and its gaze levels out.
        let height = 1000.0 * (2.0f32 / 1000.0).powf(t);
        let eye = Vec3::new(0.0, height, 200.0 - 200.0 * t);
        let target = eye + Vec3::new(0.3, -(1.0 - t) * 1.5 - 0.05, -1.0);
        poses.push(("descent", Camera::look_at(eye, target, FOVY, WIDTH, HEIGHT)));
    }
    for i in 0..30 {
        let t = i as f32 / 29.0;
        let eye = Vec3::new(10.0 * (t * 6.0).sin(), 2.0, -60.0 * t * 5.0);
        let heading = Vec3::new(0.4 * (t * 6.0).cos(), 0.08, -1.0);
        poses.push(("inside", Camera::look_at(eye, eye + heading, FOVY, WIDTH, HEIGHT)));
    }
    poses
}

fn median(mut samples: Vec<Duration>) -> Duration {
    samples.sort();
    samples[samples.len() / 2]
}

/// Prints, per phase of the fly-through, the median and the largest of its poses' median times.
fn print_phases(poses: &[(&str, Camera)], medians: &[Duration]) {
    for phase in ["overview", "descent", "inside"] {
        let mut times: Vec<Duration> =
            poses.iter().zip(medians).filter(|((p, _), _)| *p == phase).map(|(_, &m)| m).collect();
        times.sort();
        let max = times.last().copied().unwrap_or_default();
        println!(
            "  {phase:<8}  {:>2} poses: median {:>7.1} µs, max {:>7.1} µs",
            times.len(),
            median(times).as_secs_f64() * 1e6,
            max.as_secs_f64() * 1e6
        );
    }
}

/// What the renderer keeps between frames to select them with the policy (its `assign` and
/// `select_view` for the camera's view), and the frame's lists, reused.
struct PolicyFrame<'a> {
    lods: &'a [ModelLod],
    models: &'a [Representations],
    instances: &'a [Instance],
    /// Per model, its choices under the policy (made once, as the renderer does per policy).
    choices: Vec<Option<Choices>>,
    state: PolicyState,
    chosen: Vec<Option<Technique>>,
    assignment: Assignment,
    draws: TreeDraws,
    /// Pruning's held `λ` per instance, and the visible fractions of the occlusion test (all 1:
    /// no GPU measures them here).
    prune_shown: Vec<Option<f32>>,
    chain_levels: Vec<Option<treelod_runtime::ChainPick>>,
    visible_fraction: Vec<f32>,
    spt_list: Vec<u32>,
    spt_instances: Vec<Instance>,
    list: DrawList,
    lod: LodSettings,
    technique: TechniqueSettings,
}

impl<'a> PolicyFrame<'a> {
    /// The renderer's default settings: the default policy, `s_min` 1 px, `s_max` 2 px, pruning,
    /// impostor bark, ellipsoid levels and lines as `treelod_render::Settings::default()` sets them.
    fn new(
        lods: &'a [ModelLod],
        models: &'a [Representations],
        calibrations: &[Calibration],
        instances: &'a [Instance],
    ) -> Self {
        let policy = Policy::default();
        let lod = LodSettings::default();
        Self {
            lods,
            models,
            instances,
            choices: calibrations.iter().zip(models).map(|(c, m)| Some(Choices::new(c, &policy, m))).collect(),
            state: PolicyState::default(),
            chosen: Vec::new(),
            assignment: Assignment::default(),
            draws: TreeDraws::default(),
            prune_shown: vec![None; instances.len()],
            chain_levels: vec![None; instances.len()],
            visible_fraction: vec![1.0; instances.len()],
            spt_list: Vec::new(),
            spt_instances: Vec::new(),
            list: DrawList::new(),
            lod,
            technique: TechniqueSettings {
                s_min: lod.s_min,
                lod,
                pruning: Pruning::default(),
                impostor_bark: ImpostorBark::default(),
                pixel_level: PixelLevel { quality: 1.0, blend: 0.5 },
                lines: true,
                chain_policy: policy,
                culled: false,
            },
        }
    }

    /// One frame for `camera`: each tree's technique, the assignment, every technique's selection
    /// and the point tree's over its trees; returns the point tree's counts.
    fn select(&mut self, camera: &Camera) -> FrameStats {
        choose_instances(
            self.instances,
            self.lods,
            &self.choices,
            camera,
            Technique::Spt,
            &mut self.state,
            &mut self.chosen,
        );
        let chosen = self.chosen.iter().enumerate().filter_map(|(i, t)| Some((u32::try_from(i).ok()?, (*t)?)));
        self.assignment.assign_listed(self.instances, self.models, chosen);
        self.draws.clear();
        let scene = Scene { lods: self.lods, models: self.models, instances: self.instances };
        let prune_state = PruneState { shown: &mut self.prune_shown, visible_fraction: &self.visible_fraction };
        let chain_state = treelod_runtime::ChainState { previous: &mut self.chain_levels, hold: false };
        let technique = &self.technique;
        select_techniques(
            &scene,
            &self.assignment,
            camera,
            technique,
            Some(prune_state),
            Some(chain_state),
            &mut self.draws,
        );
        let (full, spt) = (&self.assignment[Technique::Full], &self.assignment[Technique::Spt]);
        merge_ascending(&[full, spt, &self.draws.point_tree], &mut self.spt_list);
        let remapped = self.spt_list.len() != self.instances.len();
        self.spt_instances.clear();
        if remapped {
            self.spt_instances.extend(self.spt_list.iter().map(|&i| self.instances[i as usize]));
        }
        let spt_instances = if remapped { &self.spt_instances[..] } else { self.instances };
        select_frame(self.lods, spt_instances, camera, &self.lod, &mut self.list)
    }
}

/// Prints, per pose selected with the policy, the visible trees by technique, the draws and the
/// median time over 15 runs (the hysteresis state carried from pose to pose, as in a flight that
/// pauses at each pose), then the per-phase summary.
fn print_policy_table(frame: &mut PolicyFrame<'_>, poses: &[(&str, Camera)]) {
    let shown = [
        Technique::Spt,
        Technique::PruneOpt,
        Technique::Impostors,
        Technique::Ellipsoids,
        Technique::LodChain,
        Technique::Billboard,
        Technique::Crossed,
    ];
    println!(
        "policy (target {}, hysteresis {} octaves): visible trees by technique, draws, median time",
        Policy::default().target,
        Policy::default().hysteresis
    );
    print!("frame  phase   ");
    for technique in shown {
        print!(" {:>10}", technique.name());
    }
    println!("  tri draws  prefixes    ranges  median µs");
    let mut medians = Vec::new();
    for (index, (phase, camera)) in poses.iter().enumerate() {
        let mut stats = FrameStats::default();
        let samples: Vec<Duration> = (0..15)
            .map(|_| {
                let start = Instant::now();
                stats = frame.select(camera);
                start.elapsed()
            })
            .collect();
        let m = median(samples);
        medians.push(m);
        let mut visible: PerTechnique<u32> = frame.draws.visible;
        *visible.get_mut(Technique::Spt) += stats.instances_visible;
        print!("{index:>5}  {phase:<8}");
        for technique in shown {
            print!(" {:>10}", visible.get(technique));
        }
        let draws = &frame.draws;
        println!(
            " {:>10} {:>9} {:>9} {:>10.1}",
            draws.triangles.len(),
            draws.planes.len() + draws.ellipsoids.len() + draws.lines.len() + draws.billboards.len(),
            stats.ranges,
            m.as_secs_f64() * 1e6
        );
    }
    let max = medians.iter().max().copied().unwrap_or_default();
    println!(
        "median of the per-frame medians {:.1} µs, slowest frame {:.1} µs",
        median(medians.clone()).as_secs_f64() * 1e6,
        max.as_secs_f64() * 1e6
    );
    print_phases(poses, &medians);
    println!();
}

/// Prints what every pose selects with `settings` and its median time over 15 runs; every row if
/// `rows`, else only the summary.
fn print_table(
    models: &[ModelLod],
    instances: &[Instance],
    poses: &[(&str, Camera)],
    settings: &LodSettings,
    rows: bool,
) {
    let mut list = DrawList::new();
    let mut medians = Vec::new();
    let mut primitives = 0;
    println!(
        "\nforest: {} instances of the demo tree ({} cells, R = {:.2} m); s_min {} px, s_max {} px, k {}, \
         shading {:?}; {} rayon threads",
        instances.len(),
        models[0].cells().len(),
        models[0].radius(),
        settings.s_min,
        settings.s_max,
        settings.depth_bias_k,
        settings.shading,
        rayon::current_num_threads(),
    );
    if rows {
        println!("frame  phase     visible    far  cells   ranges  triangles     points  median µs");
    }
    for (frame, (phase, camera)) in poses.iter().enumerate() {
        let mut stats = FrameStats::default();
        let samples: Vec<Duration> = (0..15)
            .map(|_| {
                let start = Instant::now();
                stats = select_frame(models, instances, camera, settings, &mut list);
                start.elapsed()
            })
            .collect();
        let m = median(samples);
        medians.push(m);
        primitives += stats.primitives();
        if rows {
            println!(
                "{frame:>5}  {phase:<8} {:>8} {:>6} {:>6} {:>8} {:>10} {:>10} {:>10.1}",
                stats.instances_visible,
                stats.instances_far,
                stats.cells_visible,
                stats.ranges,
                stats.triangles,
                stats.points,
                m.as_secs_f64() * 1e6
            );
        }
    }
    let max = medians.iter().max().copied().unwrap_or_default();
    println!(
        "median of the per-frame medians {:.1} µs, slowest frame {:.1} µs, {:.0} primitives per frame on average\n",
        median(medians.clone()).as_secs_f64() * 1e6,
        max.as_secs_f64() * 1e6,
        primitives as f64 / poses.len() as f64
    );
    print_phases(poses, &medians);
}

fn select(c: &mut Criterion) {
    let models = [demo_model()];
    let instances = forest();
    let poses = fly_through();
    let settings = LodSettings::default();
    let biased = LodSettings { depth_bias_k: 1.0, shading: Some((0.5, 1.0)), ..settings };
    print_table(&models, &instances, &poses, &settings, true);
    print_table(&models, &instances, &poses, &biased, false);

    let (policy_lod, representations, calibration) = policy_model();
    let policy_lods = [policy_lod];
    let policy_models = [representations];
    let calibrations = [calibration];
    let mut policy = PolicyFrame::new(&policy_lods, &policy_models, &calibrations, &instances);
    print_policy_table(&mut policy, &poses);

    let mut group = c.benchmark_group("select_frame");
    let mut list = DrawList::new();
    let mut next = 0;
    group.bench_function("fly-through, one pose per iteration", |b| {
        b.iter(|| {
            let camera = &poses[next % poses.len()].1;
            next += 1;
            black_box(select_frame(&models, &instances, camera, &settings, &mut list))
        });
    });
    let mut next = 0;
    group.bench_function("fly-through, depth bias and shading", |b| {
        b.iter(|| {
            let camera = &poses[next % poses.len()].1;
            next += 1;
            black_box(select_frame(&models, &instances, camera, &biased, &mut list))
        });
    });
    let mut next = 0;
    group.bench_function("fly-through, policy", |b| {
        b.iter(|| {
            let camera = &poses[next % poses.len()].1;
            next += 1;
            black_box(policy.select(camera))
        });
    });
    // Budget mode makes a model's choices again each frame its target moves (spec §10.2).
    let mut step = 0u16;
    group.bench_function("policy choices, a new target per iteration", |b| {
        b.iter(|| {
            step = step.wrapping_add(1);
            let target = Policy::DEFAULT_TARGET * (1.0 + f32::from(step % 512) / 256.0);
            let policy = Policy { target, ..Policy::default() };
            black_box(Choices::new(&calibrations[0], &policy, &policy_models[0]))
        });
    });
    for (name, frame) in [("overview (frame 0)", 0), ("descent (frame 22)", 22), ("inside (frame 45)", 45)] {
        let camera = &poses[frame].1;
        group.bench_function(name, |b| {
            b.iter(|| black_box(select_frame(&models, &instances, camera, &settings, &mut list)))
        });
    }
    group.finish();
}

criterion_group!(benches, select);
criterion_main!(benches);
