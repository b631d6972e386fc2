//! Models uploaded from containers ([`Renderer::add_model`]): the GPU records the shaders read
//! (vertices with their ambient occlusion, materials, and each representation's records with
//! its occlusion in place of reserved fields), the model's buffers, textures and bind groups, its
//! pinned roots in the pool, and what drawing it needs of its container ([`Model`]).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use treelod_format::{Container, MaterialRecord, NO_IMAGE, PointRecord};
use treelod_runtime::{Billboards, ModelLod, PlaneLod, Representations};

use crate::gpu_select::GpuSelection;
use crate::renderer::{ModelId, RenderError, Renderer};
use crate::streaming::UNIT;
use crate::technique::baselines::gpu_billboards;
use crate::technique::ellipsoids::{gpu_ellipsoids, gpu_lines};
use crate::technique::impostors::gpu_planes;
use crate::textures;

/// A vertex as the shaders read it: the record, then its ambient occlusion (0 without).
/// WGSL twin: `VertexGpu` in `shaders/tree/common.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct VertexGpu {
    record: treelod_format::VertexRecord,
    ao: f32,
}

/// Point `index` of `container` as the pool holds it: its `flags` (reserved in the file, spec
/// §6.5) carry its ambient-occlusion byte (§6.14), 0 without.
fn gpu_point(container: &Container, index: usize, point: PointRecord) -> PointRecord {
    PointRecord { flags: container.point_ao().get(index).copied().map_or(0, u32::from), ..point }
}

/// Points `first..` of `container` (`records`) as the pools hold them ([`gpu_point`]): the
/// file's records themselves where they already are (no `POINT_AO` and every reserved `flags` 0,
/// which the shaders would otherwise read as occlusion), else rewritten into `scratch`.
pub(crate) fn gpu_points<'a>(
    container: &Container,
    first: usize,
    records: &'a [PointRecord],
    scratch: &'a mut Vec<PointRecord>,
) -> &'a [PointRecord] {
    if container.point_ao().is_empty() && records.iter().all(|p| p.flags == 0) {
        return records;
    }
    scratch.clear();
    scratch.extend(records.iter().enumerate().map(|(k, &p)| gpu_point(container, first + k, p)));
    scratch
}

/// Records as the GPU holds them: each one's `flags` (reserved in the file, spec §6.8, §6.9, and
/// not read) replaced by its ambient-occlusion byte `ao[i]` (§6.14), 0 where `ao` is empty (no
/// `ELLIPSOID_AO`, `LINE_AO`).
pub(crate) fn with_ao_in_flags<T: Copy>(records: &[T], ao: &[u8], with_flags: fn(T, u32) -> T) -> Vec<T> {
    records.iter().enumerate().map(|(i, &r)| with_flags(r, ao.get(i).copied().map_or(0, u32::from))).collect()
}

/// A material as the shaders read it: the record's fields that shading needs, its image as a
/// layer of the model's texture array (-1 for none). WGSL twin: `MaterialGpu` in
/// `shaders/tree/common.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct MaterialGpu {
    base_color: [f32; 4],
    layer: i32,
    alpha_mode: u32,
    alpha_cutoff: f32,
    material_class: u32,
}

/// The GPU resources of one model and what drawing it needs of its container (what its
/// selections read is its [`Representations`], held beside it in `Renderer::representations`).
pub(crate) struct Model {
    /// The mapped container: streamed ranges are uploaded from it.
    pub(crate) container: Arc<Container>,
    /// Vertices, materials, images and the sampler.
    pub(crate) bind_group: wgpu::BindGroup,
    /// Bytes uploaded whole at [`Renderer::add_model`] (vertices, materials, images).
    pub(crate) static_bytes: u64,
    /// Pool unit (= point index) of the pinned copy of [`ModelLod::roots`].
    pub(crate) roots_start: u32,
    /// Per container cell: where its roots start in [`ModelLod::roots`], and how many.
    pub(crate) cell_roots: Vec<(u32, u32)>,
    /// Per container cell: its index in [`ModelLod::cells`], `u32::MAX` if empty.
    pub(crate) cell_lod: Vec<u32>,
    /// The hull samples of the occlusion test: first and count in the sample buffer.
    pub(crate) samples: (u32, u32),
    /// The baseline billboards' bind group (the model's, with the billboards in place of the
    /// planes and their atlas in place of the impostor atlas), if the container has billboards
    /// and their atlas decodes.
    pub(crate) billboards: Option<wgpu::BindGroup>,
}

