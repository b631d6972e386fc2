//! Impostor planes (Garcia et al. 2005, spec §6.10; [`Technique::Impostors`]): the planes as
//! uploaded. The selection, with the bark drawn beside them (`ImpostorBark`), is
//! `treelod_runtime::impostor::select`. WGSL: `shaders/tree/planes.wgsl`.

use treelod_format::{Container, PlaneRecord};
#[cfg(doc)]
use treelod_runtime::Technique;

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
