//! Frame-level selection on the CPU: which instances are in view, and per instance and cell which
//! prefixes of the triangle and point arrays to draw (spec §10; Gilet, Meyer, Neyret 2005, §5).
//!
//! [`ModelLod`] is a per-model view of a container made once (cell bounds, ranges, and the sort keys
//! of each cell copied into compact arrays). Each frame, [`select_frame`] walks the instances in
//! order, culls them against the [`Frustum`] of the [`Camera`], computes per cell the two world-size
//! thresholds `τ_p ≤ τ_t` from the pixel thresholds of [`LodSettings`] (with Gilet's front-to-back
//! depth bias), binary-searches the size-sorted arrays and appends one [`DrawRange`] per non-empty
//! prefix to a reused [`DrawList`]. [`BudgetController`] adjusts `s_min` from frame to frame to keep
//! the primitive count near a target (Gilet §5.1: `s_m` "allows the user to control the frame rate,
//! or to keep the frame rate constant").
//!
//! Nothing here touches the GPU: a renderer uploads the draw list as indirect draws, and the vertex
//! shader drops the points of a prefix that fail [`crate::point_drawn`] at the range's thresholds.

use glam::{Mat4, Vec3, Vec4};
use treelod_format::{BlockRecord, CellRecord, Container, PointRecord, Range, TriangleRecord};

/// A perspective camera as selection sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, world space, metres.
    pub position: Vec3,
    /// World to clip, WebGPU conventions (clip-space depth `0 ..= w`).
    pub view_proj: Mat4,
    /// Viewport height, pixels (`> 0`).
    pub viewport_height: f32,
    /// Vertical field of view, radians, in `(0, π)`.
    pub fovy: f32,
}

impl Camera {
    /// A camera at `eye` looking at `target` (see [`look_at_matrices`]), vertical field of view
    /// `fovy` radians, a `width`×`height` pixel viewport.
    #[must_use]
    pub fn look_at(eye: Vec3, target: Vec3, fovy: f32, width: u32, height: u32) -> Self {
        let (view, proj) = look_at_matrices(eye, target, fovy, width, height);
        #[expect(clippy::cast_precision_loss, reason = "viewport heights are far below 2^24")]
        Self { position: eye, view_proj: proj * view, viewport_height: height.max(1) as f32, fovy }
    }

    /// World size per pixel at one metre of distance: `2·tan(fovy/2) / H` (spec §10.1), so
    /// `τ = s_px · d · world_per_pixel()`.
    #[must_use]
    pub fn world_per_pixel(&self) -> f32 {
        2.0 * (0.5 * self.fovy).tan() / self.viewport_height
    }
}

/// The view and projection of a camera at `eye` looking at `target` with Y up (Z up when looking
/// straight up or down), vertical field of view `fovy` radians, a `width`×`height` viewport:
/// right-handed view, WebGPU depth range 0..1, near plane 0.05 m, far plane 20 km. The one
/// projection of the runtime's and `treelod-render`'s cameras.
#[must_use]
pub fn look_at_matrices(eye: Vec3, target: Vec3, fovy: f32, width: u32, height: u32) -> (Mat4, Mat4) {
    let forward = (target - eye).normalize_or(Vec3::NEG_Z);
    // Looking straight up or down: any up vector not parallel to the view direction.
    let up = if forward.cross(Vec3::Y).length_squared() < 1e-8 { Vec3::Z } else { Vec3::Y };
    #[expect(clippy::cast_precision_loss, reason = "viewport sizes are far below 2^24")]
    let aspect = width.max(1) as f32 / height.max(1) as f32;
    let view = glam::camera::rh::view::look_at_mat4(eye, target, up);
    let proj = glam::camera::rh::proj::directx::perspective(fovy, aspect, 0.05, 20_000.0);
    (view, proj)
}

/// Where a bounding volume lies with respect to a [`Frustum`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Containment {
    Outside,
    Inside,
    Straddles,
}

/// The six planes of a view-projection's frustum, for conservative culling.
///
/// Each plane is `(n, w)` with `n` a unit normal pointing into the frustum: a point `p` is on the
/// inner side when `n·p + w ≥ 0`. Planes are extracted from the rows of the matrix (Gribb and
/// Hartmann) for WebGPU clip space: `−w ≤ x ≤ w`, `−w ≤ y ≤ w`, `0 ≤ z ≤ w`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    planes: [Vec4; 6],
}

impl Frustum {
    /// The frustum of `view_proj` (world to clip, clip-space depth `0 ..= w`).
    #[must_use]
    pub fn from_view_proj(view_proj: Mat4) -> Self {
        let r = [view_proj.row(0), view_proj.row(1), view_proj.row(2), view_proj.row(3)];
        let planes = [r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[2], r[3] - r[2]]
            .map(|p| p / p.truncate().length().max(f32::MIN_POSITIVE));
        Self { planes }
    }

    /// The planes: left, right, bottom, top, near, far; see the type's documentation.
    #[must_use]
    pub fn planes(&self) -> &[Vec4; 6] {
        &self.planes
    }

    /// Whether the world-space box `min ..= max` may be visible: `false` only if it lies entirely
    /// outside one plane (conservative: a box near a corner of the frustum may be kept).
    #[must_use]
    pub fn intersects_aabb(&self, min: Vec3, max: Vec3) -> bool {
        let centre = 0.5 * (min + max);
        let half = 0.5 * (max - min);
        self.planes.iter().all(|p| p.truncate().dot(centre) + p.w >= -p.truncate().abs().dot(half))
    }

    /// Whether the world-space sphere may be visible (conservative as [`Self::intersects_aabb`]).
    #[must_use]
    pub fn intersects_sphere(&self, centre: Vec3, radius: f32) -> bool {
        self.classify_sphere(centre, radius) != Containment::Outside
    }

    /// Whether the model-space sphere `(centre, radius)` of an instance drawn by `transform` lies
    /// wholly inside the frustum (on the inner side of every plane by at least its radius, scaled
    /// by the transform's largest axis): none of the instance's cells is culled. `false` where the
    /// transform is degenerate.
    #[must_use]
    pub fn contains_instance_sphere(&self, transform: Mat4, (centre, radius): (Vec3, f32)) -> bool {
        usable_scale(transform).is_some_and(|scale| {
            self.classify_sphere(transform.transform_point3(centre), radius * scale) == Containment::Inside
        })
    }

    fn classify_sphere(&self, centre: Vec3, radius: f32) -> Containment {
        let mut inside = true;
        for p in &self.planes {
            let distance = p.truncate().dot(centre) + p.w;
            if distance < -radius {
                return Containment::Outside;
            }
            inside &= distance >= radius;
        }
        if inside { Containment::Inside } else { Containment::Straddles }
    }

    /// The frustum's planes in the model space of an instance drawn by `transform`: per plane,
    /// `n·p + w` as a function of the model-space point, and the reach of a unit half-extent
    /// along each model axis (for [`cell_in_view`]).
    pub(crate) fn model_planes(&self, transform: Mat4) -> [(Vec4, Vec3); 6] {
        let (ax, ay, az, t) = (
            transform.x_axis.truncate(),
            transform.y_axis.truncate(),
            transform.z_axis.truncate(),
            transform.w_axis.truncate(),
        );
        self.planes.map(|p| {
            let n = p.truncate();
            let along = Vec3::new(n.dot(ax), n.dot(ay), n.dot(az));
            (along.extend(n.dot(t) + p.w), along.abs())
        })
    }

    /// Whether the oriented box with world centre `centre` and half-axis vectors `axes` may be visible.
    fn intersects_box(&self, centre: Vec3, axes: [Vec3; 3]) -> bool {
        self.planes.iter().all(|p| {
            let n = p.truncate();
            let reach = n.dot(axes[0]).abs() + n.dot(axes[1]).abs() + n.dot(axes[2]).abs();
            n.dot(centre) + p.w >= -reach
        })
    }
}

/// Level-of-detail settings of [`select_frame`].
///
/// Gilet et al. give no default values for the pixel thresholds; the defaults here are one-pixel
/// points and triangles from two pixels on (the renderer's defaults: at 1–2 px a point and the
/// triangle it replaces cover the same pixels, see `crates/treelod-render/tests/render.rs`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LodSettings {
    /// `s_m`, pixels: the smallest projected size of a drawn point; finer points give way to their
    /// parent (Gilet §5.1). Default 1.
    pub s_min: f32,
    /// `s_M`, pixels: primitives projecting larger than this are drawn as triangles (Gilet §5.1);
    /// raised to `s_min` if smaller. Default 2.
    pub s_max: f32,
    /// `k`, pixels: Gilet's depth bias (§5.2, eq. 2 and 3), added to both pixel thresholds times
    /// `Z_i ∈ [−1, 1]` (front to back of the block), so the back of a block is drawn coarser and
    /// the front finer; see [`Self::biased_pixels`]. The paper writes the shift on its thresholds
    /// `S_m`, `S_M` and shows them in pixel units (its Figure 3); applied in pixels, as here, the
    /// front/back contrast is the same at every distance, whereas a shift in metres would vanish
    /// for far blocks and swamp near ones. 0 disables it. Default 0.
    pub depth_bias_k: f32,
    /// `(L_m, L_M)`: Gilet's estimated self-shadowing (§5.3), stored per draw as
    /// [`DrawRange::shading`]; `None` stores 1. Default `None`.
    pub shading: Option<(f32, f32)>,
    /// An instance whose bounding radius is below this fraction of its distance takes the far path:
    /// every cell uses the block centre's distance and a linearised `Z_i`, so a cell's thresholds
    /// are off by at most `r/(1 − r)` for `r` this fraction, and no cell is culled on its own. 0 disables the far path.
    /// Default 0.02 (thresholds within 2 %).
    pub far_ratio: f32,
}

impl Default for LodSettings {
    fn default() -> Self {
        Self { s_min: 1.0, s_max: 2.0, depth_bias_k: 0.0, shading: None, far_ratio: 0.02 }
    }
}

impl LodSettings {
    /// The biased pixel thresholds `(s_min_i, s_max_i)` of a cell at depth `z = Z_i` (Gilet §5.2,
    /// eq. 2 and 3): `s_m^i = s_m + k·Z_i`, `s_M^i = s_M + k·Z_i`, then clamped so that
    /// `0 ≤ s_min_i ≤ s_max_i`.
    #[must_use]
    #[inline]
    pub fn biased_pixels(&self, z: f32) -> (f32, f32) {
        let shift = self.depth_bias_k * z;
        let s_min = (self.s_min + shift).max(0.0);
        (s_min, (self.s_max + shift).max(s_min))
    }

    /// Gilet's estimated lighting of a cell at depth `z = Z_i` (§5.3): `L = L_M + (Z_i − 1)/2 ·
    /// (L_M − L_m)`, as the paper writes it (so `L_m` at the nearest cell, `L_M` at the farthest);
    /// 1 without [`Self::shading`].
    #[must_use]
    #[inline]
    pub fn shading_at(&self, z: f32) -> f32 {
        match self.shading {
            Some((l_min, l_max)) => l_max + 0.5 * (z - 1.0) * (l_max - l_min),
            None => 1.0,
        }
    }
}

/// Why [`ModelLod::from_records`] refused its input.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum ModelError {
    /// The block bounds are not finite or not ordered.
    BlockBounds {
        /// Lower corner.
        min: [f32; 3],
        /// Upper corner.
        max: [f32; 3],
    },
    /// A cell's range reaches past the end of its array.
    RangeOutOfBounds {
        /// Index of the cell.
        cell: usize,
        /// `"triangles"` or `"points"`.
        kind: &'static str,
        /// The range.
        range: Range,
        /// Length of the array.
        len: usize,
    },
    /// A cell's array is not sorted by its key, largest first (spec §6.4, §6.5).
    NotSorted {
        /// Index of the cell.
        cell: usize,
        /// `"triangles"` (by `size`) or `"points"` (by `hi`).
        kind: &'static str,
    },
    /// A non-empty cell's bounds are not finite.
    CellBounds {
        /// Index of the cell.
        cell: usize,
    },
    /// More cells than a `u32` counts.
    TooManyCells,
}

impl std::fmt::Display for ModelError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::BlockBounds { min, max } => write!(f, "block bounds {min:?} ..= {max:?} are not finite and ordered"),
            Self::RangeOutOfBounds { cell, kind, range, len } => write!(
                f,
                "cell {cell}: {kind} {}..{} reach past the array of {len}",
                range.first,
                u64::from(range.first) + u64::from(range.count)
            ),
            Self::NotSorted { cell, kind } => write!(f, "cell {cell}: {kind} are not sorted largest first"),
            Self::CellBounds { cell } => write!(f, "cell {cell}: bounds are not finite"),
            Self::TooManyCells => f.write_str("more cells than a u32 counts"),
        }
    }
}

impl std::error::Error for ModelError {}

/// One non-empty cell of a [`ModelLod`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellLod {
    /// Centre of the cell's bounds, model space.
    centre: Vec3,
    /// Half extent of the cell's bounds, model space.
    half: Vec3,
    /// Index of the cell in the container's `CELLS`.
    index: u32,
    /// Whether this is the block cell (selected at the block centre's distance, `Z_i = 0`).
    block_cell: bool,
    /// The cell's triangles in the container's `TRIANGLES`.
    triangles: Range,
    /// The cell's points in the container's `POINTS`.
    points: Range,
    /// Where the cell's triangle sizes start in [`ModelLod::triangle_sizes`].
    sizes_at: u32,
    /// Where the cell's point `hi` values start in [`ModelLod::point_hi`].
    hi_at: u32,
    /// Where the [`search_index`] of the cell's triangle sizes starts in `ModelLod::sampled_sizes`.
    sizes_sampled_at: u32,
    /// Where the [`search_index`] of the cell's point `hi` starts in `ModelLod::sampled_hi`.
    hi_sampled_at: u32,
    /// Size of the cell's largest triangle, `−∞` without triangles: no triangle is drawn at
    /// `τ_t ≥ largest`, and the sizes need not be read.
    largest: f32,
    /// Number of leading points with `hi = +∞` (the roots), drawn at every finite `τ_p ≥ next_hi`.
    roots: u32,
    /// `hi` of the first point after the roots, `−∞` if none.
    next_hi: f32,
    /// `hi` of the first point, `−∞` if none: the point prefix is non-empty exactly when `τ_p < hi0`.
    hi0: f32,
}

impl CellLod {
    /// Index of the cell in the container's `CELLS` (the block cell is the last one).
    #[must_use]
    pub fn index(&self) -> u32 {
        self.index
    }

    /// Whether this is the block cell, selected at the block centre's distance (spec §6.2).
    #[must_use]
    pub fn is_block_cell(&self) -> bool {
        self.block_cell
    }

    /// The cell's bounds, model space, metres.
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (self.centre - self.half, self.centre + self.half)
    }

    /// The cell's range in the container's `TRIANGLES`.
    #[must_use]
    pub fn triangles(&self) -> Range {
        self.triangles
    }

    /// The cell's range in the container's `POINTS`.
    #[must_use]
    pub fn points(&self) -> Range {
        self.points
    }

    /// Centre and half extent of the cell's bounds, model space, exactly as selection uses them
    /// (for mirrors of [`select_frame`], such as a GPU one).
    #[must_use]
    pub fn centre_half(&self) -> (Vec3, Vec3) {
        (self.centre, self.half)
    }

    /// Size of the cell's largest triangle, `−∞` without triangles: the triangle prefix is
    /// non-empty exactly when `τ_t` is below it.
    #[must_use]
    pub fn largest_triangle(&self) -> f32 {
        self.largest
    }

    /// Number of leading points with `hi = +∞` (the cell's roots).
    #[must_use]
    pub fn root_count(&self) -> u32 {
        self.roots
    }

    /// `hi` of the first point after the roots, `−∞` if none: at finite `τ_p ≥` it the point prefix
    /// is the roots.
    #[must_use]
    pub fn next_hi(&self) -> f32 {
        self.next_hi
    }

    /// `hi` of the first point, `−∞` if none: the point prefix is non-empty exactly when `τ_p` is
    /// below it.
    #[must_use]
    pub fn first_hi(&self) -> f32 {
        self.hi0
    }
}

/// What selection needs of one model (container), made once: block bounds and radius, the
/// non-empty cells, and per cell the triangle sizes and point `hi` values in compact arrays.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelLod {
    /// Centre of the block bounds, model space.
    centre: Vec3,
    /// Half extent of the block bounds.
    half: Vec3,
    /// `R`, half the diagonal of the block bounds.
    radius: f32,
    /// Centre, half extent and bounding radius of the box that holds the block bounds and every
    /// non-empty cell's bounds (cells may reach past the block by their elements' radii): culling.
    cull_centre: Vec3,
    cull_half: Vec3,
    cull_radius: f32,
    cells: Vec<CellLod>,
    triangle_sizes: Vec<f32>,
    point_hi: Vec<f32>,
    /// The [`search_index`] of each cell's `triangle_sizes` and `point_hi`, and of `far_hi`.
    sampled_sizes: Vec<f32>,
    sampled_hi: Vec<f32>,
    sampled_far_hi: Vec<f32>,
    /// The cells' `largest`, largest first: how many cells draw triangles at one `τ_t`.
    cells_by_largest: Vec<f32>,
    /// The far list ([`Self::far_list`]): `POINTS` indices of every cell's roots in cell order,
    /// then of every other point with `hi > far_tau`, by `hi` (largest first).
    far: Vec<u32>,
    /// `hi` of each entry of `far` (`+∞` for the roots): its prefixes, as a cell's.
    far_hi: Vec<f32>,
    /// Number of leading entries of `far` that are roots.
    root_count: u32,
    /// Number of cells with roots: the cells a far-list range stands for in the statistics.
    root_cells: u32,
    /// `far` holds every point with `hi > far_tau`.
    far_tau: f32,
    /// The greatest distance of a grid cell's centre from the block centre, model space: the
    /// nearest cell of an instance is no nearer than `d_block` less it (times the scale).
    cell_reach: f32,
}

