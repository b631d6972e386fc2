//! The renderer: models uploaded from containers, instances, per-frame selection into indirect
//! draws, and the draws themselves inside the host's render pass.

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3, Vec4};
use treelod_format::{CellRecord, Container, MaterialRecord, NO_IMAGE, PointRecord, TriangleRecord};
use treelod_runtime::{Thresholds, select_cell};

use crate::camera::Camera;
use crate::textures;

/// WGSL of the pipelines: the record structs, then the tree shader.
const SHADER: &str =
    concat!(include_str!("../../../shaders/shared/records.wgsl"), include_str!("../../../shaders/tree.wgsl"));

/// The target formats of the host's render pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RendererFormats {
    /// Colour attachment format.
    pub color: wgpu::TextureFormat,
    /// Depth attachment format (depth-tested, depth-written).
    pub depth: wgpu::TextureFormat,
    /// MSAA samples of both attachments (1 for none).
    pub sample_count: u32,
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
}

/// Level-of-detail and shading settings; change them between frames with [`Renderer::settings_mut`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// `s_min`, pixels: points are drawn down to this projected size (Gilet's point threshold).
    pub s_min: f32,
    /// `s_max`, pixels: triangles projecting larger than this are drawn as triangles.
    pub s_max: f32,
    /// Scale of the splat radii: 1 draws each point as a disc of the opaque area it stands for.
    pub point_scale: f32,
    /// Draw every triangle and no point: the full mesh, for comparison.
    pub full_mesh: bool,
    /// What to colour by.
    pub debug: DebugView,
    /// Direction towards the sun, world space.
    pub sun: Vec3,
    /// Ambient share of the light, 0..1.
    pub ambient: f32,
}

