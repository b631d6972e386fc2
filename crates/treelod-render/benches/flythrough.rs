//! Level of detail against the full mesh along a fly-through, rendered: per pose, the primitives
//! drawn (triangles + points) against the full mesh's triangles, and the pixel-coverage agreement
//! of the two images (precision: covered LoD pixels the full mesh also covers; recall: covered
//! full-mesh pixels the LoD image also covers).
//!
//! `cargo bench -p treelod-render --bench flythrough` renders a forest of the built-in demo tree
//! (`TREELOD_BENCH_INSTANCES`, default 1000, one tree per 400 m² as in the selection bench) at
//! 480×270 on whatever Vulkan adapter is present (lavapipe without a GPU: there the full mesh of
//! a large forest takes seconds a frame, so keep the count small) along 12 poses: overview from
//! 1 km, descent, inside the forest at 2 m. Frame times are wall-clock `prepare` + render +
//! read-back, so they mean something only on a real GPU.

use std::time::Instant;

use glam::{Mat4, Quat, Vec3};
use treelod_build::{BuildConfig, DemoTreeConfig, Placed, SplitMix64, build_block, demo_tree};
use treelod_format::{Compression, Container};
use treelod_render::Primitive;
use treelod_render::offscreen::{Gpu, Image, render_image};
use treelod_render::{Camera, Instance, Renderer, Settings, Technique};

const WIDTH: u32 = 480;
const HEIGHT: u32 = 270;
const FOVY: f32 = 1.0;
const BACKGROUND: wgpu::Color = wgpu::Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 };

fn poses(half: f32) -> Vec<(&'static str, Camera)> {
    let mut poses = Vec::new();
    for i in 0..3 {
        let t = i as f32 / 2.0;
        let eye = Vec3::new(-0.2 * half + 0.2 * half * t, 1000.0, 0.3 * half);
        poses.push(("overview", Camera::look_at(eye, Vec3::new(eye.x + 0.15 * half, 0.0, 0.0), FOVY, WIDTH, HEIGHT)));
    }
    for i in 0..4 {
        let t = (i + 1) as f32 / 4.0;
        let height = 1000.0 * (2.0f32 / 1000.0).powf(t);
        let eye = Vec3::new(0.0, height, 0.2 * half * (1.0 - t));
        let target = eye + Vec3::new(0.3, -(1.0 - t) * 1.5 - 0.05, -1.0);
        poses.push(("descent", Camera::look_at(eye, target, FOVY, WIDTH, HEIGHT)));
    }
    for i in 0..5 {
        let t = i as f32 / 4.0;
        let eye = Vec3::new(10.0 * (t * 6.0).sin(), 2.0, -0.5 * half * t);
        let heading = Vec3::new(0.4 * (t * 6.0).cos(), 0.08, -1.0);
        poses.push(("inside", Camera::look_at(eye, eye + heading, FOVY, WIDTH, HEIGHT)));
    }
    poses
}

fn covered(image: &Image) -> Vec<bool> {
    image.rgba.chunks_exact(4).map(|p| p[0] < 250 || p[1] < 250 || p[2] < 250).collect()
}

fn main() {
    let count: usize = std::env::var("TREELOD_BENCH_INSTANCES").ok().and_then(|v| v.parse().ok()).unwrap_or(1000);
    let half = 0.5 * (count as f32 * 400.0).sqrt();
    let gpu = Gpu::new().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
    let scene = demo_tree(&DemoTreeConfig::default());
    let built =
        build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &BuildConfig::default(), "bench")
            .expect("the demo tree builds");
    let container = Container::from_bytes(&built.data.to_bytes(Compression::None).expect("encodes")).expect("opens");
    let full_triangles = container.triangles().len();
    let mut rng = SplitMix64(2005);
    let mut lod = Renderer::new(&gpu.device, Gpu::formats(), Settings::default());
    let mut full = Renderer::new(&gpu.device, Gpu::formats(), Settings::forced(Technique::Full));
    let container = std::sync::Arc::new(container);
    let (a, b) = (
        lod.add_model(&gpu.device, &gpu.queue, container.clone()).expect("uploads"),
        full.add_model(&gpu.device, &gpu.queue, container).expect("uploads"),
    );
    let transforms: Vec<Mat4> = (0..count)
        .map(|_| {
            let position = Vec3::new(rng.range(-half, half), 0.0, rng.range(-half, half));
            let rotation = Quat::from_rotation_y(rng.range(0.0, std::f32::consts::TAU));
            Mat4::from_scale_rotation_translation(Vec3::splat(rng.range(0.8, 1.2)), rotation, position)
        })
        .collect();
    lod.set_instances(&transforms.iter().map(|&transform| Instance { model: a, transform }).collect::<Vec<_>>());
    full.set_instances(&transforms.iter().map(|&transform| Instance { model: b, transform }).collect::<Vec<_>>());
    println!(
        "{count} demo trees ({full_triangles} triangles each) on {:.0} m × {:.0} m, {WIDTH}×{HEIGHT}, adapter: {} ({:?})",
        2.0 * half,
        2.0 * half,
        gpu.info.name,
        gpu.info.device_type
    );
    println!(
        "| pose | kind | visible | LoD triangles | LoD points | full triangles | LoD/full | precision | recall | LoD ms | full ms |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (i, (kind, camera)) in poses(half).iter().enumerate() {
        // Let streaming settle, then measure the frame.
        for _ in 0..3 {
            render_image(&gpu, &mut lod, camera, BACKGROUND).expect("renders");
        }
        let start = Instant::now();
        let (lod_image, s) = render_image(&gpu, &mut lod, camera, BACKGROUND).expect("renders");
        let lod_ms = start.elapsed().as_secs_f64() * 1e3;
        render_image(&gpu, &mut full, camera, BACKGROUND).expect("renders");
        let start = Instant::now();
        let (full_image, f) = render_image(&gpu, &mut full, camera, BACKGROUND).expect("renders");
        let full_ms = start.elapsed().as_secs_f64() * 1e3;
        let (x, y) = (covered(&lod_image), covered(&full_image));
        let both = x.iter().zip(&y).filter(|(p, q)| **p && **q).count() as f64;
        let (nx, ny) = (x.iter().filter(|p| **p).count() as f64, y.iter().filter(|p| **p).count() as f64);
        println!(
            "| {i} | {kind} | {} | {} | {} | {} | {:.4} | {:.3} | {:.3} | {lod_ms:.1} | {full_ms:.1} |",
            s.instances_visible,
            s.submitted[Primitive::Triangle],
            s.submitted[Primitive::Point],
            f.submitted[Primitive::Triangle],
            (s.submitted[Primitive::Triangle] + s.submitted[Primitive::Point]) as f64
                / f.submitted[Primitive::Triangle].max(1) as f64,
            both / nx.max(1.0),
            both / ny.max(1.0),
        );
    }
}
