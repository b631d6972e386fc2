//! Image metrics of `treelod eval`, on the CPU and free of GPU types: coverage masks, pixel
//! Precision and Recall with Neubert 2011's quality `Q`, multi-scale RMSE along a z-order curve
//! (Clasen 2011 §4), and the box filter that resolves a supersampled reference.
//!
//! Colours are compared in **linear light**: 8-bit sRGB pixels are decoded to linear values in
//! `0..=1` per channel ([`LinearImage::from_srgba8`]), so the box filter and the coarser levels of
//! the multi-scale RMSE average light as a larger pixel would integrate it. Alpha is ignored (the
//! renderer's targets are opaque).
//!
//! ## Multi-scale RMSE
//!
//! For two `W×H` images `a` and `b` with the difference `d = a − b`, level `l` (`l = 0..=L`,
//! `L = ⌈log2 max(W, H)⌉`) divides the image into blocks of `2^l × 2^l` pixels aligned at the top
//! left; blocks at the right and bottom edges are clipped by the image (equivalently, the image is
//! padded to a `2^L × 2^L` square whose padding pixels are left out of every count). With `S_b`
//! the sum of `d` over the `n_b` image pixels of block `b` (per channel), the level's error is
//!
//! ```text
//! RMSE_l = sqrt( Σ_b |S_b|² / n_b  /  (3 · W · H) )
//! ```
//!
//! (`|·|²` sums the three colour channels): the RMSE over all pixels and channels of the
//! difference after each block has been replaced by its mean. Level 0 is the ordinary per-pixel
//! RMSE, level `L` compares the mean colours of the whole images; a constant offset `c` reads `c`
//! at every level. [`multiscale_rmse`] accumulates every level in one pass over the pixels in
//! z-order (Morton order), where every aligned block is a contiguous run, keeping one running sum
//! per level, as Clasen et al. do on the GPU. The summary is the mean of the `L + 1` levels, so
//! it is comparable only between images of the same size.

use std::fmt;

/// Two images or masks do not have the same size, or a size does not divide as asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SizeMismatch {
    /// The size expected, `(width, height)`.
    pub expected: (u32, u32),
    /// The size given.
    pub got: (u32, u32),
}

impl fmt::Display for SizeMismatch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "image sizes differ: {}x{} and {}x{}", self.expected.0, self.expected.1, self.got.0, self.got.1)
    }
}

impl std::error::Error for SizeMismatch {}

/// The linear value of an 8-bit sRGB-encoded channel (IEC 61966-2-1).
#[must_use]
pub fn srgb_to_linear(c: u8) -> f32 {
    let c = f64::from(c) / 255.0;
    (if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }) as f32
}

/// The 8-bit sRGB encoding of a linear value (clamped to `0..=1`), rounded to the nearest.
#[must_use]
pub fn linear_to_srgb(v: f32) -> u8 {
    let v = f64::from(v).clamp(0.0, 1.0);
    let c = if v <= 0.003_130_8 { v * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (c * 255.0).round().clamp(0.0, 255.0) as u8
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
    /// [`SizeMismatch`] if `rgba` does not hold `width · height · 4` bytes.
    pub fn from_srgba8(width: u32, height: u32, rgba: &[u8]) -> Result<Self, SizeMismatch> {
        check_bytes(width, height, rgba)?;
        let lut: Vec<f32> = (0..=255).map(srgb_to_linear).collect();
        let pixels = rgba
            .chunks_exact(4)
            .map(|p| [lut[usize::from(p[0])], lut[usize::from(p[1])], lut[usize::from(p[2])]])
            .collect();
        Ok(Self { width, height, pixels })
    }

    /// A `width×height` image of one colour.
    #[cfg(test)]
    #[must_use]
    pub fn filled(width: u32, height: u32, rgb: [f32; 3]) -> Self {
        Self { width, height, pixels: vec![rgb; width as usize * height as usize] }
    }

    /// The pixel at `(x, y)`; `None` outside the image.
    #[cfg(test)]
    #[must_use]
    pub fn get(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.pixels.get(y as usize * self.width as usize + x as usize).copied()
    }

    /// The image box-filtered down by `k` per side: each output pixel is the mean, in linear
    /// light, of the `k×k` input pixels it covers.
    ///
    /// # Errors
    /// [`SizeMismatch`] if `k` is 0 or does not divide both sides.
    pub fn box_filter(&self, k: u32) -> Result<Self, SizeMismatch> {
        let (width, height) = divided(self.width, self.height, k)?;
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
                pixels.push(sum.map(|s| (s * inverse) as f32));
            }
        }
        Ok(Self { width, height, pixels })
    }
}

