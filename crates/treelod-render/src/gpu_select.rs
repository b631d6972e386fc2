//! GPU-driven selection: [`treelod_runtime::select_frame`] as compute shaders
//! (`shaders/select.wgsl`) that write the indirect draws themselves, for 10^5–10^6 instances.
//!
//! **Data.** When it is turned on ([`crate::Renderer::enable_gpu_selection`]) every model's
//! triangles and points are uploaded whole into a pool of their own (the streamed pool is left as
//! it is), with a contiguous copy of its far list (`ModelLod::far_list`, the roots first), so
//! every prefix selection can ask for is resident; a model that does not fit the memory budget is
//! refused. Next to it: per model the block sphere, culling box and far-list bounds of its
//! [`ModelLod`], per non-empty cell its bounds, ranges and first keys, and the cells' sorted keys
//! (triangle sizes, point `hi`) and the far list's `hi` in one array.
//!
//! **Instances** are sorted once per [`crate::Renderer::set_instances`] into blocks of
//! [`BLOCK_INSTANCES`] by the Morton code of their culling sphere's centre (ties by index, so the
//! order is deterministic), each block with a bounding sphere. Each record keeps the instance's
//! index in the renderer's list, which is what the draws carry back.
//!
//! **A frame** is one compute pass of two dispatches and O(models) CPU work: `cull_blocks` tests
//! every block's sphere and appends the visible ones, counting them into the x of an indirect
//! dispatch; `select_instances` runs one workgroup per visible block and selects each instance as
//! the CPU does (culling, far path and far-list range, near path with cell culling, Gilet's depth
//! bias and shading, prefix search), appending one `DrawInfo` + `DrawIndirectArgs` pair per range
//! to its model's triangle or point bucket through an atomic counter (and, in a policy frame, one
//! per octahedral impostor tree to its quad bucket, one per billboard tree to its billboard
//! bucket). The render pass draws each
//! bucket with `multi_draw_indirect_count` (the counter is the count), or, on adapters without
//! `MULTI_DRAW_INDIRECT_COUNT`, with `multi_draw_indirect` over the whole bucket after the
//! indirect buffer was cleared (unused slots are empty draws).
//!
//! **Which trees** ([`InstanceDrawGpu`], one per instance of the renderer's list, indexed by the
//! index each instance record carries). A frame without a policy that chooses (no
//! [`Settings::policy`](crate::Settings::policy), or no model with calibration tables) draws every
//! instance with the point tree on every pixel; that buffer is written once and kept until a
//! policy frame changes it. In a policy frame the CPU assigns the trees as in a CPU frame
//! (transitions included), selects and records every technique but the point tree itself, and
//! gives the GPU the trees it would draw through the point tree's selection — the trees assigned
//! [`Technique::Spt`] or [`Technique::Full`] (which a policy frame draws through the point tree's
//! selection at the frame's thresholds) and those a technique hands back (pruned trees below their
//! height) — each with the technique it is tinted with and counted under and the share of the
//! transition dither its draws keep, the CPU path's `DrawInfo::fade` (`pack_fade` of the same
//! share: `[0, shown)` entering, `[shown, 1)` leaving, every pixel outside a transition, and every
//! pixel for a tree both entering and leaving the point tree's selection, whose two selections
//! are one). The trees the policy draws with their octahedral impostor (most trees of a large
//! forest: every one below about a hundred pixels) or their billboards (a facing one or the
//! crossed ones: the far trees of a model whose tables find them as good, a sparse weeping
//! willow's, say) are given to the GPU too, flagged with their [`QuadKind`]
//! ([`InstanceDrawGpu::quads`]), where the point tree leaves their entry free (all but a tree
//! fading between the two, whose quads the CPU records): the CPU culled them, and
//! `select_instances` appends each one's quads to its model's quad or billboard bucket as the CPU
//! path records its `QuadDraw` (the same quads, tint and dither share), so the CPU neither records
//! nor uploads a draw per such tree. Every other instance is skipped. With shadows, each cascade selects
//! its trees on the CPU beside this (a policy frame), or the whole frame is the CPU's (without a
//! policy).
//!
//! **Capacity.** Each bucket's slots are fixed on the CPU (the bind group and the render pass
//! need them): `min(upper bound, max(2^16, what earlier frames needed × 1.25))`, the upper bound
//! being the model's instances times its cells with triangles (points), and its instances for the
//! quads (none where the renderer draws no octahedral impostor, or no billboard, of it). Ranges
//! past a bucket's capacity are dropped that frame and counted; the counters are read back without
//! blocking a frame or two later, and the buckets that overflowed grow for the next frames. A quad
//! or billboard bucket grows before the frame instead: the CPU knows how many trees it hands over.
//!
//! **Order.** Within a bucket the draws come in the order the atomics hand out slots, which
//! varies between runs: the set of draws equals the CPU selection's (up to `f32` rounding of keys
//! that lie at a threshold), their order does not, so images may differ where two primitives tie
//! in depth.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use treelod_format::{Container, PointRecord};
use treelod_runtime::{DrawRange, Kind, ModelLod, PerTechnique, ROOTS_CELL, Technique};

use crate::draws::DrawInfo;
use crate::renderer::RenderError;
use crate::streaming::UNIT;
use crate::technique::DrawSource;

/// WGSL of the selection: the draw constants it writes, then the two compute entry points (after
/// the table of technique tints, [`shader`]).
const SHADER: &str =
    concat!(include_str!("../../../shaders/shared/draw.wgsl"), include_str!("../../../shaders/select.wgsl"));

/// The selection's WGSL: `TECHNIQUE_TINTS`, each technique's [`DrawInfo::tint`] by
/// [`Technique::index`], and `FAR_LIST_EXTRA` ([`treelod_runtime::FAR_LIST_EXTRA`]), then
/// [`SHADER`].
fn shader() -> String {
    let tints: Vec<String> = Technique::ALL.map(|t| format!("{}u", crate::draws::tint(t))).to_vec();
    let n = Technique::COUNT;
    format!(
        "// DrawInfo::tint of each technique by Technique::index (crates/treelod-render/src/draws.rs, `tint`).\n\
         const TECHNIQUE_COUNT: u32 = {n}u;\nconst TECHNIQUE_TINTS = array<u32, {n}>({});\n\
         const FAR_LIST_EXTRA: f32 = {:?};\n{SHADER}",
        tints.join(", "),
        treelod_runtime::FAR_LIST_EXTRA,
    )
}

