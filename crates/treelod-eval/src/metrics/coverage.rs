//! Coverage masks and their pixel classification against a reference: Precision, Recall and
//! Neubert's quality `Q` (definitions in the [module documentation](super)).

use super::{check_bytes, divided, same_size};
use crate::MetricError;

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
    /// [`MetricError::SizeMismatch`] if `rgba` does not hold `width · height · 4` bytes.
    pub fn from_srgba8(width: u32, height: u32, rgba: &[u8], background: [u8; 3]) -> Result<Self, MetricError> {
        check_bytes(width, height, rgba, 4)?;
        let covered = rgba.chunks_exact(4).map(|p| p[..3] != background).collect();
        Ok(Self { width, height, covered })
    }

    /// The mask reduced by `k` per side: an output pixel is covered when at least half of its
    /// `k×k` input pixels are (for `k = 1`, the mask itself). This approximates what a renderer
    /// sampling pixel centres at the smaller size covers, without the dilation of "any".
    ///
    /// # Errors
    /// [`MetricError::BadFactor`] if `k` is 0 or does not divide both sides;
    /// [`MetricError::SizeMismatch`] if the flags do not match the size.
    pub fn reduce_majority(&self, k: u32) -> Result<Self, MetricError> {
        let (width, height) = divided(self.width, self.height, k)?;
        same_size((self.width, self.height), super::colour::pixel_size(self.covered.len(), self.width))?;
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

    /// The mask as values 0 and 1 (one channel), rows top to bottom: the coverage image whose
    /// multi-scale RMSE [`super::coverage_multiscale_rmse`] measures.
    #[must_use]
    pub fn values(&self) -> Vec<f64> {
        self.covered.iter().map(|&c| f64::from(u8::from(c))).collect()
    }
}

/// Pixel classification of a sample's coverage against the reference's (Neubert et al. 2011,
/// Table 1).
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
    /// [`MetricError::SizeMismatch`] if the masks differ in size.
    pub fn compare(reference: &Mask, sample: &Mask) -> Result<Self, MetricError> {
        same_size((reference.width, reference.height), (sample.width, sample.height))?;
        same_size((reference.width, reference.height), super::colour::pixel_size(sample.covered.len(), sample.width))?;
        same_size(
            (reference.width, reference.height),
            super::colour::pixel_size(reference.covered.len(), reference.width),
        )?;
        Ok(Self::of_flags(&reference.covered, &sample.covered))
    }

    /// Counts the flags of `sample` against those of `reference`, pixel by pixel (the shorter
    /// slice's length).
    #[must_use]
    pub fn of_flags(reference: &[bool], sample: &[bool]) -> Self {
        let mut counts = Self::default();
        for (&r, &s) in reference.iter().zip(sample) {
            match (r, s) {
                (true, true) => counts.tp += 1,
                (false, true) => counts.fp += 1,
                (true, false) => counts.fn_ += 1,
                (false, false) => {}
            }
        }
        counts
    }

    /// The sum of two classifications (of disjoint pixels, e.g. several views).
    #[must_use]
    pub fn plus(self, other: Self) -> Self {
        Self { tp: self.tp + other.tp, fp: self.fp + other.fp, fn_: self.fn_ + other.fn_ }
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

    /// `(P, R)`: two empty masks score `(1, 1)`.
    #[must_use]
    pub fn precision_recall(&self) -> (f64, f64) {
        (self.precision(), self.recall())
    }

    /// Neubert's quality `Q = 1 − ‖(1 − P, 1 − R)‖`: 1 when both are perfect, `1 − √2` at worst.
    #[must_use]
    pub fn quality(&self) -> f64 {
        quality(self.precision(), self.recall())
    }
}

/// `Q = 1 − sqrt((1 − P)² + (1 − R)²)` (Neubert et al. 2011, eq. 4).
#[must_use]
pub fn quality(precision: f64, recall: f64) -> f64 {
    1.0 - (1.0 - precision).hypot(1.0 - recall)
}

/// `n / d`, 1 when `d` is 0.
fn ratio(n: u64, d: u64) -> f64 {
    #[expect(clippy::cast_precision_loss, reason = "pixel counts far below 2^53")]
    let r = if d == 0 { 1.0 } else { n as f64 / d as f64 };
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(width: u32, rows: &[&str]) -> Mask {
        let covered: Vec<bool> = rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect();
        assert_eq!(covered.len(), width as usize * rows.len());
        Mask { width, height: u32::try_from(rows.len()).expect("few rows"), covered }
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
        let nothing = mask(4, &["....", "....", "....", "...."]);
        assert_eq!(Coverage::compare(&reference, &nothing).expect("same size").precision_recall(), (1.0, 0.0));
        assert_eq!(Coverage::compare(&nothing, &reference).expect("same size").precision_recall(), (0.0, 1.0));
        assert_eq!(quality(1.0, 0.0), 0.0);
        // Disjoint: P = R = 0, the worst Q.
        let other = mask(4, &["..##", "..##", "....", "...."]);
        let worst = Coverage::compare(&reference, &other).expect("same size");
        assert_eq!((worst.precision(), worst.recall()), (0.0, 0.0));
        assert!((worst.quality() - (1.0 - 2f64.sqrt())).abs() < 1e-12);
        assert_eq!(
            Coverage::compare(&reference, &empty),
            Err(MetricError::SizeMismatch { expected: (4, 4), got: (2, 2) })
        );
        let mut short = sample.clone();
        short.covered.pop();
        assert!(Coverage::compare(&reference, &short).is_err(), "flags that do not match the size");
        assert_eq!(c.plus(worst), Coverage { tp: 3, fp: 6, fn_: 5 });
        assert_eq!(Coverage::of_flags(&reference.covered, &sample.covered), c);
    }

    #[test]
    fn masks_come_from_the_background_colour_and_reduce_by_majority() {
        let bg = [255, 255, 255];
        let rgba = [255, 255, 255, 255, 254, 255, 255, 255, 0, 0, 0, 255, 255, 255, 255, 0];
        let m = Mask::from_srgba8(2, 2, &rgba, bg).expect("4 pixels");
        assert_eq!(m.covered, [false, true, true, false], "alpha is ignored");
        assert_eq!(m.values(), [0.0, 1.0, 1.0, 0.0]);
        assert_eq!(m.reduce_majority(2).expect("divides").covered, [true], "2 of 4 is half");
        let one = Mask { width: 2, height: 2, covered: vec![true, false, false, false] };
        assert_eq!(one.reduce_majority(2).expect("divides").covered, [false]);
        assert_eq!(one.reduce_majority(1).expect("divides"), one);
        assert!(one.reduce_majority(3).is_err() && one.reduce_majority(0).is_err());
        assert!(Mask::from_srgba8(2, 2, &rgba[..12], bg).is_err());
    }
}
