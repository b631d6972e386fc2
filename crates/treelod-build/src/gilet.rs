//! Gilet, Meyer & Neyret 2005: the triangle + point hierarchy of one grid cell.
//!
//! Per cell: one point per triangle (centroid; equal-area radius; triangle normal; texture colour
//! integrated over the triangle), then a binary PCA clustering (split at the centroid across the
//! direction of greatest variance until a cluster holds at most [`GiletConfig::cluster_max`]
//! points) whose inner nodes average their children, with the paper's radius rule
//! `R = 2/π · (R_m + α(R_M − R_m))` made monotone for the selection size. The disc drawn is sized
//! for the area the leaves cover on screen instead: half a leaf's opaque area (the mean over view
//! directions), and for a cluster the expected union of its children's discs (overlaps counted
//! once); a cluster's selection size is never smaller than that disc's diameter. Each point also
//! records how much of that coverage faces along its normal ([`CellPoint::facing`], spec §6.5.1),
//! so that a renderer covers with a patch of a closed surface what it projects along the view.
//! The hierarchy is flattened by [`crate::spt`].

use glam::{Vec3, Vec4};

use crate::parallel_rays::{sort_key, sort_key_value};
use crate::spt::{FlattenError, flatten};

/// Tunables of the point hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct GiletConfig {
    /// A cluster with at most this many points is not split further; its points become the
    /// children of one node. Gilet uses about 5. Default 5; at least 2.
    pub cluster_max: usize,
}

impl Default for GiletConfig {
    fn default() -> Self {
        Self { cluster_max: 5 }
    }
}

/// The point of one triangle, before clustering.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafPoint {
    /// Centroid, metres.
    pub position: Vec3,
    /// Unit triangle normal.
    pub normal: Vec3,
    /// Triangle area, m².
    pub area: f32,
    /// Linear RGB of the opaque part, and in `w` the opaque fraction of the area (coverage).
    pub color: Vec4,
    /// Triangle size `2·sqrt(area/π)` (spec §2), metres.
    pub size: f32,
}

/// A node of the flattened cell hierarchy, ready to become a `PointRecord`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellPoint {
    /// Disc centre, metres.
    pub position: Vec3,
    /// Unit normal.
    pub normal: Vec3,
    /// Linear RGB and coverage.
    pub color: Vec4,
    /// Disc radius to draw: for a leaf, the disc of half its opaque area (a mostly transparent
    /// card draws less); for a cluster, the expected union of its children's discs.
    pub radius: f32,
    /// Selection size, metres (monotone).
    pub size: f32,
    /// Threshold interval.
    pub lo: f32,
    /// Threshold interval, `+∞` for the root.
    pub hi: f32,
    /// Leaf run.
    pub leaf_first: u32,
    /// Leaf run length.
    pub leaf_count: u32,
    /// How flat the represented surface is, 0 (normals spread evenly) to 1 (one plane): `2m − 1`
    /// clamped to `[0, 1]`, `m` the coverage-weighted mean `|n_i · n|` of its leaves' normals
    /// `n_i` to the point's normal `n` (1 for a leaf); spec §6.5.1.
    pub facing: f32,
}

/// The flattened hierarchy of one cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CellHierarchy {
    /// Points in SPT order (`hi` descending).
    pub points: Vec<CellPoint>,
    /// Per input leaf point (= per triangle of the cell, in input order): its leaf id.
    pub leaf_of_triangle: Vec<u32>,
}

