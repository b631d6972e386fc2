//! Calibration (spec §6.15): the image error and the cost of every representation a container
//! holds, as functions of the block's projected height in pixels, measured by the build on each
//! model so that a runtime policy can choose among them without tuned constants. Neubert et al.'s
//! λ(h) measurement (2011 §2.2), generalised to every representation.
//!
//! **What is measured.** For each height `h` of [`HEIGHTS`] and each orthographic view of
//! [`calibration_views`] (`views` around the tree at each elevation of [`ELEVATIONS`] below 90°,
//! more under 64 pixels, [`views_at`], and straight down, one from 64 pixels up and more below,
//! each turned about the vertical, [`down_views_at`]), the block is drawn about `h` pixels high —
//! each view at its own fraction of an octave around `h`, the views of one elevation spread evenly
//! over the octave (with two, `h·2^(−1/4)` and `h·2^(1/4)`; one alone at `h`), so that a table
//! holds the mean over the phases of the representations' level switches, as a forest's
//! trees at every distance show them, not the one phase an exact octave falls on (measured on the
//! shared pine, whose planes switch levels between 14 and 60 pixels: at exactly 32 pixels its
//! impostors read 0.0473 against its point tree's 0.0331, mid-morph; over the octave, 0.0441
//! against 0.0352):
//! - the *reference*: every triangle of `TRIANGLES`, rasterised at `k × k` samples per pixel
//!   (`k` = `supersample`, lowered so a side stays within [`MAX_REFERENCE_SIDE`]) and
//!   box-filtered to the pixel's mean colour, its alpha-tested leaves kept as `treelod eval`'s
//!   reference keeps them (the renderer's stochastic alpha: a minified fragment where its
//!   filtered coverage exceeds a hash of its sample and depth), so on average they cover what
//!   their texels cover at any distance;
//! - each representation at one sample per pixel, as the renderer draws it without MSAA, with
//!   the runtime's own selection rules at the metres per pixel `p = H/h` of that height (`H` the
//!   block's height): Gilet's cut at the default pixel thresholds (`s_min` 1, `s_max` 2, no depth
//!   bias), point discs of their radius (a sub-pixel disc as the one-pixel splat of spec §10.1,
//!   half of them drawn as their disc covers the pixel's centre; under 64 pixels the mean over
//!   several draws of which splats the hash keeps, [`splat_seeds_at`]), pruned leaves at `λ(h)` scaled by
//!   `s_opt(λ)` or `1/λ`, impostor planes at `τ_p` with their atlas' alpha test, each morphing
//!   towards its parent over the last octave of its interval and cross-fading with it over the
//!   last quarter as the renderer draws them by default (`vs_plane`), the bark of both
//!   as the runtime draws it by default (impostor trees: the branch lines of `τ = p` where the
//!   container has lines; pruned trees, and impostor trees without lines: the LoD chain's bark
//!   level for `τ_p` where the container has a chain, else every bark triangle), ellipsoids at
//!   `τ = p` with the renderer's noise holes
//!   and the branch lines (or every bark triangle without lines), both with the renderer's
//!   default level blend ([`DEFAULT_LEVEL_BLEND`]: the level fading out and the one fading in
//!   each on its share of the pixels by a per-pixel dither, both submitted), the billboards, the
//!   octahedral impostors (one quad per tree facing the view, each pixel textured by one of the
//!   three baked views around the view direction with the probability of its weight, by the same
//!   per-pixel dither, each pixel lit by the chosen view's normal texel where the container has
//!   the views' normals, spec §6.13.3, as `shaders/tree/octahedral.wgsl` draws it; their rows go to the sections
//!   of format 1.12, spec §6.18); and
//!   each
//!   level of the LoD chain, every tree's level of that number as the runtime switches a block's
//!   trees together (spec §6.17; the chain's `lod-chain` rows follow from them, below). Alpha-tested triangles are tested against their cutoff at the
//!   trilinear sample of the renderer's own texture layers ([`treelod_runtime::texels`]: every
//!   material image resampled to one side of at most 512 texels, binary alpha, mips of the
//!   covered fraction), so thin leaves thin out far away exactly as on the GPU (measured on the
//!   shared orchid tree, whose 1024-texel leaf atlas the source-resolution test with nearest mips
//!   of earlier builds drew 1.7× as dark as the reference at 64–256 pixels, where the renderer
//!   draws it 1.15× as dark); planes and billboards sample their atlases' stored mips.
//!
//! Each view is a square image the width of the block's bounding sphere, at most
//! [`MAX_VIEW_HEIGHTS`] heights across (`view_side`); of a block wider than that it shows the middle.
//!
//! Every image is shaded ([`crate::shade`]): each surface's albedo (material colour, vertex or
//! record colour, texture at the mip level the renderer samples), its normal and its ambient
//! occlusion, lit by the renderer's default light ([`treelod_runtime::Light::DEFAULT`]) without
//! shadows, nearest fragment in front, on a white background as `treelod eval` draws it. The
//! error is the multi-scale RMSE of that linear colour (`treelod_eval::metrics`, Clasen §4:
//! levels from single pixels to the whole image) against the reference, averaged over every view
//! (`CALIBRATION`, spec §6.15) and over the views of each elevation (`CALIBRATION_ELEVATIONS`,
//! §6.16: a policy chooses a tree by the views nearest to its own) — the measure `eval` reports, so a representation that keeps a tree's silhouette but darkens
//! it, or lights a clump of leaves as one flat card, pays for it in the table. The metadata
//! records it as `calibration.error = "colour"`. (Earlier builds, whose metadata lacks the key,
//! measured coverage alone, against a reference and with leaves tested at the source texture's
//! resolution: on the shared orchid tree the impostors then read as the best image at 128–256
//! pixels, 0.054 against the full mesh's 0.077, where `eval` measures them at 0.054 against
//! 0.037; these tables read 0.050 and 0.057 against 0.035 and 0.034.) The cost is
//! the number of primitives submitted: the prefixes of points, planes, ellipsoids and lines a
//! renderer submits per cell, the coarser records its vertex shader drops included, so that the
//! tables count what the renderer's frame statistics, `eval` and the policy's budget count (the
//! point tree's cut alone undercounted it about twofold: the Quaternius tree at 32–128 pixels
//! submits 4013 primitives where its cut holds about 1900; counting the level of `τ` alone, the
//! ellipsoid, line and plane rows of earlier builds said the shared pine's impostor trees submit
//! 36 primitives at 16 pixels where the renderer, with its level blend, submits 87, and 145 at 32
//! where it submits 347). Drawn and counted as the renderer draws them, each view at its own
//! phase, the tables moved the policy's forests as follows (`bench --trees 200 --frames 30 --size
//! 480x270`, policy primitives, with `--quality` RMSE and FLIP against the reference whose
//! pixel-depth hash keeps far layers apart; earlier tables, then these): the oak 29,669, 0.01828,
//! 0.03641 and 35,448, 0.01781, 0.03662; the pine 42,786, 0.02042, 0.04172 and 59,270, 0.01986,
//! 0.04153; primitives alone, the orchid 52,191 and 54,193, the Quaternius tree 51,457 and
//! 46,515, the jacaranda 281,494 and 202,077. Everything runs on the CPU rasteriser
//! ([`crate::raster`]): the tables are the same on every machine and for any thread count (views
//! run in parallel, results are summed in order).
//!
//! **FLIP** (spec §6.19). With the `flip` feature (the command line's), every image is also
//! compared with its reference by FLIP (Andersson et al. 2020: LDR, 67 pixels per degree, both
//! encoded to 8-bit sRGB; `treelod_eval::metrics::flip`, as `treelod eval` measures it), and the
//! mean over the same views of each row of the four tables goes to `CALIBRATION_FLIP`
//! ([`Calibrated::flip`]): the multi-scale RMSE counts a single pixel's difference as much as a
//! crown's, FLIP weighs them as a viewer sees them, and the policy asks for both (spec §10.2).
//! The chain's levels are compared too, their means over every view going to
//! `CHAIN_CALIBRATION_FLIP` (spec §6.20, [`Calibrated::chain_flip`]): the runtime then picks the
//! chain's level by both errors, as it picks a representation, and the `lod-chain` rows, the
//! level so picked, have a FLIP error at every height. (Before format 1.18 the levels were chosen
//! by their RMSE alone and the `lod-chain` rows had a FLIP error only where the chain drew the
//! full mesh: comparing the levels too took the maple's calibration from 17.2 to 19.5–19.8 s,
//! its build with every representation from 45.6 to 47.9–48.5 s, alternating, 2 runs each.)
//! Measured on 2 cores, alternating builds with every
//! representation: the oak's calibration stage 4.86–5.03 s → 8.04–8.29 s (the build 16.3 → 19.5 s),
//! the maple's 10.6 → 20.1 s (43.7 → 53.7 s), the same peak memory.
//!
//! **The LoD chain** (spec §6.17, §10.2). The chain's levels are drawn from the same views as
//! every representation and their table, `CHAIN_CALIBRATION`, is the mean over every view, as
//! `CALIBRATION` is: the runtime picks the chain's level per model by those means whatever the
//! elevation a tree is seen from, so one table per level is all it reads (a level is a mesh, and
//! loses against the full mesh much the same from every side: spec §6.17 gives the numbers).
//! The levels cost one drawing per level, height and view in place of the chain's one: `treelod
//! build --impostors --ellipsoids --lines --baselines --timings`, stage `calibration`, three runs
//! each on a shared two-core machine, the oak 6.3–7.2 s without them and 7.6–7.9 s with them
//! (its five levels), the pine 3.6–3.8 and 4.0–4.3 s, the Quaternius tree 1.6–1.8 and 2.0–2.2 s.
//! The chain's own `lod-chain` rows are then not drawn by the
//! geometric rule but describe the chain as the runtime draws it with these tables: at each
//! height the full mesh or the level that [`Calibration::chain_level`] picks with
//! [`Policy::DEFAULT_TARGET`] (among the representations measured here), measured over every view
//! for `CALIBRATION` and over each elevation's views for `CALIBRATION_ELEVATIONS`, so a policy
//! compares the chain it will draw from where it is seen. (A chain whose levels do not cover
//! every tree, which verified files do not have, is drawn by the geometric rule instead: per
//! tree the coarsest level whose error is at most `τ = p`.)
//!
//! Impostor planes textured indirectly (`LEAF_SLOTS`, spec §6.10.1) are not drawn here: a
//! container with them has no impostor rows, and a policy never picks a representation without
//! rows.

use glam::{Quat, Vec2, Vec3, Vec4};
use rayon::prelude::*;
use treelod_eval::metrics::{LinearImage, multiscale_rmse};
use treelod_format::pack::{oct_decode, unpack_rgba8, unpack_unorm16x2};
use treelod_format::{
    CalibrationRecord, ChainCalibrationRecord, ChainFlipCalibrationRecord, ContainerData, ElevationCalibrationRecord,
    FlipCalibrationRecord, ImageRecord, NO_IMAGE, OctahedralDepthRecord, OctahedralNormalGridRecord,
    OctahedralNormalRecord, OctahedralRecord, PlaneDiffuseRecord, Setting, TriangleRecord, billboard_kind,
    calibration_technique, decode_ao, image, image_format, material_class, octahedral_depth_starts, point_facing_scale,
    prune_leaves_drawn,
};
use treelod_runtime::impostor::{
    BARK_AREA_KEPT, BARK_ERROR_SHARE, NO_PARENT, area, crossfade, morph_corner, morph_share, plane_parents,
};
use treelod_runtime::prune::{PruneScale, curve_at, leaf_scale, size_factor};
use treelod_runtime::{
    Calibration, ChainPick, DEFAULT_LEVEL_BLEND, Light, LodChain, LodSettings, Policy, Technique, Thresholds,
    level_keep, point_drawn, triangle_drawn,
};

