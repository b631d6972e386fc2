//! A model's images as one texture array: every image resampled to one square layer size, with
//! a full mip chain made on the CPU. Images that materials alpha-test get a binary alpha (opaque
//! where the test passes, else transparent) before their mips are filtered, so a mip's alpha is the
//! fraction of its footprint that is opaque — what alpha to coverage (with MSAA) draws.
//!
//! Images only impostor planes sample (an atlas, spec §6.10) get no layer: they are uploaded as
//! they are stored, with their own mips, by the renderer ([`atlas`]).

use treelod_format::{Container, image_format};

/// Largest layer size; leaf textures seldom need more at the distances where triangles are drawn.
const MAX_LAYER: u32 = 512;

/// The texel layers of one model: `layers` images of `size`×`size`, each with `mips` levels,
/// level-major per layer (level 0 of layer 0, level 1 of layer 0, …).
pub(crate) struct Layers {
    pub size: u32,
    pub mips: u32,
    /// Per layer, per level, RGBA8 sRGB texels.
    pub levels: Vec<Vec<Vec<u8>>>,
    /// Per image of the container, its layer, or −1 for an image without one (an atlas).
    pub layer_of: Vec<i32>,
}

/// Decodes every image of `container`. An image that fails to decode becomes a grey layer and a
/// warning, so one bad texture does not stop a forest from drawing.
pub(crate) fn layers(container: &Container, warnings: &mut Vec<String>) -> Layers {
    // Images sampled by planes and by no material are atlases: no layer.
    let mut atlas = vec![false; container.images().len()];
    for plane in container.planes() {
        if let Some(slot) = atlas.get_mut(plane.image as usize) {
            *slot = true;
        }
    }
    for material in container.materials() {
        if let Some(slot) = atlas.get_mut(material.image as usize) {
            *slot = false;
        }
    }
    let mut decoded = Vec::new();
    let mut layer_of = Vec::with_capacity(atlas.len());
    for (index, record) in container.images().iter().enumerate() {
        if atlas[index] {
            layer_of.push(-1);
            continue;
        }
        layer_of.push(i32::try_from(decoded.len()).unwrap_or(-1));
        let start = usize::try_from(record.data_offset).unwrap_or(usize::MAX);
        let end = start.saturating_add(usize::try_from(record.data_length).unwrap_or(usize::MAX));
        let result = container
            .image_data()
            .get(start..end)
            .ok_or_else(|| "its bytes lie outside IMAGE_DATA".to_owned())
            .and_then(|data| treelod_format::image::decode(record, data));
        match result {
            Ok(image) => decoded.push(Some(image)),
            Err(e) => {
                warnings.push(format!("image {index}: {e}; drawn grey"));
                decoded.push(None);
            }
        }
    }
    let by_image = alpha_cutoffs(container, atlas.len());
    let cutoffs: Vec<Option<f32>> = (0..atlas.len()).filter(|&i| !atlas[i]).map(|i| by_image[i]).collect();
    let largest = decoded.iter().flatten().map(|i| i.width.max(i.height)).max().unwrap_or(1);
    let size = largest.next_power_of_two().clamp(1, MAX_LAYER);
    let mips = size.ilog2() + 1;
    let mut levels = Vec::with_capacity(decoded.len().max(1));
    for (image, cutoff) in decoded.iter().zip(&cutoffs) {
        let mut base = match image {
            Some(image) => resample(&image.texels, image.width, image.height, size),
            None => vec![128; (size * size * 4) as usize],
        };
        if let Some(cutoff) = cutoff {
            binarise_alpha(&mut base, *cutoff);
        }
        levels.push(mip_chain(base, size));
    }
    if levels.is_empty() {
        // A texture array needs a layer even when no material samples it.
        levels.push(mip_chain(vec![255; (size * size * 4) as usize], size));
    }
    Layers { size, mips, levels, layer_of }
}

/// An image as stored, with the mips it holds, for a texture of its own.
pub(crate) struct Atlas {
    pub width: u32,
    pub height: u32,
    /// Whether RGB is sRGB-encoded.
    pub srgb: bool,
    /// A leaf-slot image (spec §6.10.1): each texel two `u16` slots, uploaded as `Rg16Uint`.
    pub slots: bool,
    /// BC7 blocks (spec §6.7 formats 6, 7), uploaded as they are (the device has
    /// `TEXTURE_COMPRESSION_BC`); else the levels are RGBA8 texels.
    pub bc7: bool,
    /// Level by level, largest first: RGBA8 texels, or with [`Self::bc7`] rows of 16-byte blocks.
    pub levels: Vec<Vec<u8>>,
}

