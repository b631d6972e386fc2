//! The tree pipelines and their bind group layouts: per draw bucket ([`Bucket`]) one shader
//! module of its stages (`Bucket::stages`, composed from `shaders/tree/`: the common part, then
//! the representation's files), a pipeline of the host's pass and a depth-only pipeline of the
//! shadow pass; the frame (group 0) and model (group 1) layouts every bucket binds, beside the
//! shadow receivers' (group 2) and the bucket's own (group 3, `Bucket::group_entries`).

use crate::settings::{DepthConvention, RendererFormats};
use crate::shadows::{SHADOW_FORMAT, ShadowMaps};
use crate::technique::{Bucket, sampler, storage, texture};

/// The tree pipelines, in bucket order, and the layouts of their bind groups.
pub(crate) struct Pipelines {
    /// Group 0: the view's frame uniform, the draw infos, and the pool as triangles and points.
    pub(crate) frame_layout: wgpu::BindGroupLayout,
    /// Group 1: a model's vertices, materials, textures, and its whole-triangle list with the
    /// pruned leaves.
    pub(crate) model_layout: wgpu::BindGroupLayout,
    /// Group 3 per bucket: its representation's buffers and textures, if it has any.
    pub(crate) group_layouts: [Option<wgpu::BindGroupLayout>; Bucket::COUNT],
    /// Group 2: the shadow receivers' cascades and maps.
    pub(crate) shadow_layout: wgpu::BindGroupLayout,
    /// The host's pass's pipelines.
    pub(crate) colour: [wgpu::RenderPipeline; Bucket::COUNT],
    /// The shadow pass's depth-only pipelines.
    pub(crate) shadow: [wgpu::RenderPipeline; Bucket::COUNT],
    /// What more depth-only pipelines are made from.
    pub(crate) casters: Casters,
}

impl Pipelines {
    /// Creates the layouts and the pipelines for the host's target formats and depth convention.
    pub(crate) fn new(device: &wgpu::Device, formats: RendererFormats, depth: DepthConvention) -> Self {
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
                // The draws: the ellipsoids' and lines' fragment stages read them too.
                storage(1, wgpu::ShaderStages::VERTEX_FRAGMENT),
                storage(2, wgpu::ShaderStages::VERTEX),
                storage(3, wgpu::ShaderStages::VERTEX),
                // The instances' transforms, which the draws name (and the fragment stages
                // that ray-cast in model space read).
                storage(4, wgpu::ShaderStages::VERTEX_FRAGMENT),
            ],
        });
        let float = wgpu::TextureSampleType::Float { filterable: true };
        let model_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod model"),
            entries: &[
                storage(0, wgpu::ShaderStages::VERTEX),
                storage(1, wgpu::ShaderStages::FRAGMENT),
                texture(2, float, wgpu::TextureViewDimension::D2Array),
                sampler(3, wgpu::SamplerBindingType::Filtering),
                // The whole-triangle list and the pruned leaves.
                storage(4, wgpu::ShaderStages::VERTEX),
                storage(5, wgpu::ShaderStages::VERTEX),
            ],
        });
        let group_layouts = Bucket::ALL.map(|bucket| {
            bucket.group_entries().map(|entries| {
                device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some(bucket.stages().label),
                    entries,
                })
            })
        });
        let shadow_layout = ShadowMaps::layout(device);
        // Per bucket, the layouts of its colour pipeline (the receivers in group 2) and of its
        // shadow caster (group 2 unused), each with the bucket's own group 3 if it has one.
        let layouts = |caster: bool| {
            Bucket::ALL.map(|bucket| {
                let own = group_layouts[bucket as usize].as_ref();
                let receivers = if caster { None } else { Some(&shadow_layout) };
                let groups = [Some(&frame_layout), Some(&model_layout), receivers, own];
                let count = if own.is_some() {
                    4
                } else if caster {
                    2
                } else {
                    3
                };
                device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some(if caster { "treelod shadow casters" } else { "treelod" }),
                    bind_group_layouts: &groups[..count],
                    immediate_size: 0,
                })
            })
        };
        let (colour_layouts, caster_layouts) = (layouts(false), layouts(true));
        // One module per bucket, shared by its colour and shadow pipelines.
        let modules = Bucket::ALL.map(|bucket| {
            let stages = bucket.stages();
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(stages.module),
                source: wgpu::ShaderSource::Wgsl(stages.wgsl.into()),
            })
        });
        // With MSAA, alpha-tested leaves write a sample mask from their filtered alpha (alpha to
        // coverage, in the shader) so their density holds where small mips thin out a test.
        let overrides = [
            ("sample_count", f64::from(formats.sample_count.max(1))),
            ("crossfade", f64::from(treelod_runtime::CROSSFADE)),
        ];
        let colour_target =
            [Some(wgpu::ColorTargetState { format: formats.color, blend: None, write_mask: wgpu::ColorWrites::ALL })];
        let colour = Bucket::ALL.map(|bucket| {
            let stages = bucket.stages();
            tree_pipeline(
                device,
                &TreePipeline {
                    label: stages.label,
                    layout: &colour_layouts[bucket as usize],
                    module: &modules[bucket as usize],
                    entry_points: (stages.vs, stages.fs),
                    overrides: &overrides,
                    depth: wgpu::DepthStencilState {
                        format: formats.depth,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(depth.compare()),
                        stencil: wgpu::StencilState::default(),
                        bias: wgpu::DepthBiasState::default(),
                    },
                    sample_count: formats.sample_count.max(1),
                    targets: &colour_target,
                    unclipped_depth: false,
                },
            )
        });
        let casters = Casters { modules, layouts: caster_layouts };
        // The renderer's own maps are always standard depth, with a slope-scaled bias against
        // self-shadowing (its receivers add no bias of their own but the normal offset).
        let shadow = casters.pipelines(
            device,
            CasterTarget {
                format: SHADOW_FORMAT,
                compare: wgpu::CompareFunction::Less,
                bias: wgpu::DepthBiasState { constant: 2, slope_scale: 2.0, clamp: 0.0 },
                unclipped_depth: false,
            },
        );
        Self { frame_layout, model_layout, group_layouts, shadow_layout, colour, shadow, casters }
    }
}

