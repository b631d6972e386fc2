//! Calibration (spec §6.15): the image error and the cost of every representation a container
//! holds, as functions of the block's projected height in pixels, measured by the build on each
//! model so that a runtime policy can choose among them without tuned constants. Neubert et al.'s
//! λ(h) measurement (2011 §2.2), generalised to every representation.
//!
//! **What is measured.** For each height `h` of [`HEIGHTS`] and each of `views` orthographic views
//! ([`view_directions`]), the block is drawn `h` pixels high:
//! - the *reference*: every triangle of `TRIANGLES` with the alpha test, rasterised at `k × k`
//!   samples per pixel (`k` = `supersample`, lowered so a side stays within
//!   [`MAX_REFERENCE_SIDE`]) and box-filtered to the pixel's covered fraction;
//! - each representation at one sample per pixel, as the renderer draws it without MSAA, with
//!   the runtime's own selection rules at the metres per pixel `p = H/h` of that height (`H` the
//!   block's height): Gilet's cut at the default pixel thresholds (`s_min` 1, `s_max` 2, no depth
//!   bias), point discs of their radius (a sub-pixel disc as the one-pixel splat of spec §10.1,
//!   drawn when a hash of the point falls below its coverage), pruned leaves at `λ(h)` scaled by
//!   `s_opt(λ)` or `1/λ`, impostor planes at `τ_p` with their atlas' alpha test, the bark of both
//!   as the runtime draws it by default (the LoD chain's bark level for `τ_p` where the container
//!   has a chain, else every bark triangle), ellipsoids at `τ = p` with the renderer's noise holes and the branch lines (or every
//!   bark triangle without lines), the billboards;
//! - each level of the LoD chain (spec §6.16), every tree's level of that number as the runtime
//!   switches a block's trees together: the `CHAIN_CALIBRATION` table. The chain's own
//!   `lod-chain` row is then not drawn but read from it: at each height, the full mesh's or the
//!   level's measurement that the runtime's rule by image error picks with the default target
//!   ([`Calibration::chain_level`], spec §10.2), so the row describes the chain as the runtime
//!   draws it with these tables, and a policy compares the chain it will draw. (A chain whose
//!   levels do not cover every tree, which verified files do not have, is drawn by the geometric
//!   rule instead: the coarsest level whose error is at most `τ = p`.) The levels cost one more
//!   drawing per level, height and view, in place of the chain's one: `treelod build --baselines
//!   --timings`, stage `calibration`, two runs each on a shared two-core machine, the oak
//!   0.78–0.94 s before and 1.05–1.11 s with them, the pine 0.61–0.65 and 0.66–0.75 s, the
//!   Quaternius tree 0.29–0.39 and 0.46–0.48 s (of builds of 11–17, 11–12 and 0.5–0.8 s).
//!
//! The error is the multi-scale RMSE of coverage (`treelod_eval::metrics`, Clasen §4: levels from
//! single pixels to the whole image) against the reference, averaged over the views; the cost is
//! the number of primitives submitted: the prefixes of points, planes, ellipsoids and lines a
//! renderer submits per cell, the coarser records its vertex shader drops included, so that the
//! tables count what the renderer's frame statistics, `eval` and the policy's budget count (the
//! point tree's cut alone undercounted it about twofold: the Quaternius tree at 32–128 pixels
//! submits 4013 primitives where its cut holds about 1900). Colour and shading are not measured: the table says how well a
//! representation keeps the silhouette and the canopy's density, which is what its level of detail
//! changes. Everything runs on the CPU rasteriser ([`crate::raster`]): the tables are the same on
//! every machine and for any thread count (views run in parallel, results are summed in order).
//!
//! Impostor planes textured indirectly (`LEAF_SLOTS`, spec §6.10.1) are not drawn here: a
//! container with them has no impostor rows, and a policy never picks a representation without
//! rows.

use glam::{Quat, Vec2, Vec3};
use rayon::prelude::*;
use treelod_eval::metrics::{LinearImage, multiscale_rmse};
use treelod_format::{
    CalibrationRecord, ChainCalibrationRecord, ContainerData, ImageRecord, NO_IMAGE, Setting, TriangleRecord,
    billboard_kind, calibration_technique, image_format, material_class, pack::unpack_unorm16x2, prune_leaves_drawn,
};
use treelod_runtime::ellipsoid::{ellipsoid_drawn, line_drawn};
use treelod_runtime::impostor::{BARK_AREA_KEPT, BARK_ERROR_SHARE, area};
use treelod_runtime::prune::{PruneScale, curve_at, leaf_scale, size_factor};
use treelod_runtime::{
    Calibration, LodChain, LodSettings, Policy, SptRecord, Technique, Thresholds, point_drawn, triangle_drawn,
};

