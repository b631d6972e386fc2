//! The occlusion factor of pruned trees (Neubert et al. 2011 §5): the fraction of a tree's hull
//! samples that the depth buffer of an earlier frame shows, measured on the GPU and read back
//! without stalling.
//!
//! After the host's pass, [`crate::Renderer::measure_occlusion`] records a compute pass that
//! projects the hull samples ([`treelod_runtime::PruneLod::samples`]) of every tree drawn pruned
//! with that frame's camera into that frame's depth buffer — the reprojection of the paper: the
//! test runs with the camera the depth was drawn with. Only samples on the side of the hull that
//! faces the camera count (the far side is hidden by the tree's own leaves); each is moved towards
//! the eye by a quarter of the tree's radius first, so that the leaf it sits on and the crown's
//! own outer leaves do not hide it (with 5 % an unoccluded tree measured 0.73–0.93 visible and
//! lost that share of its leaves), while a tree in front, a radius or more away, still does. A
//! sample is visible if its depth is not behind the buffer's, or if it lies off-screen. The counts
//! are copied to a mappable buffer, mapped by a later [`crate::Renderer::prepare`] and turned into
//! per-instance fractions; while a measurement is in flight no new one is recorded.
//!
//! With the policy's occlusion on (`Policy::occlusion`), the trees measured are the camera's
//! drawn trees whose choice their fraction can change (`PolicyState::visibility_matters`): in a
//! large forest most trees are far and drawn alike whatever their fraction, and each job is a
//! workgroup and 8 bytes uploaded. A read gives the trees of its measurement their fraction and
//! puts those of the read before that it lacks back to 1.
//!
//! A job is the tree's instance and model: the shader reads the tree's transform from the
//! renderer's instance transforms (uploaded when the instances change, shared with the draws) and
//! its model's hull centre, radius and samples from a table made once per model. Each job held
//! the tree's transform, centre and margin before (96 bytes); measured on the weeping willow's
//! 10^6 trees (`docs/cli.md`), a frame measured up to 813,603 trees, 78 MB uploaded where it is
//! now 6.5 MB.
//!
//! A measurement is ignored (its trees count as fully visible) for a tree whose distance to the
//! eye at measurement time is less than 4× how far the eye has moved since, or when the view
//! direction has turned by more than 15°: after a camera jump the old depth says nothing.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};

/// WGSL of the measurement (after the instance transform it reads); `DEPTH_TEXTURE` is replaced
/// by the depth binding's type.
const SHADER: &str =
    concat!(include_str!("../../../shaders/shared/draw.wgsl"), include_str!("../../../shaders/occlusion.wgsl"));

/// Largest view-direction change, as a cosine, for which a measurement still applies (15°).
const MAX_TURN_COS: f32 = 0.965_925_8;
/// A measurement applies to a tree while the eye has moved less than this fraction of the tree's
/// distance at measurement time.
const MAX_MOVE_FRACTION: f32 = 0.25;
/// Samples are moved towards the eye by this fraction of the tree's radius (see the module
/// documentation).
const SAMPLE_MARGIN: f32 = 0.25;
/// Trees measured per frame at most (one workgroup each, in a 2D dispatch).
const MAX_JOBS: usize = 65_535 * 16;
/// Workgroups per row of the dispatch.
const ROW: u32 = 65_535;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FrameGpu {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    size: [f32; 2],
    jobs: u32,
    _pad: u32,
}

/// A model's hull as the measurement reads it. WGSL twin: `OcclusionModel`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ModelGpu {
    /// Hull centre (xyz) and culling radius (w), model space.
    centre: [f32; 4],
    /// Its samples in the sample buffer.
    first: u32,
    count: u32,
    _pad: [u32; 2],
}

/// One tree to measure: its instance (in the renderer's list and transforms) and its model (an
/// index of [`Occlusion::add_model`]'s models). WGSL twin: `OcclusionJob`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct Job {
    pub instance: u32,
    pub model: u32,
}

/// A measurement recorded and not yet read.
struct Pending {
    staging: wgpu::Buffer,
    /// Instance and distance to the eye of each job.
    jobs: Vec<(u32, f32)>,
    eye: Vec3,
    forward: Vec3,
    mapping: bool,
    /// [`MAPPING`], [`MAPPED`] or [`FAILED`].
    state: Arc<AtomicU8>,
}

const MAPPING: u8 = 0;
const MAPPED: u8 = 1;
const FAILED: u8 = 2;

