//! A model's images as one texture array: every image resampled to one square layer size, with
//! a full mip chain made on the CPU (`treelod_runtime::texels`, which the build's calibration
//! samples too). Images that materials alpha-test get a binary alpha (opaque
//! where the test passes, else transparent) before their mips are filtered, so a mip's alpha is the
//! fraction of its footprint that is opaque — what alpha to coverage (with MSAA) draws.
//!
//! Images only impostor planes sample (an atlas, spec §6.10) get no layer: they are uploaded as
//! they are stored, with their own mips, by the renderer ([`atlas`]).

use treelod_format::image::Rgba8Levels;
use treelod_format::{Container, image_format};
use treelod_runtime::texels::{self, Texels, alpha_cutoffs, atlas_only};

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
    let atlas = atlas_only(container.images().len(), container.materials(), container.planes());
    let mut decoded = Vec::new();
    let mut layer_of = Vec::with_capacity(atlas.len());
    for (index, record) in container.images().iter().enumerate() {
        if atlas[index] {
            layer_of.push(-1);
            continue;
        }
        layer_of.push(i32::try_from(decoded.len()).unwrap_or(-1));
        let result = record
            .bytes(container.image_data())
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
    let by_image = alpha_cutoffs(container.materials(), atlas.len());
    let cutoffs: Vec<Option<f32>> = (0..atlas.len()).filter(|&i| !atlas[i]).map(|i| by_image[i]).collect();
    let images: Vec<Option<Texels<'_>>> = decoded
        .iter()
        .map(|image| image.as_ref().map(|i| Texels { width: i.width, height: i.height, rgba: &i.texels }))
        .collect();
    let texels::Layers { size, levels } = texels::Layers::new(&images, &cutoffs);
    Layers { size, mips: size.ilog2() + 1, levels, layer_of }
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
    let data = record.bytes(container.image_data()).ok_or("its bytes lie outside IMAGE_DATA")?;
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
        image_format::LEAF_SLOTS => {
            let texels = data.get(..width as usize * height as usize * 4).ok_or("the leaf slots are cut short")?;
            Ok(Atlas { width, height, srgb: false, slots: true, bc7: false, levels: vec![texels.to_vec()] })
        }
        // The stored levels, or the one level a PNG or JPEG decodes to.
        _ => {
            let Rgba8Levels { width, height, levels } = treelod_format::image::decode_mips(record, data)?;
            Ok(Atlas { width, height, srgb, slots: false, bc7: false, levels })
        }
    }
}
