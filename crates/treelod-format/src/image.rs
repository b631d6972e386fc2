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
        image_format::BC7_SRGB | image_format::BC7_LINEAR => {
            let len = usize::try_from(record.level_length(0).unwrap_or(u64::MAX)).unwrap_or(usize::MAX);
            let level0 = data.get(..len).ok_or_else(|| format!("{} bytes, level 0 needs {len}", data.len()))?;
            (record.width, record.height, decode_bc7(record.width, record.height, level0)?)
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

/// An image's mip levels as RGBA8 texels, largest first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rgba8Levels {
    /// Texels across at level 0.
    pub width: u32,
    /// Texels down at level 0.
    pub height: u32,
    /// Level by level, each `max(1, width >> i) · max(1, height >> i) · 4` bytes.
    pub levels: Vec<Vec<u8>>,
}

/// The mip levels an image stores ([`decode_levels`] for raw and BC7 formats), or its one decoded
/// level (PNG, JPEG): what a renderer samples it with when the image is a texture of its own.
///
/// # Errors
/// As [`decode_levels`] and [`decode`].
pub fn decode_mips(record: &ImageRecord, data: &[u8]) -> Result<Rgba8Levels, String> {
    if image_format::is_bc7(record.format)
        || matches!(record.format, image_format::RGBA8_SRGB | image_format::RGBA8_LINEAR)
    {
        let levels = decode_levels(record, data)?;
        return Ok(Rgba8Levels { width: record.width.max(1), height: record.height.max(1), levels });
    }
    let image = decode(record, data)?;
    Ok(Rgba8Levels { width: image.width, height: image.height, levels: vec![image.texels] })
}

/// Every mip level of a raw (formats 1, 2) or BC7 (formats 6, 7) image as RGBA8 texels, largest
/// first, each `max(1, width >> i) · max(1, height >> i) · 4` bytes.
///
/// # Errors
/// A sentence naming what is wrong: another format, or data shorter than its levels.
pub fn decode_levels(record: &ImageRecord, data: &[u8]) -> Result<Vec<Vec<u8>>, String> {
    let bc7 = image_format::is_bc7(record.format);
    if !bc7 && !matches!(record.format, image_format::RGBA8_SRGB | image_format::RGBA8_LINEAR) {
        return Err(format!("image format {} has no stored mip levels", record.format));
    }
    let mut levels = Vec::new();
    let mut at = 0usize;
    for level in 0..record.mip_count.max(1) {
        let len = record.level_length(level).and_then(|l| usize::try_from(l).ok()).ok_or("a level too large")?;
        let bytes = at.checked_add(len).and_then(|end| data.get(at..end)).ok_or_else(|| {
            format!("mip {level} is cut short: {} bytes of data, the levels up to it need {}", data.len(), at + len)
        })?;
        let (w, h) = record.level_size(level);
        levels.push(if bc7 { decode_bc7(w, h, bytes)? } else { bytes.to_vec() });
        at += len;
    }
    Ok(levels)
}

/// Decodes one BC7 level of `width × height` texels (any size: the blocks at the right and bottom
/// edges are partly outside it) to RGBA8, `width · height · 4` bytes.
///
/// # Errors
/// A sentence saying that `blocks` is not `ceil(width / 4) · ceil(height / 4)` blocks of 16 bytes.
pub fn decode_bc7(width: u32, height: u32, blocks: &[u8]) -> Result<Vec<u8>, String> {
    let (bw, bh) = (width.div_ceil(4) as usize, height.div_ceil(4) as usize);
    let expected = bw * bh * 16;
    if blocks.len() != expected {
        return Err(format!(
            "{} bytes of BC7 blocks, a {width}x{height} level needs {expected} ({bw}x{bh} blocks of 16 bytes)",
            blocks.len()
        ));
    }
    // Decoded at whole blocks, then cropped: the decoder writes full 4x4 blocks.
    let (pw, ph) = (bw * 4, bh * 4);
    let mut padded = vec![0u8; pw * ph * 4];
    let variant = block_compression::CompressionVariant::BC7(block_compression::BC7Settings::alpha_basic());
    #[expect(clippy::cast_possible_truncation, reason = "sides at most 16384 + 3")]
    block_compression::decode::decompress_blocks_as_rgba8(variant, pw as u32, ph as u32, blocks, &mut padded);
    if (pw, ph) == (width as usize, height as usize) {
        return Ok(padded);
    }
    let row = width as usize * 4;
    Ok((0..height as usize).flat_map(|y| &padded[y * pw * 4..y * pw * 4 + row]).copied().collect())
}