/// The image `index` of `container` with its stored mips (raw RGBA8 and BC7 formats), or decoded
/// with one level (PNG, JPEG). A BC7 image keeps its blocks when `bc_textures` (the device samples
/// BC formats), else it is decoded to RGBA8 on the CPU, level by level.
pub(crate) fn atlas(container: &Container, index: u32, bc_textures: bool) -> Result<Atlas, String> {
    let record = container.images().get(index as usize).ok_or_else(|| format!("image {index} does not exist"))?;
    let start = usize::try_from(record.data_offset).unwrap_or(usize::MAX);
    let end = start.saturating_add(usize::try_from(record.data_length).unwrap_or(usize::MAX));
    let data = container.image_data().get(start..end).ok_or("its bytes lie outside IMAGE_DATA")?;
    let (width, height) = (record.width.max(1), record.height.max(1));
    let srgb = image_format::is_srgb(record.format);
    match record.format {
        image_format::BC7_SRGB | image_format::BC7_LINEAR if bc_textures => {
            if !width.is_multiple_of(4) || !height.is_multiple_of(4) {
                return Err(format!("a BC7 image of {width}x{height}: its sides must be multiples of 4"));
            }
            let mut levels = Vec::new();
            let mut at = 0usize;
            for level in 0..record.mip_count.max(1) {
                let len =
                    record.level_length(level).and_then(|l| usize::try_from(l).ok()).ok_or("a level too large")?;
                let blocks = at
                    .checked_add(len)
                    .and_then(|e| data.get(at..e))
                    .ok_or_else(|| format!("mip {level} is cut short"))?;
                levels.push(blocks.to_vec());
                at += len;
            }
            Ok(Atlas { width, height, srgb, slots: false, bc7: true, levels })
        }
        image_format::RGBA8_SRGB | image_format::RGBA8_LINEAR | image_format::BC7_SRGB | image_format::BC7_LINEAR => {
            let levels = treelod_format::image::decode_levels(record, data)?;
            Ok(Atlas { width, height, srgb, slots: false, bc7: false, levels })
        }
        image_format::LEAF_SLOTS => {
            let texels = data.get(..width as usize * height as usize * 4).ok_or("the leaf slots are cut short")?;
            Ok(Atlas { width, height, srgb: false, slots: true, bc7: false, levels: vec![texels.to_vec()] })
        }
        _ => {
            let image = treelod_format::image::decode(record, data)?;
            Ok(Atlas {
                width: image.width,
                height: image.height,
                srgb: true,
                slots: false,
                bc7: false,
                levels: vec![image.texels],
            })
        }
    }
}

/// Bilinear resampling of an RGBA8 image to `size`×`size` (texel centres aligned, edges clamped).
fn resample(texels: &[u8], width: u32, height: u32, size: u32) -> Vec<u8> {
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

/// Per image, the texel alpha below which the first material that alpha-tests it discards
/// (`alpha_cutoff` for mask, 0.5 for blend — the shader draws blend as a mask — divided by the
/// material's base-colour alpha, which multiplies the texel's); `None` for images no material
/// alpha-tests.
fn alpha_cutoffs(container: &Container, images: usize) -> Vec<Option<f32>> {
    let mut cutoffs = vec![None; images];
    for material in container.materials() {
        let cutoff = match material.alpha_mode {
            1 => material.alpha_cutoff,
            2 => 0.5,
            _ => continue,
        };
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
fn binarise_alpha(rgba: &mut [u8], cutoff: f32) {
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
fn mip_chain(base: Vec<u8>, size: u32) -> Vec<Vec<u8>> {
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

fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

fn linear_to_srgb(v: f32) -> f32 {
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

    #[test]
    fn mips_average_a_checkerboard() {
        let base: Vec<u8> =
            (0..4).flat_map(|i| if i % 3 == 0 { [0u8, 0, 0, 0] } else { [255, 255, 255, 255] }).collect();
        let chain = mip_chain(base, 2);
        // The transparent black texels do not darken the opaque white ones.
        assert_eq!(chain[1], [255, 255, 255, 128]);
    }

    #[test]
    fn mips_average_in_linear_light() {
        // Opaque black and white: half the light, sRGB 188, not the bytes' mean 128.
        let base: Vec<u8> =
            (0..4).flat_map(|i| if i % 3 == 0 { [0u8, 0, 0, 255] } else { [255, 255, 255, 255] }).collect();
        let chain = mip_chain(base, 2);
        assert_eq!(chain[1], [188, 188, 188, 255]);
    }
}
