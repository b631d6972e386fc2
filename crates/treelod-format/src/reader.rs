//! The zero-copy reader: [`Container::open`] maps a file, validates it once (spec §9.1) and then
//! hands out typed slices that cannot fail.

use std::path::{Path, PathBuf};

use bytemuck::{Pod, Zeroable};

use crate::error::{Error, Result};
use crate::metadata::{MAX_META_BYTES, Metadata};
use crate::records::{
    AO_KINDS, BillboardRecord, BlockRecord, CalibrationRecord, CellRecord, ChainCalibrationRecord,
    ChainFlipCalibrationRecord, CurveSample, ElevationCalibrationRecord, EllipsoidRecord, FLAG_SHUFFLE, FLAG_ZSTD,
    FlipCalibrationRecord, HEADER_SIZE, Header, ImageRecord, LineRecord, LodLevelRecord, MAGIC, MAJOR, MaterialRecord,
    OctahedralDepthRecord, OctahedralNormalGridRecord, OctahedralNormalRecord, OctahedralRecord, PlaneDiffuseRecord,
    PlaneLeafRecord, PlaneRecord, PointRecord, PruneLeafRecord, SECTION_ALIGN, SECTION_ENTRY_SIZE, SectionEntry,
    SectionKind, TriangleRecord, VertexRecord,
};

/// Largest section table a reader accepts (spec §12).
pub const MAX_SECTIONS: u32 = 256;
/// Largest header a reader accepts (spec §12).
pub const MAX_HEADER_SIZE: u32 = 4096;
/// A compressed section may decode to at most this many times its stored size (spec §8).
pub const MAX_COMPRESSION_RATIO: u64 = 1024;
/// Default budget for all decoded compressed sections together (spec §8).
pub const DEFAULT_DECODE_BUDGET: u64 = 4 << 30;
/// Largest grid axis (spec §6.1).
pub const MAX_GRID_AXIS: u32 = 256;
/// Largest number of grid cells (spec §6.1).
pub const MAX_GRID_CELLS: usize = 65_536;

/// Settings of [`Container::open_with`].
#[derive(Clone, Debug)]
pub struct OpenOptions {
    /// Largest total of decoded compressed sections, in bytes. Default 4 GiB.
    pub decode_budget: u64,
}

impl Default for OpenOptions {
    fn default() -> Self {
        Self { decode_budget: DEFAULT_DECODE_BUDGET }
    }
}

/// 16 bytes with 16-byte alignment: the unit of [`AlignedBuf`].
#[repr(C, align(16))]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Chunk([u8; 16]);

/// An owned byte buffer aligned to 16 bytes, so record slices can be cast from it.
pub(crate) struct AlignedBuf {
    chunks: Vec<Chunk>,
    len: usize,
}

impl AlignedBuf {
    pub(crate) fn zeroed(len: usize) -> Self {
        Self { chunks: vec![Chunk::zeroed(); len.div_ceil(16)], len }
    }

    pub(crate) fn copy_from(bytes: &[u8]) -> Self {
        let mut buf = Self::zeroed(bytes.len());
        buf.as_mut_bytes().copy_from_slice(bytes);
        buf
    }

    pub(crate) fn as_bytes(&self) -> &[u8] {
        &bytemuck::cast_slice(&self.chunks)[..self.len]
    }

    fn as_mut_bytes(&mut self) -> &mut [u8] {
        &mut bytemuck::cast_slice_mut(&mut self.chunks)[..self.len]
    }
}

enum Storage {
    Mapped(memmap2::Mmap),
    Owned(AlignedBuf),
}

impl Storage {
    fn bytes(&self) -> &[u8] {
        match self {
            Self::Mapped(map) => map,
            Self::Owned(buf) => buf.as_bytes(),
        }
    }

    /// Lets the system drop the mapped pages of a stored range that has been decoded and is not
    /// read again (a compressed section), so that a compressed file's pages are not resident
    /// beside its decoded sections: for the 669k-triangle maple, 25 MB of 110. Pages at the
    /// range's ends may be shared with neighbours; those are read back from the file if touched.
    fn release(&self, entry: &SectionEntry) {
        #[cfg(unix)]
        if let Self::Mapped(map) = self
            && let Ok(len) = usize::try_from(entry.length)
            && let Ok(offset) = usize::try_from(entry.offset)
        {
            // SAFETY: the map is read-only (never written through, so it has no private pages to
            // lose); MADV_DONTNEED on it only drops resident pages, which the kernel reads back
            // from the file, with the same bytes, on the next access. A failure (an unsupported
            // advice) leaves the pages resident, as before.
            let _ = unsafe { map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, offset, len) };
        }
        #[cfg(not(unix))]
        let _ = entry;
    }
}

/// A section as listed in the table, with its decoded bytes if it was compressed.
pub struct Section {
    /// The table entry as stored.
    pub entry: SectionEntry,
    decoded: Option<AlignedBuf>,
}

impl Section {
    /// The section's kind.
    #[must_use]
    pub fn kind(&self) -> SectionKind {
        SectionKind(self.entry.kind)
    }

    /// Whether the payload is stored as a zstd frame.
    #[must_use]
    pub fn is_compressed(&self) -> bool {
        self.entry.flags & FLAG_ZSTD != 0
    }

    /// Number of records (`raw_length / record_size`; bytes for byte sections).
    #[must_use]
    pub fn record_count(&self) -> u64 {
        self.entry.raw_length / u64::from(self.entry.record_size.max(1))
    }
}

/// An open, validated `.treelod` container.
///
/// Everything returned after [`Container::open`] succeeded is a view into the mapped file (or into
/// the decoded copy of a compressed section): no accessor can fail.
pub struct Container {
    storage: Storage,
    header: Header,
    sections: Vec<Section>,
    metadata: Metadata,
    path: Option<PathBuf>,
}

impl std::fmt::Debug for Container {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Container")
            .field("path", &self.path)
            .field("version", &(self.header.major, self.header.minor))
            .field("sections", &self.sections.len())
            .finish_non_exhaustive()
    }
}

