//! The benchmark's forest, after Clasen 2011 §7 ("a scene of 10 000 plants in forest groups"): a
//! main forest made of groups of trees laid out on a sunflower spiral, with clearings between
//! them, and a smaller separate group east of it. Deterministic from the seed; the density follows
//! the models' size, so the layout works for trees in any unit.
//!
//! Trees are kept as position, rotation and scale (20 bytes each) rather than matrices, so a
//! forest of 10^6 costs 20 MB here; [`Tree::transform`] makes the matrix where it is needed.

use glam::{Mat4, Quat, Vec2, Vec3};
use treelod_build::SplitMix64;

/// Share of the trees in the smaller separate group.
const SMALL_GROUP_SHARE: f64 = 0.08;
/// Fewest trees for which a separate group is planted.
const SMALL_GROUP_MIN_FOREST: usize = 20;
/// Share of the main forest's disc its groups cover; the rest are clearings.
const GROUP_COVER: f32 = 0.65;
/// Groups in the main forest: `sqrt(trees) / GROUPS_PER_SQRT` (about 19 for 10^4 trees, 200 for
/// 10^6), so groups grow with the forest.
const GROUPS_PER_SQRT: f64 = 5.0;
/// Ground per tree inside a group, in footprint radii squared: `(1.7 r)²`, crowns about touching.
const SPACING_RADII: f32 = 1.7;
/// The scale of each instance is uniform in this range.
const SCALE_RANGE: (f32, f32) = (0.8, 1.2);
/// Golden angle of the sunflower spiral, radians.
const GOLDEN_ANGLE: f32 = 2.399_963;

/// The size of one model, from its block bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    /// Horizontal footprint radius: half the larger of the x and z extents, model units.
    pub radius: f32,
    /// Height: the y extent, model units.
    pub height: f32,
}

impl Shape {
    /// The shape of a model whose block bounds are `min..max` (degenerate or non-finite bounds
    /// give a small shape rather than nonsense).
    #[must_use]
    pub fn from_bounds(min: Vec3, max: Vec3) -> Self {
        let extent = (max - min).max(Vec3::ZERO);
        let sane = |v: f32| if v.is_finite() { v.max(0.1) } else { 1.0 };
        Self { radius: sane(0.5 * extent.x.max(extent.z)), height: sane(extent.y) }
    }
}

/// One placed tree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tree {
    /// Index of its model.
    pub model: u32,
    /// Position on the ground (x, z), metres; the model's origin stands there at y = 0.
    pub position: Vec2,
    /// Rotation about +y, radians.
    pub rotation: f32,
    /// Uniform scale.
    pub scale: f32,
}

impl Tree {
    /// World from model: scale, then rotation about y, then translation.
    #[must_use]
    pub fn transform(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(
            Vec3::splat(self.scale),
            Quat::from_rotation_y(self.rotation),
            Vec3::new(self.position.x, 0.0, self.position.y),
        )
    }
}

/// The forest and the figures the camera path is fitted to.
#[derive(Clone, Debug, PartialEq)]
pub struct Forest {
    /// The trees, group by group (main forest first, the separate group last).
    pub trees: Vec<Tree>,
    /// Groups of the main forest.
    pub groups: usize,
    /// Trees of the main forest.
    pub main_trees: usize,
    /// Radius of the main forest around the origin, to the outer edge of its outermost group.
    pub main_radius: f32,
    /// Trees of the separate group.
    pub small_trees: usize,
    /// Centre of the separate group (x, z), on the +x axis.
    pub small_centre: Vec2,
    /// Radius of the separate group.
    pub small_radius: f32,
    /// Ground per tree inside a group, square metres.
    pub area_per_tree: f32,
    /// Mean height of the models (scale 1).
    pub tree_height: f32,
    /// Mean footprint radius of the models (scale 1).
    pub footprint: f32,
}

