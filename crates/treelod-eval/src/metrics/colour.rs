//! Linear-light colour images: sRGB decoding and encoding, and the box filter that resolves a
//! supersampled reference.
//!
//! Colours are compared in **linear light**: 8-bit sRGB pixels are decoded to linear values in
//! `0..=1` per channel ([`LinearImage::from_srgba8`]), so the box filter and the coarser levels of
//! the multi-scale RMSE average light as a larger pixel would integrate it. Alpha is ignored (the
//! renderer's targets are opaque).

use super::{check_bytes, divided};
use crate::MetricError;

/// The linear value of an 8-bit sRGB-encoded channel (IEC 61966-2-1).
#[must_use]
pub fn srgb_to_linear(c: u8) -> f32 {
    let c = f64::from(c) / 255.0;
    #[expect(clippy::cast_possible_truncation, reason = "a value in 0..=1")]
    let linear = (if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }) as f32;
    linear
}

/// The 8-bit sRGB encoding of a linear value (clamped to `0..=1`), rounded to the nearest.
#[must_use]
pub fn linear_to_srgb(v: f32) -> u8 {
    let v = f64::from(v).clamp(0.0, 1.0);
    let c = if v <= 0.003_130_8 { v * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 0..=255")]
    let byte = (c * 255.0).round().clamp(0.0, 255.0) as u8;
    byte
}

/// A linear-light RGB image.
#[derive(Clone, Debug, PartialEq)]
pub struct LinearImage {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// `width · height` pixels, rows top to bottom, linear RGB in `0..=1`.
    pub pixels: Vec<[f32; 3]>,
}

impl LinearImage {
    /// Decodes `width·height` RGBA8 sRGB pixels (alpha ignored).
    ///
    /// # Errors
    /// [`MetricError::SizeMismatch`] if `rgba` does not hold `width · height · 4` bytes.
    pub fn from_srgba8(width: u32, height: u32, rgba: &[u8]) -> Result<Self, MetricError> {
        check_bytes(width, height, rgba, 4)?;
        let lut: Vec<f32> = (0..=255).map(srgb_to_linear).collect();
        let pixels = rgba
            .chunks_exact(4)
            .map(|p| [lut[usize::from(p[0])], lut[usize::from(p[1])], lut[usize::from(p[2])]])
            .collect();
        Ok(Self { width, height, pixels })
    }

    /// A `width×height` image of one colour.
    #[must_use]
    pub fn filled(width: u32, height: u32, rgb: [f32; 3]) -> Self {
        Self { width, height, pixels: vec![rgb; width as usize * height as usize] }
    }

    /// The pixel at `(x, y)`; `None` outside the image.
    #[must_use]
    pub fn get(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.pixels.get(y as usize * self.width as usize + x as usize).copied()
    }

    /// The image encoded as 8-bit sRGB, three bytes per pixel, rows top to bottom
    /// ([`linear_to_srgb`] per channel).
    #[must_use]
    pub fn to_srgb8(&self) -> Vec<u8> {
        self.pixels.iter().flat_map(|p| p.map(linear_to_srgb)).collect()
    }

    /// The image box-filtered down by `k` per side: each output pixel is the mean, in linear
    /// light, of the `k×k` input pixels it covers.
    ///
    /// # Errors
    /// [`MetricError::BadFactor`] if `k` is 0 or does not divide both sides;
    /// [`MetricError::SizeMismatch`] if the pixels do not match the size.
    pub fn box_filter(&self, k: u32) -> Result<Self, MetricError> {
        let (width, height) = divided(self.width, self.height, k)?;
        super::same_size((self.width, self.height), pixel_size(self.pixels.len(), self.width))?;
        let inverse = 1.0 / f64::from(k * k);
        let mut pixels = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                let mut sum = [0.0f64; 3];
                for sy in 0..k {
                    let row = (y * k + sy) as usize * self.width as usize;
                    for sx in 0..k {
                        let p = self.pixels[row + (x * k + sx) as usize];
                        for c in 0..3 {
                            sum[c] += f64::from(p[c]);
                        }
                    }
                }
                #[expect(clippy::cast_possible_truncation, reason = "a mean of values in 0..=1")]
                pixels.push(sum.map(|s| (s * inverse) as f32));
            }
        }
        Ok(Self { width, height, pixels })
    }
}

/// The `(width, height)` that `len` pixels in rows of `width` make, for size checks: the true
/// size when `len` is a multiple of `width`, else one that differs from any stated size.
pub(super) fn pixel_size(len: usize, width: u32) -> (u32, u32) {
    let w = width.max(1) as usize;
    let height = u32::try_from(len / w).unwrap_or(u32::MAX);
    if len.is_multiple_of(w) { (width, height) } else { (u32::MAX, u32::MAX) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_box_filter_averages_linear_light() {
        let mut image = LinearImage::filled(4, 2, [0.0; 3]);
        image.pixels[0] = [1.0, 0.5, 0.25];
        image.pixels[5] = [1.0, 0.5, 0.25];
        let small = image.box_filter(2).expect("divides");
        assert_eq!((small.width, small.height), (2, 1));
        assert_eq!(small.pixels, [[0.5, 0.25, 0.125], [0.0; 3]]);
        assert_eq!(image.box_filter(3), Err(MetricError::BadFactor { width: 4, height: 2, factor: 3 }));
        assert!(image.box_filter(0).is_err());
        let mut short = image.clone();
        short.pixels.pop();
        assert!(short.box_filter(1).is_err(), "pixels that do not match the size");
    }

    #[test]
    fn srgb_round_trips_every_byte() {
        assert!((0..=255).all(|c| linear_to_srgb(srgb_to_linear(c)) == c));
        assert_eq!((srgb_to_linear(0), srgb_to_linear(255)), (0.0, 1.0));
        assert!((srgb_to_linear(188) - 0.5).abs() < 0.003);
        let image = LinearImage::from_srgba8(2, 1, &[0, 128, 255, 7, 10, 20, 30, 0]).expect("2 pixels");
        assert_eq!(image.to_srgb8(), [0, 128, 255, 10, 20, 30]);
        assert!(LinearImage::from_srgba8(2, 2, &[0; 12]).is_err());
    }
}
