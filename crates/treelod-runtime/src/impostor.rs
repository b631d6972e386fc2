//! Impostor planes at run time (Garcia, Sbert and Szirmay-Kalos 2005; spec §6.10, §10): which
//! prefix of each cell's planes an instance draws.
//!
//! A container's planes are nested levels flattened into sequential-point-tree order: per cell,
//! sorted by `hi`, largest first, each with its interval `[lo, hi)` of world-size thresholds. For
//! an instance, [`PlaneLod::select`] turns the pixel threshold `s_min` into `τ` at the distance of
//! each cell holding planes (the block cell at the block centre's distance, spec §6.2) as for
//! points (§10.1), and passes on the leading planes with `hi > τ`; the vertex shader then drops
//! those failing [`plane_drawn`] (`lo ≤ τ < hi`), so exactly one level covers each leaf.
//!
//! [`select`] is the per-frame selection of the trees drawn with planes (see [`crate::draws`]),
//! their bark included ([`ImpostorBark`]).

use std::ops::Deref;

use glam::{Mat4, Vec3};
use treelod_format::{Container, PlaneRecord, Range, TriangleRecord, VertexRecord};

use crate::baseline::instance_tau;
use crate::draws::{
    PrefixDraw, Representations, Scene, TechniqueSettings, TreeDraws, TriangleDraw, TriangleSource, select_into,
};
use crate::frame::{Camera, CellPrefix, Frustum, Instance, ModelLod};
use crate::spt_lod::{SptCell, SptLod, spt_drawn};
use crate::technique::Technique;

/// Whether a plane is drawn at `τ` (spec §10): its interval holds `τ`.
#[must_use]
pub fn plane_drawn(plane: &PlaneRecord, tau: f32) -> bool {
    spt_drawn(plane, tau)
}

/// No parent plane ([`plane_parents`]): a root of its cell's hierarchy.
pub const NO_PARENT: u32 = u32::MAX;

/// The parent of every plane of `planes` (a container's `PLANES`, whose cells' ranges are
/// `ranges`): the index of the plane of the next coarser level that holds its leaves, or
/// [`NO_PARENT`] for a root. The levels nest (spec §6.10), so within a cell the leaf runs form a
/// forest and a plane's parent is the smallest run around its own; its interval starts where the
/// plane's ends (`parent.lo == hi`). Garcia's smooth level of detail interpolates a plane towards
/// its parent before the parent takes over ([`morph_share`]).
#[must_use]
pub fn plane_parents(planes: &[PlaneRecord], ranges: impl IntoIterator<Item = Range>) -> Vec<u32> {
    let mut parents = vec![NO_PARENT; planes.len()];
    let mut order: Vec<u32> = Vec::new();
    let mut open: Vec<u32> = Vec::new();
    for range in ranges {
        if planes.get(range.as_usize()).is_none() {
            continue;
        }
        let end = |p: &PlaneRecord| u64::from(p.leaf_first) + u64::from(p.leaf_count);
        // Enclosing runs first: by first leaf, then longest, then coarsest.
        order.clear();
        order.extend(range.first..range.first + range.count);
        order.sort_by(|&a, &b| {
            let (p, q) = (&planes[a as usize], &planes[b as usize]);
            p.leaf_first.cmp(&q.leaf_first).then(end(q).cmp(&end(p))).then(q.lo.total_cmp(&p.lo))
        });
        open.clear();
        for &i in &order {
            let p = &planes[i as usize];
            while let Some(&top) = open.last() {
                let q = &planes[top as usize];
                if q.leaf_first <= p.leaf_first && end(p) <= end(q) {
                    break;
                }
                open.pop();
            }
            if let Some(&top) = open.last() {
                parents[i as usize] = top;
            }
            open.push(i);
        }
    }
    parents
}

/// How far a plane drawn at `τ` has moved towards its parent's plane (Garcia 2005 §2.4, "we can
/// interpolate the plane parameters of the two enclosing levels"): 0 up to half its `hi`, then
/// linearly to 1 at `hi`, where the parent takes over. Over that octave of distances the plane's
/// corners slide, along the parent's normal, onto the parent's plane, so the switch moves no leaf
/// (the parent's image is its leaves projected onto that plane). A root never moves.
#[must_use]
pub fn morph_share(plane: &PlaneRecord, tau: f32) -> f32 {
    if !plane.hi.is_finite() {
        return 0.0;
    }
    let start = plane.lo.max(0.5 * plane.hi);
    if plane.hi <= start { 0.0 } else { ((tau - start) / (plane.hi - start)).clamp(0.0, 1.0) }
}

