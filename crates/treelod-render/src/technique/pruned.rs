//! Pruned trees (Neubert et al. 2011, spec §6.11; [`Technique::PruneOpt`],
//! [`Technique::PruneCook`], tuned by [`Pruning`]): the per-frame selection of the trees drawn
//! with a prefix of each cell's leaf priority list and their bark, and the draws of whole-tree
//! triangles from a model's extra triangle buffer ([`PrunedDraw`]: pruned leaves, bark, LoD
//! chain levels). WGSL: `shaders/tree/pruned.wgsl`.

#[cfg(doc)]
use treelod_runtime::Technique;
use treelod_runtime::prune::{MIN_VISIBLE_FRACTION, leaf_scale, leaves_drawn, projected_height, size_factor};
use treelod_runtime::{Frustum, PruneScale};

#[cfg(doc)]
use crate::draws::RecordedDraw;
use crate::draws::{DrawSource, View};
use crate::occlusion::Job;
use crate::renderer::{Renderer, max_axis_scale};
use crate::settings::Pruning;

/// One draw of a pruned tree: leaves of one cell, or the bark.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PrunedDraw {
    pub(crate) instance: u32,
    pub(crate) model: u32,
    /// Container cell, or `ROOTS_CELL` for the bark.
    pub(crate) cell: u32,
    pub(crate) source: DrawSource,
    /// Into the model's extra triangle buffer.
    pub(crate) first: u32,
    pub(crate) count: u32,
    pub(crate) lambda: f32,
    pub(crate) leaf_scale: f32,
    /// What [`RecordedDraw::tau_triangles`] reports: `leaf_scale`, or a chain level's error.
    pub(crate) tau_triangles: f32,
}

impl Renderer {
    /// Which instances are drawn pruned this frame (see [`Pruning`]): appends to `view`'s `pruned`
    /// their draws and `spt_instances`/`spt_map` with the others. Returns the pruned instances inside
    /// the frustum and the leaves they draw. Only the camera's view (`main`) holds `λ` between
    /// frames and lists trees for the occlusion test.
    pub(crate) fn select_pruned(
        &mut self,
        view: &mut View,
        pruning: &Pruning,
        leaf_scaling: PruneScale,
        camera: &treelod_runtime::Camera,
        main: bool,
    ) -> (u32, u64) {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let world_per_pixel = camera.world_per_pixel();
        if main {
            self.occlusion_jobs.clear();
        }
        let (mut visible, mut leaves) = (0u32, 0u64);
        for (i, instance) in self.instances.iter().enumerate() {
            let m = instance.model as usize;
            let (Some(model), Some(lod)) = (self.models.get(m), self.lods.get(m)) else { continue };
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let scale = max_axis_scale(instance.transform);
            let (centre, radius) = lod.cull_sphere();
            let world_centre = instance.transform.transform_point3(centre);
            let height = model.prune.as_ref().map_or(0.0, |p| {
                projected_height(p.height(), scale, world_centre.distance(camera.position), world_per_pixel)
            });
            let Some(prune) = model.prune.as_ref().filter(|_| height >= pruning.spt_below_pixels) else {
                if main {
                    self.prune_shown[i] = None;
                }
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            };
            if !frustum.intersects_sphere(world_centre, radius * scale) {
                if main {
                    self.prune_shown[i] = None;
                }
                continue;
            }
            visible += 1;
            if main && pruning.occlusion && model.samples.1 > 0 {
                self.occlusion_jobs.push(Job {
                    instance: index,
                    transform: instance.transform,
                    centre,
                    radius: radius * scale,
                    first: model.samples.0,
                    count: model.samples.1,
                });
            }
            let target = pruning.lambda.unwrap_or_else(|| prune.lambda_at(height));
            // A shadow cascade prunes by the tree's height in texels, with no hysteresis and no
            // occlusion: what the camera cannot see may still cast.
            let lambda = if main {
                let seen = if pruning.occlusion { self.visible_fraction[i].max(MIN_VISIBLE_FRACTION) } else { 1.0 };
                let lambda = pruning.hysteresis.update(self.prune_shown[i], target * seen);
                self.prune_shown[i] = Some(lambda);
                lambda
            } else {
                target
            };
            let factor = size_factor(leaf_scale(leaf_scaling, prune.scale_curve(), lambda));
            for cell in prune.cells() {
                let drawn = leaves_drawn(cell.leaves.count, lambda);
                let (first, count) = prune.prefix_triangles(cell, drawn);
                leaves += u64::from(drawn);
                if count > 0 {
                    view.pruned.push(PrunedDraw {
                        instance: index,
                        model: instance.model,
                        cell: cell.cell,
                        source: DrawSource::PrunedLeaves,
                        first,
                        count,
                        lambda,
                        leaf_scale: factor,
                        tau_triangles: factor,
                    });
                }
            }
            view.pruned.extend(model.bark_draw(index, instance.model, lambda));
        }
        (visible, leaves)
    }
}
