//! The texels of the materials' textures as a renderer samples them, on the CPU: every image
//! resampled to one square layer size (at most [`MAX_LAYER`]), alpha-tested images made binary at
//! their cutoff, a full mip chain averaged in linear light, and the trilinear sample a GPU's
//! linear sampler takes ([`sample`]). The renderer uploads these layers
//! (`treelod-render`'s texture array); the build's calibration samples the same texels, so the
//! leaves it measures thin out or keep their density with distance exactly as drawn.

use treelod_format::{MaterialRecord, PlaneRecord};

/// Largest layer size; leaf textures seldom need more at the distances where triangles are drawn.
pub const MAX_LAYER: u32 = 512;

/// The layers of a model's images: `size`×`size` texels each, with every mip level down to 1×1.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layers {
    /// Texels along a side of level 0.
    pub size: u32,
    /// Per layer, per level (largest first), RGBA8 texels, RGB sRGB-encoded.
    pub levels: Vec<Vec<Vec<u8>>>,
}

/// One decoded image: `width`×`height` RGBA8 texels, RGB sRGB-encoded.
#[derive(Clone, Copy, Debug)]
pub struct Texels<'a> {
    /// Texels across.
    pub width: u32,
    /// Texels down.
    pub height: u32,
    /// The texels, rows top to bottom.
    pub rgba: &'a [u8],
}

impl Layers {
    /// The layers of `images` (`None`: an image that did not decode, drawn grey), each made binary
    /// at its `cutoffs` entry where it has one ([`alpha_cutoffs`]): the side is the largest
    /// image's rounded up to a power of two, at most [`MAX_LAYER`]. One opaque white layer where
    /// there is no image (a texture array needs one).
    #[must_use]
    pub fn new(images: &[Option<Texels<'_>>], cutoffs: &[Option<f32>]) -> Self {
        let largest = images.iter().flatten().map(|i| i.width.max(i.height)).max().unwrap_or(1);
        let size = largest.next_power_of_two().clamp(1, MAX_LAYER);
        let mut levels = Vec::with_capacity(images.len().max(1));
        for (i, image) in images.iter().enumerate() {
            let mut base = match image {
                Some(image) => resample(image.rgba, image.width, image.height, size),
                None => vec![128; (size * size * 4) as usize],
            };
            if let Some(Some(cutoff)) = cutoffs.get(i) {
                binarise_alpha(&mut base, *cutoff);
            }
            levels.push(mip_chain(base, size));
        }
        if levels.is_empty() {
            levels.push(mip_chain(vec![255; (size * size * 4) as usize], size));
        }
        Self { size, levels }
    }

    /// Mip levels per layer.
    #[must_use]
    pub fn mips(&self) -> u32 {
        self.size.ilog2() + 1
    }
}

/// How a texture is sampled: the GPU sampler's addressing and mip filter, and whether its RGB
/// is sRGB-encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sampler {
    /// Repeat addressing (else clamp to edge).
    pub repeat: bool,
    /// Blend the two mip levels around the level of detail (else the nearest level).
    pub mip_linear: bool,
    /// RGB is sRGB-encoded: decoded to linear light before filtering, as an sRGB texture format.
    pub srgb: bool,
}

impl Sampler {
    /// The material textures' sampler: repeat, trilinear, sRGB.
    pub const MATERIALS: Self = Self { repeat: true, mip_linear: true, srgb: true };
    /// The atlases' sampler (planes, billboards): clamp to edge, bilinear in the nearest level.
    pub const ATLASES: Self = Self { repeat: false, mip_linear: false, srgb: true };
}

