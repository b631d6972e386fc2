//! The policy: per tree and frame, the cheapest representation whose image error at the tree's
//! projected size stays within a target of the best the tables know there — chosen from the calibration
//! tables the build measured on each model (spec §6.15, §10.2), so nothing is tuned per model.
//!
//! **The rule** (spec §10.2). A tree `h` pixels high on screen (its block's height, scaled by its
//! instance, over its block centre's distance times [`Camera::world_per_pixel`]) is drawn with
//! the technique `t` of least primitives at `h` among those whose error satisfies
//! `error_t(h) ≤ floor(h) + target_h`, the floor the least error at `h` of the full mesh and every
//! representation: drawn at one sample per pixel the full mesh aliases against the supersampled
//! reference too (near, a representation is asked to keep *that* image, not a better one), and
//! far away, where its thin leaves drop out of the mip-filtered alpha test, the representation
//! that keeps them sets the image to keep. Ties go to the lower error; when nothing qualifies, the
//! lowest error wins. The full mesh itself is never chosen (the sequential point tree and the LoD
//! chain converge to it). Above the largest calibrated height the choice at that height holds if
//! it converges to the full mesh as trees come near ([`converges`]: the point tree, the LoD
//! chain), else the rule's choice there among the techniques that converge; and the point tree
//! ([`Technique::FALLBACK`]) stands in for that choice where it costs less for what is in view:
//! it culls per cell, so a near tree the view cuts draws only the share `s` of its triangles in
//! cells the view holds ([`in_view_share`]), while the chain draws the whole tree. The tables
//! count whole trees, so the point tree is drawn where its primitives at the largest height
//! times `s` are fewer than the choice's there (and its image is within the target there), with
//! a quarter of hysteresis either way against last frame's technique. Below the smallest height
//! the smallest height's choice holds. (Measured: the point tree for every tree above the range
//! drew whole near trees with 2.2–2.5× the full mesh's primitives at the same error, the oak's
//! 49,409 against the chain's 22,566 in `eval` at 2 radii, the Quaternius tree's 7,121 against
//! 2,888; the chain for every one drew the pine's forest bench, `bench --quality` over 200 trees,
//! with 64,115 primitives per frame against 44,272 with the point tree for trees the view cuts.)
//!
//! **The allowance by size.** `target_h` is [`Policy::target`] for a tree up to
//! [`TARGET_HEIGHT`] (64) pixels high and `target · 64 / h` above ([`target_at`]): an error over
//! the floor costs the frame in proportion to the pixels that carry it, so a tree `h` pixels high
//! adds `∝ h² · target_h²` to the frame's squared error, and no tree adds more than a 64-pixel
//! tree at the target — the argument the occlusion classes make for a tree partly hidden. Small
//! trees keep the whole target rather than more: there the floor is the full mesh's own aliasing,
//! and a forest holds many of them. (Measured with `bench --quality` over 200 trees, 30 frames,
//! 480×270, primitives per frame / RMSE / FLIP, the same target 0.01 everywhere against this: the
//! oak 26,874 / 0.0193 / 0.0415 against 40,384 / 0.0179 / 0.0379, the pine 43,454 / 0.0201 /
//! 0.0421 against 44,947 / 0.0198 / 0.0415, the orchid 77,268 / 0.0334 / 0.0692 against 87,909 /
//! 0.0332 / 0.0683; the point tree 784,488 / 0.0214 / 0.0367, 591,782 / 0.0181 / 0.0378 and
//! 378,200 / 0.0401 / 0.0688. With the same target everywhere, the descent into the oak's forest
//! drew its nearest trees, about 250 pixels high and seen from 19° above, as ellipsoids, which
//! the tables put within 0.01 of the full mesh's 0.0153 there: frame RMSE 0.039 and FLIP 0.150
//! where the point tree's read 0.026 and 0.093. The reference height, measured at 32, 64 and 128:
//! 43,867 / 0.0175 / 0.0370, 40,384 / 0.0179 / 0.0379 and 35,502 / 0.0185 / 0.0393 on the oak,
//! 138,570 / 0.0189 / 0.0390, 44,947 / 0.0198 / 0.0415 and 44,043 / 0.0198 / 0.0416 on the pine.
//! And loosening small trees too, `target · 64 / h` at every height: the oak 35,294 / 0.0212 /
//! 0.0403, the pine 22,245 / 0.0225 / 0.0434, the orchid 65,856 / 0.0390 / 0.0710.)
//!
//! **FLIP** (spec §6.19, §10.2). The tables' error, multi-scale RMSE, weighs every pixel's
//! difference alike at every scale from single pixels up; FLIP (Andersson et al. 2020) weighs
//! them as a viewer sees them, and the two can rank representations the other way: a lone
//! billboard or an octahedral quad, smooth where the reference's crown shows gaps, against the
//! point tree, whose splats are speckled where the reference is a soft wash. Where the container
//! has FLIP tables (`CALIBRATION_FLIP`, format 1.17, which the build writes when built with FLIP,
//! as the command line is) a technique qualifies only if its FLIP error is also within the same
//! share of the FLIP floor (the least FLIP error at `h` of the full mesh and every
//! representation, from the same elevation class): `flip_t(h) ≤ flip_floor(h) · (1 + target_h /
//! floor(h))`, so the one target means one thing for both errors, and no second knob or constant
//! is needed. A technique without FLIP rows is judged by its RMSE alone. The LoD chain is judged by
//! the level it draws: where the container has its levels' FLIP tables (`CHAIN_CALIBRATION_FLIP`,
//! format 1.18) by that level's FLIP error over every view plus the chain's offset from the
//! elevation class (its FLIP row there less its row over every view), as its RMSE is read; in a
//! file of 1.17, whose `lod-chain` rows have a FLIP error only where it draws the full mesh, by
//! that row (the chain at the build's default target). When nothing qualifies, the technique
//! whose larger share over the two floors is least wins (without FLIP tables, the lowest error,
//! as before). Measured with `bench --quality` over 200 trees of each shared model built with every representation (30 frames,
//! 480×270; primitives per frame / RMSE / FLIP, the RMSE tables alone → with the FLIP tables,
//! the point tree's in the same runs after): the Quaternius tree 9,909 / .01182 / .01740 →
//! 9,935 / .01182 / .01740 (.01204 / .01759), the oak 20,349 / .01763 / .03350 → 24,670 / .01711
//! / .03225 (.01829 / .03399), the pine 35,964 / .01817 / .03832 → 39,845 / .01812 / .03822
//! (.01764 / .03721), the orchid 70,718 / .03325 / .06708 → 272,544 / .03136 / .06355 (.03184 /
//! .06120), the jacaranda 65,924 / .02047 / .04340 → 99,329 / .02049 / .04244 (.02372 / .04078),
//! the willow 232,906 / .03061 / .05731 → 278,112 / .03089 / .05466 (.03268 / .05409), the maple
//! 280,263 / .03578 / .06113 → 385,970 / .03513 / .05850 (.03556 / .05625). The gap to the
//! point tree's FLIP narrows on every model that had one (the orchid's from 9.6 % to 3.8 %, the
//! willow's from 6.0 % to 1.1 %, the maple's from 8.7 % to 4.0 %), and the oak's policy is now below the point tree in
//! both errors; the primitives rise by up to 3.9× (the orchid, still 0.69× the point tree's):
//! where the two errors disagree, the choice now keeps the image both see. In `eval --orbit
//! 2,8,32` (one tree, 640×480) the choice changes in one band of one model: the jacaranda at
//! 8–32 pixels draws its point tree (964 primitives, RMSE .00163, FLIP .00022) where it drew the
//! octahedral quad (1, .00151, .00024), which then has the lower RMSE for fewer primitives.
//!
//! **The LoD chain's level** (spec §6.17, §10.2). Where a container holds the chain's per-level
//! tables, the chain's level at `h` follows the same rule among the full mesh and the chain's
//! levels ([`Calibration::chain_level`]): the fewest triangles with
//! `error ≤ floor(h) + target_h`, the floor now counting the levels (and not the chain's own row,
//! which the build derives from them with the default target, so that the policy compares the
//! chain it will draw). Where no level reaches the floor (far away the point tree keeps leaves
//! every mesh loses to the alpha test), the fewest triangles within `target_h` of the least error
//! among them: the policy
//! would not pick the chain there, and a chain drawn anyway keeps its best image for less.
//! Where the container has the levels' FLIP tables (`CHAIN_CALIBRATION_FLIP`, format 1.18), a
//! level (or the full mesh) must also be within the same share of the FLIP floor over every
//! view, the floor counting the levels' FLIP errors in place of the chain's own row, as a
//! representation must be (above); where none is, the same shares of the chain's own least
//! errors, then its RMSE alone. (Measured with `bench --quality` over 200 trees of each shared
//! model built with every representation, 30 frames, 480×270: the Quaternius tree's chain at 64
//! pixels draws 764 triangles where it drew 722, its forest 9,935 / .01182 / .01740 → 10,043 /
//! .01170 / .01700 in primitives per frame / RMSE / FLIP, the point tree's .01204 / .01759; the
//! other six models' forests are the same to the last digit.)
//! [`ChainChoices`] tables it per model and policy as [`Choices`] does, with the same
//! hysteresis; `baseline::select` looks it up per tree, and keeps the geometric rule (levels by
//! meshoptimizer's error alone) for containers without the tables.
//!
//! The per-level tables are means over every calibration view (spec §6.17), so the level is
//! picked by the tables over every view whatever the tree's elevation class, one table per
//! model and policy; where the tables have rows per elevation, among the levels that are also
//! within the target from every elevation class (their errors there as below), since the one
//! level drawn must keep the image from each. (Without that, the shared Quaternius tree's chain
//! at 256 pixels drew a level of every leaf and a quarter of its bark, 0.0060 over every view
//! but 0.0095 from the side against a floor of 0.0050 there; from the side the policy then
//! rejected the chain and drew the point tree, 7,121 primitives, where the full mesh keeps the
//! image with 2,888.) Among the representations the policy compares the chain as drawn at its own
//! target ([`Calibration::chain_at`]); from elevation class `c` a level reads its mean error
//! plus the chain's offset there, the class's `lod-chain` row less the row over every view
//! ([`Calibration::level_at_elevation`]): exact for the level the default target picks, which
//! those rows measure. Measured on the shared oak, pine and Quaternius tree (each level drawn
//! from the 7 views, 6 heights), a level's error from one elevation is so predicted to within
//! 0.0035–0.0044 on average (0.017–0.033 at worst), where its mean alone is off by
//! 0.0050–0.0089 (0.021–0.032). Those estimates set no floor ([`Calibration::floor`]): from
//! class `c` the floor is the least error measured there, the chain's own row among them. (When
//! they did, the shared jacaranda's level 0, estimated at 0.0523 from straight above at 8
//! pixels, under everything measured there, left no representation but the chain within the
//! target: 6 of the 200 trees of `bench`'s overview drew 34,993 triangles each.)
//!
//! **Hysteresis.** A tree keeps last frame's technique while that technique is still the choice
//! somewhere within [`Policy::hysteresis`] octaves of its height (a tree crossing a boundary must
//! move that much further before it switches back), so a tree hovering at a boundary does not
//! flicker.
//!
//! **Short runs.** The rule at one height does not look at the next, and where two representations'
//! errors lie near the target the choice can change for a few steps and back (the shared jacaranda
//! seen from 10° went octahedral, spt, octahedral, spt, Cook's pruning, the chain). The hysteresis
//! keeps a tree moving through a run of up to its own width on what it drew; a longer run costs a
//! cross-fade in and another out. So each table's runs shorter than an octave
//! ([`SHORTEST_RUN_STEPS`]) that lie between two others are merged into a neighbour admissible at
//! every step of the run (within the target of both floors there, as the rule asks) that draws at
//! most [`MERGE_COST`] (two) times the primitives of the rule's choices over the run — what a tree
//! fading between two techniques draws, both at once — the cheaper of the two neighbours, the
//! shortest run first, until none can be. Every step still draws a technique the rule allows there.
//! Measured on the shared models built with every representation, summed over the ten elevation
//! classes from 4 to 256 pixels: the technique changes of the tables (`treelod dump`'s runs) 18,
//! 20, 26, 44, 39, 44 and 49 → 18, 20, 21, 29, 37, 36 and 34 (the Quaternius tree, oak, pine,
//! willow, orchid, maple, jacaranda), and those a tree coming nearer goes through (counted on those
//! runs with the hysteresis's rule, a step at a time) 12, 15, 18, 37, 35, 28 and 35 → 12, 15, 18,
//! 29, 35, 25 and 25. `bench --trees 1000000 --frames 12 --size 480x270 --no-render`, primitives
//! per frame: the pine 178,047 → 176,957, the willow 1,080,022 → 1,080,828, the jacaranda 464,910 →
//! 477,937, the other four the same; over 1,000 trees (30 frames): the pine 46,832 → 45,197, the
//! orchid 382,122 → 382,389, the jacaranda 126,817 → 146,240, the willow 347,896 → 348,565, the
//! maple 378,041 → 375,377, the other two the same. Merged without the cost bound, the maple's
//! 1,000 trees drew 453,342 (its small trees' point trees went to impostor planes of many times
//! their primitives). Merging runs of up to half an octave, a tree coming nearer goes through 33,
//! 27 and 34 changes on the willow, maple and jacaranda; up to two octaves, 25, 25 and 20, and the
//! jacaranda's 1,000 trees draw 183,024. `bench --quality` over 200 trees (30 frames, 480×270;
//! primitives per frame / RMSE / FLIP / temporal noise): the jacaranda 115,433 / .02050 / .04246 /
//! .18359 → 135,306 / .01985 / .04230 / .18414 (the reference's noise .17847), the willow 276,993 /
//! .03103 / .05480 / .18020 → 277,542 / .03072 / .05440 / .17983, the pine 39,845 / .01812 / .03822
//! / .18605 → 40,904 / .01801 / .03827 / .18603, the orchid 262,108 → 262,476 at the same errors,
//! the maple 402,476 / .03491 / .05845 / .17435 → 399,148 / .03459 / .05821 / .17405. `eval --path`
//! over 240 poses coming nearer to the jacaranda from 3 to 300 pixels high (320×240), at 0° and at
//! 60° above it: in the 32–128 pixel band 15,091 → 16,810 primitives, RMSE .01418 → .01400, FLIP
//! .01286 → .01317, and 9,518 → 11,665, .01494 → .01375, .01743 → .01607; the temporal noise over
//! the path .01911 → .01923 and .02028 → .02031 (the reference's .01316 and .01503); the other
//! bands the same.
//!
//! **Transitions.** A tree that changes technique is not switched at once: for
//! [`Policy::transition`] frames it is drawn with both, on complementary pixels of a screen-door
//! dither whose share moves from the old technique to the new one a step per frame
//! ([`PolicyState::transition`]), so the change reads as a short cross-fade rather than a pop
//! (as the point tree's and the ellipsoids' levels blend, spec §10.2). A tree that switches back
//! mid-way reverses from where it is; one that switches to a third technique starts a new
//! transition from the one it was going to. Frames, not seconds: the renderer has no clock, and
//! the same count gives the same images whatever the frame rate (a host at other than 60 frames
//! per second scales it).
//!
//! **Elevation.** A representation's error depends on where it is seen from, and most for the
//! cheapest: three crossed quads are a tree from the side and three lines from above (the shared
//! oak's crossed billboards read 0.049 at 8 pixels from the side, 0.229 from straight above, where
//! its point tree reads 0.058 to 0.072). Where the container has tables per elevation of the
//! calibration's views (spec §6.16, format 1.7: 0°, 30°, 60°, 90°), the choices are made per
//! elevation class: every 10°, [`ELEVATION_SUBDIVISIONS`] classes per span between two measured
//! elevations, each class's tables blended linearly in elevation from the two measured ones
//! ([`Calibration::with_elevations_between`]). Each tree is chosen by the class of its
//! view: the elevation of the eye above the tree's horizontal plane at the block centre
//! ([`view_elevation`]; views from below count as from the side), with a hysteresis of a quarter of
//! the classes' spacing ([`elevation_class_after`]), so a camera climbing over a forest hands its
//! far trees from billboards to planes or points while a walker keeps them billboards. A tree
//! seen from below the tables (more than half the classes' spacing below the lowest, −5° with
//! the build's classes; [`Choices::below_horizon`], with a quarter of the spacing of hysteresis)
//! is chosen by the lowest class's tables among the techniques whose representations do not
//! hold only views from above ([`upper_hemisphere_only`]: the octahedral impostor, which draws a
//! tree seen from below with its horizon's views); the tables do not look from below, and the
//! other representations are the tree's own geometry, as near from below as from the side
//! (measured on the shared pine's forest, `bench --quality`, where the eye walks 3.4 m above
//! the ground under trees whose centres are 34 m up, see `docs/cli.md`). Without
//! those tables every tree is chosen by the tables over every view. A shadow cascade's trees are
//! chosen by the view that sets their height (the camera's or the cascade's, whichever sees the
//! tree smaller). The classes between measured elevations: with the nearest measured class
//! alone, `eval --orbit 8` (640×480, views 21° up) read the shared orchid from the 30° tables,
//! where its point tree is the floor (0.038 at 58 pixels against the full mesh's 0.057 and the
//! impostors' 0.051; from 0° it reads 0.075 against 0.063 and 0.052), and drew it with the
//! chain's full mesh (31,004 triangles, RMSE 0.0074, FLIP 0.0028); at 20° the blend puts the
//! impostors within the target and draws them (257 primitives, 0.0097, 0.0043). `bench --quality`
//! over 200 trees (30 frames, 480×270, primitives per frame / RMSE / FLIP), nearest measured
//! class against classes every 10°: the oak 40,384 / 0.0179 / 0.0379 against 44,057 / 0.0176 /
//! 0.0376, the pine 44,374 / 0.0198 / 0.0415 against 42,459 / 0.0198 / 0.0419, the orchid
//! 81,602 / 0.0333 / 0.0683 against 68,180 / 0.0334 / 0.0686 (the point tree 784,488 / 0.0214 /
//! 0.0367, 591,782 / 0.0181 / 0.0378, 378,200 / 0.0401 / 0.0688).
//!
//! **Occlusion.** A tree partly hidden behind others shows only part of its error: with
//! [`Policy::occlusion`] and a measured visible fraction `v` (the share of its hull samples the
//! depth of an earlier frame shows, Neubert et al. 2011 §5), the errors above the floor are
//! scaled by `√v` — the squared error of the pixels it covers falls with their number — so it
//! is chosen with the allowance raised to `target_h / √v`. `v` is rounded to one of
//! [`VISIBILITY_CLASSES`] classes (1, ½, ¼, ⅛; geometric midpoints between), each with its own
//! table of choices, so a frame still pays a lookup per tree.
//!
//! **Cost per frame.** The rule is evaluated once per model and policy into a table of choices
//! every [`STEPS_PER_OCTAVE`]-th of an octave per elevation and visibility class ([`Choices`]);
//! per tree the frame pays a distance, a `log2`, an `asin` (with tables per elevation) and a
//! lookup ([`Choices::choose_framed`]); a tree above the calibrated range also a box test per
//! cell ([`in_view_share`]). Measured with `cargo bench -p treelod-runtime --bench select`
//! (10,000 demo trees with every representation, 60 poses, 1920×1080, 2 cores): the whole frame
//! with the policy, choice, assignment and every technique's selection, takes a median of
//! 0.87–1.10 ms over the poses; the overview, 6,000 impostor trees drawing 220,000 plane and
//! line prefixes, 1.89–1.97 ms (2.42–2.45 ms while each impostor tree's bark allocated its own
//! list of line prefixes); the point tree alone for every tree, 0.68 ms.

use glam::{Mat4, Vec3};
use rayon::prelude::*;
use treelod_format::{
    CalibrationRecord, ChainCalibrationRecord, ChainFlipCalibrationRecord, Container, ElevationCalibrationRecord,
    FlipCalibrationRecord,
};

use crate::draws::Representations;
use crate::frame::{Camera, Frustum, Instance, ModelLod};
use crate::technique::{PerTechnique, Technique};

/// Steps of the choice tables per octave of projected height.
pub const STEPS_PER_OCTAVE: f32 = 8.0;

/// What the policy keeps: one user-facing knob, the error allowed over the floor, and the
/// hysteresis against flicker.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Policy {
    /// Error allowed above the floor (the least error of the full mesh and every representation
    /// at the same projected height, module docs), in units of the calibration's error
    /// (multi-scale RMSE of the shaded image, `[0, 1]`, spec §6.15), for a tree up to
    /// [`TARGET_HEIGHT`] pixels high; a larger one is allowed less, in proportion to its height
    /// ([`target_at`]). 0 asks for the best image the tables know (only
    /// representations as good as it qualify); larger values trade image for primitives. Default [`Policy::DEFAULT_TARGET`]. Not finite or negative: 0.
    pub target: f32,
    /// Octaves of projected height around a boundary within which a tree keeps last frame's
    /// technique. Default 0.25 (a tree moves about 19 % of its distance past a boundary before
    /// it switches back). Not finite or negative: 0.
    pub hysteresis: f32,
    /// Budget mode: primitives per frame to aim for (every kind, as the renderer counts them in
    /// the camera's view, less the draws of the techniques trees in a transition leave, which
    /// come on top for the transition's frames; shadow passes are not counted). `Some`: a [`BudgetController`]
    /// (created with [`BudgetController::for_policy`]) moves the target and `s_min` together
    /// from frame to frame so the frame meets the count, starting from [`Self::target`] and
    /// the renderer's `s_min`; the error is then spread as the target spreads it: every tree
    /// gets the controller's target over its floor, scaled by its size on screen as
    /// [`target_at`] says (spec §10.2). Default `None`: the target holds.
    ///
    /// [`BudgetController`]: crate::BudgetController
    /// [`BudgetController::for_policy`]: crate::BudgetController::for_policy
    pub budget: Option<u64>,
    /// Frames over which a tree that changes technique fades from the old one to the new one
    /// (module docs), both drawn on complementary dithered pixels meanwhile; 0 or 1: switch at
    /// once. Default [`Policy::DEFAULT_TRANSITION`]; at most [`Policy::MAX_TRANSITION`].
    pub transition: u32,
    /// Trees partly hidden behind others are chosen with the target raised to `target / √v`,
    /// `v` their measured visible fraction (module docs; the renderer measures it where the host
    /// calls `Renderer::measure_occlusion` after its pass, else every tree counts as visible).
    /// Default `true`.
    pub occlusion: bool,
}

impl Policy {
    /// The default [`Policy::transition`]: 15 frames, a quarter of a second at 60 frames per
    /// second — long enough that the change is not seen as a pop, short enough that few trees are
    /// drawn twice at once (the extra primitives of a fly-through are reported by `bench`).
    pub const DEFAULT_TRANSITION: u32 = 15;

    /// The largest [`Policy::transition`] (ten seconds at 60 frames per second).
    pub const MAX_TRANSITION: u32 = 600;

    /// The default [`Policy::target`]: one hundredth of RMSE over the floor (the tables' error is
    /// of the shaded image on a white background, where a missing leaf pixel costs about 0.9 and
    /// a wrong shade of green a few hundredths). At a few pixels every representation's error is
    /// 0.05–0.1 (the full mesh's aliasing included), so 0.01 separates what keeps a small tree's
    /// silhouette, density and shade from what does not (a lone billboard loses two to five times
    /// that on the shared trees); near, the full mesh's own error is 0.005–0.035, so the target
    /// allows differences as large as its aliasing.
    ///
    /// Measured against half the target (`bench --quality`, 200 trees, 30 frames, 480×270;
    /// primitives per frame / RMSE / FLIP, 0.01 → 0.005, the point tree's in the same forests
    /// after): the Quaternius tree 9,909 / .01182 / .01727 → 34,476 / .00994 / .01476 (spt
    /// .01204 / .01759), the oak 20,349 / .01763 / .03350 → 23,508 / .01746 / .03314 (.01829 /
    /// .03399), the pine 35,964 / .01817 / .03832 → 61,242 / .01756 / .03714 (.01764 / .03721;
    /// 0.0025: 76,055 / .01758 / .03708), the orchid 70,718 / .03320 / .06698 → 262,653 / .03137
    /// / .06391 (.03184 / .06120), the jacaranda 65,924 / .02047 / .04341 → 99,363 / .02004 /
    /// .04211 (.02372 / .04078), the willow 232,906 / .03061 / .05730 → 380,648 / .03019 / .05623
    /// (280,797 / .03268 / .05409). Halving it buys the pine the point tree's FLIP for 70 % more
    /// primitives, but not the orchid's, the jacaranda's or the willow's, at two to four times
    /// the primitives (the willow's more than the point tree's own): where the policy loses FLIP
    /// to the point tree, the tables' RMSE ranks the choice the other way. The willow's overview,
    /// 186 of its 200 trees one billboard each, reads RMSE .0272–.0309 against the point tree's
    /// .0380–.0415 and FLIP .0356–.0478 against .0345–.0419; the orchid's last thirteen frames,
    /// every tree in view an octahedral quad, lose both (frame 24: RMSE .0482 against .0330, FLIP
    /// .0795 against .0550), where its tables put the quad within the target. So the target stays
    /// 0.01: the remedy is in what the tables measure, not in the allowance. (Those figures are
    /// of the RMSE tables alone; the FLIP tables of format 1.17 are that remedy, module docs.)
    pub const DEFAULT_TARGET: f32 = 0.01;

    /// The target, sanitised (not finite or negative: 0).
    #[must_use]
    pub fn target(&self) -> f32 {
        sanitise(self.target)
    }

    /// The hysteresis in octaves, sanitised (not finite or negative: 0).
    #[must_use]
    pub fn hysteresis(&self) -> f32 {
        sanitise(self.hysteresis)
    }

    /// The transition in frames, at most [`Self::MAX_TRANSITION`].
    #[must_use]
    pub fn transition(&self) -> u32 {
        self.transition.min(Self::MAX_TRANSITION)
    }
}

impl Default for Policy {
    fn default() -> Self {
        Self {
            target: Self::DEFAULT_TARGET,
            hysteresis: 0.25,
            budget: None,
            transition: Self::DEFAULT_TRANSITION,
            occlusion: true,
        }
    }
}

fn sanitise(x: f32) -> f32 {
    if x.is_finite() { x.max(0.0) } else { 0.0 }
}

/// One sample of a calibration curve.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    log2_height: f32,
    error: f32,
    primitives: f32,
}

/// A model's calibration tables (spec §6.15, §6.16, §6.17): per technique, its error and
/// primitives as functions of the block's projected height, interpolated linearly in
/// `log2(height)` and clamped outside the sampled range — over every view (`CALIBRATION`) and,
/// where the container has them, per elevation of the views (`CALIBRATION_ELEVATIONS`, format
/// 1.7) and per level of its LoD chain over every view (`CHAIN_CALIBRATION`, format 1.8).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Calibration {
    curves: PerTechnique<Vec<Sample>>,
    /// Per elevation of the views, ascending: its degrees and its curves.
    elevations: Vec<(f32, PerTechnique<Vec<Sample>>)>,
    /// Per LoD chain level, finest first, over every view (`CHAIN_CALIBRATION`); empty without
    /// them.
    levels: Vec<Vec<Sample>>,
    /// Per technique its FLIP error over every view (`CALIBRATION_FLIP`, format 1.17: each
    /// sample's `error` the FLIP error, its `primitives` 0); empty without them.
    flip: PerTechnique<Vec<Sample>>,
    /// The same per elevation of [`Self::elevations`], index for index (empty curves where the
    /// tables have none at that elevation; no entries without FLIP tables).
    flip_elevations: Vec<PerTechnique<Vec<Sample>>>,
    /// Per LoD chain level, its FLIP error over every view (`CHAIN_CALIBRATION_FLIP`, format
    /// 1.18; each sample's `error` the FLIP error, its `primitives` 0); empty without them.
    level_flips: Vec<Vec<Sample>>,
}

/// Appends `record`'s sample to `curves` if its technique is known, its values finite and its
/// height above the curve's last (records are sorted, spec §6.15).
fn push_sample(curves: &mut PerTechnique<Vec<Sample>>, technique: u32, height: f32, error: f32, primitives: f32) {
    let Some(technique) = Technique::ALL.get(technique as usize).copied() else { return };
    push_to_curve(&mut curves[technique], height, error, primitives);
}

/// Appends `(height, error, primitives)` to `curve` if its values are finite and its height
/// above the curve's last.
fn push_to_curve(curve: &mut Vec<Sample>, height: f32, error: f32, primitives: f32) {
    let valid = height.is_finite() && height > 0.0 && error.is_finite() && primitives.is_finite();
    let log2_height = height.log2();
    if valid && curve.last().is_none_or(|s| s.log2_height < log2_height) {
        curve.push(Sample { log2_height, error, primitives });
    }
}

/// Per LoD chain level from 0, its curve of the `(level, height, error, primitives)` samples
/// (sorted by level, then height, spec §6.17, §6.20): samples with non-finite values are
/// skipped, and the levels end at the first level number without a valid sample.
fn level_curves(samples: impl Iterator<Item = (u32, f32, f32, f32)>) -> Vec<Vec<Sample>> {
    let mut levels: Vec<Vec<Sample>> = Vec::new();
    for (level, height, error, primitives) in samples {
        let Ok(level) = usize::try_from(level) else { break };
        if level > levels.len() {
            break;
        }
        if level == levels.len() {
            levels.push(Vec::new());
        }
        push_to_curve(&mut levels[level], height, error, primitives);
    }
    if let Some(gap) = levels.iter().position(Vec::is_empty) {
        levels.truncate(gap);
    }
    levels
}

/// `(error, primitives)` of `curve` at `log2(height) = x`.
fn curve_at(curve: &[Sample], x: f32) -> Option<(f32, f32)> {
    let (first, last) = (curve.first()?, curve.last()?);
    if x <= first.log2_height {
        return Some((first.error, first.primitives));
    }
    if x >= last.log2_height {
        return Some((last.error, last.primitives));
    }
    let next = curve.partition_point(|s| s.log2_height <= x);
    let (a, b) = (curve[next - 1], curve[next]);
    let t = (x - a.log2_height) / (b.log2_height - a.log2_height);
    Some((a.error + t * (b.error - a.error), a.primitives + t * (b.primitives - a.primitives)))
}

/// `(1 − t)·a + t·b` at every height `a` or `b` samples (each read as [`curve_at`] reads it,
/// clamped outside its range); empty if either is.
fn blend_curves(a: &[Sample], b: &[Sample], t: f32) -> Vec<Sample> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    let mut heights: Vec<f32> = a.iter().chain(b).map(|s| s.log2_height).collect();
    heights.sort_by(f32::total_cmp);
    heights.dedup();
    heights
        .into_iter()
        .filter_map(|x| {
            let ((ea, pa), (eb, pb)) = (curve_at(a, x)?, curve_at(b, x)?);
            Some(Sample { log2_height: x, error: ea + t * (eb - ea), primitives: pa + t * (pb - pa) })
        })
        .collect()
}

/// Which of a LoD chain's meshes draws a block: the full mesh (`TRIANGLES`), or the chain's level
/// of this number (0 the finest), every tree's level of that number.
pub type ChainPick = Option<u32>;

/// The finer of two chain picks (the full mesh is the finest).
fn finer(a: ChainPick, b: ChainPick) -> ChainPick {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        _ => None,
    }
}

