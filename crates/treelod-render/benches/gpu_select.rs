//! Selection time per frame, GPU path against CPU path, for large forests.
//!
//! `cargo bench -p treelod-render --bench gpu_select` scatters 10^5 and 10^6 instances of the
//! built-in demo tree (one per 400 m², random Y rotation, scale 0.8–1.2; `TREELOD_BENCH_COUNTS`,
//! comma-separated, overrides the counts) and times, at 1920×1080, for three poses (2 m above the
//! ground inside the forest, 100 m up looking across it, 1 km up looking down):
//!
//! - **GPU**: wall clock of `Renderer::prepare` with [`Renderer::enable_gpu_selection`] plus
//!   waiting for its compute submission to finish (`device.poll(wait)`), median over several
//!   frames after three warm-up frames (which also let the draw buckets grow to fit);
//! - **CPU**: wall clock of `Renderer::prepare` on the CPU path (`select_frame` on rayon's pool,
//!   streaming, building and uploading the indirect draws), median likewise.
//!
//! The demo tree has no calibration tables, so the default policy chooses no tree and the GPU
//! selects every tree; a calibrated container's policy frames are shared between the CPU (the
//! assignment and the other techniques) and the GPU (the point tree's trees): `treelod bench
//! --technique policy --gpu-selection` measures those.
//!
//! Nothing is rendered: this measures selection only, on whatever Vulkan adapter is present (on
//! lavapipe the "GPU" is the same CPU cores, so the numbers compare algorithms, not hardware).
//! A hand-rolled loop rather than criterion: a 10^6-instance frame on lavapipe takes long enough
//! that criterion's default sample counts would take many minutes.

use std::time::{Duration, Instant};

use glam::{Mat4, Quat, Vec3};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, SplitMix64, build_block, demo_tree};
use treelod_format::{Compression, Container};
use treelod_render::Primitive;
use treelod_render::offscreen::Gpu;
use treelod_render::{Camera, FrameStats, Instance, Renderer, Settings};

const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
const FOVY: f32 = 1.0;

fn poses(half: f32) -> Vec<(&'static str, Camera)> {
    vec![
        ("ground", Camera::look_at(Vec3::new(3.0, 2.0, 0.5 * half), Vec3::new(40.0, 2.5, 0.0), FOVY, WIDTH, HEIGHT)),
        ("across", Camera::look_at(Vec3::new(0.0, 100.0, half), Vec3::new(0.0, 0.0, 0.0), FOVY, WIDTH, HEIGHT)),
        (
            "overview",
            Camera::look_at(Vec3::new(0.0, 1000.0, 300.0), Vec3::new(150.0, 0.0, -250.0), FOVY, WIDTH, HEIGHT),
        ),
    ]
}

fn median(mut samples: Vec<Duration>) -> f64 {
    samples.sort();
    samples[samples.len() / 2].as_secs_f64() * 1e3
}

fn time_frames(gpu: &Gpu, renderer: &mut Renderer, camera: &Camera, frames: usize) -> (f64, FrameStats) {
    let mut stats = FrameStats::default();
    for _ in 0..3 {
        renderer.prepare(&gpu.device, &gpu.queue, camera);
        gpu.device.poll(wgpu::PollType::wait_indefinitely()).expect("polls");
    }
    let mut samples = Vec::new();
    for _ in 0..frames {
        let start = Instant::now();
        stats = renderer.prepare(&gpu.device, &gpu.queue, camera);
        gpu.device.poll(wgpu::PollType::wait_indefinitely()).expect("polls");
        samples.push(start.elapsed());
    }
    (median(samples), stats)
}

fn main() {
    let counts: Vec<usize> = std::env::var("TREELOD_BENCH_COUNTS")
        .ok()
        .map(|v| v.split(',').filter_map(|c| c.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![100_000, 1_000_000]);
    let gpu = Gpu::new().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "bench")
            .expect("the demo tree builds");
    let container = std::sync::Arc::new(
        Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens"),
    );
    println!(
        "adapter: {} ({:?}), multi_draw_indirect_count: {}, {} rayon threads, {WIDTH}×{HEIGHT}",
        gpu.info.name,
        gpu.info.device_type,
        gpu.device.features().contains(wgpu::Features::MULTI_DRAW_INDIRECT_COUNT),
        rayon_threads(),
    );
    println!("| instances | pose | path | ms/frame | visible | ranges | dropped | triangles | points |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for count in counts {
        let half = 0.5 * (count as f32 * 400.0).sqrt();
        let mut rng = SplitMix64(2005);
        let transforms: Vec<Mat4> = (0..count)
            .map(|_| {
                let position = Vec3::new(rng.range(-half, half), 0.0, rng.range(-half, half));
                let rotation = Quat::from_rotation_y(rng.range(0.0, std::f32::consts::TAU));
                Mat4::from_scale_rotation_translation(Vec3::splat(rng.range(0.8, 1.2)), rotation, position)
            })
            .collect();
        let frames = if count >= 1_000_000 { 5 } else { 9 };
        for gpu_path in [true, false] {
            let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
            let model = renderer.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads");
            let instances: Vec<Instance> = transforms.iter().map(|&transform| Instance { model, transform }).collect();
            renderer.set_instances(&instances);
            if gpu_path {
                let start = Instant::now();
                renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("the demo tree fits");
                gpu.device.poll(wgpu::PollType::wait_indefinitely()).expect("polls");
                println!(
                    "<!-- {count} instances: sorting into blocks and uploading took {:.0} ms -->",
                    start.elapsed().as_secs_f64() * 1e3
                );
            }
            for (name, camera) in poses(half) {
                let (ms, s) = time_frames(&gpu, &mut renderer, &camera, frames);
                println!(
                    "| {count} | {name} | {} | {ms:.1} | {} | {} | {} | {} | {} |",
                    if gpu_path { "GPU" } else { "CPU" },
                    s.instances_visible,
                    s.ranges,
                    s.ranges_dropped,
                    s.submitted[Primitive::Triangle],
                    s.submitted[Primitive::Point]
                );
            }
        }
    }
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism().map_or(1, usize::from)
}