/// `(width / k, height / k)`, or why not.
fn divided(width: u32, height: u32, k: u32) -> Result<(u32, u32), SizeMismatch> {
    if k == 0 || !width.is_multiple_of(k) || !height.is_multiple_of(k) {
        let (w, h) = if k == 0 { (0, 0) } else { (width.div_ceil(k) * k, height.div_ceil(k) * k) };
        return Err(SizeMismatch { expected: (w, h), got: (width, height) });
    }
    Ok((width / k, height / k))
}

/// Checks that `rgba` holds `width · height` RGBA8 pixels.
fn check_bytes(width: u32, height: u32, rgba: &[u8]) -> Result<(), SizeMismatch> {
    let pixels = width as usize * height as usize;
    if rgba.len() != pixels * 4 {
        let got = u32::try_from(rgba.len() / 4).unwrap_or(u32::MAX);
        return Err(SizeMismatch { expected: (width, height), got: (got, 1) });
    }
    Ok(())
}

/// Which pixels an image covers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mask {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// `width · height` flags, rows top to bottom: `true` where something was drawn.
    pub covered: Vec<bool>,
}

impl Mask {
    /// The coverage of an RGBA8 image rendered over `background` (its 8-bit sRGB colour): a pixel
    /// is covered when its RGB differs from the background in any channel (alpha ignored). A
    /// drawn pixel of exactly the background colour counts as not covered.
    ///
    /// # Errors
    /// [`SizeMismatch`] if `rgba` does not hold `width · height · 4` bytes.
    pub fn from_srgba8(width: u32, height: u32, rgba: &[u8], background: [u8; 3]) -> Result<Self, SizeMismatch> {
        check_bytes(width, height, rgba)?;
        let covered = rgba.chunks_exact(4).map(|p| p[..3] != background).collect();
        Ok(Self { width, height, covered })
    }

    /// The mask reduced by `k` per side: an output pixel is covered when at least half of its
    /// `k×k` input pixels are (for `k = 1`, the mask itself). This approximates what a renderer
    /// sampling pixel centres at the smaller size covers, without the dilation of "any".
    ///
    /// # Errors
    /// [`SizeMismatch`] if `k` is 0 or does not divide both sides.
    pub fn reduce_majority(&self, k: u32) -> Result<Self, SizeMismatch> {
        let (width, height) = divided(self.width, self.height, k)?;
        let mut covered = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                let mut count = 0u64;
                for sy in 0..k {
                    let row = (y * k + sy) as usize * self.width as usize;
                    count += (0..k).filter(|&sx| self.covered[row + (x * k + sx) as usize]).count() as u64;
                }
                covered.push(2 * count >= u64::from(k * k));
            }
        }
        Ok(Self { width, height, covered })
    }
}

/// Pixel classification of a sample's coverage against the reference's (Neubert 2011, Table 1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Coverage {
    /// True positives: covered in both.
    pub tp: u64,
    /// False positives: covered by the sample only.
    pub fp: u64,
    /// False negatives: covered by the reference only.
    pub fn_: u64,
}