/// A size or `hi` as a sort key: NaN compares like −∞ (never above a threshold), so it sorts as
/// −∞, last in a largest-first list.
pub(crate) fn sort_key(v: f32) -> f32 {
    if v.is_nan() { f32::NEG_INFINITY } else { v }
}

/// The cut of a far list ([`ModelLod::far_list`], `SptLod::far_list`): sorts `candidates`
/// (`(sort_key(hi), index)`) by `hi`, largest first (ties by index: the same list on every
/// machine), and returns the list's `far_tau`, the `hi` of the first candidate past `room` (0
/// where all fit), with the leading candidates whose `hi` is above it: the list ends where `hi`
/// changes, so it holds every candidate with `hi > far_tau`. Where more than `room` candidates
/// share the first `hi`, the list is empty.
pub(crate) fn far_cut(mut candidates: Vec<(f32, u32)>, room: usize) -> (f32, Vec<(f32, u32)>) {
    candidates.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let far_tau = candidates.get(room).map_or(0.0, |&(hi, _)| hi.max(0.0));
    let kept = candidates.partition_point(|&(hi, _)| hi > far_tau);
    candidates.truncate(kept);
    (far_tau, candidates)
}

/// The most points per cell (with points) the far list holds ([`ModelLod::far_list`]): a bound
/// of its copy's size, 12 KiB of 48-byte points per cell, whatever the model. Where the cells of
/// a tree draw more than that between them, they draw enough per range that one range per cell
/// costs little beside their points. (64 per cell left the shared weeping willow's trees nearer
/// than about 50 radii, a few hundred in a forest of 10⁴, drawing 80–100 ranges each; with 256,
/// and their triangles beside the list, `bench --trees 10000 --frames 48 --no-render --technique
/// policy`, 3 alternating runs, drew 11,909 ranges a frame where it drew 20,923, in 2.39 ms where
/// it took 3.40 (the mean of each frame's least), for 1.6 % more primitives; 1024 per cell, 10,444
/// ranges in 2.22 ms against 2.35 ms in the same runs, for four times the copy.)
pub const FAR_POINTS_PER_CELL: usize = 256;

/// The most points a tree draws from the far list, at its nearest cell's thresholds (or its least
/// biased depth's), as a multiple of the list's points at its block centre's unbiased ones: beyond,
/// it is drawn cell by cell (`ModelLod::far_list_pays`). A tree 10 radii away draws about `(10/9)² ≈ 1.23` times
/// the points there, one 4 radii away `(4/3)² ≈ 1.8` times.
pub const FAR_LIST_EXTRA: f32 = 1.25;

impl ModelLod {
    /// The selection view of an open container.
    #[must_use]
    pub fn from_container(container: &Container) -> Self {
        // Ranges and bounds were checked when the container was opened (spec §9.1).
        Self::build(container.block(), container.cells(), container.triangles(), container.points())
    }

    /// The selection view of raw records (for example synthetic ones in tests). `cells` are the
    /// container's cells in order; the one at index `block.grid_cell_count()`, if present, is the
    /// block cell. Cells with neither triangles nor points are skipped.
    ///
    /// # Errors
    /// [`ModelError`] if the block bounds are not finite and ordered, a cell's range reaches past
    /// its array, a non-empty cell's bounds are not finite, or a cell's triangles (points) are not
    /// sorted by `size` (`hi`), largest first.
    pub fn from_records(
        block: &BlockRecord,
        cells: &[CellRecord],
        triangles: &[TriangleRecord],
        points: &[PointRecord],
    ) -> Result<Self, ModelError> {
        let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        if !min.is_finite() || !max.is_finite() || min.cmpgt(max).any() {
            return Err(ModelError::BlockBounds { min: block.bounds_min, max: block.bounds_max });
        }
        if u32::try_from(cells.len()).is_err() {
            return Err(ModelError::TooManyCells);
        }
        for (index, cell) in cells.iter().enumerate() {
            for (kind, range, len) in
                [("triangles", cell.triangles, triangles.len()), ("points", cell.points, points.len())]
            {
                if range.as_usize().end > len {
                    return Err(ModelError::RangeOutOfBounds { cell: index, kind, range, len });
                }
            }
            let tris = &triangles[cell.triangles.as_usize()];
            let pts = &points[cell.points.as_usize()];
            let finite = Vec3::from_array(cell.bounds_min).is_finite() && Vec3::from_array(cell.bounds_max).is_finite();
            if (!tris.is_empty() || !pts.is_empty()) && !finite {
                return Err(ModelError::CellBounds { cell: index });
            }
            if tris.windows(2).any(|w| w[0].size < w[1].size) {
                return Err(ModelError::NotSorted { cell: index, kind: "triangles" });
            }
            if pts.windows(2).any(|w| w[0].hi < w[1].hi) {
                return Err(ModelError::NotSorted { cell: index, kind: "points" });
            }
        }
        Ok(Self::build(block, cells, triangles, points))
    }

    /// Builds the view; a range outside its array counts as empty (cannot happen once checked).
    fn build(block: &BlockRecord, cells: &[CellRecord], triangles: &[TriangleRecord], points: &[PointRecord]) -> Self {
        let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        let block_cell = block.grid_cell_count();
        let mut model = Self {
            centre: 0.5 * (min + max),
            half: 0.5 * (max - min),
            radius: 0.5 * (max - min).length(),
            ..Self::default()
        };
        for (index, cell) in cells.iter().enumerate() {
            let tris = triangles.get(cell.triangles.as_usize()).unwrap_or_default();
            let pts = points.get(cell.points.as_usize()).unwrap_or_default();
            let (Ok(index_u32), Ok(sizes_at), Ok(hi_at), Ok(sizes_sampled_at), Ok(hi_sampled_at)) = (
                u32::try_from(index),
                u32::try_from(model.triangle_sizes.len()),
                u32::try_from(model.point_hi.len()),
                u32::try_from(model.sampled_sizes.len()),
                u32::try_from(model.sampled_hi.len()),
            ) else {
                break;
            };
            if tris.is_empty() && pts.is_empty() {
                continue;
            }
            let (lo, hi) = (Vec3::from_array(cell.bounds_min), Vec3::from_array(cell.bounds_max));
            let roots = pts.iter().take_while(|p| p.hi == f32::INFINITY).count();
            model.cells.push(CellLod {
                centre: 0.5 * (lo + hi),
                half: (0.5 * (hi - lo)).abs(),
                index: index_u32,
                block_cell: index == block_cell,
                triangles: if tris.is_empty() { Range::default() } else { cell.triangles },
                points: if pts.is_empty() { Range::default() } else { cell.points },
                sizes_at,
                hi_at,
                sizes_sampled_at,
                hi_sampled_at,
                largest: tris.first().map_or(f32::NEG_INFINITY, |t| t.size),
                roots: u32::try_from(roots).unwrap_or(u32::MAX),
                next_hi: pts.get(roots).map_or(f32::NEG_INFINITY, |p| p.hi),
                hi0: pts.first().map_or(f32::NEG_INFINITY, |p| p.hi),
            });
            model.far.extend((0..u32::try_from(roots).unwrap_or(0)).map(|i| cell.points.first + i));
            if index != block_cell {
                model.cell_reach = model.cell_reach.max((0.5 * (lo + hi)).distance(model.centre));
            }
            model.triangle_sizes.extend(tris.iter().map(|t| t.size));
            model.point_hi.extend(pts.iter().map(|p| p.hi));
            model.sampled_sizes.extend(search_index(&model.triangle_sizes[sizes_at as usize..]));
            model.sampled_hi.extend(search_index(&model.point_hi[hi_at as usize..]));
        }
        let (lo, hi) =
            model.cells.iter().fold((min, max), |(lo, hi), c| (lo.min(c.centre - c.half), hi.max(c.centre + c.half)));
        model.cull_centre = 0.5 * (lo + hi);
        model.cull_half = 0.5 * (hi - lo);
        model.cull_radius = model.cull_half.length();
        model.cells_by_largest = model.cells.iter().map(|c| sort_key(c.largest)).collect();
        model.cells_by_largest.sort_by(|a, b| b.total_cmp(a));
        model.root_cells = u32::try_from(model.cells.iter().filter(|c| c.roots > 0).count()).unwrap_or(u32::MAX);
        model.add_far_points(points);
        model.sampled_far_hi = search_index(&model.far_hi).collect();
        model
    }

    /// Appends to the roots in `far` the other points of the far list: the points after the
    /// roots of every cell, by `hi` (largest first, then by index: the same list on every
    /// machine), up to [`FAR_POINTS_PER_CELL`] per cell with points in all, ending where `hi`
    /// changes so that the list holds every point with `hi > far_tau`.
    fn add_far_points(&mut self, points: &[PointRecord]) {
        self.root_count = u32::try_from(self.far.len()).unwrap_or(u32::MAX);
        self.far_hi = vec![f32::INFINITY; self.far.len()];
        let with_points = self.cells.iter().filter(|c| c.points.count > 0).count();
        let room = (FAR_POINTS_PER_CELL * with_points).saturating_sub(self.far.len());
        // NaN is never above a threshold: it sorts last and never enters the list.
        let mut rest: Vec<(f32, u32)> = Vec::new();
        for cell in &self.cells {
            let first = cell.points.first + cell.roots;
            let end = cell.points.first + cell.points.count;
            rest.extend((first..end).filter_map(|i| points.get(i as usize).map(|p| (sort_key(p.hi), i))));
        }
        // `far_tau` is at most the largest `hi` after any cell's roots: the far list is drawn
        // wherever every cell would draw its roots alone.
        let (far_tau, kept) = far_cut(rest, room);
        self.far_tau = far_tau;
        for (hi, index) in kept {
            self.far.push(index);
            self.far_hi.push(hi);
        }
    }

    /// `POINTS` indices of every cell's roots (its leading points with `hi = +∞`), in cell order:
    /// the head of [`Self::far_list`].
    #[must_use]
    pub fn roots(&self) -> &[u32] {
        self.far.get(..self.root_count as usize).unwrap_or_default()
    }

    /// The far list: `POINTS` indices of every cell's roots, in cell order, then of every other
    /// point with `hi >` [`Self::far_tau`], by `hi` (largest first, ties by index), at most
    /// [`FAR_POINTS_PER_CELL`] per cell with points in all.
    ///
    /// Gilet's hierarchies are per cell, so a tree drawn cell by cell is at least one range per
    /// cell, however few points each draws: the shared weeping willow's 83 non-empty cells drew
    /// 1,252 points between them 32 pixels high, 15 per cell. Where one `τ_p ≥ far_tau` serves every
    /// cell, the points every cell draws are the far list's prefix with `hi > τ_p` (its
    /// [`Self::far_hi`] sorted as a cell's), and [`select_frame`] emits that one [`Kind::Roots`]
    /// range instead of the cells' point ranges (a far tree, and one whose nearest cell bounds
    /// them all, see there), beside the triangle prefix of each cell that draws triangles at the
    /// same `τ_t`: a renderer keeps these points contiguous (a copy, pinned) and draws the tree's
    /// points with one draw. The cut is the cells' own at those thresholds (spec §10); the shader
    /// drops the prefix's points with `lo > τ_p`, or larger than `τ_t`, as in a cell's.
    #[must_use]
    pub fn far_list(&self) -> &[u32] {
        &self.far
    }

    /// `hi` of each entry of [`Self::far_list`], largest first (`+∞` for the roots).
    #[must_use]
    pub fn far_hi(&self) -> &[f32] {
        &self.far_hi
    }

    /// The far list holds every point with `hi` above this (0 where it holds every point).
    #[must_use]
    pub fn far_tau(&self) -> f32 {
        self.far_tau
    }

    /// The greatest distance of a grid cell's centre from the block centre, model space: an
    /// instance's nearest cell is no nearer the eye than `d_block` less it times the instance's
    /// scale.
    #[must_use]
    pub fn cell_reach(&self) -> f32 {
        self.cell_reach
    }

    /// The number of cells with roots: the cells a far-list range stands for.
    #[must_use]
    pub fn root_cells(&self) -> u32 {
        self.root_cells
    }

    /// The largest triangle of any cell (`−∞` without triangles; NaN counts as `−∞`): no cell
    /// draws a triangle at `τ_t` at or above it.
    #[must_use]
    pub fn largest_triangle(&self) -> f32 {
        self.cells_by_largest.first().copied().unwrap_or(f32::NEG_INFINITY)
    }

    /// Whether an instance whose smallest `τ_p` over its cells is `tau_points` draws, of every
    /// cell, points of the far list only: then the far list's prefix with `hi > τ_p` is what
    /// every cell draws at that `τ_p` (and the triangles' `τ_t`, which the shader tests the points
    /// against as a cell's). Not at `τ_p = 0`, the full mesh's thresholds, where no point is drawn
    /// and a renderer drops the cells' point ranges.
    fn far_points(&self, tau_points: f32) -> bool {
        !self.far.is_empty() && tau_points >= self.far_tau && tau_points > 0.0 && tau_points < f32::INFINITY
    }

    /// Whether a tree whose far list is drawn at `tau_near` (the `τ_p` of its nearest cell, or of
    /// its least biased depth, [`Self::far_points`]) draws at most [`FAR_LIST_EXTRA`] times the list's points at
    /// `tau_centre` (its block centre's `τ_p`, about what its cells would draw at their own): the
    /// far list trades a tree's ranges for points finer than its farther cells need, which pays
    /// while the tree is far against its size and not when it is near.
    fn far_list_pays(&self, tau_near: f32, tau_centre: f32) -> bool {
        let near = self.far_above(tau_near) as f32;
        near <= FAR_LIST_EXTRA * self.far_above(tau_centre) as f32
    }

    /// The block bounds, model space, metres.
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (self.centre - self.half, self.centre + self.half)
    }

    /// Centre of the block bounds, model space, exactly as selection uses it (`d_block` is measured
    /// to it).
    #[must_use]
    pub fn centre(&self) -> Vec3 {
        self.centre
    }

    /// Centre and half extent, model space, of the box culling tests (the block and every
    /// non-empty cell's bounds); [`Self::cull_sphere`] is its bounding sphere.
    #[must_use]
    pub fn cull_box(&self) -> (Vec3, Vec3) {
        (self.cull_centre, self.cull_half)
    }

    /// The bounds under which an instance draws the far list (a [`Kind::Roots`] range), for
    /// mirrors of [`select_frame`]: at its smallest thresholds `(τ_p, τ_t)` it does exactly when
    /// the list is not empty, `τ_p` is finite and `τ_p ≥ far_tau`; then where `τ_t <
    /// largest_triangle` each cell with a triangle larger than `τ_t` also draws its triangle
    /// prefix at those thresholds. Returns `(far_tau, largest_triangle)` ([`Self::far_tau`],
    /// [`Self::largest_triangle`]).
    #[must_use]
    pub fn far_bounds(&self) -> (f32, f32) {
        (self.far_tau, self.largest_triangle())
    }

    /// `R`: half the diagonal of the block bounds, metres, model space (Gilet §5.2's block size).
    #[must_use]
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// A sphere, model space, holding the block and every non-empty cell's bounds (cells reach
    /// past the block by their elements' radii): `(centre, radius)`, what culling tests.
    #[must_use]
    pub fn cull_sphere(&self) -> (Vec3, f32) {
        (self.cull_centre, self.cull_radius)
    }

    /// The non-empty cells, in container order.
    #[must_use]
    pub fn cells(&self) -> &[CellLod] {
        &self.cells
    }

    /// The triangle sizes of `cell`, largest first.
    #[must_use]
    pub fn triangle_sizes(&self, cell: &CellLod) -> &[f32] {
        let at = cell.sizes_at as usize;
        self.triangle_sizes.get(at..at + cell.triangles.count as usize).unwrap_or_default()
    }

    /// The point `hi` values of `cell`, largest first.
    #[must_use]
    pub fn point_hi(&self, cell: &CellLod) -> &[f32] {
        let at = cell.hi_at as usize;
        self.point_hi.get(at..at + cell.points.count as usize).unwrap_or_default()
    }

    /// The triangles `cell` draws at `τ_t`: its leading [`Self::triangle_sizes`] above `tau`
    /// ([`leading_above`]'s count, found through the sizes' [`search_index`]).
    #[must_use]
    pub fn triangles_above(&self, cell: &CellLod, tau: f32) -> u32 {
        let at = cell.sizes_sampled_at as usize;
        let sampled = self.sampled_sizes.get(at..at + search_index_len(cell.triangles.count as usize));
        leading_above_sampled(self.triangle_sizes(cell), sampled.unwrap_or_default(), tau)
    }

    /// The points `cell` draws at `τ_p`: its leading [`Self::point_hi`] above `tau`
    /// ([`leading_above`]'s count, found through the values' [`search_index`]).
    #[must_use]
    pub fn points_above(&self, cell: &CellLod, tau: f32) -> u32 {
        let at = cell.hi_sampled_at as usize;
        let sampled = self.sampled_hi.get(at..at + search_index_len(cell.points.count as usize));
        leading_above_sampled(self.point_hi(cell), sampled.unwrap_or_default(), tau)
    }

    /// The entries of [`Self::far_list`] drawn at `τ_p`: its leading [`Self::far_hi`] above
    /// `tau` ([`leading_above`]'s count, found through the values' [`search_index`]).
    #[must_use]
    pub fn far_above(&self, tau: f32) -> u32 {
        leading_above_sampled(&self.far_hi, &self.sampled_far_hi, tau)
    }
}