impl Renderer {
    /// Adds a container: uploads its vertices, materials and images, and a copy of every cell's
    /// roots; its triangles and points stream from the mapped file as frames need them. Images
    /// that fail to decode are drawn grey; [`Self::add_model_with_warnings`] says which.
    ///
    /// # Errors
    /// [`RenderError::TooLarge`] if the vertices or materials exceed the device's storage-buffer
    /// binding limit, [`RenderError::Budget`] if the memory budget cannot hold the roots.
    pub fn add_model(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        container: Arc<Container>,
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
        container: Arc<Container>,
    ) -> Result<(ModelId, Vec<String>), RenderError> {
        let limit = device.limits().max_storage_buffer_binding_size;
        if self.gpu.is_some() {
            // GPU selection keeps every model whole: refuse what does not fit before adding it.
            let lod = ModelLod::from_container(&container);
            let bytes = self.gpu.as_ref().map_or(0, GpuSelection::pool_bytes)
                + crate::gpu_select::model_units(&container, &lod) * UNIT;
            let budget = self.gpu_budget(device);
            if bytes > budget {
                let model = u32::try_from(self.models.len()).unwrap_or(u32::MAX);
                return Err(RenderError::GpuSelectionBudget { model, bytes, budget });
            }
        }
        let mut warnings = Vec::new();
        let mut bytes = 0u64;
        let mut upload = |what: &'static str, data: &[u8]| -> Result<wgpu::Buffer, RenderError> {
            if data.len() as u64 > limit {
                return Err(RenderError::TooLarge { what, bytes: data.len() as u64, limit });
            }
            // Bindings may not be empty, nor smaller than one record of the array they hold: an
            // empty array becomes 64 zero bytes (the largest record) no draw reads.
            let padded = data.len().max(64).next_multiple_of(4) as u64;
            let buffer = storage_buffer(device, what, padded, false);
            queue.write_buffer(&buffer, 0, data);
            bytes += padded;
            Ok(buffer)
        };
        let layers = textures::layers(&container, &mut warnings);
        let image_layer = |image: u32| -> i32 {
            if image == NO_IMAGE { -1 } else { layers.layer_of.get(image as usize).copied().unwrap_or(-1) }
        };
        let materials: Vec<MaterialGpu> = container
            .materials()
            .iter()
            .map(|m: &MaterialRecord| MaterialGpu {
                base_color: m.base_color,
                layer: image_layer(m.image),
                alpha_mode: m.alpha_mode,
                alpha_cutoff: m.alpha_cutoff,
                material_class: m.class,
            })
            .collect();
        // The vertices as the shaders read them: each record followed by its ambient occlusion.
        let vertex_ao = container.vertex_ao();
        let vertices: Vec<VertexGpu> = container
            .vertices()
            .iter()
            .enumerate()
            .map(|(i, &record)| VertexGpu {
                record,
                ao: vertex_ao.get(i).map_or(0.0, |&a| treelod_format::decode_ao(a)),
            })
            .collect();
        let vertices = upload("VERTICES", bytemuck::cast_slice(&vertices))?;
        let materials = upload("MATERIALS", bytemuck::cast_slice(&materials))?;
        // What the selections read, and the whole-triangle list (pruned leaves, bark, the LoD
        // chain) they address.
        let (mut representations, whole) = Representations::from_container(&container);
        let r = &representations;
        let (extra, prune_leaves) =
            if r.prune.is_some() || r.planes.is_some() || r.ellipsoids.is_some() || r.chain.is_some() {
                let extra = upload("PRUNE_TRIANGLES, bark and LoD chain", bytemuck::cast_slice(&whole))?;
                (extra, upload("PRUNE_LEAVES", bytemuck::cast_slice(container.prune_leaves()))?)
            } else {
                (upload("no pruned triangles", &[])?, upload("no pruned leaves", &[])?)
            };
        drop(whole);
        // Baseline billboards: the facing quads, then the crossed ones.
        let billboard_kinds = Billboards::from_container(&container);
        let billboard_records = gpu_billboards(&container, billboard_kinds.as_ref());
        let billboard_buffer = match &billboard_kinds {
            Some(_) => Some(upload("BILLBOARDS", bytemuck::cast_slice(&billboard_records))?),
            None => None,
        };
        let gpu_planes = gpu_planes(&container, &mut warnings);
        let plane_buffer = upload("PLANES", bytemuck::cast_slice(&gpu_planes))?;
        let plane_leaves = upload("PLANE_LEAVES", bytemuck::cast_slice(container.plane_leaves()))?;
        let gpu_ellipsoids = gpu_ellipsoids(&container);
        let ellipsoid_buffer = upload("ELLIPSOIDS", bytemuck::cast_slice(&gpu_ellipsoids))?;
        drop(gpu_ellipsoids);
        let gpu_lines = gpu_lines(&container);
        let line_buffer = upload("LINES", bytemuck::cast_slice(&gpu_lines))?;
        drop(gpu_lines);
        if self.noise_view.is_none() {
            let (view, noise_bytes) = crate::noise::upload(device, queue);
            self.noise_view = Some(view);
            bytes += noise_bytes;
        }

