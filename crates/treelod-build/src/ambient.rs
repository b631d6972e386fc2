//! Precomputed ambient occlusion (Clasen, Paar and Prohaska 2011 §5; spec §6.14).
//!
//! Per vertex, rays leave the surface in cosine-weighted directions about the vertex normal (both
//! sides of two-sided materials: leaves are lit from both faces) and are traced through the whole
//! block until they leave it, as the paper does for its meshes. A ray that meets a triangle loses
//! that triangle's *opacity*, the opaque share of its area (the alpha of its leaf point, spec
//! §6.5): an alpha-tested leaf card stops a ray as often as its texture is opaque, without looking
//! up texels, and a ray carries on until less than 1/512 of it is left. The vertex's occlusion is
//! one minus the mean of what the rays keep: 0 in the open, 1 inside a closed opaque box.
//!
//! The level-of-detail primitives get the area-weighted mean of the occlusion of the leaves they
//! stand for ([`mean_occlusion`]), like their colour: a point drawn in place of its leaves keeps
//! their brightness, so switching levels does not change the canopy's shading. An impostor plane
//! stands for a whole cluster, which a view sees mostly by its open leaves: it gets the mean
//! weighted by how often a view from outside reaches each leaf ([`seen_occlusion`]). (The paper
//! samples its ellipsoids' and lines' own surfaces instead; those are not points of the source
//! surface, and their occlusion would differ from the mesh's they replace.)
//!
//! Two ways to trace the rays ([`AoMethod`]). The default, [`AoMethod::Parallel`]
//! ([`crate::parallel_rays`]), gives every vertex the same `2 × rays` directions, evenly spread
//! over the sphere, and traces each direction from all vertices at once through a grid of the
//! triangles projected along it; each vertex weights the directions on its side by their cosine
//! (about `rays` of them; both sides, all of them, for two-sided materials). The rest of this
//! documentation is of [`AoMethod::Traced`], each vertex's own `rays` directions through a BVH,
//! which the measurements take as their reference (256 rays per vertex). Measured
//! (`benches/ao.rs`, release, 2 cores; mean |Δ| per vertex against the reference, wall clock of
//! the stage):
//!
//! | model | vertices | traced, 16 rays | parallel, 32 directions (default) | parallel, 24 |
//! |---|---|---|---|---|
//! | Quaternius (3k triangles) | 5.8k | 0.0231, 0.02 s | 0.0215, 0.02 s | 0.0279, 0.02 s |
//! | ez-tree pine (19k) | 22k | 0.0261, 0.44 s | 0.0207, 0.20 s | 0.0257, 0.15 s |
//! | ez-tree oak (23k) | 30k | 0.0260, 0.59 s | 0.0203, 0.32 s | 0.0249, 0.22 s |
//! | orchid (31k) | 62k | 0.0752, 0.35 s | 0.0589, 0.19 s | 0.0687, 0.14 s |
//! | jacaranda (55k) | 102k | 0.0695, 0.65 s | 0.0532, 0.42 s | 0.0624, 0.32 s |
//! | willow (154k) | 187k | 0.0590, 2.13 s | 0.0536, 1.38 s | 0.0624, 1.08 s |
//! | maple (669k) | 717k | 0.0643, 11.0 s | 0.0628, 4.9 s | 0.0733, 3.6 s |
//!
//! The shared directions are evenly spread where a vertex's own random rays clump, and the rays
//! of a direction that start in one cell of its grid share that cell's list; with neither
//! method biased (mean Δ within ±0.003 on every model), the parallel rays are closer to the
//! reference on every model, and their stage takes 0.45–0.65× the time on the six larger models
//! (the Quaternius tree's 0.02 s either way). Without the BVH the maple's build peaked at 169 MB
//! instead of 319 MB (122.8 MB since the stage holds a band of a direction's rows at a time and
//! runs before the build's per-cell stage, [`crate::parallel_rays`]).
//!
//! The traced rays run against a BVH (`obvhs`, an 8-wide compressed BVH), in parallel over
//! batches of vertices. Directions come from a per-vertex rotated stratified spiral seeded by the vertex
//! index, so the result is the same whatever the thread count.
//!
//! Cost. Where foliage is dense, most vertices are buried: every ray they cast is stopped. The
//! vertices of a small flat piece (a leaf card's 4 corners: a connected set of at most 16
//! vertices, alike in sidedness, normals within 25°, no more than 1/16 of the block's diagonal
//! across) therefore first trace half of their rays each (every stratum, both sides); if every
//! one of those rays was stopped, or every one left the block untouched, the whole piece gets 1
//! (or 0) — adaptive sampling, with the piece as the neighbourhood that must agree. Otherwise
//! each vertex traces the other half, and gets exactly what it would on its own. Measured
//! (`benches/ao.rs`, release, 2 cores shared with other work) against 256 rays per vertex, as
//! the mean absolute difference per vertex, with the default 16 rays:
//!
//! | model | vertices | every vertex on its own | as built | stage time, own → as built |
//! |---|---|---|---|---|
//! | demo tree, 10⁵ leaves | 403k | 0.0088 | 0.0089 | 12.7 → 11.1 s CPU |
//! | demo tree, 10⁶ leaves | 4.0M | (no reference) | | 361 → 195 s CPU |
//! | ez-tree oak (23k triangles) | 30k | 0.0260 | 0.0260 | 0.76 s CPU, unchanged |
//! | sapling maple (669k triangles) | 717k | 0.0643 | 0.0643 | 12.5 s CPU, unchanged |
//!
//! (The stage before this, every vertex on its own with another jitter: 0.0088, 0.0259 and
//! 0.0644.) Sharing rays outright measured worse: a piece's mean for all its vertices (32 rays
//! per card) 0.0162 on the 10⁵-leaf demo and 0.0282 on the oak (the corners of a card see
//! different neighbours; on the maple it was 0.0592), and settling a piece on a quarter of its
//! rays 0.0099 on the demo. Russian roulette on a ray's last 1/16 cut a third of the demo's
//! triangle tests for +0.0002; splitting large triangles in the BVH saved nothing.
//!
//! Cheaper methods measured and not taken (`benches/ao.rs`, same references, mean |Δ| per
//! vertex; 16 rays as built: oak 0.0260, jacaranda 0.0695, Quaternius 0.0231, pine 0.0261,
//! willow 0.0590, maple 0.0643, 10⁵-leaf demo 0.0089):
//! - *An opacity volume* (the block's opaque area deposited into voxels, Beer–Lambert
//!   transmittance swept per direction over 64 directions, read trilinearly at each vertex; no
//!   ray meets a triangle): 15× faster on the maple (0.9 s against 14.4 s wall) but 2–6× the
//!   error: at 64 voxels across, oak 0.062–0.087, jacaranda 0.092–0.132, Quaternius 0.127–0.184,
//!   pine 0.078–0.121, maple 0.097–0.098, demo 0.030–0.069 (isotropic or per-direction projected
//!   area, exponential or per-voxel linear attenuation, with the lookup on the surface or half
//!   a voxel off it); at 128 voxels oak 0.044, demo 0.019, at 9× the time. The volume cannot
//!   see the near field (a leaf's neighbours within a voxel, a branch's own side), where most
//!   of a tree's occlusion is.
//! - *Rays near, the volume far* (rays cut at 2 or 4 voxels, the volume beyond): no faster than
//!   full rays on the willow (3.3–3.6 s against 5.2–5.6 s CPU), and biased (mean Δ −0.06 to
//!   +0.10; mean |Δ| 0.037–0.117).
//! - *Fewer rays, smoothed over the mesh* (each vertex averaged with its edge neighbours of
//!   normals within 25°, two passes): on the jacaranda 8 rays smoothed reach 0.0797 (0.1050
//!   raw) and 16 smoothed 0.0627, but on the oak and pine 16 smoothed read 0.0648 and 0.0764
//!   against 0.026 raw: there neighbouring vertices differ by more than the noise.
//! - *An irradiance cache* (Ward, Rubinstein and Clear 1988) over the vertices not in pieces:
//!   the first vertex of each grid cell (1/256 of the diagonal) and normal octant traced in
//!   full, the others taking the mean of the samples near them whose error estimate
//!   `|p − pᵢ|/Rᵢ + √(1 − n·nᵢ)` is under 0.3 (`Rᵢ` the harmonic mean distance of the sample's
//!   hits, at most 4 cells), weighted `1 − ε/0.3`, or traced where none is: the maple 26 % less
//!   CPU (14.0 s against 19.0) for 0.0675 against 0.0643 (biased darker, mean Δ −0.0064), the
//!   willow 5 % less at 0.0594 against 0.0590, the jacaranda 9 % less at 0.0697 against
//!   0.0695. Leaves sit among near hits (small `Rᵢ`): with the cache over every vertex, the
//!   10⁵-leaf demo's leaf corners reused a sample 334 times in 402,640. At 1/64 of the
//!   diagonal the jacaranda read 0.0783 (open samples reused by occluded vertices).
//! - *A BVH over runs of up to 4 or 8 connected triangles* instead of triangles (fewer
//!   primitives to build on): 14–21 % more CPU on the willow, and 8 % less peak memory for
//!   the bench.
//!
//! Memory. Traced, the stage is the build's peak: on the maple, 317 MB against 118 MB without
//! it, the same with 1 ray as with 16, and the same with obvhs's fast and very fast presets (measured).
//! It is the BVH's construction: the triangles (24 MB), the binary BVH (2 nodes per triangle,
//! 43 MB) and its conversion to the 8-wide tree, which keeps 7 decisions per binary node (75 MB).