/// Lays out `count` trees of models of the given shapes (at least one) from `seed`.
#[must_use]
pub fn layout(count: usize, seed: u64, shapes: &[Shape]) -> Forest {
    let mut rng = SplitMix64(seed);
    let n = shapes.len().max(1) as f32;
    let footprint = shapes.iter().map(|s| s.radius).sum::<f32>() / n;
    let tree_height = shapes.iter().map(|s| s.height).sum::<f32>() / n;
    let area_per_tree = (SPACING_RADII * footprint.max(0.1)).powi(2);
    let small_trees =
        if count >= SMALL_GROUP_MIN_FOREST { (count as f64 * SMALL_GROUP_SHARE).round() as usize } else { 0 };
    let main_trees = count - small_trees;
    let groups = ((main_trees as f64).sqrt() / GROUPS_PER_SQRT).round().max(1.0) as usize;
    let disc = |trees: usize| (trees as f32 * area_per_tree / std::f32::consts::PI).sqrt();

    // Group sizes: random weights in [0.5, 1.5), the trees shared out by largest remainder.
    let weights: Vec<f64> = (0..groups).map(|_| 0.5 + rng.next_f64()).collect();
    let sizes = share_out(main_trees, &weights);
    let spiral_radius = disc(main_trees) / GROUP_COVER.sqrt();
    let turn = rng.range(0.0, std::f32::consts::TAU);
    let mut trees = Vec::with_capacity(count);
    let mut main_radius = 0.0f32;
    for (g, &size) in sizes.iter().enumerate() {
        // The sunflower spiral spreads the group centres evenly over the disc.
        let rho = spiral_radius * ((g as f32 + 0.5) / groups as f32).sqrt();
        let angle = turn + g as f32 * GOLDEN_ANGLE;
        let centre = rho * Vec2::new(angle.cos(), angle.sin());
        let radius = disc(size);
        main_radius = main_radius.max(centre.length() + radius);
        plant(&mut trees, &mut rng, centre, radius, size, shapes.len());
    }
    let small_radius = disc(small_trees);
    // The separate group stands east, a clear gap away: a third of the forest's radius, and at
    // least a few tree heights.
    let gap = (0.35 * main_radius).max(8.0 * tree_height);
    let small_centre = Vec2::new(main_radius + gap + small_radius, 0.0);
    plant(&mut trees, &mut rng, small_centre, small_radius, small_trees, shapes.len());
    Forest {
        trees,
        groups,
        main_trees,
        main_radius,
        small_trees,
        small_centre,
        small_radius,
        area_per_tree,
        tree_height,
        footprint,
    }
}

/// Plants `count` trees uniformly in the disc of `radius` around `centre`.
fn plant(trees: &mut Vec<Tree>, rng: &mut SplitMix64, centre: Vec2, radius: f32, count: usize, models: usize) {
    for _ in 0..count {
        let model = rng.below(models.max(1) as u64) as u32;
        let rho = radius * rng.unit().sqrt();
        let angle = rng.range(0.0, std::f32::consts::TAU);
        let rotation = rng.range(0.0, std::f32::consts::TAU);
        let scale = rng.range(SCALE_RANGE.0, SCALE_RANGE.1);
        trees.push(Tree { model, position: centre + rho * Vec2::new(angle.cos(), angle.sin()), rotation, scale });
    }
}

/// `total` split in proportion to `weights` (positive), by largest remainder: the parts sum to
/// `total` exactly.
fn share_out(total: usize, weights: &[f64]) -> Vec<usize> {
    let sum: f64 = weights.iter().sum();
    if weights.is_empty() || sum <= 0.0 {
        return Vec::new();
    }
    let exact: Vec<f64> = weights.iter().map(|w| total as f64 * w / sum).collect();
    let mut parts: Vec<usize> = exact.iter().map(|e| e.floor() as usize).collect();
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| (exact[b] - exact[b].floor()).total_cmp(&(exact[a] - exact[a].floor())).then(a.cmp(&b)));
    let missing = total - parts.iter().sum::<usize>();
    for &i in order.iter().cycle().take(missing) {
        parts[i] += 1;
    }
    parts
}

/// Moves every tree standing closer than `clearance` to the polyline `track` (ground positions
/// x, z) out to that distance, so a camera walking along it at human height does not pass through
/// a trunk. The number of trees does not change.
pub fn clear_track(forest: &mut Forest, track: &[Vec2], clearance: f32) {
    if track.is_empty() || clearance <= 0.0 {
        return;
    }
    let (lo, hi) = track.iter().fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let (lo, hi) = (lo - Vec2::splat(clearance), hi + Vec2::splat(clearance));
    for tree in &mut forest.trees {
        let p = tree.position;
        if p.cmplt(lo).any() || p.cmpgt(hi).any() {
            continue;
        }
        // Straight away from the nearest point of the track (a tree exactly on it goes to its
        // left); again if that brings it near another segment, on the inside of a bend.
        for _ in 0..4 {
            let Some((nearest, distance)) = nearest_on_polyline(track, tree.position) else { break };
            if distance >= clearance {
                break;
            }
            let away = (tree.position - nearest).try_normalize().unwrap_or_else(|| {
                let along = track.last().copied().unwrap_or(p) - track.first().copied().unwrap_or(p);
                along.perp().try_normalize().unwrap_or(Vec2::X)
            });
            tree.position = nearest + 1.001 * clearance * away;
        }
    }
}

