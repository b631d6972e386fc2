//! FLIP (Andersson et al. 2020, "FLIP: A Difference Evaluator for Alternating Images"): NVIDIA's
//! perceptual difference of a sample image against a reference, through the `nv-flip` crate
//! (the same library wgpu's image tests use). Only with the cargo feature `flip`.

use super::{LinearImage, check_bytes, same_size};
use crate::MetricError;

/// The viewing condition FLIP is evaluated for, in pixels per degree of visual angle: `nv-flip`'s
/// default, a 0.7 m wide monitor of 3840 pixels seen from 0.7 m (about 67).
pub const PIXELS_PER_DEGREE: f32 = nv_flip::DEFAULT_PIXELS_PER_DEGREE;

/// The mean over pixels of the LDR-FLIP error map of `sample` against `reference`, both
/// `width×height` 8-bit sRGB images of three bytes per pixel, rows top to bottom: 0 for identical
/// images, at most 1. The mean is summed in `f64` in pixel order, so it is deterministic.
///
/// Only the pixels that can differ are evaluated: FLIP's filters reach [`FILTER_REACH`] pixels,
/// so a pixel whose surroundings within that reach are the same in both images reads exactly 0.
/// The map is computed over the box of the differing pixels grown by twice the reach (every pixel
/// that can read above 0 then sees what it sees in the whole image, and the rest see no
/// difference) and summed over it, in pixel order, with the zeros outside added as nothing: the
/// same number, to the bit, as the whole map's mean (tested), at the cost of the box. A
/// calibration image or an `eval` frame is mostly background around a tree.
///
/// # Errors
/// [`MetricError::SizeMismatch`] if a buffer does not hold `width · height · 3` bytes;
/// [`MetricError::Empty`] for an image without pixels.
pub fn mean_flip_srgb8(width: u32, height: u32, sample: &[u8], reference: &[u8]) -> Result<f64, MetricError> {
    check_bytes(width, height, sample, 3)?;
    check_bytes(width, height, reference, 3)?;
    if width == 0 || height == 0 {
        return Err(MetricError::Empty { width, height });
    }
    #[expect(clippy::cast_precision_loss, reason = "pixel counts far below 2^53")]
    let n = (u64::from(width) * u64::from(height)) as f64;
    let Some([x0, y0, x1, y1]) = differing_box(width, sample, reference) else {
        return Ok(0.0); // identical images: every pixel reads 0
    };
    let grow = 2 * FILTER_REACH;
    let (x0, y0) = (x0.saturating_sub(grow), y0.saturating_sub(grow));
    let (x1, y1) = ((x1 + grow).min(width - 1), (y1 + grow).min(height - 1));
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let crop = |image: &[u8]| -> Vec<u8> {
        if (w, h) == (width, height) {
            return image.to_vec();
        }
        let row = |y: u32| {
            let at = 3 * (y as usize * width as usize + x0 as usize);
            &image[at..at + 3 * w as usize]
        };
        (y0..=y1).flat_map(row).copied().collect()
    };
    let reference = nv_flip::FlipImageRgb8::with_data(w, h, &crop(reference));
    let sample = nv_flip::FlipImageRgb8::with_data(w, h, &crop(sample));
    let errors = nv_flip::flip(reference, sample, PIXELS_PER_DEGREE).to_vec();
    Ok(errors.iter().map(|&e| f64::from(e)).sum::<f64>() / n)
}

/// How far FLIP's filters reach at [`PIXELS_PER_DEGREE`], pixels: the larger of the radius of its
/// colour pipeline's spatial filter, `⌈3·√(0.04 / 2π²)·ppd⌉` (0.04 its largest scale parameter),
/// and of its feature filters, `⌈3 · ½·0.082·ppd⌉` (`nv-flip`'s `calculateSpatialFilterRadius`
/// and `setFeatureFilter`): 10 and 9.
pub const FILTER_REACH: u32 = 10;

/// The box `[x0, y0, x1, y1]` (inclusive) of the pixels that differ between two images of
/// `width` pixels per row, three bytes per pixel; `None` if none does.
fn differing_box(width: u32, a: &[u8], b: &[u8]) -> Option<[u32; 4]> {
    let row_bytes = 3 * width as usize;
    let mut bounds: Option<[u32; 4]> = None;
    for (y, (ra, rb)) in a.chunks_exact(row_bytes).zip(b.chunks_exact(row_bytes)).enumerate() {
        if ra == rb {
            continue;
        }
        let first = ra.chunks_exact(3).zip(rb.chunks_exact(3)).position(|(p, q)| p != q)?;
        let last = ra.chunks_exact(3).zip(rb.chunks_exact(3)).rposition(|(p, q)| p != q)?;
        #[expect(clippy::cast_possible_truncation, reason = "indices within a u32 width and height")]
        let (first, last, y) = (first as u32, last as u32, y as u32);
        bounds = Some(match bounds {
            None => [first, y, last, y],
            Some([x0, y0, x1, _]) => [x0.min(first), y0, x1.max(last), y],
        });
    }
    bounds
}