/// Builds and flattens the point hierarchy over the leaf points of one cell.
///
/// # Errors
/// Only if the leaf points carry non-finite sizes, which the build filters out before.
pub fn build_cell(leaves: &[LeafPoint], config: &GiletConfig) -> Result<CellHierarchy, FlattenError> {
    if leaves.is_empty() {
        return Ok(CellHierarchy::default());
    }
    let cluster_max = config.cluster_max.max(2);
    // Arena: nodes 0..n are the leaf points; inner nodes are appended.
    let mut children: Vec<Vec<u32>> = vec![Vec::new(); leaves.len()];
    let mut nodes: Vec<Node> = leaves.iter().map(Node::leaf).collect();
    let mut indices: Vec<u32> = (0..leaves.len() as u32).collect();
    cluster(&mut indices, leaves, cluster_max, &mut children, &mut nodes);

    let sizes: Vec<f32> = nodes.iter().map(|n| n.size).collect();
    let spt = flatten(&children, &sizes)?;
    let points = spt
        .order
        .iter()
        .map(|&i| {
            let node = &nodes[i as usize];
            let flat = spt.nodes[i as usize];
            let is_leaf = children[i as usize].is_empty();
            CellPoint {
                position: node.position,
                normal: node.normal,
                color: node.color,
                radius: node.draw_radius,
                // Leaf points keep the triangle's size bit for bit (spec §10 rule 3).
                size: if is_leaf { leaves[i as usize].size } else { flat.size },
                lo: flat.lo,
                hi: flat.hi,
                leaf_first: flat.leaf_first,
                leaf_count: flat.leaf_count,
                facing: node.facing,
            }
        })
        .collect();
    let leaf_of_triangle = spt.leaf_id[..leaves.len()].iter().map(|id| id.unwrap_or(0)).collect();
    Ok(CellHierarchy { points, leaf_of_triangle })
}

/// Attributes of a hierarchy node.
#[derive(Clone, Copy, Debug)]
struct Node {
    position: Vec3,
    normal: Vec3,
    color: Vec4,
    /// Represented area, m² (the averaging weight).
    area: f32,
    /// Radius from full areas, for selection.
    radius: f32,
    /// Radius of the disc drawn (see [`Node::leaf`] and [`Node::merge`]).
    draw_radius: f32,
    /// Radius of the sphere about `position` holding the drawn discs of the node's leaves.
    extent: f32,
    /// `2·radius`.
    size: f32,
    /// See [`CellPoint::facing`]; set by [`cluster`] for inner nodes.
    facing: f32,
}

impl Node {
    fn leaf(p: &LeafPoint) -> Self {
        let radius = p.size * 0.5;
        Self {
            position: p.position,
            normal: p.normal,
            color: p.color,
            area: p.area,
            radius,
            draw_radius: radius * (p.color.w.clamp(0.0, 1.0) * MEAN_PROJECTED_FRACTION).sqrt(),
            extent: radius,
            size: p.size,
            facing: 1.0,
        }
    }

    /// Gilet's average of two nodes: area-weighted position, normal and colour; the radius rule
    /// `2/π · (R_m + α(R_M − R_m))` with `R_M = R_l + R_r`, `R_m = (R_l + R_r)/2`,
    /// `α = |N_l · N_r|`.
    fn merge(l: &Self, r: &Self) -> Self {
        let area = l.area + r.area;
        let (wl, wr) = if area > 0.0 { (l.area / area, r.area / area) } else { (0.5, 0.5) };
        let position = l.position * wl + r.position * wr;
        let extent = (l.position.distance(position) + l.extent).max(r.position.distance(position) + r.extent);
        let normal =
            (l.normal * wl + r.normal * wr).try_normalize().unwrap_or(if wl >= wr { l.normal } else { r.normal });
        let alpha = l.normal.dot(r.normal).abs().min(1.0);
        let rule = |a: f32, b: f32| std::f32::consts::FRAC_2_PI * (0.5 * (a + b) + alpha * 0.5 * (a + b));
        let radius = rule(l.radius, r.radius);
        // Coverage of the union is the area-weighted mean; colour of the opaque part is weighted by
        // opaque area.
        let (ol, or) = (l.area * l.color.w, r.area * r.color.w);
        let rgb = if ol + or > 0.0 {
            (l.color.truncate() * ol + r.color.truncate() * or) / (ol + or)
        } else {
            l.color.truncate() * wl + r.color.truncate() * wr
        };
        let draw_radius = union_radius(l, r, extent);
        Self {
            position,
            normal,
            color: rgb.extend(l.color.w * wl + r.color.w * wr),
            area,
            radius,
            draw_radius,
            extent,
            // Selection draws a point at most the threshold across: its drawn disc must be no
            // larger, or a cluster of small, sparse leaves (whose rule radius hardly grows up the
            // hierarchy while the union of their discs does) is drawn as one blob several pixels
            // wide.
            size: 2.0 * radius.max(draw_radius),
            facing: 1.0,
        }
    }
}

