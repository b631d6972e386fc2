//! The renderer: models uploaded from containers, instances, per-frame selection into indirect
//! draws, and the draws themselves inside the host's render pass.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3, Vec4};
use treelod_format::{Container, MaterialRecord, NO_IMAGE, PointRecord, TriangleRecord, material_class};
use treelod_runtime::prune::{MIN_VISIBLE_FRACTION, leaf_scale, leaves_drawn, projected_height, size_factor};
use treelod_runtime::spt_lod::PixelLevel;
use treelod_runtime::{
    BillboardKind, Billboards, CellPrefix, DrawList, DrawRange, EllipsoidLod, EllipsoidRange, Frustum, Hysteresis,
    Kind, LineLod, LineRange, LodChain, LodSettings, ModelLod, PlaneLod, PlaneRange, PruneLod, PruneScale, ROOTS_CELL,
    instance_tau, select_frame,
};

use crate::camera::Camera;
use crate::gpu_select::{GpuSelection, select_frame_gpu};
use crate::occlusion::{Job, Occlusion};
use crate::shadows::{Cascade, MAX_CASCADES, SHADOW_FORMAT, ShadowMaps, ShadowUniform, Shadows, fit_cascades};
use crate::streaming::{Array, Pool, Request, Residency, UNIT, Upload};
use crate::textures;

/// WGSL of the pipelines: the record structs, the draw constants, then the tree shader.
const SHADER: &str = concat!(
    include_str!("../../../shaders/shared/records.wgsl"),
    include_str!("../../../shaders/shared/draw.wgsl"),
    include_str!("../../../shaders/shared/shadow.wgsl"),
    include_str!("../../../shaders/tree.wgsl")
);

/// The target formats of the host's render pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RendererFormats {
    /// Colour attachment format.
    pub color: wgpu::TextureFormat,
    /// Depth attachment format (depth-tested, depth-written).
    pub depth: wgpu::TextureFormat,
    /// MSAA samples of both attachments (1 for none). With more than one, alpha-tested leaves
    /// write a sample mask from their filtered alpha where their texture is minified (alpha to
    /// coverage), keeping a distant canopy's density; the host resolves the colour target.
    pub sample_count: u32,
}

/// Which way the host's depth buffer runs: the depth test of the pipelines drawing into it, fixed
/// when the [`Renderer`] is made ([`Renderer::with_depth_convention`]).
///
/// The depth written is always the camera projection's `z / w`, so the projection decides the
/// values ([`Camera::proj`](crate::Camera::proj)); the convention says which of two depths is
/// nearer. Neither the shadow maps (the renderer's own) nor selection depend on it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum DepthConvention {
    /// 0 at the near plane, 1 at the far plane: the host clears depth to 1, and a fragment is
    /// kept where its depth is `Less` than the buffer's. What
    /// [`Camera::look_at`](crate::Camera::look_at) projects to, and [`Renderer::new`]'s.
    #[default]
    Standard,
    /// Reverse Z: 1 at the near plane, 0 at the far plane (or at infinity), for depth precision
    /// far away, as Bevy and many engines draw: the host clears depth to 0, and a fragment is
    /// kept where its depth is `Greater` than the buffer's. The camera's projection must map
    /// near to 1.
    Reverse,
}

impl DepthConvention {
    /// The depth test that keeps the nearer of two fragments.
    #[must_use]
    pub fn compare(self) -> wgpu::CompareFunction {
        match self {
            Self::Standard => wgpu::CompareFunction::Less,
            Self::Reverse => wgpu::CompareFunction::Greater,
        }
    }

    /// The depth a buffer is cleared to: the far end of the range.
    #[must_use]
    pub fn far(self) -> f32 {
        match self {
            Self::Standard => 1.0,
            Self::Reverse => 0.0,
        }
    }
}

/// What a frame shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DebugView {
    /// Shaded colours.
    #[default]
    Shaded,
    /// A flat colour per grid cell.
    Cells,
    /// Triangles red, points blue.
    Kinds,
    /// A colour per level: per octave of the end of each point's, plane's, ellipsoid's or line's
    /// interval of `τ` (neighbouring levels differ), triangles light grey, billboards as in
    /// [`Self::Kinds`].
    Levels,
}

/// Level-of-detail and shading settings; change them between frames with [`Renderer::settings_mut`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// `s_min`, pixels: points are drawn down to this projected size (Gilet's point threshold).
    pub s_min: f32,
    /// `s_max`, pixels: triangles projecting larger than this are drawn as triangles.
    pub s_max: f32,
    /// `k`, pixels: Gilet's depth bias, added to both thresholds times `Z_i ∈ [−1, 1]` from the
    /// front to the back of each tree ([`LodSettings::depth_bias_k`]); 0 for none.
    pub depth_bias_k: f32,
    /// `(L_m, L_M)`: Gilet's estimated self-shadowing, a brightness per cell from `L_m` at the
    /// front of each tree to `L_M` at the back as the paper writes it
    /// ([`LodSettings::shading_at`]); `None` for none.
    pub shading: Option<(f32, f32)>,
    /// Scale of the splat radii: 1 draws each point as a disc of the opaque area it stands for.
    pub point_scale: f32,
    /// Draw every triangle and no point: the full mesh, for comparison.
    pub full_mesh: bool,
    /// What to colour by.
    pub debug: DebugView,
    /// Direction towards the sun, world space.
    pub sun: Vec3,
    /// Colour of the sunlight, linear RGB (white: 1, 1, 1), multiplying its diffuse share.
    pub sun_colour: Vec3,
    /// Ambient share of the light, 0..1: a surface receives `ambient + (1 − ambient) · |n·l| ·
    /// sun_colour` of its albedo (both faces lit: leaves are cards).
    pub ambient: f32,
    /// Scale the ambient share by the containers' precomputed ambient occlusion `a` (spec
    /// §6.14), where they have it: `ambient · (1 − a)`. The sun's share is the shadow maps'
    /// business ([`Self::shadows`]).
    pub ambient_occlusion: bool,
    /// Bytes of triangles and points uploaded per frame at most: prefixes grow towards the
    /// selection by this much each frame, emptiest cells first.
    pub upload_budget: u64,
    /// Bytes of GPU memory for streamed triangles and points (fixed at [`Renderer::new`], and
    /// capped there by the device's storage-binding limit). When full, the finest halves of the
    /// least recently needed cells' prefixes are evicted.
    pub memory_budget: u64,
    /// Draw near trees with pruned leaves (Neubert et al. 2011) where their containers have
    /// priority lists; `None` draws every tree with the sequential point trees.
    pub pruning: Option<Pruning>,
    /// Draw the leaves of every tree whose container has impostor planes (Garcia et al. 2005,
    /// spec §6.10) as those planes, and its bark as [`Self::impostor_bark`] says. The level of
    /// planes is the
    /// one whose interval holds `τ` from [`Self::s_min`] pixels at the block centre's distance,
    /// as the point thresholds are chosen (spec §10.1). Trees without planes are drawn with the
    /// sequential point trees. Takes precedence over [`Self::pruning`].
    pub impostors: bool,
    /// With [`Self::impostors`]: smooth changes of level. Garcia's interpolation of the planes:
    /// over the last octave of each plane's interval its corners slide onto the plane of the next
    /// coarser level, which takes over where they arrive ([`treelod_runtime::morph_share`]), so a
    /// change of level moves no leaf. And a cross-fade of the textures: over the last quarter of
    /// the interval the plane and its parent are drawn on complementary dithered pixels
    /// ([`treelod_runtime::crossfade`]). `false` switches levels at once.
    pub impostor_morph: bool,
    /// With [`Self::impostors`]: the bark drawn beside the planes.
    pub impostor_bark: ImpostorBark,
    /// Draw the leaves of every tree whose container has Clasen's ellipsoids (spec §6.8) as those
    /// ellipsoids, ray-cast per pixel with their noise, and its bark as Clasen's lines (spec §6.9,
    /// [`Self::lines`]) where the container has them, else as triangles (every bark triangle, as
    /// [`ImpostorBark::All`]). Per cell, the level drawn is the one whose interval holds `τ`, the
    /// metres per pixel at the cell's distance (the point threshold's `τ_p / s_min`, Gilet's depth
    /// bias included) divided by [`Self::ellipsoid_quality`], blended with the next over
    /// [`Self::level_blend`]; lines use the same `τ`. Takes precedence over
    /// [`Self::impostors`] (a tree with both is drawn with ellipsoids, one with planes only with
    /// planes) and [`Self::pruning`]; [`Self::baseline`] takes precedence over it. Selected on the
    /// CPU (GPU selection is not used for such frames).
    pub ellipsoids: bool,
    /// With [`Self::ellipsoids`]: the user's quality factor `q`, `τ = mpp / q` (1: the level the
    /// build chose for the pixel size; 2: the level for pixels half as large, finer).
    pub ellipsoid_quality: f32,
    /// With [`Self::ellipsoids`]: `β`, octaves of `τ` over which ellipsoids and lines blend from
    /// one level to the next instead of switching at once (Clasen 2011 §5: the levels are close
    /// enough for image-space blending). An element of interval `[lo, hi)` fades in over `β`
    /// octaves centred on `lo` and out over `β` octaves centred on `hi`: it is drawn on the share
    /// `clamp(log2(τ/lo)/β + ½, 0, 1) · clamp(log2(hi/τ)/β + ½, 0, 1)` of its pixels (no fade at
    /// `lo = 0` or `hi = ∞`), chosen by a per-pixel dither of the cell and instance that is the
    /// same for both levels at a boundary (the samples of each pixel with MSAA), so each pixel
    /// shows exactly one of them: no doubled density, no holes
    /// ([`treelod_runtime::spt_lod::level_keep`]). Exact where adjacent boundaries are at least
    /// `β` octaves apart. The prefix drawn holds the records with `hi > τ · 2^(−β/2)`. Colour and
    /// shadow passes alike. 0 switches at once; clamped to `[0, 2]` (not finite: 0). Default 0.5.
    pub level_blend: f32,
    /// With [`Self::ellipsoids`]: draw the bark of ellipsoid trees as Clasen's lines when the
    /// container has them (spec §6.9); `false`: bark triangles. Each line is a round cone (a
    /// capsule whose radius goes linearly from `r0` to `r1`), ray-cast per pixel with its exact
    /// depth. Lines thinner than a pixel (Clasen's build aims at a mean width of one) are drawn
    /// one pixel wide, which leaves no gaps along them, covering the share of each pixel their
    /// true width `w < 1` px asks for: `w` of the samples with MSAA, else of the pixels (a hash of
    /// pixel and depth), at the depth of their axis.
    pub lines: bool,
    /// Draw every tree whose container has this baseline (spec §6.12, §6.13) with it instead of
    /// treelod's representations, for comparisons; trees without it are drawn with the sequential
    /// point trees. Takes precedence over [`Self::impostors`] and [`Self::pruning`].
    pub baseline: Option<Baseline>,
    /// Cascaded shadow maps of the sun ([`Shadows`]); `None` for none. With shadows, each frame
    /// also selects every cascade from the light's view (on the CPU, also when GPU selection is
    /// on) and [`Renderer::render_shadows`] draws them before the host's pass.
    pub shadows: Option<Shadows>,
    /// Without MSAA: an alpha-tested fragment whose texture is minified (a texel under a pixel)
    /// is kept where its filtered alpha — the share of its footprint the leaf covers — exceeds a
    /// hash of the pixel and depth, as the shadow pass keeps it, instead of where it passes the
    /// material's cutoff. The plain test drops every texel less than half covered, so a canopy of
    /// thin leaves thins out and vanishes with distance; this one keeps its density (expected
    /// coverage exact; overlapping leaves at other depths independent) at the cost of noise that
    /// changes as the camera moves, which a temporal anti-aliasing pass averages (with MSAA, alpha
    /// to coverage does the same per sample without it). `eval` draws its reference so. Default
    /// off.
    pub stochastic_alpha: bool,
}

/// The bark of a tree drawn with impostor planes ([`Settings::impostor_bark`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ImpostorBark {
    /// Every bark triangle (the paper keeps the trunk polygonal).
    All,
    /// Where the container has a LoD chain (spec §6.12, built with `--baselines`), the bark of
    /// its coarsest level whose error projects below half of [`Settings::s_min`] pixels (`τ` as
    /// for the planes' level, at the block centre) among the levels whose bark keeps 90 % of the
    /// full bark's area; every bark triangle nearer than the finest level allows, or without a
    /// chain. The chain's error is where the surface moves, not what it covers: thin branches
    /// collapse into slivers at a small error, hence the area guard. Measured against the full
    /// mesh at 320×240 (recall of the image, all bark → chain): the maple draws 247270 of its
    /// 498464 bark triangles from 2 bounding radii on, 1.00 → 0.97 (2 radii), 0.96 (8); the oak
    /// 2835 of 12006 from 32 radii on, unchanged. Without the guard the maple's coarsest level
    /// (4963) would be drawn, at 0.77 and 0.83.
    #[default]
    Chain,
}

/// A baseline a user would draw instead of treelod ([`Settings::baseline`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Baseline {
    /// The discrete level-of-detail chain of a general mesh simplifier (spec §6.12): per
    /// instance the coarsest level whose error projects below [`Settings::s_min`] pixels, the
    /// full mesh nearer than the finest level's distance.
    LodChain,
    /// Billboards (spec §6.13): one quad per tree turned towards the camera, or fixed crossed
    /// quads.
    Billboard(BillboardKind),
}

/// Pruning settings: which trees are pruned, by how much, and how survivors are scaled.
///
/// A pruned tree draws every bark triangle of its container and, of each cell's leaf priority
/// list, the first `ceil(λ·count)` leaves, scaled about their centres (spec §6.11). `λ` is the
/// container's `λ(h)` at the tree's projected height `h` (or [`Self::lambda`]), times
/// `max(f, 0.1)` with `f` the visible fraction of the tree's hull samples measured by
/// [`Renderer::measure_occlusion`] on an earlier frame, then held by [`Self::hysteresis`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pruning {
    /// How survivors are scaled: `s_opt(λ)` from the container, Cook's `1/λ`, or not at all.
    pub scale: PruneScale,
    /// A fixed `λ` for every pruned tree instead of the container's `λ(h)` (for comparisons).
    pub lambda: Option<f32>,
    /// Multiply `λ` by the trees' measured visible fraction (needs
    /// [`Renderer::measure_occlusion`] each frame; without measurements every tree counts as
    /// visible).
    pub occlusion: bool,
    /// Hold `λ` while its target stays within a band, so it does not flicker.
    pub hysteresis: Hysteresis,
    /// Trees projecting fewer pixels high than this are drawn with the sequential point tree
    /// instead (pruning is the near-to-mid-field representation); 0 prunes every tree.
    pub spt_below_pixels: f32,
}

impl Default for Pruning {
    /// `s_opt`, `λ(h)` from the container, occlusion on, ±10 % hysteresis, trees below 64 pixels
    /// high by the sequential point tree.
    fn default() -> Self {
        Self {
            scale: PruneScale::Optimal,
            lambda: None,
            occlusion: true,
            hysteresis: Hysteresis::default(),
            spt_below_pixels: 64.0,
        }
    }
}

