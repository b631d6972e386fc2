//! Baseline: discrete LoD chains from a general mesh simplifier (spec §6.12). This is what a
//! user without treelod gets from meshoptimizer (the `meshopt` crate, meshoptimizer 1.3): for
//! each tree, a few levels that keep a share of its source triangles (by default 50 %, 25 %,
//! 10 %, 5 % and 1 %). Each level has a geometric error in metres, so that a runtime can switch
//! levels by projected size with treelod's pixel thresholds.
//!
//! - **Groups.** A tree's triangles are grouped by material and class (bark, leaf), in ascending
//!   order, and each group is simplified on its own, as gltfpack simplifies each primitive on its
//!   own. A group of `n` triangles aims at `max(1, round(fraction·n))` triangles. A level is the
//!   union of its groups, so it aims at about `fraction` of the tree's triangles.
//! - **Welding.** Inside a group, vertices with the same position (bit for bit; `+0` and `−0` are
//!   equal) become one vertex before simplifying. glTF splits vertices at UV and normal seams,
//!   and meshoptimizer collapses seam vertices only along their seams. On a flat-shaded model,
//!   every triangle has three vertices of its own, and nothing can collapse. Measured without
//!   welding: the Quaternius tree's bark stayed at all of its 2,360 triangles at every level, the
//!   orchid's at 4,584 of 4,736, and the jacaranda's at 15.8k of 26k at 1 %. With welding, all
//!   three reach their targets or go a little under, apart from the jacaranda's trunk at 1 %.
//!   Every output index is an input vertex: the container stores a chain as triangles over its
//!   existing vertex array (§6.12). At a former seam, each corner of an output triangle is
//!   written as the copy of its position (among those the group's triangles use) whose normal
//!   lies nearest the triangle's face normal, ties to the lowest input id. Where the copies
//!   differ only in UV (smooth shading) that is the lowest id; on a flat-shaded source, whose
//!   positions have a copy per face, it is the copy of a face the triangle lies along, so a
//!   simplified low-poly tree keeps its facets lit as faces. (Written as the lowest id, as
//!   gltfpack's position-only welding leaves it, a triangle took a neighbouring face's normal
//!   at its corners and lit as a smooth blend of faces it does not lie in. Measured on the
//!   shared Quaternius tree, `eval` of a scene of 150 trees scattered over 29 × 29 m, 12 views
//!   along the ground and from 6 m up, 480×270, `--technique lod-chain,policy`: the chain's
//!   FLIP 0.0398 → 0.0361, its RMSE 0.01809 → 0.01814; the policy's FLIP 0.0458 → 0.0436, RMSE
//!   0.02201 → 0.02198. `eval --orbit 2,8,32` of the lone tree moved by at most 0.00001; the
//!   oak's chain is the same byte for byte, the pine's, orchid's and jacaranda's differ and
//!   read the same there.) UVs are not chosen: a copy at a UV seam keeps the lowest id's.
//! - **Compact buffers.** meshoptimizer sees only the group's welded vertices, renumbered from
//!   0. Its cost and its extent (the unit of relative errors) then follow the group, not the
//!   block.
//! - **Bark**: `meshopt_simplify` with `ErrorAbsolute`, and an error limit equal to the group's
//!   extent (`meshopt_simplifyScale`). That is no practical limit, so levels reach their targets
//!   wherever topology allows. There is no `Prune`, although gltfpack sets it by default: on the
//!   seven test models it changed only the pine's two coarsest bark levels, by 1 and 6
//!   triangles, and it can overshoot to nothing. Its clean-up pass removes every piece under a
//!   growing cutoff at once: aiming at 1 %, it removed all 12,860 triangles of the jacaranda's
//!   trunk, and 2,000 leaf cards whose faces are stored twice all vanished together.
//! - **Foliage** does what gltfpack does with `-sa` (aggressive): the regular simplifier as for
//!   bark first. When that stays above the target, `meshopt_simplifySloppy` runs on its result.
//!   It gets an error limit of 1, its largest, so it gets to or under the target whenever it
//!   returns anything. Its error is relative to the buffer's extent; multiplied by
//!   `meshopt_simplifyScale` of the same buffer it becomes metres, and it adds to the regular
//!   pass's error. meshoptimizer 1.3's regular simplifier reduces disconnected leaf cards itself:
//!   border collapses turn a quad into a triangle, then remove it. So on all seven models the
//!   sloppy fallback never ran. It is there for foliage that cannot collapse, e.g. faces stored
//!   twice. If the sloppy result is empty (a target below any grid's count), the regular result
//!   stays.
//! - **From the source.** Each level is simplified from the group's source triangles, not from
//!   the previous level, as a gltfpack user makes each LoD with its own `-si` run. The error
//!   meshoptimizer returns is then measured against the source itself. A chain that feeds each
//!   level the previous one, as meshoptimizer's README suggests, has to sum the step errors to
//!   bound the error. Measured at 1 %, those sums were 2 to 5 times the direct errors (the
//!   willow's leaves: 0.22 m against 0.045 m), and a runtime would switch levels later than it
//!   needs to. This costs about 2.3 times the simplification work of a chain, but the levels are
//!   independent and run in parallel. The 669k-triangle maple takes 1.0 s on 2 cores.
//! - **Error** of a level: the largest of its groups' errors, in metres. It is meshoptimizer's
//!   quadric distance of the simplified surface from the source, and it is one-sided: a removed
//!   leaf card counts for its own size, not for the hole it leaves. So foliage levels keep small
//!   errors however many cards they drop: the willow's leaves measure 4.5 cm at 50 % and at 1 %.
//!   Along the chain a running maximum keeps the error non-decreasing, because levels are
//!   simplified independently and a coarser level can come out with a smaller error.
//! - **Bark-first levels** ([`LodChainConfig::bark_first`], on by default). Simplified foliage
//!   loses the image long before simplified bark does: a leaf card that collapses or vanishes
//!   is a hole, a branch of fewer sides hardly shows. So each tree of leaves and bark also gets,
//!   per fraction, a level of every leaf triangle as the source has it (the full mesh's) and
//!   the bark of that fraction's level, with the bark's error; its fraction is what it keeps of
//!   the tree. Only the leading fractions whose bark keeps [`BARK_AREA_KEPT`] (90 %) of the
//!   bark's area get one (a coarser bark collapses branches, as the impostor trees' bark rule
//!   says), so a tree gets none where even half its bark loses area (the shared orchid). The
//!   levels of both kinds are ordered by that fraction, so they alternate. These are the near
//!   levels that SpeedTree-like chains draw (branches reduced before leaves); the policy picks
//!   among all levels by the image error the build measures for each (spec §6.17), so a level
//!   that does not keep the image is not drawn. Measured (the build's calibration, mean
//!   multi-scale RMSE over every view against the supersampled full mesh, at 256 pixels high):
//!   the shared oak's bark-first levels at 0.5 and 0.25 of its bark read 0.0162 (16,393
//!   triangles) and 0.0169 (13,395) against the full mesh's 0.0160 (22,566), where the chain's
//!   own level 0 (11,113) reads 0.0270; the pine's at 0.5, 0.0269 (13,277) against 0.0270
//!   (19,384); the Quaternius tree's at 0.5, 0.25 and 0.1, 0.0047 (1,708), 0.0060 (1,118) and
//!   0.0123 (764) against 0.0042 (2,888). A block whose trees would get different numbers of
//!   levels gets none, as its trees switch levels together.
//! - **Guards.** Input triangles with a repeated vertex (after welding) or a non-finite corner
//!   are ignored; degenerate output triangles are dropped. A group's level never has more
//!   triangles than its previous level and is never empty: such a result is replaced by the
//!   group's previous level (or its source). So no group vanishes from a level. A tree with no
//!   usable triangles gets no levels.
//!
//! Deterministic: meshoptimizer is, hash maps are only looked up, never iterated, and rayon runs
//! over `(group, level)` pairs collected in order. The same input gives the same output for any
//! thread count.