impl Calibration {
    /// The tables of `container`, with its tables per elevation and its LoD chain's per-level
    /// tables where it has them; `None` when it has none (built without calibration, or before
    /// format 1.5).
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        // The techniques of format 1.12 on (spec §6.18) are tabled in sections of their own; with
        // `CALIBRATION`'s they are the file's tables. Their codes follow every code of
        // `CALIBRATION`, so appended they keep the order §6.15 asks for, and per elevation they
        // follow that elevation's records of `CALIBRATION_ELEVATIONS` (a stable sort by
        // elevation).
        let records: Vec<CalibrationRecord> =
            container.calibration().iter().chain(container.calibration_added()).copied().collect();
        let mut elevations: Vec<ElevationCalibrationRecord> = container
            .calibration_elevations()
            .iter()
            .chain(container.calibration_elevations_added())
            .copied()
            .collect();
        elevations.sort_by(|a, b| a.elevation.total_cmp(&b.elevation));
        Self::from_records(&records).map(|c| {
            c.with_elevations(&elevations)
                .with_chain_levels(container.chain_calibration())
                .with_flip(container.calibration_flip())
                .with_chain_flip(container.chain_calibration_flip())
        })
    }

    /// The tables of `records` (sorted as spec §6.15 asks; [`Container`] has verified that).
    /// Records of unknown techniques or with non-finite values are skipped; `None` when no
    /// technique is left.
    #[must_use]
    pub fn from_records(records: &[CalibrationRecord]) -> Option<Self> {
        let mut curves = PerTechnique::<Vec<Sample>>::default();
        for r in records {
            push_sample(&mut curves, r.technique, r.height, r.error, r.primitives);
        }
        curves.0.iter().any(|c| !c.is_empty()).then_some(Self { curves, ..Self::default() })
    }

    /// These tables with the FLIP tables of `records` (`CALIBRATION_FLIP`, sorted as spec §6.19
    /// asks), replacing any they had: the rows over every view, and per elevation of the tables
    /// per elevation ([`Self::with_elevations`], which must come first) the rows of that
    /// elevation. Rows of unknown techniques, with non-finite values or of elevations the tables
    /// lack are skipped. The policy's rule then asks for both errors (module docs).
    #[must_use]
    pub fn with_flip(mut self, records: &[FlipCalibrationRecord]) -> Self {
        self.flip = PerTechnique::default();
        self.flip_elevations = vec![PerTechnique::default(); self.elevations.len()];
        for r in records {
            if r.elevation == FlipCalibrationRecord::EVERY_VIEW {
                push_sample(&mut self.flip, r.technique, r.height, r.flip, 0.0);
            } else if let Some(e) = self.elevations.iter().position(|(degrees, _)| *degrees == r.elevation) {
                push_sample(&mut self.flip_elevations[e], r.technique, r.height, r.flip, 0.0);
            }
        }
        if self.flip.0.iter().all(Vec::is_empty) {
            self.flip_elevations.clear();
        }
        self
    }

    /// Whether the tables hold FLIP errors (`CALIBRATION_FLIP`).
    #[must_use]
    pub fn has_flip(&self) -> bool {
        self.flip.0.iter().any(|c| !c.is_empty())
    }

    /// The FLIP error of `technique` at a projected height of `height` pixels from elevation
    /// class `elevation` (`None`, or a class without FLIP tables: over every view), if the FLIP
    /// tables hold it.
    #[must_use]
    pub fn flip_at(&self, elevation: Option<usize>, technique: Technique, height: f32) -> Option<f32> {
        let curves = elevation.and_then(|e| self.flip_elevations.get(e)).unwrap_or(&self.flip);
        curve_at(&curves[technique], height.max(f32::MIN_POSITIVE).log2()).map(|(flip, _)| flip)
    }

    /// The FLIP floor at one height (elevation class `elevation`, as [`Self::flip_at`]): the
    /// least FLIP error of the full mesh and of every technique the FLIP tables hold and
    /// `usable` accepts, and over every view the LoD chain's levels in place of its own row where
    /// the tables hold their FLIP errors (as [`Self::floor`] counts them); `+∞` without FLIP
    /// tables.
    #[must_use]
    pub fn flip_floor(&self, elevation: Option<usize>, height: f32, usable: impl Fn(Technique) -> bool) -> f32 {
        let by_class = elevation.is_some_and(|e| e < self.flip_elevations.len());
        let per_level = !self.level_flips.is_empty() && !by_class;
        let techniques = Technique::ALL
            .into_iter()
            .filter(|&t| t == Technique::Full || (usable(t) && !(per_level && t == Technique::LodChain)))
            .filter_map(|t| self.flip_at(elevation, t, height));
        let chain = per_level && usable(Technique::LodChain);
        #[expect(clippy::cast_possible_truncation, reason = "a chain has a few levels")]
        let levels = (0..self.level_flips.len() as u32).filter(|_| chain).filter_map(|l| self.level_flip_at(l, height));
        techniques.chain(levels).fold(f32::INFINITY, f32::min)
    }

    /// These tables with the LoD chain levels' FLIP tables of `records` (`CHAIN_CALIBRATION_FLIP`,
    /// sorted as spec §6.20 asks), replacing any they had. Samples with non-finite values are
    /// skipped; the levels end at the first level number without a valid sample. The chain's
    /// level is then picked by both errors ([`Self::chain_level`]).
    #[must_use]
    pub fn with_chain_flip(mut self, records: &[ChainFlipCalibrationRecord]) -> Self {
        self.level_flips = level_curves(records.iter().map(|r| (r.level, r.height, r.flip, 0.0)));
        self
    }

    /// The FLIP error of the LoD chain's level `level` at a projected height of `height` pixels
    /// over every view, if the tables hold it (`CHAIN_CALIBRATION_FLIP`).
    #[must_use]
    pub fn level_flip_at(&self, level: u32, height: f32) -> Option<f32> {
        let curve = self.level_flips.get(usize::try_from(level).ok()?)?;
        curve_at(curve, height.max(f32::MIN_POSITIVE).log2()).map(|(flip, _)| flip)
    }

    /// The FLIP error of the LoD chain drawn as `pick` ([`Self::chain_level`]'s at the policy's
    /// target; `None`: the tables hold no pick) at a projected height of `height` pixels, seen
    /// from elevation class `elevation`: its level's FLIP error over every view plus the chain's
    /// offset there, the elevation's `lod-chain` FLIP row less the row over every view (as
    /// [`Self::level_at_elevation`] reads the RMSE), or the full mesh's where it picks the full
    /// mesh. Without the levels' FLIP tables, the `lod-chain` row (the chain at the default
    /// target). `None` where the tables hold neither.
    fn chain_flip_at(&self, elevation: Option<usize>, height: f32, pick: Option<ChainPick>) -> Option<f32> {
        if self.level_flips.is_empty() {
            return self.flip_at(elevation, Technique::LodChain, height);
        }
        match pick? {
            Some(level) => {
                let offset = match (
                    elevation.and_then(|_| self.flip_at(elevation, Technique::LodChain, height)),
                    self.flip_at(None, Technique::LodChain, height),
                ) {
                    (Some(seen), Some(mean)) => seen - mean,
                    _ => 0.0,
                };
                self.level_flip_at(level, height).map(|f| (f + offset).max(0.0))
            }
            None => self.flip_at(elevation, Technique::Full, height),
        }
    }

    /// These tables with the tables per elevation of `records` (sorted as spec §6.16 asks),
    /// replacing any before; elevations that are not finite, not ascending or whose tables hold
    /// no technique are skipped.
    /// Any FLIP tables per elevation are dropped with the elevations they were read for
    /// ([`Self::with_flip`] reads them again).
    #[must_use]
    pub fn with_elevations(mut self, records: &[ElevationCalibrationRecord]) -> Self {
        self.elevations.clear();
        self.flip_elevations.clear();
        for r in records {
            if !r.elevation.is_finite() {
                continue;
            }
            let same = self.elevations.last().is_some_and(|(e, _)| *e == r.elevation);
            if !same {
                if self.elevations.last().is_some_and(|(e, _)| *e > r.elevation) {
                    continue;
                }
                self.elevations.push((r.elevation, PerTechnique::default()));
            }
            if let Some((_, curves)) = self.elevations.last_mut() {
                push_sample(curves, r.technique, r.height, r.error, r.primitives);
            }
        }
        self.elevations.retain(|(_, curves)| curves.0.iter().any(|c| !c.is_empty()));
        self
    }

    /// These tables with the LoD chain's per-level tables of `records` (sorted as spec §6.17
    /// asks), replacing any it had. Samples with non-finite values are skipped; the levels end at
    /// the first level number without a valid sample (verified files have every level from 0).
    #[must_use]
    pub fn with_chain_levels(mut self, records: &[ChainCalibrationRecord]) -> Self {
        self.levels = level_curves(records.iter().map(|r| (r.level, r.height, r.error, r.primitives)));
        self
    }

    /// These tables with `subdivisions − 1` tables blended between each two neighbouring
    /// elevations of the tables per elevation, at even steps of elevation: each technique's
    /// error and primitives interpolated linearly in elevation at every height either table
    /// samples (a technique one of the two lacks has no curve there). The policy chooses by
    /// these ([`Choices::among`] with [`ELEVATION_SUBDIVISIONS`]), so a tree seen from 20° reads
    /// two thirds of the 30° tables and a third of the 0° ones rather than all of the nearer.
    /// `subdivisions` 0 or 1, or fewer than two elevations: the tables as they are.
    #[must_use]
    pub fn with_elevations_between(&self, subdivisions: usize) -> Self {
        let mut fine = self.clone();
        if subdivisions < 2 || self.elevations.len() < 2 {
            return fine;
        }
        fine.elevations.clear();
        fine.flip_elevations.clear();
        let blend = |lower: &PerTechnique<Vec<Sample>>, upper: &PerTechnique<Vec<Sample>>, t: f32| {
            let mut curves = PerTechnique::<Vec<Sample>>::default();
            for technique in Technique::ALL {
                curves[technique] = blend_curves(&lower[technique], &upper[technique], t);
            }
            curves
        };
        let flip = !self.flip_elevations.is_empty();
        for (i, pair) in self.elevations.windows(2).enumerate() {
            let ((a, lower), (b, upper)) = (&pair[0], &pair[1]);
            fine.elevations.push((*a, lower.clone()));
            if flip {
                fine.flip_elevations.push(self.flip_elevations[i].clone());
            }
            for k in 1..subdivisions {
                #[expect(clippy::cast_precision_loss, reason = "a few subdivisions")]
                let t = k as f32 / subdivisions as f32;
                fine.elevations.push((a + t * (b - a), blend(lower, upper, t)));
                if flip {
                    fine.flip_elevations.push(blend(&self.flip_elevations[i], &self.flip_elevations[i + 1], t));
                }
            }
        }
        fine.elevations.extend(self.elevations.last().cloned());
        if flip {
            fine.flip_elevations.extend(self.flip_elevations.last().cloned());
        }
        fine
    }

    /// The elevations of the tables per elevation, degrees, ascending (empty without them).
    #[must_use]
    pub fn elevations(&self) -> Vec<f32> {
        self.elevations.iter().map(|(e, _)| *e).collect()
    }

    /// The curves of elevation class `elevation` (an index into [`Self::elevations`]), or the
    /// mean ones for `None` or a class the tables lack.
    fn curves(&self, elevation: Option<usize>) -> &PerTechnique<Vec<Sample>> {
        elevation.and_then(|e| self.elevations.get(e)).map_or(&self.curves, |(_, curves)| curves)
    }

    /// Whether the tables hold `technique`.
    #[must_use]
    pub fn holds(&self, technique: Technique) -> bool {
        !self.curves[technique].is_empty()
    }

    /// `(error, primitives)` of `technique` at a projected height of `height` pixels over every
    /// view, if the tables hold it.
    #[must_use]
    pub fn at(&self, technique: Technique, height: f32) -> Option<(f32, f32)> {
        self.at_elevation(None, technique, height)
    }

    /// [`Self::at`] from the views of elevation class `elevation` (an index into
    /// [`Self::elevations`]; `None`, or a class the tables lack: over every view).
    #[must_use]
    pub fn at_elevation(&self, elevation: Option<usize>, technique: Technique, height: f32) -> Option<(f32, f32)> {
        curve_at(&self.curves(elevation)[technique], height.max(f32::MIN_POSITIVE).log2())
    }

    /// The number of LoD chain levels with tables (0 without `CHAIN_CALIBRATION`).
    #[must_use]
    pub fn chain_levels(&self) -> usize {
        self.levels.len()
    }

    /// `(error, primitives)` of the LoD chain's level `level` at a projected height of `height`
    /// pixels over every view, if the tables hold it.
    #[must_use]
    pub fn level_at(&self, level: u32, height: f32) -> Option<(f32, f32)> {
        curve_at(self.levels.get(usize::try_from(level).ok()?)?, height.max(f32::MIN_POSITIVE).log2())
    }

    /// [`Self::level_at`] as seen from elevation class `elevation` (`None`: over every view).
    /// The per-level tables are means over every view (spec §6.17), so a level's error from one
    /// elevation is its mean error plus the chain's own offset there: the elevation's `lod-chain`
    /// row less the row over every view at the same height (the build derives both from the
    /// levels, the level picked at the default target measured from that elevation's views and
    /// from every view). Exact for the level the default target picks; for the others it assumes
    /// the chain's levels differ from one elevation to another as its picked level does. The
    /// primitives are the level's (a mesh submits its triangles from every view).
    #[must_use]
    pub fn level_at_elevation(&self, elevation: Option<usize>, level: u32, height: f32) -> Option<(f32, f32)> {
        let (error, primitives) = self.level_at(level, height)?;
        Some((error + self.chain_offset(elevation, height), primitives))
    }

    /// The `lod-chain` row of elevation class `elevation` less the row over every view at
    /// `height` (0 for `None`, or where either row is missing).
    fn chain_offset(&self, elevation: Option<usize>, height: f32) -> f32 {
        let Some(e) = elevation.filter(|&e| e < self.elevations.len()) else { return 0.0 };
        match (self.at_elevation(Some(e), Technique::LodChain, height), self.at(Technique::LodChain, height)) {
            (Some((seen, _)), Some((mean, _))) => seen - mean,
            _ => 0.0,
        }
    }

    /// The smallest and largest calibrated heights over every technique, pixels.
    #[must_use]
    pub fn heights(&self) -> (f32, f32) {
        let mut range = (f32::INFINITY, f32::NEG_INFINITY);
        for curve in &self.curves.0 {
            if let (Some(first), Some(last)) = (curve.first(), curve.last()) {
                range = (range.0.min(first.log2_height.exp2()), range.1.max(last.log2_height.exp2()));
            }
        }
        range
    }

    /// The floor at one height by the tables of elevation class `elevation` (module docs;
    /// `None`: over every view): the least error of the full mesh and of every technique the
    /// tables hold and `usable` accepts. Over every view the LoD chain's levels stand for the
    /// chain where the tables hold them (its own row then describes the level the chain draws at
    /// the default target, one of them); from an elevation class the tables hold, the chain's
    /// own row there, the one level measured from it (the others' errors there are estimates,
    /// [`Self::level_at_elevation`]). `+∞` when the tables hold none.
    #[must_use]
    pub fn floor(&self, elevation: Option<usize>, height: f32, usable: impl Fn(Technique) -> bool) -> f32 {
        // Only measured errors set the floor. Over every view the levels are measured, and the
        // chain's own row is derived from them. From one elevation class only the chain's own
        // row is measured there (the level the default target picks); the other levels' errors
        // are estimates ([`Self::level_at_elevation`]), and a level that reads better there than
        // anything measured would hold every representation to it (module docs).
        let by_class = elevation.is_some_and(|e| e < self.elevations.len());
        let per_level = !self.levels.is_empty() && !by_class;
        let techniques = Technique::ALL
            .into_iter()
            .filter(|&t| t == Technique::Full || (usable(t) && !(per_level && t == Technique::LodChain)))
            .filter_map(|t| self.at_elevation(elevation, t, height).map(|(e, _)| e));
        let chain = per_level && usable(Technique::LodChain);
        #[expect(clippy::cast_possible_truncation, reason = "a chain has a few levels")]
        let levels = (0..self.levels.len() as u32)
            .filter(|_| chain)
            .filter_map(|l| self.level_at_elevation(elevation, l, height).map(|(e, _)| e));
        techniques.chain(levels).fold(f32::INFINITY, f32::min)
    }

    /// The policy's rule at one height (module docs): among the techniques the tables hold and
    /// `usable` accepts, less the full mesh, the one of least primitives whose error is within
    /// `target` of the floor ([`Self::floor`]) (ties: lower error; none within: least error), by
    /// the tables over every view. With per-level tables the LoD chain is the level it draws at
    /// `target` ([`Self::chain_at`]), so a policy whose target moves (budget mode) sees the
    /// chain it draws.
    /// [`Technique::FALLBACK`] when no technique is left.
    #[must_use]
    pub fn choose(&self, height: f32, target: f32, usable: impl Fn(Technique) -> bool) -> Technique {
        self.choose_at_elevation(None, height, target, usable)
    }

    /// [`Self::choose`] by the tables of elevation class `elevation` (as [`Self::at_elevation`];
    /// the chain as [`Self::chain_at`] sees it from there).
    #[must_use]
    pub fn choose_at_elevation(
        &self,
        elevation: Option<usize>,
        height: f32,
        target: f32,
        usable: impl Fn(Technique) -> bool,
    ) -> Technique {
        self.judge(elevation, height, target, usable).choice()
    }

    /// The techniques the rule lets a tree `height` pixels high seen from elevation class
    /// `elevation` take under `target` ([`Self::choose_at_elevation`]), each with its
    /// primitives there: those within the target of the floor (of both floors with FLIP
    /// tables), least primitives first; where none is, the rule's choice alone.
    #[must_use]
    pub fn admissible_at_elevation(
        &self,
        elevation: Option<usize>,
        height: f32,
        target: f32,
        usable: impl Fn(Technique) -> bool,
    ) -> Vec<(Technique, f32)> {
        self.judge(elevation, height, target, usable).admissible()
    }

    /// Every technique the tables hold and `usable` accepts, less the full mesh, judged at one
    /// height against the floors (module docs): what [`Self::choose_at_elevation`] and
    /// [`Self::admissible_at_elevation`] read.
    fn judge(&self, elevation: Option<usize>, height: f32, target: f32, usable: impl Fn(Technique) -> bool) -> Judged {
        let chain = usable(Technique::LodChain).then(|| self.chain_level(height, target, &usable));
        self.judge_but_chain(elevation, height, &usable).with_chain(self, elevation, height, target, chain)
    }

    /// [`Self::judge`] but for the LoD chain and the target, which [`Judged::with_chain`] adds:
    /// every other technique's errors and the floors at one height are the same whatever the
    /// target, so [`Choices::among`] reads them once for all of its targets.
    fn judge_but_chain(&self, elevation: Option<usize>, height: f32, usable: impl Fn(Technique) -> bool) -> Judged {
        let floor = self.floor(elevation, height, &usable);
        // With FLIP tables a technique must also be within its share of the FLIP floor: the
        // allowance is the same share of either floor (module docs), and where the FLIP tables
        // lack the technique, or either floor is not positive, the RMSE decides alone.
        let flip_floor = self.flip_floor(elevation, height, &usable);
        let flip_checked = floor > 0.0 && flip_floor.is_finite() && floor.is_finite();
        let candidates = Technique::ALL
            .into_iter()
            .filter(|&t| t != Technique::Full && t != Technique::LodChain && usable(t))
            .filter_map(|t| {
                let (e, p) = self.at_elevation(elevation, t, height)?;
                let f = if flip_checked { self.flip_at(elevation, t, height) } else { None };
                Some(Candidate { technique: t, error: e, primitives: p, flip: f })
            });
        let mut judged =
            Judged { slots: [Candidate::NONE; CANDIDATES], len: 0, floor, flip_floor, flip_checked, target: 0.0 };
        candidates.for_each(|c| judged.push(c));
        judged
    }

    /// The LoD chain judged at one height from elevation class `elevation`, drawn as `pick`
    /// ([`Self::chain_level`]'s at the target; `None` without per-level tables: its row, the
    /// chain at the default target), its level picked once for both errors; its FLIP error only
    /// where `flip_checked`.
    fn chain_candidate(
        &self,
        elevation: Option<usize>,
        height: f32,
        pick: Option<ChainPick>,
        flip_checked: bool,
    ) -> Option<Candidate> {
        let drawn = pick.and_then(|pick| self.drawn_as(elevation, pick, height));
        let (e, p) = drawn.or_else(|| self.at_elevation(elevation, Technique::LodChain, height))?;
        let f = if flip_checked { self.chain_flip_at(elevation, height, pick) } else { None };
        Some(Candidate { technique: Technique::LodChain, error: e, primitives: p, flip: f })
    }

    /// `(error, primitives)` of `technique` drawn under a policy of `target` seen from elevation
    /// class `elevation`: its row, or for the LoD chain with per-level tables the chain as drawn
    /// at `target` ([`Self::chain_at`]; its stored row is the chain at the default target).
    #[cfg(test)]
    fn measured(
        &self,
        elevation: Option<usize>,
        technique: Technique,
        height: f32,
        target: f32,
        usable: impl Fn(Technique) -> bool,
    ) -> Option<(f32, f32)> {
        let chain = (technique == Technique::LodChain).then(|| self.chain_at(elevation, height, target, usable));
        chain.flatten().or_else(|| self.at_elevation(elevation, technique, height))
    }

    /// `(error, primitives)` of the LoD chain drawn at `target` ([`Self::chain_level`], which
    /// picks by the tables over every view) at a projected height of `height` pixels, seen from
    /// elevation class `elevation` ([`Self::level_at_elevation`]; `None`: over every view);
    /// `None` without per-level tables.
    #[must_use]
    pub fn chain_at(
        &self,
        elevation: Option<usize>,
        height: f32,
        target: f32,
        usable: impl Fn(Technique) -> bool,
    ) -> Option<(f32, f32)> {
        self.drawn_as(elevation, self.chain_level(height, target, usable)?, height)
    }

    /// `(error, primitives)` of the LoD chain drawn as `pick` at a projected height of `height`
    /// pixels, seen from elevation class `elevation` ([`Self::chain_at`]).
    fn drawn_as(&self, elevation: Option<usize>, pick: ChainPick, height: f32) -> Option<(f32, f32)> {
        match pick {
            Some(level) => self.level_at_elevation(elevation, level, height),
            None => self.at_elevation(elevation, Technique::Full, height),
        }
    }

    /// The LoD chain's level at one height by image error (spec §10.2, module docs): among the
    /// full mesh and the chain's levels, the one of least primitives whose error is within
    /// `target` of the policy's floor over every view ([`Self::floor`] with `usable`), ties to
    /// the lower error, then the finer. Where none is within (the floor is set by a
    /// representation the chain cannot match, as the point tree keeps far leaves a mesh loses to
    /// the alpha test), the one of least primitives within `target` of the least error among
    /// them: the policy would not choose the chain there, and a chain drawn anyway keeps its best
    /// image for fewer triangles. By the tables over every view whatever the elevation a tree is
    /// seen from (the per-level tables are means over every view, spec §6.17), and, where the
    /// tables have rows per elevation, among the levels within the target of the floor from every
    /// elevation class too ([`Self::level_at_elevation`]; if there are any): one level is drawn
    /// whatever the elevation, so it must keep the image from each. `None` when the
    /// tables hold no chain levels (the chain then picks by geometric error,
    /// [`LodChain::pick`](crate::LodChain::pick)).
    #[must_use]
    pub fn chain_level(&self, height: f32, target: f32, usable: impl Fn(Technique) -> bool) -> Option<ChainPick> {
        if self.levels.is_empty() {
            return None;
        }
        self.chain_basis(height, usable).pick(target)
    }

    /// What [`Self::chain_level`] reads at one height whatever the target ([`ChainBasis`]):
    /// [`ChoiceBasis`] makes it once per height for every target.
    fn chain_basis(&self, height: f32, usable: impl Fn(Technique) -> bool) -> ChainBasis {
        let floors = Floors {
            by_class: (0..self.elevations.len()).map(|e| self.floor(Some(e), height, &usable)).collect(),
            all: self.floor(None, height, &usable),
            flip_all: self.flip_floor(None, height, &usable),
        };
        let flips = !self.level_flips.is_empty();
        let classes = floors.by_class.len();
        let candidate = |pick: ChainPick, (error, primitives): (f32, f32), order: usize| {
            let flip = if flips {
                match pick {
                    Some(level) => self.level_flip_at(level, height),
                    None => self.flip_at(None, Technique::Full, height),
                }
            } else {
                None
            };
            let by_class = (0..classes)
                .map(|e| {
                    let error = match pick {
                        Some(level) => self.level_at_elevation(Some(e), level, height),
                        None => self.at_elevation(Some(e), Technique::Full, height),
                    };
                    error.map(|(error, _)| error)
                })
                .collect();
            ChainCandidate { pick, error, primitives, order, flip, by_class }
        };
        // The full mesh first, then finest to coarsest.
        let full = self.at(Technique::Full, height).map(|ep| candidate(None, ep, 0));
        let levels = (0..self.levels.len()).filter_map(|i| {
            let level = u32::try_from(i).ok()?;
            Some(candidate(Some(level), self.level_at(level, height)?, i + 1))
        });
        let candidates: Vec<ChainCandidate> = full.into_iter().chain(levels).collect();
        let best = candidates.iter().map(|c| c.error).fold(f32::INFINITY, f32::min);
        let best_flip = candidates.iter().filter_map(|c| c.flip).fold(f32::INFINITY, f32::min);
        ChainBasis { candidates, floors, flips, best, best_flip }
    }
}

/// One technique judged at one height ([`Calibration::judge`]): its error, primitives and FLIP
/// error where the FLIP floor is checked.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    technique: Technique,
    error: f32,
    primitives: f32,
    flip: Option<f32>,
}

impl Candidate {
    /// An empty slot of [`Judged`].
    const NONE: Self = Self { technique: Technique::Full, error: f32::INFINITY, primitives: f32::INFINITY, flip: None };
}

/// The most candidates a [`Judged`] holds: one per technique.
const CANDIDATES: usize = Technique::ALL.len();

/// The techniques at one height and the floors they are judged against ([`Calibration::judge`]).
/// The candidates are held in place, not in a `Vec`: budget mode judges every height again for
/// each target it predicts (`Judged::with_candidate`), and allocating each copy was a tenth of
/// its choice tables' time.
#[derive(Debug)]
struct Judged {
    /// The candidates, the first [`Self::len`] of them ([`Self::candidates`]).
    slots: [Candidate; CANDIDATES],
    len: usize,
    floor: f32,
    flip_floor: f32,
    flip_checked: bool,
    /// The error allowed over the floor (sanitised).
    target: f32,
}

/// The floors at one height that [`Calibration::chain_level`] judges the chain's levels against.
#[derive(Debug)]
struct Floors {
    /// Per elevation class the tables hold, [`Calibration::floor`] there.
    by_class: Vec<f32>,
    /// [`Calibration::floor`] over every view.
    all: f32,
    /// [`Calibration::flip_floor`] over every view.
    flip_all: f32,
}

/// The full mesh or one of the LoD chain's levels at one height ([`ChainBasis`]).
#[derive(Debug)]
struct ChainCandidate {
    pick: ChainPick,
    /// Its error and primitives over every view.
    error: f32,
    primitives: f32,
    /// The order of ties: the full mesh first (0), then finest to coarsest.
    order: usize,
    /// Its FLIP error over every view, where the tables hold the levels' FLIP errors.
    flip: Option<f32>,
    /// Its error from each elevation class the tables hold ([`Calibration::level_at_elevation`]).
    by_class: Vec<Option<f32>>,
}

/// What [`Calibration::chain_level`] reads at one height whatever the target: the candidates'
/// errors (over every view, from each elevation class, FLIP) and the floors they are judged
/// against, each a lookup in the tables. Picking among them for a target
/// ([`ChainBasis::pick`]) is arithmetic: budget mode's tables for a new target
/// ([`ChoiceBasis`]) read these once per height instead of once per height and target.
#[derive(Debug)]
struct ChainBasis {
    candidates: Vec<ChainCandidate>,
    floors: Floors,
    /// Whether the tables hold the levels' FLIP errors.
    flips: bool,
    /// The least error and the least FLIP error among the candidates.
    best: f32,
    best_flip: f32,
}

impl ChainBasis {
    /// [`Calibration::chain_level`] at this height under `target`.
    fn pick(&self, target: f32) -> Option<ChainPick> {
        let target = sanitise(target);
        // Per elevation class, the limit there (the floor from that class plus the target).
        let limits: Vec<f32> = self.floors.by_class.iter().map(|floor| floor + target).collect();
        let floor = self.floors.all;
        // The FLIP limit of the same share as `limit` (the RMSE one) of `flip_floor` over `floor`.
        let flip_limit = |floor: f32, flip_floor: f32, limit: f32| {
            (self.flips && floor > 0.0 && floor.is_finite() && flip_floor.is_finite())
                .then(|| flip_floor + (limit - floor) * flip_floor / floor)
        };
        let cheapest_within = |limit: f32, everywhere: bool, flip_limit: Option<f32>| {
            self.candidates
                .iter()
                .filter(|c| {
                    c.error <= limit
                        && (!everywhere || Self::within_from_every_elevation(c, &limits))
                        && flip_limit.is_none_or(|l| c.flip.is_none_or(|f| f <= l))
                })
                .min_by(|a, b| {
                    a.primitives.total_cmp(&b.primitives).then(a.error.total_cmp(&b.error)).then(a.order.cmp(&b.order))
                })
        };
        let (best, best_flip) = (self.best, self.best_flip);
        let limit = floor + target;
        // With the levels' FLIP tables a level (or the full mesh) must also be within the same
        // share of the FLIP floor over every view, as the policy's rule asks of a technique
        // (module docs); a candidate without a FLIP error is judged by its RMSE alone. Where none
        // is, the same shares of the chain's own least errors, then its RMSE alone.
        let flip_at_floor = flip_limit(floor, self.floors.flip_all, limit);
        let flip_at_best = flip_limit(best, best_flip, best + target);
        cheapest_within(limit, true, flip_at_floor)
            .or_else(|| cheapest_within(limit, false, flip_at_floor))
            .or_else(|| cheapest_within(best + target, false, flip_at_best))
            .or_else(|| cheapest_within(best + target, false, None))
            .map(|c| c.pick)
    }

    /// Whether the chain drawn as candidate `c` is within `limits` from every elevation class
    /// the tables hold (per class, its floor plus the target; [`Calibration::level_at_elevation`],
    /// [`Calibration::floor`]); true without tables per elevation. One level is drawn whatever the
    /// elevation a tree is seen from, so it must keep the image from each: a level of every leaf
    /// and a quarter of the bark (spec §6.12) can be within the target over every view yet not
    /// from the side, where the trunk shows (the shared Quaternius tree at 256 pixels: 0.0060
    /// over every view, 0.0095 from 0° against a floor of 0.0050 there), and the policy would
    /// then draw the point tree where the full mesh keeps the image for less.
    fn within_from_every_elevation(c: &ChainCandidate, limits: &[f32]) -> bool {
        limits.iter().zip(&c.by_class).all(|(&limit, error)| error.is_none_or(|error| error <= limit))
    }
}

impl Judged {
    /// These judgements ([`Calibration::judge_but_chain`]) under `target` at `height` from
    /// elevation class `elevation`, with the LoD chain drawn as `chain` says: `None` where it is
    /// not usable, else [`Calibration::chain_level`]'s pick there.
    fn with_chain(
        &self,
        calibration: &Calibration,
        elevation: Option<usize>,
        height: f32,
        target: f32,
        chain: Option<Option<ChainPick>>,
    ) -> Self {
        let candidate = chain.and_then(|pick| calibration.chain_candidate(elevation, height, pick, self.flip_checked));
        self.with_candidate(target, candidate)
    }

    /// These judgements under `target` with the LoD chain judged as `chain` (`None`: not
    /// usable, or not in the tables).
    fn with_candidate(&self, target: f32, chain: Option<Candidate>) -> Self {
        let mut judged = Self { target: sanitise(target), ..*self };
        chain.into_iter().for_each(|c| judged.push(c));
        judged
    }

    /// The candidates.
    fn candidates(&self) -> &[Candidate] {
        &self.slots[..self.len]
    }

    /// Adds `candidate` (at most one per technique: [`CANDIDATES`] in all).
    fn push(&mut self, candidate: Candidate) {
        self.slots[self.len] = candidate;
        self.len += 1;
    }

    /// Whether `c` is within the target of the floor, and with FLIP tables within the same share
    /// of the FLIP floor.
    fn within(&self, c: &Candidate) -> bool {
        c.error <= self.floor + self.target
            && c.flip.is_none_or(|f| f <= self.flip_floor + self.target * self.flip_floor / self.floor)
    }

    /// The order of the candidates within the target: least primitives, then lower error, then
    /// the technique's order.
    fn cheaper(a: &Candidate, b: &Candidate) -> std::cmp::Ordering {
        a.primitives.total_cmp(&b.primitives).then(a.error.total_cmp(&b.error)).then(a.technique.cmp(&b.technique))
    }

    /// The candidate within the target of least primitives (ties: lower error); none within: the
    /// least error, or with FLIP tables the least share over the floors (the larger of the two).
    fn chosen(&self) -> Option<&Candidate> {
        let cheapest = self.candidates().iter().filter(|c| self.within(c)).min_by(|a, b| Self::cheaper(a, b));
        let excess = |c: &Candidate| {
            let over = (c.error - self.floor) / self.floor;
            c.flip.map_or(over, |f| over.max((f - self.flip_floor) / self.flip_floor.max(f32::MIN_POSITIVE)))
        };
        let key = |c: &Candidate| if self.flip_checked { excess(c) } else { c.error };
        let best = || {
            self.candidates().iter().min_by(|a, b| {
                key(a)
                    .total_cmp(&key(b))
                    .then(a.primitives.total_cmp(&b.primitives))
                    .then(a.technique.cmp(&b.technique))
            })
        };
        cheapest.or_else(best)
    }

    /// The rule's choice; [`Technique::FALLBACK`] when no technique is left.
    fn choice(&self) -> Technique {
        self.chosen().map_or(Technique::FALLBACK, |c| c.technique)
    }

    /// The primitives of `technique` where it is among [`Self::admissible`] (without sorting
    /// them or making the list: [`merge_short_runs`] reads a few of them per table).
    fn admissible_primitives(&self, technique: Technique) -> Option<f32> {
        if self.candidates().iter().any(|c| self.within(c)) {
            self.candidates().iter().find(|c| c.technique == technique && self.within(c)).map(|c| c.primitives)
        } else {
            self.chosen().filter(|c| c.technique == technique).map(|c| c.primitives)
        }
    }

    /// The candidates within the target with their primitives, least first; none within: the
    /// choice alone ([`Calibration::admissible_at_elevation`]).
    fn admissible(&self) -> Vec<(Technique, f32)> {
        let mut within: Vec<&Candidate> = self.candidates().iter().filter(|c| self.within(c)).collect();
        within.sort_by(|a, b| Self::cheaper(a, b));
        if within.is_empty() {
            return self.chosen().map(|c| vec![(c.technique, c.primitives)]).unwrap_or_default();
        }
        within.into_iter().map(|c| (c.technique, c.primitives)).collect()
    }
}

/// The steps of a model's tables of choices ([`Choices`], [`ChainChoices`]): every
/// [`STEPS_PER_OCTAVE`]-th of an octave of projected height from the smallest calibrated height
/// to the largest.
struct StepGrid {
    /// `log2` of the smallest calibrated height.
    log2_min: f32,
    /// Steps, the first at the smallest height and the last at the largest.
    count: usize,
}

impl StepGrid {
    /// The steps over `calibration`'s heights ([`Calibration::heights`]; one step where they do
    /// not span a range).
    fn of(calibration: &Calibration) -> Self {
        let (min, max) = calibration.heights();
        let (log2_min, log2_max) = (min.log2(), max.log2());
        let octaves = if log2_max.is_finite() && log2_min.is_finite() { (log2_max - log2_min).max(0.0) } else { 0.0 };
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a few octaves")]
        let count = (octaves * STEPS_PER_OCTAVE).round() as usize + 1;
        Self { log2_min, count }
    }

    /// The projected height of step `i`, pixels.
    fn height(&self, i: usize) -> f32 {
        height_of_step(self.log2_min, i)
    }

    /// Where [`step_of`] measures from: `log2` of the smallest height, 0 where that is not finite.
    fn origin(&self) -> f32 {
        if self.log2_min.is_finite() { self.log2_min } else { 0.0 }
    }
}

/// Steps either side of a tree's height within which it keeps last frame's choice under
/// `policy` ([`Policy::hysteresis`], at most 8 octaves).
fn hysteresis_steps(policy: &Policy) -> usize {
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a few octaves")]
    let steps = (policy.hysteresis().min(8.0) * STEPS_PER_OCTAVE).round() as usize;
    steps
}

/// Where `height` falls on a table of choices whose step 0 is at `log2_min` (`log2` of the
/// smallest calibrated height), fractional, [`STEPS_PER_OCTAVE`] steps per octave.
fn step_of(log2_min: f32, height: f32) -> f32 {
    (height.max(f32::MIN_POSITIVE).log2() - log2_min) * STEPS_PER_OCTAVE
}

/// The projected height, pixels, of step `i` of a table of choices whose step 0 is at `log2_min`
/// ([`step_of`]'s inverse at whole steps).
fn height_of_step(log2_min: f32, i: usize) -> f32 {
    #[expect(clippy::cast_precision_loss, reason = "a few dozen steps")]
    let octaves = i as f32 / STEPS_PER_OCTAVE;
    (log2_min + octaves).exp2()
}

/// The hysteresis of a table of choices read at step `x` by `at` (module docs): `previous`
/// (last frame's choice) where it is the choice within `hysteresis_steps` steps either side of
/// `x`, else the choice at `x`.
fn held<T: Copy + PartialEq>(at: impl Fn(f32) -> T, x: f32, hysteresis_steps: usize, previous: Option<T>) -> T {
    let now = at(x);
    if let Some(previous) = previous
        && previous != now
    {
        #[expect(clippy::cast_precision_loss, reason = "a few dozen steps")]
        let within = (1..=hysteresis_steps).any(|k| at(x - k as f32) == previous || at(x + k as f32) == previous);
        if within {
            return previous;
        }
    }
    now
}

/// A model's LoD chain levels under one policy, every [`STEPS_PER_OCTAVE`]-th of an octave of
/// projected height over its calibrated range ([`Calibration::chain_level`] at each step): what
/// [`ChainChoices::choose`] looks up per tree drawn with the chain. In budget mode one table per
/// target class of the lattice the policy's target falls in ([`TreeDither`], [`lattice_cell`]),
/// as [`Choices`] holds them: the same for every target within the cell.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainChoices {
    /// `log2` of the smallest calibrated height.
    log2_min: f32,
    /// Per target class (one without a budget), the level at `log2_min + i / STEPS_PER_OCTAVE`,
    /// up to the largest calibrated height.
    steps: Vec<Vec<ChainPick>>,
    /// Steps either side within which a tree keeps last frame's level.
    hysteresis_steps: usize,
}

impl ChainChoices {
    /// The chain's levels of a model with `calibration` under `policy` (its target, allowed at
    /// each height as [`target_at`] says, and its hysteresis; in budget mode the targets of the
    /// lattice cell it falls in, [`lattice_cell`]), the floor over the techniques `usable`
    /// accepts; `None` when the tables hold no chain levels.
    #[must_use]
    pub fn new(calibration: &Calibration, policy: &Policy, usable: impl Fn(Technique) -> bool) -> Option<Self> {
        if calibration.levels.is_empty() {
            return None;
        }
        let grid = StepGrid::of(calibration);
        let cell = policy.budget.is_some().then(|| lattice_cell(policy.target()).0);
        let steps = class_targets(policy.target(), 1, cell)
            .into_iter()
            .map(|target| {
                (0..grid.count)
                    .map(|i| {
                        let height = grid.height(i);
                        calibration.chain_level(height, target_at(target, height), &usable).flatten()
                    })
                    .collect()
            })
            .collect();
        Some(Self { log2_min: grid.origin(), steps, hysteresis_steps: hysteresis_steps(policy) })
    }

    /// The level for a tree `height` pixels high whose level last frame was `previous` (`None`:
    /// none, the tree was not drawn with the chain): last frame's if it is the level within the
    /// hysteresis of `height`, else the level at `height`. Below the calibrated range the
    /// smallest height's level holds; above it the finer of the largest height's level and
    /// `geometric` (the level by geometric error, [`LodChain::pick`](crate::LodChain::pick)), so
    /// that a tree coming nearer than the tables reach converges to the full mesh. In budget
    /// mode, under the lattice target nearest the policy's.
    #[must_use]
    pub fn choose(&self, height: f32, previous: Option<ChainPick>, geometric: impl FnOnce() -> ChainPick) -> ChainPick {
        self.choose_in(height, self.steps.len() / 2, previous, geometric)
    }

