//! The tree pipelines and their bind group layouts: per draw bucket ([`Bucket`]) one shader
//! module composed from `shaders/tree/` (the common part, then the representation's files), a
//! pipeline of the host's pass and a depth-only pipeline of the shadow pass; the frame (group 0)
//! and model (group 1) layouts they bind, beside the shadow receivers' (group 2).

use crate::draws::Bucket;
use crate::settings::{DepthConvention, RendererFormats};
use crate::shadows::{SHADOW_FORMAT, ShadowMaps};

/// The WGSL of a tree pipeline: the record structs, the draw constants and the shadow receivers
/// (`shaders/shared/`), the tree shaders' common part, then the named files of `shaders/tree/`.
macro_rules! tree_wgsl {
    ($($file:literal),+) => {
        concat!(
            include_str!("../../../shaders/shared/records.wgsl"),
            include_str!("../../../shaders/shared/draw.wgsl"),
            include_str!("../../../shaders/shared/shadow.wgsl"),
            include_str!("../../../shaders/tree/common.wgsl"),
            $(include_str!(concat!("../../../shaders/tree/", $file))),+
        )
    };
}

/// The tree pipelines, in bucket order, and the layouts of their bind groups.
pub(crate) struct Pipelines {
    /// Group 0: the view's frame uniform, the draw infos, and the pool as triangles and points.
    pub(crate) frame_layout: wgpu::BindGroupLayout,
    /// Group 1: a model's vertices, materials, textures and per-representation buffers.
    pub(crate) model_layout: wgpu::BindGroupLayout,
    /// Group 2: the shadow receivers' cascades and maps.
    pub(crate) shadow_layout: wgpu::BindGroupLayout,
    /// The host's pass's pipelines.
    pub(crate) colour: [wgpu::RenderPipeline; Bucket::COUNT],
    /// The shadow pass's depth-only pipelines.
    pub(crate) shadow: [wgpu::RenderPipeline; Bucket::COUNT],
}

impl Pipelines {
    /// Creates the layouts and the pipelines for the host's target formats and depth convention.
    pub(crate) fn new(device: &wgpu::Device, formats: RendererFormats, depth: DepthConvention) -> Self {
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
        // One module per bucket, shared by its colour and shadow pipelines.
        let modules = Bucket::ALL.map(|bucket| {
            let stages = stages(bucket);
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
        // The shadow pass: depth only, one sample, a slope-scaled bias against self-shadowing.
        let caster_overrides = [("sample_count", 1.0), ("crossfade", f64::from(treelod_runtime::CROSSFADE))];
        let colour_target =
            [Some(wgpu::ColorTargetState { format: formats.color, blend: None, write_mask: wgpu::ColorWrites::ALL })];
        // A pipeline of the host's pass, or (`caster`) of the shadow pass.
        let pipeline = |module: &wgpu::ShaderModule, label: &str, vs: &str, fs: &str, caster: bool| {
            let constants = || wgpu::PipelineCompilationOptions {
                constants: if caster { &caster_overrides } else { &overrides },
                ..wgpu::PipelineCompilationOptions::default()
            };
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(if caster { &caster_layout } else { &layout }),
                vertex: wgpu::VertexState {
                    module,
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
                    module,
                    entry_point: Some(fs),
                    compilation_options: constants(),
                    targets: if caster { &[] } else { &colour_target },
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let colour = Bucket::ALL.map(|bucket| {
            let stages = stages(bucket);
            pipeline(&modules[bucket as usize], stages.label, stages.vs, stages.fs, false)
        });
        let shadow = Bucket::ALL.map(|bucket| {
            let stages = stages(bucket);
            pipeline(&modules[bucket as usize], stages.shadow_label, stages.vs, stages.shadow_fs, true)
        });
        Self { frame_layout, model_layout, shadow_layout, colour, shadow }
    }
}

/// The shader stages of one bucket's pipelines and the WGSL they come from.
struct Stages {
    /// The shader module's label.
    module: &'static str,
    /// The module's WGSL (`tree_wgsl!`).
    wgsl: &'static str,
    /// The vertex stage, shared by the colour and shadow pipelines.
    vs: &'static str,
    /// The colour pass's fragment stage and pipeline label.
    fs: &'static str,
    label: &'static str,
    /// The shadow pass's fragment stage and pipeline label.
    shadow_fs: &'static str,
    shadow_label: &'static str,
}

/// What `bucket` is drawn with. Pruned leaves share the triangles' fragment stages, billboards
/// the impostor planes'.
fn stages(bucket: Bucket) -> Stages {
    match bucket {
        Bucket::Triangles => Stages {
            module: "treelod tree/triangles.wgsl",
            wgsl: tree_wgsl!("triangles.wgsl"),
            vs: "vs_triangle",
            fs: "fs_triangle",
            label: "treelod triangles",
            shadow_fs: "fs_shadow_triangle",
            shadow_label: "treelod shadow triangles",
        },
        Bucket::Points => Stages {
            module: "treelod tree/points.wgsl",
            wgsl: tree_wgsl!("points.wgsl"),
            vs: "vs_point",
            fs: "fs_point",
            label: "treelod points",
            shadow_fs: "fs_shadow_point",
            shadow_label: "treelod shadow points",
        },
        Bucket::Pruned => Stages {
            module: "treelod tree/pruned.wgsl",
            wgsl: tree_wgsl!("triangles.wgsl", "pruned.wgsl"),
            vs: "vs_pruned",
            fs: "fs_triangle",
            label: "treelod pruned leaves and bark",
            shadow_fs: "fs_shadow_triangle",
            shadow_label: "treelod shadow pruned leaves and bark",
        },
        Bucket::Planes => Stages {
            module: "treelod tree/planes.wgsl",
            wgsl: tree_wgsl!("planes.wgsl"),
            vs: "vs_plane",
            fs: "fs_plane",
            label: "treelod impostor planes",
            shadow_fs: "fs_shadow_plane",
            shadow_label: "treelod shadow impostor planes",
        },
        Bucket::Billboards => Stages {
            module: "treelod tree/billboards.wgsl",
            wgsl: tree_wgsl!("planes.wgsl", "billboards.wgsl"),
            vs: "vs_billboard",
            fs: "fs_plane",
            label: "treelod baseline billboards",
            shadow_fs: "fs_shadow_plane",
            shadow_label: "treelod shadow billboards",
        },
        Bucket::Ellipsoids => Stages {
            module: "treelod tree/ellipsoids.wgsl",
            wgsl: tree_wgsl!("ellipsoids.wgsl"),
            vs: "vs_ellipsoid",
            fs: "fs_ellipsoid",
            label: "treelod ellipsoids",
            shadow_fs: "fs_shadow_ellipsoid",
            shadow_label: "treelod shadow ellipsoids",
        },
        Bucket::Lines => Stages {
            module: "treelod tree/lines.wgsl",
            wgsl: tree_wgsl!("lines.wgsl"),
            vs: "vs_line",
            fs: "fs_line",
            label: "treelod lines",
            shadow_fs: "fs_shadow_line",
            shadow_label: "treelod shadow lines",
        },
    }
}