/// [`mean_flip_srgb8`] of two linear-light images, each encoded to 8-bit sRGB first
/// ([`LinearImage::to_srgb8`]).
///
/// # Errors
/// [`MetricError::SizeMismatch`] if the images differ in size or their pixels do not match it;
/// [`MetricError::Empty`] for an image without pixels.
pub fn mean_flip(sample: &LinearImage, reference: &LinearImage) -> Result<f64, MetricError> {
    same_size((reference.width, reference.height), (sample.width, sample.height))?;
    mean_flip_srgb8(sample.width, sample.height, &sample.to_srgb8(), &reference.to_srgb8())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_read_zero_and_different_ones_more() {
        let mut reference = LinearImage::filled(32, 24, [0.8, 0.9, 1.0]);
        for (i, p) in reference.pixels.iter_mut().enumerate() {
            if (i % 32) / 4 % 2 == 0 && i / 32 > 6 {
                *p = [0.05, 0.2, 0.02];
            }
        }
        assert_eq!(mean_flip(&reference, &reference), Ok(0.0));
        // A leaf-green square drawn over the sky.
        let mut sample = reference.clone();
        for y in 2..10 {
            for x in 10..20 {
                sample.pixels[y * 32 + x] = [0.05, 0.3, 0.02];
            }
        }
        let error = mean_flip(&sample, &reference).expect("same size");
        assert!(error > 0.01 && error <= 1.0, "{error}");
        // Deterministic, and a larger change reads more.
        assert_eq!(mean_flip(&sample, &reference), Ok(error));
        let black = LinearImage::filled(32, 24, [0.0; 3]);
        assert!(mean_flip(&black, &reference).expect("same size") > error);
    }

    /// The whole map's mean, as `mean_flip_srgb8` computed it before it evaluated only the box.
    fn whole_map_mean(width: u32, height: u32, sample: &[u8], reference: &[u8]) -> f64 {
        let reference = nv_flip::FlipImageRgb8::with_data(width, height, reference);
        let sample = nv_flip::FlipImageRgb8::with_data(width, height, sample);
        let errors = nv_flip::flip(reference, sample, PIXELS_PER_DEGREE).to_vec();
        errors.iter().map(|&e| f64::from(e)).sum::<f64>() / errors.len() as f64
    }

    #[test]
    fn the_filters_reach_is_nv_flips() {
        let ppd = f64::from(PIXELS_PER_DEGREE);
        let pi_sq = std::f64::consts::PI * std::f64::consts::PI;
        let spatial = (3.0 * (0.04 / (2.0 * pi_sq)).sqrt() * ppd).ceil();
        let feature = (3.0 * 0.5 * 0.082 * ppd).ceil();
        assert_eq!(f64::from(FILTER_REACH), spatial.max(feature), "spatial {spatial}, feature {feature}");
    }

    #[test]
    fn the_mean_over_the_differing_box_is_the_whole_maps_to_the_bit() {
        let (width, height) = (160u32, 120u32);
        // A sky-blue background with a textured "crown" (the reference) and, in the sample, that
        // crown changed here and there: patches in the middle, at the borders and corners, and
        // single pixels.
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let mut reference = vec![0u8; (3 * width * height) as usize];
        for (i, p) in reference.chunks_exact_mut(3).enumerate() {
            let (x, y) = (i as u32 % width, i as u32 / width);
            let crown = (x as i32 - 80).pow(2) + (y as i32 - 60).pow(2) < 40 * 40;
            let v = next();
            p.copy_from_slice(&if crown {
                [20 + (v % 60) as u8, 90 + (v >> 8) as u8 % 80, 20]
            } else {
                [200, 220, 255]
            });
        }
        let changes: [&[(u32, u32, u32, u32)]; 6] = [
            &[(70, 50, 8, 6)],
            &[(0, 0, 3, 3)],
            &[(155, 115, 5, 5)],
            &[(0, 60, 2, 1), (159, 10, 1, 1)],
            &[(80, 0, 1, 1)],
            &[(30, 30, 1, 1), (120, 90, 1, 1)],
        ];
        for patches in changes {
            let mut sample = reference.clone();
            for &(x0, y0, w, h) in patches {
                for y in y0..(y0 + h).min(height) {
                    for x in x0..(x0 + w).min(width) {
                        let at = 3 * (y * width + x) as usize;
                        let v = next();
                        sample[at..at + 3].copy_from_slice(&[v as u8, (v >> 8) as u8, (v >> 16) as u8]);
                    }
                }
            }
            let whole = whole_map_mean(width, height, &sample, &reference);
            let boxed = mean_flip_srgb8(width, height, &sample, &reference).expect("same size");
            assert!(whole > 0.0, "{patches:?}");
            assert_eq!(boxed.to_bits(), whole.to_bits(), "{patches:?}: {boxed} against {whole}");
        }
        assert_eq!(mean_flip_srgb8(width, height, &reference, &reference), Ok(0.0));
        assert_eq!(whole_map_mean(width, height, &reference, &reference), 0.0);
    }

    #[test]
    fn bad_sizes_are_errors() {
        let a = LinearImage::filled(4, 4, [0.0; 3]);
        assert!(mean_flip(&a, &LinearImage::filled(4, 3, [0.0; 3])).is_err());
        let mut short = a.clone();
        short.pixels.pop();
        assert!(mean_flip(&short, &a).is_err());
        assert_eq!(mean_flip_srgb8(0, 0, &[], &[]), Err(MetricError::Empty { width: 0, height: 0 }));
        assert!(mean_flip_srgb8(2, 2, &[0; 12], &[0; 11]).is_err());
    }
}
