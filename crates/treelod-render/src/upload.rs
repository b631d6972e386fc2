//! Models uploaded from containers ([`Renderer::add_model`]): the GPU records the shaders read
//! (vertices with their ambient occlusion, materials, and each representation's records with
//! its occlusion in place of reserved fields), the model's buffers, textures and bind groups, its
//! pinned roots in the pool, and what drawing it needs of its container ([`Model`]).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use treelod_format::{Container, MaterialRecord, NO_IMAGE, PointRecord};
use treelod_runtime::{ModelLod, Representations};

use crate::gpu_select::GpuSelection;
use crate::renderer::{ModelId, RenderError, Renderer};
use crate::streaming::UNIT;
use crate::technique::{Bucket, upload_groups};
use crate::textures;

/// The most points of a model without pruning data its occlusion hull samples are chosen from
/// (every n-th point): the outermost of 64 directions over all of a 10⁶-point tree would cost
/// 64 passes over it when the model is added, and a sparser set reaches the same hull.
const HULL_CANDIDATES: usize = 16_384;

/// Each model's far list is pinned past its roots within this fraction of the streamed pool's
/// budget (`ModelLod::far_list`: at most 12 KiB per cell, 1 MiB for the shared weeping willow's
/// 83 cells with points): the whole list under the default 1 GiB budget for hundreds of models,
/// and a budget of a few hundred kilobytes still holds two demo trees' roots and what they
/// stream (`a_small_memory_budget_is_never_exceeded...` in `tests/render.rs`).
const FAR_LIST_POOL_SHARE: u64 = 64;

/// A vertex as the shaders read it: the record, then its ambient occlusion (0 without).
/// WGSL twin: `VertexGpu` in `shaders/tree/common.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct VertexGpu {
    record: treelod_format::VertexRecord,
    ao: f32,
}

/// A point as the pool holds it: its `flags` (reserved in the file, spec §6.5) carry its
/// ambient-occlusion byte (§6.14) in bits 0–7 and its facing byte (§6.5.1) in bits 8–15, each 0
/// without. `PointAttributes` holds the container's two byte arrays, looked up once: a point
/// stream of tens of thousands of points once looked up both sections per point, a seventh of
/// the willow's frame time while it streamed.
struct PointAttributes<'a> {
    ao: &'a [u8],
    facing: &'a [u8],
}

impl<'a> PointAttributes<'a> {
    fn of(container: &'a Container) -> Self {
        Self { ao: container.point_ao(), facing: container.point_facing() }
    }

    /// Whether `records` are already as the pool holds them: no `POINT_AO`, no `POINT_FACING` and
    /// every reserved `flags` 0 (which the shaders would otherwise read as occlusion and facing).
    fn as_stored(&self, records: &[PointRecord]) -> bool {
        self.ao.is_empty() && self.facing.is_empty() && records.iter().all(|p| p.flags == 0)
    }

    /// Point `index` (`point`) as the pool holds it.
    fn gpu_point(&self, index: usize, point: PointRecord) -> PointRecord {
        let byte = |bytes: &[u8]| bytes.get(index).copied().map_or(0, u32::from);
        PointRecord { flags: byte(self.ao) | (byte(self.facing) << 8), ..point }
    }
}

/// Points `first..` of `container` (`records`) as the pools hold them
/// ([`PointAttributes::gpu_point`]): the file's records themselves where they already are
/// ([`PointAttributes::as_stored`]), else rewritten into `scratch`.
pub(crate) fn gpu_points<'a>(
    container: &Container,
    first: usize,
    records: &'a [PointRecord],
    scratch: &'a mut Vec<PointRecord>,
) -> &'a [PointRecord] {
    let attributes = PointAttributes::of(container);
    if attributes.as_stored(records) {
        return records;
    }
    scratch.clear();
    scratch.extend(records.iter().enumerate().map(|(k, &p)| attributes.gpu_point(first + k, p)));
    scratch
}

