//! Hostile input, after meshoptimizer's decoder tests: every corruption of a valid file gives a
//! typed error of the right class (never a panic), found before the reader allocates more than
//! the file justifies.
//!
//! A counting global allocator records the process's peak of live heap bytes while a hostile
//! file is opened and verified (the reader decodes sections on rayon's workers, so the calling
//! thread's own peak would not see them); every case asserts that peak stays under 64 × the file
//! size plus a small constant, so a lying length can never make the reader allocate what the file
//! does not back. Each test runs alone among this binary's tests ([`exclusive`]), so the peak is
//! its own under `cargo test`'s threads too.

use std::panic::{AssertUnwindSafe, catch_unwind};

use treelod_format::{
    Compression, Container, ContainerData, Error, ErrorClass, FLAG_SHUFFLE, FLAG_ZSTD, OpenOptions, PlaneLeafRecord,
    SectionKind, image_format, verify,
};
use treelod_tests::alloc::{self, CountingAllocator, exclusive};
use treelod_tests::raw::{Part, RawFile, layout};
use treelod_tests::{SyntheticOptions, synthetic};

// ---------------------------------------------------------------------------------------------
// Allocation accounting

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// Runs `f` and returns its result with the peak of extra live heap bytes in the process
/// meanwhile (the caller's test holds [`exclusive`]).
fn peak_during<R>(f: impl FnOnce() -> R) -> (R, usize) {
    let (result, peak) = alloc::peak_during(f);
    (result, peak.process)
}

/// Heap a reader may use beyond 64 × the file size: error messages, the section list, metadata.
const SLACK: usize = 64 << 10;

// ---------------------------------------------------------------------------------------------
// Fixtures and checks

/// A small valid file (a few KiB) with every kind of section, named "hostile".
fn small_options() -> SyntheticOptions {
    SyntheticOptions { name: Some("hostile".into()), ..SyntheticOptions::small() }
}

fn small_data() -> ContainerData {
    synthetic(0x0405_711E, &small_options())
}

/// The uncompressed and the compressed variant of the small file.
fn variants() -> [(&'static str, Vec<u8>); 2] {
    let data = small_data();
    [
        ("uncompressed", data.to_bytes(Compression::None).expect("writes")),
        ("compressed", data.to_bytes(Compression::Zstd { level: 19 }).expect("writes")),
    ]
}

fn compressed() -> Vec<u8> {
    small_data().to_bytes(Compression::Zstd { level: 19 }).expect("writes")
}

/// Opens `bytes` and, if that succeeds, verifies the container; panics are caught and reported
/// with `case`, and the peak heap use is checked against the file size.
fn open_and_verify(case: &str, bytes: &[u8], options: &OpenOptions) -> Result<(), Error> {
    let (result, peak) = peak_during(|| {
        catch_unwind(AssertUnwindSafe(|| {
            let container = Container::from_bytes_with(bytes, options)?;
            verify(&container).map(|_| ())
        }))
    });
    let limit = 64 * bytes.len() + SLACK;
    assert!(peak <= limit, "{case}: peak heap {peak} bytes for a {}-byte file (limit {limit})", bytes.len());
    result.unwrap_or_else(|_| panic!("{case}: the reader panicked"))
}

/// The error of opening `bytes` (open alone must refuse it), checked for panics and heap use.
fn open_error(case: &str, bytes: &[u8]) -> Error {
    open_error_with(case, bytes, &OpenOptions::default())
}

fn open_error_with(case: &str, bytes: &[u8], options: &OpenOptions) -> Error {
    let (result, peak) =
        peak_during(|| catch_unwind(AssertUnwindSafe(|| Container::from_bytes_with(bytes, options).map(|_| ()))));
    let limit = 64 * bytes.len() + SLACK;
    assert!(peak <= limit, "{case}: peak heap {peak} bytes for a {}-byte file (limit {limit})", bytes.len());
    match result {
        Err(_) => panic!("{case}: the reader panicked"),
        Ok(Ok(())) => panic!("{case}: open accepted the file"),
        Ok(Err(e)) => e,
    }
}

/// Open or verify must refuse `bytes`.
fn rejected(case: &str, bytes: &[u8]) -> Error {
    match open_and_verify(case, bytes, &OpenOptions::default()) {
        Ok(()) => panic!("{case}: open and verify accepted the file"),
        Err(e) => e,
    }
}

fn assert_invalid(case: &str, err: &Error) {
    assert_eq!(err.class(), ErrorClass::Invalid, "{case}: {err}");
    assert!(!err.to_string().is_empty());
}

fn index_of(file: &RawFile, kind: SectionKind) -> usize {
    file.find(kind).unwrap_or_else(|| panic!("{kind} present"))
}

fn compressed_index(file: &RawFile, record_size_above_one: bool) -> usize {
    file.entries()
        .iter()
        .position(|e| {
            e.flags & FLAG_ZSTD != 0
                && SectionKind(e.kind).record_size().is_some()
                && (e.record_size > 1) == record_size_above_one
        })
        .expect("the compressed fixture has such a section")
}

// ---------------------------------------------------------------------------------------------
// Length

#[test]
fn fixtures_are_small_and_valid() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        // Under 10 KiB: 8 KiB until 1.12's tables of the added techniques (CALIBRATION_ADDED,
        // CALIBRATION_ELEVATIONS_ADDED) took it past 8.4 KiB, 9 KiB until 1.18's chain levels' FLIP
        // error (CHAIN_CALIBRATION_FLIP) took the uncompressed one past 9.1 KiB.
        assert!(bytes.len() < 10 << 10, "{name} fixture is {} bytes", bytes.len());
        open_and_verify(name, &bytes, &OpenOptions::default()).unwrap();
    }
    let file = RawFile::new(compressed());
    // Indirectly textured planes: PLANE_LEAVES and a LEAF_SLOTS image (spec §6.10.1).
    assert!(file.find(SectionKind::PLANE_LEAVES).is_some());
    assert!(small_data().images.iter().any(|i| i.format == image_format::LEAF_SLOTS));
    let flags: Vec<u32> = file.entries().iter().map(|e| e.flags).collect();
    assert!(flags.contains(&(FLAG_ZSTD | FLAG_SHUFFLE)), "a shuffled section: {flags:?}");
    assert!(flags.contains(&FLAG_ZSTD), "a plain zstd section: {flags:?}");
}

#[test]
fn every_prefix_is_truncated() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        for len in 0..bytes.len() {
            let case = format!("{name} prefix of {len} bytes");
            let err = open_error(&case, &bytes[..len]);
            assert!(matches!(err, Error::Truncated { .. }), "{case}: {err:?}");
            assert_invalid(&case, &err);
        }
    }
}