use crate::raster::{
    AlphaMask, Mask, NO_ALPHA, NOISE_SIZE, RasterTriangle, View, fill_ellipse, fill_ellipsoid_cut, fill_triangle,
    noise_cut, rasterize, view_directions,
};
use crate::scene::{Image, ImageEncoding};

/// Projected heights of the block at which every representation is measured, pixels: octaves
/// from a tree a few pixels high to one a quarter of a 1080p screen high. Larger trees are few
/// and near: a policy draws them with the representation that converges to the full mesh (the
/// point tree), so the table stops here and the build spends its time where the choice is made
/// (the images of 512 pixels would cost four times all the others).
pub const HEIGHTS: [f32; 6] = [8.0, 16.0, 32.0, 64.0, 128.0, 256.0];

/// The largest side of a supersampled reference image, samples: the supersampling is lowered
/// where a view would be larger (a block much wider than high at 256 pixels).
pub const MAX_REFERENCE_SIDE: u32 = 2048;

/// Noise texels per radian of the renderer's ellipsoid noise (`shaders/tree/ellipsoids.wgsl`).
const NOISE_TEXELS_PER_RADIAN: f32 = 40.0;

/// Settings of the calibration (recorded in the metadata as `calibration.*`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CalibrationConfig {
    /// Orthographic views per height ([`view_directions`]). Default 4: three around the tree and
    /// one from 45° above.
    pub views: usize,
    /// Samples per pixel side of the reference. Default 4.
    pub supersample: u32,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self { views: 4, supersample: 4 }
    }
}

impl CalibrationConfig {
    /// The metadata settings recording this configuration (spec §7.1).
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        vec![
            Setting { key: "calibration.views".into(), value: self.views.to_string() },
            Setting { key: "calibration.supersample".into(), value: self.supersample.to_string() },
        ]
    }
}

/// What the calibration draws, gathered once from the container's arrays.
struct Scene<'a> {
    data: &'a ContainerData,
    /// Alpha masks: one per material (index = material), then one per image used by planes and
    /// billboards (`image_alpha`).
    alphas: Vec<AlphaMask>,
    /// Per index into `alphas` of a textured material's mask: the indices of its mip levels
    /// ([`AlphaMask::mip_chain`]), level 0 first; empty for the other masks.
    alpha_mips: Vec<Vec<u32>>,
    /// Per material, its index into `alphas` or [`NO_ALPHA`].
    material_alpha: Vec<u32>,
    /// Per image, its index into `alphas` as a plane's or billboard's texture, or [`NO_ALPHA`].
    image_alpha: Vec<u32>,
    /// Every triangle of `TRIANGLES`, ready to rasterise (the reference and the full mesh).
    full: Vec<RasterTriangle>,
    /// The triangles of `TRIANGLES` that are not of a leaf material (pruned and impostor trees
    /// draw them all where the container has no chain, and near).
    bark: Vec<RasterTriangle>,
    /// The LoD chain's bark levels as the runtime keeps them for pruned and impostor trees
    /// (`treelod_runtime::ChainRanges::bark_levels`): per level, finest first, its block error
    /// (the largest of its trees', kept non-decreasing) and its bark triangles, while they keep
    /// [`BARK_AREA_KEPT`] of the full bark's area; empty without a chain, planes or pruning.
    chain_bark: Vec<(f32, Vec<RasterTriangle>)>,
    /// The LoD chain's levels as the runtime switches a block's trees together
    /// ([`LodChain::from_records`]): per level, finest first, every tree's triangles of that
    /// level; empty without a chain.
    chain_levels: Vec<Vec<RasterTriangle>>,
    /// Whether the impostor planes can be drawn (an RGBA atlas, not leaf slots).
    planes_drawable: bool,
}

/// What [`calibrate`] measures: the table of every representation (`CALIBRATION`, spec §6.15)
/// and of every level of the LoD chain (`CHAIN_CALIBRATION`, §6.16).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Calibrated {
    /// Per representation and height, sorted by technique, then height.
    pub records: Vec<CalibrationRecord>,
    /// Per LoD chain level and height, sorted by level, then height; empty without a chain.
    pub chain_levels: Vec<ChainCalibrationRecord>,
}