/// The sample of `levels` (a mip chain of `size` = (width, height) texels at level 0, each level
/// halving both down to 1, as many levels as given) at `uv` and level of detail `lod` (`log2` of
/// texels per pixel at level 0, clamped to the chain), as a GPU's linear sampler takes it:
/// bilinear within a level (texel centres at `+½`), blended between the two levels around
/// `lod` or in the nearest level (`sampler`). Linear RGBA.
#[must_use]
pub fn sample(levels: &[Vec<u8>], size: (u32, u32), uv: [f32; 2], lod: f32, sampler: Sampler) -> [f32; 4] {
    let lut = srgb_table();
    let decode = |b: u8| if sampler.srgb { lut[usize::from(b)] } else { f32::from(b) / 255.0 };
    filtered(levels, size, uv, lod, sampler, |t| [decode(t[0]), decode(t[1]), decode(t[2]), f32::from(t[3]) / 255.0])
}

/// The alpha of [`sample`] alone (a quarter of its work: an alpha test needs no colour).
#[must_use]
pub fn sample_alpha(levels: &[Vec<u8>], size: (u32, u32), uv: [f32; 2], lod: f32, sampler: Sampler) -> f32 {
    filtered(levels, size, uv, lod, sampler, |t| [f32::from(t[3]) / 255.0])[0]
}

/// [`sample`] of the values `texel` reads from each RGBA8 texel.
fn filtered<const N: usize>(
    levels: &[Vec<u8>],
    size: (u32, u32),
    uv: [f32; 2],
    lod: f32,
    sampler: Sampler,
    texel: impl Fn(&[u8]) -> [f32; N],
) -> [f32; N] {
    let last = levels.len().saturating_sub(1);
    #[expect(clippy::cast_precision_loss, reason = "a mip count")]
    let lod = if lod.is_finite() { lod.clamp(0.0, last as f32) } else { 0.0 };
    let lod = if sampler.mip_linear { lod } else { (lod + 0.5).floor().min(lod.ceil()) };
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to the chain")]
    let fine = lod.floor() as usize;
    let t = lod - lod.floor();
    let a = bilinear(levels, size, uv, fine, sampler, &texel);
    if t <= 0.0 || fine >= last {
        return a;
    }
    let b = bilinear(levels, size, uv, fine + 1, sampler, &texel);
    core::array::from_fn(|c| a[c] + (b[c] - a[c]) * t)
}

/// Linear light of every sRGB byte.
fn srgb_table() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| core::array::from_fn(|b| srgb_to_linear(f32::from(u8::try_from(b).unwrap_or(255)) / 255.0)))
}

/// The bilinear sample of level `level` (texel centres at `+½`) of the values `texel` reads.
fn bilinear<const N: usize>(
    levels: &[Vec<u8>],
    size: (u32, u32),
    uv: [f32; 2],
    level: usize,
    sampler: Sampler,
    texel: &impl Fn(&[u8]) -> [f32; N],
) -> [f32; N] {
    let Some(texels) = levels.get(level) else { return [1.0; N] };
    let shift = u32::try_from(level).unwrap_or(31).min(31);
    let (w, h) = ((size.0 >> shift).max(1) as usize, (size.1 >> shift).max(1) as usize);
    #[expect(clippy::cast_precision_loss, reason = "texture sides")]
    let (fx, fy) = (uv[0] * w as f32 - 0.5, uv[1] * h as f32 - 0.5);
    let (tx, ty) = (fx - fx.floor(), fy - fy.floor());
    #[expect(clippy::cast_possible_truncation, reason = "wrapped or clamped below")]
    let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
    #[expect(clippy::cast_possible_wrap, reason = "texture sides")]
    let (nw, nh) = (w as i64, h as i64);
    let wrap = |v: i64, n: i64| if sampler.repeat { v.rem_euclid(n) } else { v.clamp(0, n - 1) };
    #[expect(clippy::cast_sign_loss, clippy::cast_possible_truncation, reason = "wrapped into the level")]
    let at = |x: i64, y: i64| -> [f32; N] {
        let i = (wrap(y, nh) as usize * w + wrap(x, nw) as usize) * 4;
        texel(texels.get(i..i + 4).unwrap_or(&[255; 4]))
    };
    let (a, b, c, d) = (at(x0, y0), at(x0 + 1, y0), at(x0, y0 + 1), at(x0 + 1, y0 + 1));
    core::array::from_fn(|k| {
        let top = a[k] + (b[k] - a[k]) * tx;
        let bottom = c[k] + (d[k] - c[k]) * tx;
        top + (bottom - top) * ty
    })
}