use std::sync::atomic::{AtomicU64, Ordering};

use glam::{Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::Ray;
use obvhs::triangle::Triangle;
use rayon::prelude::*;
use treelod_format::{Setting, VertexRecord, pack::oct_decode};

use crate::BuildError;
use crate::rng::SplitMix64;
use crate::union_find::{find, singletons, union};

/// A ray stops once less than this share of it is left.
pub(crate) const STOP: f32 = 1.0 / 512.0;

/// Per vertex, whether a triangle uses it (bit 0) and whether a two-sided one does (bit 1).
pub(crate) fn vertex_uses(vertex_count: usize, triangles: &[AoTriangle]) -> Vec<u8> {
    let mut used = vec![0u8; vertex_count];
    for t in triangles {
        for &v in &t.v {
            used[v as usize] |= 1 | (u8::from(t.two_sided) << 1);
        }
    }
    used
}

/// The diagonal of the bounding box of the vertices that `used` marks ([`vertex_uses`]: those
/// of a triangle), and how far off the surface a ray starts (and how near a hit it ignores),
/// against self-intersection: `10⁻⁴` of the diagonal.
pub(crate) fn diagonal_and_offset(vertices: &[VertexRecord], used: &[u8]) -> (f32, f32) {
    let (lo, hi) = vertices.iter().zip(used).filter(|(_, u)| **u != 0).fold(
        (Vec3::INFINITY, Vec3::NEG_INFINITY),
        |(lo, hi), (v, _)| {
            let p = Vec3::from_array(v.position);
            (lo.min(p), hi.max(p))
        },
    );
    let diagonal = (hi - lo).length();
    (diagonal, (1e-4 * diagonal).max(1e-7))
}

/// How the rays are traced (module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AoMethod {
    /// `2 × rays` directions shared by every vertex, each traced from all vertices at once
    /// through a grid of the triangles projected along it ([`crate::parallel_rays`]); a vertex
    /// traces those on its side of its normal, about `rays` (both sides for two-sided
    /// materials). The default: against 256 rays per vertex, closer than `rays` random rays per
    /// vertex on every shared model, in less time and without the BVH's memory. A ray tests
    /// the triangles of its cell that reach past its origin until it is stopped, so the cost
    /// grows with the depth complexity; with cells no smaller than the triangles and buried
    /// leaf cards settled by half of the directions, the 10⁶-leaf demo tree (2M overlapping
    /// leaf triangles) builds in 0.46× [`AoMethod::Traced`]'s time and 0.67× its memory.
    #[default]
    Parallel,
    /// `rays` cosine-weighted rays per vertex through a BVH, each vertex its own directions; the
    /// reference of measurements (with [`AoConfig::per_vertex`] and 256 rays).
    Traced,
}