        // The roots, pinned in the pool: what a cell draws before its own points are resident.
        let lod = ModelLod::from_container(&container);
        let roots: Vec<PointRecord> =
            lod.roots().iter().map(|&i| gpu_point(&container, i as usize, container.points()[i as usize])).collect();
        let roots_len = u32::try_from(roots.len()).unwrap_or(u32::MAX);
        let cells = container.cells().len();
        let Some(roots_start) = self.residency.add_model(cells, roots_len) else {
            return Err(RenderError::Budget { bytes: u64::from(roots_len) * UNIT, budget: self.pool_budget() });
        };
        self.grow_pool_buffer(device, queue);
        if !roots.is_empty() {
            queue.write_buffer(&self.pool_buffer, u64::from(roots_start) * UNIT, bytemuck::cast_slice(&roots));
        }
        let mut cell_roots = vec![(0, 0); cells];
        let mut cell_lod = vec![u32::MAX; cells];
        let mut at = 0u32;
        for (i, cell) in lod.cells().iter().enumerate() {
            let count = lod.roots()[at as usize..]
                .iter()
                .take_while(|&&p| cell.points().as_usize().contains(&(p as usize)))
                .count();
            let count = u32::try_from(count).unwrap_or(0);
            cell_roots[cell.index() as usize] = (at, count);
            cell_lod[cell.index() as usize] = u32::try_from(i).unwrap_or(u32::MAX);
            at += count;
        }

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
        // The impostor atlas, as stored with its mips; without planes (or if it does not decode,
        // then without impostors) one transparent texel.
        let blank = |slots| textures::Atlas { width: 1, height: 1, srgb: true, slots, levels: vec![vec![0; 4]] };
        let (atlas, planes) = match representations.planes.take() {
            Some(p) => match textures::atlas(&container, p.image()) {
                Ok(atlas) if atlas.width.max(atlas.height) > device.limits().max_texture_dimension_2d => {
                    warnings.push(format!(
                        "impostor atlas (image {}) is {}x{}, larger than the device's textures; impostors are not drawn",
                        p.image(),
                        atlas.width,
                        atlas.height
                    ));
                    (blank(false), None)
                }
                Ok(atlas) => (atlas, Some(p)),
                Err(e) => {
                    warnings.push(format!("impostor atlas (image {}): {e}; impostors are not drawn", p.image()));
                    (blank(false), None)
                }
            },
            None => (blank(false), None),
        };
        // A leaf-slot image (spec §6.10.1) is bound as such, with a blank atlas; otherwise a blank
        // slot image.
        let (atlas, slots) = if atlas.slots { (blank(false), atlas) } else { (atlas, blank(true)) };
        if planes.as_ref().is_some_and(|p| container.planes().iter().any(|q| q.image != p.image())) {
            warnings.push(format!(
                "impostor planes sample several images; all are drawn from image {}",
                planes.as_ref().map_or(0, PlaneLod::image)
            ));
        }
        representations.planes = planes;
        let (atlas_view, atlas_bytes) = upload_atlas(device, queue, &atlas, "treelod impostor atlas");
        let (slots_view, slot_bytes) = upload_atlas(device, queue, &slots, "treelod leaf slots");
        bytes += atlas_bytes + slot_bytes;
        let Some(noise_view) = &self.noise_view else { unreachable!("uploaded above") };
        let model_group = |label: &str, planes: &wgpu::Buffer, atlas: &wgpu::TextureView| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &self.model_layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: vertices.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: materials.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::TextureView(&view) },
                    wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::Sampler(&self.sampler) },
                    wgpu::BindGroupEntry { binding: 4, resource: extra.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: prune_leaves.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 6, resource: planes.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 7, resource: wgpu::BindingResource::TextureView(atlas) },
                    wgpu::BindGroupEntry { binding: 8, resource: wgpu::BindingResource::Sampler(&self.atlas_sampler) },
                    wgpu::BindGroupEntry { binding: 9, resource: wgpu::BindingResource::TextureView(&slots_view) },
                    wgpu::BindGroupEntry { binding: 10, resource: plane_leaves.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 11, resource: ellipsoid_buffer.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 12, resource: wgpu::BindingResource::TextureView(noise_view) },
                    wgpu::BindGroupEntry { binding: 13, resource: wgpu::BindingResource::Sampler(&self.noise_sampler) },
                    wgpu::BindGroupEntry { binding: 14, resource: line_buffer.as_entire_binding() },
                ],
            })
        };
        let bind_group = model_group("treelod model", &plane_buffer, &atlas_view);
        // Billboards: their own atlas and bind group (the image of the first record; builders
        // write one), not drawn if it does not decode or fit.
        let billboards = match (billboard_kinds, billboard_buffer, billboard_records.first()) {
            (Some(_), Some(buffer), Some(first)) => match textures::atlas(&container, first.image) {
                Ok(atlas) if atlas.width.max(atlas.height) > device.limits().max_texture_dimension_2d => {
                    warnings.push(format!(
                        "billboard atlas (image {}) is {}x{}, larger than the device's textures; billboards are not drawn",
                        first.image, atlas.width, atlas.height
                    ));
                    None
                }
                Ok(atlas) => {
                    let (billboard_view, atlas_bytes) = upload_atlas(device, queue, &atlas, "treelod billboard atlas");
                    bytes += atlas_bytes;
                    Some(model_group("treelod billboards", &buffer, &billboard_view))
                }
                Err(e) => {
                    warnings.push(format!("billboard atlas (image {}): {e}; billboards are not drawn", first.image));
                    None
                }
            },
            _ => None,
        };
        if billboards.is_none() {
            representations.billboards = None;
        }
        let id = ModelId(u32::try_from(self.models.len()).unwrap_or(u32::MAX));
        let samples = match &representations.prune {
            Some(p) => (self.occlusion.add_samples(p.samples()), u32::try_from(p.samples().len()).unwrap_or(0)),
            None => (0, 0),
        };
        self.models.push(Model {
            samples,
            container,
            bind_group,
            static_bytes: bytes,
            roots_start,
            cell_roots,
            cell_lod,
            billboards,
        });
        self.lods.push(lod);
        self.representations.push(representations);
        self.policy
            .calibrations
            .push(treelod_runtime::Calibration::from_container(&self.models[id.0 as usize].container));
        self.policy.models_changed();
        self.wanted.push(vec![[0; 2]; cells]);
        if self.gpu.is_some() {
            // Checked above, so it fits; should it not, GPU selection is turned off.
            if self.enable_gpu_selection(device, queue).is_err() {
                self.gpu = None;
            }
        }
        Ok((id, warnings))
    }
}

