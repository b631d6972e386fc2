//! Clasen's leaf ellipsoids and branch lines (Clasen and Prohaska 2011, spec §6.8, §6.9;
//! [`Technique::Ellipsoids`]): their records as uploaded, and the per-frame selection of the
//! trees drawn with them. WGSL: `shaders/tree/ellipsoids.wgsl`, `shaders/tree/lines.wgsl`.

use treelod_format::{Container, EllipsoidRecord, LineRecord};
#[cfg(doc)]
use treelod_runtime::Technique;
use treelod_runtime::{Frustum, LodSettings};

use crate::draws::{PrefixDraw, View};
use crate::renderer::Renderer;
#[cfg(doc)]
use crate::settings::Settings;
use crate::upload::with_ao_in_flags;

impl Renderer {
    /// Which instances are drawn with ellipsoids this frame ([`Technique::Ellipsoids`]): appends to
    /// `view`'s `ellipsoid_draws`, and its `line_draws` with their bark's lines (with
    /// [`Settings::lines`] and where the model has lines; else `pruned` with all their bark
    /// triangles), for instances whose model has ellipsoids, and `spt_instances`/`spt_map` with
    /// the others. Returns the ellipsoid instances inside the frustum.
    pub(crate) fn select_ellipsoids(
        &mut self,
        view: &mut View,
        camera: &treelod_runtime::Camera,
        lod_settings: &LodSettings,
    ) -> u32 {
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let level = self.settings.pixel_level();
        let draw_lines = self.settings.lines;
        let mut visible = 0;
        for (i, instance) in self.instances.iter().enumerate() {
            let index = u32::try_from(i).unwrap_or(u32::MAX);
            let Some(model) = self.models.get(instance.model as usize) else { continue };
            let Some(ellipsoids) = &model.ellipsoids else {
                view.spt_instances.push(*instance);
                view.spt_map.push(index);
                continue;
            };
            self.ellipsoid_ranges.clear();
            let leaves_seen = ellipsoids.select_per_pixel_blended(
                instance.transform,
                camera,
                &frustum,
                lod_settings,
                level,
                &mut self.ellipsoid_ranges,
            );
            // The lines' sphere holds their radii: they may be in view where the leaves are not.
            let lines = model.lines.as_ref().filter(|_| draw_lines);
            self.line_ranges.clear();
            let lines_seen = lines.is_some_and(|lines| {
                let ranges = &mut self.line_ranges;
                lines.select_per_pixel_blended(instance.transform, camera, &frustum, lod_settings, level, ranges)
            });
            if !(leaves_seen || lines_seen) {
                continue;
            }
            visible += 1;
            for range in &self.ellipsoid_ranges {
                view.ellipsoid_draws.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            for range in &self.line_ranges {
                view.line_draws.push(PrefixDraw { instance: index, model: instance.model, range: *range });
            }
            if lines.is_none() {
                view.pruned.extend(model.bark_draw(index, instance.model, 1.0));
            }
        }
        visible
    }
}

/// The ellipsoids of `container` as uploaded: each one's `flags` (reserved in the file, spec
/// §6.8) holds its ambient occlusion byte (§6.14), 0 without `ELLIPSOID_AO`: never the file's own
/// flags.
pub(crate) fn gpu_ellipsoids(container: &Container) -> Vec<EllipsoidRecord> {
    with_ao_in_flags(container.ellipsoids(), container.ellipsoid_ao(), |e, flags| EllipsoidRecord { flags, ..e })
}

/// The branch lines of `container` as uploaded, likewise: each one's `flags` holds its `LINE_AO`
/// byte, never the file's flags.
pub(crate) fn gpu_lines(container: &Container) -> Vec<LineRecord> {
    with_ao_in_flags(container.lines(), container.line_ao(), |l, flags| LineRecord { flags, ..l })
}
