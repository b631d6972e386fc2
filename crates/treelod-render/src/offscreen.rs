//! Rendering with no window: a device of its own, an offscreen target, and the pixels read back.

use crate::{Camera, Ground, Renderer, RendererFormats};

/// The colour format of offscreen images.
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// The depth format of offscreen images.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Why no offscreen device could be made.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter at all (no Vulkan driver, not even a software one).
    #[error("no GPU adapter: {0} (on a machine without a GPU, install Mesa's lavapipe: mesa-vulkan-drivers)")]
    NoAdapter(String),
    /// The adapter lacks a feature the renderer needs.
    #[error("the adapter {adapter} lacks {missing:?}")]
    MissingFeatures {
        /// Adapter name.
        adapter: String,
        /// What is missing.
        missing: wgpu::Features,
    },
    /// Device creation failed.
    #[error("cannot create a device: {0}")]
    Device(String),
    /// Reading the image back failed.
    #[error("cannot read the image back: {0}")]
    Readback(String),
}

/// A device and queue made for offscreen work.
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// What the adapter says of itself.
    pub info: wgpu::AdapterInfo,
}

impl Gpu {
    /// Opens the first adapter the environment allows (`WGPU_BACKEND` may restrict it) with the
    /// features [`Renderer::required_features`] names, and where the adapter offers them
    /// timestamp queries (for [`render_image_timed`]), `TEXTURE_COMPRESSION_BC` (BC7 atlases are then
    /// uploaded as stored), `DEPTH_CLIP_CONTROL` (host shadow maps' casters clamped to their near
    /// plane) and [`Renderer::gpu_selection_features`].
    ///
    /// # Errors
    /// [`GpuError`] if there is no adapter or it lacks the features.
    pub fn new() -> Result<Self, GpuError> {
        Self::without(wgpu::Features::empty())
    }

    /// As [`Self::new`], but the device is made without the optional features in `excluded`, as
    /// on an adapter that lacks them: `TEXTURE_COMPRESSION_BC` makes the renderer decode BC7
    /// atlases on the CPU.
    ///
    /// # Errors
    /// [`GpuError`] if there is no adapter or it lacks the required features.
    pub fn without(excluded: wgpu::Features) -> Result<Self, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            ..wgpu::RequestAdapterOptions::default()
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let missing = Renderer::required_features() - adapter.features();
        if !missing.is_empty() {
            return Err(GpuError::MissingFeatures { adapter: info.name, missing });
        }
        // Timestamps for the timed renders, the indirect count for GPU selection, where offered;
        // BC textures for BC7 atlases (else they are decoded to RGBA8 on upload); depth clamping
        // for host shadow maps (`Renderer::set_host_shadow_views`).
        let optional = adapter.features()
            & (wgpu::Features::TIMESTAMP_QUERY
                | wgpu::Features::TEXTURE_COMPRESSION_BC
                | wgpu::Features::DEPTH_CLIP_CONTROL
                | Renderer::gpu_selection_features())
            & !excluded;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("treelod offscreen"),
            required_features: Renderer::required_features() | optional,
            required_limits: adapter.limits(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device(e.to_string()))?;
        Ok(Self { device, queue, info })
    }

    /// The formats [`render_image`] draws with, without MSAA.
    #[must_use]
    pub fn formats() -> RendererFormats {
        Self::formats_msaa(1)
    }

    /// The formats [`render_image`] draws with, with `sample_count` MSAA samples (1 or 4: the
    /// counts every adapter offers for these formats). [`render_image`] makes multisampled
    /// targets for a renderer made with them and resolves the colour.
    #[must_use]
    pub fn formats_msaa(sample_count: u32) -> RendererFormats {
        RendererFormats { color: COLOR_FORMAT, depth: DEPTH_FORMAT, sample_count }
    }
}

/// An RGBA8 (sRGB) image read back from the GPU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// `width · height · 4` bytes, rows top to bottom.
    pub rgba: Vec<u8>,
}

impl Image {
    /// The pixel at `(x, y)`.
    #[must_use]
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        [self.rgba[i], self.rgba[i + 1], self.rgba[i + 2], self.rgba[i + 3]]
    }
}