/// Instances per block: one workgroup of `select_instances`.
pub const BLOCK_INSTANCES: usize = 64;

/// Most blocks a frame dispatches (one dispatch dimension): beyond
/// `BLOCK_INSTANCES × MAX_BLOCKS` ≈ 4.19 M instances the renderer selects on the CPU.
pub const MAX_BLOCKS: usize = 65_535;

/// Slots a bucket starts with (if its upper bound is not smaller).
const INITIAL_BUCKET_DRAWS: u32 = 1 << 16;

/// Buckets per model: triangles, points, the octahedral impostors' quads, the billboards' quads.
const BUCKET_KINDS: usize = 4;

/// Statistics counters after the bucket counters: instances visible, far, cells selected, cells
/// culled, triangles, points, primitives of leaving draws, then primitives per technique.
const STATS: usize = 7 + Technique::COUNT;

/// Bytes of one indirect draw.
const INDIRECT_BYTES: u64 = size_of::<wgpu::util::DrawIndirectArgs>() as u64;

/// Per-frame constants of the selection. WGSL twin: `SelectFrame` in `shaders/select.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct SelectFrameGpu {
    /// Frustum planes, as [`treelod_runtime::Frustum::planes`].
    pub planes: [[f32; 4]; 6],
    /// Eye (xyz), world size per pixel at one metre (w).
    pub eye: [f32; 4],
    /// `s_min`, `s_max`, `k`, far ratio.
    pub pixels: [f32; 4],
    /// `L_m`, `L_M`, shading on (1/0), `Z_i` needed (1/0).
    pub shading: [f32; 4],
    pub block_count: u32,
    pub stats_at: u32,
    pub _pad: [u32; 2],
}

/// A block of instances. WGSL twin: `Block`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct BlockGpu {
    centre: [f32; 3],
    radius: f32,
    first: u32,
    count: u32,
    _pad: [u32; 2],
}

/// An instance in block order: its model, and its index in [`crate::Renderer::set_instances`]'
/// list, where the selection reads its transform (the renderer's instance transforms, which the
/// tree shaders read too: the transform is held once on the GPU). WGSL twin: `InstanceGpu`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct InstanceGpu {
    model: u32,
    index: u32,
}

/// A model's selection constants and buckets. WGSL twin: `ModelGpu`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct ModelGpu {
    centre: [f32; 3],
    radius: f32,
    cull_centre: [f32; 3],
    cull_radius: f32,
    cull_half: [f32; 3],
    first_cell: u32,
    cell_count: u32,
    far_tau: f32,
    largest: f32,
    cell_reach: f32,
    far_count: u32,
    root_cells: u32,
    roots_at: u32,
    far_hi_at: u32,
    triangle_base: u32,
    point_base: u32,
    bucket_first: [u32; BUCKET_KINDS],
    bucket_capacity: [u32; BUCKET_KINDS],
    /// Per [`QuadKind`] (by [`QuadKind::index`]) the model's quads a tree drawn so is drawn
    /// with, first and count, as the CPU path's `QuadDraw::first`, `count` (count 0 where the
    /// model has none, or the renderer cannot draw them).
    quads: [u32; 2 * QuadKind::COUNT],
}

/// The quads a tree may be drawn with instead of through the point tree's selection, which the
/// GPU appends as the CPU path records a [`treelod_runtime::QuadDraw`] of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum QuadKind {
    /// Its octahedral impostor ([`Technique::Octahedral`]): the quad bucket (kind 2).
    Octahedral,
    /// Its camera-facing billboard ([`Technique::Billboard`]): the billboard bucket (kind 3).
    Facing,
    /// Its crossed billboards ([`Technique::Crossed`]): the billboard bucket (kind 3).
    Crossed,
}

impl QuadKind {
    /// Kinds.
    pub(crate) const COUNT: usize = 3;

    /// Every kind, by [`Self::index`].
    pub(crate) const ALL: [Self; Self::COUNT] = [Self::Octahedral, Self::Facing, Self::Crossed];

    /// Index into a model's quad ranges.
    pub(crate) const fn index(self) -> usize {
        self as usize
    }
}

/// A non-empty cell. WGSL twin: `CellGpu`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct CellGpu {
    centre: [f32; 3],
    index: u32,
    half: [f32; 3],
    block_cell: u32,
    triangles_first: u32,
    triangles_count: u32,
    points_first: u32,
    points_count: u32,
    sizes_at: u32,
    hi_at: u32,
    largest: f32,
    roots: u32,
    next_hi: f32,
    hi0: f32,
    _pad: [u32; 2],
}

/// What the selection draws of one instance this frame, indexed by the instance's index in the
/// renderer's list. WGSL twin: `InstanceDraw` in `shaders/select.wgsl`.
///
/// ```text
/// fade       0: the GPU skips the instance (the CPU draws it, or nothing does);
///            else the DrawInfo::fade its draws carry: bits 0..16 lo, 16..32 hi of the
///            transition dither's share [lo, hi) (draws::pack_fade), 0xFFFF0000 = every pixel
/// technique  Technique::index of the technique the draws count under and are tinted with;
///            (bits 0..30); bits 30..32: 0 drawn through the point tree's selection, else
///            1 + the QuadKind::index of the model's quads it is drawn with instead
///            (octahedral impostor, facing billboard, crossed billboards)
/// ```
///
/// `lo == 0` marks the technique the instance is assigned this frame (it counts as a visible
/// instance); `lo > 0` only the draws of a technique it leaves in a transition (its primitives
/// count as leaving).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub(crate) struct InstanceDrawGpu {
    pub fade: u32,
    pub technique: u32,
}

impl InstanceDrawGpu {
    /// Skipped by the GPU.
    pub const SKIP: Self = Self { fade: 0, technique: 0 };

    /// Drawn with the point tree on every pixel: every instance of a frame without a policy.
    pub const POINT_TREE: Self = Self { fade: 0xFFFF_0000, technique: Technique::Spt.index() as u32 };

    /// The first bit in `technique` of the quads an instance is drawn with (1 + [`QuadKind::index`]).
    pub const QUAD_SHIFT: u32 = 30;