#[test]
fn trailing_bytes_are_refused() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        for (extra, fill) in [(1usize, 0u8), (15, 0), (16, 0xFF), (4096, 0)] {
            let mut longer = bytes.clone();
            longer.resize(bytes.len() + extra, fill);
            let case = format!("{name} + {extra} bytes");
            let err = open_error(&case, &longer);
            assert!(
                matches!(err, Error::TrailingBytes { extra: e, file_size } if e == extra as u64 && file_size == bytes.len() as u64),
                "{case}: {err:?}"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Magic and version

#[test]
fn bad_magic_is_refused() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    for i in 0..12 {
        let mut bad = bytes.clone();
        bad[i] ^= 0x20;
        let err = open_error(&format!("magic byte {i}"), &bad);
        assert!(matches!(err, Error::BadMagic { found } if found[..] == bad[..12]), "{err:?}");
    }
    for (case, other) in [
        ("text", b"hello, world\n".to_vec()),
        ("png", b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR".to_vec()),
        ("zeros", vec![0; 64]),
        ("zeros, long", vec![0; 4096]),
        ("one byte", vec![0x00]),
        ("a different magic prefix", vec![0x89, b'T', b'R', b'E', b'E', b'X']),
    ] {
        let err = open_error(case, &other);
        assert!(matches!(err, Error::BadMagic { .. }), "{case}: {err:?}");
        assert_invalid(case, &err);
    }
}

#[test]
fn text_mode_mangling_is_detected_by_the_magic() {
    let _alone = exclusive();
    fn replace(bytes: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(bytes.len() * 2);
        let mut i = 0;
        while i < bytes.len() {
            if bytes[i..].starts_with(from) {
                out.extend_from_slice(to);
                i += from.len();
            } else {
                out.push(bytes[i]);
                i += 1;
            }
        }
        out
    }
    for (name, bytes) in variants() {
        let manglings = [
            ("CRLF -> LF", replace(&bytes, b"\r\n", b"\n")),
            ("LF -> CRLF", replace(&bytes, b"\n", b"\r\n")),
            ("7-bit transfer", bytes.iter().map(|b| b & 0x7F).collect()),
        ];
        for (what, mangled) in manglings {
            let case = format!("{name}: {what}");
            let err = open_error(&case, &mangled);
            assert!(matches!(err, Error::BadMagic { .. }), "{case}: {err:?}");
        }
        // A DOS reader stops at ^Z: what remains is a truncated header.
        let cut = bytes.iter().position(|&b| b == 0x1A).unwrap();
        let err = open_error("cut at ^Z", &bytes[..cut]);
        assert!(matches!(err, Error::Truncated { .. }), "{err:?}");
    }
}

#[test]
fn other_major_versions_are_unsupported() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    // The fixture holds the chain levels' FLIP error (CHAIN_CALIBRATION_FLIP), so it is a 1.18
    // file.
    let minor = Container::from_bytes(&bytes).unwrap().header().minor;
    assert_eq!(minor, 18);
    for major in [0u16, 2, 3, u16::MAX] {
        for reseal in [false, true] {
            let mut file = RawFile::new(bytes.clone());
            let mut header = file.header();
            header.major = major;
            file.set_header(header);
            if reseal {
                file.reseal();
            }
            let case = format!("major {major}");
            let err = open_error(&case, &file.bytes);
            assert!(
                matches!(err, Error::UnsupportedVersion { major: m, minor: n, supported: 1, .. } if m == major && n == minor),
                "{case}: {err:?}"
            );
            assert_eq!(err.class(), ErrorClass::Unsupported, "{case}");
            let message = err.to_string();
            assert!(message.contains(&format!("{major}.{minor}")) && message.contains("1.x"), "{case}: {message}");
        }
    }
    // A later minor version of the same major is read.
    let mut file = RawFile::new(bytes);
    file.patch_header(|h| h.minor = 7);
    let container = Container::from_bytes(&file.bytes).unwrap();
    assert_eq!(ContainerData::from_container(&container), small_data());
}

// ---------------------------------------------------------------------------------------------
// Header and table fields

#[test]
fn header_bit_flips_are_refused() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        for bit in 0..64 * 8 {
            let mut bad = bytes.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            let case = format!("{name}: header bit {bit}");
            let err = open_error(&case, &bad);
            let byte = bit / 8;
            match byte {
                0..12 => assert!(matches!(err, Error::BadMagic { .. }), "{case}: {err:?}"),
                12..14 => assert_eq!(err.class(), ErrorClass::Unsupported, "{case}: {err:?}"),
                _ => assert!(
                    matches!(err, Error::ChecksumMismatch { .. } | Error::BadHeader { .. } | Error::Truncated { .. }),
                    "{case}: {err:?}"
                ),
            }
        }
    }
}

#[test]
fn table_bit_flips_are_caught_by_the_header_checksum() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        let file = RawFile::new(bytes.clone());
        let table = file.entry_offset(0)..file.entry_offset(file.section_count());
        for bit in table.start * 8..table.end * 8 {
            let mut bad = bytes.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            let case = format!("{name}: table bit {bit}");
            let err = open_error(&case, &bad);
            assert!(matches!(err, Error::ChecksumMismatch { .. }), "{case}: {err:?}");
        }
    }
}

#[test]
fn resealed_table_bit_flips_never_panic() {
    let _alone = exclusive();
    // With the header checksum recomputed, a flip reaches the table rules: most are refused,
    // a few (reserved fields, an uncompressed section's checksum) only by verify, and a kind
    // turned unknown may be skipped; none may panic or allocate beyond the file's size.
    for (name, bytes) in variants() {
        let file = RawFile::new(bytes.clone());
        for index in 0..file.section_count() {
            let start = file.entry_offset(index);
            for bit in 0..48 * 8 {
                let mut bad = RawFile::new(bytes.clone());
                bad.bytes[start + bit / 8] ^= 1 << (bit % 8);
                bad.reseal();
                let case = format!("{name}: entry {index} bit {bit}, resealed");
                if let Err(err) = open_and_verify(&case, &bad.bytes, &OpenOptions::default()) {
                    assert!(!err.to_string().is_empty());
                    let field = bit / 8;
                    // Offsets, lengths and record sizes out of place are always caught at open.
                    if (8..32).contains(&field) && matches!(err.class(), ErrorClass::Io) {
                        panic!("{case}: {err:?}");
                    }
                }
            }
        }
    }
}

#[test]
fn every_single_bit_flip_is_rejected_by_open_or_verify() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        let file = RawFile::new(bytes.clone());
        // Sections open reads at every open: a flip there is caught by open itself.
        let mut open_checked = vec![false; bytes.len()];
        open_checked[..file.entry_offset(file.section_count())].fill(true);
        for (index, entry) in file.entries().iter().enumerate() {
            let kind = SectionKind(entry.kind);
            let read_at_open = matches!(kind, SectionKind::META | SectionKind::BLOCK | SectionKind::CELLS)
                || (entry.flags & FLAG_ZSTD != 0 && kind.record_size().is_some());
            if read_at_open {
                open_checked[file.payload_range(index)].fill(true);
            }
        }
        for bit in 0..bytes.len() * 8 {
            let byte = bit / 8;
            let mut bad = bytes.clone();
            bad[byte] ^= 1 << (bit % 8);
            let case = format!("{name}: bit {bit} (byte {byte})");
            if open_checked[byte] {
                let _ = open_error(&case, &bad);
            } else {
                let _ = rejected(&case, &bad);
            }
        }
    }
}