impl Settings {
    /// How ellipsoids and lines pick their levels: [`Self::ellipsoid_quality`] and
    /// [`Self::level_blend`].
    fn pixel_level(&self) -> PixelLevel {
        PixelLevel { quality: self.ellipsoid_quality, blend: self.level_blend }
    }
}

impl Default for Settings {
    /// One-pixel points, triangles above two pixels, light from above and the side.
    fn default() -> Self {
        Self {
            s_min: 1.0,
            s_max: 2.0,
            depth_bias_k: 0.0,
            shading: None,
            point_scale: 1.0,
            full_mesh: false,
            debug: DebugView::Shaded,
            sun: Vec3::new(0.4, 0.8, 0.45),
            sun_colour: Vec3::ONE,
            ambient: 0.35,
            ambient_occlusion: true,
            upload_budget: 64 << 20,
            memory_budget: 1 << 30,
            pruning: None,
            impostors: false,
            impostor_morph: true,
            impostor_bark: ImpostorBark::default(),
            ellipsoids: false,
            ellipsoid_quality: 1.0,
            level_blend: 0.5,
            lines: true,
            baseline: None,
            shadows: None,
            stochastic_alpha: false,
        }
    }
}

/// A model added with [`Renderer::add_model`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ModelId(pub u32);

/// One tree in the world: a model and its world-from-model transform (rotation, translation and a
/// uniform scale).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// The model.
    pub model: ModelId,
    /// World from model.
    pub transform: Mat4,
}

/// What [`Renderer::prepare`] selected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// Instances inside the view frustum.
    pub instances_visible: u32,
    /// Indirect draws recorded (one per non-empty range).
    pub ranges: u32,
    /// Draws made coarser than the selection because their prefix is not resident yet.
    pub ranges_clamped: u32,
    /// Triangles submitted.
    pub triangles: u64,
    /// Points submitted (the prefix; the vertex shader drops those outside the cut).
    pub points: u64,
    /// Bytes of model data on the GPU: vertices, materials and images of every model, and the
    /// streamed prefixes and roots in use.
    pub bytes_resident: u64,
    /// Bytes of triangles and points uploaded by this frame.
    pub bytes_uploaded: u64,
    /// Visible instances drawn with pruned leaves ([`Settings::pruning`]).
    pub instances_pruned: u32,
    /// Leaves drawn by pruned instances (their triangles count in [`Self::triangles`]).
    pub leaves_pruned: u64,
    /// Visible instances drawn with impostor planes ([`Settings::impostors`]).
    pub instances_impostors: u32,
    /// Impostor planes submitted (the prefixes; the vertex shader drops those outside the level).
    pub planes: u64,
    /// Visible instances drawn with ellipsoids ([`Settings::ellipsoids`]).
    pub instances_ellipsoids: u32,
    /// Ellipsoids submitted (the prefixes; the vertex shader drops those outside the level).
    pub ellipsoids: u64,
    /// Branch lines submitted by ellipsoid trees ([`Settings::lines`]; the prefixes; the vertex
    /// shader drops those outside the level).
    pub lines: u64,
    /// Visible instances drawn with a baseline ([`Settings::baseline`]).
    pub instances_baseline: u32,
    /// Billboard quads submitted (their triangles are not counted in [`Self::triangles`]; LoD
    /// chain triangles are).
    pub billboards: u64,
    /// Whether this frame was selected on the GPU ([`Renderer::enable_gpu_selection`]). Then
    /// [`Self::instances_visible`], [`Self::ranges`], [`Self::triangles`], [`Self::points`] and
    /// [`Self::ranges_dropped`] are those of the latest earlier frame whose counters have been
    /// read back (without waiting: usually one or two frames old, zero before the first),
    /// [`Self::bytes_resident`] is current, and the other fields are zero.
    pub gpu_selection: bool,
    /// GPU selection: ranges selected but not drawn because their bucket was full (the buckets
    /// grow for later frames once the counters are read back).
    pub ranges_dropped: u32,
    /// What the shadow pass draws, all cascades together ([`Settings::shadows`]; zero without).
    pub shadow: ShadowStats,
}

/// What the shadow pass of a frame draws, summed over its cascades (a tree in two cascades
/// counts twice).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadowStats {
    /// Cascades drawn.
    pub cascades: u32,
    /// Instances inside a cascade's frustum, per cascade.
    pub instances_visible: u32,
    /// Indirect draws.
    pub ranges: u32,
    /// Draws made coarser than the cascades' selections because their prefixes are not resident
    /// yet (0 once the cascades' data has streamed in).
    pub ranges_clamped: u32,
    /// Triangles submitted (bark, leaves, pruned leaves, LoD chain levels).
    pub triangles: u64,
    /// Points submitted.
    pub points: u64,
    /// Impostor planes submitted.
    pub planes: u64,
    /// Billboard quads submitted.
    pub billboards: u64,
    /// Ellipsoids submitted.
    pub ellipsoids: u64,
    /// Branch lines submitted.
    pub lines: u64,
}

/// Why a model could not be added.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// An array is larger than the device lets a shader bind.
    #[error("{what} is {bytes} bytes, the device binds at most {limit} bytes per storage buffer")]
    TooLarge {
        /// Which array.
        what: &'static str,
        /// Its size.
        bytes: u64,
        /// The device limit.
        limit: u64,
    },
    /// The memory budget cannot hold the roots every cell keeps resident.
    #[error("the model's roots need {bytes} bytes of a streaming budget of {budget} bytes that is full")]
    Budget {
        /// Bytes needed.
        bytes: u64,
        /// The budget as capped by the device.
        budget: u64,
    },
    /// GPU selection ([`Renderer::enable_gpu_selection`]) keeps every model's triangles and
    /// points resident whole, and they do not fit the memory budget.
    #[error(
        "GPU selection needs {bytes} bytes for the models up to model {model}, the memory budget is {budget} bytes"
    )]
    GpuSelectionBudget {
        /// The first model that does not fit.
        model: u32,
        /// Bytes of the models up to and including it.
        bytes: u64,
        /// [`Settings::memory_budget`] as capped by the device's binding limit.
        budget: u64,
    },
    /// Reading GPU buffers back failed.
    #[error("cannot read the GPU selection back: {0}")]
    Readback(String),
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FrameUniform {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    sun: [f32; 4],
    sun_colour: [f32; 4],
    debug: u32,
    /// 1 with [`Settings::impostor_morph`].
    morph: u32,
    /// 1 with [`Settings::ambient_occlusion`].
    ambient_occlusion: u32,
    /// [`Settings::level_blend`], clamped.
    level_blend: f32,
    /// 1 with [`Settings::stochastic_alpha`].
    stochastic_alpha: u32,
    pad: [u32; 3],
}

/// One draw's constants. WGSL twin: `DrawInfo` in `shaders/tree.wgsl` and `shaders/select.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct DrawInfo {
    pub(crate) model: [[f32; 4]; 4],
    pub(crate) tau_p: f32,
    pub(crate) tau_t: f32,
    pub(crate) cell: u32,
    pub(crate) scale: f32,
    pub(crate) shading: f32,
    /// Size factor of pruned leaves about their centres (1 for everything else).
    pub(crate) leaf_scale: f32,
    /// Index of the instance in [`Renderer::set_instances`]' list (read by the shaders only to
    /// seed the level blend's dither, `level_dither`).
    pub(crate) instance: u32,
    pub(crate) _pad: u32,
}

const _: () = assert!(size_of::<DrawInfo>() == 96);

/// A vertex as the shaders read it: the record, then its ambient occlusion (0 without).
/// WGSL twin: `VertexGpu` in `shaders/tree.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct VertexGpu {
    record: treelod_format::VertexRecord,
    ao: f32,
}

/// Point `index` of `container` as the pool holds it: its `flags` (reserved in the file, spec
/// §6.5) carry its ambient-occlusion byte (§6.14), 0 without.
fn gpu_point(container: &Container, index: usize, point: PointRecord) -> PointRecord {
    PointRecord { flags: container.point_ao().get(index).copied().map_or(0, u32::from), ..point }
}

/// Points `first..` of `container` (`records`) as the pools hold them ([`gpu_point`]): the
/// file's records themselves where they already are (no `POINT_AO` and every reserved `flags` 0,
/// which the shaders would otherwise read as occlusion), else rewritten into `scratch`.
pub(crate) fn gpu_points<'a>(
    container: &Container,
    first: usize,
    records: &'a [PointRecord],
    scratch: &'a mut Vec<PointRecord>,
) -> &'a [PointRecord] {
    if container.point_ao().is_empty() && records.iter().all(|p| p.flags == 0) {
        return records;
    }
    scratch.clear();
    scratch.extend(records.iter().enumerate().map(|(k, &p)| gpu_point(container, first + k, p)));
    scratch
}

/// Records as the GPU holds them: each one's `flags` (reserved in the file, spec §6.8, §6.9, and
/// not read) replaced by its ambient-occlusion byte `ao[i]` (§6.14), 0 where `ao` is empty (no
/// `ELLIPSOID_AO`, `LINE_AO`).
fn with_ao_in_flags<T: Copy>(records: &[T], ao: &[u8], with_flags: fn(T, u32) -> T) -> Vec<T> {
    records.iter().enumerate().map(|(i, &r)| with_flags(r, ao.get(i).copied().map_or(0, u32::from))).collect()
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct MaterialGpu {
    base_color: [f32; 4],
    layer: i32,
    alpha_mode: u32,
    alpha_cutoff: f32,
    material_class: u32,
}

/// The GPU resources of one model and what drawing it needs of its container.
struct Model {
    /// The mapped container: streamed ranges are uploaded from it.
    container: Arc<Container>,
    /// Vertices, materials, images and the sampler.
    bind_group: wgpu::BindGroup,
    /// Bytes uploaded whole at [`Renderer::add_model`] (vertices, materials, images).
    static_bytes: u64,
    /// Pool unit (= point index) of the pinned copy of [`ModelLod::roots`].
    roots_start: u32,
    /// Per container cell: where its roots start in [`ModelLod::roots`], and how many.
    cell_roots: Vec<(u32, u32)>,
    /// Per container cell: its index in [`ModelLod::cells`], `u32::MAX` if empty.
    cell_lod: Vec<u32>,
    /// The priority lists, if the container has them.
    prune: Option<PruneLod>,
    /// The bark triangles in the model's extra triangle buffer (after `PRUNE_TRIANGLES`): first
    /// and count. Pruned trees and trees drawn with impostors draw them all.
    bark: (u32, u32),
    /// The impostor planes, if the container has them (uploaded whole with their atlas).
    planes: Option<PlaneLod>,
    /// Clasen's ellipsoids, if the container has them (uploaded whole).
    ellipsoids: Option<EllipsoidLod>,
    /// Clasen's branch lines, if the container has them (uploaded whole).
    lines: Option<LineLod>,
    /// The hull samples of the occlusion test: first and count in the sample buffer.
    samples: (u32, u32),
    /// The baseline LoD chain, if the container has one: levels, and where the full mesh and each
    /// level lie in the extra triangle buffer.
    chain: Option<ChainModel>,
    /// The baseline billboards, if the container has them.
    billboards: Option<BillboardModel>,
}

/// A model's baseline LoD chain on the GPU (after the bark in the extra triangle buffer).
struct ChainModel {
    chain: LodChain,
    /// Every triangle of the container (the full mesh): first and count.
    full: (u32, u32),
    /// Per level, every tree's triangles of that level, contiguous: first and count.
    levels: Vec<(u32, u32)>,
    /// Per level, the bark (non-leaf) triangles of `levels`, for trees drawn with impostor
    /// planes ([`ImpostorBark::Chain`]): the leading levels whose bark keeps [`BARK_AREA_KEPT`]
    /// of the full bark's area; empty without planes.
    bark_levels: Vec<(u32, u32)>,
}

/// A model's baseline billboards on the GPU: a bind group like the model's with the billboards
/// in place of the planes and their atlas in place of the impostor atlas.
struct BillboardModel {
    bind_group: wgpu::BindGroup,
    /// The facing quads, then the crossed ones, in the billboard buffer: first and count each.
    facing: (u32, u32),
    crossed: (u32, u32),
}

/// Where a recorded draw reads its elements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DrawSource {
    /// The leading `count` triangles of the cell's range (resident in the pool).
    Triangles,
    /// The leading `count` points of the cell's range (resident in the pool).
    Points,
    /// The cell's roots, from the model's pinned copy of the roots: the cell's points are not
    /// resident yet, or (for [`treelod_runtime::ROOTS_CELL`]) a far tree drawn with one range.
    Roots,
    /// The leading `count` triangles of the cell's pruned leaves (a pruned tree, uploaded whole
    /// at [`Renderer::add_model`]).
    PrunedLeaves,
    /// All `count` bark triangles of the model (a pruned tree or one drawn with impostors;
    /// `cell` is [`treelod_runtime::ROOTS_CELL`]).
    Bark,
    /// The leading `count` impostor planes of the cell's range (uploaded whole at
    /// [`Renderer::add_model`]); `tau_points` is the `τ` the shader tests them with.
    Planes,
    /// A baseline LoD chain level (or the full mesh) of the whole block (`cell` is
    /// [`treelod_runtime::ROOTS_CELL`]); `tau_points` is the instance's `τ`, `tau_triangles` the
    /// level's error (0 for the full mesh).
    LodLevel,
    /// Baseline billboard quads of the block (`cell` is [`treelod_runtime::ROOTS_CELL`]).
    Billboards,
    /// The leading `count` ellipsoids of the cell's range (uploaded whole at
    /// [`Renderer::add_model`]); `tau_points` is the `τ` (metres per pixel) the shader tests them
    /// with.
    Ellipsoids,
    /// The leading `count` branch lines of the cell's range (uploaded whole at
    /// [`Renderer::add_model`]); `tau_points` is the `τ` (metres per pixel) the shader tests them
    /// with.
    Lines,
}

/// One draw of the last [`Renderer::prepare`], as the GPU will execute it, for tests and tools.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedDraw {
    /// Index of the instance in [`Renderer::set_instances`]'s list.
    pub instance: u32,
    /// The instance's model.
    pub model: ModelId,
    /// The container cell, or [`treelod_runtime::ROOTS_CELL`] for a far tree's roots.
    pub cell: u32,
    /// What is drawn.
    pub source: DrawSource,
    /// Elements drawn: a prefix of the cell's range (or all the roots it stands for).
    pub count: u32,
    /// `τ_p` the shader tests points with, model units (raised above the selection's when the
    /// resident prefix is shorter than the selection asked for); for pruned leaves, `λ`.
    pub tau_points: f32,
    /// `τ_t`, model units, likewise; for pruned leaves, their size factor.
    pub tau_triangles: f32,
    /// Whether residency made this draw coarser than the selection.
    pub clamped: bool,
}

