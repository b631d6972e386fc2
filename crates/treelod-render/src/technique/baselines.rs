//! The baselines ([`Technique::LodChain`], [`Technique::Billboard`], [`Technique::Crossed`]): a
//! model's LoD chain and billboards on the GPU, the billboard records as uploaded, and the
//! per-frame selection of the trees drawn with them. WGSL: `shaders/tree/billboards.wgsl` (the
//! chain's levels are triangles, drawn as pruned trees' are).

use treelod_format::{BillboardRecord, Container};
use treelod_runtime::{Billboards, Frustum, LodChain, Technique, instance_tau};

use crate::draws::{DrawSource, View};
use crate::renderer::Renderer;
#[cfg(doc)]
use crate::settings::ImpostorBark;
#[cfg(doc)]
use crate::technique::impostors::BARK_AREA_KEPT;
use crate::upload::Model;

/// A model's baseline LoD chain on the GPU (after the bark in the extra triangle buffer).
pub(crate) struct ChainModel {
    pub(crate) chain: LodChain,
    /// Every triangle of the container (the full mesh): first and count.
    pub(crate) full: (u32, u32),
    /// Per level, every tree's triangles of that level, contiguous: first and count.
    pub(crate) levels: Vec<(u32, u32)>,
    /// Per level, the bark (non-leaf) triangles of `levels`, for trees drawn with impostor
    /// planes ([`ImpostorBark::Chain`]): the leading levels whose bark keeps [`BARK_AREA_KEPT`]
    /// of the full bark's area; empty without planes.
    pub(crate) bark_levels: Vec<(u32, u32)>,
}

/// A model's baseline billboards on the GPU: a bind group like the model's with the billboards
/// in place of the planes and their atlas in place of the impostor atlas.
pub(crate) struct BillboardModel {
    pub(crate) bind_group: wgpu::BindGroup,
    /// The facing quads, then the crossed ones, in the billboard buffer: first and count each.
    pub(crate) facing: (u32, u32),
    pub(crate) crossed: (u32, u32),
}

impl ChainModel {
    /// The error of level `level`, metres (0 past the chain).
    pub(crate) fn level_error(&self, level: usize) -> f32 {
        self.chain.levels().get(level).map_or(0.0, |l| l.error)
    }
}

impl Renderer {
    /// Which instances are drawn with the baseline `baseline` this frame ([`Technique::LodChain`],
    /// [`Technique::Billboard`] or [`Technique::Crossed`]): appends to `view`'s `pruned` with LoD
    /// chain draws or `billboard_draws` for instances whose model has the baseline, and
    /// `spt_instances`/`spt_map` with the others. Returns the baseline instances inside the
    /// frustum.
    pub(crate) fn select_baseline(
        &mut self,
        view: &mut View,
        baseline: Technique,
        camera: &treelod_runtime::Camera,
    ) -> u32 {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let mut visible = 0;
        for (i, instance) in self.instances.iter().enumerate() {
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let m = instance.model as usize;
            let (Some(model), Some(lod)) = (self.models.get(m), self.lods.get(m)) else { continue };
            // A model with billboards of the other kind only is drawn with the point tree, as
            // `Technique::held_by` says.
            let has = match baseline {
                Technique::LodChain => model.chain.is_some(),
                Technique::Crossed => model.billboards.as_ref().is_some_and(|b| b.crossed.1 > 0),
                _ => model.billboards.as_ref().is_some_and(|b| b.facing.1 > 0),
            };
            if !has {
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            }
            let Some(tau) = instance_tau(
                instance.transform,
                camera,
                &frustum,
                self.settings.s_min,
                lod.cull_sphere(),
                model.block_centre(),
            ) else {
                continue;
            };
            visible += 1;
            match (baseline, &model.chain, &model.billboards) {
                (Technique::LodChain, Some(chain), _) => {
                    let (range, error) = match chain.chain.pick(tau) {
                        Some(level) => (
                            chain.levels.get(level as usize).copied().unwrap_or(chain.full),
                            chain.level_error(level as usize),
                        ),
                        None => (chain.full, 0.0),
                    };
                    view.pruned.extend(Model::whole_draw(
                        index,
                        instance.model,
                        DrawSource::LodLevel,
                        range,
                        tau,
                        error,
                    ));
                }
                (Technique::Billboard | Technique::Crossed, _, Some(billboards)) => {
                    let (first, count) =
                        if baseline == Technique::Crossed { billboards.crossed } else { billboards.facing };
                    if count > 0 {
                        view.billboard_draws.push((index, instance.model, first, count));
                    }
                }
                _ => {}
            }
        }
        visible
    }
}

/// The billboards of `container` as uploaded: the facing quads (`kinds.facing`), then the
/// crossed ones; none without `kinds`.
pub(crate) fn gpu_billboards(container: &Container, kinds: Option<&Billboards>) -> Vec<BillboardRecord> {
    kinds.map_or_else(Vec::new, |b| {
        b.facing.iter().chain(&b.crossed).filter_map(|&i| container.billboards().get(i as usize).copied()).collect()
    })
}