#[test]
fn oversize_counts_and_lengths_are_refused() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    let file = RawFile::new(bytes.clone());
    let cells = index_of(&file, SectionKind::CELLS);
    let block = index_of(&file, SectionKind::BLOCK);
    let file_size = bytes.len() as u64;
    type Patch = Box<dyn Fn(&mut treelod_format::SectionEntry)>;
    let table_cases: Vec<(&str, usize, Patch)> = vec![
        ("CELLS record_size 81", cells, Box::new(|e| e.record_size = 81)),
        ("CELLS record_size 1", cells, Box::new(|e| e.record_size = 1)),
        ("CELLS record_size u32::MAX", cells, Box::new(|e| e.record_size = u32::MAX)),
        ("CELLS raw_length lie", cells, Box::new(|e| e.raw_length += 80)),
        ("CELLS raw_length huge", cells, Box::new(|e| e.raw_length = u64::MAX / 80 * 80)),
        (
            "CELLS length and raw_length + 80",
            cells,
            Box::new(|e| (e.length, e.raw_length) = (e.length + 80, e.raw_length + 80)),
        ),
        ("BLOCK raw_length lie", block, Box::new(|e| e.raw_length = 96)),
        ("BLOCK record_size 1", block, Box::new(|e| e.record_size = 1)),
        ("BLOCK 2^32 records, compressed", block, Box::new(|e| (e.flags, e.raw_length) = (FLAG_ZSTD, 48 << 32))),
        ("length past the end", cells, Box::new(move |e| e.length = file_size)),
        ("length u64::MAX", cells, Box::new(|e| (e.length, e.raw_length) = (u64::MAX, u64::MAX))),
        ("offset + length overflows", cells, Box::new(|e| e.offset = u64::MAX - 15)),
        ("offset past the end", cells, Box::new(move |e| e.offset = file_size + 16)),
        ("offset not aligned", cells, Box::new(|e| e.offset += 8)),
        ("offset inside the table", 0, Box::new(|e| e.offset = 64)),
        ("shuffle without zstd", cells, Box::new(|e| e.flags = FLAG_SHUFFLE)),
    ];
    for (case, index, patch) in table_cases {
        let mut bad = RawFile::new(bytes.clone());
        bad.patch_entry(index, |e| patch(e));
        let err = open_error(case, &bad.bytes);
        // A section grown into the next one is reported at the next one.
        let at = if case.contains("+ 80") { index + 1 } else { index };
        assert!(matches!(err, Error::BadSection { index: i, .. } if i == at), "{case}: {err:?}");
        assert_invalid(case, &err);
    }

    type HeaderPatch = Box<dyn Fn(&mut treelod_format::Header)>;
    let header_cases: Vec<(&str, &str, HeaderPatch)> = vec![
        ("section_count 1000", "section_count", Box::new(|h| h.section_count = 1000)),
        ("section_count 257", "section_count", Box::new(|h| h.section_count = 257)),
        ("header_size 1 GiB", "header_size", Box::new(|h| h.header_size = 1 << 30)),
        ("header_size 0", "header_size", Box::new(|h| h.header_size = 0)),
        ("header_size 72", "header_size", Box::new(|h| h.header_size = 72)),
        ("header_size 80, table inside it", "table_offset", Box::new(|h| h.header_size = 80)),
        ("table_offset 8", "table_offset", Box::new(|h| h.table_offset = 8)),
        ("table_offset 72", "table_offset", Box::new(|h| h.table_offset = 72)),
    ];
    for (case, field, patch) in header_cases {
        let mut bad = RawFile::new(bytes.clone());
        bad.patch_header(|h| patch(h));
        let err = open_error(case, &bad.bytes);
        assert!(matches!(err, Error::BadHeader { field: f, .. } if f == field), "{case}: {err:?}");
    }
    for (case, patch) in [
        ("table_offset 2^60", Box::new(|h: &mut treelod_format::Header| h.table_offset = 1 << 60) as HeaderPatch),
        ("table_offset u64::MAX - 15", Box::new(|h| h.table_offset = u64::MAX - 15)),
        ("section_count 256", Box::new(|h| h.section_count = 256)),
        ("file_size + 16", Box::new(|h| h.file_size += 16)),
        ("file_size u64::MAX", Box::new(|h| h.file_size = u64::MAX)),
    ] {
        let mut bad = RawFile::new(bytes.clone());
        bad.patch_header(|h| patch(h));
        let err = open_error(case, &bad.bytes);
        assert!(matches!(err, Error::Truncated { .. }), "{case}: {err:?}");
    }
    for (case, size) in [("file_size - 16", file_size - 16), ("file_size 0", 0)] {
        let mut bad = RawFile::new(bytes.clone());
        bad.patch_header(|h| h.file_size = size);
        let err = open_error(case, &bad.bytes);
        assert!(matches!(err, Error::TrailingBytes { .. } | Error::BadSection { .. }), "{case}: {err:?}");
    }

    // CELLS shorter by one record, its checksum recomputed: the cell count no longer fits the grid.
    let mut short = RawFile::new(bytes.clone());
    short.patch_entry(cells, |e| (e.length, e.raw_length) = (e.length - 80, e.raw_length - 80));
    short.reseal_section(cells);
    let err = open_error("CELLS one record short", &short.bytes);
    assert!(matches!(err, Error::BadRecord { kind: SectionKind::CELLS, .. }), "{err:?}");
}

#[test]
fn block_and_cell_content_is_checked_at_open() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    let file = RawFile::new(bytes.clone());
    let block = index_of(&file, SectionKind::BLOCK);
    let cells = index_of(&file, SectionKind::CELLS);
    // Byte offsets inside BlockRecord and CellRecord (spec §6.1, §6.2).
    let block_cases: Vec<(&str, usize, Vec<u8>)> = vec![
        ("grid x 0", 24, 0u32.to_le_bytes().to_vec()),
        ("grid y 257", 28, 257u32.to_le_bytes().to_vec()),
        ("grid 256x256x2", 24, [256u32, 256, 2].iter().flat_map(|v| v.to_le_bytes()).collect()),
        ("grid 3x1x1, cells for 2", 24, 3u32.to_le_bytes().to_vec()),
        ("bounds NaN", 0, f32::NAN.to_le_bytes().to_vec()),
        ("bounds +inf", 12, f32::INFINITY.to_le_bytes().to_vec()),
        ("bounds min > max", 4, 1.0e9f32.to_le_bytes().to_vec()),
        ("tree_count 0", 36, 0u32.to_le_bytes().to_vec()),
    ];
    for (case, at, value) in block_cases {
        let mut bad = RawFile::new(bytes.clone());
        bad.payload_mut(block)[at..at + value.len()].copy_from_slice(&value);
        // Without the section checksum fixed, the checksum catches it.
        let err = open_error(case, &bad.bytes);
        assert!(matches!(err, Error::ChecksumMismatch { .. }), "{case}: {err:?}");
        bad.reseal_section(block);
        let err = open_error(case, &bad.bytes);
        let kind = if case.starts_with("grid 3") { SectionKind::CELLS } else { SectionKind::BLOCK };
        assert!(matches!(err, Error::BadRecord { kind: k, .. } if k == kind), "{case}: {err:?}");
    }
    // Ranges that do not tile: cell 0's triangles start at 1; cell 1's points end short.
    for (case, at, value) in [("triangles start at 1", 24usize, 1u32), ("points count + 1", 80 + 36, 99)] {
        let mut bad = RawFile::new(bytes.clone());
        bad.payload_mut(cells)[at..at + 4].copy_from_slice(&value.to_le_bytes());
        bad.reseal_section(cells);
        let err = open_error(case, &bad.bytes);
        assert!(matches!(err, Error::BadCell { .. }), "{case}: {err:?}");
    }
}

