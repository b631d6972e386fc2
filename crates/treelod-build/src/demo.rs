//! The built-in demo tree: a procedural tree made in our own code, deterministic from a seed, so
//! `treelod demo` builds a container with no input and tests have a realistic tree at hand.
//!
//! A tapering trunk and recursive branches are tubes (bark); leaf quads (two triangles, own
//! vertices, alpha-tested generated texture) sit along the outer branches (leaves).

use glam::{Quat, Vec3};

use crate::rng::SplitMix64;
use crate::scene::{AlphaMode, Image, ImageEncoding, Material, Part, Scene, SourceInfo};

/// Settings of [`demo_tree`].
#[derive(Clone, Debug, PartialEq)]
pub struct DemoTreeConfig {
    /// Seed of the generator; the same seed gives the same tree on every machine. Default 1.
    pub seed: u64,
    /// Number of leaf quads. Default 4000.
    pub leaves: u32,
    /// Trunk height to the first fork, metres; the crown adds about as much. Default 4.
    pub height: f32,
    /// Sides of each branch tube. Default 7.
    pub sides: u32,
    /// Levels of branching below the trunk. Default 3.
    pub levels: u32,
}

impl Default for DemoTreeConfig {
    fn default() -> Self {
        Self { seed: 1, leaves: 4000, height: 4.0, sides: 7, levels: 3 }
    }
}

/// One branch: a straight-ish tube from `start` along `dir`.
struct Branch {
    start: Vec3,
    dir: Vec3,
    length: f32,
    radius: f32,
    level: u32,
}

/// Builds the demo tree (see the module documentation).
#[must_use]
pub fn demo_tree(config: &DemoTreeConfig) -> Scene {
    let mut rng = SplitMix64(config.seed);
    let sides = config.sides.clamp(3, 32);
    let mut bark = Part { mesh_name: "bark".into(), node_name: "demo-tree".into(), material: 1, ..Part::default() };
    let mut tips: Vec<(Vec3, Vec3, f32)> = Vec::new(); // (point, direction, branch length) for leaves
    let mut stack = vec![Branch {
        start: Vec3::ZERO,
        dir: Vec3::Y,
        length: config.height.max(0.1),
        radius: 0.05 * config.height.max(0.1),
        level: 0,
    }];
    while let Some(b) = stack.pop() {
        let segments = 4u32;
        let mut points = Vec::with_capacity(segments as usize + 1);
        let mut p = b.start;
        let mut d = b.dir;
        for s in 0..=segments {
            points.push((p, d, b.radius * (1.0 - 0.6 * s as f32 / segments as f32)));
            // Bend: a little gravity for side branches, a little light-seeking for all.
            let bend =
                Vec3::new(rng.range(-0.15, 0.15), 0.08, rng.range(-0.15, 0.15)) - Vec3::Y * 0.05 * b.level as f32;
            d = (d + bend).normalize_or(Vec3::Y);
            p += d * (b.length / segments as f32);
        }
        tube(&mut bark, &points, sides);
        if b.level >= config.levels {
            for &(q, dir, _) in &points[1..] {
                tips.push((q, dir, b.length));
            }
            continue;
        }
        let children = if b.level == 0 { 5 } else { 3 };
        for c in 0..children {
            let t = if b.level == 0 {
                0.45 + 0.55 * (c as f32 + rng.unit()) / children as f32
            } else {
                rng.range(0.3, 1.0)
            };
            let k = ((t * segments as f32) as usize).min(segments as usize);
            let (at, along, r) = points[k];
            let around = Quat::from_axis_angle(along, c as f32 * 2.4 + rng.range(-0.3, 0.3));
            let side = around * along.any_orthonormal_vector();
            let dir = (along * rng.range(0.3, 0.7) + side).normalize_or(Vec3::Y);
            stack.push(Branch {
                start: at,
                dir,
                length: b.length * rng.range(0.45, 0.65) * if b.level == 0 { 1.2 } else { 1.0 },
                radius: (r * 0.6).max(0.004),
                level: b.level + 1,
            });
        }
    }
    let mut leaves = Part { mesh_name: "leaves".into(), node_name: "demo-tree".into(), material: 0, ..Part::default() };
    if !tips.is_empty() {
        for _ in 0..config.leaves {
            let (q, dir, len) = tips[(rng.next_u64() % tips.len() as u64) as usize];
            let center = q
                + Vec3::new(rng.range(-1.0, 1.0), rng.range(-0.6, 0.8), rng.range(-1.0, 1.0)) * 0.35 * len
                + dir * 0.1 * len;
            let size = config.height * rng.range(0.03, 0.05);
            let normal =
                Vec3::new(rng.range(-1.0, 1.0), rng.range(0.2, 1.0), rng.range(-1.0, 1.0)).normalize_or(Vec3::Y);
            let u = (normal.cross(dir).normalize_or(Vec3::X) * size) * 0.5;
            let v = normal.cross(u);
            let base = leaves.positions.len() as u32;
            for (corner, uv) in [(-u - v, [0.0, 1.0]), (u - v, [1.0, 1.0]), (u + v, [1.0, 0.0]), (-u + v, [0.0, 0.0])] {
                leaves.positions.push((center + corner).to_array());
                leaves.normals.push(normal.to_array());
                leaves.uvs.push(uv);
            }
            leaves.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        }
    }
    Scene {
        name: "demo-tree".into(),
        source: SourceInfo { unit_scale: 1.0, ..SourceInfo::default() },
        parts: vec![leaves, bark],
        materials: vec![
            leaf_material(),
            Material { name: "bark".into(), base_color: [0.35, 0.25, 0.18, 1.0], ..Material::default() },
        ],
        images: vec![leaf_texture(64)],
        warnings: Vec::new(),
    }
}