use std::collections::HashMap;

use meshopt::{SimplifyOptions, VertexDataAdapter};
use rayon::prelude::*;
use treelod_format::pack::oct_decode;
use treelod_format::{Setting, VertexRecord};
use treelod_runtime::impostor::BARK_AREA_KEPT;

use crate::billboard::OctahedralConfig;
use crate::error::BuildError;

/// Default shares of a tree's source triangles, finest level first.
pub const DEFAULT_FRACTIONS: [f32; 5] = [0.5, 0.25, 0.1, 0.05, 0.01];

/// Most levels a chain may have.
pub const MAX_LEVELS: usize = 16;

/// Error limit of the regular simplifier, as a share of the group's extent: 1 is no practical
/// limit (a deviation as large as the whole group).
const REGULAR_LIMIT: f32 = 1.0;

/// Error limit of the sloppy simplifier, relative to the group's extent: its largest value, with
/// which it always gets to or under the target.
const SLOPPY_LIMIT: f32 = 1.0;

/// A triangle of the block as the chain builder sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChainTriangle {
    /// Indices into the block's vertices.
    pub v: [u32; 3],
    /// Material id; the output triangles keep it.
    pub material: u32,
    /// Tree id; each tree gets its own chain.
    pub tree: u32,
    /// Foliage (`true`) or bark (`false`): selects the simplifier.
    pub leaf: bool,
}

/// Tunables of the chains (recorded in the container's settings as `baselines.*`, spec §7.1).
#[derive(Clone, Debug, PartialEq)]
pub struct LodChainConfig {
    /// Share of each tree's source triangles that each level aims at, finest first: each in
    /// `(0, 1)`, strictly decreasing, 1 to 16 of them. Default `[0.5, 0.25, 0.1, 0.05, 0.01]`.
    pub fractions: Vec<f32>,
    /// Also make, for each fraction, a *bark-first* level: every leaf triangle of the tree as
    /// the source has it, and the bark simplified as that fraction's level simplifies it (module
    /// documentation). Default `true`; `false` gives the chain as gltfpack makes it.
    pub bark_first: bool,
    /// How each tree's octahedral impostor is baked, where the billboards are (with impostors,
    /// [`crate::BuildConfig::baselines`]): its views and their texels. Default 16 × 16 views of
    /// 96 texels.
    pub octahedral: OctahedralConfig,
}

impl Default for LodChainConfig {
    fn default() -> Self {
        Self { fractions: DEFAULT_FRACTIONS.to_vec(), bark_first: true, octahedral: OctahedralConfig::default() }
    }
}

impl LodChainConfig {
    /// Checks the ranges documented on the fields.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the field.
    pub fn validate(&self) -> Result<(), BuildError> {
        let f = &self.fractions;
        if f.is_empty()
            || f.len() > MAX_LEVELS
            || f.iter().any(|&x| !(x > 0.0 && x < 1.0))
            || f.windows(2).any(|w| w[1] >= w[0])
        {
            return Err(BuildError::Setting(format!(
                "LoD chain fractions {f:?}: 1 to {MAX_LEVELS} of them, strictly decreasing, each in (0, 1)"
            )));
        }
        self.octahedral.validate()
    }

    /// The settings to record in the container's metadata (spec §7.1), e.g.
    /// `baselines.lod_fractions = 0.5,0.25,0.1,0.05,0.01`.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        let fractions: Vec<String> = self.fractions.iter().map(f32::to_string).collect();
        vec![
            Setting { key: "baselines.lod_fractions".into(), value: fractions.join(",") },
            Setting { key: "baselines.bark_first".into(), value: self.bark_first.to_string() },
        ]
    }
}

/// One level of one tree's chain.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainLevel {
    /// Tree id, as in the input triangles.
    pub tree: u32,
    /// Position in the tree's chain, 0 the finest.
    pub level: u32,
    /// Share of the tree's source triangles aimed at: one of [`LodChainConfig::fractions`], or
    /// for a bark-first level the leaves' share plus that fraction of the bark's.
    pub fraction: f32,
    /// Geometric error against the source, metres: finite, `≥ 0`, non-decreasing along the chain.
    pub error: f32,
    /// Triangles as indices into the input vertices, each with its material.
    pub triangles: Vec<([u32; 3], u32)>,
}