/// Bilinear resampling of an RGBA8 image to `size`×`size` (texel centres aligned, edges clamped).
pub fn resample(texels: &[u8], width: u32, height: u32, size: u32) -> Vec<u8> {
    let (w, h) = (width.max(1) as usize, height.max(1) as usize);
    let at = |x: usize, y: usize, c: usize| f32::from(texels.get((y * w + x) * 4 + c).copied().unwrap_or(255));
    let mut out = Vec::with_capacity((size * size * 4) as usize);
    for y in 0..size {
        let fy = ((y as f32 + 0.5) * h as f32 / size as f32 - 0.5).clamp(0.0, (h - 1) as f32);
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped into the image")]
        let (y0, ty) = (fy.floor() as usize, fy.fract());
        let y1 = (y0 + 1).min(h - 1);
        for x in 0..size {
            let fx = ((x as f32 + 0.5) * w as f32 / size as f32 - 0.5).clamp(0.0, (w - 1) as f32);
            #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped into the image")]
            let (x0, tx) = (fx.floor() as usize, fx.fract());
            let x1 = (x0 + 1).min(w - 1);
            for c in 0..4 {
                let top = at(x0, y0, c) * (1.0 - tx) + at(x1, y0, c) * tx;
                let bottom = at(x0, y1, c) * (1.0 - tx) + at(x1, y1, c) * tx;
                #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "in 0..=255")]
                out.push((top * (1.0 - ty) + bottom * ty).round().clamp(0.0, 255.0) as u8);
            }
        }
    }
    out
}

/// Per image of a container, whether it is an atlas of its own rather than a layer: sampled by
/// planes and by no material (spec §6.10).
#[must_use]
pub fn atlas_only(images: usize, materials: &[MaterialRecord], planes: &[PlaneRecord]) -> Vec<bool> {
    let mut atlas = vec![false; images];
    for plane in planes {
        if let Some(slot) = atlas.get_mut(plane.image as usize) {
            *slot = true;
        }
    }
    for material in materials {
        if let Some(slot) = atlas.get_mut(material.image as usize) {
            *slot = false;
        }
    }
    atlas
}

/// The alpha a material's fragments are tested against: `alpha_cutoff` for mask, 0.5 for blend
/// (the shaders draw blend as a mask), `None` for opaque (`material_cutoff` in the shaders).
#[must_use]
pub fn material_cutoff(material: &MaterialRecord) -> Option<f32> {
    match material.alpha_mode {
        1 => Some(material.alpha_cutoff),
        2 => Some(0.5),
        _ => None,
    }
}

/// Per image, the texel alpha below which the first material that alpha-tests it discards
/// ([`material_cutoff`] divided by the material's base-colour alpha, which multiplies the
/// texel's); `None` for images no material alpha-tests.
#[must_use]
pub fn alpha_cutoffs(materials: &[MaterialRecord], images: usize) -> Vec<Option<f32>> {
    let mut cutoffs = vec![None; images];
    for material in materials {
        let Some(cutoff) = material_cutoff(material) else { continue };
        let factor = material.base_color[3];
        let Some(slot) = usize::try_from(material.image).ok().and_then(|i| cutoffs.get_mut(i)) else { continue };
        if slot.is_none() && factor > 0.0 && cutoff.is_finite() {
            *slot = Some((cutoff / factor).clamp(0.0, 1.0));
        }
    }
    cutoffs
}

/// Sets every alpha to 255 where it passes `cutoff` (texel alpha, `0..=1`) and to 0 elsewhere.
/// The test at full resolution is unchanged; the mips then average coverage rather than soft
/// alpha (a card's faint fringe no longer reads as partly covered at a distance).
pub fn binarise_alpha(rgba: &mut [u8], cutoff: f32) {
    for texel in rgba.chunks_exact_mut(4) {
        texel[3] = if f32::from(texel[3]) / 255.0 >= cutoff { 255 } else { 0 };
    }
}