/// The point of `track` nearest to `p` and its distance.
fn nearest_on_polyline(track: &[Vec2], p: Vec2) -> Option<(Vec2, f32)> {
    let segments = track.windows(2).map(|w| (w[0], w[1])).chain((track.len() == 1).then(|| (track[0], track[0])));
    segments
        .map(|(a, b)| {
            let ab = b - a;
            let t =
                if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
            let q = a + t * ab;
            (q, q.distance(p))
        })
        .min_by(|x, y| x.1.total_cmp(&y.1))
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEMO: Shape = Shape { radius: 3.2, height: 5.5 };

    #[test]
    fn the_forest_has_groups_and_a_separate_group() {
        let forest = layout(10_000, 1, &[DEMO, Shape { radius: 2.0, height: 4.0 }]);
        assert_eq!(forest.trees.len(), 10_000);
        assert_eq!((forest.main_trees, forest.small_trees), (9200, 800));
        assert_eq!(forest.groups, 19);
        assert!(forest.trees.iter().all(|t| t.model < 2 && (0.8..1.2).contains(&t.scale)));
        assert!(forest.trees.iter().any(|t| t.model == 1) && forest.trees.iter().any(|t| t.model == 0));
        // Main forest within its radius; the separate group in its disc, clear of the forest.
        for (i, tree) in forest.trees.iter().enumerate() {
            if i < forest.main_trees {
                assert!(tree.position.length() <= forest.main_radius + 1e-3, "{tree:?}");
            } else {
                assert!(tree.position.distance(forest.small_centre) <= forest.small_radius + 1e-3, "{tree:?}");
            }
        }
        assert!(forest.small_centre.x - forest.small_radius > forest.main_radius + 100.0, "{forest:?}");
        // A few hundred metres across for 10^4 trees of this size.
        assert!((250.0..600.0).contains(&forest.main_radius), "{}", forest.main_radius);
        // The same seed gives the same forest; another seed another.
        assert_eq!(layout(500, 7, &[DEMO]), layout(500, 7, &[DEMO]));
        assert_ne!(layout(500, 7, &[DEMO]).trees, layout(500, 8, &[DEMO]).trees);
    }

    #[test]
    fn tiny_forests_work() {
        for count in [1, 2, 19, 20] {
            let forest = layout(count, 3, &[DEMO]);
            assert_eq!(forest.trees.len(), count);
            assert!(forest.main_radius > 0.0 && forest.main_radius.is_finite());
        }
        assert_eq!(layout(19, 3, &[DEMO]).small_trees, 0);
        assert_eq!(layout(20, 3, &[DEMO]).small_trees, 2);
    }

    #[test]
    fn shares_add_up() {
        assert_eq!(share_out(10, &[1.0, 1.0, 1.0]), [4, 3, 3]);
        assert_eq!(share_out(7, &[0.5, 1.5]), [2, 5]);
        assert_eq!(share_out(0, &[1.0, 2.0]).iter().sum::<usize>(), 0);
        assert!(share_out(5, &[]).is_empty());
    }

    #[test]
    fn the_track_is_cleared_of_trunks() {
        let mut forest = layout(2000, 5, &[DEMO]);
        let track = [Vec2::new(-100.0, 0.0), Vec2::new(0.0, 0.0), Vec2::new(50.0, 60.0)];
        let before = forest.trees.len();
        clear_track(&mut forest, &track, 1.5);
        assert_eq!(forest.trees.len(), before);
        for tree in &forest.trees {
            let (_, d) = nearest_on_polyline(&track, tree.position).expect("a track");
            assert!(d >= 1.5 - 1e-3, "{tree:?} at {d}");
        }
        let transform = Tree { model: 0, position: Vec2::new(1.0, 2.0), rotation: 0.0, scale: 2.0 }.transform();
        assert_eq!(transform.transform_point3(Vec3::Y), Vec3::new(1.0, 2.0, 2.0));
    }
}