/// A group's key: tree, material, leaf; the sort order of groups.
type GroupKey = (u32, u32, bool);

/// A group's triangles over a compact buffer of its welded vertices.
struct Local {
    /// Input id written for each local vertex where no face normal chooses among its copies
    /// ([`Local::corner`]): the lowest input id of its position.
    ids: Vec<u32>,
    /// The input ids of each local vertex's position (every copy the group's triangles use),
    /// ascending: those of local vertex `l` at `copies[copy_start[l]..copy_start[l + 1]]`.
    copies: Vec<u32>,
    /// Where each local vertex's copies start in `copies`, one more entry than vertices.
    copy_start: Vec<u32>,
    /// Position of each local vertex, metres.
    positions: Vec<[f32; 3]>,
    /// The group's usable triangles, three local indices each.
    indices: Vec<u32>,
}

impl Local {
    /// The input vertex written for corner `l` (a local vertex) of an output triangle whose face
    /// normal is `face` (need not be unit): among the copies of its position, the one whose
    /// normal lies nearest the face's (the largest dot product; ties, and a zero face normal,
    /// keep the lowest id). A flat-shaded source has a copy per face at each corner, and this
    /// keeps its facets lit as faces again (module documentation); where every copy has the same
    /// normal (smooth shading, UV seams) it is the lowest id.
    fn corner(&self, vertices: &[VertexRecord], l: u32, face: glam::Vec3) -> u32 {
        let copies = &self.copies[self.copy_start[l as usize] as usize..self.copy_start[l as usize + 1] as usize];
        let lowest = self.ids[l as usize];
        if copies.len() < 2 || face == glam::Vec3::ZERO {
            return lowest;
        }
        let facing = |v: u32| face.dot(glam::Vec3::from_array(oct_decode(vertices[v as usize].normal)));
        let (mut best, mut best_dot) = (lowest, facing(lowest));
        for &v in copies {
            let d = facing(v);
            if d > best_dot {
                (best, best_dot) = (v, d);
            }
        }
        best
    }

    /// The input vertices of the output triangle of local vertices `c` ([`Local::corner`]).
    fn triangle(&self, vertices: &[VertexRecord], c: &[u32]) -> [u32; 3] {
        let p = |i: u32| glam::Vec3::from_array(self.positions[i as usize]);
        let face = (p(c[1]) - p(c[0])).cross(p(c[2]) - p(c[0]));
        [0, 1, 2].map(|k| self.corner(vertices, c[k], face))
    }
}

/// Builds the LoD chain of every tree of a block (see the module documentation). The levels
/// come sorted by `(tree, level)`; each tree that has usable triangles gets one level per
/// fraction.
///
/// # Errors
/// [`BuildError::Setting`] for a bad `config`.
///
/// # Panics
/// If a triangle indexes past `vertices`.
pub fn build_lod_chain(
    vertices: &[VertexRecord],
    triangles: &[ChainTriangle],
    config: &LodChainConfig,
) -> Result<Vec<ChainLevel>, BuildError> {
    config.validate()?;
    let fractions = &config.fractions;

    // Stage: group triangles by (tree, material, class), in that order.
    let mut keys: Vec<GroupKey> = triangles.iter().map(|t| (t.tree, t.material, t.leaf)).collect();
    keys.sort_unstable();
    keys.dedup();
    let mut groups: Vec<Vec<[u32; 3]>> = vec![Vec::new(); keys.len()];
    for t in triangles {
        assert!(t.v.iter().all(|&v| (v as usize) < vertices.len()), "triangle {:?} indexes past the vertices", t.v);
        if let Ok(g) = keys.binary_search(&(t.tree, t.material, t.leaf)) {
            groups[g].push(t.v);
        }
    }

    // Stage: weld each group into a compact buffer.
    let locals: Vec<Local> = groups.par_iter().map(|tris| weld(vertices, tris)).collect();

    // Stage: simplify every (group, level) from the group's source.
    let jobs: Vec<(usize, usize)> = (0..keys.len()).flat_map(|g| (0..fractions.len()).map(move |l| (g, l))).collect();
    let simplified: Vec<(Vec<u32>, f32)> =
        jobs.par_iter().map(|&(g, l)| simplify_level(&locals[g], keys[g].2, fractions[l])).collect();

    // Stage: each tree's levels (with bark-first levels where it has leaves and bark to
    // simplify), renumbered per tree. A block switches its trees' levels together (spec §6.12),
    // so where its trees would get different numbers of levels, none gets bark-first levels.
    let trees: Vec<std::ops::Range<usize>> = {
        let mut trees = Vec::new();
        let mut first = 0;
        while first < keys.len() {
            let end = first + keys[first..].iter().take_while(|k| k.0 == keys[first].0).count();
            if !locals[first..end].iter().all(|l| l.indices.is_empty()) {
                trees.push(first..end);
            }
            first = end;
        }
        trees
    };
    let chains = |bark_first: bool| -> Vec<Vec<ChainLevel>> {
        trees
            .iter()
            .map(|range| {
                tree_levels(vertices, range.clone(), &keys, &groups, &locals, &simplified, fractions, bark_first)
            })
            .collect()
    };
    let mut by_tree = chains(config.bark_first);
    if by_tree.windows(2).any(|w| w[0].len() != w[1].len()) {
        by_tree = chains(false);
    }
    Ok(by_tree.into_iter().flatten().collect())
}

