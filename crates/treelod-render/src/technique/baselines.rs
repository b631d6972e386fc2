//! The baselines ([`Technique::LodChain`], [`Technique::Billboard`], [`Technique::Crossed`]): the
//! billboard records as uploaded, their group (the planes' layout: the quads and their atlas) and
//! their stages. The chain's levels are triangles of the model's whole-triangle list, drawn as
//! pruned trees' are; the selection is `treelod_runtime::baseline::select`. WGSL:
//! `shaders/tree/planes.wgsl` then `shaders/tree/billboards.wgsl`.

use treelod_format::{BillboardRecord, Container};
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

/// The billboards' group of the model `up` uploads, if it has billboards and their atlas (the
/// image of the first record; builders write one) decodes and fits; else the billboards are taken
/// out of its representations, with a warning where the atlas is at fault.
pub(crate) fn upload(up: &mut ModelUpload<'_>) -> Result<Option<wgpu::BindGroup>, RenderError> {
    let kinds = Billboards::from_container(up.container);
    let records = gpu_billboards(up.container, kinds.as_ref());
    let atlas = match records.first() {
        Some(first) if kinds.is_some() => up.decode_atlas(first.image, "billboard"),
        _ => None,
    };
    let Some(atlas) = atlas else {
        up.representations.billboards = None;
        return Ok(None);
    };
    let buffer = up.buffer("BILLBOARDS", bytemuck::cast_slice(&records))?;
    let leaves = up.buffer("no plane leaves", &[])?;
    let atlas = up.atlas(&atlas, "treelod billboard atlas");
    let slots = up.atlas(&impostors::blank(true), "treelod no leaf slots");
    Ok(Some(impostors::group(up, Bucket::Billboards, &buffer, &atlas, &slots, &leaves)))
}

/// The billboards of `container` as uploaded: the facing quads (`kinds.facing`), then the
/// crossed ones; none without `kinds`.
pub(crate) fn gpu_billboards(container: &Container, kinds: Option<&Billboards>) -> Vec<BillboardRecord> {
    kinds.map_or_else(Vec::new, |b| {
        b.facing.iter().chain(&b.crossed).filter_map(|&i| container.billboards().get(i as usize).copied()).collect()
    })
}