/// Share of `τ` below a switch of level over which the two levels cross-fade ([`crossfade`]).
pub const CROSSFADE: f32 = 0.25;

/// The part of a screen-space dither value `h ∈ [0, 1)` for which `plane` is drawn at `τ` with
/// the cross-fade between levels: `Some((from, to))` draws where `from ≤ h < to`, `None` not at
/// all. A plane is drawn over its interval `[lo, hi)` extended down to `lo·(1 − CROSSFADE)`; below
/// `lo` it fades in (`h < f`), and in the last `CROSSFADE` of its interval, if it has a parent,
/// it fades out (`h ≥ f`), with `f` rising from 0 to 1 across the band. A plane's `hi` is its
/// parent's `lo`, so at every `τ` the two are drawn on complementary pixels: the texture changes
/// a few pixels at a time instead of all at once. The WGSL twin is in `vs_plane`.
#[must_use]
pub fn crossfade(plane: &PlaneRecord, has_parent: bool, tau: f32) -> Option<(f32, f32)> {
    let lo_ext = plane.lo * (1.0 - CROSSFADE);
    if !(lo_ext <= tau && tau < plane.hi) {
        return None;
    }
    let mut keep = (0.0, 1.0);
    if tau < plane.lo {
        keep.1 = (tau - lo_ext) / (plane.lo - lo_ext);
    }
    let start = plane.hi * (1.0 - CROSSFADE);
    if has_parent && plane.hi.is_finite() && tau >= start {
        keep.0 = (tau - start) / (plane.hi - start);
    }
    Some(keep)
}

/// The corner `corner` of `plane` moved by `share` towards the plane of `parent` ([`morph_share`]):
/// the WGSL twin is in `vs_plane`.
#[must_use]
pub fn morph_corner(corner: Vec3, parent: &PlaneRecord, share: f32) -> Vec3 {
    let normal = Vec3::from_array(parent.axis_u).cross(Vec3::from_array(parent.axis_v)).normalize_or_zero();
    corner - share * (corner - Vec3::from_array(parent.center)).dot(normal) * normal
}

/// One cell holding planes.
pub type PlaneCell = SptCell;

/// One prefix of a cell's planes to draw.
pub type PlaneRange = CellPrefix;

/// What drawing a model's planes needs of its container, made once: its [`SptLod`] over
/// `PLANES`, and the image the planes sample. Its far list ([`SptLod::far_list`]) is not placed:
/// the planes treelod builds are one hierarchy in the block cell, one range per tree already.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneLod {
    spt: SptLod,
    /// The image of the first plane: the atlas.
    image: u32,
}

impl PlaneLod {
    /// The planes of an open container; `None` if it has none.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        let image = container.planes().first()?.image;
        let spt = SptLod::from_container(container, container.planes(), |cell| cell.planes)?;
        Some(Self { spt, image })
    }

    /// The image the first plane samples: the atlas a renderer binds (builders write one).
    #[must_use]
    pub fn image(&self) -> u32 {
        self.image
    }

    /// The planes an instance with world-from-model `transform` draws for `camera`, at `s_min`
    /// pixels (spec §10.1: `τ = s_min · d · 2·tan(fovy/2) / H`, divided by the transform's
    /// largest axis scale, `d` the distance to each cell's anchor), appended to `out`
    /// ([`SptLod::select_at_pixels`]). Returns `false`, appending nothing, if the instance's
    /// sphere lies outside `frustum` or the transform is degenerate.
    pub fn select(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        s_min: f32,
        out: &mut Vec<PlaneRange>,
    ) -> bool {
        self.spt.select_at_pixels(transform, camera, frustum, s_min, out)
    }
}

impl Deref for PlaneLod {
    type Target = SptLod;

    fn deref(&self) -> &SptLod {
        &self.spt
    }
}

