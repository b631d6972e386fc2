//! Baseline billboards (spec §6.13): per tree, one camera-facing quad and three crossed quads,
//! each showing the whole tree (bark and leaves) baked from its full mesh, at the texel budget of
//! the tree's impostor planes, in one atlas made as the impostor atlas is ([`crate::impostor`]).
//!
//! - **Axis**: vertical (`+Y` up) through the centre of the tree's bounds in `x` and `z`; the
//!   quads' centre is the bounds' centre, their half-height `h` half the bounds' `y` extent, their
//!   half-width `R` the largest horizontal distance of a vertex of the tree from the axis (each at
//!   least half a millimetre, so no quad is degenerate).
//! - **Quads**: `axis_v = (0, h, 0)` always. The facing quad has `axis_u = (R, 0, 0)`, normal
//!   `axis_u × axis_v = +Z`; the runtime turns `axis_u` about the vertical towards the eye. The
//!   crossed quads have `axis_u = R·(cos θ, 0, −sin θ)`, normal `(sin θ, 0, cos θ)`, for
//!   `θ = 0°, 60°, 120°` about `+Y`.
//! - **Images**: each quad's image is the tree projected orthographically along the quad's
//!   normal, the front-most surface seen from the side the normal `axis_u × axis_v` points to
//!   winning each sample (triangles are drawn front to back, so hidden ones are rarely shaded).
//!   A viewer on that side, head along `axis_v`, sees `axis_u` to its right and the image
//!   unmirrored, as the tree itself looks from there (the texel at `center + s·axis_u + t·axis_v` lies at `uv_min + ((s + 1)/2, (t + 1)/2)·(uv_max −
//!   uv_min)`, spec §6.10, so the tree's foot, `t = −1`, is on the rectangle's top row). From the
//!   other side a crossed quad shows the same silhouette, unmirrored, with the far side's
//!   surface. Colour, coverage, mips (coverage-preserving alpha) and gutters are the impostor
//!   atlas's, so the same shader draws both.
//! - **Resolution**: the facing quad gets the tree's whole budget, each crossed quad a third of
//!   it (so the atlas holds about twice the impostors' texels per tree). A quad's content keeps
//!   the quad's aspect `R : h` (square texels) and is the size whose region (content, 4-texel
//!   gutter, 16-texel alignment) is nearest to its budget in ratio (the largest content of
//!   equal region). A quad's budget is at least [`MIN_QUAD_TEXELS`] (a 32 × 32 region), so a tree
//!   whose budget is 0 (no leaves, hence no impostor planes) still gets images. If the atlas
//!   would exceed [`MAX_ATLAS`] texels per side, every budget drops by 3/4 steps until it fits.
//! - **Packing**: shelves as in the impostor atlas, at the width that wastes least (not a power
//!   of two: with four large regions per tree that would leave up to half of the atlas empty).
//!
//! Everything is deterministic: quads are baked in parallel and collected in order.

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use treelod_format::{
    BillboardRecord, OctahedralDepthRecord, OctahedralNormalGridRecord, OctahedralRecord, PlaneDiffuseRecord, Setting,
    billboard_kind, pack,
};

use crate::error::BuildError;
use crate::impostor::{
    ALIGN, Atlas, Baked, DepthMoments, GUTTER, ImpostorMesh, MIP_LEVELS, MayCover, PlaneFit, Quad, Region, SAMPLES,
    Winner, align, bake, compose, diffuse_item, diffuse_mixture, diffuse_moments, seen_triangle_occlusion, shelf_pack,
};

/// Views per side of a tree's octahedral impostor by default ([`OctahedralConfig::views`], spec
/// §6.13.1): 16 × 16 views over the upper hemisphere, 60 along the horizon (6° apart) and 7.5
/// steps from the horizon to straight above (12°). Between views the silhouette differs (no view is the one seen), which is most of an
/// impostor's error far away: measured with `eval --orbit 2,8,32` on the oak and the pine, 16 × 16
/// views of 96 texels read 13–14 % less RMSE at 32–128 px than 12 × 12 of 128 texels, the same
/// texture memory (at 8–32 px, −9 % and +6 %).
pub const OCTAHEDRAL_FRAMES: u32 = 16;

/// Texels per side of an octahedral view's cell by default ([`OctahedralConfig::texels`]; a
/// multiple of [`CELL_ALIGN`]; its content is the cell less a 4-texel gutter on each side),
/// before any shrinking: a tree up to about 88 pixels high on screen keeps a texel per pixel,
/// 2.36 M colour texels per tree before mips (and its normals a quarter of that). Where the atlas
/// would exceed [`MAX_ATLAS`], cells shrink by 3/4 steps (to multiples of 32, 32 at least) as the
/// billboards' budgets do.
pub const OCTAHEDRAL_CELL: u32 = 96;

/// What an octahedral view's cell is a multiple of: twice the atlas's alignment (16), so that
/// the cell of its normals, at half the colour's resolution (spec §6.13.3), keeps that alignment
/// and every mip level of both lies on whole texels.
pub const CELL_ALIGN: u32 = 2 * ALIGN;

/// How each tree's octahedral impostor is baked (`treelod build --octahedral-views`,
/// `--octahedral-texels`): what impostor bakers let an artist trade, the views' density against
/// the atlas's texels. The atlas of one tree holds `(views · texels)²` colour texels before mips
/// (2.36 M by default) and a quarter of that of normals; where the block's atlas would pass
/// [`MAX_ATLAS`] texels a side, cells shrink in 3/4 steps (to multiples of 32, 32 at least).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OctahedralConfig {
    /// Views per side of the hemi-octahedral grid (`frames`, spec §6.13.1), in
    /// [`OctahedralRecord::MIN_FRAMES`]`..=`[`OctahedralRecord::MAX_FRAMES`] (`2..=64`). Default
    /// [`OCTAHEDRAL_FRAMES`].
    pub views: u32,
    /// Texels per side of a view's cell, a gutter of 4 on each side included: a multiple of
    /// [`CELL_ALIGN`] (32) in [`Self::MIN_TEXELS`]`..=`[`Self::MAX_TEXELS`] (`32..=256`). Default
    /// [`OCTAHEDRAL_CELL`].
    pub texels: u32,
}

impl Default for OctahedralConfig {
    fn default() -> Self {
        Self { views: OCTAHEDRAL_FRAMES, texels: OCTAHEDRAL_CELL }
    }
}

impl OctahedralConfig {
    /// The fewest texels per side of a view's cell: the least the atlas's shrinking leaves.
    pub const MIN_TEXELS: u32 = CELL_ALIGN;
    /// The most texels per side of a view's cell.
    pub const MAX_TEXELS: u32 = 256;

    /// Checks the ranges documented on the fields.
    ///
    /// # Errors
    /// [`BuildError::Setting`] naming the field.
    pub fn validate(&self) -> Result<(), BuildError> {
        let (min_views, max_views) = (OctahedralRecord::MIN_FRAMES, OctahedralRecord::MAX_FRAMES);
        if !(min_views..=max_views).contains(&self.views) {
            return Err(BuildError::Setting(format!(
                "octahedral views {}: {min_views} to {max_views} views per side of the grid",
                self.views
            )));
        }
        if !(Self::MIN_TEXELS..=Self::MAX_TEXELS).contains(&self.texels) || !self.texels.is_multiple_of(CELL_ALIGN) {
            return Err(BuildError::Setting(format!(
                "octahedral texels {}: a multiple of {CELL_ALIGN} from {} to {} texels per side of a view",
                self.texels,
                Self::MIN_TEXELS,
                Self::MAX_TEXELS
            )));
        }
        Ok(())
    }