#[test]
fn overlapping_and_unordered_sections_are_refused() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    let file = RawFile::new(bytes.clone());
    for index in 1..file.section_count() {
        let previous = file.entry(index - 1);
        let mut bad = RawFile::new(bytes.clone());
        bad.patch_entry(index, |e| e.offset = previous.offset);
        let err = open_error(&format!("entry {index} on top of {}", index - 1), &bad.bytes);
        assert!(matches!(err, Error::BadSection { index: i, .. } if i == index), "{err:?}");
        // One byte of overlap, as long as the offset stays aligned: the previous section grows.
        let mut bad = RawFile::new(bytes.clone());
        let overlap = file.entry(index).offset - previous.offset - previous.length + 1;
        bad.patch_entry(index - 1, |e| (e.length, e.raw_length) = (e.length + overlap, e.raw_length + overlap));
        let err = open_error(&format!("entry {} grown into {index}", index - 1), &bad.bytes);
        assert!(matches!(err, Error::BadSection { .. }), "{err:?}");
    }
    // Two entries swapped: offsets no longer ascend.
    let mut bad = RawFile::new(bytes);
    let (a, b) = (bad.entry(1), bad.entry(2));
    bad.set_entry(1, b);
    bad.set_entry(2, a);
    bad.reseal();
    let err = open_error("entries swapped", &bad.bytes);
    assert!(matches!(err, Error::BadSection { index: 2, .. }), "{err:?}");
}

#[test]
fn duplicate_kinds_are_refused() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    let file = RawFile::new(bytes.clone());
    for index in 1..file.section_count() {
        for earlier in 0..index {
            let kind = file.entry(earlier).kind;
            let mut bad = RawFile::new(bytes.clone());
            bad.patch_entry(index, |e| e.kind = kind);
            let case = format!("entry {index} repeats kind {kind:#x}");
            let err = open_error(&case, &bad.bytes);
            assert!(
                matches!(&err, Error::BadSection { index: i, reason, .. } if *i == index && reason.contains("twice")),
                "{case}: {err:?}"
            );
        }
    }
}

#[test]
fn unknown_flag_bits_on_known_kinds_are_unsupported() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        let file = RawFile::new(bytes.clone());
        for (index, entry) in file.entries().iter().enumerate() {
            let kind = SectionKind(entry.kind);
            if kind.record_size().is_none() {
                continue;
            }
            for bit in 2..32 {
                let mut bad = RawFile::new(bytes.clone());
                bad.patch_entry(index, |e| e.flags |= 1 << bit);
                let case = format!("{name}: {kind} flag bit {bit}");
                let err = open_error(&case, &bad.bytes);
                assert!(matches!(err, Error::UnsupportedFeature { kind: k, .. } if k == kind), "{case}: {err:?}");
                assert_eq!(err.class(), ErrorClass::Unsupported, "{case}");
            }
        }
    }
    // SHUFFLE on a byte kind (META), even with ZSTD: not allowed (spec §4).
    let mut file = RawFile::new(compressed());
    let meta = index_of(&file, SectionKind::META);
    file.patch_entry(meta, |e| e.flags |= FLAG_ZSTD | FLAG_SHUFFLE);
    let err = open_error("META shuffled", &file.bytes);
    assert!(matches!(err, Error::BadSection { .. }), "{err:?}");
}

#[test]
fn unknown_kinds_are_skipped_whatever_their_flags() {
    let _alone = exclusive();
    let data = small_data();
    let expected_known = ContainerData { extra_sections: Vec::new(), ..data.clone() };
    for (name, bytes) in variants() {
        let file = RawFile::new(bytes.clone());
        let extension = file.entries().iter().position(|e| SectionKind(e.kind).record_size().is_none()).unwrap();
        for (flags, record_size, raw_length) in
            [(0xFFFF_FFFF, 0, u64::MAX), (FLAG_ZSTD, 7, 1 << 40), (FLAG_SHUFFLE, 1, 0)]
        {
            let mut odd = RawFile::new(bytes.clone());
            odd.patch_entry(extension, |e| (e.flags, e.record_size, e.raw_length) = (flags, record_size, raw_length));
            let case = format!("{name}: extension with flags {flags:#x}");
            open_and_verify(&case, &odd.bytes, &OpenOptions::default()).unwrap_or_else(|e| panic!("{case}: {e}"));
            let back = ContainerData::from_container(&Container::from_bytes(&odd.bytes).unwrap());
            let known = ContainerData { extra_sections: Vec::new(), ..back.clone() };
            assert_eq!(known, expected_known, "{case}: the known sections are intact");
            if flags & FLAG_ZSTD == 0 {
                assert_eq!(back.extra_sections, data.extra_sections, "{case}");
            }
        }
        // A garbage section of a new kind, laid out anywhere in the file, is skipped.
        let mut parts = file.parts();
        parts.insert(
            3,
            Part { kind: 0x0099, flags: FLAG_ZSTD, raw_length: 1 << 50, record_size: 3, stored: vec![0xAB; 40] },
        );
        parts.push(Part::plain(SectionKind(0xDEAD_BEEF), 1, b"private".to_vec()));
        let grown = layout(&parts);
        let container = Container::from_bytes(&grown).unwrap_or_else(|e| panic!("{name}: {e}"));
        verify(&container).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(
            ContainerData { extra_sections: Vec::new(), ..ContainerData::from_container(&container) },
            expected_known
        );
    }
}

#[test]
fn plane_leaves_of_a_wrong_length_or_record_size() {
    let _alone = exclusive();
    // Spec §6.10.1: PLANE_LEAVES' length against the planes is a verify rule, not an open rule: a
    // section one record short or long opens and fails verify; a record size other than the
    // kind's is refused at open (§4).
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    let file = RawFile::new(bytes.clone());
    let index = index_of(&file, SectionKind::PLANE_LEAVES);
    let size = size_of::<PlaneLeafRecord>();
    for delta in [-1i64, 1] {
        let mut parts = file.parts();
        let part = &mut parts[index];
        if delta < 0 {
            part.stored.truncate(part.stored.len() - size);
        } else {
            part.stored.extend(std::iter::repeat_n(0, size));
        }
        part.raw_length = part.stored.len() as u64;
        let case = format!("PLANE_LEAVES {delta:+} record");
        let err = rejected(&case, &layout(&parts));
        assert!(matches!(err, Error::BadRecord { kind: SectionKind::PLANE_LEAVES, index: 0, .. }), "{case}: {err:?}");
        assert_invalid(&case, &err);
    }
    for record_size in [1, size as u32 - 8, size as u32 + 8, u32::MAX] {
        let mut bad = RawFile::new(bytes.clone());
        bad.patch_entry(index, |e| e.record_size = record_size);
        let case = format!("PLANE_LEAVES record_size {record_size}");
        let err = open_error(&case, &bad.bytes);
        assert!(matches!(err, Error::BadSection { index: i, .. } if i == index), "{case}: {err:?}");
    }
}

