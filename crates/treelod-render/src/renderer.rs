//! The renderer's core: the [`Renderer`], its models' instances, `prepare` (per-frame selection
//! of every view, streaming requests, the draw lists recorded into indirect draws) and `render`
//! (the draws themselves inside the host's render pass).
//!
//! Beside it: `settings` and `stats` (the public settings and statistics), `upload` (models
//! uploaded from containers), `pipelines` (the tree pipelines and their layouts), `draws` (the
//! draw lists and their buckets) and `technique` (each representation's selection).

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3, Vec4};
use treelod_format::{Container, PointRecord};
use treelod_runtime::{
    Assignment, BudgetController, ChainState, DrawList, DrawRange, Kind, LodSettings, ModelLod, PerPrimitive,
    PerTechnique, Policy, PolicyState, Primitive, PruneState, ROOTS_CELL, Representations, Scene, Technique,
    TechniqueSettings, Transition, merge_ascending, select_frame, select_techniques,
};

use crate::assign::{Drawn, PolicyModels};
use crate::camera::Camera;
use crate::draws::{DrawInfo, EVERY_PIXEL, InstanceTransform, RECORD_CHUNK, RecordedDraw, Recording, View, pack_fade};
use crate::gpu_select::{GpuDraw, GpuQuadDraw, GpuSelection, InstanceDrawGpu, QuadKind, ReadDraws, select_frame_gpu};
use crate::occlusion::{Job, Occlusion};
use crate::pipelines::{CasterTarget, Pipelines};
#[cfg(doc)]
use crate::settings::Pruning;
use crate::settings::{DebugView, DepthConvention, RendererFormats, Settings, prune_scale};
use crate::shadows::{
    Cascade, Casters, HostReceiver, HostShadowCascade, HostShadowError, HostShadowView, MAX_CASCADES,
    MAX_HOST_SHADOW_VIEWS, ShadowMaps, ShadowUniform, fit_cascades,
};
use crate::stats::{BudgetFrame, FrameStats, Laps, PreparePhases, ShadowStats};
use crate::streaming::{Array, Pool, Request, Residency, StreamStats, UNIT, Upload};
use crate::technique::{Bucket, DrawSource};
use crate::upload::{Model, storage_buffer, upload_gpu_points, write_in_runs};

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

/// Draws treelod models inside a host's render pass. See the crate documentation for a frame.
pub struct Renderer {
    pub(crate) settings: Settings,
    formats: RendererFormats,
    depth_convention: DepthConvention,
    pub(crate) models: Vec<Model>,
    pub(crate) lods: Vec<ModelLod>,
    /// Per model: what the selections of its representations read (beside its GPU resources in
    /// `models`).
    pub(crate) representations: Vec<Representations>,
    pub(crate) instances: Vec<treelod_runtime::Instance>,
    pub(crate) model_layout: wgpu::BindGroupLayout,
    /// Per bucket, the layout of its own group (group 3), if it has one.
    pub(crate) group_layouts: [Option<wgpu::BindGroupLayout>; Bucket::COUNT],
    frame_layout: wgpu::BindGroupLayout,
    /// The colour pass's pipelines, one per bucket, in bucket order ([`Bucket`]).
    pipelines: [wgpu::RenderPipeline; Bucket::COUNT],
    /// The shadow pass's depth-only pipelines, in bucket order.
    shadow_pipelines: [wgpu::RenderPipeline; Bucket::COUNT],
    /// What the host shadow maps' pipelines are made from, and those pipelines with the target
    /// they were made for ([`Self::set_host_shadow_views`]).
    casters: crate::pipelines::Casters,
    host_pipelines: Option<(CasterTarget, [wgpu::RenderPipeline; Bucket::COUNT])>,
    /// The host's shadow maps the trees are cast into, each with its index in the host's list
    /// and the cascade its trees are selected with (remade by every [`Self::prepare`] with the
    /// scene's bounds and the settings' `lod_texels`).
    host_shadows: Vec<(usize, HostShadowView, Cascade)>,
    /// The receivers' bind group layout (group 2) and the maps.
    shadow_layout: wgpu::BindGroupLayout,
    shadow_maps: ShadowMaps,
    /// The host's shadow maps the trees receive instead of the renderer's own
    /// ([`Self::receive_host_shadows`]).
    host_receiver: Option<HostReceiver>,
    /// This frame's cascades (empty without shadows).
    cascades: Vec<Cascade>,
    /// World bounds of the instances (their transformed blocks), for the cascades' casters and
    /// [`Renderer::instance_bounds`].
    scene_bounds: Option<(Vec3, Vec3)>,
    pub(crate) sampler: wgpu::Sampler,
    /// The atlases' sampler: clamped, so a region's edge never wraps to the atlas's far side,
    /// and the nearest mip level.
    pub(crate) atlas_sampler: wgpu::Sampler,
    /// The ellipsoids' white-noise cube map (`crate::noise`; uploaded by the first
    /// [`Renderer::add_model`]) and its nearest-texel sampler.
    pub(crate) noise_view: Option<wgpu::TextureView>,
    pub(crate) noise_sampler: wgpu::Sampler,
    /// The frame uniforms: the camera's at offset 0, then each cascade's at
    /// [`FRAME_UNIFORM_STRIDE`] steps.
    frame_buffer: wgpu::Buffer,
    draw_buffer: wgpu::Buffer,
    /// The instances' transforms ([`InstanceTransform`]), which the draws name by index.
    transform_buffer: wgpu::Buffer,
    /// The instances changed since their transforms were uploaded.
    transforms_stale: bool,
    pub(crate) indirect_buffer: wgpu::Buffer,
    /// The streamed triangles and points of every model (see `streaming`).
    pub(crate) pool_buffer: wgpu::Buffer,
    /// Per view (the camera, then each cascade): the frame bind group.
    frame_bind_groups: Vec<wgpu::BindGroup>,
    pub(crate) residency: Residency,
    /// The camera's selection and draws of this frame, and each cascade's.
    main: View,
    shadow_views: Vec<View>,
    /// Per instance: the `λ` its pruned leaves were drawn with last frame (hysteresis).
    pub(crate) prune_shown: Vec<Option<f32>>,
    /// Per instance: the LoD chain level it was drawn with last frame (hysteresis).
    pub(crate) chain_levels: Vec<Option<treelod_runtime::ChainPick>>,
    /// Per instance: for the trees leaving the LoD chain in a transition, the level they drew
    /// before the camera's view forgot it, which they hold while they fade (`ChainState::hold`;
    /// an entry outlives its transition, and is replaced when the tree next leaves the chain).
    pub(crate) leaving_chain_levels: Vec<Option<treelod_runtime::ChainPick>>,
    /// Per instance: the visible fraction of its hull samples last measured (1 if never).
    pub(crate) visible_fraction: Vec<f32>,
    /// This frame's trees per technique ([`Self::assign`]) from the camera's view.
    pub(crate) assignment: Assignment,
    /// Whether [`Self::assignment`] was chosen by the policy for this frame's camera, which
    /// leaves out the trees outside its frustum (`TechniqueSettings::culled`).
    pub(crate) assignment_culled: bool,
    /// Per shadow cascade, this frame's trees per technique from the light's view.
    pub(crate) cascade_assignments: Vec<Assignment>,
    /// The trees in a transition ([`Policy::transition`]) under the technique each is leaving
    /// (the camera's view), and what their selections draw.
    pub(crate) leaving_assignment: Assignment,
    leaving: View,
    /// This frame's transitions of the camera's view, ascending by instance.
    pub(crate) transitions: Vec<(u32, Transition)>,
    /// The policy's per-model tables and per-instance state ([`Settings::policy`]).
    pub(crate) policy: PolicyModels,
    /// Per instance, the technique it is drawn with this frame (this frame's assignment), for
    /// [`DebugView::Techniques`] and [`FrameStats::by_technique`].
    pub(crate) drawn_with: Vec<Technique>,
    /// Per instance, whether this frame's assignment lists it (with a policy: in the camera's
    /// view), which [`Self::drawn_with`] alone does not tell from the point tree.
    pub(crate) assigned: Vec<bool>,
    /// Scratch: the instance indices the point tree selects in a view.
    spt_list: Vec<u32>,
    /// The occlusion measurement, and the trees to measure after this frame.
    pub(crate) occlusion: Occlusion,
    pub(crate) occlusion_jobs: Vec<Job>,
    /// Scratch of [`Self::set_occlusion_jobs`]: a bit per instance.
    occlusion_marks: Vec<u64>,
    /// Per instance, its model: what an occlusion job and the assignment's lists read of it, 4
    /// bytes where an entry of `instances` takes 80 (10^6 willows list up to 887k jobs a frame;
    /// `docs/cli.md`).
    pub(crate) instance_models: Vec<u32>,
    /// Per instance, [`treelod_runtime::chosen_in_view`] of its transform: made with the list,
    /// read for each quad tree handed to the GPU (`Self::hand_quads_over`).
    cull_trusted: Vec<bool>,
    /// The camera of the last `prepare`: view-projection, eye, forward, viewport size.
    last_camera: Option<(Mat4, Vec3, Vec3, (u32, u32))>,
    /// GPU-driven selection, when enabled ([`Self::enable_gpu_selection`]).
    pub(crate) gpu: Option<GpuSelection>,
    /// Whether the last `prepare` selected on the GPU (then `render` draws its buckets).
    gpu_frame: bool,
    /// The instances changed since GPU selection last sorted them into blocks.
    gpu_instances_stale: bool,
    /// Scratch: per instance, what GPU selection draws of it in a policy frame.
    gpu_instance_draws: Vec<InstanceDrawGpu>,
    /// Scratch of policy frames with GPU selection: the trees whose octahedral impostor or
    /// billboards the GPU draws, counted.
    gpu_quads: HandedQuads,
    // Scratch reused between frames.
    requests: Vec<Request>,
    uploads: Vec<Upload>,
    /// Per model, per cell: the largest prefix asked for this frame (triangles, points).
    pub(crate) wanted: Vec<Vec<[u32; 2]>>,
    /// What each piece of a view's draws recorded ([`Self::record_view`]).
    pub(crate) recordings: Vec<Recording>,
    /// The camera's view's draws of the last frame in one list, made when [`Self::draws`] is
    /// first asked for them (emptied as each frame is prepared).
    pub(crate) draws: std::sync::OnceLock<Vec<RecordedDraw>>,
    /// The most entries of a view's lists one piece records ([`RECORD_CHUNK`]).
    pub(crate) record_chunk: usize,
    /// How many of `recordings` this frame's views used, the runs of draw infos in the order
    /// of their indices (recording, bucket), and their count ([`Self::record_view`]).
    pub(crate) recordings_used: usize,
    pub(crate) info_segments: Vec<(usize, usize)>,
    pub(crate) info_count: usize,
    pub(crate) indirect: Vec<wgpu::util::DrawIndirectArgs>,
    /// Scratch: [`Self::indirect`] as bytes for the upload.
    indirect_scratch: Vec<u8>,
    /// Where the latest [`Self::prepare`] spent its time ([`Self::prepare_phases`]).
    phases: PreparePhases,
}

/// What [`Renderer::select_view`] counted.
#[derive(Clone, Copy, Default)]
struct ViewCounts {
    /// Visible instances by the technique each is drawn with.
    instances: PerTechnique<u32>,
    leaves_pruned: u64,
}