/// Draws treelod models inside a host's render pass. See the crate documentation for a frame.
pub struct Renderer {
    settings: Settings,
    formats: RendererFormats,
    depth_convention: DepthConvention,
    models: Vec<Model>,
    lods: Vec<ModelLod>,
    instances: Vec<treelod_runtime::Instance>,
    model_layout: wgpu::BindGroupLayout,
    frame_layout: wgpu::BindGroupLayout,
    triangle_pipeline: wgpu::RenderPipeline,
    point_pipeline: wgpu::RenderPipeline,
    /// Pruned leaves and bark, from each model's extra triangle buffer.
    pruned_pipeline: wgpu::RenderPipeline,
    /// Impostor planes, from each model's plane buffer and atlas.
    plane_pipeline: wgpu::RenderPipeline,
    /// Baseline billboards, from each model's billboard bind group.
    billboard_pipeline: wgpu::RenderPipeline,
    /// Clasen's ellipsoids, ray-cast, from each model's ellipsoid buffer and the noise cube.
    ellipsoid_pipeline: wgpu::RenderPipeline,
    /// Clasen's branch lines, ray-cast round cones, from each model's line buffer.
    line_pipeline: wgpu::RenderPipeline,
    /// The shadow pass's depth-only pipelines, in bucket order (triangles, points, pruned,
    /// planes, billboards, ellipsoids, lines).
    shadow_pipelines: [wgpu::RenderPipeline; BUCKETS],
    /// The receivers' bind group layout (group 2) and the maps.
    shadow_layout: wgpu::BindGroupLayout,
    shadow_maps: ShadowMaps,
    /// This frame's cascades (empty without shadows).
    cascades: Vec<Cascade>,
    /// World bounds of the instances (their transformed blocks), for the cascades' casters and
    /// [`Renderer::instance_bounds`].
    scene_bounds: Option<(Vec3, Vec3)>,
    sampler: wgpu::Sampler,
    /// The atlases' sampler: clamped, so a region's edge never wraps to the atlas's far side,
    /// and the nearest mip level.
    atlas_sampler: wgpu::Sampler,
    /// The ellipsoids' white-noise cube map (`crate::noise`; uploaded by the first
    /// [`Renderer::add_model`]) and its nearest-texel sampler.
    noise_view: Option<wgpu::TextureView>,
    noise_sampler: wgpu::Sampler,
    /// The frame uniforms: the camera's at offset 0, then each cascade's at
    /// [`FRAME_UNIFORM_STRIDE`] steps.
    frame_buffer: wgpu::Buffer,
    draw_buffer: wgpu::Buffer,
    indirect_buffer: wgpu::Buffer,
    /// The streamed triangles and points of every model (see `streaming`).
    pool_buffer: wgpu::Buffer,
    /// Per view (the camera, then each cascade): the frame bind group.
    frame_bind_groups: Vec<wgpu::BindGroup>,
    residency: Residency,
    /// The camera's selection and draws of this frame, and each cascade's.
    main: View,
    shadow_views: Vec<View>,
    /// Per instance: the `λ` its pruned leaves were drawn with last frame (hysteresis).
    prune_shown: Vec<Option<f32>>,
    /// Per instance: the visible fraction of its hull samples last measured (1 if never).
    visible_fraction: Vec<f32>,
    plane_ranges: Vec<PlaneRange>,
    ellipsoid_ranges: Vec<EllipsoidRange>,
    line_ranges: Vec<LineRange>,
    /// The occlusion measurement, and the trees to measure after this frame.
    occlusion: Occlusion,
    occlusion_jobs: Vec<Job>,
    /// The camera of the last `prepare`: view-projection, eye, forward, viewport size.
    last_camera: Option<(Mat4, Vec3, Vec3, (u32, u32))>,
    /// GPU-driven selection, when enabled ([`Self::enable_gpu_selection`]).
    gpu: Option<GpuSelection>,
    /// Whether the last `prepare` selected on the GPU (then `render` draws its buckets).
    gpu_frame: bool,
    /// The instances changed since GPU selection last sorted them into blocks.
    gpu_instances_stale: bool,
    // Scratch reused between frames.
    requests: Vec<Request>,
    uploads: Vec<Upload>,
    /// Per model, per cell: the largest prefix asked for this frame (triangles, points).
    wanted: Vec<Vec<[u32; 2]>>,
    buckets: Vec<Vec<(DrawInfo, u32, u32)>>,
    draw_infos: Vec<DrawInfo>,
    indirect: Vec<wgpu::util::DrawIndirectArgs>,
}

/// What one view of a frame (the camera, or a shadow cascade) selected and draws.
#[derive(Default)]
struct View {
    selection: DrawList,
    /// The draws, as recorded for the GPU.
    recorded: Vec<RecordedDraw>,
    /// Instances drawn with the sequential point tree when pruning, impostors or a baseline are
    /// on, and their indices in `instances` (see `spt_remapped`).
    spt_instances: Vec<treelod_runtime::Instance>,
    spt_map: Vec<u32>,
    /// Whether the selection ran over `spt_instances`, so its instance indices go through
    /// `spt_map`.
    spt_remapped: bool,
    /// Pruned draws (pruned leaves, bark, LoD chain levels).
    pruned: Vec<PrunedDraw>,
    /// Impostor draws: per instance and plane cell, the prefix and its `τ`.
    plane_draws: Vec<PrefixDraw>,
    /// Ellipsoid draws: per instance and ellipsoid cell, the prefix and its `τ`.
    ellipsoid_draws: Vec<PrefixDraw>,
    /// Line draws: per instance and line cell, the prefix and its `τ`.
    line_draws: Vec<PrefixDraw>,
    /// Baseline billboard draws: (instance, model, first quad, quads).
    billboard_draws: Vec<(u32, u32, u32, u32)>,
    /// Per model, per bucket: the view's range of the indirect buffer.
    model_draws: Vec<[(u32, u32); BUCKETS]>,
}

impl View {
    /// The index in the renderer's instances of an instance of this view's selection.
    fn instance_index(&self, selected: u32) -> u32 {
        if self.spt_remapped { self.spt_map.get(selected as usize).copied().unwrap_or(selected) } else { selected }
    }
}

/// How the trees of a frame are drawn: the representations [`Settings`] turn on.
#[derive(Clone, Copy)]
struct Modes {
    baseline: Option<Baseline>,
    impostors: bool,
    ellipsoids: bool,
    pruning: Option<Pruning>,
}

/// What [`Renderer::select_view`] counted.
#[derive(Clone, Copy, Default)]
struct ViewCounts {
    instances_visible: u32,
    instances_pruned: u32,
    leaves_pruned: u64,
    instances_impostors: u32,
    instances_ellipsoids: u32,
    instances_baseline: u32,
}

/// Bytes between the frame uniforms of the views (WebGPU's largest uniform offset alignment).
const FRAME_UNIFORM_STRIDE: u64 = 256;

/// Pool units the pool buffer starts with (1.5 MiB).
const INITIAL_POOL_UNITS: u32 = 1 << 15;

/// Draw buckets per model: triangles, points, pruned (leaves and bark, and LoD chain levels),
/// impostor planes, billboards, ellipsoids, lines.
const BUCKETS: usize = 7;

/// [`ImpostorBark::Chain`] draws only levels whose bark keeps this share of the full bark's area.
const BARK_AREA_KEPT: f64 = 0.9;

/// The area of `triangles` of `container`, m² (model space).
fn area(container: &Container, triangles: &[TriangleRecord]) -> f64 {
    let vertices = container.vertices();
    let position = |i: u32| vertices.get(i as usize).map_or(Vec3::ZERO, |v| Vec3::from_array(v.position));
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.indices.map(position);
            f64::from(0.5 * (b - a).cross(c - a).length())
        })
        .sum()
}

/// [`ImpostorBark::Chain`] takes the coarsest level whose error is at most this share of `τ`:
/// meshoptimizer's error of a tube collapsed to a sliver is about its radius, so half a pixel
/// keeps the branches wider than about a pixel.
const BARK_ERROR_SHARE: f32 = 0.5;

/// One draw of impostor planes, ellipsoids or lines: a prefix of one cell's elements for one instance.
#[derive(Clone, Copy, Debug)]
struct PrefixDraw {
    instance: u32,
    model: u32,
    range: CellPrefix,
}

impl Model {
    /// The draw of all this model's bark triangles for instance `instance` (a pruned tree or one
    /// drawn with impostors; `lambda` is recorded with it), if it has any.
    fn bark_draw(&self, instance: u32, model: u32, lambda: f32) -> Option<PrunedDraw> {
        Self::whole_draw(instance, model, DrawSource::Bark, self.bark, lambda, 1.0)
    }

    /// A draw of the triangles `first, count` of the extra triangle buffer for the whole tree
    /// (no cell: the bark, a LoD chain level), if there are any; `lambda` and `tau_triangles`
    /// are recorded with it.
    fn whole_draw(
        instance: u32,
        model: u32,
        source: DrawSource,
        (first, count): (u32, u32),
        lambda: f32,
        tau_triangles: f32,
    ) -> Option<PrunedDraw> {
        (count > 0).then_some(PrunedDraw {
            instance,
            model,
            cell: ROOTS_CELL,
            source,
            first,
            count,
            lambda,
            leaf_scale: 1.0,
            tau_triangles,
        })
    }

    /// The centre of the model's block: where `τ` is measured for its baselines and impostors.
    fn block_centre(&self) -> Vec3 {
        let block = self.container.block();
        0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max))
    }
}

impl ChainModel {
    /// The error of level `level`, metres (0 past the chain).
    fn level_error(&self, level: usize) -> f32 {
        self.chain.levels().get(level).map_or(0.0, |l| l.error)
    }
}

/// One draw of a pruned tree: leaves of one cell, or the bark.
#[derive(Clone, Copy, Debug)]
struct PrunedDraw {
    instance: u32,
    model: u32,
    /// Container cell, or `ROOTS_CELL` for the bark.
    cell: u32,
    source: DrawSource,
    /// Into the model's extra triangle buffer.
    first: u32,
    count: u32,
    lambda: f32,
    leaf_scale: f32,
    /// What [`RecordedDraw::tau_triangles`] reports: `leaf_scale`, or a chain level's error.
    tau_triangles: f32,
}

impl Renderer {
    /// The device features the renderer needs: indirect draws that set the first instance.
    #[must_use]
    pub fn required_features() -> wgpu::Features {
        wgpu::Features::INDIRECT_FIRST_INSTANCE
    }

    /// The device features GPU selection ([`Self::enable_gpu_selection`]) uses where present:
    /// `MULTI_DRAW_INDIRECT_COUNT`, so each bucket draws exactly the ranges the compute pass
    /// appended (without it, whole buckets are drawn with empty draws in the unused slots).
    #[must_use]
    pub fn gpu_selection_features() -> wgpu::Features {
        wgpu::Features::MULTI_DRAW_INDIRECT_COUNT
    }

    /// Creates the pipelines for the host's target formats, with a standard depth buffer
    /// ([`DepthConvention::Standard`]: cleared to 1, nearer is less).
    ///
    /// The memory budget of `settings` is fixed here, capped by the device's largest storage
    /// binding (the pool is one binding): ask for larger `max_storage_buffer_binding_size` and
    /// `max_buffer_size` limits when creating the device to stream more.
    #[must_use]
    pub fn new(device: &wgpu::Device, formats: RendererFormats, settings: Settings) -> Self {
        Self::with_depth_convention(device, formats, settings, DepthConvention::Standard)
    }

