//! A sky gradient for tools to draw behind the trees (the viewer): lighter at the horizon, bluer
//! up, a glow around the renderer's sun. Engines draw their own sky; this one exists so that a
//! tree is judged against something like the backgrounds it will be seen on, not a white page.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::{Camera, Renderer};

const SHADER: &str = include_str!("../../../shaders/sky.wgsl");

/// WGSL twin: `SkyUniform` in `shaders/sky.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct SkyUniform {
    inverse_view_proj: [[f32; 4]; 4],
    sun: [f32; 4],
    zenith: [f32; 4],
    horizon: [f32; 4],
    below: [f32; 4],
}

/// A full-screen gradient drawn first in a pass, without depth test or write.
pub struct Sky {
    /// Colour straight up, linear RGB.
    pub zenith: Vec3,
    /// Colour at the horizon, linear RGB.
    pub horizon: Vec3,
    /// Colour looked at below the horizon where no ground is drawn, linear RGB.
    pub below: Vec3,
    pipeline: wgpu::RenderPipeline,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl Sky {
    /// A sky for `renderer`'s target formats (colour, depth and samples), a clear day's colours.
    #[must_use]
    pub fn new(device: &wgpu::Device, renderer: &Renderer) -> Self {
        let formats = renderer.formats();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod sky"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("treelod sky"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("treelod sky.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("treelod sky"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_sky"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            // In the pass's depth attachment, but neither tested nor written: what is drawn after
            // covers it.
            depth_stencil: Some(wgpu::DepthStencilState {
                format: formats.depth,
                depth_write_enabled: Some(false),
                depth_compare: Some(wgpu::CompareFunction::Always),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState {
                count: formats.sample_count.max(1),
                ..wgpu::MultisampleState::default()
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_sky"),
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
            label: Some("treelod sky"),
            size: size_of::<SkyUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("treelod sky"),
            layout: &layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }],
        });
        Self {
            zenith: Vec3::new(0.16, 0.33, 0.72),
            horizon: Vec3::new(0.66, 0.78, 0.92),
            below: Vec3::new(0.36, 0.38, 0.32),
            pipeline,
            uniform,
            bind_group,
        }
    }

    /// Draws the sky into `pass` for `camera`, with the glow towards `renderer`'s sun. Draw it
    /// before anything else: it overwrites every pixel.
    pub fn render(&self, queue: &wgpu::Queue, pass: &mut wgpu::RenderPass<'_>, renderer: &Renderer, camera: &Camera) {
        let sun = renderer.settings().sun.normalize_or(Vec3::Y);
        let uniform = SkyUniform {
            inverse_view_proj: camera.view_proj().inverse().to_cols_array_2d(),
            sun: sun.extend(0.0).to_array(),
            zenith: self.zenith.extend(1.0).to_array(),
            horizon: self.horizon.extend(1.0).to_array(),
            below: self.below.extend(1.0).to_array(),
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}

const _: () = assert!(size_of::<SkyUniform>() == 128);
