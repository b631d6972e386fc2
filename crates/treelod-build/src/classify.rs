//! Leaf / bark classification of every part of a scene.
//!
//! Order of evidence, first match wins:
//! 1. command-line overrides (`--leaves PATTERN`, `--bark PATTERN`) matched against the material,
//!    mesh and node names;
//! 2. keywords in the material name, then the mesh name, then the node name (case-insensitive):
//!    leaf words `leaf leaves foliage needle canopy crown frond`; bark words `bark trunk branch twig
//!    stem wood`;
//! 3. geometry and appearance: a part is leaves if its material is alpha-tested (`MASK`/`BLEND`)
//!    with a texture, or its base colour is green (low-poly canopies such as Quaternius' "Green"),
//!    or it consists of small, flat pieces (mean piece extent under 5 % of the tree, pieces nearly
//!    planar);
//! 4. otherwise bark (`default`).
//!
//! Connectivity alone is not used as evidence of leaves: generators such as Sapling and ez-tree
//! make every branch a separate piece.

use glam::Vec3;

use crate::scene::{AlphaMode, Class, Part, Scene};
use crate::union_find::{find, singletons, union};

/// Leaf words matched in names (lowercase).
const LEAF_WORDS: [&str; 7] = ["leaf", "leaves", "foliage", "needle", "canopy", "crown", "frond"];
/// Bark words matched in names (lowercase).
const BARK_WORDS: [&str; 6] = ["bark", "trunk", "branch", "twig", "stem", "wood"];

/// User overrides: glob patterns (`*` any run, `?` one character; case-insensitive) matched against
/// material, mesh and node names.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ClassifyOptions {
    /// Parts matching any of these are leaves.
    pub leaves: Vec<String>,
    /// Parts matching any of these are bark (checked after `leaves`).
    pub bark: Vec<String>,
}

/// How a part's class was decided (recorded in the container's metadata, spec §7.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClassifiedBy {
    /// A command-line pattern.
    Override,
    /// The material's name.
    Name,
    /// The mesh's name.
    Mesh,
    /// The node's name.
    Node,
    /// Alpha testing, piece size, flatness and colour.
    Geometry,
    /// No evidence: bark.
    Default,
}

impl ClassifiedBy {
    /// The metadata spelling (spec §7.1).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Override => "override",
            Self::Name => "name",
            Self::Mesh => "mesh",
            Self::Node => "node",
            Self::Geometry => "geometry",
            Self::Default => "default",
        }
    }
}

/// The class of a part and the evidence for it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Classification {
    /// Leaf or bark.
    pub class: Class,
    /// The evidence.
    pub by: ClassifiedBy,
}

/// Classifies every part of `scene`, in part order.
#[must_use]
pub fn classify(scene: &Scene, options: &ClassifyOptions) -> Vec<Classification> {
    let tree_extent = scene_extent(scene);
    scene.parts.iter().map(|part| classify_part(scene, part, options, tree_extent)).collect()
}

fn classify_part(scene: &Scene, part: &Part, options: &ClassifyOptions, tree_extent: f32) -> Classification {
    let material = scene.materials.get(part.material);
    let material_name = material.map_or("", |m| m.name.as_str());
    let names = [material_name, part.mesh_name.as_str(), part.node_name.as_str()];
    let hit = |patterns: &[String]| patterns.iter().any(|p| names.iter().any(|n| glob_match(p, n)));
    if hit(&options.leaves) {
        return Classification { class: Class::Leaf, by: ClassifiedBy::Override };
    }
    if hit(&options.bark) {
        return Classification { class: Class::Bark, by: ClassifiedBy::Override };
    }
    for (name, by) in names.iter().zip([ClassifiedBy::Name, ClassifiedBy::Mesh, ClassifiedBy::Node]) {
        if let Some(class) = keyword_class(name) {
            return Classification { class, by };
        }
    }
    let masked = material.is_some_and(|m| m.alpha_mode != AlphaMode::Opaque && m.image.is_some());
    let green = material.is_some_and(|m| is_green(m.base_color));
    if masked || green || small_flat_pieces(part, tree_extent) {
        return Classification { class: Class::Leaf, by: ClassifiedBy::Geometry };
    }
    Classification { class: Class::Bark, by: ClassifiedBy::Default }
}

