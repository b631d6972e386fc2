//! Impostor planes (Garcia et al. 2005, spec §6.10; [`Technique::Impostors`]): the planes as
//! uploaded, the bark drawn beside them ([`ImpostorBark`]), and the per-frame selection of the
//! trees drawn with them. WGSL: `shaders/tree/planes.wgsl`.

use glam::Vec3;
use treelod_format::{Container, PlaneRecord, TriangleRecord};
#[cfg(doc)]
use treelod_runtime::Technique;
use treelod_runtime::{Frustum, instance_tau};

use crate::draws::{DrawSource, PrefixDraw, View};
use crate::renderer::Renderer;
use crate::settings::ImpostorBark;
use crate::upload::Model;

/// [`ImpostorBark::Chain`] draws only levels whose bark keeps this share of the full bark's area.
pub(crate) const BARK_AREA_KEPT: f64 = 0.9;

/// The area of `triangles` of `container`, m² (model space).
pub(crate) fn area(container: &Container, triangles: &[TriangleRecord]) -> f64 {
    let vertices = container.vertices();
    let position = |i: u32| vertices.get(i as usize).map_or(Vec3::ZERO, |v| Vec3::from_array(v.position));
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.indices.map(position);
            f64::from(0.5 * (b - a).cross(c - a).length())
        })
        .sum()
}

/// [`ImpostorBark::Chain`] takes the coarsest level whose error is at most this share of `τ`:
/// meshoptimizer's error of a tube collapsed to a sliver is about its radius, so half a pixel
/// keeps the branches wider than about a pixel.
const BARK_ERROR_SHARE: f32 = 0.5;

impl Renderer {
    /// Which instances are drawn with impostor planes this frame ([`Technique::Impostors`]): appends to
    /// `view`'s `plane_draws`, and `pruned` with their bark, for instances whose model has planes, and
    /// `spt_instances`/`spt_map` with the others. Returns the impostor instances inside the
    /// frustum.
    pub(crate) fn select_impostors(&mut self, view: &mut View, camera: &treelod_runtime::Camera) -> u32 {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let mut visible = 0;
        for (i, instance) in self.instances.iter().enumerate() {
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let Some(model) = self.models.get(instance.model as usize) else { continue };
            let Some(planes) = &model.planes else {
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            };
            self.plane_ranges.clear();
            if !planes.select(instance.transform, camera, &frustum, self.settings.s_min, &mut self.plane_ranges) {
                continue;
            }
            visible += 1;
            for range in &self.plane_ranges {
                view.plane_draws.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            // The chain's bark level (its triangles and error), if the policy and the model have one.
            let chain_bark = match (self.settings.impostor_bark, &model.chain, self.lods.get(instance.model as usize)) {
                (ImpostorBark::Chain, Some(chain), Some(lod)) => {
                    let (s_min, sphere) = (self.settings.s_min, lod.cull_sphere());
                    instance_tau(instance.transform, camera, &frustum, s_min, sphere, model.block_centre())
                        .and_then(|tau| chain.chain.pick(tau * BARK_ERROR_SHARE))
                        .and_then(|level| {
                            let level = (level as usize).min(chain.bark_levels.len().checked_sub(1)?);
                            Some((chain.bark_levels[level], chain.level_error(level)))
                        })
                }
                _ => None,
            };
            view.pruned.extend(match chain_bark {
                Some((range, error)) => Model::whole_draw(index, instance.model, DrawSource::Bark, range, 1.0, error),
                None => model.bark_draw(index, instance.model, 1.0),
            });
        }
        visible
    }
}

/// The impostor planes of `container` as uploaded: each plane's `leaf_first` (which no shader
/// reads) holds the index of its parent plane, for the morph between levels (`vs_plane`), its
/// `leaf_count` its ambient occlusion byte (spec §6.14), and its `image` (bound separately) where
/// its leaves start in `PLANE_LEAVES` if it is textured indirectly (spec §6.10.1), else
/// 0xFFFFFFFF. Says in `warnings` when `PLANE_LEAVES` does not hold what the planes need.
pub(crate) fn gpu_planes(container: &Container, warnings: &mut Vec<String>) -> Vec<PlaneRecord> {
    let parents = treelod_runtime::plane_parents(container.planes(), container.cells().iter().map(|c| c.planes));
    let plane_ao = container.plane_ao();
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
            leaf_count: plane_ao.get(i).copied().map_or(0, u32::from),
            ..*plane
        })
        .collect()
}