#[test]
fn missing_required_sections_are_refused() {
    let _alone = exclusive();
    for (name, bytes) in variants() {
        for kind in [SectionKind::META, SectionKind::BLOCK, SectionKind::CELLS] {
            let parts: Vec<Part> =
                RawFile::new(bytes.clone()).parts().into_iter().filter(|p| p.kind != kind.0).collect();
            let case = format!("{name} without {kind}");
            let err = open_error(&case, &layout(&parts));
            assert!(matches!(err, Error::MissingSection { kind: k } if k == kind), "{case}: {err:?}");
        }
    }
    let err = open_error("no sections", &layout(&[]));
    assert!(matches!(err, Error::MissingSection { kind: SectionKind::META }), "{err:?}");
}

#[test]
fn hostile_metadata_is_a_typed_error() {
    let _alone = exclusive();
    let bytes = small_data().to_bytes(Compression::None).unwrap();
    let file = RawFile::new(bytes);
    let meta = index_of(&file, SectionKind::META);
    let mut vec_claim = vec![0u8, 0]; // generator "", name ""
    vec_claim.extend_from_slice(&[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x0F]); // 2^63 sources
    let mut long_string = vec![0xFF, 0xFF, 0xFF, 0xFF, 0x0F]; // a 4 GiB generator string
    long_string.extend_from_slice(b"abc");
    let bad_utf8 = vec![3, 0xC3, 0x28, 0x41];
    for (case, payload) in
        [("empty", Vec::new()), ("2^63 sources", vec_claim), ("4 GiB string", long_string), ("bad UTF-8", bad_utf8)]
    {
        let mut parts = file.parts();
        parts[meta] = Part::plain(SectionKind::META, 1, payload);
        let err = open_error(case, &layout(&parts));
        assert!(matches!(err, Error::Metadata(_)), "{case}: {err:?}");
        assert_invalid(case, &err);
    }
    // Bytes after the encoded value are ignored (a later minor version may append fields).
    let mut parts = file.parts();
    parts[meta].stored.extend_from_slice(&[1, 2, 3, 4]);
    parts[meta].raw_length += 4;
    let container = Container::from_bytes(&layout(&parts)).unwrap();
    assert_eq!(container.metadata(), &small_data().metadata);
}

// ---------------------------------------------------------------------------------------------
// Compression

/// A zstd frame of `raw`, declaring its content size (as writers make them) or not.
fn frame(raw: &[u8], content_size: bool) -> Vec<u8> {
    let mut compressor = zstd::bulk::Compressor::new(3).expect("zstd context");
    compressor.include_checksum(true).expect("zstd parameter");
    compressor.include_contentsize(content_size).expect("zstd parameter");
    compressor.compress(raw).expect("compresses")
}

/// Rewrites the Frame_Content_Size field of a zstd frame (RFC 8878 §3.1.1.1), keeping its width.
fn set_frame_content_size(frame: &mut [u8], size: u64) {
    let descriptor = frame[4];
    let fcs_flag = descriptor >> 6;
    let single_segment = descriptor & 0x20 != 0;
    let dict_bytes = [0, 1, 2, 4][usize::from(descriptor & 3)];
    let at = 5 + usize::from(!single_segment) + dict_bytes;
    match (fcs_flag, single_segment) {
        (0, true) => frame[at] = u8::try_from(size).expect("fits the field"),
        (1, _) => frame[at..at + 2].copy_from_slice(&u16::try_from(size - 256).expect("fits the field").to_le_bytes()),
        (2, _) => frame[at..at + 4].copy_from_slice(&u32::try_from(size).expect("fits the field").to_le_bytes()),
        (3, _) => frame[at..at + 8].copy_from_slice(&size.to_le_bytes()),
        _ => panic!("the frame declares no content size"),
    }
}

/// The compressed fixture with section `index` replaced by `stored`, declaring `raw_length`.
fn with_section(index: usize, flags: u32, raw_length: u64, stored: Vec<u8>) -> Vec<u8> {
    let mut parts = RawFile::new(compressed()).parts();
    parts[index].flags = flags;
    parts[index].raw_length = raw_length;
    parts[index].stored = stored;
    layout(&parts)
}

#[test]
fn a_declared_size_beyond_1024_times_the_stored_size_is_refused_before_decoding() {
    let _alone = exclusive();
    let file = RawFile::new(compressed());
    for index in [compressed_index(&file, true), compressed_index(&file, false)] {
        let entry = file.entry(index);
        let size = u64::from(entry.record_size);
        let above = (entry.length * 1024 / size + 1) * size;
        for raw_length in [above, u64::MAX / size * size, (u64::from(u32::MAX) - 1) * size] {
            let mut bad = RawFile::new(compressed());
            bad.patch_entry(index, |e| e.raw_length = raw_length);
            let case = format!("{} raw_length {raw_length}", SectionKind(entry.kind));
            let err = open_error(&case, &bad.bytes);
            assert!(
                matches!(err, Error::DecodeLimit { raw_length: r, rule, .. } if r == raw_length
                    && (rule.contains("1024") || entry.kind == SectionKind::META.0 && rule.contains("metadata")))
                    || matches!(err, Error::BadSection { .. }),
                "{case}: {err:?}"
            );
        }
    }
}

#[test]
fn a_zstd_bomb_is_refused_before_any_allocation() {
    let _alone = exclusive();
    // A real frame of 64 MiB of zeros (a few KiB stored) in VERTICES, honestly declared.
    let raw_length = (64u64 << 20) / 28 * 28;
    let mut encoder = zstd::stream::Encoder::new(Vec::new(), 19).unwrap();
    encoder.include_checksum(true).unwrap();
    encoder.include_contentsize(true).unwrap();
    encoder.set_pledged_src_size(Some(raw_length)).unwrap();
    let chunk = vec![0u8; 28 << 14];
    let mut left = raw_length as usize;
    while left > 0 {
        let n = left.min(chunk.len());
        std::io::Write::write_all(&mut encoder, &chunk[..n]).unwrap();
        left -= n;
    }
    let bomb = encoder.finish().unwrap();
    assert!((bomb.len() as u64) * 1024 < raw_length, "the bomb's ratio is above 1024: {} bytes", bomb.len());
    assert_eq!(zstd::zstd_safe::get_frame_content_size(&bomb).unwrap(), Some(raw_length));

    let file = RawFile::new(compressed());
    let vertices = index_of(&file, SectionKind::VERTICES);
    for flags in [FLAG_ZSTD, FLAG_ZSTD | FLAG_SHUFFLE] {
        let bad = with_section(vertices, flags, raw_length, bomb.clone());
        // open_error asserts the peak heap stayed within 64 × the file size: nothing was decoded.
        let err = open_error("zstd bomb", &bad);
        assert!(
            matches!(err, Error::DecodeLimit { kind: SectionKind::VERTICES, raw_length: r, .. } if r == raw_length),
            "{err:?}"
        );
    }
    // The same bomb as META is refused by the metadata limit or the ratio, also before decoding.
    let meta = index_of(&file, SectionKind::META);
    let err = open_error("META bomb", &with_section(meta, FLAG_ZSTD, raw_length, bomb));
    assert!(matches!(err, Error::DecodeLimit { kind: SectionKind::META, .. }), "{err:?}");
    // META declaring more than 16 MiB is refused even when the ratio would allow it.
    let mut big_meta = RawFile::new(compressed());
    big_meta.patch_entry(meta, |e| (e.flags, e.raw_length, e.length) = (FLAG_ZSTD, (16 << 20) + 1, e.length));
    let err = open_error("META over 16 MiB", &big_meta.bytes);
    assert!(matches!(err, Error::DecodeLimit { kind: SectionKind::META, .. }), "{err:?}");
}