/// Appends a tube through `rings` (centre, direction, radius) with `sides` sides, UVs around and
/// along.
fn tube(part: &mut Part, rings: &[(Vec3, Vec3, f32)], sides: u32) {
    let base = part.positions.len() as u32;
    let mut reference = rings[0].1.any_orthonormal_vector();
    for (r, &(c, d, radius)) in rings.iter().enumerate() {
        // Carry the reference frame along so the tube does not twist.
        reference = (reference - d * reference.dot(d)).normalize_or(d.any_orthonormal_vector());
        for s in 0..=sides {
            let a = s as f32 / sides as f32 * std::f32::consts::TAU;
            let n = Quat::from_axis_angle(d, a) * reference;
            part.positions.push((c + n * radius).to_array());
            part.normals.push(n.to_array());
            part.uvs.push([s as f32 / sides as f32, r as f32 * 0.5]);
        }
    }
    let row = sides + 1;
    for r in 0..rings.len() as u32 - 1 {
        for s in 0..sides {
            let a = base + r * row + s;
            let b = a + row;
            part.triangles.extend([[a, a + 1, b + 1], [a, b + 1, b]]);
        }
    }
}

/// A leaf: an ellipse with a midrib, green shades, transparent outside (RGBA, sRGB).
fn leaf_texture(size: u32) -> Image {
    let mut rgba = Vec::with_capacity((size * size * 4) as usize);
    for y in 0..size {
        for x in 0..size {
            let u = (x as f32 + 0.5) / size as f32 * 2.0 - 1.0;
            let v = (y as f32 + 0.5) / size as f32 * 2.0 - 1.0;
            let inside = u * u / 0.45 + v * v < 0.95;
            let rib = u.abs() < 0.04;
            let shade = 1.0 - 0.3 * (v + 1.0) * 0.5;
            let (r, g, b) = if rib { (150.0, 170.0, 80.0) } else { (60.0 * shade, 130.0 * shade, 40.0 * shade) };
            rgba.extend([r as u8, g as u8, b as u8, if inside { 255 } else { 0 }]);
        }
    }
    Image { width: size, height: size, rgba, encoded: Vec::new(), encoding: ImageEncoding::Raw }
}

/// The demo's leaf material: `leaves`, white, image 0, alpha-tested at 0.5, two-sided.
#[must_use]
pub fn leaf_material() -> Material {
    Material {
        name: "leaves".into(),
        base_color: [1.0; 4],
        image: Some(0),
        alpha_mode: AlphaMode::Mask,
        alpha_cutoff: 0.5,
        double_sided: true,
    }
}

/// Square leaf cards lying on known planes, for tests and examples of leaf-cluster impostors:
/// on each plane (a point on it and its unit normal) a `grid × grid` square of cards `spacing`
/// metres apart centred on the point, each `2·half` metres across, card `k` (counted over all
/// planes) turned in its plane by `k · turn` radians and every other one facing the opposite
/// way. Corners run around the card, the first at texture coordinates `(0, 1)` of a card whose
/// UVs cover `[0, 1]²` in the order `(0, 1), (1, 1), (1, 0), (0, 0)`.
#[must_use]
pub fn cards_on_planes(planes: &[(Vec3, Vec3)], grid: usize, spacing: f32, half: f32, turn: f32) -> Vec<[Vec3; 4]> {
    let mut cards = Vec::with_capacity(planes.len() * grid * grid);
    let offset = 0.5 * spacing * (grid as f32 - 1.0);
    for &(centre, normal) in planes {
        let (a, b) = normal.any_orthonormal_pair();
        for i in 0..grid {
            for j in 0..grid {
                let k = cards.len();
                let c = centre + a * (spacing * i as f32 - offset) + b * (spacing * j as f32 - offset);
                let rotation = Quat::from_axis_angle(normal, k as f32 * turn);
                let (u, v) = (rotation * a * half, rotation * b * half);
                let mut corners = [c - u - v, c + u - v, c + u + v, c - u + v];
                if k % 2 == 1 {
                    corners.swap(1, 3);
                }
                cards.push(corners);
            }
        }
    }
    cards
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::{ClassifyOptions, classify};
    use crate::scene::Class;

    #[test]
    fn the_demo_tree_is_deterministic_and_looks_like_a_tree() {
        let config = DemoTreeConfig::default();
        let a = demo_tree(&config);
        let b = demo_tree(&config);
        assert_eq!(a.parts[0].positions, b.parts[0].positions);
        assert_eq!(a.parts[1].positions, b.parts[1].positions);
        let other = demo_tree(&DemoTreeConfig { seed: 2, ..config.clone() });
        assert_ne!(a.parts[0].positions, other.parts[0].positions);
        assert_eq!(a.parts[0].triangles.len(), 2 * config.leaves as usize);
        assert!(a.parts[1].triangles.len() > 1000, "trunk and branches as tubes");
        let classes: Vec<Class> = classify(&a, &ClassifyOptions::default()).iter().map(|c| c.class).collect();
        assert_eq!(classes, [Class::Leaf, Class::Bark]);
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for p in a.parts.iter().flat_map(|p| &p.positions) {
            let p = Vec3::from_array(*p);
            assert!(p.is_finite());
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let extent = hi - lo;
        assert!(lo.y > -0.5 && extent.y > config.height, "grows up from the ground: {lo} .. {hi}");
        assert!(extent.x > 0.3 * extent.y && extent.x < 2.0 * extent.y, "a crown, not a pole: {extent}");
        for part in &a.parts {
            assert!(part.triangles.iter().flatten().all(|&i| (i as usize) < part.positions.len()));
        }
    }
}
