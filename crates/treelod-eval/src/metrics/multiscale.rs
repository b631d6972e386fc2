//! Multi-scale RMSE (Clasen et al. 2011 §4) and temporal noise; the definition is in the
//! [module documentation](super).

use super::colour::pixel_size;
use super::{LinearImage, Mask, same_size};
use crate::MetricError;

/// The multi-scale RMSE of two images: one RMSE per level of block size.
#[derive(Clone, Debug, PartialEq)]
pub struct MultiScaleRmse {
    /// `RMSE_l` for `l = 0..=L`: blocks of 1, 2, 4, … `2^L` pixels per side, the last the whole
    /// image.
    pub levels: Vec<f64>,
}

impl MultiScaleRmse {
    /// The summary: the mean of [`Self::levels`] (0 if there are none).
    #[must_use]
    pub fn summary(&self) -> f64 {
        #[expect(clippy::cast_precision_loss, reason = "at most 33 levels")]
        let n = self.levels.len() as f64;
        if self.levels.is_empty() { 0.0 } else { self.levels.iter().sum::<f64>() / n }
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
        #[expect(clippy::cast_possible_truncation, reason = "32 bits gathered")]
        let low = v as u32;
        low
    }
    (compact(index), compact(index >> 1))
}

/// The multi-scale RMSE of the colour image `a` against `b` (three channels), every level
/// accumulated in one pass along the z-order curve.
///
/// # Errors
/// [`MetricError::SizeMismatch`] if the images differ in size or their pixels do not match it.
pub fn multiscale_rmse(a: &LinearImage, b: &LinearImage) -> Result<MultiScaleRmse, MetricError> {
    same_size((a.width, a.height), (b.width, b.height))?;
    same_size((a.width, a.height), pixel_size(a.pixels.len(), a.width))?;
    same_size((b.width, b.height), pixel_size(b.pixels.len(), b.width))?;
    Ok(z_order(a.width, a.height, |i| {
        let (p, q) = (a.pixels[i], b.pixels[i]);
        [0, 1, 2].map(|c| f64::from(p[c]) - f64::from(q[c]))
    }))
}

/// The multi-scale RMSE of the coverage `sample` against `reference` as images of 0 and 1 (one
/// channel), every level accumulated in one pass along the z-order curve.
///
/// # Errors
/// [`MetricError::SizeMismatch`] if the masks differ in size or their flags do not match it.
pub fn coverage_multiscale_rmse(sample: &Mask, reference: &Mask) -> Result<MultiScaleRmse, MetricError> {
    same_size((reference.width, reference.height), (sample.width, sample.height))?;
    same_size((sample.width, sample.height), pixel_size(sample.covered.len(), sample.width))?;
    same_size((reference.width, reference.height), pixel_size(reference.covered.len(), reference.width))?;
    Ok(z_order(sample.width, sample.height, |i| {
        [f64::from(i8::from(sample.covered[i]) - i8::from(reference.covered[i]))]
    }))
}

/// The temporal noise of a frame: the multi-scale RMSE summary of its image `current` against
/// the `previous` frame's image of the same technique.
///
/// # Errors
/// [`MetricError::SizeMismatch`] if the images differ in size.
pub fn temporal_noise(current: &LinearImage, previous: &LinearImage) -> Result<f64, MetricError> {
    Ok(multiscale_rmse(current, previous)?.summary())
}

/// The multi-scale RMSE written out as its definition: per level, per block, the sum of the
/// difference over the block's pixels. `a` and `b` hold `width · height` pixels of `channels`
/// values each, rows top to bottom. `O(levels · pixels)`: the reference that faster
/// implementations (the z-order pass here, the build's bit-mask and grey-cut passes) are tested
/// against.
///
/// # Errors
/// [`MetricError::SizeMismatch`] if `a` or `b` does not hold `width · height · channels` values;
/// [`MetricError::Empty`] for no channels.
pub fn multiscale_rmse_by_blocks(
    width: u32,
    height: u32,
    channels: usize,
    a: &[f64],
    b: &[f64],
) -> Result<MultiScaleRmse, MetricError> {
    if channels == 0 {
        return Err(MetricError::Empty { width, height });
    }
    let pixels = width as usize * height as usize;
    for values in [a, b] {
        if values.len() != pixels * channels {
            let got = u32::try_from(values.len() / channels).unwrap_or(u32::MAX);
            return Err(MetricError::SizeMismatch { expected: (width, height), got: (got, 1) });
        }
    }
    let samples = channels as f64 * f64::from(width) * f64::from(height);
    let levels = (0..level_count(width, height))
        .map(|level| {
            let side = 1u32 << level;
            let mut total = 0.0;
            for by in 0..height.div_ceil(side) {
                for bx in 0..width.div_ceil(side) {
                    let (mut sum, mut n) = (vec![0.0f64; channels], 0u32);
                    for y in by * side..((by + 1) * side).min(height) {
                        for x in bx * side..((bx + 1) * side).min(width) {
                            let i = (y as usize * width as usize + x as usize) * channels;
                            for (c, s) in sum.iter_mut().enumerate() {
                                *s += a[i + c] - b[i + c];
                            }
                            n += 1;
                        }
                    }
                    total += sum.iter().map(|s| s * s).sum::<f64>() / f64::from(n);
                }
            }
            if samples > 0.0 { (total / samples).max(0.0).sqrt() } else { 0.0 }
        })
        .collect();
    Ok(MultiScaleRmse { levels })
}