use treelod_runtime::policy::target_at;
use treelod_runtime::texels::{self, Sampler, Texels};

use crate::raster::{CHUNK, NOISE_SIZE, ProjectedChunk, View, ellipse_spans, ellipsoid_hits, noise_cut};
use crate::shade::{Canvas, Surface, depth, triangle_pixels};

/// Projected heights of the block at which every representation is measured, pixels: octaves
/// from a tree a few pixels high to one a quarter of a 1080p screen high. Larger trees are few
/// and near: a policy draws them with the representation that converges to the full mesh (the
/// point tree), so the table stops here and the build spends its time where the choice is made
/// (the images of 512 pixels would cost four times all the others).
///
/// The table starts at 4 pixels (builds before it started at 8): below its smallest height a
/// policy draws every tree as it draws one of that height, and a large forest's trees are mostly
/// smaller than 8 pixels. With the table from 8 pixels the shared orchid's 10⁶ trees (`bench
/// --trees 1000000 --frames 12 --size 480x270 --technique policy --no-render`) drew 349,115
/// trees a frame with impostor planes and their branch lines, 8.56 million primitives, the
/// 8-pixel choice seen from low; the weeping willow's drew 336,390 with the point tree, 28.0
/// million. Measured at 4 pixels, the cheap quads come within the target there (the orchid's
/// billboard is the least error over every view at 4 pixels, 0.0894, where the impostors read
/// 0.0751 at 8 pixels and 0.0903 at 4), and the same flights submit 2.38 and 1.36 million
/// primitives. The 1,000-orchid forest (`--trees 1000 --frames 30 --quality`), whose overview
/// holds about 940 trees under 8 pixels, drew them as billboards and crossed quads and read
/// RMSE .03568 → .03468, FLIP .06217 → .06019 and temporal noise 1.08 → 1.05 times the
/// reference's, with 398,025 → 394,545 primitives a frame. Its recall fell (.893 → .816; in the
/// overview .91 → .54, precision .75 → .78): the planes had covered 1.2 times the reference's
/// pixels there, the quads cover 0.7 of them, each pixel nearer the reference's colour. The
/// other shared models' forests and flights, whose small trees were already one octahedral quad
/// each, draw the same. The 49 views more cost the maple's build with every representation
/// 17.6 → 20.9 s of calibration (49.4 → 52.2 s in all, one run each, 2 cores), the jacaranda's
/// 6.8–7.1 → 7.1–8.1 s and the orchid's within the runs' noise (7.8–8.9 → 7.9–8.2 s; two
/// alternating runs each). A 2-pixel height was measured and not taken: there the full mesh (its
/// mip-filtered alpha test on a few pixels) becomes the least error of all (the orchid 0.0870
/// against its billboard's 0.0972), and the tables would put every representation but the LoD
/// chain past the target.
pub const HEIGHTS: [f32; 7] = [4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0];

/// The widest a view's image is, in heights of the block (the `h` pixels it is drawn at): the
/// block's sphere is `2·radius/p` pixels across at `p` metres per pixel, and a view whose sphere
/// is wider shows the middle of it, this many heights across, in the reference and every
/// representation alike — as a screen frames a tree. The shared models' spheres are 1.32–2.23
/// heights across (the pine's and the orchid's), so no view of theirs is cut. A block far wider
/// than high — a stray vertex a hundred metres from a 2.5-metre tree — would otherwise draw
/// every image thousands of pixels wide at the largest heights, and its calibration, whose cost
/// grows with the square of that width, took minutes (measured: `--baselines` on a 3k-triangle
/// tree over 120 s); cut, a view costs at most (4 / 2.23)² ≈ 3.2 times the orchid's.
pub const MAX_VIEW_HEIGHTS: f32 = 4.0;

/// The side of a view's square image, pixels, for a block of bounding-sphere `radius` drawn at
/// `metres_per_pixel`, `pixels` high: the sphere's width, at most [`MAX_VIEW_HEIGHTS`] times
/// `pixels`, at least 4.
#[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "rounded up, saturating")]
fn view_side(radius: f32, metres_per_pixel: f32, pixels: f32) -> u32 {
    let widest = (MAX_VIEW_HEIGHTS * pixels).ceil() as u32;
    ((2.0 * radius / metres_per_pixel).ceil() as u32).min(widest).max(4)
}

/// The largest side of a supersampled reference image, samples: the supersampling is lowered
/// where a view would be larger (a block much wider than high at 256 pixels).
pub const MAX_REFERENCE_SIDE: u32 = 2048;

/// How far the renderer turns an ellipsoid's normal towards its noise texel's random vector
/// (`ELLIPSOID_NORMAL_NOISE` in `shaders/tree/ellipsoids.wgsl`).
const ELLIPSOID_NORMAL_NOISE: f32 = 0.5;

/// Noise texels per radian of the renderer's ellipsoid noise (`shaders/tree/ellipsoids.wgsl`).
const NOISE_TEXELS_PER_RADIAN: f32 = 40.0;

/// Elevations of the calibration's views above the block's horizontal plane, degrees (spec
/// §6.16): from the side, as a walker sees a tree far away, to straight down, as a flight over a
/// forest sees it. Representations differ most in how they take elevation: measured on the
/// shared oak at 8 pixels, its crossed billboards read 0.049, 0.077, 0.147 and 0.229 from 0°,
/// 45°, 75° and 89°, where its point tree reads 0.058 to 0.072 — so a policy choosing by one
/// table made mostly of side views drew forests seen from above with billboards.
pub const ELEVATIONS: [f32; 4] = [0.0, 30.0, 60.0, 90.0];

/// Settings of the calibration (recorded in the metadata as `calibration.*`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CalibrationConfig {
    /// Orthographic views per elevation of [`ELEVATIONS`] below 90° ([`calibration_views`]) at
    /// 64 pixels and above, more below ([`views_at`]); one view straight down from 64 pixels up,
    /// more below ([`down_views_at`]). Default 2: 7 views in all from 64 pixels up, 56 at 8 and 4
    /// pixels.
    pub views: usize,
    /// Samples per pixel side of the reference. Default 4.
    pub supersample: u32,
    /// Whether heights under 64 pixels take more views ([`views_at`], [`down_views_at`]). Default
    /// `true`; `false` takes `views` and one straight down at every height, as builds before did
    /// (tests that count on one view a height).
    pub more_small_views: bool,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self { views: 2, supersample: 4, more_small_views: true }
    }
}

impl CalibrationConfig {
    /// The views per elevation below 90° at a height of `pixels`: [`views_at`], or
    /// [`Self::views`] without [`Self::more_small_views`].
    #[must_use]
    pub fn views_at(&self, pixels: f32) -> usize {
        if self.more_small_views { views_at(self.views, pixels) } else { self.views.max(1) }
    }

    /// The views straight down at a height of `pixels`: [`down_views_at`], or one without
    /// [`Self::more_small_views`].
    #[must_use]
    pub fn down_views_at(&self, pixels: f32) -> usize {
        if self.more_small_views { down_views_at(pixels) } else { 1 }
    }

    /// The draws of the point tree per view at a height of `pixels`: [`splat_seeds_at`], or one
    /// without [`Self::more_small_views`].
    #[must_use]
    pub fn splat_seeds_at(&self, pixels: f32) -> usize {
        if self.more_small_views { splat_seeds_at(pixels) } else { 1 }
    }

    /// The metadata settings recording this configuration (spec §7.1): `calibration.views`, the
    /// views per elevation from 64 pixels up, `calibration.views_by_height`, those at each of
    /// [`HEIGHTS`] ([`views_at`]), `calibration.views_down_by_height`, the views straight down at
    /// each ([`down_views_at`]; files without it took one), and `calibration.elevations`, the
    /// elevations in degrees (files of format 1.5 and 1.6, without the latter, counted every view
    /// in `calibration.views`).
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        let elevations: Vec<String> = ELEVATIONS.iter().map(ToString::to_string).collect();
        let by_height: Vec<String> = HEIGHTS.iter().map(|&h| self.views_at(h).to_string()).collect();
        let down: Vec<String> = HEIGHTS.iter().map(|&h| self.down_views_at(h).to_string()).collect();
        let seeds: Vec<String> = HEIGHTS.iter().map(|&h| self.splat_seeds_at(h).to_string()).collect();
        vec![
            Setting { key: "calibration.views".into(), value: self.views.to_string() },
            Setting { key: "calibration.views_by_height".into(), value: by_height.join(",") },
            Setting { key: "calibration.views_down_by_height".into(), value: down.join(",") },
            Setting { key: "calibration.splat_seeds_by_height".into(), value: seeds.join(",") },
            Setting { key: "calibration.elevations".into(), value: elevations.join(",") },
            Setting { key: "calibration.supersample".into(), value: self.supersample.to_string() },
            Setting { key: "calibration.error".into(), value: "colour".into() },
        ]
    }
}

/// The views per elevation below 90° at a height of `pixels` for `views` at 64 pixels and above:
/// `views · 64 / pixels` below, at most 8 times as many (8 and 4 pixels: 8 times). A view's error
/// is a mean over the few pixels the tree covers, and which of them a thin leaf or a splat lands on
/// changes from view to view: with 2 views at every height the shared weeping willow's full mesh
/// read 0.0507 from 30° at 8 pixels (0.0704 at 16) and its point tree 0.1044 (0.0614 at 16), a
/// floor no cheap representation came within the target of, so a policy drew its small trees with
/// the LoD chain's 15,037 triangles; with 8 views at every height the same entries read 0.0674 and
/// 0.0794 and the point tree's row over every view fell with size at every height. Small images
/// cost little beyond their primitives, so the views are added where they are noisiest and
/// cheapest; the same holds straight down ([`down_views_at`]). At 4 pixels the views stay as many
/// as at 8 (16 times would add as many again for a table a policy reads only below 8 pixels).
#[must_use]
pub fn views_at(views: usize, pixels: f32) -> usize {
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a factor of 1 to 8")]
    let factor = (SMALL_HEIGHT / pixels).ceil().clamp(1.0, 8.0) as usize;
    views.max(1) * factor
}

/// The height from which the calibration takes `views` per elevation, and below which more
/// ([`views_at`]).
pub const SMALL_HEIGHT: f32 = 64.0;

/// The views straight down at a height of `pixels`: one from 64 pixels up, below as many more as
/// [`views_at`] takes around the tree (`64 / pixels`, at most 8: 8, 8, 4 and 2 at 4, 8, 16 and 32
/// pixels), each turned about the vertical a step of a full turn further and drawn at its own
/// phase of the octave. One view straight down is as noisy at a few pixels as one from the side:
/// which pixels the crown's gaps fall on changes with the turn of the pixel grid. Measured on the
/// shared orchid, whose one view read its point tree 0.0748 at 4 pixels, 0.1092 at 8 and 0.0547 at
/// 16, so that its trees under 8 pixels seen from above took the point tree (11,947 trees a frame
/// of a 10⁶-tree flight); over 8 views 0.1279, 0.0800 and 0.0609, its impostor planes the least
/// error at 4 and 8 pixels (0.0968 and 0.0796), which `treelod eval` from 84–86° confirms. The
/// maple's one view had read its octahedral quad 0.0659 at 4 pixels, the least there; over 8
/// views 0.0887 against its planes' 0.0817, where `eval` from 84–86° still reads the quad best
/// (the calibration and `eval` still disagree on some models' trees of a few pixels).
#[must_use]
pub fn down_views_at(pixels: f32) -> usize {
    views_at(1, pixels)
}