    /// As [`Self::new`], for a host's depth buffer that runs as `depth` says (reverse Z for
    /// [`DepthConvention::Reverse`]; the cameras passed to [`Self::prepare`] must then project
    /// near to 1). [`Self::measure_occlusion`] reads that buffer with the same convention.
    #[must_use]
    pub fn with_depth_convention(
        device: &wgpu::Device,
        formats: RendererFormats,
        settings: Settings,
        depth: DepthConvention,
    ) -> Self {
        let storage = |binding: u32, visibility: wgpu::ShaderStages| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod frame"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                // The draws: the ellipsoids' fragment stage reads their transforms too.
                storage(1, wgpu::ShaderStages::VERTEX_FRAGMENT),
                storage(2, wgpu::ShaderStages::VERTEX),
                storage(3, wgpu::ShaderStages::VERTEX),
            ],
        });
        let texture = |binding: u32, view_dimension| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension,
                multisampled: false,
            },
            count: None,
        };
        let sampler = |binding: u32| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
            count: None,
        };
        let model_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod model"),
            entries: &[
                storage(0, wgpu::ShaderStages::VERTEX),
                storage(1, wgpu::ShaderStages::FRAGMENT),
                texture(2, wgpu::TextureViewDimension::D2Array),
                sampler(3),
                storage(4, wgpu::ShaderStages::VERTEX),
                storage(5, wgpu::ShaderStages::VERTEX),
                // Impostor planes and their atlas.
                storage(6, wgpu::ShaderStages::VERTEX),
                texture(7, wgpu::TextureViewDimension::D2),
                sampler(8),
                // Indirect texturing: the leaf-slot image and the planes' leaves.
                wgpu::BindGroupLayoutEntry {
                    binding: 9,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                storage(10, wgpu::ShaderStages::FRAGMENT),
                // Ellipsoids, and the white-noise cube map they sample.
                storage(11, wgpu::ShaderStages::VERTEX_FRAGMENT),
                texture(12, wgpu::TextureViewDimension::Cube),
                wgpu::BindGroupLayoutEntry {
                    binding: 13,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::NonFiltering),
                    count: None,
                },
                // Branch lines.
                storage(14, wgpu::ShaderStages::VERTEX_FRAGMENT),
            ],
        });
        let shadow_layout = ShadowMaps::layout(device);
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("treelod"),
            bind_group_layouts: &[Some(&frame_layout), Some(&model_layout), Some(&shadow_layout)],
            immediate_size: 0,
        });
        let caster_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("treelod shadow casters"),
            bind_group_layouts: &[Some(&frame_layout), Some(&model_layout)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("treelod tree.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        // With MSAA, alpha-tested leaves write a sample mask from their filtered alpha (alpha to
        // coverage, in the shader) so their density holds where small mips thin out a test.
        let overrides = [
            ("sample_count", f64::from(formats.sample_count.max(1))),
            ("crossfade", f64::from(treelod_runtime::CROSSFADE)),
        ];
        // The shadow pass: depth only, one sample, a slope-scaled bias against self-shadowing.
        let caster_overrides = [("sample_count", 1.0), ("crossfade", f64::from(treelod_runtime::CROSSFADE))];
        let colour_target =
            [Some(wgpu::ColorTargetState { format: formats.color, blend: None, write_mask: wgpu::ColorWrites::ALL })];
        // A pipeline of the host's pass, or (`caster`) of the shadow pass.
        let pipeline = |label: &str, vs: &str, fs: &str, caster: bool| {
            let constants = || wgpu::PipelineCompilationOptions {
                constants: if caster { &caster_overrides } else { &overrides },
                ..wgpu::PipelineCompilationOptions::default()
            };
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(if caster { &caster_layout } else { &layout }),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some(vs),
                    compilation_options: constants(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    // Leaves are cards seen from both sides; splats always face the camera.
                    cull_mode: None,
                    ..wgpu::PrimitiveState::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: if caster { SHADOW_FORMAT } else { formats.depth },
                    depth_write_enabled: Some(true),
                    // The shadow maps are the renderer's own, always standard.
                    depth_compare: Some(if caster { wgpu::CompareFunction::Less } else { depth.compare() }),
                    stencil: wgpu::StencilState::default(),
                    bias: if caster {
                        wgpu::DepthBiasState { constant: 2, slope_scale: 2.0, clamp: 0.0 }
                    } else {
                        wgpu::DepthBiasState::default()
                    },
                }),
                multisample: wgpu::MultisampleState {
                    count: if caster { 1 } else { formats.sample_count.max(1) },
                    mask: !0,
                    alpha_to_coverage_enabled: false,
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: constants(),
                    targets: if caster { &[] } else { &colour_target },
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let triangle_pipeline = pipeline("treelod triangles", "vs_triangle", "fs_triangle", false);
        let point_pipeline = pipeline("treelod points", "vs_point", "fs_point", false);
        let pruned_pipeline = pipeline("treelod pruned leaves and bark", "vs_pruned", "fs_triangle", false);
        let plane_pipeline = pipeline("treelod impostor planes", "vs_plane", "fs_plane", false);
        let billboard_pipeline = pipeline("treelod baseline billboards", "vs_billboard", "fs_plane", false);
        let ellipsoid_pipeline = pipeline("treelod ellipsoids", "vs_ellipsoid", "fs_ellipsoid", false);
        let line_pipeline = pipeline("treelod lines", "vs_line", "fs_line", false);
        let shadow_pipelines = [
            pipeline("treelod shadow triangles", "vs_triangle", "fs_shadow_triangle", true),
            pipeline("treelod shadow points", "vs_point", "fs_shadow_point", true),
            pipeline("treelod shadow pruned leaves and bark", "vs_pruned", "fs_shadow_triangle", true),
            pipeline("treelod shadow impostor planes", "vs_plane", "fs_shadow_plane", true),
            pipeline("treelod shadow billboards", "vs_billboard", "fs_shadow_plane", true),
            pipeline("treelod shadow ellipsoids", "vs_ellipsoid", "fs_shadow_ellipsoid", true),
            pipeline("treelod shadow lines", "vs_line", "fs_shadow_line", true),
        ];
        let shadow_maps = ShadowMaps::new(device, &shadow_layout, 1, 1);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("treelod textures"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..wgpu::SamplerDescriptor::default()
        });
        // Nearest mip: each level's alpha is scaled so that its filtered test covers what the
        // leaves cover (the build's coverage-preserving mips); a blend of two levels would not.
        let atlas_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("treelod atlases"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Nearest,
            ..wgpu::SamplerDescriptor::default()
        });
        let noise_sampler = crate::noise::sampler(device);
        let frame_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("treelod frame"),
            size: FRAME_UNIFORM_STRIDE * (1 + MAX_CASCADES as u64),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let draw_buffer = storage_buffer(device, "treelod draws", 64 * size_of::<DrawInfo>() as u64, false);
        let indirect_buffer = indirect_buffer(device, 64);
        let limits = device.limits();
        let binding_limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let max_units = u32::try_from(settings.memory_budget.min(binding_limit) / UNIT).unwrap_or(u32::MAX).max(1);
        let pool = Pool::new(INITIAL_POOL_UNITS, max_units);
        let pool_buffer = storage_buffer(device, "treelod pool", u64::from(pool.capacity()).max(1) * UNIT, true);
        let frame_bind_groups = frame_bind_groups(device, &frame_layout, &frame_buffer, &draw_buffer, &pool_buffer);
        Self {
            formats,
            settings,
            depth_convention: depth,
            models: Vec::new(),
            lods: Vec::new(),
            instances: Vec::new(),
            model_layout,
            frame_layout,
            triangle_pipeline,
            point_pipeline,
            pruned_pipeline,
            plane_pipeline,
            billboard_pipeline,
            ellipsoid_pipeline,
            line_pipeline,
            shadow_pipelines,
            shadow_layout,
            shadow_maps,
            cascades: Vec::new(),
            scene_bounds: None,
            sampler,
            atlas_sampler,
            noise_view: None,
            noise_sampler,
            frame_buffer,
            draw_buffer,
            indirect_buffer,
            pool_buffer,
            frame_bind_groups,
            residency: Residency::new(pool),
            main: View::default(),
            shadow_views: Vec::new(),
            prune_shown: Vec::new(),
            visible_fraction: Vec::new(),
            plane_ranges: Vec::new(),
            ellipsoid_ranges: Vec::new(),
            line_ranges: Vec::new(),
            occlusion: Occlusion::new(device, formats.sample_count.max(1), depth),
            occlusion_jobs: Vec::new(),
            last_camera: None,
            gpu: None,
            gpu_frame: false,
            gpu_instances_stale: false,
            requests: Vec::new(),
            uploads: Vec::new(),
            wanted: Vec::new(),
            buckets: Vec::new(),
            draw_infos: Vec::new(),
            indirect: Vec::new(),
        }
    }

    /// The target formats the pipelines were made for.
    #[must_use]
    pub fn formats(&self) -> RendererFormats {
        self.formats
    }

    /// Which way the host's depth buffer runs, as made.
    #[must_use]
    pub fn depth_convention(&self) -> DepthConvention {
        self.depth_convention
    }

    /// The settings used by the next [`Self::prepare`].
    pub fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }

    /// The current settings.
    #[must_use]
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Adds a container: uploads its vertices, materials and images, and a copy of every cell's
    /// roots; its triangles and points stream from the mapped file as frames need them. Images
    /// that fail to decode are drawn grey; [`Self::add_model_with_warnings`] says which.
    ///
    /// # Errors
    /// [`RenderError::TooLarge`] if the vertices or materials exceed the device's storage-buffer
    /// binding limit, [`RenderError::Budget`] if the memory budget cannot hold the roots.
    pub fn add_model(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        container: Arc<Container>,
    ) -> Result<ModelId, RenderError> {
        self.add_model_with_warnings(device, queue, container).map(|(id, _)| id)
    }

    /// As [`Self::add_model`], also returning warnings (one sentence each).
    ///
    /// # Errors
    /// As [`Self::add_model`].
    pub fn add_model_with_warnings(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        container: Arc<Container>,
    ) -> Result<(ModelId, Vec<String>), RenderError> {
        let limit = device.limits().max_storage_buffer_binding_size;
        if self.gpu.is_some() {
            // GPU selection keeps every model whole: refuse what does not fit before adding it.
            let lod = ModelLod::from_container(&container);
            let bytes = self.gpu.as_ref().map_or(0, GpuSelection::pool_bytes)
                + crate::gpu_select::model_units(&container, &lod) * UNIT;
            let budget = self.gpu_budget(device);
            if bytes > budget {
                let model = u32::try_from(self.models.len()).unwrap_or(u32::MAX);
                return Err(RenderError::GpuSelectionBudget { model, bytes, budget });
            }
        }
        let mut warnings = Vec::new();
        let mut bytes = 0u64;
        let mut upload = |what: &'static str, data: &[u8]| -> Result<wgpu::Buffer, RenderError> {
            if data.len() as u64 > limit {
                return Err(RenderError::TooLarge { what, bytes: data.len() as u64, limit });
            }
            // Bindings may not be empty, nor smaller than one record of the array they hold: an
            // empty array becomes 64 zero bytes (the largest record) no draw reads.
            let padded = data.len().max(64).next_multiple_of(4) as u64;
            let buffer = storage_buffer(device, what, padded, false);
            queue.write_buffer(&buffer, 0, data);
            bytes += padded;
            Ok(buffer)
        };
        let layers = textures::layers(&container, &mut warnings);
        let image_layer = |image: u32| -> i32 {
            if image == NO_IMAGE { -1 } else { layers.layer_of.get(image as usize).copied().unwrap_or(-1) }
        };
        let materials: Vec<MaterialGpu> = container
            .materials()
            .iter()
            .map(|m: &MaterialRecord| MaterialGpu {
                base_color: m.base_color,
                layer: image_layer(m.image),
                alpha_mode: m.alpha_mode,
                alpha_cutoff: m.alpha_cutoff,
                material_class: m.class,
            })
            .collect();
        // The vertices as the shaders read them: each record followed by its ambient occlusion.
        let vertex_ao = container.vertex_ao();
        let vertices: Vec<VertexGpu> = container
            .vertices()
            .iter()
            .enumerate()
            .map(|(i, &record)| VertexGpu {
                record,
                ao: vertex_ao.get(i).map_or(0.0, |&a| treelod_format::decode_ao(a)),
            })
            .collect();
        let vertices = upload("VERTICES", bytemuck::cast_slice(&vertices))?;
        let materials = upload("MATERIALS", bytemuck::cast_slice(&materials))?;
        // Pruning: the leaves' triangles, then every bark (non-leaf) triangle, and the leaves.
        // Impostors draw the bark triangles too.
        let prune = PruneLod::from_container(&container);
        let planes = PlaneLod::from_container(&container);
        let ellipsoids = EllipsoidLod::from_container(&container);
        let lod_chain = LodChain::from_container(&container);
        let mut chain = None;
        let (extra, prune_leaves, bark) = if prune.is_some()
            || planes.is_some()
            || ellipsoids.is_some()
            || lod_chain.is_some()
        {
            let classes = container.materials();
            let is_bark =
                |t: &&TriangleRecord| classes.get(t.material as usize).is_none_or(|m| m.class != material_class::LEAF);
            let mut extra: Vec<TriangleRecord> = container.prune_triangles().to_vec();
            let at = |extra: &Vec<TriangleRecord>| u32::try_from(extra.len()).unwrap_or(u32::MAX);
            let bark_first = at(&extra);
            extra.extend(container.triangles().iter().filter(is_bark));
            let bark_count = at(&extra) - bark_first;
            // The baseline chain: the full mesh, then each level with every tree's triangles.
            if let Some(lod_chain) = lod_chain {
                let full_first = at(&extra);
                extra.extend_from_slice(container.triangles());
                let full = (full_first, at(&extra) - full_first);
                let mut levels = Vec::new();
                for level in lod_chain.levels() {
                    let first = at(&extra);
                    for range in &level.ranges {
                        extra.extend_from_slice(container.lod_triangles().get(range.as_usize()).unwrap_or_default());
                    }
                    levels.push((first, at(&extra) - first));
                }
                let mut bark_levels = Vec::new();
                if planes.is_some() {
                    let full_area = area(&container, &extra[bark_first as usize..(bark_first + bark_count) as usize]);
                    for level in lod_chain.levels() {
                        let first = at(&extra);
                        for range in &level.ranges {
                            let triangles = container.lod_triangles().get(range.as_usize()).unwrap_or_default();
                            extra.extend(triangles.iter().filter(is_bark));
                        }
                        // The levels that keep the bark's surface: a coarser one collapses
                        // branches that its error does not count.
                        let kept = area(&container, &extra[first as usize..]);
                        if kept < BARK_AREA_KEPT * full_area {
                            extra.truncate(first as usize);
                            break;
                        }
                        bark_levels.push((first, at(&extra) - first));
                    }
                }
                chain = Some(ChainModel { chain: lod_chain, full, levels, bark_levels });
            }
            let extra = upload("PRUNE_TRIANGLES, bark and LoD chain", bytemuck::cast_slice(&extra))?;
            let leaves = upload("PRUNE_LEAVES", bytemuck::cast_slice(container.prune_leaves()))?;
            (extra, leaves, (bark_first, bark_count))
        } else {
            (upload("no pruned triangles", &[])?, upload("no pruned leaves", &[])?, (0, 0))
        };
        // Baseline billboards: the facing quads, then the crossed ones.
        let billboard_kinds = Billboards::from_container(&container);
        let billboard_records: Vec<treelod_format::BillboardRecord> =
            billboard_kinds.as_ref().map_or_else(Vec::new, |b| {
                b.facing
                    .iter()
                    .chain(&b.crossed)
                    .filter_map(|&i| container.billboards().get(i as usize).copied())
                    .collect()
            });
        let billboard_buffer = match &billboard_kinds {
            Some(_) => Some(upload("BILLBOARDS", bytemuck::cast_slice(&billboard_records))?),
            None => None,
        };
        // As uploaded, each plane's `leaf_first` (which no shader reads) holds the index of its
        // parent plane, for the morph between levels (`vs_plane`), its `leaf_count` its ambient
        // occlusion byte (spec §6.14), and its `image` (bound separately) where its leaves start
        // in `PLANE_LEAVES` if it is textured indirectly (spec §6.10.1), else 0xFFFFFFFF.
        let parents = treelod_runtime::plane_parents(container.planes(), container.cells().iter().map(|c| c.planes));
        let plane_ao = container.plane_ao();
        let bases = treelod_format::plane_leaf_bases(container.planes());
        let is_slots = |image: u32| {
            container.images().get(image as usize).is_some_and(|i| i.format == treelod_format::image_format::LEAF_SLOTS)
        };
        let indirect = container.planes().iter().any(|p| is_slots(p.image));
        if indirect && bases.last().copied() != Some(container.plane_leaves().len() as u64) {
            warnings.push(format!(
                "PLANE_LEAVES holds {} records, the planes need {}; indirectly textured planes are not drawn",
                container.plane_leaves().len(),
                bases.last().copied().unwrap_or(0)
            ));
        }
        let leaf_base = |i: usize, plane: &treelod_format::PlaneRecord| {
            if is_slots(plane.image) && container.plane_leaves().len() as u64 == bases[bases.len() - 1] {
                u32::try_from(bases[i]).unwrap_or(u32::MAX)
            } else {
                u32::MAX
            }
        };
        let gpu_planes: Vec<treelod_format::PlaneRecord> = container
            .planes()
            .iter()
            .zip(&parents)
            .enumerate()
            .map(|(i, (plane, &parent))| treelod_format::PlaneRecord {
                image: leaf_base(i, plane),
                leaf_first: parent,
                leaf_count: plane_ao.get(i).copied().map_or(0, u32::from),
                ..*plane
            })
            .collect();
        let plane_buffer = upload("PLANES", bytemuck::cast_slice(&gpu_planes))?;
        let plane_leaves = upload("PLANE_LEAVES", bytemuck::cast_slice(container.plane_leaves()))?;
        // As uploaded, each ellipsoid's `flags` (reserved in the file, spec §6.8) holds its ambient
        // occlusion byte (§6.14), 0 without `ELLIPSOID_AO`: never the file's own flags.
        let gpu_ellipsoids = with_ao_in_flags(container.ellipsoids(), container.ellipsoid_ao(), |e, flags| {
            treelod_format::EllipsoidRecord { flags, ..e }
        });
        let ellipsoid_buffer = upload("ELLIPSOIDS", bytemuck::cast_slice(&gpu_ellipsoids))?;
        drop(gpu_ellipsoids);
        // Lines likewise: each one's `flags` holds its `LINE_AO` byte, never the file's flags.
        let lines = LineLod::from_container(&container);
        let gpu_lines = with_ao_in_flags(container.lines(), container.line_ao(), |l, flags| {
            treelod_format::LineRecord { flags, ..l }
        });
        let line_buffer = upload("LINES", bytemuck::cast_slice(&gpu_lines))?;
        drop(gpu_lines);
        if self.noise_view.is_none() {
            let (view, noise_bytes) = crate::noise::upload(device, queue);
            self.noise_view = Some(view);
            bytes += noise_bytes;
        }

        // The roots, pinned in the pool: what a cell draws before its own points are resident.
        let lod = ModelLod::from_container(&container);
        let roots: Vec<PointRecord> =
            lod.roots().iter().map(|&i| gpu_point(&container, i as usize, container.points()[i as usize])).collect();
        let roots_len = u32::try_from(roots.len()).unwrap_or(u32::MAX);
        let cells = container.cells().len();
        let Some(roots_start) = self.residency.add_model(cells, roots_len) else {
            return Err(RenderError::Budget { bytes: u64::from(roots_len) * UNIT, budget: self.pool_budget() });
        };
        self.grow_pool_buffer(device, queue);
        if !roots.is_empty() {
            queue.write_buffer(&self.pool_buffer, u64::from(roots_start) * UNIT, bytemuck::cast_slice(&roots));
        }
        let mut cell_roots = vec![(0, 0); cells];
        let mut cell_lod = vec![u32::MAX; cells];
        let mut at = 0u32;
        for (i, cell) in lod.cells().iter().enumerate() {
            let count = lod.roots()[at as usize..]
                .iter()
                .take_while(|&&p| cell.points().as_usize().contains(&(p as usize)))
                .count();
            let count = u32::try_from(count).unwrap_or(0);
            cell_roots[cell.index() as usize] = (at, count);
            cell_lod[cell.index() as usize] = u32::try_from(i).unwrap_or(u32::MAX);
            at += count;
        }

        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("treelod images"),
            size: wgpu::Extent3d {
                width: layers.size,
                height: layers.size,
                depth_or_array_layers: u32::try_from(layers.levels.len()).unwrap_or(1),
            },
            mip_level_count: layers.mips,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8UnormSrgb,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        for (layer, chain) in layers.levels.iter().enumerate() {
            for (level, texels) in chain.iter().enumerate() {
                let side = (layers.size >> level).max(1);
                queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &texture,
                        mip_level: u32::try_from(level).unwrap_or(0),
                        origin: wgpu::Origin3d { x: 0, y: 0, z: u32::try_from(layer).unwrap_or(0) },
                        aspect: wgpu::TextureAspect::All,
                    },
                    texels,
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(side * 4),
                        rows_per_image: Some(side),
                    },
                    wgpu::Extent3d { width: side, height: side, depth_or_array_layers: 1 },
                );
                bytes += texels.len() as u64;
            }
        }
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..wgpu::TextureViewDescriptor::default()
        });
        // The impostor atlas, as stored with its mips; without planes (or if it does not decode,
        // then without impostors) one transparent texel.
        let blank = |slots| textures::Atlas { width: 1, height: 1, srgb: true, slots, levels: vec![vec![0; 4]] };
        let (atlas, planes) = match planes {
            Some(p) => match textures::atlas(&container, p.image()) {
                Ok(atlas) if atlas.width.max(atlas.height) > device.limits().max_texture_dimension_2d => {
                    warnings.push(format!(
                        "impostor atlas (image {}) is {}x{}, larger than the device's textures; impostors are not drawn",
                        p.image(),
                        atlas.width,
                        atlas.height
                    ));
                    (blank(false), None)
                }
                Ok(atlas) => (atlas, Some(p)),
                Err(e) => {
                    warnings.push(format!("impostor atlas (image {}): {e}; impostors are not drawn", p.image()));
                    (blank(false), None)
                }
            },
            None => (blank(false), None),
        };
        // A leaf-slot image (spec §6.10.1) is bound as such, with a blank atlas; otherwise a blank
        // slot image.
        let (atlas, slots) = if atlas.slots { (blank(false), atlas) } else { (atlas, blank(true)) };
        if planes.as_ref().is_some_and(|p| container.planes().iter().any(|q| q.image != p.image())) {
            warnings.push(format!(
                "impostor planes sample several images; all are drawn from image {}",
                planes.as_ref().map_or(0, PlaneLod::image)
            ));
        }
        let (atlas_view, atlas_bytes) = upload_atlas(device, queue, &atlas, "treelod impostor atlas");
        let (slots_view, slot_bytes) = upload_atlas(device, queue, &slots, "treelod leaf slots");
        bytes += atlas_bytes + slot_bytes;
        let Some(noise_view) = &self.noise_view else { unreachable!("uploaded above") };
        let model_group = |label: &str, planes: &wgpu::Buffer, atlas: &wgpu::TextureView| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &self.model_layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: vertices.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: materials.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::TextureView(&view) },
                    wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::Sampler(&self.sampler) },
                    wgpu::BindGroupEntry { binding: 4, resource: extra.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: prune_leaves.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 6, resource: planes.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 7, resource: wgpu::BindingResource::TextureView(atlas) },
                    wgpu::BindGroupEntry { binding: 8, resource: wgpu::BindingResource::Sampler(&self.atlas_sampler) },
                    wgpu::BindGroupEntry { binding: 9, resource: wgpu::BindingResource::TextureView(&slots_view) },
                    wgpu::BindGroupEntry { binding: 10, resource: plane_leaves.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 11, resource: ellipsoid_buffer.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 12, resource: wgpu::BindingResource::TextureView(noise_view) },
                    wgpu::BindGroupEntry { binding: 13, resource: wgpu::BindingResource::Sampler(&self.noise_sampler) },
                    wgpu::BindGroupEntry { binding: 14, resource: line_buffer.as_entire_binding() },
                ],
            })
        };
        let bind_group = model_group("treelod model", &plane_buffer, &atlas_view);
        // Billboards: their own atlas and bind group (the image of the first record; builders
        // write one), not drawn if it does not decode or fit.
        let billboards = match (billboard_kinds, billboard_buffer, billboard_records.first()) {
            (Some(kinds), Some(buffer), Some(first)) => match textures::atlas(&container, first.image) {
                Ok(atlas) if atlas.width.max(atlas.height) > device.limits().max_texture_dimension_2d => {
                    warnings.push(format!(
                        "billboard atlas (image {}) is {}x{}, larger than the device's textures; billboards are not drawn",
                        first.image, atlas.width, atlas.height
                    ));
                    None
                }
                Ok(atlas) => {
                    let (billboard_view, atlas_bytes) = upload_atlas(device, queue, &atlas, "treelod billboard atlas");
                    bytes += atlas_bytes;
                    let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
                    Some(BillboardModel {
                        bind_group: model_group("treelod billboards", &buffer, &billboard_view),
                        facing: (0, count(kinds.facing.len())),
                        crossed: (count(kinds.facing.len()), count(kinds.crossed.len())),
                    })
                }
                Err(e) => {
                    warnings.push(format!("billboard atlas (image {}): {e}; billboards are not drawn", first.image));
                    None
                }
            },
            _ => None,
        };
        let id = ModelId(u32::try_from(self.models.len()).unwrap_or(u32::MAX));
        let samples = match &prune {
            Some(p) => (self.occlusion.add_samples(p.samples()), u32::try_from(p.samples().len()).unwrap_or(0)),
            None => (0, 0),
        };
        self.models.push(Model {
            samples,
            container,
            bind_group,
            static_bytes: bytes,
            roots_start,
            cell_roots,
            cell_lod,
            prune,
            bark,
            planes,
            ellipsoids,
            lines,
            chain,
            billboards,
        });
        self.lods.push(lod);
        self.wanted.push(vec![[0; 2]; cells]);
        if self.gpu.is_some() {
            // Checked above, so it fits; should it not, GPU selection is turned off.
            if self.enable_gpu_selection(device, queue).is_err() {
                self.gpu = None;
            }
        }
        Ok((id, warnings))
    }

    /// Bytes GPU selection may keep resident: [`Settings::memory_budget`] capped by the device's
    /// largest storage binding and buffer.
    fn gpu_budget(&self, device: &wgpu::Device) -> u64 {
        let limits = device.limits();
        self.settings.memory_budget.min(limits.max_storage_buffer_binding_size).min(limits.max_buffer_size)
    }

    /// Turns on GPU-driven selection: from the next [`Self::prepare`] on, compute shaders select
    /// the instances and write the indirect draws (`crate::gpu_select`; same inputs and, up to
    /// `f32` rounding at thresholds, the same ranges as [`treelod_runtime::select_frame`]), so the
    /// CPU does O(models) work per frame, not O(instances). Uploads every model's triangles and
    /// points whole into a pool of their own (GPU selection does not stream: everything a
    /// selection may ask for is resident); models added later are uploaded when added. Calling
    /// it again re-uploads.
    ///
    /// The CPU path is still used for frames with [`Settings::pruning`] or
    /// [`Settings::full_mesh`] on, and when there are more than about 4.19 M instances
    /// (`64 × 65535`, one dispatch of instance blocks). Needs a device with
    /// [`wgpu::Features::MULTI_DRAW_INDIRECT_COUNT`] for best results; without it every bucket
    /// is drawn at its full capacity with unused slots as empty draws.
    ///
    /// # Errors
    /// [`RenderError::GpuSelectionBudget`] if the models' triangles, points and roots do not fit
    /// [`Settings::memory_budget`] (capped by the device's largest storage binding); GPU
    /// selection then stays off.
    pub fn enable_gpu_selection(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<(), RenderError> {
        let budget = self.gpu_budget(device);
        let containers: Vec<&Container> = self.models.iter().map(|m| &*m.container).collect();
        let mut gpu = GpuSelection::new(device, queue, &containers, &self.lods, budget)?;
        gpu.set_instances(device, queue, &self.instances, &self.lods);
        self.gpu = Some(gpu);
        self.gpu_instances_stale = false;
        Ok(())
    }

    /// Turns GPU-driven selection off and frees its buffers: the CPU selects from the next
    /// [`Self::prepare`] on.
    pub fn disable_gpu_selection(&mut self) {
        self.gpu = None;
        self.gpu_frame = false;
    }

    /// Whether GPU-driven selection is on ([`Self::enable_gpu_selection`]).
    #[must_use]
    pub fn gpu_selection_enabled(&self) -> bool {
        self.gpu.is_some()
    }

    /// The ranges the GPU selected in the last [`Self::prepare`], read back (this blocks until
    /// the GPU has finished): as [`treelod_runtime::select_frame`] lists them, with `instance`
    /// the index in [`Self::set_instances`]' list, grouped by model and kind in no fixed order.
    /// Ranges dropped for lack of capacity ([`FrameStats::ranges_dropped`]) are missing. `None`
    /// if the last frame was selected on the CPU ([`Self::selection`] has it). For tests and
    /// tools.
    ///
    /// # Errors
    /// [`RenderError::Readback`] if mapping the buffers fails.
    pub fn read_gpu_selection(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Option<Vec<DrawRange>>, RenderError> {
        match &self.gpu {
            Some(gpu) if self.gpu_frame => gpu.read_ranges(device, queue).map(Some),
            _ => Ok(None),
        }
    }

    /// The largest pool, bytes (the memory budget as capped by the device).
    fn pool_budget(&self) -> u64 {
        u64::from(self.residency.pool.max()) * UNIT
    }

    /// Replaces the pool buffer by a larger one if the pool grew, keeping its contents.
    fn grow_pool_buffer(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
        let size = u64::from(self.residency.pool.capacity()).max(1) * UNIT;
        if size <= self.pool_buffer.size() {
            return;
        }
        let buffer = storage_buffer(device, "treelod pool", size, true);
        let mut encoder =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("treelod pool") });
        encoder.copy_buffer_to_buffer(&self.pool_buffer, 0, &buffer, 0, self.pool_buffer.size());
        // Submitted now: the writes that follow are made at the start of the next submission,
        // after this copy.
        queue.submit([encoder.finish()]);
        self.pool_buffer = buffer;
        self.frame_bind_groups =
            frame_bind_groups(device, &self.frame_layout, &self.frame_buffer, &self.draw_buffer, &self.pool_buffer);
    }

    /// Replaces the instances drawn from the next frame on. Instances of unknown models are ignored.
    ///
    /// Per-instance pruning state (the held `λ`, the measured visible fraction) is kept by index
    /// when the number of instances stays the same (moving trees), and reset otherwise.
    pub fn set_instances(&mut self, instances: &[Instance]) {
        let before = self.instances.len();
        self.instances.clear();
        self.instances.extend(
            instances
                .iter()
                .filter(|i| (i.model.0 as usize) < self.models.len())
                .map(|i| treelod_runtime::Instance { model: i.model.0, transform: i.transform }),
        );
        if self.instances.len() != before {
            self.prune_shown = vec![None; self.instances.len()];
            self.visible_fraction = vec![1.0; self.instances.len()];
        }
        // The union of the instances' transformed blocks (their container's bounds).
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for instance in &self.instances {
            let block = self.models[instance.model as usize].container.block();
            let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
            let (a, b) = transformed_bounds(instance.transform, min, max);
            (lo, hi) = (lo.min(a), hi.max(b));
        }
        self.scene_bounds = (lo.is_finite() && hi.is_finite() && lo.cmple(hi).all()).then_some((lo, hi));
        self.gpu_instances_stale = true;
    }

    /// Which instances are drawn with impostor planes this frame ([`Settings::impostors`]): appends to
    /// `view`'s `plane_draws`, and `pruned` with their bark, for instances whose model has planes, and
    /// `spt_instances`/`spt_map` with the others. Returns the impostor instances inside the
    /// frustum. With `ellipsoids`, instances whose model has ellipsoids are skipped: they were
    /// drawn by [`Self::select_ellipsoids`].
    fn select_impostors(&mut self, view: &mut View, camera: &treelod_runtime::Camera, ellipsoids: bool) -> u32 {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let mut visible = 0;
        for (i, instance) in self.instances.iter().enumerate() {
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let Some(model) = self.models.get(instance.model as usize) else { continue };
            if ellipsoids && model.ellipsoids.is_some() {
                continue;
            }
            let Some(planes) = &model.planes else {
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            };
            self.plane_ranges.clear();
            if !planes.select(instance.transform, camera, &frustum, self.settings.s_min, &mut self.plane_ranges) {
                continue;
            }
            visible += 1;
            for range in &self.plane_ranges {
                view.plane_draws.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            // The chain's bark level (its triangles and error), if the policy and the model have one.
            let chain_bark = match (self.settings.impostor_bark, &model.chain, self.lods.get(instance.model as usize)) {
                (ImpostorBark::Chain, Some(chain), Some(lod)) => {
                    let (s_min, sphere) = (self.settings.s_min, lod.cull_sphere());
                    instance_tau(instance.transform, camera, &frustum, s_min, sphere, model.block_centre())
                        .and_then(|tau| chain.chain.pick(tau * BARK_ERROR_SHARE))
                        .and_then(|level| {
                            let level = (level as usize).min(chain.bark_levels.len().checked_sub(1)?);
                            Some((chain.bark_levels[level], chain.level_error(level)))
                        })
                }
                _ => None,
            };
            view.pruned.extend(match chain_bark {
                Some((range, error)) => Model::whole_draw(index, instance.model, DrawSource::Bark, range, 1.0, error),
                None => model.bark_draw(index, instance.model, 1.0),
            });
        }
        visible
    }

    /// Which instances are drawn with ellipsoids this frame ([`Settings::ellipsoids`]): appends to
    /// `view`'s `ellipsoid_draws`, and its `line_draws` with their bark's lines (with
    /// [`Settings::lines`] and where the model has lines; else `pruned` with all their bark
    /// triangles), for instances whose model has ellipsoids, and `spt_instances`/`spt_map` with
    /// the others, except those [`Self::select_impostors`] draws (`impostors` on and the model has
    /// planes). Returns the ellipsoid instances inside the frustum.
    fn select_ellipsoids(
        &mut self,
        view: &mut View,
        camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
        impostors: bool,
    ) -> u32 {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let level = self.settings.pixel_level();
        let draw_lines = self.settings.lines;
        let mut visible = 0;
        for (i, instance) in self.instances.iter().enumerate() {
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let Some(model) = self.models.get(instance.model as usize) else { continue };
            let Some(ellipsoids) = &model.ellipsoids else {
                if !(impostors && model.planes.is_some()) {
                    view.spt_instances.push(*instance);
                    view.spt_map.push(index);
                }
                continue;
            };
            self.ellipsoid_ranges.clear();
            let leaves_seen = ellipsoids.select_per_pixel_blended(
                instance.transform,
                camera,
                &frustum,
                lod_settings,
                level,
                &mut self.ellipsoid_ranges,
            );
            // The lines' sphere holds their radii: they may be in view where the leaves are not.
            let lines = model.lines.as_ref().filter(|_| draw_lines);
            self.line_ranges.clear();
            let lines_seen = lines.is_some_and(|lines| {
                let ranges = &mut self.line_ranges;
                lines.select_per_pixel_blended(instance.transform, camera, &frustum, lod_settings, level, ranges)
            });
            if !(leaves_seen || lines_seen) {
                continue;
            }
            visible += 1;
            for range in &self.ellipsoid_ranges {
                view.ellipsoid_draws.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            for range in &self.line_ranges {
                view.line_draws.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            if lines.is_none() {
                view.pruned.extend(model.bark_draw(index, instance.model, 1.0));
            }
        }
        visible
    }

    /// Which instances are drawn with a baseline this frame ([`Settings::baseline`]): appends to
    /// `view`'s `pruned` with LoD chain draws or `billboard_draws` for instances whose model has the
    /// baseline, and `spt_instances`/`spt_map` with the others. Returns the baseline instances
    /// inside the frustum.
    fn select_baseline(&mut self, view: &mut View, baseline: Baseline, camera: &treelod_runtime::Camera) -> u32 {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let mut visible = 0;
        for (i, instance) in self.instances.iter().enumerate() {
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let m = instance.model as usize;
            let (Some(model), Some(lod)) = (self.models.get(m), self.lods.get(m)) else { continue };
            let has = match baseline {
                Baseline::LodChain => model.chain.is_some(),
                Baseline::Billboard(_) => model.billboards.is_some(),
            };
            if !has {
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            }
            let Some(tau) = instance_tau(
                instance.transform,
                camera,
                &frustum,
                self.settings.s_min,
                lod.cull_sphere(),
                model.block_centre(),
            ) else {
                continue;
            };
            visible += 1;
            match (baseline, &model.chain, &model.billboards) {
                (Baseline::LodChain, Some(chain), _) => {
                    let (range, error) = match chain.chain.pick(tau) {
                        Some(level) => (
                            chain.levels.get(level as usize).copied().unwrap_or(chain.full),
                            chain.level_error(level as usize),
                        ),
                        None => (chain.full, 0.0),
                    };
                    view.pruned.extend(Model::whole_draw(
                        index,
                        instance.model,
                        DrawSource::LodLevel,
                        range,
                        tau,
                        error,
                    ));
                }
                (Baseline::Billboard(kind), _, Some(billboards)) => {
                    let (first, count) = match kind {
                        BillboardKind::Facing => billboards.facing,
                        BillboardKind::Crossed => billboards.crossed,
                    };
                    if count > 0 {
                        view.billboard_draws.push((index, instance.model, first, count));
                    }
                }
                _ => {}
            }
        }
        visible
    }

    /// Which instances are drawn pruned this frame (see [`Pruning`]): appends to `view`'s `pruned`
    /// their draws and `spt_instances`/`spt_map` with the others. Returns the pruned instances inside
    /// the frustum and the leaves they draw. Only the camera's view (`main`) holds `λ` between
    /// frames and lists trees for the occlusion test.
    fn select_pruned(
        &mut self,
        view: &mut View,
        pruning: &Pruning,
        camera: &treelod_runtime::Camera,
        main: bool,
    ) -> (u32, u64) {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let world_per_pixel = camera.world_per_pixel();
        if main {
            self.occlusion_jobs.clear();
        }
        let (mut visible, mut leaves) = (0u32, 0u64);
        for (i, instance) in self.instances.iter().enumerate() {
            let m = instance.model as usize;
            let (Some(model), Some(lod)) = (self.models.get(m), self.lods.get(m)) else { continue };
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let scale = max_axis_scale(instance.transform);
            let (centre, radius) = lod.cull_sphere();
            let world_centre = instance.transform.transform_point3(centre);
            let height = model.prune.as_ref().map_or(0.0, |p| {
                projected_height(p.height(), scale, world_centre.distance(camera.position), world_per_pixel)
            });
            let Some(prune) = model.prune.as_ref().filter(|_| height >= pruning.spt_below_pixels) else {
                if main {
                    self.prune_shown[i] = None;
                }
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            };
            if !frustum.intersects_sphere(world_centre, radius * scale) {
                if main {
                    self.prune_shown[i] = None;
                }
                continue;
            }
            visible += 1;
            if main && pruning.occlusion && model.samples.1 > 0 {
                self.occlusion_jobs.push(Job {
                    instance: index,
                    transform: instance.transform,
                    centre,
                    radius: radius * scale,
                    first: model.samples.0,
                    count: model.samples.1,
                });
            }
            let target = pruning.lambda.unwrap_or_else(|| prune.lambda_at(height));
            // A shadow cascade prunes by the tree's height in texels, with no hysteresis and no
            // occlusion: what the camera cannot see may still cast.
            let lambda = if main {
                let seen = if pruning.occlusion { self.visible_fraction[i].max(MIN_VISIBLE_FRACTION) } else { 1.0 };
                let lambda = pruning.hysteresis.update(self.prune_shown[i], target * seen);
                self.prune_shown[i] = Some(lambda);
                lambda
            } else {
                target
            };
            let factor = size_factor(leaf_scale(pruning.scale, prune.scale_curve(), lambda));
            for cell in prune.cells() {
                let drawn = leaves_drawn(cell.leaves.count, lambda);
                let (first, count) = prune.prefix_triangles(cell, drawn);
                leaves += u64::from(drawn);
                if count > 0 {
                    view.pruned.push(PrunedDraw {
                        instance: index,
                        model: instance.model,
                        cell: cell.cell,
                        source: DrawSource::PrunedLeaves,
                        first,
                        count,
                        lambda,
                        leaf_scale: factor,
                        tau_triangles: factor,
                    });
                }
            }
            view.pruned.extend(model.bark_draw(index, instance.model, lambda));
        }
        (visible, leaves)
    }

    /// The selection of the last [`Self::prepare`] (before residency clamped it).
    #[must_use]
    pub fn selection(&self) -> &DrawList {
        &self.main.selection
    }

    /// The draws of the last [`Self::prepare`], as recorded for the GPU, in selection order.
    #[must_use]
    pub fn draws(&self) -> &[RecordedDraw] {
        &self.main.recorded
    }

    /// The points of the last [`Self::prepare`]'s draws that the vertex shader keeps (those in the
    /// cut: [`treelod_runtime::point_drawn`] at each draw's thresholds), as opposed to
    /// [`FrameStats::points`], the prefixes submitted. A scan of the submitted points on the CPU,
    /// for tools and reports, not for every frame of a host; 0 after a GPU-selected frame.
    #[must_use]
    pub fn points_in_cut(&self) -> u64 {
        let mut drawn = 0u64;
        for draw in &self.main.recorded {
            let (Some(model), Some(lod)) =
                (self.models.get(draw.model.0 as usize), self.lods.get(draw.model.0 as usize))
            else {
                continue;
            };
            let points = model.container.points();
            let t = treelod_runtime::Thresholds { points: draw.tau_points, triangles: draw.tau_triangles };
            let count = draw.count as usize;
            let kept = |p: &PointRecord| treelod_runtime::point_drawn(p, t);
            drawn += match draw.source {
                DrawSource::Points => {
                    let first = model.container.cells().get(draw.cell as usize).map_or(0, |c| c.points.first as usize);
                    points.get(first..first + count).unwrap_or_default().iter().filter(|p| kept(p)).count()
                }
                DrawSource::Roots => {
                    let at = if draw.cell == ROOTS_CELL {
                        0
                    } else {
                        model.cell_roots.get(draw.cell as usize).map_or(0, |r| r.0 as usize)
                    };
                    lod.roots()
                        .get(at..at + count)
                        .unwrap_or_default()
                        .iter()
                        .filter_map(|&i| points.get(i as usize))
                        .filter(|p| kept(p))
                        .count()
                }
                DrawSource::Triangles
                | DrawSource::PrunedLeaves
                | DrawSource::Bark
                | DrawSource::Planes
                | DrawSource::LodLevel
                | DrawSource::Billboards
                | DrawSource::Ellipsoids
                | DrawSource::Lines => 0,
            } as u64;
        }
        drawn
    }

    /// Leading triangles and points of a cell's ranges that are resident on the GPU.
    #[must_use]
    pub fn resident(&self, model: ModelId, cell: u32) -> (u32, u32) {
        let (m, c) = (model.0 as usize, cell as usize);
        (self.residency.slot(m, c, Array::Triangles).resident, self.residency.slot(m, c, Array::Points).resident)
    }

    /// Selects what to draw for `camera` (per instance and cell, spec §10, with
    /// [`treelod_runtime::select_frame`]), streams what the selection needs within the budgets,
    /// and uploads the draws, clamped to what is resident. With [`Settings::shadows`], also fits
    /// the cascades to `camera` and selects each from the sun's view (sizes in texels), streaming
    /// what they need beside the camera's selection; [`Self::render_shadows`] draws them.
    pub fn prepare(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, camera: &Camera) -> FrameStats {
        let settings = self.settings;
        let view_proj = camera.view_proj();
        let (s_min, s_max) = if settings.full_mesh { (0.0, 0.0) } else { (settings.s_min, settings.s_max) };
        let lod_settings = LodSettings {
            s_min,
            s_max,
            depth_bias_k: settings.depth_bias_k,
            shading: settings.shading,
            ..LodSettings::default()
        };
        let runtime_camera = treelod_runtime::Camera {
            position: camera.position,
            view_proj,
            viewport_height: camera.height as f32,
            fovy: camera.fovy,
        };
        let baseline = settings.baseline.filter(|_| !settings.full_mesh);
        let impostors = settings.impostors && !settings.full_mesh && baseline.is_none();
        let ellipsoids = settings.ellipsoids && !settings.full_mesh && baseline.is_none();
        let pruning =
            settings.pruning.filter(|_| !settings.full_mesh && !impostors && !ellipsoids && baseline.is_none());
        let modes = Modes { baseline, impostors, ellipsoids, pruning };
        let forward = -camera.view.row(2).truncate().normalize_or(Vec3::NEG_Z);
        self.last_camera = Some((view_proj, camera.position, forward, (camera.width, camera.height)));
        if let Some(pruning) = &pruning
            && pruning.occlusion
        {
            self.occlusion.collect(device, camera.position, forward, &mut self.visible_fraction);
        }
        self.cascades = match settings.shadows {
            Some(mut shadows) => {
                shadows.resolution = shadows.resolution.clamp(1, device.limits().max_texture_dimension_2d);
                fit_cascades(camera, settings.sun, &shadows, self.scene_bounds)
            }
            None => Vec::new(),
        };
        self.ensure_shadow_maps(device, queue);
        if self.gpu_instances_stale
            && let Some(gpu) = &mut self.gpu
        {
            gpu.set_instances(device, queue, &self.instances, &self.lods);
        }
        self.gpu_instances_stale = false;
        self.gpu_frame = false;
        if pruning.is_none()
            && !settings.full_mesh
            && !impostors
            && !ellipsoids
            && baseline.is_none()
            && self.cascades.is_empty()
            && let Some(gpu) = self.gpu.as_mut().filter(|g| g.usable())
        {
            // GPU selection: one compute submission writes the draws; nothing per instance here.
            self.main = View::default();
            let counts = gpu.prepare(device, queue, select_frame_gpu(&runtime_camera, &lod_settings));
            gpu.ensure_frame_group(device, &self.frame_layout, &self.frame_buffer);
            let pool_bytes = gpu.pool_bytes();
            self.gpu_frame = true;
            self.write_frame_uniform(queue, camera);
            return FrameStats {
                instances_visible: counts.instances_visible,
                ranges: counts.ranges,
                triangles: counts.triangles,
                points: counts.points,
                bytes_resident: self.models.iter().map(|m| m.static_bytes).sum::<u64>()
                    + u64::from(self.residency.pool.used()) * UNIT
                    + pool_bytes,
                gpu_selection: true,
                ranges_dropped: counts.dropped,
                ..FrameStats::default()
            };
        }

        // The camera's selection, then each cascade's.
        let mut main = std::mem::take(&mut self.main);
        let counts = self.select_view(&mut main, &runtime_camera, &lod_settings, modes, true);
        let mut shadow_views = std::mem::take(&mut self.shadow_views);
        shadow_views.resize_with(self.cascades.len(), View::default);
        let mut shadow =
            ShadowStats { cascades: u32::try_from(self.cascades.len()).unwrap_or(0), ..ShadowStats::default() };
        for (k, view) in shadow_views.iter_mut().enumerate() {
            let light = self.cascades[k].selection_camera();
            shadow.instances_visible += self.select_view(view, &light, &lod_settings, modes, false).instances_visible;
        }

        // What each cell needs: the largest prefix any view asked for.
        self.residency.begin_frame();
        self.requests.clear();
        for view in std::iter::once(&main).chain(&shadow_views) {
            self.request(view, settings.full_mesh);
        }
        for request in &mut self.requests {
            request.wanted = self.wanted[request.model][request.cell][request.array as usize];
        }
        self.uploads.clear();
        let streamed = self.residency.stream(&mut self.requests, settings.upload_budget, &mut self.uploads);
        for request in &self.requests {
            self.wanted[request.model][request.cell] = [0; 2];
        }
        self.grow_pool_buffer(device, queue);
        let mut points = Vec::new();
        for upload in &self.uploads {
            let Some(model) = self.models.get(upload.model) else { continue };
            let (first, end) = (upload.first as usize, (upload.first + upload.count) as usize);
            let data: &[u8] = match upload.array {
                Array::Triangles => bytemuck::cast_slice(&model.container.triangles()[first..end]),
                Array::Points => bytemuck::cast_slice(gpu_points(
                    &model.container,
                    first,
                    &model.container.points()[first..end],
                    &mut points,
                )),
            };
            queue.write_buffer(&self.pool_buffer, upload.offset, data);
        }

        // The draws of every view, clamped to what is resident, bucketed by model and kind.
        self.draw_infos.clear();
        self.indirect.clear();
        let mut stats = FrameStats {
            instances_visible: counts.instances_visible,
            instances_pruned: counts.instances_pruned,
            leaves_pruned: counts.leaves_pruned,
            instances_impostors: counts.instances_impostors,
            instances_ellipsoids: counts.instances_ellipsoids,
            instances_baseline: counts.instances_baseline,
            bytes_uploaded: streamed.bytes_uploaded,
            bytes_resident: self.models.iter().map(|m| m.static_bytes).sum::<u64>()
                + u64::from(self.residency.pool.used()) * UNIT,
            ..FrameStats::default()
        };
        self.record_view(&mut main, settings.full_mesh, &mut stats);
        for view in &mut shadow_views {
            let mut counted = FrameStats::default();
            self.record_view(view, settings.full_mesh, &mut counted);
            shadow.ranges += counted.ranges;
            shadow.ranges_clamped += counted.ranges_clamped;
            shadow.triangles += counted.triangles;
            shadow.points += counted.points;
            shadow.planes += counted.planes;
            shadow.billboards += counted.billboards;
            shadow.ellipsoids += counted.ellipsoids;
            shadow.lines += counted.lines;
        }
        stats.shadow = shadow;
        self.main = main;
        self.shadow_views = shadow_views;

        self.write_frame_uniform(queue, camera);
        let draw_bytes = (self.draw_infos.len().max(1) * size_of::<DrawInfo>()) as u64;
        if draw_bytes > self.draw_buffer.size() {
            self.draw_buffer = storage_buffer(device, "treelod draws", draw_bytes.next_power_of_two(), false);
            self.frame_bind_groups =
                frame_bind_groups(device, &self.frame_layout, &self.frame_buffer, &self.draw_buffer, &self.pool_buffer);
        }
        if !self.draw_infos.is_empty() {
            queue.write_buffer(&self.draw_buffer, 0, bytemuck::cast_slice(&self.draw_infos));
        }
        let indirect_bytes = (self.indirect.len().max(1) * size_of::<wgpu::util::DrawIndirectArgs>()) as u64;
        if indirect_bytes > self.indirect_buffer.size() {
            self.indirect_buffer = indirect_buffer(device, self.indirect.len().next_power_of_two() as u64);
        }
        if !self.indirect.is_empty() {
            let bytes: Vec<u8> = self.indirect.iter().flat_map(|a| a.as_bytes().iter().copied()).collect();
            queue.write_buffer(&self.indirect_buffer, 0, &bytes);
        }
        stats
    }

    /// Selects one view (its lists cleared first): the trees drawn pruned, with impostors or a
    /// baseline per `modes`, and the others with the sequential point trees. `main`: the camera's view (see
    /// [`Self::select_pruned`]).
    fn select_view(
        &mut self,
        view: &mut View,
        camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
        modes: Modes,
        main: bool,
    ) -> ViewCounts {
        let mut counts = ViewCounts::default();
        view.pruned.clear();
        view.billboard_draws.clear();
        view.plane_draws.clear();
        view.ellipsoid_draws.clear();
        view.line_draws.clear();
        view.spt_instances.clear();
        view.spt_map.clear();
        if let Some(pruning) = &modes.pruning {
            (counts.instances_pruned, counts.leaves_pruned) = self.select_pruned(view, pruning, camera, main);
        }
        if let Some(baseline) = modes.baseline {
            counts.instances_baseline = self.select_baseline(view, baseline, camera);
        }
        if modes.ellipsoids {
            counts.instances_ellipsoids = self.select_ellipsoids(view, camera, lod_settings, modes.impostors);
        }
        if modes.impostors {
            counts.instances_impostors = self.select_impostors(view, camera, modes.ellipsoids);
        }
        view.spt_remapped = modes.pruning.is_some() || modes.impostors || modes.ellipsoids || modes.baseline.is_some();
        let spt_instances = if view.spt_remapped { &view.spt_instances } else { &self.instances };
        let selected = select_frame(&self.lods, spt_instances, camera, lod_settings, &mut view.selection);
        counts.instances_visible = selected.instances_visible
            + counts.instances_pruned
            + counts.instances_impostors
            + counts.instances_ellipsoids
            + counts.instances_baseline;
        counts
    }

    /// Adds the prefixes `view`'s selection needs to this frame's requests (`wanted` holds the
    /// largest per cell).
    fn request(&mut self, view: &View, full_mesh: bool) {
        for range in view.selection.ranges() {
            let array = match range.kind {
                Kind::Triangles => Array::Triangles,
                Kind::Points => Array::Points,
                Kind::Roots => continue,
            };
            let (m, c) = (range.model as usize, range.cell as usize);
            if full_mesh && array == Array::Points {
                // The full mesh needs points only while its triangles are not all resident.
                let wanted_triangles = self.wanted[m][c][0];
                if self.residency.slot(m, c, Array::Triangles).resident >= wanted_triangles {
                    continue;
                }
            }
            let wanted = &mut self.wanted[m][c][array as usize];
            if *wanted == 0 {
                self.requests.push(Request { model: m, cell: c, array, first: range.first, wanted: 0 });
            }
            *wanted = (*wanted).max(range.count);
        }
    }

    /// Records `view`'s draws, clamped to what is resident, after the draw infos and indirect
    /// draws of the views before it; counts them into `stats`.
    fn record_view(&mut self, view: &mut View, full_mesh: bool, stats: &mut FrameStats) {
        view.recorded.clear();
        self.buckets.resize_with(BUCKETS * self.models.len(), Vec::new);
        for bucket in &mut self.buckets {
            bucket.clear();
        }
        let ranges = view.selection.ranges();
        let mut i = 0;
        while i < ranges.len() {
            let range = ranges[i];
            // A cell's triangle range is followed by its point range, if any.
            let points = ranges
                .get(i + 1)
                .filter(|next| {
                    range.kind == Kind::Triangles
                        && next.kind == Kind::Points
                        && (next.instance, next.cell) == (range.instance, range.cell)
                })
                .copied();
            i += 1 + usize::from(points.is_some());
            let (triangles, points) = match range.kind {
                Kind::Triangles => (Some(range), points),
                Kind::Points | Kind::Roots => (None, Some(range)),
            };
            let instance = view.instance_index(range.instance);
            for draw in self.clamp(instance, range, triangles, points, full_mesh) {
                let Some(draw) = draw else { continue };
                stats.ranges_clamped += u32::from(draw.clamped);
                let (bucket, first_vertex, corners) = self.gpu_first(&draw);
                match draw.source {
                    DrawSource::Triangles | DrawSource::PrunedLeaves | DrawSource::Bark | DrawSource::LodLevel => {
                        stats.triangles += u64::from(draw.count);
                    }
                    DrawSource::Points | DrawSource::Roots => stats.points += u64::from(draw.count),
                    DrawSource::Planes => stats.planes += u64::from(draw.count),
                    DrawSource::Billboards => stats.billboards += u64::from(draw.count),
                    DrawSource::Ellipsoids => stats.ellipsoids += u64::from(draw.count),
                    DrawSource::Lines => stats.lines += u64::from(draw.count),
                }
                let transform = self.instances[draw.instance as usize].transform;
                let info = DrawInfo {
                    model: transform.to_cols_array_2d(),
                    tau_p: draw.tau_points,
                    tau_t: draw.tau_triangles,
                    cell: draw.cell,
                    scale: max_axis_scale(transform),
                    shading: range.shading,
                    leaf_scale: 1.0,
                    instance: draw.instance,
                    _pad: 0,
                };
                self.buckets[bucket].push((info, first_vertex, draw.count * corners));
                view.recorded.push(draw);
            }
        }
        // Pruned trees: leaves and bark from each model's extra triangles, unshaded by Gilet's
        // per-cell estimate (it is a property of the point hierarchy's cells).
        for draw in &view.pruned {
            stats.triangles += u64::from(draw.count);
            let record = RecordedDraw {
                instance: draw.instance,
                model: ModelId(draw.model),
                cell: draw.cell,
                source: draw.source,
                count: draw.count,
                tau_points: draw.lambda,
                tau_triangles: draw.tau_triangles,
                clamped: false,
            };
            let vertices = (3 * draw.first, 3 * draw.count);
            record_direct(&self.instances, &mut self.buckets, &mut view.recorded, record, 2, vertices, draw.leaf_scale);
        }
        // Impostor planes (bucket 3), ellipsoids (bucket 5) and lines (bucket 6): a prefix of one
        // cell's elements, six corners each, the level chosen in the shader by `τ`.
        stats.planes += view.plane_draws.iter().map(|d| u64::from(d.range.count)).sum::<u64>();
        stats.ellipsoids += view.ellipsoid_draws.iter().map(|d| u64::from(d.range.count)).sum::<u64>();
        stats.lines += view.line_draws.iter().map(|d| u64::from(d.range.count)).sum::<u64>();
        let prefixes = (view.plane_draws.iter().map(|d| (d, DrawSource::Planes, 3)))
            .chain(view.ellipsoid_draws.iter().map(|d| (d, DrawSource::Ellipsoids, 5)))
            .chain(view.line_draws.iter().map(|d| (d, DrawSource::Lines, 6)));
        for (draw, source, bucket) in prefixes {
            let range = draw.range;
            let record = RecordedDraw {
                instance: draw.instance,
                model: ModelId(draw.model),
                cell: range.cell,
                source,
                count: range.count,
                tau_points: range.tau,
                tau_triangles: range.tau,
                clamped: false,
            };
            let vertices = (6 * range.first, 6 * range.count);
            record_direct(&self.instances, &mut self.buckets, &mut view.recorded, record, bucket, vertices, 1.0);
        }
        // Baseline billboards: every quad of the chosen kind.
        for &(instance, model, first, count) in &view.billboard_draws {
            stats.billboards += u64::from(count);
            let record = RecordedDraw {
                instance,
                model: ModelId(model),
                cell: ROOTS_CELL,
                source: DrawSource::Billboards,
                count,
                tau_points: 0.0,
                tau_triangles: 0.0,
                clamped: false,
            };
            record_direct(
                &self.instances,
                &mut self.buckets,
                &mut view.recorded,
                record,
                4,
                (6 * first, 6 * count),
                1.0,
            );
        }
        view.model_draws.clear();
        let before = self.indirect.len();
        for pair in self.buckets.chunks(BUCKETS) {
            let mut draws = [(0, 0); BUCKETS];
            for (kind, bucket) in pair.iter().enumerate() {
                let start = u32::try_from(self.indirect.len()).unwrap_or(u32::MAX);
                for &(info, first_vertex, vertex_count) in bucket {
                    let index = u32::try_from(self.draw_infos.len()).unwrap_or(u32::MAX);
                    self.draw_infos.push(info);
                    self.indirect.push(wgpu::util::DrawIndirectArgs {
                        vertex_count,
                        instance_count: 1,
                        first_vertex,
                        first_instance: index,
                    });
                }
                draws[kind] = (start, u32::try_from(self.indirect.len()).unwrap_or(u32::MAX) - start);
            }
            view.model_draws.push(draws);
        }
        stats.ranges += u32::try_from(self.indirect.len() - before).unwrap_or(u32::MAX);
    }

    /// Creates the shadow maps this frame's cascades need when their size or number changed (a
    /// 1×1 stand-in without shadows), and writes the receivers' uniform.
    fn ensure_shadow_maps(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
        // Without shadows a 1×1 map stands in (and a larger one is freed).
        let size = self
            .cascades
            .first()
            .map_or((1, 1), |cascade| (cascade.resolution, u32::try_from(self.cascades.len()).unwrap_or(1)));
        if self.shadow_maps.size != size {
            self.shadow_maps = ShadowMaps::new(device, &self.shadow_layout, size.0, size.1);
        }
        let normal_offset = self.settings.shadows.map_or(0.0, |s| s.normal_offset);
        let uniform = ShadowUniform::new(&self.cascades, normal_offset);
        queue.write_buffer(&self.shadow_maps.uniform, 0, bytemuck::bytes_of(&uniform));
    }

    /// Writes the frame uniforms (camera, light, debug view) for `camera` and for each cascade's
    /// shadow pass.
    fn write_frame_uniform(&self, queue: &wgpu::Queue, camera: &Camera) {
        let settings = &self.settings;
        let (right, up) = camera.right_up();
        let sun = settings.sun.normalize_or(Vec3::Y);
        let uniform = FrameUniform {
            view_proj: camera.view_proj().to_cols_array_2d(),
            eye: camera.position.extend(camera.height as f32).to_array(),
            right: right.extend(camera.proj.y_axis.y).to_array(),
            up: up.extend(settings.point_scale.max(0.0)).to_array(),
            sun: Vec4::new(sun.x, sun.y, sun.z, settings.ambient.clamp(0.0, 1.0)).to_array(),
            sun_colour: settings.sun_colour.max(Vec3::ZERO).extend(1.0).to_array(),
            debug: match settings.debug {
                DebugView::Shaded => 0,
                DebugView::Cells => 1,
                DebugView::Kinds => 2,
                DebugView::Levels => 3,
            },
            morph: u32::from(settings.impostor_morph),
            ambient_occlusion: u32::from(settings.ambient_occlusion),
            level_blend: settings.pixel_level().clamped_blend(),
            stochastic_alpha: u32::from(settings.stochastic_alpha),
            pad: [0; 3],
        };
        queue.write_buffer(&self.frame_buffer, 0, bytemuck::bytes_of(&uniform));
        for (k, cascade) in self.cascades.iter().enumerate() {
            let (eye, right, up) = crate::shadows::cascade_frame(cascade);
            let light = FrameUniform {
                view_proj: cascade.view_proj.to_cols_array_2d(),
                eye: eye.to_array(),
                right: right.to_array(),
                up: up.extend(settings.point_scale.max(0.0)).to_array(),
                debug: 0,
                ..uniform
            };
            queue.write_buffer(&self.frame_buffer, (k as u64 + 1) * FRAME_UNIFORM_STRIDE, bytemuck::bytes_of(&light));
        }
    }

    /// The draws of one selected cell (or one roots range), clamped to what is resident so that
    /// a missing prefix shows coarser data, never a hole:
    ///
    /// - **Points**: if only `r` leading points are resident, `τ_p` rises to the `hi` of the first
    ///   missing one, so every point the cut needs lies in the resident prefix; with nothing (or
    ///   less than the roots) resident, the cell draws its roots from the pinned copy.
    /// - **Triangles**: `τ_t` rises to at least `τ_p` (the rule needs `τ_p ≤ τ_t`) and, if only `r`
    ///   leading triangles are resident, to the size of the first missing one; the smaller
    ///   triangles are then drawn through their points.
    ///
    /// For any `τ_p ≤ τ_t` the drawn elements are an exact cut (spec §10), so a clamped cell is a
    /// valid coarser level of detail.
    fn clamp(
        &self,
        instance: u32,
        range: DrawRange,
        triangles: Option<DrawRange>,
        points: Option<DrawRange>,
        full_mesh: bool,
    ) -> [Option<RecordedDraw>; 2] {
        let base = RecordedDraw {
            instance,
            model: ModelId(range.model),
            cell: range.cell,
            source: DrawSource::Roots,
            count: 0,
            tau_points: range.tau_points,
            tau_triangles: range.tau_triangles,
            clamped: false,
        };
        let (m, c) = (range.model as usize, range.cell as usize);
        let (Some(model), Some(lod)) = (self.models.get(m), self.lods.get(m)) else { return [None, None] };
        if range.kind == Kind::Roots {
            return [None, Some(RecordedDraw { count: range.count, ..base })];
        }
        let Some(cell) = model.cell_lod.get(c).and_then(|&i| lod.cells().get(i as usize)) else {
            return [None, None];
        };
        let (sizes, his) = (lod.triangle_sizes(cell), lod.point_hi(cell));
        let (mut tau_p, mut tau_t) = (range.tau_points, range.tau_triangles);
        let resident_t = self.residency.slot(m, c, Array::Triangles).resident as usize;
        let resident_p = self.residency.slot(m, c, Array::Points).resident as usize;
        let roots = model.cell_roots.get(c).map_or(0, |r| r.1) as usize;
        let triangles_complete = triangles.is_none_or(|t| resident_t >= t.count as usize);
        let mut point_draw = None;
        let mut clamped = false;
        if let Some(p) = points.filter(|_| !(full_mesh && triangles_complete)) {
            let wanted = p.count as usize;
            let (source, count) = if resident_p >= wanted {
                (DrawSource::Points, wanted)
            } else if resident_p >= roots.max(1) {
                tau_p = tau_p.max(his[resident_p]);
                (DrawSource::Points, leading_above(his, tau_p))
            } else {
                tau_p = tau_p.max(his.get(roots).copied().unwrap_or(tau_p));
                (DrawSource::Roots, roots)
            };
            clamped |= count < wanted || source == DrawSource::Roots;
            if count > 0 {
                point_draw = Some((source, count));
            }
        }
        tau_t = tau_t.max(tau_p);
        let mut count_t = leading_above(sizes, tau_t);
        if count_t > resident_t {
            tau_t = tau_t.max(sizes[resident_t]);
            count_t = leading_above(sizes, tau_t);
        }
        clamped |= triangles.is_some_and(|t| count_t < t.count as usize);
        let base = RecordedDraw { tau_points: tau_p, tau_triangles: tau_t, clamped, ..base };
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        [
            (count_t > 0).then(|| RecordedDraw { source: DrawSource::Triangles, count: count(count_t), ..base }),
            point_draw.map(|(source, n)| RecordedDraw { source, count: count(n), ..base }),
        ]
    }

    /// The bucket (model × kind), first vertex and vertices per element of a recorded draw.
    fn gpu_first(&self, draw: &RecordedDraw) -> (usize, u32, u32) {
        let m = draw.model.0 as usize;
        let model = &self.models[m];
        match draw.source {
            DrawSource::Triangles => {
                let slot = self.residency.slot(m, draw.cell as usize, Array::Triangles);
                (BUCKETS * m, 2 * slot.start * 3, 3)
            }
            DrawSource::Points => {
                let slot = self.residency.slot(m, draw.cell as usize, Array::Points);
                (BUCKETS * m + 1, slot.start * 6, 6)
            }
            DrawSource::Roots => {
                let at = if draw.cell == ROOTS_CELL {
                    0
                } else {
                    model.cell_roots.get(draw.cell as usize).map_or(0, |r| r.0)
                };
                (BUCKETS * m + 1, (model.roots_start + at) * 6, 6)
            }
            // Recorded directly by `prepare`, never clamped.
            DrawSource::PrunedLeaves | DrawSource::Bark | DrawSource::LodLevel => (BUCKETS * m + 2, 0, 3),
            DrawSource::Planes => (BUCKETS * m + 3, 0, 6),
            DrawSource::Billboards => (BUCKETS * m + 4, 0, 6),
            DrawSource::Ellipsoids => (BUCKETS * m + 5, 0, 6),
            DrawSource::Lines => (BUCKETS * m + 6, 0, 6),
        }
    }

    /// Measures which of the trees drawn pruned this frame are hidden, for the occlusion factor
    /// of later frames ([`Pruning::occlusion`]): call it after the pass that drew this frame,
    /// in the same or a later encoder, with that pass's depth attachment (`depth_view`, which
    /// needs [`wgpu::TextureUsages::TEXTURE_BINDING`]). It records a small compute pass; the
    /// result is read by a later [`Self::prepare`] without waiting for the GPU. Does nothing when
    /// pruning or its occlusion factor is off, or while an earlier measurement is in flight.
    pub fn measure_occlusion(
        &mut self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        depth_view: &wgpu::TextureView,
    ) {
        let on = self.settings.pruning.is_some_and(|p| p.occlusion) && !self.settings.full_mesh;
        let Some((view_proj, eye, forward, size)) = self.last_camera.filter(|_| on) else { return };
        self.occlusion.record(device, encoder, depth_view, size, view_proj, eye, forward, &self.occlusion_jobs);
    }

    /// The visible fraction of each instance's hull samples last measured by
    /// [`Self::measure_occlusion`] (1 where never measured, off-screen or after a camera jump).
    #[must_use]
    pub fn visible_fractions(&self) -> &[f32] {
        &self.visible_fraction
    }

    /// Records this frame's draws into the host's pass (after [`Self::prepare`]).
    pub fn render(&self, pass: &mut wgpu::RenderPass<'_>) {
        if self.gpu_frame
            && let Some(gpu) = &self.gpu
        {
            let group = |m: usize| self.models.get(m).map(|model| &model.bind_group);
            pass.set_bind_group(2, &self.shadow_maps.bind_group, &[]);
            gpu.render(pass, [&self.triangle_pipeline, &self.point_pipeline], group);
            return;
        }
        pass.set_bind_group(0, &self.frame_bind_groups[0], &[]);
        pass.set_bind_group(2, &self.shadow_maps.bind_group, &[]);
        let pipelines = [
            &self.triangle_pipeline,
            &self.point_pipeline,
            &self.pruned_pipeline,
            &self.plane_pipeline,
            &self.billboard_pipeline,
            &self.ellipsoid_pipeline,
            &self.line_pipeline,
        ];
        self.draw_view(pass, &self.main, pipelines);
    }

    /// Draws `view`'s buckets with `pipelines` (in bucket order) into `pass`, whose frame bind
    /// group is set.
    fn draw_view(&self, pass: &mut wgpu::RenderPass<'_>, view: &View, pipelines: [&wgpu::RenderPipeline; BUCKETS]) {
        let stride = size_of::<wgpu::util::DrawIndirectArgs>() as u64;
        for (kind, pipeline) in pipelines.into_iter().enumerate() {
            pass.set_pipeline(pipeline);
            for (model, draws) in self.models.iter().zip(&view.model_draws) {
                let (first, count) = draws[kind];
                if count == 0 {
                    continue;
                }
                let group = match (kind, &model.billboards) {
                    (4, Some(billboards)) => &billboards.bind_group,
                    _ => &model.bind_group,
                };
                pass.set_bind_group(1, group, &[]);
                pass.multi_draw_indirect(&self.indirect_buffer, u64::from(first) * stride, count);
            }
        }
    }

    /// Records this frame's shadow pass ([`Settings::shadows`], after [`Self::prepare`]): one
    /// depth-only pass per cascade into the renderer's shadow maps, drawing what each cascade
    /// selected. Record it before the host's pass that calls [`Self::render`] (in the same
    /// encoder or an earlier submission): that pass samples the maps. Does nothing without
    /// shadows.
    pub fn render_shadows(&self, encoder: &mut wgpu::CommandEncoder) {
        let shadow_pipelines = [
            &self.shadow_pipelines[0],
            &self.shadow_pipelines[1],
            &self.shadow_pipelines[2],
            &self.shadow_pipelines[3],
            &self.shadow_pipelines[4],
            &self.shadow_pipelines[5],
            &self.shadow_pipelines[6],
        ];
        for (k, view) in self.shadow_views.iter().enumerate().take(self.cascades.len()) {
            let Some(layer) = self.shadow_maps.layers.get(k) else { continue };
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("treelod shadow cascade"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: layer,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
                    stencil_ops: None,
                }),
                ..wgpu::RenderPassDescriptor::default()
            });
            pass.set_bind_group(0, &self.frame_bind_groups[k + 1], &[]);
            self.draw_view(&mut pass, view, shadow_pipelines);
        }
    }

    /// World bounds (min, max) of the instances: the union of their containers' block bounds,
    /// transformed; `None` without instances (or with only empty or non-finite blocks).
    #[must_use]
    pub fn instance_bounds(&self) -> Option<(Vec3, Vec3)> {
        self.scene_bounds
    }

    /// This frame's shadow cascades (empty without [`Settings::shadows`]): what a host needs to
    /// draw its own receivers with [`Self::shadow_bind_group`].
    #[must_use]
    pub fn shadow_cascades(&self) -> &[Cascade] {
        &self.cascades
    }

    /// The layout of [`Self::shadow_bind_group`]: bind it as group 2 of a host pipeline that
    /// includes [`crate::SHADOW_WGSL`] and calls its `sunlit(world, normal, sun)`.
    #[must_use]
    pub fn shadow_bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        &self.shadow_layout
    }

    /// The receivers' bind group: this frame's cascades' matrices, the shadow maps and their
    /// comparison sampler (everything lit without [`Settings::shadows`]). It may be replaced by
    /// [`Self::prepare`] when the shadow settings change: fetch it each frame.
    #[must_use]
    pub fn shadow_bind_group(&self) -> &wgpu::BindGroup {
        &self.shadow_maps.bind_group
    }
}