/// Every level of the multi-scale RMSE of a `width×height` difference image of `C` channels
/// (`difference(i)` for the pixel at row-major index `i`), in one pass along the z-order curve
/// over the image padded to a power-of-two square (padding skipped a whole aligned block at a
/// time), one running sum per level.
fn z_order<const C: usize>(width: u32, height: u32, difference: impl Fn(usize) -> [f64; C]) -> MultiScaleRmse {
    let levels = level_count(width, height);
    let top = levels - 1;
    let end = 1u64 << (2 * top);
    // Per level: closed blocks' Σ |S_b|² / n_b; the open block's sum and pixel count.
    let mut accumulated = vec![0.0f64; levels];
    let mut open_sum = vec![[0.0f64; C]; levels];
    let mut open_count = vec![0u64; levels];
    let mut index = 0u64;
    while index < end {
        let (x, y) = morton_decode(index);
        let step = if x < width && y < height {
            let d = difference(y as usize * width as usize + x as usize);
            accumulated[0] += d.iter().map(|v| v * v).sum::<f64>();
            if top > 0 {
                for c in 0..C {
                    open_sum[1][c] += d[c];
                }
                open_count[1] += 1;
            }
            1
        } else {
            // Every pixel of an aligned block starting here lies at or beyond (x, y), so outside:
            // skip the largest such block.
            #[expect(clippy::cast_possible_truncation, reason = "at most 33 levels")]
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
                #[expect(clippy::cast_precision_loss, reason = "pixel counts far below 2^53")]
                let n = count as f64;
                accumulated[level] += sum.iter().map(|v| v * v).sum::<f64>() / n;
                if level < top {
                    for c in 0..C {
                        open_sum[level + 1][c] += sum[c];
                    }
                    open_count[level + 1] += count;
                }
            }
            open_sum[level] = [0.0; C];
            open_count[level] = 0;
        }
    }
    #[expect(clippy::cast_precision_loss, reason = "a channel count")]
    let samples = C as f64 * f64::from(width) * f64::from(height);
    let levels = accumulated.iter().map(|&e| if samples > 0.0 { (e / samples).max(0.0).sqrt() } else { 0.0 }).collect();
    MultiScaleRmse { levels }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn values(image: &LinearImage) -> Vec<f64> {
        image.pixels.iter().flat_map(|p| p.map(f64::from)).collect()
    }

    /// The definition, block by block, on colour images.
    fn by_blocks(a: &LinearImage, b: &LinearImage) -> Vec<f64> {
        multiscale_rmse_by_blocks(a.width, a.height, 3, &values(a), &values(b)).expect("same size").levels
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
            assert_eq!(temporal_noise(&a, &a), Ok(0.0));
            assert!((temporal_noise(&a, &b).expect("same size") - 0.1).abs() < 1e-6);
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
    fn coverage_reads_as_one_channel_of_zero_and_one() {
        // Left half against right half of 4×4: every pixel differs (level 0: 1), every 2×2 block
        // is all +1 or all −1 (level 1: 1), the whole image sums to 0 (level 2: 0).
        let left = Mask { width: 4, height: 4, covered: (0..16).map(|i| i % 4 < 2).collect() };
        let right = Mask { width: 4, height: 4, covered: (0..16).map(|i| i % 4 >= 2).collect() };
        let rmse = coverage_multiscale_rmse(&left, &right).expect("same size");
        assert_eq!(rmse.levels, [1.0, 1.0, 0.0]);
        // One pixel of 16 more: RMSE 1/4 per pixel; its 2×2 block's mean 1/4 over 4 pixels
        // (sqrt(4 · 1/16 / 16)); the whole image's mean 1/16.
        let mut one = Mask { width: 4, height: 4, covered: vec![false; 16] };
        let empty = one.clone();
        one.covered[5] = true;
        let rmse = coverage_multiscale_rmse(&one, &empty).expect("same size");
        let expected = [0.25, (1.0f64 / 4.0 / 16.0).sqrt(), 1.0 / 16.0];
        for (e, x) in rmse.levels.iter().zip(expected) {
            assert!((e - x).abs() < 1e-12, "{:?}", rmse.levels);
        }
        // The same coverage as a grey colour image reads the same.
        let grey = |m: &Mask| LinearImage {
            width: m.width,
            height: m.height,
            pixels: m.covered.iter().map(|&c| [f32::from(u8::from(c)); 3]).collect(),
        };
        assert_eq!(multiscale_rmse(&grey(&one), &grey(&empty)).expect("same size"), rmse);
        assert!(coverage_multiscale_rmse(&one, &Mask { width: 2, height: 8, covered: vec![false; 16] }).is_err());
    }

    #[test]
    fn bad_sizes_are_errors() {
        let a = LinearImage::filled(4, 4, [0.0; 3]);
        assert_eq!(
            multiscale_rmse(&a, &LinearImage::filled(4, 5, [0.0; 3])),
            Err(MetricError::SizeMismatch { expected: (4, 4), got: (4, 5) })
        );
        let mut short = a.clone();
        short.pixels.pop();
        assert!(multiscale_rmse(&a, &short).is_err() && multiscale_rmse(&short, &short).is_err());
        assert!(multiscale_rmse_by_blocks(2, 2, 1, &[0.0; 4], &[0.0; 3]).is_err());
        assert!(multiscale_rmse_by_blocks(2, 2, 0, &[], &[]).is_err());
    }

    #[test]
    fn the_z_order_curve_visits_aligned_blocks_in_turn() {
        let order: Vec<(u32, u32)> = (0..16).map(morton_decode).collect();
        assert_eq!(&order[..8], &[(0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (3, 0), (2, 1), (3, 1)]);
        assert_eq!(order[15], (3, 3));
        assert_eq!(morton_decode((1 << 40) - 1), ((1 << 20) - 1, (1 << 20) - 1));
    }

    fn image(width: u32, height: u32) -> impl Strategy<Value = LinearImage> {
        proptest::collection::vec(proptest::array::uniform3(0.0f32..=1.0), (width * height) as usize)
            .prop_map(move |pixels| LinearImage { width, height, pixels })
    }

    fn mask(width: u32, height: u32) -> impl Strategy<Value = Mask> {
        proptest::collection::vec(any::<bool>(), (width * height) as usize).prop_map(move |covered| Mask {
            width,
            height,
            covered,
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn z_order_equals_the_definition_on_random_images(
            (a, b) in (1u32..=24, 1u32..=24).prop_flat_map(|(w, h)| (image(w, h), image(w, h)))
        ) {
            let fast = multiscale_rmse(&a, &b).expect("same size");
            let slow = by_blocks(&a, &b);
            prop_assert_eq!(fast.levels.len(), slow.len());
            for (f, s) in fast.levels.iter().zip(&slow) {
                prop_assert!((f - s).abs() < 1e-9, "{:?} vs {:?}", fast.levels, slow);
            }
            // A block's mean is never further off than its quarters' (Cauchy–Schwarz): coarser
            // levels never read more than finer ones.
            prop_assert!(fast.levels.windows(2).all(|pair| pair[1] <= pair[0] + 1e-9), "{:?}", fast.levels);
        }

        #[test]
        fn z_order_equals_the_definition_on_random_masks(
            (a, b) in (1u32..=24, 1u32..=24).prop_flat_map(|(w, h)| (mask(w, h), mask(w, h)))
        ) {
            let fast = coverage_multiscale_rmse(&a, &b).expect("same size");
            let slow = multiscale_rmse_by_blocks(a.width, a.height, 1, &a.values(), &b.values()).expect("same size");
            prop_assert_eq!(fast.levels.len(), slow.levels.len());
            for (f, s) in fast.levels.iter().zip(&slow.levels) {
                prop_assert!((f - s).abs() < 1e-12, "{:?} vs {:?}", fast.levels, slow.levels);
            }
        }
    }
}