impl Container {
    /// Maps and validates the file at `path` (spec §9.1). Errors name the file.
    ///
    /// Cost is independent of the size of the bulk arrays: only the header, section table, `META`,
    /// `BLOCK`, `CELLS` and compressed sections are read.
    ///
    /// # Errors
    /// [`Error::Io`] if the file cannot be read, any other variant (wrapped in [`Error::InFile`]) if it
    /// is not a valid container.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        Self::open_with(path, &OpenOptions::default())
    }

    /// [`Container::open`] with explicit options.
    ///
    /// # Errors
    /// As [`Container::open`].
    pub fn open_with(path: impl AsRef<Path>, options: &OpenOptions) -> Result<Self> {
        let path = path.as_ref();
        let io = |source| Error::Io { path: path.to_owned(), source };
        let file = std::fs::File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let storage = if len == 0 {
            // An empty file cannot be mapped on every platform; it is invalid anyway.
            Storage::Owned(AlignedBuf::zeroed(0))
        } else {
            // SAFETY: the map is read-only and private to this process. Another process truncating or
            // rewriting the file while it is mapped is outside this crate's contract (as for every
            // memory-mapped reader); treelod itself replaces files by atomic rename, never in place.
            Storage::Mapped(unsafe { memmap2::Mmap::map(&file) }.map_err(io)?)
        };
        let mut container = Self::validate(storage, options).map_err(|e| e.in_file(path))?;
        container.path = Some(path.to_owned());
        Ok(container)
    }

    /// Validates a container held in memory. The bytes are copied once into an aligned buffer.
    ///
    /// # Errors
    /// Any variant but [`Error::Io`] if the bytes are not a valid container.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        Self::from_bytes_with(bytes, &OpenOptions::default())
    }

    /// [`Container::from_bytes`] with explicit options.
    ///
    /// # Errors
    /// As [`Container::from_bytes`].
    pub fn from_bytes_with(bytes: &[u8], options: &OpenOptions) -> Result<Self> {
        Self::validate(Storage::Owned(AlignedBuf::copy_from(bytes)), options)
    }

    fn validate(storage: Storage, options: &OpenOptions) -> Result<Self> {
        let bytes = storage.bytes();
        let available = bytes.len() as u64;
        let header = read_header(bytes)?;
        let entries = read_table(bytes, &header)?;
        // The limits in table order (the budget is spent in that order), up to the first section
        // past one; then the frames before it decoded side by side on the caller's rayon pool. The
        // error is the first in table order, as decoding one section after the other finds it.
        let mut budget = options.decode_budget;
        let mut compressed = Vec::with_capacity(entries.len());
        let mut past_limit = None;
        for entry in &entries {
            match decode_limits(entry, &mut budget) {
                Ok(is) => compressed.push(is),
                Err(e) => {
                    past_limit = Some(e);
                    break;
                }
            }
        }
        let decoded: Vec<Result<Option<AlignedBuf>>> = {
            use rayon::prelude::*;
            compressed
                .par_iter()
                .enumerate()
                .map(|(index, &is)| {
                    if !is {
                        return Ok(None);
                    }
                    let entry = &entries[index];
                    let buf = decode_section(bytes, index, entry)?;
                    storage.release(entry);
                    Ok(Some(buf))
                })
                .collect()
        };
        let mut sections = Vec::with_capacity(entries.len());
        for (entry, decoded) in entries.iter().zip(decoded) {
            sections.push(Section { entry: *entry, decoded: decoded? });
        }
        if let Some(e) = past_limit {
            return Err(e);
        }
        debug_assert_eq!(available, header.file_size);
        let mut container = Self { storage, header, sections, metadata: Metadata::default(), path: None };
        for kind in [SectionKind::META, SectionKind::BLOCK, SectionKind::CELLS] {
            let Some(section) = container.section(kind) else {
                return Err(Error::MissingSection { kind });
            };
            // Read at every open anyway, so their checksums cost nothing extra (spec §9.1).
            if !section.is_compressed() {
                check_section_checksum(container.storage.bytes(), section)?;
            }
        }
        container.metadata =
            postcard::from_bytes(container.raw_bytes(SectionKind::META)).map_err(|e| Error::Metadata(e.to_string()))?;
        container.validate_block_and_cells()?;
        Ok(container)
    }

    /// Spec §6.1 grid and bounds, §6.2 cell count and tiling, §6.14 ambient-occlusion lengths.
    fn validate_block_and_cells(&self) -> Result<()> {
        check_block_and_cells(self.records(SectionKind::BLOCK), self.cells(), |kind| self.record_count(kind))
    }

    /// The header as stored.
    #[must_use]
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The path the container was opened from, if any.
    #[must_use]
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// The whole file's bytes (mapped or owned).
    #[must_use]
    pub fn file_bytes(&self) -> &[u8] {
        self.storage.bytes()
    }

    /// After a pass over a compressed section's stored bytes (its checksum), lets the system drop
    /// their mapped pages again, as the open does after decoding them.
    pub(crate) fn release_stored(&self, section: &Section) {
        if section.is_compressed() {
            self.storage.release(&section.entry);
        }
    }

    /// Every section in table order, known or not.
    #[must_use]
    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// The section of `kind`, if present.
    #[must_use]
    pub fn section(&self, kind: SectionKind) -> Option<&Section> {
        self.sections.iter().find(|s| s.kind() == kind)
    }

    /// The stored (possibly compressed) bytes of a section. Bounds checked in `open`.
    #[must_use]
    pub fn stored_bytes(&self, section: &Section) -> &[u8] {
        stored_slice(self.storage.bytes(), &section.entry)
    }

    /// The decoded bytes of section `kind`, empty if absent.
    #[must_use]
    pub fn raw_bytes(&self, kind: SectionKind) -> &[u8] {
        match self.section(kind) {
            None => &[],
            Some(section) => match &section.decoded {
                Some(buf) => buf.as_bytes(),
                // Unknown compressed kinds are not decoded; they have no typed accessor either.
                None if section.is_compressed() => &[],
                None => self.stored_bytes(section),
            },
        }
    }

    /// Number of records of a known kind (0 if absent).
    #[must_use]
    pub fn record_count(&self, kind: SectionKind) -> u64 {
        self.section(kind).map_or(0, Section::record_count)
    }

    /// The records of section `kind` as a typed slice, empty if absent.
    ///
    #[must_use]
    pub(crate) fn records<T: Pod>(&self, kind: SectionKind) -> &[T] {
        let bytes = self.raw_bytes(kind);
        if bytes.is_empty() {
            return &[]; // an empty `&[u8]` may have a dangling, unaligned pointer
        }
        // Length is a multiple of the record size and the start is 16-byte aligned: checked in `open`.
        bytemuck::cast_slice(bytes)
    }

    /// The decoded metadata.
    #[must_use]
    pub fn metadata(&self) -> &Metadata {
        &self.metadata
    }

    /// The block record (bounds and grid).
    #[must_use]
    pub fn block(&self) -> &BlockRecord {
        // Exactly one record: checked in `open`.
        &self.records::<BlockRecord>(SectionKind::BLOCK)[0]
    }

    /// All cell records: the grid cells in index order, then the block cell.
    #[must_use]
    pub fn cells(&self) -> &[CellRecord] {
        self.records(SectionKind::CELLS)
    }

    /// All vertices.
    #[must_use]
    pub fn vertices(&self) -> &[VertexRecord] {
        self.records(SectionKind::VERTICES)
    }

    /// All triangles, size-sorted per cell.
    #[must_use]
    pub fn triangles(&self) -> &[TriangleRecord] {
        self.records(SectionKind::TRIANGLES)
    }

    /// All points, in SPT order per cell.
    #[must_use]
    pub fn points(&self) -> &[PointRecord] {
        self.records(SectionKind::POINTS)
    }

    /// All materials.
    #[must_use]
    pub fn materials(&self) -> &[MaterialRecord] {
        self.records(SectionKind::MATERIALS)
    }

    /// All images.
    #[must_use]
    pub fn images(&self) -> &[ImageRecord] {
        self.records(SectionKind::IMAGES)
    }

    /// The texel bytes of all images.
    #[must_use]
    pub fn image_data(&self) -> &[u8] {
        self.raw_bytes(SectionKind::IMAGE_DATA)
    }

    /// All ellipsoids, in SPT order per cell.
    #[must_use]
    pub fn ellipsoids(&self) -> &[EllipsoidRecord] {
        self.records(SectionKind::ELLIPSOIDS)
    }

    /// All lines, in SPT order per cell.
    #[must_use]
    pub fn lines(&self) -> &[LineRecord] {
        self.records(SectionKind::LINES)
    }

    /// The block's far lines (spec §6.9.1), one hierarchy in SPT order; empty in files without
    /// them (before 1.9, or built without lines). Since 1.9.
    #[must_use]
    pub fn far_lines(&self) -> &[LineRecord] {
        self.records(SectionKind::FAR_LINES)
    }

    /// All impostor planes, in SPT order per cell.
    #[must_use]
    pub fn planes(&self) -> &[PlaneRecord] {
        self.records(SectionKind::PLANES)
    }

    /// The leaves of indirectly textured planes (spec §6.10.1): per plane in
    /// [`Container::planes`] order, `leaf_count` records; empty if no plane is textured
    /// indirectly. Its length is checked by [`crate::verify()`], not at open.
    #[must_use]
    pub fn plane_leaves(&self) -> &[PlaneLeafRecord] {
        self.records(SectionKind::PLANE_LEAVES)
    }

    /// How the leaves of each plane take the sun (spec §6.10.2), empty or as long as
    /// [`Container::planes`] (checked at open). Since 1.10.
    #[must_use]
    pub fn plane_diffuse(&self) -> &[PlaneDiffuseRecord] {
        self.records(SectionKind::PLANE_DIFFUSE)
    }

    /// The pruning priority lists, per cell.
    #[must_use]
    pub fn prune_leaves(&self) -> &[PruneLeafRecord] {
        self.records(SectionKind::PRUNE_LEAVES)
    }

    /// Triangles of the pruned leaves.
    #[must_use]
    pub fn prune_triangles(&self) -> &[TriangleRecord] {
        self.records(SectionKind::PRUNE_TRIANGLES)
    }

    /// `s_opt(λ)` samples.
    #[must_use]
    pub fn prune_scale(&self) -> &[CurveSample] {
        self.records(SectionKind::PRUNE_SCALE)
    }

    /// `λ(projected height)` samples.
    #[must_use]
    pub fn prune_lambda(&self) -> &[CurveSample] {
        self.records(SectionKind::PRUNE_LAMBDA)
    }

    /// `CALIBRATION` records (spec §6.15; empty without the section).
    #[must_use]
    pub fn calibration(&self) -> &[CalibrationRecord] {
        self.records(SectionKind::CALIBRATION)
    }

    /// `CALIBRATION_ELEVATIONS` records (spec §6.16; empty without the section, as in every file
    /// before 1.7).
    #[must_use]
    pub fn calibration_elevations(&self) -> &[ElevationCalibrationRecord] {
        self.records(SectionKind::CALIBRATION_ELEVATIONS)
    }

    /// `CALIBRATION_ADDED` records (spec §6.18): the calibration of the techniques added after
    /// 1.11 (codes [`calibration_technique::FIRST_ADDED`](crate::calibration_technique::FIRST_ADDED)
    /// and up), which `CALIBRATION` does not hold; with [`Self::calibration`] the file's tables.
    /// Empty without the section, as in every file before 1.12.
    #[must_use]
    pub fn calibration_added(&self) -> &[CalibrationRecord] {
        self.records(SectionKind::CALIBRATION_ADDED)
    }

    /// `CALIBRATION_ELEVATIONS_ADDED` records (spec §6.18): the calibration of the techniques of
    /// [`Self::calibration_added`] per elevation of the views; with
    /// [`Self::calibration_elevations`] the file's tables per elevation. Empty without the
    /// section, as in every file before 1.12.
    #[must_use]
    pub fn calibration_elevations_added(&self) -> &[ElevationCalibrationRecord] {
        self.records(SectionKind::CALIBRATION_ELEVATIONS_ADDED)
    }

    /// `CALIBRATION_FLIP` records (spec §6.19): each representation's mean LDR-FLIP error by
    /// projected height, the rows over every view ([`FlipCalibrationRecord::EVERY_VIEW`]) first,
    /// then per elevation, of the techniques of both [`Self::calibration`] and
    /// [`Self::calibration_added`]. Empty without the section, as in every file before 1.17 and
    /// in files built without FLIP; a reader then chooses by the RMSE of the other tables alone.
    /// Since 1.17.
    #[must_use]
    pub fn calibration_flip(&self) -> &[FlipCalibrationRecord] {
        self.records(SectionKind::CALIBRATION_FLIP)
    }

    /// `CHAIN_CALIBRATION_FLIP` records (spec §6.20): each LoD chain level's mean LDR-FLIP error
    /// by projected height over every view, sorted by level, then height. Empty without the
    /// section, as in every file before 1.18 and in files built without FLIP; a reader then picks
    /// the chain's level by the RMSE of `CHAIN_CALIBRATION` alone. Since 1.18.
    #[must_use]
    pub fn chain_calibration_flip(&self) -> &[ChainFlipCalibrationRecord] {
        self.records(SectionKind::CHAIN_CALIBRATION_FLIP)
    }

    /// `CHAIN_CALIBRATION` records (spec §6.17; empty without the section, as in every file
    /// before 1.8).
    #[must_use]
    pub fn chain_calibration(&self) -> &[ChainCalibrationRecord] {
        self.records(SectionKind::CHAIN_CALIBRATION)
    }

    /// Baseline level-of-detail chains: the levels of every tree (spec §6.12).
    #[must_use]
    pub fn lod_levels(&self) -> &[LodLevelRecord] {
        self.records(SectionKind::LOD_LEVELS)
    }

    /// Baseline level-of-detail chains: the levels' triangles.
    #[must_use]
    pub fn lod_triangles(&self) -> &[TriangleRecord] {
        self.records(SectionKind::LOD_TRIANGLES)
    }

    /// Baseline billboards of every tree (spec §6.13).
    #[must_use]
    pub fn billboards(&self) -> &[BillboardRecord] {
        self.records(SectionKind::BILLBOARDS)
    }

    /// Baseline octahedral impostors, one per tree that has one (spec §6.13.1). Since 1.11.
    #[must_use]
    pub fn octahedral(&self) -> &[OctahedralRecord] {
        self.records(SectionKind::OCTAHEDRAL)
    }

    /// The octahedral views' depth planes (spec §6.13.2): for each of [`Self::octahedral`] in
    /// order, `frames²` records, view `(i, j)` at `j·frames + i`. Empty without the section, as in
    /// every file before 1.13: every view is then the plane through the impostor's centre across
    /// its direction (all three values zero). Its length is checked by [`crate::verify()`], not
    /// at open. Since 1.13.
    #[must_use]
    pub fn octahedral_depth(&self) -> &[OctahedralDepthRecord] {
        self.records(SectionKind::OCTAHEDRAL_DEPTH)
    }

    /// Where each of [`Self::octahedral`]'s views' normals lie in its image (spec §6.13.3), one
    /// record per impostor in order (checked at open). Empty without the section, as in every
    /// file before 1.15: the views are then lit as a whole by each record's diffuse mixture and
    /// occlusion. Since 1.15.
    #[must_use]
    pub fn octahedral_normals(&self) -> &[OctahedralNormalRecord] {
        self.records(SectionKind::OCTAHEDRAL_NORMALS)
    }

    /// Where each of [`Self::octahedral`]'s views' normals lie in its image and at what size
    /// (spec §6.13.3), one record per impostor in order (checked at open), as the section
    /// `OCTAHEDRAL_NORMAL_GRIDS` holds them. Empty without the section. Since 1.16; readers
    /// take [`Self::octahedral_normal_grid`], which also reads the grids of 1.15.
    #[must_use]
    pub fn octahedral_normal_grids(&self) -> &[OctahedralNormalGridRecord] {
        self.records(SectionKind::OCTAHEDRAL_NORMAL_GRIDS)
    }

    /// The grid of the views' normals of impostor `index` of [`Self::octahedral`] (spec
    /// §6.13.3): its `OCTAHEDRAL_NORMAL_GRIDS` record (1.16), else the grid of the colour grid's
    /// size its `OCTAHEDRAL_NORMALS` record places (1.15, [`OctahedralNormalRecord::grid`]);
    /// `None` where the file has neither (before 1.15: the views are lit as a whole by the
    /// record's diffuse mixture and occlusion) or there is no such impostor.
    #[must_use]
    pub fn octahedral_normal_grid(&self, index: usize) -> Option<OctahedralNormalGridRecord> {
        crate::records::octahedral_normal_grid(
            self.octahedral(),
            self.octahedral_normal_grids(),
            self.octahedral_normals(),
            index,
        )
    }

    /// Ambient occlusion of each vertex (spec §6.14; [`crate::decode_ao`]), empty if the file has
    /// none; otherwise as long as [`Container::vertices`] (checked at open).
    #[must_use]
    pub fn vertex_ao(&self) -> &[u8] {
        self.raw_bytes(SectionKind::VERTEX_AO)
    }

    /// Ambient occlusion of each point, empty or as long as [`Container::points`].
    #[must_use]
    pub fn point_ao(&self) -> &[u8] {
        self.raw_bytes(SectionKind::POINT_AO)
    }

    /// How flat the surface of each point is (spec §6.5.1), empty or as long as
    /// [`Container::points`]: `unorm8` of the share `f` of its disc's coverage that faces along
    /// its normal. See [`crate::point_facing_scale`].
    #[must_use]
    pub fn point_facing(&self) -> &[u8] {
        self.raw_bytes(SectionKind::POINT_FACING)
    }

    /// Ambient occlusion of each plane, empty or as long as [`Container::planes`].
    #[must_use]
    pub fn plane_ao(&self) -> &[u8] {
        self.raw_bytes(SectionKind::PLANE_AO)
    }

    /// Ambient occlusion of each ellipsoid, empty or as long as [`Container::ellipsoids`]. Since
    /// 1.3.
    #[must_use]
    pub fn ellipsoid_ao(&self) -> &[u8] {
        self.raw_bytes(SectionKind::ELLIPSOID_AO)
    }

    /// Ambient occlusion of each line, empty or as long as [`Container::lines`]. Since 1.4.
    #[must_use]
    pub fn line_ao(&self) -> &[u8] {
        self.raw_bytes(SectionKind::LINE_AO)
    }

    /// Ambient occlusion of each far line, empty or as long as [`Container::far_lines`]. Since
    /// 1.9.
    #[must_use]
    pub fn far_line_ao(&self) -> &[u8] {
        self.raw_bytes(SectionKind::FAR_LINE_AO)
    }
}