/// The calibration of `data` (spec §6.15, §6.16): for every representation it holds, its error
/// and primitive count at each of [`HEIGHTS`], sorted by technique, then height; and where it has
/// a LoD chain, the same for each of the chain's levels. Empty for a block without height or
/// triangles.
///
/// With a chain, its `lod-chain` row is not drawn by the geometric rule but describes the chain
/// as the runtime draws it with per-level tables (spec §10.2): at each height, the full mesh's or
/// the level's measurement that [`Calibration::chain_level`] picks with
/// [`Policy::DEFAULT_TARGET`] among the representations measured here.
#[must_use]
pub fn calibrate(data: &ContainerData, config: &CalibrationConfig) -> Calibrated {
    let (lo, hi) = (Vec3::from_array(data.block.bounds_min), Vec3::from_array(data.block.bounds_max));
    let height = hi.y - lo.y;
    if !(height.is_finite() && height > 0.0) || data.triangles.is_empty() {
        return Calibrated::default();
    }
    let scene = Scene::new(data);
    let held = scene.techniques();
    // With per-level tables the chain's row follows from them: its levels are drawn instead.
    let per_level = !scene.chain_levels.is_empty();
    let techniques: Vec<u32> =
        held.iter().copied().filter(|&t| !(per_level && t == calibration_technique::LOD_CHAIN)).collect();
    let (centre, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
    let directions = view_directions(config.views.max(1));
    let jobs: Vec<(usize, usize)> =
        (0..HEIGHTS.len()).flat_map(|h| (0..directions.len()).map(move |v| (h, v))).collect();
    // Per job: per technique, then per chain level, (error, primitives).
    let results: Vec<Vec<(f64, f64)>> = jobs
        .par_iter()
        .map(|&(h, v)| {
            let pixels = HEIGHTS[h];
            let metres_per_pixel = height / pixels;
            let side = ((2.0 * radius / metres_per_pixel).ceil() as u32).max(4);
            let k = config.supersample.max(1).min((MAX_REFERENCE_SIDE / side).max(1));
            // The sphere fitted to exactly `side` pixels of `metres_per_pixel`.
            let fitted = 0.5 * side as f32 * metres_per_pixel;
            let view = View::fit(directions[v], centre, fitted, side);
            let reference = scene.reference(&View::fit(directions[v], centre, fitted, side * k), k);
            let measured = techniques.iter().map(|&t| {
                let mut mask = Mask::new(side);
                let primitives = scene.draw(t, &view, metres_per_pixel, pixels, &mut mask);
                (error(&mask, &reference), primitives as f64)
            });
            let levels = scene.chain_levels.iter().map(|triangles| {
                let mut mask = Mask::new(side);
                scene.rasterize_1x(&mut mask, &view, triangles);
                (error(&mask, &reference), triangles.len() as f64)
            });
            measured.chain(levels).collect()
        })
        .collect();
    // The mean over the views of column `column` at height index `h`.
    let mean = |h: usize, column: usize| {
        let per_view: Vec<(f64, f64)> =
            jobs.iter().zip(&results).filter(|((jh, _), _)| *jh == h).map(|(_, r)| r[column]).collect();
        let n = per_view.len().max(1) as f64;
        let error = per_view.iter().map(|r| r.0).sum::<f64>() / n;
        let primitives = per_view.iter().map(|r| r.1).sum::<f64>() / n;
        ((error as f32).clamp(0.0, 1.0), primitives as f32)
    };
    let mut records = Vec::new();
    for (ti, &technique) in techniques.iter().enumerate() {
        for (h, &pixels) in HEIGHTS.iter().enumerate() {
            let (error, primitives) = mean(h, ti);
            records.push(CalibrationRecord { technique, height: pixels, error, primitives });
        }
    }
    let mut chain_levels = Vec::new();
    for level in 0..scene.chain_levels.len() {
        for (h, &pixels) in HEIGHTS.iter().enumerate() {
            let (error, primitives) = mean(h, techniques.len() + level);
            let level = u32::try_from(level).unwrap_or(u32::MAX);
            chain_levels.push(ChainCalibrationRecord { level, height: pixels, error, primitives });
        }
    }
    if per_level {
        records.extend(chain_rows(&records, &chain_levels, &held));
        records.sort_by(|a, b| a.technique.cmp(&b.technique).then(a.height.total_cmp(&b.height)));
    }
    Calibrated { records, chain_levels }
}

/// The `lod-chain` rows of a chain drawn by image error (spec §10.2): at each height of
/// `chain_levels`, the measurement of the full mesh (in `records`) or of the level that
/// [`Calibration::chain_level`] picks with the default target, the floor over the techniques
/// `held`.
fn chain_rows(
    records: &[CalibrationRecord],
    chain_levels: &[ChainCalibrationRecord],
    held: &[u32],
) -> Vec<CalibrationRecord> {
    let Some(tables) = Calibration::from_records(records).map(|c| c.with_chain_levels(chain_levels)) else {
        return Vec::new();
    };
    let usable = |t: Technique| u32::try_from(t.index()).is_ok_and(|code| held.contains(&code));
    let full = |height: f32| {
        records.iter().find(|r| r.technique == calibration_technique::FULL && r.height == height).copied()
    };
    let mut heights: Vec<f32> = chain_levels.iter().map(|r| r.height).collect();
    heights.sort_by(f32::total_cmp);
    heights.dedup();
    heights
        .into_iter()
        .filter_map(|height| {
            let measured = match tables.chain_level(height, Policy::DEFAULT_TARGET, usable)? {
                Some(level) => chain_levels
                    .iter()
                    .find(|r| r.level == level && r.height == height)
                    .map(|r| (r.error, r.primitives))?,
                None => full(height).map(|r| (r.error, r.primitives))?,
            };
            Some(CalibrationRecord {
                technique: calibration_technique::LOD_CHAIN,
                height,
                error: measured.0,
                primitives: measured.1,
            })
        })
        .collect()
}

/// The multi-scale RMSE of the one-sample coverage `mask` against `reference` (grey, the
/// covered fraction of each pixel in every channel, as [`Scene::reference`] gives it).
fn error(mask: &Mask, reference: &LinearImage) -> f64 {
    multiscale_rmse(&coverage_image(mask), reference).map_or(1.0, |m| m.summary())
}

/// `mask` as a linear image: 1 in every channel where covered, 0 elsewhere.
fn coverage_image(mask: &Mask) -> LinearImage {
    let size = mask.size();
    let pixels = (0..size)
        .flat_map(|y| (0..size).map(move |x| (x, y)))
        .map(|(x, y)| [f32::from(u8::from(mask.get(x, y))); 3])
        .collect();
    LinearImage { width: size, height: size, pixels }
}

impl<'a> Scene<'a> {
    fn new(data: &'a ContainerData) -> Self {
        let decoded: Vec<Option<Image>> = data.images.iter().map(|record| decode(data, record)).collect();
        let mut alphas = Vec::new();
        let mut cutoffs = Vec::new();
        let mut push = |mask: AlphaMask| {
            alphas.push(mask);
            u32::try_from(alphas.len() - 1).unwrap_or(NO_ALPHA)
        };
        let material_alpha: Vec<u32> = data
            .materials
            .iter()
            .map(|m| {
                let cutoff = match m.alpha_mode {
                    1 => m.alpha_cutoff,
                    2 => 0.5,
                    _ => return NO_ALPHA,
                };
                let factor = m.base_color[3];
                match (m.image != NO_IMAGE).then(|| decoded.get(m.image as usize)).flatten().and_then(Option::as_ref) {
                    Some(image) => {
                        let index = push(AlphaMask::from_image(image, factor, cutoff));
                        cutoffs.push((index, cutoff));
                        index
                    }
                    None if factor >= cutoff => NO_ALPHA,
                    None => push(AlphaMask::from_image(&transparent(), 1.0, 0.5)),
                }
            })
            .collect();
        // Planes and billboards test their atlas' alpha at 0.5 (spec §6.10).
        let textured: Vec<u32> =
            data.planes.iter().map(|p| p.image).chain(data.billboards.iter().map(|b| b.image)).collect();
        let image_alpha: Vec<u32> = decoded
            .iter()
            .enumerate()
            .map(|(i, image)| match image {
                Some(image) if textured.contains(&(i as u32)) => push(AlphaMask::from_image(image, 1.0, 0.5)),
                _ => NO_ALPHA,
            })
            .collect();
        // Each textured material's mips, as the renderer alpha-tests them (`rasterize_1x`).
        let mut alpha_mips = vec![Vec::new(); alphas.len()];
        for (index, cutoff) in cutoffs {
            let Some(mask) = alphas.get(index as usize) else { continue };
            let chain = mask.mip_chain(cutoff);
            let mut levels = vec![index];
            for level in chain.into_iter().skip(1) {
                alphas.push(level);
                levels.push(u32::try_from(alphas.len() - 1).unwrap_or(NO_ALPHA));
            }
            alpha_mips[index as usize] = levels;
        }
        let raster = |t: &TriangleRecord| raster_triangle(data, t, &material_alpha, 1.0, None);
        let full: Vec<RasterTriangle> = data.triangles.iter().map(raster).collect();
        let bark: Vec<RasterTriangle> = data
            .triangles
            .iter()
            .filter(|t| data.materials.get(t.material as usize).is_none_or(|m| m.class != material_class::LEAF))
            .map(raster)
            .collect();
        let planes_drawable = !data.planes.is_empty()
            && data.planes.iter().all(|p| {
                data.images.get(p.image as usize).is_some_and(|i| i.format != image_format::LEAF_SLOTS)
                    && image_alpha.get(p.image as usize).is_some_and(|&a| a != NO_ALPHA)
            });
        let chain_bark = if data.planes.is_empty() && data.prune_leaves.is_empty() {
            Vec::new()
        } else {
            chain_bark_levels(data, &material_alpha)
        };
        let chain_levels = LodChain::from_records(&data.lod_levels).map_or_else(Vec::new, |chain| {
            chain
                .levels()
                .iter()
                .map(|level| {
                    level
                        .ranges
                        .iter()
                        .flat_map(|range| data.lod_triangles.get(range.as_usize()).unwrap_or(&[]))
                        .map(|t| raster_triangle(data, t, &material_alpha, 1.0, None))
                        .collect()
                })
                .collect()
        });
        Self {
            data,
            alphas,
            alpha_mips,
            material_alpha,
            image_alpha,
            full,
            bark,
            chain_bark,
            chain_levels,
            planes_drawable,
        }
    }

    /// Draws the bark of a pruned or impostor tree at `τ = tau` (metres) as the runtime's
    /// `ImpostorBark::Chain` does: the chain's coarsest bark level whose error is at most
    /// [`BARK_ERROR_SHARE`] of `τ`, else every bark triangle. Returns the triangles drawn.
    fn draw_bark(&self, view: &View, tau: f32, mask: &mut Mask) -> u64 {
        let usable = self.chain_bark.partition_point(|(error, _)| *error <= tau * BARK_ERROR_SHARE);
        let triangles = match usable.checked_sub(1) {
            Some(level) => &self.chain_bark[level].1,
            None => &self.bark,
        };
        self.rasterize_1x(mask, view, triangles);
        triangles.len() as u64
    }

    /// Rasterises `triangles` at one sample per pixel as the renderer alpha-tests them: each
    /// textured triangle against the mip level its texel footprint selects (texels per pixel
    /// along the screen axis that stretches them most, as `textureSample` chooses, rounded to a
    /// level), so that leaves thinner than a pixel drop out far away as they do on the GPU. The
    /// supersampled reference keeps testing the full resolution: it stands for the image the
    /// stochastic alpha keeps.
    fn rasterize_1x(&self, mask: &mut Mask, view: &View, triangles: &[RasterTriangle]) {
        for t in triangles {
            let p = t.positions.map(|q| view.project(q));
            let alpha = self.alpha_mips.get(t.alpha as usize).filter(|l| l.len() > 1).map_or(t.alpha, |levels| {
                let (w, h) = self.alphas.get(t.alpha as usize).map_or((1, 1), AlphaMask::size);
                #[expect(clippy::cast_precision_loss, reason = "texture sides")]
                let texels = Vec2::new(w as f32, h as f32);
                let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
                let (u1, u2) = ((t.uvs[1] - t.uvs[0]) * texels, (t.uvs[2] - t.uvs[0]) * texels);
                let det = e1.perp_dot(e2);
                if det.abs() < 1e-12 {
                    return t.alpha;
                }
                // d(texel)/d(screen x) and d(texel)/d(screen y).
                let along_x = (u1 * e2.y - u2 * e1.y) / det;
                let along_y = (u2 * e1.x - u1 * e2.x) / det;
                let footprint = along_x.length().max(along_y.length());
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a mip level")]
                let level = if footprint > 1.0 { footprint.log2().round() as usize } else { 0 };
                levels[level.min(levels.len() - 1)]
            });
            fill_triangle(mask, p, t.uvs, self.alphas.get(alpha as usize));
        }
    }

    /// The techniques the container holds data for, in code order.
    fn techniques(&self) -> Vec<u32> {
        use calibration_technique as t;
        let d = self.data;
        let has_billboard = |kind| d.billboards.iter().any(|b| b.kind == kind);
        [
            (t::FULL, true),
            (t::SPT, true),
            (t::PRUNE_OPT, !d.prune_leaves.is_empty() && !d.prune_lambda.is_empty()),
            (t::PRUNE_COOK, !d.prune_leaves.is_empty() && !d.prune_lambda.is_empty()),
            (t::IMPOSTORS, self.planes_drawable),
            (t::ELLIPSOIDS, !d.ellipsoids.is_empty()),
            (t::LOD_CHAIN, !d.lod_levels.is_empty()),
            (t::BILLBOARD, has_billboard(billboard_kind::FACING)),
            (t::CROSSED, has_billboard(billboard_kind::CROSSED)),
        ]
        .into_iter()
        .filter_map(|(code, held)| held.then_some(code))
        .collect()
    }

    /// The reference of `view` (`k` samples per pixel side): every triangle's coverage,
    /// box-filtered to the covered fraction of each pixel (grey, in every channel).
    fn reference(&self, view: &View, k: u32) -> LinearImage {
        let mut fine = Mask::new(view.size);
        rasterize(&mut fine, view, &self.full, &self.alphas);
        let fine = coverage_image(&fine);
        // The view is `k` times the image's side, so the filter cannot fail.
        fine.box_filter(k).unwrap_or(fine)
    }

    /// Draws `technique` as seen in `view` at `p` metres per pixel (`pixels` the block's height on
    /// screen) into `mask`; returns the primitives drawn.
    fn draw(&self, technique: u32, view: &View, p: f32, pixels: f32, mask: &mut Mask) -> u64 {
        use calibration_technique as t;
        let d = self.data;
        let lod = LodSettings::default();
        match technique {
            t::FULL => {
                self.rasterize_1x(mask, view, &self.full);
                self.full.len() as u64
            }
            t::SPT => {
                self.draw_spt(view, Thresholds { points: lod.s_min * p, triangles: lod.s_max.max(lod.s_min) * p }, mask)
            }
            t::PRUNE_OPT | t::PRUNE_COOK => {
                let mode = if technique == t::PRUNE_OPT { PruneScale::Optimal } else { PruneScale::Cook };
                let lambda = curve_at(&d.prune_lambda, pixels).unwrap_or(1.0).clamp(0.0, 1.0);
                let grow = size_factor(leaf_scale(mode, &d.prune_scale, lambda));
                let mut drawn = self.draw_bark(view, lod.s_min * p, mask);
                let mut leaves = Vec::new();
                for cell in &d.cells {
                    let list = d.prune_leaves.get(cell.prune_leaves.as_usize()).unwrap_or(&[]);
                    let n = prune_leaves_drawn(u32::try_from(list.len()).unwrap_or(u32::MAX), lambda) as usize;
                    for leaf in &list[..n.min(list.len())] {
                        let first = leaf.first_triangle as usize;
                        let tris = d.prune_triangles.get(first..first + leaf.triangle_count as usize).unwrap_or(&[]);
                        let centre = Vec3::from_array(leaf.center);
                        leaves.extend(
                            tris.iter().map(|tri| raster_triangle(d, tri, &self.material_alpha, grow, Some(centre))),
                        );
                    }
                }
                self.rasterize_1x(mask, view, &leaves);
                drawn += leaves.len() as u64;
                drawn
            }
            t::IMPOSTORS => {
                let tau = lod.s_min * p;
                let mut drawn = self.draw_bark(view, tau, mask);
                // The prefix `hi > τ` is submitted; the vertex shader drops the coarser planes.
                drawn += d.planes.iter().filter(|pl| tau < pl.hi && pl.lo > tau).count() as u64;
                for plane in d.planes.iter().filter(|pl| pl.lo <= tau && tau < pl.hi) {
                    let (u, v) = (Vec3::from_array(plane.axis_u), Vec3::from_array(plane.axis_v));
                    self.quad(
                        mask,
                        view,
                        Vec3::from_array(plane.center),
                        u,
                        v,
                        plane.image,
                        (plane.uv_min, plane.uv_max),
                    );
                    drawn += 1;
                }
                drawn
            }
            t::ELLIPSOIDS => self.draw_ellipsoids(view, p, mask),
            t::LOD_CHAIN => {
                // Only for a chain without per-level tables (levels missing for some tree): per
                // tree, the coarsest level whose error is at most τ = s_min pixels; the full mesh
                // where none is.
                let tau = lod.s_min * p;
                let mut chosen: Vec<Option<&treelod_format::LodLevelRecord>> = vec![None; d.block.tree_count as usize];
                for level in &d.lod_levels {
                    if level.error <= tau
                        && let Some(slot) = chosen.get_mut(level.tree as usize)
                        && slot.is_none_or(|s| s.level < level.level)
                    {
                        *slot = Some(level);
                    }
                }
                if chosen.iter().any(Option::is_none) {
                    self.rasterize_1x(mask, view, &self.full);
                    return self.full.len() as u64;
                }
                let tris: Vec<RasterTriangle> = chosen
                    .iter()
                    .flatten()
                    .flat_map(|l| d.lod_triangles.get(l.triangles.as_usize()).unwrap_or(&[]))
                    .map(|tri| raster_triangle(d, tri, &self.material_alpha, 1.0, None))
                    .collect();
                self.rasterize_1x(mask, view, &tris);
                tris.len() as u64
            }
            t::BILLBOARD | t::CROSSED => {
                let kind = if technique == t::BILLBOARD { billboard_kind::FACING } else { billboard_kind::CROSSED };
                let mut drawn = 0;
                for b in d.billboards.iter().filter(|b| b.kind == kind) {
                    let (mut u, v) = (Vec3::from_array(b.axis_u), Vec3::from_array(b.axis_v));
                    if kind == billboard_kind::FACING {
                        // Turned about axis_v towards the viewer (spec §6.13).
                        let up = v.normalize_or_zero();
                        let towards = (view.direction - up * view.direction.dot(up)).normalize_or_zero();
                        let turned = up.cross(towards);
                        if turned != Vec3::ZERO {
                            u = turned * u.length();
                        }
                    }
                    self.quad(mask, view, Vec3::from_array(b.center), u, v, b.image, (b.uv_min, b.uv_max));
                    drawn += 1;
                }
                drawn
            }
            _ => 0,
        }
    }

    /// A plane's or billboard's quad textured by the rectangle `uv` of `image`, alpha-tested at
    /// 0.5 ([`quad`]).
    #[expect(clippy::too_many_arguments, reason = "a quad's frame and its texture rectangle")]
    fn quad(&self, mask: &mut Mask, view: &View, centre: Vec3, u: Vec3, v: Vec3, image: u32, uv: (u32, u32)) {
        let alpha = self.image_alpha.get(image as usize).copied().unwrap_or(NO_ALPHA);
        quad(mask, view, centre, u, v, uv, self.alphas.get(alpha as usize));
    }

    /// Gilet's cut at `thresholds`: the triangles above `τ_t`, the points of `τ_p`.
    fn draw_spt(&self, view: &View, thresholds: Thresholds, mask: &mut Mask) -> u64 {
        let d = self.data;
        let mut tris = Vec::new();
        let mut drawn = 0u64;
        for cell in &d.cells {
            for tri in d.triangles.get(cell.triangles.as_usize()).unwrap_or(&[]) {
                if !triangle_drawn(tri, thresholds) {
                    break;
                }
                tris.push(raster_triangle(d, tri, &self.material_alpha, 1.0, None));
            }
            let first = cell.points.first as usize;
            for (i, point) in d.points.get(cell.points.as_usize()).unwrap_or(&[]).iter().enumerate() {
                if point.hi <= thresholds.points {
                    break;
                }
                // The prefix is submitted; the vertex shader drops the points outside the cut.
                drawn += 1;
                if !point_drawn(point, thresholds) {
                    continue;
                }
                disc(mask, view, Vec3::from_array(point.position), point.radius, (first + i) as u64);
            }
        }
        self.rasterize_1x(mask, view, &tris);
        drawn + tris.len() as u64
    }

    /// The ellipsoids of `τ = p` with the renderer's noise holes, and the lines of `τ` (or every
    /// bark triangle where the container has no lines, as the renderer draws them).
    fn draw_ellipsoids(&self, view: &View, p: f32, mask: &mut Mask) -> u64 {
        let d = self.data;
        let mut drawn = 0u64;
        let top = NOISE_SIZE.ilog2() as f32;
        // Each cell's prefix `hi > τ` is submitted; the vertex shader drops the coarser levels.
        let above = |interval: (f32, f32)| u64::from(interval.0 > p && interval.1 > p);
        drawn += d.ellipsoids.iter().map(|e| above(e.interval())).sum::<u64>();
        for e in d.ellipsoids.iter().filter(|e| ellipsoid_drawn(e, p)) {
            let q = Quat::from_array(e.orientation.map(|c| f32::from(c) / 32767.0)).normalize();
            let axes = [Vec3::X, Vec3::Y, Vec3::Z].map(|a| q * a);
            let axes = [axes[0] * e.radii[0], axes[1] * e.radii[1], axes[2] * e.radii[2]];
            // The renderer's mip: the cluster's noise level, or coarser where the noise texels
            // would be finer than the pixels (its footprint at the ellipsoid's middle).
            let radius_px = (e.radii.iter().sum::<f32>() / 3.0 * view.scale).max(1e-6);
            let footprint = (NOISE_TEXELS_PER_RADIAN / radius_px).log2();
            let level = (top - e.noise_mip).max(footprint).clamp(0.0, top);
            let level = ((level + 0.5).ceil() - 1.0).clamp(0.0, top) as u32;
            fill_ellipsoid_cut(mask, view, Vec3::from_array(e.center), axes, level, noise_cut(e.alpha_threshold));
            drawn += 1;
        }
        if d.lines.is_empty() {
            self.rasterize_1x(mask, view, &self.bark);
            return drawn + self.bark.len() as u64;
        }
        drawn += d.lines.iter().map(|l| above(l.interval())).sum::<u64>();
        for line in d.lines.iter().filter(|l| line_drawn(l, p)) {
            let (a, b) = (view.project(Vec3::from_array(line.p0)), view.project(Vec3::from_array(line.p1)));
            let (ra, rb) = (line.r0 * view.scale, line.r1 * view.scale);
            let across = (b - a).perp().normalize_or_zero();
            let corners = [a + across * ra, a - across * ra, b - across * rb, b + across * rb];
            fill_triangle(mask, [corners[0], corners[1], corners[2]], [Vec2::ZERO; 3], None);
            fill_triangle(mask, [corners[0], corners[2], corners[3]], [Vec2::ZERO; 3], None);
            for (c, r) in [(a, ra), (b, rb)] {
                fill_ellipse(mask, c, [f64::from(r * r), 0.0, f64::from(r * r)]);
            }
            drawn += 1;
        }
        drawn
    }
}

/// A point's disc of `radius` metres at `centre`, facing the viewer. A disc under half a pixel in
/// radius is the renderer's one-pixel splat (spec §10.1): its pixel is covered when a hash of the
/// point falls below the disc's coverage `π·r²`.
fn disc(mask: &mut Mask, view: &View, centre: Vec3, radius: f32, id: u64) {
    let c = view.project(centre);
    let r = radius * view.scale;
    if r >= 0.5 {
        let r2 = f64::from(r * r);
        fill_ellipse(mask, c, [r2, 0.0, r2]);
        return;
    }
    let coverage = std::f32::consts::PI * r * r;
    let hash = crate::rng::SplitMix64(id).next_u64();
    if ((hash >> 40) as f32) / ((1u64 << 24) as f32) < coverage && c.x >= 0.0 && c.y >= 0.0 {
        let (x, y) = (c.x as u32, c.y as u32);
        if x < mask.size() && y < mask.size() {
            mask.set(x, y);
        }
    }
}

/// The quad `centre ± u ± v` textured by the atlas rectangle `uv_min ..= uv_max` (spec §6.10:
/// the corner `centre − u − v` at `uv_min`), alpha-tested with `alpha`.
fn quad(
    mask: &mut Mask,
    view: &View,
    centre: Vec3,
    u: Vec3,
    v: Vec3,
    (uv_min, uv_max): (u32, u32),
    alpha: Option<&AlphaMask>,
) {
    let (lo, hi) = (Vec2::from_array(unpack_unorm16x2(uv_min)), Vec2::from_array(unpack_unorm16x2(uv_max)));
    let corner = |s: f32, t: f32| {
        (view.project(centre + u * s + v * t), lo + Vec2::new(0.5 * (s + 1.0), 0.5 * (t + 1.0)) * (hi - lo))
    };
    let [a, b, c, e] = [corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0)];
    fill_triangle(mask, [a.0, b.0, c.0], [a.1, b.1, c.1], alpha);
    fill_triangle(mask, [a.0, c.0, e.0], [a.1, c.1, e.1], alpha);
}