/// Box-filtered mips down to 1×1, in linear light and weighted by alpha: RGB is sRGB-encoded
/// (the array is `Rgba8UnormSrgb`), so averaging its bytes would darken every coarse level (a
/// black and white checkerboard would become sRGB 128, linear 0.22, instead of linear 0.5), and
/// the colour of transparent texels (often black) would bleed into the leaves at their edges.
/// Alpha is averaged plainly; leaves far enough away for the small mips to thin them out are
/// drawn as points instead.
pub fn mip_chain(base: Vec<u8>, size: u32) -> Vec<Vec<u8>> {
    let to_linear: Vec<f32> = (0..=255u8).map(|b| srgb_to_linear(f32::from(b) / 255.0)).collect();
    let mut chain = vec![base];
    let mut s = size as usize;
    while s > 1 {
        let half = s / 2;
        let Some(prev) = chain.last() else { break };
        let mut next = Vec::with_capacity(half * half * 4);
        for y in 0..half {
            for x in 0..half {
                let texels = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| ((2 * y + dy) * s + 2 * x + dx) * 4);
                let alpha: f32 = texels.iter().map(|&t| f32::from(prev[t + 3]) / 255.0).sum();
                for c in 0..3 {
                    let colour = if alpha > 0.0 {
                        texels
                            .iter()
                            .map(|&t| to_linear[prev[t + c] as usize] * f32::from(prev[t + 3]) / 255.0)
                            .sum::<f32>()
                            / alpha
                    } else {
                        texels.iter().map(|&t| to_linear[prev[t + c] as usize]).sum::<f32>() / 4.0
                    };
                    next.push(unorm8(linear_to_srgb(colour)));
                }
                next.push(unorm8(alpha / 4.0));
            }
        }
        chain.push(next);
        s = half;
    }
    chain
}

/// An sRGB-encoded value in `[0, 1]` as linear light.
#[must_use]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// Linear light in `[0, 1]` sRGB-encoded.
#[must_use]
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 { v * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}

