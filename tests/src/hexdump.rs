//! The annotated hex dump of spec §13.1.

use std::fmt::Write as _;

use treelod_format::{Container, FLAG_SHUFFLE, FLAG_ZSTD, Result, SectionKind};

/// The record type stored in a known section kind, as the spec names it.
fn record_name(kind: SectionKind) -> Option<&'static str> {
    Some(match kind {
        SectionKind::BLOCK => "BlockRecord",
        SectionKind::CELLS => "CellRecord",
        SectionKind::VERTICES => "VertexRecord",
        SectionKind::TRIANGLES | SectionKind::PRUNE_TRIANGLES => "TriangleRecord",
        SectionKind::POINTS => "PointRecord",
        SectionKind::MATERIALS => "MaterialRecord",
        SectionKind::IMAGES => "ImageRecord",
        SectionKind::ELLIPSOIDS => "EllipsoidRecord",
        SectionKind::LINES => "LineRecord",
        SectionKind::PLANES => "PlaneRecord",
        SectionKind::PRUNE_LEAVES => "PruneLeafRecord",
        SectionKind::PRUNE_SCALE | SectionKind::PRUNE_LAMBDA => "CurveSample",
        _ => return None,
    })
}

fn plural(n: u64, what: &str) -> String {
    if n == 1 { format!("1 {what}") } else { format!("{n} {what}s") }
}

/// Appends hex lines for `bytes[start..end]`, 16 per line, each starting at its file offset.
fn hex_lines(out: &mut String, bytes: &[u8], start: usize, end: usize) {
    for line_start in (start..end).step_by(16) {
        let line = &bytes[line_start..(line_start + 16).min(end)];
        let mut hex = String::new();
        for i in 0..16 {
            if i == 8 {
                hex.push(' ');
            }
            match line.get(i) {
                Some(b) => {
                    let _ = write!(hex, "{b:02x} ");
                }
                None => hex.push_str("   "),
            }
        }
        let ascii: String =
            line.iter().map(|&b| if b.is_ascii_graphic() || b == b' ' { b as char } else { '.' }).collect();
        let _ = writeln!(out, "{line_start:08x}  {hex} |{ascii}|");
    }
}

/// The Markdown of spec §13.1 for a container file: a short legend, then one fenced block with
/// every byte of the file as a hex dump (offset, 16 bytes in hex, ASCII), where a line starting
/// with `--` marks the start of the header, of each table entry and of each section, with its
/// decoded fields.
///
/// `cargo run -p treelod-tests --bin spec-example` prints this for `tests/data/v1_0/minimal.treelod`,
/// and the test `spec_example_matches` checks that the spec holds exactly that text.
///
/// # Errors
/// Any error of [`Container::from_bytes`]: only a valid file is dumped.
pub fn spec_hex_dump(bytes: &[u8]) -> Result<String> {
    let container = Container::from_bytes(bytes)?;
    let header = container.header();
    let sections = container.sections();
    let mut out = String::new();
    let _ = writeln!(
        out,
        "The file is {} bytes: the {}-byte header, a section table of {} entries of 48 bytes at offset {},\n\
         then the sections, each starting on a multiple of 16 and followed by zero padding up to the next.\n\
         All integers are little endian. A line starting with `--` marks where a structure begins and gives\n\
         its decoded fields.",
        header.file_size,
        header.header_size,
        sections.len(),
        header.table_offset,
    );
    out.push('\n');
    out.push_str("```text\n");
    out.push_str("offset    00 01 02 03 04 05 06 07  08 09 0a 0b 0c 0d 0e 0f  ascii\n");
    // Regions in file order: (start, description); each runs to the next region's start.
    let mut regions: Vec<(u64, String)> = Vec::new();
    regions.push((
        0,
        format!(
            "header: magic, version {}.{}, header_size {}, section_count {}, table_offset {}, file_size {}, \
             flags {}, header_checksum 0x{:08x}",
            header.major,
            header.minor,
            header.header_size,
            header.section_count,
            header.table_offset,
            header.file_size,
            header.flags,
            header.header_checksum
        ),
    ));
    for (index, section) in sections.iter().enumerate() {
        let e = &section.entry;
        regions.push((
            header.table_offset + (index * 48) as u64,
            format!(
                "section table entry {index}: kind 0x{:04x} ({}), flags {}, offset {}, length {}, raw_length {}, \
                 record_size {}, checksum 0x{:08x}",
                e.kind,
                section.kind(),
                e.flags,
                e.offset,
                e.length,
                e.raw_length,
                e.record_size,
                e.checksum
            ),
        ));
    }
    let table_end = header.table_offset + (sections.len() * 48) as u64;
    if sections.first().is_none_or(|s| s.entry.offset > table_end) {
        regions.push((table_end, "zero padding".into()));
    }
    for (index, section) in sections.iter().enumerate() {
        let e = &section.entry;
        let kind = section.kind();
        let content = match (kind, record_name(kind)) {
            (SectionKind::META, _) => {
                format!("{} of postcard metadata", plural(e.raw_length, "byte"))
            }
            (SectionKind::IMAGE_DATA, _) => {
                format!("{} of texel data", plural(e.raw_length, "byte"))
            }
            (_, Some(name)) => plural(e.raw_length / u64::from(e.record_size.max(1)), name),
            (_, None) => format!("{} of an unknown kind", plural(e.raw_length, "byte")),
        };
        let stored = if e.flags & FLAG_ZSTD != 0 {
            let shuffled = if e.flags & FLAG_SHUFFLE != 0 { ", byte-shuffled" } else { "" };
            format!("a zstd frame of {} holding {content}{shuffled}", plural(e.length, "byte"))
        } else {
            content
        };
        let next = sections.get(index + 1).map_or(header.file_size, |s| s.entry.offset);
        let padding = next - (e.offset + e.length);
        let padding =
            if padding > 0 { format!(", then {} of zero padding", plural(padding, "byte")) } else { String::new() };
        regions.push((e.offset, format!("section {kind} at {}: {stored}{padding}", e.offset)));
    }
    regions.sort_by_key(|(start, _)| *start);
    for (i, (start, description)) in regions.iter().enumerate() {
        let end = regions.get(i + 1).map_or(header.file_size, |(next, _)| *next);
        let _ = writeln!(out, "-- {description}");
        #[expect(clippy::cast_possible_truncation, reason = "the file is in memory")]
        hex_lines(&mut out, bytes, *start as usize, end as usize);
    }
    out.push_str("```\n");
    Ok(out)
}