impl AoMethod {
    /// The name in settings and on the command line: `parallel`, `traced`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Parallel => "parallel",
            Self::Traced => "traced",
        }
    }
}

/// The ambient-occlusion stage's settings.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AoConfig {
    /// Rays per vertex, `1..=4096`. Default 16. With [`AoMethod::Parallel`], `2 × rays`
    /// directions shared by all vertices (a one-sided vertex traces the half on its side);
    /// against 256 rays per vertex, a mean absolute difference per vertex of 0.020 (oak) and
    /// 0.063 (maple), in 0.32 s and 4.9 s on 2 cores (module documentation). With
    /// [`AoMethod::Traced`], each vertex's own stratified rays: 0.026 (oak), 0.064 (maple), 0.009
    /// on the 10⁵-leaf demo tree; where foliage is dense, leaf cards settled by their first half
    /// of rays cost half (the 10⁶-leaf demo tree, 4M vertices, builds in 104 s, 96 s of it the
    /// rays; 169 s before; 164 s and 155 s in a later run, parallel 75 s and 64 s).
    pub rays: u32,
    /// Seed of the directions' per-vertex rotations.
    pub seed: u64,
    /// Trace all rays of every vertex, as the stage did before small flat pieces were settled
    /// by their first rays (module documentation; with [`AoMethod::Parallel`], by every other
    /// direction, [`crate::parallel_rays::vertex_occlusion`]); the reference of measurements.
    /// Default `false`.
    pub per_vertex: bool,
    /// How the rays are traced. Default [`AoMethod::Parallel`].
    pub method: AoMethod,
}

impl Default for AoConfig {
    fn default() -> Self {
        Self { rays: 16, seed: 0, per_vertex: false, method: AoMethod::Parallel }
    }
}

impl AoConfig {
    /// The largest [`Self::rays`].
    pub const MAX_RAYS: u32 = 4096;

    /// Checks the settings.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the setting out of range.
    pub fn validate(&self) -> Result<(), BuildError> {
        if !(1..=Self::MAX_RAYS).contains(&self.rays) {
            return Err(BuildError::Setting(format!("ao.rays is {}, it must be in 1..={}", self.rays, Self::MAX_RAYS)));
        }
        Ok(())
    }

    /// The settings recorded in the container (spec §7.1): `ao.rays`, `ao.seed`, `ao.method`.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        vec![
            Setting { key: "ao.rays".into(), value: self.rays.to_string() },
            Setting { key: "ao.seed".into(), value: self.seed.to_string() },
            Setting { key: "ao.method".into(), value: self.method.name().into() },
        ]
    }
}

/// A triangle as the rays see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AoTriangle {
    /// Indices into the vertices.
    pub v: [u32; 3],
    /// The opaque share of its area, `[0, 1]`: what a ray through it loses.
    pub opacity: f32,
    /// Whether its material is two-sided (its vertices gather light from both faces).
    pub two_sided: bool,
}