/// The chain's bark levels as the runtime builds them (`Representations::from_container`): the
/// levels of [`LodChain::from_records`], each with its error and the non-leaf triangles of its
/// trees' ranges, up to the first whose bark keeps less than [`BARK_AREA_KEPT`] of the full
/// bark's area ([`area`]).
fn chain_bark_levels(data: &ContainerData, material_alpha: &[u32]) -> Vec<(f32, Vec<RasterTriangle>)> {
    let is_bark =
        |t: &&TriangleRecord| data.materials.get(t.material as usize).is_none_or(|m| m.class != material_class::LEAF);
    let Some(chain) = LodChain::from_records(&data.lod_levels) else { return Vec::new() };
    let full_bark: Vec<TriangleRecord> = data.triangles.iter().filter(is_bark).copied().collect();
    let full_area = area(&data.vertices, &full_bark);
    let mut levels = Vec::new();
    for level in chain.levels() {
        let bark: Vec<TriangleRecord> = level
            .ranges
            .iter()
            .flat_map(|range| data.lod_triangles.get(range.as_usize()).unwrap_or(&[]))
            .filter(is_bark)
            .copied()
            .collect();
        if area(&data.vertices, &bark) < BARK_AREA_KEPT * full_area {
            break;
        }
        levels.push((level.error, bark.iter().map(|t| raster_triangle(data, t, material_alpha, 1.0, None)).collect()));
    }
    levels
}

