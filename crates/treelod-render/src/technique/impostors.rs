//! Impostor planes (Garcia et al. 2005, spec §6.10; [`Technique::Impostors`]): the planes as
//! uploaded, their group (the planes, the atlas and, for indirect texturing, the leaf-slot image
//! and the planes' leaves; the baseline billboards bind the same layout) and their stages. The
//! selection, with the bark drawn beside them (`ImpostorBark`), is
//! `treelod_runtime::impostor::select`. WGSL: `shaders/tree/planes.wgsl`.

use treelod_format::{Container, PlaneDiffuseRecord, PlaneRecord};
#[cfg(doc)]
use treelod_runtime::Technique;
use wgpu::{SamplerBindingType, ShaderStages, TextureSampleType, TextureViewDimension};

use super::{Bucket, Stages, sampler, storage, texture, tree_wgsl};
use crate::renderer::RenderError;
use crate::textures::Atlas;
use crate::upload::ModelUpload;

/// Group 3 of the planes' and the billboards' pipelines: the quads, their atlas and its sampler,
/// the leaf-slot image and the planes' leaves (`shaders/tree/planes.wgsl`); the octahedral
/// impostors bind their views' depth planes in place of the leaves, which their vertex stage
/// reads (`shaders/tree/octahedral.wgsl`).
pub(crate) const GROUP: &[wgpu::BindGroupLayoutEntry] = &[
    storage(0, ShaderStages::VERTEX),
    texture(1, TextureSampleType::Float { filterable: true }, TextureViewDimension::D2),
    sampler(2, SamplerBindingType::Filtering),
    texture(3, TextureSampleType::Uint, TextureViewDimension::D2),
    storage(4, ShaderStages::VERTEX_FRAGMENT),
];

/// The planes' pipelines.
pub(crate) const STAGES: Stages = Stages {
    module: "treelod tree/planes.wgsl",
    wgsl: tree_wgsl!("planes.wgsl"),
    vs: "vs_plane",
    fs: "fs_plane",
    label: "treelod impostor planes",
    shadow_fs: "fs_shadow_plane",
    shadow_label: "treelod shadow impostor planes",
};

/// One transparent texel: the atlas of a group without one (`slots`: a blank leaf-slot image).
pub(crate) fn blank(slots: bool) -> Atlas {
    Atlas { width: 1, height: 1, srgb: true, slots, bc7: false, levels: vec![vec![0; 4]] }
}

/// The planes' group of the model `up` uploads, if it has planes and their atlas decodes and
/// fits (else the planes are taken out of its representations, with a warning).
pub(crate) fn upload(up: &mut ModelUpload<'_>) -> Result<Option<wgpu::BindGroup>, RenderError> {
    let Some(planes) = up.representations.planes.take() else { return Ok(None) };
    let Some(atlas) = up.decode_atlas(planes.image(), "impostor") else { return Ok(None) };
    let container = up.container;
    let records = gpu_planes(container, &mut up.warnings);
    let buffer = up.buffer("PLANES", bytemuck::cast_slice(&records))?;
    drop(records);
    let leaves = up.buffer("PLANE_LEAVES", bytemuck::cast_slice(container.plane_leaves()))?;
    // A leaf-slot image (spec §6.10.1) is bound as such, with a blank atlas; otherwise a blank
    // slot image.
    let (atlas, slots) = if atlas.slots { (blank(false), atlas) } else { (atlas, blank(true)) };
    if container.planes().iter().any(|q| q.image != planes.image()) {
        up.warnings.push(format!("impostor planes sample several images; all are drawn from image {}", planes.image()));
    }
    up.representations.planes = Some(planes);
    let atlas = up.atlas(&atlas, "treelod impostor atlas");
    let slots = up.atlas(&slots, "treelod leaf slots");
    Ok(Some(group(up, Bucket::Planes, &buffer, &atlas, &slots, &leaves)))
}

/// The group of `bucket` (planes or billboards) over its quads, atlas, leaf slots and leaves.
pub(crate) fn group(
    up: &ModelUpload<'_>,
    bucket: Bucket,
    quads: &wgpu::Buffer,
    atlas: &wgpu::TextureView,
    slots: &wgpu::TextureView,
    leaves: &wgpu::Buffer,
) -> wgpu::BindGroup {
    up.group(
        bucket,
        &[
            quads.as_entire_binding(),
            wgpu::BindingResource::TextureView(atlas),
            wgpu::BindingResource::Sampler(up.atlas_sampler),
            wgpu::BindingResource::TextureView(slots),
            leaves.as_entire_binding(),
        ],
    )
}

/// The impostor planes of `container` as uploaded: each plane's `leaf_first` (which no shader
/// reads) holds the index of its parent plane, for the morph between levels (`vs_plane`), its
/// `leaf_count` its ambient occlusion byte (spec §6.14) in bits 0–7 and its diffuse response
/// (spec §6.10.2, [`pack_diffuse`]) above, and its `image` (bound separately) where
/// its leaves start in `PLANE_LEAVES` if it is textured indirectly (spec §6.10.1), else
/// 0xFFFFFFFF. Says in `warnings` when `PLANE_LEAVES` does not hold what the planes need.
pub(crate) fn gpu_planes(container: &Container, warnings: &mut Vec<String>) -> Vec<PlaneRecord> {
    let parents = treelod_runtime::plane_parents(container.planes(), container.cells().iter().map(|c| c.planes));
    let plane_ao = container.plane_ao();
    let plane_diffuse = container.plane_diffuse();
    let bases = treelod_format::plane_leaf_bases(container.planes());
    let is_slots = |image: u32| {
        container.images().get(image as usize).is_some_and(|i| i.format == treelod_format::image_format::LEAF_SLOTS)
    };
    let indirect = container.planes().iter().any(|p| is_slots(p.image));
    if indirect && bases.last().copied() != Some(container.plane_leaves().len() as u64) {
        warnings.push(format!(
            "PLANE_LEAVES holds {} records, the planes need {}; indirectly textured planes are not drawn",
            container.plane_leaves().len(),
            bases.last().copied().unwrap_or(0)
        ));
    }
    let leaf_base = |i: usize, plane: &PlaneRecord| {
        if is_slots(plane.image) && container.plane_leaves().len() as u64 == bases[bases.len() - 1] {
            u32::try_from(bases[i]).unwrap_or(u32::MAX)
        } else {
            u32::MAX
        }
    };
    container
        .planes()
        .iter()
        .zip(&parents)
        .enumerate()
        .map(|(i, (plane, &parent))| PlaneRecord {
            image: leaf_base(i, plane),
            leaf_first: parent,
            leaf_count: plane_ao.get(i).copied().map_or(0, u32::from)
                | pack_diffuse(plane_diffuse.get(i).copied().unwrap_or(PlaneDiffuseRecord::FLAT)),
            ..*plane
        })
        .collect()
}

/// A plane's diffuse response as `vs_plane` reads it from the uploaded `leaf_count`: the share of
/// leaves in the plane in bits 8–19 and of leaves turned every way in bits 20–31, each a 12-bit
/// unorm rounded from the record's 16 bits.
pub(crate) fn pack_diffuse(record: PlaneDiffuseRecord) -> u32 {
    let twelve = |v: u16| (u32::from(v) * 4095 + 32767) / 65535;
    twelve(record.flat) << 8 | twelve(record.scattered) << 20
}