/// GPU state of the occlusion measurement.
pub(crate) struct Occlusion {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    samples: Vec<[f32; 4]>,
    sample_buffer: Option<wgpu::Buffer>,
    /// Per model, in the renderer's order.
    models: Vec<ModelGpu>,
    model_buffer: Option<wgpu::Buffer>,
    pending: Option<Pending>,
    /// The instances the last measurement read ([`Self::collect`]) gave a fraction.
    read: Vec<u32>,
}

impl Occlusion {
    /// The measurement pipeline for a depth attachment of `sample_count` samples that runs as
    /// `depth` says.
    pub fn new(device: &wgpu::Device, sample_count: u32, depth: crate::DepthConvention) -> Self {
        let multisampled = sample_count > 1;
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod occlusion"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                storage(1, true),
                storage(2, true),
                storage(3, false),
                storage(5, true),
                storage(6, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled,
                    },
                    count: None,
                },
            ],
        });
        let depth_type = if multisampled { "texture_depth_multisampled_2d" } else { "texture_depth_2d" };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("treelod occlusion.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.replace("DEPTH_TEXTURE", depth_type).into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("treelod occlusion"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("treelod occlusion"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("measure"),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: &[
                    ("reverse_z", f64::from(u8::from(depth == crate::DepthConvention::Reverse))),
                    ("sample_margin", f64::from(SAMPLE_MARGIN)),
                ],
                ..wgpu::PipelineCompilationOptions::default()
            },
            cache: None,
        });
        Self {
            layout,
            pipeline,
            samples: Vec::new(),
            sample_buffer: None,
            models: Vec::new(),
            model_buffer: None,
            pending: None,
            read: Vec::new(),
        }
    }

    /// Adds the next model (models are added in the renderer's order, a job names its model by
    /// that index): its hull samples, and the centre and radius of its culling sphere, all model
    /// space.
    pub fn add_model(&mut self, samples: &[Vec3], centre: Vec3, radius: f32) {
        let first = u32::try_from(self.samples.len()).unwrap_or(u32::MAX);
        let count = u32::try_from(samples.len()).unwrap_or(u32::MAX);
        self.samples.extend(samples.iter().map(|s| s.extend(1.0).to_array()));
        self.models.push(ModelGpu { centre: centre.extend(radius).to_array(), first, count, _pad: [0; 2] });
        self.sample_buffer = None;
        self.model_buffer = None;
    }

    /// The hull samples of model `model` (an index of [`Self::add_model`]'s); 0 for an unknown
    /// model. A tree of a model without samples is not measured.
    pub fn sample_count(&self, model: u32) -> u32 {
        self.models.get(model as usize).map_or(0, |m| m.count)
    }

    /// Whether a measurement is recorded and not read yet: [`Self::record`] records none until
    /// [`Self::collect`] has read it, so a frame prepared meanwhile needs no jobs.
    pub fn in_flight(&self) -> bool {
        self.pending.is_some()
    }

    /// Records the measurement of `jobs` against `depth` (drawn with `view_proj` from `eye`) into
    /// `encoder`, unless one is still in flight or there is nothing to measure. `instances` and
    /// `transforms` are the renderer's list and the buffer of their transforms
    /// ([`crate::draws::InstanceTransform`]), which the jobs index.
    #[expect(clippy::too_many_arguments, reason = "one frame's camera, targets and instances")]
    pub fn record(
        &mut self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        depth: &wgpu::TextureView,
        size: (u32, u32),
        (view_proj, eye, forward): (Mat4, Vec3, Vec3),
        (instances, transforms): (&[treelod_runtime::Instance], &wgpu::Buffer),
        jobs: &[Job],
    ) {
        if self.pending.is_some() || jobs.is_empty() || self.samples.is_empty() {
            return;
        }
        let jobs = &jobs[..jobs.len().min(MAX_JOBS)];
        let init = |label, contents: &[u8], usage| {
            wgpu::util::DeviceExt::create_buffer_init(
                device,
                &wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage },
            )
        };
        let storage = wgpu::BufferUsages::STORAGE;
        let samples = self
            .sample_buffer
            .get_or_insert_with(|| init("treelod occlusion samples", bytemuck::cast_slice(&self.samples), storage));
        let models = self
            .model_buffer
            .get_or_insert_with(|| init("treelod occlusion models", bytemuck::cast_slice(&self.models), storage));
        let count = u32::try_from(jobs.len()).unwrap_or(u32::MAX);
        #[expect(clippy::cast_precision_loss, reason = "viewport sizes are far below 2^24")]
        let frame = FrameGpu {
            view_proj: view_proj.to_cols_array_2d(),
            eye: eye.extend(0.0).to_array(),
            size: [size.0 as f32, size.1 as f32],
            jobs: count,
            _pad: 0,
        };
        let frame_buffer = init("treelod occlusion frame", bytemuck::bytes_of(&frame), wgpu::BufferUsages::UNIFORM);
        let job_buffer = init("treelod occlusion jobs", bytemuck::cast_slice(jobs), storage);
        let counts_size = u64::from(count) * 8;
        // A new buffer reads as zeros (wgpu clears it): nothing to upload.
        let counts = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("treelod occlusion counts"),
            size: counts_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("treelod occlusion readback"),
            size: counts_size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("treelod occlusion"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: frame_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: job_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: samples.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: counts.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::TextureView(depth) },
                wgpu::BindGroupEntry { binding: 5, resource: transforms.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 6, resource: models.as_entire_binding() },
            ],
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("treelod occlusion"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(count.min(ROW), count.div_ceil(ROW), 1);
        }
        encoder.copy_buffer_to_buffer(&counts, 0, &staging, 0, counts_size);
        self.pending = Some(Pending {
            staging,
            jobs: self.distances(instances, jobs, eye),
            eye,
            forward,
            mapping: false,
            state: Arc::new(AtomicU8::new(MAPPING)),
        });
    }

    /// Each job's instance and the distance from `eye` to its tree's hull centre, in parallel
    /// (a job whose instance or model is unknown: infinitely far, never stale).
    fn distances(&self, instances: &[treelod_runtime::Instance], jobs: &[Job], eye: Vec3) -> Vec<(u32, f32)> {
        use rayon::prelude::*;
        jobs.par_iter()
            .map(|j| {
                let centre =
                    self.models.get(j.model as usize).map(|m| Vec3::new(m.centre[0], m.centre[1], m.centre[2]));
                let distance = match (instances.get(j.instance as usize), centre) {
                    (Some(instance), Some(centre)) => instance.transform.transform_point3(centre).distance(eye),
                    _ => f32::INFINITY,
                };
                (j.instance, distance)
            })
            .collect()
    }

    /// Reads a finished measurement, if any, into `fractions` (per instance, 1 = fully visible),
    /// given the camera of the frame being prepared: the trees it measured get their fraction,
    /// and those the measurement before gave one and this one did not go back to 1, so that no
    /// tree keeps an old measurement (the policy measures only the trees whose fraction matters
    /// to it, `PolicyState::visibility_matters`: a tree that comes near again starts fully
    /// visible, as one new to the view). Never blocks: a measurement whose commands have not
    /// been submitted or finished yet is read by a later call.
    pub fn collect(&mut self, device: &wgpu::Device, eye: Vec3, forward: Vec3, fractions: &mut [f32]) {
        let Some(pending) = &mut self.pending else { return };
        if !pending.mapping {
            // The host has submitted the frame that recorded it by now.
            let state = Arc::clone(&pending.state);
            pending.staging.slice(..).map_async(wgpu::MapMode::Read, move |result| {
                state.store(if result.is_ok() { MAPPED } else { FAILED }, Ordering::Release);
            });
            pending.mapping = true;
        }
        // A failed poll leaves the measurement pending; the next frame tries again.
        let _ = device.poll(wgpu::PollType::Poll);
        match pending.state.load(Ordering::Acquire) {
            MAPPED => {}
            FAILED => {
                // Lost (e.g. the device was lost): measure again.
                self.pending = None;
                return;
            }
            _ => return,
        }
        let turned = forward.dot(pending.forward) < MAX_TURN_COS;
        let moved = eye.distance(pending.eye);
        if let Ok(mapped) = pending.staging.slice(..).get_mapped_range() {
            for &instance in &self.read {
                if let Some(fraction) = fractions.get_mut(instance as usize) {
                    *fraction = 1.0;
                }
            }
            self.read.clear();
            self.read.extend(pending.jobs.iter().map(|&(instance, _)| instance));
            let counts: &[u32] = bytemuck::cast_slice(&mapped);
            for (&(instance, distance), pair) in pending.jobs.iter().zip(counts.chunks_exact(2)) {
                let Some(fraction) = fractions.get_mut(instance as usize) else { continue };
                let stale = turned || moved > MAX_MOVE_FRACTION * distance;
                #[expect(clippy::cast_precision_loss, reason = "at most 64 samples")]
                let visible = if pair[0] == 0 { 1.0 } else { pair[1] as f32 / pair[0] as f32 };
                *fraction = if stale { 1.0 } else { visible };
            }
        }
        pending.staging.unmap();
        self.pending = None;
    }
}