/// The trees of a policy frame with GPU selection whose octahedral impostor or billboards the
/// GPU draws ([`InstanceDrawGpu::quads`]), counted as each is handed over: by
/// `Renderer::hand_quads_over` (trees outside a transition) and after the CPU's selection
/// (trees in one), the same way.
#[derive(Default)]
struct HandedQuads {
    /// Trees handed over: one range and one draw command each.
    trees: u32,
    /// Per model, the trees handed over drawn with the octahedral impostor, and with billboards.
    per_model: Vec<[u32; 2]>,
    /// Quads handed over, per technique.
    by_technique: PerTechnique<u64>,
    /// Quads handed over of trees leaving in a transition.
    leaving: u64,
}

impl HandedQuads {
    /// Empties the counts for a frame of `models` models.
    fn clear(&mut self, models: usize) {
        self.trees = 0;
        self.per_model.clear();
        self.per_model.resize(models, [0; 2]);
        self.by_technique = PerTechnique::default();
        self.leaving = 0;
    }

    /// Adds the counts of `other` (trees handed over elsewhere) to these.
    fn add(&mut self, other: &Self) {
        self.trees += other.trees;
        for (n, m) in self.per_model.iter_mut().zip(&other.per_model) {
            n[0] += m[0];
            n[1] += m[1];
        }
        self.by_technique += other.by_technique;
        self.leaving += other.leaving;
    }

    /// Hands one tree of `model` to the GPU: its entry `slot` draws its `count` quads of `kind`
    /// for `technique` on the share `dither` of the pixels; `leaving`: it is the tree's leaving
    /// draw in a transition.
    fn hand(
        &mut self,
        slot: &mut InstanceDrawGpu,
        model: usize,
        (kind, technique): (QuadKind, Technique),
        dither: [f32; 2],
        count: u32,
        leaving: bool,
    ) {
        *slot = InstanceDrawGpu::quads(kind, pack_fade(dither), technique);
        self.trees += 1;
        if let Some(n) = self.per_model.get_mut(model) {
            n[usize::from(kind != QuadKind::Octahedral)] += 1;
        }
        self.by_technique[technique] += u64::from(count);
        if leaving {
            self.leaving += u64::from(count);
        }
    }
}

/// Bytes between the frame uniforms of the views (WebGPU's largest uniform offset alignment).
const FRAME_UNIFORM_STRIDE: u64 = 256;

/// The views with a frame uniform: the camera, each of the renderer's cascades, each host
/// shadow map.
const FRAME_VIEWS: u64 = 1 + MAX_CASCADES as u64 + MAX_HOST_SHADOW_VIEWS as u64;

/// The frame uniform slot of host shadow map `k`.
const fn host_slot(k: usize) -> usize {
    1 + MAX_CASCADES + k
}