/// The mean fraction of a flat leaf's area that it covers on screen, over directions:
/// `E|cos θ| = 1/2` for a leaf seen from a uniformly random direction. Splats always face the
/// camera, so a leaf point's disc gets this fraction of the leaf's opaque area. The renderer
/// spreads that mean over view directions by the point's [`facing`] (a leaf's disc covers
/// `2|n · v|` of it along `v`), which leaves the mean as it is.
///
/// Measured and not taken (`treelod eval --orbit 2,8,32`, spt's mean multi-scale RMSE at 2, 8 and
/// 32 bounding radii):
/// - A quarter for the triangles of closed surfaces (each edge shared, the vertices welded by
///   position; Cauchy's mean projected area of a closed convex body, its back faces behind its
///   front ones): the willow and maple a little better, but the Quaternius tree (closed leaf
///   blobs) 0.0025 → 0.0036 at 8 and 0.0016 → 0.0027 at 32 (recall 0.92 → 0.75), the oak
///   0.0089 → 0.0098 at 8: real blobs and tubes are not convex, and the union rule of
///   [`union_radius`] already counts much of the overlap.
/// - A quarter for bark triangles only (a branch is a tube), against the reference that keeps
///   minified leaves' coverage: willow 0.0081 → 0.0075 (8) and 0.0022 → 0.0020 (32), maple
///   0.0130 → 0.0120 and 0.0029 → 0.0028, orchid 0.0097 → 0.0093, but the Quaternius tree
///   0.0025 → 0.0036 at 8 (recall 0.98 → 0.97), the oak 0.0096 → 0.0106 at 8 and the willow
///   0.0317 → 0.0357 at 2: thick low-poly trunks are not thin tubes.
const MEAN_PROJECTED_FRACTION: f32 = 0.5;

/// The radius of the disc drawn for the union of two nodes whose discs lie within a sphere of
/// radius `extent`: the expected area covered by discs of total area `S` scattered at random over
/// the sphere's projected disc of area `E = π·extent²` is `E·(1 − exp(−S/E))` (Poisson coverage),
/// so overlapping leaves count once, as they do on screen; never smaller than either child's disc
/// (sizes stay monotone up the hierarchy). Gilet's rule, which sets the selection size, is not used
/// for drawing: summing areas instead made distant canopies twice to ten times too dense
/// (precision 0.16–0.86 at 8 bounding radii in `treelod eval`).
///
/// Measured and not taken: summing instead for children that lie in one plane (the sum and the
/// Poisson union mixed by `|N_l · N_r|` times the smaller of their facings, spec §6.5.1), since
/// leaves tiling a surface do not overlap. `eval --orbit 2,8,32` of the point tree, RMSE at 8–32
/// and 32–128 pixels against the Poisson union alone: Quaternius tree .00129 → .00139 and .00213
/// → .00214, oak .00138 → .00142 and .00953 → .00928, orchid .00244 → .00281 and .00705 →
/// .00714, jacaranda .00176 → .00189 and .00628 → .00574: far trees grew too dense.
fn union_radius(l: &Node, r: &Node, extent: f32) -> f32 {
    let (dl, dr) = (l.draw_radius, r.draw_radius);
    let sum = dl * dl + dr * dr;
    let union = if extent > 0.0 { extent * (1.0 - (-sum / (extent * extent)).exp()).sqrt() } else { sum.sqrt() };
    union.max(dl).max(dr)
}

/// How flat the leaves' surface is as seen along `normal`: `2m − 1` clamped to `[0, 1]`, where
/// `m` is the mean `|n_i · normal|` of the leaves' normals weighted by their opaque area.
///
/// A disc's coverage is the mean over view directions of the area its leaves project,
/// `½ Σ A_i` (`MEAN_PROJECTED_FRACTION`), whatever the view. The area they project along a view
/// `v` is `Σ A_i |n_i · v|`; modelled as a mixture of a plane facing `normal` (projecting
/// `2|normal · v|` times the mean) and an isotropic part (the mean), with the mixture's weight
/// `f` of the plane set so that it projects `Σ A_i |n_i · normal|` along `normal`: `f = 2m − 1`.
/// The renderer draws the disc with its area scaled by `1 − f + 2f |normal · v|` (spec §6.5.1),
/// whose mean over directions is 1. A patch of a closed surface seen face on then covers the
/// pixels behind it, and seen edge on no more than its sliver, where the mean made face-on
/// patches of closed crowns half transparent and their rims too dense.
fn facing<'a>(leaves: impl Iterator<Item = &'a LeafPoint>, normal: Vec3) -> f32 {
    let (mut dot, mut weight) = (0.0f64, 0.0f64);
    for leaf in leaves {
        let w = f64::from(leaf.area * leaf.color.w.clamp(0.0, 1.0));
        dot += w * f64::from(leaf.normal.dot(normal).abs().min(1.0));
        weight += w;
    }
    if weight <= 0.0 {
        return 0.0;
    }
    #[expect(clippy::cast_possible_truncation, reason = "a share in [0, 1]")]
    let f = (2.0 * dot / weight - 1.0).clamp(0.0, 1.0) as f32;
    f
}