/// The width and height an encoded PNG or JPEG declares in its header, read without decoding
/// any pixel, so that a caller can refuse an image too large before allocating for it (a small
/// file may declare billions of pixels). `None` for bytes that are neither PNG nor JPEG.
///
/// # Errors
/// A sentence saying why the header does not read.
pub fn encoded_size(bytes: &[u8]) -> Option<Result<(u32, u32), String>> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        return Some(decoder.read_info().map(|r| (r.info().width, r.info().height)).map_err(|e| png_message(&e)));
    }
    if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        let mut decoder = jpeg_decoder::Decoder::new(std::io::Cursor::new(bytes));
        return Some(match decoder.read_info() {
            Ok(()) => decoder
                .info()
                .map(|i| (u32::from(i.width), u32::from(i.height)))
                .ok_or_else(|| "not a valid JPEG: no frame header".to_owned()),
            Err(e) => Err(format!("not a valid JPEG: {e}")),
        });
    }
    None
}

/// A PNG decoder's error as one readable sentence: the decoder writes chunk types as Rust debug
/// structs (`ChunkType { type: IHDR, critical: true, … }`), which become their four letters.
fn png_message(error: &png::DecodingError) -> String {
    const MARK: &str = "ChunkType { type: ";
    let mut text = error.to_string();
    while let Some(start) = text.find(MARK) {
        let rest = &text[start + MARK.len()..];
        let (Some(comma), Some(close)) = (rest.find(','), rest.find('}')) else { break };
        let name = rest[..comma.min(close)].to_owned();
        let end = start + MARK.len() + close + 1;
        text.replace_range(start..end, &name);
    }
    format!("not a valid PNG: {text}")
}

/// Decodes a PNG file to RGBA8 texels (16-bit channels stripped, palettes and grey expanded).
///
/// # Errors
/// A sentence saying why the bytes are not a PNG this decoder reads.
pub fn decode_png(bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| png_message(&e))?;
    let size = reader.output_buffer_size().ok_or("image too large")?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| png_message(&e))?;
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
    // The decoder's own bound, beside the callers' check of the header (`encoded_size`): no
    // image a container may hold needs more (4 bytes per texel at the largest side).
    let side = crate::records::MAX_IMAGE_SIDE as usize;
    decoder.set_max_decoding_buffer_size(side * side * 4);
    let pixels = decoder.decode().map_err(|e| format!("not a valid JPEG: {e}"))?;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn png_2x1() -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, 2, 1);
        encoder.set_color(png::ColorType::Rgba);
        let mut writer = encoder.write_header().expect("header");
        writer.write_image_data(&[1, 2, 3, 4, 5, 6, 7, 8]).expect("data");
        writer.finish().expect("finish");
        out
    }

    #[test]
    fn the_header_gives_the_size_without_decoding() {
        let png = png_2x1();
        assert_eq!(encoded_size(&png), Some(Ok((2, 1))));
        assert_eq!(encoded_size(b"GIF89a"), None);
        // A PNG declaring 30000 x 30000 pixels over 2 pixels of data: its size reads.
        let mut huge = png.clone();
        huge[16..20].copy_from_slice(&30_000u32.to_be_bytes());
        huge[20..24].copy_from_slice(&30_000u32.to_be_bytes());
        let crc = crc32fast::hash(&huge[12..29]);
        huge[29..33].copy_from_slice(&crc.to_be_bytes());
        assert_eq!(encoded_size(&huge), Some(Ok((30_000, 30_000))));
    }

    #[test]
    fn a_corrupt_png_is_one_readable_sentence() {
        let mut png = png_2x1();
        png[17] ^= 0xFF; // the IHDR width: its CRC no longer matches
        for message in [decode_png(&png).unwrap_err(), encoded_size(&png).and_then(Result::err).unwrap_or_default()] {
            assert!(message.starts_with("not a valid PNG: "), "{message}");
            assert!(message.contains("IHDR"), "{message}");
            assert!(!message.contains('{'), "{message}");
        }
    }
}