/// Pool units the pool buffer starts with (1.5 MiB).
const INITIAL_POOL_UNITS: u32 = 1 << 15;

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
        let Pipelines {
            frame_layout,
            model_layout,
            group_layouts,
            shadow_layout,
            colour: pipelines,
            shadow: shadow_pipelines,
            casters,
        } = Pipelines::new(device, formats, depth);
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
            size: FRAME_UNIFORM_STRIDE * FRAME_VIEWS,
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
        let transform_buffer =
            storage_buffer(device, "treelod instance transforms", 64 * size_of::<InstanceTransform>() as u64, false);
        let frame_bind_groups =
            frame_bind_groups(device, &frame_layout, &frame_buffer, [&draw_buffer, &pool_buffer, &transform_buffer]);
        Self {
            formats,
            settings,
            depth_convention: depth,
            models: Vec::new(),
            lods: Vec::new(),
            representations: Vec::new(),
            policy: PolicyModels::default(),
            drawn_with: Vec::new(),
            assigned: Vec::new(),
            instances: Vec::new(),
            model_layout,
            group_layouts,
            frame_layout,
            pipelines,
            shadow_pipelines,
            casters,
            host_pipelines: None,
            host_shadows: Vec::new(),
            shadow_layout,
            shadow_maps,
            host_receiver: None,
            cascades: Vec::new(),
            scene_bounds: None,
            sampler,
            atlas_sampler,
            noise_view: None,
            noise_sampler,
            frame_buffer,
            draw_buffer,
            transform_buffer,
            transforms_stale: false,
            indirect_buffer,
            pool_buffer,
            frame_bind_groups,
            residency: Residency::new(pool),
            main: View::default(),
            shadow_views: Vec::new(),
            prune_shown: Vec::new(),
            chain_levels: Vec::new(),
            leaving_chain_levels: Vec::new(),
            visible_fraction: Vec::new(),
            assignment: Assignment::default(),
            assignment_culled: false,
            cascade_assignments: Vec::new(),
            leaving_assignment: Assignment::default(),
            leaving: View::default(),
            transitions: Vec::new(),
            spt_list: Vec::new(),
            occlusion: Occlusion::new(device, formats.sample_count.max(1), depth),
            occlusion_jobs: Vec::new(),
            occlusion_marks: Vec::new(),
            instance_models: Vec::new(),
            cull_trusted: Vec::new(),
            last_camera: None,
            gpu: None,
            gpu_frame: false,
            gpu_instances_stale: false,
            gpu_instance_draws: Vec::new(),
            gpu_quads: HandedQuads::default(),
            requests: Vec::new(),
            uploads: Vec::new(),
            wanted: Vec::new(),
            recordings: Vec::new(),
            draws: std::sync::OnceLock::new(),
            record_chunk: RECORD_CHUNK,
            recordings_used: 0,
            info_segments: Vec::new(),
            info_count: 0,
            indirect: Vec::new(),
            indirect_scratch: Vec::new(),
            phases: PreparePhases::default(),
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

    /// Bytes GPU selection may keep resident: [`Settings::memory_budget`] capped by the device's
    /// largest storage binding and buffer.
    pub(crate) fn gpu_budget(&self, device: &wgpu::Device) -> u64 {
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
    /// Which frames it selects:
    ///
    /// - **Without a policy** that chooses (no [`Settings::policy`], or no model with calibration
    ///   tables) and with [`Settings::technique`] the point tree ([`Technique::Spt`]): every tree,
    ///   with O(models) CPU work.
    /// - **With the policy**: the CPU assigns every tree a technique as in a CPU frame
    ///   (hysteresis, occlusion and transitions included), and selects and records the trees of
    ///   every technique but the point tree; the GPU selects the trees the CPU path draws through
    ///   the point tree's selection ([`Technique::Spt`], [`Technique::Full`] where the policy
    ///   chose it, pruned trees handed back), told per instance which, with which technique and
    ///   on which share of a transition's dither, so trees fading into or out of the point tree
    ///   fade as on the CPU path; and it appends the quads of the trees drawn with their
    ///   octahedral impostor ([`Technique::Octahedral`], most trees of a large forest) or their
    ///   billboards ([`Technique::Billboard`], [`Technique::Crossed`]). The render pass draws
    ///   both. The CPU's work is then O(instances) for the assignment, but the point tree's
    ///   per-cell selection, usually most of a frame's selection, and its streaming are the
    ///   GPU's, and so are the impostor and billboard trees' draw records. [`FrameStats`] adds
    ///   the CPU's counts of this frame's other techniques and of the quad trees to the GPU's
    ///   read back from an earlier frame. With [`Settings::shadows`], each cascade then selects and draws
    ///   its own trees on the CPU as in a CPU frame, streaming what it needs.
    ///
    /// Frames with [`Settings::shadows`] without a policy (each cascade selects its own trees),
    /// frames of another forced technique without a policy, with [`Technique::Full`] as
    /// [`Settings::technique`] (the full mesh's zero thresholds), and more than about 4.19 M
    /// instances (`64 × 65535`, one dispatch of instance blocks) are selected on the CPU. Needs a
    /// device with [`wgpu::Features::MULTI_DRAW_INDIRECT_COUNT`] for best results; without it
    /// every bucket is drawn at its full capacity with unused slots as empty draws.
    ///
    /// # Errors
    /// [`RenderError::GpuSelectionBudget`] if the models' triangles, points and roots do not fit
    /// [`Settings::memory_budget`] (capped by the device's largest storage binding); GPU
    /// selection then stays off.
    pub fn enable_gpu_selection(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<(), RenderError> {
        let budget = self.gpu_budget(device);
        let containers: Vec<&Container> = self.models.iter().map(|m| &*m.container).collect();
        let quads: Vec<[(u32, u32); QuadKind::COUNT]> =
            self.representations.iter().map(|r| QuadKind::ALL.map(|kind| quad_range(r, kind))).collect();
        let mut gpu = GpuSelection::new(device, queue, &containers, &self.lods, &quads, budget)?;
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
        Ok(self.read_gpu_draws(device, queue)?.map(|draws| draws.into_iter().map(|d| d.range).collect()))
    }

    /// The draws the GPU selected in the last [`Self::prepare`], read back (this blocks until the
    /// GPU has finished): [`Self::read_gpu_selection`]'s ranges, each with the technique it is
    /// tinted with and counted under and the share of the transition dither it keeps (as
    /// [`RecordedDraw::technique`] and [`RecordedDraw::dither`] of the CPU path's draws). `None`
    /// if the last frame was selected on the CPU. For tests and tools.
    ///
    /// # Errors
    /// [`RenderError::Readback`] if mapping the buffers fails.
    pub fn read_gpu_draws(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Option<Vec<GpuDraw>>, RenderError> {
        Ok(self.read_gpu(device, queue)?.map(|(draws, _)| draws))
    }

    /// The GPU selection's draws and impostor quads of the last frame, read back; `None` if the
    /// CPU selected it.
    fn read_gpu(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Option<ReadDraws>, RenderError> {
        match &self.gpu {
            Some(gpu) if self.gpu_frame => gpu.read_draws(device, queue).map(Some),
            _ => Ok(None),
        }
    }

    /// The octahedral impostors and billboards the GPU drew in the last [`Self::prepare`] of a
    /// policy frame with GPU selection, read back (this blocks until the GPU has finished): the
    /// CPU path's [`treelod_runtime::QuadDraw`]s of those trees, with the technique and dither of
    /// each, in no fixed order. `None` if the last frame was selected on the CPU. For tests and tools.
    ///
    /// # Errors
    /// [`RenderError::Readback`] if mapping the buffers fails.
    pub fn read_gpu_quads(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Option<Vec<GpuQuadDraw>>, RenderError> {
        Ok(self.read_gpu(device, queue)?.map(|(_, quads)| quads))
    }

    /// Per instance of [`Self::set_instances`]' list, the technique it was drawn with in the last
    /// frame that assigned techniques: every frame but those GPU selection selects whole (no
    /// policy, [`Settings::technique`] the point tree), which draw every tree with the point
    /// tree and leave this as it was. A tree in a transition is listed under the technique it
    /// goes to.
    #[must_use]
    pub fn instance_techniques(&self) -> &[Technique] {
        &self.drawn_with
    }

    /// The largest pool, bytes (the memory budget as capped by the device).
    pub(crate) fn pool_budget(&self) -> u64 {
        u64::from(self.residency.pool.max()) * UNIT
    }

    /// Replaces the pool buffer by a larger one if the pool grew, keeping its contents.
    pub(crate) fn grow_pool_buffer(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
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
        self.frame_bind_groups = self.frame_bind_groups_now(device);
    }

    /// How many entries of a view's lists one task records at most (default 512; at least 1).
    /// The draws, their order and the image do not depend on it; the tests set it to 1 and to
    /// `usize::MAX` (one piece, recorded on the calling thread) to check that.
    #[doc(hidden)]
    pub fn set_record_chunk(&mut self, entries: usize) {
        self.record_chunk = entries.max(1);
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
        self.instance_models.clear();
        self.instance_models.extend(self.instances.iter().map(|i| i.model));
        self.cull_trusted.clear();
        self.cull_trusted.extend(self.instances.iter().map(|i| treelod_runtime::chosen_in_view(i.transform)));
        if self.instances.len() != before {
            self.prune_shown = vec![None; self.instances.len()];
            self.chain_levels = vec![None; self.instances.len()];
            self.leaving_chain_levels = vec![None; self.instances.len()];
            self.visible_fraction = vec![1.0; self.instances.len()];
            self.policy.state.reset();
            self.policy.cascade_states.iter_mut().for_each(PolicyState::reset);
        }
        self.policy.chunks = treelod_runtime::ChunkBounds::new(&self.instances, &self.lods);
        self.policy.sample = None;
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
        self.transforms_stale = true;
    }

    /// The selection of the last [`Self::prepare`] (before residency clamped it).
    #[must_use]
    pub fn selection(&self) -> &DrawList {
        &self.main.selection
    }

    /// The draws of the last [`Self::prepare`], as recorded for the GPU, in selection order.
    #[must_use]
    pub fn draws(&self) -> &[RecordedDraw] {
        // The pieces' draws are read in place by the frame; joined only for a caller that asks
        // (tools and tests), so a frame of 10^6 trees does not copy a list of 48 bytes a draw.
        self.draws.get_or_init(|| Self::recorded(&self.recordings, &self.main).copied().collect())
    }

    /// Where the latest [`Self::prepare`] spent its time on the CPU, phase by phase (zero before
    /// the first): its selection time broken down, as `treelod bench` reports it.
    #[must_use]
    pub fn prepare_phases(&self) -> PreparePhases {
        self.phases
    }

    /// The points of the last [`Self::prepare`]'s draws that the vertex shader keeps (those in the
    /// cut: [`treelod_runtime::point_drawn`] at each draw's thresholds), as opposed to the points
    /// of [`FrameStats::submitted`], the prefixes submitted. A scan of the submitted points on the
    /// CPU, for tools and reports, not for every frame of a host; 0 after a GPU-selected frame.
    /// The pieces of the frame's draws are scanned side by side on rayon's pool (the count is
    /// the same whatever the thread count).
    #[must_use]
    pub fn points_in_cut(&self) -> u64 {
        use rayon::prelude::*;
        Self::recorded_pieces(&self.recordings, &self.main)
            .par_iter()
            .map(|piece| piece.draws().iter().map(|draw| self.points_in_cut_of(draw)).sum::<u64>())
            .sum()
    }

    /// [`Self::points_in_cut`] of one draw.
    fn points_in_cut_of(&self, draw: &RecordedDraw) -> u64 {
        let (Some(model), Some(lod)) = (self.models.get(draw.model.0 as usize), self.lods.get(draw.model.0 as usize))
        else {
            return 0;
        };
        let points = model.container.points();
        let t = treelod_runtime::Thresholds { points: draw.tau_points, triangles: draw.tau_triangles };
        let count = draw.count as usize;
        let kept = |p: &PointRecord| treelod_runtime::point_drawn(p, t);
        (match draw.source {
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
                lod.far_list()
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
            | DrawSource::Octahedral
            | DrawSource::Ellipsoids
            | DrawSource::Lines => 0,
        }) as u64
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
    ///
    /// In the policy's budget mode ([`Policy::budget`]) the frame is selected with the target and
    /// `s_min` a [`BudgetController`] keeps (made from [`Settings::policy`]'s target and
    /// [`Settings::s_min`] when budget mode starts; `s_max` keeps its ratio to `s_min`), which
    /// then takes the frame's [`FrameStats::primitives`] for the next frame, the draws of the
    /// techniques trees in a transition leave ([`FrameStats::leaving`]) included: steered
    /// without them, the frames settled within the budget and the transitions their choices
    /// started drew on top of it, up to 1.5 times the budget for a transition's frames (spec
    /// §10.2 has the measurements). Where the controller steps the target down,
    /// the step's count is predicted before it is drawn (`Renderer::predict_count`), and a step
    /// predicted over [`BudgetController::raise_count`] (1.1 times the budget) is refused
    /// ([`BudgetController::refuse`]; spec §10.2). Frames are predicted before they are drawn
    /// in three more places: the first frame of budget mode from the calibration tables alone,
    /// which starts the steering within the budget ([`BudgetController::start_within`]); a
    /// frame whose camera moved since the last one, from the last one, raised before it is
    /// drawn where it is predicted over [`BudgetController::raise_count`]
    /// ([`BudgetController::raise_within`]), and lowered as below where it is predicted far
    /// under the budget (trees that leave the view, or the camera turning from near ones, take
    /// the frame far under it in one move); and after a frame far under the budget, the
    /// steering moved on down to the least pressure predicted within it
    /// ([`BudgetController::lower_within`]; not for a forest predicted from a sample, whose
    /// predictions fall short near the camera). Far under is read without the leaving draws:
    /// they end within a transition's frames, and a frame under half the budget once they
    /// have ended is far under it already (1,000 trees of each shared model, `bench --budget
    /// 100000`, 4,200 frames: within ½–1.1 times the budget 2,783 → 2,823, under half 1,251 →
    /// 1,215, over 1.1 times 166 → 162). A prediction counts each LoD chain tree by the
    /// triangles of the level its selection would pick (near trees above the tables' heights
    /// pick it by geometric error at `s_min`), the point trees that stay point trees by their
    /// cut scaled by `s_min`, and a point tree that changes technique, or stays one above the
    /// tables' heights, by the cut its selection draws, cells out of view culled; what a tree cost in the last frame is read at that frame's camera; a tree that
    /// changes technique counts both its old and its new cost while it fades, and the leaving
    /// draws of transitions that end come off. The
    /// settings themselves are not changed;
    /// [`Self::budget_steering`] reads what the controller holds.
    ///
    /// The call runs on a thread of rayon's global pool (the calling thread waits; a call from
    /// one of the pool's threads runs where it is), so that the frame's parallel sections (the
    /// policy's choice, each technique's selection, the draw records) are split by a thread of
    /// the pool, which goes on with its share while another thread wakes, rather than by the
    /// caller, which hands each whole section to the pool and sleeps until it is done: a wake-up
    /// each way per section, where the call now pays one each way per frame.
    pub fn prepare(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, camera: &Camera) -> FrameStats {
        let mut stats = rayon::scope(|_| self.prepare_on_pool(device, queue, camera));
        stats.host_shadows_received =
            self.host_receiver.as_ref().map_or(0, |host| u32::try_from(host.cascades.len()).unwrap_or(0));
        stats
    }

    /// [`Self::prepare`], on the calling thread.
    fn prepare_on_pool(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, camera: &Camera) -> FrameStats {
        let user = self.settings;
        let Some((policy, budget)) = user.policy.and_then(|p| p.budget.map(|n| (p, n))) else {
            (self.policy.budget, self.policy.last_frame) = (None, None);
            return self.prepare_frame(device, queue, camera);
        };
        let mut controller = (self.policy.budget.take())
            .unwrap_or_else(|| BudgetController::for_policy(budget, user.s_min, policy.target()));
        controller.target_primitives = budget;
        let clock = std::time::Instant::now();
        let selection = camera.selection();
        // The visible fractions the frame will be chosen with, read before it is predicted (the
        // frame's own read, `Self::prepare_frame`, then finds nothing new): a prediction made
        // with the fractions from before a measurement arrived chose the trees otherwise than
        // the frame did. Drawn (`bench --budget 100000 --size 320x180`, 1,000 trees, seed 1),
        // frames within ½–1.1 times the budget went 147 → 152 on the orchid, 159 → 163 on the
        // jacaranda, 218 → 227 on the willow, and over 1.1 times it 38 → 30, 11 → 7, 23 → 15.
        self.collect_occlusion(device, camera);
        let predict = |renderer: &mut Self, s_min: f32, target: f32, drawn: Option<Drawn>| {
            let policy = Policy { target, ..policy };
            match drawn {
                None => renderer.predict_total(&selection, policy, s_min),
                Some(drawn) => renderer.predict_count(&selection, policy, s_min, drawn),
            }
        };
        let mut predicted = false;
        if controller.awaits_first_frame() {
            // The first frame is predicted before it is drawn, and starts within the budget.
            controller.start_within(|s_min, target| predict(self, s_min, target, None));
            predicted = true;
        } else if let Some(drawn) = self.policy.last_frame
            && drawn.camera.view_proj != selection.view_proj
        {
            // The camera moved: the frame is predicted from the last one before it is drawn,
            // raised where it would meet a cliff, and lowered where it would be far under the
            // budget.
            let (s_min, target) = (controller.s_min(), controller.target());
            let count = predict(self, s_min, target, Some(drawn));
            if count > controller.raise_count() {
                controller.raise_within(|s_min, target| predict(self, s_min, target, Some(drawn)));
            } else if controller.far_under(count) {
                controller.lower_within(|s_min, target| predict(self, s_min, target, Some(drawn)));
            }
            predicted = true;
        }
        let started = predicted.then(|| clock.elapsed());
        let (drawn_s_min, target) = (controller.s_min(), controller.target());
        let steering = BudgetFrame { s_min: drawn_s_min, target, finest: controller.at_finest() };
        self.settings.s_min = drawn_s_min;
        if user.s_min > 0.0 {
            self.settings.s_max = user.s_max * drawn_s_min / user.s_min;
        }
        self.settings.policy = Some(Policy { target, ..policy });
        let stats = self.prepare_frame(device, queue, camera);
        self.phases.assign += started.unwrap_or_default();
        self.settings = user;
        // What the frame drew, the leaving draws included (the documentation above).
        let count = stats.primitives();
        let drawn = self.drawn(selection, steering, &stats, policy);
        self.policy.last_frame = Some(drawn);
        controller.update_policy(count);
        let started = std::time::Instant::now();
        if controller.steps_down_from(target)
            && predict(self, controller.s_min(), controller.target(), Some(drawn)) > controller.raise_count()
        {
            // Look before stepping down: a step predicted over the budget is refused undrawn.
            controller.refuse();
        }
        if controller.far_under(count.saturating_sub(stats.leaving)) {
            // Far under the budget once the transitions end: on down by prediction, not a step
            // a frame. After a refused step too, from the pressure drawn: the refusal alone held
            // the frame where it was whenever the scene changed before the bracket closed.
            controller.lower_within(|s_min, target| predict(self, s_min, target, Some(drawn)));
        }
        self.phases.assign += started.elapsed();
        self.policy.budget = Some(controller);
        stats
    }

    /// In the policy's budget mode, the `s_min` and the policy target the next frame is selected
    /// with ([`Self::prepare`]); `None` outside it.
    #[must_use]
    pub fn budget_steering(&self) -> Option<(f32, f32)> {
        self.policy.budget.as_ref().map(|c| (c.s_min(), c.target()))
    }

    /// In the policy's budget mode, the `s_min` and the policy target the latest frame was
    /// selected with ([`Self::prepare`]), and whether that was the finest steering; `None`
    /// outside it.
    #[must_use]
    pub fn budget_frame(&self) -> Option<BudgetFrame> {
        self.policy.last_frame.map(|drawn| drawn.steering)
    }

    /// [`Self::prepare`] with the settings as they are.
    fn prepare_frame(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, camera: &Camera) -> FrameStats {
        self.draws = std::sync::OnceLock::new();
        self.phases = PreparePhases::default();
        let mut laps = Laps::start();
        let settings = self.settings;
        let technique = settings.technique;
        let full_mesh = technique == Technique::Full;
        let (s_min, s_max) = if full_mesh { (0.0, 0.0) } else { (settings.s_min, settings.s_max) };
        let lod_settings = LodSettings {
            s_min,
            s_max,
            depth_bias_k: settings.depth_bias_k,
            shading: settings.shading,
            ..LodSettings::default()
        };
        let runtime_camera = camera.selection();
        let forward = -camera.view.row(2).truncate().normalize_or(Vec3::NEG_Z);
        self.last_camera = Some((runtime_camera.view_proj, camera.position, forward, (camera.width, camera.height)));
        self.collect_occlusion(device, camera);
        // While the trees receive the host's maps, the renderer's own are neither fitted nor drawn.
        self.cascades = match settings.shadows {
            Some(mut shadows) if self.host_receiver.is_none() => {
                shadows.resolution = shadows.resolution.clamp(1, device.limits().max_texture_dimension_2d);
                fit_cascades(camera, settings.sun, &shadows, self.scene_bounds)
            }
            _ => Vec::new(),
        };
        self.ensure_shadow_maps(device, queue);
        let lod_texels = settings.shadows.unwrap_or_default().lod_texels;
        for (_, view, cascade) in &mut self.host_shadows {
            if let Some(now) = Cascade::from_host(view, self.depth_convention, lod_texels, self.scene_bounds) {
                *cascade = now;
            }
        }
        if self.gpu_instances_stale
            && let Some(gpu) = &mut self.gpu
        {
            gpu.set_instances(device, queue, &self.instances, &self.lods);
        }
        self.gpu_instances_stale = false;
        self.upload_transforms(device, queue);
        self.gpu_frame = false;
        // GPU selection takes the point tree's part of the camera's view (see
        // `enable_gpu_selection`): the whole frame without a policy and without shadows, the
        // trees the policy draws through the point tree's selection (and the impostor trees)
        // with one, the shadow cascades then selected on the CPU.
        let gpu_usable = self.gpu.as_ref().is_some_and(GpuSelection::usable);
        let policy_chooses = self.policy.chooses(settings.policy.as_ref());
        laps.lap(&mut self.phases.setup);
        if gpu_usable && policy_chooses && !full_mesh {
            return self.prepare_hybrid(device, queue, camera, &runtime_camera, &lod_settings, laps);
        }
        if gpu_usable
            && self.cascades.is_empty()
            && self.host_shadows.is_empty()
            && technique == Technique::Spt
            && !policy_chooses
            && let Some(gpu) = self.gpu.as_mut()
        {
            // GPU selection: one compute submission writes the draws; nothing per instance here.
            self.main = View::default();
            gpu.point_tree_everywhere(queue);
            let counts =
                gpu.prepare(device, queue, select_frame_gpu(&runtime_camera, &lod_settings), &self.transform_buffer);
            gpu.ensure_frame_group(device, &self.frame_layout, &self.frame_buffer, &self.transform_buffer);
            let pool_bytes = gpu.pool_bytes();
            self.gpu_frame = true;
            laps.lap(&mut self.phases.select);
            self.write_frame_uniform(queue, camera);
            laps.lap(&mut self.phases.upload);
            let mut instances = PerTechnique::default();
            instances[Technique::Spt] = counts.instances_visible;
            let mut submitted = PerPrimitive::default();
            submitted[Primitive::Triangle] = counts.triangles;
            submitted[Primitive::Point] = counts.points;
            let mut by_technique = PerTechnique::default();
            by_technique[Technique::Spt] = submitted.total();
            return FrameStats {
                instances_visible: counts.instances_visible,
                instances,
                ranges: counts.ranges,
                draw_commands: counts.ranges,
                submitted,
                by_technique,
                bytes_resident: self.models.iter().map(|m| m.static_bytes).sum::<u64>()
                    + u64::from(self.residency.pool.used()) * UNIT
                    + pool_bytes,
                gpu_selection: true,
                ranges_dropped: counts.dropped,
                ..FrameStats::default()
            };
        }

        // The camera's selection, then each cascade's, of the same assignment.
        self.assign(&runtime_camera);
        laps.lap(&mut self.phases.assign);
        let mut main = std::mem::take(&mut self.main);
        let assignment = std::mem::take(&mut self.assignment);
        let counts = self.select_view(&mut main, &runtime_camera, &lod_settings, Role::Camera, &assignment, full_mesh);
        self.assignment = assignment;
        // Trees in a transition: the same view of the techniques they are leaving.
        let mut leaving = std::mem::take(&mut self.leaving);
        let leaving_assignment = std::mem::take(&mut self.leaving_assignment);
        let fading = !self.transitions.is_empty();
        if fading {
            self.select_view(
                &mut leaving,
                &runtime_camera,
                &lod_settings,
                Role::Leaving,
                &leaving_assignment,
                full_mesh,
            );
        }
        self.leaving_assignment = leaving_assignment;
        let mut shadow_views = std::mem::take(&mut self.shadow_views);
        let (shadow, cascade_full) = self.select_cascades(&mut shadow_views, &runtime_camera, &lod_settings, full_mesh);
        laps.lap(&mut self.phases.select);

        let mut views = vec![(&main, full_mesh)];
        if fading {
            views.push((&leaving, full_mesh));
        }
        views.extend(shadow_views.iter().map(|v| (v, cascade_full)));
        let streamed = self.stream_views(device, queue, &views);
        laps.lap(&mut self.phases.stream);

        // The draws of every view, clamped to what is resident, bucketed by model and kind.
        self.begin_draws();
        let mut stats = FrameStats {
            instances_visible: counts.instances.total(),
            instances: counts.instances,
            leaves_pruned: counts.leaves_pruned,
            bytes_uploaded: streamed.bytes_uploaded,
            bytes_resident: self.models.iter().map(|m| m.static_bytes).sum::<u64>()
                + u64::from(self.residency.pool.used()) * UNIT,
            transitions: u32::try_from(self.transitions.len()).unwrap_or(u32::MAX),
            ..FrameStats::default()
        };
        self.record_view(&mut main, fading.then_some(&leaving), full_mesh, &mut stats);
        if self.policy_occlusion() {
            // Every tree the camera draws is measured (pruned ones included, once), but those
            // whose choice does not depend on it (`set_occlusion_jobs`).
            self.set_occlusion_jobs(&main, &[]);
        }
        self.record_cascades(shadow_views, cascade_full, shadow, &mut stats);
        self.main = main;
        self.leaving = leaving;
        laps.lap(&mut self.phases.record);
        self.upload_frame(device, queue, camera, &mut laps);
        stats
    }

    /// The frame's uniform and its recorded draws uploaded (the last phase of [`Self::prepare`]).
    fn upload_frame(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, camera: &Camera, laps: &mut Laps) {
        self.write_frame_uniform(queue, camera);
        self.upload_draws(device, queue);
        laps.lap(&mut self.phases.upload);
    }

    /// Each shadow cascade's selection ([`Settings::shadows`]; none without), then each host
    /// shadow map's ([`Self::set_host_shadow_views`]): its trees assigned from the light's view
    /// as [`Casters`] asks and selected into `shadow_views` (one per cascade, then one per host
    /// map). Returns the counts so far (the cascades', the host maps') and whether they draw
    /// the full mesh.
    fn select_cascades(
        &mut self,
        shadow_views: &mut Vec<View>,
        runtime_camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
        full_mesh: bool,
    ) -> ([ShadowStats; 2], bool) {
        // The renderer's own cascades, then the host's shadow maps (each with hysteresis of its
        // own, by its index here).
        let lights: Vec<treelod_runtime::Camera> = self
            .cascades
            .iter()
            .chain(self.host_shadows.iter().map(|(_, _, cascade)| cascade))
            .map(Cascade::selection_camera)
            .collect();
        shadow_views.resize_with(lights.len(), View::default);
        let mut shadow =
            ShadowStats { cascades: u32::try_from(self.cascades.len()).unwrap_or(0), ..ShadowStats::default() };
        let mut assignments = std::mem::take(&mut self.cascade_assignments);
        assignments.resize_with(lights.len(), Assignment::default);
        // The cascades' casters: as the camera's trees, or forced (`Shadows::casters`).
        let casters = self.settings.shadows.map_or(Casters::default(), |s| s.casters);
        let cascade_full = casters.full_mesh(full_mesh);
        let cascade_lod =
            if cascade_full { LodSettings { s_min: 0.0, s_max: 0.0, ..*lod_settings } } else { *lod_settings };
        let mut host =
            ShadowStats { cascades: u32::try_from(self.host_shadows.len()).unwrap_or(0), ..ShadowStats::default() };
        for (k, ((view, assignment), light)) in shadow_views.iter_mut().zip(&mut assignments).zip(lights).enumerate() {
            self.assign_cascade(k, casters, *runtime_camera, light, assignment);
            let counts = self.select_view(view, &light, &cascade_lod, Role::Shadow, assignment, cascade_full);
            let sums = if k < self.cascades.len() { &mut shadow } else { &mut host };
            sums.instances_visible += counts.instances.total();
            sums.instances += counts.instances;
        }
        self.cascade_assignments = assignments;
        ([shadow, host], cascade_full)
    }

    /// Records each cascade's and host map's draws (after [`Self::select_cascades`] and
    /// streaming), counting them into `shadow` and `host`, which become `stats.shadow` and
    /// `stats.host_shadow`, and keeps the views for [`Self::render_shadows`] and
    /// [`Self::render_host_shadow`].
    fn record_cascades(
        &mut self,
        mut shadow_views: Vec<View>,
        cascade_full: bool,
        [mut shadow, mut host]: [ShadowStats; 2],
        stats: &mut FrameStats,
    ) {
        let own = self.cascades.len();
        for (k, view) in shadow_views.iter_mut().enumerate() {
            let mut counted = FrameStats::default();
            self.record_view(view, None, cascade_full, &mut counted);
            if k < own {
                shadow.add_view(k, &counted);
            } else {
                host.add_view(k - own, &counted);
            }
        }
        stats.shadow = shadow;
        stats.host_shadow = host;
        self.shadow_views = shadow_views;
    }

    /// Streams what `views` (each with whether it draws the full mesh) selected: per cell the
    /// largest prefix any view asked for, within the upload budget.
    fn stream_views(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, views: &[(&View, bool)]) -> StreamStats {
        // What each cell needs: the largest prefix any view asked for.
        self.residency.begin_frame();
        self.requests.clear();
        for &(view, full_mesh) in views {
            self.request(view, full_mesh);
        }
        for request in &mut self.requests {
            request.wanted = self.wanted[request.model][request.cell][request.array as usize];
        }
        self.uploads.clear();
        let streamed = self.residency.stream(&mut self.requests, self.settings.upload_budget, &mut self.uploads);
        for request in &self.requests {
            self.wanted[request.model][request.cell] = [0; 2];
        }
        self.grow_pool_buffer(device, queue);
        for upload in &self.uploads {
            let Some(model) = self.models.get(upload.model) else { continue };
            let (first, end) = (upload.first as usize, (upload.first + upload.count) as usize);
            match upload.array {
                Array::Triangles => queue.write_buffer(
                    &self.pool_buffer,
                    upload.offset,
                    bytemuck::cast_slice(&model.container.triangles()[first..end]),
                ),
                Array::Points => upload_gpu_points(
                    queue,
                    &self.pool_buffer,
                    upload.offset,
                    &model.container,
                    first,
                    &model.container.points()[first..end],
                ),
            }
        }

        streamed
    }

    /// Uploads the instances' transforms if they changed since the last upload, growing their
    /// buffer (and the bind groups that hold it) to fit.
    fn upload_transforms(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
        if !self.transforms_stale {
            return;
        }
        self.transforms_stale = false;
        let bytes = (self.instances.len().max(1) * size_of::<InstanceTransform>()) as u64;
        if bytes > self.transform_buffer.size() {
            self.transform_buffer =
                storage_buffer(device, "treelod instance transforms", bytes.next_power_of_two(), false);
            self.frame_bind_groups = self.frame_bind_groups_now(device);
            if let Some(gpu) = &mut self.gpu {
                gpu.forget_transforms();
            }
        }
        // Into the staging memory a run at a time (10^6 instances are 80 MB).
        let instances = &self.instances;
        write_in_runs(queue, &self.transform_buffer, 0, instances.len(), |range, run| {
            run.extend(instances[range].iter().map(|i| InstanceTransform::new(i.transform)));
        });
    }

    /// The frame bind groups of the renderer's buffers as they are now.
    fn frame_bind_groups_now(&self, device: &wgpu::Device) -> Vec<wgpu::BindGroup> {
        frame_bind_groups(
            device,
            &self.frame_layout,
            &self.frame_buffer,
            [&self.draw_buffer, &self.pool_buffer, &self.transform_buffer],
        )
    }

    /// Uploads the recorded draw infos and indirect draws of the frame, growing their buffers
    /// (and the frame bind groups that name the draw infos) as needed.
    fn upload_draws(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
        let draw_bytes = (self.info_count.max(1) * size_of::<DrawInfo>()) as u64;
        if draw_bytes > self.draw_buffer.size() {
            self.draw_buffer = storage_buffer(device, "treelod draws", draw_bytes.next_power_of_two(), false);
            self.frame_bind_groups = self.frame_bind_groups_now(device);
        }
        // The infos straight from the pieces' buckets into the queue's staging memory.
        if let Some(size) = wgpu::BufferSize::new((self.info_count * size_of::<DrawInfo>()) as u64)
            && let Some(mut staged) = queue.write_buffer_with(&self.draw_buffer, 0, size)
        {
            self.write_draw_infos(staged.slice(..));
        }
        let indirect_bytes = (self.indirect.len().max(1) * size_of::<wgpu::util::DrawIndirectArgs>()) as u64;
        if indirect_bytes > self.indirect_buffer.size() {
            self.indirect_buffer = indirect_buffer(device, self.indirect.len().next_power_of_two() as u64);
        }
        if !self.indirect.is_empty() {
            // A draw's 16 bytes at a time into a buffer kept between frames (a frame of a forest
            // drawn with ellipsoids or octahedral impostors records 10^5 draws and more).
            let mut bytes = std::mem::take(&mut self.indirect_scratch);
            bytes.clear();
            for args in &self.indirect {
                bytes.extend_from_slice(args.as_bytes());
            }
            queue.write_buffer(&self.indirect_buffer, 0, &bytes);
            self.indirect_scratch = bytes;
        }
    }

    /// A frame of the policy with GPU selection ([`Self::enable_gpu_selection`]): the CPU
    /// assigns the trees ([`Self::assign`], transitions included) and selects and records those of
    /// every technique but the point tree, as a CPU frame does; the GPU selects the trees the CPU
    /// would draw through the point tree's selection, told per instance which ones and on which
    /// share of the transition dither ([`InstanceDrawGpu`]), and appends the octahedral impostor
    /// and billboard quads of the trees the policy draws so, where the point tree leaves their
    /// entry free.
    ///
    /// - The point tree's trees are the assignment's [`Technique::Full`] and [`Technique::Spt`]
    ///   lists and those the other techniques hand back ([`point_tree_list`]), drawn on the
    ///   dither share [`Self::drawn_by`] gives them; of the trees in a transition, those whose
    ///   leaving view lists them so, on the share of the technique they leave. A tree in both
    ///   lists (a pruned tree below its height going to the point tree, say) has the same
    ///   selection in both, so the GPU draws it once on every pixel, under the technique it goes
    ///   to, where the CPU path draws it twice on complementary pixels: the same image.
    /// - Nothing the camera's view records here is streamed: the other techniques' data is
    ///   uploaded whole by `add_model`, and the point tree's is resident whole for GPU
    ///   selection. The shadow cascades select, stream and record their trees as in a CPU frame.
    /// - The quad trees: those of the assignment's [`Technique::Octahedral`],
    ///   [`Technique::Billboard`] and [`Technique::Crossed`] lists, and of the trees leaving
    ///   them in a transition, whose entry the point tree left free, are
    ///   [`InstanceDrawGpu::quads`] (of their [`QuadKind`]) on the share [`Self::drawn_by`] gives
    ///   them, and the CPU records none of them; a tree fading between its quads and the point
    ///   tree keeps its quads on the CPU. Those outside a transition are not selected on the CPU
    ///   at all (`hand_quads_over`: the chooser culled them, and their quads are their model's);
    ///   those in one are selected with the other techniques and handed over after.
    /// - Statistics: the CPU's counts of this frame's other techniques and of the quad trees it
    ///   hands over (their quads, ranges and draw commands: the GPU draws each of them)
    ///   plus the GPU's of the point tree read back from an earlier frame
    ///   ([`FrameStats::gpu_selection`]).
    fn prepare_hybrid(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        camera: &Camera,
        runtime_camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
        mut laps: Laps,
    ) -> FrameStats {
        self.assign(runtime_camera);
        laps.lap(&mut self.phases.assign);
        let mut draws = std::mem::take(&mut self.gpu_instance_draws);
        draws.clear();
        draws.resize(self.instances.len(), InstanceDrawGpu::SKIP);
        let technique_index = |t: Technique| u32::try_from(t.index()).unwrap_or(0);

        let mut main = std::mem::take(&mut self.main);
        let mut assignment = std::mem::take(&mut self.assignment);
        // The octahedral impostors' and the billboards' trees outside a transition are the GPU's
        // outright (`hand_quads_over`), not selected on the CPU first; the others are selected as
        // the rest are, and handed over below.
        let mut quads = std::mem::take(&mut self.gpu_quads);
        quads.clear(self.models.len());
        let whole = self.hand_quads_over(&mut assignment, &mut draws, &mut quads);
        self.select_techniques_of(&mut main, runtime_camera, lod_settings, Role::Camera, &assignment);
        for (technique, list) in whole {
            let selected = std::mem::replace(&mut assignment[technique], list);
            let handed = assignment[technique].len() - selected.len();
            *main.draws.visible.get_mut(technique) += u32::try_from(handed).unwrap_or(u32::MAX);
        }
        point_tree_list(&assignment, &main, &mut self.spt_list);
        self.assignment = assignment;
        for &i in &self.spt_list {
            let (technique, dither) = self.drawn_by(i, false);
            if let Some(slot) = draws.get_mut(i as usize) {
                *slot = InstanceDrawGpu { fade: pack_fade(dither), technique: technique_index(technique) };
            }
        }
        let mut leaving = std::mem::take(&mut self.leaving);
        let leaving_assignment = std::mem::take(&mut self.leaving_assignment);
        let fading = !self.transitions.is_empty();
        if fading {
            self.select_techniques_of(&mut leaving, runtime_camera, lod_settings, Role::Leaving, &leaving_assignment);
            point_tree_list(&leaving_assignment, &leaving, &mut self.spt_list);
            for &i in &self.spt_list {
                let (technique, dither) = self.drawn_by(i, true);
                let Some(slot) = draws.get_mut(i as usize) else { continue };
                *slot = if *slot == InstanceDrawGpu::SKIP {
                    InstanceDrawGpu { fade: pack_fade(dither), technique: technique_index(technique) }
                } else {
                    InstanceDrawGpu { fade: pack_fade(EVERY_PIXEL), ..*slot }
                };
            }
        }
        self.leaving_assignment = leaving_assignment;
        // The octahedral impostors' and the billboards' trees the CPU selected (those in a
        // transition) are the GPU's too where the point tree left their slot free (all but a tree
        // fading between the two): it appends their quads as the CPU path records them, on the
        // same share of the dither. The CPU culled them and knows their quads, so it counts them
        // in this frame's statistics itself.
        for (view, leaves) in [(&mut main, false), (&mut leaving, true)] {
            if leaves && !fading {
                continue;
            }
            let mut hand_over = |d: &treelod_runtime::QuadDraw, billboards: bool| {
                let Some(slot) = draws.get_mut(d.instance as usize).filter(|s| **s == InstanceDrawGpu::SKIP) else {
                    return true;
                };
                let Some(representations) = self.representations.get(d.model as usize) else { return true };
                let kinds: &[QuadKind] =
                    if billboards { &[QuadKind::Facing, QuadKind::Crossed] } else { &[QuadKind::Octahedral] };
                // (The runtime's draws are always one of the model's ranges; any other stays the CPU's.)
                let Some(&kind) = kinds.iter().find(|&&k| quad_range(representations, k) == (d.first, d.count)) else {
                    return true;
                };
                let (technique, dither) = self.drawn_by(d.instance, leaves);
                quads.hand(slot, d.model as usize, (kind, technique), dither, d.count, leaves);
                false
            };
            view.draws.octahedral.retain(|d| hand_over(d, false));
            view.draws.billboards.retain(|d| hand_over(d, true));
        }
        // The point tree's ranges are the GPU's: the CPU records none.
        for view in [&mut main, &mut leaving] {
            view.selection.clear();
            view.spt_remapped = false;
        }
        // The shadow cascades, on the CPU as in a CPU frame.
        let mut shadow_views = std::mem::take(&mut self.shadow_views);
        let (shadow, cascade_full) = self.select_cascades(&mut shadow_views, runtime_camera, lod_settings, false);

        let Some(gpu) = self.gpu.as_mut() else { unreachable!("prepare_hybrid runs with GPU selection") };
        gpu.set_instance_draws(queue, &draws, &quads.per_model);
        let gpu_counts =
            gpu.prepare(device, queue, select_frame_gpu(runtime_camera, lod_settings), &self.transform_buffer);
        gpu.ensure_frame_group(device, &self.frame_layout, &self.frame_buffer, &self.transform_buffer);
        let pool_bytes = gpu.pool_bytes();
        self.gpu_frame = true;
        laps.lap(&mut self.phases.select);
        // Only the cascades stream: the point tree's trees of the camera's view are the GPU's,
        // resident whole, and the other techniques' data is uploaded whole.
        let mut bytes_uploaded = 0;
        if !shadow_views.is_empty() {
            let views: Vec<(&View, bool)> = shadow_views.iter().map(|v| (v, cascade_full)).collect();
            bytes_uploaded = self.stream_views(device, queue, &views).bytes_uploaded;
        }
        laps.lap(&mut self.phases.stream);

        self.begin_draws();
        let mut instances = main.draws.visible;
        instances[Technique::FALLBACK] += gpu_counts.instances_visible;
        let mut stats = FrameStats {
            instances_visible: instances.total(),
            instances,
            leaves_pruned: main.draws.leaves_pruned,
            bytes_resident: self.models.iter().map(|m| m.static_bytes).sum::<u64>()
                + u64::from(self.residency.pool.used()) * UNIT
                + pool_bytes,
            bytes_uploaded,
            transitions: u32::try_from(self.transitions.len()).unwrap_or(u32::MAX),
            gpu_selection: true,
            ranges_dropped: gpu_counts.dropped,
            ..FrameStats::default()
        };
        self.record_view(&mut main, fading.then_some(&leaving), false, &mut stats);
        stats.ranges += gpu_counts.ranges;
        stats.draw_commands += gpu_counts.ranges;
        stats.submitted[Primitive::Triangle] += gpu_counts.triangles;
        stats.submitted[Primitive::Point] += gpu_counts.points;
        stats.submitted[Primitive::Billboard] += quads.by_technique.total();
        stats.by_technique += quads.by_technique;
        stats.leaving += quads.leaving;
        stats.ranges += quads.trees;
        stats.draw_commands += quads.trees;
        stats.by_technique += gpu_counts.by_technique;
        stats.leaving += gpu_counts.leaving;
        if self.policy_occlusion() {
            // Every tree drawn whose visible fraction matters to its choice is measured
            // (`set_occlusion_jobs`): of the CPU's recorded ones, and of those the GPU draws (the
            // point tree's, and the impostors' and billboards' handed over), looked for among the
            // trees the policy lists as needing it, not among every instance. The policy lists
            // only trees its choice found in the camera's view, by the culling sphere and frustum
            // a test here would use, so none is tested again: on the willow's 10^6 trees that
            // test took about half of the frame's `record` (`docs/cli.md`). (The GPU culls them
            // further; an extra job costs only time.)
            self.set_occlusion_jobs(&main, &draws);
        }
        self.record_cascades(shadow_views, cascade_full, shadow, &mut stats);
        self.gpu_instance_draws = draws;
        self.gpu_quads = quads;
        self.main = main;
        self.leaving = leaving;
        laps.lap(&mut self.phases.record);
        self.upload_frame(device, queue, camera, &mut laps);
        stats
    }

    /// Hands the trees of `assignment` drawn with their octahedral impostor or billboards to the
    /// GPU outright in a frame the policy chose (`Self::assignment_culled`): each one outside a
    /// transition, in view by the chooser's cull ([`treelod_runtime::chosen_in_view`]) and of a
    /// model that has its quads gets its entry of `draws` ([`InstanceDrawGpu::quads`], every
    /// pixel), is counted in `quads` and is taken out of `assignment`, so the CPU neither
    /// selects nor records it. Returns the lists as they were, per technique, to be put back
    /// once the CPU has selected the rest.
    ///
    /// The CPU's selection of such a tree does nothing but count it and name its model's quads
    /// (`treelod_runtime::baseline::select` trusts the chooser's cull), after which the frame
    /// handed each of those draws over one by one (see `docs/cli.md` for what it cost).
    fn hand_quads_over(
        &self,
        assignment: &mut Assignment,
        draws: &mut [InstanceDrawGpu],
        quads: &mut HandedQuads,
    ) -> Vec<(Technique, Vec<u32>)> {
        if !self.assignment_culled {
            return Vec::new();
        }
        /// List entries per task.
        const CHUNK: usize = 4096;
        let models = self.models.len();
        let mut whole = Vec::new();
        for technique in [Technique::Octahedral, Technique::Billboard, Technique::Crossed] {
            let kind = quad_kind(technique);
            let list = std::mem::take(&mut assignment[technique]);
            // Hands tree `i` over through its entry `slot` of `draws`, counted in `handed`;
            // false where the CPU keeps it.
            let hand = |i: u32, slot: Option<&mut InstanceDrawGpu>, handed: &mut HandedQuads| {
                let Some(model) = self.instance_models.get(i as usize).map(|&m| m as usize) else { return false };
                let count = self.representations.get(model).map_or(0, |r| quad_range(r, kind).1);
                let drawn = count > 0
                    && self.cull_trusted.get(i as usize).copied().unwrap_or(false)
                    && self.transition(i).is_none();
                match slot {
                    Some(slot) if drawn => {
                        handed.hand(slot, model, (kind, technique), EVERY_PIXEL, count, false);
                        true
                    }
                    _ => false,
                }
            };
            // The list is ascending (`Assignment::assign_chosen`), so each chunk's entries of
            // `draws` lie in a part of it of their own, from the chunk's first tree to the next
            // chunk's: the chunks are handed over in parallel, their counts and the trees they
            // leave to the CPU joined in order. (Any other list on this thread.)
            let mut rest = Vec::new();
            let handed = in_ascending_chunks(&list, draws, CHUNK, |chunk, part, offset| {
                let mut handed = HandedQuads::default();
                handed.clear(models);
                let kept = chunk.iter().copied().filter(|&i| !hand(i, part.get_mut(i as usize - offset), &mut handed));
                (kept.collect::<Vec<u32>>(), handed)
            });
            if let Some(handed) = handed {
                for (kept, handed) in &handed {
                    rest.extend_from_slice(kept);
                    quads.add(handed);
                }
            } else {
                rest.extend(list.iter().copied().filter(|&i| !hand(i, draws.get_mut(i as usize), quads)));
            }
            assignment[technique] = rest;
            whole.push((technique, list));
        }
        whole
    }

    /// Selects one view (its lists cleared first): each technique's runtime selection over the
    /// trees the assignment gives it, then the point tree's ([`select_frame`]) over the full
    /// mesh's and the point tree's trees and those a technique handed back (pruned trees below
    /// their height). `main`: the camera's view, the only one that holds pruning's `λ` between
    /// frames and lists trees for the occlusion test.
    ///
    /// The full mesh and the point tree share one [`select_frame`] pass with the frame's
    /// thresholds (zero when [`Settings::technique`] is [`Technique::Full`]): a policy that mixes
    /// them per tree would need a pass of its own for each.
    fn select_view(
        &mut self,
        view: &mut View,
        camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
        role: Role,
        assignment: &Assignment,
        full_mesh: bool,
    ) -> ViewCounts {
        self.select_techniques_of(view, camera, lod_settings, role, assignment);
        // The point tree: over every instance where all are its (no remapping), else over its own.
        point_tree_list(assignment, view, &mut self.spt_list);
        view.spt_remapped = self.spt_list.len() != self.instances.len();
        view.spt_instances.clear();
        view.spt_map.clear();
        if view.spt_remapped {
            view.spt_instances.extend(self.spt_list.iter().map(|&i| self.instances[i as usize]));
            view.spt_map.extend_from_slice(&self.spt_list);
        }
        let spt_instances = if view.spt_remapped { &view.spt_instances } else { &self.instances };
        let selected = select_frame(&self.lods, spt_instances, camera, lod_settings, &mut view.selection);
        // The full mesh is selected as the point tree with zero thresholds: its trees are drawn
        // as the full mesh; every other technique's fallback is the point tree.
        let rest = if full_mesh { Technique::Full } else { Technique::FALLBACK };
        let mut counts = ViewCounts { instances: view.draws.visible, leaves_pruned: view.draws.leaves_pruned };
        *counts.instances.get_mut(rest) += selected.instances_visible;
        counts
    }

    /// The part of [`Self::select_view`] before the point tree: `view`'s draws cleared, then each
    /// technique's runtime selection but the point tree's over the trees `assignment` gives it
    /// ([`select_techniques`], which lists the trees they hand back to the point tree), and, for
    /// the camera's view, the pruned trees to measure for occlusion.
    fn select_techniques_of(
        &mut self,
        view: &mut View,
        camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
        role: Role,
        assignment: &Assignment,
    ) {
        let main = role == Role::Camera;
        if main && !self.transitions.is_empty() {
            // The trees leaving the chain keep the level they drew, which the camera's view
            // forgets in the first frame they are drawn otherwise (later frames of the
            // transition find it forgotten, and keep what was kept).
            for &i in &self.leaving_assignment[Technique::LodChain] {
                let i = i as usize;
                if let (Some(slot), Some(&Some(level))) =
                    (self.leaving_chain_levels.get_mut(i), self.chain_levels.get(i))
                {
                    *slot = Some(level);
                }
            }
        }
        let settings = self.settings;
        view.draws.clear();
        let scene = Scene { lods: &self.lods, models: &self.representations, instances: &self.instances };
        // The camera's view's assignment, chosen by the policy for this camera, is culled.
        let technique_settings = self.technique_settings(settings.s_min, *lod_settings, main && self.assignment_culled);
        let prune_state =
            main.then_some(PruneState { shown: &mut self.prune_shown, visible_fraction: &self.visible_fraction });
        let chain_state = match role {
            Role::Camera => Some(ChainState { previous: &mut self.chain_levels, hold: false }),
            Role::Leaving => Some(ChainState { previous: &mut self.leaving_chain_levels, hold: true }),
            Role::Shadow => None,
        };
        select_techniques(&scene, assignment, camera, &technique_settings, prune_state, chain_state, &mut view.draws);
        if main {
            self.occlusion_jobs.clear();
            // (None while the measurement recorded earlier is not read: `set_occlusion_jobs`.)
            let jobs = if self.occlusion.in_flight() { &[][..] } else { &view.draws.occlusion[..] };
            for &index in jobs {
                if let Some(job) = self.occlusion_job(index) {
                    self.occlusion_jobs.push(job);
                }
            }
        }
    }

    /// The settings the techniques other than the point tree select with ([`select_techniques`])
    /// at `s_min`, the point tree's `lod` settings, and whether the assignment is `culled`
    /// already: the rest from the renderer's settings. The frame's views and budget mode's
    /// predictions of one tree (`Renderer::selected_cost`) take them from here alike.
    pub(crate) fn technique_settings(&self, s_min: f32, lod: LodSettings, culled: bool) -> TechniqueSettings {
        let settings = &self.settings;
        TechniqueSettings {
            s_min,
            lod,
            pruning: settings.pruning,
            impostor_bark: settings.impostor_bark,
            pixel_level: settings.pixel_level(),
            lines: settings.lines,
            chain_policy: settings.policy.unwrap_or_default(),
            culled,
        }
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
        let resolution = self.cascades.first().map_or(1, |c| c.resolution);
        let own = self.cascades.iter().zip(0..).map(|(c, layer)| (c.view_proj, c.texel, layer));
        let uniform = ShadowUniform::new(own, resolution, normal_offset, false);
        queue.write_buffer(&self.shadow_maps.uniform, 0, bytemuck::bytes_of(&uniform));
        self.write_host_receiver(queue);
    }

    /// Writes the uniform of the host's shadow maps the trees receive, if any.
    fn write_host_receiver(&self, queue: &wgpu::Queue) {
        if let Some(receiver) = &self.host_receiver {
            let normal_offset = self.settings.shadows.unwrap_or_default().normal_offset;
            let uniform = receiver.uniform(normal_offset, self.depth_convention);
            queue.write_buffer(&receiver.uniform, 0, bytemuck::bytes_of(&uniform));
        }
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
                DebugView::Techniques => 4,
            },
            morph: u32::from(settings.impostor_morph),
            ambient_occlusion: u32::from(settings.ambient_occlusion),
            level_blend: settings.pixel_level().clamped_blend(),
            stochastic_alpha: u32::from(settings.stochastic_alpha),
            pad: [0; 3],
        };
        queue.write_buffer(&self.frame_buffer, 0, bytemuck::bytes_of(&uniform));
        // A shadow map's uniform at slot `slot`: drawn with `view_proj`, facing and splat sizes
        // from `cascade`.
        let write_light = |slot: usize, view_proj: Mat4, cascade: &Cascade| {
            let (eye, right, up) = crate::shadows::cascade_frame(cascade);
            let light = FrameUniform {
                view_proj: view_proj.to_cols_array_2d(),
                eye: eye.to_array(),
                right: right.to_array(),
                up: up.extend(settings.point_scale.max(0.0)).to_array(),
                debug: 0,
                ..uniform
            };
            queue.write_buffer(&self.frame_buffer, slot as u64 * FRAME_UNIFORM_STRIDE, bytemuck::bytes_of(&light));
        };
        for (k, cascade) in self.cascades.iter().enumerate() {
            write_light(k + 1, cascade.view_proj, cascade);
        }
        // The host's maps: drawn with the host's own matrix, so that its receivers read the
        // depths its casters write.
        for (k, (_, view, cascade)) in self.host_shadows.iter().enumerate() {
            write_light(host_slot(k), view.clip_from_world, cascade);
        }
    }

    /// Measures which of the trees drawn this frame are hidden, for the occlusion factor of later
    /// frames: of the trees drawn pruned when pruning is forced ([`Pruning::occlusion`]), of
    /// every tree drawn when the policy chooses with occlusion ([`Policy::occlusion`]). Call it
    /// after the pass that drew this frame, in the same or a later encoder, with that pass's
    /// depth attachment (`depth_view`, which needs [`wgpu::TextureUsages::TEXTURE_BINDING`]). It
    /// records a small compute pass; the result is read by a later [`Self::prepare`] without
    /// waiting for the GPU. Does nothing when neither is on, or while an earlier measurement is
    /// in flight.
    pub fn measure_occlusion(
        &mut self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        depth_view: &wgpu::TextureView,
    ) {
        let on = self.measures_occlusion();
        let Some((view_proj, eye, forward, size)) = self.last_camera.filter(|_| on) else { return };
        let instances = (&self.instances[..], &self.transform_buffer);
        self.occlusion.record(
            device,
            encoder,
            depth_view,
            size,
            (view_proj, eye, forward),
            instances,
            &self.occlusion_jobs,
        );
    }

    /// Reads the occlusion measurement of an earlier frame into the trees' visible fractions
    /// where it has arrived (and the renderer measures), for `camera`'s frame.
    fn collect_occlusion(&mut self, device: &wgpu::Device, camera: &Camera) {
        if self.measures_occlusion() {
            let forward = -camera.view.row(2).truncate().normalize_or(Vec3::NEG_Z);
            self.occlusion.collect(device, camera.position, forward, &mut self.visible_fraction);
        }
    }

    /// Whether this frame's trees are measured for occlusion ([`Self::measure_occlusion`]):
    /// forced pruning with its occlusion factor, or a policy that chooses with occlusion.
    fn measures_occlusion(&self) -> bool {
        let settings = &self.settings;
        (prune_scale(settings.technique).is_some() && settings.pruning.occlusion) || self.policy_occlusion()
    }

    /// Whether the policy chooses trees with occlusion this frame ([`Policy::occlusion`]).
    pub(crate) fn policy_occlusion(&self) -> bool {
        self.settings.policy.is_some_and(|p| p.occlusion && self.policy.chooses(Some(&p)))
    }

    /// The occlusion tests of the instances drawn this frame whose visible fraction matters to
    /// the policy's choice ([`PolicyState::visibility_matters`]): the instances of `view`'s
    /// recorded draws ([`Self::recorded`]; each any number of times) and those `gpu` draws (its
    /// entries not [`InstanceDrawGpu::SKIP`]; empty in a CPU frame), one per instance, in the
    /// order of the instances ([`occlusion_candidates`]). None while the measurement recorded
    /// earlier is not read yet ([`Occlusion::in_flight`]): [`Occlusion::record`] would record
    /// nothing this frame.
    fn set_occlusion_jobs(&mut self, view: &View, gpu: &[InstanceDrawGpu]) {
        use rayon::prelude::*;
        self.occlusion_jobs.clear();
        if self.occlusion.in_flight() {
            return;
        }
        let mut marks = std::mem::take(&mut self.occlusion_marks);
        let count = self.instances.len();
        marks.clear();
        marks.resize(count.div_ceil(64), 0);
        for index in Self::recorded(&self.recordings, view).map(|d| d.instance).filter(|&i| (i as usize) < count) {
            marks[index as usize / 64] |= 1 << (index % 64);
        }
        let mut jobs = std::mem::take(&mut self.occlusion_jobs);
        let flags = self.policy.state.visibility_flags();
        let chunks = (0..count.div_ceil(treelod_runtime::CHOOSE_CHUNK)).into_par_iter();
        jobs.par_extend(chunks.flat_map_iter(|chunk| {
            occlusion_candidates(chunk, count, (&marks, flags, gpu)).filter_map(|index| self.occlusion_job(index))
        }));
        (self.occlusion_jobs, self.occlusion_marks) = (jobs, marks);
    }

    /// The occlusion test of instance `index` with its model's hull samples, if it has any.
    fn occlusion_job(&self, index: u32) -> Option<Job> {
        let model = *self.instance_models.get(index as usize)?;
        (self.occlusion.sample_count(model) > 0).then_some(Job { instance: index, model })
    }

    /// The visible fraction of each instance's hull samples last measured by
    /// [`Self::measure_occlusion`] (1 where the last measurement read did not measure it: a
    /// tree off-screen, or whose choice does not depend on it,
    /// [`PolicyState::visibility_matters`]; and after a camera jump).
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
            pass.set_bind_group(2, self.shadow_bind_group(), &[]);
            if !self.main.model_draws.is_empty() {
                // A policy frame: the other techniques' draws, recorded on the CPU. Drawn before
                // the GPU's buckets: on lavapipe, draws recorded after a `multi_draw_indirect_count`
                // whose count was 0 (the GPU drew no tree) did not show.
                pass.set_bind_group(0, &self.frame_bind_groups[0], &[]);
                self.draw_view(pass, &self.main, &self.pipelines);
            }
            const BUCKETS: [Bucket; 4] = [Bucket::Triangles, Bucket::Points, Bucket::Octahedral, Bucket::Billboards];
            let pipelines = BUCKETS.map(|b| &self.pipelines[b as usize]);
            let quads = |m: usize, kind: usize| {
                let bucket = *BUCKETS.get(kind)?;
                self.models.get(m).and_then(|model| model.groups[bucket as usize].as_ref())
            };
            gpu.render(pass, pipelines, group, quads);
            return;
        }
        pass.set_bind_group(0, &self.frame_bind_groups[0], &[]);
        pass.set_bind_group(2, self.shadow_bind_group(), &[]);
        self.draw_view(pass, &self.main, &self.pipelines);
    }

    /// Records this frame's shadow pass ([`Settings::shadows`], after [`Self::prepare`]): one
    /// depth-only pass per cascade into the renderer's shadow maps, drawing what each cascade
    /// selected. Record it before the host's pass that calls [`Self::render`] (in the same
    /// encoder or an earlier submission): that pass samples the maps. Does nothing without
    /// shadows.
    pub fn render_shadows(&self, encoder: &mut wgpu::CommandEncoder) {
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
            self.draw_view(&mut pass, view, &self.shadow_pipelines);
        }
    }

    /// Casts the trees into shadow maps the host renders and samples itself (an engine's
    /// directional-light cascades), from the next [`Self::prepare`] on: each frame the trees are
    /// selected from each map's light view (as the renderer's own cascades are:
    /// [`Shadows::casters`](crate::Shadows::casters) and
    /// [`Shadows::lod_texels`](crate::Shadows::lod_texels) of [`Settings::shadows`], their
    /// defaults without) and [`Self::render_host_shadow`] draws them depth-only into map `k`.
    /// Call it each frame the maps change (an empty list stops). The maps have the renderer's
    /// depth convention and `format`; where the device has `DEPTH_CLIP_CONTROL`, depth is
    /// clamped rather than clipped, so that casters between the light and a map's near plane
    /// are pancaked onto it (as engines fit a cascade's depth to the view and clamp the rest).
    /// `k` is a view's index in `views`. A view that is not an orthographic projection is left
    /// out (it draws nothing), as are those past the first [`MAX_HOST_SHADOW_VIEWS`] taken;
    /// returns how many views were taken.
    pub fn set_host_shadow_views(
        &mut self,
        device: &wgpu::Device,
        format: wgpu::TextureFormat,
        views: &[HostShadowView],
    ) -> usize {
        let lod_texels = self.settings.shadows.unwrap_or_default().lod_texels;
        self.host_shadows = views
            .iter()
            .enumerate()
            .filter_map(|(k, view)| {
                Cascade::from_host(view, self.depth_convention, lod_texels, self.scene_bounds).map(|c| (k, *view, c))
            })
            .take(MAX_HOST_SHADOW_VIEWS)
            .collect();
        if !self.host_shadows.is_empty() {
            let target = CasterTarget {
                format,
                compare: self.depth_convention.nearer_or_equal(),
                bias: wgpu::DepthBiasState::default(),
                unclipped_depth: device.features().contains(wgpu::Features::DEPTH_CLIP_CONTROL),
            };
            if self.host_pipelines.as_ref().is_none_or(|(made, _)| *made != target) {
                self.host_pipelines = Some((target, self.casters.pipelines(device, target)));
            }
        }
        self.host_shadows.len()
    }

    /// Records the trees' depth into host shadow map `k` ([`Self::set_host_shadow_views`]),
    /// in the host's pass over that map (after [`Self::prepare`]): what the map's light view
    /// selected this frame. Does nothing for a `k` not taken.
    pub fn render_host_shadow(&self, k: usize, pass: &mut wgpu::RenderPass<'_>) {
        let Some(taken) = self.host_shadows.iter().position(|(index, _, _)| *index == k) else { return };
        let (Some((_, pipelines)), Some(view), Some(group)) = (
            self.host_pipelines.as_ref(),
            self.shadow_views.get(self.cascades.len() + taken),
            self.frame_bind_groups.get(host_slot(taken)),
        ) else {
            return;
        };
        pass.set_bind_group(0, group, &[]);
        self.draw_view(pass, view, pipelines);
    }

    /// World bounds (min, max) of the instances: the union of their containers' block bounds,
    /// transformed; `None` without instances (or with only empty or non-finite blocks).
    #[must_use]
    pub fn instance_bounds(&self) -> Option<(Vec3, Vec3)> {
        self.scene_bounds
    }

    /// This frame's shadow cascades (empty without [`Settings::shadows`], and while the trees
    /// receive the host's maps, [`Self::receive_host_shadows`]): what a host needs to draw its
    /// own receivers with [`Self::shadow_bind_group`].
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
    /// comparison sampler (everything lit without [`Settings::shadows`]); the host's maps while
    /// the trees receive them ([`Self::receive_host_shadows`]). It may be replaced by
    /// [`Self::prepare`] when the shadow settings change: fetch it each frame.
    #[must_use]
    pub fn shadow_bind_group(&self) -> &wgpu::BindGroup {
        self.host_receiver.as_ref().map_or(&self.shadow_maps.bind_group, |host| &host.bind_group)
    }

    /// The trees (and host pipelines bound to [`Self::shadow_bind_group`]) receive the host's
    /// own shadow maps of the sun ([`Settings::sun`]) in place of the renderer's cascades: the
    /// cascades of a directional light whose maps the host renders, its casters' and, with
    /// [`Self::set_host_shadow_views`] and [`Self::render_host_shadow`], the trees'. `maps` is
    /// the host's depth texture (a 2D array, or a 2D texture with one layer: sampled, single
    /// sampled), `cascades` the light views of its layers in the renderer's depth convention.
    /// The orthographic ones are taken, finest first, at most [`MAX_CASCADES`]; each point
    /// reads the finest that holds it, with the same filter and normal offset
    /// ([`Shadows::normal_offset`](crate::Shadows::normal_offset)) as the renderer's own maps.
    /// Call it each frame (its matrices move with the view; an empty list, or
    /// [`Self::stop_receiving_host_shadows`], stops), before the pass that calls [`Self::render`]
    /// and after the host's shadow passes have been recorded. While the trees receive the host's
    /// maps, the renderer's own cascades are neither fitted nor drawn ([`FrameStats::shadow`]
    /// counts none); [`Settings::shadows`] still gives the casters, `lod_texels` and
    /// `normal_offset`. Returns how many cascades were taken.
    ///
    /// # Errors
    /// [`HostShadowError`] if `maps` is not a sampled, single-sampled 2D depth texture or a
    /// cascade names a layer it does not have; the trees then stop receiving the host's maps.
    pub fn receive_host_shadows(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        maps: &wgpu::Texture,
        cascades: &[HostShadowCascade],
    ) -> Result<usize, HostShadowError> {
        let previous = self.host_receiver.take();
        self.host_receiver =
            HostReceiver::new(device, &self.shadow_layout, maps, cascades, self.depth_convention, previous)?;
        self.write_host_receiver(queue);
        Ok(self.host_receiver.as_ref().map_or(0, |host| host.cascades.len()))
    }

    /// The trees receive the renderer's own shadow maps again ([`Settings::shadows`]; none
    /// without), not the host's ([`Self::receive_host_shadows`]), from the next
    /// [`Self::prepare`] on.
    pub fn stop_receiving_host_shadows(&mut self) {
        self.host_receiver = None;
    }
}

/// The quads a tree drawn with `technique` (the octahedral impostor or a billboard) is drawn with.
fn quad_kind(technique: Technique) -> QuadKind {
    match technique {
        Technique::Billboard => QuadKind::Facing,
        Technique::Crossed => QuadKind::Crossed,
        _ => QuadKind::Octahedral,
    }
}

/// The quads of `representations` a tree drawn with `kind` is drawn with, first and count, as the
/// runtime's [`treelod_runtime::QuadDraw`] of it lists them (count 0 where the model has none).
fn quad_range(representations: &Representations, kind: QuadKind) -> (u32, u32) {
    match (kind, &representations.billboards) {
        (QuadKind::Octahedral, _) => (0, representations.octahedral),
        (QuadKind::Facing, Some(billboards)) => billboards.facing,
        (QuadKind::Crossed, Some(billboards)) => billboards.crossed,
        (QuadKind::Facing | QuadKind::Crossed, None) => (0, 0),
    }
}

/// The trees a view draws through the point tree's selection ([`select_frame`]), ascending into
/// `out`: `assignment`'s full-mesh and point-tree trees and those `view`'s other techniques handed
/// back ([`treelod_runtime::TreeDraws::point_tree`]: pruned trees below their height).
fn point_tree_list(assignment: &Assignment, view: &View, out: &mut Vec<u32>) {
    let (full, spt) = (&assignment[Technique::Full], &assignment[Technique::Spt]);
    merge_ascending(&[full, spt, &view.draws.point_tree], out);
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

pub(crate) use treelod_runtime::max_axis_scale;

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
    [draws, pool, transforms]: [&wgpu::Buffer; 3],
) -> Vec<wgpu::BindGroup> {
    (0..FRAME_VIEWS)
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
                    wgpu::BindGroupEntry { binding: 4, resource: transforms.as_entire_binding() },
                ],
            })
        })
        .collect()
}