    /// The settings to record in the container's metadata (spec §7.1):
    /// `baselines.octahedral_views` and `baselines.octahedral_texels`.
    #[must_use]
    pub fn settings(&self) -> Vec<Setting> {
        vec![
            Setting { key: "baselines.octahedral_views".into(), value: self.views.to_string() },
            Setting { key: "baselines.octahedral_texels".into(), value: self.texels.to_string() },
        ]
    }
}

/// Samples per texel side of an octahedral view (a billboard's 4): each view of a tree costs a
/// pass over its triangles (256 by default), and a view stands for a tree a few dozen pixels high.
pub const OCTAHEDRAL_SAMPLES: usize = 2;

/// `kind` of an octahedral view's bake job (not a [`billboard_kind`]: views are not billboards).
const OCTAHEDRAL_VIEW: u32 = u32::MAX;

/// Crossed quads per tree.
pub const CROSSED_QUADS: u32 = 3;

/// The least texel budget of a quad: a 32 × 32 region (24 × 24 texels of content for a square
/// quad).
pub const MIN_QUAD_TEXELS: u64 = 32 * 32;

/// Largest atlas side, texels: wgpu's default limit `max_texture_dimension_2d`.
pub const MAX_ATLAS: u32 = 8192;

/// Largest content side of one quad, texels.
const MAX_CONTENT: u32 = 4096;

/// What [`build_billboards`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct Billboards {
    /// Per tree with triangles, in tree order: its `FACING` record, then its three `CROSSED`
    /// ones (0°, 60°, 120°); `image` 0: the caller sets the atlas's index.
    pub records: Vec<BillboardRecord>,
    /// The atlas every record samples.
    pub atlas: Atlas,
    /// Atlas texels of each tree's facing quad (region, gutter and alignment included, level 0),
    /// per tree of the block; 0 for a tree without triangles.
    pub facing_texels: Vec<u64>,
    /// The same for each tree's crossed quads together.
    pub crossed_texels: Vec<u64>,
    /// Per tree with triangles, in tree order, its octahedral impostor (with `octahedral`);
    /// `image` 0: the caller sets the atlas's index.
    pub octahedral: Vec<OctahedralRecord>,
    /// The same for each tree's octahedral views together, their normal cells included.
    pub octahedral_texels: Vec<u64>,
    /// Where each octahedral impostor's views' normals lie, at half the colour's resolution, in
    /// the order of `octahedral`: the `OCTAHEDRAL_NORMAL_GRIDS` section (spec §6.13.3).
    pub octahedral_normal_grids: Vec<OctahedralNormalGridRecord>,
    /// Each octahedral view's depth plane, in the order of `octahedral` and of the views in
    /// each (`j · frames + i`): the `OCTAHEDRAL_DEPTH` section (spec §6.13.2).
    pub octahedral_depth: Vec<OctahedralDepthRecord>,
}

/// One quad to bake.
struct Job {
    tree: u32,
    kind: u32,
    /// The tree's centre, block space: the origin of work of its triangles.
    centre: DVec3,
    quad: Quad,
    /// Its texel budget before any shrinking.
    budget: u64,
}