/// Recursive PCA split of `indices` (leaf point ids); appends inner nodes and returns the id of
/// the subtree's root.
fn cluster(
    indices: &mut [u32],
    leaves: &[LeafPoint],
    cluster_max: usize,
    children: &mut Vec<Vec<u32>>,
    nodes: &mut Vec<Node>,
) -> u32 {
    if indices.len() == 1 {
        return indices[0];
    }
    let kids: Vec<u32> = if indices.len() <= cluster_max {
        indices.to_vec()
    } else {
        let split = split_at_centroid(indices, leaves);
        let (left, right) = indices.split_at_mut(split);
        vec![cluster(left, leaves, cluster_max, children, nodes), cluster(right, leaves, cluster_max, children, nodes)]
    };
    // Fold the binary rule over the children in order (a bottom cluster may hold up to
    // `cluster_max` points).
    let mut node = nodes[kids[0] as usize];
    for &k in &kids[1..] {
        node = Node::merge(&node, &nodes[k as usize]);
    }
    node.facing = facing(indices.iter().map(|&i| &leaves[i as usize]), node.normal);
    #[expect(clippy::cast_possible_truncation, reason = "a cell holds fewer than 2^31 nodes")]
    let id = nodes.len() as u32;
    nodes.push(node);
    children.push(kids);
    id
}

/// Reorders `indices` so the points on the negative side of the plane through their centroid,
/// across the direction of greatest variance, come first; returns the split position, which is
/// always in `1..len` (ties fall back to the median along that direction).
fn split_at_centroid(indices: &mut [u32], leaves: &[LeafPoint]) -> usize {
    let n = indices.len() as f32;
    let centroid = indices.iter().map(|&i| leaves[i as usize].position).sum::<Vec3>() / n;
    let mut cov = [[0.0f32; 3]; 3];
    for &i in indices.iter() {
        let d = (leaves[i as usize].position - centroid).to_array();
        for (r, row) in cov.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v += d[r] * d[c];
            }
        }
    }
    let axis = principal_axis(cov);
    // Ordered along the axis (ties by id, a total order: the result is deterministic), each
    // key computed once and sorted as an integer.
    let mut keys: Vec<u64> =
        indices.iter().map(|&i| sort_key((leaves[i as usize].position - centroid).dot(axis), i)).collect();
    keys.sort_unstable();
    #[expect(clippy::cast_possible_truncation, reason = "the low half is the id")]
    for (slot, &key) in indices.iter_mut().zip(&keys) {
        *slot = key as u32;
    }
    let split = keys.partition_point(|&key| sort_key_value(key) < 0.0);
    if split == 0 || split == indices.len() { indices.len() / 2 } else { split }
}