/// A triangle record as a rasteriser triangle, its corners moved to `c + sqrt(s)·(p − c)` when
/// `centre` is given (a pruned leaf grown by `s`, spec §6.11; `grow` is `sqrt(s)`).
fn raster_triangle(
    data: &ContainerData,
    t: &TriangleRecord,
    material_alpha: &[u32],
    grow: f32,
    centre: Option<Vec3>,
) -> RasterTriangle {
    let vertex = |i: u32| data.vertices.get(i as usize).copied().unwrap_or_default();
    let corners = t.indices.map(vertex);
    let position = |p: [f32; 3]| {
        let p = Vec3::from_array(p);
        centre.map_or(p, |c| c + (p - c) * grow)
    };
    RasterTriangle {
        positions: corners.map(|v| position(v.position)),
        uvs: corners.map(|v| Vec2::from_array(v.uv)),
        alpha: material_alpha.get(t.material as usize).copied().unwrap_or(NO_ALPHA),
    }
}

/// An image of the container decoded for its alpha test; `None` for leaf slots and images that
/// do not decode (their texels are not colours).
fn decode(data: &ContainerData, record: &ImageRecord) -> Option<Image> {
    let bytes = data.image_data.get(record.data_offset as usize..)?.get(..record.data_length as usize)?;
    let image = treelod_format::image::decode(record, bytes).ok()?;
    Some(Image {
        width: image.width,
        height: image.height,
        rgba: image.texels,
        encoded: Vec::new(),
        encoding: ImageEncoding::Raw,
    })
}

/// A 1 × 1 transparent image (a material whose alpha factor fails its own cutoff).
fn transparent() -> Image {
    Image { width: 1, height: 1, rgba: vec![0; 4], encoded: Vec::new(), encoding: ImageEncoding::Raw }
}
