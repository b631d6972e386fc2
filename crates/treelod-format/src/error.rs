//! The one error type of the format crate. Variants carry the offending values.

use std::path::PathBuf;

use crate::records::SectionKind;

/// The class of a failure, which the command-line tool maps to its exit code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorClass {
    /// The file is not a valid `.treelod` file (corrupt, truncated, breaks a rule of the spec).
    Invalid,
    /// The file is valid for another version or needs a feature this reader lacks.
    Unsupported,
    /// Reading or writing failed at the operating-system level.
    Io,
}

/// Everything that can go wrong reading, verifying or writing a container.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An operating-system error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file is shorter than the header or than `file_size` says.
    #[error("truncated: {what} needs {needed} bytes, the file has {available}")]
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// Bytes available.
        available: u64,
    },
    /// The file is longer than `file_size` says.
    #[error("{extra} trailing bytes after the declared file size {file_size}")]
    TrailingBytes {
        /// Declared size.
        file_size: u64,
        /// Bytes beyond it.
        extra: u64,
    },
    /// The first twelve bytes are not the magic.
    #[error("not a .treelod file (magic bytes are {found:02X?})")]
    BadMagic {
        /// The bytes found.
        found: [u8; 12],
    },
    /// A major version this reader does not read.
    #[error("unsupported format version {major}.{minor}: this reader reads {supported}.x{hint}")]
    UnsupportedVersion {
        /// The file's major version.
        major: u16,
        /// The file's minor version.
        minor: u16,
        /// The major version this reader reads.
        supported: u16,
        /// Advice, e.g. to upgrade treelod.
        hint: &'static str,
    },
    /// A header field has a value the spec forbids.
    #[error("invalid header: {field} = {value} ({rule})")]
    BadHeader {
        /// Field name.
        field: &'static str,
        /// Its value.
        value: u64,
        /// The rule it breaks.
        rule: &'static str,
    },
    /// A stored checksum does not match the bytes.
    #[error("checksum mismatch in {what}: stored {stored:#010x}, computed {computed:#010x}")]
    ChecksumMismatch {
        /// The header or a section.
        what: String,
        /// The checksum in the file.
        stored: u32,
        /// The checksum of the bytes.
        computed: u32,
    },
    /// A section-table entry breaks a rule of spec §4.
    #[error("section {index} ({kind}): {reason}")]
    BadSection {
        /// Index in the section table.
        index: usize,
        /// Its kind.
        kind: SectionKind,
        /// What is wrong, with the values involved.
        reason: String,
    },
    /// A known section uses a feature (flag bit) this reader does not support.
    #[error("section {kind} uses unsupported flags {flags:#x}")]
    UnsupportedFeature {
        /// Its kind.
        kind: SectionKind,
        /// The flags found.
        flags: u32,
    },
    /// A required section is absent.
    #[error("required section {kind} is missing")]
    MissingSection {
        /// The kind.
        kind: SectionKind,
    },
    /// A compressed section's declared size is beyond the limits of spec §8.
    #[error("section {kind}: decoded size {raw_length} exceeds the limit {limit} ({rule})")]
    DecodeLimit {
        /// The kind.
        kind: SectionKind,
        /// Declared decoded size.
        raw_length: u64,
        /// The limit it exceeds.
        limit: u64,
        /// Which limit.
        rule: &'static str,
    },
    /// A compressed section does not decode to its declared size.
    #[error("section {kind}: zstd payload is corrupt ({reason})")]
    Decompress {
        /// The kind.
        kind: SectionKind,
        /// The decoder's message or the size mismatch.
        reason: String,
    },
    /// The `META` section does not decode.
    #[error("metadata does not decode: {0}")]
    Metadata(String),
    /// A record breaks a rule of spec §6 or §10.
    #[error("{kind} record {index}: {reason}")]
    BadRecord {
        /// The section.
        kind: SectionKind,
        /// Record index within the section.
        index: usize,
        /// What is wrong, with the values involved.
        reason: String,
    },
    /// A cell breaks a rule of spec §6.2 or the exact-cut invariant of §10.
    #[error("cell {cell}: {reason}")]
    BadCell {
        /// Cell index (the block cell is the last).
        cell: usize,
        /// What is wrong, with the values involved.
        reason: String,
    },
    /// A section that holds one hierarchy for the whole block rather than one per cell (`FAR_LINES`,
    /// spec §6.9.1) breaks a rule of its own or the exact-cut invariant of §10.
    #[error("{kind}: {reason}")]
    BadHierarchy {
        /// The section.
        kind: SectionKind,
        /// What is wrong, with the values involved.
        reason: String,
    },
    /// The writer was given data that would make an invalid file.
    #[error("cannot write: {0}")]
    Write(String),
    /// A written file failed the check made before renaming it over `path`
    /// ([`crate::ContainerData::into_path_verified`]): it was removed, and `path` is as it was.
    #[error("{path}: {source} (the new file fails verification and was not written{})", kept_note(*.kept))]
    NotReplaced {
        /// The file that was to be written.
        path: PathBuf,
        /// Whether a file exists at `path`: the old one, kept.
        kept: bool,
        /// Why the written file was refused.
        source: Box<Error>,
    },
    /// Any error, with the file it happened in.
    #[error("{path}: {source}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: Box<Error>,
    },
}

impl Error {
    /// The failure class, for exit codes.
    #[must_use]
    pub fn class(&self) -> ErrorClass {
        match self {
            Self::Io { .. } => ErrorClass::Io,
            Self::UnsupportedVersion { .. } | Self::UnsupportedFeature { .. } => ErrorClass::Unsupported,
            Self::InFile { source, .. } | Self::NotReplaced { source, .. } => source.class(),
            _ => ErrorClass::Invalid,
        }
    }

    /// Wraps the error with the path of the file it concerns (unless it names one already).
    #[must_use]
    pub fn in_file(self, path: impl Into<PathBuf>) -> Self {
        match self {
            Self::Io { .. } | Self::InFile { .. } | Self::NotReplaced { .. } => self,
            other => Self::InFile { path: path.into(), source: Box::new(other) },
        }
    }
}

/// The end of [`Error::NotReplaced`]'s message: what became of the old file.
fn kept_note(kept: bool) -> &'static str {
    if kept { "; the old file is kept" } else { "" }
}

/// Result alias of the format crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
