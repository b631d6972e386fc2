//! Colour of a triangle integrated over its texture (Gilet 2005 §4.1): the point that replaces a
//! triangle carries the mean colour of what the triangle shows, and the fraction of it that is
//! opaque.

use glam::{Vec2, Vec3, Vec4};

use crate::scene::{AlphaMode, Image, Material};

/// Most samples per edge of a triangle: up to `MAX_SPLITS²` = 64 samples.
const MAX_SPLITS: u32 = 8;

/// sRGB-encoded byte → linear value.
pub(crate) fn srgb_to_linear_table() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        core::array::from_fn(|i| {
            let c = i as f32 / 255.0;
            if c <= 0.040_45 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
        })
    })
}

/// Linear value in `[0, 1]` → sRGB-encoded value in `[0, 1]`.
#[must_use]
pub fn linear_to_srgb(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

/// One triangle's appearance inputs: UVs and linear vertex colours at its corners.
#[derive(Clone, Copy, Debug)]
pub struct TriangleSurface {
    /// Texture coordinates of the corners (zero when the source has none).
    pub uv: [Vec2; 3],
    /// Linear RGBA vertex colours of the corners (ones when the source has none).
    pub color: [Vec4; 3],
}

/// Mean linear RGB of the opaque part of the triangle, and in `w` its opaque fraction.
///
/// Samples the texture (nearest texel, wrapped) at the centroids of a regular subdivision of the
/// triangle into `k²` parts, `k` growing with the triangle's texel footprint up to 8, times the
/// material factor and the interpolated vertex colour. Opaque means alpha at or above the cutoff
/// for `MASK`; for `BLEND` the fraction is the mean alpha; `OPAQUE` is fully opaque.
#[must_use]
pub fn integrate(material: &Material, image: Option<&Image>, surface: &TriangleSurface) -> Vec4 {
    let factor = Vec4::from_array(material.base_color);
    let k = match image {
        Some(img) => {
            let e1 = surface.uv[1] - surface.uv[0];
            let e2 = surface.uv[2] - surface.uv[0];
            let texels = 0.5 * e1.perp_dot(e2).abs() * img.width as f32 * img.height as f32;
            // About two texels per sample: finer sampling would not change the mean. Texture
            // coordinates so far apart that the area overflows (NaN) sample once. (On the shared
            // maple and willow every triangle reaches the cap, 64 samples: all 840,224 and
            // 216,540 integrations of their builds, leaves and bark, so the cap sets the cost.)
            let k = (texels * 0.5).sqrt().ceil();
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 1..=8")]
            let k = if k.is_nan() { 1 } else { k.clamp(1.0, MAX_SPLITS as f32) as u32 };
            k
        }
        None => 1,
    };
    let lut = srgb_to_linear_table();
    let (mut rgb_opaque, mut opaque, mut rgb_all, mut alpha_sum, mut n) =
        (Vec3::ZERO, 0.0f32, Vec3::ZERO, 0.0f32, 0.0f32);
    let mut sample = |a: f32, b: f32| {
        let w = Vec3::new(1.0 - a - b, a, b);
        let vc = surface.color[0] * w.x + surface.color[1] * w.y + surface.color[2] * w.z;
        let texel = match image {
            Some(img) => {
                let uv = surface.uv[0] * w.x + surface.uv[1] * w.y + surface.uv[2] * w.z;
                let t = img.texel(floor(uv.x * img.width as f32), floor(uv.y * img.height as f32));
                Vec4::new(lut[t[0] as usize], lut[t[1] as usize], lut[t[2] as usize], f32::from(t[3]) / 255.0)
            }
            None => Vec4::ONE,
        };
        let c = texel * factor * vc;
        let rgb = c.truncate();
        rgb_all += rgb;
        alpha_sum += c.w;
        n += 1.0;
        let passes = match material.alpha_mode {
            AlphaMode::Mask => c.w >= material.alpha_cutoff,
            AlphaMode::Blend | AlphaMode::Opaque => true,
        };
        if passes {
            let weight = if material.alpha_mode == AlphaMode::Blend { c.w } else { 1.0 };
            rgb_opaque += rgb * weight;
            opaque += weight;
        }
    };
    for &(a, b) in sample_points(k) {
        sample(a, b);
    }
    let coverage = match material.alpha_mode {
        AlphaMode::Opaque => 1.0,
        AlphaMode::Mask => opaque / n,
        AlphaMode::Blend => alpha_sum / n,
    };
    let rgb = if opaque > 0.0 { rgb_opaque / opaque } else { rgb_all / n };
    rgb.extend(coverage)
}

/// The barycentric sample points `(a, b)` of a triangle split into `k²` parts (`k` in
/// `1..=MAX_SPLITS`), in the order [`integrate`] sums them: per part its centroid, the parts with
/// a corner at the triangle's first vertex first. Computed once per `k`, not per triangle (two
/// divisions a sample, 128 for each of the maple's 840,224 integrations), with the same
/// arithmetic: every shared model's default container, and the oak's with every representation,
/// the same bytes; the maple's cells stage (`--ao-rays 0`, 5 alternating builds, 2 cores)
/// 0.83–0.99 s (median 0.89) → 0.78–0.87 s (median 0.85).
fn sample_points(k: u32) -> &'static [(f32, f32)] {
    static TABLES: std::sync::OnceLock<Vec<Vec<(f32, f32)>>> = std::sync::OnceLock::new();
    let tables = TABLES.get_or_init(|| {
        (0..=MAX_SPLITS)
            .map(|k| {
                #[expect(clippy::cast_precision_loss, reason = "at most 8")]
                let kf = k as f32;
                let mut points = Vec::with_capacity((k * k) as usize);
                for i in 0..k {
                    for j in 0..k - i {
                        #[expect(clippy::cast_precision_loss, reason = "at most 8")]
                        let (fi, fj) = (i as f32, j as f32);
                        points.push(((fi + 1.0 / 3.0) / kf, (fj + 1.0 / 3.0) / kf));
                        if i + j + 1 < k {
                            points.push(((fi + 2.0 / 3.0) / kf, (fj + 2.0 / 3.0) / kf));
                        }
                    }
                }
                points
            })
            .collect()
    });
    &tables[k.min(MAX_SPLITS) as usize]
}

