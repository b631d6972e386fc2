//! The light trees are shaded with: one sun and an ambient share, both faces of a
//! surface lit (leaves are cards). The renderer's default light, and the light the build's
//! calibration shades its images with (spec §6.15), so the tables measure the image a renderer
//! with its defaults shows.

use glam::Vec3;
use treelod_format::{OctahedralNormalRecord, PlaneDiffuseRecord};

/// A sun and an ambient share.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Direction towards the sun (need not be unit: [`Light::shade`] normalises it).
    pub sun: Vec3,
    /// Colour of the sunlight, linear RGB.
    pub sun_colour: Vec3,
    /// Ambient share of the light, `0..1`.
    pub ambient: f32,
}

impl Light {
    /// The renderer's default light: a sun from above and to one side, white, with 35 % ambient.
    pub const DEFAULT: Self = Self { sun: Vec3::new(0.4, 0.8, 0.45), sun_colour: Vec3::ONE, ambient: 0.35 };

    /// What a surface of linear `albedo`, `normal` (need not be unit) and ambient occlusion `ao`
    /// reflects without shadows: `albedo · (ambient · (1 − ao) + (1 − ambient) · |n·l| ·
    /// sun_colour)`, the twin of `shade` in `shaders/tree/common.wgsl` with the sun's share fully
    /// lit. A zero normal takes the sun's share as lit from the front.
    #[must_use]
    pub fn shade(&self, albedo: Vec3, normal: Vec3, ao: f32) -> Vec3 {
        let diffuse = normal.try_normalize().map_or(1.0, |n| n.dot(self.sun_direction()).abs());
        self.shade_diffuse(albedo, diffuse, ao)
    }

    /// As [`Light::shade`], with the sun's diffuse factor given: `|n·l|` for a surface, or what
    /// [`Light::plane_diffuse`] gives an impostor plane.
    #[must_use]
    pub fn shade_diffuse(&self, albedo: Vec3, diffuse: f32, ao: f32) -> Vec3 {
        albedo * (self.ambient * (1.0 - ao) + (1.0 - self.ambient) * diffuse * self.sun_colour)
    }

    /// The sun's diffuse factor of an impostor plane of `normal` (need not be unit) seen along
    /// `view` (towards the viewer or away, need not be unit) whose leaves take the sun as `record`
    /// says (spec §6.10.2): the leaves' mean `|n·l|` weighted by the area each shows, not the
    /// plane's own `|N·l|`. The twin of `plane_diffuse` in `shaders/tree/planes.wgsl`. A zero
    /// normal or view takes the sun as lit from the front.
    #[must_use]
    pub fn plane_diffuse(&self, normal: Vec3, view: Vec3, record: PlaneDiffuseRecord) -> f32 {
        let sun = self.sun_direction();
        match (normal.try_normalize(), view.try_normalize()) {
            (Some(n), Some(v)) => record.diffuse(n.to_array(), v.to_array(), sun.to_array()),
            _ => 1.0,
        }
    }

    /// The sun's diffuse factor of an octahedral impostor's texel whose decoded normal is `n`
    /// (block space, [`OctahedralNormalRecord::decode`]) where the impostor's diffuse mixture
    /// gives `mixture` (spec §6.13.3): [`OctahedralNormalRecord::sun_factor`] with this sun. The
    /// twin of `octahedral_sun` in `shaders/tree/octahedral.wgsl`.
    #[must_use]
    pub fn octahedral_texel_diffuse(&self, n: [f32; 3], mixture: f32) -> f32 {
        OctahedralNormalRecord::sun_factor(n, self.sun_direction().to_array(), mixture)
    }

    /// The unit direction towards the sun (`+Y` for a zero `sun`).
    fn sun_direction(&self) -> Vec3 {
        self.sun.normalize_or(Vec3::Y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sun_lights_both_faces_and_ambient_occlusion_darkens_only_the_ambient_share() {
        let light = Light::DEFAULT;
        let albedo = Vec3::new(0.2, 0.5, 0.1);
        let sun = light.sun.normalize();
        assert!((light.shade(albedo, sun, 0.0) - albedo).abs().max_element() < 1e-6);
        assert_eq!(light.shade(albedo, sun, 0.0), light.shade(albedo, -sun, 0.0));
        let edge_on = sun.any_orthogonal_vector();
        assert!((light.shade(albedo, edge_on, 0.0) - albedo * 0.35).abs().max_element() < 1e-6);
        assert!((light.shade(albedo, edge_on, 1.0)).abs().max_element() < 1e-6);
        assert!((light.shade(albedo, sun, 1.0) - albedo * 0.65).abs().max_element() < 1e-6);
    }
}