/// Prepares and renders one frame of `renderer` for `camera` into a new `camera.width`×`camera.height`
/// image cleared to `background`, and reads it back.
///
/// # Errors
/// [`GpuError::Readback`] if mapping the read-back buffer fails.
pub fn render_image(
    gpu: &Gpu,
    renderer: &mut Renderer,
    camera: &Camera,
    background: wgpu::Color,
) -> Result<(Image, crate::FrameStats), GpuError> {
    render_image_timed(gpu, renderer, camera, background).map(|(image, stats, _)| (image, stats))
}

/// [`render_image`], and the GPU time of the render pass in milliseconds, from timestamp queries
/// written at its beginning and end — `None` when the device has no timestamp queries
/// ([`Gpu::new`] asks for them where the adapter offers them).
///
/// # Errors
/// [`GpuError::Readback`] if mapping a read-back buffer fails.
pub fn render_image_timed(
    gpu: &Gpu,
    renderer: &mut Renderer,
    camera: &Camera,
    background: wgpu::Color,
) -> Result<(Image, crate::FrameStats, Option<f64>), GpuError> {
    let stats = renderer.prepare(&gpu.device, &gpu.queue, camera);
    let (image, gpu_ms) = render_prepared_timed(gpu, renderer, camera, background)?;
    Ok((image, stats, gpu_ms))
}

/// [`render_image_timed`] without the [`Renderer::prepare`]: draws what the renderer's last
/// `prepare` (for `camera`) recorded, so a caller can time the preparation on its own and draw
/// each frame's selection exactly once, as a host does.
///
/// # Errors
/// [`GpuError::Readback`] if mapping a read-back buffer fails.
pub fn render_prepared_timed(
    gpu: &Gpu,
    renderer: &mut Renderer,
    camera: &Camera,
    background: wgpu::Color,
) -> Result<(Image, Option<f64>), GpuError> {
    render_prepared_scene(gpu, renderer, camera, background, None, true)
}

/// [`render_prepared_timed`] with a `ground` drawn before the trees (receiving their shadows),
/// and the trees drawn or not (`trees: false` shows only their shadows on the ground). With
/// [`crate::Settings::shadows`] the shadow pass is recorded first.
///
/// # Errors
/// [`GpuError::Readback`] if mapping a read-back buffer fails.
pub fn render_prepared_scene(
    gpu: &Gpu,
    renderer: &mut Renderer,
    camera: &Camera,
    background: wgpu::Color,
    ground: Option<&Ground>,
    trees: bool,
) -> Result<(Image, Option<f64>), GpuError> {
    let (width, height) = (camera.width.max(1), camera.height.max(1));
    let extent = wgpu::Extent3d { width, height, depth_or_array_layers: 1 };
    let samples = renderer.formats().sample_count.max(1);
    let target = |format, usage, sample_count| {
        gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("treelod offscreen"),
            size: extent,
            mip_level_count: 1,
            sample_count,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let color = target(COLOR_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC, 1);
    // Sampled after the pass by the occlusion measurement of pruned trees.
    let depth =
        target(DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING, samples);
    // With MSAA the pass draws into a multisampled target resolved into `color`.
    let multisampled = (samples > 1).then(|| target(COLOR_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT, samples));
    let color_view = color.create_view(&wgpu::TextureViewDescriptor::default());
    let multisampled_view = multisampled.as_ref().map(|t| t.create_view(&wgpu::TextureViewDescriptor::default()));
    let depth_view = depth.create_view(&wgpu::TextureViewDescriptor::default());
    let mut encoder =
        gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("treelod frame") });
    let timer = gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY).then(|| PassTimer::new(&gpu.device));
    renderer.render_shadows(&mut encoder);
    {
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("treelod offscreen"),
            color_attachments: &[Some(match &multisampled_view {
                Some(view) => wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: Some(&color_view),
                    ops: wgpu::Operations { load: wgpu::LoadOp::Clear(background), store: wgpu::StoreOp::Discard },
                },
                None => wgpu::RenderPassColorAttachment {
                    view: &color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Clear(background), store: wgpu::StoreOp::Store },
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(renderer.depth_convention().far()),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: timer.as_ref().map(PassTimer::writes),
            ..wgpu::RenderPassDescriptor::default()
        });
        if let Some(ground) = ground {
            ground.render(&gpu.queue, &mut pass, renderer, camera);
        }
        if trees {
            renderer.render(&mut pass);
        }
    }
    if let Some(timer) = &timer {
        timer.resolve(&mut encoder);
    }
    renderer.measure_occlusion(&gpu.device, &mut encoder, &depth_view);
    let readback = Readback::record(&gpu.device, &mut encoder, &color);
    gpu.queue.submit([encoder.finish()]);
    let image = readback.read(&gpu.device)?;
    let gpu_ms = match &timer {
        Some(timer) => timer.read(gpu)?,
        None => None,
    };
    Ok((image, gpu_ms))
}