/// Leaf or bark if `name` contains one of the keywords as a word part. Leaf words win ties, since
/// "leaf_branch" cards are foliage.
fn keyword_class(name: &str) -> Option<Class> {
    let lower = name.to_lowercase();
    if LEAF_WORDS.iter().any(|w| lower.contains(w)) {
        Some(Class::Leaf)
    } else if BARK_WORDS.iter().any(|w| lower.contains(w)) {
        Some(Class::Bark)
    } else {
        None
    }
}

/// Greenish: green dominates red and blue.
fn is_green(c: [f32; 4]) -> bool {
    c[1] > c[0] && c[1] > c[2]
}

fn scene_extent(scene: &Scene) -> f32 {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for p in scene.parts.iter().flat_map(|p| &p.positions) {
        let v = Vec3::from_array(*p);
        if v.is_finite() {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if lo.x > hi.x { 0.0 } else { (hi - lo).max_element() }
}

/// Whether the part consists of small, nearly planar pieces (connected by shared vertices): mean
/// piece extent under 5 % of the tree and pieces whose triangle normals agree.
fn small_flat_pieces(part: &Part, tree_extent: f32) -> bool {
    let n = part.positions.len();
    if part.triangles.is_empty() || n == 0 || tree_extent <= 0.0 {
        return false;
    }
    let mut uf = singletons(n);
    for t in &part.triangles {
        if t.iter().all(|&i| (i as usize) < n) {
            union(&mut uf, t[0], t[1]);
            union(&mut uf, t[0], t[2]);
        }
    }
    // Per piece: bounds and the sum of area-weighted normals vs the sum of areas.
    let mut pieces: std::collections::BTreeMap<u32, (Vec3, Vec3, Vec3, f32)> = std::collections::BTreeMap::new();
    for t in &part.triangles {
        if t.iter().any(|&i| (i as usize) >= n) {
            continue;
        }
        let [a, b, c] = t.map(|i| Vec3::from_array(part.positions[i as usize]));
        let cross = (b - a).cross(c - a);
        let entry = pieces.entry(find(&mut uf, t[0])).or_insert((a, a, Vec3::ZERO, 0.0));
        for v in [a, b, c] {
            entry.0 = entry.0.min(v);
            entry.1 = entry.1.max(v);
        }
        // Orientation-free flatness: align each normal with the piece's running sum.
        entry.2 += if cross.dot(entry.2) < 0.0 { -cross } else { cross };
        entry.3 += cross.length();
    }
    let count = pieces.len() as f32;
    let mean_extent = pieces.values().map(|(lo, hi, _, _)| (*hi - *lo).max_element()).sum::<f32>() / count;
    let flat = pieces.values().filter(|(_, _, sum, area)| *area > 0.0 && sum.length() >= 0.9 * area).count() as f32;
    mean_extent < 0.05 * tree_extent && flat >= 0.8 * count
}

/// Case-insensitive glob match: `*` matches any run of characters, `?` one character.
#[must_use]
pub fn glob_match(pattern: &str, text: &str) -> bool {
    let p: Vec<char> = pattern.to_lowercase().chars().collect();
    let t: Vec<char> = text.to_lowercase().chars().collect();
    let (mut pi, mut ti) = (0, 0);
    let (mut star, mut mark) = (None, 0);
    while ti < t.len() {
        if pi < p.len() && (p[pi] == '?' || p[pi] == t[ti]) {
            pi += 1;
            ti += 1;
        } else if pi < p.len() && p[pi] == '*' {
            star = Some(pi);
            mark = ti;
            pi += 1;
        } else if let Some(s) = star {
            pi = s + 1;
            mark += 1;
            ti = mark;
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|&c| c == '*')
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Material;

    fn scene_with(material: &str, mesh: &str, mode: AlphaMode, color: [f32; 4], image: bool) -> Scene {
        // Two parts: a big trunk box-ish piece and the part under test made of small quads.
        let mut quads = Part { mesh_name: mesh.into(), material: 0, ..Part::default() };
        for i in 0..20 {
            let o = i as f32 * 0.5;
            let base = quads.positions.len() as u32;
            quads.positions.extend([[o, 5.0, 0.0], [o + 0.1, 5.0, 0.0], [o + 0.1, 5.1, 0.0], [o, 5.1, 0.0]]);
            quads.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        }
        let trunk = Part {
            material: 1,
            positions: vec![[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 10.0, 0.5]],
            triangles: vec![[0, 1, 2]],
            ..Part::default()
        };
        Scene {
            parts: vec![quads, trunk],
            materials: vec![
                Material {
                    name: material.into(),
                    base_color: color,
                    alpha_mode: mode,
                    image: image.then_some(0),
                    ..Material::default()
                },
                Material { name: "Wood".into(), base_color: [0.4, 0.3, 0.2, 1.0], ..Material::default() },
            ],
            ..Scene::default()
        }
    }

    #[test]
    fn names_decide_first_material_then_mesh() {
        let s = scene_with("jacaranda_tree_leaves", "tree.016", AlphaMode::Opaque, [1.0; 4], false);
        let c = classify(&s, &ClassifyOptions::default());
        assert_eq!(c[0], Classification { class: Class::Leaf, by: ClassifiedBy::Name });
        assert_eq!(c[1], Classification { class: Class::Bark, by: ClassifiedBy::Name });
        let s = scene_with("Material.001", "Bauhinia leaf 04_0", AlphaMode::Opaque, [1.0; 4], false);
        assert_eq!(classify(&s, &ClassifyOptions::default())[0].by, ClassifiedBy::Mesh);
    }

    #[test]
    fn unnamed_green_or_small_flat_pieces_are_leaves() {
        let s = scene_with("Green", "CommonTree_1", AlphaMode::Opaque, [0.2, 0.6, 0.1, 1.0], false);
        let c = classify(&s, &ClassifyOptions::default());
        assert_eq!(c[0], Classification { class: Class::Leaf, by: ClassifiedBy::Geometry });
        assert_eq!(c[1], Classification { class: Class::Bark, by: ClassifiedBy::Name }, "\"Wood\" is bark");
        let brown = scene_with("Mat", "CommonTree_1", AlphaMode::Opaque, [0.6, 0.4, 0.2, 1.0], false);
        assert_eq!(classify(&brown, &ClassifyOptions::default())[0].by, ClassifiedBy::Geometry, "small flat quads");
        let masked = scene_with("Mat", "x", AlphaMode::Mask, [1.0; 4], true);
        assert_eq!(classify(&masked, &ClassifyOptions::default())[0].by, ClassifiedBy::Geometry);
        // One large brown piece with no telling name: bark by default.
        let mut trunk = scene_with("Mat", "x", AlphaMode::Opaque, [0.6, 0.4, 0.2, 1.0], false);
        trunk.materials[1].name = "Mat.002".into();
        assert_eq!(
            classify(&trunk, &ClassifyOptions::default())[1],
            Classification { class: Class::Bark, by: ClassifiedBy::Default }
        );
    }

    #[test]
    fn overrides_win_and_globs_match() {
        let s = scene_with("jacaranda_tree_leaves", "tree", AlphaMode::Opaque, [1.0; 4], false);
        let o = ClassifyOptions { leaves: vec![], bark: vec!["*LEAVES".into()] };
        assert_eq!(classify(&s, &o)[0], Classification { class: Class::Bark, by: ClassifiedBy::Override });
        assert!(glob_match("leaf?", "Leafs"));
        assert!(glob_match("*trunk*", "Bauhinia_blak_trunk"));
        assert!(!glob_match("trunk", "trunk2"));
        assert!(glob_match("*", ""));
    }
}