/// The occlusion of every vertex, `[0, 1]` (module documentation). Vertices of no triangle get 0.
/// `progress` is called with the vertices done so far and their total, now and then.
#[must_use]
pub fn vertex_occlusion(
    vertices: &[VertexRecord],
    triangles: &[AoTriangle],
    config: &AoConfig,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Vec<f32> {
    if config.method == AoMethod::Parallel {
        let directions = crate::parallel_rays::sphere_directions(2 * config.rays.max(1), config.seed);
        return crate::parallel_rays::vertex_occlusion(vertices, triangles, &directions, !config.per_vertex, progress);
    }
    let position = |i: u32| Vec3A::from_array(vertices[i as usize].position);
    let used = vertex_uses(vertices.len(), triangles);
    let (shapes, opacities): (Vec<Triangle>, Vec<f32>) = triangles
        .iter()
        .filter(|t| t.opacity > 0.0)
        .map(|t| (Triangle { v0: position(t.v[0]), v1: position(t.v[1]), v2: position(t.v[2]) }, t.opacity.min(1.0)))
        .unzip();
    if shapes.is_empty() {
        return vec![0.0; vertices.len()];
    }
    let (diagonal, offset) = diagonal_and_offset(vertices, &used);
    let groups = if config.per_vertex {
        Groups::singles(&used)
    } else {
        Groups::pieces(vertices, triangles, &used, PIECE_SIZE * diagonal)
    };
    let bvh = build_cwbvh_from_tris(&shapes, BvhBuildParams::medium_build(), &mut std::time::Duration::default());
    // The triangles in the BVH's order, so a leaf's index needs no indirection.
    let ordered: Vec<(Triangle, f32)> =
        bvh.primitive_indices.iter().map(|&i| (shapes[i as usize], opacities[i as usize])).collect();
    drop((shapes, opacities));
    let transmitted = |origin: Vec3A, direction: Vec3A| -> f32 {
        let ray = Ray::new(origin, direction, offset, f32::INFINITY);
        let mut kept = 1.0f32;
        // Every hit along the ray, in the BVH's order (a product does not depend on it, and
        // front-to-back searches, one per hit, measured twice as slow through foliage); the
        // traversal ends at the hit that leaves less than `STOP`.
        bvh.ray_traverse_miss(ray, |ray, id| {
            let (triangle, opacity) = &ordered[id];
            if triangle.intersect(ray).is_finite() {
                kept *= 1.0 - opacity;
                if kept < STOP {
                    kept = 0.0;
                    return ray.tmin; // a hit: the traversal ends here
                }
            }
            f32::INFINITY
        });
        kept
    };

    let rays = config.rays.max(1);
    // What the rays `ks` (of `rays`) of vertex `v` keep, summed, and whether every one of them
    // kept all (`Some(true)`) or nothing (`Some(false)`).
    let trace = |v: u32, ks: &mut dyn Iterator<Item = u32>| -> (f32, Option<bool>) {
        let p = Vec3A::from_array(vertices[v as usize].position);
        let normal = Vec3A::from_array(oct_decode(vertices[v as usize].normal));
        let (tangent, bitangent) = normal.any_orthonormal_pair();
        let two_sided = used[v as usize] & 2 != 0;
        let seed = config.seed ^ u64::from(v).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let turn = SplitMix64(seed).unit();
        let (mut kept, mut alike) = (0.0f32, None);
        for (i, k) in ks.enumerate() {
            // Cosine-weighted: sin²θ uniform over strata (jittered by a hash of the vertex and
            // the ray), φ along a golden-angle spiral turned by the vertex's random offset.
            #[expect(clippy::cast_precision_loss, reason = "at most 4096 rays")]
            let u = (k as f32 + SplitMix64(seed.wrapping_add(u64::from(k) + 1)).unit()) / rays as f32;
            #[expect(clippy::cast_precision_loss, reason = "at most 4096 rays")]
            let phi = std::f32::consts::TAU * (turn + k as f32 * 0.618_034).fract();
            let side = if two_sided && k % 2 == 1 { -normal } else { normal };
            let (sin_t, cos_t) = (u.sqrt(), (1.0 - u).max(0.0).sqrt());
            let direction = side * cos_t + (tangent * phi.cos() + bitangent * phi.sin()) * sin_t;
            let t = transmitted(p + side * offset, direction.normalize());
            kept += t;
            let all_or_nothing = if t == 1.0 { Some(true) } else { (t == 0.0).then_some(false) };
            alike = if i == 0 { all_or_nothing } else { alike.filter(|&a| Some(a) == all_or_nothing) };
        }
        (kept, alike)
    };
    // The first round of a piece's vertices: half of each one's rays, over every stratum of
    // `sin²θ` (0, 1, 4, 5, … of 16) and both sides (a quarter measured too many false "all alike").
    let first_round = |k: &u32| k % 4 < 2;

    let total = groups.vertices.len() as u64;
    // Progress about 200 times over the stage.
    let step = (total / 200).max(1);
    let done = AtomicU64::new(0);
    // Batches of groups, whose members are consecutive in `groups.vertices`.
    let batches = groups.len().div_ceil(BATCH);
    let by_slot: Vec<Vec<f32>> = (0..batches)
        .into_par_iter()
        .map(|b| {
            let range = b * BATCH..((b + 1) * BATCH).min(groups.len());
            let mut values = Vec::new();
            let mut first = [0.0f32; PIECE_VERTICES];
            for g in range {
                let members = groups.members(g);
                if members.len() > 1 && rays >= 8 {
                    // First half of every member's rays: if each of them kept all light, or each
                    // kept none, the piece is in the open or buried, and so would all its
                    // members' other rays be, nearly always.
                    let mut alike = None;
                    for (i, &v) in members.iter().enumerate() {
                        let (kept, all) = trace(v, &mut (0..rays).filter(first_round));
                        first[i] = kept;
                        alike = if i == 0 { all } else { alike.filter(|&a| Some(a) == all) };
                    }
                    if let Some(open) = alike {
                        values.extend(std::iter::repeat_n(if open { 0.0 } else { 1.0 }, members.len()));
                    } else {
                        for (i, &v) in members.iter().enumerate() {
                            let (kept, _) = trace(v, &mut (0..rays).filter(|k| !first_round(k)));
                            #[expect(clippy::cast_precision_loss, reason = "at most 4096 rays")]
                            values.push(1.0 - (first[i] + kept) / rays as f32);
                        }
                    }
                } else {
                    for &v in members {
                        let (kept, _) = trace(v, &mut (0..rays));
                        #[expect(clippy::cast_precision_loss, reason = "at most 4096 rays")]
                        values.push(1.0 - kept / rays as f32);
                    }
                }
            }
            let n = values.len() as u64;
            let before = done.fetch_add(n, Ordering::Relaxed);
            if before / step != (before + n) / step {
                progress(before + n, total);
            }
            values
        })
        .collect();
    let mut out = vec![0.0f32; vertices.len()];
    for (&v, value) in groups.vertices.iter().zip(by_slot.into_iter().flatten()) {
        out[v as usize] = value;
    }
    out
}

/// Groups per parallel task.
const BATCH: usize = 64;

/// The largest piece whose vertices share their rays, as a share of the block's diagonal.
pub(crate) const PIECE_SIZE: f32 = 1.0 / 16.0;

/// The most vertices of a piece whose vertices share their rays.
const PIECE_VERTICES: usize = 16;
/// The least cosine between a piece's first vertex normal and any other of its vertices'.
const PIECE_FLAT: f32 = 0.9;

/// The used vertices in groups that share their rays: runs of [`Self::vertices`], each group's
/// vertices ascending, the groups in the order of their first vertex.
pub(crate) struct Groups {
    /// Every used vertex once.
    pub(crate) vertices: Vec<u32>,
    /// Where each group starts in `vertices`, and the end.
    pub(crate) starts: Vec<u32>,
}

impl Groups {
    pub(crate) fn len(&self) -> usize {
        self.starts.len() - 1
    }

    pub(crate) fn members(&self, group: usize) -> &[u32] {
        &self.vertices[self.starts[group] as usize..self.starts[group + 1] as usize]
    }

    /// Every used vertex on its own.
    fn singles(used: &[u8]) -> Self {
        #[expect(clippy::cast_possible_truncation, reason = "vertex ids fit u32")]
        let vertices: Vec<u32> = (0..used.len() as u32).filter(|&v| used[v as usize] != 0).collect();
        #[expect(clippy::cast_possible_truncation, reason = "vertex ids fit u32")]
        let starts = (0..=vertices.len() as u32).collect();
        Self { vertices, starts }
    }

    /// Small flat pieces together: the vertices of a connected set of triangles (sharing vertex
    /// ids) of at most [`PIECE_VERTICES`] vertices, all used alike (one- or two-sided), with
    /// normals within [`PIECE_FLAT`] of their first's and a bounding box no more than `size`
    /// across; every other used vertex on its own.
    pub(crate) fn pieces(vertices: &[VertexRecord], triangles: &[AoTriangle], used: &[u8], size: f32) -> Self {
        // Union-find over the vertices by the triangles: a set's root is its smallest vertex
        // whatever the order of the unions.
        let mut root = singletons(vertices.len());
        for t in triangles {
            union(&mut root, t.v[0], t.v[1]);
            union(&mut root, t.v[0], t.v[2]);
        }
        let mut count = vec![0u32; vertices.len()];
        for v in 0..vertices.len() {
            #[expect(clippy::cast_possible_truncation, reason = "vertex ids fit u32")]
            let r = find(&mut root, v as u32);
            root[v] = r;
            count[r as usize] += u32::from(used[v] != 0);
        }
        let candidate = |r: u32| (2..=PIECE_VERTICES).contains(&(count[r as usize] as usize));
        // Each set of a candidate piece (by its root) and each other used vertex gets a run, in
        // the order of their first vertex; then the runs are filled in vertex order.
        let mut start = vec![u32::MAX; vertices.len()];
        let mut starts = vec![0u32];
        let mut cursor = 0u32;
        for v in (0..vertices.len()).filter(|&v| used[v] != 0) {
            let r = root[v] as usize;
            let key = if candidate(root[v]) { r } else { v };
            if start[key] == u32::MAX {
                start[key] = cursor;
                cursor += if key == r && candidate(root[v]) { count[r] } else { 1 };
                starts.push(cursor);
            }
        }
        let mut members = vec![0u32; cursor as usize];
        for v in (0..vertices.len()).filter(|&v| used[v] != 0) {
            let r = root[v] as usize;
            let key = if candidate(root[v]) { r } else { v };
            let slot = &mut start[key];
            #[expect(clippy::cast_possible_truncation, reason = "vertex ids fit u32")]
            let id = v as u32;
            members[*slot as usize] = id;
            *slot += 1;
        }
        drop((root, count, start));
        // A candidate that is not small, flat and alike is split into its vertices.
        let normal = |v: u32| Vec3::from_array(oct_decode(vertices[v as usize].normal));
        let position = |v: u32| Vec3::from_array(vertices[v as usize].position);
        let mut groups = Self { vertices: members, starts: vec![0] };
        let mut next = 0u32;
        for run in starts.windows(2) {
            let piece = &groups.vertices[run[0] as usize..run[1] as usize];
            let first = piece[0];
            let (lo, hi) = piece
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &v| (lo.min(position(v)), hi.max(position(v))));
            let shares = piece.len() == 1
                || ((hi - lo).max_element() <= size
                    && piece.iter().all(|&v| {
                        used[v as usize] == used[first as usize] && normal(v).dot(normal(first)) >= PIECE_FLAT
                    }));
            if shares {
                next += run[1] - run[0];
                groups.starts.push(next);
            } else {
                for _ in run[0]..run[1] {
                    next += 1;
                    groups.starts.push(next);
                }
            }
        }
        groups
    }
}