/// One tree's levels (its groups `range` of `keys`): per fraction the union of its groups'
/// latest levels, and with `bark_first` (for a tree with leaves and bark) a bark-first level,
/// every leaf triangle of the source with that level's bark; finest first by fraction (a
/// bark-first level whose share is not below the previous level's is left out), numbered, with
/// the running maximum of errors.
#[expect(clippy::too_many_arguments, reason = "the block, the tree's groups and what was made of them")]
fn tree_levels(
    vertices: &[VertexRecord],
    range: std::ops::Range<usize>,
    keys: &[GroupKey],
    groups: &[Vec<[u32; 3]>],
    locals: &[Local],
    simplified: &[(Vec<u32>, f32)],
    fractions: &[f32],
    bark_first: bool,
) -> Vec<ChainLevel> {
    let tree = keys[range.start].0;
    let is_leaf = |g: usize| keys[g].2;
    let mut bark_first = bark_first
        && range.clone().any(|g| is_leaf(g) && !groups[g].is_empty())
        && range.clone().any(|g| !is_leaf(g) && locals[g].indices.len() > 3);
    let source: usize = range.clone().map(|g| groups[g].len()).sum();
    // The bark's area in the source, and in the level being made: bark-first levels stop at the
    // first whose bark keeps less than `BARK_AREA_KEPT` of it (branches collapsed).
    let bark_area = |indices: &[u32], g: usize| -> f64 {
        let p = |i: u32| glam::Vec3::from_array(locals[g].positions[i as usize]);
        indices.chunks_exact(3).map(|c| f64::from((p(c[1]) - p(c[0])).cross(p(c[2]) - p(c[0])).length())).sum()
    };
    let source_bark: f64 = range.clone().filter(|&g| !is_leaf(g)).map(|g| bark_area(&locals[g].indices, g)).sum();
    let leaves: usize = range.clone().filter(|&g| is_leaf(g)).map(|g| groups[g].len()).sum();
    // Each group's latest level: its source before level 0.
    let mut kept: Vec<(&[u32], f32)> = locals[range.clone()].iter().map(|l| (l.indices.as_slice(), 0.0)).collect();
    let mut levels: Vec<ChainLevel> = Vec::new();
    for (level, &fraction) in fractions.iter().enumerate() {
        let mut per_group: Vec<Vec<([u32; 3], u32)>> = Vec::with_capacity(range.len());
        let (mut error, mut bark_error, mut bark_aimed) = (0.0f32, 0.0f32, 0usize);
        for (k, g) in range.clone().enumerate() {
            // A result that is empty or larger than the group's previous level keeps that one.
            let (indices, e) = &simplified[g * fractions.len() + level];
            if !indices.is_empty() && indices.len() <= kept[k].0.len() {
                kept[k] = (indices.as_slice(), *e);
            }
            let (indices, e) = kept[k];
            error = error.max(e);
            if !is_leaf(g) {
                bark_error = bark_error.max(e);
                let count = locals[g].indices.len() / 3;
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=count")]
                let aimed = ((f64::from(fraction) * count as f64).round() as usize).clamp(1, count.max(1));
                bark_aimed += aimed;
            }
            let local = &locals[g];
            per_group.push(
                indices
                    .chunks_exact(3)
                    .map(|c| local.triangle(vertices, c))
                    .filter(|v| v[0] != v[1] && v[1] != v[2] && v[2] != v[0])
                    .map(|v| (v, keys[g].1))
                    .collect(),
            );
        }
        let kept_bark: f64 = range
            .clone()
            .zip(&kept)
            .filter(|&(g, _)| !is_leaf(g))
            .map(|(g, &(indices, _))| bark_area(indices, g))
            .sum();
        bark_first &= kept_bark >= BARK_AREA_KEPT * source_bark;
        if bark_first {
            // Leaves as TRIANGLES holds them, bark as this level has it, the groups in order.
            let mut triangles = Vec::new();
            for (g, simplified) in range.clone().zip(&per_group) {
                if is_leaf(g) {
                    triangles.extend(groups[g].iter().map(|&v| (v, keys[g].1)));
                } else {
                    triangles.extend_from_slice(simplified);
                }
            }
            #[expect(clippy::cast_precision_loss, clippy::cast_possible_truncation, reason = "a share")]
            let share = ((leaves + bark_aimed) as f64 / source.max(1) as f64) as f32;
            levels.push(ChainLevel { tree, level: 0, fraction, error, triangles: per_group.concat() });
            levels.push(ChainLevel { tree, level: 0, fraction: share, error: bark_error, triangles });
        } else {
            levels.push(ChainLevel { tree, level: 0, fraction, error, triangles: per_group.concat() });
        }
    }
    // Finest first (stable: a chain level before a bark-first level of the same share, which is
    // then left out, as is one whose share is not in (0, 1)).
    levels.sort_by(|a, b| b.fraction.total_cmp(&a.fraction));
    let mut out: Vec<ChainLevel> = Vec::with_capacity(levels.len());
    let mut running = 0.0f32;
    for mut level in levels {
        let previous = out.last().map_or(1.0, |l| l.fraction);
        if !(level.fraction < previous && level.fraction > 0.0) {
            continue;
        }
        // meshoptimizer's errors are finite for finite input; keep the spec's promise anyway.
        running = running.max(if level.error.is_finite() { level.error } else { f32::MAX });
        level.error = running;
        #[expect(clippy::cast_possible_truncation, reason = "at most 2 × MAX_LEVELS levels")]
        let number = out.len() as u32;
        level.level = number;
        out.push(level);
    }
    out
}

/// Welds a group's vertices by exact position into a compact buffer, dropping triangles with a
/// repeated (welded) vertex or a non-finite corner.
fn weld(vertices: &[VertexRecord], tris: &[[u32; 3]]) -> Local {
    let mut local = Local {
        ids: Vec::new(),
        copies: Vec::new(),
        copy_start: Vec::new(),
        positions: Vec::new(),
        indices: Vec::with_capacity(tris.len() * 3),
    };
    let mut by_position: HashMap<[u32; 3], u32> = HashMap::new();
    // (local vertex, input id) of every corner of a usable triangle.
    let mut used: Vec<(u32, u32)> = Vec::with_capacity(tris.len() * 3);
    for tri in tris {
        let corners = tri.map(|v| vertices[v as usize].position);
        if corners.iter().flatten().any(|x| !x.is_finite()) {
            continue;
        }
        let welded = tri.map(|v| {
            let p = vertices[v as usize].position;
            // +0 and −0 are the same position.
            let key = p.map(|x| if x == 0.0 { 0 } else { x.to_bits() });
            #[expect(clippy::cast_possible_truncation, reason = "no more local vertices than u32 input ids")]
            let next = local.ids.len() as u32;
            let l = *by_position.entry(key).or_insert(next);
            if l == next {
                local.ids.push(v);
                local.positions.push(p);
            } else {
                local.ids[l as usize] = local.ids[l as usize].min(v);
            }
            l
        });
        if welded[0] != welded[1] && welded[1] != welded[2] && welded[2] != welded[0] {
            local.indices.extend_from_slice(&welded);
            used.extend(welded.iter().copied().zip(tri.iter().copied()));
        }
    }
    used.sort_unstable();
    used.dedup();
    local.copy_start = vec![0; local.ids.len() + 1];
    for &(l, _) in &used {
        local.copy_start[l as usize + 1] += 1;
    }
    for l in 0..local.ids.len() {
        local.copy_start[l + 1] += local.copy_start[l];
    }
    local.copies = used.into_iter().map(|(_, v)| v).collect();
    local
}