/// The draws of the point tree per view at a height of `pixels`, each keeping its sub-pixel
/// splats by another hash (`seed`), whose errors are averaged: one from 64 pixels up, below
/// `64 / pixels`, at most 8 (8, 8, 4 and 2 at 4, 8, 16 and 32 pixels). A splat under a pixel is
/// kept or dropped whole by a hash (spec §10.1), and the renderer's hash is of the point's
/// position and the tree's instance: each tree of a forest shows its own draw, so the table must
/// hold the mean over draws, not the one draw a view's hash happens to make. A tree a few pixels
/// high keeps a handful of splats, and which ones weighs as much as the view: measured on the
/// shared willow from the side at 4 pixels (16 views, 8 draws each), the point tree's error
/// varied by 0.0274 (standard deviation) between the draws of one view and by 0.0281 between
/// views, and the one draw of earlier builds read 0.0727 where the mean of 8 reads 0.0925 (at 8
/// pixels 0.0758 and 0.0782). Earlier builds, one draw a view, ranked the point tree first among
/// the willow's representations at 4 pixels, where `treelod eval` ranks the octahedral quad
/// first. The full mesh's and the pruned trees' triangles keep one draw a view: the renderer
/// alpha-tests them with the plain test by default (`Settings::stochastic_alpha` off), which
/// reads the texture at the pixel and no hash, as the calibration draws them; only the
/// reference takes the stochastic test, over `supersample²` samples a pixel.
#[must_use]
pub fn splat_seeds_at(pixels: f32) -> usize {
    views_at(1, pixels)
}

/// The calibration's views (unit directions towards the viewer) with the index of their
/// elevation in [`ELEVATIONS`]: per elevation below 90°, `per_elevation` views (at least one)
/// spread evenly around the vertical axis — over half a turn from the side (an orthographic view
/// from the opposite side sees the mirror image), over a full turn from above — half a step off
/// the axes, and each ring a quarter step further round than the one below it; and one view
/// straight down. No view lies along the axes the build bakes billboards from (`+Z` for the
/// facing quad, 0°, 60° and 120° for the crossed ones): a billboard seen exactly from its bake
/// direction shows its best image, which a camera almost never sees. Measured on the shared
/// orchid from the side: with views at 0° and 90° azimuth its facing billboard read 0.057, 0.061
/// and 0.059 at 32, 64 and 128 pixels, close enough to its impostor planes for a policy to draw
/// far trees with it; with views at 45° and 135°, 0.068, 0.075 and 0.080.
#[must_use]
pub fn calibration_views(per_elevation: usize, down: usize) -> Vec<CalibrationView> {
    let n = per_elevation.max(1);
    let mut views = Vec::new();
    for (e, &degrees) in ELEVATIONS.iter().enumerate() {
        if degrees >= 90.0 {
            let m = down.max(1);
            #[expect(clippy::cast_precision_loss, reason = "a few views")]
            views.extend((0..m).map(|k| CalibrationView {
                elevation: e,
                direction: Vec3::Y,
                roll: std::f32::consts::TAU * k as f32 / m as f32,
            }));
            continue;
        }
        let elevation = degrees.to_radians();
        let turn = if degrees == 0.0 { std::f32::consts::PI } else { std::f32::consts::TAU };
        #[expect(clippy::cast_precision_loss, reason = "a few views")]
        for k in 0..n {
            let azimuth = turn * (k as f32 + 0.5 + 0.25 * e as f32) / n as f32;
            let (s, c) = azimuth.sin_cos();
            let direction = Vec3::new(elevation.cos() * s, elevation.sin(), elevation.cos() * c);
            views.push(CalibrationView { elevation: e, direction, roll: 0.0 });
        }
    }
    views
}

/// One of the calibration's views ([`calibration_views`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationView {
    /// The index of its elevation in [`ELEVATIONS`].
    pub elevation: usize,
    /// The unit direction towards the viewer.
    pub direction: Vec3,
    /// The turn of its image about the direction, radians ([`View::rolled`]): 0 but for the
    /// views straight down after the first.
    pub roll: f32,
}

/// What [`calibrate`] measured: the tables over every view (`CALIBRATION`, spec §6.15), per
/// elevation (`CALIBRATION_ELEVATIONS`, spec §6.16) and per level of the LoD chain
/// (`CHAIN_CALIBRATION`, spec §6.17).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Calibrated {
    /// Per technique of `CALIBRATION` (codes below `FIRST_ADDED`) and height, the mean over every
    /// view.
    pub mean: Vec<CalibrationRecord>,
    /// Per elevation of [`ELEVATIONS`], technique of `CALIBRATION` and height, the mean over that
    /// elevation's views.
    pub elevations: Vec<ElevationCalibrationRecord>,
    /// The same as `mean` for the techniques of format 1.12 on (`CALIBRATION_ADDED`, spec
    /// §6.18), in sections of their own so that readers of 1.5 to 1.11 skip them rather than
    /// refuse codes they do not know.
    pub added: Vec<CalibrationRecord>,
    /// The same as `elevations` for those techniques (`CALIBRATION_ELEVATIONS_ADDED`).
    pub elevations_added: Vec<ElevationCalibrationRecord>,
    /// Per LoD chain level and height, sorted by level, then height, the mean over every view;
    /// empty without a chain.
    pub chain_levels: Vec<ChainCalibrationRecord>,
    /// The mean FLIP error of every row of `mean`, `added`, `elevations` and `elevations_added`
    /// (`CALIBRATION_FLIP`, spec §6.19): the rows over every view first, then per elevation,
    /// each sorted by technique, then height. Empty without the `flip` feature.
    pub flip: Vec<FlipCalibrationRecord>,
    /// The mean FLIP error of every record of `chain_levels`, in the same order
    /// (`CHAIN_CALIBRATION_FLIP`, spec §6.20). Empty without the `flip` feature or a chain.
    pub chain_flip: Vec<ChainFlipCalibrationRecord>,
}

/// What the calibration draws, gathered once from the container's arrays.
struct Scene<'a> {
    data: &'a ContainerData,
    /// Per image a plane or billboard samples: its stored mip levels (RGBA8), its size and how
    /// it is sampled; `None` for other images, leaf slots and images that do not decode.
    atlases: Vec<Option<Atlas>>,
    /// The materials' textures as the renderer's texture array holds them ([`texels::Layers`]).
    layers: texels::Layers,
    /// Per material: its base colour (linear RGBA), its image's layer, if any, and its alpha
    /// cutoff (`None`: opaque), as `fs_triangle` reads them.
    materials: Vec<(Vec4, Option<usize>, Option<f32>)>,
    /// Per vertex: its normal, its colour (linear RGBA) and its ambient occlusion.
    vertices: Vec<(Vec3, Vec4, f32)>,
    /// Every triangle of `TRIANGLES`, ready to rasterise (the reference and the full mesh).
    full: Tris,
    /// The triangles of `TRIANGLES` that are not of a leaf material (pruned and impostor trees
    /// draw them all where the container has no chain, and near).
    bark: Tris,
    /// The LoD chain's bark levels as the runtime keeps them for pruned and impostor trees
    /// (`treelod_runtime::ChainRanges::bark_levels`): per level, finest first, its block error
    /// (the largest of its trees', kept non-decreasing) and its bark triangles, while they keep
    /// [`BARK_AREA_KEPT`] of the full bark's area; empty without a chain, planes or pruning.
    chain_bark: Vec<(f32, Tris)>,
    /// The LoD chain's levels as the runtime switches a block's trees together
    /// ([`LodChain::from_records`]): per level, finest first, every tree's triangles of that
    /// level; empty without a chain.
    chain_levels: Vec<Tris>,
    /// Whether the impostor planes can be drawn (an RGBA atlas, not leaf slots).
    planes_drawable: bool,
    /// Per plane, its parent's index or [`NO_PARENT`] ([`plane_parents`]).
    plane_parents: Vec<u32>,
}

/// A textured quad to draw: an impostor plane or a billboard.
struct Quad {
    /// Corners, metres, at [`QUAD_CORNERS`] of the quad's axes.
    corners: [Vec3; 4],
    /// The normal it is lit with (`axis_u × axis_v`).
    normal: Vec3,
    /// How the leaves it stands for take the sun (spec §6.10.2; [`PlaneDiffuseRecord::FLAT`]
    /// for a billboard or a plane without the record).
    diffuse: PlaneDiffuseRecord,
    /// The atlas it samples.
    image: u32,
    /// The atlas coordinates of its corners (texture coordinates vary linearly over it).
    uvs: [Vec2; 4],
    /// The rectangle of the atlas (`min`, `max`) outside which it is empty (an octahedral
    /// impostor's view past its cell); `None` for a quad textured all over.
    window: Option<(Vec2, Vec2)>,
    /// Mip levels finer than the pixel's footprint it is sampled from: 1 for an octahedral
    /// impostor's view (as `octahedral_texel` samples it), 0 for planes and billboards.
    finer: f32,
    /// Where its normals lie: an octahedral impostor's view with normals (spec §6.13.3), each
    /// pixel lit by its normal texel as `fs_octahedral` lights it; `None` for a quad lit as a
    /// whole.
    normals: Option<NormalGrid>,
}

/// Where an octahedral impostor's normals lie in its atlas (spec §6.13.3): the colour grid's
/// point `uv` has its normal at `normal_min + (uv − colour_min) · scale`, atlas coordinates.
#[derive(Clone, Copy)]
struct NormalGrid {
    colour_min: Vec2,
    normal_min: Vec2,
    /// The normal grid's side over the colour grid's, per axis (½ as builders write it).
    scale: Vec2,
}

impl NormalGrid {
    /// The grid of `normals` for the colour grid of `record`.
    fn new(record: &OctahedralRecord, normals: &OctahedralNormalGridRecord) -> Self {
        let corner = |packed: u32| Vec2::from_array(unpack_unorm16x2(packed));
        let (colour_min, colour_max) = (corner(record.uv_min), corner(record.uv_max));
        let (normal_min, normal_max) = (corner(normals.uv_min), corner(normals.uv_max));
        Self {
            colour_min,
            normal_min,
            scale: (normal_max - normal_min) / (colour_max - colour_min).max(Vec2::splat(1e-9)),
        }
    }

    /// The normal grid's point of the colour grid's `uv`.
    fn uv(&self, uv: Vec2) -> Vec2 {
        self.normal_min + (uv - self.colour_min) * self.scale
    }

    /// The mip level, of a colour texel's footprint `lod`, of its normal texel's (a texel of a
    /// smaller grid covers more of the colour's).
    fn lod(&self, lod: f32) -> f32 {
        lod + self.scale.max_element().max(1e-9).log2()
    }
}

/// A quad's corners in its axes, in [`Quad::corners`] order: `(−1, −1)` at `uv_min`, then
/// counter-clockwise in texture space.
const QUAD_CORNERS: [(f32, f32); 4] = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];

impl Quad {
    /// The flat quad `centre ± u ± v` (spec §6.10), lit with `u × v`.
    fn flat(centre: Vec3, (u, v): (Vec3, Vec3), image: u32, uv: (u32, u32)) -> Self {
        let (lo, hi) = (Vec2::from_array(unpack_unorm16x2(uv.0)), Vec2::from_array(unpack_unorm16x2(uv.1)));
        Self {
            corners: QUAD_CORNERS.map(|(s, t)| centre + u * s + v * t),
            normal: u.cross(v),
            diffuse: PlaneDiffuseRecord::FLAT,
            image,
            uvs: QUAD_CORNERS.map(|(s, t)| lo + Vec2::new(0.5 * (s + 1.0), 0.5 * (t + 1.0)) * (hi - lo)),
            window: None,
            finer: 0.0,
            normals: None,
        }
    }
}

/// An atlas as the renderer samples it: its stored levels, largest first, as RGBA8 texels.
struct Atlas {
    levels: Vec<Vec<u8>>,
    size: (u32, u32),
    sampler: Sampler,
}