/// Records a draw that streaming does not clamp (pruned leaves, bark, impostor planes: uploaded
/// whole): its `DrawInfo` (thresholds from `record`, unshaded) into the model's bucket `kind` with
/// `(first vertex, vertex count)`, and `record` itself.
fn record_direct(
    instances: &[treelod_runtime::Instance],
    buckets: &mut [Vec<(DrawInfo, u32, u32)>],
    recorded: &mut Vec<RecordedDraw>,
    record: RecordedDraw,
    kind: usize,
    (first_vertex, vertices): (u32, u32),
    leaf_scale: f32,
) {
    let transform = instances[record.instance as usize].transform;
    let info = DrawInfo {
        model: transform.to_cols_array_2d(),
        tau_p: record.tau_points,
        tau_t: record.tau_triangles,
        cell: record.cell,
        scale: max_axis_scale(transform),
        shading: 1.0,
        leaf_scale,
        instance: record.instance,
        _pad: 0,
    };
    buckets[BUCKETS * record.model.0 as usize + kind].push((info, first_vertex, vertices));
    recorded.push(record);
}

/// The axis-aligned bounds of the box `min..max` transformed by `transform`; an empty or
/// non-finite box gives an empty result (`+inf..-inf`).
fn transformed_bounds(transform: Mat4, min: Vec3, max: Vec3) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    if !(min.is_finite() && max.is_finite() && min.cmple(max).all()) {
        return (lo, hi);
    }
    for corner in 0..8 {
        let p = Vec3::new(
            if corner & 1 == 0 { min.x } else { max.x },
            if corner & 2 == 0 { min.y } else { max.y },
            if corner & 4 == 0 { min.z } else { max.z },
        );
        let q = transform.transform_point3(p);
        lo = lo.min(q);
        hi = hi.max(q);
    }
    (lo, hi)
}