/// What a depth-only caster pipeline draws into.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CasterTarget {
    pub(crate) format: wgpu::TextureFormat,
    pub(crate) compare: wgpu::CompareFunction,
    pub(crate) bias: wgpu::DepthBiasState,
    /// Depth clamped instead of clipped (`wgpu::Features::DEPTH_CLIP_CONTROL`): casters between
    /// the light and the map's near plane are pancaked onto it.
    pub(crate) unclipped_depth: bool,
}

/// The shader modules and caster layouts the depth-only pipelines are made from: kept, so that
/// pipelines for a host's shadow maps ([`CasterTarget`]) can be made when the host names them.
pub(crate) struct Casters {
    modules: [wgpu::ShaderModule; Bucket::COUNT],
    layouts: [wgpu::PipelineLayout; Bucket::COUNT],
}

impl Casters {
    /// One depth-only pipeline per bucket (the bucket's shadow stages: alpha-tested leaves, no
    /// colour), one sample.
    pub(crate) fn pipelines(
        &self,
        device: &wgpu::Device,
        target: CasterTarget,
    ) -> [wgpu::RenderPipeline; Bucket::COUNT] {
        let overrides = [("sample_count", 1.0), ("crossfade", f64::from(treelod_runtime::CROSSFADE))];
        Bucket::ALL.map(|bucket| {
            let stages = bucket.stages();
            tree_pipeline(
                device,
                &TreePipeline {
                    label: stages.shadow_label,
                    layout: &self.layouts[bucket as usize],
                    module: &self.modules[bucket as usize],
                    entry_points: (stages.vs, stages.shadow_fs),
                    overrides: &overrides,
                    depth: wgpu::DepthStencilState {
                        format: target.format,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(target.compare),
                        stencil: wgpu::StencilState::default(),
                        bias: target.bias,
                    },
                    sample_count: 1,
                    targets: &[],
                    unclipped_depth: target.unclipped_depth,
                },
            )
        })
    }
}

/// What differs between the tree pipelines: the host's pass's and the depth-only casters'.
struct TreePipeline<'a> {
    label: &'a str,
    layout: &'a wgpu::PipelineLayout,
    module: &'a wgpu::ShaderModule,
    /// The vertex and fragment entry points.
    entry_points: (&'a str, &'a str),
    overrides: &'a [(&'a str, f64)],
    depth: wgpu::DepthStencilState,
    sample_count: u32,
    targets: &'a [Option<wgpu::ColorTargetState>],
    unclipped_depth: bool,
}

/// A tree pipeline: triangle lists from no vertex buffers (the stages read the draws), both
/// faces drawn (leaves are cards seen from both sides; splats always face the camera).
fn tree_pipeline(device: &wgpu::Device, p: &TreePipeline<'_>) -> wgpu::RenderPipeline {
    let constants =
        || wgpu::PipelineCompilationOptions { constants: p.overrides, ..wgpu::PipelineCompilationOptions::default() };
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(p.label),
        layout: Some(p.layout),
        vertex: wgpu::VertexState {
            module: p.module,
            entry_point: Some(p.entry_points.0),
            compilation_options: constants(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            cull_mode: None,
            unclipped_depth: p.unclipped_depth,
            ..wgpu::PrimitiveState::default()
        },
        depth_stencil: Some(p.depth.clone()),
        multisample: wgpu::MultisampleState { count: p.sample_count, mask: !0, alpha_to_coverage_enabled: false },
        fragment: Some(wgpu::FragmentState {
            module: p.module,
            entry_point: Some(p.entry_points.1),
            compilation_options: constants(),
            targets: p.targets,
        }),
        multiview_mask: None,
        cache: None,
    })
}
