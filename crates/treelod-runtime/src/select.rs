//! Per-cell level-of-detail selection (spec §10): thresholds and prefixes.

use treelod_format::{CellRecord, PointRecord, SptElement, TriangleRecord};

/// World-size thresholds of one cell, metres, with `points ≤ triangles` (spec §10).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thresholds {
    /// `τ_p`: points are drawn where their interval `[lo, hi)` contains it.
    pub points: f32,
    /// `τ_t`: triangles larger than it are drawn as triangles, smaller ones as points.
    pub triangles: f32,
}

impl Thresholds {
    /// Gilet's thresholds for one cell: pixel sizes `s_min ≤ s_max` turned into metres at distance
    /// `distance` (spec §10.1). `s_max` is raised to `s_min` if smaller, so the rule's `τ_p ≤ τ_t`
    /// always holds.
    #[must_use]
    pub fn from_pixels(s_min: f32, s_max: f32, distance: f32, fovy: f32, viewport_height: f32) -> Self {
        let points = pixels_to_world(s_min, distance, fovy, viewport_height);
        let triangles = pixels_to_world(s_max.max(s_min), distance, fovy, viewport_height);
        Self { points, triangles: triangles.max(points) }
    }
}

/// The world size, metres, that covers `pixels` pixels at `distance` metres from a perspective
/// camera with vertical field of view `fovy` (radians) and a viewport `viewport_height` pixels high.
#[must_use]
pub fn pixels_to_world(pixels: f32, distance: f32, fovy: f32, viewport_height: f32) -> f32 {
    pixels * 2.0 * distance.max(0.0) * (0.5 * fovy).tan() / viewport_height
}

/// What to draw of one cell: prefixes of its triangle and point ranges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CellSelection {
    /// Leading triangles of the cell's range to draw (all of them are drawn).
    pub triangles: u32,
    /// Leading points of the cell's range to submit; the shader drops those that fail
    /// [`point_drawn`].
    pub points: u32,
}

/// Whether a triangle is drawn at `t` (spec §10).
#[must_use]
pub fn triangle_drawn(triangle: &TriangleRecord, t: Thresholds) -> bool {
    triangle.size > t.triangles
}

/// Whether a point is drawn at `t` (spec §10): its interval holds `τ_p` and it is not larger than
/// `τ_t`, so a leaf point gives way to its triangle exactly when the triangle is drawn.
#[must_use]
pub fn point_drawn(point: &PointRecord, t: Thresholds) -> bool {
    point.lo <= t.points && t.points < point.hi && point.size <= t.triangles
}