/// Number of leading `values` (sorted largest first) above `tau`.
fn leading_above(values: &[f32], tau: f32) -> usize {
    values.partition_point(|&v| v > tau)
}

/// The largest axis scale of an affine transform (what selection converts sizes with).
fn max_axis_scale(m: Mat4) -> f32 {
    let (x, y, z) = (m.x_axis.truncate(), m.y_axis.truncate(), m.z_axis.truncate());
    x.length_squared().max(y.length_squared()).max(z.length_squared()).sqrt().max(1e-12)
}

/// Uploads an atlas with its mips; returns its view and the bytes uploaded.
fn upload_atlas(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    atlas: &textures::Atlas,
    label: &str,
) -> (wgpu::TextureView, u64) {
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: atlas.width, height: atlas.height, depth_or_array_layers: 1 },
        mip_level_count: u32::try_from(atlas.levels.len()).unwrap_or(1),
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: match (atlas.slots, atlas.srgb) {
            (true, _) => wgpu::TextureFormat::Rg16Uint,
            (false, true) => wgpu::TextureFormat::Rgba8UnormSrgb,
            (false, false) => wgpu::TextureFormat::Rgba8Unorm,
        },
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let mut bytes = 0u64;
    for (level, texels) in atlas.levels.iter().enumerate() {
        let level = u32::try_from(level).unwrap_or(0);
        let (w, h) = ((atlas.width >> level).max(1), (atlas.height >> level).max(1));
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: level,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            texels,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(w * 4), rows_per_image: Some(h) },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        bytes += texels.len() as u64;
    }
    (texture.create_view(&wgpu::TextureViewDescriptor::default()), bytes)
}