/// A triangle to draw: its corners and what it is made of.
#[derive(Clone, Copy, Debug)]
struct Tri {
    /// Corners, metres.
    positions: [Vec3; 3],
    /// What it is made of.
    made_of: MadeOf,
}

/// What a [`Tri`] is made of: read only where it holds a pixel centre.
#[derive(Clone, Copy, Debug)]
struct MadeOf {
    /// Texture coordinates of the corners.
    uvs: [Vec2; 3],
    /// Its corners' vertices (their normals, colours and ambient occlusion).
    indices: [u32; 3],
    material: u32,
}

/// Triangles to draw, their corners apart from what they are made of: every view projects each
/// triangle's corners, but most triangles of a large tree in a small view hold no pixel centre,
/// and only the others read the rest (a [`Tri`]'s corners are 36 of its 76 bytes, so the views
/// stream under half as much memory). The corners are stored coordinate by coordinate, so that a
/// view projects [`CHUNK`] triangles at once ([`View::project_chunk`]).
#[derive(Default)]
struct Tris {
    /// `corners[3·c + a][i]`: axis `a` (x, y, z) of corner `c` of triangle `i`, metres.
    corners: [Vec<f32>; 9],
    /// Per triangle, what it is made of.
    made_of: Vec<MadeOf>,
}

impl Tris {
    fn len(&self) -> usize {
        self.made_of.len()
    }

    fn push(&mut self, Tri { positions, made_of }: Tri) {
        for (k, corner) in positions.iter().enumerate() {
            self.corners[3 * k].push(corner.x);
            self.corners[3 * k + 1].push(corner.y);
            self.corners[3 * k + 2].push(corner.z);
        }
        self.made_of.push(made_of);
    }

    /// The corners of triangle `i`.
    fn positions(&self, i: usize) -> [Vec3; 3] {
        let c = &self.corners;
        core::array::from_fn(|k| Vec3::new(c[3 * k][i], c[3 * k + 1][i], c[3 * k + 2][i]))
    }

    /// The corners of the triangles from `start` on as [`View::project_chunk`] takes them: read in
    /// place, or copied into `padded` where fewer than [`CHUNK`] are left (the rest NaN, holding
    /// no pixel centre).
    fn chunk<'a>(&'a self, start: usize, padded: &'a mut [[f32; CHUNK]; 9]) -> [&'a [f32; CHUNK]; 9] {
        let mut axes = self.corners.iter();
        padded.each_mut().map(|pad| {
            let rest = axes.next().and_then(|axis| axis.get(start..)).unwrap_or(&[]);
            match rest.first_chunk::<CHUNK>() {
                Some(whole) => whole,
                None => {
                    pad[..rest.len()].copy_from_slice(rest);
                    pad[rest.len()..].fill(f32::NAN);
                    pad
                }
            }
        })
    }
}

impl Extend<Tri> for Tris {
    fn extend<I: IntoIterator<Item = Tri>>(&mut self, iter: I) {
        for tri in iter {
            self.push(tri);
        }
    }
}

impl FromIterator<Tri> for Tris {
    fn from_iter<I: IntoIterator<Item = Tri>>(iter: I) -> Self {
        let mut tris = Self::default();
        tris.extend(iter);
        tris
    }
}

/// The calibration of `data` (spec §6.15–§6.17): for every representation it holds, its error
/// and primitive count at each of [`HEIGHTS`] over every view, sorted by technique, then height,
/// the same per elevation of [`ELEVATIONS`], sorted by elevation first, and where it has a LoD
/// chain, the same for each of the chain's levels over every view. Empty for a block without
/// height or triangles.
///
/// With a chain, its `lod-chain` rows are not drawn by the geometric rule but describe the chain
/// as the runtime draws it with per-level tables (module docs): at each height, the full mesh's
/// or the level's measurement that [`Calibration::chain_level`] picks with
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
    // With per-level tables the chain's rows follow from them: its levels are drawn instead.
    let per_level = !scene.chain_levels.is_empty();
    let techniques: Vec<u32> =
        held.iter().copied().filter(|&t| !(per_level && t == calibration_technique::LOD_CHAIN)).collect();
    let (centre, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
    // Per height, its views ([`views_at`]: more below 64 pixels).
    let directions: Vec<Vec<CalibrationView>> = HEIGHTS
        .iter()
        .map(|&pixels| calibration_views(config.views_at(pixels), config.down_views_at(pixels)))
        .collect();
    // Each view measures its own fraction of an octave off the nominal height, the views of an
    // elevation spread evenly over the octave around it (module docs): a table then holds the
    // mean over the phases of the representations' level switches, as trees at every distance
    // in a forest show them, not the one phase an exact octave falls on.
    #[expect(clippy::cast_precision_loss, reason = "a few views")]
    let offsets: Vec<Vec<f32>> = directions
        .iter()
        .map(|directions| {
            (0..directions.len())
                .map(|v| {
                    let elevation = directions[v].elevation;
                    let same = directions.iter().filter(|d| d.elevation == elevation).count();
                    let k = directions[..v].iter().filter(|d| d.elevation == elevation).count();
                    ((k as f32 + 0.5) / same as f32 - 0.5).exp2()
                })
                .collect()
        })
        .collect();
    let jobs: Vec<(usize, usize)> =
        (0..HEIGHTS.len()).flat_map(|h| (0..directions[h].len()).map(move |v| (h, v))).collect();
    // Per job: per technique, then per chain level, (error, primitives, FLIP error; NaN without
    // the `flip` feature).
    let results: Vec<Vec<(f64, f64, f64)>> = jobs
        .par_iter()
        .map(|&(h, v)| {
            let pixels = HEIGHTS[h] * offsets[h][v];
            let metres_per_pixel = height / pixels;
            let side = view_side(radius, metres_per_pixel, pixels);
            let k = config.supersample.max(1).min((MAX_REFERENCE_SIDE / side).max(1));
            // The sphere fitted to exactly `side` pixels of `metres_per_pixel`.
            let fitted = 0.5 * side as f32 * metres_per_pixel;
            let CalibrationView { direction, roll, .. } = directions[h][v];
            let view = View::fit(direction, centre, fitted, side).rolled(roll);
            let reference = scene.reference(&View::fit(direction, centre, fitted, side * k).rolled(roll), k);
            // Encoded for FLIP once, for every technique drawn in this view.
            let flip_reference = FlipReference::new(&reference);
            let measured = techniques.iter().map(|&t| {
                // The point tree's sub-pixel splats: the mean over `seeds` draws (module docs).
                let seeds = if t == calibration_technique::SPT { config.splat_seeds_at(pixels) } else { 1 };
                let (mut sum, mut primitives) = ((0.0, 0.0), 0);
                for seed in 0..seeds as u64 {
                    let mut canvas = Canvas::new(side, BACKGROUND);
                    primitives = scene.draw(t, &view, metres_per_pixel, pixels, seed, &mut canvas);
                    let image = canvas.image();
                    sum = (sum.0 + error(&image, &reference), sum.1 + flip(&image, &flip_reference));
                }
                #[expect(clippy::cast_precision_loss, reason = "a few seeds")]
                let n = seeds.max(1) as f64;
                (sum.0 / n, primitives as f64, sum.1 / n)
            });
            let levels = scene.chain_levels.iter().map(|triangles| {
                let mut canvas = Canvas::new(side, BACKGROUND);
                scene.draw_triangles(&mut canvas, &view, triangles, false);
                let image = canvas.image();
                (error(&image, &reference), triangles.len() as f64, flip(&image, &flip_reference))
            });
            measured.chain(levels).collect()
        })
        .collect();
    // A view's weight in the means: one, but the views straight down share one view's weight, so
    // that over every view the elevations weigh as they did with one view straight down (more
    // views there make its own rows less noisy, not the rows over every view more top-down).
    #[expect(clippy::cast_precision_loss, reason = "a few views")]
    let weight = |h: usize, v: usize| -> f64 {
        if ELEVATIONS[directions[h][v].elevation] >= 90.0 { 1.0 / config.down_views_at(HEIGHTS[h]) as f64 } else { 1.0 }
    };
    // The weighted means of column `column` of the results at height `h` over the views `keep`
    // accepts, in view order: error, primitives and FLIP error (NaN where not measured).
    let means = |column: usize, h: usize, keep: &dyn Fn(usize) -> bool| -> (f32, f32, f32) {
        let per_view: Vec<(f64, (f64, f64, f64))> = jobs
            .iter()
            .zip(&results)
            .filter(|((jh, v), _)| *jh == h && keep(*v))
            .map(|(&(_, v), r)| (weight(h, v), r[column]))
            .collect();
        let n = per_view.iter().map(|r| r.0).sum::<f64>();
        let n = if n > 0.0 { n } else { 1.0 };
        let error = per_view.iter().map(|(w, r)| w * r.0).sum::<f64>() / n;
        let primitives = per_view.iter().map(|(w, r)| w * r.1).sum::<f64>() / n;
        let flip = per_view.iter().map(|(w, r)| w * r.2).sum::<f64>() / n;
        (
            (error as f32).clamp(0.0, 1.0),
            primitives as f32,
            if flip.is_nan() { f32::NAN } else { (flip as f32).clamp(0.0, 1.0) },
        )
    };
    let every = |_: usize| true;
    let mut calibrated = Calibrated::default();
    for level in 0..scene.chain_levels.len() {
        for (h, &pixels) in HEIGHTS.iter().enumerate() {
            let (error, primitives, flip) = means(techniques.len() + level, h, &every);
            let level = u32::try_from(level).unwrap_or(u32::MAX);
            calibrated.chain_levels.push(ChainCalibrationRecord { level, height: pixels, error, primitives });
            if !flip.is_nan() {
                calibrated.chain_flip.push(ChainFlipCalibrationRecord { level, height: pixels, flip });
            }
        }
    }
    // Per height, the chain's pick by image error over every view (the runtime's, at the default
    // target); empty without per-level tables.
    let picks: Vec<Option<ChainPick>> = if per_level {
        // The drawn techniques' rows over every view, and their FLIP rows where measured, so the
        // picks ask for both errors as the runtime does.
        let (mut drawn, mut drawn_flip) = (Vec::new(), Vec::new());
        for (ti, &technique) in techniques.iter().enumerate() {
            for (h, &height) in HEIGHTS.iter().enumerate() {
                let (error, primitives, flip) = means(ti, h, &every);
                drawn.push(CalibrationRecord { technique, height, error, primitives });
                if !flip.is_nan() {
                    let elevation = FlipCalibrationRecord::EVERY_VIEW;
                    drawn_flip.push(FlipCalibrationRecord { elevation, technique, height, flip });
                }
            }
        }
        let tables = Calibration::from_records(&drawn).map(|c| {
            c.with_chain_levels(&calibrated.chain_levels).with_flip(&drawn_flip).with_chain_flip(&calibrated.chain_flip)
        });
        chain_picks(tables.as_ref(), &held)
    } else {
        Vec::new()
    };
    // The column of the results that measures `technique` at height `h`: its own, or for a chain
    // with per-level tables the full mesh's or the level's it picks there (none: no row).
    let column = |technique: u32, h: usize| -> Option<usize> {
        if per_level && technique == calibration_technique::LOD_CHAIN {
            match picks.get(h).copied().flatten()? {
                Some(level) => Some(techniques.len() + level as usize),
                None => techniques.iter().position(|&t| t == calibration_technique::FULL),
            }
        } else {
            techniques.iter().position(|&t| t == technique)
        }
    };
    for &technique in &held {
        for (h, &pixels) in HEIGHTS.iter().enumerate() {
            if let Some(c) = column(technique, h) {
                let (error, primitives, flip) = means(c, h, &every);
                if !flip.is_nan() {
                    let elevation = FlipCalibrationRecord::EVERY_VIEW;
                    calibrated.flip.push(FlipCalibrationRecord { elevation, technique, height: pixels, flip });
                }
                let record = CalibrationRecord { technique, height: pixels, error, primitives };
                if technique >= calibration_technique::FIRST_ADDED {
                    calibrated.added.push(record);
                } else {
                    calibrated.mean.push(record);
                }
            }
        }
    }
    for (e, &elevation) in ELEVATIONS.iter().enumerate() {
        for &technique in &held {
            for (h, &pixels) in HEIGHTS.iter().enumerate() {
                if let Some(c) = column(technique, h) {
                    let (error, primitives, flip) = means(c, h, &|v| directions[h][v].elevation == e);
                    if !flip.is_nan() {
                        calibrated.flip.push(FlipCalibrationRecord { elevation, technique, height: pixels, flip });
                    }
                    let record = ElevationCalibrationRecord { elevation, technique, height: pixels, error, primitives };
                    if technique >= calibration_technique::FIRST_ADDED {
                        calibrated.elevations_added.push(record);
                    } else {
                        calibrated.elevations.push(record);
                    }
                }
            }
        }
    }
    // Rows over every view, then per elevation, each by technique, then height (spec §6.19); the
    // sort is stable and the heights ascend within a technique already.
    calibrated.flip.sort_by(|a, b| a.elevation.total_cmp(&b.elevation).then(a.technique.cmp(&b.technique)));
    calibrated
}

