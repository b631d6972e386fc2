//! Shaded images on the CPU rasteriser ([`crate::raster`]): what the calibration (spec §6.15)
//! compares, so that its tables measure colour and shading as well as coverage — a
//! representation that keeps a tree's silhouette but darkens it, or lights its leaves as one
//! flat card, reads as the error a viewer sees.
//!
//! - A [`Canvas`] holds per pixel a linear colour and a depth (orthographic: the distance along
//!   the view direction), cleared to a background; [`Canvas::put`] keeps the nearest fragment.
//!   The pixels each primitive visits are the coverage rasteriser's ([`triangle_pixels`] for
//!   triangles, [`crate::raster::ellipse_spans`] for discs, [`crate::raster::ellipsoid_hits`] for
//!   ellipsoids), so an opaque primitive covers the pixels the coverage rasteriser gives it.
//! - Surfaces are lit by [`Light::DEFAULT`], the renderer's default light, without shadows:
//!   `albedo · (ambient · (1 − ao) + (1 − ambient) · |n·l|)` (both faces lit, as leaves are).
//! - Textures are sampled as the renderer samples them ([`treelod_runtime::texels`]): the
//!   materials' from the same layers and mips as its texture array, trilinear; the atlases from
//!   their stored mips.

use glam::Vec3;
use treelod_eval::metrics::LinearImage;
use treelod_runtime::Light;

use crate::raster::View;
pub use crate::raster::triangle_pixels;

/// A linear colour and a depth per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Canvas {
    size: u32,
    colour: Vec<Vec3>,
    depth: Vec<f32>,
}

impl Canvas {
    /// A `size × size` canvas of `background` at infinite depth.
    #[must_use]
    pub fn new(size: u32, background: Vec3) -> Self {
        let n = size as usize * size as usize;
        Self { size, colour: vec![background; n], depth: vec![f32::INFINITY; n] }
    }

    /// Pixels along each side.
    #[must_use]
    pub fn size(&self) -> u32 {
        self.size
    }

    /// Whether a fragment at `depth` would show at `(x, y)` (nearer than what is there).
    #[inline]
    #[must_use]
    pub fn nearer(&self, x: usize, y: usize, depth: f32) -> bool {
        self.depth.get(y * self.size as usize + x).is_some_and(|&d| depth < d)
    }

    /// Draws `colour` at `(x, y)` if `depth` is nearer than what is there (ties keep the first).
    #[inline]
    pub fn put(&mut self, x: usize, y: usize, depth: f32, colour: Vec3) {
        let i = y * self.size as usize + x;
        if let Some(d) = self.depth.get_mut(i)
            && depth < *d
        {
            *d = depth;
            self.colour[i] = colour;
        }
    }

    /// The colour at `(x, y)`.
    #[must_use]
    pub fn colour(&self, x: usize, y: usize) -> Vec3 {
        self.colour[y * self.size as usize + x]
    }

    /// The canvas as a linear image.
    #[must_use]
    pub fn image(&self) -> LinearImage {
        LinearImage { width: self.size, height: self.size, pixels: self.colour.iter().map(|c| c.to_array()).collect() }
    }
}

/// The depth of `p` in `view`: its distance from the view's centre plane, along the view (towards
/// the model; smaller is nearer the viewer).
#[inline]
#[must_use]
pub fn depth(view: &View, p: Vec3) -> f32 {
    -(p - view.centre).dot(view.direction)
}

/// A surface point to shade.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    /// Linear albedo.
    pub albedo: Vec3,
    /// Normal (need not be unit).
    pub normal: Vec3,
    /// Ambient occlusion, `0..=1`.
    pub ao: f32,
}

impl Surface {
    /// Its colour under the renderer's default light, without shadows.
    #[inline]
    #[must_use]
    pub fn shaded(&self) -> Vec3 {
        Light::DEFAULT.shade(self.albedo, self.normal, self.ao)
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec2;

    use super::*;
    use crate::raster::{Mask, fill_triangle};

    #[test]
    fn triangle_pixels_visit_the_pixels_the_coverage_rasteriser_covers_with_corner_weights() {
        let mut state = 7u64;
        let mut next = || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..200 {
            let p: [Vec2; 3] = core::array::from_fn(|_| Vec2::new(next() * 40.0 - 4.0, next() * 40.0 - 4.0));
            let mut mask = Mask::new(32);
            fill_triangle(&mut mask, p, [Vec2::ZERO; 3], None);
            let mut visited = Mask::new(32);
            triangle_pixels(32, p, |x, y, b| {
                assert!(!visited.get(x as u32, y as u32), "a pixel visited twice");
                visited.set(x as u32, y as u32);
                assert!((b.iter().sum::<f32>() - 1.0).abs() < 1e-3, "weights {b:?}");
                let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let at = p[0] * b[0] + p[1] * b[1] + p[2] * b[2];
                assert!(at.distance(centre) < 0.05, "weights {b:?} give {at}, not the centre {centre}");
            });
            assert_eq!(visited, mask);
        }
    }

    #[test]
    fn the_nearest_fragment_shows_whatever_the_order() {
        let mut a = Canvas::new(2, Vec3::ONE);
        a.put(0, 0, 2.0, Vec3::X);
        a.put(0, 0, 1.0, Vec3::Y);
        let mut b = Canvas::new(2, Vec3::ONE);
        b.put(0, 0, 1.0, Vec3::Y);
        b.put(0, 0, 2.0, Vec3::X);
        assert_eq!(a, b);
        assert_eq!(a.colour(0, 0), Vec3::Y);
        assert_eq!(a.colour(1, 1), Vec3::ONE);
        assert!(a.nearer(1, 1, 1e30) && !a.nearer(0, 0, 1.0));
    }
}
