//! Ambient occlusion by parallel rays: a fixed set of directions, each traced from every vertex
//! at once through a grid of the triangles projected along it (spec §6.14).
//!
//! Rays that share a direction are parallel, so the plane across that direction is a perfect
//! acceleration structure for all of them: each triangle is projected onto it and listed in the
//! cells of a square grid that its projection's bounding box covers, each cell's list sorted by
//! how far along the direction the triangle reaches; a vertex's ray tests only the triangles of
//! its own cell that reach past its origin, nearest first, and stops where less than 1/512 of it
//! is left. A test is the ray's own: the origin's projection inside the projected triangle, and
//! the triangle's plane there beyond the origin. What a ray keeps is therefore what a ray traced
//! through a BVH keeps ([`crate::ambient`]); only the directions differ: the same `D` for every
//! vertex (a Fibonacci sphere turned by the seed), each weighted by its cosine to the vertex
//! normal on the side it faces (both sides of two-sided materials).
//!
//! Per direction the rays are sorted by their cell, so that a cell's list is read once for all
//! the rays that start in it, and traced in parallel; each vertex adds what its ray keeps to its
//! sums in the order of the directions, so the result does not depend on the thread count.
//! Memory is one direction's grid at a time: on the 669k-triangle maple about 90 MB besides the
//! build's arrays (the triangles' planes, their lists, the rays), against the BVH's 200 MB: the
//! build peaks at 209 MB against 319 MB traced.
//! Where the time goes on the maple (32 directions, 2 cores, about 0.28 s a direction): the grid
//! 0.10 s (sorting the triangles by reach, listing them), the rays 0.13 s, of which reading the
//! triangles' planes is the largest part (a cell holds about 20 triangles, of which a ray meets
//! 2). Cells of a sixteenth to one per triangle cost the same within 10 %: finer cells cut the
//! tests but list each triangle in more cells.

use glam::{Vec2, Vec3, Vec3A};
use rayon::prelude::*;
use treelod_format::{VertexRecord, pack::oct_decode};

use crate::ambient::{AoTriangle, STOP, diagonal_and_offset, vertex_uses};
use crate::rng::SplitMix64;

/// `n` directions spread evenly over the sphere (a Fibonacci lattice), turned by a rotation
/// drawn from `seed`.
#[must_use]
pub fn sphere_directions(n: u32, seed: u64) -> Vec<Vec3A> {
    let mut rng = SplitMix64(seed);
    let axis = {
        let (z, phi) = (rng.range(-1.0, 1.0), rng.range(0.0, std::f32::consts::TAU));
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    };
    let turn = glam::Quat::from_axis_angle(axis, rng.range(0.0, std::f32::consts::TAU));
    #[expect(clippy::cast_precision_loss, reason = "at most a few thousand directions")]
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f32 + 1.0) / n as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = i as f32 * 2.399_963_2;
            Vec3A::from(turn * Vec3::new(r * phi.cos(), r * phi.sin(), z))
        })
        .collect()
}

/// Cells of a direction's grid per triangle (module documentation).
const CELLS_PER_TRIANGLE: f32 = 0.125;