/// Binary-searches the prefixes of one cell (spec §10): triangles with `size > τ_t`, points with
/// `hi > τ_p`. `triangles` and `points` are the container's whole arrays.
///
/// # Panics
/// If the cell's ranges lie outside the arrays, which cannot happen for a cell and arrays of the
/// same opened container (ranges are checked when it is opened).
#[must_use]
pub fn select_cell(
    cell: &CellRecord,
    triangles: &[TriangleRecord],
    points: &[PointRecord],
    t: Thresholds,
) -> CellSelection {
    let tris = &triangles[cell.triangles.as_usize()];
    let pts = &points[cell.points.as_usize()];
    #[expect(clippy::cast_possible_truncation, reason = "a cell's range count is a u32")]
    CellSelection {
        triangles: tris.partition_point(|tri| tri.size > t.triangles) as u32,
        points: pts.partition_point(|p| p.hi() > t.points) as u32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use treelod_format::Range;

    /// A cell of `n` triangles under a balanced binary point hierarchy, flattened as the spec says.
    fn cell(sizes: &[f32]) -> (CellRecord, Vec<TriangleRecord>, Vec<PointRecord>) {
        let n = sizes.len();
        // Nodes 0..n are leaves; inner nodes pair up the previous level.
        let mut children: Vec<Vec<u32>> = vec![Vec::new(); n];
        let mut node_sizes: Vec<f32> = sizes.to_vec();
        let mut level: Vec<u32> = (0..n as u32).collect();
        while level.len() > 1 {
            let mut next = Vec::new();
            for pair in level.chunks(2) {
                let id = children.len() as u32;
                children.push(pair.to_vec());
                node_sizes.push(pair.iter().map(|&c| node_sizes[c as usize]).sum::<f32>() * 0.8);
                next.push(id);
            }
            level = next;
        }
        let spt = treelod_build::flatten(&children, &node_sizes).unwrap();
        let points: Vec<PointRecord> = spt
            .order
            .iter()
            .map(|&i| {
                let node = spt.nodes[i as usize];
                PointRecord {
                    size: node.size,
                    lo: node.lo,
                    hi: node.hi,
                    leaf_first: node.leaf_first,
                    leaf_count: node.leaf_count,
                    ..PointRecord::default()
                }
            })
            .collect();
        let mut triangles: Vec<TriangleRecord> = (0..n)
            .map(|i| TriangleRecord { size: sizes[i], leaf: spt.leaf_id[i].unwrap(), ..TriangleRecord::default() })
            .collect();
        triangles.sort_by(|a, b| b.size.total_cmp(&a.size));
        let cell = CellRecord {
            triangles: Range { first: 0, count: n as u32 },
            points: Range { first: 0, count: points.len() as u32 },
            ..CellRecord::default()
        };
        (cell, triangles, points)
    }

    proptest! {
        #[test]
        fn selection_draws_each_triangle_exactly_once(
            sizes in proptest::collection::vec(0.01f32..1.0, 1..40),
            tau_p in 0.0f32..3.0,
            extra in 0.0f32..3.0,
        ) {
            let (cell, triangles, points) = cell(&sizes);
            let t = Thresholds { points: tau_p, triangles: tau_p + extra };
            let sel = select_cell(&cell, &triangles, &points, t);
            let mut cover = vec![0; sizes.len()];
            for (i, tri) in triangles.iter().enumerate() {
                prop_assert_eq!(i < sel.triangles as usize, triangle_drawn(tri, t));
                if i < sel.triangles as usize {
                    cover[tri.leaf as usize] += 1;
                }
            }
            for (i, p) in points.iter().enumerate() {
                if point_drawn(p, t) {
                    prop_assert!(i < sel.points as usize, "a drawn point lies outside the prefix");
                    for leaf in p.leaf_first..p.leaf_first + p.leaf_count {
                        cover[leaf as usize] += 1;
                    }
                }
            }
            prop_assert!(cover.iter().all(|&c| c == 1), "cover {:?}", cover);
        }
    }

    #[test]
    fn pixel_thresholds_scale_with_distance() {
        let fovy = std::f32::consts::FRAC_PI_2; // tan(45°) = 1
        assert!((pixels_to_world(2.0, 10.0, fovy, 1000.0) - 0.04).abs() < 1e-6);
        let near = Thresholds::from_pixels(1.0, 4.0, 1.0, fovy, 1000.0);
        let far = Thresholds::from_pixels(1.0, 4.0, 100.0, fovy, 1000.0);
        assert!(far.points > near.points * 99.0 && far.triangles > far.points);
        let swapped = Thresholds::from_pixels(4.0, 1.0, 1.0, fovy, 1000.0);
        assert_eq!(swapped.points, swapped.triangles);
    }

    #[test]
    fn far_away_draws_only_the_root() {
        let (cell, triangles, points) = cell(&[0.1, 0.2, 0.3, 0.4]);
        let t = Thresholds { points: 1e6, triangles: 1e6 };
        let sel = select_cell(&cell, &triangles, &points, t);
        assert_eq!(sel.triangles, 0);
        assert_eq!(sel.points, 1, "only the root has hi above every threshold");
        assert!(point_drawn(&points[0], t));
    }
}