/// Uploads points `first..` of `container` (`records`) to `buffer` at `offset` as the pools hold
/// them ([`gpu_points`]): where they must be rewritten, straight into the queue's staging memory,
/// a run at a time, rather than into a list first (the maple's frame that streams 43 MB copied
/// its points twice).
///
/// Each such write stages into memory of its own, freed once the copy is done, so a frame that
/// streams megabytes faults its pages in afresh: on lavapipe, page faults and clearing the pages
/// were 55 % of the samples under the maple's uploads (`bench --trees 10000 --no-render
/// --technique policy`, 96 frames, 110 MB streamed between frames 35 and 60). A staging belt
/// kept between frames (`wgpu::util::StagingBelt`, chunks of 4 MiB, the uploads cut to fit them,
/// copied and submitted at the end of the frame's streaming, the device polled first so that the
/// last frame's chunks come back) was measured and not taken: the faults were gone from the
/// profile, but the submission of the copies inside `prepare` waited 9 and 35 ms in the two
/// largest frames (24 and 18 MB) on lavapipe, and the mean of each frame's least selection time
/// over 5 alternating runs rose (2.14 → 2.49 ms without the poll, 2.27 → 2.46 ms with it). The
/// queue's writes are made by the host's next submission instead, outside `prepare`.
pub(crate) fn upload_gpu_points(
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    offset: u64,
    container: &Container,
    first: usize,
    records: &[PointRecord],
) {
    let attributes = PointAttributes::of(container);
    if attributes.as_stored(records) {
        queue.write_buffer(buffer, offset, bytemuck::cast_slice(records));
        return;
    }
    write_in_runs(queue, buffer, offset, records.len(), |range, run: &mut Vec<PointRecord>| {
        run.extend(records[range.clone()].iter().zip(range).map(|(&p, i)| attributes.gpu_point(first + i, p)));
    });
}

/// Writes `count` records to `buffer` at `offset` straight into the queue's staging memory, a run
/// of at most 1024 at a time: `fill(range, run)` appends records `range` of them to the empty
/// `run`, exactly that many.
pub(crate) fn write_in_runs<T: Pod>(
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    offset: u64,
    count: usize,
    mut fill: impl FnMut(std::ops::Range<usize>, &mut Vec<T>),
) {
    const RUN: usize = 1024;
    let Some(size) = wgpu::BufferSize::new((count * size_of::<T>()) as u64) else { return };
    let Some(mut staged) = queue.write_buffer_with(buffer, offset, size) else { return };
    let mut rest = staged.slice(..);
    let mut run = Vec::with_capacity(RUN.min(count));
    for start in (0..count).step_by(RUN) {
        run.clear();
        fill(start..(start + RUN).min(count), &mut run);
        let bytes: &[u8] = bytemuck::cast_slice(&run);
        let (mut head, tail) = rest.split_at(bytes.len());
        head.copy_from_slice(bytes);
        rest = tail;
    }
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

/// What [`Renderer::add_model`] hands each representation's `upload` (`crate::technique`): the
/// device, the container, the model's [`Representations`] (a representation that cannot be drawn
/// takes itself out), the bucket's group layouts and the samplers they bind, and the warnings and
/// bytes of the model so far.
pub(crate) struct ModelUpload<'a> {
    pub(crate) device: &'a wgpu::Device,
    pub(crate) queue: &'a wgpu::Queue,
    pub(crate) container: &'a Container,
    pub(crate) representations: &'a mut Representations,
    /// Per bucket, the layout of its group 3 (`crate::technique::Bucket::group_entries`).
    layouts: &'a [Option<wgpu::BindGroupLayout>; Bucket::COUNT],
    /// The atlases' sampler: clamped, nearest mip level.
    pub(crate) atlas_sampler: &'a wgpu::Sampler,
    /// The ellipsoids' white-noise cube map, shared by every model (made by the first model
    /// that draws ellipsoids), and its nearest-texel sampler.
    pub(crate) noise: &'a mut Option<wgpu::TextureView>,
    pub(crate) noise_sampler: &'a wgpu::Sampler,
    /// One sentence per problem that leaves something undrawn.
    pub(crate) warnings: Vec<String>,
    /// Bytes uploaded so far.
    pub(crate) bytes: u64,
    /// The device's storage-buffer binding limit.
    limit: u64,
}