fn bad_record(kind: SectionKind, index: usize, reason: String) -> Error {
    Error::BadRecord { kind, index, reason }
}

fn bad_header(field: &'static str, value: u64, rule: &'static str) -> Error {
    Error::BadHeader { field, value, rule }
}

/// Spec §3: magic, version, header fields, checksum, file size.
fn read_header(bytes: &[u8]) -> Result<Header> {
    let available = bytes.len() as u64;
    let Some(head) = bytes.get(..HEADER_SIZE) else {
        // A short file that does not even start with the magic is "not a treelod file".
        let n = bytes.len().min(MAGIC.len());
        if bytes[..n] != MAGIC[..n] {
            let mut found = [0u8; 12];
            found[..n].copy_from_slice(&bytes[..n]);
            return Err(Error::BadMagic { found });
        }
        return Err(Error::Truncated { what: "header", needed: HEADER_SIZE as u64, available });
    };
    let header: Header = bytemuck::pod_read_unaligned(head);
    if header.magic != MAGIC {
        return Err(Error::BadMagic { found: header.magic });
    }
    // The magic and version fields keep their place in every major version (spec §11).
    if header.major != MAJOR {
        let hint = if header.major > MAJOR {
            "; the file was written by a newer treelod, upgrade to read it"
        } else {
            "; pre-release files must be rebuilt"
        };
        return Err(Error::UnsupportedVersion { major: header.major, minor: header.minor, supported: MAJOR, hint });
    }
    let header_size = header.header_size;
    if !(HEADER_SIZE as u32..=MAX_HEADER_SIZE).contains(&header_size) || !header_size.is_multiple_of(16) {
        return Err(bad_header("header_size", header_size.into(), "must be a multiple of 16 in 64..=4096"));
    }
    if header.section_count > MAX_SECTIONS {
        return Err(bad_header("section_count", header.section_count.into(), "at most 256"));
    }
    if !header.table_offset.is_multiple_of(SECTION_ALIGN) || header.table_offset < u64::from(header_size) {
        return Err(bad_header("table_offset", header.table_offset, "multiple of 16, at or after the header"));
    }
    // Cannot overflow: offset is checked against the file length first, count is at most 256.
    let table_end = header.table_offset.saturating_add(u64::from(header.section_count) * SECTION_ENTRY_SIZE as u64);
    if table_end > available {
        return Err(Error::Truncated { what: "section table", needed: table_end, available });
    }
    let hs = header_size as usize;
    if hs > bytes.len() {
        return Err(Error::Truncated { what: "header", needed: hs as u64, available });
    }
    let mut crc = crc32fast::Hasher::new();
    crc.update(&bytes[..60]);
    crc.update(&[0; 4]);
    crc.update(&bytes[64..hs]);
    #[expect(clippy::cast_possible_truncation, reason = "table_end <= file length, which is addressable")]
    crc.update(&bytes[header.table_offset as usize..table_end as usize]);
    let computed = crc.finalize();
    if computed != header.header_checksum {
        return Err(Error::ChecksumMismatch {
            what: "header and section table".into(),
            stored: header.header_checksum,
            computed,
        });
    }
    if available < header.file_size {
        return Err(Error::Truncated { what: "file", needed: header.file_size, available });
    }
    if available > header.file_size {
        return Err(Error::TrailingBytes { file_size: header.file_size, extra: available - header.file_size });
    }
    Ok(header)
}