/// Uploads an atlas with its mips; returns its view and the bytes uploaded.
fn upload_atlas(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    atlas: &textures::Atlas,
    label: &str,
) -> (wgpu::TextureView, u64) {
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: atlas.width, height: atlas.height, depth_or_array_layers: 1 },
        mip_level_count: u32::try_from(atlas.levels.len()).unwrap_or(1),
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: match (atlas.slots, atlas.srgb) {
            (true, _) => wgpu::TextureFormat::Rg16Uint,
            (false, true) => wgpu::TextureFormat::Rgba8UnormSrgb,
            (false, false) => wgpu::TextureFormat::Rgba8Unorm,
        },
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let mut bytes = 0u64;
    for (level, texels) in atlas.levels.iter().enumerate() {
        let level = u32::try_from(level).unwrap_or(0);
        let (w, h) = ((atlas.width >> level).max(1), (atlas.height >> level).max(1));
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: level,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            texels,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(w * 4), rows_per_image: Some(h) },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        bytes += texels.len() as u64;
    }
    (texture.create_view(&wgpu::TextureViewDescriptor::default()), bytes)
}

/// A storage buffer of `size` bytes that can be written (and, with `copy_src`, copied from).
pub(crate) fn storage_buffer(device: &wgpu::Device, label: &str, size: u64, copy_src: bool) -> wgpu::Buffer {
    let copy = if copy_src { wgpu::BufferUsages::COPY_SRC } else { wgpu::BufferUsages::empty() };
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | copy,
        mapped_at_creation: false,
    })
}