/// Eigenvector of the largest eigenvalue of a symmetric 3×3 matrix, by power iteration started
/// from the column of largest norm (so the start is never orthogonal to it in practice).
fn principal_axis(cov: [[f32; 3]; 3]) -> Vec3 {
    let m = glam::Mat3::from_cols_array_2d(&cov);
    let mut v = [m.x_axis, m.y_axis, m.z_axis]
        .into_iter()
        .max_by(|a, b| a.length_squared().total_cmp(&b.length_squared()))
        .unwrap_or(Vec3::X);
    if v.length_squared() <= f32::MIN_POSITIVE {
        return Vec3::X; // all points coincide
    }
    for _ in 0..32 {
        let next = m * v;
        match next.try_normalize() {
            Some(n) => v = n,
            None => break,
        }
    }
    v.try_normalize().unwrap_or(Vec3::X)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leaf(x: f32, y: f32, size: f32) -> LeafPoint {
        let r = size * 0.5;
        LeafPoint {
            position: Vec3::new(x, y, 0.0),
            normal: Vec3::Z,
            area: std::f32::consts::PI * r * r,
            color: Vec4::new(0.2, 0.5, 0.1, 1.0),
            size,
        }
    }

    #[test]
    fn clusters_split_along_the_longest_axis_and_stop_at_cluster_max() {
        // Two groups far apart along x: the first split separates them.
        let mut leaves: Vec<LeafPoint> = (0..6).map(|i| leaf(i as f32 * 0.01, 0.0, 0.1)).collect();
        leaves.extend((0..6).map(|i| leaf(10.0 + i as f32 * 0.01, 0.0, 0.1)));
        let h = build_cell(&leaves, &GiletConfig::default()).unwrap();
        let root = h.points[0];
        assert_eq!(root.leaf_count, 12);
        assert!(root.hi.is_infinite());
        // Root's two children each cover one group of 6, which splits once more (6 > 5).
        let children: Vec<_> = h.points.iter().filter(|p| p.hi == root.lo).collect();
        assert_eq!(children.len(), 2);
        assert!(children.iter().all(|c| c.leaf_count == 6));
        // 12 leaves + root + 2 group nodes + 4 bottom clusters of 3.
        assert_eq!(h.points.len(), 12 + 1 + 2 + 4);
    }

    #[test]
    fn radius_rule_follows_the_paper_and_sizes_are_monotone() {
        // Parallel normals (α = 1): R = 2/π · (R_l + R_r) sets the selection size.
        let h = build_cell(&[leaf(0.0, 0.0, 2.0), leaf(1.0, 0.0, 2.0)], &GiletConfig::default()).unwrap();
        let root = h.points[0];
        assert!((root.size - 2.0 * std::f32::consts::FRAC_2_PI * 2.0).abs() < 1e-6);
        // Drawn discs: each leaf's is half its area (radius sqrt(1/2)); the two lie within 1.5 of
        // their centre, so the union covers 1.5² · (1 − exp(−1/1.5²)) of π.
        let child = std::f32::consts::FRAC_1_SQRT_2;
        assert!(h.points[1..].iter().all(|p| (p.radius - child).abs() < 1e-6));
        let union = 1.5 * (1.0 - (-1.0f32 / 2.25).exp()).sqrt();
        assert!((root.radius - union).abs() < 1e-5, "{} vs {union}", root.radius);
        assert!(root.radius > child && root.radius < 1.0, "more than a child, less than the summed area");
        // Far apart, leaves do not overlap and the union keeps their summed area.
        let h = build_cell(&[leaf(0.0, 0.0, 2.0), leaf(100.0, 0.0, 2.0)], &GiletConfig::default()).unwrap();
        assert!((h.points[0].radius - 1.0).abs() < 1e-3, "{}", h.points[0].radius);
        // Perpendicular normals (α = 0): the rule gives 2/π · R_m < R, made monotone for selection.
        let mut b = leaf(1.0, 0.0, 2.0);
        b.normal = Vec3::X;
        let h = build_cell(&[leaf(0.0, 0.0, 2.0), b], &GiletConfig::default()).unwrap();
        assert!(h.points[0].size >= 2.0, "parent selection size never below a child's");
        assert!(h.points[0].radius >= h.points[1].radius.max(h.points[2].radius), "drawn discs are monotone too");
        for p in &h.points[1..] {
            assert_eq!(p.lo, 0.0);
            assert_eq!(p.hi, h.points[0].lo);
        }
    }

    #[test]
    fn sparse_leaves_with_scattered_normals_select_their_cluster_by_its_drawn_disc() {
        // Sixteen unit leaves far apart, normals cycling through three perpendicular axes:
        // Gilet's rule (α small) grows little up the hierarchy, while their union covers sixteen
        // half-leaf discs, a disc of radius sqrt(16 / 2) = 2.83. The root is selected by that
        // disc: drawn at the threshold, it is no wider than the threshold.
        let leaves: Vec<LeafPoint> = (0..16)
            .map(|i| {
                let mut p = leaf(100.0 * (i % 4) as f32, 100.0 * (i / 4) as f32, 2.0);
                p.normal = [Vec3::Z, Vec3::X, Vec3::Y][i % 3];
                p
            })
            .collect();
        let h = build_cell(&leaves, &GiletConfig { cluster_max: 2 }).unwrap();
        let root = h.points[0];
        assert!((root.radius - 8f32.sqrt()).abs() < 0.05, "{}", root.radius);
        assert!(
            (root.size - 2.0 * root.radius).abs() < 1e-5,
            "size {} for a disc of radius {}",
            root.size,
            root.radius
        );
        for p in &h.points {
            assert!(p.size >= 2.0 * p.radius - 1e-5, "a point of size {} draws a disc of radius {}", p.size, p.radius);
        }
    }

    #[test]
    fn leaf_points_keep_the_triangle_size_and_coverage_shrinks_the_disc() {
        let mut card = leaf(0.0, 0.0, 0.3);
        card.color.w = 0.25;
        let h = build_cell(&[card, leaf(0.5, 0.0, 0.2)], &GiletConfig::default()).unwrap();
        let p = h.points.iter().find(|p| p.leaf_count == 1 && p.size == 0.3).unwrap();
        assert!((p.radius - 0.15 * (0.25f32 * 0.5).sqrt()).abs() < 1e-6, "radius 0.15 scaled by sqrt(0.25 · 1/2)");
        assert_eq!(h.leaf_of_triangle.len(), 2);
    }

    #[test]
    fn facing_is_one_for_a_plane_and_falls_as_the_normals_spread() {
        // A leaf and a cluster of coplanar leaves face along their normal: the whole coverage.
        let flat: Vec<LeafPoint> = (0..8).map(|i| leaf(i as f32, 0.0, 1.0)).collect();
        let h = build_cell(&flat, &GiletConfig::default()).unwrap();
        assert!(
            h.points.iter().all(|p| p.facing == 1.0),
            "{:?}",
            h.points.iter().map(|p| p.facing).collect::<Vec<_>>()
        );
        // Normals evenly over three perpendicular axes: f = 2m − 1 for the mean |n_i · n| to the
        // point's normal n (about (1, 1, 1)/√3, where m = 1/√3 and f = 0.155).
        let spread: Vec<LeafPoint> = (0..6)
            .map(|i| LeafPoint { normal: [Vec3::X, Vec3::Y, Vec3::Z][i % 3], ..leaf(i as f32, 0.0, 1.0) })
            .collect();
        let root = build_cell(&spread, &GiletConfig { cluster_max: 8 }).unwrap().points[0];
        assert_eq!(root.leaf_count, 6);
        let m = (root.normal.x.abs() + root.normal.y.abs() + root.normal.z.abs()) / 3.0;
        assert!((root.facing - (2.0 * m - 1.0)).abs() < 1e-5, "{} for {}", root.facing, root.normal);
        assert!((0.1..0.16).contains(&root.facing), "{}", root.facing);
        // Leaves facing every way (a sphere's) give none: mean |cos| about 1/2.
        let n = 400;
        let sphere: Vec<LeafPoint> = (0..n)
            .map(|i| {
                // A Fibonacci sphere, each leaf at its normal.
                let z = 1.0 - (2 * i + 1) as f32 / n as f32;
                let (s, c) = (i as f32 * 2.399_963).sin_cos();
                let r = (1.0 - z * z).sqrt();
                let normal = Vec3::new(r * c, r * s, z);
                LeafPoint { position: normal * 10.0, normal, ..leaf(0.0, 0.0, 0.1) }
            })
            .collect();
        let root = build_cell(&sphere, &GiletConfig::default()).unwrap().points[0];
        assert!(root.facing < 0.02, "{}", root.facing);
        // The weight is the opaque area: a transparent leaf across the plane tilts the point's
        // normal (averaged by area) but counts for nothing in m, which is the plane's |z · n|.
        let mut mixed = flat.clone();
        mixed.push(LeafPoint { normal: Vec3::X, color: Vec4::new(0.2, 0.5, 0.1, 0.0), ..leaf(9.0, 0.0, 1.0) });
        let root = build_cell(&mixed, &GiletConfig { cluster_max: 16 }).unwrap().points[0];
        assert!(root.normal.x > 0.05, "tilted: {}", root.normal);
        assert!((root.facing - (2.0 * root.normal.z - 1.0)).abs() < 1e-5, "{} for {}", root.facing, root.normal);
    }

    #[test]
    fn identical_positions_still_split() {
        let leaves: Vec<LeafPoint> = (0..40).map(|_| leaf(1.0, 1.0, 0.1)).collect();
        let h = build_cell(&leaves, &GiletConfig { cluster_max: 2 }).unwrap();
        assert_eq!(h.points.iter().filter(|p| p.leaf_count == 1).count(), 40);
        assert_eq!(h.points[0].leaf_count, 40);
    }
}
