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
//! Per direction the rays are ordered by their cell (a counting sort), so that a cell's list is
//! gathered once for all the rays that start in it and the rays of a cell are traced side by
//! side in memory; the cells are traced in parallel. Gathering a cell sorts its list (listed in
//! the triangles' order; tens to hundreds of them) and lays out the triangles' planes, computed
//! from the projected corners there, eight to a block, coefficient beside coefficient, so that a
//! ray tests a block's triangles at once, inside and beyond its origin, and takes its hits in the
//! list's order. The tests run four lanes at a time in SSE2 registers, with the same arithmetic
//! as one at a time, so the output is identical; alternating runs of the stage, one lane at a
//! time against four for the inside test, then for the depth too: the maple's 5.43, 5.34 and
//! 5.82 s (medians of 3, the last in a slower run where the second took 6.05 s), the
//! 3·10⁵-leaf demo's 21.7, 18.8 and 17.2 s (means of 2, the last against 20.3 s).
//!
//! Each vertex adds what its ray keeps to its sums in the order of the directions, so the result
//! does not depend on the thread count (nor on the grid: the hits and their order are the ray's
//! own).
//!
//! Memory is one direction at a time, and of it one band of the grid's rows at a time: per
//! vertex its ray's place (4 bytes) and per triangle the cells its box covers (8 bytes) for the
//! whole direction; per band its triangles' ids in its cells (4 bytes each, about 4 per
//! triangle; planes are computed where a cell is gathered) and its rays in the order of their
//! cells (24 bytes each, written there from the vertices in their order), the rows cut into
//! bands of about 16 MiB of both (`BAND_BYTES`: the maple's grids take 2 bands, the willow's and
//! smaller trees' 1, the 3·10⁵-leaf demo's 3 and the 10⁶-leaf demo's 11 or 12). Bands change
//! nothing but what is held at once: a ray's hits and their order are its own. The maple's
//! build peaked at 209 MB before the rays were laid out by cell, 319 MB with the BVH, and
//! 169.8 MB with each direction whole and the stage after the build's per-cell stage (beside
//! the points, 49 MB); run before it, 130 MB with each direction whole and 122.8 MB with bands
//! (the same bytes written).
//!
//! The arrays of a direction (the rays' cells and places, the boxes, a band's lists and rays)
//! are kept for the next one, but for the step that finds the pieces to settle, which would
//! otherwise hold them beside its own. Each was allocated afresh per direction, above the
//! allocator's mmap threshold, so the kernel mapped, zeroed and faulted in its pages every
//! time, much of it on the thread that runs the stage's serial steps while the pool waits. The
//! maple's default build, six alternating runs (2 cores, `--timings`): the stage 5.68 → 4.86 s
//! (medians; every run faster), the build 8.8 → 8.1 s, system time 1.4–2.0 → 0.7–0.9 s, peak
//! 120.5 → 121.1 MB; every shared model's container the same byte for byte (the willow's build
//! peaks 2.6 MB higher, at 48.5 MB).
//!
//! Where the time goes on the maple (32 directions, 2 cores, 0.15 s a direction): listing the
//! triangles a seventh, the rays (their cells, order and places) a quarter, tracing three fifths
//! (gathering each cell's planes and sorting them, then the tests): the cell of a ray lists 110
//! triangles on average, 57 beyond
//! its origin, because long thin bark triangles cover many cells with their bounding boxes and
//! the canopy's depth stacks them. Cells of a sixteenth to one per triangle were measured (one
//! run each): an eighth is fastest, a sixteenth about 5 %, a quarter 15 %, a half 35 % and one
//! per triangle 70 % slower (finer cells shorten the lists but list each triangle in more
//! cells). Before the rays were laid out by cell, the loads of each ray's vertex, normal and
//! sums at random were the largest cost in a profile.
//!
//! Listing a triangle only in the cells its projection meets, not every cell of its box (per
//! row of the box, the columns of the triangle's span across the row, widened by a 64th of a
//! cell), was measured and not taken: on the maple it cut the lists' entries by a fifth (1.82
//! → 1.44 million in one direction's grid), but computing the spans cost more than the shorter
//! lists saved (`benches/ao`, alternating runs: 4.46 and 4.54 s with boxes, 6.06 and 6.28 s
//! with every box spanned, 5.47 and 5.84 s with only boxes of 3 × 3 cells or more spanned
//! against 4.80 and 4.82 s).
//!
//! Tracing each of 16 axes both ways through one grid, instead of 32 directions each through
//! its own (the axes a hemisphere of the lattice: a triangle covers the same cells seen from
//! either end, so the lists, the rays' order and the planes serve two directions, against the
//! axis with the depths mirrored), was measured and not taken: on 2 cores, `benches/ao` with
//! four seeds of the directions each (`TREELOD_AO_SEEDS`), the maple's stage took 3.96–4.13 s
//! against 4.53–4.63 s (the willow 0.96–1.04 against 1.12–1.20 s, the jacaranda 0.36–0.39
//! against 0.38–0.49 s), but the error against 256 traced rays rose on four of the seven shared
//! models: maple 0.0627–0.0633 against 0.0625–0.0627, oak 0.0207–0.0210 against 0.0199–0.0205,
//! pine 0.0214–0.0216 against 0.0206–0.0209, willow 0.0533–0.0546 against 0.0527–0.0539 (the
//! orchid's, jacaranda's and Quaternius tree's within each other's spread). The stage's time
//! grows with the axes, so winning the error back with more of them would take much of the 12 %
//! saved; what makes the mirrored set worse was not isolated.
//!
//! Cells sized by the count alone suit meshes, whose triangles shrink as there are more of them;
//! leaf cards do not: the demo tree keeps its leaves' size whatever their number, and with 10⁶
//! of them each leaf triangle's box covered 149 cells (21 with 10⁵, 51 with 3·10⁵), so listing
//! them took 1.8 GB and the stage 456 s. Cells are therefore never smaller than those in which
//! the triangles' projected boxes cover 8 cells on average (`smallest_cell`). Measured
//! (`benches/ao`, 2 cores, one run each, bounds of 4, 8 and 16 against none): the 3·10⁵-leaf
//! demo 48.8 s with none, 26.6, 27.0 and 32.6 s (the traced method 38.5 s); the 10⁵-leaf demo
//! 7.5 s, 6.6, 6.9 and 7.4 s; the 10⁶-leaf demo 157 s with 4 and 143 s with 8 (whole build
//! 172 s and 629 MB, against 465 s and 1.8 GB). The shared models' boxes cover 2.5 (Quaternius)
//! to 6 (oak, willow; maple 3.8) cells at the count's size, so their grids are unchanged (with
//! 4 the oak's and willow's cells grow and their times do not change). A ray's hits and their
//! order do not depend on its cell, so the occlusion is the same, bit for bit, with any cells
//! (tested).
//!
//! Tracing one ray for the copies of a vertex (the same position and normal, bit for bit, in
//! triangles of the same sides: a mesh's seams), the others adding what it kept, was measured
//! and not taken. The occlusion is the same bit for bit (the maple's container was byte for
//! byte the same), and the maple holds 74,955 such copies among its 716,535 vertices, all of
//! them on its bark (the jacaranda 10 %, the oak 7.5 %, the others 5 % or none), but the stage
//! took as long (four alternating builds each: 4.65–5.36 s before, 4.83–5.61 s after): a bark
//! vertex's ray is stopped by the first triangle it meets, and its copy's cell is gathered for
//! its neighbours anyway, so what the copies saved the lookups of their twins cost again.
//!
//! The stage's steps timed in one build of the maple (wall clock summed over the directions, 2
//! cores; two runs): projecting the vertices and boxing the triangles 0.22–0.25 s, the rays'
//! cells and their counting sort 0.29–0.33 s, the bands' lists 0.53–0.59 s, the rays written to
//! their places 0.42–0.45 s, tracing 2.26–2.55 s, adding each ray to its vertex's sums 0.51–0.59
//! s. Two changes were measured and not taken:
//! - Adding each ray's share to its vertex's sums where it is traced (the rays carrying their
//!   vertex instead of their share; a vertex has one ray a direction, so the sums still take
//!   them in the order of the directions and the container was byte for byte the same): the
//!   random writes cost more than the pass over the vertices saved. `benches/ao` on the maple, 5
//!   alternating runs: 6.09–6.65 s against 5.68–6.31 s (CPU 11.3–12.3 against 10.3–11.4 s); in
//!   the build the stage's medians 4.52 against 4.70 s (5 alternating builds, within the noise).
//! - The vertices and triangles ordered along a Morton curve of their positions (and the
//!   triangles' centroids) before the stage, the occlusion put back in the vertices' order
//!   after: where the stage reads them in a container's written order (`benches/ao`: vertices
//!   by first use, triangles by cell and size) it ran 3.90–4.98 s against 4.53–6.29 s (7
//!   alternating runs), but in the build, which reads them in the source's order (its meshes'
//!   own), 4.69–5.10 s against 3.81–4.65 s (4 alternating builds, the reordering included): the
//!   source's order is already as local. (So `benches/ao` times the maple's stage about a fifth
//!   above what the build's stage takes.)
//!
//! A cell's gathered list leaves out the triangles that reach no farther along the direction
//! than the nearest origin of its rays: each ray skips those anyway (`transmitted` tests only
//! what reaches past its own origin), so the hits and their order are the same and so is the
//! output (every shared model's default container compared byte for byte), without their
//! planes or their place in the sort. Default builds of the maple, 5 alternating runs each (2
//! cores, `--timings`): the stage 3.80–4.03 s → 3.69–3.80 s (medians 3.84 → 3.73), the build
//! 6.23–6.50 → 6.08–6.24 s; the willow's within the runs' noise (1.15–1.23 → 1.12–1.27 s).
//!
//! Two more were measured and not taken (`benches/ao`, the maple, alternating runs on 2 cores):
//! - Each triangle's plane and reach computed once per direction (a pass over the triangles in
//!   their order, 44 bytes each) and copied where a cell is gathered, instead of computed there
//!   from its three projected corners, loaded at random, in each of the about 4 cells that list
//!   it: the same arithmetic (the outputs not compared), 3.72–3.83 s against 4.07–4.10 s (2 runs
//!   each), but the 29 MB of planes held per direction would raise the build's peak past four
//!   times the source's size (the stage peaks about 6 MB under the build's 121 MB, the source is
//!   31.6 MB); the reach alone
//!   (4 bytes a triangle, to leave out what reaches no farther than the cell's nearest origin
//!   before loading its corners) read within the runs' noise (4.66–5.65 s against 5.04–5.93 s,
//!   3 runs each).
//! - Grazing rays left out (a direction whose cosine to the normal is under 0.15 or 0.25, a
//!   fifth or a quarter of a vertex's rays and 2–6 % of their weight): the error against 256
//!   traced rays rose on every model (pine 0.0207 → 0.0214 → 0.0229, oak 0.0203 → 0.0210 →
//!   0.0224, orchid 0.0589 → 0.0602 → 0.0626, jacaranda 0.0532 → 0.0545 → 0.0566, willow 0.0536
//!   → 0.0549 → 0.0571, Quaternius tree 0.0220 → 0.0242 → 0.0275) for times within the noise.
//!
//! Decoding the vertices' normals once for all the directions (instead of in each ray's setup,
//! twice a direction) was measured and not taken: the maple's stage took as long within the
//! runs' noise (3 alternating default builds: 3.68–4.65 s against 4.01–4.38 s) and the build
//! peaked 7 MB higher (127.3–127.8 MB against 119.9–120.6, over four times the source's 31.6).
//!
//! Where foliage is dense most leaf cards are buried, and every ray they cast is stopped. With
//! 16 directions or more, the even ones are traced first (a Fibonacci lattice's every other
//! point is spread evenly too); a small flat piece of [`crate::ambient`] (a leaf card's corners)
//! whose every ray along them was stopped, or kept all, is settled (1, or 0) and traces none of
//! the odd ones, as the traced method settles a piece by its first half of rays. Measured
//! (`benches/ao`, 2 cores, one run, settled against every vertex traced): 17 % of the
//! 10⁵-leaf demo's vertices are settled (4.74 s against 4.98 s), 44 % of the 3·10⁵-leaf demo's
//! (20.1 s against 27.0 s) and 65 % of the 10⁶-leaf demo's (110 s against 143 s, before the
//! tests ran four lanes at a time; its whole build now takes 75 s and 634 MB, traced 164 s and
//! 950 MB); none of the oak's. Against 256 rays the error is unchanged on six shared models
//! and on the 10⁵-leaf demo (0.0058) and 0.0220 against 0.0215 on the Quaternius tree (traced,
//! 0.0231).
//!
//! A triangle's three corners are looked up written out, not through `array::map`, whose
//! closure was not inlined (a call per corner, in each cell a triangle is gathered for and each
//! time it is boxed): the maple's default build, five alternating runs on 2 cores, the stage
//! 3.35–4.01 s → 3.08–3.54 s (medians 3.52 → 3.22 s; every run faster), the build 5.30–6.25 →
//! 5.13–5.65 s; every shared model's default container the same bytes.