    /// Drawn as its model's quads of `kind` on the dither share `fade` packs, tinted and counted
    /// as `technique`.
    pub fn quads(kind: QuadKind, fade: u32, technique: Technique) -> Self {
        let kind = u32::try_from(kind.index()).unwrap_or(0) + 1;
        Self { fade, technique: u32::try_from(technique.index()).unwrap_or(0) | (kind << Self::QUAD_SHIFT) }
    }
}

const _: () = assert!(size_of::<InstanceDrawGpu>() == 8);
const _: () = assert!(size_of::<SelectFrameGpu>() == 160);
const _: () = assert!(size_of::<BlockGpu>() == 32);
const _: () = assert!(size_of::<InstanceGpu>() == 8);
const _: () = assert!(size_of::<ModelGpu>() == 144);
const _: () = assert!(size_of::<CellGpu>() == 80);

/// A key as the shader holds it: ±∞ as ±`f32::MAX`, NaN as `−f32::MAX` (selection's thresholds
/// are finite and non-negative, so every comparison gives the CPU's result).
fn key(v: f32) -> f32 {
    if v.is_nan() { -f32::MAX } else { v.clamp(-f32::MAX, f32::MAX) }
}

/// What the counters of a finished frame said.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct GpuCounts {
    /// Instances visible, of those drawn with their assigned technique (`InstanceDrawGpu`'s
    /// `lo == 0`).
    pub instances_visible: u32,
    pub instances_far: u32,
    pub cells_visible: u32,
    pub cells_culled: u32,
    pub triangles: u64,
    pub points: u64,
    /// Primitives of the draws of instances only leaving the point tree (`lo > 0`).
    pub leaving: u64,
    /// Primitives per technique the point tree's draws count under.
    pub by_technique: PerTechnique<u64>,
    pub ranges: u32,
    pub dropped: u32,
}

/// One draw the GPU selection appended, read back ([`crate::Renderer::read_gpu_draws`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuDraw {
    /// The range, as [`treelod_runtime::select_frame`] lists it, `instance` the index in
    /// [`crate::Renderer::set_instances`]' list.
    pub range: DrawRange,
    /// The technique the draw is tinted with and counted under: the one its tree is drawn with,
    /// or for a tree leaving the point tree in a transition, the one it leaves
    /// ([`crate::RecordedDraw::technique`]).
    pub technique: Technique,
    /// The share `[lo, hi)` of the transition dither the draw keeps, as the shader unpacks it
    /// (16-bit unorm): as [`crate::RecordedDraw::dither`] to within 1/65535.
    pub dither: [f32; 2],
}

/// One draw of an octahedral impostor or of billboards the GPU selection appended, read back
/// ([`crate::Renderer::read_gpu_quads`]): a [`treelod_runtime::QuadDraw`] of the CPU path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuQuadDraw {
    /// What is drawn: [`DrawSource::Octahedral`] or [`DrawSource::Billboards`], as the CPU
    /// path's [`crate::RecordedDraw::source`].
    pub source: DrawSource,
    /// The instance's index in [`crate::Renderer::set_instances`]' list.
    pub instance: u32,
    /// The instance's model.
    pub model: u32,
    /// The first of the model's quads drawn, as the CPU path's `QuadDraw::first`.
    pub first: u32,
    /// Quads drawn, as the CPU path's `QuadDraw::count`.
    pub count: u32,
    /// As [`GpuDraw::technique`].
    pub technique: Technique,
    /// As [`GpuDraw::dither`].
    pub dither: [f32; 2],
}

/// A frame's draws read back: the point tree's ranges and the impostors' and billboards' quads.
pub(crate) type ReadDraws = (Vec<GpuDraw>, Vec<GpuQuadDraw>);

/// A counter read-back in flight.
struct Pending {
    staging: wgpu::Buffer,
    mapping: bool,
    /// 0 mapping, 1 mapped, 2 failed.
    state: Arc<AtomicU8>,
}

/// Pool units a model takes whole: its triangles, points and a copy of its far list (roots first).
pub(crate) fn model_units(container: &Container, lod: &ModelLod) -> u64 {
    let triangles = u64::try_from(container.triangles().len()).unwrap_or(u64::MAX).div_ceil(2);
    let points = u64::try_from(container.points().len()).unwrap_or(u64::MAX);
    let roots = u64::try_from(lod.far_list().len()).unwrap_or(u64::MAX);
    triangles.saturating_add(points).saturating_add(roots)
}

/// The GPU state of the selection.
pub(crate) struct GpuSelection {
    cull_pipeline: wgpu::ComputePipeline,
    select_pipeline: wgpu::ComputePipeline,
    /// `multi_draw_indirect_count` is available.
    count_feature: bool,
    uniform: wgpu::Buffer,
    models_cpu: Vec<ModelGpu>,
    models: wgpu::Buffer,
    cells: wgpu::Buffer,
    keys: wgpu::Buffer,
    /// The whole triangles, points and roots of every model, in 48-byte units.
    pool: wgpu::Buffer,
    pool_bytes: u64,
    blocks: wgpu::Buffer,
    block_count: u32,
    /// More blocks than one dispatch holds: the CPU selects.
    too_many: bool,
    instances: wgpu::Buffer,
    /// Per instance of the renderer's list, what the selection draws of it ([`InstanceDrawGpu`]).
    instance_draws: wgpu::Buffer,
    /// Instances `instance_draws` holds.
    instance_draws_len: usize,
    /// `instance_draws` holds [`InstanceDrawGpu::POINT_TREE`] for every instance.
    every_instance_point_tree: bool,
    /// Per model, its valid instances.
    per_model: Vec<u32>,
    visible: wgpu::Buffer,
    dispatch: wgpu::Buffer,
    counters: wgpu::Buffer,
    draws: wgpu::Buffer,
    indirect: wgpu::Buffer,
    /// Per model: cells with triangles, cells with points, and 1 if it has octahedral impostor
    /// quads (billboard quads) to draw (the upper bounds of each bucket per instance).
    cells_with: Vec<[u32; BUCKET_KINDS]>,
    /// Per model and kind: slots needed by the largest frame read back so far (for the quads'
    /// buckets, also the largest count handed over, [`Self::set_instance_draws`]).
    needed: Vec<[u32; BUCKET_KINDS]>,
    /// A quad bucket is smaller than the quads handed over for the next frame.
    quads_grow: bool,
    cull_group: Option<wgpu::BindGroup>,
    select_group: Option<wgpu::BindGroup>,
    /// The render pass's frame bind group over the draws and the whole pool.
    frame_group: Option<wgpu::BindGroup>,
    pending: Option<Pending>,
    last: GpuCounts,
}