impl Coverage {
    /// Counts the pixels of `sample` against `reference`.
    ///
    /// # Errors
    /// [`SizeMismatch`] if the masks differ in size.
    pub fn compare(reference: &Mask, sample: &Mask) -> Result<Self, SizeMismatch> {
        if (reference.width, reference.height) != (sample.width, sample.height) {
            return Err(SizeMismatch {
                expected: (reference.width, reference.height),
                got: (sample.width, sample.height),
            });
        }
        let mut counts = Self::default();
        for (&r, &s) in reference.covered.iter().zip(&sample.covered) {
            match (r, s) {
                (true, true) => counts.tp += 1,
                (false, true) => counts.fp += 1,
                (true, false) => counts.fn_ += 1,
                (false, false) => {}
            }
        }
        Ok(counts)
    }

    /// Precision `P = TP / (TP + FP)`; 1 when the sample covers nothing (nothing drawn wrongly).
    #[must_use]
    pub fn precision(&self) -> f64 {
        ratio(self.tp, self.tp + self.fp)
    }

    /// Recall `R = TP / (TP + FN)`; 1 when the reference covers nothing (nothing missed).
    #[must_use]
    pub fn recall(&self) -> f64 {
        ratio(self.tp, self.tp + self.fn_)
    }

    /// Neubert's quality `Q = 1 − ‖(1 − P, 1 − R)‖`: 1 when both are perfect, `1 − √2` at worst.
    #[must_use]
    pub fn quality(&self) -> f64 {
        quality(self.precision(), self.recall())
    }
}

/// `Q = 1 − sqrt((1 − P)² + (1 − R)²)` (Neubert 2011, eq. 4).
#[must_use]
pub fn quality(precision: f64, recall: f64) -> f64 {
    1.0 - (1.0 - precision).hypot(1.0 - recall)
}

/// `n / d`, 1 when `d` is 0.
fn ratio(n: u64, d: u64) -> f64 {
    if d == 0 { 1.0 } else { n as f64 / d as f64 }
}

/// The multi-scale RMSE of two images (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct MultiScaleRmse {
    /// `RMSE_l` for `l = 0..=L`: blocks of 1, 2, 4, … `2^L` pixels per side.
    pub levels: Vec<f64>,
}

impl MultiScaleRmse {
    /// The summary: the mean of [`Self::levels`] (0 if there are none).
    #[must_use]
    pub fn summary(&self) -> f64 {
        if self.levels.is_empty() { 0.0 } else { self.levels.iter().sum::<f64>() / self.levels.len() as f64 }
    }
}

/// Levels of the multi-scale RMSE of a `width×height` image: `⌈log2 max(width, height)⌉ + 1`.
#[must_use]
pub fn level_count(width: u32, height: u32) -> usize {
    u64::from(width.max(height).max(1)).next_power_of_two().trailing_zeros() as usize + 1
}

/// The x and y of the `index`-th pixel of the z-order curve (x in the even bits, y in the odd).
#[must_use]
pub fn morton_decode(index: u64) -> (u32, u32) {
    /// Gathers the even bits of `v` into the low half.
    fn compact(mut v: u64) -> u32 {
        v &= 0x5555_5555_5555_5555;
        v = (v | (v >> 1)) & 0x3333_3333_3333_3333;
        v = (v | (v >> 2)) & 0x0f0f_0f0f_0f0f_0f0f;
        v = (v | (v >> 4)) & 0x00ff_00ff_00ff_00ff;
        v = (v | (v >> 8)) & 0x0000_ffff_0000_ffff;
        v = (v | (v >> 16)) & 0x0000_0000_ffff_ffff;
        v as u32
    }
    (compact(index), compact(index >> 1))
}