/// The bark of a tree drawn with impostor planes ([`TechniqueSettings::impostor_bark`]) or pruned
/// ([`Pruning::bark`]): a renderer's setting.
///
/// [`TechniqueSettings::impostor_bark`]: crate::TechniqueSettings::impostor_bark
/// [`Pruning::bark`]: crate::Pruning::bark
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ImpostorBark {
    /// Every bark triangle (the paper keeps the trunk polygonal).
    All,
    /// Where the container has a LoD chain (spec §6.12, built with `--baselines`), the bark of
    /// its coarsest level whose error projects below half of `s_min` pixels (`τ` as for the
    /// planes' level, at the block centre) among the levels whose bark keeps 90 % of the full
    /// bark's area ([`BARK_AREA_KEPT`]); every bark triangle nearer than the finest level allows,
    /// or without a chain. The chain's error is where the surface moves, not what it covers: thin
    /// branches collapse into slivers at a small error, hence the area guard. Measured against
    /// the full mesh at 320×240 (recall of the image, all bark → chain): the maple draws 247270 of
    /// its 498464 bark triangles from 2 bounding radii on, 1.00 → 0.97 (2 radii), 0.96 (8); the
    /// oak 2835 of 12006 from 32 radii on, unchanged. Without the guard the maple's coarsest
    /// level (4963) would be drawn, at 0.77 and 0.83.
    Chain,
    /// Where the model has branch lines (spec §6.9, built with `--lines`), the lines the
    /// ellipsoid technique draws, with the same `τ`, level blend and depth bias (Clasen's
    /// skeleton of the branches, radii included), in place of every bark triangle; else as
    /// [`Self::Chain`]. The default for impostor trees: the planes stand for the leaves at any
    /// distance, and the bark drawn as thousands of triangles beside a few dozen planes made
    /// impostor trees cost about as much as the full mesh — the reason a policy chose them
    /// rarely, and the forests' largest cost where it did. Measured by the build's calibration
    /// (§6.15, 4 views, RMSE of the shaded image at 8/32/128/256 pixels, primitives submitted):
    /// the oak 0.0563/0.0363/0.0393/0.0466 with 157/207/800/1687 primitives against
    /// 0.0537/0.0366/0.0382/0.0454 with 2843/12052/12052/12052 for the chain's bark; the pine
    /// 0.0670/0.0418/0.0346/0.0411 (209/247/287/611) against 0.0625/0.0406/0.0342/0.0404
    /// (6085/12228/12230/12230); the orchid 0.0655/0.0515/0.0532/0.0584 (212/257/259/276)
    /// against 0.0637/0.0514/0.0501/0.0545 (4744/4785); the Quaternius tree
    /// 0.0556/0.0447/0.0414/0.0471 (36/91/185/185) against 0.0558/0.0429/0.0315/0.0357
    /// (244/2373/2406/2406) — within 5 % up to 64 pixels on every model, up to a third worse
    /// near on the tree whose few bark triangles are large, where a policy draws the mesh anyway.
    /// Pruned trees keep [`Self::Chain`] ([`Pruning::bark`]): pruning draws near trees.
    ///
    /// [`Pruning::bark`]: crate::Pruning::bark
    #[default]
    Lines,
}

/// [`ImpostorBark::Chain`] draws only levels whose bark keeps this share of the full bark's area.
pub const BARK_AREA_KEPT: f64 = 0.9;

/// [`ImpostorBark::Chain`] takes the coarsest level whose error is at most this share of `τ`:
/// meshoptimizer's error of a tube collapsed to a sliver is about its radius, so half a pixel
/// keeps the branches wider than about a pixel.
pub const BARK_ERROR_SHARE: f32 = 0.5;

/// The area of `triangles` over `vertices`, m² (model space).
#[must_use]
pub fn area(vertices: &[VertexRecord], triangles: &[TriangleRecord]) -> f64 {
    let position = |i: u32| vertices.get(i as usize).map_or(Vec3::ZERO, |v| Vec3::from_array(v.position));
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.indices.map(position);
            f64::from(0.5 * (b - a).cross(c - a).length())
        })
        .sum()
}

