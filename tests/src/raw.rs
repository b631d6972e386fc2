//! Byte-level access to a container file, for hostile-input tests: read and patch the header and
//! the section table in place and recompute the checksums so a patch reaches the checks behind
//! them, or take a file apart into [`Part`]s and lay it out again with [`layout`].
//!
//! Nothing here validates: these helpers exist to make invalid files.
//!
//! ```
//! use treelod_format::{Compression, Container, Error, SectionKind};
//! use treelod_tests::raw::RawFile;
//! use treelod_tests::{SyntheticOptions, synthetic};
//!
//! let bytes = synthetic(1, &SyntheticOptions::minimal()).to_bytes(Compression::None)?;
//! let mut file = RawFile::new(bytes);
//! let cells = file.find(SectionKind::CELLS).unwrap();
//! file.patch_entry(cells, |e| e.record_size = 64); // the header checksum is recomputed
//! assert!(matches!(Container::from_bytes(&file.bytes), Err(Error::BadSection { .. })));
//! # Ok::<(), treelod_format::Error>(())
//! ```

use core::ops::Range;

use treelod_format::{
    HEADER_SIZE, Header, MAGIC, MAJOR, MINOR, SECTION_ALIGN, SECTION_ENTRY_SIZE, SectionEntry, SectionKind,
};

/// A container file as bytes, with accessors for its header and section table.
///
/// The accessors read the header and table as the bytes say, without checks; they panic (as a test
/// helper may) only when the bytes are too short to hold what is asked for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawFile {
    /// The whole file.
    pub bytes: Vec<u8>,
}

/// The header checksum the bytes should carry (spec §3): CRC-32 of the header with the checksum
/// field taken as zero (`header_size` bytes, clamped to the file), then the section table (clamped
/// to the file).
#[must_use]
pub fn header_checksum(bytes: &[u8]) -> u32 {
    let header: Header = bytemuck::pod_read_unaligned(&bytes[..HEADER_SIZE]);
    let header_end = (header.header_size as usize).clamp(HEADER_SIZE, bytes.len());
    let table_start = usize::try_from(header.table_offset).unwrap_or(usize::MAX).min(bytes.len());
    let table_len = header.section_count as usize * SECTION_ENTRY_SIZE;
    let table_end = table_start.saturating_add(table_len).min(bytes.len());
    let mut crc = crc32fast::Hasher::new();
    crc.update(&bytes[..60]);
    crc.update(&[0; 4]);
    crc.update(&bytes[HEADER_SIZE..header_end]);
    crc.update(&bytes[table_start..table_end]);
    crc.finalize()
}

impl RawFile {
    /// Wraps file bytes.
    #[must_use]
    pub fn new(bytes: Vec<u8>) -> Self {
        Self { bytes }
    }

    /// The file bytes.
    #[must_use]
    pub fn into_bytes(self) -> Vec<u8> {
        self.bytes
    }

    /// The header as stored.
    #[must_use]
    pub fn header(&self) -> Header {
        bytemuck::pod_read_unaligned(&self.bytes[..HEADER_SIZE])
    }

    /// Overwrites the header bytes (checksum as given: call [`Self::reseal`] to fix it).
    pub fn set_header(&mut self, header: Header) {
        self.bytes[..HEADER_SIZE].copy_from_slice(bytemuck::bytes_of(&header));
    }

    /// Number of entries the header announces.
    #[must_use]
    pub fn section_count(&self) -> usize {
        self.header().section_count as usize
    }

    /// Byte offset of table entry `index`.
    #[must_use]
    pub fn entry_offset(&self, index: usize) -> usize {
        self.header().table_offset as usize + index * SECTION_ENTRY_SIZE
    }

    /// Table entry `index` as stored.
    #[must_use]
    pub fn entry(&self, index: usize) -> SectionEntry {
        let at = self.entry_offset(index);
        bytemuck::pod_read_unaligned(&self.bytes[at..at + SECTION_ENTRY_SIZE])
    }

    /// Every table entry, in table order.
    #[must_use]
    pub fn entries(&self) -> Vec<SectionEntry> {
        (0..self.section_count()).map(|i| self.entry(i)).collect()
    }

    /// Overwrites table entry `index` (header checksum as before: call [`Self::reseal`]).
    pub fn set_entry(&mut self, index: usize, entry: SectionEntry) {
        let at = self.entry_offset(index);
        self.bytes[at..at + SECTION_ENTRY_SIZE].copy_from_slice(bytemuck::bytes_of(&entry));
    }

    /// Index of the first table entry of `kind`.
    #[must_use]
    pub fn find(&self, kind: SectionKind) -> Option<usize> {
        self.entries().iter().position(|e| e.kind == kind.0)
    }

    /// The byte range of section `index`'s stored payload.
    #[must_use]
    pub fn payload_range(&self, index: usize) -> Range<usize> {
        let entry = self.entry(index);
        entry.offset as usize..entry.offset.saturating_add(entry.length) as usize
    }

    /// Section `index`'s stored payload.
    #[must_use]
    pub fn payload(&self, index: usize) -> &[u8] {
        let range = self.payload_range(index);
        &self.bytes[range]
    }