/// `x.floor() as i64` (saturating, NaN to 0) without a call to `floorf`, which this target
/// does not inline: truncate, then step down where that rounded a negative value up.
#[expect(clippy::cast_possible_truncation, clippy::cast_precision_loss, reason = "saturating casts, as floor() as i64")]
fn floor(x: f32) -> i64 {
    let t = x as i64;
    if x < t as f32 { t.saturating_sub(1) } else { t }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ImageEncoding;

    /// The same integer as `floor() as i64` everywhere, the edges of i64 and NaN included.
    #[test]
    fn floor_is_floor_as_i64() {
        let mut values = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999_8, -2.999_999_8, 1e30, -1e30, f32::NAN];
        values.extend([f32::INFINITY, f32::NEG_INFINITY, 9.2e18, -9.2e18, 9.3e18, -9.3e18, f32::MIN_POSITIVE]);
        values.extend((0..2000).map(|i| (i as f32 - 1000.0) * 0.37));
        for x in values {
            #[expect(clippy::cast_possible_truncation, reason = "the reference")]
            let reference = x.floor() as i64;
            assert_eq!(floor(x), reference, "{x}");
        }
    }

    fn checker_image() -> Image {
        // 2×1 texels: left opaque red, right transparent.
        Image {
            width: 2,
            height: 1,
            rgba: vec![255, 0, 0, 255, 0, 0, 255, 0],
            encoded: Vec::new(),
            encoding: ImageEncoding::Raw,
        }
    }

    fn material(mode: AlphaMode) -> Material {
        Material { base_color: [1.0; 4], alpha_mode: mode, alpha_cutoff: 0.5, image: Some(0), ..Material::default() }
    }

    #[test]
    fn masked_texture_gives_colour_of_opaque_part_and_its_coverage() {
        // A large triangle over the whole 2×1 texture, split evenly at u = 0.5 by symmetry:
        // corners (0,0), (1,0), (0,1) ... use a rectangle half: the left half of u is red.
        let surface = TriangleSurface {
            uv: [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0)],
            color: [Vec4::ONE; 3],
        };
        let img = Image { width: 64, height: 64, ..checker_image() };
        let img = Image {
            rgba: (0..64 * 64).flat_map(|i| if i % 64 < 32 { [255, 0, 0, 255] } else { [0, 0, 255, 0] }).collect(),
            ..img
        };
        let c = integrate(&material(AlphaMode::Mask), Some(&img), &surface);
        assert!((c.x - 1.0).abs() < 1e-6 && c.z == 0.0, "only red passes the alpha test: {c}");
        // The triangle's area with u < 0.5 is 3/4 of it.
        assert!((c.w - 0.75).abs() < 0.05, "coverage {}", c.w);
        let opaque = integrate(&material(AlphaMode::Opaque), Some(&img), &surface);
        assert_eq!(opaque.w, 1.0);
        assert!(opaque.z > 0.1, "opaque mode averages every texel");
    }

    #[test]
    fn factor_and_vertex_colours_multiply_in() {
        let m = Material { base_color: [0.5, 1.0, 1.0, 1.0], ..Material::default() };
        let surface = TriangleSurface { uv: [Vec2::ZERO; 3], color: [Vec4::new(1.0, 0.5, 1.0, 1.0); 3] };
        let c = integrate(&m, None, &surface);
        assert_eq!(c, Vec4::new(0.5, 0.5, 1.0, 1.0));
    }

    #[test]
    fn texture_coordinates_far_apart_still_give_a_finite_coverage() {
        let img = Image { width: 64, height: 64, ..checker_image() };
        let img = Image { rgba: vec![255; 64 * 64 * 4], ..img };
        let huge = 3e38;
        let surface = TriangleSurface {
            uv: [Vec2::new(-huge, 0.0), Vec2::new(huge, 0.0), Vec2::new(0.0, huge)],
            color: [Vec4::ONE; 3],
        };
        let c = integrate(&material(AlphaMode::Mask), Some(&img), &surface);
        assert!(c.is_finite(), "{c}");
    }

    #[test]
    fn srgb_conversions_round_trip() {
        let lut = srgb_to_linear_table();
        for i in [0usize, 1, 10, 128, 200, 255] {
            assert!((linear_to_srgb(lut[i]) * 255.0 - i as f32).abs() < 0.01);
        }
    }
}