/// One placed copy of a model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index into the `models` of [`select_frame`].
    pub model: u32,
    /// World from model: an affine transform (rotation, translation, scale). Sizes are converted
    /// with the largest axis scale, so a uniform scale gives exact thresholds and a non-uniform
    /// one errs towards finer detail; culling is conservative for any affine transform.
    pub transform: Mat4,
}

/// Which array a [`DrawRange`] indexes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u32)]
pub enum Kind {
    /// `TRIANGLES`: draw every triangle of the range.
    Triangles = 0,
    /// `POINTS`: draw the points of the range that pass [`crate::point_drawn`].
    Points = 1,
    /// The points of every cell of the model at once, a prefix of its far list: `first..first +
    /// count` indexes [`ModelLod::far_list`], a list of `POINTS` indices, roots first (see there
    /// for when); draw those that pass [`crate::point_drawn`].
    Roots = 2,
}

/// [`DrawRange::cell`] of a [`Kind::Roots`] range, which spans every cell.
pub const ROOTS_CELL: u32 = u32::MAX;

/// One range to draw: a prefix of one cell's triangles or points for one instance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DrawRange {
    /// Index of the instance in the `instances` of [`select_frame`].
    pub instance: u32,
    /// The instance's model.
    pub model: u32,
    /// Index of the cell in the model's `CELLS`; [`ROOTS_CELL`] for a [`Kind::Roots`] range.
    pub cell: u32,
    /// Which array `first` indexes.
    pub kind: Kind,
    /// First record, absolute index in the container's `TRIANGLES` or `POINTS`, or in
    /// [`ModelLod::far_list`] for [`Kind::Roots`] (0).
    pub first: u32,
    /// Number of records, `≥ 1`.
    pub count: u32,
    /// `τ_p`, metres, model space: the shader draws a point where `lo ≤ τ_p < hi`.
    pub tau_points: f32,
    /// `τ_t`, metres, model space: triangles larger are drawn, and points larger are not.
    pub tau_triangles: f32,
    /// Estimated lighting factor of the cell ([`LodSettings::shading_at`]), 1 without shading.
    pub shading: f32,
}

/// The ranges of one frame, in instance order, then cell order, triangles before points. Reuse
/// one list across frames: [`select_frame`] overwrites it and keeps its allocations.
#[derive(Clone, Debug, Default)]
pub struct DrawList {
    /// The ranges.
    storage: Vec<DrawRange>,
    triangle_ranges: u32,
    point_ranges: u32,
    /// Per chunk of the parallel path, its ranges and tally, kept between frames.
    chunks: Vec<(Vec<DrawRange>, Tally)>,
}

impl DrawList {
    /// An empty list.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// An empty list with room for `ranges` ranges.
    #[must_use]
    pub fn with_capacity(ranges: usize) -> Self {
        Self { storage: Vec::with_capacity(ranges), ..Self::default() }
    }

    /// Empties the list, keeping its allocations.
    pub fn clear(&mut self) {
        self.storage.clear();
        self.triangle_ranges = 0;
        self.point_ranges = 0;
    }

    /// The ranges.
    #[must_use]
    pub fn ranges(&self) -> &[DrawRange] {
        &self.storage
    }

    /// Number of ranges.
    #[must_use]
    pub fn len(&self) -> usize {
        self.storage.len()
    }

    /// Whether the list holds no range.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.storage.is_empty()
    }

    /// Ranges the list holds without reallocating.
    #[must_use]
    pub fn capacity(&self) -> usize {
        self.storage.capacity()
    }

    /// Number of [`Kind::Triangles`] ranges.
    #[must_use]
    pub fn triangle_ranges(&self) -> u32 {
        self.triangle_ranges
    }

    /// Number of [`Kind::Points`] ranges.
    #[must_use]
    pub fn point_ranges(&self) -> u32 {
        self.point_ranges
    }
}

/// Counts of one [`select_frame`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// Instances inside the view frustum.
    pub instances_visible: u32,
    /// Visible instances that took the far path ([`LodSettings::far_ratio`]).
    pub instances_far: u32,
    /// Instances skipped because their model index is out of range or their transform degenerate.
    pub instances_invalid: u32,
    /// Non-empty cells of visible instances that were selected.
    pub cells_visible: u32,
    /// Non-empty cells of visible instances culled on their own bounds.
    pub cells_culled: u32,
    /// Ranges in the draw list.
    pub ranges: u32,
    /// Triangles submitted (all are drawn).
    pub triangles: u64,
    /// Points submitted: the prefixes, of which the shader draws those in the cut.
    pub points: u64,
}

impl FrameStats {
    /// Triangles and points submitted, the count [`BudgetController::update`] steers.
    #[must_use]
    pub fn primitives(&self) -> u64 {
        self.triangles + self.points
    }
}

/// Per-frame constants of the selection.
struct Frame<'a> {
    frustum: Frustum,
    eye: Vec3,
    world_per_pixel: f32,
    settings: &'a LodSettings,
    /// Whether `Z_i` matters (depth bias or shading on).
    needs_z: bool,
}

/// Selects what to draw of every instance for `camera` (spec §10) into `out`, which is cleared
/// first; returns the frame's counts.
///
/// Per instance, in order:
///
/// 1. **Cull** the bounding sphere of the block and its cells' bounds, then, if it straddles the
///    frustum, their transformed box.
/// 2. **Depth** of each non-empty cell (Gilet §5.2): `d_cell` from the eye to the cell's centre and
///    `d_block` to the block's centre, world space, and `Z_i = clamp((d_cell − d_block) / R, −1, 1)`
///    with `R` the block radius in world units. The block cell uses `d_block` and `Z_i = 0`.
/// 3. **Thresholds**: Gilet's eq. (2) and (3), `s_m^i = s_m + k·Z_i` and `s_M^i = s_M + k·Z_i`
///    ([`LodSettings::biased_pixels`]), turned into metres at `d_cell` (spec §10.1) and into model
///    space by dividing by the instance's largest axis scale: `τ = s^i · d_cell · 2·tan(fovy/2) /
///    (H · scale)`.
/// 4. **Prefixes**: triangles with `size > τ_t`, points with `hi > τ_p` (spec §10), found by a
///    galloping binary search of the cell's sorted keys.
///
/// **Far path.** When `R·scale < far_ratio · d_block` the block is small on screen: every grid cell
/// uses `d_block` (each `d_cell` is within `R·scale` of it, so thresholds are off by at most
/// `r/(1 − r)`, `r = far_ratio`), and `Z_i` is linearised as `(c_i − c_block)·v̂ / R` with `v̂` the
/// unit view direction to the block, one dot product per cell; with `k = 0` and no shading the
/// thresholds are the same for every cell. The far path's list equals the near path's except for
/// elements whose key lies within that threshold error. **Cell culling** happens only on the near
/// path, and only for instances straddling the frustum.
///
/// **Far list.** Where one instance's cells would draw points only from the top of their
/// hierarchies, its points are drawn with one [`Kind::Roots`] range, a prefix of the model's far
/// list ([`ModelLod::far_list`]), and its triangles with each cell's prefix (cells without
/// triangles that large have none), at one pair of thresholds for every cell: on the far path
/// those of the nearest depth (`Z_i = ±1` with a bias, else the block's); on the near path, for an
/// instance wholly in view and drawn without shading, those at `d_block − cell_reach·scale`, no
/// nearer than its nearest cell ([`ModelLod::cell_reach`]), so no cell is drawn coarser than its
/// own thresholds would draw it. On either path only where the list's points at those thresholds
/// are at most [`FAR_LIST_EXTRA`] times its points at the block centre's unbiased ones: a tree
/// near against its size, or a strong depth bias, is drawn cell by cell. The cut is the cells'
/// own at those thresholds. Measured with `bench --trees 10000 --no-render --technique policy`
/// on the shared weeping willow, 48 frames at 1536×864, 3 alternating runs: up to 704,118 ranges
/// a frame (7 points each on the descent) fell to at most 45,275, the mean of each frame's least
/// selection time from 22.1 to 4.2 ms, for 0.29 % more primitives (the cells farther than the
/// nearest drawn at its thresholds). Trees that draw triangles took the list too once it held
/// more points ([`FAR_POINTS_PER_CELL`] gives the numbers): before, a tree drawing one triangle
/// took a range per cell.
///
/// Instances whose `model` is not an index of `models`, or whose transform has a zero or
/// non-finite scale, are skipped and counted in [`FrameStats::instances_invalid`].
///
/// **Threads.** From [`PARALLEL_MIN_INSTANCES`] instances on, chunks of [`CHUNK_INSTANCES`]
/// instances run on rayon's pool, each into a list of its own kept between frames, and the lists
/// are joined in chunk order. The output is the same as on one thread.
pub fn select_frame(
    models: &[ModelLod],
    instances: &[Instance],
    camera: &Camera,
    settings: &LodSettings,
    out: &mut DrawList,
) -> FrameStats {
    let frame = Frame {
        frustum: Frustum::from_view_proj(camera.view_proj),
        eye: camera.position,
        world_per_pixel: camera.world_per_pixel(),
        settings,
        needs_z: settings.depth_bias_k != 0.0 || settings.shading.is_some(),
    };
    if instances.len() >= PARALLEL_MIN_INSTANCES && rayon::current_num_threads() > 1 {
        select_parallel(&frame, models, instances, out)
    } else {
        select_sequential(&frame, models, instances, out)
    }
}

/// Instances per chunk of the parallel path: enough to amortise a task, few enough that the
/// chunks of a frame balance across threads when visibility is uneven.
pub const CHUNK_INSTANCES: usize = 256;

/// Smallest instance count [`select_frame`] spreads over threads.
pub const PARALLEL_MIN_INSTANCES: usize = 4 * CHUNK_INSTANCES;

/// Counts gathered while selecting.
#[derive(Clone, Copy, Debug, Default)]
struct Tally {
    stats: FrameStats,
    triangle_ranges: u32,
}

impl Tally {
    fn add(&mut self, other: &Self) {
        let (a, b) = (&mut self.stats, &other.stats);
        a.instances_visible += b.instances_visible;
        a.instances_far += b.instances_far;
        a.instances_invalid += b.instances_invalid;
        a.cells_visible += b.cells_visible;
        a.cells_culled += b.cells_culled;
        a.triangles += b.triangles;
        a.points += b.points;
        self.triangle_ranges += other.triangle_ranges;
    }

    fn finish(mut self, out: &mut DrawList) -> FrameStats {
        self.stats.ranges = u32::try_from(out.len()).unwrap_or(u32::MAX);
        out.triangle_ranges = self.triangle_ranges;
        out.point_ranges = self.stats.ranges.saturating_sub(self.triangle_ranges);
        self.stats
    }
}

/// Whether an instance is drawn, and how it lies in the frustum.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Visibility {
    /// Outside the frustum.
    #[default]
    Hidden,
    /// Unknown model, degenerate transform, or an index past `u32`.
    Invalid,
    /// Wholly inside the frustum: no cell is culled.
    Inside,
    /// Crossing a plane: cells may be culled.
    Straddles,
}

/// One prefix of a cell's elements of an SPT kind drawn as a whole range (impostor planes,
/// ellipsoids; spec §10): the shader draws those of them whose interval holds `tau`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellPrefix {
    /// Index of the cell in the container's `CELLS`.
    pub cell: u32,
    /// First element, absolute index in the kind's array.
    pub first: u32,
    /// Leading elements of the cell with `hi > τ`, `≥ 1`.
    pub count: u32,
    /// `τ`, model space, in the unit of the kind's intervals (metres for planes, metres per pixel
    /// for ellipsoids).
    pub tau: f32,
}

/// How many of `count` thresholds `hi[first..]` (sorted largest first, spec §10) exceed `tau`:
/// the leading elements a cell draws at `tau`, by galloping from the front ([`leading_above`]),
/// since a far tree's prefix of each cell is short.
pub(crate) fn prefix_above(hi: &[f32], first: u32, count: u32, tau: f32) -> u32 {
    leading_above(hi.get(first as usize..first as usize + count as usize).unwrap_or_default(), tau)
}

/// `τ` per metre of distance for an instance drawn whole by one threshold (impostor planes,
/// baselines): `s_min · 2·tan(fovy/2) / H` (spec §10.1) divided by the transform's largest axis
/// scale, so `τ` is in model units. `None` if the instance's sphere `(centre, radius)` (model
/// space) lies outside `frustum` or the transform is degenerate.
pub(crate) fn tau_per_metre(
    transform: Mat4,
    camera: &Camera,
    frustum: &Frustum,
    s_min: f32,
    (centre, radius): (Vec3, f32),
) -> Option<f32> {
    let scale = usable_scale(transform)?;
    if !frustum.intersects_sphere(transform.transform_point3(centre), radius * scale) {
        return None;
    }
    Some(s_min.max(0.0) * camera.world_per_pixel() / scale)
}

/// The largest axis scale of `transform` (the length of its longest axis), `None` where it is
/// not positive and finite (a transform nothing is drawn with): [`tau_per_metre`]'s.
pub(crate) fn usable_scale(transform: Mat4) -> Option<f32> {
    let (ax, ay, az) = (transform.x_axis.truncate(), transform.y_axis.truncate(), transform.z_axis.truncate());
    let scale = ax.length_squared().max(ay.length_squared()).max(az.length_squared()).sqrt();
    (scale > 0.0 && scale.is_finite()).then_some(scale)
}

/// Culls one instance (step 1 of [`select_frame`]).
fn cull_instance(frame: &Frame<'_>, models: &[ModelLod], instance: &Instance) -> Visibility {
    let Some(model) = models.get(instance.model as usize) else {
        return Visibility::Invalid;
    };
    let m = instance.transform;
    let (ax, ay, az) = (m.x_axis.truncate(), m.y_axis.truncate(), m.z_axis.truncate());
    let scale = ax.length_squared().max(ay.length_squared()).max(az.length_squared()).sqrt();
    if !(scale > 0.0 && scale.is_finite()) {
        return Visibility::Invalid;
    }
    let centre = m.transform_point3(model.cull_centre);
    let h = model.cull_half;
    match frame.frustum.classify_sphere(centre, model.cull_radius * scale) {
        Containment::Inside => Visibility::Inside,
        Containment::Straddles if frame.frustum.intersects_box(centre, [ax * h.x, ay * h.y, az * h.z]) => {
            Visibility::Straddles
        }
        Containment::Straddles | Containment::Outside => Visibility::Hidden,
    }
}

/// Selects `instances`, numbering them from `first`.
fn select_chunk(
    frame: &Frame<'_>,
    models: &[ModelLod],
    first: usize,
    instances: &[Instance],
    sink: &mut Vec<DrawRange>,
    tally: &mut Tally,
) {
    for (offset, instance) in instances.iter().enumerate() {
        let index = u32::try_from(first + offset);
        let visibility = if index.is_ok() { cull_instance(frame, models, instance) } else { Visibility::Invalid };
        match (visibility, index, models.get(instance.model as usize)) {
            (Visibility::Hidden, ..) => {}
            (Visibility::Inside | Visibility::Straddles, Ok(index), Some(model)) => {
                let straddles = visibility == Visibility::Straddles;
                select_instance(frame, model, index, instance, straddles, sink, tally);
            }
            _ => tally.stats.instances_invalid += 1,
        }
    }
}

fn select_sequential(frame: &Frame<'_>, models: &[ModelLod], instances: &[Instance], out: &mut DrawList) -> FrameStats {
    out.clear();
    let mut tally = Tally::default();
    select_chunk(frame, models, 0, instances, &mut out.storage, &mut tally);
    tally.finish(out)
}