/// The occlusion of every vertex, `[0, 1]`, along `directions` (module documentation). Vertices
/// of no triangle get 0. `progress` is called after each direction with the vertices' share of
/// the work done and their count.
#[must_use]
pub fn vertex_occlusion(
    vertices: &[VertexRecord],
    triangles: &[AoTriangle],
    directions: &[Vec3A],
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Vec<f32> {
    if !triangles.iter().any(|t| t.opacity > 0.0) {
        return vec![0.0; vertices.len()];
    }
    let used = vertex_uses(vertices.len(), triangles);
    let position = |v: usize| Vec3A::from_array(vertices[v].position);
    let normals: Vec<Vec3> = vertices.iter().map(|v| Vec3::from_array(oct_decode(v.normal))).collect();
    let (_, offset) = diagonal_and_offset(vertices);
    // Per vertex, the weighted sum of what its rays keep and the sum of the weights.
    let mut sums = vec![(0.0f32, 0.0f32); vertices.len()];
    let mut projected = vec![Vec3::ZERO; vertices.len()];
    let total = vertices.len() as u64;
    for (k, &d) in directions.iter().enumerate() {
        let (u, w) = d.any_orthonormal_pair();
        projected.par_iter_mut().zip(vertices).for_each(|(q, v)| {
            let p = Vec3A::from_array(v.position);
            *q = Vec3::new(p.dot(u), p.dot(w), p.dot(d));
        });
        let grid = Grid::new(&projected, triangles);
        // The rays in the order of their cells (then vertex), so that a cell's list is read
        // once for all of its rays.
        let ray = |v: usize| -> Option<(f32, Vec3)> {
            if used[v] == 0 {
                return None;
            }
            let normal = Vec3A::from(normals[v]);
            let c = normal.dot(d);
            let weight = if used[v] & 2 != 0 { c.abs() } else { c.max(0.0) };
            if weight <= 0.0 {
                return None;
            }
            let side = if c >= 0.0 { normal } else { -normal };
            let origin = position(v) + side * offset;
            Some((weight, Vec3::new(origin.dot(u), origin.dot(w), origin.dot(d) + offset)))
        };
        let mut rays: Vec<u64> = (0..vertices.len())
            .into_par_iter()
            .filter_map(|v| ray(v).map(|(_, origin)| (u64::from(grid.cell(origin)) << 32) | v as u64))
            .collect();
        rays.par_sort_unstable();
        // Per ray, its weight times what it keeps, and its weight (every listed vertex has a ray).
        #[expect(clippy::cast_possible_truncation, reason = "the low half is the vertex id")]
        let weighted: Vec<(f32, f32)> = rays
            .par_iter()
            .map(|&key| ray((key as u32) as usize).map_or((0.0, 0.0), |(w, origin)| (w * grid.transmitted(origin), w)))
            .collect();
        for (&key, (kept, weight)) in rays.iter().zip(weighted) {
            #[expect(clippy::cast_possible_truncation, reason = "the low half is the vertex id")]
            let sum = &mut sums[(key as u32) as usize];
            sum.0 += kept;
            sum.1 += weight;
        }
        progress(total * (k as u64 + 1) / directions.len() as u64, total);
    }
    sums.iter().map(|&(kept, weight)| if weight > 0.0 { (1.0 - kept / weight).clamp(0.0, 1.0) } else { 0.0 }).collect()
}

/// The triangles projected along one direction, listed per cell of a square grid.
struct Grid {
    origin: Vec2,
    inverse_cell: f32,
    width: usize,
    height: usize,
    /// Where each cell's entries start in `entries`, and the end.
    starts: Vec<u32>,
    /// Per cell, `(reach, triangle)`: how far along the direction the triangle reaches (its
    /// largest corner depth) and its position in `planes`, ascending.
    entries: Vec<(f32, u32)>,
    /// The triangles' planes, in the order of their reach.
    planes: Vec<Plane>,
}

impl Grid {
    /// The grid of the `triangles` that stop any light, projected as `projected`.
    fn new(projected: &[Vec3], triangles: &[AoTriangle]) -> Self {
        let (lo, hi) = projected
            .iter()
            .fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| (lo.min(p.truncate()), hi.max(p.truncate())));
        let extent = (hi - lo).max(Vec2::splat(1e-6));
        #[expect(clippy::cast_precision_loss, reason = "a cell count estimate")]
        let cells = (triangles.len() as f32 * CELLS_PER_TRIANGLE).clamp(1.0, 16.0e6);
        let cell = (extent.x * extent.y / cells).sqrt().max(extent.max_element() / 4096.0);
        let inverse_cell = 1.0 / cell;
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "at most 4097 cells a side")]
        let (width, height) = ((extent.x * inverse_cell) as usize + 1, (extent.y * inverse_cell) as usize + 1);
        let cell_of = |x: f32, max: usize| {
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped")]
            let c = (x * inverse_cell).max(0.0) as usize;
            c.min(max - 1)
        };
        let range = |t: &[u32; 3]| {
            let [a, b, c] = t.map(|i| projected[i as usize]);
            let (lo_t, hi_t) = (a.min(b).min(c).truncate() - lo, a.max(b).max(c).truncate() - lo);
            #[expect(clippy::cast_possible_truncation, reason = "at most 4097 cells a side")]
            let r = [cell_of(lo_t.x, width), cell_of(hi_t.x, width), cell_of(lo_t.y, height), cell_of(hi_t.y, height)]
                .map(|c| c as u16);
            r
        };
        // The triangles by reach (then id: a total order), so that filling the cells in this
        // order leaves every cell's list sorted.
        #[expect(clippy::cast_possible_truncation, reason = "triangle ids fit u32")]
        let mut order: Vec<(f32, u32, [u16; 4])> = triangles
            .par_iter()
            .enumerate()
            .filter(|(_, t)| t.opacity > 0.0)
            .map(|(id, AoTriangle { v: t, .. })| {
                let reach = t.iter().map(|&i| projected[i as usize].z).fold(f32::NEG_INFINITY, f32::max);
                (reach, id as u32, range(t))
            })
            .collect();
        order.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        // Counted and filled in chunks of the order, each chunk's entries of a cell after the
        // previous chunk's: the lists do not depend on the chunks. Each chunk counts into a
        // histogram of every cell, so there are at most 8 of them whatever the thread count.
        let chunk = order.len().div_ceil((rayon::current_num_threads() * 2).clamp(1, 8)).max(1);
        let cells_of = |r: [u16; 4]| {
            (usize::from(r[2])..=usize::from(r[3]))
                .flat_map(move |y| (usize::from(r[0])..=usize::from(r[1])).map(move |x| y * width + x))
        };
        let mut counts: Vec<Vec<u32>> = order
            .par_chunks(chunk)
            .map(|part| {
                let mut count = vec![0u32; width * height];
                for e in part {
                    for c in cells_of(e.2) {
                        count[c] += 1;
                    }
                }
                count
            })
            .collect();
        let mut starts = vec![0u32; width * height + 1];
        let mut total = 0u32;
        for c in 0..width * height {
            starts[c] = total;
            for count in &mut counts {
                let n = count[c];
                count[c] = total;
                total += n;
            }
        }
        starts[width * height] = total;
        // The triangles' planes in the order of their reach.
        let planes: Vec<Plane> = order
            .par_iter()
            .map(|e| {
                let t = &triangles[e.1 as usize];
                Plane::new(t.v.map(|i| projected[i as usize]), t.opacity.min(1.0))
            })
            .collect();
        let mut entries = vec![(0.0f32, 0u32); total as usize];
        let shared = SharedSlice(entries.as_mut_ptr());
        order.par_chunks(chunk).zip(counts.par_iter_mut()).enumerate().for_each(|(k, (part, next))| {
            for (i, e) in part.iter().enumerate() {
                #[expect(clippy::cast_possible_truncation, reason = "triangle counts fit u32")]
                let position = (k * chunk + i) as u32;
                for c in cells_of(e.2) {
                    // SAFETY: the chunks' slots of a cell are disjoint ranges (prefix sums above),
                    // each written once, all inside `entries`.
                    unsafe { shared.write(next[c] as usize, (e.0, position)) };
                    next[c] += 1;
                }
            }
        });
        Self { origin: lo, inverse_cell, width, height, starts, entries, planes }
    }

    /// The cell of a projected point; past the last cell for a point outside the grid.
    fn cell(&self, origin: Vec3) -> u32 {
        let q = origin.truncate() - self.origin;
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "checked")]
        let (x, y) = ((q.x * self.inverse_cell) as usize, (q.y * self.inverse_cell) as usize);
        if q.x < 0.0 || q.y < 0.0 || x >= self.width || y >= self.height {
            return u32::MAX;
        }
        #[expect(clippy::cast_possible_truncation, reason = "at most 4097² cells")]
        let cell = (y * self.width + x) as u32;
        cell
    }

    /// What a ray from `origin` (projected: across, across, along the direction) keeps; hits
    /// nearer than its depth `origin.z` are ignored.
    fn transmitted(&self, origin: Vec3) -> f32 {
        let cell = self.cell(origin) as usize;
        if cell >= self.width * self.height {
            return 1.0;
        }
        let list = &self.entries[self.starts[cell] as usize..self.starts[cell + 1] as usize];
        let first = list.partition_point(|e| e.0 <= origin.z);
        let p = origin.truncate();
        let mut kept = 1.0f32;
        for &(_, position) in &list[first..] {
            let plane = &self.planes[position as usize];
            let s = plane.s[0] * p.x + plane.s[1] * p.y + plane.s[2];
            let t = plane.t[0] * p.x + plane.t[1] * p.y + plane.t[2];
            if !(s >= 0.0 && t >= 0.0 && s + t <= 1.0) {
                continue;
            }
            let depth = plane.z[0] * p.x + plane.z[1] * p.y + plane.z[2];
            if depth > origin.z {
                kept *= plane.clear;
                if kept < STOP {
                    return 0.0;
                }
            }
        }
        kept
    }
}