    /// [`Self::choose`] for a tree of target class `class` ([`TreeDither::apply`], which also
    /// gives the height it is chosen at): in budget mode, trees at like heights whose levels
    /// follow the tables' largest height (all the trees nearer than the tables reach) switch
    /// level at targets of their own, not all at one. Measured on 1,000 willows (`bench
    /// --budget 100000 --seed 1`, frame 146): fourteen trees from 322 to 817 pixels high went
    /// from the chain's 1,427-triangle level to its 7,280-triangle one in one step of the
    /// steering, the frame's count from 37,917 primitives to 119,861.
    #[must_use]
    pub fn choose_in(
        &self,
        height: f32,
        class: usize,
        previous: Option<ChainPick>,
        geometric: impl FnOnce() -> ChainPick,
    ) -> ChainPick {
        let steps = &self.steps[class.min(self.steps.len() - 1)];
        let x = step_of(self.log2_min, height);
        let last = steps.len() - 1;
        #[expect(clippy::cast_precision_loss, reason = "a few dozen steps")]
        if x > last as f32 + 0.5 {
            return finer(steps[last], geometric());
        }
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to the table")]
        let at = |i: f32| steps[(i.round().max(0.0) as usize).min(last)];
        held(at, x, self.hysteresis_steps, previous)
    }

    /// The level at each step, smallest height first (for tests and panels); in budget mode
    /// under the lattice target nearest the policy's.
    #[must_use]
    pub fn steps(&self) -> &[ChainPick] {
        &self.steps[self.steps.len() / 2]
    }
}

/// A model's choices under one policy, every [`STEPS_PER_OCTAVE`]-th of an octave of projected
/// height over its calibrated range (module docs): what [`Choices::choose`] looks up per tree —
/// one table per elevation class of the calibration's views (one over every view without tables
/// per elevation) and per visibility class (one without [`Policy::occlusion`]), each with its runs
/// shorter than [`SHORTEST_RUN_STEPS`] merged into a neighbour where [`MERGE_COST`] allows (module
/// docs, *Short runs*).
#[derive(Clone, Debug, PartialEq)]
pub struct Choices {
    /// `log2` of the smallest calibrated height.
    log2_min: f32,
    /// Per elevation class, then visibility class (`e · visibility + k`). Visibility class `k`
    /// (a visible fraction about `2^-k`) is chosen with the target raised to `target / √(2^-k)`.
    tables: Vec<Table>,
    /// The elevations of the classes' views, degrees, ascending; empty: one class, every view.
    elevations: Vec<f32>,
    /// Visibility classes per elevation class: [`VISIBILITY_CLASSES`] with
    /// [`Policy::occlusion`], else 1.
    visibility: usize,
    /// Per visibility class, the tables of the lowest elevation class among the techniques that
    /// are not [`upper_hemisphere_only`], for a tree seen from below the tables
    /// ([`Self::below_horizon`]); empty where that changes nothing (no such technique usable, or
    /// fewer than two elevation classes).
    below: Vec<Table>,
    /// Steps either side within which a tree keeps last frame's technique.
    hysteresis_steps: usize,
    /// Per elevation class, the technique its tables choose below a height, and that height
    /// ([`Self::uniform_below_in`]; [`Self::uniform_below`] follows from them).
    uniform_by_class: Vec<Option<(f32, Technique)>>,
    /// How budget mode varies each tree's choice ([`Self::dither`]): in budget mode where the
    /// target falls on the lattice of targets, the cell of the first target class's tables and
    /// the fraction of a step past it; the number of target classes follows from it
    /// ([`Self::dithers`]).
    dither: TreeDither,
}

/// The elevation class (an index for [`Choices::choose_framed`]) of a tree seen from below the
/// calibration's views by more than half the classes' spacing ([`Choices::below_horizon`]): the
/// lowest class's tables without the techniques whose representations hold only the upper
/// hemisphere ([`upper_hemisphere_only`]).
pub const BELOW_HORIZON: usize = usize::MAX;

/// In budget mode, the octaves either side of its projected height a tree is chosen at
/// ([`Choices::dither`]): two of the tables' steps ([`STEPS_PER_OCTAVE`]).
///
/// One model's trees at like distances switch representation at one target, and the frame's
/// count falls off a cliff there: budget mode then holds far under the budget rather than
/// draw a frame many times over it (spec §10.2). With each tree chosen at its height times a
/// factor of its own, the trees at one height switch over a range of targets, and the count
/// falls in smaller steps. Measured (`bench --trees 1000 --frames 300 --budget 100000
/// --no-render`, every shared model, seeds 1 and 2: 4,200 frames), none → two steps → four:
/// frames within ½–1.1 times the budget 3,143 → 3,255 → 3,289, under half of it 830 → 707 →
/// 648, over 1.1 times it 227 → 238 → 263 (the primitives over it summed 8.72 → 9.39 → 9.78
/// million); one step: 3,154, 792 and 254.
pub const BUDGET_DITHER_OCTAVES: f32 = 2.0 / STEPS_PER_OCTAVE;

/// In budget mode, the octaves between the targets of the lattice trees are chosen under
/// ([`Choices::dither`], [`lattice_cell`]): a quarter.
///
/// Where a technique's error hardly changes with height, a factor on the height
/// ([`BUDGET_DITHER_OCTAVES`]) does not spread the trees' switches: the shared willow's
/// octahedral impostor reads 0.070–0.075 from 4 to 64 pixels, its impostor planes 0.061–0.072,
/// so its 1,000 trees seen from afar switched between them within 4 % of target, and the count
/// went from 6,900 primitives to 190,800 in one step of the steering (a frame far under the
/// budget or twice over it). Each tree is therefore chosen under a target of its own: the
/// policy's target rounded to this lattice, down or up by a share of the tree's own (a hash of
/// where it stands) and spread over [`BUDGET_TARGET_SPREAD`] steps, so that as the target moves
/// the trees move to the next lattice target one at a time, each at a target of its own. The
/// tables are made for the lattice's targets, so the targets within one step share them
/// (budget mode's predictions and steering move the target by a few percent at a time).
///
/// Measured (`bench --trees 1000 --frames 300 --budget 100000 --no-render`, every shared model,
/// seeds 1 and 2: 4,200 frames; the `assign` phase's mean on 2 cores), steps of an eighth / a
/// sixth / a quarter of an octave over a spread of 1, 2, 3 or 4 of them, against none: within
/// ½–1.1 times the budget 3,393 without; an eighth over 2 steps 3,501, over 4 steps 3,566; a
/// sixth over 3 steps 3,540; a quarter over 2 steps 3,545, over 4 steps 3,606 (a tree's
/// target then up to 2^±0.75 off the policy's); under half the budget 734 → 631, 563, 594, 585
/// and 517; over 1.1 times it 73 → 68, 71, 66, 70 and 77; `assign` 0.69 ms → 0.68, 0.82–0.92,
/// 0.74, 0.57 and 0.63 (targets within a cell share the tables). A quarter over 2 steps (3
/// tables per class) taken; an eighth over 4 (5 tables) drew the four-model forest's frames
/// (`--budget 300000`) with `assign` at 2.60–2.70 ms against 1.67 ms.
pub const BUDGET_TARGET_STEP: f32 = 0.25;

/// In budget mode, the steps of [`BUDGET_TARGET_STEP`] over which the trees' targets are spread
/// ([`lattice_cell`]): a tree's target is within `spread/2 + 1` steps of the policy's (half an
/// octave), and the choices hold `spread + 1` tables per class.
pub const BUDGET_TARGET_SPREAD: usize = 2;

/// What a model's [`Choices`]' tables depend on ([`Choices::tables_key`]): the policy, in budget
/// mode with its target replaced by 0 beside the cell of the lattice of targets it falls in.
pub type TablesKey = (Policy, i32);

// The middle target class is the policy's own (`Choices::target_class`).
const _: () = assert!(BUDGET_TARGET_SPREAD.is_multiple_of(2), "an even spread");

/// How budget mode varies each tree's choice under one policy ([`Choices::dither`],
/// [`ChainChoices::choose_in`]): a factor on its height of up to [`BUDGET_DITHER_OCTAVES`] either
/// way and a target of its own on the lattice of targets; without a budget, neither.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TreeDither {
    /// In budget mode, the lattice cell and fraction of the policy's target ([`lattice_cell`]).
    cell: Option<(i32, f32)>,
}

impl TreeDither {
    /// No dither: every tree at its own height, under the policy's target.
    pub const NONE: Self = Self { cell: None };

    /// The dither of `policy`: its target's [`lattice_cell`] in budget mode, else none.
    #[must_use]
    pub fn of(policy: &Policy) -> Self {
        Self { cell: policy.budget.is_some().then(|| lattice_cell(policy.target())) }
    }

    /// `log2` of the largest factor a tree's height is chosen at: [`BUDGET_DITHER_OCTAVES`] in
    /// budget mode, else 0.
    fn octaves(self) -> f32 {
        if self.cell.is_some() { BUDGET_DITHER_OCTAVES } else { 0.0 }
    }

    /// Target classes ([`class_targets`]): [`BUDGET_TARGET_SPREAD`]` + 1` in budget mode, else 1.
    fn classes(self) -> usize {
        if self.cell.is_some() { BUDGET_TARGET_SPREAD + 1 } else { 1 }
    }

    /// The target class whose lattice target lies nearest the policy's own (within half a
    /// lattice step): in budget mode the middle one whatever the fraction, since the classes'
    /// `log2` targets average the policy's ([`lattice_cell`]; the spread is even); otherwise 0,
    /// the policy's target.
    fn nearest_class(self) -> usize {
        if self.cell.is_some() { BUDGET_TARGET_SPREAD / 2 } else { 0 }
    }

    /// The height a tree `height` pixels high placed by `transform` is chosen at, and its
    /// target class: `height` times a factor of the tree's own, `2^(±octaves)` at most, and
    /// the class of the lattice target its share rounds the policy's target to, both drawn from
    /// where it stands (the translation's bits, so the same every frame and in every view);
    /// without a budget `height` and class 0.
    #[must_use]
    pub fn apply(&self, height: f32, transform: &Mat4) -> (f32, usize) {
        if self.cell.is_none() {
            return (height, 0);
        }
        let t = transform.w_axis;
        let key = (u64::from(t.x.to_bits()) << 32) ^ u64::from(t.z.to_bits()) ^ (u64::from(t.y.to_bits()) << 16);
        let bits = treelod_format::SplitMix64(key).next_u64();
        // The top 24 bits for the height (uniform in [0, 1)), the low 32 for the class.
        #[expect(clippy::cast_precision_loss, reason = "24 bits")]
        let u = (bits >> 40) as f32 / (1u64 << 24) as f32;
        // The low 32 bits, a share in [0, 1), spread over the lattice's steps past the cell.
        #[expect(clippy::cast_precision_loss, reason = "a share")]
        let share = (bits & 0xFFFF_FFFF) as f32 / (1u64 << 32) as f32;
        let class = self.cell.map_or(0, |(_, fraction)| {
            #[expect(
                clippy::cast_precision_loss,
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss,
                reason = "a few steps"
            )]
            let j = (fraction + share * BUDGET_TARGET_SPREAD as f32).floor().max(0.0) as usize;
            j.min(BUDGET_TARGET_SPREAD)
        });
        (height * ((2.0 * u - 1.0) * self.octaves()).exp2(), class)
    }
}

/// Where `target` falls on budget mode's lattice of targets (`2^(k · BUDGET_TARGET_STEP)`): the
/// cell `k` of the lowest target its trees are chosen under and the fraction `f ∈ [0, 1)` of a
/// step past it. A tree whose share is `u ∈ [0, 1)` is chosen under the lattice target
/// `k + ⌊f + u · BUDGET_TARGET_SPREAD⌋`, whose `log2` is `log2(target)` on average over the
/// trees: the cell is placed half the spread less half a step below it.
#[must_use]
pub fn lattice_cell(target: f32) -> (i32, f32) {
    #[expect(clippy::cast_precision_loss, reason = "a few steps")]
    let half = BUDGET_TARGET_SPREAD as f32 / 2.0 - 0.5;
    let x = sanitise(target).max(f32::MIN_POSITIVE).log2() / BUDGET_TARGET_STEP - half;
    let k = x.floor();
    #[expect(clippy::cast_possible_truncation, reason = "log2 of an f32 over a step: within i32")]
    (k as i32, (x - k).clamp(0.0, 1.0 - f32::EPSILON))
}

/// The targets of [`Choices`]' classes under `target`: per visibility class `k` (outer) the
/// target raised to `target / √(2^-k)`; in budget mode (`cell`, [`lattice_cell`]) per target
/// class `j` (inner) the lattice target `2^((cell + j) · BUDGET_TARGET_STEP)` raised so, `j` up
/// to [`BUDGET_TARGET_SPREAD`].
#[must_use]
fn class_targets(target: f32, visibility: usize, cell: Option<i32>) -> Vec<f32> {
    #[expect(clippy::cast_precision_loss, reason = "a few classes")]
    let raise = |k: usize| (k as f32 * 0.5).exp2();
    match cell {
        None => (0..visibility).map(|k| target * raise(k)).collect(),
        Some(cell) => (0..visibility)
            .flat_map(|k| {
                #[expect(clippy::cast_precision_loss, clippy::cast_possible_wrap, reason = "a few steps")]
                let lattice = move |j: usize| ((cell + j as i32) as f32 * BUDGET_TARGET_STEP).exp2();
                (0..=BUDGET_TARGET_SPREAD).map(move |j| lattice(j) * raise(k))
            })
            .collect(),
    }
}

/// Whether technique `t`'s representation shows a tree only from the upper hemisphere: the
/// octahedral impostor, whose views (spec §6.13.1) are all taken from above the horizon and which
/// draws a tree seen from below with the horizon's views. Seen from below, the lowest
/// elevation's tables (0° for the build's) do not describe it: measured with `eval --path` on
/// the shared pine at 8 radii (640×480), its RMSE against the point tree's is ×0.99 from the
/// side, ×1.64 from 12° below and ×2.19 from 25° below (at 3 radii ×1.94, ×2.09 and ×3.10).
#[must_use]
pub fn upper_hemisphere_only(t: Technique) -> bool {
    t == Technique::Octahedral
}

/// One table of [`Choices`].
#[derive(Clone, Debug, PartialEq)]
struct Table {
    /// Above the calibrated range, for a tree wholly in view: the choice at the largest height if
    /// it converges to the full mesh ([`converges`]), else the rule's choice there among those
    /// that do (module docs).
    above: Technique,
    /// The primitives of [`Self::above`] and of the point tree at the largest height (whole
    /// trees), for trees partly in view.
    above_cost: (f32, f32),
    /// The choice at `log2_min + i / STEPS_PER_OCTAVE`, up to the largest calibrated height,
    /// short runs merged.
    steps: Vec<Technique>,
}

/// The elevation class of a view `elevation` degrees above a tree's horizontal plane among
/// classes whose views are at `centres` degrees (ascending, at least one) for a tree of class
/// `previous` last frame (`None`: a new tree): the nearest centre for a new tree (a view from
/// below counts as from the side); else the class changes only once `elevation` lies a quarter of
/// the spacing of two classes past the midpoint between them, so a camera hovering at a bound
/// does not switch trees back and forth.
#[must_use]
pub fn elevation_class_after(previous: Option<usize>, elevation: f32, centres: &[f32]) -> usize {
    let last = centres.len().saturating_sub(1);
    let elevation = if elevation.is_finite() { elevation } else { 0.0 };
    let bound = |lower: usize, sign: f32| class_bound(centres, lower, sign);
    match previous.map(|p| p.min(last)) {
        None => (0..last).take_while(|&c| elevation >= bound(c, 0.0)).count(),
        Some(p) => {
            let up = (p..last).take_while(|&c| elevation >= bound(c, 1.0)).count();
            let down = (0..p).rev().take_while(|&c| elevation <= bound(c, -1.0)).count();
            p + up - down
        }
    }
}

/// The bound of [`elevation_class_after`] between classes `lower` and `lower + 1` of `centres`:
/// their midpoint (`sign` 0), or a quarter of their spacing past it upwards (`sign` 1, where a
/// tree of the lower class moves up) or downwards (`sign` −1, where one of the upper moves down).
fn class_bound(centres: &[f32], lower: usize, sign: f32) -> f32 {
    let (a, b) = (centres[lower], centres[lower + 1]);
    0.5 * (a + b) + sign * 0.25 * (b - a)
}

/// How far inside a class's bounds, in the sine of the elevation, the chooser takes a tree's
/// class from the sine alone (`Choices::stay_bands`): a ten-thousandth, over a hundred times the
/// rounding of the arc sine and of the bounds' sines, so the class is the one the elevation in
/// degrees gives.
const STAY_MARGIN: f32 = 1e-4;

/// Classes of elevation the policy chooses by per span between two calibrated elevations
/// ([`Calibration::with_elevations_between`]): with the build's 0°, 30°, 60° and 90°, classes
/// every 10°, so a view is at most 5° from its class's tables and blends the measured ones by
/// its elevation.
pub const ELEVATION_SUBDIVISIONS: usize = 3;

/// The projected height, pixels, up to which a tree is allowed the whole [`Policy::target`] over
/// the floor; a larger tree is allowed `target · TARGET_HEIGHT / h` ([`target_at`], module docs).
pub const TARGET_HEIGHT: f32 = 64.0;

/// The error a tree `height` pixels high is allowed over the floor under `target` (module docs):
/// `target` up to [`TARGET_HEIGHT`], then `target · TARGET_HEIGHT / height`, so no tree adds more
/// squared error to the frame than a tree [`TARGET_HEIGHT`] pixels high at the target. Not
/// finite or not positive `height`: `target`.
#[must_use]
pub fn target_at(target: f32, height: f32) -> f32 {
    if height.is_finite() && height > TARGET_HEIGHT { target * (TARGET_HEIGHT / height) } else { target }
}

/// Classes of the visible fraction `v` the policy chooses by ([`Policy::occlusion`]): about 1,
/// ½, ¼ and ⅛, split at their geometric midpoints.
pub const VISIBILITY_CLASSES: usize = 4;

/// The visibility class of a visible fraction (0 for fully visible; not finite: 0).
#[must_use]
pub fn visibility_class(visible: f32) -> usize {
    let v = if visible.is_finite() { visible } else { 1.0 };
    // Class k stands for v = 2^-k; its lower bound is 2^-(k + 1/2).
    let lower = &class_bounds().lower;
    (0..VISIBILITY_CLASSES - 1).find(|&k| v >= lower[k]).unwrap_or(VISIBILITY_CLASSES - 1)
}

/// The visibility class of a tree of class `previous` last frame whose visible fraction is now
/// `visible`: it changes only once `visible` lies a quarter of a class (an eighth of an octave
/// of `v`) past the bound it crosses, so a measurement that wavers at a bound (the samples of a
/// tree moving behind leaves) does not switch the tree back and forth.
#[must_use]
pub fn visibility_class_after(previous: usize, visible: f32) -> usize {
    let now = visibility_class(visible);
    let v = if visible.is_finite() { visible } else { 1.0 };
    let bounds = class_bounds();
    #[expect(clippy::cast_precision_loss, reason = "a few classes")]
    let bound = |table: &[f32; VISIBILITY_CLASSES], offset: f32| {
        table.get(previous).copied().unwrap_or_else(|| (-(previous as f32) + offset).exp2())
    };
    let far_enough = match now.cmp(&previous) {
        std::cmp::Ordering::Greater => v < bound(&bounds.down, -0.75),
        std::cmp::Ordering::Less => v >= bound(&bounds.up, 0.75),
        std::cmp::Ordering::Equal => true,
    };
    if far_enough { now } else { previous }
}

/// The bounds [`visibility_class`] and [`visibility_class_after`] compare a visible fraction
/// with, per class `k`: `2^-(k + 1/2)`, `2^-(k + 3/4)` and `2^-(k − 3/4)`. Computed once with
/// [`f32::exp2`] as the rules state them (the same bits), where the chooser took three or more
/// `exp2` a tree every frame.
struct ClassBounds {
    lower: [f32; VISIBILITY_CLASSES],
    down: [f32; VISIBILITY_CLASSES],
    up: [f32; VISIBILITY_CLASSES],
}

fn class_bounds() -> &'static ClassBounds {
    static BOUNDS: std::sync::OnceLock<ClassBounds> = std::sync::OnceLock::new();
    BOUNDS.get_or_init(|| {
        // `-k + offset` is `-k - |offset|` for a negative offset, to the bit.
        #[expect(clippy::cast_precision_loss, reason = "a few classes")]
        let at = |offset: f32| std::array::from_fn(|k| (-(k as f32) + offset).exp2());
        ClassBounds { lower: at(-0.5), down: at(-0.75), up: at(0.75) }
    })
}

/// What a model's tables of choices ([`Choices::among`]) read from its calibration whatever the
/// policy: the calibration with its elevation classes ([`Calibration::with_elevations_between`]),
/// the heights of the tables' steps, and at each step every technique's judgement but the LoD
/// chain's (its errors and the floors, [`Calibration::floor`]) and what picking the chain's
/// level reads (its levels' errors from every elevation class). [`Choices::from_basis`] then
/// makes the tables for a policy from these alone: budget mode makes a model's choices again
/// each time its target moves, and a host keeps one basis per model for every target.
///
/// Measured on the shared models' containers with every representation (release, 2 cores, the
/// mean of 100 makings at 100 targets): [`Choices::new`] took 1.5–2.2 ms a model when it read
/// the tables again for every target; from a basis the tables take 0.15–0.20 ms, and the basis
/// about 1 ms, once (the same tables: a digest of the choices over 8 targets, with and without
/// occlusion, among two sets of techniques, on the seven containers).
#[derive(Debug)]
pub struct ChoiceBasis {
    /// The calibration with its elevation classes.
    calibration: Calibration,
    /// `log2` of the smallest calibrated height ([`StepGrid::origin`]).
    log2_min: f32,
    /// The steps' heights, pixels.
    heights: Vec<f32>,
    /// Among the techniques the host can draw.
    all: Judgements,
    /// Among those that are not [`upper_hemisphere_only`], from the lowest elevation class: the
    /// tables for a tree seen from below ([`Choices::below_horizon`]); `None` where that changes
    /// nothing.
    below: Option<Judgements>,
}

impl ChoiceBasis {
    /// The basis of a model with `calibration` whose representations are `representations`
    /// ([`Representations::holds`]).
    #[must_use]
    pub fn new(calibration: &Calibration, representations: &Representations) -> Self {
        Self::among(calibration, |t| representations.holds(t))
    }

    /// [`Self::new`] among the techniques `usable` accepts.
    #[must_use]
    pub fn among(calibration: &Calibration, usable: impl Fn(Technique) -> bool) -> Self {
        let calibration = calibration.with_elevations_between(ELEVATION_SUBDIVISIONS);
        let grid = StepGrid::of(&calibration);
        let heights: Vec<f32> = (0..grid.count).map(|i| grid.height(i)).collect();
        let elevations = calibration.elevations().len();
        let classes: Vec<Option<usize>> =
            if elevations == 0 { vec![None] } else { (0..elevations).map(Some).collect() };
        // `usable` read once per technique, so that the judgements are made in parallel.
        let usable = PerTechnique(Technique::ALL.map(usable));
        let all = Judgements::new(&calibration, &heights, classes, usable);
        let below = (elevations >= 2 && Technique::ALL.into_iter().any(|t| upper_hemisphere_only(t) && usable[t]))
            .then(|| {
                let above_only = PerTechnique(Technique::ALL.map(|t| usable[t] && !upper_hemisphere_only(t)));
                Judgements::new(&calibration, &heights, vec![Some(0)], above_only)
            });
        Self { log2_min: grid.origin(), calibration, heights, all, below }
    }
}

/// [`ChoiceBasis`] among one set of techniques.
#[derive(Debug)]
struct Judgements {
    /// The techniques judged.
    usable: PerTechnique<bool>,
    /// The elevation classes of the tables (`None`: one, every view).
    classes: Vec<Option<usize>>,
    /// Per class, per height: [`Calibration::judge_but_chain`].
    judged: Vec<Vec<Judged>>,
    /// Per height, what picking the chain's level reads ([`Calibration::chain_basis`]); empty
    /// where the chain is not usable or the tables hold no levels.
    chain: Vec<ChainBasis>,
    /// Per class, per height, the chain judged as each pick it can be drawn as
    /// ([`Calibration::chain_candidate`], at [`pick_index`]); empty where it is not usable.
    chain_judged: Vec<Vec<Vec<Option<Candidate>>>>,
    /// Per class, at the largest height, [`Calibration::judge_but_chain`] among the techniques
    /// that converge ([`converges`]): what a table holds above the tables where its last step
    /// does not converge.
    converging: Vec<Judged>,
    /// [`Self::chain`] at the largest height among the techniques that converge.
    converging_chain: Option<ChainBasis>,
}

/// Where [`Judgements::chain_judged`] keeps the LoD chain judged as `pick`: 0 for none (the
/// chain's own row), 1 for the full mesh, `2 + l` for level `l`.
fn pick_index(pick: Option<ChainPick>) -> usize {
    match pick {
        None => 0,
        Some(None) => 1,
        Some(Some(level)) => 2 + level as usize,
    }
}

impl Judgements {
    /// The judgements of `calibration` at `heights` from `classes` among `usable`, made in
    /// parallel, each alone, so the same whatever the thread count.
    fn new(
        calibration: &Calibration,
        heights: &[f32],
        classes: Vec<Option<usize>>,
        usable: PerTechnique<bool>,
    ) -> Self {
        let judge = |t: Technique| usable[t];
        let judged = classes
            .par_iter()
            .map(|&e| heights.iter().map(|&h| calibration.judge_but_chain(e, h, judge)).collect())
            .collect();
        let chain = if usable[Technique::LodChain] && calibration.chain_levels() > 0 {
            heights.par_iter().map(|&h| calibration.chain_basis(h, judge)).collect()
        } else {
            Vec::new()
        };
        let chain_judged = if usable[Technique::LodChain] {
            #[expect(clippy::cast_possible_truncation, reason = "a chain has a few levels")]
            let picks: Vec<Option<ChainPick>> = [None, Some(None)]
                .into_iter()
                .chain((0..calibration.chain_levels() as u32).map(|l| Some(Some(l))))
                .collect();
            classes
                .par_iter()
                .zip(&judged)
                .map(|(&e, judged): (&Option<usize>, &Vec<Judged>)| {
                    let each = |(&h, j): (&f32, &Judged)| {
                        picks.iter().map(|&pick| calibration.chain_candidate(e, h, pick, j.flip_checked)).collect()
                    };
                    heights.iter().zip(judged).map(each).collect()
                })
                .collect()
        } else {
            Vec::new()
        };
        let top = heights.last().copied().unwrap_or(1.0);
        let converging_usable = |t: Technique| converges(t) && usable[t];
        let converging = classes.iter().map(|&e| calibration.judge_but_chain(e, top, converging_usable)).collect();
        let converging_chain = (converging_usable(Technique::LodChain) && calibration.chain_levels() > 0)
            .then(|| calibration.chain_basis(top, converging_usable));
        Self { usable, classes, judged, chain, chain_judged, converging, converging_chain }
    }

    /// The tables for each class (outer) and each of `targets` (visibility classes, inner) of
    /// [`Choices::from_basis`], from the judgements: the LoD chain's level picked once per
    /// target and height for every class ([`ChainBasis::pick`]), each table made in parallel and
    /// alone, so the same whatever the thread count. Budget mode makes the choices again each
    /// frame the target moves, so this is a frame's cost there.
    fn tables(&self, calibration: &Calibration, heights: &[f32], targets: &[f32]) -> Vec<Table> {
        let usable = |t: Technique| self.usable[t];
        let chain = usable(Technique::LodChain);
        let picks: Vec<Vec<Option<ChainPick>>> = targets
            .iter()
            .map(|&target| {
                let at = |(i, &h): (usize, &f32)| self.chain.get(i).and_then(|b| b.pick(target_at(target, h)));
                heights.iter().enumerate().map(at).collect()
            })
            .collect();
        let each: Vec<(usize, usize)> =
            (0..self.classes.len()).flat_map(|c| (0..targets.len()).map(move |k| (c, k))).collect();
        each.into_par_iter()
            .map(|(c, k)| {
                let target = targets[k];
                let judged: Vec<Judged> = (self.judged[c].iter().zip(heights).zip(&picks[k]).enumerate())
                    .map(|(i, ((j, &h), &pick))| {
                        let candidate =
                            chain.then(|| self.chain_judged[c][i].get(pick_index(pick)).copied().flatten()).flatten();
                        j.with_candidate(target_at(target, h), candidate)
                    })
                    .collect();
                self.table(calibration, heights, c, target, &judged)
            })
            .collect()
    }

    /// [`Choices::table`] of class `c` under `target` from its `judged` steps, reading what it
    /// needs at the largest height from the basis (the last step's floor and chain, the
    /// converging judgements).
    fn table(&self, calibration: &Calibration, heights: &[f32], c: usize, target: f32, judged: &[Judged]) -> Table {
        let usable = |t: Technique| self.usable[t];
        let elevation = self.classes[c];
        let top = heights[heights.len() - 1];
        let top_target = target_at(target, top);
        let converging = || {
            let chain = (converges(Technique::LodChain) && usable(Technique::LodChain))
                .then(|| self.converging_chain.as_ref().and_then(|b| b.pick(top_target)));
            self.converging[c].with_chain(calibration, elevation, top, top_target, chain).choice()
        };
        // A technique as drawn at the top: its row, or the chain as drawn at the target there
        // ([`Calibration::measured`]).
        let at = |t: Technique| {
            let chain = (t == Technique::LodChain)
                .then(|| self.chain.last().and_then(|b| calibration.drawn_as(elevation, b.pick(top_target)?, top)));
            chain.flatten().or_else(|| calibration.at_elevation(elevation, t, top))
        };
        let floor = judged.last().map_or(f32::INFINITY, |j| j.floor);
        Choices::table_from(judged, converging, at, floor, top_target, &usable)
    }
}

impl Choices {
    /// The choices of a model with `calibration` under `policy`, among the techniques
    /// `representations` can draw ([`Representations::holds`]).
    #[must_use]
    pub fn new(calibration: &Calibration, policy: &Policy, representations: &Representations) -> Self {
        Self::among(calibration, policy, |t| representations.holds(t))
    }

    /// [`Self::new`] among the techniques `usable` accepts. With tables per elevation, one
    /// class per elevation of [`Calibration::with_elevations_between`] with
    /// [`ELEVATION_SUBDIVISIONS`] (module docs).
    #[must_use]
    pub fn among(calibration: &Calibration, policy: &Policy, usable: impl Fn(Technique) -> bool) -> Self {
        Self::from_basis(&ChoiceBasis::among(calibration, usable), policy)
    }

    /// The height a tree `height` pixels high placed by `transform` is chosen at, and its target
    /// class (which of the tables the chooser reads). In budget mode ([`Policy::budget`]), `height`
    /// times a factor of the tree's own, `2^(±`[`BUDGET_DITHER_OCTAVES`]`)` at most, and the
    /// class of the lattice target its share rounds the policy's target to ([`lattice_cell`]),
    /// both drawn from where it stands (the translation's bits, so the same every frame and in
    /// every view), so that trees at like heights switch representation at different targets;
    /// otherwise `height` and class 0 (the policy's target).
    #[must_use]
    pub fn dither(&self, height: f32, transform: &Mat4) -> (f32, usize) {
        self.dither.apply(height, transform)
    }

    /// Target classes per visibility class ([`Self::dither`], [`TreeDither::classes`]).
    fn dithers(&self) -> usize {
        self.dither.classes()
    }

    /// The target class a tree is chosen under when no share of its own is drawn
    /// ([`Self::choose_framed`], [`Self::steps_at`]): the lattice target nearest the policy's
    /// ([`TreeDither::nearest_class`]).
    fn target_class(&self) -> usize {
        self.dither.nearest_class()
    }

    /// What the tables of the choices under `policy` depend on: `policy` itself, but in budget
    /// mode with its target replaced by the cell of the lattice its tables are made at
    /// ([`lattice_cell`]), so that a host keeps one model's choices for every target within a
    /// cell and moves them to the target with [`Self::retarget`].
    #[must_use]
    pub fn tables_key(policy: &Policy) -> TablesKey {
        if policy.budget.is_some() {
            (Policy { target: 0.0, ..*policy }, lattice_cell(policy.target()).0)
        } else {
            (*policy, 0)
        }
    }

    /// These choices moved to `policy`'s target, whose [`Self::tables_key`] must be theirs: in
    /// budget mode the fraction of a lattice step the trees' targets are rounded from
    /// ([`lattice_cell`]); otherwise nothing changes.
    pub fn retarget(&mut self, policy: &Policy) {
        if let Some((cell, fraction)) = &mut self.dither.cell {
            let (now, f) = lattice_cell(policy.target());
            debug_assert_eq!(now, *cell, "retargeted across cells");
            *fraction = if now == *cell { f } else { *fraction };
        }
    }

    /// [`Self::among`] from what it reads whatever the policy, made once ([`ChoiceBasis`]): the
    /// same choices, for a fraction of the cost where a host makes a model's choices for many
    /// targets (budget mode).
    #[must_use]
    pub fn from_basis(basis: &ChoiceBasis, policy: &Policy) -> Self {
        let target = policy.target();
        let visibility = if policy.occlusion { VISIBILITY_CLASSES } else { 1 };
        let dither = TreeDither::of(policy);
        // Class k stands for a visible fraction 2^-k: the target over its square root.
        let targets = class_targets(target, visibility, dither.cell.map(|c| c.0));
        let (calibration, heights) = (&basis.calibration, &basis.heights);
        let tables = basis.all.tables(calibration, heights, &targets);
        let below = basis.below.as_ref().map_or_else(Vec::new, |b| b.tables(calibration, heights, &targets));
        let mut choices = Self {
            log2_min: basis.log2_min,
            tables,
            elevations: basis.calibration.elevations(),
            visibility,
            below,
            hysteresis_steps: hysteresis_steps(policy),
            uniform_by_class: Vec::new(),
            dither,
        };
        choices.measure_uniform();
        choices
    }

    /// The table of elevation class `elevation` under `target` from its `judged` steps at
    /// `heights`, each judged by the calibration alone: the rule's choices with the short runs
    /// merged, and what is drawn above the largest height. [`Judgements::tables`] makes the same
    /// from its basis; this is the reference the tests compare it with.
    #[cfg(test)]
    fn table(
        calibration: &Calibration,
        heights: &[f32],
        elevation: Option<usize>,
        target: f32,
        usable: &dyn Fn(Technique) -> bool,
        judged: &[Judged],
    ) -> Table {
        let top = heights[heights.len() - 1];
        let top_target = target_at(target, top);
        let converging = || calibration.choose_at_elevation(elevation, top, top_target, |t| converges(t) && usable(t));
        let at = |t: Technique| calibration.measured(elevation, t, top, top_target, usable);
        let floor = calibration.floor(elevation, top, usable);
        Self::table_from(judged, converging, at, floor, top_target, usable)
    }

    /// The table of [`Self::table`] from its `judged` steps and what it reads at the largest
    /// height: the rule's choice there among the techniques that converge (`converging`, read
    /// where the last step does not converge), a technique's `(error, primitives)` as drawn
    /// there (`at`), the floor there and the target allowed there.
    fn table_from(
        judged: &[Judged],
        converging: impl FnOnce() -> Technique,
        at: impl Fn(Technique) -> Option<(f32, f32)>,
        floor: f32,
        top_target: f32,
        usable: &dyn Fn(Technique) -> bool,
    ) -> Table {
        let mut steps: Vec<Technique> = judged.iter().map(Judged::choice).collect();
        merge_short_runs(&mut steps, |i, t| judged[i].admissible_primitives(t));
        let above = steps.last().copied().filter(|&t| converges(t)).unwrap_or_else(|| {
            let converging = converging();
            if converges(converging) { converging } else { Technique::FALLBACK }
        });
        // The point tree may stand in for a tree partly in view only where its image at the
        // top is within the target, as any choice there.
        let limit = floor + sanitise(top_target);
        let point_tree = at(Technique::FALLBACK)
            .filter(|&(e, _)| usable(Technique::FALLBACK) && e <= limit)
            .map_or(f32::INFINITY, |(_, p)| p);
        Table { above, above_cost: (at(above).map_or(f32::INFINITY, |(_, p)| p), point_tree), steps }
    }

