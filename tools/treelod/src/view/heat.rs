//! The viewer's error view: the frame drawn with the chosen representation beside the full mesh
//! drawn by a second renderer (same scene, camera, light and MSAA; every triangle, no point), and
//! per pixel their difference as a heat map. The reference is the full mesh at the window's own
//! resolution, as `eval`'s `full-1x` technique draws it, not `eval`'s supersampled reference: a
//! representation that keeps a far canopy's density where the 1× mesh aliases shows there too.

use std::sync::Arc;

use treelod_format::Container;
use treelod_render::{Camera, RendererFormats, Settings};

use super::{Stage, draw_scene, overlay_pass};
use crate::scene::{Scene, SceneError};

/// The error (RMS over linear RGB channels) at which the ramp reaches red. Half of it is yellow,
/// a quarter blue-cyan.
pub const FULL_SCALE: f32 = 0.25;

/// Targets for both frames and the pass that compares them.
pub struct Heat {
    /// The full mesh's renderer, ground and sky.
    pub reference: Stage,
    /// The frame with the chosen representation, and the full mesh's, window-sized.
    drawn: wgpu::TextureView,
    full: wgpu::TextureView,
    pipeline: wgpu::RenderPipeline,
    bind_group: wgpu::BindGroup,
}

/// `settings` for the reference: the full mesh, shaded, with the same light.
#[must_use]
pub fn reference_settings(settings: &Settings) -> Settings {
    Settings { technique: treelod_render::Technique::Full, debug: treelod_render::DebugView::Shaded, ..*settings }
}

impl Heat {
    /// A reference renderer for `scene` and its opened models (shared with the viewer's
    /// renderer) with `formats` and `settings`, and targets of `size`.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        formats: RendererFormats,
        settings: &Settings,
        scene: (&Scene, &[Arc<Container>]),
        size: (u32, u32),
    ) -> Result<Self, SceneError> {
        let (reference, _) = Stage::new(device, queue, formats, reference_settings(settings), scene, size)?;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod view heat"),
            entries: &[0, 1].map(|binding| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }),
        });
        let source = format!("const HEAT_FULL_SCALE: f32 = {FULL_SCALE:?};\n{}", include_str!("heat.wgsl"));
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("treelod view heat.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("treelod view heat"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("treelod view heat"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_heat"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_heat"),
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
        let target = |label| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d { width: size.0, height: size.1, depth_or_array_layers: 1 },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format: formats.color,
                    usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
                    view_formats: &[],
                })
                .create_view(&wgpu::TextureViewDescriptor::default())
        };
        let (drawn, full) = (target("treelod view heat drawn"), target("treelod view heat reference"));
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("treelod view heat"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&drawn) },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&full) },
            ],
        });
        Ok(Self { reference, drawn, full, pipeline, bind_group })
    }

    /// Selects the reference for `camera` with `settings` (the chosen representation's, made the
    /// full mesh's) and records its shadows and both frames: `stage`'s (selected already; its pass
    /// timed by `timestamps`) and the reference's.
    #[expect(clippy::too_many_arguments, reason = "the frame's device, encoder, stage, camera and timer")]
    pub fn record(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        stage: &Stage,
        settings: &Settings,
        camera: &Camera,
        timestamps: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) {
        *self.reference.renderer.settings_mut() = reference_settings(settings);
        self.reference.renderer.prepare(device, queue, camera);
        self.reference.renderer.render_shadows(encoder);
        draw_scene(encoder, &self.full, &self.reference, queue, camera, None);
        draw_scene(encoder, &self.drawn, stage, queue, camera, timestamps);
    }

    /// Draws the heat map of the frames [`Self::record`] drew into the left `camera.width`
    /// pixels of `target`.
    pub fn draw(&self, encoder: &mut wgpu::CommandEncoder, target: &wgpu::TextureView, camera: &Camera) {
        let mut pass = overlay_pass(encoder, target, "treelod view heat");
        pass.set_viewport(0.0, 0.0, camera.width as f32, camera.height as f32, 0.0, 1.0);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_is_the_shaded_full_mesh_under_the_same_light() {
        let settings = Settings {
            technique: treelod_render::Technique::Impostors,
            debug: treelod_render::DebugView::Cells,
            ambient: 0.42,
            ..Settings::default()
        };
        let reference = reference_settings(&settings);
        assert_eq!(reference.technique, treelod_render::Technique::Full);
        assert_eq!(reference.debug, treelod_render::DebugView::Shaded);
        assert_eq!((reference.ambient, reference.sun, reference.shadows), (0.42, settings.sun, settings.shadows));
    }
}
