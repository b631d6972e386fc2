//! The baselines ([`Technique::LodChain`], [`Technique::Billboard`], [`Technique::Crossed`]): the
//! billboard records as uploaded (their bind group is made by `crate::upload`). The chain's levels
//! are triangles of the model's whole-triangle list, drawn as pruned trees' are; the selection is
//! `treelod_runtime::baseline::select`. WGSL: `shaders/tree/billboards.wgsl`.

use treelod_format::{BillboardRecord, Container};
use treelod_runtime::Billboards;
#[cfg(doc)]
use treelod_runtime::Technique;

/// The billboards of `container` as uploaded: the facing quads (`kinds.facing`), then the
/// crossed ones; none without `kinds`.
pub(crate) fn gpu_billboards(container: &Container, kinds: Option<&Billboards>) -> Vec<BillboardRecord> {
    kinds.map_or_else(Vec::new, |b| {
        b.facing.iter().chain(&b.crossed).filter_map(|&i| container.billboards().get(i as usize).copied()).collect()
    })
}