use glam::{Vec2, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use treelod_format::{VertexRecord, pack::oct_decode};

use crate::ambient::{AoTriangle, Groups, PIECE_SIZE, STOP, diagonal_and_offset, vertex_uses};
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

/// The most cells a triangle's projected bounding box covers on average: where triangles overlap
/// (dense foliage), cells of [`CELLS_PER_TRIANGLE`] would be smaller than the triangles and list
/// each in many of them (module documentation).
const MEAN_CELLS_COVERED: f64 = 8.0;

/// The bytes of lists and rays a direction holds at once: its grid's rows are taken in bands of
/// about this much (module documentation).
const BAND_BYTES: usize = 16 << 20;

/// The side of the smallest square cells in which the projected bounding boxes of the
/// `triangles` that stop any light cover at most `mean_covered` cells on average. A box `w × h`
/// laid at random on cells of side `s` covers `(w/s + 1)(h/s + 1)` of them on average, so the
/// mean over the boxes is `A/s² + B/s + 1`, with `A` their mean area and `B` their mean
/// `w + h`. Summed in fixed chunks, so the same whatever the thread count. 0 where there is
/// nothing to bound.
fn smallest_cell(projected: &[Vec3], triangles: &[AoTriangle], mean_covered: f64) -> f32 {
    let (area, sides, count) = triangles
        .par_chunks(1 << 16)
        .map(|part| {
            part.iter().filter(|t| t.opacity > 0.0).fold((0.0f64, 0.0f64, 0u64), |(area, sides, count), t| {
                let corner = |k: usize| projected[t.v[k] as usize].truncate();
                let [a, b, c] = [corner(0), corner(1), corner(2)];
                let size = a.max(b).max(c) - a.min(b).min(c);
                (area + f64::from(size.x * size.y), sides + f64::from(size.x + size.y), count + 1)
            })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0.0, 0.0, 0), |x, y| (x.0 + y.0, x.1 + y.1, x.2 + y.2));
    if count == 0 || mean_covered <= 1.0 {
        return 0.0;
    }
    #[expect(clippy::cast_precision_loss, reason = "a mean")]
    let (a, b) = (area / count as f64, sides / count as f64);
    // The positive root of a/s² + b/s + 1 = mean_covered.
    let k = mean_covered - 1.0;
    #[expect(clippy::cast_possible_truncation, reason = "a cell size")]
    let side = ((b + (b * b + 4.0 * a * k).sqrt()) / (2.0 * k)) as f32;
    side
}

/// The occlusion of every vertex, `[0, 1]`, along `directions` (module documentation). Vertices
/// of no triangle get 0. With `settle` (and at least 16 directions), the small flat pieces of
/// [`crate::ambient`] (a leaf card's corners) whose vertices' rays along every other direction
/// were all stopped, or all kept everything, get 1 (or 0) without tracing the others.
/// `progress` is called after each direction with the vertices' share of the work done and
/// their count.
#[must_use]
pub fn vertex_occlusion(
    vertices: &[VertexRecord],
    triangles: &[AoTriangle],
    directions: &[Vec3A],
    settle: bool,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Vec<f32> {
    occlusion(vertices, triangles, directions, settle, Cells::DEFAULT, progress)
}

/// How a direction's grid is cut: cells that the triangles' boxes cover at most `mean_covered`
/// times on average ([`smallest_cell`]; 0 for cells by the triangles' count alone), lists and
/// rays held in bands of rows of about `band_bytes` ([`Grid::bands`]).
#[derive(Clone, Copy)]
struct Cells {
    mean_covered: f64,
    band_bytes: usize,
}

impl Cells {
    const DEFAULT: Self = Self { mean_covered: MEAN_CELLS_COVERED, band_bytes: BAND_BYTES };
}

/// [`vertex_occlusion`] with grids cut as `cells` says.
fn occlusion(
    vertices: &[VertexRecord],
    triangles: &[AoTriangle],
    directions: &[Vec3A],
    settle: bool,
    Cells { mean_covered, band_bytes }: Cells,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Vec<f32> {
    if !triangles.iter().any(|t| t.opacity > 0.0) {
        return vec![0.0; vertices.len()];
    }
    let mut used = vertex_uses(vertices.len(), triangles);
    let (diagonal, offset) = diagonal_and_offset(vertices, &used);
    // Settling traces every other direction first (evenly spread over the sphere too), then,
    // for the pieces not settled by them, the rest.
    let settle = settle && directions.len() >= SETTLE_DIRECTIONS;
    let order: Vec<usize> = if settle {
        (0..directions.len()).step_by(2).chain((1..directions.len()).step_by(2)).collect()
    } else {
        (0..directions.len()).collect()
    };
    // Per vertex, the weighted sum of what its rays keep and the sum of the weights.
    let mut sums = vec![(0.0f32, 0.0f32); vertices.len()];
    // Per vertex, over the first half of the directions, whether any of its rays was traced
    // (`TRACED`), kept less than all (`DIMMED`), kept anything (`LIT`); then whether its piece
    // was settled in the open (`OPEN`) or buried (`BURIED`).
    let mut seen = vec![0u8; vertices.len()];
    let half = directions.len().div_ceil(2);
    let mut projected = vec![Vec3::ZERO; vertices.len()];
    // The arrays of a direction, kept for the next: allocated once, not mapped afresh (and
    // faulted in page by page) for each of the directions.
    let mut scratch = Scratch::default();
    let total = vertices.len() as u64;
    for (done, &k) in order.iter().enumerate() {
        if settle && done == half {
            // The pieces only now, between two directions' grids and rays (the build's peak),
            // without the arrays kept from the last direction.
            scratch = Scratch::default();
            let groups = Groups::pieces(vertices, triangles, &used, PIECE_SIZE * diagonal);
            settle_pieces(&groups, &mut seen, &mut used);
        }
        let d = directions[k];
        let (u, w) = project(vertices, d, &mut projected);
        let grid = Grid::with_covered(&projected, triangles, mean_covered, std::mem::take(&mut scratch.covered));
        // A vertex's ray along the direction: its weight and origin (projected: across, across,
        // along), in its cell; none for a vertex that faces away or is in no triangle.
        let ray = |v: usize| -> Option<Ray> {
            if used[v] == 0 {
                return None;
            }
            let normal = Vec3A::from_array(oct_decode(vertices[v].normal));
            let c = normal.dot(d);
            let weight = if used[v] & 2 != 0 { c.abs() } else { c.max(0.0) };
            if weight <= 0.0 {
                return None;
            }
            let side = if c >= 0.0 { normal } else { -normal };
            let p = Vec3A::from_array(vertices[v].position) + side * offset;
            let origin = Vec3::new(p.dot(u), p.dot(w), p.dot(d) + offset);
            Some(Ray { cell: grid.cell(origin), weight, origin, kept: 0.0 })
        };
        // The rays' places in the order of their cells (then vertices), so that a cell's list is
        // gathered once for all of its rays, each traced with its neighbours in memory; rays
        // outside the grid last.
        let Scratch { cells, starts, rank, next, sorted, band, .. } = &mut scratch;
        (0..vertices.len()).into_par_iter().map(|v| ray(v).map_or(NO_RAY, |r| r.cell)).collect_into_vec(cells);
        by_cell_into(cells, grid.width * grid.height + 1, [starts, rank, next]);
        let (starts, rank) = (&*starts, &*rank);
        // A band of rows at a time (the rays outside the grid with the last): its triangles'
        // lists, then its rays, each written to its place from the vertices in their order (a
        // load at random waits, a store does not), traced, and added to its vertex's sums.
        let record = settle && done < half;
        for rows in grid.bands(starts, band_bytes) {
            grid.band_into(rows.clone(), band);
            let band = &*band;
            let slots = starts[rows.start * grid.width]..starts[grid.cells_end(rows.end, starts)];
            let in_band = |slot: u32| slots.contains(&slot);
            sorted.clear();
            sorted.resize(slots.len(), Ray { cell: NO_RAY, weight: 0.0, origin: Vec3::ZERO, kept: 0.0 });
            let shared = SharedSlice(sorted.as_mut_ptr());
            rank.par_iter().enumerate().filter(|(_, slot)| in_band(**slot)).for_each(|(v, &slot)| {
                if let Some(ray) = ray(v) {
                    // SAFETY: the vertices' places are distinct (by_cell_into), and those of the band's
                    // rays are inside `sorted` once its first place is taken off.
                    unsafe { shared.update((slot - slots.start) as usize, |_| ray) };
                }
            });
            sorted.par_chunk_by_mut(|a, b| a.cell == b.cell).for_each_init(Gathered::default, |gathered, group| {
                // No ray of the cell meets a triangle that reaches no farther than the nearest
                // origin among them: those are left out of its list.
                let nearest = group.iter().fold(f32::INFINITY, |z, ray| z.min(ray.origin.z));
                grid.gather(band, group[0].cell, nearest, gathered);
                for ray in group {
                    ray.kept = ray.weight * transmitted(gathered, ray.origin);
                }
            });
            // Each vertex adds its ray's share to its sums in the order of the directions (and,
            // to settle, notes in the first half what its rays kept).
            sums.par_iter_mut().zip(&mut seen).zip(rank).filter(|(_, slot)| in_band(**slot)).for_each(
                |((sum, seen), &slot)| {
                    let ray = &sorted[(slot - slots.start) as usize];
                    *sum = (sum.0 + ray.kept, sum.1 + ray.weight);
                    if record {
                        *seen |= TRACED
                            | if ray.kept < ray.weight { DIMMED } else { 0 }
                            | if ray.kept > 0.0 { LIT } else { 0 };
                    }
                },
            );
        }
        scratch.covered = grid.covered;
        progress(total * (done as u64 + 1) / directions.len() as u64, total);
    }
    sums.iter()
        .zip(&seen)
        .map(|(&(kept, weight), &settled)| {
            if settled & OPEN != 0 {
                0.0
            } else if settled & BURIED != 0 {
                1.0
            } else if weight > 0.0 {
                (1.0 - kept / weight).clamp(0.0, 1.0)
            } else {
                0.0
            }
        })
        .collect()
}

/// The fewest directions with which pieces are settled (as the traced method settles them with
/// 8 rays or more).
const SETTLE_DIRECTIONS: usize = 16;

/// Bits of a vertex's rays over the first half of the directions: one was traced; one kept less
/// than all; one kept anything. Then its piece's settling: in the open; buried.
const TRACED: u8 = 1;
const DIMMED: u8 = 2;
const LIT: u8 = 4;
const OPEN: u8 = 8;
const BURIED: u8 = 16;

/// After the first half of the directions: each piece of several vertices whose every ray so far
/// kept all (or each kept nothing) is settled in the open (or buried) for all of its vertices,
/// which trace no more.
fn settle_pieces(groups: &Groups, seen: &mut [u8], used: &mut [u8]) {
    for g in 0..groups.len() {
        let members = groups.members(g);
        if members.len() < 2 {
            continue;
        }
        let none = |bit: u8| members.iter().all(|&v| seen[v as usize] & (TRACED | bit) == TRACED);
        let settled = if none(DIMMED) {
            OPEN
        } else if none(LIT) {
            BURIED
        } else {
            continue;
        };
        for &v in members {
            seen[v as usize] |= settled;
            used[v as usize] = 0;
        }
    }
}

/// The `vertices` projected along `d`: across (along the two axes returned) and along.
fn project(vertices: &[VertexRecord], d: Vec3A, projected: &mut [Vec3]) -> (Vec3A, Vec3A) {
    let (u, w) = d.any_orthonormal_pair();
    projected.par_iter_mut().zip(vertices).for_each(|(q, v)| {
        let p = Vec3A::from_array(v.position);
        *q = Vec3::new(p.dot(u), p.dot(w), p.dot(d));
    });
    (u, w)
}

/// The cell, and the position among the sorted rays, of a vertex without a ray: after every
/// cell and the grid's outside.
const NO_RAY: u32 = u32::MAX;

/// A vertex's ray along a direction.
#[derive(Clone, Copy)]
struct Ray {
    /// Its cell in the direction's grid; [`NO_RAY`] for a vertex that traces none.
    cell: u32,
    /// Its cosine weight.
    weight: f32,
    /// Where it starts, projected: across, across, along the direction.
    origin: Vec3,
    /// Its weight times what it keeps, once traced.
    kept: f32,
}

/// The arrays of one direction that [`occlusion`] keeps for the next (their contents are each
/// direction's own).
#[derive(Default)]
struct Scratch {
    /// Per vertex, its ray's cell ([`NO_RAY`] for none).
    cells: Vec<u32>,
    /// [`by_cell_into`]'s starts: per cell, where its rays start in cell order.
    starts: Vec<u32>,
    /// [`by_cell_into`]'s places: per vertex, its ray's place in cell order.
    rank: Vec<u32>,
    /// [`by_cell_into`]'s running places: per cell, the next place to hand out.
    next: Vec<u32>,
    /// The grid's boxes ([`Grid::covered`]).
    covered: Vec<[u16; 4]>,
    /// A band's rays in the order of their cells.
    sorted: Vec<Ray>,
    /// A band's lists.
    band: Band,
}

/// [`by_cell_into`] into new vectors: `(starts, rank)`.
#[cfg(test)]
fn by_cell(cells: &[u32], buckets: usize) -> (Vec<u32>, Vec<u32>) {
    let (mut starts, mut rank) = (Vec::new(), Vec::new());
    by_cell_into(cells, buckets, [&mut starts, &mut rank, &mut Vec::new()]);
    (starts, rank)
}

/// The rays ordered by their vertices' `cells` (cells past `buckets - 1`, outside the grid, as
/// the last; [`NO_RAY`] for a vertex without one), then vertex: into `starts`, where each
/// bucket's rays start in that order (and, last, their count), and into `rank`, per vertex its
/// ray's place ([`NO_RAY`] for none); `next` holds the places taken so far. The three are
/// cleared first and their memory reused.
fn by_cell_into(cells: &[u32], buckets: usize, [starts, rank, next]: [&mut Vec<u32>; 3]) {
    let bucket = |cell: u32| (cell as usize).min(buckets - 1);
    starts.clear();
    starts.resize(buckets + 1, 0);
    for &cell in cells.iter().filter(|&&cell| cell != NO_RAY) {
        starts[bucket(cell) + 1] += 1;
    }
    for b in 0..buckets {
        starts[b + 1] += starts[b];
    }
    next.clone_from(starts);
    rank.clear();
    rank.extend(cells.iter().map(|&cell| {
        if cell == NO_RAY {
            return NO_RAY;
        }
        let slot = &mut next[bucket(cell)];
        *slot += 1;
        *slot - 1
    }));
}

/// What a ray from `origin` (projected: across, across, along the direction) keeps through its
/// cell's triangles as [`Grid::gather`] lays them out; hits nearer than its depth `origin.z` are
/// ignored. Each block's triangles are tested for the origin's projection at once; the hits are
/// then taken in the list's order.
fn transmitted(Gathered { reach, blocks, .. }: &Gathered, origin: Vec3) -> f32 {
    let first = reach.partition_point(|&r| r <= origin.z);
    let p = origin.truncate();
    let (x, y, depth) = (Vec4::splat(p.x), Vec4::splat(p.y), Vec4::splat(origin.z));
    let mut kept = 1.0f32;
    for (b, block) in blocks.iter().enumerate().skip(first / LANES) {
        // Four lanes at a time (SSE2 on x86-64): the same products and sums, in the same order,
        // as one lane at a time.
        let mut mask = 0u32;
        for half in 0..LANES / 4 {
            let lanes = half * 4..half * 4 + 4;
            let affine = |c: &[[f32; LANES]; 3]| {
                Vec4::from_slice(&c[0][lanes.clone()]) * x
                    + Vec4::from_slice(&c[1][lanes.clone()]) * y
                    + Vec4::from_slice(&c[2][lanes.clone()])
            };
            let (s, t, z) = (affine(&block.s), affine(&block.t), affine(&block.z));
            let hit = s.cmpge(Vec4::ZERO) & t.cmpge(Vec4::ZERO) & (s + t).cmple(Vec4::ONE) & z.cmpgt(depth);
            mask |= hit.bitmask() << (half * 4);
        }
        if b == first / LANES {
            mask &= !0 << (first % LANES);
        }
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            kept *= block.clear[i];
            if kept < STOP {
                return 0.0;
            }
        }
    }
    kept
}

/// Triangles tested at once by [`transmitted`].
const LANES: usize = 8;

/// [`LANES`] planes, each coefficient of them side by side.
#[derive(Clone, Copy)]
struct Block {
    s: [[f32; LANES]; 3],
    t: [[f32; LANES]; 3],
    z: [[f32; LANES]; 3],
    clear: [f32; LANES],
}

impl Block {
    /// Planes that no ray meets.
    const EMPTY: Self = Self {
        s: [[0.0; LANES], [0.0; LANES], [-1.0; LANES]],
        t: [[0.0; LANES]; 3],
        z: [[0.0; LANES]; 3],
        clear: [1.0; LANES],
    };
}

/// The triangles projected along one direction on a square grid: the cells each one's bounding
/// box covers, listed a band of rows at a time ([`Grid::band`]).
struct Grid<'a> {
    projected: &'a [Vec3],
    triangles: &'a [AoTriangle],
    origin: Vec2,
    inverse_cell: f32,
    width: usize,
    height: usize,
    /// Per triangle, the columns and rows of the cells its projection's bounding box covers,
    /// `[x0, x1, y0, y1]` inclusive (none, `x0 > x1`, for triangles that let all light through).
    covered: Vec<[u16; 4]>,
}

/// The lists of a band of a [`Grid`]'s rows.
#[derive(Default)]
struct Band {
    /// The band's first cell and the end of its cells.
    cells: std::ops::Range<usize>,
    /// Where each of its cells' entries start in `entries`, and the end.
    starts: Vec<u32>,
    /// Per cell, the triangles whose projection's bounding box meets it, ascending.
    entries: Vec<u32>,
    /// Per chunk of the triangles, its entries per cell, then where they go ([`Grid::band_into`]).
    counts: Vec<Vec<u32>>,
}

impl<'a> Grid<'a> {
    /// [`Self::with_covered`] into a new vector.
    #[cfg(test)]
    fn new(projected: &'a [Vec3], triangles: &'a [AoTriangle], mean_covered: f64) -> Self {
        Self::with_covered(projected, triangles, mean_covered, Vec::new())
    }

    /// The grid of the `triangles` that stop any light, projected as `projected`: cells of
    /// [`CELLS_PER_TRIANGLE`], or larger where the triangles would cover more than `mean_covered`
    /// of them on average ([`smallest_cell`]). Its boxes are written into `covered`'s memory
    /// (cleared first).
    fn with_covered(
        projected: &'a [Vec3],
        triangles: &'a [AoTriangle],
        mean_covered: f64,
        mut covered: Vec<[u16; 4]>,
    ) -> Self {
        let (lo, hi) = projected
            .iter()
            .fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| (lo.min(p.truncate()), hi.max(p.truncate())));
        let extent = (hi - lo).max(Vec2::splat(1e-6));
        #[expect(clippy::cast_precision_loss, reason = "a cell count estimate")]
        let cells = (triangles.len() as f32 * CELLS_PER_TRIANGLE).clamp(1.0, 16.0e6);
        let cell = (extent.x * extent.y / cells)
            .sqrt()
            .max(smallest_cell(projected, triangles, mean_covered))
            .max(extent.max_element() / 4096.0);
        let inverse_cell = 1.0 / cell;
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "at most 4097 cells a side")]
        let (width, height) = ((extent.x * inverse_cell) as usize + 1, (extent.y * inverse_cell) as usize + 1);
        let cell_of = |x: f32, max: usize| {
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped")]
            let c = (x * inverse_cell).max(0.0) as usize;
            c.min(max - 1)
        };
        triangles
            .par_iter()
            .map(|AoTriangle { v: t, opacity, .. }| {
                if *opacity <= 0.0 {
                    return [1, 0, 1, 0];
                }
                // Written out: through `map` each corner was a call (its closure not inlined).
                let [a, b, c] = [projected[t[0] as usize], projected[t[1] as usize], projected[t[2] as usize]];
                let (lo_t, hi_t) = (a.min(b).min(c).truncate() - lo, a.max(b).max(c).truncate() - lo);
                #[expect(clippy::cast_possible_truncation, reason = "at most 4097 cells a side")]
                let r =
                    [cell_of(lo_t.x, width), cell_of(hi_t.x, width), cell_of(lo_t.y, height), cell_of(hi_t.y, height)]
                        .map(|c| c as u16);
                r
            })
            .collect_into_vec(&mut covered);
        Self { projected, triangles, origin: lo, inverse_cell, width, height, covered }
    }

    /// The grid's rows in bands of about `bytes` each of lists (4 bytes an entry) and rays (a
    /// [`Ray`] each; `starts`, the rays' places by cell of [`by_cell_into`], the rays outside the
    /// grid counted in the last row), a row at least: where the rays and lists of a direction
    /// are held a band at a time, memory is the band's. Integer counts, so the same whatever the
    /// thread count.
    fn bands(&self, starts: &[u32], bytes: usize) -> Vec<std::ops::Range<usize>> {
        // Entries per row: each box adds its width to the rows it spans (a difference array).
        let mut diff = vec![0i64; self.height + 1];
        for &[x0, x1, y0, y1] in self.covered.iter().filter(|r| r[0] <= r[1]) {
            let n = i64::from(x1 - x0) + 1;
            diff[usize::from(y0)] += n;
            diff[usize::from(y1) + 1] -= n;
        }
        let mut bands = Vec::new();
        let (mut first, mut held, mut entries) = (0, 0usize, 0i64);
        for y in 0..self.height {
            entries += diff[y];
            let rays = (starts[self.cells_end(y + 1, starts)] - starts[y * self.width]) as usize;
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a count")]
            let row = 4 * entries as usize + size_of::<Ray>() * rays + 4 * self.width;
            if held > 0 && held + row > bytes {
                bands.push(first..y);
                (first, held) = (y, 0);
            }
            held += row;
        }
        bands.push(first..self.height);
        bands
    }

    /// Where the rays of the rows before `row` end in `starts` ([`by_cell_into`]'s buckets): the
    /// rays outside the grid count in the last row.
    fn cells_end(&self, row: usize, starts: &[u32]) -> usize {
        if row == self.height { starts.len() - 1 } else { row * self.width }
    }

    /// [`Self::band_into`] a new band.
    #[cfg(test)]
    fn band(&self, rows: std::ops::Range<usize>) -> Band {
        let mut band = Band::default();
        self.band_into(rows, &mut band);
        band
    }

    /// The lists of the cells of `rows`, into `band` (its memory reused): the triangles whose
    /// boxes meet each cell, in the order of the triangles. Counted and filled in chunks of the
    /// triangles, each chunk's entries of a cell after the previous chunk's, so the lists do not
    /// depend on the chunks; each chunk counts into a histogram of the band's cells, at most 8 of
    /// them whatever the thread count.
    fn band_into(&self, rows: std::ops::Range<usize>, band: &mut Band) {
        let width = self.width;
        let cells = rows.start * width..rows.end * width;
        #[expect(clippy::cast_possible_truncation, reason = "at most 4097 rows")]
        let (top, last) = (rows.start as u16, (rows.end - 1) as u16);
        let first_row = rows.start;
        let covered = &self.covered;
        let chunk = covered.len().div_ceil((rayon::current_num_threads() * 2).clamp(1, 8)).max(1);
        // A triangle's cells in the band, as indices among the band's cells (none for a box
        // across no row of it, or for one of a triangle that lets all light through).
        let cells_of = |[x0, x1, y0, y1]: [u16; 4]| {
            let (x0, x1) = (usize::from(x0), usize::from(x1));
            let ys = if x0 <= x1 { usize::from(y0.max(top))..usize::from(y1.min(last)) + 1 } else { 0..0 };
            ys.flat_map(move |y| (x0..=x1).map(move |x| (y - first_row) * width + x))
        };
        let Band { cells: band_cells, starts, entries, counts } = band;
        counts.resize_with(covered.len().div_ceil(chunk), Vec::new);
        counts.par_iter_mut().zip(covered.par_chunks(chunk)).for_each(|(count, part)| {
            count.clear();
            count.resize(cells.len(), 0);
            for &e in part.iter().filter(|e| e[2] <= last && e[3] >= top) {
                for c in cells_of(e) {
                    count[c] += 1;
                }
            }
        });
        starts.clear();
        starts.resize(cells.len() + 1, 0);
        let mut total = 0u32;
        for c in 0..cells.len() {
            starts[c] = total;
            for count in counts.iter_mut() {
                let n = count[c];
                count[c] = total;
                total += n;
            }
        }
        starts[cells.len()] = total;
        entries.clear();
        entries.resize(total as usize, 0);
        let shared = SharedSlice(entries.as_mut_ptr());
        covered.par_chunks(chunk).zip(counts.par_iter_mut()).enumerate().for_each(|(k, (part, next))| {
            for (i, &e) in part.iter().enumerate().filter(|(_, e)| e[2] <= last && e[3] >= top) {
                #[expect(clippy::cast_possible_truncation, reason = "triangle ids fit u32")]
                let id = (k * chunk + i) as u32;
                for c in cells_of(e) {
                    // SAFETY: the chunks' slots of a cell are disjoint ranges (prefix sums above),
                    // each written once, all inside `entries`.
                    unsafe { shared.update(next[c] as usize, |_| id) };
                    next[c] += 1;
                }
            }
        });
        *band_cells = cells;
    }

    /// The cell of a projected point; past the last cell for a point outside the grid.
    fn cell(&self, origin: Vec3) -> u32 {
        let q = origin.truncate() - self.origin;
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "checked")]
        let (x, y) = ((q.x * self.inverse_cell) as usize, (q.y * self.inverse_cell) as usize);
        if q.x < 0.0 || q.y < 0.0 || x >= self.width || y >= self.height {
            #[expect(clippy::cast_possible_truncation, reason = "at most 4097² cells")]
            let outside = (self.width * self.height) as u32;
            return outside;
        }
        #[expect(clippy::cast_possible_truncation, reason = "at most 4097² cells")]
        let cell = (y * self.width + x) as u32;
        cell
    }

    /// A cell's triangles that reach past `nearest` (the nearest origin of its rays, which
    /// [`transmitted`] tests against none of the others) ascending by reach (then id: a total
    /// order): their reaches and planes, gathered so that its rays read them in place; none for
    /// the outside, nor for a cell out of `band` (the band holds its rays).
    fn gather(&self, band: &Band, cell: u32, nearest: f32, scratch: &mut Gathered) {
        let Gathered { planes, keys, reach, blocks } = scratch;
        planes.clear();
        keys.clear();
        reach.clear();
        blocks.clear();
        let cell = cell as usize;
        if !band.cells.contains(&cell) {
            return;
        }
        let cell = cell - band.cells.start;
        // Listed in the order of the triangles, so a triangle's place in the list orders ties of
        // reach as its id does.
        for &id in &band.entries[band.starts[cell] as usize..band.starts[cell + 1] as usize] {
            let t = &self.triangles[id as usize];
            // Written out: through `map` each corner was a call (its closure not inlined).
            let corners =
                [self.projected[t.v[0] as usize], self.projected[t.v[1] as usize], self.projected[t.v[2] as usize]];
            let reach = corners[0].z.max(corners[1].z).max(corners[2].z);
            if reach <= nearest {
                continue;
            }
            #[expect(clippy::cast_possible_truncation, reason = "a list is shorter than the triangles")]
            keys.push(sort_key(reach, planes.len() as u32));
            planes.push(Plane::new(corners, t.opacity.min(1.0)));
        }
        keys.sort_unstable();
        reach.extend(keys.iter().map(|&key| sort_key_value(key)));
        blocks.extend(keys.chunks(LANES).map(|part| {
            let mut block = Block::EMPTY;
            for (i, &key) in part.iter().enumerate() {
                #[expect(clippy::cast_possible_truncation, reason = "the low half is the place")]
                let plane = &planes[key as u32 as usize];
                for j in 0..3 {
                    block.s[j][i] = plane.s[j];
                    block.t[j][i] = plane.t[j];
                    block.z[j][i] = plane.z[j];
                }
                block.clear[i] = plane.clear;
            }
            block
        }));
    }
}