/// Chunks of instances on rayon's pool, each selected into its own list (kept between frames, so
/// a frame allocates only where a chunk draws more than ever before), then the lists joined in
/// chunk order: the sequential order. (The two passes this replaces, counting each chunk's
/// ranges and then writing them into its slice of one list, made the select phase of the
/// willow's policy frames, 10^4 trees on 2 cores, slower than one thread's: 1.67–1.80 against
/// 1.35–1.49 ms, 3 alternating runs. With this path a frame takes what it takes with one thread
/// selecting, 2.67 against 2.70 ms, 5 runs: waking the pool's other thread costs about what it
/// saves at a few thousand instances.)
fn select_parallel(frame: &Frame<'_>, models: &[ModelLod], instances: &[Instance], out: &mut DrawList) -> FrameStats {
    use rayon::prelude::*;
    out.clear();
    let chunk_count = instances.len().div_ceil(CHUNK_INSTANCES);
    out.chunks.resize_with(chunk_count, Default::default);
    instances.par_chunks(CHUNK_INSTANCES).zip(out.chunks.par_iter_mut()).enumerate().for_each(
        |(c, (part, (ranges, tally)))| {
            ranges.clear();
            *tally = Tally::default();
            select_chunk(frame, models, c * CHUNK_INSTANCES, part, ranges, tally);
        },
    );
    let mut tally = Tally::default();
    for (ranges, chunk) in &out.chunks[..chunk_count] {
        out.storage.extend_from_slice(ranges);
        tally.add(chunk);
    }
    tally.finish(out)
}

/// Whether a cell may be in view by `planes` ([`Frustum::model_planes`] of its instance): its
/// oriented box is not wholly outside a plane. The block cell (the roots and whatever no grid
/// cell holds) is always in view of a visible instance: [`select_instance`] never culls it.
pub(crate) fn cell_in_view(planes: &[(Vec4, Vec3); 6], cell: &CellLod) -> bool {
    cell.block_cell || planes.iter().all(|(p, reach)| p.truncate().dot(cell.centre) + p.w >= -reach.dot(cell.half))
}

/// Selects the cells of a visible instance (steps 2–4 of [`select_frame`]); `straddles` if it
/// crosses a frustum plane, so its cells may be culled.
fn select_instance(
    frame: &Frame<'_>,
    model: &ModelLod,
    index: u32,
    instance: &Instance,
    straddles: bool,
    sink: &mut Vec<DrawRange>,
    tally: &mut Tally,
) {
    let m = instance.transform;
    let (ax, ay, az, t) = (m.x_axis.truncate(), m.y_axis.truncate(), m.z_axis.truncate(), m.w_axis.truncate());
    let scale = ax.length_squared().max(ay.length_squared()).max(az.length_squared()).sqrt();
    let to_world = |p: Vec3| t + ax * p.x + ay * p.y + az * p.z;
    let centre = to_world(model.centre);
    let radius = model.radius * scale;
    tally.stats.instances_visible += 1;
    let to_block = centre - frame.eye;
    let d_block = to_block.length();
    let inv_radius = if radius > 0.0 { radius.recip() } else { 0.0 };
    let mut cells = CellEmitter {
        settings: *frame.settings,
        model,
        instance: index,
        model_index: instance.model,
        // τ (model space) = s_px · d · per_metre.
        per_metre: frame.world_per_pixel / scale,
        sink,
        cells: 0,
        triangle_ranges: 0,
        triangles: 0,
        points: 0,
    };

    if radius < frame.settings.far_ratio * d_block {
        // Far path: d_cell − d_block ≈ v̂·M·(c_i − c_block), so Z_i ≈ (c_i − c_block)·(Mᵀv̂)/R.
        tally.stats.instances_far += 1;
        let (lowest_p, lowest_t) = cells.least_thresholds(frame.needs_z, d_block);
        if model.far_points(lowest_p) && model.far_list_pays(lowest_p, cells.thresholds(0.0, d_block).0) {
            cells.emit_far(lowest_p, lowest_t);
        } else if frame.needs_z && d_block > 0.0 {
            let to_z = Vec3::new(ax.dot(to_block), ay.dot(to_block), az.dot(to_block)) * (inv_radius / d_block);
            for cell in &model.cells {
                let z = if cell.block_cell { 0.0 } else { (cell.centre - model.centre).dot(to_z).clamp(-1.0, 1.0) };
                cells.emit(cell, z, d_block);
            }
        } else {
            for cell in &model.cells {
                cells.emit(cell, 0.0, d_block);
            }
        }
    } else if let Some((tau_points, tau_triangles)) = (!straddles && frame.settings.shading.is_none())
        .then(|| cells.least_thresholds(frame.needs_z, d_block - model.cell_reach * scale))
        .filter(|&(p, _)| model.far_points(p) && model.far_list_pays(p, cells.thresholds(0.0, d_block).0))
    {
        // Every cell in view and none nearer than `d_block − cell_reach·scale`: the far list at
        // that distance's thresholds, no coarser than any cell's own, where it draws few points
        // more than the cells would, and without Gilet's shading, which darkens each cell by its
        // own depth (the far list's range is shaded as the block centre).
        cells.emit_far(tau_points, tau_triangles);
    } else {
        // Near path: exact per-cell distances; cells culled on their own if the block straddles.
        let cull = straddles;
        let planes = frame.frustum.model_planes(m);
        for cell in &model.cells {
            if cell.block_cell {
                cells.emit(cell, 0.0, d_block);
                continue;
            }
            if cull && !cell_in_view(&planes, cell) {
                tally.stats.cells_culled += 1;
                continue;
            }
            let d_cell = to_world(cell.centre).distance(frame.eye);
            let z = if frame.needs_z { ((d_cell - d_block) * inv_radius).clamp(-1.0, 1.0) } else { 0.0 };
            cells.emit(cell, z, d_cell);
        }
    }
    tally.stats.cells_visible += cells.cells;
    tally.stats.triangles += cells.triangles;
    tally.stats.points += cells.points;
    tally.triangle_ranges += cells.triangle_ranges;
}

/// Selects the cells of one visible instance into a list of ranges.
struct CellEmitter<'a> {
    /// A copy, so the hot loop reads it from registers or the stack, not through a pointer.
    settings: LodSettings,
    model: &'a ModelLod,
    instance: u32,
    model_index: u32,
    /// World per pixel per metre of distance, divided by the instance's scale.
    per_metre: f32,
    sink: &'a mut Vec<DrawRange>,
    cells: u32,
    triangle_ranges: u32,
    triangles: u64,
    points: u64,
}

impl CellEmitter<'_> {
    /// `(τ_p, τ_t)`, model space, of a cell at depth `z` and distance `distance` (world metres).
    #[inline(always)]
    fn thresholds(&self, z: f32, distance: f32) -> (f32, f32) {
        let (s_min, s_max) = self.settings.biased_pixels(z);
        let unit = distance.max(0.0) * self.per_metre;
        (s_min * unit, s_max * unit)
    }

    /// The least `(τ_p, τ_t)` of a cell at `distance` over the depths it may have: `Z_i = 0`
    /// without `needs_z`, else either end of `[−1, 1]` (the bias is monotone in `Z_i`).
    #[inline]
    fn least_thresholds(&self, needs_z: bool, distance: f32) -> (f32, f32) {
        if !needs_z {
            return self.thresholds(0.0, distance);
        }
        let (a, b) = (self.thresholds(-1.0, distance), self.thresholds(1.0, distance));
        (a.0.min(b.0), a.1.min(b.1))
    }

    /// Passes on one [`Kind::Roots`] range, the far list's prefix with `hi > τ_p`, at thresholds
    /// under which [`ModelLod::far_points`] holds, then the triangle prefix `size > τ_t` of each
    /// cell that has one, at the same thresholds: every cell's cut at `(τ_p, τ_t)`.
    fn emit_far(&mut self, tau_points: f32, tau_triangles: f32) {
        if tau_triangles < self.model.largest_triangle() {
            for cell in &self.model.cells {
                self.emit_triangles(cell, tau_points, tau_triangles);
            }
        }
        let count = self.model.far_above(tau_points);
        self.cells += self.model.root_cells;
        self.points += u64::from(count);
        let shading = self.settings.shading_at(0.0);
        self.sink.push(self.range((ROOTS_CELL, Kind::Roots, 0, count), (tau_points, tau_triangles), shading));
    }

    /// A range of this instance: `(cell, kind, first, count)` at `(τ_p, τ_t)`, shaded `shading`.
    #[inline(always)]
    fn range(&self, (cell, kind, first, count): (u32, Kind, u32, u32), taus: (f32, f32), shading: f32) -> DrawRange {
        let (instance, model) = (self.instance, self.model_index);
        DrawRange { instance, model, cell, kind, first, count, tau_points: taus.0, tau_triangles: taus.1, shading }
    }

    /// Passes on the triangle prefix `size > τ_t` of `cell`, if not empty, at `(τ_p, τ_t)`: a
    /// cell of a tree whose points the far list draws ([`Self::emit_far`]).
    fn emit_triangles(&mut self, cell: &CellLod, tau_points: f32, tau_triangles: f32) {
        if cell.largest <= tau_triangles {
            return;
        }
        let triangles = self.model.triangles_above(cell, tau_triangles);
        self.triangles += u64::from(triangles);
        let shading = self.settings.shading_at(0.0);
        let range = self.range(
            (cell.index, Kind::Triangles, cell.triangles.first, triangles),
            (tau_points, tau_triangles),
            shading,
        );
        self.sink.push(range);
        self.triangle_ranges += 1;
    }

    /// Selects `cell` at depth `z` and distance `distance` (world metres) and passes on its ranges.
    #[inline(always)]
    fn emit(&mut self, cell: &CellLod, z: f32, distance: f32) {
        let (tau_points, tau_triangles) = self.thresholds(z, distance);
        // Whether each prefix is empty, from the cell's first keys (`leading_above` > 0 exactly
        // when the first key is above τ).
        let any_triangles = cell.largest > tau_triangles;
        let any_points = cell.hi0 > tau_points;
        let triangles = if any_triangles { self.model.triangles_above(cell, tau_triangles) } else { 0 };
        let points = if !any_points {
            0
        } else if tau_points >= cell.next_hi && tau_points < f32::INFINITY {
            // Every point after the roots has `hi ≤ τ_p`: the prefix is the roots.
            cell.roots
        } else {
            self.model.points_above(cell, tau_points)
        };
        self.cells += 1;
        self.triangles += u64::from(triangles);
        self.points += u64::from(points);
        let taus = (tau_points, tau_triangles);
        let mut range = self.range(
            (cell.index, Kind::Triangles, cell.triangles.first, triangles),
            taus,
            self.settings.shading_at(z),
        );
        if triangles > 0 {
            self.sink.push(range);
            self.triangle_ranges += 1;
        }
        if points > 0 {
            range.kind = Kind::Points;
            range.first = cell.points.first;
            range.count = points;
            self.sink.push(range);
        }
    }
}

/// Number of leading `values` above `tau`, `values` sorted largest first: `partition_point(v > τ)`
/// by galloping from the front, so a short prefix (a far cell) costs `O(log prefix)`, and an
/// empty one (a cell whose largest value is not above `tau`) one comparison. A model's cells
/// and far list are searched through their samples ([`leading_above_sampled`]).
#[must_use]
pub fn leading_above(values: &[f32], tau: f32) -> u32 {
    let n = values.len();
    if !values.first().is_some_and(|&v| v > tau) {
        return 0;
    }
    // Invariant: values[bound / 2] > tau.
    let mut bound = 1;
    while bound < n && values[bound] > tau {
        bound *= 2;
    }
    let start = bound / 2 + 1;
    let end = bound.min(n);
    let count = start + values[start..end].partition_point(|&v| v > tau);
    u32::try_from(count).unwrap_or(u32::MAX)
}

/// The run length of a [`search_index`]: 16 `f32`, one 64-byte cache line.
pub const SAMPLED: usize = 16;

/// What [`leading_above_sampled`] searches in place of a sorted array `values`: its first
/// [`SAMPLED`] values, then every [`SAMPLED`]-th value after them (`values[16]`, `values[32]`,
/// …). A model's indices hold a sixteenth of its cells' sizes and `hi` values and their first
/// cache line (the willow's 1.6 MB, 0.11 MB), so a frame's searches meet them in the cache,
/// where a search of the values themselves misses at most of its steps, and a prefix shorter
/// than a run (a far tree's cell) is counted without reading the values at all.
pub fn search_index(values: &[f32]) -> impl Iterator<Item = f32> + '_ {
    values.iter().take(SAMPLED).chain(values.iter().skip(SAMPLED).step_by(SAMPLED)).copied()
}

/// The length of the [`search_index`] of `n` values.
#[must_use]
pub const fn search_index_len(n: usize) -> usize {
    if n <= SAMPLED { n } else { SAMPLED + (n - SAMPLED).div_ceil(SAMPLED) }
}

/// [`leading_above`] of `values` (sorted largest first), given `index`, its [`search_index`]:
/// the count within the first run from the index alone; past it, the samples above `tau` by
/// [`leading_above`], then a binary search of the one run of `values` after the last of them.
#[must_use]
pub fn leading_above_sampled(values: &[f32], index: &[f32], tau: f32) -> u32 {
    let head = index.get(..SAMPLED.min(index.len())).unwrap_or_default();
    let count = if head.len() < SAMPLED || head[SAMPLED - 1] <= tau || values.len() <= SAMPLED {
        head.partition_point(|&v| v > tau)
    } else {
        // `values[15] > τ`; sample `j` is `values[16·(j + 1)]`, and `runs` of them are above `τ`.
        let runs = leading_above(&index[SAMPLED..], tau) as usize;
        let start = (runs * SAMPLED + 1).max(SAMPLED).min(values.len());
        let end = ((runs + 1) * SAMPLED).min(values.len()).max(start);
        start + values[start..end].partition_point(|&v| v > tau)
    };
    u32::try_from(count).unwrap_or(u32::MAX)
}

/// Keeps the primitive count near a target by adjusting `s_min` from frame to frame, and with the
/// policy ([`Policy::budget`](crate::Policy::budget)) its error target too.
///
/// Gilet et al. note that `s_m` "allows the user to control the frame rate, or to keep the frame
/// rate constant if required" (§5.1) without giving a rule; this is ours. With `r = last / target`:
///
/// - **Hysteresis**: while idle, nothing changes until `|r − 1| > dead_band`; once adjusting, it goes
///   on until `|r − 1| ≤ dead_band / 2`, so a count hovering at the band's edge does not flicker.
/// - **Step**: `s_min ← s_min · r^(gain/2)`, the factor clamped to `[1/max_step, max_step]` and
///   `s_min` to `[s_min_floor, s_min_ceiling]`. The count of a cut falls roughly as `1/s_min²` (the
///   elements are areas), so `r^(1/2)` would jump to the target; `gain < 1` damps it so a model
///   that reacts more steeply than that still converges without overshoot.
/// - **With the policy** ([`Self::update_policy`], spec §10.2's budget mode): the same step moves
///   `s_min` and, squared, the policy's error target (clamped to `[target_floor,
///   target_ceiling]`). Every tree is then allowed that target over its floor, scaled by its
///   size on screen as the policy's target is ([`target_at`](crate::policy::target_at): no tree
///   adds more squared error to the frame than a 64-pixel tree at the target), so the frame's
///   error is spread evenly rather than spent on a few trees: near trees (drawn with the
///   point tree above the calibrated heights) coarsen through `s_min`, calibrated ones through
///   the target, by the same factor. The square: `s_min` is a length, the target an error read
///   off tables whose cost falls in steps, so it needs the larger move to reach the next choice.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BudgetController {
    /// Primitives (triangles + points) per frame to aim for.
    pub target_primitives: u64,
    /// Relative error tolerated before adjusting. Default 0.05.
    pub dead_band: f32,
    /// Largest factor `s_min` changes by in one frame (`> 1`). Default 1.25.
    pub max_step: f32,
    /// Damping of the step, in `(0, 1]`. Default 0.5.
    pub gain: f32,
    /// Smallest `s_min`, pixels. Default 0.5.
    pub s_min_floor: f32,
    /// Largest `s_min`, pixels. Default 64.
    pub s_min_ceiling: f32,
    /// Smallest policy target ([`Self::update_policy`]). Default 1/1024: below it the choices are
    /// those of target 0 on measured tables (errors are stored to about that precision).
    pub target_floor: f32,
    /// Largest policy target. Default 1: every representation qualifies, the cheapest is drawn.
    pub target_ceiling: f32,
    s_min: f32,
    target: f32,
    adjusting: bool,
    /// Budget mode of the policy: where it started and how far it has moved.
    steering: Steering,
}

/// [`BudgetController::update_policy`]'s state: `s_min = start.0·e^p` and `target =
/// start.1·e^(2p)` (each clamped) for the pressure `p`, and the pressures last seen over and under
/// the budget. A policy frame's count falls in steps as the target grows (a model's trees switch
/// representation together), so a plain step would jump back and forth across a step forever;
/// the bracket halves the move each time the count crosses the budget, and settles on the least
/// pressure seen under it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Steering {
    start: (f32, f32),
    pressure: f64,
    /// Greatest pressure whose frame was over the budget; after a cliff, half a
    /// [`PRESSURE_RESOLUTION`] under the pressure held, so that every pressure below it counts as
    /// over ([`CLIFF`]) and the two are one pressure whatever the rounding (a whole resolution
    /// under could read as more than one, and the steering would probe between them).
    over: Option<f64>,
    /// Least pressure whose frame was under the budget.
    under: Option<f64>,
    /// The pressure and the count of the first frame at it: a count that moves away from it
    /// while the pressure holds means the scene changed (the camera moved), and the bounds no
    /// longer hold.
    last: Option<(f64, u64)>,
    /// Where the frame at [`Self::over`] was a cliff (over [`CLIFF`] times the budget): the count
    /// expected of a frame there, that frame's count scaled as the count at the hold has fallen
    /// since. A fall releases the hold only where this has fallen to twice the budget; else the
    /// hold lasts [`RETRY_FRAMES`] or more.
    cliff: Option<f64>,
    /// Frames the steering has held since its last cliff.
    held: u32,
    /// Frames a hold after a cliff lasts before the steering tries below it again, whatever the
    /// count did; 0 until a cliff is met ([`RETRY_FRAMES`]).
    retry_after: u32,
    /// The pressure of the last frame given to [`BudgetController::update_policy`]
    /// ([`BudgetController::refuse`] goes back to it).
    drawn: Option<f64>,
}