/// Spec §4: the section table's rules.
fn read_table(bytes: &[u8], header: &Header) -> Result<Vec<SectionEntry>> {
    let count = header.section_count as usize;
    #[expect(clippy::cast_possible_truncation, reason = "bounds checked in read_header")]
    let start = header.table_offset as usize;
    let table_end = (start + count * SECTION_ENTRY_SIZE) as u64;
    let mut entries: Vec<SectionEntry> = Vec::with_capacity(count);
    let mut prev_end = table_end;
    for index in 0..count {
        let at = start + index * SECTION_ENTRY_SIZE;
        let entry: SectionEntry = bytemuck::pod_read_unaligned(&bytes[at..at + SECTION_ENTRY_SIZE]);
        let kind = SectionKind(entry.kind);
        let bad = |reason: String| Error::BadSection { index, kind, reason };
        if !entry.offset.is_multiple_of(SECTION_ALIGN) {
            return Err(bad(format!("offset {} is not a multiple of 16", entry.offset)));
        }
        if entry.offset < prev_end {
            return Err(bad(format!(
                "offset {} overlaps the previous section or the table (which end at {prev_end}); sections are in offset order",
                entry.offset
            )));
        }
        let end = entry.offset.checked_add(entry.length).filter(|&end| end <= header.file_size).ok_or_else(|| {
            bad(format!("bytes {}+{} reach past the file size {}", entry.offset, entry.length, header.file_size))
        })?;
        prev_end = end;
        if entries.iter().any(|e| e.kind == entry.kind) {
            return Err(bad("the kind appears twice".into()));
        }
        let Some(record_size) = kind.record_size() else {
            entries.push(entry);
            continue; // unknown kind: bounds checked, then skipped (spec §4)
        };
        if entry.flags & !(FLAG_ZSTD | FLAG_SHUFFLE) != 0 {
            return Err(Error::UnsupportedFeature { kind, flags: entry.flags });
        }
        if entry.flags & FLAG_SHUFFLE != 0 && (entry.flags & FLAG_ZSTD == 0 || record_size == 1) {
            return Err(bad("the shuffle flag needs the zstd flag and a record size above 1".into()));
        }
        if entry.record_size != record_size {
            return Err(bad(format!("record_size {} but the spec's record is {record_size} bytes", entry.record_size)));
        }
        if !entry.raw_length.is_multiple_of(u64::from(record_size)) {
            return Err(bad(format!(
                "raw_length {} is not a multiple of the record size {record_size}",
                entry.raw_length
            )));
        }
        if entry.raw_length / u64::from(record_size) > u64::from(u32::MAX) {
            return Err(bad(format!("{} records, the limit is 2^32-1", entry.raw_length / u64::from(record_size))));
        }
        if entry.flags & FLAG_ZSTD == 0 && entry.raw_length != entry.length {
            return Err(bad(format!("uncompressed but raw_length {} != length {}", entry.raw_length, entry.length)));
        }
        if kind == SectionKind::META && entry.raw_length > MAX_META_BYTES {
            return Err(Error::DecodeLimit {
                kind,
                raw_length: entry.raw_length,
                limit: MAX_META_BYTES,
                rule: "metadata limit",
            });
        }
        entries.push(entry);
    }
    Ok(entries)
}