    /// Sets [`Self::uniform_below_in`] (and so [`Self::uniform_below`]) from the tables.
    fn measure_uniform(&mut self) {
        self.uniform_by_class =
            self.tables.chunks((self.visibility * self.dithers()).max(1)).map(|class| self.uniform(class)).collect();
    }

    /// The technique [`Self::choose_framed`] gives every tree under a height in every elevation
    /// class but [`BELOW_HORIZON`], whatever its visibility, share in view and last frame's
    /// technique, and that height: where every elevation's tables' first steps choose the same
    /// technique, a tree lower than the hysteresis short of the first step where any of them
    /// differs. The chooser takes it without looking the tree up (`choose_instances`): in a
    /// large forest most trees are that small. (Seen from below, a tree whose smallest choice is
    /// the octahedral impostor gets another: those are looked up.)
    ///
    /// Every class's [`Self::uniform_below_in`] with one technique, and the least of their
    /// heights: the run of that technique the classes' tables share is the shortest class's, and
    /// the height grows with the run.
    #[must_use]
    pub fn uniform_below(&self) -> Option<(f32, Technique)> {
        let (first, rest) = self.uniform_by_class.split_first()?;
        rest.iter().try_fold((*first)?, |(height, technique), class| {
            class.filter(|c| c.1 == technique).map(|c| (height.min(c.0), technique))
        })
    }

    /// [`Self::uniform_below`] for the trees of elevation class `elevation` alone (an index into
    /// [`Self::elevations`], past the last: the last; [`BELOW_HORIZON`]: `None`): the technique
    /// that class's tables give every tree under a height, whatever its visibility, share in view
    /// and last frame's technique, and that height. The chooser takes it without looking the tree
    /// up once it knows the tree's class. Where the elevation classes' smallest trees differ (a
    /// table measured from 4 pixels up may give the view straight down another technique than the
    /// side's), every other class keeps its own. Measured on 10⁶ trees (`bench --trees 1000000
    /// --frames 12 --size 480x270 --technique policy --no-render`, 2 cores, two alternating runs
    /// each, `assign` and `record` ms), against the one height for every class: the Quaternius
    /// tree's and the jacaranda's containers calibrated from 4 pixels (whose view straight down
    /// takes ellipsoids and impostor planes at 4 pixels, so that no height was shared) 12.3 and
    /// 8.2 → 9.6–9.7 and 6.2; 8.5–8.9 and 5.6–5.8 → 6.2–6.4 and 3.4–4.1 (as from 8 pixels:
    /// 9.0–9.2 and 5.9–6.3; 6.4–6.6 and 3.5); the orchid's and the willow's calibrated from 8
    /// pixels, which shared none either, `assign` 13.4–13.8 → 12.2–12.8 and 13.0–13.1 →
    /// 12.4–12.6.
    #[must_use]
    pub fn uniform_below_in(&self, elevation: usize) -> Option<(f32, Technique)> {
        if elevation == BELOW_HORIZON {
            return None;
        }
        let last = self.uniform_by_class.len().checked_sub(1)?;
        self.uniform_by_class[elevation.min(last)]
    }

    /// [`Self::uniform_below`] measured from `tables`: the steps `i` that their first steps
    /// share, and the height whose step `x` keeps `x + hysteresis` under `i − ½` (the steps
    /// [`Self::choose_framed`] reads round to the nearest), lowered by a thousandth so that
    /// `log2`'s rounding never lifts a tree under it past that step.
    fn uniform(&self, tables: &[Table]) -> Option<(f32, Technique)> {
        let first = tables.first()?.steps.first().copied()?;
        let shared =
            tables.iter().map(|t| t.steps.iter().take_while(|&&s| s == first).count()).min().filter(|&n| n > 0)?;
        #[expect(clippy::cast_precision_loss, reason = "a few dozen steps")]
        let x = shared as f32 - 0.5 - self.hysteresis_steps as f32;
        let height = (self.log2_min + x / STEPS_PER_OCTAVE).exp2() * 0.999;
        (height > 0.0 && height.is_finite()).then_some((height, first))
    }

    /// Whether a tree seen from `elevation` degrees (its [`view_elevation`]) is below the
    /// tables: more than half the spacing of the two lowest classes below the lowest class (with
    /// the build's classes every 10° from 0°, below −5°: a view is then farther from any table
    /// than the classes let a view be anywhere else), with a quarter of that spacing of
    /// hysteresis as [`elevation_class_after`] keeps: a tree not below last frame (`was_below`)
    /// goes below past −7.5°, one below comes back past −2.5°. Always `false` where nothing
    /// changes below (no usable technique is [`upper_hemisphere_only`], or fewer than two
    /// classes).
    #[must_use]
    pub fn below_horizon(&self, elevation: f32, was_below: bool) -> bool {
        self.below_classes()
            .is_some_and(|classes| elevation_class_after(Some(usize::from(!was_below)), elevation, &classes) == 0)
    }

    /// The two classes [`Self::below_horizon`] tells apart: below is a class of its own under
    /// the lowest (at or under the horizon), one spacing down, so the classes' rule places its
    /// bounds. `None` where nothing changes below.
    fn below_classes(&self) -> Option<[f32; 2]> {
        let (Some(&lowest), Some(&next), false) =
            (self.elevations.first(), self.elevations.get(1), self.below.is_empty())
        else {
            return None;
        };
        let floor = lowest.min(0.0);
        Some([floor - (next - lowest), floor])
    }

    /// Per elevation class `c`, the sines `(lo, hi)` of the elevations between which a tree of
    /// class `c` last frame, not below the horizon, stays in class `c` and above the horizon
    /// ([`elevation_class_after`], [`Self::below_horizon`]) whatever the rounding of the
    /// elevation: each bound's sine moved inwards by [`STAY_MARGIN`]. The chooser reads a tree's
    /// class from its elevation's sine there, without the arc sine.
    fn stay_bands(&self) -> Vec<(f32, f32)> {
        let centres = &self.elevations;
        let last = centres.len().saturating_sub(1);
        // Below the horizon at or under this elevation (where a tree not below moves down).
        let below = self.below_classes().map_or(f32::NEG_INFINITY, |classes| class_bound(&classes, 0, -1.0));
        let sine = |degrees: f32| degrees.to_radians().sin();
        (0..centres.len())
            .map(|c| {
                let lo = if c > 0 { class_bound(centres, c - 1, -1.0).max(below) } else { below };
                let hi = if c < last { class_bound(centres, c, 1.0) } else { f32::INFINITY };
                let lo = if lo > -90.0 { sine(lo) + STAY_MARGIN } else { f32::NEG_INFINITY };
                let hi = if hi < 90.0 { sine(hi) - STAY_MARGIN } else { f32::INFINITY };
                (lo, hi)
            })
            .collect()
    }

    /// The technique for a tree `height` pixels high whose technique last frame was `previous`
    /// (`None`: none, a new tree): last frame's if it is the choice within the hysteresis of
    /// `height`, else the choice at `height`; above the calibrated range the choice at its top if
    /// that converges to the full mesh as trees come nearer ([`converges`]), else the rule's
    /// choice there among those that converge (module docs). Seen from the side (elevation class
    /// 0), fully visible and wholly in view.
    #[must_use]
    pub fn choose(&self, height: f32, previous: Option<Technique>) -> Technique {
        self.choose_viewed(height, 0, 1.0, previous)
    }

    /// [`Self::choose`] for a tree of which the visible fraction `visible` is seen: by the table
    /// of its visibility class ([`visibility_class`]) where the choices were made with
    /// [`Policy::occlusion`], else as fully visible. Seen from the side (elevation class 0).
    #[must_use]
    pub fn choose_seen(&self, height: f32, visible: f32, previous: Option<Technique>) -> Technique {
        self.choose_viewed(height, 0, visible, previous)
    }

    /// [`Self::choose_seen`] for a tree seen from elevation class `elevation` (an index into
    /// [`Self::elevations`], [`elevation_class_after`]; past the last: the last; without tables
    /// per elevation every class reads the tables over every view), wholly in view.
    #[must_use]
    pub fn choose_viewed(&self, height: f32, elevation: usize, visible: f32, previous: Option<Technique>) -> Technique {
        self.choose_framed(height, elevation, visible, 1.0, previous)
    }

    /// [`Self::choose_viewed`] for a tree of which the share `in_view` of its triangles lies in
    /// cells the view holds ([`in_view_share`]; 1: wholly in view): above the calibrated range
    /// the point tree, which culls per cell, where its primitives at the largest height times
    /// that share are fewer than the whole tree of the table's choice there (with a quarter of
    /// hysteresis either way against last frame's technique); module docs. In budget mode, under
    /// the lattice target nearest the policy's (a tree's own is drawn by [`Self::dither`]).
    #[must_use]
    pub fn choose_framed(
        &self,
        height: f32,
        elevation: usize,
        visible: f32,
        in_view: f32,
        previous: Option<Technique>,
    ) -> Technique {
        self.choose_in_class(height, elevation, visibility_class(visible), self.target_class(), in_view, previous)
    }

    /// [`Self::choose_framed`] for a tree of visibility class `class` ([`visibility_class`]),
    /// which the chooser knows: a fraction of exactly `2^-class` reads as that class; in target
    /// class `dither` ([`Self::dither`]; without a budget there is one, 0, the policy's target).
    fn choose_in_class(
        &self,
        height: f32,
        elevation: usize,
        class: usize,
        dither: usize,
        in_view: f32,
        previous: Option<Technique>,
    ) -> Technique {
        let k = class.min(self.visibility - 1) * self.dithers() + dither.min(self.dithers() - 1);
        let table = match self.below.get(k) {
            Some(below) if elevation == BELOW_HORIZON => below,
            _ => {
                let e =
                    if elevation == BELOW_HORIZON { 0 } else { elevation.min(self.elevations.len().saturating_sub(1)) };
                &self.tables[e * self.visibility * self.dithers() + k]
            }
        };
        let (whole, culled) = (table.above_cost.0, table.above_cost.1 * in_view.clamp(0.0, 1.0));
        let bias = match previous {
            Some(Technique::FALLBACK) => 1.25,
            Some(p) if p == table.above => 0.8,
            _ => 1.0,
        };
        let above_range =
            if table.above != Technique::FALLBACK && culled < whole * bias { Technique::FALLBACK } else { table.above };
        let steps = &table.steps;
        let x = self.step(height);
        let last = steps.len() - 1;
        // Above the range: one step per STEPS_PER_OCTAVE past its end reads as the fallback.
        let above = |i: f32| i > last as f32 + 0.5;
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to the table")]
        // A step half way past the last (`above` is false there) rounds up to one past it: the
        // last step's choice.
        let at = |i: f32| if above(i) { above_range } else { steps[(i.round().max(0.0) as usize).min(last)] };
        held(at, x, self.hysteresis_steps, previous)
    }

    /// Whether a tree `height` pixels high lies above the calibrated range (where
    /// [`Self::choose_framed`] reads its share in view).
    #[must_use]
    pub fn above_range(&self, height: f32) -> bool {
        let last = self.tables.first().map_or(0, |t| t.steps.len().saturating_sub(1));
        #[expect(clippy::cast_precision_loss, reason = "a few dozen steps")]
        let top = last as f32 + 0.5;
        self.step(height) > top
    }

    /// Where `height` falls on the tables' steps, fractional: 0 at the smallest calibrated height.
    fn step(&self, height: f32) -> f32 {
        step_of(self.log2_min, height)
    }

    /// The elevations of the classes' views, degrees, ascending (empty: one class, the tables
    /// over every view).
    #[must_use]
    pub fn elevations(&self) -> &[f32] {
        &self.elevations
    }

    /// The choice at each step seen from the side and fully visible, smallest height first (for
    /// tests and panels); in budget mode under the lattice target nearest the policy's.
    #[must_use]
    pub fn steps(&self) -> &[Technique] {
        self.steps_at(0)
    }

    /// [`Self::steps`] seen from elevation class `elevation` (past the last: the last).
    #[must_use]
    pub fn steps_at(&self, elevation: usize) -> &[Technique] {
        let e = elevation.min(self.elevations.len().saturating_sub(1));
        &self.tables[e * self.visibility * self.dithers() + self.target_class()].steps
    }

    /// [`Self::steps_at`] as runs: each technique with the projected height, pixels, of the first
    /// step of its run, smallest first (the first at the smallest calibrated height). A tree of
    /// elevation class `elevation`, fully visible, wholly in view and chosen afresh, gets a run's
    /// technique from that height up to the next run's (up to the hysteresis, [`Self::choose`]).
    /// For `treelod dump` and panels.
    #[must_use]
    pub fn runs_at(&self, elevation: usize) -> Vec<(f32, Technique)> {
        let steps = self.steps_at(elevation);
        runs_of(steps).into_iter().map(|run| (height_of_step(self.log2_min, run.start), steps[run.start])).collect()
    }
}

/// The shortest run of one technique between two others that [`Choices`] keeps unmerged: an
/// octave of projected height, [`STEPS_PER_OCTAVE`] steps (module docs, *Short runs*).
#[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a whole number of steps")]
pub const SHORTEST_RUN_STEPS: usize = STEPS_PER_OCTAVE as usize;

/// The most primitives a merged run may draw, as a multiple of what the rule's own choices draw
/// over it ([`Choices`]): two, what a tree draws while it fades from one technique to
/// the other, both at once (module docs, *Short runs*).
pub const MERGE_COST: f32 = 2.0;

/// Merges into a neighbour each run of `steps` (one technique over consecutive steps) shorter
/// than [`SHORTEST_RUN_STEPS`] that lies between two others, where a neighbour's technique is
/// admissible at every step of the run (`admissible[i]`: the techniques the rule lets step `i`
/// take, with their primitives, the rule's choice `steps[i]` among them;
/// [`Calibration::admissible_at_elevation`]) and draws at most [`MERGE_COST`] times the
/// primitives of the rule's choices over the run: the neighbour of fewer primitives (ties: the
/// smaller heights' side). The shortest run is merged first, then the runs are measured again,
/// until no short run can be merged; the cost is always against the rule's choices, so merges
/// do not compound. The first and last runs stay: below the smallest height the first step's
/// choice holds, and above the largest the last's or the one that converges (module docs).
fn merge_short_runs(steps: &mut [Technique], primitives: impl Fn(usize, Technique) -> Option<f32>) {
    let chosen: Vec<f32> = steps.iter().enumerate().map(|(i, &t)| primitives(i, t).unwrap_or(0.0)).collect();
    loop {
        let runs = runs_of(steps);
        let mut shortest: Option<(std::ops::Range<usize>, Technique)> = None;
        for run in runs.iter().skip(1).take(runs.len().saturating_sub(2)) {
            if run.len() >= SHORTEST_RUN_STEPS || shortest.as_ref().is_some_and(|(s, _)| s.len() <= run.len()) {
                continue;
            }
            let allowed = MERGE_COST * chosen[run.clone()].iter().sum::<f32>();
            let merged = [steps[run.start - 1], steps[run.end]]
                .into_iter()
                .filter_map(|t| run.clone().map(|i| primitives(i, t)).sum::<Option<f32>>().map(|c| (t, c)))
                .filter(|&(_, c)| c <= allowed)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((technique, _)) = merged {
                shortest = Some((run.clone(), technique));
            }
        }
        let Some((run, technique)) = shortest else { return };
        steps[run].fill(technique);
    }
}

/// The runs of `steps`: the ranges of consecutive steps of one technique, in order.
fn runs_of(steps: &[Technique]) -> Vec<std::ops::Range<usize>> {
    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
    for (i, &t) in steps.iter().enumerate() {
        match runs.last_mut() {
            Some(run) if steps[run.start] == t => run.end = i + 1,
            _ => runs.push(i..i + 1),
        }
    }
    runs
}

/// Whether `technique` converges to the full mesh as a tree comes nearer, so that the choice at
/// the largest calibrated height may hold above it: the point tree (its cut reaches every
/// triangle) and the LoD chain (its finest level is the full mesh). Impostor planes, ellipsoids
/// and billboards keep their error near, and hand over there. So does pruning: its `λ(h)` reaches
/// 1 only where the tree is about as tall as the screen (spec §6.11), and between the tables' top
/// and there it draws a share of the leaves that Neubert et al.'s schedule sets, which no table
/// measures.
#[must_use]
pub const fn converges(technique: Technique) -> bool {
    matches!(technique, Technique::Full | Technique::Spt | Technique::LodChain)
}

/// Whether `technique` reads a tree's visible fraction when it draws it: pruning thins a tree
/// partly hidden (Neubert et al. 2011 §5), whatever chose it.
const fn prunes(technique: Technique) -> bool {
    matches!(technique, Technique::PruneOpt | Technique::PruneCook)
}

/// The share of [`Choices::uniform_below_in`]'s height (the tree's elevation class's) from which a
/// tree it chose is measured for occlusion ([`PolicyState::visibility_matters`]): one octave. A
/// measurement is read a frame or more after it is taken, and it stands only while the eye has
/// moved less than a quarter of the tree's distance (the renderer's occlusion test), in which time
/// the tree grows by at most a third on screen: a tree that comes nearer without a jump has been
/// measured at least twice before its visible fraction can change its choice.
///
/// Measured and not taken: a height per model under which no visibility class's tables choose
/// differently from the fully visible one's in any elevation class (what
/// [`Choices::uniform_below`] bounds across elevations, taken across visibility classes), to
/// measure fewer trees of models whose elevation classes choose differently for their smallest
/// trees. On the shared weeping willow and orchid (built with every representation, the models
/// without a [`Choices::uniform_below`]) the tables differ between visibility classes from their
/// smallest step (a hidden far willow takes billboards where a visible one takes the point
/// tree), so it measured no tree less.
pub const VISIBILITY_LEAD: f32 = 0.5;

/// The projected height in pixels of a model's block drawn by `instance` (its block bounds'
/// height scaled by the instance's y axis, over the distance of its transformed block centre
/// times [`Camera::world_per_pixel`]): the height the calibration tables are indexed by.
#[must_use]
pub fn projected_height(lod: &ModelLod, transform: Mat4, camera: &Camera) -> f32 {
    projected_height_at(lod, transform, camera.position, camera.world_per_pixel())
}

/// [`projected_height`] with the camera's position and [`Camera::world_per_pixel`] given, so a
/// frame computes the latter (a tangent) once rather than per tree.
pub(crate) fn projected_height_at(lod: &ModelLod, transform: Mat4, eye: Vec3, world_per_pixel: f32) -> f32 {
    height_from(world_height(lod, transform), transform.transform_point3(lod.centre()), eye, world_per_pixel)
}

/// A model's block height drawn by `transform`, world space: the model's times the transform's y
/// axis's length.
fn world_height(lod: &ModelLod, transform: Mat4) -> f32 {
    let (min, max) = lod.bounds();
    (max.y - min.y) * transform.y_axis.truncate().length()
}

/// [`projected_height_at`] of a block `height` high (world space) centred at `centre`.
fn height_from(height: f32, centre: Vec3, eye: Vec3, world_per_pixel: f32) -> f32 {
    let distance = centre.distance(eye).max(1e-6);
    height / (distance * world_per_pixel)
}

/// Per instance, the technique the policy gave it last frame, for hysteresis, and the transition
/// it is in, if any: reset when the instances change.
#[derive(Clone, Debug, Default)]
pub struct PolicyState {
    previous: Vec<Option<Technique>>,
    /// Per instance: the technique it is leaving and the frames of the transition gone.
    transitions: Vec<Option<(Technique, u16)>>,
    /// Frames of a transition ([`Policy::transition`]); 0: none (switch at once).
    frames: u16,
    /// Per instance: its visible fraction ([`Policy::occlusion`]); empty or short: 1.
    visible: Vec<f32>,
    /// Per instance: the visibility class it was chosen by last frame ([`visibility_class_after`]).
    classes: Vec<u8>,
    /// Per instance: the elevation class it was chosen by last frame ([`elevation_class_after`]),
    /// [`NO_CLASS`] for none, [`BELOW_CLASS`] for a view from below the tables.
    elevations: Vec<u8>,
    /// Per instance: whether its visible fraction matters to its choice now or soon
    /// ([`Self::visibility_matters`]).
    measure: Vec<bool>,
    /// Per chunk of [`CHOOSE_CHUNK`] instances, whether the last choice left any of them in a
    /// transition (`false` only where none is), so that [`Self::transitions`] reads only those
    /// chunks; of another length than the chunks, every chunk is read.
    busy: Vec<bool>,
}

/// [`PolicyState`]'s elevation class of a tree not chosen by elevation last frame.
const NO_CLASS: u8 = u8::MAX;

/// `PolicyState::elevations` of a tree seen from below the tables last frame ([`BELOW_HORIZON`]).
const BELOW_CLASS: u8 = u8::MAX - 1;

/// A tree's transition from one technique to another this frame ([`PolicyState::transition`]):
/// it is drawn with both, the new technique on the pixels whose transition dither `h ∈ [0, 1)`
/// is below [`Self::shown`], the old one on the rest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transition {
    /// The technique the tree is leaving.
    pub from: Technique,
    /// The share of the pixels the new technique covers, in `(0, 1)`; it grows by one
    /// [`Policy::transition`]-th per frame.
    pub shown: f32,
}

impl PolicyState {
    /// A state whose trees fade over `frames` frames when they change technique (at most
    /// [`Policy::MAX_TRANSITION`]; 0 or 1: switch at once). The default state switches at once.
    #[must_use]
    pub fn with_transition(frames: u32) -> Self {
        let mut state = Self::default();
        state.set_transition(frames);
        state
    }

    /// Sets the frames of later transitions ([`Self::with_transition`]); transitions under way
    /// longer than that end now.
    pub fn set_transition(&mut self, frames: u32) {
        let frames = u16::try_from(frames.min(Policy::MAX_TRANSITION)).unwrap_or(u16::MAX);
        let frames = if frames <= 1 { 0 } else { frames };
        // Every transition under way is shorter than the frames it was made with (`advance`),
        // so the same frames end none: read every instance only when they change.
        if frames != self.frames {
            self.frames = frames;
            for t in &mut self.transitions {
                *t = t.filter(|&(_, k)| k < frames);
            }
        }
    }

    /// Forgets every instance's previous technique, transition and visible fraction (the
    /// instance list changed).
    pub fn reset(&mut self) {
        self.previous.clear();
        self.transitions.clear();
        self.visible.clear();
        self.classes.clear();
        self.elevations.clear();
        self.measure.clear();
        self.busy.clear();
    }

    /// Whether instance `index`'s visible fraction ([`Self::set_visible`]) matters to the last
    /// choice made for it, or will once it grows a little on screen: `false` for a tree out of
    /// view, and for a tree its elevation class's [`Choices::uniform_below_in`] chose (whatever
    /// its visible fraction) that is also less than [`VISIBILITY_LEAD`] of that height high (a
    /// tree whose class changes to one with a lower height counts as fully visible until it is
    /// measured, a frame or two: the choice of a visible tree), unless the
    /// technique it got prunes by its visible fraction. A host measuring occlusion measures only
    /// the trees for which this is `true` (in a large forest most trees are far and small: of the
    /// about 127,000 trees a frame of the shared pine's 10^6 draws, 0 to 120, `docs/cli.md`); the
    /// others' fractions are not read until they matter again. `true` past the instances the last
    /// choice had.
    #[must_use]
    pub fn visibility_matters(&self, index: usize) -> bool {
        self.measure.get(index).copied().unwrap_or(true)
    }

    /// Per instance the last choice was made for, [`Self::visibility_matters`]: a host walks it
    /// in chunks of [`CHOOSE_CHUNK`] (in parallel, skipping a chunk of none with no more than a
    /// byte compare per instance) to list the trees to measure. Instances past its end matter.
    #[must_use]
    pub fn visibility_flags(&self) -> &[bool] {
        &self.measure
    }

    /// Sets the instances' visible fractions the next choices read (per instance, 1 = fully
    /// visible; instances past the end count as visible), for choices made with
    /// [`Policy::occlusion`].
    pub fn set_visible(&mut self, visible: &[f32]) {
        self.visible.clear();
        self.visible.extend_from_slice(visible);
    }

    /// Runs `choose` on this state with `visible` as the visible fractions it reads
    /// ([`Self::set_visible`]), lent without copying them (10^6 instances: 4 MB a frame), and
    /// gives them back, padded with 1 to the instances if the choice had more. The fractions the
    /// state held before are kept for after.
    pub fn with_visible<R>(&mut self, visible: &mut Vec<f32>, choose: impl FnOnce(&mut Self) -> R) -> R {
        std::mem::swap(&mut self.visible, visible);
        let result = choose(self);
        std::mem::swap(&mut self.visible, visible);
        result
    }

    /// The state of instances `index` (each at most once), laid end to end: what a choice made
    /// for those instances alone reads (budget mode's look-ahead chooses a sample of a large
    /// forest's chunks and its nearest trees). Entries the state lacks read as a new instance's;
    /// the visible fractions are not copied.
    #[must_use]
    pub fn gathered(&self, index: &[usize]) -> Self {
        fn gather<T: Copy>(all: &[T], index: &[usize], default: T) -> Vec<T> {
            index.iter().map(|&i| all.get(i).copied().unwrap_or(default)).collect()
        }
        Self {
            previous: gather(&self.previous, index, None),
            transitions: gather(&self.transitions, index, None),
            frames: self.frames,
            visible: Vec::new(),
            classes: gather(&self.classes, index, 0),
            elevations: gather(&self.elevations, index, NO_CLASS),
            measure: gather(&self.measure, index, true),
            busy: Vec::new(),
        }
    }

    /// Instance `index`'s transition this frame, if it is changing technique: the technique it
    /// leaves and the share the new one covers.
    #[must_use]
    pub fn transition(&self, index: usize) -> Option<Transition> {
        let (from, k) = (*self.transitions.get(index)?)?;
        Some(Transition { from, shown: f32::from(k) / f32::from(self.frames.max(1)) })
    }

    /// Every instance in a transition this frame, ascending: its index and [`Self::transition`].
    /// Only the chunks of instances the last choice left a transition in are read.
    pub fn transitions(&self) -> impl Iterator<Item = (u32, Transition)> + '_ {
        let n = self.transitions.len();
        let chunks = n.div_ceil(CHOOSE_CHUNK);
        let known = self.busy.len() == chunks;
        (0..chunks)
            .filter(move |&c| !known || self.busy[c])
            .flat_map(move |c| chunk_range(c, n))
            .filter_map(|i| Some((u32::try_from(i).ok()?, self.transition(i)?)))
    }
}

/// The transition after one frame of a tree that was `previous` (`None`: a new tree) and is now
/// `chosen`, in transition `current` before the frame, with transitions of `frames` frames (0:
/// none): a change starts one (reversing one under way back to where it was), every frame moves
/// it a step, and it ends after `frames` steps.
fn advance(
    previous: Option<Technique>,
    chosen: Technique,
    current: Option<(Technique, u16)>,
    frames: u16,
) -> Option<(Technique, u16)> {
    if frames == 0 {
        return None;
    }
    let started = match (previous, current) {
        // Back to the technique it was leaving: the other way from where it is.
        (Some(p), Some((from, k))) if p != chosen && from == chosen => Some((p, frames - k)),
        (Some(p), _) if p != chosen => Some((p, 0)),
        _ => current,
    };
    started.and_then(|(from, k)| (k + 1 < frames).then_some((from, k + 1)))
}

/// Instances per parallel task of [`choose_instances`]: a tree's choice costs a few tens of
/// nanoseconds, so a task of a thousand outweighs rayon's cost of a task, and 10^4 trees still
/// split into enough tasks to balance two to eight threads.
pub const CHOOSE_CHUNK: usize = 1024;

/// The instances of chunk `chunk` of [`CHOOSE_CHUNK`] among `instances` in all (the last chunk
/// may be short).
#[must_use]
pub fn chunk_range(chunk: usize, instances: usize) -> std::ops::Range<usize> {
    (chunk * CHOOSE_CHUNK).min(instances)..instances.min((chunk + 1) * CHOOSE_CHUNK)
}

/// Chooses each instance's technique for one frame: the policy's [`Choices`] of its model where
/// the model has them (`choices[model]`, `None` for a model without calibration tables), else
/// `otherwise`; `state` keeps the choices for the next frame's hysteresis. The result goes into
/// [`Assignment::assign_listed`](crate::Assignment), which still checks that each model holds
/// its technique. `state` also moves each tree's transition on ([`PolicyState::transition`]; none
/// unless it was made [`PolicyState::with_transition`]).
///
/// A tree whose culling sphere ([`ModelLod::cull_sphere`], which the point tree's, the impostors'
/// and the baselines' selections cull with; the cells' bounds it holds also hold their
/// ellipsoids and lines as builders write them, spec §6.2) lies outside the camera's frustum is
/// not chosen: its entry is `None` and it is forgotten, as
/// a new tree (no previous technique, no transition, no elevation class), so it comes back into
/// view with the plain choice at its height and without a transition. No technique would draw
/// it, and a forest of 10^6 trees has about a tenth of them in view: the choice, the most costly
/// work per tree of a policy frame, is then made for those alone. (Measured on the shared pine's
/// container with every representation, `bench --trees 1000000 --no-render --technique policy`,
/// see `docs/cli.md`.)
///
/// [`choose_instances_in_chunks`] culls chunks of [`CHOOSE_CHUNK`] instances whole first, with
/// the same result.
///
/// Each instance's choice depends only on it and its own previous choice, so more than
/// [`CHOOSE_CHUNK`] instances are chosen in chunks on rayon's pool, each writing its own slice:
/// the result is the same whatever the thread count.
pub fn choose_instances(
    instances: &[Instance],
    lods: &[ModelLod],
    choices: &[Option<Choices>],
    camera: &Camera,
    otherwise: Technique,
    state: &mut PolicyState,
    out: &mut Vec<Option<Technique>>,
) {
    choose_instances_coarsest(instances, lods, choices, std::slice::from_ref(camera), otherwise, state, out);
}

/// As [`choose_instances`], each tree at the smallest of its projected heights for `cameras`:
/// for a shadow map, the map's own and the screen's, so a tree casts no more detail than the
/// screen shows or the map resolves. Only the first camera culls: a tree outside its frustum is
/// not chosen, whatever the others see (a shadow map's first, so a tree casts into a map only
/// from inside the map's frustum; the screen's camera only bounds its detail). No camera: every
/// tree at height 0, none culled.
///
/// The first camera alone culls because a view draws only what is in its own frustum: a shadow
/// cascade's selection culls every caster outside the map's, so choosing the trees of the
/// screen outside it was work thrown away. When the camera's view culled as well, each of the
/// three cascades of the willow's 10^6 trees (`bench --shadows --technique policy`) chose every
/// tree in view of either, 36–64 ms a cascade, the same trees for all three (see `docs/cli.md`).
pub fn choose_instances_coarsest(
    instances: &[Instance],
    lods: &[ModelLod],
    choices: &[Option<Choices>],
    cameras: &[Camera],
    otherwise: Technique,
    state: &mut PolicyState,
    out: &mut Vec<Option<Technique>>,
) {
    let bounds = ChunkBounds::default();
    choose_instances_in_chunks(instances, lods, &bounds, choices, cameras, otherwise, state, out);
}

/// The bounding spheres of the instances' culling spheres ([`ModelLod::cull_sphere`]) in chunks
/// of [`CHOOSE_CHUNK`] consecutive instances, world space, for [`choose_instances_in_chunks`]:
/// a chunk outside every view is culled whole, without reading its instances. Made again
/// whenever the instances change (a renderer makes it in its `set_instances`): bounds made of
/// other instances of the same count would choose for those. A chunk helps where consecutive
/// instances stand near each other (a host listing its trees by tile or group); scattered, its
/// sphere holds most of the scene and culls nothing, at the cost of one sphere test.
///
/// It also holds each instance's placement (48 bytes an instance): its culling sphere, block
/// centre and height in world space and its unit up axis, which the chooser would otherwise
/// compute from its transform every frame (three point transforms and three square roots).
/// They are computed as the per-frame path computes them, so the choices are the same to the
/// bit, and the chooser reads them in place of the instances' transforms. Measured (`bench --no-render
/// --technique policy`, 48 frames, the binaries alternating; `docs/cli.md`): the shared pine's
/// 10^6 trees select in 23.5 → 21.4 ms (mean of each frame's least over 3 runs), the orchid's
/// 10^4 in 1.96 → 1.90 ms (5 runs), every count of the frames the same.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChunkBounds {
    /// Per chunk, its sphere's centre and radius; a radius of infinity for a chunk holding an
    /// instance whose model or transform is not usable (never culled whole).
    spheres: Vec<(Vec3, f32)>,
    /// Per instance, its [`Placement`] ([`Placement::UNKNOWN`] for an instance of an unknown
    /// model): what the chooser reads of it every frame, computed once. 48 bytes an instance.
    placements: Vec<Placement>,
    /// The instances they were made of.
    instances: usize,
    /// The instances by cell of a grid over their blocks' centres, made the first time
    /// [`Self::tallest_in_view`] reads it.
    grid: GridCache,
}

/// [`ChunkBounds`]' grid ([`Grid`]), made when first needed: a cache, so a clone starts without
/// it and bounds compare without it.
#[derive(Debug, Default)]
struct GridCache(std::sync::OnceLock<Grid>);

impl Clone for GridCache {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl PartialEq for GridCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// A grid over instances' block centres ([`Placement::centre`]), about [`GRID_OCCUPANCY`]
/// instances a cell, for [`ChunkBounds::tallest_in_view`] to read the cells from the nearest
/// out, each bounded by its tallest block over its box's distance, and stop where no cell left
/// can hold a tree as tall on the screen as those it has.
#[derive(Debug)]
struct Grid {
    /// The instances of known models with finite centres, by cell, ascending within a cell:
    /// cell `c`'s are `order[starts[c]..starts[c + 1]]`.
    order: Vec<u32>,
    starts: Vec<u32>,
    /// Per cell, what bounds its instances: their centres' box, their tallest block and how far
    /// beyond its centre an instance's culling sphere reaches.
    cells: Vec<GridCell>,
}

#[derive(Clone, Copy, Debug)]
struct GridCell {
    lo: Vec3,
    hi: Vec3,
    height: f32,
    reach: f32,
}

/// Instances per cell of [`Grid`], on average over the cells of its box.
const GRID_OCCUPANCY: f32 = 64.0;

impl Grid {
    /// The grid of `placements`.
    fn new(placements: &[Placement]) -> Self {
        let usable = |p: &Placement| p.model != Placement::UNKNOWN.model && p.centre.is_finite();
        let (lo, hi, known) = placements
            .iter()
            .filter(|p| usable(p))
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY, 0usize), |(lo, hi, known), p| {
                (lo.min(p.centre), hi.max(p.centre), known + 1)
            });
        let extent = if known == 0 { Vec3::ZERO } else { (hi - lo).max(Vec3::ZERO) };
        let dims = grid_dims(extent, known);
        let cell_of = |centre: Vec3| -> usize {
            let mut index = 0;
            for axis in (0..3).rev() {
                let n = dims[axis];
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to the grid")]
                let k = if extent[axis] > 0.0 {
                    (((centre[axis] - lo[axis]) / extent[axis] * n as f32) as usize).min(n - 1)
                } else {
                    0
                };
                index = index * n + k;
            }
            index
        };
        let cell_count = dims[0] * dims[1] * dims[2];
        let mut counts = vec![0u32; cell_count + 1];
        let cells_of: Vec<usize> =
            placements.iter().map(|p| if usable(p) { cell_of(p.centre) } else { usize::MAX }).collect();
        for &c in cells_of.iter().filter(|&&c| c != usize::MAX) {
            counts[c + 1] += 1;
        }
        for c in 0..cell_count {
            counts[c + 1] += counts[c];
        }
        let starts = counts;
        let mut next = starts.clone();
        let mut order = vec![0u32; known];
        let empty = GridCell { lo: Vec3::INFINITY, hi: Vec3::NEG_INFINITY, height: 0.0, reach: 0.0 };
        let mut cells = vec![empty; cell_count];
        for (i, (&c, p)) in cells_of.iter().zip(placements).enumerate() {
            if c == usize::MAX {
                continue;
            }
            order[next[c] as usize] = u32::try_from(i).unwrap_or(u32::MAX);
            next[c] += 1;
            let cell = &mut cells[c];
            cell.lo = cell.lo.min(p.centre);
            cell.hi = cell.hi.max(p.centre);
            cell.height = cell.height.max(p.height);
            cell.reach = cell.reach.max(p.cull.1 + p.cull.0.distance(p.centre));
        }
        Self { order, starts, cells }
    }
}