impl Steering {
    /// Forgets the bounds and the cliff: the next frames probe as from a new scene.
    fn release(&mut self) {
        (self.over, self.under, self.cliff) = (None, None, None);
    }

    /// The count of the frame at a new greatest pressure over the budget, where it is a cliff:
    /// a new hold, which lasts [`RETRY_FRAMES`] the first time, twice as long each time after.
    fn set_cliff(&mut self, count: Option<f64>) {
        self.cliff = count;
        if count.is_some() {
            self.held = 0;
            self.retry_after =
                if self.retry_after == 0 { RETRY_FRAMES } else { (2 * self.retry_after).min(MAX_RETRY_FRAMES) };
        }
    }
}

/// Pressures closer than this are one (2 % in `s_min`, 4 % in the target).
const PRESSURE_RESOLUTION: f64 = 0.02;

/// The bracket [`BudgetController::lower_within`] closes to: a quarter of
/// [`PRESSURE_RESOLUTION`] (0.5 % in `s_min`, 1 % in the target). Where many trees' choices
/// change over a narrow range of targets the count falls steeply: on 1,000 trees of the shared
/// maple (`bench --budget 100000 --seed 1`, frame 80) the count predicted at pressures 0.497,
/// 0.517 and 0.537 was 163,000, 44,000 and 8,000 primitives. The steering held at 0.529 for
/// twelve frames, drawing 45,000 down to 3,700 primitives, where 0.517 was predicted at 37,000
/// to 95,000: a search closed to [`PRESSURE_RESOLUTION`] stops short of a pressure 0.012 away.
const LOWER_RESOLUTION: f64 = 0.25 * PRESSURE_RESOLUTION;

/// The bracket [`BudgetController::lower_within`] and [`BudgetController::raise_within`] go on
/// closing to where the end within the budget is still predicted far under it ([`FAR_UNDER`]):
/// a fortieth of [`PRESSURE_RESOLUTION`] (0.05 % in `s_min`, 0.1 % in the target). In budget
/// mode each tree is chosen under a target of its own ([`crate::policy::BUDGET_TARGET_STEP`]),
/// so a step of the target moves a share of the trees, and where a model's trees have nothing
/// between one quad and tens of thousands of primitives at their heights, the share that
/// [`LOWER_RESOLUTION`] moves is already many times the budget: on 1,000 trees of the shared
/// jacaranda (`bench --budget 100000 --seed 2`, frames 284–292, flying away from the forest)
/// 767–829 trees, each one octahedral quad, were drawn at a target of 0.01013, where 0.7 % lower
/// was predicted at 280,000–413,000 primitives (a few trees leaving the quad for techniques of
/// 4,000–35,000 primitives), and the steering held there for nine frames.
const CLIFF_RESOLUTION: f64 = 0.025 * PRESSURE_RESOLUTION;

/// A frame over this many times the budget at a pressure under one whose frame was under it: a
/// cliff in the count, not probed again ([`BudgetController::update_policy`]).
const CLIFF: f64 = 2.0;

/// A frame predicted over this many times the budget is raised before it is drawn
/// ([`BudgetController::raise_within`]), and a step down predicted over it refused
/// ([`BudgetController::refuse`]): [`BudgetController::raise_count`]. Twice the default dead
/// band, so that a frame the steering would step back from anyway is not predicted again.
const PREDICTED_OVER: f64 = 1.1;

/// A frame under this share of the budget is far under it: the steering's next step down is
/// searched for by prediction ([`BudgetController::lower_within`]) rather than taken one largest
/// step a frame.
pub const FAR_UNDER: f64 = 0.5;

/// Frames a hold after a cliff lasts before [`BudgetController::update_policy`] tries below it
/// again where the count has not fallen enough to release it (a scene that got cheaper in ways
/// the count at the hold does not show: the cliff moved); doubled at each cliff met after that,
/// up to [`MAX_RETRY_FRAMES`], until a fall releases a hold (about a second at 60 Hz, then 2, 4,
/// 8 and 16).
const RETRY_FRAMES: u32 = 60;

/// The longest hold after a cliff ([`RETRY_FRAMES`]).
const MAX_RETRY_FRAMES: u32 = 16 * RETRY_FRAMES;

impl BudgetController {
    /// A controller aiming at `target_primitives`, starting from `s_min` pixels.
    #[must_use]
    pub fn new(target_primitives: u64, s_min: f32) -> Self {
        Self {
            target_primitives,
            dead_band: 0.05,
            max_step: 1.25,
            gain: 0.5,
            s_min_floor: 0.5,
            s_min_ceiling: 64.0,
            target_floor: 1.0 / 1024.0,
            target_ceiling: 1.0,
            s_min,
            target: crate::Policy::DEFAULT_TARGET,
            adjusting: false,
            steering: Steering {
                start: (s_min, crate::Policy::DEFAULT_TARGET),
                pressure: 0.0,
                over: None,
                under: None,
                last: None,
                cliff: None,
                held: 0,
                retry_after: 0,
                drawn: None,
            },
        }
    }

    /// A controller for the policy's budget mode ([`Self::update_policy`]): aiming at
    /// `target_primitives`, starting from `s_min` pixels and the policy target `target` (raised
    /// to [`Self::target_floor`] if below it).
    #[must_use]
    pub fn for_policy(target_primitives: u64, s_min: f32, target: f32) -> Self {
        let mut controller = Self::new(target_primitives, s_min);
        controller.target = if target.is_finite() { target.max(controller.target_floor) } else { 1.0 };
        controller.steering.start = (s_min, controller.target);
        controller
    }

    /// The current policy target ([`Self::update_policy`]).
    #[must_use]
    pub fn target(&self) -> f32 {
        self.target
    }

    /// The current `s_min`, pixels.
    #[must_use]
    pub fn s_min(&self) -> f32 {
        self.s_min
    }

    /// Whether the steering is at its finest: `s_min` at [`Self::s_min_floor`] and the policy
    /// target at [`Self::target_floor`], the least pressure that still acts. No steering draws
    /// more detail there, so a frame far under the budget at it has nothing left to spend the
    /// budget on: its forest, at the finest the policy chooses, costs less.
    #[must_use]
    pub fn at_finest(&self) -> bool {
        self.s_min <= self.s_min_floor && self.target <= self.target_floor
    }

    /// Takes the primitive count of the last frame ([`FrameStats::primitives`]) and returns the
    /// `s_min` for the next one (see the type's documentation for the rule).
    pub fn update(&mut self, last_frame_primitives: u64) -> f32 {
        if let Some(factor) = self.step(last_frame_primitives) {
            self.scale_s_min(factor);
        }
        self.s_min
    }

    /// Budget mode of the policy: takes the primitive count of the last frame (every kind,
    /// as the renderer counts them) and returns the `s_min` and the policy target for the next
    /// one: [`Self::update`]'s step applied to `s_min`, and squared to the target (the type's
    /// documentation).
    ///
    /// Where the count falls in steps (a target at which many trees switch representation at
    /// once), the move halves each time the count crosses the budget, and the controller settles
    /// on the least pressure it has seen under the budget: the frame then stays under the
    /// budget, by up to one such step, rather than flickering across it. Where the step is a
    /// cliff (a frame more than twice over the budget at a pressure below one whose frame was
    /// under it: many trees switched at once, as a forest of one model's trees at like distances
    /// does), halving the gap would cost a frame far over the budget per halving, so the
    /// pressure goes straight back to the least seen under the budget and holds there. When the
    /// count falls by more than the dead band while the steering holds (the scene got cheaper:
    /// the camera moved), it tries again; a count that rises over the budget raises the pressure
    /// as any frame over it does.
    ///
    /// A hold next to a cliff (the greatest pressure over the budget had a frame over twice it,
    /// whether the cliff's rule or the halving got there) is not released by every fall: trees
    /// leaving the view lower the count at the hold by a few percent and leave the frame below
    /// it as far over. The frame below is taken to have fallen by the same share as the count at
    /// the hold, and the hold is released once that brings it down to twice the budget. As the
    /// cliff may also move where the count at the hold does not show it, the steering tries
    /// below a hold after 60 frames whatever the count did, then after twice as many at each
    /// cliff met, up to 960, until a fall releases a hold.
    ///
    /// Measured (`bench --trees 1000 --frames 300 --budget 100000 --no-render`, each shared model
    /// with every representation; frames over twice the budget, then over 5 times, halving the
    /// gap against the cliff's rule): the Quaternius tree 6, 0 → 1, 0; oak 36, 4 → 36, 4; pine
    /// 54, 12 → 48, 3; orchid 42, 5 → 39, 0; jacaranda 31, 11 → 22, 7; maple 51, 16 → 28, 13;
    /// willow 23, 13 → 20, 7; along another path (`--seed 2`) pine 36, 5 → 31, 1, maple 47, 17
    /// → 28, 12 and jacaranda 43, 17 → 21, 1. The price is budget left unused while the hold
    /// lasts: frames under half the budget went 50 → 121 on the maple (the others within ±8).
    /// A cliff met again after the bounds are dropped is still met, once: the jacaranda's worst
    /// frame read 1.7 million primitives before and 21.4 million after, each one frame where
    /// its path met a cliff (with `--seed 2`, 21.1 million before, 3.0 million after).
    ///
    /// Holding next to a cliff through falls (the same runs; the worst frame, frames over twice
    /// the budget, over 5 times, the mean frame, before → after): the pine 14.4 million, 48, 3,
    /// 180,200 → 0.46 million, 44, 0, 105,900 (its descent had released a hold as 56 of 1,000
    /// trees left the view, and met 14.4 million at the next step down); the maple 2.2 million,
    /// 28, 13, 115,000 → 2.2 million, 20, 9, 98,200 (`--seed 2`: 28, 12, 138,600 → 20, 9,
    /// 121,500); the willow 20, 7 → 14, 6 (`--seed 2`: 17, 7 → 21, 6); the jacaranda 22, 7 → 21,
    /// 5; the others the same frames. The jacaranda's 21.4 million remain: the camera turned
    /// back and its count fell from 28,000 to 686, a real fall, and the steering, stepping down
    /// by the largest step each frame from far under the budget, met 580 trees switching to the
    /// chain at once. A host that predicts each step down before drawing it refuses such a step
    /// ([`Self::refuse`]; the renderer does): the jacaranda's worst frame then read 0.40 million.
    pub fn update_policy(&mut self, last_frame_primitives: u64) -> (f32, f32) {
        let over_budget = last_frame_primitives > self.target_primitives;
        #[expect(clippy::cast_precision_loss, reason = "counts need no integer precision here")]
        let cliff_limit = self.cliff_count() as f64;
        let steering = &mut self.steering;
        let p = steering.pressure;
        steering.drawn = Some(p);
        // Bounds are stale once the scene changes under them: the count fell while the pressure
        // held (compared with the first frame at this pressure, so that a slow drift counts
        // too), or the frame contradicts one of them. Only a fall releases a hold under the
        // budget: trying again costs a frame over it, worth it only where the scene got cheaper.
        let band = f64::from(self.dead_band.max(0.0));
        #[expect(clippy::cast_precision_loss, reason = "a ratio of counts needs no integer precision")]
        let fell = steering
            .last
            .is_some_and(|(q, count)| q == p && (last_frame_primitives as f64) < count as f64 * (1.0 - band));
        if fell {
            // After a cliff, the count at the hold falling (trees leaving the view) does not
            // make the frame below it cheaper by more than the same share: the hold stays until
            // that share has brought the cliff's count down to twice the budget.
            #[expect(clippy::cast_precision_loss, reason = "a ratio of counts needs no integer precision")]
            let share = steering.last.map_or(1.0, |(_, first)| last_frame_primitives as f64 / first.max(1) as f64);
            match steering.cliff {
                Some(count) if count * share > cliff_limit => steering.cliff = Some(count * share),
                held => {
                    if held.is_some() {
                        steering.retry_after = 0;
                    }
                    steering.release();
                }
            }
        }
        if fell || steering.last.is_none_or(|(q, _)| q != p) {
            steering.last = Some((p, last_frame_primitives));
        }
        if steering.cliff.is_some() {
            steering.held += 1;
            if steering.held >= steering.retry_after {
                steering.release();
            }
        }
        if over_budget && steering.under.is_some_and(|u| p >= u) {
            (steering.under, steering.cliff) = (None, None);
        }
        if !over_budget && steering.over.is_some_and(|o| p <= o) {
            (steering.over, steering.cliff) = (None, None);
        }
        let Some(factor) = self.step(last_frame_primitives) else {
            return (self.s_min, self.target);
        };
        let steering = &mut self.steering;
        let mut next = p + factor.ln();
        if over_budget {
            // The count below the hold the steering will settle on is this frame's where this is
            // the greatest pressure over the budget: a cliff where it is more than `CLIFF` times
            // the budget.
            #[expect(clippy::cast_precision_loss, reason = "a count needs no integer precision here")]
            let count = last_frame_primitives as f64;
            let greatest = steering.over.is_none_or(|o| p >= o);
            if greatest {
                steering.set_cliff((count > cliff_limit).then_some(count));
            }
            steering.over = Some(steering.over.map_or(p, |o| o.max(p)));
            if let Some(u) = steering.under {
                // Over by more than `CLIFF` times where a higher pressure was under: the count
                // jumps there (a model's trees switching together), and halving the gap would
                // cost a frame far over the budget per halving. Back to the pressure that was
                // under, held there as if every pressure below it were over, until the scene
                // changes (the bounds are dropped as for any frame).
                let cliff = count > cliff_limit;
                if cliff {
                    steering.over = steering.over.map(|o| o.max(u - 0.5 * PRESSURE_RESOLUTION));
                    if !greatest {
                        steering.set_cliff(Some(count));
                    }
                }
                next = if u - p <= PRESSURE_RESOLUTION || cliff { u } else { next.min(0.5 * (p + u)) };
            }
        } else {
            steering.under = Some(steering.under.map_or(p, |u| u.min(p)));
            if let Some(o) = steering.over {
                if p - o <= PRESSURE_RESOLUTION {
                    next = p;
                } else {
                    next = next.max(0.5 * (p + o));
                }
            }
        }
        self.set_pressure(next)
    }

    /// Whether no frame has been given to [`Self::update_policy`] yet: the steering is where it
    /// started, and [`Self::start_within`] may move it before the first frame is drawn.
    #[must_use]
    pub fn awaits_first_frame(&self) -> bool {
        self.steering.drawn.is_none()
    }

    /// Budget mode's first frame, predicted before it is drawn: a host that can predict the
    /// count of a frame selected with a given `s_min` and policy target (`predict(s_min,
    /// target)`, from the calibration tables) starts the steering at the least pressure whose
    /// predicted count is within the budget, rather than drawing its first frames at the
    /// starting target and stepping down by at most [`Self::max_step`] a frame (1,000 trees of
    /// the shared maple, `bench --budget 100000`, drew their first three frames at 15 to 22 times
    /// the budget, the willow's their first four at 8 to 29 times; started within it, the first
    /// frames read 99,400 and 26,900 on the maple's two paths, and the willow's 1,000). The
    /// pressure is found as [`Self::raise_within`] finds it (to within half a largest step, the
    /// steering's own steps down closing the rest). The predictions mark no bound: the
    /// frames drawn then steer as from any start. Returns the `s_min` and target to draw with;
    /// once a frame has been given ([`Self::awaits_first_frame`]), changes nothing and predicts
    /// nothing.
    pub fn start_within(&mut self, mut predict: impl FnMut(f32, f32) -> u64) -> (f32, f32) {
        if !self.awaits_first_frame() || predict(self.s_min, self.target) <= self.target_primitives {
            return (self.s_min, self.target);
        }
        self.search_up(predict)
    }