/// The multi-scale RMSE of `a` against `b`, every level accumulated in one pass along the
/// z-order curve over the image padded to a power-of-two square (padding skipped a whole aligned
/// block at a time).
///
/// # Errors
/// [`SizeMismatch`] if the images differ in size.
pub fn multiscale_rmse(a: &LinearImage, b: &LinearImage) -> Result<MultiScaleRmse, SizeMismatch> {
    if (a.width, a.height) != (b.width, b.height) || a.pixels.len() != b.pixels.len() {
        return Err(SizeMismatch { expected: (a.width, a.height), got: (b.width, b.height) });
    }
    let (width, height) = (a.width, a.height);
    let levels = level_count(width, height);
    let top = levels - 1;
    let end = 1u64 << (2 * top);
    // Per level: closed blocks' Σ |S_b|² / n_b; the open block's sum and pixel count.
    let mut accumulated = vec![0.0f64; levels];
    let mut open_sum = vec![[0.0f64; 3]; levels];
    let mut open_count = vec![0u64; levels];
    let mut index = 0u64;
    while index < end {
        let (x, y) = morton_decode(index);
        let step = if x < width && y < height {
            let i = y as usize * width as usize + x as usize;
            let (p, q) = (a.pixels[i], b.pixels[i]);
            let d = [0, 1, 2].map(|c| f64::from(p[c]) - f64::from(q[c]));
            accumulated[0] += d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            if top > 0 {
                for c in 0..3 {
                    open_sum[1][c] += d[c];
                }
                open_count[1] += 1;
            }
            1
        } else {
            // Every pixel of an aligned block starting here lies at or beyond (x, y), so outside:
            // skip the largest such block.
            let aligned = (index.trailing_zeros() / 2).min(top as u32);
            1u64 << (2 * aligned)
        };
        index += step;
        // Close every level whose block ends here, passing its sum on to the next level.
        for level in 1..=top {
            if !index.is_multiple_of(1u64 << (2 * level)) {
                break;
            }
            let (sum, count) = (open_sum[level], open_count[level]);
            if count > 0 {
                accumulated[level] += (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]) / count as f64;
                if level < top {
                    for c in 0..3 {
                        open_sum[level + 1][c] += sum[c];
                    }
                    open_count[level + 1] += count;
                }
            }
            open_sum[level] = [0.0; 3];
            open_count[level] = 0;
        }
    }
    let samples = 3.0 * width as f64 * height as f64;
    let levels = accumulated.iter().map(|&e| if samples > 0.0 { (e / samples).max(0.0).sqrt() } else { 0.0 }).collect();
    Ok(MultiScaleRmse { levels })
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// The multi-scale RMSE computed directly, level by level, block by block.
    fn naive_rmse(a: &LinearImage, b: &LinearImage) -> Vec<f64> {
        let (w, h) = (a.width, a.height);
        (0..level_count(w, h))
            .map(|level| {
                let side = 1u32 << level;
                let mut total = 0.0;
                for by in 0..h.div_ceil(side) {
                    for bx in 0..w.div_ceil(side) {
                        let (mut sum, mut n) = ([0.0f64; 3], 0u32);
                        for y in by * side..((by + 1) * side).min(h) {
                            for x in bx * side..((bx + 1) * side).min(w) {
                                let (p, q) = (a.get(x, y).expect("inside"), b.get(x, y).expect("inside"));
                                for c in 0..3 {
                                    sum[c] += f64::from(p[c]) - f64::from(q[c]);
                                }
                                n += 1;
                            }
                        }
                        total += sum.iter().map(|s| s * s).sum::<f64>() / f64::from(n);
                    }
                }
                (total / (3.0 * f64::from(w) * f64::from(h))).sqrt()
            })
            .collect()
    }

    fn mask(width: u32, rows: &[&str]) -> Mask {
        let covered: Vec<bool> = rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect();
        assert_eq!(covered.len(), width as usize * rows.len());
        Mask { width, height: rows.len() as u32, covered }
    }

    #[test]
    fn precision_and_recall_of_two_hand_made_masks() {
        let reference = mask(4, &["##..", "##..", "....", "...."]);
        let sample = mask(4, &["#...", "##.#", "...#", "...."]);
        let c = Coverage::compare(&reference, &sample).expect("same size");
        assert_eq!(c, Coverage { tp: 3, fp: 2, fn_: 1 });
        assert!((c.precision() - 0.6).abs() < 1e-12 && (c.recall() - 0.75).abs() < 1e-12);
        let q = 1.0 - (0.4f64 * 0.4 + 0.25 * 0.25).sqrt();
        assert!((c.quality() - q).abs() < 1e-12, "{}", c.quality());
        // Identical masks are perfect; empty ones too (nothing to miss, nothing wrong).
        let same = Coverage::compare(&reference, &reference).expect("same size");
        assert_eq!((same.precision(), same.recall(), same.quality()), (1.0, 1.0, 1.0));
        let empty = mask(2, &["..", ".."]);
        assert_eq!(Coverage::compare(&empty, &empty).expect("same size").quality(), 1.0);
        // Disjoint: P = R = 0, the worst Q.
        let other = mask(4, &["..##", "..##", "....", "...."]);
        let worst = Coverage::compare(&reference, &other).expect("same size");
        assert_eq!((worst.precision(), worst.recall()), (0.0, 0.0));
        assert!((worst.quality() - (1.0 - 2f64.sqrt())).abs() < 1e-12);
        assert!(Coverage::compare(&reference, &empty).is_err());
    }

    #[test]
    fn masks_come_from_the_background_colour_and_reduce_by_majority() {
        let bg = [255, 255, 255];
        let rgba = [255, 255, 255, 255, 254, 255, 255, 255, 0, 0, 0, 255, 255, 255, 255, 0];
        let m = Mask::from_srgba8(2, 2, &rgba, bg).expect("4 pixels");
        assert_eq!(m.covered, [false, true, true, false], "alpha is ignored");
        assert_eq!(m.reduce_majority(2).expect("divides").covered, [true], "2 of 4 is half");
        let one = Mask { width: 2, height: 2, covered: vec![true, false, false, false] };
        assert_eq!(one.reduce_majority(2).expect("divides").covered, [false]);
        assert_eq!(one.reduce_majority(1).expect("divides"), one);
        assert!(one.reduce_majority(3).is_err() && one.reduce_majority(0).is_err());
        assert!(Mask::from_srgba8(2, 2, &rgba[..12], bg).is_err());
    }

    #[test]
    fn the_box_filter_averages_linear_light() {
        let mut image = LinearImage::filled(4, 2, [0.0; 3]);
        image.pixels[0] = [1.0, 0.5, 0.25];
        image.pixels[5] = [1.0, 0.5, 0.25];
        let small = image.box_filter(2).expect("divides");
        assert_eq!((small.width, small.height), (2, 1));
        assert_eq!(small.pixels, [[0.5, 0.25, 0.125], [0.0; 3]]);
        assert!(image.box_filter(3).is_err());
        // sRGB round trip of every byte, and the decode of the ends and middle grey.
        assert!((0..=255).all(|c| linear_to_srgb(srgb_to_linear(c)) == c));
        assert_eq!((srgb_to_linear(0), srgb_to_linear(255)), (0.0, 1.0));
        assert!((srgb_to_linear(188) - 0.5).abs() < 0.003);
    }

    #[test]
    fn a_constant_offset_reads_the_offset_at_every_scale() {
        for (w, h) in [(8, 8), (13, 5), (1, 1), (1, 9), (128, 96)] {
            let a = LinearImage::filled(w, h, [0.5, 0.25, 0.75]);
            let b = LinearImage::filled(w, h, [0.4, 0.15, 0.65]);
            let rmse = multiscale_rmse(&a, &b).expect("same size");
            assert_eq!(rmse.levels.len(), level_count(w, h));
            for (level, e) in rmse.levels.iter().enumerate() {
                assert!((e - 0.1).abs() < 1e-6, "{w}x{h} level {level}: {e}");
            }
            assert!((rmse.summary() - 0.1).abs() < 1e-6);
            let zero = multiscale_rmse(&a, &a).expect("same size");
            assert!(zero.levels.iter().all(|e| *e == 0.0) && zero.summary() == 0.0);
        }
        assert_eq!(level_count(128, 96), 8);
        assert_eq!(level_count(1, 1), 1);
        assert_eq!(level_count(3, 2), 3);
    }

    #[test]
    fn fine_noise_fades_at_coarse_scales() {
        // A checkerboard of ±0.2: every pixel is off by 0.2, every 2×2 block and above by 0.
        let a = LinearImage::filled(8, 8, [0.5; 3]);
        let mut b = a.clone();
        for (i, p) in b.pixels.iter_mut().enumerate() {
            let (x, y) = (i % 8, i / 8);
            *p = if (x + y) % 2 == 0 { [0.7; 3] } else { [0.3; 3] };
        }
        let rmse = multiscale_rmse(&a, &b).expect("same size");
        assert!((rmse.levels[0] - 0.2).abs() < 1e-6, "{:?}", rmse.levels);
        assert!(rmse.levels[1..].iter().all(|e| e.abs() < 1e-6), "{:?}", rmse.levels);
    }

    #[test]
    fn the_z_order_curve_visits_aligned_blocks_in_turn() {
        let order: Vec<(u32, u32)> = (0..16).map(morton_decode).collect();
        assert_eq!(&order[..8], &[(0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (3, 0), (2, 1), (3, 1)]);
        assert_eq!(order[15], (3, 3));
        assert_eq!(morton_decode((1 << 40) - 1), ((1 << 20) - 1, (1 << 20) - 1));
    }

    #[test]
    fn z_order_accumulation_equals_the_naive_per_level_computation() {
        let (w, h) = (11, 6);
        let a = LinearImage {
            width: w,
            height: h,
            pixels: (0..w * h)
                .map(|i| [(i % 7) as f32 / 7.0, (i % 3) as f32 / 3.0, (i * i % 11) as f32 / 11.0])
                .collect(),
        };
        let b = LinearImage::filled(w, h, [0.3, 0.6, 0.1]);
        let fast = multiscale_rmse(&a, &b).expect("same size");
        let slow = naive_rmse(&a, &b);
        assert_eq!(fast.levels.len(), slow.len());
        for (f, s) in fast.levels.iter().zip(&slow) {
            assert!((f - s).abs() < 1e-9, "{:?} vs {slow:?}", fast.levels);
        }
        assert!(multiscale_rmse(&a, &LinearImage::filled(w, h + 1, [0.0; 3])).is_err());
    }

    fn image(width: u32, height: u32) -> impl Strategy<Value = LinearImage> {
        proptest::collection::vec(proptest::array::uniform3(0.0f32..=1.0), (width * height) as usize)
            .prop_map(move |pixels| LinearImage { width, height, pixels })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn z_order_equals_naive_on_random_images(
            (a, b) in (1u32..=24, 1u32..=24).prop_flat_map(|(w, h)| (image(w, h), image(w, h)))
        ) {
            let fast = multiscale_rmse(&a, &b).expect("same size");
            let slow = naive_rmse(&a, &b);
            prop_assert_eq!(fast.levels.len(), slow.len());
            for (f, s) in fast.levels.iter().zip(&slow) {
                prop_assert!((f - s).abs() < 1e-9, "{:?} vs {:?}", fast.levels, slow);
            }
            // A block's mean is never further off than its quarters' (Cauchy–Schwarz): coarser
            // levels never read more than finer ones.
            prop_assert!(fast.levels.windows(2).all(|pair| pair[1] <= pair[0] + 1e-9), "{:?}", fast.levels);
        }
    }
}