impl Default for Settings {
    /// One-pixel points, triangles above two pixels, light from above and the side.
    fn default() -> Self {
        Self {
            s_min: 1.0,
            s_max: 2.0,
            point_scale: 1.0,
            full_mesh: false,
            debug: DebugView::Shaded,
            sun: Vec3::new(0.4, 0.8, 0.45),
            ambient: 0.35,
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
    /// Triangles submitted.
    pub triangles: u64,
    /// Points submitted (the prefix; the vertex shader drops those outside the cut).
    pub points: u64,
    /// Bytes of model data on the GPU.
    pub bytes_resident: u64,
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
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FrameUniform {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    sun: [f32; 4],
    debug: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DrawInfo {
    model: [[f32; 4]; 4],
    tau_p: f32,
    tau_t: f32,
    cell: u32,
    scale: f32,
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

/// The CPU copy of what selection reads, and the GPU resources of one model.
struct Model {
    cells: Vec<CellRecord>,
    /// Per cell: triangle sizes and point `hi`, copied so selection runs without the container.
    triangles: Vec<TriangleRecord>,
    points: Vec<PointRecord>,
    /// Model-space bounds of the whole block.
    bounds: (Vec3, Vec3),
    bind_group: wgpu::BindGroup,
    bytes: u64,
}

/// One selected range: its draw info, first element and element count.
type Draw = (DrawInfo, u32, u32);

/// Draws of one model in this frame: ranges into the indirect buffer.
#[derive(Clone, Copy, Default)]
struct ModelDraws {
    triangles: (u32, u32),
    points: (u32, u32),
}

/// Draws treelod models inside a host's render pass. See the crate documentation for a frame.
pub struct Renderer {
    settings: Settings,
    models: Vec<Model>,
    instances: Vec<Instance>,
    model_layout: wgpu::BindGroupLayout,
    frame_layout: wgpu::BindGroupLayout,
    triangle_pipeline: wgpu::RenderPipeline,
    point_pipeline: wgpu::RenderPipeline,
    sampler: wgpu::Sampler,
    frame_buffer: wgpu::Buffer,
    draw_buffer: wgpu::Buffer,
    indirect_buffer: wgpu::Buffer,
    frame_bind_group: wgpu::BindGroup,
    /// Per model, this frame's draw ranges.
    model_draws: Vec<ModelDraws>,
    // Scratch reused between frames.
    draw_infos: Vec<DrawInfo>,
    indirect: Vec<wgpu::util::DrawIndirectArgs>,
}

impl Renderer {
    /// The device features the renderer needs: indirect draws that set the first instance.
    #[must_use]
    pub fn required_features() -> wgpu::Features {
        wgpu::Features::INDIRECT_FIRST_INSTANCE
    }

    /// Creates the pipelines for the host's target formats.
    #[must_use]
    pub fn new(device: &wgpu::Device, formats: RendererFormats, settings: Settings) -> Self {
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
                storage(1, wgpu::ShaderStages::VERTEX),
            ],
        });
        let model_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod model"),
            entries: &[
                storage(0, wgpu::ShaderStages::VERTEX),
                storage(1, wgpu::ShaderStages::VERTEX),
                storage(2, wgpu::ShaderStages::VERTEX),
                storage(3, wgpu::ShaderStages::FRAGMENT),
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("treelod"),
            bind_group_layouts: &[Some(&frame_layout), Some(&model_layout)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("treelod tree.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = |label: &str, vs: &str, fs: &str| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some(vs),
                    compilation_options: wgpu::PipelineCompilationOptions::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    // Leaves are cards seen from both sides; splats always face the camera.
                    cull_mode: None,
                    ..wgpu::PrimitiveState::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: formats.depth,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: wgpu::StencilState::default(),
                    bias: wgpu::DepthBiasState::default(),
                }),
                multisample: wgpu::MultisampleState {
                    count: formats.sample_count.max(1),
                    mask: !0,
                    alpha_to_coverage_enabled: false,
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: wgpu::PipelineCompilationOptions::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: formats.color,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let triangle_pipeline = pipeline("treelod triangles", "vs_triangle", "fs_triangle");
        let point_pipeline = pipeline("treelod points", "vs_point", "fs_point");
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("treelod textures"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..wgpu::SamplerDescriptor::default()
        });
        let frame_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("treelod frame"),
            size: size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let draw_buffer = storage_buffer(device, "treelod draws", 64 * size_of::<DrawInfo>() as u64);
        let indirect_buffer = indirect_buffer(device, 64);
        let frame_bind_group = frame_bind_group(device, &frame_layout, &frame_buffer, &draw_buffer);
        Self {
            settings,
            models: Vec::new(),
            instances: Vec::new(),
            model_layout,
            frame_layout,
            triangle_pipeline,
            point_pipeline,
            sampler,
            frame_buffer,
            draw_buffer,
            indirect_buffer,
            frame_bind_group,
            model_draws: Vec::new(),
            draw_infos: Vec::new(),
            indirect: Vec::new(),
        }
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

    /// Uploads a container's vertices, triangles, points, materials and images. Images that fail
    /// to decode are drawn grey; the returned warnings say which.
    ///
    /// # Errors
    /// [`RenderError::TooLarge`] if an array exceeds the device's storage-buffer binding limit.
    pub fn add_model(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        container: &Container,
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
        container: &Container,
    ) -> Result<(ModelId, Vec<String>), RenderError> {
        let limit = device.limits().max_storage_buffer_binding_size;
        let mut warnings = Vec::new();
        let mut bytes = 0u64;
        let mut upload = |what: &'static str, data: &[u8]| -> Result<wgpu::Buffer, RenderError> {
            if data.len() as u64 > limit {
                return Err(RenderError::TooLarge { what, bytes: data.len() as u64, limit });
            }
            // Bindings may not be empty: an empty array becomes 16 zero bytes no draw reads.
            let padded = data.len().max(16).next_multiple_of(4) as u64;
            let buffer = storage_buffer(device, what, padded);
            queue.write_buffer(&buffer, 0, data);
            bytes += padded;
            Ok(buffer)
        };
        let layers = textures::layers(container, &mut warnings);
        let image_layer =
            |image: u32| -> i32 { if image == NO_IMAGE { -1 } else { i32::try_from(image).unwrap_or(-1) } };
        let materials: Vec<MaterialGpu> = container
            .materials()
            .iter()
            .map(|m: &MaterialRecord| MaterialGpu {
                base_color: m.base_color,
                layer: if (m.image as usize) < layers.levels.len() { image_layer(m.image) } else { -1 },
                alpha_mode: m.alpha_mode,
                alpha_cutoff: m.alpha_cutoff,
                material_class: m.class,
            })
            .collect();
        let vertices = upload("VERTICES", bytemuck::cast_slice(container.vertices()))?;
        let triangles = upload("TRIANGLES", bytemuck::cast_slice(container.triangles()))?;
        let points = upload("POINTS", bytemuck::cast_slice(container.points()))?;
        let materials = upload("MATERIALS", bytemuck::cast_slice(&materials))?;
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
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("treelod model"),
            layout: &self.model_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: vertices.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: triangles.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: points.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: materials.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::TextureView(&view) },
                wgpu::BindGroupEntry { binding: 5, resource: wgpu::BindingResource::Sampler(&self.sampler) },
            ],
        });
        let block = container.block();
        let id = ModelId(u32::try_from(self.models.len()).unwrap_or(u32::MAX));
        self.models.push(Model {
            cells: container.cells().to_vec(),
            triangles: container.triangles().to_vec(),
            points: container.points().to_vec(),
            bounds: (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max)),
            bind_group,
            bytes,
        });
        Ok((id, warnings))
    }

    /// Replaces the instances drawn from the next frame on. Instances of unknown models are ignored.
    pub fn set_instances(&mut self, instances: &[Instance]) {
        self.instances.clear();
        self.instances.extend(instances.iter().filter(|i| (i.model.0 as usize) < self.models.len()));
    }

    /// Selects what to draw for `camera` (per instance and cell, spec §10) and uploads the draws.
    pub fn prepare(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, camera: &Camera) -> FrameStats {
        let mut stats =
            FrameStats { bytes_resident: self.models.iter().map(|m| m.bytes).sum(), ..FrameStats::default() };
        let view_proj = camera.view_proj();
        let frustum = Frustum::new(view_proj);
        let settings = self.settings;
        // Per model, per kind: the draws in instance order, gathered model by model so each model's
        // draws are contiguous in the indirect buffer.
        let mut per_model: Vec<(Vec<Draw>, Vec<Draw>)> = self.models.iter().map(|_| (Vec::new(), Vec::new())).collect();
        for instance in &self.instances {
            let model = &self.models[instance.model.0 as usize];
            let (lo, hi) = model.bounds;
            if !frustum.intersects(instance.transform, lo, hi) {
                continue;
            }
            stats.instances_visible += 1;
            let scale = instance.transform.x_axis.truncate().length().max(1e-12);
            let (tri_draws, point_draws) = &mut per_model[instance.model.0 as usize];
            for (index, cell) in model.cells.iter().enumerate() {
                if cell.triangles.count == 0 && cell.points.count == 0 {
                    continue;
                }
                let centre = 0.5 * (Vec3::from_array(cell.bounds_min) + Vec3::from_array(cell.bounds_max));
                let distance = instance.transform.transform_point3(centre).distance(camera.position);
                let t = if settings.full_mesh {
                    Thresholds { points: 0.0, triangles: 0.0 }
                } else {
                    let world = Thresholds::from_pixels(
                        settings.s_min,
                        settings.s_max,
                        distance,
                        camera.fovy,
                        camera.height as f32,
                    );
                    Thresholds { points: world.points / scale, triangles: world.triangles / scale }
                };
                let selection = select_cell(cell, &model.triangles, &model.points, t);
                let info = DrawInfo {
                    model: instance.transform.to_cols_array_2d(),
                    tau_p: t.points,
                    tau_t: t.triangles,
                    cell: u32::try_from(index).unwrap_or(u32::MAX),
                    scale,
                };
                if selection.triangles > 0 {
                    tri_draws.push((info, cell.triangles.first, selection.triangles));
                    stats.triangles += u64::from(selection.triangles);
                }
                if selection.points > 0 && !settings.full_mesh {
                    point_draws.push((info, cell.points.first, selection.points));
                    stats.points += u64::from(selection.points);
                }
            }
        }
        self.draw_infos.clear();
        self.indirect.clear();
        self.model_draws.clear();
        for (tri_draws, point_draws) in per_model {
            let mut draws = ModelDraws::default();
            for (kind, list, corners) in [(0, tri_draws, 3u32), (1, point_draws, 6u32)] {
                let start = u32::try_from(self.indirect.len()).unwrap_or(u32::MAX);
                for (info, first, count) in list {
                    let index = u32::try_from(self.draw_infos.len()).unwrap_or(u32::MAX);
                    self.draw_infos.push(info);
                    self.indirect.push(wgpu::util::DrawIndirectArgs {
                        vertex_count: count * corners,
                        instance_count: 1,
                        first_vertex: first * corners,
                        first_instance: index,
                    });
                }
                let range = (start, u32::try_from(self.indirect.len()).unwrap_or(u32::MAX) - start);
                if kind == 0 { draws.triangles = range } else { draws.points = range }
            }
            self.model_draws.push(draws);
        }
        stats.ranges = u32::try_from(self.indirect.len()).unwrap_or(u32::MAX);

        let (right, up) = camera.right_up();
        let sun = settings.sun.normalize_or(Vec3::Y);
        let uniform = FrameUniform {
            view_proj: view_proj.to_cols_array_2d(),
            eye: camera.position.extend(camera.height as f32).to_array(),
            right: right.extend(camera.proj.y_axis.y).to_array(),
            up: up.extend(settings.point_scale.max(0.0)).to_array(),
            sun: Vec4::new(sun.x, sun.y, sun.z, settings.ambient.clamp(0.0, 1.0)).to_array(),
            debug: match settings.debug {
                DebugView::Shaded => 0,
                DebugView::Cells => 1,
                DebugView::Kinds => 2,
            },
            _pad: [0; 3],
        };
        queue.write_buffer(&self.frame_buffer, 0, bytemuck::bytes_of(&uniform));
        let draw_bytes = (self.draw_infos.len().max(1) * size_of::<DrawInfo>()) as u64;
        if draw_bytes > self.draw_buffer.size() {
            self.draw_buffer = storage_buffer(device, "treelod draws", draw_bytes.next_power_of_two());
            self.frame_bind_group = frame_bind_group(device, &self.frame_layout, &self.frame_buffer, &self.draw_buffer);
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

    /// Records this frame's draws into the host's pass (after [`Self::prepare`]).
    pub fn render(&self, pass: &mut wgpu::RenderPass<'_>) {
        let stride = size_of::<wgpu::util::DrawIndirectArgs>() as u64;
        pass.set_bind_group(0, &self.frame_bind_group, &[]);
        for (pipeline, triangles) in [(&self.triangle_pipeline, true), (&self.point_pipeline, false)] {
            pass.set_pipeline(pipeline);
            for (model, draws) in self.models.iter().zip(&self.model_draws) {
                let (first, count) = if triangles { draws.triangles } else { draws.points };
                if count == 0 {
                    continue;
                }
                pass.set_bind_group(1, &model.bind_group, &[]);
                pass.multi_draw_indirect(&self.indirect_buffer, u64::from(first) * stride, count);
            }
        }
    }
}

fn storage_buffer(device: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
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

fn frame_bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    frame: &wgpu::Buffer,
    draws: &wgpu::Buffer,
) -> wgpu::BindGroup {
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("treelod frame"),
        layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: frame.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: draws.as_entire_binding() },
        ],
    })
}

/// The six planes of a view-projection's frustum (WebGPU depth 0..1), for conservative culling.
struct Frustum {
    planes: [Vec4; 6],
}

impl Frustum {
    fn new(m: Mat4) -> Self {
        let r = [m.row(0), m.row(1), m.row(2), m.row(3)];
        Self { planes: [r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[2], r[3] - r[2]] }
    }

    /// Whether the box `lo..hi` under `transform` may be visible.
    fn intersects(&self, transform: Mat4, lo: Vec3, hi: Vec3) -> bool {
        let corners: [Vec4; 8] = std::array::from_fn(|i| {
            let p = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            transform.transform_point3(p).extend(1.0)
        });
        self.planes.iter().all(|plane| corners.iter().any(|c| plane.dot(*c) >= 0.0))
    }
}