/// Bakes the facing and crossed billboards of each of `trees` trees from `mesh`, whose triangles
/// are all of the block's (bark and leaves) with their tree set (see the module documentation),
/// and with `octahedral` each tree's octahedral impostor: [`OctahedralConfig::views`]² views, each
/// baked as a billboard is, along [`OctahedralRecord::view_direction`] onto a square of the
/// tree's bounding sphere about the centre of its bounds, laid out in a grid of cells of the same
/// atlas (spec §6.13.1); its `occlusion` is the tree's triangles' as seen from outside
/// ([`seen_occlusion`](crate::ambient::seen_occlusion)) where `mesh` has occlusion.
/// `budget_texels[t]` is tree `t`'s texel budget (its impostors' texels, [`crate::Impostors`]'s
/// `texels_per_tree`); a missing entry counts as 0. `None` when there are no triangles; a tree
/// without triangles gets no records.
///
/// # Errors
/// None yet: the signature leaves room for limits on the input.
///
/// # Panics
/// If an index of `mesh` is out of range or a triangle's tree is not below `trees`.
pub fn build_billboards(
    mesh: &ImpostorMesh<'_>,
    trees: u32,
    budget_texels: &[u64],
    octahedral: Option<&OctahedralConfig>,
) -> Result<Option<Billboards>, BuildError> {
    if let Some(config) = octahedral {
        config.validate()?;
    }
    if mesh.triangles.is_empty() {
        return Ok(None);
    }
    let position = |v: u32| Vec3::from_array(mesh.vertices[v as usize].position).as_dvec3();

    // Stage: each tree's triangles.
    let mut by_tree: Vec<Vec<u32>> = vec![Vec::new(); trees as usize];
    for (i, t) in mesh.triangles.iter().enumerate() {
        assert!(t.tree < trees, "triangle {i} is of tree {}, but the block has {trees}", t.tree);
        #[expect(clippy::cast_possible_truncation, reason = "triangle counts fit u32")]
        by_tree[t.tree as usize].push(i as u32);
    }

    // Stage: each tree's axis, extent and quads; and its octahedral impostor's centre and the
    // radius of its bounding sphere.
    let mut jobs: Vec<Job> = Vec::new();
    let mut spheres: Vec<(u32, DVec3, f64)> = Vec::new();
    for (tree, tris) in by_tree.iter().enumerate() {
        if tris.is_empty() {
            continue;
        }
        #[expect(clippy::cast_possible_truncation, reason = "tree < trees: u32")]
        let tree = tree as u32;
        let corners = || tris.iter().flat_map(|&t| mesh.triangles[t as usize].v.map(position));
        let (lo, hi) = corners().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| (lo.min(p), hi.max(p)));
        let centre = 0.5 * (lo + hi);
        let radius = corners().map(|p| (p.x - centre.x).hypot(p.z - centre.z)).fold(0.0f64, f64::max).max(5e-4);
        let half_height = (0.5 * (hi.y - lo.y)).max(5e-4);
        if octahedral.is_some() {
            spheres.push((tree, centre, corners().map(|p| (p - centre).length()).fold(0.0f64, f64::max).max(5e-4)));
        }
        let v = DVec3::new(0.0, half_height, 0.0);
        let budget = budget_texels.get(tree as usize).copied().unwrap_or(0);
        jobs.push(Job {
            tree,
            kind: billboard_kind::FACING,
            centre,
            quad: Quad { centre: DVec3::ZERO, u: DVec3::new(radius, 0.0, 0.0), v },
            budget,
        });
        for k in 0..CROSSED_QUADS {
            let angle = std::f64::consts::PI * f64::from(k) / f64::from(CROSSED_QUADS);
            let (sin, cos) = angle.sin_cos();
            jobs.push(Job {
                tree,
                kind: billboard_kind::CROSSED,
                centre,
                quad: Quad { centre: DVec3::ZERO, u: DVec3::new(cos, 0.0, -sin) * radius, v },
                budget: budget / u64::from(CROSSED_QUADS),
            });
        }
    }

    // Stage: region sizes from the budgets, and their packing, shrinking until it fits: the
    // billboards' regions, then each octahedral impostor's grid as one region.
    let mut scale = 1.0f64;
    let OctahedralConfig { views, texels: mut cell } = octahedral.copied().unwrap_or_default();
    let (mut regions, width, height) = loop {
        let mut regions: Vec<Region> = jobs
            .iter()
            .map(|job| {
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a positive texel count")]
                let budget = (job.budget as f64 * scale) as u64;
                let (tw, th) = content_size(budget, job.quad.u.length(), job.quad.v.length());
                Region::new(tw, th)
            })
            .collect();
        let grid = views * cell;
        // The views' colour cells, then their normal cells, at half the colour's resolution, to
        // the right (spec §6.13.3).
        regions.extend(spheres.iter().map(|_| Region::new(grid + grid / 2 - 2 * GUTTER, grid - 2 * GUTTER)));
        let (width, height) = pack_tight(&mut regions);
        if (width <= MAX_ATLAS && height <= MAX_ATLAS) || scale < 1e-9 {
            break (regions, width, height);
        }
        scale *= 0.75;
        cell = (cell * 3 / 4 / CELL_ALIGN * CELL_ALIGN).max(CELL_ALIGN);
    };
    // The grids' places, then each view as a job of its own in its cell: its content the cell
    // less a gutter, a square of the tree's bounding sphere seen along the view's direction.
    let grids: Vec<Region> = regions.split_off(jobs.len());
    let view_content = cell - 2 * GUTTER;
    for (&(tree, centre, radius), grid) in spheres.iter().zip(&grids) {
        for j in 0..views {
            for i in 0..views {
                let d = OctahedralRecord::view_direction(views, i, j);
                let (right, up) = OctahedralRecord::view_basis(d);
                let (right, up) = (Vec3::from_array(right).as_dvec3(), Vec3::from_array(up).as_dvec3());
                jobs.push(Job {
                    tree,
                    kind: OCTAHEDRAL_VIEW,
                    centre,
                    quad: Quad { centre: DVec3::ZERO, u: right * radius, v: up * radius },
                    budget: 0,
                });
                regions.push(Region {
                    x: grid.x + i * cell,
                    y: grid.y + j * cell,
                    ..Region::new(view_content, view_content)
                });
            }
        }
    }

    // Stage: bake each quad: the tree's triangles about its centre, front-most from the normal's
    // side. Each tree's triangles are placed about its centre once, for all of its quads and
    // views (a job's centre is its tree's).
    let placed: Vec<Vec<(u32, [DVec3; 3])>> = by_tree
        .par_iter()
        .enumerate()
        .map(|(tree, tris)| {
            let Some(centre) = jobs.iter().find(|j| j.tree as usize == tree).map(|j| j.centre) else {
                return Vec::new();
            };
            tris.iter().map(|&t| (t, mesh.triangles[t as usize].v.map(|v| position(v) - centre))).collect()
        })
        .collect();
    let baked: Vec<Baked> = jobs
        .par_iter()
        .zip(&regions)
        .map(|(job, region)| {
            let normal = job.quad.u.cross(job.quad.v).normalize();
            let plane = PlaneFit { normal, offset: 0.0 };
            let triangles = &placed[job.tree as usize];
            // Only an octahedral view's depth plane is fitted (spec §6.13.2).
            let octahedral_view = job.kind == OCTAHEDRAL_VIEW;
            let samples = if octahedral_view { OCTAHEDRAL_SAMPLES } else { SAMPLES };
            let grid = (region.tw as usize * samples, region.th as usize * samples);
            // Front to back (by the nearest corner; ties in index order), so that the samples
            // of the triangles behind fail the depth test before they are shaded; only those
            // whose box holds a sample, which are all that draw, so the rest are not sorted
            // (the maple's octahedral views, 176 samples across, keep 118k–154k of its 669k
            // triangles; the bytes are the same, and the stage took 15.7 s instead of 27.4).
            let may_cover = MayCover::new(&job.quad, grid);
            let mut order: Vec<(f64, u32)> = triangles
                .iter()
                .enumerate()
                .filter(|(_, (_, corners))| may_cover.test(corners))
                .map(|(k, (_, corners))| {
                    #[expect(clippy::cast_possible_truncation, reason = "a tree's triangles fit u32")]
                    let k = k as u32;
                    (corners.iter().map(|p| p.dot(normal)).fold(f64::NEG_INFINITY, f64::max), k)
                })
                .collect();
            order.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            // Gathered once: `bake` goes over them once per band of rows and once before.
            let in_order: Vec<(u32, [DVec3; 3])> = order.iter().map(|&(_, k)| triangles[k as usize]).collect();
            bake(mesh, in_order.iter().copied(), &plane, Winner::Front, &job.quad, region, samples, octahedral_view)
        })
        .collect();
    // Each impostor's normal grid lies right of its colour grid, at half its size: a view's
    // normal cell at half its colour cell's place in the grid.
    let normal_shift = views * cell;
    let mut placed_regions = regions.clone();
    let mut levels: Vec<Vec<Vec<u8>>> = Vec::with_capacity(baked.len());
    let mut moments: Vec<DepthMoments> = Vec::with_capacity(baked.len());
    let mut normal_levels = Vec::new();
    let mut view_grids = grids.iter().flat_map(|grid| std::iter::repeat_n(grid, (views * views) as usize));
    for ((job, region), b) in jobs.iter().zip(&regions).zip(baked) {
        if job.kind == OCTAHEDRAL_VIEW
            && let Some(grid) = view_grids.next()
        {
            placed_regions.push(Region {
                tw: region.tw / 2,
                th: region.th / 2,
                rw: region.rw / 2,
                rh: region.rh / 2,
                x: grid.x + normal_shift + (region.x - grid.x) / 2,
                y: grid.y + (region.y - grid.y) / 2,
            });
            normal_levels.push(b.normals);
        }
        levels.push(b.levels);
        moments.push(b.moments);
    }
    levels.extend(normal_levels);
    let texels = compose(&placed_regions, &levels, width, height);

    // Stage: the records and each tree's texels.
    let mut facing_texels = vec![0u64; trees as usize];
    let mut crossed_texels = vec![0u64; trees as usize];
    let mut octahedral_texels = vec![0u64; trees as usize];
    let mut records = Vec::with_capacity(jobs.len());
    // The views' jobs follow the billboards', each impostor's together in the order of
    // `spheres` and of its views (`j · frames + i`): the section's order.
    let mut octahedral_depth = Vec::new();
    for ((job, region), moments) in jobs.iter().zip(&regions).zip(&moments) {
        if job.kind == OCTAHEDRAL_VIEW {
            // Its colour cell and its normal cell, a quarter of it.
            octahedral_texels[job.tree as usize] += region.texels() + region.texels() / 4;
            // In the record's units: the offset over its radius (the view's cell, gutter
            // included), the slopes as they are; none where the view shows nothing.
            let radius = job.quad.u.length() * f64::from(cell) / f64::from(view_content);
            let [a, b, c] = moments.plane().unwrap_or([0.0; 3]);
            #[expect(clippy::cast_possible_truncation, reason = "bounded")]
            octahedral_depth.push(OctahedralDepthRecord {
                offset: (a / radius).clamp(-1.0, 1.0) as f32,
                slope_s: b.clamp(-MAX_SLOPE, MAX_SLOPE) as f32,
                slope_t: c.clamp(-MAX_SLOPE, MAX_SLOPE) as f32,
            });
            continue;
        }
        let share = if job.kind == billboard_kind::FACING { &mut facing_texels } else { &mut crossed_texels };
        share[job.tree as usize] += region.texels();
        let (uv_min, uv_max) = region.uv(width, height);
        records.push(BillboardRecord {
            center: job.centre.as_vec3().to_array(),
            axis_u: job.quad.u.as_vec3().to_array(),
            axis_v: job.quad.v.as_vec3().to_array(),
            image: 0,
            uv_min,
            uv_max,
            tree: job.tree,
            kind: job.kind,
            reserved: [0; 2],
        });
    }
    // Each octahedral impostor's normal grid, to the right of its colour grid, half its side
    // (spec §6.13.3).
    let octahedral_normal_grids = grids
        .iter()
        .map(|grid| {
            let (w, h) = (f64::from(width), f64::from(height));
            let (x, y, side) = (f64::from(grid.x + normal_shift), f64::from(grid.y), f64::from(views * cell / 2));
            #[expect(clippy::cast_possible_truncation, reason = "uv in [0, 1]")]
            let record = OctahedralNormalGridRecord {
                uv_min: pack::unorm16x2((x / w) as f32, (y / h) as f32),
                uv_max: pack::unorm16x2(((x + side) / w) as f32, ((y + side) / h) as f32),
            };
            record
        })
        .collect();
    // Each octahedral impostor: the whole grid as its rectangle, each view's cell (gutter
    // included) as the square of `radius`.
    let octahedral = spheres
        .iter()
        .zip(&grids)
        .map(|(&(tree, centre, radius), grid)| {
            let (w, h) = (f64::from(width), f64::from(height));
            let side = f64::from(views * cell);
            let (x, y) = (f64::from(grid.x), f64::from(grid.y));
            #[expect(clippy::cast_possible_truncation, reason = "uv in [0, 1]; metres")]
            let record = OctahedralRecord {
                center: centre.as_vec3().to_array(),
                radius: (radius * f64::from(cell) / f64::from(view_content)) as f32,
                image: 0,
                uv_min: pack::unorm16x2((x / w) as f32, (y / h) as f32),
                uv_max: pack::unorm16x2(((x + side) / w) as f32, ((y + side) / h) as f32),
                frames: views,
                tree,
                occlusion: tree_occlusion(mesh, &placed[tree as usize]),
                diffuse: tree_diffuse(mesh, &placed[tree as usize], views),
                reserved: 0,
            };
            record
        })
        .collect();
    Ok(Some(Billboards {
        records,
        atlas: Atlas { width, height, format: treelod_format::image_format::RGBA8_SRGB, mip_count: MIP_LEVELS, texels },
        facing_texels,
        crossed_texels,
        octahedral_depth,
        octahedral_normal_grids,
        octahedral,
        octahedral_texels,
    }))
}