/// The trees of `list` drawn with impostor planes ([`Technique::Impostors`]; every model of
/// `list` has planes): appends to `out` each visible instance's plane prefixes at
/// `settings.s_min` pixels ([`PlaneLod::select`]) and its bark as `settings.impostor_bark` says
/// ([`ImpostorBark`]), and counts it visible.
pub fn select(scene: &Scene<'_>, list: &[u32], camera: &Camera, settings: &TechniqueSettings, out: &mut TreeDraws) {
    let frustum = Frustum::from_view_proj(camera.view_proj);
    select_into(list, out, |chunk, out| {
        let (mut ranges, mut bark_ranges) = (Vec::new(), Vec::new());
        for &index in chunk {
            let Some((instance, lod, model)) = scene.get(index) else { continue };
            let Some(planes) = &model.planes else { continue };
            ranges.clear();
            if !planes.select(instance.transform, camera, &frustum, settings.s_min, &mut ranges) {
                continue;
            }
            *out.visible.get_mut(Technique::Impostors) += 1;
            for range in &ranges {
                out.planes.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            let tree = (index, instance, lod, model);
            push_bark(tree, camera, &frustum, settings, settings.impostor_bark, 1.0, &mut bark_ranges, out);
        }
    });
}

/// Appends to `out` the bark of instance `index` (with its model's point tree and
/// representations) drawn as `bark` says for `camera` (the trees drawn with impostor planes or
/// pruned): with [`ImpostorBark::Lines`] and a model with lines, its line prefixes as the
/// ellipsoid technique selects them (`settings.lod`, `settings.pixel_level`); with
/// [`ImpostorBark::Chain`] (or `Lines` without lines) and a chain that has bark levels, the bark
/// of its coarsest level whose error is at most [`BARK_ERROR_SHARE`] of `τ` at `settings.s_min`
/// pixels at the block centre; else every bark triangle. `lambda` is recorded with a triangle
/// draw. `scratch`: reused for the line prefixes (its contents are replaced), so a chunk of
/// trees allocates once.
#[expect(clippy::too_many_arguments, reason = "the tree, its view, its bark, and scratch")]
pub(crate) fn push_bark(
    (index, instance, lod, model): (u32, &Instance, &ModelLod, &Representations),
    camera: &Camera,
    frustum: &Frustum,
    settings: &TechniqueSettings,
    bark: ImpostorBark,
    lambda: f32,
    scratch: &mut Vec<CellPrefix>,
    out: &mut TreeDraws,
) {
    if let (ImpostorBark::Lines, Some(lines)) = (bark, &model.lines) {
        let ranges = scratch;
        ranges.clear();
        lines.select_per_pixel_blended(
            instance.transform,
            camera,
            frustum,
            &settings.lod,
            settings.pixel_level,
            ranges,
        );
        out.lines.extend(ranges.iter().map(|range| PrefixDraw {
            instance: index,
            model: instance.model,
            range: *range,
        }));
        return;
    }
    // The chain's bark level (its triangles and error), if the setting and the model have one.
    let chain_bark = match (bark, &model.chain) {
        (ImpostorBark::Chain | ImpostorBark::Lines, Some(chain)) => {
            instance_tau(instance.transform, camera, frustum, settings.s_min, lod.cull_sphere(), model.block_centre)
                .and_then(|tau| chain.chain.pick(tau * BARK_ERROR_SHARE))
                .and_then(|level| {
                    let level = (level as usize).min(chain.bark_levels.len().checked_sub(1)?);
                    Some((chain.bark_levels[level], chain.level_error(level)))
                })
        }
        _ => None,
    };
    let draw = match chain_bark {
        Some((range, error)) => TriangleDraw::whole(index, instance.model, TriangleSource::Bark, range, lambda, error),
        None => model.bark_draw(index, instance.model, lambda),
    };
    out.triangles.extend(draw);
}

#[cfg(test)]
mod tests {
    use super::*;
    use treelod_build::{BuildConfig, DemoTreeConfig, ImpostorConfig, Placed, build_block, demo_tree};
    use treelod_format::Compression;

    fn demo() -> Container {
        let scene = demo_tree(&DemoTreeConfig { leaves: 1000, ..DemoTreeConfig::default() });
        let config = BuildConfig { impostors: Some(ImpostorConfig::default()), ..BuildConfig::default() };
        let built = build_block("demo", &[Placed { scene: &scene, translation: Vec3::ZERO }], &config, "t").unwrap();
        Container::from_bytes(&built.data.to_bytes(Compression::None).unwrap()).unwrap()
    }

    #[test]
    fn each_distance_draws_one_level_covering_every_leaf_once_and_far_means_coarser() {
        let container = demo();
        let lod = PlaneLod::from_container(&container).unwrap();
        assert_eq!(lod.cells().len(), 1, "the block cell");
        let planes = container.planes();
        let leaves = planes.iter().map(|p| p.leaf_first + p.leaf_count).max().unwrap();
        let mut previous = usize::MAX;
        for distance in [5.0, 50.0, 500.0, 5000.0, 15_000.0] {
            let camera = Camera::look_at(Vec3::new(0.0, 4.0, distance), Vec3::new(0.0, 4.0, 0.0), 0.8, 512, 512);
            let frustum = Frustum::from_view_proj(camera.view_proj);
            let mut out = Vec::new();
            assert!(lod.select(Mat4::IDENTITY, &camera, &frustum, 1.0, &mut out));
            let [range] = out[..] else { panic!("one range: {out:?}") };
            let first = range.first as usize;
            let drawn: Vec<&PlaneRecord> =
                planes[first..first + range.count as usize].iter().filter(|p| plane_drawn(p, range.tau)).collect();
            let mut covered: Vec<u32> = drawn.iter().flat_map(|p| p.leaf_first..p.leaf_first + p.leaf_count).collect();
            covered.sort_unstable();
            assert_eq!(covered, (0..leaves).collect::<Vec<_>>(), "at {distance} m");
            assert!(drawn.len() <= previous, "fewer planes farther away");
            previous = drawn.len();
        }
        assert!(previous < 32, "the far levels are coarser: {previous}");
        // Behind the camera: culled.
        let camera = Camera::look_at(Vec3::new(0.0, 4.0, 50.0), Vec3::new(0.0, 4.0, 100.0), 0.8, 512, 512);
        let mut out = Vec::new();
        assert!(!lod.select(Mat4::IDENTITY, &camera, &Frustum::from_view_proj(camera.view_proj), 1.0, &mut out));
        assert!(out.is_empty());
    }

    #[test]
    fn each_plane_morphs_onto_its_parent_which_takes_over_where_it_ends() {
        let container = demo();
        let planes = container.planes();
        let parents = plane_parents(planes, container.cells().iter().map(|c| c.planes));
        let mut children = 0;
        for (plane, &parent) in planes.iter().zip(&parents) {
            if parent == NO_PARENT {
                assert!(plane.hi.is_infinite(), "only roots lack a parent: {plane:?}");
                assert_eq!(morph_share(plane, 1e9), 0.0, "a root never moves");
                continue;
            }
            children += 1;
            let q = &planes[parent as usize];
            assert_eq!(q.lo.to_bits(), plane.hi.to_bits(), "the parent's interval starts where the plane's ends");
            assert!(
                q.leaf_first <= plane.leaf_first && plane.leaf_first + plane.leaf_count <= q.leaf_first + q.leaf_count
            );
            assert!(q.leaf_count > plane.leaf_count, "a coarser plane holds more leaves");
            // Unmoved in the lower half of its interval, on the parent's plane at its end.
            assert_eq!(morph_share(plane, plane.lo), 0.0);
            assert_eq!(morph_share(plane, 0.5 * plane.hi), 0.0);
            let share = morph_share(plane, plane.hi * (1.0 - 1e-6));
            assert!(share > 0.999, "{share}");
            let normal = Vec3::from_array(q.axis_u).cross(Vec3::from_array(q.axis_v)).normalize();
            let (c, u, v) =
                (Vec3::from_array(plane.center), Vec3::from_array(plane.axis_u), Vec3::from_array(plane.axis_v));
            for corner in [c + u + v, c - u + v, c + u - v, c - u - v] {
                assert_eq!(morph_corner(corner, q, 0.0), corner);
                let moved = morph_corner(corner, q, 1.0);
                assert!((moved - Vec3::from_array(q.center)).dot(normal).abs() < 1e-4, "on the parent's plane");
                assert!((moved - corner).cross(normal).length() < 1e-4, "moved along the parent's normal");
            }
        }
        assert!(children >= 16, "the finer levels have parents: {children}");
    }

    #[test]
    fn a_plane_and_its_parent_cross_fade_on_complementary_pixels() {
        let container = demo();
        let planes = container.planes();
        let parents = plane_parents(planes, container.cells().iter().map(|c| c.planes));
        for (plane, &parent) in planes.iter().zip(&parents) {
            if parent == NO_PARENT {
                continue;
            }
            let q = &planes[parent as usize];
            let grandparent = parents[parent as usize] != NO_PARENT;
            // Across the band below the switch, and on either side of it.
            for step in 0..=40 {
                let tau = plane.hi * (0.7 + 0.4 * step as f32 / 40.0);
                let child = crossfade(plane, true, tau);
                let coarse = crossfade(q, grandparent, tau);
                if tau < plane.hi * (1.0 - CROSSFADE) {
                    assert!(child.is_none_or(|(a, _)| a == 0.0), "the child is not fading out yet: {child:?}");
                    assert_eq!(coarse, None, "the parent is not drawn yet");
                } else if tau < plane.hi {
                    let (Some((a, _)), Some((_, d))) = (child, coarse) else { panic!("both drawn in the band") };
                    assert!((a - d).abs() < 1e-5, "complementary at τ = {tau}: child from {a}, parent to {d}");
                } else {
                    assert_eq!(child, None, "past the switch the child is gone");
                    let faded_in = coarse.is_some_and(|(_, d)| d == 1.0);
                    assert!(faded_in || tau >= q.hi, "the parent has faded in: {coarse:?}");
                }
            }
        }
    }
}