/// A cell's triangles as its rays read them ([`Grid::gather`]).
#[derive(Default)]
struct Gathered {
    /// Their planes in the order of the list.
    planes: Vec<Plane>,
    /// Their entries ([`sort_key`], of their place in the list), ascending.
    keys: Vec<u64>,
    /// Their reaches, ascending.
    reach: Vec<f32>,
    /// Their planes in that order.
    blocks: Vec<Block>,
}

/// A key that sorts by `value` as [`f32::total_cmp`] does, then by `id`: the value's bits mapped
/// so that unsigned order is `total_cmp`'s, above the id. Sorting such keys is a plain integer
/// sort (a cell's list here by reach, then place; points along an axis in [`crate::gilet`]).
pub(crate) fn sort_key(value: f32, id: u32) -> u64 {
    let bits = value.to_bits();
    let ordered = if bits >> 31 == 1 { !bits } else { bits | 1 << 31 };
    (u64::from(ordered) << 32) | u64::from(id)
}

/// The value of a [`sort_key`].
pub(crate) fn sort_key_value(key: u64) -> f32 {
    let ordered = (key >> 32) as u32;
    f32::from_bits(if ordered >> 31 == 1 { ordered & !(1 << 31) } else { !ordered })
}

/// A slice written from several threads, each slot by one of them.
struct SharedSlice<T>(*mut T);
impl<T> Clone for SharedSlice<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SharedSlice<T> {}
// SAFETY: only used to write disjoint slots (`Grid::new`, `vertex_occlusion`).
unsafe impl<T: Send> Send for SharedSlice<T> {}
// SAFETY: as above.
unsafe impl<T: Send> Sync for SharedSlice<T> {}