/// Simplifies a group from its source towards `fraction` of its triangles: the result (local
/// indices, possibly none) and its error against the source, metres.
fn simplify_level(local: &Local, leaf: bool, fraction: f32) -> (Vec<u32>, f32) {
    let count = local.indices.len() / 3;
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=count")]
    let target = ((f64::from(fraction) * count as f64).round() as usize).max(1);
    if count <= target {
        return (local.indices.clone(), 0.0);
    }
    let adapter = VertexDataAdapter::new(meshopt::typed_to_bytes(&local.positions), size_of::<[f32; 3]>(), 0)
        .expect("a [f32; 3] buffer divides into 12-byte vertices");
    // Metres per unit of relative error: the group's extent.
    let scale = meshopt::simplify_scale(&adapter);

    // Stage: the regular simplifier, with no practical error limit.
    let mut error = 0.0f32;
    let mut result = meshopt::simplify(
        &local.indices,
        &adapter,
        target * 3,
        REGULAR_LIMIT * scale,
        SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );

    // Stage: foliage still above the target goes on with the sloppy simplifier (gltfpack -sa).
    if leaf && result.len() / 3 > target {
        let mut relative = 0.0f32;
        let sloppy = meshopt::simplify_sloppy(&result, &adapter, target * 3, SLOPPY_LIMIT, Some(&mut relative));
        if !sloppy.is_empty() {
            result = sloppy;
            error += relative * scale;
        }
    }
    (result, error)
}

#[cfg(test)]
mod tests {
    use std::collections::HashSet;

    use super::*;
    use crate::classify::{ClassifyOptions, classify};
    use crate::rng::SplitMix64;
    use crate::scene::Class;

    /// A block under construction: vertices with positions only, and chain triangles.
    #[derive(Default)]
    struct Block {
        vertices: Vec<VertexRecord>,
        triangles: Vec<ChainTriangle>,
    }

    impl Block {
        /// Appends a mesh (local indices) as one (tree, material, class) group.
        fn push(&mut self, positions: &[[f32; 3]], tris: &[[u32; 3]], tree: u32, material: u32, leaf: bool) {
            let base = u32::try_from(self.vertices.len()).expect("small test meshes");
            self.vertices
                .extend(positions.iter().map(|&position| VertexRecord { position, ..VertexRecord::default() }));
            self.triangles.extend(tris.iter().map(|t| ChainTriangle { v: t.map(|i| base + i), material, tree, leaf }));
        }

        /// The chain as gltfpack makes it (no bark-first levels).
        fn chain(&self, fractions: &[f32]) -> Vec<ChainLevel> {
            self.chain_with(fractions, false)
        }

        fn chain_with(&self, fractions: &[f32], bark_first: bool) -> Vec<ChainLevel> {
            let config = LodChainConfig { fractions: fractions.to_vec(), bark_first, ..LodChainConfig::default() };
            build_lod_chain(&self.vertices, &self.triangles, &config).expect("valid config")
        }
    }

    /// A flat `n × n` grid of quads in the XZ plane, 1 m cells.
    fn grid(n: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let positions = (0..=n).flat_map(|z| (0..=n).map(move |x| [x as f32, 0.0, z as f32])).collect();
        let id = |x: u32, z: u32| z * (n + 1) + x;
        let tris = (0..n)
            .flat_map(|z| {
                (0..n).flat_map(move |x| {
                    [[id(x, z), id(x, z + 1), id(x + 1, z)], [id(x + 1, z), id(x, z + 1), id(x + 1, z + 1)]]
                })
            })
            .collect();
        (positions, tris)
    }

    /// An open tube along Y: `sides` around, `rings` segments of 0.5 m, radius 0.3 m.
    fn tube(sides: u32, rings: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let positions = (0..=rings)
            .flat_map(|r| {
                (0..sides).map(move |s| {
                    let a = std::f32::consts::TAU * s as f32 / sides as f32;
                    [0.3 * a.cos(), 0.5 * r as f32, 0.3 * a.sin()]
                })
            })
            .collect();
        let id = |s: u32, r: u32| r * sides + s % sides;
        let tris = (0..rings)
            .flat_map(|r| {
                (0..sides).flat_map(move |s| {
                    [[id(s, r), id(s, r + 1), id(s + 1, r)], [id(s + 1, r), id(s, r + 1), id(s + 1, r + 1)]]
                })
            })
            .collect();
        (positions, tris)
    }

    /// `count` disconnected 10 cm leaf quads scattered in a 10 m box, each face stored `copies`
    /// times.
    fn leaf_quads(count: u32, copies: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut rng = SplitMix64(seed);
        let mut positions = Vec::new();
        let mut tris = Vec::new();
        for q in 0..count {
            let c = [rng.range(0.0, 10.0), rng.range(0.0, 10.0), rng.range(0.0, 10.0)];
            positions
                .extend([[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]].map(|[dx, dy]| [c[0] + dx, c[1] + dy, c[2]]));
            let b = 4 * q;
            for _ in 0..copies {
                tris.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
            }
        }
        (positions, tris)
    }

