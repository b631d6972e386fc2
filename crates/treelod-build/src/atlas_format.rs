//! How the build stores its baked atlases (impostor planes, billboards; spec §6.7): BC7 blocks by
//! default, a quarter of RGBA8's bytes, or RGBA8 as baked.
//!
//! The encoder is the `block_compression` crate's CPU BC7 encoder (MIT; a Rust port of Intel's
//! ISPC texture compressor kernels, with no C, no GPU and only `bytemuck` beneath it; it tracks
//! wgpu's releases, and its decoder is what the format crate's `images` feature decodes with).
//! Hand-written BC7 encoders are slow or poor; the other maintained encoders bind C or C++ (Intel's
//! ISPC kernels through prebuilt libraries, bc7enc) or encode on a GPU, which a build on a machine
//! without one cannot use. Only this crate (the build) depends on the encoder.
//!
//! Determinism: each `4 × 4` block is encoded from its own texels alone, in plain Rust arithmetic,
//! so the blocks are the same whichever thread encodes them; the rows of blocks are encoded in
//! parallel and written in order, so the bytes do not depend on the thread count.

use block_compression::{BC7Settings, CompressionVariant};
use rayon::prelude::*;
use treelod_format::image_format;

use crate::impostor::Atlas;

/// The image format of the build's atlases (`--atlas-format`, setting `atlas.format`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum AtlasFormat {
    /// BC7 blocks (formats 6, 7): 1 byte per texel, decoded by the GPU.
    #[default]
    Bc7,
    /// RGBA8 texels as baked (formats 1, 2): 4 bytes per texel.
    Rgba8,
}

impl AtlasFormat {
    /// The name the settings and the command line use: `bc7` or `rgba8`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Bc7 => "bc7",
            Self::Rgba8 => "rgba8",
        }
    }
}

impl std::str::FromStr for AtlasFormat {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "bc7" => Ok(Self::Bc7),
            "rgba8" => Ok(Self::Rgba8),
            other => Err(format!("unknown atlas format {other:?} (expected bc7 or rgba8)")),
        }
    }
}

/// The encoder's settings: its "ultrafast" quality for images with alpha, the first of its five
/// (`alpha_ultrafast` to `alpha_slow`). Measured on a 256² pattern, µs per block and RMSE of 255:
/// ultrafast 24 and 10.8, very fast 52 and 5.1, fast 96 and 4.9, basic 183 and 2.0. On the
/// shared oak with every representation (a million blocks; `build --timings`, 2 cores) the
/// encoding took 234 s at basic, 13.1 s at very fast and 2.7 s at ultrafast (the build 10.8 s
/// against 8.3 s with RGBA8 atlases), while `eval --orbit 2,8,32` of impostors and billboards read
/// the same RMSE and FLIP as with RGBA8 atlases at every quality to ±0.0001: at the sizes the
/// atlases are drawn at, the encoder's colour error is below what the image shows. The alpha the
/// renderer's test cuts at 0.5 is carried by the endpoints of every mode alike.
fn settings() -> CompressionVariant {
    CompressionVariant::BC7(BC7Settings::alpha_ultrafast())
}

/// `atlas` stored as `format`: unchanged for [`AtlasFormat::Rgba8`], for images that are not
/// RGBA8 (leaf slots) and for sides that are not multiples of 4 (BC7 needs whole blocks at level
/// 0, spec §6.7); else each level encoded as BC7 (RGBA8_SRGB → BC7_SRGB, RGBA8_LINEAR →
/// BC7_LINEAR).
#[must_use]
pub fn store(atlas: Atlas, format: AtlasFormat) -> Atlas {
    let target = match atlas.format {
        image_format::RGBA8_SRGB => image_format::BC7_SRGB,
        image_format::RGBA8_LINEAR => image_format::BC7_LINEAR,
        _ => return atlas,
    };
    if format == AtlasFormat::Rgba8 || !atlas.width.is_multiple_of(4) || !atlas.height.is_multiple_of(4) {
        return atlas;
    }
    let mut blocks = Vec::new();
    let mut at = 0usize;
    for level in 0..atlas.mip_count {
        let (w, h) = ((atlas.width >> level).max(1), (atlas.height >> level).max(1));
        let len = w as usize * h as usize * 4;
        let Some(texels) = atlas.texels.get(at..at + len) else { return atlas };
        blocks.extend(encode_bc7(texels, w, h));
        at += len;
    }
    Atlas { format: target, texels: blocks, ..atlas }
}