/// The occlusion of a triangle: the mean of its corners'.
#[must_use]
pub fn triangle_occlusion(vertex_ao: &[f32], v: [u32; 3]) -> f32 {
    v.iter().map(|&i| vertex_ao.get(i as usize).copied().unwrap_or(0.0)).sum::<f32>() / 3.0
}

/// The weighted mean of `(occlusion, weight)` pairs; 0 if the weights sum to 0.
#[must_use]
pub fn mean_occlusion(items: impl IntoIterator<Item = (f32, f32)>) -> f32 {
    let (sum, weight) = items
        .into_iter()
        .fold((0.0f64, 0.0f64), |(s, w), (ao, weight)| (s + f64::from(ao) * f64::from(weight), w + f64::from(weight)));
    #[expect(clippy::cast_possible_truncation, reason = "a mean of values in [0, 1]")]
    let mean = if weight > 0.0 { (sum / weight) as f32 } else { 0.0 };
    mean
}

/// The occlusion of a cluster of leaves as it is seen from outside: the mean of `(occlusion,
/// area)` pairs weighted by area times `1 − occlusion`, the share of the directions about a leaf
/// that leave the block (the rays of its occlusion), which is the chance that a view from outside
/// along a random direction reaches it. An impostor plane stands for a whole cluster, the inner
/// leaves with the outer ones, but a view of the cluster sees mostly its outer, open leaves: the
/// plain area-weighted mean made the shared oak's impostor trees 3.8 % darker than the full mesh
/// in mean luminance at its default framing (0.9 % without ambient occlusion). 0 if the weights
/// sum to 0; 1 where every leaf of some area is wholly occluded (what the plain mean gives).
#[must_use]
pub fn seen_occlusion(items: &[(f32, f32)]) -> f32 {
    let closed = items.iter().any(|&(_, area)| area > 0.0) && items.iter().all(|&(ao, area)| area <= 0.0 || ao >= 1.0);
    if closed {
        return 1.0;
    }
    mean_occlusion(items.iter().map(|&(ao, area)| (ao, area * (1.0 - ao.clamp(0.0, 1.0)))))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::{AoConfig, AoMethod, AoTriangle, Groups, seen_occlusion, vertex_occlusion};

    /// The default (parallel rays) and the traced method, 16 rays.
    const METHODS: [AoMethod; 2] = [AoMethod::Parallel, AoMethod::Traced];

    fn with(method: AoMethod) -> AoConfig {
        AoConfig { method, ..AoConfig::default() }
    }

    /// A cluster seen from outside shows its open leaves: the mean weights each leaf by the share
    /// of directions that leave it; equal occlusions give that occlusion; all closed gives 1.
    #[test]
    fn a_cluster_seen_from_outside_reads_its_open_leaves() {
        // An open leaf (0.2) and a buried one (0.8) of equal area: weights 0.8 and 0.2.
        let seen = seen_occlusion(&[(0.2, 1.0), (0.8, 1.0)]);
        assert!((seen - (0.2 * 0.8 + 0.8 * 0.2) / 1.0).abs() < 1e-6, "{seen}");
        assert!(seen < super::mean_occlusion([(0.2, 1.0), (0.8, 1.0)]), "brighter than the plain mean 0.5");
        assert!((seen_occlusion(&[(0.4, 2.0), (0.4, 1.0)]) - 0.4).abs() < 1e-6);
        assert_eq!(seen_occlusion(&[(1.0, 1.0), (1.0, 3.0)]), 1.0);
        assert_eq!(seen_occlusion(&[]), 0.0);
        assert_eq!(seen_occlusion(&[(0.5, 0.0)]), 0.0, "no area, no weight");
    }
    use glam::Vec3;
    use treelod_format::{VertexRecord, pack::oct_encode};

    pub(crate) fn vertex(p: [f32; 3], n: [f32; 3]) -> VertexRecord {
        VertexRecord { position: p, normal: oct_encode(n), uv: [0.0; 2], color: u32::MAX }
    }

    /// A small upward-facing triangle at `y`, its vertices appended to `vertices`.
    fn patch(vertices: &mut Vec<VertexRecord>, y: f32, two_sided: bool) -> AoTriangle {
        #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
        let first = vertices.len() as u32;
        for p in [[-0.1, y, -0.1], [0.1, y, -0.1], [0.0, y, 0.1]] {
            vertices.push(vertex(p, [0.0, 1.0, 0.0]));
        }
        AoTriangle { v: [first, first + 2, first + 1], opacity: 1.0, two_sided }
    }

    /// The 12 triangles of a closed box of half-size `h` about the origin, normals outwards.
    fn closed_box(vertices: &mut Vec<VertexRecord>, h: f32, opacity: f32) -> Vec<AoTriangle> {
        let mut triangles = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let n = Vec3::from_array(std::array::from_fn(|i| if i == axis { sign } else { 0.0 }));
                let (t, b) = n.any_orthonormal_pair();
                #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
                let first = vertices.len() as u32;
                for (s, r) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    vertices.push(vertex((n * h + t * s * h + b * r * h).to_array(), n.to_array()));
                }
                for v in [[first, first + 1, first + 2], [first, first + 2, first + 3]] {
                    triangles.push(AoTriangle { v, opacity, two_sided: false });
                }
            }
        }
        triangles
    }

    #[test]
    fn a_triangle_inside_a_closed_box_is_fully_occluded_and_one_outside_is_not() {
        let mut vertices = Vec::new();
        let mut triangles = closed_box(&mut vertices, 1.0, 1.0);
        let inside = patch(&mut vertices, 0.0, true);
        let outside = patch(&mut vertices, 3.0, false);
        triangles.extend([inside, outside]);
        for method in METHODS {
            let ao = vertex_occlusion(&vertices, &triangles, &with(method), &|_, _| {});
            for v in inside.v {
                assert!((ao[v as usize] - 1.0).abs() < 1e-6, "{method:?}, inside the box: {}", ao[v as usize]);
            }
            for v in outside.v {
                assert!(ao[v as usize] < 1e-6, "{method:?}, above the box, facing away: {}", ao[v as usize]);
            }
            // The box's own outer faces see nothing but sky (their rays leave it).
            assert!(ao[0] < 1e-6, "{method:?}: {}", ao[0]);
        }
    }

    #[test]
    fn a_half_transparent_box_lets_half_through_and_a_floor_occludes_half_of_a_two_sided_leaf() {
        let mut vertices = Vec::new();
        let mut triangles = closed_box(&mut vertices, 1.0, 0.5);
        let inside = patch(&mut vertices, 0.0, false);
        triangles.push(inside);
        for method in METHODS {
            let ao = vertex_occlusion(&vertices, &triangles, &with(method), &|_, _| {});
            // Every ray crosses exactly one wall.
            assert!((ao[inside.v[0] as usize] - 0.5).abs() < 1e-3, "{method:?}: {}", ao[inside.v[0] as usize]);
        }

        // A two-sided leaf just above a wide opaque floor: its lower hemisphere is blocked.
        let mut vertices = Vec::new();
        let leaf = patch(&mut vertices, 0.5, true);
        let first = 3;
        for p in [[-100.0, 0.0, -100.0], [100.0, 0.0, -100.0], [100.0, 0.0, 100.0], [-100.0, 0.0, 100.0]] {
            vertices.push(vertex(p, [0.0, 1.0, 0.0]));
        }
        let floor = [[first, first + 2, first + 1], [first, first + 3, first + 2]].map(|v| AoTriangle {
            v,
            opacity: 1.0,
            two_sided: false,
        });
        let mut triangles = vec![leaf];
        triangles.extend(floor);
        let one_sided = [AoTriangle { two_sided: false, ..leaf }, floor[0], floor[1]];
        for method in METHODS {
            let ao = vertex_occlusion(&vertices, &triangles, &with(method), &|_, _| {});
            let a = ao[leaf.v[0] as usize];
            assert!((a - 0.5).abs() < 0.02, "{method:?}, two-sided leaf over a floor: {a}");
            // One-sided and facing up, the same leaf is open.
            assert!(vertex_occlusion(&vertices, &one_sided, &with(method), &|_, _| {})[0] < 1e-6);
        }
    }

    #[test]
    fn the_result_does_not_depend_on_the_thread_count() {
        let mut vertices = Vec::new();
        let mut triangles = closed_box(&mut vertices, 1.0, 0.3);
        for k in 0..40 {
            #[expect(clippy::cast_precision_loss, reason = "test sizes")]
            let y = -0.9 + 0.045 * k as f32;
            triangles.push(patch(&mut vertices, y, k % 2 == 0));
        }
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
        for method in METHODS {
            let config = AoConfig { rays: 16, seed: 7, method, ..AoConfig::default() };
            let a = one.install(|| vertex_occlusion(&vertices, &triangles, &config, &|_, _| {}));
            let b = four.install(|| vertex_occlusion(&vertices, &triangles, &config, &|_, _| {}));
            assert_eq!(
                a.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                b.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                "{method:?}"
            );
            // Stacked leaves shade each other: the middle of the stack is darker than its top.
            assert!(a[triangles[12 + 20].v[0] as usize] > a[triangles[12 + 39].v[0] as usize], "{method:?}");
        }
    }

    /// A square card of half-size `h` at `centre` facing up: 4 vertices, 2 triangles.
    pub(crate) fn card(vertices: &mut Vec<VertexRecord>, centre: Vec3, h: f32, two_sided: bool) -> [AoTriangle; 2] {
        #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
        let first = vertices.len() as u32;
        for (x, z) in [(-h, -h), (h, -h), (h, h), (-h, h)] {
            vertices.push(vertex((centre + Vec3::new(x, 0.0, z)).to_array(), [0.0, 1.0, 0.0]));
        }
        [[first, first + 2, first + 1], [first, first + 3, first + 2]].map(|v| AoTriangle {
            v,
            opacity: 0.7,
            two_sided,
        })
    }

    /// A canopy of `n` small semi-transparent two-sided cards stacked in a column of layers, and
    /// a large opaque floor below them.
    fn canopy(n: u32) -> (Vec<VertexRecord>, Vec<AoTriangle>) {
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        let mut rng = crate::rng::SplitMix64(3);
        for _ in 0..n {
            let centre = Vec3::new(rng.range(-1.0, 1.0), rng.range(0.5, 2.5), rng.range(-1.0, 1.0));
            triangles.extend(card(&mut vertices, centre, 0.04, true));
        }
        let floor = card(&mut vertices, Vec3::ZERO, 3.0, false).map(|t| AoTriangle { opacity: 1.0, ..t });
        triangles.extend(floor);
        (vertices, triangles)
    }

    #[test]
    fn a_small_flat_card_is_one_piece_and_a_large_or_bent_one_is_not() {
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        triangles.extend(card(&mut vertices, Vec3::ZERO, 0.05, true)); // 0..4: a piece
        triangles.extend(card(&mut vertices, Vec3::X, 2.0, true)); // 4..8: too large
        let bent = card(&mut vertices, Vec3::Z, 0.05, true); // 8..12: one corner bent up
        vertices[10] = vertex(vertices[10].position, [0.0, 0.0, 1.0]);
        triangles.extend(bent);
        let mixed = card(&mut vertices, -Vec3::Z, 0.05, true); // 12..16: one- and two-sided
        triangles.extend([mixed[0], AoTriangle { two_sided: false, ..mixed[1] }]);
        vertices.push(vertex([5.0; 3], [0.0, 1.0, 0.0])); // 16: used by no triangle
        let used = super::vertex_uses(vertices.len(), &triangles);
        let groups = Groups::pieces(&vertices, &triangles, &used, 0.5);
        let all: Vec<&[u32]> = (0..groups.len()).map(|g| groups.members(g)).collect();
        assert_eq!(all[0], &[0, 1, 2, 3]);
        assert_eq!(all.len(), 1 + 12, "{all:?}");
        assert!(all[1..].iter().all(|g| g.len() == 1));
        let singles = Groups::singles(&used);
        assert_eq!(singles.len(), 16);
    }

    #[test]
    fn a_card_is_settled_by_its_first_rays_only_when_they_all_agree() {
        let (mut vertices, mut triangles) = canopy(40);
        // A card inside a small closed box, and one high above everything.
        #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
        let inside = vertices.len() as u32;
        let mut enclosed = Vec::new();
        let shell = closed_box(&mut enclosed, 0.3, 1.0);
        let shell_card = card(&mut enclosed, Vec3::ZERO, 0.04, true);
        let above = card(&mut enclosed, Vec3::new(0.0, 9.0, 0.0), 0.04, false);
        let shifted = |t: AoTriangle| AoTriangle { v: t.v.map(|v| v + inside), ..t };
        vertices.extend(enclosed);
        triangles.extend(shell.into_iter().chain(shell_card).chain(above).map(shifted));
        let shared = vertex_occlusion(&vertices, &triangles, &with(AoMethod::Traced), &|_, _| {});
        let alone = AoConfig { per_vertex: true, ..with(AoMethod::Traced) };
        let alone = vertex_occlusion(&vertices, &triangles, &alone, &|_, _| {});
        let (buried, open) = (inside as usize + 24, inside as usize + 28);
        assert_eq!(&shared[buried..buried + 4], &[1.0; 4], "a card inside a closed opaque box");
        assert_eq!(&shared[open..open + 4], &[0.0; 4], "a one-sided card facing the open sky");
        // Each canopy card: settled whole (all its first rays stopped, or all left untouched), or
        // each corner gets what it gets on its own.
        let mut settled = 0;
        for card in 0..40 {
            let (s, a) = (&shared[4 * card..4 * card + 4], &alone[4 * card..4 * card + 4]);
            if s.iter().all(|&x| x == 1.0) || s.iter().all(|&x| x == 0.0) {
                settled += 1;
            } else {
                assert!(s.iter().zip(a).all(|(x, y)| (x - y).abs() < 1e-5), "card {card}: {s:?} alone {a:?}");
            }
        }
        assert!(settled < 40, "the canopy's cards are partly lit");
    }

    #[test]
    fn the_stage_is_as_close_to_a_256_ray_reference_as_every_vertex_on_its_own() {
        let (vertices, triangles) = canopy(300);
        let reference = AoConfig { rays: 256, seed: 99, per_vertex: true, method: AoMethod::Traced };
        let reference = vertex_occlusion(&vertices, &triangles, &reference, &|_, _| {});
        let error = |config: &AoConfig| {
            let ao = vertex_occlusion(&vertices, &triangles, config, &|_, _| {});
            ao.iter().zip(&reference).map(|(a, b)| (a - b).abs()).sum::<f32>() / ao.len() as f32
        };
        let per_vertex = error(&AoConfig { per_vertex: true, ..with(AoMethod::Traced) });
        let shared = error(&with(AoMethod::Traced));
        let parallel = error(&AoConfig::default());
        assert!(per_vertex < 0.08, "16 rays per vertex: mean |Δ| {per_vertex}");
        assert!(shared <= per_vertex * 1.1, "pieces settled: mean |Δ| {shared}, per vertex {per_vertex}");
        assert!(parallel <= per_vertex, "parallel rays (default): mean |Δ| {parallel}, per vertex {per_vertex}");
        // Not biased: the mean difference is well under the mean absolute difference.
        let ao = vertex_occlusion(&vertices, &triangles, &AoConfig::default(), &|_, _| {});
        let bias = ao.iter().zip(&reference).map(|(a, b)| a - b).sum::<f32>() / ao.len() as f32;
        assert!(bias.abs() < parallel / 4.0, "parallel rays: mean Δ {bias}, mean |Δ| {parallel}");
        // The canopy is darker below than above, and the floor under it darker than its rim.
        assert!(reference.iter().any(|&a| a > 0.2));
    }

    #[test]
    fn progress_reaches_the_total() {
        let (vertices, triangles) = canopy(100);
        for method in METHODS {
            let last = std::sync::Mutex::new((0, 0));
            let _ = vertex_occlusion(&vertices, &triangles, &with(method), &|done, total| {
                let mut last = last.lock().unwrap();
                assert!(done <= total);
                last.0 = last.0.max(done);
                last.1 = total;
            });
            let (done, total) = *last.lock().unwrap();
            assert_eq!((done, total), (vertices.len() as u64, vertices.len() as u64), "{method:?}");
        }
    }

    #[test]
    fn settings_out_of_range_are_refused() {
        assert!(AoConfig { rays: 0, ..AoConfig::default() }.validate().is_err());
        assert!(AoConfig { rays: 4097, ..AoConfig::default() }.validate().is_err());
        assert!(AoConfig::default().validate().is_ok());
    }
}