fn storage_buffer(device: &wgpu::Device, label: &str, size: u64, copy_src: bool) -> wgpu::Buffer {
    let copy = if copy_src { wgpu::BufferUsages::COPY_SRC } else { wgpu::BufferUsages::empty() };
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | copy,
        mapped_at_creation: false,
    })
}

fn indirect_buffer(device: &wgpu::Device, draws: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("treelod indirect"),
        size: draws.max(1) * size_of::<wgpu::util::DrawIndirectArgs>() as u64,
        usage: wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// The frame bind groups of the camera and of each cascade: the view's uniform, the draw infos,
/// and the pool bound twice (triangles, points).
fn frame_bind_groups(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    frame: &wgpu::Buffer,
    draws: &wgpu::Buffer,
    pool: &wgpu::Buffer,
) -> Vec<wgpu::BindGroup> {
    (0..=MAX_CASCADES as u64)
        .map(|view| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("treelod frame"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: frame,
                            offset: view * FRAME_UNIFORM_STRIDE,
                            size: wgpu::BufferSize::new(size_of::<FrameUniform>() as u64),
                        }),
                    },
                    wgpu::BindGroupEntry { binding: 1, resource: draws.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: pool.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: pool.as_entire_binding() },
                ],
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transformed_bounds_cover_the_rotated_box() {
        let t = Mat4::from_rotation_y(std::f32::consts::FRAC_PI_4);
        let (lo, hi) = transformed_bounds(t, Vec3::splat(-1.0), Vec3::splat(1.0));
        let r = std::f32::consts::SQRT_2;
        assert!((hi - Vec3::new(r, 1.0, r)).length() < 1e-5, "{hi}");
        assert!((lo + Vec3::new(r, 1.0, r)).length() < 1e-5, "{lo}");
        let (lo, hi) = transformed_bounds(t, Vec3::ONE, Vec3::ZERO);
        assert!(lo.x > hi.x, "an empty box stays empty");
    }
}