/// Encodes one level of `width × height` RGBA8 texels (rows top to bottom) as BC7 blocks, rows of
/// blocks top to bottom: `ceil(width / 4) · ceil(height / 4)` blocks of 16 bytes. A partial block
/// at the right or bottom edge repeats the level's last column or row.
///
/// # Panics
/// If `texels` is not `width · height · 4` bytes.
#[must_use]
pub fn encode_bc7(texels: &[u8], width: u32, height: u32) -> Vec<u8> {
    let (w, h) = (width as usize, height as usize);
    assert_eq!(texels.len(), w * h * 4, "{width}x{height} RGBA8 texels");
    let (bw, bh) = (w.div_ceil(4), h.div_ceil(4));
    let row_bytes = bw * 16;
    let mut out = vec![0u8; row_bytes * bh];
    let empty = empty_block();
    out.par_chunks_mut(row_bytes).enumerate().for_each(|(by, row)| {
        // The 4 rows of texels of this row of blocks, padded to whole blocks by repeating the
        // last column and row.
        let pw = bw * 4;
        let mut strip = vec![0u8; pw * 4 * 4];
        for dy in 0..4 {
            let y = (by * 4 + dy).min(h - 1);
            for x in 0..pw {
                let src = (y * w + x.min(w - 1)) * 4;
                strip[(dy * pw + x) * 4..][..4].copy_from_slice(&texels[src..src + 4]);
            }
        }
        // Blocks of transparent black texels (the space between an atlas's regions and around
        // the octahedral views: 61–69 % of the shared oak's level-0 blocks, 14–32 % of its
        // smallest level's) take the one encoding such a block has; each run of the other blocks
        // is encoded at once, read in place from the strip. A block's encoding is its texels'
        // alone, so the bytes are those of encoding the whole row (the oak's `--baselines
        // --impostors` stage 4.3 s -> 1.8 s).
        let is_empty = |bx: usize| (0..4).all(|dy| strip[(dy * pw + bx * 4) * 4..][..16].iter().all(|&b| b == 0));
        let mut bx = 0;
        while bx < bw {
            if is_empty(bx) {
                row[bx * 16..][..16].copy_from_slice(&empty);
                bx += 1;
                continue;
            }
            let end = (bx + 1..bw).find(|&b| is_empty(b)).unwrap_or(bw);
            encode_strip(&strip[bx * 16..], &mut row[bx * 16..end * 16], (end - bx) * 4, pw * 4);
            bx = end;
        }
    });
    out
}

/// Encodes the first `width` texels (a multiple of 4) of 4 rows of `strip`, `stride` bytes apart,
/// into `blocks`.
fn encode_strip(strip: &[u8], blocks: &mut [u8], width: usize, stride: usize) {
    #[expect(clippy::cast_possible_truncation, reason = "sides at most 16384 + 3")]
    block_compression::encode::compress_rgba8(settings(), strip, blocks, width as u32, 4, stride as u32);
}