fn buffer(device: &wgpu::Device, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        // At least one element of every array the shaders bind (the largest is 100 bytes).
        size: size.max(256).next_multiple_of(16),
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

const STORAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE;

impl GpuSelection {
    /// The pipelines and the scene of `models` (checked against `budget` bytes); `quads` per
    /// model and [`QuadKind`] (by [`QuadKind::index`]), the quads the renderer draws of a tree
    /// drawn so, first and count (count 0 for none).
    ///
    /// # Errors
    /// [`RenderError::GpuSelectionBudget`] if the models' triangles and points do not fit.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        containers: &[&Container],
        lods: &[ModelLod],
        quads: &[[(u32, u32); QuadKind::COUNT]],
        budget: u64,
    ) -> Result<Self, RenderError> {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("treelod select.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shader().into()),
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: None,
            })
        };
        let empty = |label| buffer(device, label, 16, STORAGE);
        let mut selection = Self {
            cull_pipeline: pipeline("cull_blocks"),
            select_pipeline: pipeline("select_instances"),
            count_feature: device.features().contains(wgpu::Features::MULTI_DRAW_INDIRECT_COUNT),
            uniform: buffer(
                device,
                "treelod select frame",
                size_of::<SelectFrameGpu>() as u64,
                wgpu::BufferUsages::UNIFORM,
            ),
            models_cpu: Vec::new(),
            models: empty("treelod select models"),
            cells: empty("treelod select cells"),
            keys: empty("treelod select keys"),
            pool: empty("treelod select pool"),
            pool_bytes: 0,
            blocks: empty("treelod select blocks"),
            block_count: 0,
            too_many: false,
            instances: empty("treelod select instances"),
            instance_draws: empty("treelod select instance draws"),
            instance_draws_len: 0,
            every_instance_point_tree: false,
            per_model: Vec::new(),
            visible: empty("treelod select visible blocks"),
            dispatch: buffer(device, "treelod select dispatch", 16, STORAGE | wgpu::BufferUsages::INDIRECT),
            counters: empty("treelod select counters"),
            draws: empty("treelod select draws"),
            indirect: empty("treelod select indirect"),
            cells_with: Vec::new(),
            needed: Vec::new(),
            quads_grow: false,
            cull_group: None,
            select_group: None,
            frame_group: None,
            pending: None,
            last: GpuCounts::default(),
        };
        selection.load_models(device, queue, containers, lods, quads, budget)?;
        Ok(selection)
    }

    /// Bytes of the whole pool.
    pub fn pool_bytes(&self) -> u64 {
        self.pool_bytes
    }

    /// Whether the instances fit one dispatch (else the CPU selects).
    pub fn usable(&self) -> bool {
        !self.too_many
    }

    /// Uploads the models whole and their selection tables.
    fn load_models(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        containers: &[&Container],
        lods: &[ModelLod],
        quads: &[[(u32, u32); QuadKind::COUNT]],
        budget: u64,
    ) -> Result<(), RenderError> {
        let limits = device.limits();
        let budget = budget.min(limits.max_storage_buffer_binding_size).min(limits.max_buffer_size);
        let mut units = 0u64;
        for (m, (container, lod)) in containers.iter().zip(lods).enumerate() {
            units = units.saturating_add(model_units(container, lod));
            if units.saturating_mul(UNIT) > budget {
                return Err(RenderError::GpuSelectionBudget {
                    model: u32::try_from(m).unwrap_or(u32::MAX),
                    bytes: units.saturating_mul(UNIT),
                    budget,
                });
            }
        }
        let to_u32 = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        self.pool_bytes = units * UNIT;
        self.pool = buffer(device, "treelod select pool", self.pool_bytes, STORAGE);
        let (mut models, mut cells, mut keys) = (Vec::new(), Vec::new(), Vec::<f32>::new());
        self.cells_with.clear();
        let mut at = 0u64;
        for (m, (container, lod)) in containers.iter().zip(lods).enumerate() {
            let unit = |n: u64| u32::try_from(n).unwrap_or(u32::MAX);
            let model_quads = quads.get(m).copied().unwrap_or_default();
            let has = |kinds: &[QuadKind]| u32::from(kinds.iter().any(|k| model_quads[k.index()].1 > 0));
            // The points with their ambient occlusion in `flags`, as the streamed pool holds them.
            let mut scratch = Vec::new();
            let triangles = container.triangles();
            let points = crate::upload::gpu_points(container, 0, container.points(), &mut scratch);
            let roots: Vec<PointRecord> = lod.far_list().iter().map(|&i| points[i as usize]).collect();
            let triangles_at = at;
            let points_at = triangles_at + u64::try_from(triangles.len()).unwrap_or(0).div_ceil(2);
            let roots_at = points_at + u64::try_from(points.len()).unwrap_or(0);
            at = roots_at + u64::try_from(roots.len()).unwrap_or(0);
            for (unit_at, bytes) in [
                (triangles_at, bytemuck::cast_slice::<_, u8>(triangles)),
                (points_at, bytemuck::cast_slice(points)),
                (roots_at, bytemuck::cast_slice(&roots)),
            ] {
                if !bytes.is_empty() {
                    queue.write_buffer(&self.pool, unit_at * UNIT, bytes);
                }
            }
            let (far_tau, largest) = lod.far_bounds();
            let (cull_centre, cull_half) = lod.cull_box();
            let first_cell = to_u32(cells.len());
            let mut with = [0, 0, has(&[QuadKind::Octahedral]), has(&[QuadKind::Facing, QuadKind::Crossed])];
            for cell in lod.cells() {
                let (centre, half) = cell.centre_half();
                let (t, p) = (cell.triangles(), cell.points());
                with[0] += u32::from(t.count > 0);
                with[1] += u32::from(p.count > 0);
                cells.push(CellGpu {
                    centre: centre.to_array(),
                    index: cell.index(),
                    half: half.to_array(),
                    block_cell: u32::from(cell.is_block_cell()),
                    triangles_first: t.first,
                    triangles_count: t.count,
                    points_first: p.first,
                    points_count: p.count,
                    sizes_at: to_u32(keys.len()),
                    hi_at: to_u32(keys.len() + lod.triangle_sizes(cell).len()),
                    largest: key(cell.largest_triangle()),
                    roots: cell.root_count(),
                    next_hi: key(cell.next_hi()),
                    hi0: key(cell.first_hi()),
                    _pad: [0; 2],
                });
                keys.extend(lod.triangle_sizes(cell).iter().map(|&v| key(v)));
                keys.extend(lod.point_hi(cell).iter().map(|&v| key(v)));
            }
            self.cells_with.push(with);
            let far_hi_at = keys.len();
            keys.extend(lod.far_hi().iter().map(|&v| key(v)));
            models.push(ModelGpu {
                centre: lod.centre().to_array(),
                radius: lod.radius(),
                cull_centre: cull_centre.to_array(),
                cull_radius: lod.cull_sphere().1,
                cull_half: cull_half.to_array(),
                first_cell,
                cell_count: to_u32(lod.cells().len()),
                far_tau: key(far_tau),
                largest: key(largest),
                cell_reach: lod.cell_reach(),
                far_count: to_u32(roots.len()),
                root_cells: lod.root_cells(),
                roots_at: unit(roots_at),
                far_hi_at: to_u32(far_hi_at),
                triangle_base: unit(2 * triangles_at),
                point_base: unit(points_at),
                bucket_first: [0; BUCKET_KINDS],
                bucket_capacity: [0; BUCKET_KINDS],
                quads: std::array::from_fn(|i| {
                    let (first, count) = model_quads[i / 2];
                    if i % 2 == 0 { first } else { count }
                }),
            });
        }
        let upload = |label, bytes: &[u8]| {
            let b = buffer(device, label, bytes.len() as u64, STORAGE);
            queue.write_buffer(&b, 0, bytes);
            b
        };
        self.cells = upload("treelod select cells", bytemuck::cast_slice(&cells));
        self.keys = upload("treelod select keys", bytemuck::cast_slice(&keys));
        self.models_cpu = models;
        self.needed = vec![[0; BUCKET_KINDS]; self.models_cpu.len()];
        self.per_model = vec![0; self.models_cpu.len()];
        self.counters = buffer(
            device,
            "treelod select counters",
            4 * (BUCKET_KINDS * self.models_cpu.len() + STATS) as u64,
            STORAGE | wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_SRC,
        );
        self.pending = None;
        self.last = GpuCounts::default();
        Ok(())
    }

    /// Sorts `instances` into blocks and uploads them (see the module documentation).
    pub fn set_instances(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        instances: &[treelod_runtime::Instance],
        lods: &[ModelLod],
    ) {
        // Valid instances with their culling spheres, world space.
        let mut spheres = Vec::with_capacity(instances.len());
        self.per_model.iter_mut().for_each(|n| *n = 0);
        for (i, instance) in instances.iter().enumerate() {
            let (Some(lod), Ok(index)) = (lods.get(instance.model as usize), u32::try_from(i)) else { continue };
            let m = instance.transform;
            let scale = m
                .x_axis
                .truncate()
                .length_squared()
                .max(m.y_axis.truncate().length_squared())
                .max(m.z_axis.truncate().length_squared())
                .sqrt();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let (centre, radius) = lod.cull_sphere();
            spheres.push((m.transform_point3(centre), radius * scale, index));
            if let Some(n) = self.per_model.get_mut(instance.model as usize) {
                *n += 1;
            }
        }
        // Morton order of the centres over their bounds, ties by index.
        let (lo, hi) = spheres
            .iter()
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), s| (lo.min(s.0), hi.max(s.0)));
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        let mut order: Vec<(u32, u32, usize)> = spheres
            .iter()
            .enumerate()
            .map(|(k, s)| {
                let q = ((s.0 - lo) / extent * 1023.0).clamp(Vec3::ZERO, Vec3::splat(1023.0));
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 0..=1023")]
                let code = morton(q.x as u32, q.y as u32, q.z as u32);
                (code, s.2, k)
            })
            .collect();
        order.sort_unstable();
        let mut gpu_instances = Vec::with_capacity(order.len());
        let mut blocks = Vec::with_capacity(order.len().div_ceil(BLOCK_INSTANCES));
        for chunk in order.chunks(BLOCK_INSTANCES) {
            let first = u32::try_from(gpu_instances.len()).unwrap_or(u32::MAX);
            let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            for &(_, index, k) in chunk {
                let (c, r, _) = spheres[k];
                lo = lo.min(c - Vec3::splat(r));
                hi = hi.max(c + Vec3::splat(r));
                let instance = &instances[index as usize];
                gpu_instances.push(InstanceGpu { model: instance.model, index });
            }
            let centre = 0.5 * (lo + hi);
            let radius =
                chunk.iter().map(|&(_, _, k)| spheres[k].0.distance(centre) + spheres[k].1).fold(0.0, f32::max);
            // Inflated so rounding never culls a block whose instance the exact test keeps.
            let radius = radius * 1.001 + 1e-4 * centre.length() + 0.01;
            blocks.push(BlockGpu {
                centre: centre.to_array(),
                radius,
                first,
                count: u32::try_from(chunk.len()).unwrap_or(0),
                _pad: [0; 2],
            });
        }
        self.too_many = blocks.len() > MAX_BLOCKS;
        self.block_count = u32::try_from(blocks.len()).unwrap_or(u32::MAX);
        let upload = |label, bytes: &[u8]| {
            let b = buffer(device, label, bytes.len() as u64, STORAGE);
            queue.write_buffer(&b, 0, bytes);
            b
        };
        self.instances = upload("treelod select instances", bytemuck::cast_slice(&gpu_instances));
        self.instance_draws_len = instances.len();
        self.instance_draws = buffer(
            device,
            "treelod select instance draws",
            (instances.len() * size_of::<InstanceDrawGpu>()) as u64,
            STORAGE,
        );
        self.every_instance_point_tree = false;
        self.point_tree_everywhere(queue);
        self.blocks = upload("treelod select blocks", bytemuck::cast_slice(&blocks));
        self.visible = buffer(device, "treelod select visible blocks", 8 * blocks.len() as u64, STORAGE);
        self.cull_group = None;
        self.select_group = None;
        self.layout_buckets(device, queue);
    }

    /// Fixes each bucket's slots (see the module documentation), reallocates the draw buffers if
    /// they grew, and drops the bind groups that name them.
    fn layout_buckets(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
        let limits = device.limits();
        let limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let max_draws = limit / size_of::<DrawInfo>() as u64;
        let mut wanted = Vec::with_capacity(self.models_cpu.len());
        for ((&n, with), needed) in self.per_model.iter().zip(&self.cells_with).zip(&self.needed) {
            let mut caps = [0u64; BUCKET_KINDS];
            for kind in 0..BUCKET_KINDS {
                let upper = u64::from(n) * u64::from(with[kind]);
                let grown = u64::from(needed[kind]).saturating_mul(5).div_ceil(4).next_power_of_two();
                caps[kind] = upper.min(grown.max(u64::from(INITIAL_BUCKET_DRAWS)));
            }
            wanted.push(caps);
        }
        let total: u64 = wanted.iter().flatten().sum();
        // Scaled down if the device cannot bind that many draws.
        let scale = if total > max_draws { max_draws as f64 / total as f64 } else { 1.0 };
        let mut first = 0u32;
        for (model, caps) in self.models_cpu.iter_mut().zip(&wanted) {
            for (kind, &wanted) in caps.iter().enumerate() {
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "at most max_draws")]
                let cap = ((wanted as f64 * scale) as u64).min(u64::from(u32::MAX)) as u32;
                model.bucket_first[kind] = first;
                model.bucket_capacity[kind] = cap;
                first = first.saturating_add(cap);
            }
        }
        let draws_bytes = u64::from(first) * size_of::<DrawInfo>() as u64;
        if draws_bytes > self.draws.size() || self.frame_group.is_none() {
            self.draws = buffer(
                device,
                "treelod select draws",
                draws_bytes.next_power_of_two(),
                STORAGE | wgpu::BufferUsages::COPY_SRC,
            );
            self.indirect = buffer(
                device,
                "treelod select indirect",
                (u64::from(first) * INDIRECT_BYTES).next_power_of_two(),
                STORAGE | wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_SRC,
            );
            self.frame_group = None;
        }
        self.models =
            buffer(device, "treelod select models", (self.models_cpu.len() * size_of::<ModelGpu>()) as u64, STORAGE);
        queue.write_buffer(&self.models, 0, bytemuck::cast_slice(&self.models_cpu));
        self.cull_group = None;
        self.select_group = None;
    }

    /// Makes every instance drawn with the point tree on every pixel (a frame without a policy);
    /// written only when the buffer holds something else.
    pub fn point_tree_everywhere(&mut self, queue: &wgpu::Queue) {
        if !self.every_instance_point_tree {
            let draws = vec![InstanceDrawGpu::POINT_TREE; self.instance_draws_len];
            queue.write_buffer(&self.instance_draws, 0, bytemuck::cast_slice(&draws));
            self.every_instance_point_tree = true;
        }
    }

    /// Sets what the next [`Self::prepare`] draws of each instance (one per instance of the
    /// renderer's list, as [`Self::set_instances`] was given it; extra entries are ignored).
    /// `quads` counts per model the instances drawn with its octahedral impostor, and with its
    /// billboards ([`InstanceDrawGpu::quads`]): a quad bucket too small for them grows before
    /// the frame is selected, so no impostor or billboard is dropped (the CPU knows how many it
    /// hands over; the point tree's buckets grow from what frames read back).
    pub fn set_instance_draws(&mut self, queue: &wgpu::Queue, draws: &[InstanceDrawGpu], quads: &[[u32; 2]]) {
        let n = draws.len().min(self.instance_draws_len);
        if n > 0 {
            queue.write_buffer(&self.instance_draws, 0, bytemuck::cast_slice(&draws[..n]));
        }
        self.every_instance_point_tree = false;
        for ((needed, model), counts) in self.needed.iter_mut().zip(&self.models_cpu).zip(quads) {
            for (kind, &count) in [2, 3].into_iter().zip(counts) {
                if count > model.bucket_capacity[kind] {
                    needed[kind] = needed[kind].max(count);
                    self.quads_grow = true;
                }
            }
        }
    }

    /// Makes the render pass's frame bind group (uniform, draws, pool twice, the renderer's
    /// instance transforms) if it is missing.
    pub fn ensure_frame_group(
        &mut self,
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        frame: &wgpu::Buffer,
        transforms: &wgpu::Buffer,
    ) {
        if self.frame_group.is_some() {
            return;
        }
        self.frame_group = Some(device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("treelod select frame"),
            layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: frame.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: self.draws.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: self.pool.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: self.pool.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: transforms.as_entire_binding() },
            ],
        }));
    }

    /// Drops the bind groups that hold the renderer's instance transforms: that buffer was
    /// replaced.
    pub(crate) fn forget_transforms(&mut self) {
        self.frame_group = None;
        self.select_group = None;
    }

    /// Runs the selection for `frame` (its `block_count` and `stats_at` are filled here): one
    /// submission; returns the counts of the latest frame read back so far.
    /// `transforms` is the renderer's buffer of the instances' transforms (`InstanceTransform`),
    /// uploaded before.
    pub fn prepare(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        mut frame: SelectFrameGpu,
        transforms: &wgpu::Buffer,
    ) -> GpuCounts {
        // (`collect` runs every frame: it reads the counters back.)
        let grow = self.collect(device);
        if grow || std::mem::take(&mut self.quads_grow) {
            self.layout_buckets(device, queue);
        }
        frame.block_count = self.block_count;
        frame.stats_at = u32::try_from(BUCKET_KINDS * self.models_cpu.len()).unwrap_or(u32::MAX);
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&frame));
        let zeros = vec![0u32; BUCKET_KINDS * self.models_cpu.len() + STATS];
        queue.write_buffer(&self.counters, 0, bytemuck::cast_slice(&zeros));
        queue.write_buffer(&self.dispatch, 0, bytemuck::cast_slice(&[0u32, 1, 1]));
        let cull_group = self.cull_group.get_or_insert_with(|| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("treelod cull blocks"),
                layout: &self.cull_pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: self.uniform.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: self.blocks.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: self.visible.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: self.dispatch.as_entire_binding() },
                ],
            })
        });
        let select_group = self.select_group.get_or_insert_with(|| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("treelod select instances"),
                layout: &self.select_pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: self.uniform.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: self.visible.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: self.instances.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 6, resource: self.models.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 7, resource: self.cells.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 8, resource: self.keys.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 9, resource: self.counters.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 10, resource: self.draws.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 11, resource: self.indirect.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 12, resource: self.instance_draws.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 13, resource: transforms.as_entire_binding() },
                ],
            })
        });
        let mut encoder =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("treelod select") });
        if !self.count_feature {
            // Every slot past a bucket's count must be an empty draw.
            encoder.clear_buffer(&self.indirect, 0, None);
        }
        if self.block_count > 0 {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("treelod select"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.cull_pipeline);
            pass.set_bind_group(0, &*cull_group, &[]);
            pass.dispatch_workgroups(self.block_count.div_ceil(64), 1, 1);
            pass.set_pipeline(&self.select_pipeline);
            pass.set_bind_group(0, &*select_group, &[]);
            pass.dispatch_workgroups_indirect(&self.dispatch, 0);
        }
        let read_now = self.pending.is_none();
        if read_now {
            let staging = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("treelod select counters read-back"),
                size: self.counters.size(),
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            encoder.copy_buffer_to_buffer(&self.counters, 0, &staging, 0, self.counters.size());
            self.pending = Some(Pending { staging, mapping: false, state: Arc::new(AtomicU8::new(0)) });
        }
        queue.submit([encoder.finish()]);
        if let Some(pending) = self.pending.as_mut().filter(|p| !p.mapping) {
            let state = Arc::clone(&pending.state);
            pending.staging.slice(..).map_async(wgpu::MapMode::Read, move |result| {
                state.store(if result.is_ok() { 1 } else { 2 }, Ordering::Release);
            });
            pending.mapping = true;
        }
        self.last
    }

    /// Reads a finished counter read-back, if any, without blocking; returns whether a bucket
    /// needs more slots than it has.
    fn collect(&mut self, device: &wgpu::Device) -> bool {
        let Some(pending) = &self.pending else { return false };
        // A failed poll leaves the read-back pending; the next frame tries again.
        let _ = device.poll(wgpu::PollType::Poll);
        match pending.state.load(Ordering::Acquire) {
            1 => {}
            2 => {
                self.pending = None;
                return false;
            }
            _ => return false,
        }
        let mut grow = false;
        if let Ok(mapped) = pending.staging.slice(..).get_mapped_range() {
            let words: &[u32] = bytemuck::cast_slice(&mapped);
            let n = self.models_cpu.len();
            if words.len() >= BUCKET_KINDS * n + STATS {
                let mut counts = GpuCounts::default();
                for (m, model) in self.models_cpu.iter().enumerate() {
                    for kind in 0..BUCKET_KINDS {
                        let (wanted, cap) = (words[BUCKET_KINDS * m + kind], model.bucket_capacity[kind]);
                        // The quads' draws are counted by the CPU, which hands them over.
                        counts.ranges += if kind < 2 { wanted.min(cap) } else { 0 };
                        counts.dropped += wanted.saturating_sub(cap);
                        if wanted > cap {
                            grow = true;
                        }
                        self.needed[m][kind] = self.needed[m][kind].max(wanted);
                    }
                }
                let s = &words[BUCKET_KINDS * n..];
                counts.instances_visible = s[0];
                counts.instances_far = s[1];
                counts.cells_visible = s[2];
                counts.cells_culled = s[3];
                counts.triangles = u64::from(s[4]);
                counts.points = u64::from(s[5]);
                counts.leaving = u64::from(s[6]);
                for technique in Technique::ALL {
                    counts.by_technique[technique] = u64::from(s[7 + technique.index()]);
                }
                self.last = counts;
            }
        }
        pending.staging.unmap();
        self.pending = None;
        grow
    }

    /// Records the draws into the host's pass: per kind (pipeline: triangles, points, octahedral
    /// impostors, billboards) and model, one `multi_draw_indirect_count` over its bucket, with
    /// the model bind group `model_group(m)` and, for the quads, the model's octahedral
    /// impostors' or billboards' group `quad_group(m, kind)` (group 3).
    pub fn render<'a>(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        pipelines: [&wgpu::RenderPipeline; BUCKET_KINDS],
        model_group: impl Fn(usize) -> Option<&'a wgpu::BindGroup>,
        quad_group: impl Fn(usize, usize) -> Option<&'a wgpu::BindGroup>,
    ) {
        let Some(frame_group) = &self.frame_group else { return };
        pass.set_bind_group(0, frame_group, &[]);
        for (kind, pipeline) in pipelines.into_iter().enumerate() {
            pass.set_pipeline(pipeline);
            for (m, model) in self.models_cpu.iter().enumerate() {
                let (first, capacity) = (model.bucket_first[kind], model.bucket_capacity[kind]);
                let Some(group) = model_group(m) else { continue };
                if capacity == 0 || self.per_model.get(m).is_none_or(|&n| n == 0) {
                    continue;
                }
                if kind >= 2 {
                    let Some(quads) = quad_group(m, kind) else { continue };
                    pass.set_bind_group(3, quads, &[]);
                }
                pass.set_bind_group(1, group, &[]);
                let offset = u64::from(first) * INDIRECT_BYTES;
                if self.count_feature {
                    let count_at = 4 * (BUCKET_KINDS * m + kind) as u64;
                    pass.multi_draw_indirect_count(&self.indirect, offset, &self.counters, count_at, capacity);
                } else {
                    pass.multi_draw_indirect(&self.indirect, offset, capacity);
                }
            }
        }
    }

    /// Reads the draws of the last [`Self::prepare`] back, blocking until the GPU is done: the
    /// ranges as the CPU selection would list them (in bucket order, not the CPU's), with the
    /// technique and dither of each, and the octahedral impostors' and billboards' quad draws,
    /// for tests and tools. Draws dropped for lack of capacity are missing.
    ///
    /// # Errors
    /// [`RenderError::Readback`] if mapping fails.
    pub fn read_draws(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<ReadDraws, RenderError> {
        let mut encoder =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("treelod select read") });
        let copy = |encoder: &mut wgpu::CommandEncoder, source: &wgpu::Buffer| {
            let staging = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("treelod select read"),
                size: source.size(),
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            encoder.copy_buffer_to_buffer(source, 0, &staging, 0, source.size());
            staging
        };
        let (counters, draws, indirect) =
            (copy(&mut encoder, &self.counters), copy(&mut encoder, &self.draws), copy(&mut encoder, &self.indirect));
        queue.submit([encoder.finish()]);
        let read = |b: &wgpu::Buffer| -> Result<Vec<u8>, RenderError> {
            let (sender, receiver) = std::sync::mpsc::channel();
            b.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = sender.send(r);
            });
            device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| RenderError::Readback(e.to_string()))?;
            receiver
                .recv()
                .map_err(|e| RenderError::Readback(e.to_string()))?
                .map_err(|e| RenderError::Readback(e.to_string()))?;
            let bytes = b.slice(..).get_mapped_range().map_err(|e| RenderError::Readback(e.to_string()))?.to_vec();
            b.unmap();
            Ok(bytes)
        };
        let (counters, draws, indirect) = (read(&counters)?, read(&draws)?, read(&indirect)?);
        let counters: &[u32] = bytemuck::cast_slice(&counters);
        let draws: &[DrawInfo] =
            bytemuck::cast_slice(&draws[..draws.len() / size_of::<DrawInfo>() * size_of::<DrawInfo>()]);
        let indirect: &[[u32; 4]] = bytemuck::cast_slice(&indirect[..indirect.len() / 16 * 16]);
        let tints = Technique::ALL.map(crate::draws::tint);
        let unorm = |v: u32| f32::from(u16::try_from(v & 0xFFFF).unwrap_or(u16::MAX)) / 65535.0;
        let technique_of =
            |tint: u32| Technique::ALL.into_iter().zip(tints).find(|&(_, t)| t == tint).map_or(Technique::Spt, |p| p.0);
        let slots = |m: usize, kind: usize| {
            let model = &self.models_cpu[m];
            let n = counters.get(BUCKET_KINDS * m + kind).copied().unwrap_or(0).min(model.bucket_capacity[kind]);
            (0..n).filter_map(move |s| {
                let slot = (model.bucket_first[kind] + s) as usize;
                Some((draws.get(slot)?, indirect.get(slot)?))
            })
        };
        let mut quads = Vec::new();
        for m in 0..self.models_cpu.len() {
            for (kind, source) in [(2, DrawSource::Octahedral), (3, DrawSource::Billboards)] {
                for (info, args) in slots(m, kind) {
                    quads.push(GpuQuadDraw {
                        source,
                        instance: info.instance,
                        model: u32::try_from(m).unwrap_or(u32::MAX),
                        first: args[2] / 6,
                        count: args[0] / 6,
                        technique: technique_of(info.tint),
                        dither: [unorm(info.fade), unorm(info.fade >> 16)],
                    });
                }
            }
        }
        let mut ranges = Vec::new();
        for (m, model) in self.models_cpu.iter().enumerate() {
            for kind in 0..2 {
                for (info, args) in slots(m, kind) {
                    let (kind, first, count) = match kind {
                        0 => (Kind::Triangles, args[2] / 3 - model.triangle_base, args[0] / 3),
                        _ if info.cell == ROOTS_CELL => (Kind::Roots, args[2] / 6 - model.roots_at, args[0] / 6),
                        _ => (Kind::Points, args[2] / 6 - model.point_base, args[0] / 6),
                    };
                    let range = DrawRange {
                        instance: info.instance,
                        model: u32::try_from(m).unwrap_or(u32::MAX),
                        cell: info.cell,
                        kind,
                        first,
                        count,
                        tau_points: info.tau_p,
                        tau_triangles: info.tau_t,
                        shading: info.shading,
                    };
                    let dither = [unorm(info.fade), unorm(info.fade >> 16)];
                    ranges.push(GpuDraw { range, technique: technique_of(info.tint), dither });
                }
            }
        }
        Ok((ranges, quads))
    }
}