/// The steepest depth plane an octahedral view keeps (spec §6.13.1): `|b|, |c| ≤ 1`, the
/// plane at most 45° from facing its view.
const MAX_SLOPE: f64 = 1.0;

/// The occlusion of a tree's `triangles` (placed) as its views show them: their mean, each
/// weighted by its area and its share of open directions ([`seen_triangle_occlusion`]); 0 where
/// `mesh` has none.
fn tree_occlusion(mesh: &ImpostorMesh<'_>, triangles: &[(u32, [DVec3; 3])]) -> f32 {
    if mesh.occlusion.is_empty() {
        return 0.0;
    }
    seen_triangle_occlusion(mesh, triangles.iter().copied()).clamp(0.0, 1.0)
}

/// How a tree's `triangles` take the sun as its octahedral views show them (spec §6.13.1): the
/// mixture of [`diffuse_mixture`] whose `|n·d|` has the mean and mean square of the triangles'
/// (each weighted as [`diffuse_item`] weighs it), averaged over the directions `d` of the
/// `frames × frames` views.
fn tree_diffuse(mesh: &ImpostorMesh<'_>, triangles: &[(u32, [DVec3; 3])], frames: u32) -> PlaneDiffuseRecord {
    let items: Vec<(DVec3, f64)> = triangles.iter().map(|&(t, corners)| diffuse_item(mesh, t, corners)).collect();
    let (mut m1, mut m2, mut views) = (0.0, 0.0, 0.0);
    for j in 0..frames {
        for i in 0..frames {
            let d = Vec3::from_array(OctahedralRecord::view_direction(frames, i, j)).as_dvec3();
            if let Some((a, b)) = diffuse_moments(d, &items) {
                (m1, m2, views) = (m1 + a, m2 + b, views + 1.0);
            }
        }
    }
    if views > 0.0 { diffuse_mixture(m1 / views, m2 / views) } else { PlaneDiffuseRecord::FLAT }
}

/// Shelf-packs `regions` ([`shelf_pack`]) at the width, of up to 256 evenly spaced multiples of
/// [`ALIGN`] from the widest region's to twice the side of a square of their area (and at most
/// [`MAX_ATLAS`] where one fits), that gives the least atlas area (ties: the narrowest); returns
/// the atlas's size. A power-of-two width, as the impostor atlas has, would leave up to half of
/// the atlas empty: a tree's four regions are few and large.
fn pack_tight(regions: &mut [Region]) -> (u32, u32) {
    let area: u64 = regions.iter().map(Region::texels).sum();
    let widest = regions.iter().map(|r| r.rw).max().unwrap_or(ALIGN).max(ALIGN);
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "a square root of a u64 area")]
    let side = (area as f64).sqrt().ceil() as u32;
    let last = align(side.saturating_mul(2)).max(widest);
    let step = align((last - widest) / 256).max(ALIGN);
    let mut best: Option<(u64, u32)> = None;
    for width in (widest..=last).step_by(step as usize).filter(|&w| w <= MAX_ATLAS || w == widest) {
        let height = shelf_pack(regions, width);
        let texels = u64::from(width) * u64::from(height);
        if best.is_none_or(|(t, _)| texels < t) {
            best = Some((texels, width));
        }
    }
    let width = best.map_or(widest, |(_, w)| w);
    (width, shelf_pack(regions, width))
}