fn stored_slice<'a>(bytes: &'a [u8], entry: &SectionEntry) -> &'a [u8] {
    #[expect(clippy::cast_possible_truncation, reason = "bounds checked against the file length in read_table")]
    &bytes[entry.offset as usize..(entry.offset + entry.length) as usize]
}

pub(crate) fn check_section_checksum(bytes: &[u8], section: &Section) -> Result<()> {
    let computed = crc32fast::hash(stored_slice(bytes, &section.entry));
    if computed != section.entry.checksum {
        return Err(Error::ChecksumMismatch {
            what: format!("section {}", section.kind()),
            stored: section.entry.checksum,
            computed,
        });
    }
    Ok(())
}

/// Spec §8, the limits: whether the section is one the reader decodes (compressed, of a known
/// kind), and if so its decoded size taken from `budget`; an error for a section past a limit.
fn decode_limits(entry: &SectionEntry, budget: &mut u64) -> Result<bool> {
    let kind = SectionKind(entry.kind);
    if entry.flags & FLAG_ZSTD == 0 || kind.record_size().is_none() {
        return Ok(false);
    }
    let ratio_limit = entry.length.saturating_mul(MAX_COMPRESSION_RATIO);
    if entry.raw_length > ratio_limit {
        return Err(Error::DecodeLimit {
            kind,
            raw_length: entry.raw_length,
            limit: ratio_limit,
            rule: "1024 x stored size",
        });
    }
    if entry.raw_length > *budget {
        return Err(Error::DecodeLimit { kind, raw_length: entry.raw_length, limit: *budget, rule: "decode budget" });
    }
    *budget -= entry.raw_length;
    Ok(true)
}