impl ModelUpload<'_> {
    /// A storage buffer holding `data` (`what` names it in errors).
    ///
    /// # Errors
    /// [`RenderError::TooLarge`] beyond the device's binding limit.
    pub(crate) fn buffer(&mut self, what: &'static str, data: &[u8]) -> Result<wgpu::Buffer, RenderError> {
        if data.len() as u64 > self.limit {
            return Err(RenderError::TooLarge { what, bytes: data.len() as u64, limit: self.limit });
        }
        // Bindings may not be empty, nor smaller than one record of the array they hold: an
        // empty array becomes 64 zero bytes (the largest record) no draw reads.
        let padded = data.len().max(64).next_multiple_of(4) as u64;
        let buffer = storage_buffer(self.device, what, padded, false);
        self.queue.write_buffer(&buffer, 0, data);
        self.bytes += padded;
        Ok(buffer)
    }

    /// The atlas `image` of the container decoded with its mips, or `None` (and a warning that
    /// `what` is not drawn) if it does not decode or is larger than the device's textures.
    pub(crate) fn decode_atlas(&mut self, image: u32, what: &str) -> Option<textures::Atlas> {
        let bc = self.device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC);
        match textures::atlas(self.container, image, bc) {
            Ok(atlas) if atlas.width.max(atlas.height) > self.device.limits().max_texture_dimension_2d => {
                self.warnings.push(format!(
                    "{what} atlas (image {image}) is {}x{}, larger than the device's textures; {what}s are not drawn",
                    atlas.width, atlas.height
                ));
                None
            }
            Ok(atlas) => Some(atlas),
            Err(e) => {
                self.warnings.push(format!("{what} atlas (image {image}): {e}; {what}s are not drawn"));
                None
            }
        }
    }

    /// Uploads an atlas with its mips; returns its view.
    pub(crate) fn atlas(&mut self, atlas: &textures::Atlas, label: &str) -> wgpu::TextureView {
        let (view, bytes) = upload_atlas(self.device, self.queue, atlas, label);
        self.bytes += bytes;
        view
    }

    /// `bucket`'s group 3 over `entries` (binding `i` at position `i`).
    pub(crate) fn group(&self, bucket: Bucket, entries: &[wgpu::BindingResource<'_>]) -> wgpu::BindGroup {
        let entries: Vec<_> = entries
            .iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry {
                binding: u32::try_from(i).unwrap_or(u32::MAX),
                resource: resource.clone(),
            })
            .collect();
        let Some(layout) = &self.layouts[bucket as usize] else { unreachable!("{bucket:?} has no group of its own") };
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(bucket.stages().label),
            layout,
            entries: &entries,
        })
    }
}

/// The GPU resources of one model and what drawing it needs of its container (what its
/// selections read is its [`Representations`], held beside it in `Renderer::representations`).
pub(crate) struct Model {
    /// The mapped container: streamed ranges are uploaded from it.
    pub(crate) container: Arc<Container>,
    /// Group 1: vertices, materials, images and their sampler, and the whole-triangle list with
    /// the pruned leaves.
    pub(crate) bind_group: wgpu::BindGroup,
    /// Group 3 per bucket: the representations' own buffers and textures (`None` where the
    /// bucket has none, or the model draws nothing in it).
    pub(crate) groups: [Option<wgpu::BindGroup>; Bucket::COUNT],
    /// Bytes uploaded whole at [`Renderer::add_model`] (vertices, materials, images).
    pub(crate) static_bytes: u64,
    /// Pool unit (= point index) of the pinned copy of [`ModelLod::far_list`] (the roots first).
    pub(crate) roots_start: u32,
    /// Entries of [`ModelLod::far_list`] pinned from [`Self::roots_start`] on (the roots at least).
    pub(crate) far_pinned: u32,
    /// Per container cell: where its roots start in [`ModelLod::roots`] (the far list's head),
    /// and how many.
    pub(crate) cell_roots: Vec<(u32, u32)>,
    /// Per container cell: its index in [`ModelLod::cells`], `u32::MAX` if empty.
    pub(crate) cell_lod: Vec<u32>,
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
        // What the selections read, and the whole-triangle list (pruned leaves, bark, the LoD
        // chain) they address.
        let (mut representations, whole) = Representations::from_container(&container);
        let mut up = ModelUpload {
            device,
            queue,
            container: &container,
            representations: &mut representations,
            layouts: &self.group_layouts,
            atlas_sampler: &self.atlas_sampler,
            noise: &mut self.noise_view,
            noise_sampler: &self.noise_sampler,
            warnings: Vec::new(),
            bytes: 0,
            limit,
        };
        let layers = textures::layers(&container, &mut up.warnings);
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
        let vertices = up.buffer("VERTICES", bytemuck::cast_slice(&vertices))?;
        let materials = up.buffer("MATERIALS", bytemuck::cast_slice(&materials))?;
        let r = &up.representations;
        let whole_drawn = r.prune.is_some() || r.planes.is_some() || r.ellipsoids.is_some() || r.chain.is_some();
        let (extra, prune_leaves) = if whole_drawn {
            let extra = up.buffer("PRUNE_TRIANGLES, bark and LoD chain", bytemuck::cast_slice(&whole))?;
            (extra, up.buffer("PRUNE_LEAVES", bytemuck::cast_slice(container.prune_leaves()))?)
        } else {
            (up.buffer("no pruned triangles", &[])?, up.buffer("no pruned leaves", &[])?)
        };
        drop(whole);
        let groups = upload_groups(&mut up)?;
        let (warnings, mut bytes) = (up.warnings, up.bytes);