/// Content texels across and down for a quad of half-extents `half_u × half_v` metres at
/// `budget` texels (at least [`MIN_QUAD_TEXELS`]): the aspect of the quad, and the region
/// ([`Region::new`]) nearest to the budget in ratio; of equal regions, the largest content.
fn content_size(budget: u64, half_u: f64, half_v: f64) -> (u32, u32) {
    let budget = budget.max(MIN_QUAD_TEXELS) as f64;
    let aspect = half_v / half_u;
    let mut best = (f64::INFINITY, 1, 1);
    for tw in 1..=MAX_CONTENT {
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 1..=MAX_CONTENT")]
        let th = (f64::from(tw) * aspect).round().clamp(1.0, f64::from(MAX_CONTENT)) as u32;
        let texels = Region::new(tw, th).texels() as f64;
        let miss = (texels / budget).ln().abs();
        if miss <= best.0 {
            best = (miss, tw, th);
        }
        if texels > 4.0 * budget {
            break;
        }
    }
    (best.1, best.2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::impostor::{LeafTriangle, Surface};
    use crate::scene::{AlphaMode, Material};
    use treelod_format::{VertexRecord, pack};

    /// Opaque red, opaque blue and an invisible material (masked, alpha 0).
    fn materials() -> [Material; 3] {
        let colour = |base_color| Material { base_color, ..Material::default() };
        let invisible = Material {
            base_color: [1.0, 1.0, 1.0, 0.0],
            alpha_mode: AlphaMode::Mask,
            alpha_cutoff: 0.5,
            ..Material::default()
        };
        [colour([1.0, 0.0, 0.0, 1.0]), colour([0.0, 0.0, 1.0, 1.0]), invisible]
    }

    /// An axis-aligned rectangle in the plane `z` = const: `x0..x1 × y0..y1`.
    fn push_rect(
        vertices: &mut Vec<VertexRecord>,
        triangles: &mut Vec<LeafTriangle>,
        [x0, x1, y0, y1, z]: [f32; 5],
        material: u32,
        tree: u32,
    ) {
        #[expect(clippy::cast_possible_truncation, reason = "a test mesh")]
        let base = vertices.len() as u32;
        for (x, y) in [(x0, y0), (x1, y0), (x1, y1), (x0, y1)] {
            vertices.push(VertexRecord { position: [x, y, z], normal: 0, uv: [0.0; 2], color: u32::MAX });
        }
        triangles.push(LeafTriangle { v: [base, base + 1, base + 2], material, tree });
        triangles.push(LeafTriangle { v: [base, base + 2, base + 3], material, tree });
    }

    /// A tree standing at `(dx, 0, 0)`: a red rectangle over `x ∈ [−1, 0]`, `y ∈ [0, 4]` at
    /// `z = 0.6`, a blue one behind it at `z = −0.3`, and an invisible one over `x ∈ [0, 1]` at
    /// `z = 0` that widens its bounds: the right half of a view from `+Z` is empty.
    fn tree(vertices: &mut Vec<VertexRecord>, triangles: &mut Vec<LeafTriangle>, dx: f32, tree: u32) {
        push_rect(vertices, triangles, [dx - 1.0, dx, 0.0, 4.0, -0.3], 1, tree);
        push_rect(vertices, triangles, [dx - 1.0, dx, 0.0, 4.0, 0.6], 0, tree);
        push_rect(vertices, triangles, [dx, dx + 1.0, 0.0, 4.0, 0.0], 2, tree);
    }

    fn build(vertices: &[VertexRecord], triangles: &[LeafTriangle], trees: u32, budget: &[u64]) -> Billboards {
        let materials = materials();
        let surfaces: Vec<Surface<'_>> = materials.iter().map(|m| Surface { material: m, image: None }).collect();
        let mesh = ImpostorMesh { vertices, triangles, surfaces: &surfaces, occlusion: &[] };
        build_billboards(&mesh, trees, budget, None).unwrap().unwrap()
    }

    /// The content rectangle of a record in level 0: `(x0, y0, x1, y1)`, texels.
    fn rect(atlas: &Atlas, record: &BillboardRecord) -> (usize, usize, usize, usize) {
        let [u0, v0] = pack::unpack_unorm16x2(record.uv_min);
        let [u1, v1] = pack::unpack_unorm16x2(record.uv_max);
        let (w, h) = (atlas.width as f32, atlas.height as f32);
        let px = |u: f32, size: f32| (u * size).round() as usize;
        (px(u0, w), px(v0, h), px(u1, w), px(v1, h))
    }

    fn texel(atlas: &Atlas, x: usize, y: usize) -> [u8; 4] {
        let i = (y * atlas.width as usize + x) * 4;
        [atlas.texels[i], atlas.texels[i + 1], atlas.texels[i + 2], atlas.texels[i + 3]]
    }

    /// The level-0 texel of `record`'s image where the block-space point `p` projects.
    fn texel_at(atlas: &Atlas, record: &BillboardRecord, p: Vec3) -> [u8; 4] {
        let (c, u, v) =
            (Vec3::from_array(record.center), Vec3::from_array(record.axis_u), Vec3::from_array(record.axis_v));
        let (s, t) = ((p - c).dot(u) / u.length_squared(), (p - c).dot(v) / v.length_squared());
        let (x0, y0, x1, y1) = rect(atlas, record);
        let x = x0 as f32 + (s + 1.0) * 0.5 * (x1 - x0) as f32;
        let y = y0 as f32 + (t + 1.0) * 0.5 * (y1 - y0) as f32;
        texel(atlas, x.floor() as usize, y.floor() as usize)
    }

    const RED: [u8; 3] = [255, 0, 0];
    const BLUE: [u8; 3] = [0, 0, 255];

    /// The level-0 texel of view `(i, j)` of `record`'s grid where the block-space point `p`
    /// projects (spec §6.13.1).
    fn view_texel_at(atlas: &Atlas, record: &OctahedralRecord, view: (u32, u32), p: Vec3) -> [u8; 4] {
        let (x, y) = view_texel_xy(atlas, record, view, p);
        texel(atlas, x, y)
    }

    /// Where [`view_texel_at`] reads: the level-0 texel's column and row.
    fn view_texel_xy(atlas: &Atlas, record: &OctahedralRecord, (i, j): (u32, u32), p: Vec3) -> (usize, usize) {
        let d = OctahedralRecord::view_direction(record.frames, i, j);
        let (right, up) = OctahedralRecord::view_basis(d);
        let q = p - Vec3::from_array(record.center);
        let (s, t) = (q.dot(Vec3::from_array(right)) / record.radius, q.dot(Vec3::from_array(up)) / record.radius);
        let [u0, v0] = pack::unpack_unorm16x2(record.uv_min);
        let [u1, v1] = pack::unpack_unorm16x2(record.uv_max);
        let n = record.frames as f32;
        let u = u0 + (i as f32 + (s + 1.0) * 0.5) / n * (u1 - u0);
        let v = v0 + (j as f32 + (t + 1.0) * 0.5) / n * (v1 - v0);
        ((u * atlas.width as f32).floor() as usize, (v * atlas.height as f32).floor() as usize)
    }

    /// Each octahedral view's normal cell (spec §6.13.3) holds, where its colour cell shows a
    /// surface, that surface's shading normal turned towards the viewer, `(n + 1)/2` sRGB-encoded,
    /// and its ambient occlusion in alpha: from `+Z` the red card's normal tilted 45° towards `+X`
    /// and its occlusion 0.5; from `−Z` the blue card's `+Z` normal turned to `−Z`, occlusion 0.
    #[test]
    fn octahedral_normal_cells_hold_the_front_surfaces_normals_and_occlusion() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        let tilted = Vec3::new(1.0, 0.0, 1.0).normalize();
        for (k, v) in vertices.iter_mut().enumerate() {
            // The blue card (0–3) faces +Z; the red one (4–7) is lit as if tilted.
            let normal = if (4..8).contains(&k) { tilted } else { Vec3::Z };
            v.normal = pack::oct_encode(normal.to_array());
        }
        let materials = materials();
        let surfaces: Vec<Surface<'_>> = materials.iter().map(|m| Surface { material: m, image: None }).collect();
        let occlusion: Vec<f32> = (0..triangles.len()).map(|t| if (2..4).contains(&t) { 0.5 } else { 0.0 }).collect();
        let mesh =
            ImpostorMesh { vertices: &vertices, triangles: &triangles, surfaces: &surfaces, occlusion: &occlusion };
        let out = build_billboards(&mesh, 1, &[20_000], Some(&OctahedralConfig::default())).unwrap().unwrap();
        let (record, normals) = (&out.octahedral[0], &out.octahedral_normal_grids[..]);
        assert_eq!(normals.len(), 1);
        let n = record.frames;
        // The normal cell's texel: the colour texel's place in the colour grid, halved, in the
        // normal grid.
        let (w, h) = (out.atlas.width as f32, out.atlas.height as f32);
        let corner = |packed: u32| {
            let [u, v] = pack::unpack_unorm16x2(packed);
            ((u * w).round() as usize, (v * h).round() as usize)
        };
        let (colour_grid, normal_grid) = (corner(record.uv_min), corner(normals[0].uv_min));
        let normal_at = |view: (u32, u32), p: Vec3| {
            let colour = view_texel_at(&out.atlas, record, view, p);
            assert!(colour[3] >= 128, "the colour cell shows a surface at {p}: {colour:?}");
            let (x, y) = view_texel_xy(&out.atlas, record, view, p);
            let t = texel(&out.atlas, normal_grid.0 + (x - colour_grid.0) / 2, normal_grid.1 + (y - colour_grid.1) / 2);
            let unit = |b: u8| 2.0 * crate::texture::srgb_to_linear_table()[b as usize] - 1.0;
            (Vec3::new(unit(t[0]), unit(t[1]), unit(t[2])), f32::from(t[3]) / 255.0)
        };
        let front = Vec3::new(-0.5, 2.0, 0.6);
        let (from_z, ao) = normal_at((n - 1, 0), front);
        assert!(from_z.abs_diff_eq(tilted, 0.02), "{from_z}");
        assert!((ao - 0.5).abs() < 0.01, "{ao}");
        let (from_minus_z, ao) = normal_at((0, n - 1), front);
        assert!(from_minus_z.abs_diff_eq(-Vec3::Z, 0.02), "{from_minus_z}");
        assert!(ao.abs() < 0.01, "{ao}");
        // A texel whose surfaces agree takes the sun by their normal alone, not the mixture.
        let lit = treelod_format::OctahedralNormalRecord::sun_factor(from_z.to_array(), tilted.to_array(), 0.25);
        assert!((lit - 1.0).abs() < 0.03, "a normal facing the sun takes it whole: {lit}");
    }

    /// Each octahedral view's depth plane (spec §6.13.2) is fitted to the front-most surfaces
    /// it shows: from the horizon at `+Z` the red card, 0.45 m in front of the centre, from `−Z`
    /// the blue one, 0.45 m in front seen from there; edge on, nothing (the plane through the
    /// centre). A card tilted about the vertical, `z = x/2`, reads slope 1/2 from `+Z`.
    #[test]
    fn octahedral_depth_planes_follow_the_front_surfaces() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        // Tree 1: one red card over x ∈ [4, 6], y ∈ [0, 2], tilted: z = (x − 5)/2.
        for (x, y) in [(4.0f32, 0.0f32), (6.0, 0.0), (6.0, 2.0), (4.0, 2.0)] {
            vertices.push(VertexRecord { position: [x, y, 0.5 * (x - 5.0)], normal: 0, uv: [0.0; 2], color: u32::MAX });
        }
        triangles.push(LeafTriangle { v: [12, 13, 14], material: 0, tree: 1 });
        triangles.push(LeafTriangle { v: [12, 14, 15], material: 0, tree: 1 });
        let materials = materials();
        let surfaces: Vec<Surface<'_>> = materials.iter().map(|m| Surface { material: m, image: None }).collect();
        let mesh = ImpostorMesh { vertices: &vertices, triangles: &triangles, surfaces: &surfaces, occlusion: &[] };
        let out = build_billboards(&mesh, 2, &[20_000, 20_000], Some(&OctahedralConfig::default())).unwrap().unwrap();
        let n = OCTAHEDRAL_FRAMES as usize;
        assert_eq!(out.octahedral_depth.len(), 2 * n * n, "every view of each impostor");
        let plane = |tree: usize, i: usize, j: usize| {
            let p = out.octahedral_depth[tree * n * n + j * n + i];
            [p.offset, p.slope_s, p.slope_t]
        };
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 0.01);
        let r0 = out.octahedral[0].radius;
        assert!(close(plane(0, n - 1, 0), [0.45 / r0, 0.0, 0.0]), "{:?}", plane(0, n - 1, 0));
        assert!(close(plane(0, 0, n - 1), [0.45 / r0, 0.0, 0.0]), "{:?}", plane(0, 0, n - 1));
        assert_eq!(plane(0, n - 1, n - 1), [0.0; 3], "cards edge on: nothing seen");
        // From +Z (right = +X, up = +Y) the tilted card's depth grows with s at 1/2.
        assert!(close(plane(1, n - 1, 0), [0.0, 0.5, 0.0]), "{:?}", plane(1, n - 1, 0));
        // From −Z (right = −X, up = +Y) its depth along −Z, (5 − x)/2, also grows with s at 1/2.
        assert!(close(plane(1, 0, n - 1), [0.0, 0.5, 0.0]), "{:?}", plane(1, 0, n - 1));
        // Every plane is within the spec's bounds.
        let values = out.octahedral_depth.iter().flat_map(|p| [p.offset, p.slope_s, p.slope_t]);
        assert!(values.into_iter().all(|v| v.is_finite() && v.abs() <= 1.0));
    }

    /// Each tree's octahedral impostor: its grid of square cells in the atlas, the bounding
    /// sphere's square in each cell's content, and the views as the spec maps them: from the
    /// horizon at `+Z` the red card in front, from `−Z` the blue one, from `+X` both cards edge on
    /// (nothing), the cells' borders transparent; with the default views and texels and with
    /// others (`--octahedral-views`, `--octahedral-texels`).
    #[test]
    fn octahedral_views_show_the_tree_from_their_directions() {
        for config in [OctahedralConfig::default(), OctahedralConfig { views: 7, texels: 64 }] {
            octahedral_views_as_configured(config);
        }
    }

    fn octahedral_views_as_configured(config: OctahedralConfig) {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        tree(&mut vertices, &mut triangles, 5.0, 1);
        let materials = materials();
        let surfaces: Vec<Surface<'_>> = materials.iter().map(|m| Surface { material: m, image: None }).collect();
        let occlusion: Vec<f32> = (0..triangles.len()).map(|t| if t < 6 { 0.5 } else { 0.0 }).collect();
        let mesh =
            ImpostorMesh { vertices: &vertices, triangles: &triangles, surfaces: &surfaces, occlusion: &occlusion };
        let out = build_billboards(&mesh, 2, &[20_000, 20_000], Some(&config)).unwrap().unwrap();
        assert_eq!(out.records.len(), 8, "the billboards as without");
        assert_eq!(out.octahedral.len(), 2);
        let n = config.views;
        for (k, r) in out.octahedral.iter().enumerate() {
            let dx = 5.0 * k as f32;
            assert_eq!((r.tree, r.frames, r.image, r.reserved), (k as u32, n, 0, 0));
            // Centre of the bounds; the farthest corner (±1, 0 or 4, −0.3) 2.0224 from it, and a
            // gutter of 4 texels on each side of a cell.
            let c = Vec3::new(dx, 2.0, 0.15);
            assert!(Vec3::from_array(r.center).abs_diff_eq(c, 1e-6), "{r:?}");
            let sphere = (1.0f32 + 4.0 + 0.45 * 0.45).sqrt();
            let (cell, content) = (config.texels as f32, (config.texels - 2 * GUTTER) as f32);
            assert!((r.radius - sphere * cell / content).abs() < 1e-4, "{r:?}");
            // Tree 0's triangles are half occluded, tree 1's open.
            assert!((r.occlusion - if k == 0 { 0.5 } else { 0.0 }).abs() < 1e-6, "{r:?}");
            let (x0, y0, x1, y1) = {
                let [u0, v0] = pack::unpack_unorm16x2(r.uv_min);
                let [u1, v1] = pack::unpack_unorm16x2(r.uv_max);
                let (w, h) = (out.atlas.width as f32, out.atlas.height as f32);
                ((u0 * w).round() as u32, (v0 * h).round() as u32, (u1 * w).round() as u32, (v1 * h).round() as u32)
            };
            let c = config.texels;
            assert_eq!((x1 - x0, y1 - y0), (n * c, n * c), "{r:?}");
            assert_eq!((x0 % ALIGN, y0 % ALIGN), (0, 0));
            // The colour cells and as many normal cells at half their side (spec §6.13.3), right
            // of them.
            assert_eq!(out.octahedral_texels[k], u64::from(n * n * c * c + n * n * c * c / 4));
            let grid = out.octahedral_normal_grids[k];
            let (w, h) = (out.atlas.width as f32, out.atlas.height as f32);
            let at = |packed: u32| {
                let [u, v] = pack::unpack_unorm16x2(packed);
                ((u * w).round() as u32, (v * h).round() as u32)
            };
            assert_eq!(
                (at(grid.uv_min), at(grid.uv_max)),
                ((x0 + n * c, y0), (x0 + n * c + n * c / 2, y0 + n * c / 2))
            );
            assert_eq!(
                ((x0 + n * c) % ALIGN, (c / 2) % ALIGN),
                (0, 0),
                "each level of the normal cells on whole texels"
            );
            // The horizon at +Z is view (N − 1, 0), at −Z (0, N − 1), at +X (N − 1, N − 1).
            let front = Vec3::new(dx - 0.5, 2.0, 0.6);
            assert_eq!(view_texel_at(&out.atlas, r, (n - 1, 0), front)[..3], RED);
            assert_eq!(view_texel_at(&out.atlas, r, (0, n - 1), front)[..3], BLUE);
            assert_eq!(view_texel_at(&out.atlas, r, (n - 1, n - 1), front)[3], 0, "cards edge on");
            // The invisible card's half is empty from the front.
            assert_eq!(view_texel_at(&out.atlas, r, (n - 1, 0), Vec3::new(dx + 0.5, 2.0, 0.0))[3], 0);
            // Every cell's border (its gutter) is transparent, in every view.
            for j in 0..n {
                for i in 0..n {
                    let (cx, cy, c) = ((x0 + i * c) as usize, (y0 + j * c) as usize, c as usize);
                    for e in 0..c {
                        for (x, y) in [(cx + e, cy), (cx, cy + e), (cx + e, cy + c - 1), (cx + c - 1, cy + e)] {
                            assert_eq!(texel(&out.atlas, x, y)[3], 0, "view ({i}, {j}) at ({x}, {y})");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn octahedral_settings_out_of_range_are_refused() {
        assert!(OctahedralConfig::default().validate().is_ok());
        for (views, texels) in [(1, 96), (65, 96), (16, 16), (16, 100), (16, 48), (16, 272), (2, 32), (64, 256)] {
            let config = OctahedralConfig { views, texels };
            let valid = (2..=64).contains(&views) && (32..=256).contains(&texels) && texels.is_multiple_of(32);
            assert_eq!(config.validate().is_ok(), valid, "{config:?}");
        }
        let pairs: Vec<(String, String)> =
            OctahedralConfig::default().settings().into_iter().map(|s| (s.key, s.value)).collect();
        assert_eq!(
            pairs,
            [("baselines.octahedral_views".into(), "16".into()), ("baselines.octahedral_texels".into(), "96".into())]
        );
        // The builder refuses a bad configuration before it bakes anything.
        let empty = ImpostorMesh { vertices: &[], triangles: &[], surfaces: &[], occlusion: &[] };
        assert!(build_billboards(&empty, 1, &[100], Some(&OctahedralConfig { views: 1, texels: 96 })).is_err());
    }

    #[test]
    fn records_have_the_axis_extent_kind_and_order_of_the_module_documentation() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        let out = build(&vertices, &triangles, 1, &[20_000]);
        let kinds: Vec<u32> = out.records.iter().map(|r| r.kind).collect();
        assert_eq!(kinds, [billboard_kind::FACING, billboard_kind::CROSSED, billboard_kind::CROSSED, 1]);
        // Bounds x ∈ [−1, 1], y ∈ [0, 4], z ∈ [−0.3, 0.6]: the axis at x = 0, z = 0.15; the
        // farthest corners 1 across and 0.45 deep from it.
        let radius = (1.0f32 + 0.45 * 0.45).sqrt();
        for (k, r) in out.records.iter().enumerate() {
            assert_eq!((r.tree, r.image, r.reserved), (0, 0, [0, 0]));
            let (c, u, v) = (Vec3::from_array(r.center), Vec3::from_array(r.axis_u), Vec3::from_array(r.axis_v));
            assert!(c.abs_diff_eq(Vec3::new(0.0, 2.0, 0.15), 1e-6), "{r:?}");
            assert!(v.abs_diff_eq(Vec3::new(0.0, 2.0, 0.0), 1e-6), "{r:?}");
            assert!((u.length() - radius).abs() < 1e-5 && u.y == 0.0, "{r:?}");
            // Facing and the first crossed quad face +Z; the others are turned 60° and 120° about +Y.
            let angle = std::f32::consts::FRAC_PI_3 * k.saturating_sub(1) as f32;
            let normal = u.cross(v).normalize();
            assert!(normal.abs_diff_eq(Vec3::new(angle.sin(), 0.0, angle.cos()), 1e-5), "record {k}: {normal}");
        }
    }

    #[test]
    fn images_show_the_front_most_surface_from_the_normal_side_unmirrored() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        let out = build(&vertices, &triangles, 1, &[20_000]);
        let atlas = &out.atlas;
        assert_eq!((atlas.width % 16, atlas.height % 16, atlas.mip_count), (0, 0, 5));
        // Facing: the red rectangle hides the blue one; the tree's left half (−X, where the
        // rectangles are) is covered and the right half empty: the image is not mirrored.
        let facing = &out.records[0];
        let (x0, y0, x1, y1) = rect(atlas, facing);
        let mid = (x0 + x1) / 2;
        for y in y0..y1 {
            for x in x0..x1 {
                let t = texel(atlas, x, y);
                if x + 1 < mid && x > x0 + (x1 - x0) / 10 {
                    assert_eq!(t[..3], RED, "({x}, {y}) of {x0}..{x1}");
                    assert!(t[3] >= 128, "({x}, {y}): {t:?}");
                } else if x > mid {
                    assert!(t[3] == 0, "({x}, {y}) of {x0}..{x1}: {t:?}");
                }
            }
        }
        // Covered: the rectangles' width 1 of the quad's 2R, all of its height.
        let covered =
            (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| texel(atlas, x, y)[3] >= 128);
        let (covered, all) = (covered.count() as f32, ((x1 - x0) * (y1 - y0)) as f32);
        let radius = (1.0f32 + 0.45 * 0.45).sqrt();
        let want = 0.5 / radius;
        assert!((covered / all - want).abs() < 0.03, "{covered} of {all} texels covered, want {want}");
        // The crossed quads: at 0° as the facing one; at 60° and 120° the two rectangles project
        // apart, each where its points project, in its colour.
        let red = |x: f32| Vec3::new(x, 2.0, 0.6);
        let blue = |x: f32| Vec3::new(x, 2.0, -0.3);
        for r in &out.records[..2] {
            assert_eq!(texel_at(atlas, r, red(-0.5))[..3], RED);
            assert_eq!(texel_at(atlas, r, blue(-0.5))[..3], RED);
            assert_eq!(texel_at(atlas, r, Vec3::new(0.5, 2.0, 0.0))[3], 0);
        }
        for r in &out.records[2..] {
            for x in [-0.8, -0.5, -0.2] {
                assert_eq!(texel_at(atlas, r, red(x))[..3], RED, "{r:?}");
                assert_eq!(texel_at(atlas, r, blue(x))[..3], BLUE, "{r:?}");
            }
        }
    }

    #[test]
    fn the_atlas_gives_each_quad_its_share_of_the_budget() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        tree(&mut vertices, &mut triangles, 5.0, 1);
        let budget = [60_000, 0];
        let out = build(&vertices, &triangles, 3, &budget);
        // Two trees with triangles, the third none.
        assert_eq!(out.records.len(), 8);
        assert_eq!((out.facing_texels.len(), out.crossed_texels.len()), (3, 3));
        assert_eq!((out.facing_texels[2], out.crossed_texels[2]), (0, 0));
        // Within a few per cent of the budget for the facing quad and a third of it for each
        // crossed one (16-texel steps of a 240-texel side).
        let facing = out.facing_texels[0] as f64;
        let crossed = out.crossed_texels[0] as f64;
        assert!((facing / 60_000.0 - 1.0).abs() < 0.1, "{facing}");
        assert!((crossed / 60_000.0 - 1.0).abs() < 0.15, "{crossed}");
        // The tree without a budget gets the least size: a 32 × 32 region's worth per quad.
        assert!((out.facing_texels[1] as f64 / 1024.0 - 1.0).abs() < 0.6, "{}", out.facing_texels[1]);
        assert!((out.crossed_texels[1] as f64 / 3072.0 - 1.0).abs() < 0.6, "{}", out.crossed_texels[1]);
        // Square texels: content aspect R : h.
        let radius = (1.0f32 + 0.45 * 0.45).sqrt();
        for r in &out.records {
            let (x0, y0, x1, y1) = rect(&out.atlas, r);
            let aspect = (x1 - x0) as f32 / (y1 - y0) as f32;
            assert!((aspect / (radius / 2.0) - 1.0).abs() < 0.1, "{aspect}");
        }
        // The second tree's records stand at its place.
        for (k, r) in out.records.iter().enumerate() {
            let want = if k < 4 { 0 } else { 1 };
            assert_eq!(r.tree, want);
            assert!((r.center[0] - 5.0 * want as f32).abs() < 1e-5);
        }
        // Regions are disjoint.
        let rects: Vec<_> = out.records.iter().map(|r| rect(&out.atlas, r)).collect();
        for (i, a) in rects.iter().enumerate() {
            for b in &rects[i + 1..] {
                assert!(a.2 <= b.0 || b.2 <= a.0 || a.3 <= b.1 || b.3 <= a.1, "{a:?} overlaps {b:?}");
            }
        }
    }

    /// A quad of several bands of rows bakes its bands in parallel unless it fits a depth plane,
    /// whose sums go in the rows' order: either way, each sample sees the triangles as in one
    /// pass, so the images are the same, on one thread or several.
    #[test]
    fn bands_baked_in_parallel_give_the_images_of_bands_baked_in_turn() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        tree(&mut vertices, &mut triangles, 0.0, 0);
        let materials = materials();
        let surfaces: Vec<Surface<'_>> = materials.iter().map(|m| Surface { material: m, image: None }).collect();
        let mesh = ImpostorMesh { vertices: &vertices, triangles: &triangles, surfaces: &surfaces, occlusion: &[] };
        let centre = DVec3::new(0.0, 2.0, 0.0);
        let placed: Vec<(u32, [DVec3; 3])> = (0u32..)
            .zip(&triangles)
            .map(|(t, tri)| (t, tri.v.map(|v| Vec3::from_array(vertices[v as usize].position).as_dvec3() - centre)))
            .collect();
        let quad = Quad { centre: DVec3::ZERO, u: DVec3::X, v: DVec3::Y * 2.0 };
        let plane = PlaneFit { normal: DVec3::Z, offset: 0.0 };
        // 200 rows of content: four bands of 64 rows.
        let region = Region::new(100, 200);
        let bake_with = |threads: usize, fit_depth: bool| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                bake(&mesh, placed.iter().copied(), &plane, Winner::Front, &quad, &region, SAMPLES, fit_depth)
            })
        };
        let baked = bake_with(1, true);
        let (in_turn, moments) = (baked.levels, baked.moments);
        assert!(moments.plane().is_some(), "the depth fit saw the red card");
        let level0 = &in_turn[0];
        // The red card covers the left half of every band's rows.
        let at =
            |x: usize, y: usize| &level0[((y + GUTTER as usize) * region.rw as usize + x + GUTTER as usize) * 4..][..4];
        for y in [0, 63, 64, 130, 199] {
            // (Alpha scaled by the coverage-preserving mips, passing the test at one half.)
            assert!(at(10, y)[..3] == RED && at(10, y)[3] >= 128, "row {y}: {:?}", at(10, y));
            assert_eq!(at(90, y)[3], 0, "row {y}");
        }
        for threads in [1, 3] {
            assert!(bake_with(threads, false).levels == in_turn, "{threads} thread(s)");
        }
    }

    #[test]
    fn the_bake_is_the_same_on_any_number_of_threads_and_empty_input_gives_none() {
        let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
        for t in 0..3 {
            tree(&mut vertices, &mut triangles, 3.0 * t as f32, t);
        }
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| build(&vertices, &triangles, 3, &[30_000, 10_000, 5_000]))
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert_eq!(one.records.len(), 12);
        let materials = materials();
        let surfaces = [Surface { material: &materials[0], image: None }];
        let empty = ImpostorMesh { vertices: &vertices, triangles: &[], surfaces: &surfaces, occlusion: &[] };
        assert_eq!(build_billboards(&empty, 1, &[100], Some(&OctahedralConfig::default())).unwrap(), None);
    }
}
