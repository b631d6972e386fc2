//! A sky gradient for tools to draw behind the trees (the viewer): lighter at the horizon, bluer
//! up, a glow around the renderer's sun. Engines draw their own sky; this one exists so that a
//! tree is judged against something like the backgrounds it will be seen on, not a white page.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::ground::UniformPass;
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
        // Drawn first, neither depth-tested nor written: what is drawn after covers it.
        let UniformPass { pipeline, uniform, bind_group } = UniformPass::new(
            device,
            renderer,
            "treelod sky",
            SHADER,
            ("vs_sky", "fs_sky"),
            size_of::<SkyUniform>() as u64,
            &[],
            None,
        );
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