/// The LoD chain's pick at each of [`HEIGHTS`] by image error (spec §10.2): the full mesh or the
/// level [`Calibration::chain_level`] picks with the default target (allowed at each height as
/// [`target_at`] says, as the runtime allows it) from `tables` over every view (the techniques
/// measured here, the chain's levels, and with FLIP their FLIP errors), the floor over the
/// techniques `held`; `None` at a height where the tables hold no pick.
fn chain_picks(tables: Option<&Calibration>, held: &[u32]) -> Vec<Option<ChainPick>> {
    let Some(tables) = tables else {
        return vec![None; HEIGHTS.len()];
    };
    let usable = |t: Technique| u32::try_from(t.index()).is_ok_and(|code| held.contains(&code));
    HEIGHTS
        .iter()
        .map(|&height| tables.chain_level(height, target_at(Policy::DEFAULT_TARGET, height), usable))
        .collect()
}

/// The background of every image: white, as `treelod eval` draws it.
const BACKGROUND: Vec3 = Vec3::ONE;

/// The multi-scale RMSE of `image` against `reference` (linear colour).
fn error(image: &LinearImage, reference: &LinearImage) -> f64 {
    multiscale_rmse(image, reference).map_or(1.0, |m| m.summary())
}

/// A view's reference image as [`flip`] compares against it: encoded to 8-bit sRGB once per
/// view, for every technique drawn in it.
#[cfg(feature = "flip")]
struct FlipReference {
    width: u32,
    height: u32,
    /// Three bytes per pixel, rows top to bottom ([`LinearImage::to_srgb8`]).
    srgb8: Vec<u8>,
}

#[cfg(feature = "flip")]
impl FlipReference {
    fn new(reference: &LinearImage) -> Self {
        Self { width: reference.width, height: reference.height, srgb8: reference.to_srgb8() }
    }
}

/// The mean LDR-FLIP error of `image` against `reference`, both encoded to 8-bit sRGB (spec
/// §6.19; `treelod_eval::metrics::flip`, as `treelod eval` measures it); NaN without the `flip`
/// feature, or where the images do not compare.
#[cfg(feature = "flip")]
fn flip(image: &LinearImage, reference: &FlipReference) -> f64 {
    // As `mean_flip` does, with the reference encoded once per view: images of different sizes
    // do not compare.
    if (image.width, image.height) != (reference.width, reference.height) {
        return f64::NAN;
    }
    treelod_eval::metrics::flip::mean_flip_srgb8(image.width, image.height, &image.to_srgb8(), &reference.srgb8)
        .unwrap_or(f64::NAN)
}

/// Without the `flip` feature no reference is encoded for FLIP.
#[cfg(not(feature = "flip"))]
struct FlipReference;

#[cfg(not(feature = "flip"))]
impl FlipReference {
    fn new(_: &LinearImage) -> Self {
        Self
    }
}

/// Without the `flip` feature the calibration measures no FLIP error (NaN: no `CALIBRATION_FLIP`
/// rows).
#[cfg(not(feature = "flip"))]
fn flip(_: &LinearImage, _: &FlipReference) -> f64 {
    f64::NAN
}

