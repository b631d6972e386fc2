//! Frame selection throughput: a forest of 10,000 instances of the built-in demo tree scattered on a
//! 2 km × 2 km plane (random Y rotation, scale 0.8–1.2), along a fly-through of 60 camera poses:
//! an overview from 1 km up looking down, a descent, then a flight at 2 m height through the trees.
//!
//! Run with `cargo bench -p treelod-runtime --bench select`. Before the criterion runs, a table of
//! every pose is printed once: what it selects and its median time over a few repeats.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{Mat4, Quat, Vec3};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, SplitMix64, build_block, demo_tree};
use treelod_format::{Compression, Container};
use treelod_runtime::{Camera, DrawList, FrameStats, Instance, LodSettings, ModelLod, select_frame};

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
        median(medians).as_secs_f64() * 1e6,
        max.as_secs_f64() * 1e6,
        primitives as f64 / poses.len() as f64
    );
}

fn select(c: &mut Criterion) {
    let models = [demo_model()];
    let instances = forest();
    let poses = fly_through();
    let settings = LodSettings::default();
    let biased = LodSettings { depth_bias_k: 1.0, shading: Some((0.5, 1.0)), ..settings };
    print_table(&models, &instances, &poses, &settings, true);
    print_table(&models, &instances, &poses, &biased, false);

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