/// The cells along each axis of a grid over a box of `extent` holding `instances`: cubes of a
/// side that gives about [`GRID_OCCUPANCY`] instances a cell over the axes the box spans (a
/// flat forest is a grid of columns), at most 1,024 along an axis.
fn grid_dims(extent: Vec3, instances: usize) -> [usize; 3] {
    #[expect(clippy::cast_precision_loss, reason = "a count of cells")]
    let wanted = (instances as f32 / GRID_OCCUPANCY).max(1.0);
    let mut axes: Vec<f32> = extent.to_array().into_iter().filter(|&e| e > 0.0).collect();
    axes.sort_by(f32::total_cmp);
    // Drop the thinnest axes while they are thinner than the side the others give.
    let mut side = 0.0f32;
    while !axes.is_empty() {
        #[expect(clippy::cast_precision_loss, reason = "at most 3 axes")]
        let dimensions = axes.len() as f32;
        side = (axes.iter().product::<f32>() / wanted).powf(1.0 / dimensions);
        if axes[0] >= side || axes.len() == 1 {
            break;
        }
        axes.remove(0);
    }
    extent.to_array().map(|e| {
        if e > 0.0 && side > 0.0 && side.is_finite() {
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped")]
            let n = (e / side).ceil().clamp(1.0, 1024.0) as usize;
            n
        } else {
            1
        }
    })
}

/// What the chooser reads of an instance every frame, made of its model's [`ModelLod`] and its
/// transform once ([`ChunkBounds::new`]) instead of every frame: each value is computed as the
/// per-frame path computes it, so the choices are the same to the bit.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Placement {
    /// Its model.
    model: u32,
    /// Its culling sphere, world space ([`world_cull_sphere`]).
    cull: (Vec3, f32),
    /// Its block's centre, world space.
    centre: Vec3,
    /// Its block's height, world space: the model's times the transform's y axis's length.
    height: f32,
    /// The transform's unit y axis (world Y where it has none): its horizontal plane's normal.
    up: Vec3,
}

impl Placement {
    /// The placement of an instance of an unknown model (no [`ModelLod`]).
    const UNKNOWN: Self =
        Self { model: u32::MAX, cull: (Vec3::ZERO, 0.0), centre: Vec3::ZERO, height: 0.0, up: Vec3::Y };

    fn of(model: u32, lod: &ModelLod, transform: Mat4) -> Self {
        Self {
            model,
            cull: world_cull_sphere(lod, transform),
            centre: transform.transform_point3(lod.centre()),
            height: world_height(lod, transform),
            up: transform.y_axis.truncate().normalize_or(Vec3::Y),
        }
    }

    /// [`projected_height_at`] of the instance.
    fn projected_height(&self, eye: Vec3, world_per_pixel: f32) -> f32 {
        height_from(self.height, self.centre, eye, world_per_pixel)
    }

    /// Its projected height where [`ChunkBounds::tallest_in_view`] counts it: of a known model,
    /// in `view` (`Self::in_view`), the height finite and positive.
    fn height_in_view(&self, view: &(Vec3, f32, Frustum)) -> Option<f32> {
        let (eye, world_per_pixel, _) = *view;
        (self.model != Self::UNKNOWN.model && self.in_view(Some(view)))
            .then(|| self.projected_height(eye, world_per_pixel))
            .filter(|h| h.is_finite() && *h > 0.0)
    }

    /// The sine of the instance's [`view_elevation`].
    fn sine(&self, eye: Vec3) -> f32 {
        sine_from(self.centre, self.up, eye)
    }

    /// Whether the instance's culling sphere meets the view's frustum (every sphere does when
    /// there is no view): [`choose_instances_coarsest`]'s cull, the test each technique's
    /// selection makes.
    fn in_view(&self, view: Option<&(Vec3, f32, Frustum)>) -> bool {
        let (centre, radius) = self.cull;
        view.is_none_or(|(_, _, frustum)| frustum.intersects_sphere(centre, radius))
    }
}

impl ChunkBounds {
    /// The chunks' spheres of `instances` drawing `lods`.
    #[must_use]
    pub fn new(instances: &[Instance], lods: &[ModelLod]) -> Self {
        let placements: Vec<Placement> = instances
            .iter()
            .map(|i| {
                lods.get(i.model as usize).map_or(Placement::UNKNOWN, |lod| Placement::of(i.model, lod, i.transform))
            })
            .collect();
        let spheres = chunk_spheres(&placements);
        Self { spheres, placements, instances: instances.len(), grid: GridCache::default() }
    }

    /// The bounds of instances `index` (each at most once) laid end to end, as [`Self::new`]
    /// makes them of those instances, their placements copied rather than computed again
    /// (budget mode's look-ahead chooses a sample of a large forest's chunks and its nearest
    /// trees: computing the placements of 16 chunks of 10^6 trees took 2 ms on 2 cores). `None`
    /// where these bounds were not made of `instances` instances, or an index is not one of
    /// theirs.
    #[must_use]
    pub fn gathered(&self, index: &[usize], instances: usize) -> Option<Self> {
        if self.instances != instances {
            return None;
        }
        let placements: Vec<Placement> =
            index.iter().map(|&i| self.placements.get(i).copied()).collect::<Option<_>>()?;
        Some(Self {
            spheres: chunk_spheres(&placements),
            instances: placements.len(),
            placements,
            grid: GridCache::default(),
        })
    }

    /// The `count` instances in `camera`'s view (their culling spheres in its frustum) whose
    /// projected heights ([`projected_height`]) are largest, ascending (of equal heights, the
    /// lower index first); every one in view where fewer are. Trees of unknown models are left
    /// out; none where these bounds were not made of `instances` instances. Budget mode's
    /// look-ahead chooses these trees whole beside the sample of a large forest: they are the
    /// trees of many primitives each whose count changes most with a step, wherever they stand
    /// in the instance order.
    ///
    /// Where at most one instance in 16 is wanted, they are read from a grid over the instances
    /// (`Self::tallest_in_view_by_grid`, made on the first such call: 24–47 ms for 10^6 trees,
    /// 4.7 ms for 10^5, on 2 cores). Otherwise every tree in view is read:
    /// chunks whose spheres lie outside the view are skipped, the others' heights written to
    /// `heights` (scratch, kept by the caller so its pages are not faulted in again every call)
    /// beside a quarter-octave histogram, and the trees of the bins that reach `count` read from
    /// them (4,096 trees of the benchmark's forests, 120 frames: 3.7 ms a call for 10^6 pine
    /// trees, 0.87 ms for 10^5 maple trees, against 1.3 and 0.60 ms from the grid).
    #[must_use]
    pub fn tallest_in_view(
        &self,
        camera: &Camera,
        count: usize,
        instances: usize,
        heights: &mut Vec<f32>,
    ) -> Vec<usize> {
        /// A height's bin: its bits' exponent and two mantissa bits (a quarter octave),
        /// increasing with the height (heights are positive and finite).
        fn bin(height: f32) -> usize {
            (height.to_bits() >> 21) as usize
        }
        const BINS: usize = 1 << 10;
        if count == 0 || self.placements.is_empty() || self.instances != instances {
            return Vec::new();
        }
        if count.saturating_mul(GRID_LEAST_SHARE) <= self.placements.len() {
            return self.tallest_in_view_by_grid(camera, count);
        }
        let (eye, world_per_pixel) = (camera.position, camera.world_per_pixel());
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let view = (eye, world_per_pixel, frustum);
        heights.clear();
        heights.resize(self.placements.len(), 0.0);
        let histogram = self
            .placements
            .par_chunks(CHOOSE_CHUNK)
            .zip(heights.par_chunks_mut(CHOOSE_CHUNK))
            .enumerate()
            .filter(|(c, _)| {
                self.spheres.get(*c).is_none_or(|&(centre, radius)| frustum.intersects_sphere(centre, radius))
            })
            .fold(
                || vec![0u32; BINS],
                |mut bins, (_, (chunk, heights))| {
                    for (place, out) in chunk.iter().zip(heights) {
                        if let Some(height) = place.height_in_view(&view) {
                            *out = height;
                            bins[bin(height).min(BINS - 1)] += 1;
                        }
                    }
                    bins
                },
            )
            .reduce(
                || vec![0u32; BINS],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
                    a
                },
            );
        // The lowest bin whose trees and those above it reach `count` (0: every tree in view).
        let mut kept = 0usize;
        let mut lowest = 0;
        for (b, &n) in histogram.iter().enumerate().rev() {
            kept += n as usize;
            lowest = b;
            if kept >= count {
                break;
            }
        }
        let tall: Vec<(f32, usize)> = heights
            .par_iter()
            .enumerate()
            .filter(|&(_, &h)| h > 0.0 && bin(h).min(BINS - 1) >= lowest)
            .map(|(i, &h)| (h, i))
            .collect();
        keep_tallest(tall, count)
    }

    /// [`Self::tallest_in_view`] read from the grid ([`Grid`], made on the first call): the
    /// cells in view from the largest bound on their trees' projected heights down (their
    /// tallest block at their box's distance), until the next cell's bound is under the
    /// `count`-th height found. The same trees as the pass over every tree in view (the
    /// benchmark's forests draw the same frames either way), reading the cells of the nearest
    /// trees and a few beyond.
    fn tallest_in_view_by_grid(&self, camera: &Camera, count: usize) -> Vec<usize> {
        let grid = self.grid.0.get_or_init(|| Grid::new(&self.placements));
        let (eye, world_per_pixel) = (camera.position, camera.world_per_pixel());
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let view = (eye, world_per_pixel, frustum);
        let mut cells: std::collections::BinaryHeap<(u32, usize)> = (grid.cells.iter().enumerate())
            .filter(|&(c, cell)| {
                // Every culling sphere of the cell's trees lies within this one (a margin for
                // rounding, as the chunks' spheres have).
                let (centre, radius) = (0.5 * (cell.lo + cell.hi), 0.5 * cell.lo.distance(cell.hi) + cell.reach);
                grid.starts[c + 1] > grid.starts[c]
                    && (!radius.is_finite() || frustum.intersects_sphere(centre, radius * (1.0 + 1e-4) + 1e-3))
            })
            .map(|(c, cell)| {
                // Its box's distance a little nearer than it is, so that no tree's own distance,
                // rounded otherwise, takes its height past the bound.
                let distance = eye.clamp(cell.lo, cell.hi).distance(eye) * (1.0 - 1e-4);
                let bound = cell.height / (distance.max(1e-6) * world_per_pixel);
                // Positive floats order as their bits; a bound that is not a number is read first.
                (if bound.is_nan() { u32::MAX } else { bound.max(0.0).to_bits() }, c)
            })
            .collect();
        let mut tall: Vec<(f32, usize)> = Vec::new();
        // The `count`-th height found, made again once the trees found grow by half (a lower
        // one, made earlier, only reads more cells).
        let (mut kth, mut next_kth) = (None, count);
        while let Some((bound, c)) = cells.pop() {
            if kth.is_some_and(|kth| f32::from_bits(bound) < kth) {
                break;
            }
            for &i in &grid.order[grid.starts[c] as usize..grid.starts[c + 1] as usize] {
                if let Some(height) = self.placements[i as usize].height_in_view(&view) {
                    tall.push((height, i as usize));
                }
            }
            if tall.len() >= next_kth {
                let mut heights: Vec<f32> = tall.iter().map(|t| t.0).collect();
                kth = Some(*heights.select_nth_unstable_by(count - 1, |a, b| b.total_cmp(a)).1);
                next_kth = tall.len() + tall.len() / 2 + 1;
            }
        }
        keep_tallest(tall, count)
    }
}

/// [`ChunkBounds::tallest_in_view`] reads its grid where it wants at most one instance in this
/// many; more, and a pass over every tree in view costs less than the cells' order.
const GRID_LEAST_SHARE: usize = 16;

/// The instances of the `count` largest heights of `tall` (height, instance; ties by the lower
/// instance), ascending.
fn keep_tallest(mut tall: Vec<(f32, usize)>, count: usize) -> Vec<usize> {
    if tall.len() > count {
        // The comparison is a total order (ties by index), so the trees kept are the same
        // whatever the selection's own order.
        tall.select_nth_unstable_by(count - 1, |a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        tall.truncate(count);
    }
    let mut index: Vec<usize> = tall.into_iter().map(|(_, i)| i).collect();
    index.sort_unstable();
    index
}

/// The spheres of the chunks of [`CHOOSE_CHUNK`] placements of `placements` ([`ChunkBounds`]).
fn chunk_spheres(placements: &[Placement]) -> Vec<(Vec3, f32)> {
    placements
        .chunks(CHOOSE_CHUNK)
        .map(|chunk| {
            let mut spheres = Vec::with_capacity(chunk.len());
            for place in chunk {
                let (centre, radius) = place.cull;
                if place.model == Placement::UNKNOWN.model || !(centre.is_finite() && radius.is_finite()) {
                    return (Vec3::ZERO, f32::INFINITY);
                }
                spheres.push((centre, radius));
            }
            let (lo, hi) = spheres
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (c, r)| (lo.min(*c - *r), hi.max(*c + *r)));
            let centre = 0.5 * (lo + hi);
            let radius = spheres.iter().map(|(c, r)| c.distance(centre) + r).fold(0.0f32, f32::max);
            // A margin for rounding: a chunk is culled only where each of its spheres is
            // clearly outside.
            (centre, radius * (1.0 + 1e-4) + 1e-3)
        })
        .collect()
}

/// [`choose_instances_coarsest`], culling first each chunk of [`CHOOSE_CHUNK`] instances whose
/// sphere in `bounds` lies outside the first camera's frustum: its trees get `None` and are
/// forgotten, as each would be on its own (the same choices and state). `bounds` made of other
/// instances than `instances` (another count) is ignored.
#[expect(clippy::too_many_arguments, reason = "choose_instances_coarsest's, and the chunks' bounds")]
pub fn choose_instances_in_chunks(
    instances: &[Instance],
    lods: &[ModelLod],
    bounds: &ChunkBounds,
    choices: &[Option<Choices>],
    cameras: &[Camera],
    otherwise: Technique,
    state: &mut PolicyState,
    out: &mut Vec<Option<Technique>>,
) {
    state.previous.resize(instances.len(), None);
    state.transitions.resize(instances.len(), None);
    state.visible.resize(instances.len(), 1.0);
    state.classes.resize(instances.len(), 0);
    state.elevations.resize(instances.len(), NO_CLASS);
    state.measure.resize(instances.len(), true);
    state.busy.clear();
    state.busy.resize(instances.len().div_ceil(CHOOSE_CHUNK), false);
    out.clear();
    out.resize(instances.len(), None);
    let frames = state.frames;
    let eyes: Vec<(Vec3, f32, Frustum)> =
        cameras.iter().map(|c| (c.position, c.world_per_pixel(), Frustum::from_view_proj(c.view_proj))).collect();
    let spheres = (bounds.instances == instances.len() && !cameras.is_empty()).then_some(&bounds.spheres[..]);
    let placements = (bounds.instances == instances.len()).then_some(&bounds.placements[..]);
    // Per model, the sines within which a tree keeps its elevation class.
    let bands: Vec<Vec<(f32, f32)>> =
        choices.iter().map(|c| c.as_ref().map_or_else(Vec::new, Choices::stay_bands)).collect();
    let choose = |chunk: usize,
                  instances: &[Instance],
                  previous: &mut [Option<Technique>],
                  transitions: &mut [Option<(Technique, u16)>],
                  visible: &[f32],
                  (classes, elevations, measure): (&mut [u8], &mut [u8], &mut [bool]),
                  out: &mut [Option<Technique>],
                  busy: &mut bool| {
        if let Some(&(centre, radius)) = spheres.and_then(|s| s.get(chunk))
            && eyes.first().is_some_and(|(_, _, frustum)| !frustum.intersects_sphere(centre, radius))
        {
            // Every tree of the chunk is out of view: forgotten, as `Placement::in_view`
            // would have each (its model is usable, or the chunk's radius would be infinite).
            previous.fill(None);
            transitions.fill(None);
            elevations.fill(NO_CLASS);
            measure.fill(false);
            out.fill(None);
            return;
        }
        let placed = placements.map(|p| &p[chunk * CHOOSE_CHUNK..chunk * CHOOSE_CHUNK + instances.len()]);
        let per_instance = instances
            .iter()
            .zip(previous)
            .zip(transitions)
            .zip(visible)
            .zip(classes)
            .zip(elevations)
            .zip(measure)
            .zip(out);
        for (k, (((((((instance, previous), transition), &visible), class), elevation), measure), out)) in
            per_instance.enumerate()
        {
            // Without the placements, the instance's own; with them, the instance is read only
            // for its share in view.
            let place = match placed {
                Some(placed) => Some(placed[k]).filter(|p| p.model != Placement::UNKNOWN.model),
                None => {
                    lods.get(instance.model as usize).map(|lod| Placement::of(instance.model, lod, instance.transform))
                }
            };
            // An instance without a placement is of an unknown model: drawn with `otherwise`.
            let m = place.map_or(usize::MAX, |p| p.model as usize);
            let lod = lods.get(m);
            if let Some(place) = place
                && !place.in_view(eyes.first())
            {
                *previous = None;
                *transition = None;
                *elevation = NO_CLASS;
                *measure = false;
                *out = None;
                continue;
            }
            *out = Some(match (lod.zip(place), choices.get(m).and_then(Option::as_ref)) {
                (Some((lod, place)), Some(choices)) => {
                    // The smallest height and the view that sees it.
                    let (height, eye, frustum) = eyes
                        .iter()
                        .map(|(eye, world_per_pixel, frustum)| {
                            (place.projected_height(*eye, *world_per_pixel), *eye, Some(frustum))
                        })
                        .reduce(|a, b| if b.0 < a.0 { b } else { a })
                        .unwrap_or((0.0, Vec3::ZERO, None));
                    let seen = visibility_class_after(usize::from(*class), visible);
                    *class = u8::try_from(seen).unwrap_or(0);
                    let elevation_class = if choices.elevations().is_empty() {
                        0
                    } else {
                        let sine = place.sine(eye);
                        match bands.get(m).and_then(|b| b.get(usize::from(*elevation))) {
                            // Inside its class's bounds, above the horizon: as the degrees give.
                            Some(&(lo, hi)) if sine > lo && sine < hi => usize::from(*elevation),
                            _ => {
                                let degrees = sine.asin().to_degrees();
                                if choices.below_horizon(degrees, *elevation == BELOW_CLASS) {
                                    *elevation = BELOW_CLASS;
                                    BELOW_HORIZON
                                } else {
                                    // A tree coming up from below is new to the classes.
                                    let before = (*elevation != NO_CLASS && *elevation != BELOW_CLASS)
                                        .then_some(usize::from(*elevation));
                                    let now = elevation_class_after(before, degrees, choices.elevations());
                                    *elevation = u8::try_from(now).unwrap_or(0);
                                    now
                                }
                            }
                        }
                    };
                    *measure = true;
                    let (looked, dither) = choices.dither(height, &instance.transform);
                    let chosen = match choices.uniform_below_in(elevation_class) {
                        // The class's tables choose the same under this height, whatever the
                        // tree's visibility and last frame's choice: not looked up.
                        Some((below, uniform)) if looked < below => {
                            *measure = looked >= VISIBILITY_LEAD * below || prunes(uniform);
                            uniform
                        }
                        _ => {
                            let in_view = match frustum {
                                Some(f) if choices.above_range(height) => in_view_share(lod, instance.transform, f),
                                _ => 1.0,
                            };
                            choices.choose_in_class(looked, elevation_class, seen, dither, in_view, *previous)
                        }
                    };
                    *transition = advance(*previous, chosen, *transition, frames);
                    *busy |= transition.is_some();
                    *previous = Some(chosen);
                    chosen
                }
                _ => {
                    *previous = None;
                    *transition = None;
                    *elevation = NO_CLASS;
                    *measure = true;
                    otherwise
                }
            });
        }
    };
    if instances.len() <= CHOOSE_CHUNK {
        let classes = (&mut state.classes[..], &mut state.elevations[..], &mut state.measure[..]);
        let mut busy = false;
        choose(0, instances, &mut state.previous, &mut state.transitions, &state.visible, classes, out, &mut busy);
        if let Some(slot) = state.busy.first_mut() {
            *slot = busy;
        }
        return;
    }
    instances
        .par_chunks(CHOOSE_CHUNK)
        .enumerate()
        .zip(state.previous.par_chunks_mut(CHOOSE_CHUNK))
        .zip(state.transitions.par_chunks_mut(CHOOSE_CHUNK))
        .zip(state.visible.par_chunks(CHOOSE_CHUNK))
        .zip(state.classes.par_chunks_mut(CHOOSE_CHUNK))
        .zip(state.elevations.par_chunks_mut(CHOOSE_CHUNK))
        .zip(state.measure.par_chunks_mut(CHOOSE_CHUNK))
        .zip(out.par_chunks_mut(CHOOSE_CHUNK))
        .zip(state.busy.par_iter_mut())
        .for_each(
            |(
                ((((((((chunk, instances), previous), transitions), visible), classes), elevations), measure), out),
                busy,
            )| {
                let classes = (classes, elevations, measure);
                choose(chunk, instances, previous, transitions, visible, classes, out, busy);
            },
        );
}

/// A model's culling sphere ([`ModelLod::cull_sphere`]) drawn by `transform`, world space: what
/// [`Placement::in_view`] tests and [`ChunkBounds`] holds.
fn world_cull_sphere(lod: &ModelLod, transform: Mat4) -> (Vec3, f32) {
    let (centre, radius) = lod.cull_sphere();
    (transform.transform_point3(centre), radius * crate::max_axis_scale(transform))
}

/// The share of a model's triangles drawn by `transform` that lie in cells the point tree's
/// selection keeps in `frustum` (1 where the model has no triangles): what the point tree, which
/// culls per cell, draws of a near tree. The test is the selection's own
/// ([`select_frame`](crate::select_frame)'s: each cell's oriented box against the planes, the
/// block cell always kept), so the policy counts what is drawn.
#[must_use]
pub fn in_view_share(lod: &ModelLod, transform: Mat4, frustum: &Frustum) -> f32 {
    let planes = frustum.model_planes(transform);
    let (mut total, mut seen) = (0u64, 0u64);
    for cell in lod.cells() {
        let count = u64::from(cell.triangles().count);
        total += count;
        if crate::frame::cell_in_view(&planes, cell) {
            seen += count;
        }
    }
    #[expect(clippy::cast_precision_loss, reason = "a share")]
    if total == 0 { 1.0 } else { seen as f32 / total as f32 }
}

/// The elevation of `eye` above the horizontal plane of a model's block drawn by `transform`,
/// degrees: the angle between the direction from the block's transformed centre to the eye and
/// that plane, whose normal is the transform's y axis (`[-90, 90]`; 0 for an eye at the centre).
#[must_use]
pub fn view_elevation(lod: &ModelLod, transform: Mat4, eye: Vec3) -> f32 {
    elevation_from(transform.transform_point3(lod.centre()), transform.y_axis.truncate().normalize_or(Vec3::Y), eye)
}

/// [`view_elevation`] of a block centred at `centre` whose horizontal plane's normal is `up`
/// (unit), world space.
fn elevation_from(centre: Vec3, up: Vec3, eye: Vec3) -> f32 {
    sine_from(centre, up, eye).asin().to_degrees()
}

/// The sine of [`elevation_from`]'s elevation, `[-1, 1]` (NaN where it is).
fn sine_from(centre: Vec3, up: Vec3, eye: Vec3) -> f32 {
    let towards = (eye - centre).normalize_or_zero();
    towards.dot(up).clamp(-1.0, 1.0)
}