#[test]
fn frames_that_disagree_with_the_table_are_refused() {
    let _alone = exclusive();
    let file = RawFile::new(compressed());
    for index in [compressed_index(&file, true), compressed_index(&file, false)] {
        let entry = file.entry(index);
        let kind = SectionKind(entry.kind);
        let size = u64::from(entry.record_size);
        let stored = file.payload(index).to_vec();
        let decoded = zstd::bulk::decompress(&stored, entry.raw_length as usize).unwrap();
        let is_decompress = |e: &Error| matches!(e, Error::Decompress { kind: k, .. } if *k == kind);

        // The table declares one record more or less than the frame.
        for raw_length in [entry.raw_length + size, entry.raw_length - size] {
            let mut bad = RawFile::new(compressed());
            bad.patch_entry(index, |e| e.raw_length = raw_length);
            let err = open_error(&format!("{kind}: table says {raw_length}"), &bad.bytes);
            assert!(is_decompress(&err), "{err:?}");
        }
        // A frame that declares (and the table that says) less than it decodes to.
        let mut longer = decoded.clone();
        longer.extend_from_slice(&decoded);
        let mut lying = frame(&longer, true);
        set_frame_content_size(&mut lying, entry.raw_length);
        let err = open_error(
            &format!("{kind}: frame decodes to more"),
            &with_section(index, entry.flags, entry.raw_length, lying),
        );
        assert!(is_decompress(&err), "{err:?}");
        // A frame that declares more than it decodes to.
        let mut lying = frame(&decoded, true);
        let claimed = entry.raw_length + size;
        set_frame_content_size(&mut lying, claimed);
        let err =
            open_error(&format!("{kind}: frame decodes to less"), &with_section(index, entry.flags, claimed, lying));
        assert!(is_decompress(&err), "{err:?}");
        // No content size in the frame header.
        let bad = with_section(index, entry.flags, entry.raw_length, frame(&decoded, false));
        assert!(is_decompress(&open_error(&format!("{kind}: no content size"), &bad)));
        // Two frames, a frame with a byte cut off, garbage, an empty payload.
        let mut two = stored.clone();
        two.extend_from_slice(&frame(&[], true));
        let cases = [
            ("two frames", two),
            ("cut frame", stored[..stored.len() - 1].to_vec()),
            ("not a frame", vec![0x55; stored.len()]),
            ("empty", Vec::new()),
        ];
        for (what, payload) in cases {
            let case = format!("{kind}: {what}");
            let err = open_error(&case, &with_section(index, entry.flags, entry.raw_length, payload));
            assert!(is_decompress(&err) || matches!(err, Error::DecodeLimit { .. }), "{case}: {err:?}");
        }
        // A flipped bit in the frame's content checksum, the section checksum recomputed.
        let mut bad = RawFile::new(compressed());
        let last = bad.payload_range(index).end - 1;
        bad.bytes[last] ^= 0x10;
        bad.reseal_section(index);
        let err = open_error(&format!("{kind}: content checksum"), &bad.bytes);
        assert!(is_decompress(&err), "{err:?}");
    }
}

#[test]
fn the_decode_budget_bounds_all_compressed_sections_together() {
    let _alone = exclusive();
    let bytes = compressed();
    let file = RawFile::new(bytes.clone());
    let total: u64 = file
        .entries()
        .iter()
        .filter(|e| e.flags & FLAG_ZSTD != 0 && SectionKind(e.kind).record_size().is_some())
        .map(|e| e.raw_length)
        .sum();
    assert!(total > 0);
    let exact = OpenOptions { decode_budget: total };
    open_and_verify("budget = total", &bytes, &exact).unwrap();
    for budget in [total - 1, total / 2, 0] {
        let case = format!("budget {budget} of {total}");
        let err = open_error_with(&case, &bytes, &OpenOptions { decode_budget: budget });
        assert!(matches!(err, Error::DecodeLimit { rule, .. } if rule.contains("budget")), "{case}: {err:?}");
        assert_invalid(&case, &err);
    }
    // Uncompressed sections do not count against the budget.
    let plain = small_data().to_bytes(Compression::None).unwrap();
    Container::from_bytes_with(&plain, &OpenOptions { decode_budget: 0 }).unwrap();
}

#[test]
fn of_several_bad_sections_open_names_the_first_in_table_order() {
    let _alone = exclusive();
    // Sections are decoded side by side; the error must still be the one a reader going through
    // the table one section after the other meets first.
    let file = RawFile::new(compressed());
    let decoded: Vec<usize> = (0..file.section_count())
        .filter(|&i| {
            let e = file.entry(i);
            e.flags & FLAG_ZSTD != 0 && SectionKind(e.kind).record_size().is_some() && e.kind != SectionKind::META.0
        })
        .collect();
    let (&first, &last) = (decoded.first().unwrap(), decoded.last().unwrap());
    assert!(first < last, "the fixture has two decoded sections: {decoded:?}");
    let kind = |i: usize| SectionKind(file.entry(i).kind);
    let bad_checksum = |file: &mut RawFile, i: usize| file.payload_mut(i)[0] ^= 1;
    let past_ratio = |file: &mut RawFile, i: usize| {
        file.patch_entry(i, |e| {
            e.raw_length = (e.length * 1024 / u64::from(e.record_size) + 1) * u64::from(e.record_size)
        });
    };
    let checksum_of = |err: &Error| match err {
        Error::ChecksumMismatch { what, .. } => what.clone(),
        other => panic!("expected a checksum mismatch, got {other:?}"),
    };
    // Two bad checksums: the first section's.
    let mut both = RawFile::new(compressed());
    bad_checksum(&mut both, first);
    bad_checksum(&mut both, last);
    assert_eq!(checksum_of(&open_error("two checksums", &both.bytes)), format!("section {}", kind(first)));
    // A bad checksum before a section past a limit: the checksum.
    let mut checksum_then_limit = RawFile::new(compressed());
    bad_checksum(&mut checksum_then_limit, first);
    past_ratio(&mut checksum_then_limit, last);
    let err = open_error("checksum, then limit", &checksum_then_limit.bytes);
    assert_eq!(checksum_of(&err), format!("section {}", kind(first)));
    // A section past a limit before a bad checksum: the limit.
    let mut limit_then_checksum = RawFile::new(compressed());
    past_ratio(&mut limit_then_checksum, first);
    bad_checksum(&mut limit_then_checksum, last);
    let err = open_error("limit, then checksum", &limit_then_checksum.bytes);
    assert!(matches!(err, Error::DecodeLimit { kind: k, .. } if k == kind(first)), "{err:?}");
}

#[test]
fn the_allocation_counter_sees_large_allocations() {
    let _alone = exclusive();
    let (len, peak) = peak_during(|| vec![1u8; 1 << 20].len());
    assert_eq!(len, 1 << 20);
    assert!(peak >= 1 << 20, "peak {peak}");
    let (_, small) = peak_during(|| ());
    assert!(small < 1024, "peak {small} for nothing");
}

// ---------------------------------------------------------------------------------------------
// Content that opens but breaks a rule of §6 or §10: verify's job

/// What verify must report for a broken rule.
#[derive(Clone, Copy, Debug)]
enum Expect {
    /// `BadRecord` of this kind.
    Record(SectionKind),
    /// `BadCell`, or `BadRecord` of this kind (an ordering or exact-cut rule may be reported either
    /// way).
    CellOr(SectionKind),
}