impl<'a> Scene<'a> {
    fn new(data: &'a ContainerData) -> Self {
        // Planes and billboards sample their atlas with its stored mips (spec §6.10).
        let textured: Vec<u32> = data
            .planes
            .iter()
            .map(|p| p.image)
            .chain(data.billboards.iter().map(|b| b.image))
            .chain(data.octahedral.iter().map(|o| o.image))
            .collect();
        let atlases: Vec<Option<Atlas>> = data
            .images
            .iter()
            .enumerate()
            .map(|(i, record)| textured.contains(&(i as u32)).then(|| atlas(data, record)).flatten())
            .collect();
        // The renderer's texture array (`treelod-render`'s textures): every image but those only
        // planes sample (their atlases are textures of their own).
        let atlas_only = texels::atlas_only(data.images.len(), &data.materials, &data.planes);
        let by_image = texels::alpha_cutoffs(&data.materials, data.images.len());
        let mut layer_of = vec![None; data.images.len()];
        let (mut decoded, mut cutoffs) = (Vec::new(), Vec::new());
        for (i, record) in data.images.iter().enumerate().filter(|&(i, _)| !atlas_only[i]) {
            layer_of[i] = Some(decoded.len());
            decoded.push(record.bytes(&data.image_data).and_then(|bytes| image::decode(record, bytes).ok()));
            cutoffs.push(by_image[i]);
        }
        let images: Vec<Option<Texels<'_>>> = decoded
            .iter()
            .map(|image| image.as_ref().map(|i| Texels { width: i.width, height: i.height, rgba: &i.texels }))
            .collect();
        let layers = texels::Layers::new(&images, &cutoffs);
        let materials = data
            .materials
            .iter()
            .map(|m| {
                let layer = (m.image != NO_IMAGE).then(|| layer_of.get(m.image as usize).copied().flatten()).flatten();
                (Vec4::from_array(m.base_color), layer, texels::material_cutoff(m))
            })
            .collect();
        let vertices = data
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let ao = data.vertex_ao.get(i).map_or(0.0, |&a| decode_ao(a));
                (Vec3::from_array(oct_decode(v.normal)), linear_colour(v.color), ao)
            })
            .collect();
        let raster = |t: &TriangleRecord| tri(data, t, 1.0, None);
        let full: Tris = data.triangles.iter().map(raster).collect();
        let bark: Tris = data
            .triangles
            .iter()
            .filter(|t| data.materials.get(t.material as usize).is_none_or(|m| m.class != material_class::LEAF))
            .map(raster)
            .collect();
        let planes_drawable = !data.planes.is_empty()
            && data.planes.iter().all(|p| {
                data.images.get(p.image as usize).is_some_and(|i| i.format != image_format::LEAF_SLOTS)
                    && atlases.get(p.image as usize).is_some_and(Option::is_some)
            });
        let chain_bark =
            if data.planes.is_empty() && data.prune_leaves.is_empty() { Vec::new() } else { chain_bark_levels(data) };
        let chain_levels = LodChain::from_records(&data.lod_levels).map_or_else(Vec::new, |chain| {
            chain
                .levels()
                .iter()
                .map(|level| {
                    level
                        .ranges
                        .iter()
                        .flat_map(|range| data.lod_triangles.get(range.as_usize()).unwrap_or(&[]))
                        .map(raster)
                        .collect()
                })
                .collect()
        });
        let plane_parents = plane_parents(&data.planes, data.cells.iter().map(|c| c.planes));
        Self {
            data,
            atlases,
            layers,
            materials,
            vertices,
            full,
            bark,
            chain_bark,
            chain_levels,
            planes_drawable,
            plane_parents,
        }
    }

    /// Draws the bark of a pruned or impostor tree at `p` metres per pixel as the runtime's
    /// `ImpostorBark` does: with `lines` (`ImpostorBark::Lines`, the impostor trees' default) and
    /// a container with branch lines, the lines of `τ = p` ([`Self::draw_lines`]); else as
    /// `ImpostorBark::Chain` (pruned trees' default), the chain's coarsest bark level whose error
    /// is at most [`BARK_ERROR_SHARE`] of `τ = s_min · p`, else every bark triangle. Returns the
    /// primitives submitted.
    fn draw_bark(&self, view: &View, p: f32, lines: bool, canvas: &mut Canvas) -> u64 {
        if lines && !self.data.lines.is_empty() {
            return self.draw_lines(view, p, canvas);
        }
        let tau = LodSettings::default().s_min * p;
        let usable = self.chain_bark.partition_point(|(error, _)| *error <= tau * BARK_ERROR_SHARE);
        let triangles = match usable.checked_sub(1) {
            Some(level) => &self.chain_bark[level].1,
            None => &self.bark,
        };
        self.draw_triangles(canvas, view, triangles, false);
        triangles.len() as u64
    }

    /// Draws `triangles` shaded as `fs_triangle` draws them without MSAA: albedo the material's
    /// colour times the vertex colour times the trilinear sample of its layer ([`texels::sample`]
    /// at the level of detail of the triangle's texel footprint), alpha-tested against the
    /// material's cutoff — so leaves thinner than a pixel thin out or keep their density far away
    /// as they do on the GPU. For the supersampled `reference`, the test is `eval`'s reference's
    /// (its renderer settings' stochastic alpha): a minified fragment is kept where its filtered
    /// coverage exceeds a hash of its pixel and depth, so on average the leaves cover what their
    /// texels cover.
    fn draw_triangles(&self, canvas: &mut Canvas, view: &View, triangles: &Tris, reference: bool) {
        let (mut padded, mut chunk) = ([[0.0; CHUNK]; 9], ProjectedChunk::default());
        for start in (0..triangles.len()).step_by(CHUNK) {
            view.project_chunk(canvas.size(), triangles.chunk(start, &mut padded), &mut chunk);
            for (j, t) in triangles.made_of[start..].iter().take(CHUNK).enumerate() {
                if chunk.may_hold[j] {
                    self.draw_triangle(canvas, view, chunk.corners(j), triangles.positions(start + j), t, reference);
                }
            }
        }
    }

    /// [`Self::draw_triangles`]'s triangle of pixel corners `p`, model-space corners `positions`.
    fn draw_triangle(
        &self,
        canvas: &mut Canvas,
        view: &View,
        p: [Vec2; 3],
        positions: [Vec3; 3],
        t: &MadeOf,
        reference: bool,
    ) {
        let size = self.layers.size;
        #[expect(clippy::cast_precision_loss, reason = "a texture side")]
        let side = Vec2::splat(size as f32);
        // The corners' depths and the material, found at the first pixel centre the
        // triangle holds: most triangles of a large tree in a small view hold none.
        let mut found = None;
        // Texels per pixel (constant over an orthographic triangle), the level of detail and
        // the corners, found at the first pixel that passes the depth test.
        let mut shading = None;
        triangle_pixels(canvas.size(), p, |x, y, b| {
            let &mut (depths, (base, layer, cutoff)) = found.get_or_insert_with(|| {
                let material = self.materials.get(t.material as usize).copied().unwrap_or((Vec4::ONE, None, None));
                (positions.map(|q| depth(view, q)), material)
            });
            let z = depths[0] * b[0] + depths[1] * b[1] + depths[2] * b[2];
            if !canvas.nearer(x, y, z) {
                return;
            }
            let uvs = t.uvs;
            let levels = layer.and_then(|l| self.layers.levels.get(l));
            let &mut (footprint, lod, corners) = shading.get_or_insert_with(|| {
                let footprint = texel_footprint(p, uvs, side);
                let corners =
                    t.indices.map(|i| self.vertices.get(i as usize).copied().unwrap_or((Vec3::Y, Vec4::ONE, 0.0)));
                (footprint, footprint.max(1e-6).log2(), corners)
            });
            let uv = uvs[0] * b[0] + uvs[1] * b[1] + uvs[2] * b[2];
            let colour = corners[0].1 * b[0] + corners[1].1 * b[1] + corners[2].1 * b[2];
            if let Some(cutoff) = cutoff {
                let texel = levels
                    .map_or(1.0, |l| texels::sample_alpha(l, (size, size), uv.to_array(), lod, Sampler::MATERIALS));
                let alpha = base.w * colour.w * texel;
                let kept = if reference {
                    filtered_coverage(alpha, cutoff, footprint) > pixel_depth_hash(x, y, z)
                } else {
                    alpha >= cutoff
                };
                if !kept {
                    return;
                }
            }
            let texel = levels.map_or(Vec4::ONE, |levels| {
                Vec4::from_array(texels::sample(levels, (size, size), uv.to_array(), lod, Sampler::MATERIALS))
            });
            let albedo = base * colour * texel;
            let surface = Surface {
                albedo: albedo.truncate(),
                normal: corners[0].0 * b[0] + corners[1].0 * b[1] + corners[2].0 * b[2],
                ao: corners[0].2 * b[0] + corners[1].2 * b[1] + corners[2].2 * b[2],
            };
            canvas.put(x, y, z, surface.shaded());
        });
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
            (t::OCTAHEDRAL, !d.octahedral.is_empty()),
        ]
        .into_iter()
        .filter_map(|(code, held)| held.then_some(code))
        .collect()
    }

    /// The reference of `view` (`k` samples per pixel side): every triangle shaded at full
    /// texture resolution, box-filtered to the pixel's mean colour.
    fn reference(&self, view: &View, k: u32) -> LinearImage {
        let mut fine = Canvas::new(view.size, BACKGROUND);
        self.draw_triangles(&mut fine, view, &self.full, true);
        let fine = fine.image();
        // The view is `k` times the image's side, so the filter cannot fail.
        fine.box_filter(k).unwrap_or(fine)
    }

    /// Draws `technique` as seen in `view` at `p` metres per pixel (`pixels` the block's height on
    /// screen) into `canvas`; returns the primitives drawn.
    fn draw(&self, technique: u32, view: &View, p: f32, pixels: f32, seed: u64, canvas: &mut Canvas) -> u64 {
        use calibration_technique as t;
        let d = self.data;
        let lod = LodSettings::default();
        match technique {
            t::FULL => {
                self.draw_triangles(canvas, view, &self.full, false);
                self.full.len() as u64
            }
            t::SPT => self.draw_spt(
                view,
                Thresholds { points: lod.s_min * p, triangles: lod.s_max.max(lod.s_min) * p },
                seed,
                canvas,
            ),
            t::PRUNE_OPT | t::PRUNE_COOK => {
                let mode = if technique == t::PRUNE_OPT { PruneScale::Optimal } else { PruneScale::Cook };
                let lambda = curve_at(&d.prune_lambda, pixels).unwrap_or(1.0).clamp(0.0, 1.0);
                let grow = size_factor(leaf_scale(mode, &d.prune_scale, lambda));
                let mut drawn = self.draw_bark(view, p, false, canvas);
                let mut leaves = Tris::default();
                for cell in &d.cells {
                    let list = d.prune_leaves.get(cell.prune_leaves.as_usize()).unwrap_or(&[]);
                    let n = prune_leaves_drawn(u32::try_from(list.len()).unwrap_or(u32::MAX), lambda) as usize;
                    for leaf in &list[..n.min(list.len())] {
                        let first = leaf.first_triangle as usize;
                        let tris = d.prune_triangles.get(first..first + leaf.triangle_count as usize).unwrap_or(&[]);
                        let centre = Vec3::from_array(leaf.center);
                        leaves.extend(tris.iter().map(|t| tri(d, t, grow, Some(centre))));
                    }
                }
                self.draw_triangles(canvas, view, &leaves, false);
                drawn += leaves.len() as u64;
                drawn
            }
            t::IMPOSTORS => {
                let tau = lod.s_min * p;
                let mut drawn = self.draw_bark(view, p, true, canvas);
                // The prefix `hi > τ` is submitted (the planes fading in below their `lo` are in
                // it); the vertex shader drops the others. As the renderer draws them by default,
                // a plane morphs towards its parent over the last octave of its interval and
                // cross-fades with it over the last quarter (`vs_plane`).
                drawn += d.planes.iter().filter(|pl| tau < pl.hi).count() as u64;
                for (i, plane) in d.planes.iter().enumerate() {
                    let parent =
                        self.plane_parents.get(i).filter(|&&j| j != NO_PARENT).and_then(|&j| d.planes.get(j as usize));
                    let Some(keep) = crossfade(plane, parent.is_some(), tau) else { continue };
                    let (u, v) = (Vec3::from_array(plane.axis_u), Vec3::from_array(plane.axis_v));
                    let ao = d.plane_ao.get(i).map_or(0.0, |&a| decode_ao(a));
                    let mut quad =
                        Quad::flat(Vec3::from_array(plane.center), (u, v), plane.image, (plane.uv_min, plane.uv_max));
                    quad.diffuse = d.plane_diffuse.get(i).copied().unwrap_or(PlaneDiffuseRecord::FLAT);
                    if let Some(parent) = parent {
                        quad.corners = quad.corners.map(|corner| morph_corner(corner, parent, morph_share(plane, tau)));
                    }
                    self.quad(canvas, view, &quad, ao, keep);
                }
                drawn
            }
            t::ELLIPSOIDS => self.draw_ellipsoids(view, p, canvas),
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
                    self.draw_triangles(canvas, view, &self.full, false);
                    return self.full.len() as u64;
                }
                let tris: Tris = chosen
                    .iter()
                    .flatten()
                    .flat_map(|l| d.lod_triangles.get(l.triangles.as_usize()).unwrap_or(&[]))
                    .map(|t| tri(d, t, 1.0, None))
                    .collect();
                self.draw_triangles(canvas, view, &tris, false);
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
                    let quad = Quad::flat(Vec3::from_array(b.center), (u, v), b.image, (b.uv_min, b.uv_max));
                    // Billboards carry no ambient occlusion (their atlas bakes the tree's shading).
                    self.quad(canvas, view, &quad, 0.0, EVERY_PIXEL);
                    drawn += 1;
                }
                drawn
            }
            t::OCTAHEDRAL => {
                // The views' depth planes where the container has them all (spec §6.13.2).
                let starts = octahedral_depth_starts(&d.octahedral, d.octahedral_depth.len());
                for (k, record) in d.octahedral.iter().enumerate() {
                    let planes = starts
                        .as_ref()
                        .and_then(|s| d.octahedral_depth.get(s[k]..s[k] + (record.frames as usize).pow(2)));
                    self.octahedral(canvas, view, record, planes, d.octahedral_normal_grid(k).as_ref());
                }
                d.octahedral.len() as u64
            }
            _ => 0,
        }
    }

    /// `quad` textured by its atlas rectangle as `quad_texel` in `shaders/tree/planes.wgsl`
    /// samples it (bilinear in the stored mip level nearest to its footprint, or [`Quad::finer`]
    /// levels finer, alpha tested at one half: the atlas's mips keep the covered fraction), lit as `vs_plane` lights it (the quad's
    /// normal and the diffuse response of its leaves) with ambient occlusion `ao`, on the pixels whose [`level_dither`] value lies in `keep` (`from ≤ h <
    /// to`, the cross-fade of `vs_plane`; [`EVERY_PIXEL`] for all).
    fn quad(&self, canvas: &mut Canvas, view: &View, quad: &Quad, ao: f32, keep: (f32, f32)) {
        let Some(atlas) = self.atlases.get(quad.image as usize).and_then(Option::as_ref) else { return };
        let corner = |q: Vec3, uv: Vec2| (view.project(q), uv, depth(view, q));
        let diffuse = Light::DEFAULT.plane_diffuse(quad.normal, view.direction, quad.diffuse);
        #[expect(clippy::cast_precision_loss, reason = "texture sides")]
        let texels = Vec2::new(atlas.size.0 as f32, atlas.size.1 as f32);
        let [a, b, c, e] = [0, 1, 2, 3].map(|i| corner(quad.corners[i], quad.uvs[i]));
        for [a, b, c] in [[a, b, c], [a, c, e]] {
            let (p, uvs, depths) = ([a.0, b.0, c.0], [a.1, b.1, c.1], [a.2, b.2, c.2]);
            let lod = texel_footprint(p, uvs, texels).max(1e-6).log2() - quad.finer;
            triangle_pixels(canvas.size(), p, |x, y, w| {
                let z = depths[0] * w[0] + depths[1] * w[1] + depths[2] * w[2];
                if !canvas.nearer(x, y, z) || !kept(keep, x, y) {
                    return;
                }
                let uv = uvs[0] * w[0] + uvs[1] * w[1] + uvs[2] * w[2];
                if quad.window.is_some_and(|(lo, hi)| uv.cmplt(lo).any() || uv.cmpgt(hi).any()) {
                    return;
                }
                let [r, g, b, alpha] = texels::sample(&atlas.levels, atlas.size, uv.to_array(), lod, atlas.sampler);
                if alpha >= 0.5 {
                    let (diffuse, ao) = match quad.normals {
                        Some(grid) => {
                            let (at, lod) = (grid.uv(uv).to_array(), grid.lod(lod));
                            let [nr, ng, nb, occlusion] =
                                texels::sample(&atlas.levels, atlas.size, at, lod, atlas.sampler);
                            let n = OctahedralNormalRecord::decode([nr, ng, nb]);
                            (Light::DEFAULT.octahedral_texel_diffuse(n, diffuse), occlusion)
                        }
                        None => (diffuse, ao),
                    };
                    canvas.put(x, y, z, Light::DEFAULT.shade_diffuse(Vec3::new(r, g, b), diffuse, ao));
                }
            });
        }
    }

    /// An octahedral impostor as `vs_octahedral` and `fs_octahedral` in
    /// `shaders/tree/octahedral.wgsl` draw it (spec §6.13.1, §6.13.2): a square about its
    /// centre facing the viewer, in the basis of the view direction (below the horizon, the
    /// horizon's), reaching as far as the views' squares on their depth planes (`planes`, the
    /// record's `frames²`; each view's plane across it through the centre without them) show,
    /// each pixel textured by one of the three views of the grid triangle around the direction,
    /// the `k`-th where the pixel's [`level_dither`] value lies past the weights of the views
    /// before it, at the place where the pixel's ray meets that view's plane (empty past its
    /// square); lit with the view as its normal by the record's diffuse mixture and its
    /// occlusion, or where it has `normals` (spec §6.13.3) per pixel by the chosen view's normal
    /// texel. The view is orthographic: every ray runs along its direction.
    fn octahedral(
        &self,
        canvas: &mut Canvas,
        view: &View,
        record: &OctahedralRecord,
        planes: Option<&[OctahedralDepthRecord]>,
        normals: Option<&OctahedralNormalGridRecord>,
    ) {
        let frames = record.frames.max(2);
        let d = Vec3::new(view.direction.x, view.direction.y.max(0.0), view.direction.z);
        let d = if d.length_squared() > 1e-20 { d.normalize() } else { Vec3::Z };
        let basis = |d: Vec3| {
            let (right, up) = OctahedralRecord::view_basis(d.to_array());
            (Vec3::from_array(right), Vec3::from_array(up))
        };
        let (right, up) = basis(d);
        let (centre, radius) = (Vec3::from_array(record.center), record.radius);
        let ray = view.direction;
        let blend = OctahedralRecord::blend(frames, d.to_array());
        // Each view's basis (right, up, direction) and depth plane (offset, slopes).
        let views = blend.map(|(i, j, _)| {
            let dk = Vec3::from_array(OctahedralRecord::view_direction(frames, i, j));
            let (rk, uk) = basis(dk);
            let plane = planes.and_then(|p| p.get((j * frames + i) as usize)).copied().unwrap_or_default();
            ((rk, uk, dk), plane)
        });
        // How far the quad reaches: the views' squares on their planes, moved along the rays
        // onto the quad's plane (through the centre, across `d`), at least the radius, at most
        // 4 radii, as `vs_octahedral` finds it.
        let mut reach = 1.0f32;
        for ((rk, uk, dk), plane) in views {
            for (s, t) in QUAD_CORNERS {
                let p = radius * (s * rk + t * uk + plane.depth(s, t) * dk);
                let along = ray.dot(d);
                let on = if along.abs() > 1e-6 { p - ray * (p.dot(d) / along) } else { p };
                reach = reach.max(on.dot(right).abs().max(on.dot(up).abs()) / radius);
            }
        }
        let offsets = QUAD_CORNERS.map(|(s, t)| reach.min(4.0) * radius * (s * right + t * up));
        let (lo, hi) =
            (Vec2::from_array(unpack_unorm16x2(record.uv_min)), Vec2::from_array(unpack_unorm16x2(record.uv_max)));
        #[expect(clippy::cast_precision_loss, reason = "at most 64 frames")]
        let cell = (hi - lo) / frames as f32;
        let normals = normals.map(|n| NormalGrid::new(record, n));
        let mut from = 0.0;
        for (k, ((i, j, weight), ((rk, uk, dk), plane))) in blend.into_iter().zip(views).enumerate() {
            // The last view takes every pixel past the first two (the dither is below 1).
            let to = if k == 2 { EVERY_PIXEL.1 } else { from + weight };
            if weight > 0.0 {
                #[expect(clippy::cast_precision_loss, reason = "at most 64 frames")]
                let origin = lo + Vec2::new(i as f32, j as f32) * cell;
                // Where the ray through a corner meets the view's plane `n·p = offset·radius`.
                let n = Vec3::from_array(plane.normal(rk.to_array(), uk.to_array(), dk.to_array()));
                let on_plane = |o: Vec3| {
                    let across = n.dot(ray);
                    if across.abs() > 1e-6 { o + ray * ((plane.offset * radius - n.dot(o)) / across) } else { o }
                };
                let uvs = offsets.map(|o| {
                    let p = on_plane(o);
                    origin + 0.5 * (Vec2::new(p.dot(rk), p.dot(uk)) / radius + Vec2::ONE) * cell
                });
                let quad = Quad {
                    corners: offsets.map(|o| centre + o),
                    normal: view.direction,
                    diffuse: record.diffuse,
                    image: record.image,
                    uvs,
                    window: Some((origin, origin + cell)),
                    finer: 1.0,
                    normals,
                };
                self.quad(canvas, view, &quad, record.occlusion, (from, to));
            }
            from = to;
        }
    }

    /// Gilet's cut at `thresholds`: the triangles above `τ_t`, the points of `τ_p`, the
    /// sub-pixel splats kept by a hash of the point and `seed` ([`splat_seeds_at`]; 0: of the
    /// point alone).
    fn draw_spt(&self, view: &View, thresholds: Thresholds, seed: u64, canvas: &mut Canvas) -> u64 {
        let d = self.data;
        let mut tris = Tris::default();
        let mut drawn = 0u64;
        for cell in &d.cells {
            for t in d.triangles.get(cell.triangles.as_usize()).unwrap_or(&[]) {
                if !triangle_drawn(t, thresholds) {
                    break;
                }
                tris.push(tri(d, t, 1.0, None));
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
                let normal = Vec3::from_array(oct_decode(point.normal));
                let surface = Surface {
                    albedo: linear_colour(point.color).truncate(),
                    normal,
                    ao: d.point_ao.get(first + i).map_or(0.0, |&a| decode_ao(a)),
                };
                // The disc's area scaled by its facing along the view (spec §6.5.1).
                let facing =
                    d.point_facing.get(first + i).map_or(1.0, |&f| point_facing_scale(f, normal.dot(view.direction)));
                let radius = point.radius * facing.sqrt();
                let id = (first + i) as u64 ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15);
                disc(canvas, view, Vec3::from_array(point.position), radius, id, surface);
            }
        }
        self.draw_triangles(canvas, view, &tris, false);
        drawn + tris.len() as u64
    }

    /// The ellipsoids of `τ = p` with the renderer's noise holes, and the lines of `τ` (or every
    /// bark triangle where the container has no lines, as the renderer draws them).
    fn draw_ellipsoids(&self, view: &View, p: f32, canvas: &mut Canvas) -> u64 {
        let d = self.data;
        let mut drawn = 0u64;
        let top = NOISE_SIZE.ilog2() as f32;
        // Each cell's prefix `hi > τ·2^(−β/2)` is submitted (the level fading out included); the
        // vertex shader drops the coarser levels.
        drawn += d.ellipsoids.iter().filter(|e| e.hi > p * (-0.5 * DEFAULT_LEVEL_BLEND).exp2()).count() as u64;
        for (i, e) in d.ellipsoids.iter().enumerate() {
            let Some(keep) = level_keep(e.lo, e.hi, p, DEFAULT_LEVEL_BLEND) else { continue };
            let q = Quat::from_array(e.orientation.map(|c| f32::from(c) / 32767.0)).normalize();
            let axes = [Vec3::X, Vec3::Y, Vec3::Z].map(|a| q * a);
            let axes = [axes[0] * e.radii[0], axes[1] * e.radii[1], axes[2] * e.radii[2]];
            // The renderer's mip: the cluster's noise level, or coarser where the noise texels
            // would be finer than the pixels (its footprint at the ellipsoid's middle).
            let radius_px = (e.radii.iter().sum::<f32>() / 3.0 * view.scale).max(1e-6);
            let footprint = (NOISE_TEXELS_PER_RADIAN / radius_px).log2();
            let level = (top - e.noise_mip).max(footprint).clamp(0.0, top);
            let level = ((level + 0.5).ceil() - 1.0).clamp(0.0, top) as u32;
            let cut = noise_cut(e.alpha_threshold);
            let albedo = linear_colour(e.color).truncate();
            let ao = d.ellipsoid_ao.get(i).map_or(0.0, |&a| decode_ao(a));
            let centre = Vec3::from_array(e.center);
            // The normal at local `u` is `A⁻ᵀ u` = Σ u_i · axes[i] / r_i².
            let inverse = axes.map(|a| {
                let r2 = a.length_squared();
                if r2 > 0.0 { a / r2 } else { Vec3::ZERO }
            });
            ellipsoid_hits(view, centre, axes, level, |x, y, grey, u, random| {
                if grey < cut || !kept(keep, x, y) {
                    return;
                }
                let hit = centre + axes[0] * u.x + axes[1] * u.y + axes[2] * u.z;
                // `fs_ellipsoid`: the normal turned half-way towards the texel's random vector
                // (on the normal's side), in the local frame.
                let random = if random.dot(u) >= 0.0 { random } else { -random };
                let local = u
                    .normalize_or(Vec3::Z)
                    .lerp((random + Vec3::splat(1e-6)).normalize_or(Vec3::Z), ELLIPSOID_NORMAL_NOISE);
                let local = local.normalize_or(Vec3::Z);
                let normal = inverse[0] * local.x + inverse[1] * local.y + inverse[2] * local.z;
                canvas.put(x, y, depth(view, hit), Surface { albedo, normal, ao }.shaded());
            });
        }
        if d.lines.is_empty() {
            self.draw_triangles(canvas, view, &self.bark, false);
            return drawn + self.bark.len() as u64;
        }
        drawn + self.draw_lines(view, p, canvas)
    }

    /// The branch lines of `τ = p` as the runtime draws them with its default level blend
    /// ([`DEFAULT_LEVEL_BLEND`], `LineLod::select_per_pixel_blended`): each cell's prefix
    /// `hi > τ·2^(−β/2)` submitted, those [`level_keep`] keeps drawn as capsules of their radii
    /// on their share of the pixels; from the switch `τ_s` on, the far lines' instead (spec
    /// §6.9.1), their prefix submitted without its head of records that start above
    /// `τ·2^(β/2)`. Returns the primitives submitted.
    fn draw_lines(&self, view: &View, p: f32, canvas: &mut Canvas) -> u64 {
        let d = self.data;
        let far = p >= treelod_format::far_switch(&d.far_lines);
        let (lines, ao) = if far { (&d.far_lines, &d.far_line_ao) } else { (&d.lines, &d.line_ao) };
        let (shrink, reach) = ((-0.5 * DEFAULT_LEVEL_BLEND).exp2(), (0.5 * DEFAULT_LEVEL_BLEND).exp2());
        let mut drawn = lines.iter().filter(|l| l.hi > p * shrink).count() as u64;
        if far {
            // The leading records whose least `lo` so far starts above `τ·2^(β/2)`.
            let mut least = f32::INFINITY;
            let head = lines
                .iter()
                .take_while(|l| {
                    least = least.min(l.lo);
                    least > p * reach
                })
                .count();
            drawn = drawn.saturating_sub(head as u64);
        }
        for (i, line) in lines.iter().enumerate() {
            let Some(keep) = level_keep(line.lo, line.hi, p, DEFAULT_LEVEL_BLEND) else { continue };
            let albedo = linear_colour(line.color).truncate();
            let ao = ao.get(i).map_or(0.0, |&a| decode_ao(a));
            capsule(
                canvas,
                view,
                (Vec3::from_array(line.p0), line.r0),
                (Vec3::from_array(line.p1), line.r1),
                (albedo, ao),
                keep,
            );
        }
        drawn
    }
}