    /// Checks the invariants of one tree's levels: numbered in order, the configured fractions,
    /// finite non-decreasing errors; and each level's count near `fraction × source` (`groups`
    /// rounding slack, and up to 30 % under, since meshoptimizer's passes overshoot a little).
    fn check_tree(levels: &[ChainLevel], tree: u32, fractions: &[f32], source: usize, groups: usize) {
        assert_eq!(levels.len(), fractions.len());
        let mut previous = 0.0;
        for (l, (level, &fraction)) in levels.iter().zip(fractions).enumerate() {
            assert_eq!((level.tree, level.level as usize, level.fraction), (tree, l, fraction));
            assert!(level.error.is_finite() && level.error >= previous, "level {l}: {} after {previous}", level.error);
            previous = level.error;
            let target = f64::from(fraction) * source as f64;
            let count = level.triangles.len() as f64;
            assert!(count <= target * 1.02 + groups as f64, "level {l}: {count} triangles for {target}");
            assert!(count >= target * 0.7, "level {l}: {count} triangles for {target}");
        }
    }

    #[test]
    fn grid_and_tube_reach_their_fractions() {
        let mut block = Block::default();
        let (p, t) = grid(48);
        block.push(&p, &t, 0, 0, false);
        let (p, t) = tube(16, 64);
        block.push(&p, &t, 1, 0, false);
        let levels = block.chain(&DEFAULT_FRACTIONS);
        assert_eq!(levels.len(), 10);
        check_tree(&levels[..5], 0, &DEFAULT_FRACTIONS, 48 * 48 * 2, 1);
        check_tree(&levels[5..], 1, &DEFAULT_FRACTIONS, 16 * 64 * 2, 1);
        // A flat grid simplifies without leaving its plane: what error there is is rounding in
        // meshoptimizer's quadrics (the square root of a tiny residue), under 10⁻⁴ of the 48 m grid.
        let errors: Vec<f32> = levels.iter().map(|l| l.error).collect();
        assert!(errors[..5].iter().all(|&e| e < 48e-4), "{errors:?}");
        // The tube cannot: its coarse levels cut corners, by less than its diameter.
        assert!(levels[9].error > 1e-3 && levels[9].error < 0.6, "{errors:?}");
    }

    #[test]
    fn disconnected_leaf_quads_reach_their_fractions() {
        let mut block = Block::default();
        let (p, t) = leaf_quads(2000, 1, 3);
        block.push(&p, &t, 0, 0, true);
        let levels = block.chain(&DEFAULT_FRACTIONS);
        check_tree(&levels, 0, &DEFAULT_FRACTIONS, 4000, 1);
        // Removing a card costs its own size (14 cm diagonal) in meshoptimizer's error.
        let errors: Vec<f32> = levels.iter().map(|l| l.error).collect();
        assert!(errors.iter().all(|&e| e > 0.0 && e < 0.15), "{errors:?}");
    }

    #[test]
    fn foliage_the_regular_simplifier_cannot_collapse_falls_back_to_sloppy() {
        // Faces stored twice lock meshoptimizer's regular simplifier: as bark nothing changes.
        let (p, t) = leaf_quads(2000, 2, 4);
        let mut bark = Block::default();
        bark.push(&p, &t, 0, 0, false);
        let levels = bark.chain(&[0.1]);
        assert_eq!((levels[0].triangles.len(), levels[0].error), (8000, 0.0));
        // As foliage the sloppy pass takes it to the target.
        let mut leaves = Block::default();
        leaves.push(&p, &t, 0, 0, true);
        let levels = leaves.chain(&[0.1]);
        // The sloppy simplifier also merges the copies, so it lands well under the target.
        let count = levels[0].triangles.len();
        assert!((300..=800).contains(&count), "{count} triangles for 800");
        assert!(levels[0].error > 0.0 && levels[0].error < 5.0, "{}", levels[0].error);
    }

    #[test]
    fn seams_are_welded_to_the_lowest_input_vertex() {
        // The grid again, with the vertices of column 24 split: the triangles right of it use
        // copies with higher ids, as glTF splits vertices at a UV seam.
        let n = 48;
        let (p, t) = grid(n);
        let mut split_p = p.clone();
        let mut copy = HashMap::new();
        for (i, q) in p.iter().enumerate() {
            if q[0] == 24.0 {
                copy.insert(i as u32, split_p.len() as u32);
                split_p.push(*q);
            }
        }
        let split_t: Vec<[u32; 3]> = t
            .iter()
            .map(|tri| {
                let right = tri.iter().any(|&v| p[v as usize][0] > 24.0);
                tri.map(|v| if right { copy.get(&v).copied().unwrap_or(v) } else { v })
            })
            .collect();
        let mut plain = Block::default();
        plain.push(&p, &t, 0, 0, false);
        let mut split = Block::default();
        split.push(&split_p, &split_t, 0, 0, false);
        let levels = split.chain(&DEFAULT_FRACTIONS);
        assert_eq!(levels, plain.chain(&DEFAULT_FRACTIONS));
        let used: HashSet<u32> = split_t.iter().flatten().copied().collect();
        for level in &levels {
            for &(v, _) in &level.triangles {
                assert!(v.iter().all(|&i| used.contains(&i) && (i as usize) < p.len()), "{v:?}");
            }
        }
    }

