//! A flat ground that receives the trees' shadows: for tools and tests, and an example of a host
//! surface sampling the renderer's shadow maps through [`crate::SHADOW_WGSL`] and
//! [`Renderer::shadow_bind_group`].

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::{Camera, Renderer};

const SHADER: &str =
    concat!(include_str!("../../../shaders/shared/shadow.wgsl"), include_str!("../../../shaders/ground.wgsl"));

/// WGSL twin: `GroundUniform` in `shaders/ground.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GroundUniform {
    view_proj: [[f32; 4]; 4],
    sun: [f32; 4],
    sun_colour: [f32; 4],
    colour: [f32; 4],
    extent: [f32; 4],
}

/// A horizontal square lit as the trees are (the renderer's sun, colour and ambient), shadowed by
/// them where [`crate::Settings::shadows`] is on.
pub struct Ground {
    /// Centre of the square, world space (its height is the ground's).
    pub centre: Vec3,
    /// Half the side of the square, metres.
    pub half_size: f32,
    /// Albedo, linear RGB.
    pub colour: Vec3,
    pipeline: wgpu::RenderPipeline,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl Ground {
    /// A ground for `renderer`'s target formats, centred at `centre`, `half_size` metres to each
    /// side, a light grey-green.
    #[must_use]
    pub fn new(device: &wgpu::Device, renderer: &Renderer, centre: Vec3, half_size: f32) -> Self {
        let UniformPass { pipeline, uniform, bind_group } = UniformPass::new(
            device,
            renderer,
            "treelod ground",
            SHADER,
            ("vs_ground", "fs_ground"),
            size_of::<GroundUniform>() as u64,
            // Group 2: the renderer's shadow maps.
            &[None, Some(renderer.shadow_bind_group_layout())],
            // Tested as the trees are, so it meets them right in either depth convention.
            Some(renderer.depth_convention().compare()),
        );
        Self { centre, half_size, colour: Vec3::new(0.55, 0.6, 0.45), pipeline, uniform, bind_group }
    }

    /// A ground under every instance of `renderer`: at the lowest point of their blocks (the trunks'
    /// bases, for trees standing upright), wide enough to catch their shadows with the sun down to
    /// about 25° above the horizon.
    #[must_use]
    pub fn under_instances(device: &wgpu::Device, renderer: &Renderer) -> Self {
        let (min, max) = renderer.instance_bounds().unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
        let centre = Vec3::new(0.5 * (min.x + max.x), min.y, 0.5 * (min.z + max.z));
        let extent = (max - min).max_element().max(1.0);
        Self::new(device, renderer, centre, 0.5 * extent + 2.0 * (max.y - min.y).max(1.0))
    }

    /// Draws the ground into `pass` (after [`Renderer::prepare`] for `camera`, so that the
    /// renderer's shadow bind group holds this frame's cascades), lit by `renderer`'s settings.
    pub fn render(&self, queue: &wgpu::Queue, pass: &mut wgpu::RenderPass<'_>, renderer: &Renderer, camera: &Camera) {
        let settings = renderer.settings();
        let sun = settings.sun.normalize_or(Vec3::Y);
        let uniform = GroundUniform {
            view_proj: camera.view_proj().to_cols_array_2d(),
            sun: sun.extend(settings.ambient.clamp(0.0, 1.0)).to_array(),
            sun_colour: settings.sun_colour.max(Vec3::ZERO).extend(1.0).to_array(),
            colour: self.colour.extend(1.0).to_array(),
            extent: self.centre.extend(self.half_size).to_array(),
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_bind_group(2, renderer.shadow_bind_group(), &[]);
        pass.draw(0..6, 0..1);
    }
}

const _: () = assert!(size_of::<GroundUniform>() == 128);

/// A pipeline for a renderer's targets drawing a shader's vertices without buffers (a ground, a
/// sky), one uniform buffer at group 0 (binding 0), and the buffer and its bind group.
pub(crate) struct UniformPass {
    pub pipeline: wgpu::RenderPipeline,
    pub uniform: wgpu::Buffer,
    pub bind_group: wgpu::BindGroup,
}

impl UniformPass {
    /// `entries` (vertex, fragment) of `shader`; a uniform of `size` bytes; the layouts of groups
    /// 1 and up in `groups`; depth tested with `depth` and written, or (`None`) neither.
    #[expect(clippy::too_many_arguments, reason = "a pipeline's parts, each needed")]
    pub fn new(
        device: &wgpu::Device,
        renderer: &Renderer,
        label: &str,
        shader: &str,
        entries: (&str, &str),
        size: u64,
        groups: &[Option<&wgpu::BindGroupLayout>],
        depth: Option<wgpu::CompareFunction>,
    ) -> Self {
        let formats = renderer.formats();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let mut layouts = vec![Some(&layout)];
        layouts.extend_from_slice(groups);
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &layouts,
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(shader.into()),
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some(entries.0),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState { cull_mode: None, ..wgpu::PrimitiveState::default() },
            // In the pass's depth attachment always; without a test, not written either.
            depth_stencil: Some(wgpu::DepthStencilState {
                format: formats.depth,
                depth_write_enabled: Some(depth.is_some()),
                depth_compare: Some(depth.unwrap_or(wgpu::CompareFunction::Always)),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState {
                count: formats.sample_count.max(1),
                ..wgpu::MultisampleState::default()
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some(entries.1),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: formats.color,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }],
        });
        Self { pipeline, uniform, bind_group }
    }
}