    /// Budget mode between frames: a host that predicts the next frame at the steering it is
    /// about to draw with (the camera moved since the last frame: near trees above the
    /// calibration tables' heights, whose LoD chain level or point tree cut follows `s_min`,
    /// can take a frame from under the budget to many times it) and finds it over
    /// [`Self::raise_count`] raises the steering here before drawing it: the pressure predicted
    /// over counts as over the budget (as a refused step does, [`Self::refuse`]), and the
    /// steering moves to a pressure above it whose predicted count (`predict(s_min, target)`) is
    /// within the budget: the least to within half a largest step ([`Self::max_step`]), or the
    /// greatest that still acts if that one is predicted over too. The search gallops up by a
    /// largest step, then twice that, four times…, then halves the bracket it found: a frame a
    /// step or two over costs two or three predictions, a frame 20 times over about six (each
    /// prediction chooses the trees again and, at a new target, makes the models' tables of
    /// choices again).
    ///
    /// Where a search down ([`Self::lower_within`]) left the steering below the pressure of the
    /// frame last drawn, the raise goes back no further than that pressure, whose frame was
    /// drawn, and closes its bracket as the search down does (0.5 % in `s_min`, on to 0.05 % while
    /// the end within the budget is predicted far under it); only where that
    /// pressure too is predicted over does it go on up as above. Raised by half a largest step at
    /// a time, such a frame went from the foot of a step the search down had found to past its
    /// top: on 1,000 trees of the shared orchid (`bench --budget 100000 --seed 2`, frames 61–63)
    /// the search down took the target from 0.0107, drawn at 966 primitives, to 0.0086–0.0092,
    /// predicted within the budget; the camera moved, those were predicted at 137,000–140,000,
    /// and the raise went to 0.0108–0.0115, drawing 955 and 949 primitives, where 0.0096 drew
    /// 99,600 the next frame. Returns the `s_min` and target to draw with.
    pub fn raise_within(&mut self, mut predict: impl FnMut(f32, f32) -> u64) -> (f32, f32) {
        self.mark_over();
        let from = self.steering.pressure;
        if let Some(drawn) = self.steering.drawn.filter(|&d| d - from > LOWER_RESOLUTION) {
            // A search down left the steering below the pressure of the frame last drawn: the
            // raise goes back no further than that pressure, to the search down's bracket.
            let (_, under) = self.gallop(from, drawn, true, LOWER_RESOLUTION, &mut predict);
            if let Some(under) = under {
                return self.set_pressure(under);
            }
            self.set_pressure(drawn);
        }
        self.search_up(predict)
    }

    /// Budget mode after a frame far under the budget (under [`FAR_UNDER`] of it), or before one
    /// predicted so (the camera moved; the renderer lowers such a frame before drawing it): a host that
    /// predicts the count of a frame selected with a given `s_min` and policy target
    /// (`predict(s_min, target)`, as for [`Self::raise_within`]) moves the steering from where
    /// [`Self::update_policy`] left it on down, by prediction, to the least pressure predicted
    /// within the budget, rather than one largest step ([`Self::max_step`]) a frame, or none
    /// where the steering holds next to a cliff. Such frames follow a raise to the coarsest
    /// steering, a camera that turned to a few trees, or a hold whose scene has changed in a way
    /// its count cannot show: measured on the shared oak's forest (1,000 trees, `bench --budget
    /// 100000`), 80 trees in view, each drawn with one quad, held for 25 frames after a cliff
    /// (their count could not fall, which is what releases a hold). The search gallops down by a
    /// largest step, then twice that, four times…, until a pressure is predicted over the
    /// budget or the lowest that acts is reached, then halves the bracket to 0.5 % in `s_min` (1 %
    /// in the target; on to 0.05 % while the end within the budget is predicted far under it),
    /// not half a largest step as a raise does: where the count falls off a cliff just above
    /// the least pressure within the budget, a search that stopped within half a largest step
    /// of it left the frame far under the budget, and a hold next to the cliff kept it there (the
    /// shared pine's forest seen from above: 37,000 primitives for 30 frames, where a pressure
    /// 3 % lower in `s_min` was predicted at 91,700 against a budget of 100,000). Where it moves the steering, the predictions stand for the frames a hold waits for: the
    /// pressure predicted over becomes the greatest over the budget and the hold ends; so the
    /// predictions must not fall short. Those of a large forest predicted from a sample miss
    /// the near trees of the chunks it leaves out: on 10^6 trees of the shared pine (`--budget
    /// 1000000`) they alternated frames far under the budget with frames twice over it, even
    /// where the search kept above the pressures drawn frames had found over, and the renderer
    /// does not lower such a forest by prediction. Returns the `s_min` and target to draw with.
    pub fn lower_within(&mut self, predict: impl FnMut(f32, f32) -> u64) -> (f32, f32) {
        let (lowest, _) = self.pressure_range();
        let start = self.steering.pressure;
        let (under, over) = self.gallop(start, lowest, false, LOWER_RESOLUTION, predict);
        let steering = &mut self.steering;
        if under < start {
            (steering.over, steering.cliff) = (over, None);
        } else if let Some(o) = over {
            steering.over = Some(steering.over.map_or(o, |before| before.max(o)));
        }
        self.set_pressure(under)
    }

    /// A largest step ([`Self::max_step`]) in pressure, at least [`PRESSURE_RESOLUTION`].
    fn largest_step(&self) -> f64 {
        f64::from(self.max_step.max(1.0)).ln().max(PRESSURE_RESOLUTION)
    }

    /// Counts the current pressure as over the budget though no frame was drawn there (a
    /// prediction found it over: [`Self::refuse`], [`Self::raise_within`]).
    fn mark_over(&mut self) {
        let steering = &mut self.steering;
        steering.over = Some(steering.over.map_or(steering.pressure, |o| o.max(steering.pressure)));
    }

    /// [`Self::raise_within`]'s search from the current pressure (predicted over the budget),
    /// without marking it: the steering moves where it ends.
    fn search_up(&mut self, predict: impl FnMut(f32, f32) -> u64) -> (f32, f32) {
        let (_, highest) = self.pressure_range();
        let resolution = (0.5 * self.largest_step()).max(PRESSURE_RESOLUTION);
        let (over, under) = self.gallop(self.steering.pressure, highest, true, resolution, predict);
        self.set_pressure(under.unwrap_or(over))
    }

    /// The search of [`Self::raise_within`] and [`Self::lower_within`]: from pressure `from`,
    /// whose frame is taken to be over the budget (`from_over`) or within it, gallops towards
    /// `bound` by a largest step, then twice that, four times…, until a pressure is predicted on
    /// the other side of the budget (`predict(s_min, target)`), then halves the bracket to
    /// `resolution` (up, half a largest step; down, and up back to a pressure drawn,
    /// [`LOWER_RESOLUTION`]), and on to [`CLIFF_RESOLUTION`] while the end of the bracket within
    /// the budget is predicted under [`FAR_UNDER`] of it (a search down that has not moved
    /// counts its start, a frame drawn far under the budget, so). Measured (`bench --trees 1000
    /// --frames 300 --budget 100000 --no-render`, every shared model with every representation,
    /// 4,200 frames a pair of seeds; frames within ½–1.1 times the budget, under half of it
    /// with something left to spend, over 1.1 times it, before → after): seeds 1 and 2 3,772 →
    /// 3,827, 162 → 126, 91 → 72; seeds 3 and 4 3,801 → 3,844, 144 → 110, 99 → 90; with
    /// 15-frame transitions (seeds 1 and 2) 3,755 → 3,814, 163 → 129, 119 → 96; 10^4 trees of
    /// the oak, maple and jacaranda (120 frames each) 200 → 217, 79 → 62, 13 → 14; the
    /// four-model forest and 10^6 pine trees (predicted from a sample, never lowered) the same
    /// counts. Every search closed to [`CLIFF_RESOLUTION`] instead: 3,798, 146 and 81 (seeds 1
    /// and 2), with 15-frame transitions 3,776, 127 and 134; to a tenth of
    /// [`PRESSURE_RESOLUTION`]: 3,806, 144, 75 (seeds 1 and 2), 3,802, 139, 95 (seeds 3 and 4);
    /// the finer bracket in the searches down alone: 3,789, 148, 88 and 3,811, 134, 99.
    /// `assign` on 10^4 jacaranda trees read 2.33–3.08 ms a frame before and 2.45–2.97 ms
    /// after (three alternating runs each). Returns the
    /// last pressure found on `from`'s side and the first on the other (`None` where `bound` was
    /// reached without one); the steering is left where it predicted last.
    ///
    /// Up, the finer bracket was measured and not taken (`bench --trees 1000 --frames 300
    /// --budget 100000 --no-render`, every shared model, seeds 1 and 2: 4,200 frames): a raise
    /// that lands just within the budget is over it again as soon as the camera comes nearer,
    /// and frames over 1.1 times the budget went 172 → 218 (the primitives drawn over it, summed,
    /// 6.4 → 8.4 million) for 152 more frames within ½–1.1 times it.
    fn gallop(
        &mut self,
        from: f64,
        bound: f64,
        from_over: bool,
        resolution: f64,
        mut predict: impl FnMut(f32, f32) -> u64,
    ) -> (f64, Option<f64>) {
        let step = self.largest_step();
        // Whether the count predicted at `pressure` is over the budget, and that count.
        let mut over_at = |controller: &mut Self, pressure: f64| {
            let (s_min, target) = controller.set_pressure(pressure);
            let count = predict(s_min, target);
            (count > controller.target_primitives, count)
        };
        let up = bound >= from;
        let (mut last, mut reach) = (from, step);
        // The count predicted at the end of the bracket within the budget; `None` while that
        // end is `from` (a frame drawn, which a search down starts from because it was far under).
        let mut under_count = None;
        let mut other = loop {
            let next = if up { (last + reach).min(bound) } else { (last - reach).max(bound) };
            let moved = if up { next > last } else { next < last };
            if !moved {
                break None;
            }
            let (over, count) = over_at(self, next);
            if over != from_over {
                if from_over {
                    under_count = Some(count);
                }
                break Some(next);
            }
            if !from_over {
                under_count = Some(count);
            }
            last = next;
            reach *= 2.0;
        };
        while let Some(o) = other.filter(|&o| {
            let gap = (o - last).abs();
            gap > resolution || (gap > CLIFF_RESOLUTION && under_count.is_none_or(|c| self.far_under(c)))
        }) {
            let mid = 0.5 * (o + last);
            let (over, count) = over_at(self, mid);
            if !over {
                under_count = Some(count);
            }
            if over == from_over {
                last = mid;
            } else {
                other = Some(mid);
            }
        }
        (last, other)
    }

    /// Where the steering started, `(s_min, target)`, and the clamps of `s_min` and of the
    /// target, `(floor, ceiling)` each, as the pressure reads them.
    fn clamps(&self) -> ((f64, f64), (f64, f64), (f64, f64)) {
        let (s0, t0) = (f64::from(self.steering.start.0.max(f32::MIN_POSITIVE)), f64::from(self.steering.start.1));
        let t_floor = f64::from(self.target_floor.max(f32::MIN_POSITIVE));
        let s_floor = f64::from(self.s_min_floor.max(f32::MIN_POSITIVE));
        let s_ceiling = f64::from(self.s_min_ceiling).max(s_floor);
        ((s0, t0), (s_floor, s_ceiling), (t_floor, f64::from(self.target_ceiling).max(t_floor)))
    }

    /// The least and the greatest pressure that still act: past both clamps (`s_min`'s and the
    /// target's) a pressure changes nothing.
    fn pressure_range(&self) -> (f64, f64) {
        let ((s0, t0), (s_floor, s_ceiling), (t_floor, t_ceiling)) = self.clamps();
        let lowest = (s_floor / s0).ln().min(0.5 * (t_floor / t0).ln());
        let highest = (s_ceiling / s0).ln().max(0.5 * (t_ceiling / t0).ln());
        (lowest.min(highest), highest)
    }

    /// Moves the steering to pressure `next` (clamped to where it still acts) and sets `s_min`
    /// and the target from it.
    fn set_pressure(&mut self, next: f64) -> (f32, f32) {
        let (lowest, highest) = self.pressure_range();
        let ((s0, t0), (s_floor, s_ceiling), (t_floor, t_ceiling)) = self.clamps();
        let steering = &mut self.steering;
        steering.pressure = next.clamp(lowest, highest);
        let p = steering.pressure;
        #[expect(clippy::cast_possible_truncation, reason = "s_min in pixels and the target in [0, 1]")]
        {
            self.s_min = (s0 * p.exp()).clamp(s_floor, s_ceiling) as f32;
            self.target = (t0 * (2.0 * p).exp()).clamp(t_floor, t_ceiling) as f32;
        }
        (self.s_min, self.target)
    }

    /// The count over which [`Self::update_policy`] takes a frame over the budget for a cliff:
    /// twice the budget.
    #[must_use]
    pub fn cliff_count(&self) -> u64 {
        self.times_budget(CLIFF)
    }