/// The eye distance at which a model's block is `height` pixels high for `camera` (unit instance
/// scale): for tests and tools placing trees at a projected size.
#[must_use]
pub fn distance_for_height(lod: &ModelLod, height: f32, camera: &Camera) -> f32 {
    let (min, max) = lod.bounds();
    (max.y - min.y) / (height * camera.world_per_pixel())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`merge_short_runs`]' reading of lists of admissible techniques and their primitives per
    /// step (as [`Judged::admissible`] gives them).
    fn listed(admissible: &[Vec<(Technique, f32)>]) -> impl Fn(usize, Technique) -> Option<f32> + '_ {
        move |i, t| admissible[i].iter().find(|c| c.0 == t).map(|c| c.1)
    }
    use treelod_format::calibration_technique as code;

    fn record(technique: u32, height: f32, error: f32, primitives: f32) -> CalibrationRecord {
        CalibrationRecord { technique, height, error, primitives }
    }

    /// A table shaped like a measured leafy tree: the full mesh, the point tree converging to it,
    /// crossed quads good only when small, the chain good only when large.
    fn table() -> Calibration {
        table_with_cheap(None)
    }

    /// [`table`] with a row of technique `cheap.0` as good as the full mesh at every height, at
    /// `cheap.1` primitives.
    fn table_with_cheap(cheap: Option<(u32, f32)>) -> Calibration {
        let mut records = Vec::new();
        for (h, full, spt, spt_p, crossed, chain, chain_p) in [
            (8.0, 0.060, 0.064, 130.0, 0.067, 0.190, 220.0),
            (32.0, 0.030, 0.039, 11_000.0, 0.090, 0.032, 11_100.0),
            (128.0, 0.017, 0.019, 18_700.0, 0.108, 0.017, 22_500.0),
            (256.0, 0.012, 0.012, 21_000.0, 0.120, 0.012, 22_500.0),
        ] {
            records.push((code::FULL, record(code::FULL, h, full, 22_500.0)));
            records.push((code::SPT, record(code::SPT, h, spt, spt_p)));
            records.push((code::CROSSED, record(code::CROSSED, h, crossed, 3.0)));
            records.push((code::LOD_CHAIN, record(code::LOD_CHAIN, h, chain, chain_p)));
            if let Some((technique, primitives)) = cheap {
                records.push((technique, record(technique, h, full, primitives)));
            }
        }
        records.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.height.total_cmp(&b.1.height)));
        Calibration::from_records(&records.into_iter().map(|(_, r)| r).collect::<Vec<_>>()).expect("rows")
    }

    fn all(_: Technique) -> bool {
        true
    }

    /// A table with the full mesh, the point tree and three chain levels of 500, 250 and 100
    /// triangles (the full mesh 1,000), at 8 to 64 pixels.
    fn chain_table() -> Calibration {
        let mut records = Vec::new();
        let mut levels = Vec::new();
        for (h, full, spt, l0, l1, l2) in [
            (8.0, 0.060, 0.064, 0.058, 0.062, 0.065),
            (16.0, 0.040, 0.045, 0.040, 0.048, 0.070),
            (32.0, 0.030, 0.032, 0.031, 0.045, 0.090),
            (64.0, 0.020, 0.021, 0.022, 0.040, 0.120),
        ] {
            records.push(record(code::FULL, h, full, 1000.0));
            records.push(record(code::SPT, h, spt, 400.0));
            for (level, (error, primitives)) in [(l0, 500.0), (l1, 250.0), (l2, 100.0)].into_iter().enumerate() {
                levels.push(ChainCalibrationRecord { level: level as u32, height: h, error, primitives });
            }
        }
        records.sort_by(|a, b| a.technique.cmp(&b.technique).then(a.height.total_cmp(&b.height)));
        levels.sort_by(|a, b| a.level.cmp(&b.level).then(a.height.total_cmp(&b.height)));
        Calibration::from_records(&records).expect("rows").with_chain_levels(&levels)
    }

    fn flip_row(elevation: f32, technique: u32, height: f32, flip: f32) -> FlipCalibrationRecord {
        FlipCalibrationRecord { elevation, technique, height, flip }
    }

    #[test]
    fn with_flip_tables_a_technique_must_be_within_both_floors() {
        let c = table();
        // By RMSE alone the crossed billboards (0.067) are within 0.01 of the floor (0.060).
        assert_eq!(c.choose(8.0, 0.01, all), Technique::Crossed);
        assert!(!c.has_flip());
        let every = FlipCalibrationRecord::EVERY_VIEW;
        let rows = [
            flip_row(every, code::FULL, 8.0, 0.080),
            flip_row(every, code::SPT, 8.0, 0.085),
            flip_row(every, code::CROSSED, 8.0, 0.120),
        ];
        let f = c.clone().with_flip(&rows);
        assert!(f.has_flip());
        assert!((f.flip_floor(None, 8.0, all) - 0.080).abs() < 1e-6);
        assert_eq!(f.flip_at(None, Technique::Crossed, 8.0), Some(0.120));
        // FLIP allows the same share of its floor: 0.01 / 0.060 of 0.080, so 0.0933; the
        // billboards' 0.120 is past it and the point tree (0.064, 0.085) is the cheapest within.
        assert_eq!(f.choose(8.0, 0.01, all), Technique::Spt);
        // A FLIP good enough passes.
        let rows = [rows[0], rows[1], flip_row(every, code::CROSSED, 8.0, 0.090)];
        assert_eq!(c.clone().with_flip(&rows).choose(8.0, 0.01, all), Technique::Crossed);
        // A technique the FLIP tables lack is judged by its RMSE alone: the chain at 32 px.
        assert_eq!(c.choose(32.0, 0.01, all), f.choose(32.0, 0.01, all));
        // Nothing within (no allowance): the least share over the floors, the point tree's
        // (0.064 is 6.7 % over 0.060, 0.085 6.3 % over 0.080; the billboards' 50 %).
        assert_eq!(f.choose(8.0, 0.0, all), Technique::Spt);
        // Rows of an elevation the tables lack are skipped; the rows over every view stand in.
        let odd = c.with_flip(&[rows[0], flip_row(45.0, code::SPT, 8.0, 0.5)]);
        assert_eq!(odd.flip_at(Some(0), Technique::Spt, 8.0), None);
    }

    fn level_flips(rows: &[(u32, f32, f32)]) -> Vec<ChainFlipCalibrationRecord> {
        rows.iter().map(|&(level, height, flip)| ChainFlipCalibrationRecord { level, height, flip }).collect()
    }

    #[test]
    fn with_level_flip_tables_the_chain_level_must_be_within_both_floors() {
        let c = chain_table();
        let every = FlipCalibrationRecord::EVERY_VIEW;
        let rows = [flip_row(every, code::FULL, 8.0, 0.080), flip_row(every, code::SPT, 8.0, 0.085)];
        // By RMSE alone at 8 px (floor 0.058, level 0's) level 2 (0.065, 100 triangles) is within
        // 0.01, and the chain, drawn with it, is the cheapest technique.
        assert_eq!(c.chain_level(8.0, 0.01, all), Some(Some(2)));
        assert_eq!(c.choose(8.0, 0.01, all), Technique::LodChain);
        // FLIP tables of the techniques alone change nothing for the level.
        let f = c.clone().with_flip(&rows);
        assert_eq!(f.chain_level(8.0, 0.01, all), Some(Some(2)));
        assert_eq!(f.level_flip_at(0, 8.0), None);
        // Level 2 reads far worse in FLIP: the same share of the FLIP floor (0.080, the full
        // mesh's) allows 0.080 + 0.01 · 0.080 / 0.058 = 0.0938; level 1 (0.090) is within.
        let levels = level_flips(&[(0, 8.0, 0.082), (1, 8.0, 0.090), (2, 8.0, 0.200)]);
        let g = f.clone().with_chain_flip(&levels);
        assert_eq!(g.level_flip_at(2, 8.0), Some(0.200));
        assert_eq!(g.chain_level(8.0, 0.01, all), Some(Some(1)));
        // The policy compares the chain it draws, level 1 (250 triangles, FLIP 0.090), still
        // cheaper than the point tree.
        assert_eq!(g.choose(8.0, 0.01, all), Technique::LodChain);
        // Every level past the FLIP allowance: the chain draws the full mesh (1,000 triangles),
        // and the point tree (400, within both) is chosen.
        let levels = level_flips(&[(0, 8.0, 0.150), (1, 8.0, 0.160), (2, 8.0, 0.200)]);
        let h = f.clone().with_chain_flip(&levels);
        assert_eq!(h.chain_level(8.0, 0.01, all), Some(None));
        assert_eq!(h.choose(8.0, 0.01, all), Technique::Spt);
        // Over every view the levels' FLIP errors count in the FLIP floor, as their RMSE does.
        let levels = level_flips(&[(0, 8.0, 0.070), (1, 8.0, 0.090), (2, 8.0, 0.200)]);
        let k = f.with_chain_flip(&levels);
        assert!((k.flip_floor(None, 8.0, all) - 0.070).abs() < 1e-6);
        assert!((k.flip_floor(None, 8.0, |t| t != Technique::LodChain) - 0.080).abs() < 1e-6);
        // Level 1 is then past 0.070 + 0.01 · 0.070 / 0.058 = 0.0821: level 0 (500 triangles).
        assert_eq!(k.chain_level(8.0, 0.01, all), Some(Some(0)));
    }

    #[test]
    fn level_flip_tables_end_at_the_first_missing_level() {
        let levels = level_flips(&[(0, 8.0, 0.1), (0, 16.0, 0.08), (2, 8.0, 0.3)]);
        let c = chain_table().with_chain_flip(&levels);
        // Interpolated in log2 of the height, as every curve: halfway between 8 and 16 pixels.
        assert_eq!(c.level_flip_at(0, 8.0 * std::f32::consts::SQRT_2).map(|f| (f * 1000.0).round()), Some(90.0));
        assert_eq!(c.level_flip_at(2, 8.0), None, "level 1 is missing");
        // A non-finite sample is skipped, and a level left empty ends the tables.
        let c = chain_table().with_chain_flip(&level_flips(&[(0, 8.0, f32::NAN), (1, 8.0, 0.1)]));
        assert_eq!(c.level_flip_at(1, 8.0), None);
        assert_eq!(c.level_flip_at(0, 8.0), None);
    }

    #[test]
    fn flip_tables_per_elevation_blend_with_the_classes() {
        let rows: Vec<ElevationCalibrationRecord> = [0.0f32, 30.0]
            .into_iter()
            .flat_map(|elevation| {
                [(code::FULL, 0.06), (code::SPT, 0.064), (code::CROSSED, 0.067)].map(|(technique, error)| {
                    ElevationCalibrationRecord { elevation, technique, height: 8.0, error, primitives: 10.0 }
                })
            })
            .collect();
        let c = table().with_elevations(&rows);
        let every = FlipCalibrationRecord::EVERY_VIEW;
        let flips = [
            flip_row(every, code::CROSSED, 8.0, 0.1),
            flip_row(0.0, code::CROSSED, 8.0, 0.10),
            flip_row(30.0, code::CROSSED, 8.0, 0.16),
        ];
        let f = c.with_flip(&flips);
        assert_eq!(f.flip_at(Some(1), Technique::Crossed, 8.0), Some(0.16));
        let fine = f.with_elevations_between(3);
        assert_eq!(fine.elevations().len(), 4);
        let between = fine.flip_at(Some(1), Technique::Crossed, 8.0).expect("blended");
        assert!((between - 0.12).abs() < 1e-6, "{between}");
        // Tables per elevation read again drop the FLIP rows read for the old ones.
        let again = f.with_elevations(&rows);
        assert_eq!(again.flip_at(Some(1), Technique::Crossed, 8.0), Some(0.1), "over every view");
    }

    #[test]
    fn the_chain_level_is_the_cheapest_within_the_target_of_the_floor() {
        let c = chain_table();
        assert_eq!(c.chain_levels(), 3);
        // 8 px: the floor is level 0's 0.058; every level is within 0.01, the coarsest wins.
        assert!((c.floor(None, 8.0, all) - 0.058).abs() < 1e-6);
        assert_eq!(c.chain_level(8.0, 0.01, all), Some(Some(2)));
        // 16 px: floor 0.040, limit 0.050: level 1 (0.048) is the cheapest within.
        assert_eq!(c.chain_level(16.0, 0.01, all), Some(Some(1)));
        // 32 px: floor 0.030, limit 0.040: the full mesh and level 0; level 0 is cheaper.
        assert_eq!(c.chain_level(32.0, 0.01, all), Some(Some(0)));
        // No allowance at 64 px: only the full mesh is at the floor.
        assert_eq!(c.chain_level(64.0, 0.0, all), Some(None));
        // With the allowance, level 0 (0.022 against the full mesh's 0.020) is within.
        assert_eq!(c.chain_level(64.0, 0.01, all), Some(Some(0)));
        // Interpolated in log2(height) as the policy's tables are.
        let (e, p) = c.level_at(1, 8.0 * std::f32::consts::SQRT_2).expect("level 1");
        assert!((e - 0.5 * (0.062 + 0.048)).abs() < 1e-6 && (p - 250.0).abs() < 1e-3, "{e} {p}");
        assert_eq!(c.level_at(3, 8.0), None);
    }

    #[test]
    fn where_the_floor_is_out_of_the_chains_reach_the_chain_keeps_its_best_image_for_less() {
        // The point tree keeps far leaves (0.03) that the full mesh and every level lose.
        let records = [record(code::FULL, 8.0, 0.100, 1000.0), record(code::SPT, 8.0, 0.030, 100.0)];
        let levels = [(0.098, 500.0), (0.104, 250.0), (0.130, 100.0)].map(|(error, primitives)| (error, primitives));
        let levels: Vec<ChainCalibrationRecord> = levels
            .iter()
            .enumerate()
            .map(|(l, &(error, primitives))| ChainCalibrationRecord { level: l as u32, height: 8.0, error, primitives })
            .collect();
        let c = Calibration::from_records(&records).expect("rows").with_chain_levels(&levels);
        // Nothing is within 0.01 of 0.030: the cheapest within 0.01 of level 0's 0.098.
        assert_eq!(c.chain_level(8.0, 0.01, all), Some(Some(1)));
        // Without the point tree the floor is level 0's 0.098 and the rule is the same.
        assert_eq!(c.chain_level(8.0, 0.01, |t| t != Technique::Spt), Some(Some(1)));
        // No allowance: the least error.
        assert_eq!(c.chain_level(8.0, 0.0, all), Some(Some(0)));
    }

    /// [`chain_table`] with its `lod-chain` rows as the build derives them (the level of the
    /// default target at each height, by the tables over every view) and tables per elevation:
    /// from the side (0°) as over every view; from above (90°) the full mesh and the point tree
    /// 0.01 worse, the chain `chain_worse` worse.
    fn chain_table_with_elevations() -> Calibration {
        chain_table_seen_from_above(0.03)
    }

    fn chain_table_seen_from_above(chain_worse_above: f32) -> Calibration {
        let mean = chain_table();
        let heights = [8.0, 16.0, 32.0, 64.0];
        let chain = |h: f32| mean.chain_at(None, h, Policy::DEFAULT_TARGET, all).expect("levels");
        let mut records: Vec<CalibrationRecord> = [code::FULL, code::SPT]
            .into_iter()
            .flat_map(|t| heights.map(|h| (t, h)))
            .map(|(t, h)| {
                let (error, primitives) = mean.at(Technique::ALL[t as usize], h).expect("row");
                record(t, h, error, primitives)
            })
            .collect();
        records.extend(heights.map(|h| record(code::LOD_CHAIN, h, chain(h).0, chain(h).1)));
        let mut per_elevation = Vec::new();
        for (elevation, worse, chain_worse) in [(0.0, 0.0, 0.0), (90.0, 0.01, chain_worse_above)] {
            for r in &records {
                let extra = if r.technique == code::LOD_CHAIN { chain_worse } else { worse };
                per_elevation.push(ElevationCalibrationRecord {
                    elevation,
                    technique: r.technique,
                    height: r.height,
                    error: r.error + extra,
                    primitives: r.primitives,
                });
            }
        }
        let levels: Vec<ChainCalibrationRecord> = (0..3u32)
            .flat_map(|l| heights.map(|h| (l, h)))
            .map(|(level, height)| {
                let (error, primitives) = mean.level_at(level, height).expect("level");
                ChainCalibrationRecord { level, height, error, primitives }
            })
            .collect();
        Calibration::from_records(&records).expect("rows").with_elevations(&per_elevation).with_chain_levels(&levels)
    }

    #[test]
    fn from_an_elevation_the_chain_s_levels_read_its_own_offset_there() {
        let c = chain_table_with_elevations();
        assert_eq!((c.elevations(), c.chain_levels()), (vec![0.0, 90.0], 3));
        for h in [8.0, 12.0, 32.0, 64.0] {
            for level in 0..3 {
                let mean = c.level_at(level, h).expect("level");
                assert_eq!(c.level_at_elevation(None, level, h), Some(mean));
                assert_eq!(c.level_at_elevation(Some(0), level, h), Some(mean));
                let above = c.level_at_elevation(Some(1), level, h).expect("level");
                assert!((above.0 - mean.0 - 0.03).abs() < 1e-6 && above.1 == mean.1, "{h} px level {level}");
            }
        }
        // At 8 px the chain's coarsest level (100 triangles, 0.065) is within 0.01 of the floor
        // over every view and from the side, but from above it reads 0.095 against a floor of
        // 0.070 there (the full mesh's). One level is drawn whatever the elevation, so the chain
        // draws the one level within the target from both: at every height the full mesh (from
        // above 0.01 worse, as the floor), which the point tree (400) undercuts from either side.
        assert!((c.floor(None, 8.0, all) - 0.058).abs() < 1e-6);
        assert!((c.floor(Some(1), 8.0, all) - 0.070).abs() < 1e-6);
        for h in [8.0, 16.0, 32.0, 64.0] {
            assert_eq!(c.chain_level(h, Policy::DEFAULT_TARGET, all), Some(None), "{h} px");
            let (full, _) = c.at_elevation(Some(1), Technique::Full, h).expect("row");
            let (seen, _) = c.chain_at(Some(1), h, Policy::DEFAULT_TARGET, all).expect("levels");
            assert!((seen - full).abs() < 1e-6, "{h} px: {seen} against the full mesh's {full}");
        }
        for elevation in [None, Some(0), Some(1)] {
            assert_eq!(c.choose_at_elevation(elevation, 8.0, 0.01, all), Technique::Spt, "{elevation:?}");
        }
        // Without the tables per elevation, the coarsest level over every view (module docs).
        assert_eq!(chain_table().chain_level(8.0, Policy::DEFAULT_TARGET, all), Some(Some(2)));
    }

    /// Where a coarse level is out of the target from one elevation only, the chain draws the
    /// cheapest level within it from every elevation, not the full mesh: here the chain reads
    /// 0.005 worse from above than over every view (the full mesh and point tree 0.01 worse, so
    /// their floor 0.01 higher), so at 16 px level 1 (0.048 over every view, limit 0.050) reads
    /// 0.053 from above against a limit of 0.060 and stays; at 8 px level 2 (0.065 + 0.005 ≤
    /// 0.070 + 0.01) stays too; at 32 px level 0 (0.031, 0.036 from above) as over every view.
    #[test]
    fn the_chain_draws_the_cheapest_level_within_the_target_from_every_elevation() {
        let c = chain_table_seen_from_above(0.005);
        let mean = chain_table();
        for h in [8.0, 16.0, 32.0] {
            let pick = c.chain_level(h, Policy::DEFAULT_TARGET, all);
            assert_eq!(pick, mean.chain_level(h, Policy::DEFAULT_TARGET, all), "{h} px");
            assert!(matches!(pick, Some(Some(_))), "{h} px: {pick:?}");
        }
        // From above 0.03 worse: every level is out there, the full mesh is not.
        let c = chain_table_seen_from_above(0.03);
        assert_eq!(c.chain_level(16.0, Policy::DEFAULT_TARGET, all), Some(None));
        // 0.015 worse from above at 16 px: level 0 (0.040 + 0.015 = 0.055 ≤ 0.060) is within, level
        // 1 (0.063) is not: level 0, finer than over every view but not the full mesh.
        let c = chain_table_seen_from_above(0.015);
        assert_eq!(mean.chain_level(16.0, Policy::DEFAULT_TARGET, all), Some(Some(1)));
        assert_eq!(c.chain_level(16.0, Policy::DEFAULT_TARGET, all), Some(Some(0)));
    }

    /// From one elevation class only measured errors set the floor: the chain's levels there are
    /// estimates (their mean plus the chain's offset), and one that reads better than anything
    /// measured would hold every representation to it. Here, as on a measured tree seen from
    /// straight above at 8 pixels, the chain (its level 1, 700 triangles) reads 0.012 better from
    /// above than over every view, so its level 0 is estimated at 0.048 there, under the chain's
    /// own row (0.054) and the full mesh (0.060). Counted, the floor 0.048 would leave the point
    /// tree (10 primitives, 0.062 from above) out of the target, and the chain would be drawn;
    /// measured only, the floor is the chain's row, 0.054, and the point tree is within it.
    #[test]
    fn from_an_elevation_only_measured_errors_set_the_floor() {
        let (full, spt, levels) = ((0.065, 1000.0), (0.070, 10.0), [(0.060, 900.0), (0.066, 700.0)]);
        let mut records = vec![record(code::FULL, 8.0, full.0, full.1), record(code::SPT, 8.0, spt.0, spt.1)];
        // The chain's row over every view: the level the default target picks, level 1.
        records.push(record(code::LOD_CHAIN, 8.0, levels[1].0, levels[1].1));
        records.sort_by_key(|r| r.technique);
        let levels: Vec<ChainCalibrationRecord> = (0u32..)
            .zip(levels)
            .map(|(level, (error, primitives))| ChainCalibrationRecord { level, height: 8.0, error, primitives })
            .collect();
        let seen = |elevation: f32, technique: u32, error: f32, primitives: f32| ElevationCalibrationRecord {
            elevation,
            technique,
            height: 8.0,
            error,
            primitives,
        };
        let mut per_elevation: Vec<ElevationCalibrationRecord> =
            records.iter().map(|r| seen(0.0, r.technique, r.error, r.primitives)).collect();
        per_elevation.extend([
            seen(90.0, code::FULL, 0.060, full.1),
            seen(90.0, code::SPT, 0.062, spt.1),
            seen(90.0, code::LOD_CHAIN, 0.054, 700.0),
        ]);
        per_elevation.sort_by(|a, b| a.elevation.total_cmp(&b.elevation).then(a.technique.cmp(&b.technique)));
        let c = Calibration::from_records(&records)
            .expect("rows")
            .with_elevations(&per_elevation)
            .with_chain_levels(&levels);
        let above = Some(1);
        let (estimate, _) = c.level_at_elevation(above, 0, 8.0).expect("level 0");
        assert!((estimate - 0.048).abs() < 1e-6, "{estimate}");
        assert!((c.floor(above, 8.0, all) - 0.054).abs() < 1e-6, "the chain's row from above");
        assert!((c.floor(None, 8.0, all) - 0.060).abs() < 1e-6, "level 0 over every view");
        assert!((c.floor(Some(0), 8.0, all) - 0.065).abs() < 1e-6, "from the side as measured there");
        assert_eq!(c.choose_at_elevation(above, 8.0, 0.01, all), Technique::Spt);
        assert_eq!(c.choose_at_elevation(None, 8.0, 0.01, all), Technique::Spt);
        // Without the chain the floor is the full mesh's.
        let no_chain = |t: Technique| t != Technique::LodChain;
        assert!((c.floor(above, 8.0, no_chain) - 0.060).abs() < 1e-6);
    }

    #[test]
    fn without_chain_tables_the_chain_keeps_the_geometric_rule() {
        let c = table();
        assert_eq!(c.chain_levels(), 0);
        assert_eq!(c.chain_level(8.0, 0.01, all), None);
        assert!(ChainChoices::new(&c, &Policy::default(), all).is_none());
        // A level missing at the start (level 1 without level 0) leaves no levels.
        let c =
            table().with_chain_levels(&[ChainCalibrationRecord { level: 1, height: 8.0, error: 0.1, primitives: 1.0 }]);
        assert_eq!(c.chain_levels(), 0);
    }

    /// In budget mode the chain's trees nearer than its tables reach, whose level is the
    /// tables' largest height's whatever their height, switch level over a range of targets,
    /// each at its own target class ([`TreeDither`]); without a budget all at one target. The
    /// tables are the same for every target within a lattice cell.
    #[test]
    fn in_budget_mode_near_chain_trees_switch_level_over_a_range_of_targets() {
        let c = chain_table();
        let trees: Vec<Mat4> = (0..400)
            .map(|k| Mat4::from_translation(Vec3::new(3.0 * (k % 20) as f32, 0.0, -3.0 * (k / 20) as f32)))
            .collect();
        // Trees at 200 px, over the tables' 64, whose geometric level is the coarsest: each
        // draws the largest height's level.
        let coarser = |budget: Option<u64>, target: f32| {
            let policy = Policy { target, budget, ..Policy::default() };
            let (choices, dither) = (ChainChoices::new(&c, &policy, all).expect("levels"), TreeDither::of(&policy));
            trees
                .iter()
                .filter(|t| {
                    let (h, class) = dither.apply(200.0, t);
                    assert!(h > 64.0, "above the tables: {h}");
                    choices.choose_in(h, class, None, || Some(2)) == Some(1)
                })
                .count()
        };
        // Level 1 (0.040 at 64 px against level 0's 0.022 and the full mesh's 0.020) comes
        // within from a target of about 0.02: from well under the spread to well over it.
        let reach = (BUDGET_TARGET_SPREAD as f32 / 2.0 + 1.5) * BUDGET_TARGET_STEP;
        let targets: Vec<f32> = (-20..=20).map(|k| 0.02 * (k as f32 / 20.0 * reach).exp2()).collect();
        let without: Vec<usize> = targets.iter().map(|&t| coarser(None, t)).collect();
        assert!(without.iter().all(|&n| n == 0 || n == trees.len()), "all at once: {without:?}");
        let with: Vec<usize> = targets.iter().map(|&t| coarser(Some(100_000), t)).collect();
        assert!(with.windows(2).all(|w| w[0] <= w[1]), "{with:?}");
        assert_eq!((with[0], with[with.len() - 1]), (0, trees.len()), "{with:?}");
        let mut distinct = with.clone();
        distinct.dedup();
        assert!(distinct.len() >= 10, "{with:?}");
        // One cell's targets share the tables; a tree without a class of its own reads the
        // middle one, the lattice target nearest the policy's.
        let at =
            |target: f32| ChainChoices::new(&c, &Policy { target, budget: Some(100_000), ..Policy::default() }, all);
        let (cell, _) = lattice_cell(0.0123);
        assert_eq!(lattice_cell(0.0127).0, cell);
        assert_eq!(at(0.0123), at(0.0127));
        let middle = ((cell + 1) as f32 * BUDGET_TARGET_STEP).exp2();
        let plain = ChainChoices::new(&c, &Policy { target: middle, ..Policy::default() }, all).expect("levels");
        assert_eq!(at(0.0123).expect("levels").steps(), plain.steps());
    }

    #[test]
    fn chain_levels_hold_across_a_boundary_within_the_hysteresis() {
        let c = chain_table();
        let with = |hysteresis: f32| {
            ChainChoices::new(&c, &Policy { target: 0.01, hysteresis, ..Policy::default() }, all).expect("levels")
        };
        let (held, plain) = (with(0.25), with(0.0));
        assert_eq!(held.steps().len(), 3 * STEPS_PER_OCTAVE as usize + 1);
        // Between 16 px (level 1) and 32 px (level 0) the choice crosses over once.
        let boundary = plain.steps().iter().position(|&l| l == Some(0)).expect("level 0 somewhere");
        assert!(plain.steps()[..boundary].ends_with(&[Some(1)]), "{:?}", plain.steps());
        let height = |step: usize| (8.0f32.log2() + step as f32 / STEPS_PER_OCTAVE).exp2();
        let just_past = height(boundary);
        assert_eq!(plain.choose(just_past, Some(Some(1)), || None), Some(0), "no hysteresis: switches");
        assert_eq!(held.choose(just_past, Some(Some(1)), || None), Some(1), "within 0.25 octaves: holds");
        assert_eq!(held.choose(just_past, None, || None), Some(0), "a new tree takes the choice");
        let far_past = height(boundary + 3);
        assert_eq!(held.choose(far_past, Some(Some(1)), || None), Some(0), "past the hysteresis: switches");
        // Below the range the smallest height's level; above it the finer of the top level and
        // the geometric rule's, so near trees reach the full mesh.
        assert_eq!(held.choose(1.0, None, || None), Some(2));
        assert_eq!(held.choose(1000.0, None, || Some(3)), Some(0));
        assert_eq!(held.choose(1000.0, None, || None), None);
    }

    /// The rule's choices of [`table`] at the default target every step from 8 pixels: five
    /// octaves, as [`Choices`] makes them.
    fn steps_of(c: &Calibration) -> Vec<Technique> {
        (0..=40).map(|i| c.choose((3.0 + i as f32 / STEPS_PER_OCTAVE).exp2(), 0.01, all)).collect()
    }

    /// A model 9 m high and 4 m wide with no cells: all a choice reads of it is its bounds.
    fn tall_lod() -> ModelLod {
        block_lod(2.0, 9.0)
    }

    /// A model `height` metres high and `2 · half` wide, standing on the origin, with no cells.
    fn block_lod(half: f32, height: f32) -> ModelLod {
        let block = treelod_format::BlockRecord {
            bounds_min: [-half, 0.0, -half],
            bounds_max: [half, height, half],
            grid: [1, 1, 1],
            tree_count: 1,
            flags: 0,
            _pad: 0,
        };
        ModelLod::from_records(&block, &[], &[], &[]).expect("model")
    }

    #[test]
    fn interpolates_in_log2_height_and_clamps() {
        let c = table();
        let (e, p) = c.at(Technique::Spt, 16.0).expect("spt");
        assert!((e - 0.5 * (0.064 + 0.039)).abs() < 1e-6, "{e}");
        assert!((p - 0.5 * (130.0 + 11_000.0)).abs() < 1e-2, "{p}");
        assert_eq!(c.at(Technique::Spt, 2.0), Some((0.064, 130.0)));
        assert_eq!(c.at(Technique::Spt, 4096.0), Some((0.012, 21_000.0)));
        assert_eq!(c.at(Technique::Impostors, 16.0), None);
        assert_eq!(c.heights(), (8.0, 256.0));
        assert!(Calibration::from_records(&[]).is_none());
        assert!(Calibration::from_records(&[record(99, 8.0, 0.1, 1.0)]).is_none(), "unknown codes are skipped");
    }

    #[test]
    fn chooses_the_cheapest_within_the_target_of_the_full_mesh() {
        let c = table();
        // 8 px: crossed (3) is within 0.01 of the full mesh's 0.060.
        assert_eq!(c.choose(8.0, 0.01, all), Technique::Crossed);
        // A tighter target: only the point tree qualifies.
        assert_eq!(c.choose(8.0, 0.005, all), Technique::Spt);
        // 32 px: the point tree (11,000) and the chain (11,100) qualify; the point tree is cheaper.
        assert_eq!(c.choose(32.0, 0.01, all), Technique::Spt);
        // Without the point tree's cut available, the chain.
        assert_eq!(c.choose(32.0, 0.01, |t| t != Technique::Spt), Technique::LodChain);
        // Nothing within the target: the least error (never the full mesh itself).
        assert_eq!(c.choose(32.0, 0.0, |t| t != Technique::Spt), Technique::LodChain);
        assert_eq!(c.choose(8.0, 0.0, all), Technique::Spt);
        // Nothing usable at all: the fallback.
        assert_eq!(c.choose(8.0, 0.01, |_| false), Technique::FALLBACK);
    }

    #[test]
    fn a_negative_or_nan_target_asks_for_the_full_mesh_image() {
        let c = table();
        assert_eq!(c.choose(8.0, f32::NAN, all), c.choose(8.0, 0.0, all));
        assert_eq!(c.choose(8.0, -1.0, all), c.choose(8.0, 0.0, all));
        let policy = Policy { target: f32::INFINITY, hysteresis: -2.0, budget: None, transition: 0, occlusion: false };
        assert_eq!((policy.target(), policy.hysteresis()), (0.0, 0.0));
    }

    fn representations_holding_everything() -> Representations {
        // `holds` of the full mesh and the point tree is always true; the others need data this
        // test's tables do not ask for, so a usable set of {Spt} is what a plain model gives.
        Representations::default()
    }

    /// [`table`] with tables per elevation: from the side (0°) as over every view; from above
    /// (90°) the crossed quads read 0.2 at every height (seen from above they are three lines).
    fn table_with_elevations() -> Calibration {
        let mean = table();
        let mut records = Vec::new();
        for (elevation, crossed) in [(0.0, None), (90.0, Some(0.2))] {
            for technique in [Technique::Full, Technique::Spt, Technique::LodChain, Technique::Crossed] {
                for h in [8.0, 32.0, 128.0, 256.0] {
                    let (error, primitives) = mean.at(technique, h).unwrap();
                    let error = if technique == Technique::Crossed { crossed.unwrap_or(error) } else { error };
                    records.push(ElevationCalibrationRecord {
                        elevation,
                        technique: technique.index() as u32,
                        height: h,
                        error,
                        primitives,
                    });
                }
            }
        }
        records.sort_by(|a, b| a.elevation.total_cmp(&b.elevation).then(a.technique.cmp(&b.technique)));
        mean.with_elevations(&records)
    }

    /// Under [`Choices::uniform_below`]'s height every elevation class above the horizon,
    /// visibility class, share in view and last frame's technique gives its technique; the
    /// chooser, which takes it without those, chooses as it did. Where the classes' smallest
    /// trees differ, there is no such height.
    #[test]
    fn under_the_uniform_height_every_view_and_past_chooses_the_same() {
        use treelod_build::SplitMix64;
        let mut rows: Vec<CalibrationRecord> = Vec::new();
        let mean = table();
        for technique in [Technique::Full, Technique::Spt, Technique::Crossed, Technique::LodChain] {
            for h in [8.0, 32.0, 128.0, 256.0] {
                let (error, primitives) = mean.at(technique, h).unwrap();
                rows.push(record(technique.index() as u32, h, error, primitives));
            }
        }
        // From above, the crossed quads fail from 32 pixels up instead of from 64: the classes'
        // tables differ, but all choose the quads for the smallest trees.
        let mut records = Vec::new();
        for elevation in [0.0, 90.0] {
            for technique in [Technique::Full, Technique::Spt, Technique::LodChain, Technique::Crossed] {
                for h in [8.0, 32.0, 128.0, 256.0] {
                    let (error, primitives) = mean.at(technique, h).unwrap();
                    let failing = technique == Technique::Crossed && elevation > 0.0 && h >= 32.0;
                    let error = if failing { 0.2 } else { error };
                    let technique = technique.index() as u32;
                    records.push(ElevationCalibrationRecord { elevation, technique, height: h, error, primitives });
                }
            }
        }
        records.sort_by(|a, b| a.elevation.total_cmp(&b.elevation).then(a.technique.cmp(&b.technique)));
        let c = Calibration::from_records(&rows).expect("rows").with_elevations(&records);
        let mut rng = SplitMix64(5);
        for (occlusion, hysteresis) in [(false, 0.0), (true, Policy::default().hysteresis), (true, 0.5)] {
            let policy = Policy { target: 0.01, hysteresis, budget: None, transition: 0, occlusion };
            let choices = Choices::among(&c, &policy, all);
            let (below, uniform) = choices.uniform_below().expect("one technique for the smallest trees");
            assert!(below > 4.0, "{below}: the tables share their first step");
            let classes = choices.elevations().len().max(1);
            for _ in 0..2000 {
                let height = rng.range(0.0, 1.0) * below;
                let elevation = rng.range(0.0, classes as f32) as usize;
                let previous = Technique::ALL.get(rng.range(0.0, 12.0) as usize).copied();
                let (visible, in_view) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
                let chosen = choices.choose_framed(height, elevation, visible, in_view, previous);
                assert_eq!(chosen, uniform, "{height} px, class {elevation}, {visible}, {in_view}, after {previous:?}");
            }
            // The bound is the tables': a step or so above it, some view or past chooses otherwise.
            let above = below * (3.0 / STEPS_PER_OCTAVE).exp2();
            let differs = (0..classes).chain([BELOW_HORIZON]).any(|e| {
                Technique::ALL.iter().any(|&p| choices.choose_framed(above, e, 1.0, 1.0, Some(p)) != uniform)
                    || choices.choose_framed(above, e, 1.0, 1.0, None) != uniform
            });
            assert!(differs, "occlusion {occlusion}, hysteresis {hysteresis}: {below} is not the tables' bound");
        }
        // Where the classes differ at the smallest trees (the quads fail from above at every
        // height), no height is uniform.
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let differ = Choices::among(&table_with_elevations(), &policy, all);
        assert_ne!(differ.choose_viewed(8.0, 0, 1.0, None), differ.choose_viewed(8.0, 3, 1.0, None));
        assert_eq!(differ.uniform_below(), None);
        // Each class keeps its own height: under it, whatever the visibility, share in view and
        // past, that class's smallest trees' technique.
        let last = differ.elevations().len() - 1;
        let (side, above) = (differ.uniform_below_in(0), differ.uniform_below_in(last));
        assert!(side.zip(above).is_some_and(|(s, a)| s.1 != a.1), "{side:?} {above:?}");
        assert_eq!(differ.uniform_below_in(BELOW_HORIZON), None);
        assert_eq!(differ.uniform_below_in(99), above, "past the last class: the last");
        for e in 0..differ.elevations().len() {
            let (below, uniform) = differ.uniform_below_in(e).expect("every class starts with one technique");
            for _ in 0..500 {
                let height = rng.range(0.0, 1.0) * below;
                let previous = Technique::ALL.get(rng.range(0.0, 12.0) as usize).copied();
                let (visible, in_view) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
                let chosen = differ.choose_framed(height, e, visible, in_view, previous);
                assert_eq!(chosen, uniform, "{height} px, class {e}, {visible}, {in_view}, after {previous:?}");
            }
        }
    }

    /// The runs of a class's steps start where its technique changes, at the heights a fresh
    /// choice changes at, and expand back to the steps.
    #[test]
    fn runs_start_where_the_choice_changes_and_expand_to_the_steps() {
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let choices = Choices::among(&table_with_elevations(), &policy, all);
        let mut changes = 0;
        for e in 0..choices.elevations().len() {
            let runs = choices.runs_at(e);
            let steps = choices.steps_at(e);
            assert_eq!(runs[0].0, table_with_elevations().heights().0, "the first from the smallest height");
            assert!(runs.windows(2).all(|w| w[0].0 < w[1].0 && w[0].1 != w[1].1), "{runs:?}");
            // Expanded: each step's technique is its run's.
            let expanded: Vec<Technique> = (0..steps.len())
                .map(|i| {
                    let height = runs[0].0 * (i as f32 / STEPS_PER_OCTAVE).exp2();
                    runs.iter().rev().find(|r| r.0 <= height * 1.0001).map(|r| r.1).expect("a run")
                })
                .collect();
            assert_eq!(expanded, steps, "class {e}");
            // A fresh choice just under a run's start is the run before's, at it the run's own.
            for w in runs.windows(2) {
                assert_eq!(choices.choose_viewed(w[1].0 * 1.001, e, 1.0, None), w[1].1);
                assert_eq!(choices.choose_viewed(w[1].0 * (-1.0 / STEPS_PER_OCTAVE).exp2(), e, 1.0, None), w[0].1);
                changes += 1;
            }
        }
        assert!(changes > 0, "the tables choose more than one technique");
    }

    /// A short run between two others takes the neighbour admissible over all of it, the one of
    /// fewer primitives over the run, where that draws at most [`MERGE_COST`] times the run's
    /// own; a run an octave long, a run no neighbour can take or only at a higher cost, and the
    /// first and last runs stay.
    #[test]
    fn a_short_run_merges_into_a_neighbour_admissible_over_it() {
        use Technique::{Billboard as B, Crossed as C, Ellipsoids as E, Impostors as I, Spt as S};
        let n = SHORTEST_RUN_STEPS;
        // (technique, primitives) admissible at each step, then the steps as chosen.
        let mut admissible: Vec<Vec<(Technique, f32)>> = Vec::new();
        let mut steps = Vec::new();
        let mut run = |t: Technique, own: f32, len: usize, others: &[(Technique, f32)]| {
            for _ in 0..len {
                steps.push(t);
                admissible.push([&[(t, own)][..], others].concat());
            }
        };
        run(B, 1.0, 2, &[]); // first: short, stays
        run(S, 100.0, 5, &[]);
        run(C, 30.0, 3, &[(S, 100.0), (I, 40.0)]); // the impostors: admissible, cheaper, within 2×
        run(I, 40.0, 2 * n, &[]);
        run(E, 200.0, n, &[(I, 40.0)]); // an octave: stays
        run(S, 300.0, n - 1, &[(E, 600.0)]); // the ellipsoids: twice the run's primitives, merges
        run(C, 3.0, 2, &[(B, 1.0)]); // no neighbour admissible (billboards are not one): stays
        run(I, 40.0, 4, &[]);
        run(S, 100.0, 2, &[(I, 201.0)]); // the impostors admissible, but over twice: stays
        run(I, 40.0, 3, &[]);
        run(B, 1.0, 1, &[]); // last: short, stays
        let mut merged = steps.clone();
        merge_short_runs(&mut merged, listed(&admissible));
        let lengths = |s: &[Technique]| runs_of(s).into_iter().map(|r| (s[r.start], r.len())).collect::<Vec<_>>();
        assert_eq!(
            lengths(&merged),
            [(B, 2), (S, 5), (I, 3 + 2 * n), (E, 2 * n - 1), (C, 2), (I, 4), (S, 2), (I, 3), (B, 1)],
            "from {:?}",
            lengths(&steps)
        );
        // Every step keeps a technique admissible there.
        assert!(merged.iter().zip(&admissible).all(|(t, a)| a.iter().any(|c| c.0 == *t)));
        // A run between two of one technique takes it, and the two merge: A B A is one run.
        let mut steps = vec![S, S, C, S, S];
        let admissible: Vec<Vec<(Technique, f32)>> =
            (0..5).map(|i| if i == 2 { vec![(C, 3.0), (S, 5.0)] } else { vec![(S, 5.0)] }).collect();
        merge_short_runs(&mut steps, listed(&admissible));
        assert_eq!(steps, [S; 5]);
        // Merges do not compound: each is held to the rule's own choices. A run of one step
        // (1 primitive) takes its neighbour (2); that run, now 3 steps, may not take the next
        // (4 a step: 12 against twice the rule's 1 + 2 + 2), though it may against its own 6.
        let mut steps = [[C; 8].as_slice(), &[B], &[I, I], &[E; 8], &[S; 8]].concat();
        let admissible: Vec<Vec<(Technique, f32)>> = steps
            .iter()
            .map(|&t| match t {
                B => vec![(B, 1.0), (I, 2.0), (E, 4.0)],
                I => vec![(I, 2.0), (E, 4.0)],
                _ => vec![(t, 4.0)],
            })
            .collect();
        merge_short_runs(&mut steps, listed(&admissible));
        assert_eq!(lengths(&steps), [(C, 8), (I, 3), (E, 8), (S, 8)]);
    }

    /// `Choices::among` reads once what does not depend on the target (the judgements but the
    /// chain's, the floors) and picks the chain's level once for every elevation class, in
    /// parallel: its tables are those of each table judged on its own at every height
    /// ([`Calibration::judge`]), whatever the thread count, with FLIP tables and without.
    #[test]
    fn the_choices_are_each_table_judged_on_its_own_whatever_the_thread_count() {
        let every = FlipCalibrationRecord::EVERY_VIEW;
        let heights = [8.0, 16.0, 32.0, 64.0];
        let mut rows = Vec::new();
        for (elevation, worse) in [(every, 0.0), (0.0, 0.002), (90.0, 0.01)] {
            for (technique, flip) in [(code::FULL, 0.05), (code::SPT, 0.06), (code::LOD_CHAIN, 0.055)] {
                rows.extend(heights.map(|h| flip_row(elevation, technique, h, flip + worse + 0.1 / h)));
            }
        }
        let levels = level_flips(&[(0, 8.0, 0.06), (0, 64.0, 0.05), (1, 8.0, 0.07), (1, 64.0, 0.06), (2, 8.0, 0.2)]);
        let plain = chain_table_with_elevations();
        let flip = plain.clone().with_flip(&rows).with_chain_flip(&levels);
        assert!(flip.has_flip() && plain.chain_levels() == 3 && plain.elevations().len() == 2);
        let in_pool = |threads: usize, c: &Calibration, policy: &Policy| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool");
            pool.install(|| Choices::among(c, policy, all))
        };
        for c in [&plain, &flip] {
            // One basis serves every policy.
            let basis = ChoiceBasis::among(c, all);
            for (target, occlusion) in [(0.0, false), (0.003, true), (0.01, true), (0.05, false)] {
                let policy = Policy { target, occlusion, ..Policy::default() };
                let choices = in_pool(1, c, &policy);
                assert_eq!(choices, in_pool(3, c, &policy));
                assert_eq!(choices, Choices::from_basis(&basis, &policy));
                let between = c.with_elevations_between(ELEVATION_SUBDIVISIONS);
                let grid = StepGrid::of(&between);
                let heights: Vec<f32> = (0..grid.count).map(|i| grid.height(i)).collect();
                let own = |elevation: Option<usize>, target: f32, usable: &dyn Fn(Technique) -> bool| {
                    let judged: Vec<Judged> =
                        heights.iter().map(|&h| between.judge(elevation, h, target_at(target, h), usable)).collect();
                    Choices::table(&between, &heights, elevation, target, usable, &judged)
                };
                let targets = class_targets(target, choices.visibility, choices.dither.cell.map(|c| c.0));
                let tables: Vec<Table> = (0..between.elevations().len())
                    .flat_map(|e| targets.iter().map(move |&t| (e, t)))
                    .map(|(e, t)| own(Some(e), t, &all))
                    .collect();
                assert_eq!(choices.tables, tables, "target {target}");
                let below: Vec<Table> =
                    targets.iter().map(|&t| own(Some(0), t, &|t| !upper_hemisphere_only(t))).collect();
                assert_eq!(choices.below, below, "target {target}");
                // The tables are not all alike: the test sees the chain's levels and the classes.
                assert!(choices.tables.iter().any(|t| t.steps.contains(&Technique::LodChain)), "target {target}");
            }
        }
    }

    /// A representation within the target over less than an octave (ellipsoids measured near the
    /// full mesh at 16 pixels alone) leaves no run of its own between the point tree's where the
    /// point tree, admissible there, draws at most twice its primitives; it keeps its run where
    /// the point tree draws more, or where it is within the target over more than an octave.
    #[test]
    fn the_choices_merge_a_technique_within_the_target_over_less_than_an_octave() {
        let with_ellipsoids = |good: &[f32], share: f32| {
            let mut records = Vec::new();
            for h in [8.0, 16.0, 32.0, 64.0] {
                records.push(record(code::FULL, h, 0.050, 10_000.0));
                records.push(record(code::SPT, h, 0.052, 100.0 * h));
                let error = if good.contains(&h) { 0.055 } else { 0.080 };
                records.push(record(code::ELLIPSOIDS, h, error, share * 100.0 * h));
            }
            Calibration::from_records(&records).expect("rows")
        };
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let techniques = |c: &Choices| c.runs_at(0).into_iter().map(|r| r.1).collect::<Vec<_>>();
        let (spt, ellipsoids) = (Technique::Spt, Technique::Ellipsoids);
        let narrow = with_ellipsoids(&[16.0], 0.6);
        // The rule alone takes the ellipsoids about 16 pixels, for under an octave.
        assert_eq!(narrow.choose(16.0, 0.01, all), ellipsoids);
        assert_eq!(narrow.choose(11.0, 0.01, all), spt);
        assert_eq!(narrow.choose(23.0, 0.01, all), spt);
        let choices = Choices::among(&narrow, &policy, all);
        assert_eq!(techniques(&choices), [spt]);
        assert_eq!(choices.choose(16.0, None), spt);
        // The point tree at over twice the ellipsoids' primitives: they keep their run.
        let cheap = Choices::among(&with_ellipsoids(&[16.0], 0.4), &policy, all);
        assert_eq!(techniques(&cheap), [spt, ellipsoids, spt]);
        // Over 16 to 32 pixels, an octave and more, the ellipsoids keep their run.
        let wide = Choices::among(&with_ellipsoids(&[16.0, 32.0], 0.6), &policy, all);
        assert_eq!(techniques(&wide), [spt, ellipsoids, spt]);
        assert_eq!(wide.choose(22.6, None), ellipsoids);
    }

    /// Whose visible fraction matters ([`PolicyState::visibility_matters`]): not a tree out of
    /// view, nor one the uniform height's technique chose under [`VISIBILITY_LEAD`] of that
    /// height; a tree between that and the height, one above it and one of a model without
    /// tables do, and where that technique prunes (it reads the fraction) so does every tree in
    /// view.
    #[test]
    fn the_visible_fraction_matters_where_it_can_change_the_choice_or_the_pruning() {
        let policy = Policy { hysteresis: 0.0, transition: 0, ..Policy::default() };
        assert!(policy.occlusion, "on by default");
        let lods = [tall_lod(), tall_lod()];
        let eye = lods[0].centre();
        let camera = Camera::look_at(eye, eye - Vec3::Z, 0.8, 256, 256);
        for pruned in [false, true] {
            // The crossed quads, or Cook's pruning as good as the full mesh in 60 primitives,
            // for the smallest trees.
            let calibration = if pruned { table_with_cheap(Some((code::PRUNE_COOK, 60.0))) } else { table() };
            let choices = Choices::among(&calibration, &policy, |t| !(pruned && t == Technique::Crossed));
            let (below, uniform) = choices.uniform_below().expect("one technique for the smallest trees");
            assert_eq!(prunes(uniform), pruned, "{uniform:?}");
            // (Height as a share of the uniform one, model, ahead of the eye or behind it.)
            let trees = [(0.25, 0, true), (0.75, 0, true), (4.0, 0, true), (0.25, 1, true), (0.25, 0, false)];
            let instances: Vec<Instance> = trees
                .iter()
                .map(|&(share, model, ahead)| {
                    let distance = distance_for_height(&lods[0], share * below, &camera);
                    let z = if ahead { -distance } else { distance };
                    Instance { model, transform: Mat4::from_translation(Vec3::new(0.0, 0.0, z)) }
                })
                .collect();
            let (choices, mut out, mut state) = ([Some(choices), None], Vec::new(), PolicyState::default());
            choose_instances(&instances, &lods, &choices, &camera, Technique::Spt, &mut state, &mut out);
            assert_eq!(out[..2], [Some(uniform), Some(uniform)], "under the height, in view");
            assert_eq!((out[3], out[4]), (Some(Technique::Spt), None), "no tables; out of view");
            let matters: Vec<bool> = (0..trees.len()).map(|i| state.visibility_matters(i)).collect();
            assert_eq!(matters, [pruned, true, true, true, false], "{uniform:?} under {below} px");
            assert_eq!(state.visibility_flags(), matters, "the flags are the same answers");
            assert!(state.visibility_matters(trees.len()), "past the instances chosen");
        }
    }

    #[test]
    fn elevation_classes_are_the_nearest_for_a_new_tree_and_change_a_quarter_past_the_midpoint() {
        let centres = [0.0, 30.0, 60.0, 90.0];
        for (elevation, class) in [(-40.0, 0), (0.0, 0), (14.9, 0), (15.0, 1), (50.0, 2), (80.0, 3), (f32::NAN, 0)] {
            assert_eq!(elevation_class_after(None, elevation, &centres), class, "{elevation}°");
        }
        // From class 0 upwards: past 15° + 7.5°; and straight to the class the view reaches.
        assert_eq!(elevation_class_after(Some(0), 22.0, &centres), 0);
        assert_eq!(elevation_class_after(Some(0), 23.0, &centres), 1);
        assert_eq!(elevation_class_after(Some(0), 50.0, &centres), 1, "not yet past 45° + 7.5°");
        assert_eq!(elevation_class_after(Some(0), 53.0, &centres), 2);
        assert_eq!(elevation_class_after(Some(0), 89.0, &centres), 3);
        // Downwards: under 45° - 7.5°.
        assert_eq!(elevation_class_after(Some(2), 38.0, &centres), 2);
        assert_eq!(elevation_class_after(Some(2), 37.0, &centres), 1);
        assert_eq!(elevation_class_after(Some(2), -5.0, &centres), 0);
        // One class: always it.
        assert_eq!(elevation_class_after(Some(0), 80.0, &[0.0]), 0);
    }

    #[test]
    fn trees_seen_from_above_are_chosen_by_the_tables_of_views_from_above() {
        let c = table_with_elevations();
        assert_eq!(c.elevations(), [0.0, 90.0]);
        assert_eq!(c.at_elevation(Some(1), Technique::Crossed, 8.0), Some((0.2, 3.0)));
        assert_eq!(c.at_elevation(None, Technique::Crossed, 8.0), c.at(Technique::Crossed, 8.0));
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let choices = Choices::among(&c, &policy, all);
        // Classes every 30° between the measured 0° and 90° (ELEVATION_SUBDIVISIONS).
        assert_eq!(choices.elevations(), [0.0, 30.0, 60.0, 90.0]);
        // Small trees: crossed quads from the side, the point tree from above.
        assert_eq!(choices.choose_viewed(8.0, 0, 1.0, None), Technique::Crossed);
        assert_eq!(choices.choose_viewed(8.0, 3, 1.0, None), Technique::Spt);
        assert_eq!(choices.steps_at(0), steps_of(&c).as_slice(), "from the side as over every view");
        assert!(choices.steps_at(3).iter().all(|&t| t != Technique::Crossed), "{:?}", choices.steps_at(3));
        // Per instance: a tree 8 px high seen from the side and one seen from straight above.
        let lods = [tall_lod()];
        let camera = Camera::look_at(Vec3::new(0.0, 4.5, 100.0), Vec3::new(0.0, 4.5, 0.0), 0.8, 256, 256);
        let distance = distance_for_height(&lods[0], 8.0, &camera);
        let side = Camera::look_at(Vec3::new(0.0, 4.5, distance), Vec3::new(0.0, 4.5, 0.0), 0.8, 256, 256);
        let above = Camera::look_at(Vec3::new(0.0, 4.5 + distance, 0.01), Vec3::new(0.0, 4.5, 0.0), 0.8, 256, 256);
        assert!((view_elevation(&lods[0], Mat4::IDENTITY, above.position) - 89.9).abs() < 0.1);
        let instances = [Instance { model: 0, transform: Mat4::IDENTITY }];
        let choices = [Some(choices)];
        let mut out = Vec::new();
        for (camera, expected) in [(side, Technique::Crossed), (above, Technique::Spt)] {
            let mut state = PolicyState::default();
            choose_instances(&instances, &lods, &choices, &camera, Technique::Spt, &mut state, &mut out);
            assert_eq!(out, [Some(expected)]);
        }
        // Without tables per elevation every view reads the tables over every view.
        let mean = Choices::among(&table(), &policy, all);
        let mut state = PolicyState::default();
        choose_instances(&instances, &lods, &[Some(mean)], &above, Technique::Spt, &mut state, &mut out);
        assert_eq!(out, [Some(Technique::Crossed)]);
    }

    /// A tree seen from below the tables (more than half the classes' spacing below 0°) is not
    /// drawn with a representation that holds only views from above (the octahedral impostor),
    /// with a quarter of the spacing of hysteresis; from the side it is.
    #[test]
    fn trees_seen_from_below_are_not_drawn_with_views_from_above() {
        let mean = table();
        let mut records = Vec::new();
        for elevation in [0.0, 90.0] {
            for technique in [Technique::Full, Technique::Spt, Technique::LodChain, Technique::Crossed] {
                for h in [8.0, 32.0, 128.0, 256.0] {
                    let (error, primitives) = mean.at(technique, h).unwrap();
                    let technique = technique.index() as u32;
                    records.push(ElevationCalibrationRecord { elevation, technique, height: h, error, primitives });
                }
            }
            // The octahedral impostor: one quad, the floor's error at 8 px.
            for h in [8.0, 32.0, 128.0, 256.0] {
                let technique = Technique::Octahedral.index() as u32;
                records.push(ElevationCalibrationRecord {
                    elevation,
                    technique,
                    height: h,
                    error: 0.06,
                    primitives: 1.0,
                });
            }
        }
        records.sort_by(|a, b| a.elevation.total_cmp(&b.elevation).then(a.technique.cmp(&b.technique)));
        let mut rows: Vec<CalibrationRecord> = Vec::new();
        for technique in [Technique::Full, Technique::Spt, Technique::Crossed, Technique::LodChain] {
            for h in [8.0, 32.0, 128.0, 256.0] {
                let (error, primitives) = mean.at(technique, h).unwrap();
                rows.push(record(technique.index() as u32, h, error, primitives));
            }
        }
        rows.extend([8.0, 32.0, 128.0, 256.0].map(|h| record(Technique::Octahedral.index() as u32, h, 0.06, 1.0)));
        let c = Calibration::from_records(&rows).expect("rows").with_elevations(&records);
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let choices = Choices::among(&c, &policy, all);
        assert_eq!(choices.elevations(), [0.0, 30.0, 60.0, 90.0]);
        assert_eq!(choices.choose_viewed(8.0, 0, 1.0, None), Technique::Octahedral, "from the side");
        assert_eq!(choices.choose_viewed(8.0, BELOW_HORIZON, 1.0, None), Technique::Crossed, "from below");
        // Classes 30° apart: below past −15°, back above −7.5° (−22.5° to go below again).
        assert!(!choices.below_horizon(-14.0, false) && choices.below_horizon(-23.0, false));
        assert!(choices.below_horizon(-8.0, true) && !choices.below_horizon(-7.0, true));
        assert!(!choices.below_horizon(f32::NAN, true));
        // Without a technique held only from above, nothing is below.
        let without = Choices::among(&c, &policy, |t| t != Technique::Octahedral);
        assert!(!without.below_horizon(-80.0, false));
        assert_eq!(without.choose_viewed(8.0, BELOW_HORIZON, 1.0, None), without.choose_viewed(8.0, 0, 1.0, None));
        // Per instance: a tree 8 px high seen from 40° below, then from the side.
        let lods = [tall_lod()];
        let camera = Camera::look_at(Vec3::new(0.0, 4.5, 100.0), Vec3::new(0.0, 4.5, 0.0), 0.8, 256, 256);
        let distance = distance_for_height(&lods[0], 8.0, &camera);
        let (sin, cos) = 40f32.to_radians().sin_cos();
        let centre = lods[0].centre();
        let below = Camera::look_at(centre + distance * Vec3::new(0.0, -sin, cos), centre, 0.8, 256, 256);
        let side = Camera::look_at(centre + distance * Vec3::Z, centre, 0.8, 256, 256);
        let instances = [Instance { model: 0, transform: Mat4::IDENTITY }];
        // The smallest trees are all octahedral from above the horizon: the chooser takes that
        // without looking them up, but not from below.
        let (under, uniform) = choices.uniform_below().expect("octahedral for the smallest trees");
        assert!(under > 8.0 && uniform == Technique::Octahedral, "{under} {uniform:?}");
        let (choices, mut out, mut state) = ([Some(choices)], Vec::new(), PolicyState::default());
        choose_instances(&instances, &lods, &choices, &below, Technique::Spt, &mut state, &mut out);
        assert_eq!(out, [Some(Technique::Crossed)]);
        choose_instances(&instances, &lods, &choices, &side, Technique::Spt, &mut state, &mut out);
        assert_eq!(out, [Some(Technique::Octahedral)]);
    }

    /// Between two measured elevations the classes' tables blend them linearly in elevation, at
    /// every height either samples, and a class between them chooses by the blend.
    #[test]
    fn elevation_classes_between_measured_ones_blend_their_tables() {
        let c = table_with_elevations();
        let fine = c.with_elevations_between(ELEVATION_SUBDIVISIONS);
        assert_eq!(fine.elevations(), [0.0, 30.0, 60.0, 90.0]);
        assert_eq!(c.with_elevations_between(1), c, "one subdivision: the tables as they are");
        assert_eq!(table().with_elevations_between(3), table(), "no tables per elevation: unchanged");
        for technique in Technique::ALL {
            for h in [4.0, 8.0, 11.3, 16.0, 64.0, 300.0] {
                let (Some(side), Some(above)) =
                    (c.at_elevation(Some(0), technique, h), c.at_elevation(Some(1), technique, h))
                else {
                    assert_eq!(fine.at_elevation(Some(1), technique, h), None, "{technique:?}");
                    continue;
                };
                assert_eq!(fine.at_elevation(Some(0), technique, h), Some(side));
                assert_eq!(fine.at_elevation(Some(3), technique, h), Some(above));
                for (class, t) in [(1, 1.0 / 3.0), (2, 2.0 / 3.0)] {
                    let (e, p) = fine.at_elevation(Some(class), technique, h).expect("blended");
                    let expected = (side.0 + t * (above.0 - side.0), side.1 + t * (above.1 - side.1));
                    assert!(
                        (e - expected.0).abs() < 1e-6,
                        "{technique:?} {h} px class {class}: {e} against {expected:?}"
                    );
                    assert!((p - expected.1).abs() < 1e-3 * expected.1.max(1.0), "{p} against {expected:?}");
                }
            }
        }
        // The tables over every view and the chain's levels are kept.
        assert_eq!(fine.at(Technique::Crossed, 8.0), c.at(Technique::Crossed, 8.0));
        // Crossed quads read 0.2 from above, `table`'s value from the side: a class whose blend
        // puts them out of the target of the floor chooses otherwise.
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let choices = Choices::among(&c, &policy, all);
        for class in 0..4 {
            let expected = fine.choose_at_elevation(Some(class), 8.0, 0.01, all);
            assert_eq!(choices.choose_viewed(8.0, class, 1.0, None), expected, "class {class}");
        }
        // At 8 px the floor is the full mesh's 0.060: crossed quads (0.067 from the side) are
        // within 0.01 of it only at 0°; at 30° they read 0.067 + (0.2 − 0.067)/3 = 0.111, and the
        // point tree (0.064) is chosen, where the nearer measured class (0°) chose the quads.
        let chosen: Vec<Technique> = (0..4).map(|class| choices.choose_viewed(8.0, class, 1.0, None)).collect();
        assert_eq!(chosen, [Technique::Crossed, Technique::Spt, Technique::Spt, Technique::Spt]);
    }

    #[test]
    fn choice_tables_follow_the_rule_and_fall_back_above_the_range() {
        let c = table();
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let choices = Choices::new(&c, &policy, &representations_holding_everything());
        // A plain model draws only the point tree: every step is it.
        assert!(choices.steps().iter().all(|&t| t == Technique::Spt));
        assert_eq!(choices.steps().len(), 5 * STEPS_PER_OCTAVE as usize + 1);
        assert_eq!(choices.choose(10_000.0, None), Technique::FALLBACK);
    }

    #[test]
    fn above_the_range_the_top_choice_holds_only_if_it_converges_to_the_full_mesh() {
        assert!(!converges(Technique::PruneOpt) && converges(Technique::LodChain) && !converges(Technique::Impostors));
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        // The point tree cheapest at the top: it holds nearer.
        let choices = Choices::among(&table(), &policy, all);
        assert_eq!(choices.steps().last(), Some(&Technique::Spt));
        assert_eq!(choices.choose(10_000.0, None), Technique::Spt);
        // Without the point tree the chain (the full mesh there) is the top choice and holds.
        let choices = Choices::among(&table(), &policy, |t| t != Technique::Spt);
        assert_eq!(choices.steps().last(), Some(&Technique::LodChain));
        assert_eq!(choices.choose(10_000.0, None), Technique::LodChain);
        // The full mesh, the point tree and the chain at 8 and 256 pixels, and technique `other`
        // with its errors there and its primitives.
        let beside = |other: u32, errors: [f32; 2], primitives: f32| {
            let mut records = Vec::new();
            for ((h, spt, chain), error) in [(8.0, 0.06, 0.2), (256.0, 0.012, 0.012)].into_iter().zip(errors) {
                records.push(record(code::FULL, h, 0.012, 22_500.0));
                records.push(record(code::SPT, h, spt, 21_000.0));
                records.push(record(code::LOD_CHAIN, h, chain, 20_000.0));
                records.push(record(other, h, error, primitives));
            }
            records.sort_by_key(|r| r.technique);
            Calibration::from_records(&records).unwrap()
        };
        // Crossed quads that win the top height keep their error near: above, the rule chooses
        // among the techniques that converge, the chain here (fewer primitives than the point
        // tree at the same error) for a tree wholly in view, the point tree (which culls per
        // cell) for one partly in view.
        let choices = Choices::among(&beside(code::CROSSED, [0.05, 0.011], 3.0), &policy, all);
        assert_eq!(choices.steps().last(), Some(&Technique::Crossed));
        assert_eq!(choices.choose(10_000.0, None), Technique::LodChain);
        // Partly in view: the point tree where its whole-tree primitives (21,000) times the share
        // in view are fewer than the chain's (20,000), with a quarter of hysteresis.
        assert_eq!(choices.choose_framed(10_000.0, 0, 1.0, 0.99, None), Technique::LodChain);
        assert_eq!(choices.choose_framed(10_000.0, 0, 1.0, 0.9, None), Technique::FALLBACK);
        let spt = Some(Technique::FALLBACK);
        assert_eq!(choices.choose_framed(10_000.0, 0, 1.0, 0.99, spt), Technique::FALLBACK, "held");
        assert_eq!(choices.choose_framed(10_000.0, 0, 1.0, 0.8, Some(Technique::LodChain)), Technique::LodChain);
        assert_eq!(choices.choose_framed(10_000.0, 0, 1.0, 0.7, Some(Technique::LodChain)), Technique::FALLBACK);
        // Within the range the share in view does not matter.
        assert_eq!(choices.choose_framed(100.0, 0, 1.0, 0.1, None), choices.choose(100.0, None));
        assert!(choices.above_range(10_000.0) && !choices.above_range(100.0));
        // Pruning that wins the top height (the same error as the full mesh with half its
        // primitives) holds there and hands over above it: nearer, its λ(h) draws shares of the
        // leaves no table measured.
        for prune in [code::PRUNE_OPT, code::PRUNE_COOK] {
            let choices = Choices::among(&beside(prune, [0.012, 0.012], 11_000.0), &policy, all);
            let pruned = choices.steps().last().copied();
            assert!(matches!(pruned, Some(Technique::PruneOpt | Technique::PruneCook)), "{pruned:?}");
            assert_eq!(choices.choose(250.0, None), pruned.unwrap());
            assert_eq!(choices.choose(10_000.0, None), Technique::LodChain);
        }
    }

    #[test]
    fn hysteresis_keeps_last_frames_technique_near_a_boundary() {
        let c = table();
        let steps = steps_of(&c);
        let choices = Choices {
            log2_min: 3.0,
            tables: vec![Table { above: Technique::Spt, above_cost: (21_000.0, 21_000.0), steps }],
            elevations: Vec::new(),
            visibility: 1,
            below: Vec::new(),
            hysteresis_steps: 2,
            dither: TreeDither::NONE,
            uniform_by_class: Vec::new(),
        };
        // Find the boundary between crossed (small) and the point tree (larger).
        let boundary = choices.steps().iter().position(|&t| t != Technique::Crossed).expect("a boundary");
        assert!(boundary > 0);
        let height_at = |step: f32| (3.0 + step / STEPS_PER_OCTAVE).exp2();
        let after = choices.steps()[boundary];
        // Just past the boundary a tree that was crossed stays crossed; one without a past does not.
        assert_eq!(choices.choose(height_at(boundary as f32), Some(Technique::Crossed)), Technique::Crossed);
        assert_eq!(choices.choose(height_at(boundary as f32), None), after);
        // Three steps past it (beyond the two of hysteresis) it switches.
        assert_eq!(choices.choose(height_at(boundary as f32 + 3.0), Some(Technique::Crossed)), after);
        // A previous technique that is nowhere near is not kept.
        assert_eq!(choices.choose(height_at(0.0), Some(Technique::LodChain)), Technique::Crossed);
        // Every tree under two and a half steps short of the boundary is crossed, whatever it was:
        // the chooser takes that without looking the tree up. Half a step higher, a tree that
        // was drawn with the point tree keeps it.
        let (below, uniform) = choices.uniform(&choices.tables).expect("one technique below the boundary");
        assert_eq!(uniform, Technique::Crossed);
        assert!((below / height_at(boundary as f32 - 2.5) - 0.999).abs() < 1e-5, "{below}");
        for previous in [None, Some(after), Some(Technique::LodChain), Some(Technique::Crossed)] {
            for h in [below * 0.999_99, below * 0.5, 1.0, f32::MIN_POSITIVE] {
                assert_eq!(choices.choose(h, previous), Technique::Crossed, "{h} after {previous:?}");
            }
        }
        assert_eq!(choices.choose(height_at(boundary as f32 - 2.0), Some(after)), after);
    }

    #[test]
    fn a_tree_above_the_target_height_is_allowed_less_in_proportion_to_its_height() {
        assert_eq!(
            [8.0, 64.0, 128.0, 256.0, f32::NAN, -1.0].map(|h| target_at(0.01, h)),
            [0.01, 0.01, 0.005, 0.0025, 0.01, 0.01]
        );
        // Ellipsoids 0.008 over the full mesh at every height, a tenth of the point tree's cost.
        let mut records = Vec::new();
        for (h, full) in [(8.0, 0.060), (32.0, 0.030), (64.0, 0.020), (128.0, 0.017), (256.0, 0.012)] {
            records.push(record(code::FULL, h, full, 22_500.0));
            records.push(record(code::SPT, h, full + 0.001, 20_000.0));
            records.push(record(code::ELLIPSOIDS, h, full + 0.008, 2_000.0));
        }
        records.sort_by(|a, b| a.technique.cmp(&b.technique).then(a.height.total_cmp(&b.height)));
        let c = Calibration::from_records(&records).expect("rows");
        let policy = Policy { target: 0.01, hysteresis: 0.0, budget: None, transition: 0, occlusion: false };
        let choices = Choices::among(&c, &policy, all);
        // Within the target up to 64 pixels; above, the allowance falls under 0.008 at 80 pixels.
        for (height, expected) in [
            (8.0, Technique::Ellipsoids),
            (32.0, Technique::Ellipsoids),
            (64.0, Technique::Ellipsoids),
            (76.0, Technique::Ellipsoids),
            (84.0, Technique::Spt),
            (128.0, Technique::Spt),
            (256.0, Technique::Spt),
        ] {
            assert_eq!(choices.choose(height, None), expected, "{height} px");
        }
        // Twice the target moves the bound to twice the height.
        let loose = Choices::among(&c, &Policy { target: 0.02, ..policy }, all);
        assert_eq!([152.0, 168.0].map(|h| loose.choose(h, None)), [Technique::Ellipsoids, Technique::Spt]);
    }

    #[test]
    fn a_partly_hidden_tree_is_chosen_with_the_target_over_the_root_of_its_visible_fraction() {
        assert_eq!(
            [1.0, 0.8, 0.7, 0.5, 0.36, 0.35, 0.2, 0.17, 0.0, f32::NAN].map(visibility_class),
            [0, 0, 1, 1, 1, 2, 2, 3, 3, 0]
        );
        // A class changes a quarter of a class past its bound: 2^-0.75 = 0.59 from class 0,
        // 2^-1.75 = 0.30 from class 1 down, 2^-0.25 = 0.84 from class 1 up.
        assert_eq!([0.65, 0.55].map(|v| visibility_class_after(0, v)), [0, 1]);
        assert_eq!([0.32, 0.28, 0.8, 0.85, 1.0].map(|v| visibility_class_after(1, v)), [1, 2, 1, 0, 0]);
        assert_eq!(visibility_class_after(3, 0.2), 3, "0.2 is class 2, not a quarter past the bound 0.177");
        assert_eq!(visibility_class_after(0, 0.0), 3);
        // The bounds are looked up, the same bits as the rules' powers of two; a fraction of
        // exactly 2^-k reads as class k (the chooser passes its class on, `choose_in_class`).
        let bounds = class_bounds();
        for k in 0..VISIBILITY_CLASSES {
            let x = k as f32;
            assert_eq!(bounds.lower[k].to_bits(), (-x - 0.5).exp2().to_bits());
            assert_eq!(bounds.down[k].to_bits(), (-x - 0.75).exp2().to_bits());
            assert_eq!(bounds.up[k].to_bits(), (-x + 0.75).exp2().to_bits());
        }
        for k in 0..VISIBILITY_CLASSES + 3 {
            assert_eq!(visibility_class((-(k as f32)).exp2()), k.min(VISIBILITY_CLASSES - 1));
        }
        // Past the table (a class no state holds) the bounds are computed as before.
        assert_eq!(visibility_class_after(5, 0.0), 5);
        assert_eq!(visibility_class_after(5, 1.0), 0);
        let c = table();
        let policy = Policy { target: 0.005, hysteresis: 0.0, budget: None, transition: 0, occlusion: true };
        let choices = Choices::among(&c, &policy, all);
        let blind = Choices::among(&c, &Policy { occlusion: false, ..policy }, all);
        let mut cheaper = 0;
        for i in 0..choices.steps().len() {
            let height = (3.0 + i as f32 / STEPS_PER_OCTAVE).exp2();
            let visible_choice = choices.choose(height, None);
            for k in 0..VISIBILITY_CLASSES {
                let visible = (-(k as f32)).exp2();
                let expected = c.choose(height, target_at(0.005 * (k as f32 * 0.5).exp2(), height), all);
                assert_eq!(choices.choose_seen(height, visible, None), expected, "{height} px, {visible} visible");
                // Without occlusion every tree counts as fully visible.
                assert_eq!(blind.choose_seen(height, visible, None), visible_choice);
                let primitives = |t: Technique| c.at(t, height).map_or(0.0, |(_, p)| p);
                assert!(primitives(expected) <= primitives(visible_choice), "{height} px: never dearer hidden");
                cheaper += usize::from(primitives(expected) < primitives(visible_choice));
            }
        }
        assert!(cheaper > 0, "a hidden tree gets a cheaper choice somewhere");
    }

    #[test]
    fn a_change_of_technique_moves_a_step_per_frame_reverses_and_ends() {
        use Technique::{Crossed, Impostors, Spt};
        let run = |frames: u16, path: &[Technique]| -> Vec<Option<(Technique, u16)>> {
            let (mut previous, mut current) = (None, None);
            path.iter()
                .map(|&chosen| {
                    current = advance(previous, chosen, current, frames);
                    previous = Some(chosen);
                    current
                })
                .collect()
        };
        // A new tree starts without a transition; a change starts one that ends after 4 frames.
        assert_eq!(
            run(4, &[Spt, Crossed, Crossed, Crossed, Crossed]),
            [None, Some((Spt, 1)), Some((Spt, 2)), Some((Spt, 3)), None]
        );
        // Back mid-way: the other way from where it was (the crossed quads showed 2 of 4, the
        // point tree now shows 2 of 4, then 3).
        assert_eq!(
            run(4, &[Spt, Crossed, Crossed, Spt, Spt, Spt]),
            [None, Some((Spt, 1)), Some((Spt, 2)), Some((Crossed, 3)), None, None]
        );
        // On to a third technique: a new transition from the one it was going to.
        assert_eq!(run(4, &[Spt, Crossed, Impostors]), [None, Some((Spt, 1)), Some((Crossed, 1))]);
        // Without transitions, none.
        assert!(run(0, &[Spt, Crossed, Spt]).iter().all(Option::is_none));
        // The shares a state reports, and a shorter setting ends longer transitions.
        let mut state = PolicyState::with_transition(4);
        state.transitions = vec![Some((Spt, 1)), None, Some((Crossed, 3))];
        assert_eq!(state.transition(0), Some(Transition { from: Spt, shown: 0.25 }));
        assert_eq!(state.transition(1), None);
        assert_eq!(state.transitions().map(|(i, _)| i).collect::<Vec<_>>(), [0, 2]);
        state.set_transition(3);
        assert_eq!(state.transitions, [Some((Spt, 1)), None, None]);
        state.set_transition(3);
        assert_eq!(state.transitions, [Some((Spt, 1)), None, None], "the same frames end none");
        assert_eq!(state.transition(0).map(|t| t.shown), Some(1.0 / 3.0));
        state.set_transition(1);
        assert_eq!(state.transitions().count(), 0, "one frame: switch at once");
        assert_eq!(PolicyState::with_transition(10_000).frames, Policy::MAX_TRANSITION as u16);
    }

    /// [`table`]'s choices without hysteresis, the point tree above its range.
    fn spt_above_without_hysteresis() -> Choices {
        Choices {
            log2_min: 3.0,
            tables: vec![Table { above: Technique::Spt, above_cost: (21_000.0, 21_000.0), steps: steps_of(&table()) }],
            elevations: Vec::new(),
            visibility: 1,
            below: Vec::new(),
            hysteresis_steps: 0,
            dither: TreeDither::NONE,
            uniform_by_class: Vec::new(),
        }
    }

    /// A tree whose height falls exactly half a step past the tables' last step (`above` is
    /// false there, and the step rounds up to one past the last) is chosen with the last step's
    /// technique: its lookup indexed one past the tables and panicked (met by budget mode
    /// among 1,000 trees of the shared pine, their heights looked up at per-tree factors).
    #[test]
    fn a_height_half_a_step_past_the_tables_is_chosen_with_the_last_step() {
        let choices = spt_above_without_hysteresis();
        let last = choices.tables[0].steps.len() - 1;
        let edge = last as f32 + 0.5;
        let analytic = (choices.log2_min + edge / STEPS_PER_OCTAVE).exp2();
        // The f32 heights around it, one of which falls on the edge exactly.
        let height = (-64..=64)
            .map(|k: i32| f32::from_bits(analytic.to_bits().wrapping_add_signed(k)))
            .find(|&h| choices.step(h) == edge)
            .expect("a height on the edge");
        let chosen = choices.choose_in_class(height, 0, 0, 0, 1.0, None);
        assert_eq!(chosen, choices.tables[0].steps[last]);
    }

    /// In budget mode trees at one height are chosen at heights of their own within
    /// [`BUDGET_DITHER_OCTAVES`] of it, the same every time, so that at a boundary of the tables
    /// some of them are chosen either side of it; without a budget, at their height.
    #[test]
    fn in_budget_mode_trees_at_one_height_switch_over_a_range_of_heights() {
        let mut choices = spt_above_without_hysteresis();
        let steps = choices.tables[0].steps.clone();
        let i = (0..steps.len() - 1).find(|&i| steps[i] != steps[i + 1]).expect("a boundary");
        let boundary = (choices.log2_min + (i as f32 + 0.5) / STEPS_PER_OCTAVE).exp2();
        let trees: Vec<Mat4> = (0..400)
            .map(|k| Mat4::from_translation(Vec3::new(3.0 * (k % 20) as f32, 0.0, -3.0 * (k / 20) as f32)))
            .collect();
        let finer = |choices: &Choices, height: f32| {
            trees
                .iter()
                .filter(|t| choices.choose_in_class(choices.dither(height, t).0, 0, 0, 0, 1.0, None) == steps[i + 1])
                .count()
        };
        // Without a budget: every tree on the same side.
        for factor in [0.9f32, 1.1] {
            let n = finer(&choices, boundary * factor);
            assert!(n == 0 || n == trees.len(), "{n} at {factor}");
        }
        // Budget mode's dither (the height factor; the class is not read: one table).
        choices.dither = TreeDither { cell: Some((0, 0.0)) };
        for t in &trees {
            let (h, _) = choices.dither(100.0, t);
            assert!((h / 100.0).log2().abs() <= BUDGET_DITHER_OCTAVES, "{h}");
            assert_eq!(h, choices.dither(100.0, t).0, "the same every time");
        }
        // With it: a share either side near the boundary, growing across it.
        let shares: Vec<usize> = [0.85f32, 0.95, 1.05, 1.15].iter().map(|&f| finer(&choices, boundary * f)).collect();
        assert!(shares.windows(2).all(|w| w[0] <= w[1]), "{shares:?}");
        assert!(shares[1] > 0 && shares[2] < trees.len(), "{shares:?}");
        assert!(shares[1] < shares[2], "{shares:?}");
    }

    /// Budget mode's lattice of targets: the cell of a target and the fraction past it place it
    /// half the spread less half a step above the cell's target; a tree's class is the lattice
    /// target its share rounds to, and over the trees the `log2` of their targets averages the
    /// policy's; the tables are made for the cell's targets, raised for each visibility class.
    #[test]
    fn budget_mode_rounds_each_tree_s_target_to_the_lattice_and_keeps_the_mean() {
        assert_eq!(class_targets(0.02, 1, None), vec![0.02]);
        let spread = BUDGET_TARGET_SPREAD as f32;
        for target in [0.003f32, 0.01, 0.0123, 0.5] {
            let (cell, fraction) = lattice_cell(target);
            assert!((0.0..1.0).contains(&fraction), "{fraction}");
            let x = (cell as f32 + fraction + spread / 2.0 - 0.5) * BUDGET_TARGET_STEP;
            assert!((x - target.log2()).abs() < 1e-4, "{target}: {x}");
            let targets = class_targets(target, 2, Some(cell));
            assert_eq!(targets.len(), 2 * (BUDGET_TARGET_SPREAD + 1));
            for (k, class) in targets.chunks(BUDGET_TARGET_SPREAD + 1).enumerate() {
                for (j, t) in class.iter().enumerate() {
                    let expected = (cell + j as i32) as f32 * BUDGET_TARGET_STEP + k as f32 * 0.5;
                    assert!((t.log2() - expected).abs() < 1e-4, "{target}: {class:?}");
                }
            }
        }
        let policy = Policy { target: 0.0123, budget: Some(1000), ..Policy::default() };
        let mut choices = Choices::among(&table(), &policy, all);
        let trees: Vec<Mat4> = (0..2000)
            .map(|k| Mat4::from_translation(Vec3::new(1.5 * (k % 40) as f32, 0.0, -1.5 * (k / 40) as f32)))
            .collect();
        let (cell, _) = lattice_cell(0.0123);
        for target in [0.0123f32, 0.0127, 0.0131] {
            let moved = Policy { target, ..policy };
            assert_eq!(Choices::tables_key(&moved), Choices::tables_key(&policy), "{target}: one cell");
            choices.retarget(&moved);
            assert_eq!(choices, Choices::among(&table(), &moved, all), "{target}: as if made for it");
            let mean = trees
                .iter()
                .map(|t| {
                    let (_, class) = choices.dither(50.0, t);
                    assert!(class <= BUDGET_TARGET_SPREAD);
                    (cell + class as i32) as f32 * BUDGET_TARGET_STEP
                })
                .sum::<f32>()
                / trees.len() as f32;
            assert!((mean - target.log2()).abs() < 0.1 * BUDGET_TARGET_STEP, "{target}: {mean}");
        }
        let without = Policy { budget: None, ..policy };
        assert!(trees.iter().all(|t| Choices::among(&table(), &without, all).dither(50.0, t) == (50.0, 0)));
    }

    /// In budget mode trees whose representations' errors do not change with height (no factor
    /// on the height spreads their switches) switch over a range of targets, each tree in a
    /// target class of its own: 400 trees at one height, the billboard within the target from
    /// 0.03 and impostor planes from 0.01 at every height; without a budget every tree switches
    /// at 0.03, with one the share of billboards grows across it, a few trees at a time, and
    /// each tree's class is the same every time.
    #[test]
    fn in_budget_mode_trees_with_errors_flat_in_height_switch_over_a_range_of_targets() {
        let mut records = Vec::new();
        for (technique, error, primitives) in
            [(code::FULL, 0.05, 10_000.0), (code::IMPOSTORS, 0.06, 500.0), (code::BILLBOARD, 0.08, 1.0)]
        {
            for h in [8.0, 16.0, 32.0, 64.0] {
                records.push(record(technique, h, error, primitives));
            }
        }
        let calibration = Calibration::from_records(&records).expect("rows");
        let trees: Vec<Mat4> = (0..400)
            .map(|k| Mat4::from_translation(Vec3::new(3.0 * (k % 20) as f32, 0.0, -3.0 * (k / 20) as f32)))
            .collect();
        let billboards = |budget: Option<u64>, target: f32| {
            let choices = Choices::among(&calibration, &Policy { target, budget, ..Policy::default() }, all);
            trees
                .iter()
                .filter(|t| {
                    let (h, class) = choices.dither(20.0, t);
                    assert_eq!((h, class), choices.dither(20.0, t), "the same every time");
                    choices.choose_in_class(h, 0, 0, class, 1.0, None) == Technique::Billboard
                })
                .count()
        };
        // From well under the spread to well over it, in twentieths of a step.
        let reach = (BUDGET_TARGET_SPREAD as f32 / 2.0 + 1.5) * BUDGET_TARGET_STEP;
        // (Not at 0.03 itself, where the billboard's error equals the floor plus the target.)
        let factors: Vec<f32> = (-20..=20).filter(|&k| k != 0).map(|k| (k as f32 / 20.0 * reach).exp2()).collect();
        for &f in &factors {
            let n = billboards(None, 0.03 * f);
            assert_eq!(n, if f >= 1.0 { trees.len() } else { 0 }, "without a budget at {f}");
        }
        let shares: Vec<usize> = factors.iter().map(|&f| billboards(Some(100_000), 0.03 * f)).collect();
        assert!(shares.windows(2).all(|w| w[0] <= w[1]), "{shares:?}");
        assert_eq!((shares[0], shares[shares.len() - 1]), (0, trees.len()), "{shares:?}");
        let mut distinct = shares.clone();
        distinct.dedup();
        // Many counts between none and all: more than the two of one switch.
        assert!(distinct.len() >= 10, "{shares:?}");
        // A tree chosen without a share of its own reads the lattice target nearest the
        // policy's: the switch within half a lattice step of 0.03 either way.
        for &f in &factors {
            let choices = Choices::among(
                &calibration,
                &Policy { target: 0.03 * f, budget: Some(100_000), ..Policy::default() },
                all,
            );
            let (cell, _) = lattice_cell(0.03 * f);
            let nearest = ((cell + choices.target_class() as i32) as f32 * BUDGET_TARGET_STEP).exp2();
            assert!((nearest / (0.03 * f)).log2().abs() <= 0.5 * BUDGET_TARGET_STEP + 1e-4, "{f}: {nearest}");
            let billboard = choices.choose_seen(20.0, 1.0, None) == Technique::Billboard;
            assert_eq!(billboard, nearest >= 0.03, "{f}: nearest lattice target {nearest}");
        }
    }

    /// Trees chosen frame after frame along a path: those that change technique are in a
    /// transition for the policy's frames, on one thread as on several.
    #[test]
    fn chosen_trees_that_change_technique_are_in_transition_for_its_frames() {
        let lods = [tall_lod()];
        // The point tree above the range whether a tree is wholly in view or not: the trees the
        // camera walks past change technique once on the way.
        let choices = [Some(spt_above_without_hysteresis())];
        // Two thousand trees in a row, the camera walking along it.
        let instances: Vec<Instance> = (0..2 * CHOOSE_CHUNK)
            .map(|i| Instance { model: 0, transform: Mat4::from_translation(Vec3::new(0.0, 0.0, -2.0 * i as f32)) })
            .collect();
        let cameras: Vec<Camera> = (0..30)
            .map(|f| {
                let eye = Vec3::new(0.0, 4.0, 40.0 - 3.0 * f as f32);
                Camera::look_at(eye, eye - Vec3::Z, 1.0, 640, 480)
            })
            .collect();
        let frames = 5u32;
        let mut results = Vec::new();
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let mut state = PolicyState::with_transition(frames);
            let mut out = Vec::new();
            let mut last: Vec<Option<Technique>> = Vec::new();
            // Per tree, the frame it last changed technique, and what it left.
            let mut changed: Vec<Option<(usize, Technique)>> = vec![None; instances.len()];
            let mut seen = 0;
            let mut per_frame = Vec::new();
            for (f, camera) in cameras.iter().enumerate() {
                pool.install(|| {
                    choose_instances(&instances, &lods, &choices, camera, Technique::Spt, &mut state, &mut out)
                });
                for (i, &t) in out.iter().enumerate() {
                    match (last.get(i).copied().flatten(), t) {
                        (Some(before), Some(now)) if before != now => changed[i] = Some((f, before)),
                        // Out of view, or back as a new tree: no transition.
                        (_, None) | (None, Some(_)) => changed[i] = None,
                        _ => {}
                    }
                    let expected = changed[i]
                        .filter(|&(at, _)| f - at < frames as usize - 1)
                        .map(|(at, from)| Transition { from, shown: (f - at + 1) as f32 / frames as f32 });
                    // A tree switching again mid-way reverses or restarts: checked in the unit
                    // test above; here only clean changes are compared.
                    assert_eq!(state.transition(i), expected, "{threads} threads, frame {f}, tree {i}");
                    seen += usize::from(expected.is_some());
                }
                per_frame.push(state.transitions().collect::<Vec<_>>());
                last.clone_from(&out);
            }
            assert!(seen > 100, "trees in transition along the path: {seen}");
            results.push(per_frame);
        }
        assert_eq!(results[0], results[1], "the same on 1 and 3 threads");
    }

    /// A tree outside the view is not chosen and is forgotten: it comes back as a new tree, with
    /// the plain choice at its height (no hysteresis) and no transition.
    #[test]
    fn trees_out_of_view_are_not_chosen_and_come_back_as_new() {
        let lods = [tall_lod()];
        let choices = [Some(spt_above_without_hysteresis())];
        // One tree ahead of the camera, one behind it.
        let instances = [
            Instance { model: 0, transform: Mat4::from_translation(Vec3::new(0.0, 0.0, -200.0)) },
            Instance { model: 0, transform: Mat4::from_translation(Vec3::new(0.0, 0.0, 800.0)) },
        ];
        // 600 m away the tree ahead is about 7 pixels high: crossed quads; 10 m away, the point
        // tree.
        let eye = Vec3::new(0.0, 4.0, 400.0);
        let ahead = Camera::look_at(eye, eye - Vec3::Z, 1.0, 640, 480);
        let behind = Camera::look_at(eye, eye + Vec3::Z, 1.0, 640, 480);
        let mut state = PolicyState::with_transition(4);
        let mut out = Vec::new();
        choose_instances(&instances, &lods, &choices, &ahead, Technique::Spt, &mut state, &mut out);
        let far = out[0].expect("the tree ahead is chosen");
        assert_eq!(far, Technique::Crossed);
        assert_eq!(out[1], None, "the tree behind is not");
        assert_eq!(state.previous[1], None);
        // Nearer, the tree ahead changes technique and starts a transition; then the camera
        // turns away, and back.
        let near_eye = Vec3::new(0.0, 4.0, -190.0);
        let near = Camera::look_at(near_eye, near_eye - Vec3::Z, 1.0, 640, 480);
        choose_instances(&instances, &lods, &choices, &near, Technique::Spt, &mut state, &mut out);
        let close = out[0].expect("chosen");
        assert_eq!(close, Technique::Spt);
        assert!(state.transition(0).is_some());
        let away = Camera::look_at(near_eye, near_eye + Vec3::Z, 1.0, 640, 480);
        choose_instances(&instances, &lods, &choices, &away, Technique::Spt, &mut state, &mut out);
        assert_eq!(out[0], None);
        assert_eq!((state.previous[0], state.transition(0)), (None, None), "forgotten out of view");
        choose_instances(&instances, &lods, &choices, &near, Technique::Spt, &mut state, &mut out);
        assert_eq!((out[0], state.transition(0)), (Some(close), None), "back as a new tree: no transition");
        // Without a camera nothing is culled.
        let mut all = Vec::new();
        choose_instances_coarsest(&instances, &lods, &choices, &[], Technique::Spt, &mut state, &mut all);
        assert!(all.iter().all(Option::is_some));
        // A shadow cascade's two views, the map's first: only the first culls, the second only
        // bounds the height. Seen from 10 m by the first, the tree ahead is chosen at the 7
        // pixels the second sees it at; the tree behind, in the second's view alone, is not.
        choose_instances_coarsest(&instances, &lods, &choices, &[near, behind], Technique::Spt, &mut state, &mut all);
        assert_eq!(all, [Some(far), None]);
        choose_instances_coarsest(&instances, &lods, &choices, &[near], Technique::Spt, &mut state, &mut all);
        assert_eq!(all, [Some(close), None], "from the first view alone, its own height");
        choose_instances_coarsest(&instances, &lods, &choices, &[behind, ahead], Technique::Spt, &mut state, &mut all);
        assert_eq!((all[0], all[1].is_some()), (None, true), "{all:?}");
    }

    #[test]
    fn chunks_out_of_view_are_culled_whole_with_the_choices_and_state_of_each_tree_alone() {
        let lods = [tall_lod()];
        let choices = [Some(spt_above_without_hysteresis())];
        // Four groups of trees a chunk and a half each, 400 m apart along x, each tree 4 m from
        // the next; one tree of an unknown model in the last group (its chunk is never culled
        // whole).
        let mut instances: Vec<Instance> = (0..6 * CHOOSE_CHUNK)
            .map(|i| {
                let (group, k) = (i / (3 * CHOOSE_CHUNK / 2), i % (3 * CHOOSE_CHUNK / 2));
                #[expect(clippy::cast_precision_loss, reason = "small numbers")]
                let at = Vec3::new(400.0 * group as f32 + 4.0 * (k % 40) as f32, 0.0, -4.0 * (k / 40) as f32);
                Instance { model: 0, transform: Mat4::from_translation(at) }
            })
            .collect();
        instances[5 * CHOOSE_CHUNK].model = 7;
        let bounds = ChunkBounds::new(&instances, &lods);
        assert_eq!(bounds.spheres.len(), 6);
        // The camera walks along the groups looking down -z, then turns round, with a transition
        // so the state carries from frame to frame.
        let (mut chunked, mut alone) = (PolicyState::with_transition(4), PolicyState::with_transition(4));
        let (mut out, mut reference) = (Vec::new(), Vec::new());
        let (mut culled_whole, mut seen_tall, mut most_in_view) = (0, 0, 0);
        let mut scratch = vec![5.0; 3];
        for frame in 0..14 {
            #[expect(clippy::cast_precision_loss, reason = "small numbers")]
            let eye = Vec3::new(-100.0 + 120.0 * frame as f32, 6.0, 60.0);
            let look = if frame < 10 { -Vec3::Z } else { Vec3::Z };
            let camera = Camera::look_at(eye, eye + look, 0.9, 640, 480);
            let cameras = [camera];
            choose_instances_in_chunks(
                &instances,
                &lods,
                &bounds,
                &choices,
                &cameras,
                Technique::Spt,
                &mut chunked,
                &mut out,
            );
            choose_instances_coarsest(
                &instances,
                &lods,
                &choices,
                &cameras,
                Technique::Spt,
                &mut alone,
                &mut reference,
            );
            assert_eq!(out, reference, "frame {frame}");
            assert_eq!(
                (&chunked.previous, &chunked.transitions, &chunked.elevations, &chunked.measure),
                (&alone.previous, &alone.transitions, &alone.elevations, &alone.measure),
                "frame {frame}"
            );
            // The tallest trees in view (budget mode's look-ahead chooses them whole): those of
            // the known model chosen in view, by projected height, ties by index.
            let mut expected: Vec<(f32, usize)> = (0..instances.len())
                .filter(|&i| out[i].is_some() && instances[i].model == 0)
                .map(|i| (projected_height(&lods[0], instances[i].transform, &camera), i))
                .collect();
            expected.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            for count in [1, 100, 2 * CHOOSE_CHUNK, instances.len()] {
                let mut want: Vec<usize> = expected.iter().take(count).map(|&(_, i)| i).collect();
                want.sort_unstable();
                let tallest = bounds.tallest_in_view(&camera, count, instances.len(), &mut scratch);
                assert_eq!(tallest, want, "frame {frame}, {count} trees");
            }
            assert!(
                bounds.tallest_in_view(&camera, 100, instances.len() - 1, &mut scratch).is_empty(),
                "other instances"
            );
            seen_tall += usize::from(!expected.is_empty());
            most_in_view = most_in_view.max(expected.len());
            let frustum = Frustum::from_view_proj(camera.view_proj);
            culled_whole += bounds.spheres.iter().filter(|(c, r)| !frustum.intersects_sphere(*c, *r)).count();
        }
        assert!(culled_whole >= 20, "chunks culled whole: {culled_whole}");
        assert!(seen_tall >= 10, "frames with trees in view: {seen_tall}");
        assert!(most_in_view > 100, "the most trees in view: {most_in_view}");
        assert!(out.iter().any(Option::is_some) && out[5 * CHOOSE_CHUNK] == Some(Technique::Spt));
        // Bounds of other instances (one fewer) are not used: every tree is tested on its own.
        let short = ChunkBounds::new(&instances[1..], &lods);
        let behind = Camera::look_at(Vec3::new(0.0, 6.0, 60.0), Vec3::new(0.0, 6.0, 61.0), 0.9, 640, 480);
        instances.iter_mut().for_each(|i| i.transform = Mat4::from_translation(Vec3::new(0.0, 0.0, 100.0)));
        choose_instances_in_chunks(
            &instances,
            &lods,
            &short,
            &choices,
            &[behind],
            Technique::Spt,
            &mut chunked,
            &mut out,
        );
        assert!(out.iter().all(Option::is_some), "moved behind the camera, in its view");
    }

    /// The tallest trees in view read from the grid are those of a pass over every tree: trees
    /// of two models (and one of an unknown model) at random places in a box 400 m wide and 30 m
    /// high, scaled 0.5–2 times and some tilted, some standing on the same spot (ties), seen
    /// from cameras in and around the box looking every way.
    #[test]
    fn the_tallest_trees_in_view_read_from_the_grid_are_those_of_every_tree() {
        let lods = [tall_lod(), block_lod(6.0, 3.0)];
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            #[expect(clippy::cast_precision_loss, reason = "a random share")]
            let unit = (state >> 40) as f32 / (1u64 << 24) as f32;
            unit
        };
        let mut instances: Vec<Instance> = (0..5000u32)
            .map(|i| {
                let at = Vec3::new(400.0 * next() - 200.0, 30.0 * next() - 10.0, 400.0 * next() - 200.0);
                let scale = 0.5 + 1.5 * next();
                let tilt = if i % 7 == 0 { 0.3 * next() } else { 0.0 };
                let transform =
                    Mat4::from_scale_rotation_translation(Vec3::splat(scale), glam::Quat::from_rotation_x(tilt), at);
                Instance { model: i % 2, transform }
            })
            .collect();
        for i in (0..200).step_by(2) {
            instances[i + 1].transform = instances[i].transform;
            instances[i + 1].model = instances[i].model;
        }
        instances[4321].model = 9;
        let bounds = ChunkBounds::new(&instances, &lods);
        let mut scratch = Vec::new();
        let (mut read, mut in_view_most) = (0, 0);
        for k in 0..24 {
            let eye = Vec3::new(500.0 * next() - 250.0, 60.0 * next() - 20.0, 500.0 * next() - 250.0);
            let look = Vec3::new(next() - 0.5, 0.4 * (next() - 0.5), next() - 0.5);
            let camera = Camera::look_at(eye, eye + look, 0.4 + next(), 640, 480);
            let frustum = Frustum::from_view_proj(camera.view_proj);
            let mut expected: Vec<(f32, usize)> = (0..instances.len())
                .filter_map(|i| {
                    let lod = lods.get(instances[i].model as usize)?;
                    let (centre, radius) = world_cull_sphere(lod, instances[i].transform);
                    frustum
                        .intersects_sphere(centre, radius)
                        .then(|| (projected_height(lod, instances[i].transform, &camera), i))
                })
                .filter(|(h, _)| h.is_finite() && *h > 0.0)
                .collect();
            expected.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            in_view_most = in_view_most.max(expected.len());
            for count in [1, 7, 64, 300] {
                assert!(count * GRID_LEAST_SHARE <= instances.len(), "read from the grid");
                let mut want: Vec<usize> = expected.iter().take(count).map(|&(_, i)| i).collect();
                want.sort_unstable();
                let got = bounds.tallest_in_view(&camera, count, instances.len(), &mut scratch);
                assert_eq!(got, want, "camera {k}, {count} trees");
                read += usize::from(!got.is_empty());
            }
        }
        assert!(read >= 40 && in_view_most > 300, "{read} answers, at most {in_view_most} trees in view");
        let grid = bounds.grid.0.get().expect("the grid was made");
        assert_eq!(grid.order.len(), instances.len() - 1, "every tree of a known model, once");
        assert!(grid.cells.len() >= 40, "{} cells", grid.cells.len());
    }

    #[test]
    fn a_sampled_state_chooses_its_chunks_as_the_whole_state_does() {
        let lods = [tall_lod()];
        let choices = [Some(spt_above_without_hysteresis())];
        // Five chunks and a half of trees in rows along -z, the last chunk short.
        let n = 5 * CHOOSE_CHUNK + CHOOSE_CHUNK / 2;
        let instances: Vec<Instance> = (0..n)
            .map(|i| {
                #[expect(clippy::cast_precision_loss, reason = "small numbers")]
                let at = Vec3::new(4.0 * (i % 40) as f32, 0.0, -4.0 * (i / 40) as f32);
                Instance { model: 0, transform: Mat4::from_translation(at) }
            })
            .collect();
        // The camera comes nearer over frames, so trees change technique and are in transitions.
        let camera = |frame: usize| {
            #[expect(clippy::cast_precision_loss, reason = "small numbers")]
            let eye = Vec3::new(80.0, 6.0, 120.0 - 60.0 * frame as f32);
            Camera::look_at(eye, eye - Vec3::Z, 0.9, 640, 480)
        };
        // The frame of `instances` for camera `frame` with `state`.
        let frame = |instances: &[Instance], frame: usize, state: &mut PolicyState| {
            let mut out = Vec::new();
            let bounds = ChunkBounds::new(instances, &lods);
            choose_instances_in_chunks(
                instances,
                &lods,
                &bounds,
                &choices,
                &[camera(frame)],
                Technique::Spt,
                state,
                &mut out,
            );
            out
        };
        let mut state = PolicyState::with_transition(4);
        for k in 0..3 {
            frame(&instances, k, &mut state);
        }
        let picked = [1, 3, 5];
        let index: Vec<usize> = picked.iter().flat_map(|&c| chunk_range(c, n)).collect();
        let sampled_instances: Vec<Instance> = index.iter().map(|&i| instances[i]).collect();
        let mut sampled = state.gathered(&index);
        assert_eq!(sampled.previous.len(), index.len());
        let sampled_out = frame(&sampled_instances, 3, &mut sampled);
        let out = frame(&instances, 3, &mut state);
        let whole: Vec<Option<Technique>> = index.iter().map(|&i| out[i]).collect();
        assert_eq!(sampled_out, whole);
        let transitions: Vec<Option<Transition>> = index.iter().map(|&i| state.transition(i)).collect();
        let sampled_transitions: Vec<Option<Transition>> = (0..index.len()).map(|j| sampled.transition(j)).collect();
        assert_eq!(sampled_transitions, transitions);
        assert!(transitions.iter().any(Option::is_some), "trees in a transition were sampled");
        assert!(whole.iter().flatten().count() > 100, "trees in view were sampled: {whole:?}");
        // The whole forest's bounds sampled are the sampled instances' bounds.
        let bounds = ChunkBounds::new(&instances, &lods);
        assert_eq!(bounds.gathered(&index, n), Some(ChunkBounds::new(&sampled_instances, &lods)));
        assert_eq!(bounds.gathered(&index, n - 1), None, "made of other instances");
        assert_eq!(bounds.gathered(&[n], n), None, "no such instance");
    }

    /// The choices of a frame, made one instance at a time with [`projected_height`] and
    /// [`Choices::choose`]: what [`choose_instances`] must give.
    fn choose_reference(
        instances: &[Instance],
        lods: &[ModelLod],
        choices: &[Option<Choices>],
        camera: &Camera,
        otherwise: Technique,
        previous: &mut Vec<Option<Technique>>,
    ) -> Vec<Option<Technique>> {
        previous.resize(instances.len(), None);
        let frustum = Frustum::from_view_proj(camera.view_proj);
        instances
            .iter()
            .zip(previous.iter_mut())
            .map(|(instance, previous)| {
                let m = instance.model as usize;
                if let Some(lod) = lods.get(m) {
                    let (centre, radius) = lod.cull_sphere();
                    let scale = crate::max_axis_scale(instance.transform);
                    if !frustum.intersects_sphere(instance.transform.transform_point3(centre), radius * scale) {
                        *previous = None;
                        return None;
                    }
                }
                Some(match (lods.get(m), choices.get(m).and_then(Option::as_ref)) {
                    (Some(lod), Some(choices)) => {
                        let height = projected_height(lod, instance.transform, camera);
                        let in_view = if choices.above_range(height) {
                            in_view_share(lod, instance.transform, &frustum)
                        } else {
                            1.0
                        };
                        let chosen = choices.choose_framed(height, 0, 1.0, in_view, *previous);
                        *previous = Some(chosen);
                        chosen
                    }
                    _ => {
                        *previous = None;
                        otherwise
                    }
                })
            })
            .collect()
    }

    /// A random forest of several chunks (a model with choices, one without, an unknown model
    /// index) seen along a path of cameras: the chunked, parallel choice equals the reference
    /// frame after frame, hysteresis state included, on one thread and on four.
    #[test]
    fn choosing_in_parallel_chunks_equals_the_reference_frame_after_frame() {
        use glam::Quat;
        use treelod_build::SplitMix64;
        let lods = [tall_lod(), tall_lod()];
        let c = table();
        let steps = steps_of(&c);
        assert!(steps.iter().any(|&t| t != steps[0]), "the table switches technique: {steps:?}");
        let choices = [
            Some({
                let mut choices = Choices {
                    log2_min: 3.0,
                    tables: vec![Table { above: Technique::LodChain, above_cost: (22_500.0, 21_000.0), steps }],
                    elevations: Vec::new(),
                    visibility: 1,
                    below: Vec::new(),
                    hysteresis_steps: 2,
                    dither: TreeDither::NONE,
                    uniform_by_class: Vec::new(),
                };
                // The chunks take the technique every table shares under its height without
                // looking the tree up; the reference looks every tree up.
                choices.measure_uniform();
                assert!(choices.uniform_below().is_some(), "the table starts with one technique: {:?}", steps_of(&c));
                choices
            }),
            None,
        ];
        let mut rng = SplitMix64(24);
        let instances: Vec<Instance> = (0..3 * CHOOSE_CHUNK + 77)
            .map(|_| {
                let position = Vec3::new(rng.range(-400.0, 400.0), 0.0, rng.range(-400.0, 400.0));
                let rotation = Quat::from_rotation_y(rng.range(0.0, std::f32::consts::TAU));
                let scale = Vec3::splat(rng.range(0.5, 1.5));
                // Mostly the calibrated model, some without tables, a few of no model at all.
                let model = match rng.range(0.0, 1.0) {
                    x if x < 0.8 => 0,
                    x if x < 0.95 => 1,
                    _ => 7,
                };
                Instance { model, transform: Mat4::from_scale_rotation_translation(scale, rotation, position) }
            })
            .collect();
        let cameras: Vec<Camera> = (0..12)
            .map(|i| {
                let eye = Vec3::new(-300.0 + 50.0 * i as f32, 1.5 + 20.0 * (i % 3) as f32, 10.0 * i as f32);
                Camera::look_at(eye, eye + Vec3::new(1.0, -0.1, -0.5), 1.0, 1280, 720)
            })
            .collect();
        let mut reference_previous = Vec::new();
        let expected: Vec<Vec<Option<Technique>>> = cameras
            .iter()
            .map(|camera| {
                choose_reference(&instances, &lods, &choices, camera, Technique::Spt, &mut reference_previous)
            })
            .collect();
        let switches = expected
            .windows(2)
            .flat_map(|w| w[0].iter().zip(&w[1]))
            .filter(|(a, b)| a.is_some() && b.is_some() && a != b)
            .count();
        assert!(switches > 0, "trees change technique along the path");
        let culled = expected.iter().flatten().filter(|t| t.is_none()).count();
        assert!(culled > 0 && culled < expected.len() * instances.len(), "some trees out of view, some in: {culled}");
        // Each tree's placement computed every frame, and once by the chunks' bounds (with
        // transitions, which do not change the choices).
        let bounds = ChunkBounds::new(&instances, &lods);
        let (mut in_transition, mut quiet_chunks) = (0, 0);
        for threads in [1, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let (mut state, mut placed) = (PolicyState::default(), PolicyState::with_transition(3));
            let (mut out, mut out_placed) = (Vec::new(), Vec::new());
            for (camera, expected) in cameras.iter().zip(&expected) {
                pool.install(|| {
                    choose_instances(&instances, &lods, &choices, camera, Technique::Spt, &mut state, &mut out);
                    let cameras = std::slice::from_ref(camera);
                    let state = &mut placed;
                    choose_instances_in_chunks(
                        &instances,
                        &lods,
                        &bounds,
                        &choices,
                        cameras,
                        Technique::Spt,
                        state,
                        &mut out_placed,
                    );
                });
                assert_eq!(&out, expected, "{threads} threads");
                assert_eq!(&out_placed, expected, "{threads} threads, placed once");
                // The transitions listed read only the chunks left with one; every one is listed.
                let listed: Vec<(u32, Transition)> = placed.transitions().collect();
                #[expect(clippy::cast_possible_truncation, reason = "test sizes")]
                let every: Vec<(u32, Transition)> =
                    (0..instances.len()).filter_map(|i| Some((i as u32, placed.transition(i)?))).collect();
                assert_eq!(listed, every, "{threads} threads");
                in_transition += listed.len();
                quiet_chunks += placed.busy.iter().filter(|&&b| !b).count();
            }
            assert_eq!(state.previous, reference_previous, "{threads} threads");
            assert_eq!(placed.previous, reference_previous, "{threads} threads, placed once");
        }
        assert!(in_transition > 0 && quiet_chunks > 0, "{in_transition} transitions, {quiet_chunks} chunks without");
    }

    /// Inside the sines of its class's band, a tree keeps its class and stays above the horizon
    /// as the elevation in degrees says, for elevations swept across every bound (down to a
    /// thousandth of a degree from each) and every class it may have had.
    #[test]
    fn a_tree_inside_its_class_band_keeps_the_class_the_degrees_give() {
        let mut choices = spt_above_without_hysteresis();
        choices.elevations = vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0];
        let without_below = choices.clone();
        choices.below = choices.tables.clone();
        for choices in [choices, without_below] {
            let bands = choices.stay_bands();
            assert_eq!(bands.len(), choices.elevations.len());
            let mut bounds: Vec<f32> = vec![-7.5];
            bounds.extend((0..9).flat_map(|c| [10.0 * c as f32 + 2.5, 10.0 * c as f32 + 7.5]));
            let mut elevations: Vec<f32> = (-9000..=9000).map(|d| d as f32 * 0.01).collect();
            for b in bounds {
                elevations.extend((-100..=100).map(|k| b + k as f32 * 1e-3));
            }
            let (mut inside, mut outside) = (0, 0);
            for &degrees in &elevations {
                let sine = degrees.to_radians().sin();
                // The degrees as the chooser measures them from the sine.
                let measured = sine.asin().to_degrees();
                for (c, &(lo, hi)) in bands.iter().enumerate() {
                    if sine > lo && sine < hi {
                        inside += 1;
                        assert!(!choices.below_horizon(measured, false), "{degrees}° class {c}");
                        assert_eq!(elevation_class_after(Some(c), measured, &choices.elevations), c, "{degrees}°");
                    } else {
                        outside += 1;
                    }
                }
            }
            assert!(inside > 10_000 && outside > 10_000, "{inside} inside, {outside} outside");
            // The bands reach within a hundredth of a degree of the bounds.
            let (lo, hi) = bands[3];
            assert!(lo < (22.51f32).to_radians().sin() && hi > (37.49f32).to_radians().sin(), "{lo} {hi}");
        }
    }

    /// The chooser follows each tree's elevation class, frame after frame, as the degrees of its
    /// view elevation give it ([`elevation_class_after`] and [`Choices::below_horizon`] from last
    /// frame's class): an eye rising from below the trees to far above them and coming down,
    /// with trees tilted every way.
    #[test]
    fn the_chooser_follows_each_trees_elevation_class_as_the_degrees_give_it() {
        use glam::Quat;
        use treelod_build::SplitMix64;
        let lods = [tall_lod()];
        // Each class's table chooses a technique of its own at every height, so the choice
        // shows the class it was made with.
        let by_class =
            |c: usize| [Technique::Spt, Technique::Crossed, Technique::Billboard, Technique::LodChain][c % 4];
        let mut choices = spt_above_without_hysteresis();
        let steps = choices.tables[0].steps.len();
        let only = |t: Technique| Table { above: t, above_cost: (1.0, 1.0), steps: vec![t; steps] };
        choices.elevations = (0..10).map(|c| 10.0 * c as f32).collect();
        choices.tables = (0..10).map(|c| only(by_class(c))).collect();
        choices.below = vec![only(Technique::Impostors)];
        choices.uniform_by_class = Vec::new();
        let choices = [Some(choices)];
        let mut rng = SplitMix64(8);
        let instances: Vec<Instance> = (0..2 * CHOOSE_CHUNK + 300)
            .map(|_| {
                let position = Vec3::new(rng.range(-150.0, 150.0), rng.range(-5.0, 5.0), rng.range(-300.0, -20.0));
                let axis = Vec3::new(rng.range(-1.0, 1.0), 4.0, rng.range(-1.0, 1.0)).normalize();
                let rotation = Quat::from_axis_angle(axis, rng.range(-0.6, 0.6));
                Instance { model: 0, transform: Mat4::from_rotation_translation(rotation, position) }
            })
            .collect();
        let mut state = PolicyState::default();
        let mut reference = vec![NO_CLASS; instances.len()];
        let mut out = Vec::new();
        let mut classes_seen = std::collections::BTreeSet::new();
        for frame in 0..40 {
            // Up from 30 m below to 600 m above, then down again.
            let t = if frame < 20 { frame as f32 } else { 40.0 - frame as f32 };
            let eye = Vec3::new(0.0, -30.0 + t * t * 1.6, 40.0);
            let camera = Camera::look_at(eye, Vec3::new(0.0, 0.0, -160.0), 1.2, 640, 480);
            choose_instances(&instances, &lods, &choices, &camera, Technique::Spt, &mut state, &mut out);
            let frustum = Frustum::from_view_proj(camera.view_proj);
            let elevations = choices[0].as_ref().map(Choices::elevations).unwrap_or_default();
            for (i, instance) in instances.iter().enumerate() {
                let (centre, radius) = world_cull_sphere(&lods[0], instance.transform);
                reference[i] = if frustum.intersects_sphere(centre, radius) {
                    let degrees = view_elevation(&lods[0], instance.transform, eye);
                    let choices = choices[0].as_ref().expect("choices");
                    if choices.below_horizon(degrees, reference[i] == BELOW_CLASS) {
                        BELOW_CLASS
                    } else {
                        let before = (reference[i] != NO_CLASS && reference[i] != BELOW_CLASS)
                            .then_some(usize::from(reference[i]));
                        u8::try_from(elevation_class_after(before, degrees, elevations)).expect("a class")
                    }
                } else {
                    NO_CLASS
                };
            }
            assert_eq!(state.elevations, reference, "frame {frame}");
            let expected: Vec<Option<Technique>> = reference
                .iter()
                .map(|&c| match c {
                    NO_CLASS => None,
                    BELOW_CLASS => Some(Technique::Impostors),
                    c => Some(by_class(usize::from(c))),
                })
                .collect();
            assert_eq!(out, expected, "frame {frame}");
            classes_seen.extend(reference.iter().copied());
        }
        assert!(classes_seen.len() >= 8, "classes met along the path: {classes_seen:?}");
        assert!(classes_seen.contains(&BELOW_CLASS) && classes_seen.contains(&NO_CLASS), "{classes_seen:?}");
    }

    /// Fractions lent for a choice are read by it and given back; the state's own are kept.
    #[test]
    fn visible_fractions_lent_for_a_choice_come_back() {
        let lods = [tall_lod()];
        let choices = [Some(spt_above_without_hysteresis())];
        let instances: Vec<Instance> = (0..3)
            .map(|i| Instance { model: 0, transform: Mat4::from_translation(Vec3::new(0.0, 0.0, -40.0 * i as f32)) })
            .collect();
        let camera = Camera::look_at(Vec3::new(0.0, 5.0, 30.0), Vec3::new(0.0, 5.0, 0.0), 0.9, 640, 480);
        let mut state = PolicyState::default();
        state.set_visible(&[0.5]);
        let mut lent = vec![0.1, 0.9];
        let mut out = Vec::new();
        let read = state.with_visible(&mut lent, |state| {
            choose_instances(&instances, &lods, &choices, &camera, Technique::Spt, state, &mut out);
            state.visible.clone()
        });
        assert_eq!(read, [0.1, 0.9, 1.0], "the choice read the lent fractions, padded");
        assert_eq!(lent, [0.1, 0.9, 1.0], "given back");
        assert_eq!(state.visible, [0.5], "the state's own kept");
    }

    /// An instance's placement, made once, gives its culling sphere, projected height and view
    /// elevation bit for bit as they are computed from its transform every frame, under turned,
    /// sheared and unevenly scaled transforms (a y axis of its own).
    #[test]
    fn a_placement_made_once_reads_as_the_transform_does() {
        use glam::Quat;
        use treelod_build::SplitMix64;
        let lod = tall_lod();
        let mut rng = SplitMix64(5);
        let mut v = |lo: f32, hi: f32| Vec3::new(rng.range(lo, hi), rng.range(lo, hi), rng.range(lo, hi));
        for i in 0..2000 {
            let (axis, scale, position) = (v(-1.0, 1.0).normalize_or(Vec3::Y), v(0.3, 3.0), v(-500.0, 500.0));
            let angle = position.x.sin() * std::f32::consts::PI;
            let mut transform =
                Mat4::from_scale_rotation_translation(scale, Quat::from_axis_angle(axis, angle), position);
            if i % 3 == 0 {
                transform.y_axis += v(-0.5, 0.5).extend(0.0);
            }
            let place = Placement::of(3, &lod, transform);
            assert_eq!(place.cull, world_cull_sphere(&lod, transform));
            let eye = v(-600.0, 600.0);
            let world_per_pixel = 0.001 + (i as f32) * 1e-6;
            let h = projected_height_at(&lod, transform, eye, world_per_pixel);
            assert_eq!(place.projected_height(eye, world_per_pixel).to_bits(), h.to_bits(), "{i}");
            let elevation = place.sine(eye).asin().to_degrees();
            assert_eq!(elevation.to_bits(), view_elevation(&lod, transform, eye).to_bits(), "{i}");
        }
    }

    #[test]
    fn projected_height_matches_the_camera_and_distance_for_height_inverts_it() {
        let lod = block_lod(1.0, 10.0);
        let camera = Camera::look_at(Vec3::new(0.0, 5.0, 100.0), Vec3::new(0.0, 5.0, 0.0), 1.0, 640, 480);
        let d = distance_for_height(&lod, 64.0, &camera);
        let eye = Vec3::new(0.0, 5.0, d);
        let camera = Camera::look_at(eye, Vec3::new(0.0, 5.0, 0.0), 1.0, 640, 480);
        let h = projected_height(&lod, Mat4::IDENTITY, &camera);
        assert!((h - 64.0).abs() < 1e-3, "{h}");
        let scaled = projected_height(&lod, Mat4::from_scale(Vec3::splat(2.0)), &camera);
        assert!(scaled > 100.0, "a tree twice as large at about the same distance: {scaled}");
    }
}