/// Interleaves the low 10 bits of `x`, `y`, `z` (x lowest).
fn morton(x: u32, y: u32, z: u32) -> u32 {
    fn spread(mut v: u32) -> u32 {
        v &= 0x3ff;
        v = (v | (v << 16)) & 0x0300_00ff;
        v = (v | (v << 8)) & 0x0300_f00f;
        v = (v | (v << 4)) & 0x030c_30c3;
        (v | (v << 2)) & 0x0924_9249
    }
    spread(x) | (spread(y) << 1) | (spread(z) << 2)
}

/// The frame constants for a camera and settings (`block_count`, `stats_at` filled later).
pub(crate) fn select_frame_gpu(
    camera: &treelod_runtime::Camera,
    settings: &treelod_runtime::LodSettings,
) -> SelectFrameGpu {
    let frustum = treelod_runtime::Frustum::from_view_proj(camera.view_proj);
    let (l_min, l_max) = settings.shading.unwrap_or((1.0, 1.0));
    let needs_z = settings.depth_bias_k != 0.0 || settings.shading.is_some();
    SelectFrameGpu {
        planes: frustum.planes().map(|p| p.to_array()),
        eye: camera.position.extend(camera.world_per_pixel()).to_array(),
        pixels: [settings.s_min, settings.s_max, settings.depth_bias_k, settings.far_ratio],
        shading: [l_min, l_max, f32::from(u8::from(settings.shading.is_some())), f32::from(u8::from(needs_z))],
        block_count: 0,
        stats_at: 0,
        _pad: [0; 2],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_interleaves() {
        assert_eq!(morton(1, 0, 0), 1);
        assert_eq!(morton(0, 1, 0), 2);
        assert_eq!(morton(0, 0, 1), 4);
        assert_eq!(morton(3, 0, 0), 0b1001);
        assert_eq!(morton(1023, 1023, 1023), (1 << 30) - 1);
    }

    #[test]
    fn keys_keep_comparisons_with_finite_thresholds() {
        assert_eq!(key(f32::INFINITY), f32::MAX);
        assert_eq!(key(f32::NEG_INFINITY), -f32::MAX);
        assert_eq!(key(f32::NAN), -f32::MAX);
        assert_eq!(key(0.5), 0.5);
    }
}