    /// Section `index`'s stored payload, writable (checksums as before: see [`Self::reseal_section`]).
    pub fn payload_mut(&mut self, index: usize) -> &mut [u8] {
        let range = self.payload_range(index);
        &mut self.bytes[range]
    }

    /// Recomputes the header checksum over the current header and table.
    pub fn reseal(&mut self) {
        let crc = header_checksum(&self.bytes);
        self.bytes[60..64].copy_from_slice(&crc.to_le_bytes());
    }

    /// Recomputes section `index`'s checksum from its stored bytes, then the header checksum.
    pub fn reseal_section(&mut self, index: usize) {
        let mut entry = self.entry(index);
        entry.checksum = crc32fast::hash(self.payload(index));
        self.set_entry(index, entry);
        self.reseal();
    }

    /// Changes the header with `patch`, then recomputes the header checksum.
    pub fn patch_header(&mut self, patch: impl FnOnce(&mut Header)) {
        let mut header = self.header();
        patch(&mut header);
        self.set_header(header);
        self.reseal();
    }

    /// Changes table entry `index` with `patch`, then recomputes the header checksum.
    pub fn patch_entry(&mut self, index: usize, patch: impl FnOnce(&mut SectionEntry)) {
        let mut entry = self.entry(index);
        patch(&mut entry);
        self.set_entry(index, entry);
        self.reseal();
    }

    /// The sections taken apart, in table order.
    #[must_use]
    pub fn parts(&self) -> Vec<Part> {
        self.entries()
            .iter()
            .enumerate()
            .map(|(i, e)| Part {
                kind: e.kind,
                flags: e.flags,
                raw_length: e.raw_length,
                record_size: e.record_size,
                stored: self.payload(i).to_vec(),
            })
            .collect()
    }
}

/// One section of a file taken apart: everything [`layout`] needs to write it again.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Part {
    /// Section kind.
    pub kind: u32,
    /// Section flags as stored.
    pub flags: u32,
    /// Declared decoded length.
    pub raw_length: u64,
    /// Declared record size.
    pub record_size: u32,
    /// The stored payload.
    pub stored: Vec<u8>,
}

impl Part {
    /// An uncompressed part: `raw_length` is the payload's length.
    #[must_use]
    pub fn plain(kind: SectionKind, record_size: u32, stored: Vec<u8>) -> Self {
        Self { kind: kind.0, flags: 0, raw_length: stored.len() as u64, record_size, stored }
    }
}

/// Lays `parts` out as the writer does (spec §1): the 64-byte header, the table at offset 64, each
/// payload in the given order at the next multiple of 16 with zero padding, and fills in offsets,
/// lengths, checksums, `file_size` and the header checksum. Nothing is validated, so the result
/// is as valid as the parts are.
#[must_use]
pub fn layout(parts: &[Part]) -> Vec<u8> {
    let table_offset = HEADER_SIZE as u64;
    let mut offset = table_offset + (parts.len() * SECTION_ENTRY_SIZE) as u64;
    let mut entries = Vec::with_capacity(parts.len());
    for part in parts {
        offset = offset.div_ceil(SECTION_ALIGN) * SECTION_ALIGN;
        entries.push(SectionEntry {
            kind: part.kind,
            flags: part.flags,
            offset,
            length: part.stored.len() as u64,
            raw_length: part.raw_length,
            record_size: part.record_size,
            checksum: crc32fast::hash(&part.stored),
            reserved: 0,
        });
        offset += part.stored.len() as u64;
    }
    let header = Header {
        magic: MAGIC,
        major: MAJOR,
        // The smallest minor whose kinds the file holds (spec §11), as the writer marks it.
        minor: parts.iter().map(|p| SectionKind(p.kind).since_minor()).max().unwrap_or(0).min(MINOR),
        header_size: HEADER_SIZE as u32,
        section_count: parts.len() as u32,
        table_offset,
        file_size: offset,
        flags: 0,
        reserved: [0; 16],
        header_checksum: 0,
    };
    let mut bytes = bytemuck::bytes_of(&header).to_vec();
    bytes.extend_from_slice(bytemuck::cast_slice(&entries));
    for (entry, part) in entries.iter().zip(parts) {
        bytes.resize(entry.offset as usize, 0);
        bytes.extend_from_slice(&part.stored);
    }
    let mut file = RawFile::new(bytes);
    file.reseal();
    file.into_bytes()
}

#[cfg(test)]
mod tests {
    use treelod_format::Compression;

    use super::*;
    use crate::{SyntheticOptions, synthetic};

    #[test]
    fn taking_a_file_apart_and_laying_it_out_again_gives_the_same_bytes() {
        for compression in [Compression::None, Compression::Zstd { level: 3 }] {
            let bytes = synthetic(5, &SyntheticOptions::everything()).to_bytes(compression).unwrap();
            let file = RawFile::new(bytes.clone());
            assert_eq!(header_checksum(&bytes), file.header().header_checksum);
            assert_eq!(layout(&file.parts()), bytes);
        }
    }
}