/// Spec §8, a section within the limits ([`decode_limits`]): its checksum, then its zstd frame
/// into an exactly sized buffer.
fn decode_section(bytes: &[u8], index: usize, entry: &SectionEntry) -> Result<AlignedBuf> {
    let kind = SectionKind(entry.kind);
    let section = Section { entry: *entry, decoded: None };
    check_section_checksum(bytes, &section)?;
    let stored = stored_slice(bytes, entry);
    let corrupt = |reason: String| Error::Decompress { kind, reason };
    match zstd::zstd_safe::get_frame_content_size(stored) {
        Ok(Some(size)) if size == entry.raw_length => {}
        Ok(Some(size)) => return Err(corrupt(format!("frame declares {size} bytes, the table {}", entry.raw_length))),
        Ok(None) => return Err(corrupt("frame does not declare its content size".into())),
        Err(_) => return Err(corrupt("not a zstd frame".into())),
    }
    match zstd::zstd_safe::find_frame_compressed_size(stored) {
        Ok(n) if n == stored.len() => {}
        _ => return Err(corrupt(format!("the {} stored bytes are not exactly one zstd frame", stored.len()))),
    }
    let raw_len = usize::try_from(entry.raw_length).map_err(|_| Error::DecodeLimit {
        kind,
        raw_length: entry.raw_length,
        limit: usize::MAX as u64,
        rule: "address space",
    })?;
    let mut buf = AlignedBuf::zeroed(raw_len);
    if entry.flags & FLAG_SHUFFLE != 0 {
        decode_shuffled(stored, entry.record_size as usize, buf.as_mut_bytes())
            .map_err(|e| corrupt(format!("{e} (section {index})")))?;
        return Ok(buf);
    }
    let written = zstd::bulk::decompress_to_buffer(stored, buf.as_mut_bytes()).map_err(|e| corrupt(e.to_string()))?;
    if written != raw_len {
        return Err(corrupt(format!("decoded {written} bytes, the table says {raw_len} (section {index})")));
    }
    Ok(buf)
}

/// Bytes of a shuffled section [`decode_shuffled`] decompresses at a time (at most; a read holds
/// whole byte planes where one fits).
const UNSHUFFLE_CHUNK: usize = 4 << 20;

/// Records [`scatter_planes`] gives all their bytes of a read before going on: 96 KiB of 48-byte
/// records, which stay in the core's cache while each plane is written into them.
const UNSHUFFLE_TILE: usize = 2048;

/// Decompresses the one zstd frame `stored` (of exactly `out.len()` content bytes, checked before)
/// and undoes its byte shuffle (spec §8) into `out`, [`UNSHUFFLE_CHUNK`] bytes at a time: without
/// a second buffer of the whole section.
fn decode_shuffled(stored: &[u8], record_size: usize, out: &mut [u8]) -> std::io::Result<()> {
    decode_shuffled_by(stored, record_size, out, UNSHUFFLE_CHUNK)
}

/// [`decode_shuffled`], decompressing at most `chunk` bytes at a time.
///
/// The frame holds byte 0 of every record, then byte 1, and so on (planes of `n` bytes, `n` the
/// record count). Where whole planes fit in `chunk`, each read holds as many as fit (a multiple
/// of four where four fit; four where four fit in twice `chunk`), and [`scatter_planes`] writes
/// them into the records a tile at a time, the tiles side by side, four or eight planes of as
/// many records at once (words transposed): a 49 MB section of 48-byte records (1.02 M points)
/// then takes 12 passes over the output, not 48, each in cache-sized tiles. A plane longer than
/// `chunk` is read in runs of one plane, each byte written to its record.
fn decode_shuffled_by(stored: &[u8], record_size: usize, out: &mut [u8], chunk: usize) -> std::io::Result<()> {
    use std::io::Read as _;
    let raw_len = out.len();
    let n = raw_len / record_size.max(1);
    // The planes' bytes; bytes past the last whole record (none in a valid section) are dropped,
    // as `unshuffle` drops them.
    let body = n * record_size;
    let mut decoder = zstd::stream::read::Decoder::with_buffer(stored)?.single_frame();
    // As the one-shot decoder: no limit on the window the frame asks for (it is at most the
    // section's size, whose decoding the caller's budget already allowed).
    decoder.window_log_max(31)?;
    // Whole groups of four planes where they fit, or where four fit in twice `chunk`:
    // [`scatter_planes`] transposes them four or eight records at a time.
    let planes = match chunk.checked_div(n).unwrap_or(0) {
        p if p >= 4 => p / 4 * 4,
        _ if n > 0 && n.saturating_mul(4) <= chunk.saturating_mul(2) => 4,
        p => p,
    };
    let step = if planes > 0 { planes * n } else { chunk.max(1) };
    let mut buf = vec![0u8; step.min(raw_len)];
    let mut decoded = 0usize;
    while decoded < raw_len {
        let len = step.min(raw_len - decoded);
        decoder.read_exact(&mut buf[..len]).map_err(|e| {
            std::io::Error::new(e.kind(), format!("{e}: the frame ends within the {raw_len} bytes the table declares"))
        })?;
        if decoded < body {
            let in_body = len.min(body - decoded);
            if planes > 0 {
                // `decoded` and `in_body` are whole planes.
                scatter_planes(&buf[..in_body], n, record_size, decoded / n, out);
            } else {
                // The read covers shuffled bytes `decoded..decoded + in_body`: byte `j` of records
                // `i..`, in runs of one `j` each.
                let mut rest = &buf[..in_body];
                let mut at = decoded;
                while !rest.is_empty() {
                    let (j, i) = (at / n, at % n);
                    let run = rest.len().min(n - i);
                    for (record, &byte) in out[i * record_size..].chunks_mut(record_size).zip(&rest[..run]) {
                        record[j] = byte;
                    }
                    rest = &rest[run..];
                    at += run;
                }
            }
        }
        decoded += len;
    }
    // Reading on past the content checks the frame's end and its checksum.
    if decoder.read(&mut [0u8; 1])? != 0 {
        return Err(std::io::Error::other(format!("decoded more than the {raw_len} bytes the table declares")));
    }
    Ok(())
}

