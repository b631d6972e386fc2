//! Ambient occlusion: the stage's time and its error against a 256-ray reference.
//!
//! Run with `cargo bench -p treelod-build --bench ao -- FILE.treelod…` on containers built by
//! `treelod build`/`demo` (any `--ao-rays`, 0 is quickest). The stage's input is read back from
//! each container as the build gives it (written vertices, triangles, each triangle's coverage
//! from its leaf point's alpha, two-sided materials); then, per container, the occlusion of
//! every vertex with 256 rays traced from each vertex on its own (the reference, cached beside
//! the container as `FILE.ao256`; another seed than the compared ones), and with 16 rays: traced
//! through the BVH with every vertex on its own (`AoConfig::per_vertex`) and with small flat
//! pieces settled by their first rays, and as parallel rays along 32 directions (the default,
//! pieces settled by the even directions; and every vertex along all of them), each with its
//! wall-clock and CPU time and its mean absolute difference per vertex from the
//! reference. The input is in the container's order (vertices by first use, triangles by cell
//! and size), less local than the source's that the build's stage reads: the maple's parallel
//! rays take about a fifth longer here than in a build (`crate::parallel_rays` of the build
//! crate). `TREELOD_AO_NO_REFERENCE=1` times only; `TREELOD_AO_ONLY=parallel` (or any part of
//! a row's name) runs the rows that name it; `TREELOD_AO_RAYS=12,16` the parallel method at
//! those ray counts (`2N` directions); `TREELOD_AO_SEEDS=1,2` each row with those seeds.

use std::path::{Path, PathBuf};
use std::time::Instant;

use treelod_build::ambient::{AoTriangle, vertex_occlusion};
use treelod_build::{AoConfig, AoMethod};
use treelod_format::{Container, MATERIAL_DOUBLE_SIDED, VertexRecord};

/// The stage's input read back from a container.
fn input(container: &Container) -> (Vec<VertexRecord>, Vec<AoTriangle>) {
    let mut triangles = Vec::new();
    for cell in container.cells() {
        let cell_triangles = &container.triangles()[cell.triangles.as_usize()];
        let mut alpha_of_leaf = vec![1.0f32; cell_triangles.len()];
        for p in container.points()[cell.points.as_usize()].iter().filter(|p| p.lo == 0.0 && p.leaf_count == 1) {
            if let Some(slot) = alpha_of_leaf.get_mut(p.leaf_first as usize) {
                *slot = f32::from((p.color >> 24) as u8) / 255.0;
            }
        }
        for t in cell_triangles {
            triangles.push(AoTriangle {
                v: t.indices,
                opacity: alpha_of_leaf.get(t.leaf as usize).copied().unwrap_or(1.0),
                two_sided: container.materials()[t.material as usize].flags & MATERIAL_DOUBLE_SIDED != 0,
            });
        }
    }
    (container.vertices().to_vec(), triangles)
}

fn timed(vertices: &[VertexRecord], triangles: &[AoTriangle], config: &AoConfig) -> (Vec<f32>, f64) {
    let start = Instant::now();
    let cpu = cpu_seconds();
    let ao = vertex_occlusion(vertices, triangles, config, &|_, _| {});
    eprint!(" [{:.2} s CPU]", cpu_seconds() - cpu);
    (ao, start.elapsed().as_secs_f64())
}

/// This process's user CPU time, seconds (Linux).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    fields.get(11).and_then(|t| t.parse::<f64>().ok()).unwrap_or(0.0) / 100.0
}

fn mean_abs_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from((x - y).abs())).sum::<f64>() / a.len().max(1) as f64
}

fn mean_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from(x - y)).sum::<f64>() / a.len().max(1) as f64
}

fn reference(path: &Path, vertices: &[VertexRecord], triangles: &[AoTriangle]) -> Vec<f32> {
    let cache = PathBuf::from(format!("{}.ao256", path.display()));
    if let Ok(bytes) = std::fs::read(&cache)
        && bytes.len() == 4 * vertices.len()
    {
        return bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    }
    let config = AoConfig { rays: 256, seed: 0x5EED_0256, per_vertex: true, method: AoMethod::Traced };
    let (ao, seconds) = timed(vertices, triangles, &config);
    eprintln!("  reference (256 rays per vertex): {seconds:.1} s");
    let bytes: Vec<u8> = ao.iter().flat_map(|x| x.to_le_bytes()).collect();
    if let Err(e) = std::fs::write(&cache, bytes) {
        eprintln!("  (reference not cached: {e})");
    }
    ao
}

fn main() {
    let files: Vec<PathBuf> = std::env::args().skip(1).filter(|a| a.ends_with(".treelod")).map(PathBuf::from).collect();
    if files.is_empty() {
        eprintln!("usage: cargo bench -p treelod-build --bench ao -- FILE.treelod…");
        return;
    }
    let with_reference = std::env::var_os("TREELOD_AO_NO_REFERENCE").is_none();
    for path in files {
        let container = Container::open(&path).expect("a container");
        let (vertices, triangles) = input(&container);
        println!("{}: {} vertices, {} triangles", path.display(), vertices.len(), triangles.len());
        let reference = with_reference.then(|| reference(&path, &vertices, &triangles));
        let only = std::env::var("TREELOD_AO_ONLY").unwrap_or_default();
        let traced = AoConfig { method: AoMethod::Traced, ..AoConfig::default() };
        let mut configs = vec![
            ("traced, 16 rays per vertex".to_string(), AoConfig { per_vertex: true, ..traced.clone() }),
            ("traced, 16 rays shared".to_string(), traced),
        ];
        // `TREELOD_AO_RAYS=12,16,…`: the parallel method at those ray counts (default 16).
        for rays in std::env::var("TREELOD_AO_RAYS").unwrap_or_else(|_| "16".into()).split(',') {
            if let Ok(rays) = rays.trim().parse::<u32>() {
                let name = format!("parallel, {} directions{}", 2 * rays, if rays == 16 { " (default)" } else { "" });
                configs.push((name, AoConfig { rays, ..AoConfig::default() }));
                if rays == 16 {
                    let name = "parallel, 32 directions, every vertex".to_string();
                    configs.push((name, AoConfig { per_vertex: true, ..AoConfig::default() }));
                }
            }
        }
        // `TREELOD_AO_SEEDS=1,2,…`: each row once per seed of its directions (default: the
        // build's), for the spread of a method's error over direction sets.
        if let Ok(seeds) = std::env::var("TREELOD_AO_SEEDS") {
            let seeds: Vec<u64> = seeds.split(',').filter_map(|s| s.trim().parse().ok()).collect();
            configs = configs
                .into_iter()
                .flat_map(|(name, config)| {
                    seeds.iter().map(move |&seed| (format!("{name}, seed {seed}"), AoConfig { seed, ..config.clone() }))
                })
                .collect();
        }
        for (name, config) in configs {
            if !only.is_empty() && !name.contains(&only) {
                continue;
            }
            let (ao, seconds) = timed(&vertices, &triangles, &config);
            let error = reference.as_ref().map_or(String::new(), |r| {
                format!(", mean |Δ| {:.4}, mean Δ {:+.4}", mean_abs_diff(&ao, r), mean_diff(&ao, r))
            });
            println!("  {name:34} {seconds:7.2} s{error}");
        }
    }
}
