//! The baselines ([`Technique::LodChain`], [`Technique::Billboard`], [`Technique::Crossed`],
//! [`Technique::Octahedral`]): the billboard records as uploaded, their group (the planes' layout:
//! the quads and their atlas) and their stages, and the octahedral impostors' (their records as
//! stored, the same layout and atlas). The chain's levels are triangles of the model's
//! whole-triangle list, drawn as pruned trees' are; the selection is
//! `treelod_runtime::baseline::select`. WGSL: `shaders/tree/planes.wgsl` then
//! `shaders/tree/billboards.wgsl`; `shaders/tree/octahedral.wgsl`.

use treelod_format::{BillboardRecord, Container, OctahedralDepthRecord, OctahedralRecord, octahedral_depth_starts};
use treelod_runtime::Billboards;
#[cfg(doc)]
use treelod_runtime::Technique;

use super::{Bucket, Stages, impostors, tree_wgsl};
use crate::renderer::RenderError;
use crate::upload::ModelUpload;

/// The billboards' pipelines: their own vertex stage, the planes' fragment stages.
pub(crate) const STAGES: Stages = Stages {
    module: "treelod tree/billboards.wgsl",
    wgsl: tree_wgsl!("planes.wgsl", "billboards.wgsl"),
    vs: "vs_billboard",
    fs: "fs_plane",
    label: "treelod baseline billboards",
    shadow_fs: "fs_shadow_plane",
    shadow_label: "treelod shadow billboards",
};

/// The octahedral impostors' pipelines (spec §6.13.1): their own stages, the planes' group
/// layout (the records in place of the planes, the atlas).
pub(crate) const OCTAHEDRAL_STAGES: Stages = Stages {
    module: "treelod tree/octahedral.wgsl",
    wgsl: tree_wgsl!("octahedral.wgsl"),
    vs: "vs_octahedral",
    fs: "fs_octahedral",
    label: "treelod baseline octahedral impostors",
    shadow_fs: "fs_shadow_octahedral",
    shadow_label: "treelod shadow octahedral impostors",
};

/// The billboards' group and the octahedral impostors' of the model `up` uploads, each if it has
/// them and their atlas (the image of the first record; builders write one, the billboards' and
/// the impostors' the same, uploaded once then) decodes and fits; else they are taken out of its
/// representations, with a warning where the atlas is at fault.
pub(crate) fn upload(
    up: &mut ModelUpload<'_>,
) -> Result<(Option<wgpu::BindGroup>, Option<wgpu::BindGroup>), RenderError> {
    let kinds = Billboards::from_container(up.container);
    let records = gpu_billboards(up.container, kinds.as_ref());
    let octahedral = up.container.octahedral();
    let billboard_image = records.first().filter(|_| kinds.is_some()).map(|r| r.image);
    let octahedral_image = octahedral.first().map(|r| r.image);
    let mut atlases: Vec<(u32, Option<wgpu::TextureView>)> = Vec::new();
    for image in billboard_image.into_iter().chain(octahedral_image) {
        if atlases.iter().all(|(i, _)| *i != image) {
            let what = if Some(image) == billboard_image { "billboard" } else { "octahedral impostor" };
            let view = up.decode_atlas(image, what).map(|atlas| up.atlas(&atlas, "treelod billboard atlas"));
            atlases.push((image, view));
        }
    }
    let atlas_of = |image: Option<u32>| atlases.iter().find(|(i, _)| Some(*i) == image).and_then(|(_, v)| v.as_ref());
    let leaves = up.buffer("no plane leaves", &[])?;
    let slots = up.atlas(&impostors::blank(true), "treelod no leaf slots");
    let billboards = match atlas_of(billboard_image) {
        Some(atlas) => {
            let buffer = up.buffer("BILLBOARDS", bytemuck::cast_slice(&records))?;
            Some(impostors::group(up, Bucket::Billboards, &buffer, atlas, &slots, &leaves))
        }
        None => {
            up.representations.billboards = None;
            None
        }
    };
    let octahedral = match atlas_of(octahedral_image) {
        Some(atlas) => {
            if octahedral.iter().any(|r| Some(r.image) != octahedral_image) {
                up.warnings.push(format!(
                    "octahedral impostors sample several images; all are drawn from image {}",
                    octahedral_image.unwrap_or_default()
                ));
            }
            let (records, depth) = gpu_octahedral(up.container);
            let buffer = up.buffer("OCTAHEDRAL", bytemuck::cast_slice(&records))?;
            let depth = up.buffer("OCTAHEDRAL_DEPTH", bytemuck::cast_slice(depth))?;
            Some(impostors::group(up, Bucket::Octahedral, &buffer, atlas, &slots, &depth))
        }
        None => {
            up.representations.octahedral = 0;
            None
        }
    };
    Ok((billboards, octahedral))
}

/// An octahedral impostor as uploaded (`OctahedralRecord` in `shaders/tree/octahedral.wgsl`, 64
/// bytes): the record, its `reserved` (which no shader reads as such) holding the index of its
/// first view's depth plane in `OCTAHEDRAL_DEPTH`, then where its views' normals lie (spec
/// §6.13.3).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct OctahedralGpu {
    pub record: OctahedralRecord,
    /// The normal grid's corners, [`treelod_format::OctahedralNormalGridRecord`]'s.
    pub normals_uv_min: u32,
    pub normals_uv_max: u32,
    /// 1 where the impostor has normals, else 0 (its views lit as a whole, as before 1.15).
    pub has_normals: u32,
    pub padding: u32,
}
const _: () = assert!(size_of::<OctahedralGpu>() == 64);

/// The octahedral impostors of `container` as uploaded, and their views' depth planes (spec
/// §6.13.2). Where the container has no planes, or not one per view of every impostor, none are
/// bound and each view is drawn on the plane through the centre across it, as before 1.13; where
/// it has normals (one record per impostor, checked at open), each view is lit per texel.
pub(crate) fn gpu_octahedral(container: &Container) -> (Vec<OctahedralGpu>, &[OctahedralDepthRecord]) {
    let (records, depth) = (container.octahedral(), container.octahedral_depth());
    let starts = octahedral_depth_starts(records, depth.len());
    let uploaded = records
        .iter()
        .enumerate()
        .map(|(k, &r)| {
            #[expect(clippy::cast_possible_truncation, reason = "a section's records fit u32")]
            let reserved = starts.as_ref().map_or(0, |s| s[k] as u32);
            let normal = container.octahedral_normal_grid(k);
            OctahedralGpu {
                record: OctahedralRecord { reserved, ..r },
                normals_uv_min: normal.map_or(0, |n| n.uv_min),
                normals_uv_max: normal.map_or(0, |n| n.uv_max),
                has_normals: u32::from(normal.is_some()),
                padding: 0,
            }
        })
        .collect();
    (uploaded, if starts.is_some() { depth } else { &[] })
}

/// The billboards of `container` as uploaded: the facing quads (`kinds.facing`), then the
/// crossed ones; none without `kinds`.
pub(crate) fn gpu_billboards(container: &Container, kinds: Option<&Billboards>) -> Vec<BillboardRecord> {
    kinds.map_or_else(Vec::new, |b| {
        b.facing.iter().chain(&b.crossed).filter_map(|&i| container.billboards().get(i as usize).copied()).collect()
    })
}