/// Writes whole byte planes `first..` (each `n` bytes, one byte of each of the `n` records, back
/// to back in `planes`) into the records of `out`, [`UNSHUFFLE_TILE`] records at a time.
/// The tiles are written side by side on the caller's rayon pool (each tile's bytes by one
/// thread, so the output is the same whatever the thread count).
fn scatter_planes(planes: &[u8], n: usize, record_size: usize, first: usize, out: &mut [u8]) {
    use rayon::prelude::*;
    let count = planes.len() / n;
    out[..n * record_size].par_chunks_mut(UNSHUFFLE_TILE * record_size).enumerate().for_each(|(tile, records)| {
        let start = tile * UNSHUFFLE_TILE;
        let end = start + records.len() / record_size;
        // Eight planes of eight records at a time (eight words in, transposed, eight words out),
        // then four of four; the records past the last whole group, and the planes past the
        // last group of four, a byte at a time.
        let (eights, fours) = (count / 8 * 8, count / 4 * 4);
        let whole = (end - start) / 8 * 8;
        for q in (0..eights).step_by(8) {
            transpose_group::<8, u64>(planes, n, record_size, first, q, start, whole, records);
        }
        for q in (eights..fours).step_by(4) {
            transpose_group::<4, u32>(planes, n, record_size, first, q, start, whole, records);
        }
        for q in 0..count {
            let done = if q < fours { whole } else { 0 };
            let plane = &planes[q * n + start + done..q * n + end];
            for (record, &byte) in records[done * record_size..].chunks_exact_mut(record_size).zip(plane) {
                record[first + q] = byte;
            }
        }
    });
}

/// A word of `N` bytes that [`transpose_group`] reads `N` of at a time.
trait Word:
    Copy
    + core::ops::BitXor<Output = Self>
    + core::ops::BitAnd<Output = Self>
    + core::ops::BitXorAssign
    + core::ops::Shr<u32, Output = Self>
    + core::ops::Shl<u32, Output = Self>
{
    /// The word of `bytes` (least significant first).
    fn read(bytes: &[u8]) -> Self;
    /// The word's bytes into `out` (least significant first).
    fn write(self, out: &mut [u8]);
    /// Per round of [`transpose_words`], the mask of the low element of each pair it swaps.
    const MASKS: [Self; 3];
}

/// [`Word`] for an unsigned integer type, with its masks.
macro_rules! word {
    ($t:ty, $masks:expr) => {
        impl Word for $t {
            fn read(bytes: &[u8]) -> Self {
                Self::from_le_bytes(bytes[..size_of::<Self>()].try_into().expect("a word's bytes"))
            }
            fn write(self, out: &mut [u8]) {
                out[..size_of::<Self>()].copy_from_slice(&self.to_le_bytes());
            }
            const MASKS: [Self; 3] = $masks;
        }
    };
}

word!(u64, [0x00FF_00FF_00FF_00FF, 0x0000_FFFF_0000_FFFF, 0x0000_0000_FFFF_FFFF]);
word!(u32, [0x00FF_00FF, 0x0000_FFFF, 0]);

/// The `N` × `N` bytes of `words` transposed: byte `j` of word `i` becomes byte `i` of word `j`
/// (bytes counted from the least significant). Rounds of swaps of single bytes between words one
/// apart, then of pairs two apart (and, for eight, of quadruples four apart).
fn transpose_words<const N: usize, W: Word>(words: &mut [W; N]) {
    let mut apart = 1;
    for mask in W::MASKS.into_iter().take(N.trailing_zeros() as usize) {
        #[expect(clippy::cast_possible_truncation, reason = "at most 32 bits")]
        let bits = (8 * apart) as u32;
        for k in (0..N).filter(|k| k & apart == 0) {
            let t = ((words[k] >> bits) ^ words[k + apart]) & mask;
            words[k + apart] ^= t;
            words[k] ^= t << bits;
        }
        apart *= 2;
    }
}

/// [`scatter_planes`]'s planes `q..q + N` of its tile's first `whole` records (a multiple of
/// `N`), `N` records at a time: a word of each plane, transposed, a word into each record.
#[expect(clippy::too_many_arguments, reason = "the tile's place in the section and the records")]
fn transpose_group<const N: usize, W: Word>(
    planes: &[u8],
    n: usize,
    record_size: usize,
    first: usize,
    q: usize,
    start: usize,
    whole: usize,
    records: &mut [u8],
) {
    for i in (0..whole).step_by(N) {
        let mut words: [W; N] = core::array::from_fn(|r| W::read(&planes[(q + r) * n + start + i..]));
        transpose_words(&mut words);
        for (j, word) in words.into_iter().enumerate() {
            word.write(&mut records[(i + j) * record_size + first + q..]);
        }
    }
}