    #[test]
    fn a_flat_shaded_source_keeps_its_facets_lit_as_faces() {
        // A prism of 6 sides and 32 rings, flat-shaded as a low-poly tree's trunk is: each side's
        // quad has four vertices of its own with the side's normal, so every corner position has
        // a copy per side that meets there (glTF's split vertices).
        let (sides, rings) = (6u32, 32u32);
        let corner = |s: u32, r: u32| {
            let a = std::f32::consts::TAU * (s % sides) as f32 / sides as f32;
            [0.3 * a.cos(), 0.5 * r as f32, 0.3 * a.sin()]
        };
        let mut block = Block::default();
        for r in 0..rings {
            for s in 0..sides {
                let q = [corner(s, r), corner(s, r + 1), corner(s + 1, r), corner(s + 1, r + 1)];
                let (a, b, c) = (glam::Vec3::from(q[0]), glam::Vec3::from(q[1]), glam::Vec3::from(q[2]));
                let normal = treelod_format::pack::oct_encode((b - a).cross(c - a).normalize().to_array());
                let base = u32::try_from(block.vertices.len()).expect("a small mesh");
                block.vertices.extend(q.iter().map(|&position| VertexRecord {
                    position,
                    normal,
                    ..VertexRecord::default()
                }));
                for v in [[0, 1, 2], [2, 1, 3]] {
                    block.triangles.push(ChainTriangle { v: v.map(|k| base + k), material: 0, tree: 0, leaf: false });
                }
            }
        }
        let levels = block.chain(&[0.25]);
        assert_eq!(levels.len(), 1);
        // Collapsing along the prism keeps each triangle on one side: every corner written is
        // the copy of that side, lit as the side is (the lowest id of a position is the copy of
        // one side only, half a 60° turn off the other's).
        let n = |v: u32| glam::Vec3::from(oct_decode(block.vertices[v as usize].normal));
        let p = |v: u32| glam::Vec3::from(block.vertices[v as usize].position);
        assert!(levels[0].triangles.len() < (sides * rings) as usize, "{}", levels[0].triangles.len());
        for &(v, _) in &levels[0].triangles {
            let face = (p(v[1]) - p(v[0])).cross(p(v[2]) - p(v[0])).normalize();
            for corner in v {
                assert!(n(corner).dot(face) > 0.99, "{v:?}: {:?} against {face:?}", n(corner));
            }
        }
    }

    #[test]
    fn trees_and_materials_stay_apart() {
        let mut block = Block::default();
        let (p, t) = grid(20);
        block.push(&p, &t, 5, 0, false);
        let (p, t) = leaf_quads(500, 1, 5);
        block.push(&p, &t, 5, 2, true);
        let (p, t) = tube(8, 30);
        block.push(&p, &t, 2, 1, false);
        let (p, t) = leaf_quads(300, 1, 6);
        block.push(&p, &t, 2, 2, true);
        let mut group_of: HashMap<u32, (u32, u32)> = HashMap::new();
        for t in &block.triangles {
            for v in t.v {
                group_of.insert(v, (t.tree, t.material));
            }
        }
        let levels = block.chain(&DEFAULT_FRACTIONS);
        let order: Vec<(u32, u32)> = levels.iter().map(|l| (l.tree, l.level)).collect();
        assert_eq!(order, [2, 5].iter().flat_map(|&t| (0..5).map(move |l| (t, l))).collect::<Vec<_>>());
        check_tree(&levels[..5], 2, &DEFAULT_FRACTIONS, 8 * 30 * 2 + 600, 2);
        check_tree(&levels[5..], 5, &DEFAULT_FRACTIONS, 20 * 20 * 2 + 1000, 2);
        for level in &levels {
            let mut materials = HashSet::new();
            for &(v, material) in &level.triangles {
                assert!(v.iter().all(|i| group_of[i] == (level.tree, material)), "{v:?} in tree {}", level.tree);
                materials.insert(material);
            }
            // Every group keeps at least one triangle.
            assert_eq!(materials.len(), 2);
        }
    }

    #[test]
    fn config_is_validated_and_recorded() {
        assert!(LodChainConfig::default().validate().is_ok());
        for bad in [
            vec![],
            vec![0.5, 0.5],
            vec![0.25, 0.5],
            vec![1.0, 0.5],
            vec![0.5, 0.0],
            vec![-0.1],
            vec![f32::NAN],
            vec![0.9; 1].into_iter().chain((1..17).map(|i| 0.9 / (i as f32 + 1.0))).collect(),
        ] {
            let config = LodChainConfig { fractions: bad, ..LodChainConfig::default() };
            assert!(matches!(config.validate(), Err(BuildError::Setting(_))), "{config:?}");
            assert!(build_lod_chain(&[], &[], &config).is_err());
        }
        let sixteen: Vec<f32> = (0..16).map(|i| 0.9 / (i as f32 + 1.0)).collect();
        assert!(LodChainConfig { fractions: sixteen, ..LodChainConfig::default() }.validate().is_ok());
        let settings = LodChainConfig::default().settings();
        let pairs: Vec<(&str, &str)> = settings.iter().map(|s| (s.key.as_str(), s.value.as_str())).collect();
        assert_eq!(pairs, [("baselines.lod_fractions", "0.5,0.25,0.1,0.05,0.01"), ("baselines.bark_first", "true")]);
    }

    #[test]
    fn unusable_trees_get_no_levels() {
        assert!(build_lod_chain(&[], &[], &LodChainConfig::default()).expect("valid").is_empty());
        let mut block = Block::default();
        let (p, t) = grid(4);
        block.push(&p, &t, 1, 0, false);
        // Tree 0: a repeated index, and a non-finite corner.
        block.push(&[[0.0; 3], [1.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0]], &[[0, 0, 1], [0, 1, 2]], 0, 0, true);
        let levels = block.chain(&[0.5]);
        assert_eq!(levels.len(), 1);
        assert_eq!(levels[0].tree, 1);
    }

    #[test]
    #[should_panic(expected = "indexes past the vertices")]
    fn an_index_past_the_vertices_panics() {
        let triangle = ChainTriangle { v: [0, 1, 3], material: 0, tree: 0, leaf: false };
        let _ = build_lod_chain(&[VertexRecord::default(); 3], &[triangle], &LodChainConfig::default());
    }

    /// The demo tree as chain triangles: parts appended, classified as the build does.
    fn demo_block() -> Block {
        let scene = crate::demo::demo_tree(&crate::DemoTreeConfig::default());
        let classes = classify(&scene, &ClassifyOptions::default());
        let mut block = Block::default();
        for (part, class) in scene.parts.iter().zip(&classes) {
            let material = u32::try_from(part.material).expect("few materials");
            block.push(&part.positions, &part.triangles, 0, material, class.class == Class::Leaf);
        }
        block
    }