/// `f(chunk, part, offset)` for each chunk of `chunk` entries of `list` (at least 1), in
/// parallel, with `part` the entries of `items` from the chunk's first index (`offset`) to the
/// next chunk's (the last: to the end), so that the chunk's every index `i` is `part[i - offset]`
/// and no two parts overlap; the results in the chunks' order. `None` (nothing called) unless
/// `list` is strictly ascending and within `items`, or where it is empty.
fn in_ascending_chunks<T: Send, R: Send>(
    list: &[u32],
    items: &mut [T],
    chunk: usize,
    f: impl Fn(&[u32], &mut [T], usize) -> R + Sync,
) -> Option<Vec<R>> {
    use rayon::prelude::*;
    let ascending = list.windows(2).all(|w| w[0] < w[1]) && list.last().is_some_and(|&l| (l as usize) < items.len());
    if !ascending {
        return None;
    }
    let chunks: Vec<&[u32]> = list.chunks(chunk.max(1)).collect();
    let mut offset = chunks.first()?.first().map(|&i| i as usize)?;
    let mut after = &mut items[offset..];
    let mut parts = Vec::with_capacity(chunks.len());
    for (k, &chunk) in chunks.iter().enumerate() {
        let end = chunks.get(k + 1).map_or(offset + after.len(), |next| next[0] as usize);
        let (part, tail) = std::mem::take(&mut after).split_at_mut(end - offset);
        parts.push((chunk, part, offset));
        (after, offset) = (tail, end);
    }
    Some(parts.into_par_iter().map(|(chunk, part, offset)| f(chunk, part, offset)).collect())
}