/// A point's disc of `radius` metres at `centre`, facing the viewer, shaded as `surface` at the
/// depth of its centre. A disc under half a pixel in radius is the renderer's one-pixel splat
/// (spec §10.1, `splat_mask` in `shaders/tree/points.wgsl`): its pixel is drawn, for the share
/// [`SPLAT_DISC_SHARE`] of the points that a hash picks, when the disc holds the pixel's centre,
/// and for the others when a hash of the point falls below the disc's coverage `π·r²`.
fn disc(canvas: &mut Canvas, view: &View, centre: Vec3, radius: f32, id: u64, surface: Surface) {
    let c = view.project(centre);
    let r = radius * view.scale;
    let (z, colour) = (depth(view, centre), surface.shaded());
    if r >= 0.5 {
        let r2 = f64::from(r * r);
        ellipse_spans(canvas.size(), c, [r2, 0.0, r2], |y, x0, x1| {
            for x in x0..=x1 {
                canvas.put(x, y, z, colour);
            }
        });
        return;
    }
    if c.x >= 0.0 && c.y >= 0.0 && splat_kept(c, r, id) {
        let (x, y) = (c.x as usize, c.y as usize);
        if x < canvas.size() as usize && y < canvas.size() as usize {
            canvas.put(x, y, z, colour);
        }
    }
}

/// The share of sub-pixel splats drawn as their disc covers their pixel's centre, the others kept
/// whole by a hash (`SPLAT_DISC_SHARE` in `shaders/tree/points.wgsl`, spec §10.1).
pub const SPLAT_DISC_SHARE: f32 = 0.5;