/// The encoding of a block of 16 transparent black texels.
fn empty_block() -> [u8; 16] {
    let mut block = [0u8; 16];
    encode_strip(&[0u8; 64], &mut block, 4, 16);
    block
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A soft-edged disc of varying colour, alpha from 0 to 255.
    fn disc(size: u32) -> Vec<u8> {
        let c = size as f32 / 2.0;
        (0..size * size)
            .flat_map(|i| {
                let (x, y) = ((i % size) as f32 + 0.5, (i / size) as f32 + 0.5);
                let r = ((x - c).hypot(y - c) / c).min(1.5);
                let a = ((1.0 - r) * 4.0 + 0.5).clamp(0.0, 1.0);
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=255")]
                let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
                [q(x / size as f32), q(0.3 + 0.5 * y / size as f32), q(0.2), q(a)]
            })
            .collect()
    }

    #[test]
    fn encoding_is_the_same_whatever_the_thread_count() {
        let texels = disc(64);
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
        let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().expect("pool");
        let a = one.install(|| encode_bc7(&texels, 64, 64));
        let b = four.install(|| encode_bc7(&texels, 64, 64));
        assert_eq!(a.len(), 16 * 16 * 16);
        assert!(a == b, "BC7 blocks differ between 1 and 4 threads");
        assert!(a == encode_bc7(&texels, 64, 64));
    }

    #[test]
    fn a_level_round_trips_within_a_few_levels_and_keeps_its_alpha_test() {
        let texels = disc(64);
        let blocks = encode_bc7(&texels, 64, 64);
        let back = treelod_format::image::decode_bc7(64, 64, &blocks).expect("decodes");
        let diff: Vec<f64> = texels.iter().zip(&back).map(|(a, b)| f64::from(a.abs_diff(*b))).collect();
        let rmse = (diff.iter().map(|d| d * d).sum::<f64>() / diff.len() as f64).sqrt();
        let max = diff.iter().copied().fold(0.0, f64::max);
        eprintln!("round trip: RMSE {rmse:.3}, largest difference {max} of 255");
        assert!(rmse < 2.0, "RMSE {rmse} levels");
        assert!(max <= 24.0, "largest difference {max} levels");
        // The alpha test at 0.5 passes on the same texels but for a few at the edge.
        let passes = |t: &[u8]| t.chunks_exact(4).map(|p| p[3] >= 128).collect::<Vec<_>>();
        let (before, after) = (passes(&texels), passes(&back));
        let flipped = before.iter().zip(&after).filter(|(a, b)| a != b).count();
        let covered = before.iter().filter(|&&p| p).count();
        eprintln!("alpha test: {flipped} of {covered} covered texels flip");
        assert!(flipped * 100 <= covered, "{flipped} of {covered} covered texels change their alpha test");
    }

    /// Transparent black blocks take their one encoding without the encoder, and the runs between
    /// them are encoded apart: the bytes are those of encoding each whole row of blocks at once.
    #[test]
    fn empty_blocks_are_encoded_as_the_encoder_encodes_them() {
        // A disc with rows and columns of transparent black blocks cut through it, at the edges
        // and between runs of one and of several blocks, and a partial block at the right.
        let (w, h) = (62usize, 64usize);
        let disc = disc(64);
        let texels: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                let cut = [0, 2, 3, 7, 9].contains(&(x / 4)) || [1, 5, 6].contains(&(y / 4));
                if cut { [0; 4] } else { <[u8; 4]>::try_from(&disc[(y * 64 + x) * 4..][..4]).expect("4 bytes") }
            })
            .collect();
        let blocks = encode_bc7(&texels, w as u32, h as u32);
        let (bw, bh) = (w.div_ceil(4), h.div_ceil(4));
        let mut whole = vec![0u8; bw * bh * 16];
        for (by, row) in whole.chunks_exact_mut(bw * 16).enumerate() {
            let strip: Vec<u8> = (0..4)
                .flat_map(|dy| (0..bw * 4).map(move |x| ((by * 4 + dy).min(h - 1), x.min(w - 1))))
                .flat_map(|(y, x)| <[u8; 4]>::try_from(&texels[(y * w + x) * 4..][..4]).expect("4 bytes"))
                .collect();
            encode_strip(&strip, row, bw * 4, bw * 16);
        }
        assert!(blocks == whole, "BC7 blocks differ from encoding whole rows");
        assert!(blocks.chunks_exact(16).filter(|b| *b == empty_block()).count() > bw * 3);
    }

    #[test]
    fn partial_blocks_repeat_the_edge() {
        let texels: Vec<u8> = [200u8, 100, 50, 255].repeat(6 * 3);
        let blocks = encode_bc7(&texels, 6, 3);
        assert_eq!(blocks.len(), 2 * 16);
        let back = treelod_format::image::decode_bc7(6, 3, &blocks).expect("decodes");
        assert_eq!(back.len(), 6 * 3 * 4);
        assert!(back.chunks_exact(4).all(|t| t.iter().zip([200u8, 100, 50, 255]).all(|(a, b)| a.abs_diff(b) <= 2)));
    }

    #[test]
    fn rgba8_and_odd_sizes_are_kept() {
        let atlas = Atlas { width: 6, height: 4, format: image_format::RGBA8_SRGB, mip_count: 1, texels: vec![7; 96] };
        assert_eq!(store(atlas.clone(), AtlasFormat::Bc7), atlas);
        let atlas = Atlas { width: 8, height: 4, format: image_format::RGBA8_SRGB, mip_count: 2, texels: vec![7; 160] };
        assert_eq!(store(atlas.clone(), AtlasFormat::Rgba8), atlas);
        let stored = store(atlas, AtlasFormat::Bc7);
        assert_eq!((stored.format, stored.texels.len()), (image_format::BC7_SRGB, 2 * 16 + 16));
    }
}
