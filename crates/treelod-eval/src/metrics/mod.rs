//! The image metrics, each defined once here; every other implementation in the project (the
//! build's bit-mask and grey-cut fast paths) computes these definitions and is tested against
//! them.
//!
//! ## Coverage: Precision, Recall and `Q` (Neubert et al. 2011 §2.2)
//!
//! A [`Mask`] says which pixels an image covers. Against a reference mask, each pixel is a true
//! positive (covered in both), a false positive (covered by the sample only) or a false negative
//! (covered by the reference only), counted in [`Coverage`]. Then
//!
//! ```text
//! P = TP / (TP + FP)      (1 when the sample covers nothing: nothing drawn wrongly)
//! R = TP / (TP + FN)      (1 when the reference covers nothing: nothing missed)
//! Q = 1 − sqrt((1 − P)² + (1 − R)²)
//! ```
//!
//! `Q` is 1 for a perfect image, 0 at distance 1 from the corner `(1, 1)` of the PR diagram and
//! `1 − √2` when nothing is right.
//!
//! ## Multi-scale RMSE (Clasen et al. 2011 §4)
//!
//! For two `W×H` images `a` and `b` of `C` channels (`C = 3` for linear RGB, `C = 1` for coverage
//! as 0 and 1) with the difference `d = a − b`, level `l` (`l = 0..=L`, `L = ⌈log2 max(W, H)⌉`)
//! divides the image into blocks of `2^l × 2^l` pixels aligned at the top left; blocks at the
//! right and bottom edges are clipped by the image (equivalently, the image is padded to a
//! `2^L × 2^L` square whose padding pixels are left out of every count). With `S_b` the sum of
//! `d` over the `n_b` image pixels of block `b` (per channel), the level's error is
//!
//! ```text
//! RMSE_l = sqrt( Σ_b |S_b|² / n_b  /  (C · W · H) )
//! ```
//!
//! (`|·|²` sums the channels): the RMSE over all pixels and channels of the difference after
//! each block has been replaced by its mean. Level 0 is the ordinary per-pixel RMSE, level `L`
//! compares the mean values of the whole images; a constant offset `c` reads `c` at every level,
//! and no level reads more than a finer one. The summary ([`MultiScaleRmse::summary`]) is the
//! mean of the `L + 1` levels, so it compares only images of the same size. A coverage image
//! replicated into three colour channels reads the same as with one channel.
//!
//! [`multiscale_rmse`] (colour) and [`coverage_multiscale_rmse`] (coverage) accumulate every level
//! in one pass over the pixels in z-order (Morton order), where every aligned block is a
//! contiguous run, as Clasen et al. do on the GPU; [`multiscale_rmse_by_blocks`] is the
//! definition written out block by block, the reference that faster implementations are tested
//! against.
//!
//! ## Temporal noise
//!
//! The [`temporal_noise`] of a frame is the multi-scale RMSE summary of that frame's image
//! against the previous frame's image of the same technique along the same camera path (none for
//! the first frame): how much the picture changes between frames, popping and flicker included.
//! It is reported beside the reference's own, which measures the camera's motion.
//!
//! ## FLIP (feature `flip`)
//!
//! [`flip::mean_flip`] is the mean over pixels of NVIDIA's FLIP error map (Andersson et al.
//! 2020, LDR-FLIP) of a sample image against the reference, both as 8-bit sRGB images of the same
//! size, at `nv-flip`'s default of 67 pixels per degree (a 0.7 m wide 4K monitor seen from
//! 0.7 m): 0 for identical images, up to 1.

mod colour;
mod coverage;
#[cfg(feature = "flip")]
pub mod flip;
mod multiscale;

pub use colour::{LinearImage, linear_to_srgb, srgb_to_linear};
pub use coverage::{Coverage, Mask, quality};
pub use multiscale::{
    MultiScaleRmse, coverage_multiscale_rmse, level_count, morton_decode, multiscale_rmse, multiscale_rmse_by_blocks,
    temporal_noise,
};

use crate::MetricError;

/// `(width / k, height / k)`, or why not.
fn divided(width: u32, height: u32, k: u32) -> Result<(u32, u32), MetricError> {
    if k == 0 || !width.is_multiple_of(k) || !height.is_multiple_of(k) {
        return Err(MetricError::BadFactor { width, height, factor: k });
    }
    Ok((width / k, height / k))
}

/// Checks that `bytes` holds `width · height` pixels of `channels` bytes.
fn check_bytes(width: u32, height: u32, bytes: &[u8], channels: usize) -> Result<(), MetricError> {
    let pixels = width as usize * height as usize;
    if bytes.len() != pixels * channels {
        let got = u32::try_from(bytes.len() / channels).unwrap_or(u32::MAX);
        return Err(MetricError::SizeMismatch { expected: (width, height), got: (got, 1) });
    }
    Ok(())
}

/// Fails unless both sizes are equal.
fn same_size(expected: (u32, u32), got: (u32, u32)) -> Result<(), MetricError> {
    if expected == got { Ok(()) } else { Err(MetricError::SizeMismatch { expected, got }) }
}