/// Entries written from several threads into disjoint slots.
#[derive(Clone, Copy)]
struct SharedSlice(*mut (f32, u32));
// SAFETY: only used to write disjoint slots (`Grid::new`).
unsafe impl Send for SharedSlice {}
// SAFETY: as above.
unsafe impl Sync for SharedSlice {}

impl SharedSlice {
    /// # Safety
    /// `i` is in bounds and no other thread writes or reads slot `i` meanwhile.
    unsafe fn write(self, i: usize, value: (f32, u32)) {
        // SAFETY: the caller's contract.
        unsafe { self.0.add(i).write(value) };
    }
}

/// A triangle projected along a direction: two of its barycentric coordinates and its depth as
/// affine functions of the point across the direction, and the share of a ray it lets through.
#[derive(Clone, Copy)]
struct Plane {
    s: [f32; 3],
    t: [f32; 3],
    z: [f32; 3],
    clear: f32,
}

impl Plane {
    fn new([a, b, c]: [Vec3; 3], opacity: f32) -> Self {
        let area = edge(a, b, c.truncate());
        if area == 0.0 || !area.is_finite() {
            // Seen edge on: no ray along the direction meets it.
            return Self { s: [0.0, 0.0, -1.0], t: [0.0; 3], z: [0.0; 3], clear: 1.0 };
        }
        let inv = 1.0 / area;
        // The barycentric coordinate of `b` is edge(c, a, p) / area, of `c` edge(a, b, p) / area.
        let affine =
            |u: Vec3, v: Vec3| [-(v.y - u.y) * inv, (v.x - u.x) * inv, ((v.y - u.y) * u.x - (v.x - u.x) * u.y) * inv];
        let s = affine(c, a);
        let t = affine(a, b);
        // depth = a.z + s (b.z - a.z) + t (c.z - a.z)
        let (db, dc) = (b.z - a.z, c.z - a.z);
        let z = [s[0] * db + t[0] * dc, s[1] * db + t[1] * dc, a.z + s[2] * db + t[2] * dc];
        Self { s, t, z, clear: 1.0 - opacity }
    }
}

/// Twice the signed area of `(a, b, p)` in the plane across the direction.
fn edge(a: Vec3, b: Vec3, p: Vec2) -> f32 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}