/// Spec §6.1 grid and bounds, §6.2 cell count and tiling, §6.14 ambient-occlusion lengths (and
/// the other sections parallel to an array), §6.13.3 one kind of normal grids: the checks every
/// open makes, shared with the writer so it never emits a file the reader refuses.
/// `count` gives a section's record count.
pub(crate) fn check_block_and_cells(
    blocks: &[BlockRecord],
    cells: &[CellRecord],
    count: impl Fn(SectionKind) -> u64,
) -> Result<()> {
    let [block] = blocks else {
        return Err(bad_record(SectionKind::BLOCK, 0, format!("{} records, the spec requires 1", blocks.len())));
    };
    let grid = block.grid;
    if grid.iter().any(|&g| g == 0 || g > MAX_GRID_AXIS) || block.grid_cell_count() > MAX_GRID_CELLS {
        return Err(bad_record(
            SectionKind::BLOCK,
            0,
            format!("grid {grid:?} is outside 1..=256 per axis, 65536 cells"),
        ));
    }
    let finite = block.bounds_min.iter().chain(&block.bounds_max).all(|v| v.is_finite());
    if !finite || (0..3).any(|i| block.bounds_min[i] > block.bounds_max[i]) {
        return Err(bad_record(
            SectionKind::BLOCK,
            0,
            format!("bounds {:?}..{:?} are not finite and ordered", block.bounds_min, block.bounds_max),
        ));
    }
    if block.tree_count == 0 {
        return Err(bad_record(SectionKind::BLOCK, 0, "tree_count is 0".into()));
    }
    let expected = block.grid_cell_count() + 1;
    if cells.len() != expected {
        return Err(bad_record(
            SectionKind::CELLS,
            0,
            format!("{} cell records, the grid {grid:?} needs {expected} (cells + block cell)", cells.len()),
        ));
    }
    // Spec §6.14, §6.10.2, §6.5.1: an ambient-occlusion section holds one byte per record of its
    // array, `PLANE_DIFFUSE` one record per plane, `POINT_FACING` one byte per point,
    // `OCTAHEDRAL_NORMALS` and `OCTAHEDRAL_NORMAL_GRIDS` (§6.13.3) one record per octahedral
    // impostor.
    let parallel = [
        (SectionKind::PLANE_DIFFUSE, SectionKind::PLANES),
        (SectionKind::POINT_FACING, SectionKind::POINTS),
        (SectionKind::OCTAHEDRAL_NORMALS, SectionKind::OCTAHEDRAL),
        (SectionKind::OCTAHEDRAL_NORMAL_GRIDS, SectionKind::OCTAHEDRAL),
    ];
    for (kind, of) in AO_KINDS.into_iter().chain(parallel) {
        let (ao, records) = (count(kind), count(of));
        if ao != 0 && ao != records {
            return Err(bad_record(kind, 0, format!("{ao} records, {of} has {records}: one per record or none")));
        }
    }
    // Spec §6.13.3: the normal grids are given by 1.15's `OCTAHEDRAL_NORMALS` or by 1.16's
    // `OCTAHEDRAL_NORMAL_GRIDS`, never both (an empty section counts as absent).
    let (normals, grids) = (SectionKind::OCTAHEDRAL_NORMALS, SectionKind::OCTAHEDRAL_NORMAL_GRIDS);
    if count(normals) != 0 && count(grids) != 0 {
        return Err(bad_record(
            grids,
            0,
            format!("the file also holds {normals}; a file gives its normal grids by one of the two kinds"),
        ));
    }
    for slot in 0..6 {
        let kind = cells[0].ranges()[slot].0;
        let total = count(kind);
        let mut next = 0u64;
        for (index, cell) in cells.iter().enumerate() {
            let range = cell.ranges()[slot].1;
            if u64::from(range.first) != next {
                return Err(Error::BadCell {
                    cell: index,
                    reason: format!("{kind} range starts at {}, expected {next} (ranges tile the array)", range.first),
                });
            }
            next += u64::from(range.count);
        }
        if next != total {
            return Err(Error::BadCell {
                cell: cells.len() - 1,
                reason: format!("{kind} ranges end at {next}, the section has {total} records"),
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{UNSHUFFLE_CHUNK, decode_shuffled, decode_shuffled_by, transpose_words};
    use crate::pack::{shuffle, unshuffle};

    #[test]
    fn words_transpose_as_byte_matrices() {
        #[expect(clippy::cast_possible_truncation, reason = "test bytes")]
        let bytes: [[u8; 8]; 8] = core::array::from_fn(|i| core::array::from_fn(|j| (16 * i + j) as u8));
        let mut eight = bytes.map(u64::from_le_bytes);
        transpose_words(&mut eight);
        for (j, word) in eight.iter().enumerate() {
            assert_eq!(word.to_le_bytes(), core::array::from_fn(|i| bytes[i][j]), "word {j} of eight");
        }
        let mut four: [u32; 4] = core::array::from_fn(|i| u32::from_le_bytes(bytes[i][..4].try_into().unwrap()));
        transpose_words(&mut four);
        for (j, word) in four.iter().enumerate() {
            assert_eq!(word.to_le_bytes(), core::array::from_fn(|i| bytes[i][j]), "word {j} of four");
        }
    }

    #[test]
    fn chunked_decoding_unshuffles_as_a_whole_buffer() {
        // Reads of whole planes (several, one, and the whole section at once), of parts of a
        // plane (a chunk shorter than a plane, dividing it or not), with a record size that does
        // not divide the chunk, a tail shorter than a record, and a section shorter than one
        // record; then the default chunk.
        let cases = [
            (1000 * 7 + 3, 7, 3000),
            (1000 * 7 + 3, 7, 1000),
            (1000 * 7 + 3, 7, 999),
            (1000 * 7 + 3, 7, 250),
            (1000 * 7 + 3, 7, 1 << 20),
            (5000 * 48, 48, 5000 * 5),
            (5000 * 48, 48, 4096 * 3 + 17),
            (5, 24, 4),
            (5, 24, 1 << 20),
            (2 * UNSHUFFLE_CHUNK + 1000 * 7 + 3, 7, UNSHUFFLE_CHUNK),
            (48 * 1000, 48, UNSHUFFLE_CHUNK),
            // Groups of eight planes, transposed eight records at a time: whole groups with a
            // tail of planes, records past the last eight of a tile and of the section, tiles
            // cut by the section's end.
            (5003 * 48, 48, 5003 * 8),
            (5003 * 48, 48, 5003 * 19),
            (4099 * 28 + 5, 28, 4099 * 9),
            (2048 * 24 + 24 * 7, 24, (2048 + 7) * 24),
            (3001 * 24, 24, 3001 * 6),
            (3001 * 7, 7, 3001 * 4),
            (3001 * 28, 28, 3001 * 2),
            (3001 * 28, 28, 3001 * 2 - 1),
        ];
        for (len, record_size, chunk) in cases {
            #[expect(clippy::cast_possible_truncation, reason = "test bytes")]
            let raw: Vec<u8> = (0..len).map(|i| (i * 31 % 251) as u8 ^ (i / 997) as u8).collect();
            let mut shuffled = vec![0; len];
            shuffle(&raw, record_size, &mut shuffled);
            let frame = zstd::bulk::compress(&shuffled, 3).unwrap();
            let mut expected = vec![0; len];
            unshuffle(&shuffled, record_size, &mut expected);
            let whole = len / record_size * record_size;
            assert!(expected[..whole] == raw[..whole], "the shuffle's own round trip");
            let mut out = vec![0; len];
            decode_shuffled_by(&frame, record_size, &mut out, chunk).unwrap();
            assert!(out == expected, "len {len}, record size {record_size}, chunk {chunk}");
            let mut short = vec![0; len + 1];
            assert!(
                decode_shuffled_by(&frame, record_size, &mut short, chunk).is_err(),
                "a frame shorter than declared"
            );
            let mut long = vec![0; len - 1];
            assert!(decode_shuffled_by(&frame, record_size, &mut long, chunk).is_err(), "a frame longer than declared");
            if chunk == UNSHUFFLE_CHUNK {
                let mut by_default = vec![0; len];
                decode_shuffled(&frame, record_size, &mut by_default).unwrap();
                assert!(by_default == expected);
            }
        }
    }
}