    #[test]
    fn demo_tree_chain() {
        let block = demo_block();
        let leaves = block.triangles.iter().filter(|t| t.leaf).count();
        assert!(leaves > 0 && leaves < block.triangles.len());
        let levels = block.chain(&DEFAULT_FRACTIONS);
        check_tree(&levels, 0, &DEFAULT_FRACTIONS, block.triangles.len(), 2);
        let errors: Vec<f32> = levels.iter().map(|l| l.error).collect();
        assert!(levels[4].error > 0.0 && levels[4].error < 4.0, "{errors:?}");
    }

    /// With bark-first levels, a tree of leaves and bark gets one per leading fraction whose bark
    /// keeps [`BARK_AREA_KEPT`] of its area, besides the chain's levels, all in the order of
    /// strictly decreasing shares with non-decreasing errors: each holds every leaf triangle as
    /// the source has it and the bark of the chain's level of the same fraction, and the chain's
    /// own levels are those of the chain without them. A block whose trees would get different
    /// numbers of levels gets none.
    #[test]
    fn bark_first_levels_keep_every_leaf_and_the_bark_of_a_level() {
        let block = demo_block();
        let plain = block.chain(&DEFAULT_FRACTIONS);
        let levels = block.chain_with(&DEFAULT_FRACTIONS, true);
        let shares: Vec<f32> = levels.iter().map(|l| l.fraction).collect();
        assert!(levels.len() > DEFAULT_FRACTIONS.len(), "{shares:?}");
        assert!(levels.iter().enumerate().all(|(i, l)| l.level as usize == i && l.tree == 0));
        assert!(levels.windows(2).all(|w| w[1].fraction < w[0].fraction && w[1].error >= w[0].error));
        // The demo tree's leaf and bark materials differ.
        let leaf_materials: HashSet<u32> = block.triangles.iter().filter(|t| t.leaf).map(|t| t.material).collect();
        assert!(block.triangles.iter().all(|t| t.leaf == leaf_materials.contains(&t.material)));
        let source_leaves: Vec<([u32; 3], u32)> =
            block.triangles.iter().filter(|t| t.leaf).map(|t| (t.v, t.material)).collect();
        let bark = |l: &ChainLevel| -> Vec<([u32; 3], u32)> {
            l.triangles.iter().copied().filter(|(_, m)| !leaf_materials.contains(m)).collect()
        };
        // Twice a triangle's area (the ratios below need no factor).
        let doubled = |v: [u32; 3]| {
            let p = |i: u32| glam::Vec3::from_array(block.vertices[i as usize].position);
            f64::from((p(v[1]) - p(v[0])).cross(p(v[2]) - p(v[0])).length())
        };
        let area = |l: &ChainLevel| -> f64 { bark(l).iter().map(|&(v, _)| doubled(v)).sum() };
        let source_bark: f64 = block.triangles.iter().filter(|t| !t.leaf).map(|t| doubled(t.v)).sum();
        let mut bark_first = 0;
        for level in &levels {
            if let Some(same) = plain.iter().find(|p| p.fraction == level.fraction) {
                assert_eq!(level.triangles, same.triangles, "the chain's level {}", same.level);
                continue;
            }
            bark_first += 1;
            let mut sorted: Vec<([u32; 3], u32)> =
                level.triangles.iter().copied().filter(|(_, m)| leaf_materials.contains(m)).collect();
            sorted.sort_unstable();
            let mut expected = source_leaves.clone();
            expected.sort_unstable();
            assert_eq!(sorted, expected, "every leaf triangle once");
            // The bark of the chain's level of the same rank among the bark-first ones: the
            // leading fractions, while the bark keeps its area.
            assert_eq!(bark(level), bark(&plain[bark_first - 1]), "the bark of the chain's level {}", bark_first - 1);
            assert!(bark(level).len() < block.triangles.len() - source_leaves.len(), "the bark simplified");
            assert!(area(level) >= BARK_AREA_KEPT * source_bark, "{} of {source_bark}", area(level));
        }
        assert_eq!(levels.len(), DEFAULT_FRACTIONS.len() + bark_first);
        // The next fraction's bark collapses branches: no bark-first level for it or coarser.
        if let Some(next) = plain.get(bark_first) {
            assert!(area(next) < BARK_AREA_KEPT * source_bark, "{} of {source_bark}", area(next));
        }
        // A second tree of bark alone would get fewer levels: the block gets none.
        let mut mixed = demo_block();
        let (p, t) = tube(12, 40);
        mixed.push(&p, &t, 1, 3, false);
        assert_eq!(mixed.chain_with(&DEFAULT_FRACTIONS, true), mixed.chain(&DEFAULT_FRACTIONS));
        // Two trees of leaves and bark both get them.
        let mut two = demo_block();
        let (p, t) = tube(12, 40);
        two.push(&p, &t, 1, 3, false);
        let (p, t) = leaf_quads(300, 1, 4);
        two.push(&p, &t, 1, 7, true);
        let mut second = Block::default();
        let (p, t) = tube(12, 40);
        second.push(&p, &t, 1, 3, false);
        let (p, t) = leaf_quads(300, 1, 4);
        second.push(&p, &t, 1, 7, true);
        let alone = second.chain_with(&DEFAULT_FRACTIONS, true).len();
        assert!(alone > DEFAULT_FRACTIONS.len(), "the tube keeps its area at half its triangles: {alone}");
        let levels = two.chain_with(&DEFAULT_FRACTIONS, true);
        let each = if alone == DEFAULT_FRACTIONS.len() + bark_first { alone } else { DEFAULT_FRACTIONS.len() };
        assert_eq!(levels.len(), 2 * each);
    }

    #[test]
    fn deterministic_for_any_thread_count() {
        let mut block = demo_block();
        let (p, t) = leaf_quads(800, 1, 9);
        block.push(&p, &t, 1, 7, true);
        let (p, t) = tube(12, 40);
        block.push(&p, &t, 1, 3, false);
        let run = || block.chain_with(&DEFAULT_FRACTIONS, true);
        let reference = run();
        assert_eq!(run(), reference);
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
            assert_eq!(pool.install(run), reference, "{threads} threads");
        }
    }
}