/// The first cell whose triangles have at least two different sizes, as a slice range.
fn cell_with_two_sizes(data: &ContainerData) -> core::ops::Range<usize> {
    data.cells
        .iter()
        .map(|c| c.triangles.as_usize())
        .find(|r| r.len() >= 2 && data.triangles[r.start].size > data.triangles[r.end - 1].size)
        .expect("a cell with two triangle sizes")
}

#[test]
fn verify_refuses_content_that_breaks_the_rules() {
    let _alone = exclusive();
    use SectionKind as K;
    let good = synthetic(5, &SyntheticOptions::everything());
    Container::from_bytes(&good.to_bytes(Compression::None).unwrap()).and_then(|c| verify(&c)).unwrap();
    type Mutation = Box<dyn Fn(&mut ContainerData)>;
    let leaf_point = |d: &ContainerData| d.points.iter().position(|p| p.leaf_count == 1 && p.hi.is_finite()).unwrap();
    let png = |d: &ContainerData| d.images.iter().find(|i| i.format == 3).unwrap().data_offset as usize;
    let slots = |d: &ContainerData| d.images.iter().position(|i| i.format == image_format::LEAF_SLOTS).unwrap();
    let cases: Vec<(&str, Expect, Mutation)> = vec![
        ("vertex position NaN", Expect::Record(K::VERTICES), Box::new(|d| d.vertices[1].position[0] = f32::NAN)),
        ("vertex uv infinite", Expect::Record(K::VERTICES), Box::new(|d| d.vertices[2].uv[1] = f32::INFINITY)),
        (
            "vertex index out of range",
            Expect::Record(K::TRIANGLES),
            Box::new(|d| d.triangles[0].indices[1] = d.vertices.len() as u32),
        ),
        (
            "material out of range",
            Expect::Record(K::TRIANGLES),
            Box::new(|d| d.triangles[0].material = d.materials.len() as u32),
        ),
        ("negative triangle size", Expect::CellOr(K::TRIANGLES), Box::new(|d| d.triangles[0].size = -1.0)),
        (
            "triangles not sorted",
            Expect::CellOr(K::TRIANGLES),
            Box::new(|d| {
                let r = cell_with_two_sizes(d);
                d.triangles.swap(r.start, r.end - 1);
            }),
        ),
        (
            "leaf id repeated",
            Expect::CellOr(K::TRIANGLES),
            Box::new(|d| {
                let r = cell_with_two_sizes(d);
                d.triangles[r.start + 1].leaf = d.triangles[r.start].leaf;
            }),
        ),
        (
            "leaf point size one ulp off",
            Expect::CellOr(K::POINTS),
            Box::new(move |d| {
                let i = leaf_point(d);
                d.points[i].size = f32::from_bits(d.points[i].size.to_bits() + 1);
            }),
        ),
        (
            "leaf point interval gap",
            Expect::CellOr(K::POINTS),
            Box::new(move |d| {
                let i = leaf_point(d);
                d.points[i].hi *= 0.5;
            }),
        ),
        (
            "points not sorted by hi",
            Expect::CellOr(K::POINTS),
            Box::new(|d| {
                let r = d.cells.iter().map(|c| c.points.as_usize()).find(|r| r.len() >= 3).unwrap();
                d.points[r].reverse();
            }),
        ),
        ("point leaf_count 0", Expect::CellOr(K::POINTS), Box::new(|d| d.points[0].leaf_count = 0)),
        ("point radius negative", Expect::Record(K::POINTS), Box::new(|d| d.points[0].radius = -0.5)),
        (
            "inner point hi infinite",
            Expect::CellOr(K::POINTS),
            Box::new(move |d| {
                let i = leaf_point(d);
                d.points[i].hi = f32::INFINITY;
            }),
        ),
        (
            "ellipsoid alpha_threshold 1.5",
            Expect::Record(K::ELLIPSOIDS),
            Box::new(|d| d.ellipsoids[0].alpha_threshold = 1.5),
        ),
        ("ellipsoid run one too long", Expect::CellOr(K::ELLIPSOIDS), Box::new(|d| d.ellipsoids[0].leaf_count += 1)),
        (
            "ellipsoid lo above hi",
            Expect::CellOr(K::ELLIPSOIDS),
            Box::new(|d| {
                let e = d.ellipsoids.iter_mut().find(|e| e.hi.is_finite()).unwrap();
                e.lo = e.hi * 2.0 + 1.0;
            }),
        ),
        ("line radius negative", Expect::Record(K::LINES), Box::new(|d| d.lines[0].r0 = -1.0)),
        ("line hi NaN", Expect::CellOr(K::LINES), Box::new(|d| d.lines[0].hi = f32::NAN)),
        (
            "plane image out of range",
            Expect::Record(K::PLANES),
            Box::new(|d| d.planes[0].image = d.images.len() as u32),
        ),
        (
            "plane uv_min above uv_max",
            Expect::Record(K::PLANES),
            Box::new(|d| {
                let p = d.planes.iter_mut().find(|p| p.uv_min & 0xFFFF < p.uv_max & 0xFFFF).unwrap();
                core::mem::swap(&mut p.uv_min, &mut p.uv_max);
            }),
        ),
        ("plane leaves one record short", Expect::Record(K::PLANE_LEAVES), Box::new(|d| _ = d.plane_leaves.pop())),
        (
            "plane leaves one record too many",
            Expect::Record(K::PLANE_LEAVES),
            Box::new(|d| d.plane_leaves.push(d.plane_leaves[0])),
        ),
        (
            "plane leaf material out of range",
            Expect::Record(K::PLANE_LEAVES),
            Box::new(|d| d.plane_leaves[1].material = d.materials.len() as u32),
        ),
        ("plane leaf uv0 NaN", Expect::Record(K::PLANE_LEAVES), Box::new(|d| d.plane_leaves[0].uv0[1] = f32::NAN)),
        (
            "plane leaf du infinite",
            Expect::Record(K::PLANE_LEAVES),
            Box::new(|d| d.plane_leaves[2].du[0] = f32::INFINITY),
        ),
        (
            "LEAF_SLOTS planes without PLANE_LEAVES",
            Expect::Record(K::PLANES),
            Box::new(|d| d.plane_leaves = Vec::<PlaneLeafRecord>::new()),
        ),
        (
            "LEAF_SLOTS image with two mips",
            Expect::Record(K::IMAGES),
            Box::new(move |d| {
                let i = slots(d);
                d.images[i].mip_count = 2;
            }),
        ),
        (
            "LEAF_SLOTS image one texel short",
            Expect::Record(K::IMAGES),
            Box::new(move |d| {
                let i = slots(d);
                d.images[i].data_length -= 4;
            }),
        ),
        (
            "slots above every plane's leaf_count",
            Expect::Record(K::PLANES),
            Box::new(move |d| {
                let image = d.images[slots(d)];
                let start = image.data_offset as usize;
                d.image_data[start..start + image.data_length as usize].fill(0xFF);
            }),
        ),
        (
            "material image out of range",
            Expect::Record(K::MATERIALS),
            Box::new(|d| d.materials[0].image = d.images.len() as u32),
        ),
        ("material alpha_cutoff 2", Expect::Record(K::MATERIALS), Box::new(|d| d.materials[0].alpha_cutoff = 2.0)),
        ("image data not aligned", Expect::Record(K::IMAGES), Box::new(|d| d.images[0].data_offset += 8)),
        ("image data length wrong", Expect::Record(K::IMAGES), Box::new(|d| d.images[0].data_length -= 4)),
        ("image mip_count too large", Expect::Record(K::IMAGES), Box::new(|d| d.images[0].mip_count = 20)),
        ("image width 0", Expect::Record(K::IMAGES), Box::new(|d| d.images[0].width = 0)),
        (
            "image past IMAGE_DATA",
            Expect::Record(K::IMAGES),
            Box::new(|d| d.images.last_mut().unwrap().data_length += 4096),
        ),
        (
            "PNG signature broken",
            Expect::Record(K::IMAGES),
            Box::new(move |d| {
                let at = png(d);
                d.image_data[at] = 0;
            }),
        ),
        (
            "pruned leaf without triangles",
            Expect::Record(K::PRUNE_LEAVES),
            Box::new(|d| d.prune_leaves[0].triangle_count = 0),
        ),
        (
            "pruned triangle of another leaf",
            Expect::CellOr(K::PRUNE_TRIANGLES),
            Box::new(|d| d.prune_triangles[0].leaf += 1),
        ),
        (
            "pruned triangle vertex out of range",
            Expect::CellOr(K::PRUNE_TRIANGLES),
            Box::new(|d| {
                d.prune_triangles[0].indices[0] = u32::MAX;
            }),
        ),
        ("curve x repeated", Expect::Record(K::PRUNE_SCALE), Box::new(|d| d.prune_scale[1].x = d.prune_scale[0].x)),
        ("curve NaN", Expect::Record(K::PRUNE_LAMBDA), Box::new(|d| d.prune_lambda[0].y = f32::NAN)),
        ("LoD level of no tree", Expect::Record(K::LOD_LEVELS), Box::new(|d| d.lod_levels[1].tree = 9)),
        ("LoD level error NaN", Expect::Record(K::LOD_LEVELS), Box::new(|d| d.lod_levels[0].error = f32::NAN)),
        (
            "LoD level range past the end",
            Expect::Record(K::LOD_LEVELS),
            Box::new(|d| d.lod_levels[1].triangles.first = u32::MAX),
        ),
        (
            "LoD triangle vertex out of range",
            Expect::Record(K::LOD_TRIANGLES),
            Box::new(|d| d.lod_triangles[0].indices[2] = u32::MAX),
        ),
        ("billboard image out of range", Expect::Record(K::BILLBOARDS), Box::new(|d| d.billboards[0].image = 99)),
        ("billboard kind unknown", Expect::Record(K::BILLBOARDS), Box::new(|d| d.billboards[1].kind = 7)),
        (
            "cell bounds miss a vertex",
            Expect::CellOr(K::CELLS),
            Box::new(|d| d.cells[0].bounds_max = d.cells[0].bounds_min),
        ),
        ("cell bounds NaN", Expect::CellOr(K::CELLS), Box::new(|d| d.cells[1].bounds_min[2] = f32::NAN)),
        (
            "block cell bounds miss an ellipsoid",
            Expect::CellOr(K::CELLS),
            Box::new(|d| {
                let last = d.cells.last_mut().unwrap();
                last.bounds_min = last.bounds_max;
            }),
        ),
    ];
    let mut empty_cells =
        synthetic(6, &SyntheticOptions { triangles_per_cell: 0..=0, ..SyntheticOptions::gilet([2, 1, 1]) });
    empty_cells.cells[1].bounds_max = [1.0; 3];
    let mut all: Vec<(&str, Expect, ContainerData)> =
        vec![("empty cell with bounds", Expect::CellOr(K::CELLS), empty_cells)];
    for (case, expect, mutate) in cases {
        let mut data = good.clone();
        mutate(&mut data);
        assert_ne!(data, good, "{case}: the mutation changes something");
        all.push((case, expect, data));
    }
    for (case, expect, data) in all {
        for compression in [Compression::None, Compression::Zstd { level: 3 }] {
            // The writer checks only what open checks, so it writes these files.
            let bytes = data.to_bytes(compression).unwrap_or_else(|e| panic!("{case}: the writer refused: {e}"));
            let container = Container::from_bytes(&bytes).unwrap_or_else(|e| panic!("{case}: open refused: {e}"));
            let err = rejected(case, &bytes);
            assert_invalid(case, &err);
            let ok = match expect {
                Expect::Record(kind) => {
                    matches!(err, Error::BadRecord { kind: k, .. } if k == kind)
                }
                Expect::CellOr(kind) => {
                    matches!(err, Error::BadCell { .. }) || matches!(err, Error::BadRecord { kind: k, .. } if k == kind)
                }
            };
            assert!(ok, "{case}: expected {expect:?}, verify said {err:?}");
            drop(container);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Corruption behind valid checksums: reaches the content checks of open and verify

/// Every section checksum and the header checksum recomputed, so only the content rules remain.
fn reseal_all(bytes: Vec<u8>) -> Vec<u8> {
    let mut file = RawFile::new(bytes);
    for index in 0..file.section_count() {
        let range = file.payload_range(index);
        if range.end <= file.bytes.len() {
            file.reseal_section(index);
        }
    }
    file.reseal();
    file.into_bytes()
}

#[test]
fn every_bit_flip_behind_valid_checksums_is_handled() {
    let _alone = exclusive();
    // With every checksum recomputed, a flipped bit may still make a valid file (a colour, a uv);
    // what matters is that nothing panics or over-allocates and that errors are typed.
    for (name, bytes) in variants() {
        let payload_start = RawFile::new(bytes.clone()).entry(0).offset as usize;
        for bit in payload_start * 8..bytes.len() * 8 {
            let mut bad = bytes.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            let bad = reseal_all(bad);
            let case = format!("{name}: bit {bit} resealed");
            if let Err(err) = open_and_verify(&case, &bad, &OpenOptions::default()) {
                assert_ne!(err.class(), ErrorClass::Io, "{case}: {err:?}");
            }
        }
    }
}

mod random_patches {
    use proptest::prelude::*;

    use super::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

        /// Random bytes written anywhere after the header, every checksum recomputed: open and
        /// verify return (typed errors or a container) and never panic or over-allocate.
        #[test]
        fn random_patches_behind_valid_checksums_never_panic(
            seed in any::<u64>(),
            compress in any::<bool>(),
            patches in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 1usize..=4), 1..=6),
        ) {
            let _alone = exclusive();
            let options = SyntheticOptions { grid: [1, 2, 1], ..small_options() };
            let compression = if compress { Compression::Zstd { level: 1 } } else { Compression::None };
            let mut bytes = synthetic(seed, &options).to_bytes(compression).unwrap();
            for (at, value, len) in patches {
                let start = 64 + at.index(bytes.len() - 64);
                let end = (start + len).min(bytes.len());
                bytes[start..end].fill(value);
            }
            let bytes = reseal_all(bytes);
            let case = format!("seed {seed}, compressed {compress}");
            if let Err(err) = open_and_verify(&case, &bytes, &OpenOptions::default()) {
                prop_assert_ne!(err.class(), ErrorClass::Io);
            }
        }
    }
}
