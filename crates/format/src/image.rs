//! Decoding the container's encoded images (spec §6.7) to RGBA8 texels, for tools and renderers.
//! Behind the `images` feature, so the reader itself needs no image codec.

use crate::records::{ImageRecord, image_format};

/// An image decoded to RGBA8.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rgba8 {
    /// Texels across.
    pub width: u32,
    /// Texels down.
    pub height: u32,
    /// `width · height · 4` bytes, rows top to bottom; RGB as stored (sRGB for colour images).
    pub texels: Vec<u8>,
}

/// Decodes image `record` whose bytes are `data` (its slice of `IMAGE_DATA`), level 0 only.
///
/// # Errors
/// A sentence naming what is wrong: an unknown format, a `LEAF_SLOTS` image (leaf slots, not a
/// colour image: read its texels with [`crate::leaf_slots`]), a size that disagrees with the
/// record, or bytes the codec refuses.
pub fn decode(record: &ImageRecord, data: &[u8]) -> Result<Rgba8, String> {
    let (width, height, texels) = match record.format {
        image_format::RGBA8_SRGB | image_format::RGBA8_LINEAR => {
            let len = record.width as usize * record.height as usize * 4;
            let level0 = data.get(..len).ok_or_else(|| format!("{} bytes, level 0 needs {len}", data.len()))?;
            (record.width, record.height, level0.to_vec())
        }
        image_format::PNG => decode_png(data)?,
        image_format::JPEG => decode_jpeg(data)?,
        image_format::LEAF_SLOTS => {
            return Err(format!(
                "a {}x{} LEAF_SLOTS image holds leaf slots of indirectly textured planes (spec §6.10.1), \
                 not colours: it is not a colour image",
                record.width, record.height
            ));
        }
        other => return Err(format!("image format {other} is not defined by this version")),
    };
    if (width, height) != (record.width, record.height) {
        return Err(format!("decodes to {width}x{height}, the record says {}x{}", record.width, record.height));
    }
    Ok(Rgba8 { width, height, texels })
}

/// Decodes a PNG file to RGBA8 texels (16-bit channels stripped, palettes and grey expanded).
///
/// # Errors
/// A sentence saying why the bytes are not a PNG this decoder reads.
pub fn decode_png(bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let size = reader.output_buffer_size().ok_or("image too large")?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    let pixels = &buf[..info.buffer_size()];
    let rgba: Vec<u8> = match info.color_type {
        png::ColorType::Rgba => pixels.to_vec(),
        png::ColorType::Rgb => pixels.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        png::ColorType::GrayscaleAlpha => pixels.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0], p[1]]).collect(),
        png::ColorType::Grayscale => pixels.iter().flat_map(|&g| [g, g, g, 255]).collect(),
        png::ColorType::Indexed => return Err("indexed colour was not expanded".into()),
    };
    Ok((info.width, info.height, rgba))
}

/// Decodes a baseline or progressive JPEG file to RGBA8 texels (alpha 255).
///
/// # Errors
/// A sentence saying why the bytes are not a JPEG this decoder reads.
pub fn decode_jpeg(bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), String> {
    let mut decoder = jpeg_decoder::Decoder::new(std::io::Cursor::new(bytes));
    let pixels = decoder.decode().map_err(|e| e.to_string())?;
    let info = decoder.info().ok_or("no image information")?;
    let rgba: Vec<u8> = match info.pixel_format {
        jpeg_decoder::PixelFormat::RGB24 => pixels.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        jpeg_decoder::PixelFormat::L8 => pixels.iter().flat_map(|&g| [g, g, g, 255]).collect(),
        jpeg_decoder::PixelFormat::L16 => pixels.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0], 255]).collect(),
        jpeg_decoder::PixelFormat::CMYK32 => pixels
            .chunks_exact(4)
            .flat_map(|p| {
                let k = u16::from(255 - p[3]);
                let c = |v: u8| ((u16::from(255 - v) * k) / 255) as u8;
                [c(p[0]), c(p[1]), c(p[2]), 255]
            })
            .collect(),
    };
    Ok((u32::from(info.width), u32::from(info.height), rgba))
}