/// Of chunk `chunk` of `count` instances ([`treelod_runtime::CHOOSE_CHUNK`] each), those marked
/// in `recorded` (a bit per instance; the CPU's draws, marked once however often they are listed,
/// where sorting the list of draws took the orchid's 10^4 trees twice as long) or drawn by `gpu`
/// (entries not [`InstanceDrawGpu::SKIP`]) whose flag in `flags` is set (instances past its end:
/// set), ascending and each once; none at all, after a byte compare per instance, where the
/// chunk's flags are all unset. The willow's 10^6 trees list up to 887k a frame (`docs/cli.md`).
fn occlusion_candidates<'a>(
    chunk: usize,
    count: usize,
    (recorded, flags, gpu): (&'a [u64], &'a [bool], &'a [InstanceDrawGpu]),
) -> impl Iterator<Item = u32> + 'a {
    const CHUNK: usize = treelod_runtime::CHOOSE_CHUNK;
    let indices = (chunk * CHUNK).min(count)..count.min((chunk + 1) * CHUNK);
    let skip = indices.end <= flags.len() && !flags[indices.clone()].contains(&true);
    let indices = if skip { 0..0 } else { indices };
    indices
        .filter(move |&i| {
            let drawn = recorded.get(i / 64).is_some_and(|word| word >> (i % 64) & 1 != 0)
                || gpu.get(i).is_some_and(|d| *d != InstanceDrawGpu::SKIP);
            drawn && flags.get(i).copied().unwrap_or(true)
        })
        .filter_map(|i| u32::try_from(i).ok())
}