/// A copy of a texture of 4-byte texels (RGBA8 or BGRA8) into a mappable buffer, recorded in an
/// encoder; [`Self::read`] returns the texels once the encoder is submitted.
pub struct Readback {
    buffer: wgpu::Buffer,
    width: u32,
    height: u32,
    /// Bytes per row in the buffer (rows are padded to `COPY_BYTES_PER_ROW_ALIGNMENT`).
    row: u32,
}

impl Readback {
    /// Records the copy of the whole of `texture` (its first mip level) into `encoder`.
    #[must_use]
    pub fn record(device: &wgpu::Device, encoder: &mut wgpu::CommandEncoder, texture: &wgpu::Texture) -> Self {
        let (width, height) = (texture.width(), texture.height());
        let row = (width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("treelod readback"),
            size: u64::from(row) * u64::from(height),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        );
        Self { buffer, width, height, row }
    }

    /// Waits for the copy (the encoder must have been submitted) and returns the texels as
    /// stored, rows top to bottom without padding.
    ///
    /// # Errors
    /// [`GpuError::Readback`] if mapping the buffer fails.
    pub fn read(self, device: &wgpu::Device) -> Result<Image, GpuError> {
        let (width, height, row) = (self.width as usize, self.height as usize, self.row as usize);
        let rgba = read_mapped(device, &self.buffer, |mapped| {
            let mut rgba = Vec::with_capacity(width * height * 4);
            for y in 0..height {
                rgba.extend_from_slice(&mapped[y * row..y * row + width * 4]);
            }
            rgba
        })?;
        Ok(Image { width: self.width, height: self.height, rgba })
    }
}

/// Maps `buffer` for reading (its copies submitted), waits, hands its bytes to `f` and unmaps it.
fn read_mapped<R>(device: &wgpu::Device, buffer: &wgpu::Buffer, f: impl FnOnce(&[u8]) -> R) -> Result<R, GpuError> {
    let slice = buffer.slice(..);
    slice.map_async(wgpu::MapMode::Read, |_| {});
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
    let mapped = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
    let result = f(&mapped);
    drop(mapped);
    buffer.unmap();
    Ok(result)
}

/// Two timestamp queries around a pass, resolved into a buffer that is read back.
struct PassTimer {
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    readback: wgpu::Buffer,
}

impl PassTimer {
    const BYTES: u64 = 2 * size_of::<u64>() as u64;

    fn new(device: &wgpu::Device) -> Self {
        let queries = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("treelod pass timer"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let buffer = |usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("treelod pass timer"),
                size: Self::BYTES,
                usage,
                mapped_at_creation: false,
            })
        };
        let resolved = buffer(wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC);
        let readback = buffer(wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ);
        Self { queries, resolved, readback }
    }

    fn writes(&self) -> wgpu::RenderPassTimestampWrites<'_> {
        wgpu::RenderPassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        }
    }

    fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.resolve_query_set(&self.queries, 0..2, &self.resolved, 0);
        encoder.copy_buffer_to_buffer(&self.resolved, 0, &self.readback, 0, Self::BYTES);
    }

    /// The pass's milliseconds; `None` if the end reads before the beginning (a driver that
    /// reset its counter).
    fn read(&self, gpu: &Gpu) -> Result<Option<f64>, GpuError> {
        let ticks: [u64; 2] = read_mapped(&gpu.device, &self.readback, |mapped| {
            bytemuck::pod_read_unaligned(&mapped[..Self::BYTES as usize])
        })?;
        let period_ns = f64::from(gpu.queue.get_timestamp_period());
        Ok(ticks[1].checked_sub(ticks[0]).map(|t| t as f64 * period_ns * 1e-6))
    }
}