impl<T> SharedSlice<T> {
    /// Replaces slot `i` by `f` of it.
    ///
    /// # Safety
    /// `i` is in bounds and no other thread writes or reads slot `i` meanwhile.
    unsafe fn update(self, i: usize, f: impl FnOnce(&T) -> T) {
        // SAFETY: the caller's contract.
        unsafe {
            let slot = self.0.add(i);
            slot.write(f(&*slot));
        }
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

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::ambient::tests::{card, vertex};

    proptest! {
        /// Entries ascend as their reaches do by `total_cmp`, then by id, and give their reach
        /// back bit for bit: a cell's sorted list is the order the rays take their hits in.
        #[test]
        fn entries_order_by_reach_then_id(a in any::<u32>(), b in any::<u32>(), i in any::<u32>(), j in any::<u32>()) {
            let (ra, rb) = (f32::from_bits(a), f32::from_bits(b));
            prop_assert_eq!(sort_key_value(sort_key(ra, i)).to_bits(), a);
            prop_assert_eq!(sort_key(ra, i).cmp(&sort_key(rb, j)), ra.total_cmp(&rb).then(i.cmp(&j)));
        }
    }

    /// `n` semi-transparent two-sided square cards of half-size `h`, facing up, in the unit
    /// cube: overlapping foliage.
    fn cards(n: u32, h: f32) -> (Vec<VertexRecord>, Vec<AoTriangle>) {
        let mut rng = SplitMix64(11);
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for _ in 0..n {
            let centre = Vec3::new(rng.range(0.0, 1.0), rng.range(0.0, 1.0), rng.range(0.0, 1.0));
            triangles.extend(card(&mut vertices, centre, h, true).map(|t| AoTriangle { opacity: 0.6, ..t }));
        }
        (vertices, triangles)
    }

    /// Cells of any size give every vertex the same occlusion, bit for bit: a ray's hits and
    /// their order are its own, whatever cell lists them. Larger cells than the triangles'
    /// count gives are taken where the triangles overlap.
    #[test]
    fn the_result_does_not_depend_on_the_cells() {
        let (vertices, triangles) = cards(1000, 0.3);
        let directions = sphere_directions(12, 5);
        let mut projected = vec![Vec3::ZERO; vertices.len()];
        project(&vertices, directions[0], &mut projected);
        let sides: Vec<f32> =
            [0.0, 8.0, 3.0, 1.5].iter().map(|&m| 1.0 / Grid::new(&projected, &triangles, m).inverse_cell).collect();
        assert!(sides.windows(2).all(|w| w[0] < w[1]), "each bound gives larger cells: {sides:?}");
        // By the count alone (a cell per 8 triangles) the overlapping cards cover more than 8
        // cells each; the default bound takes larger ones.
        assert!(sides[1] > sides[0] * 1.5, "{sides:?}");
        let run = |mean_covered, band_bytes| {
            occlusion(&vertices, &triangles, &directions, false, Cells { mean_covered, band_bytes }, &|_, _| {})
        };
        let reference = run(0.0, usize::MAX);
        assert!(reference.iter().any(|&a| a > 0.3 && a < 0.9), "partly occluded vertices");
        for mean_covered in [8.0, 3.0, 1.5] {
            let ao = run(mean_covered, usize::MAX);
            assert!(ao.iter().zip(&reference).all(|(a, b)| a.to_bits() == b.to_bits()), "{mean_covered}");
        }
        // Lists and rays a band of rows at a time, down to a row per band: the same, bit for bit.
        for band_bytes in [BAND_BYTES, 20_000, 0] {
            let ao = run(MEAN_CELLS_COVERED, band_bytes);
            assert!(ao.iter().zip(&reference).all(|(a, b)| a.to_bits() == b.to_bits()), "{band_bytes}");
        }
    }

    /// Bands hold about the bytes asked, a row at least, and cover the rows once, in order;
    /// each band's lists are the grid's: a triangle is listed in every cell of the band its box
    /// covers, in the order of the triangles.
    #[test]
    fn bands_cover_the_rows_and_list_what_the_boxes_cover() {
        let (vertices, triangles) = cards(400, 0.2);
        let mut projected = vec![Vec3::ZERO; vertices.len()];
        project(&vertices, sphere_directions(4, 1)[1], &mut projected);
        let grid = Grid::new(&projected, &triangles, MEAN_CELLS_COVERED);
        assert!(grid.height > 4, "{} rows", grid.height);
        // A ray per vertex in cell 0, as many outside the grid.
        let cells: Vec<u32> = (0..vertices.len()).map(|v| if v % 2 == 0 { 0 } else { u32::MAX - 1 }).collect();
        let (starts, _) = by_cell(&cells, grid.width * grid.height + 1);
        let whole = grid.bands(&starts, usize::MAX);
        assert_eq!(whole.len(), 1);
        assert_eq!(whole[0], 0..grid.height);
        let rows = grid.bands(&starts, 0);
        assert_eq!(rows, (0..grid.height).map(|y| y..y + 1).collect::<Vec<_>>(), "a row each");
        let some = grid.bands(&starts, 30_000);
        assert!(some.len() > 1 && some.len() < grid.height, "{some:?}");
        assert!(some.windows(2).all(|w| w[0].end == w[1].start) && some[0].start == 0);
        assert_eq!(some.last().map(|b| b.end), Some(grid.height));
        let all = grid.band(0..grid.height);
        for rows in some {
            let band = grid.band(rows.clone());
            assert_eq!(band.cells, rows.start * grid.width..rows.end * grid.width);
            for (local, cell) in band.cells.clone().enumerate() {
                let list = &band.entries[band.starts[local] as usize..band.starts[local + 1] as usize];
                assert_eq!(list, &all.entries[all.starts[cell] as usize..all.starts[cell + 1] as usize]);
                assert!(list.windows(2).all(|w| w[0] < w[1]), "in the order of the triangles");
                let (x, y) = (cell % grid.width, cell / grid.width);
                for (id, r) in grid.covered.iter().enumerate() {
                    let meets = (usize::from(r[0])..=usize::from(r[1])).contains(&x)
                        && (usize::from(r[2])..=usize::from(r[3])).contains(&y);
                    #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
                    let listed = list.contains(&(id as u32));
                    assert_eq!(meets, listed, "triangle {id} in cell {cell}");
                }
            }
        }
    }

    /// A leaf card whose rays along every other direction are stopped is settled buried without
    /// tracing the others, even though those would escape; without settling, or with fewer than
    /// 16 directions, it is traced along all of them.
    #[test]
    fn a_card_buried_along_half_of_the_directions_is_settled() {
        let directions = sphere_directions(16, 5);
        let square = |vertices: &mut Vec<VertexRecord>, centre: Vec3, normal: Vec3, h: f32| {
            let (u, w) = normal.normalize().any_orthonormal_pair();
            #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
            let first = vertices.len() as u32;
            for (a, b) in [(-h, -h), (h, -h), (h, h), (-h, h)] {
                vertices.push(vertex((centre + u * a + w * b).to_array(), normal.normalize().to_array()));
            }
            [[first, first + 1, first + 2], [first, first + 2, first + 3]]
        };
        // The card at the origin, two-sided and half transparent; an opaque square across each
        // even direction, a unit away, covering the card and no odd direction.
        let mut vertices = Vec::new();
        let card = square(&mut vertices, Vec3::ZERO, Vec3::new(0.3, 1.0, 0.2), 0.02).map(|v| AoTriangle {
            v,
            opacity: 0.5,
            two_sided: true,
        });
        let mut triangles = card.to_vec();
        for d in directions.iter().step_by(2) {
            let d = Vec3::from(*d);
            let v = square(&mut vertices, d, -d, 0.1);
            triangles.extend(v.map(|v| AoTriangle { v, opacity: 1.0, two_sided: false }));
        }
        let run = |directions: &[Vec3A], settle: bool| {
            occlusion(&vertices, &triangles, directions, settle, Cells::DEFAULT, &|_, _| {})
        };
        let (alone, settled) = (run(&directions, false), run(&directions, true));
        for v in 0..4 {
            assert!(alone[v] > 0.3 && alone[v] < 0.7, "along the odd directions it is open: {}", alone[v]);
            assert_eq!(settled[v], 1.0, "settled by the even directions");
        }
        let few = &directions[..14];
        assert_eq!(run(few, true), run(few, false));
    }

    /// Settled or not, the vertices of an overlapping canopy get their occlusion, within the
    /// order of their sums.
    #[test]
    fn settling_a_canopy_changes_only_the_order_of_its_sums() {
        let (vertices, triangles) = cards(1500, 0.3);
        let directions = sphere_directions(16, 5);
        let alone = occlusion(&vertices, &triangles, &directions, false, Cells::DEFAULT, &|_, _| {});
        let settled = occlusion(&vertices, &triangles, &directions, true, Cells::DEFAULT, &|_, _| {});
        assert!(alone.iter().zip(&settled).all(|(a, b)| (a - b).abs() < 1e-5));
        assert!(settled.iter().filter(|&&a| a == 1.0).count() > vertices.len() / 4, "most of the canopy is buried");
    }

    /// A piece is settled only when each of its vertices traced a ray and all of them agree.
    #[test]
    fn a_piece_is_settled_only_when_all_its_rays_agree() {
        // Pieces {0, 1}, {2, 3}, {4, 5}, {6, 7}, {8} and {9, 10}.
        let groups = Groups { vertices: (0..11).collect(), starts: vec![0, 2, 4, 6, 8, 9, 11] };
        let open = TRACED | LIT;
        let buried = TRACED | DIMMED;
        // Pieces: all kept everything; all kept nothing; one kept some; one traced no ray; on
        // its own; one open, one buried.
        let mut seen = [open, open, buried, buried, TRACED | DIMMED | LIT, buried, open, 0, open, open, buried];
        let mut used = [1u8; 11];
        settle_pieces(&groups, &mut seen, &mut used);
        let state = |v: usize| seen[v] & (OPEN | BURIED);
        assert_eq!((0..11).map(state).collect::<Vec<_>>(), [OPEN, OPEN, BURIED, BURIED, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(used, [0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1], "settled vertices trace no more");
    }

    /// Boxes `w × h` laid at random on cells of the side found cover the asked number of
    /// cells on average.
    #[test]
    fn the_smallest_cell_is_covered_as_often_as_asked() {
        // Right triangles with 1 × 1 and 3 × 1 bounding boxes, one transparent (left out).
        let at = |x: f32, y: f32| Vec3::new(x, y, 0.0);
        let projected = [at(0.0, 0.0), at(1.0, 0.0), at(0.0, 1.0), at(3.0, 0.0), at(20.0, 20.0)];
        let triangle = |v: [u32; 3], opacity: f32| AoTriangle { v, opacity, two_sided: false };
        let triangles = [triangle([0, 1, 2], 1.0), triangle([0, 3, 2], 0.5), triangle([0, 4, 2], 0.0)];
        for mean_covered in [1.5f64, 4.0, 9.0] {
            let side = smallest_cell(&projected, &triangles, mean_covered);
            let mut rng = SplitMix64(2);
            let samples = 20_000;
            let mut covered = 0u64;
            for _ in 0..samples {
                for (w, h) in [(1.0f32, 1.0f32), (3.0, 1.0)] {
                    let (x, y) = (rng.range(0.0, side), rng.range(0.0, side));
                    let cells = |lo: f32, len: f32| ((lo + len) / side).floor() as u64 - (lo / side).floor() as u64 + 1;
                    covered += cells(x, w) * cells(y, h);
                }
            }
            #[expect(clippy::cast_precision_loss, reason = "a mean")]
            let mean = covered as f64 / (2 * samples) as f64;
            assert!((mean - mean_covered).abs() < 0.05 * mean_covered, "{mean_covered}: {mean} at {side}");
        }
        assert_eq!(smallest_cell(&projected, &triangles[2..], 8.0), 0.0, "nothing stops light");
    }

    /// The rays ordered by cell, then vertex, outside the grid last; vertices without one get
    /// none.
    #[test]
    fn rays_by_cell_then_vertex() {
        let cells = [2, NO_RAY, 0, 7, 2, 3, 0];
        let (starts, rank) = by_cell(&cells, 5);
        assert_eq!(starts, [0, 2, 2, 4, 5, 6]);
        assert_eq!(rank, [2, NO_RAY, 0, 5, 3, 4, 1]);
    }
}