    /// `share` times the budget, a count.
    fn times_budget(&self, share: f64) -> u64 {
        #[expect(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            clippy::cast_precision_loss,
            reason = "a multiple of a count"
        )]
        let limit = (share * self.target_primitives as f64) as u64;
        limit
    }

    /// The count over which a host that predicts its frames ([`Self::raise_within`],
    /// [`Self::refuse`]) takes a frame for over the budget before drawing it: 1.1 times the
    /// budget, twice the default dead band. Measured (`bench --budget 100000`, 1,000 trees of
    /// each shared model with every representation, 300 frames, seeds 1 and 2: 4,200 frames),
    /// raising and refusing at 1.1 times the budget rather than at twice it ([`Self::cliff_count`],
    /// a cliff): frames over 1.1 times the budget 1,191 → 448, over twice it 91 → 5, within ½–1.1
    /// times it 1,625 → 2,197, under half of it 1,384 → 1,555 (a raised frame settles under the
    /// budget); the `assign` phase, where the predictions run, 0.23 → 0.27 ms a frame on average.
    #[must_use]
    pub fn raise_count(&self) -> u64 {
        self.times_budget(PREDICTED_OVER)
    }

    /// Whether a frame of `count` primitives is far under the budget (under [`FAR_UNDER`] of it),
    /// where a host that predicts its frames moves the steering on down
    /// ([`Self::lower_within`]).
    #[must_use]
    pub fn far_under(&self, count: u64) -> bool {
        #[expect(clippy::cast_precision_loss, reason = "a share of a count")]
        let far = (count as f64) < FAR_UNDER * self.target_primitives as f64;
        far
    }

    /// Whether the steering [`Self::update_policy`] just returned lowers the policy target from
    /// `before` (the target of the frame it was given): a step down, which may meet a cliff.
    #[must_use]
    pub fn steps_down_from(&self, before: f32) -> bool {
        self.target < before
    }

    /// Budget mode's look-ahead: a host that predicts the count of the steering
    /// [`Self::update_policy`] just returned (from the calibration tables, before drawing it),
    /// and finds it over [`Self::raise_count`], refuses the step here: the steering goes back to
    /// the pressure of the frame last given to [`Self::update_policy`], and the refused one
    /// counts as over the budget. The next step down is then half as far (the bracket of
    /// [`Self::update_policy`]), predicted again, so the steering closes in on the cliff without
    /// drawing a frame over it. Returns the `s_min` and target to draw with; without a frame
    /// given yet, changes nothing.
    pub fn refuse(&mut self) -> (f32, f32) {
        let Some(back) = self.steering.drawn else { return (self.s_min, self.target) };
        self.mark_over();
        self.set_pressure(back)
    }

    /// The factor of this frame's step (the type's documentation), `None` while idle.
    fn step(&mut self, last_frame_primitives: u64) -> Option<f64> {
        #[expect(clippy::cast_precision_loss, reason = "a ratio of counts needs no integer precision")]
        let ratio = last_frame_primitives as f64 / self.target_primitives.max(1) as f64;
        let error = (ratio - 1.0).abs();
        let band = f64::from(self.dead_band.max(0.0));
        self.adjusting = if self.adjusting { error > 0.5 * band } else { error > band };
        let max_step = f64::from(self.max_step.max(1.0));
        self.adjusting
            .then(|| ratio.max(0.0).powf(0.5 * f64::from(self.gain.clamp(0.0, 1.0))).clamp(max_step.recip(), max_step))
    }

    fn scale_s_min(&mut self, factor: f64) {
        #[expect(clippy::cast_possible_truncation, reason = "s_min is a small number of pixels")]
        let next = (f64::from(self.s_min) * factor) as f32;
        self.s_min = next.clamp(self.s_min_floor, self.s_min_ceiling.max(self.s_min_floor));
    }

    /// [`Self::update`], then writes the new `s_min` into `settings` and scales `s_max` by the same
    /// factor, so the point/triangle boundary keeps its ratio to the point threshold.
    pub fn apply(&mut self, last_frame_primitives: u64, settings: &mut LodSettings) {
        let before = settings.s_min;
        let s_min = self.update(last_frame_primitives);
        if before > 0.0 {
            settings.s_max *= s_min / before;
        }
        settings.s_min = s_min;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Policy;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn galloping_equals_partition_point(
            mut values in proptest::collection::vec(0.0f32..10.0, 0..300),
            tau in -1.0f32..11.0,
        ) {
            values.sort_by(|a, b| b.total_cmp(a));
            let expected = values.partition_point(|&v| v > tau);
            prop_assert_eq!(leading_above(&values, tau) as usize, expected);
        }

        /// Through the index, the same count, also where `τ` equals a sampled value or one
        /// after it (runs of equal values straddle the samples: values are drawn from a few).
        #[test]
        fn the_sampled_search_equals_partition_point(
            mut values in proptest::collection::vec((0u8..12).prop_map(|v| f32::from(v) * 0.5), 0..200),
            pick in 0usize..200,
            offset in prop_oneof![Just(0.0f32), Just(0.25), Just(-0.25)],
        ) {
            values.sort_by(|a, b| b.total_cmp(a));
            values.iter_mut().take(3).for_each(|v| *v = f32::INFINITY);
            let sampled: Vec<f32> = search_index(&values).collect();
            prop_assert_eq!(sampled.len(), search_index_len(values.len()));
            let tau = values.get(pick).map_or(2.0, |&v| if v.is_finite() { v + offset } else { 1e30 });
            let expected = values.partition_point(|&v| v > tau);
            prop_assert_eq!(leading_above_sampled(&values, &sampled, tau) as usize, expected);
        }

        /// `prefix_above` (the prefixes of planes, ellipsoids and lines) gallops over one cell's
        /// run of a larger array: the same count as a binary search of that run.
        #[test]
        fn prefix_above_equals_partition_point_of_the_cell(
            mut before in proptest::collection::vec(0.0f32..10.0, 0..50),
            mut cell in proptest::collection::vec(0.0f32..10.0, 0..300),
            mut after in proptest::collection::vec(0.0f32..10.0, 0..50),
            tau in -1.0f32..11.0,
        ) {
            for run in [&mut before, &mut cell, &mut after] {
                run.sort_by(|a, b| b.total_cmp(a));
            }
            let expected = cell.partition_point(|&v| v > tau);
            let (first, count) = (before.len() as u32, cell.len() as u32);
            let hi: Vec<f32> = before.into_iter().chain(cell).chain(after).collect();
            prop_assert_eq!(prefix_above(&hi, first, count, tau) as usize, expected);
        }
    }

    #[test]
    fn galloping_edges() {
        assert_eq!(leading_above(&[], 0.0), 0);
        assert_eq!(leading_above(&[f32::INFINITY], 1e30), 1);
        assert_eq!(leading_above(&[3.0, 2.0, 1.0], 0.5), 3);
        assert_eq!(leading_above(&[3.0, 2.0, 1.0], 3.0), 0);
        let many: Vec<f32> = (0..1000).rev().map(|i| i as f32).collect();
        for tau in [-1.0, 0.0, 0.5, 1.0, 511.0, 512.0, 998.5, 999.0] {
            assert_eq!(leading_above(&many, tau) as usize, many.partition_point(|&v| v > tau), "{tau}");
        }
    }

    #[test]
    fn frustum_planes_bound_the_view() {
        let camera = Camera::look_at(Vec3::ZERO, Vec3::NEG_Z, 1.0, 800, 600);
        let f = Frustum::from_view_proj(camera.view_proj);
        assert!(f.intersects_sphere(Vec3::new(0.0, 0.0, -10.0), 0.1));
        assert!(!f.intersects_sphere(Vec3::new(0.0, 0.0, 10.0), 1.0), "behind");
        assert!(!f.intersects_sphere(Vec3::new(0.0, 0.0, -30_000.0), 1.0), "past the far plane");
        assert!(!f.intersects_aabb(Vec3::new(100.0, -1.0, -11.0), Vec3::new(101.0, 1.0, -9.0)), "to the right");
        assert!(f.intersects_aabb(Vec3::new(-1.0, -1.0, -11.0), Vec3::new(1.0, 1.0, 20.0)), "around the eye");
        // Planes are normalised: the sphere test is in metres. Half-angle 0.5 rad, 10 m ahead: the
        // top plane is 10·sin(0.5) ≈ 4.79 m above the axis, measured perpendicular to it.
        let top = f.planes()[3];
        let d = top.truncate().dot(Vec3::new(0.0, 0.0, -10.0)) + top.w;
        assert!((d - 10.0 * 0.5f32.sin()).abs() < 1e-3, "{d}");
        assert_eq!(f.classify_sphere(Vec3::new(0.0, 0.0, -10.0), 0.1), Containment::Inside);
        assert_eq!(f.classify_sphere(Vec3::new(0.0, 0.0, -10.0), 6.0), Containment::Straddles);
        // An instance's sphere: moved by its transform and grown by its largest axis.
        let sphere = (Vec3::new(0.0, 1.0, 0.0), 1.0);
        let at = Mat4::from_translation(Vec3::new(0.0, -1.0, -10.0));
        assert!(f.contains_instance_sphere(at, sphere));
        assert!(!f.contains_instance_sphere(at * Mat4::from_scale(Vec3::new(1.0, 1.0, 6.0)), sphere), "grown");
        assert!(!f.contains_instance_sphere(Mat4::from_translation(Vec3::new(6.8, -1.0, -10.0)), sphere), "cut");
        assert!(!f.contains_instance_sphere(Mat4::ZERO, sphere), "degenerate");
    }

    #[test]
    fn oriented_box_test_matches_the_aabb_test_without_rotation() {
        let camera = Camera::look_at(Vec3::new(0.0, 2.0, 5.0), Vec3::ZERO, 0.9, 640, 480);
        let f = Frustum::from_view_proj(camera.view_proj);
        for i in 0..200 {
            let c = Vec3::new((i % 20) as f32 * 3.0 - 30.0, (i / 20) as f32 - 5.0, -(i % 7) as f32 * 4.0 + 8.0);
            let h = Vec3::new(0.5, 1.0, 1.5);
            assert_eq!(
                f.intersects_box(c, [Vec3::X * h.x, Vec3::Y * h.y, Vec3::Z * h.z]),
                f.intersects_aabb(c - h, c + h)
            );
        }
    }

    #[test]
    fn bias_follows_gilet_eq_2_and_3() {
        let s = LodSettings { s_min: 1.0, s_max: 4.0, depth_bias_k: 0.5, ..LodSettings::default() };
        assert_eq!(s.biased_pixels(0.0), (1.0, 4.0));
        assert_eq!(s.biased_pixels(1.0), (1.5, 4.5));
        assert_eq!(s.biased_pixels(-1.0), (0.5, 3.5));
        let strong = LodSettings { depth_bias_k: 3.0, ..s };
        assert_eq!(strong.biased_pixels(-1.0), (0.0, 1.0), "s_min_i is clamped at 0");
        let shade = LodSettings { shading: Some((0.4, 1.0)), ..s };
        assert!((shade.shading_at(-1.0) - 0.4).abs() < 1e-6);
        assert!((shade.shading_at(1.0) - 1.0).abs() < 1e-6);
        assert!((shade.shading_at(0.0) - 0.7).abs() < 1e-6);
        assert_eq!(s.shading_at(-1.0), 1.0);
    }

    /// A block of 4 × 1 × 4 cells, each with a few triangles under a root and leaf points.
    fn synthetic_model() -> ModelLod {
        let block = BlockRecord {
            bounds_min: [0.0; 3],
            bounds_max: [4.0, 6.0, 4.0],
            grid: [4, 1, 4],
            tree_count: 1,
            ..BlockRecord::default()
        };
        let (mut cells, mut triangles, mut points) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..16u32 {
            let (x, z) = ((i % 4) as f32, (i / 4) as f32);
            let n = 1 + i % 5;
            let sizes: Vec<f32> = (0..n).map(|j| 0.3 / (1.0 + j as f32) * (1.0 + 0.1 * i as f32)).collect();
            let root = sizes.iter().sum::<f32>();
            cells.push(CellRecord {
                bounds_min: [x, 0.0, z],
                bounds_max: [x + 1.0, 6.0, z + 1.0],
                triangles: Range { first: triangles.len() as u32, count: n },
                points: Range { first: points.len() as u32, count: n + 1 },
                ..CellRecord::default()
            });
            points.push(PointRecord {
                size: root,
                lo: root,
                hi: f32::INFINITY,
                leaf_count: n,
                ..PointRecord::default()
            });
            for (j, &size) in sizes.iter().enumerate() {
                triangles.push(TriangleRecord { size, leaf: j as u32, ..TriangleRecord::default() });
                points.push(PointRecord {
                    size,
                    lo: 0.0,
                    hi: root,
                    leaf_first: j as u32,
                    leaf_count: 1,
                    ..PointRecord::default()
                });
            }
        }
        cells.push(CellRecord {
            triangles: Range { first: triangles.len() as u32, count: 0 },
            points: Range { first: points.len() as u32, count: 0 },
            ..CellRecord::default()
        });
        ModelLod::from_records(&block, &cells, &triangles, &points).unwrap()
    }

    #[test]
    fn parallel_path_equals_sequential_path() {
        let models = [synthetic_model()];
        let instances: Vec<Instance> = (0..3000)
            .map(|i| Instance {
                model: if i % 997 == 5 { 3 } else { 0 }, // a few invalid ones
                transform: Mat4::from_scale_rotation_translation(
                    Vec3::splat(0.8 + 0.0001 * i as f32),
                    glam::Quat::from_rotation_y(i as f32 * 0.7),
                    Vec3::new((i % 60) as f32 * 7.0 - 200.0, 0.0, -((i / 60) as f32) * 9.0),
                ),
            })
            .collect();
        let cameras = [
            Camera::look_at(Vec3::new(0.0, 3.0, 10.0), Vec3::new(10.0, 2.0, -50.0), 1.0, 1280, 720),
            Camera::look_at(Vec3::new(0.0, 400.0, 100.0), Vec3::new(0.0, 0.0, -200.0), 1.0, 1280, 720),
        ];
        for camera in &cameras {
            for settings in [
                LodSettings::default(),
                LodSettings { s_min: 0.3, depth_bias_k: 0.8, shading: Some((0.4, 1.0)), ..LodSettings::default() },
            ] {
                let frame = Frame {
                    frustum: Frustum::from_view_proj(camera.view_proj),
                    eye: camera.position,
                    world_per_pixel: camera.world_per_pixel(),
                    settings: &settings,
                    needs_z: settings.depth_bias_k != 0.0 || settings.shading.is_some(),
                };
                let (mut a, mut b) = (DrawList::new(), DrawList::new());
                let sa = select_sequential(&frame, &models, &instances, &mut a);
                let sb = select_parallel(&frame, &models, &instances, &mut b);
                assert_eq!(sa, sb);
                assert_eq!(a.ranges(), b.ranges());
                assert_eq!((a.triangle_ranges(), a.point_ranges()), (b.triangle_ranges(), b.point_ranges()));
                assert!(sa.instances_visible > 100 && sa.instances_invalid == 4 && sa.ranges > 1000, "{sa:?}");
                // A smaller frame after a larger one: stale storage past the end is not shown.
                let sc = select_parallel(&frame, &models, &instances[..1500], &mut b);
                let sd = select_sequential(&frame, &models, &instances[..1500], &mut a);
                assert_eq!(sc, sd);
                assert_eq!(a.ranges(), b.ranges());
            }
        }
    }

    /// A synthetic scene: the count of a cut falls as `C / s_min²`.
    fn run_budget(c: f64, exponent: f64, controller: &mut BudgetController, frames: usize) -> Vec<f32> {
        let mut trace = Vec::new();
        let mut s = controller.s_min();
        for _ in 0..frames {
            let primitives = (c / f64::from(s).powf(exponent)).round() as u64;
            s = controller.update(primitives);
            trace.push(s);
        }
        trace
    }

    #[test]
    fn budget_converges_without_oscillating() {
        for (start, target_s) in [(1.0f32, 3.0f64), (8.0, 1.5), (2.0, 2.0), (0.6, 20.0)] {
            let c = 1e6 * target_s * target_s; // target reached at s = target_s
            let mut controller = BudgetController::new(1_000_000, start);
            let trace = run_budget(c, 2.0, &mut controller, 120);
            let last = *trace.last().unwrap();
            assert!((f64::from(last) / target_s - 1.0).abs() < 0.03, "start {start}: ended at {last}, want {target_s}");
            // Monotone towards the target: never overshoots, never turns back.
            let up = target_s > f64::from(start);
            for pair in trace.windows(2) {
                assert!(if up { pair[1] >= pair[0] } else { pair[1] <= pair[0] }, "start {start}: {trace:?}");
            }
            // Settled: the last 60 frames do not move at all.
            assert!(trace[60..].iter().all(|&s| s == last), "start {start}: {trace:?}");
        }
    }

    #[test]
    fn budget_converges_for_steeper_and_flatter_scenes() {
        for exponent in [1.0, 3.0] {
            let target_s = 3.0f64;
            let c = 1e6 * target_s.powf(exponent);
            let mut controller = BudgetController::new(1_000_000, 1.0);
            let trace = run_budget(c, exponent, &mut controller, 200);
            let last = *trace.last().unwrap();
            let primitives = c / f64::from(last).powf(exponent);
            assert!((primitives / 1e6 - 1.0).abs() <= 0.05 + 1e-9, "exponent {exponent}: {trace:?}");
            let changes = trace.windows(3).filter(|w| (w[1] - w[0]) * (w[2] - w[1]) < 0.0).count();
            assert_eq!(changes, 0, "exponent {exponent}: turned back: {trace:?}");
            assert!(trace[100..].iter().all(|&s| s == last));
        }
    }

    /// A policy scene: 100 far trees whose cost falls in steps as the target grows (the point
    /// tree, then ellipsoids, then crossed quads), and near trees whose cut falls as `1/s_min²`.
    fn policy_scene(s_min: f32, target: f32) -> u64 {
        let far = if target < 0.004 {
            20_000.0
        } else if target < 0.02 {
            600.0
        } else {
            3.0
        };
        (100.0 * far + 3e6 / f64::from(s_min).powi(2)).round() as u64
    }

    #[test]
    fn policy_budget_meets_the_count_by_moving_the_target_and_s_min_together() {
        for budget in [200_000u64, 1_000_000, 6_000_000] {
            let mut controller = BudgetController::for_policy(budget, 1.0, Policy::DEFAULT_TARGET);
            let (mut s, mut t) = (1.0, controller.target());
            let mut trace = Vec::new();
            for _ in 0..200 {
                (s, t) = controller.update_policy(policy_scene(s, t));
                trace.push((s, t));
            }
            let primitives = policy_scene(s, t);
            let ratio = primitives as f64 / budget as f64;
            assert!((ratio - 1.0).abs() <= 0.05, "budget {budget}: {primitives} after {trace:?}");
            // Settled: the last 100 frames do not move.
            assert!(trace[100..].iter().all(|&p| p == (s, t)), "budget {budget}: {trace:?}");
            // Over the starting count both knobs went up, under it both went down.
            let start = policy_scene(1.0, Policy::DEFAULT_TARGET);
            if budget < start {
                assert!(s > 1.0 && t > Policy::DEFAULT_TARGET, "budget {budget}: {s} {t}");
            } else {
                assert!(s < 1.0 && t < Policy::DEFAULT_TARGET, "budget {budget}: {s} {t}");
            }
        }
    }

    /// `frames` frames of a scene whose count is `scene` of the policy target, steered by
    /// `controller` from target `t`: the counts, and the target after the last frame.
    fn run_policy_scene(
        controller: &mut BudgetController,
        mut t: f32,
        scene: impl Fn(f32) -> u64,
        frames: usize,
    ) -> (Vec<u64>, f32) {
        let mut counts = Vec::with_capacity(frames);
        for _ in 0..frames {
            counts.push(scene(t));
            t = controller.update_policy(scene(t)).1;
        }
        (counts, t)
    }

    #[test]
    fn policy_budget_settles_under_the_budget_where_the_count_jumps_across_it() {
        // Every tree switches at one target: 65k primitives below it, 37k above; a budget
        // between them cannot be met, and must not be flickered across.
        let scene = |t: f32| if t < 0.02 { 65_000 } else { 37_000 };
        let mut controller = BudgetController::for_policy(45_000, 1.0, Policy::DEFAULT_TARGET);
        let start = controller.target();
        let (counts, t) = run_policy_scene(&mut controller, start, scene, 100);
        assert!(counts[40..].iter().all(|&c| c == 37_000), "settled under the budget: {counts:?}");
        assert!(t < 0.021, "at the least target seen under the budget: {t}");
        // The scene gets cheaper (the camera moved): the count falls while the steering holds,
        // so the bounds are dropped and the new cheap count is met.
        let scene = |t: f32| if t < 0.005 { 44_000 } else { 20_000 };
        let (counts, _) = run_policy_scene(&mut controller, t, scene, 60);
        assert_eq!(*counts.last().unwrap(), 44_000, "{counts:?}");
    }

    /// Frames over twice the budget of 100,000 among `counts`.
    fn cliff_frames(counts: &[u64]) -> usize {
        counts.iter().filter(|&&c| c > 200_000).count()
    }

    #[test]
    fn policy_budget_steps_back_from_a_cliff_and_holds() {
        // Every tree switches to a representation of many primitives below one target: 1,000
        // primitives above it, 10 million below, against a budget of 100,000. Lowering the
        // target to spend the budget meets the cliff once; halving the gap would meet it again
        // at each halving.
        let cliff = 0.004;
        let scene = |t: f32| if t < cliff { 10_000_000 } else { 1_000 };
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        let start = controller.target();
        let (counts, t) = run_policy_scene(&mut controller, start, scene, RETRY_FRAMES as usize);
        let over: Vec<usize> = (0..counts.len()).filter(|&i| counts[i] > 200_000).collect();
        assert_eq!(over.len(), 1, "one frame over the cliff: {counts:?}");
        assert!(counts[over[0] + 1..].iter().all(|&c| c == 1_000), "held above it: {counts:?}");
        assert!(t >= cliff && t < cliff * 1.6, "at the least target seen under the budget: {t}");
        // The scene does not change: after `RETRY_FRAMES` of holding, the steering tries below
        // the hold once (the cliff might have moved), meets it, and holds twice as long.
        let (counts, held) = run_policy_scene(&mut controller, t, scene, 2 * RETRY_FRAMES as usize);
        assert_eq!(cliff_frames(&counts), 1, "tried again once: {counts:?}");
        assert_eq!(held, t, "back at the same hold");
        // The cliff moved lower: the next try finds the budget between, and meets the cliff
        // (now lower) once more and no more.
        let cliff = 0.001;
        let scene = |t: f32| if t < cliff { 10_000_000 } else { 1_000 };
        let (counts, t) = run_policy_scene(&mut controller, t, scene, 3 * RETRY_FRAMES as usize);
        assert_eq!(cliff_frames(&counts), 1, "{counts:?}");
        assert!(t >= cliff && t < 0.004, "tried again below the old hold: {t}");
        // A step of less than twice the budget is still halved to settle under it (above,
        // `policy_budget_settles_under_the_budget_where_the_count_jumps_across_it`).
    }

    #[test]
    fn policy_budget_holds_a_cliff_until_the_scene_is_cheap_enough_to_try_again() {
        let cliff = 0.004;
        let held = |cheap: u64, below: u64| {
            let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
            let start = controller.target();
            let scene = |t: f32| if t < cliff { 10_000_000 } else { 1_000 };
            let (counts, t) = run_policy_scene(&mut controller, start, scene, 20);
            assert_eq!(cliff_frames(&counts), 1, "{counts:?}");
            let scene = |t: f32| if t < cliff { below } else { cheap };
            run_policy_scene(&mut controller, t, scene, 30)
        };
        // Trees leave the view: the count at the hold falls by 6 %, a fall past the dead band,
        // which would drop the bounds of any other hold. The frame below it would still be
        // 9.4 million: held, no cliff met again.
        let (counts, _) = held(940, 9_400_000);
        assert!(counts.iter().all(|&c| c == 940), "{counts:?}");
        // A fall to a hundredth: the cliff's 10 million would be 100,000 now, no cliff. The hold
        // is released at once, and the budget spent below it.
        let (counts, _) = held(10, 90_000);
        assert_eq!(cliff_frames(&counts), 0, "{counts:?}");
        assert_eq!(counts.last(), Some(&90_000), "{counts:?}");
    }

    #[test]
    fn policy_budget_refuses_a_predicted_cliff_and_closes_in_on_it_undrawn() {
        // The cliff of `policy_budget_steps_back_from_a_cliff_and_holds`, with a host that
        // predicts each step down (here exactly) and refuses one that would be a cliff.
        let cliff = 0.004;
        let scene = |t: f32| if t < cliff { 10_000_000 } else { 1_000 };
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        let mut t = controller.target();
        let (mut counts, mut refused) = (Vec::new(), 0);
        for _ in 0..100 {
            counts.push(scene(t));
            controller.update_policy(scene(t));
            if controller.steps_down_from(t) && scene(controller.target()) > controller.cliff_count() {
                controller.refuse();
                refused += 1;
            }
            t = controller.target();
        }
        assert_eq!(cliff_frames(&counts), 0, "no frame drawn over the cliff: {counts:?}");
        assert!(refused >= 2, "the steps down were refused and halved: {refused}");
        // Closer to the cliff than the pressure's resolution (4 % in the target) allows telling.
        assert!(t >= cliff && t < cliff * 1.05, "closed in on the cliff: {t}");
        assert!(counts[50..].iter().all(|&c| c == 1_000), "{counts:?}");
        // Without a frame given yet, refusing changes nothing.
        let mut fresh = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        assert_eq!(fresh.refuse(), (1.0, Policy::DEFAULT_TARGET));
    }

    #[test]
    fn policy_budget_starts_at_the_least_pressure_predicted_within_the_budget() {
        // A scene whose count falls as the target rises, 20 times the budget at the start.
        let scene = |_: f32, t: f32| (2_000_000.0 * Policy::DEFAULT_TARGET / t) as u64;
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        assert!(controller.awaits_first_frame());
        let mut predictions = 0;
        let (_, t) = controller.start_within(|s, t| {
            predictions += 1;
            scene(s, t)
        });
        assert!(scene(0.0, t) <= 100_000, "within the budget: {t}");
        // The least such pressure to within half a largest step (×1.25² in the target).
        assert!(scene(0.0, t / 1.25) > 100_000, "no higher than it needs: {t}");
        assert!(predictions <= 8, "{predictions} predictions");
        // The frames drawn from there close in on the budget, and hold within its dead band.
        let counts: Vec<u64> = (0..30)
            .map(|_| {
                let count = scene(controller.s_min(), controller.target());
                controller.update_policy(count);
                count
            })
            .collect();
        assert!(counts.iter().all(|&c| c <= 100_000), "{counts:?}");
        assert!(counts[10..].iter().all(|&c| c >= 90_000), "{counts:?}");
        assert!(!controller.awaits_first_frame());
        // Once a frame is given, nothing is predicted and nothing moves.
        let before = (controller.s_min(), controller.target());
        assert_eq!(controller.start_within(|_, _| panic!("predicted after the first frame")), before);

        // A scene within the budget at the start: one prediction, no move.
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        let mut predictions = 0;
        let start = controller.start_within(|_, _| {
            predictions += 1;
            50_000
        });
        assert_eq!((start, predictions), ((1.0, Policy::DEFAULT_TARGET), 1));
        // A scene over the budget however coarse: the coarsest steering.
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        let (s, t) = controller.start_within(|_, _| 1_000_000);
        assert_eq!((s, t), (controller.s_min_ceiling, controller.target_ceiling), "the coarsest");
    }

    #[test]
    fn policy_budget_raises_a_frame_predicted_over_a_cliff_before_it_is_drawn() {
        // Settled on a scene, the camera moves to one that costs 3 times as much at every
        // target (near trees' chain levels follow `s_min`).
        let scene = |t: f32, scale: f64| (scale * 2_000_000.0 * f64::from(Policy::DEFAULT_TARGET / t)) as u64;
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        controller.start_within(|_, t| scene(t, 1.0));
        for _ in 0..30 {
            controller.update_policy(scene(controller.target(), 1.0));
        }
        let settled = controller.target();
        assert!(scene(settled, 3.0) > controller.cliff_count(), "the move meets a cliff");
        let mut predictions = 0;
        let (_, t) = controller.raise_within(|_, t| {
            predictions += 1;
            scene(t, 3.0)
        });
        assert!(scene(t, 3.0) <= 100_000, "raised within the budget: {settled} → {t}");
        assert!(scene(t / 1.25, 3.0) > 100_000, "no higher than it needs: {t}");
        assert!(predictions <= 6, "a step or two over costs few predictions: {predictions}");
        // The frames drawn from there close in on the budget without crossing the cliff, nor
        // stepping back down to the pressure predicted over (it counts as over).
        for _ in 0..30 {
            let t = controller.target();
            assert!(t > settled && scene(t, 3.0) <= controller.cliff_count(), "{t} after {settled}");
            controller.update_policy(scene(t, 3.0));
        }
    }

    #[test]
    fn a_raise_after_a_search_down_goes_back_no_further_than_the_pressure_drawn() {
        let mut controller = BudgetController::for_policy(100_000, 1.0, 0.1);
        // A frame far under the budget at target 0.1, then a search down: the scene predicted
        // within the budget down to target 0.02, a cliff below it.
        controller.update_policy(1_000);
        let drawn = 0.1f32;
        let (_, lowered) = controller.lower_within(|_, t| if t >= 0.02 { 90_000 } else { 10_000_000 });
        assert!((0.02..0.021).contains(&lowered), "{lowered}");
        // The camera moves before the next frame: the lowered target is predicted over 1.1 times
        // the budget, a target of 0.05 or more within it.
        let moved = |t: f32| if t < 0.05 { 150_000 } else { 60_000 };
        let (_, raised) = controller.raise_within(|_, t| moved(t));
        // Back to the edge to the search down's bracket (0.5 % in `s_min`, 1 % in the target),
        // never past the target drawn: a raise by half a largest step from 0.02 at a time
        // (×1.25 in the target) would have stopped up to a quarter above it.
        assert!(moved(raised) <= 100_000 && raised <= 0.05 * 1.011 && raised <= drawn, "{raised}");
        // Where even the target drawn is predicted over, the raise goes on past it as before.
        let mut controller = BudgetController::for_policy(100_000, 1.0, 0.1);
        controller.update_policy(1_000);
        controller.lower_within(|_, t| if t >= 0.02 { 90_000 } else { 10_000_000 });
        let (_, raised) = controller.raise_within(|_, t| if t < 0.3 { 150_000 } else { 60_000 });
        assert!(raised >= 0.3, "{raised}");
    }

    #[test]
    fn policy_budget_lowers_a_frame_far_under_the_budget_to_the_least_pressure_predicted_within_it() {
        // At the coarsest steering, a scene whose count falls as the target rises draws 2,000
        // primitives against a budget of 100,000.
        let scene = |t: f32| (200_000.0 * Policy::DEFAULT_TARGET / t) as u64;
        let mut controller = BudgetController::for_policy(100_000, 1.0, 1.0);
        assert!(controller.far_under(scene(controller.target())) && !controller.far_under(50_000));
        controller.update_policy(scene(controller.target()));
        let stepped = controller.target();
        let mut predictions = 0;
        let (_, t) = controller.lower_within(|_, t| {
            predictions += 1;
            scene(t)
        });
        assert!(t < stepped / 10.0, "on down, not one step: {stepped} → {t}");
        assert!(scene(t) <= 100_000, "within the budget: {t}");
        // The least such pressure to within 0.5 % in `s_min` (×1.005² in the target).
        assert!(scene(t / 1.005f32.powi(2)) > 100_000, "no higher than it needs: {t}");
        assert!(predictions <= 14, "{predictions} predictions");
        // The pressure predicted over counts as over: the frames from there do not cross it.
        for _ in 0..30 {
            let t = controller.target();
            controller.update_policy(scene(t));
            assert!(scene(controller.target()) <= 100_000, "{t} → {}", controller.target());
        }

        // A hold next to a cliff whose scene changed: 1,000 primitives above the cliff (a count
        // that cannot fall, which is what releases a hold), 10 million below it.
        let cliff = |at: f32| move |t: f32| if t < at { 10_000_000 } else { 1_000 };
        let first = cliff(0.05);
        let mut controller = BudgetController::for_policy(100_000, 1.0, 1.0);
        for _ in 0..40 {
            controller.update_policy(first(controller.target()));
        }
        let held = controller.target();
        assert!(held >= 0.05 && first(held) == 1_000, "held above the cliff: {held}");
        controller.update_policy(first(held));
        assert_eq!(controller.target(), held, "the hold lasts");
        // The cliff moves down fifty times (the camera moved away): the hold is stale.
        let moved = cliff(0.001);
        let (_, t) = controller.lower_within(|_, t| moved(t));
        assert!(t < held / 10.0 && moved(t) == 1_000, "below the hold, above the new cliff: {held} → {t}");
        for _ in 0..30 {
            controller.update_policy(moved(controller.target()));
            assert_eq!(moved(controller.target()), 1_000, "no frame drawn over the new cliff");
        }

        // Where every pressure below is predicted over the budget, nothing moves: a largest step,
        // then its halves down to the resolution, are predicted (the end within the budget is the
        // frame drawn, far under it, so `CLIFF_RESOLUTION`: ln 1.25 ≈ 0.223 halved nine times
        // to 0.00044).
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        let before = (controller.s_min(), controller.target());
        let mut predictions = 0;
        let after = controller.lower_within(|_, _| {
            predictions += 1;
            1_000_000
        });
        assert_eq!((after, predictions), (before, 10));
    }

    #[test]
    fn policy_budget_lowers_to_a_narrow_step_above_a_cliff() {
        // A far forest of one quad a tree, drawn at 800 primitives: a share of the trees moves
        // to the next lattice target with each step of the target, and a few of them switching
        // from the quad to a tree of tens of thousands of primitives take the count to 75,000
        // within 0.3 % of the target, and to 300,000 below (the shared jacaranda's forest).
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        controller.update_policy(800);
        let edge = controller.target() * 0.95;
        let scene = move |t: f32| match t {
            t if t >= edge => 800,
            t if t >= edge * 0.997 => 75_000,
            _ => 300_000,
        };
        let mut predictions = 0;
        let (_, t) = controller.lower_within(|_, t| {
            predictions += 1;
            scene(t)
        });
        // A bracket closed to `LOWER_RESOLUTION` (1 % in the target) stops on either side of the
        // step; closed on to `CLIFF_RESOLUTION` while its end within the budget is far under it,
        // on the step.
        assert_eq!(scene(t), 75_000, "on the step: target {t}, edge {edge}");
        assert!(predictions <= 12, "{predictions} predictions");
        // A smooth count stops at `LOWER_RESOLUTION` as before: the end within the budget is not
        // far under it once the bracket is closed.
        let smooth = |t: f32| (2_000.0 * Policy::DEFAULT_TARGET / t) as u64 * 50;
        let mut controller = BudgetController::for_policy(100_000, 1.0, 1.0);
        controller.update_policy(smooth(controller.target()));
        let mut gaps = Vec::new();
        let mut last = None;
        controller.lower_within(|_, t| {
            if let Some(l) = last {
                gaps.push(f64::from(t / l).ln().abs() / 2.0);
            }
            last = Some(t);
            smooth(t)
        });
        let closest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(closest > 0.5 * LOWER_RESOLUTION * 0.99, "no halving past the resolution: {closest}");
    }

    #[test]
    fn policy_budget_lowers_to_a_step_just_above_a_cliff() {
        // A forest seen from afar, held far under the budget: 37,000 primitives, 91,700 at
        // `s_min` 3 % lower, and past 10 % lower a cliff of millions (many trees switch at once).
        let scene = |s: f32| match s {
            s if s >= 0.99 => 37_000,
            s if s >= 0.90 => 91_700,
            _ => 4_600_000,
        };
        let mut controller = BudgetController::for_policy(100_000, 1.0, Policy::DEFAULT_TARGET);
        // One largest step down meets the cliff; the steering goes back and holds.
        controller.update_policy(scene(controller.s_min()));
        assert!(controller.s_min() < 0.9);
        controller.update_policy(scene(controller.s_min()));
        controller.update_policy(scene(controller.s_min()));
        assert_eq!(controller.s_min(), 1.0, "held above the cliff");
        assert!(controller.far_under(37_000));
        let (s, _) = controller.lower_within(|s, _| scene(s));
        // A search to half a largest step (×1.25^½ ≈ 1.12 in `s_min`) stops at 37,000: the
        // first step down meets the cliff, its half is over it too.
        assert_eq!(scene(s), 91_700, "down to the step within the budget: s_min {s}");
        for _ in 0..30 {
            controller.update_policy(scene(controller.s_min()));
            assert_eq!(scene(controller.s_min()), 91_700, "the frames hold there: {}", controller.s_min());
        }
    }

    #[test]
    fn policy_budget_clamps_the_target() {
        let mut controller = BudgetController::for_policy(10, 1.0, 0.0);
        assert_eq!(controller.target(), controller.target_floor, "a target of 0 starts at the floor");
        assert!(!controller.at_finest(), "s_min 1 is above its floor: there is finer to go");
        let (_, t) = controller.update_policy(1_000);
        assert!((t / controller.target_floor - 1.5625).abs() < 1e-4, "one step, squared: {t}");
        for _ in 0..200 {
            controller.update_policy(1_000_000);
        }
        assert_eq!(controller.target(), 1.0);
        assert!(!controller.at_finest());
        for _ in 0..200 {
            controller.update_policy(0);
        }
        assert_eq!(controller.target(), 1.0 / 1024.0);
        assert_eq!(controller.s_min(), controller.s_min_floor);
        assert!(controller.at_finest(), "both at their floors: nothing finer to draw");
        assert_eq!(BudgetController::for_policy(10, 1.0, f32::NAN).target(), 1.0);
    }

    #[test]
    fn budget_respects_the_clamps_and_the_step_limit() {
        let mut controller = BudgetController::new(1000, 4.0);
        let s = controller.update(1_000_000_000);
        assert!((s - 5.0).abs() < 1e-5, "one step of at most 1.25×: {s}");
        for _ in 0..100 {
            controller.update(1_000_000_000);
        }
        assert_eq!(controller.s_min(), 64.0);
        for _ in 0..100 {
            controller.update(0);
        }
        assert_eq!(controller.s_min(), 0.5);
        let mut settings = LodSettings { s_min: 2.0, s_max: 6.0, ..LodSettings::default() };
        let mut controller = BudgetController::new(1000, 2.0);
        controller.apply(4000, &mut settings);
        assert!(settings.s_min > 2.0 && (settings.s_max / settings.s_min - 3.0).abs() < 1e-5);
    }
}