        // The far list, pinned in the pool: its head, the roots, is what a cell draws before its
        // own points are resident; the list draws a far tree with one range. Past the roots it is
        // pinned within `1/FAR_LIST_POOL_SHARE` of the pool (the whole list unless the budget is
        // a few megabytes); a longer prefix is clamped to the pinned one (`Renderer::clamp`).
        let lod = ModelLod::from_container(&container);
        let share = usize::try_from(self.pool_budget() / UNIT / FAR_LIST_POOL_SHARE).unwrap_or(usize::MAX);
        let pinned = lod.far_list().len().min(lod.roots().len().saturating_add(share));
        let attributes = PointAttributes::of(&container);
        let roots: Vec<PointRecord> = lod.far_list()[..pinned]
            .iter()
            .map(|&i| attributes.gpu_point(i as usize, container.points()[i as usize]))
            .collect();
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
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("treelod model"),
            layout: &self.model_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: vertices.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: materials.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::TextureView(&view) },
                wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::Sampler(&self.sampler) },
                wgpu::BindGroupEntry { binding: 4, resource: extra.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: prune_leaves.as_entire_binding() },
            ],
        });
        let id = ModelId(u32::try_from(self.models.len()).unwrap_or(u32::MAX));
        // The occlusion test's hull samples: the pruned leaves' where the model has them, else the
        // outermost of (at most `HULL_CANDIDATES` of) the point tree's points.
        let samples = match &representations.prune {
            Some(p) => p.samples().to_vec(),
            None => {
                let points = container.points();
                let stride = points.len().div_ceil(HULL_CANDIDATES).max(1);
                treelod_runtime::hull_samples(points.iter().step_by(stride).map(|p| p.position))
            }
        };
        let (centre, radius) = lod.cull_sphere();
        self.occlusion.add_model(&samples, centre, radius);
        self.models.push(Model {
            container,
            bind_group,
            static_bytes: bytes,
            roots_start,
            far_pinned: roots_len,
            cell_roots,
            cell_lod,
            groups,
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

/// Uploads an atlas with its mips; returns its view and the bytes uploaded. BC7 blocks are
/// uploaded as they are (a level smaller than a block is one block: its physical size).
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
        format: match (atlas.slots, atlas.bc7, atlas.srgb) {
            (true, _, _) => wgpu::TextureFormat::Rg16Uint,
            (false, true, true) => wgpu::TextureFormat::Bc7RgbaUnormSrgb,
            (false, true, false) => wgpu::TextureFormat::Bc7RgbaUnorm,
            (false, false, true) => wgpu::TextureFormat::Rgba8UnormSrgb,
            (false, false, false) => wgpu::TextureFormat::Rgba8Unorm,
        },
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let mut bytes = 0u64;
    for (level, texels) in atlas.levels.iter().enumerate() {
        let level = u32::try_from(level).unwrap_or(0);
        let (w, h) = ((atlas.width >> level).max(1), (atlas.height >> level).max(1));
        let (extent, bytes_per_row, rows) = if atlas.bc7 {
            ((w.next_multiple_of(4), h.next_multiple_of(4)), w.div_ceil(4) * 16, h.div_ceil(4))
        } else {
            ((w, h), w * 4, h)
        };
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: level,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            texels,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(bytes_per_row), rows_per_image: Some(rows) },
            wgpu::Extent3d { width: extent.0, height: extent.1, depth_or_array_layers: 1 },
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