#[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 0..=255")]
fn unorm8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_keeps_flat_colour_and_mips_reach_one_texel() {
        let texels: Vec<u8> = [10u8, 20, 30, 255].repeat(3 * 5);
        let out = resample(&texels, 3, 5, 8);
        assert_eq!(out.len(), 8 * 8 * 4);
        assert!(out.chunks_exact(4).all(|t| t == [10, 20, 30, 255]));
        let chain = mip_chain(out, 8);
        assert_eq!(chain.iter().map(Vec::len).collect::<Vec<_>>(), [256, 64, 16, 4]);
        assert_eq!(chain[3], [10, 20, 30, 255]);
    }

    #[test]
    fn alpha_tested_images_become_binary_and_their_mips_hold_the_opaque_fraction() {
        // A soft card: alpha ramps 0, 85, 170, 255 across; tested at 0.5, half of it is opaque.
        let mut texels: Vec<u8> = (0..16).flat_map(|i| [10, 200, 30, [0u8, 85, 170, 255][i % 4]]).collect();
        binarise_alpha(&mut texels, 0.5);
        assert_eq!(texels.chunks_exact(4).map(|t| t[3]).take(4).collect::<Vec<_>>(), [0, 0, 255, 255]);
        let chain = mip_chain(texels, 4);
        assert_eq!(chain[2][3], 128, "the 1×1 mip is half covered");
        assert_eq!(chain[2][1], 200, "colour averages as before");
    }

    /// A 2 × 2 image: `diagonal` at texels 0 and 3, `other` at 1 and 2.
    fn checker(diagonal: [u8; 4], other: [u8; 4]) -> Vec<u8> {
        (0..4).flat_map(|i| if i % 3 == 0 { diagonal } else { other }).collect()
    }

    #[test]
    fn mips_average_a_checkerboard() {
        let chain = mip_chain(checker([0, 0, 0, 0], [255; 4]), 2);
        // The transparent black texels do not darken the opaque white ones.
        assert_eq!(chain[1], [255, 255, 255, 128]);
    }

    #[test]
    fn mips_average_in_linear_light() {
        // Opaque black and white: half the light, sRGB 188, not the bytes' mean 128.
        let chain = mip_chain(checker([0, 0, 0, 255], [255; 4]), 2);
        assert_eq!(chain[1], [188, 188, 188, 255]);
    }

    #[test]
    fn trilinear_samples_blend_levels_and_repeat() {
        // 2×2: opaque white on the diagonal, transparent black elsewhere; level 1 is half covered.
        let levels = mip_chain(checker([255; 4], [0; 4]), 2);
        // At a texel centre of level 0, that texel.
        assert_eq!(sample(&levels, (2, 2), [0.25, 0.25], 0.0, Sampler::MATERIALS), [1.0; 4]);
        assert_eq!(sample(&levels, (2, 2), [0.75, 0.25], 0.0, Sampler::MATERIALS)[3], 0.0);
        // Repeat addressing: one texture further along is the same.
        assert_eq!(sample(&levels, (2, 2), [1.25, -0.75], 0.0, Sampler::MATERIALS), [1.0; 4]);
        // Between texel centres, the mean of the four.
        assert!((sample(&levels, (2, 2), [0.5, 0.5], 0.0, Sampler::MATERIALS)[3] - 0.5).abs() < 1e-6);
        // Half-way to level 1 (alpha 0.5 everywhere): the blend of 1 and 0.5.
        assert!((sample(&levels, (2, 2), [0.25, 0.25], 0.5, Sampler::MATERIALS)[3] - 0.75).abs() < 1e-2);
        assert!((sample(&levels, (2, 2), [0.25, 0.25], 7.0, Sampler::MATERIALS)[3] - 0.5).abs() < 1e-2);
        // The atlases' sampler: the nearest level, clamped at the edges.
        assert_eq!(sample(&levels, (2, 2), [0.25, 0.25], 0.4, Sampler::ATLASES), [1.0; 4]);
        assert!((sample(&levels, (2, 2), [0.25, 0.25], 0.6, Sampler::ATLASES)[3] - 0.5).abs() < 1e-2);
        assert_eq!(sample(&levels, (2, 2), [-3.0, 0.1], 0.0, Sampler::ATLASES), [1.0; 4]);
        assert_eq!(sample(&levels, (2, 2), [1.25, -0.75], 0.0, Sampler::ATLASES)[3], 0.0);
        // The alpha alone is the sample's.
        for (uv, lod) in [([0.3, 0.6], 0.0), ([0.5, 0.5], 0.3), ([-0.2, 1.7], 0.8)] {
            let full = sample(&levels, (2, 2), uv, lod, Sampler::MATERIALS)[3];
            assert_eq!(sample_alpha(&levels, (2, 2), uv, lod, Sampler::MATERIALS), full);
        }
    }

    #[test]
    fn layers_share_the_largest_side_up_to_the_limit_and_binarise_tested_images() {
        let soft: Vec<u8> = (0..16).flat_map(|i| [10, 200, 30, [0u8, 85, 170, 255][i % 4]]).collect();
        let big = vec![255u8; 600 * 300 * 4];
        let images = [Some(Texels { width: 4, height: 4, rgba: &soft }), None];
        let layers = Layers::new(&images, &[Some(0.5), None]);
        assert_eq!((layers.size, layers.mips(), layers.levels.len()), (4, 3, 2));
        assert_eq!(layers.levels[0][0].chunks_exact(4).map(|t| t[3]).take(4).collect::<Vec<_>>(), [0, 0, 255, 255]);
        let layers = Layers::new(&[Some(Texels { width: 600, height: 300, rgba: &big })], &[None]);
        assert_eq!(layers.size, MAX_LAYER);
    }
}