/// Which view [`Renderer::select_view`] selects: the camera's, the camera's for the techniques
/// trees in a transition are leaving, or a shadow cascade's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Camera,
    Leaving,
    Shadow,
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The candidates are the instances below the count that the CPU recorded or the GPU
        /// draws and whose flag is set (or that lie past the flags), ascending and once each,
        /// whatever the chunks' sizes against the count.
        #[test]
        fn occlusion_candidates_are_the_drawn_flagged_instances_ascending_and_once(
            recorded in proptest::collection::vec(0u32..3000, 0..400),
            gpu in proptest::collection::vec(proptest::prelude::any::<bool>(), 0..2600),
            flags in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..2600),
            count in 0usize..2600,
        ) {
            // Flags mostly unset, so that whole chunks are skipped.
            let flags: Vec<bool> = flags.iter().map(|&f| f < 16).collect();
            let mut marks = vec![0u64; count.div_ceil(64)];
            for &i in recorded.iter().filter(|&&i| (i as usize) < count) {
                marks[i as usize / 64] |= 1 << (i % 64);
            }
            let draws: Vec<InstanceDrawGpu> = gpu
                .iter()
                .map(|&d| if d { InstanceDrawGpu::POINT_TREE } else { InstanceDrawGpu::SKIP })
                .collect();
            let chunks = count.div_ceil(treelod_runtime::CHOOSE_CHUNK) + 1;
            let got: Vec<u32> =
                (0..chunks).flat_map(|chunk| occlusion_candidates(chunk, count, (&marks, &flags, &draws))).collect();
            let expected: Vec<u32> = (0..count)
                .filter(|&i| recorded.contains(&u32::try_from(i).unwrap()) || gpu.get(i) == Some(&true))
                .filter(|&i| flags.get(i).copied().unwrap_or(true))
                .map(|i| u32::try_from(i).unwrap())
                .collect();
            proptest::prop_assert_eq!(got, expected);
        }
    }

    proptest::proptest! {
        /// Each chunk's part holds exactly its own indices, at their index less its offset, the
        /// results come in the chunks' order, and any list not ascending or not within the items
        /// is refused.
        #[test]
        fn ascending_chunks_write_their_own_parts(
            picks in proptest::collection::vec(proptest::prelude::any::<bool>(), 0..300),
            chunk in 1usize..40,
            unsorted in proptest::prelude::any::<bool>(),
        ) {
            let mut list: Vec<u32> =
                picks.iter().enumerate().filter(|(_, p)| **p).map(|(i, _)| u32::try_from(i).unwrap()).collect();
            if unsorted && list.len() > 1 {
                list.swap(0, 1);
            }
            let mut items = vec![u32::MAX; picks.len()];
            let got = in_ascending_chunks(&list, &mut items, chunk, |c, part, offset| {
                for &i in c {
                    part[i as usize - offset] = i;
                }
                (c.to_vec(), part.len())
            });
            if list.is_empty() || (unsorted && list.len() > 1) {
                proptest::prop_assert!(got.is_none());
                proptest::prop_assert!(items.iter().all(|&v| v == u32::MAX));
            } else {
                let got = got.expect("an ascending list");
                let joined: Vec<u32> = got.iter().flat_map(|(c, _)| c.iter().copied()).collect();
                proptest::prop_assert_eq!(&joined, &list);
                proptest::prop_assert_eq!(got.iter().map(|(_, n)| n).sum::<usize>(), items.len() - list[0] as usize);
                for (i, &v) in items.iter().enumerate() {
                    let listed = list.contains(&u32::try_from(i).unwrap());
                    proptest::prop_assert_eq!(v, if listed { u32::try_from(i).unwrap() } else { u32::MAX });
                }
            }
            let mut short = vec![0u32; list.last().map_or(0, |&l| l as usize)];
            let refused = in_ascending_chunks(&list, &mut short, chunk, |_, _, _| ());
            proptest::prop_assert!(refused.is_none(), "the last index past the items");
        }
    }

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
