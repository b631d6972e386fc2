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
/// # Errors
/// [`MetricError::SizeMismatch`] if a buffer does not hold `width · height · 3` bytes;
/// [`MetricError::Empty`] for an image without pixels.
pub fn mean_flip_srgb8(width: u32, height: u32, sample: &[u8], reference: &[u8]) -> Result<f64, MetricError> {
    check_bytes(width, height, sample, 3)?;
    check_bytes(width, height, reference, 3)?;
    if width == 0 || height == 0 {
        return Err(MetricError::Empty { width, height });
    }
    let reference = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let sample = nv_flip::FlipImageRgb8::with_data(width, height, sample);
    let errors = nv_flip::flip(reference, sample, PIXELS_PER_DEGREE).to_vec();
    #[expect(clippy::cast_precision_loss, reason = "pixel counts far below 2^53")]
    let n = errors.len() as f64;
    Ok(errors.iter().map(|&e| f64::from(e)).sum::<f64>() / n)
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