/// Whether the one-pixel splat of a disc of radius `r < 1/2` pixels centred at `c` (pixels) covers
/// the pixel holding `c` (the only one whose centre it can hold): for the share
/// [`SPLAT_DISC_SHARE`] of the ids that a hash picks, when the disc holds the pixel's centre;
/// for the others, when a hash of `id` falls below its coverage `π·r²`. Either way the expected
/// coverage over the point's place in its pixel is `π·r²`.
fn splat_kept(c: Vec2, r: f32, id: u64) -> bool {
    let mut hashes = crate::rng::SplitMix64(id);
    let unit = |h: u64| ((h >> 40) as f32) / ((1u64 << 24) as f32);
    let keep = unit(hashes.next_u64());
    if unit(hashes.next_u64()) < SPLAT_DISC_SHARE {
        let offset = c - (c.floor() + Vec2::splat(0.5));
        offset.length_squared() < r * r
    } else {
        keep < std::f32::consts::PI * r * r
    }
}

/// A branch line from `p0` (radius `r0`) to `p1` (radius `r1`), metres, as a capsule of its
/// projection (a quad along the axis and a disc at each end, the pixels the coverage rasteriser
/// covers), shaded with the normal and depth of the cone's front surface at each pixel: the
/// nearest point of the axis in the image, offset across it and towards the viewer, of `albedo`
/// and ambient occlusion `ao`. Only on the pixels whose [`level_dither`] value lies in `keep`.
fn capsule(
    canvas: &mut Canvas,
    view: &View,
    (p0, r0): (Vec3, f32),
    (p1, r1): (Vec3, f32),
    (albedo, ao): (Vec3, f32),
    keep: (f32, f32),
) {
    let (a, b) = (view.project(p0), view.project(p1));
    let (ra, rb) = (r0 * view.scale, r1 * view.scale);
    let axis = b - a;
    let length2 = axis.length_squared();
    let size = canvas.size();
    let mut shade = |x: usize, y: usize| {
        if !kept(keep, x, y) {
            return;
        }
        let pixel = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
        let s = if length2 > 0.0 { ((pixel - a).dot(axis) / length2).clamp(0.0, 1.0) } else { 0.0 };
        let (on_axis, r) = (a + axis * s, (ra + (rb - ra) * s).max(1e-6));
        let off = pixel - on_axis;
        let d = off.length().min(r);
        let h = (r * r - d * d).max(0.0).sqrt();
        let across = (view.right * off.x - view.up * off.y).normalize_or_zero();
        let normal = across * (d / r) + view.direction * (h / r);
        let z = depth(view, p0.lerp(p1, s)) - h / view.scale;
        canvas.put(x, y, z, Surface { albedo, normal, ao }.shaded());
    };
    let across = axis.perp().normalize_or_zero();
    let corners = [a + across * ra, a - across * ra, b - across * rb, b + across * rb];
    for triangle in [[corners[0], corners[1], corners[2]], [corners[0], corners[2], corners[3]]] {
        triangle_pixels(size, triangle, |x, y, _| shade(x, y));
    }
    for (c, r) in [(a, ra), (b, rb)] {
        ellipse_spans(size, c, [f64::from(r * r), 0.0, f64::from(r * r)], |y, x0, x1| {
            for x in x0..=x1 {
                shade(x, y);
            }
        });
    }
}

/// The chain's bark levels as the runtime builds them (`Representations::from_container`): the
/// levels of [`LodChain::from_records`], each with its error and the non-leaf triangles of its
/// trees' ranges, up to the first whose bark keeps less than [`BARK_AREA_KEPT`] of the full
/// bark's area ([`area`]).
fn chain_bark_levels(data: &ContainerData) -> Vec<(f32, Tris)> {
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
        levels.push((level.error, bark.iter().map(|t| tri(data, t, 1.0, None)).collect()));
    }
    levels
}

/// A triangle record to draw, its corners moved to `c + sqrt(s)·(p − c)` when `centre` is given
/// (a pruned leaf grown by `s`, spec §6.11; `grow` is `sqrt(s)`).
fn tri(data: &ContainerData, t: &TriangleRecord, grow: f32, centre: Option<Vec3>) -> Tri {
    let vertex = |i: u32| data.vertices.get(i as usize).copied().unwrap_or_default();
    let corners = t.indices.map(vertex);
    let position = |p: [f32; 3]| {
        let p = Vec3::from_array(p);
        centre.map_or(p, |c| c + (p - c) * grow)
    };
    Tri {
        positions: corners.map(|v| position(v.position)),
        made_of: MadeOf { uvs: corners.map(|v| Vec2::from_array(v.uv)), indices: t.indices, material: t.material },
    }
}

/// Texels per pixel of a triangle of pixel corners `p` and texture coordinates `uv` on a texture
/// of `texels` (across, down): along the screen axis that stretches them most, as
/// `texel_footprint` in `shaders/tree/triangles.wgsl` (0 for a degenerate triangle).
fn texel_footprint(p: [Vec2; 3], uv: [Vec2; 3], texels: Vec2) -> f32 {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (u1, u2) = ((uv[1] - uv[0]) * texels, (uv[2] - uv[0]) * texels);
    let det = e1.perp_dot(e2);
    if det.abs() < 1e-12 {
        return 0.0;
    }
    let along_x = (u1 * e2.y - u2 * e1.y) / det;
    let along_y = (u2 * e1.x - u1 * e2.x) / det;
    along_x.length().max(along_y.length())
}

/// `filtered_coverage` of `shaders/tree/common.wgsl`: the share of the pixel an alpha-tested
/// fragment of `alpha` stands for at `footprint` texels per pixel — the test against `cutoff`
/// where magnified, the filtered alpha (the covered fraction) from a texel per pixel on, blended
/// over the octave between.
fn filtered_coverage(alpha: f32, cutoff: f32, footprint: f32) -> f32 {
    let minified = footprint.max(1e-6).log2().clamp(0.0, 1.0);
    let tested = if alpha >= cutoff { 1.0 } else { 0.0 };
    tested + (alpha - tested) * minified
}

/// A value in `[0, 1)` per pixel and depth (the stochastic test's threshold, as
/// `layered_dither` in `shaders/tree/common.wgsl`): surfaces at different depths over one pixel
/// get independent values, so overlapping leaves add up.
fn pixel_depth_hash(x: usize, y: usize, depth: f32) -> f32 {
    let key = (x as u64) << 40 ^ (y as u64) << 16 ^ u64::from(depth.to_bits()).rotate_left(24);
    ((crate::rng::SplitMix64(key).next_u64() >> 40) as f32) / ((1u64 << 24) as f32)
}

/// A value in `[0, 1)` per pixel, the same for every surface over it: the dither of the level
/// blend and of the planes' cross-fade (`level_dither` and `dither` in
/// `shaders/tree/common.wgsl`), so the ranges two levels keep at a switch split the pixels
/// between them. Seeded apart from [`pixel_depth_hash`].
fn level_dither(x: usize, y: usize) -> f32 {
    let key = (x as u64) << 40 ^ (y as u64) << 16 ^ 0x5eed_0f1e_7e15;
    ((crate::rng::SplitMix64(key).next_u64() >> 40) as f32) / ((1u64 << 24) as f32)
}

/// The dither range of a surface drawn on every pixel.
const EVERY_PIXEL: (f32, f32) = (0.0, 2.0);

/// Whether the pixel `(x, y)` is among those the dither range `keep` draws (`from ≤ h < to`).
fn kept(keep: (f32, f32), x: usize, y: usize) -> bool {
    keep == EVERY_PIXEL || (keep.0..keep.1).contains(&level_dither(x, y))
}

/// An atlas image with its stored levels as the renderer samples it without BC textures
/// ([`image::decode_mips`]); `None` for leaf slots and images that do not decode.
fn atlas(data: &ContainerData, record: &ImageRecord) -> Option<Atlas> {
    if record.format == image_format::LEAF_SLOTS {
        return None;
    }
    let mips = image::decode_mips(record, record.bytes(&data.image_data)?).ok()?;
    let sampler = Sampler { srgb: image_format::is_srgb(record.format), ..Sampler::ATLASES };
    Some(Atlas { levels: mips.levels, size: (mips.width, mips.height), sampler })
}

/// A colour as records store it (RGBA8, RGB sRGB-encoded) in linear light, as `decode_color`
/// in the shaders reads it.
fn linear_colour(packed: u32) -> Vec4 {
    let [r, g, b, a] = unpack_rgba8(packed);
    Vec4::new(texels::srgb_to_linear(r), texels::srgb_to_linear(g), texels::srgb_to_linear(b), a)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The share of 40,000 ids whose splat of radius `r` at `c` covers its pixel.
    fn share_kept(c: Vec2, r: f32) -> f64 {
        let n = 40_000u64;
        (0..n).filter(|&id| splat_kept(c, r, id.wrapping_mul(0x9e37_79b9_7f4a_7c15))).count() as f64 / n as f64
    }

    #[test]
    fn a_view_is_the_spheres_width_up_to_four_heights() {
        for pixels in [8.0, 11.3, 64.0, 256.0, 362.0] {
            let metres_per_pixel = 10.0 / pixels; // a 10-metre block
            // Spheres 1.32 and 2.23 heights across (the shared pine's and orchid's): their width.
            for across in [1.32f32, 2.23] {
                let side = view_side(0.5 * across * 10.0, metres_per_pixel, pixels);
                assert_eq!(side, ((across * pixels).ceil() as u32).max(4), "{across} heights at {pixels} px");
            }
            // A stray vertex 100 m away: cut to four heights.
            assert_eq!(view_side(100.0, metres_per_pixel, pixels), ((4.0 * pixels).ceil() as u32).max(4));
            assert!(view_side(f32::INFINITY, metres_per_pixel, pixels) <= (4.0 * pixels).ceil() as u32 + 4);
        }
        assert_eq!(view_side(0.0, 1.0, 8.0), 4, "at least 4 pixels");
    }

    #[test]
    fn the_splats_disc_share_is_the_renderers() {
        let shader = include_str!("../../../shaders/tree/points.wgsl");
        let line = format!("const SPLAT_DISC_SHARE: f32 = {SPLAT_DISC_SHARE:?};");
        assert!(shader.contains(&line), "shaders/tree/points.wgsl declares {line}");
    }

    #[test]
    fn half_the_sub_pixel_splats_cover_their_pixel_as_their_disc_and_all_keep_their_coverage() {
        let r = 0.3f32;
        let coverage = f64::from(std::f32::consts::PI * r * r);
        let disc = f64::from(SPLAT_DISC_SHARE);
        // At the pixel's centre every disc holds it; the hashed ones are kept by their coverage.
        let centre = share_kept(Vec2::new(5.5, 7.5), r);
        assert!((centre - (disc + (1.0 - disc) * coverage)).abs() < 0.01, "at the centre: {centre}");
        // Near a corner no disc holds the centre: only the hashed ones are drawn.
        let corner = share_kept(Vec2::new(5.95, 7.05), r);
        assert!((corner - (1.0 - disc) * coverage).abs() < 0.01, "near a corner: {corner}");
        // Over the places in the pixel, the expected coverage is the disc's.
        let steps = 16;
        let mean = (0..steps * steps)
            .map(|i| {
                let offset = (Vec2::new((i % steps) as f32, (i / steps) as f32) + 0.5) / steps as f32;
                share_kept(Vec2::new(3.0, 9.0) + offset, r)
            })
            .sum::<f64>()
            / f64::from(steps * steps);
        assert!((mean - coverage).abs() < 0.01, "mean {mean} against {coverage}");
    }
}
