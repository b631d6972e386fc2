//! The deterministic writer: [`ContainerData`] in, `.treelod` bytes out (spec §3–§8).
//!
//! Sections are written in ascending kind order, each on a 16-byte boundary with zero padding, so
//! the same data and options always give the same bytes. They are compressed in parallel on the
//! caller's rayon pool, each into a zstd frame of its own that no other section or thread affects,
//! so the bytes do not depend on the thread count either.

use std::io::{Read as _, Write as _};
use std::path::Path;

use bytemuck::Pod;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::metadata::MAX_META_BYTES;
use crate::metadata::Metadata;
use crate::reader::{Container, MAX_COMPRESSION_RATIO, check_block_and_cells};
use crate::records::{
    BillboardRecord, BlockRecord, CalibrationRecord, CellRecord, ChainCalibrationRecord, ChainFlipCalibrationRecord,
    CurveSample, ElevationCalibrationRecord, EllipsoidRecord, FLAG_SHUFFLE, FLAG_ZSTD, FlipCalibrationRecord,
    HEADER_SIZE, Header, ImageRecord, LineRecord, LodLevelRecord, MAGIC, MAJOR, MINOR, MaterialRecord,
    OctahedralDepthRecord, OctahedralNormalGridRecord, OctahedralNormalRecord, OctahedralRecord, PlaneDiffuseRecord,
    PlaneLeafRecord, PlaneRecord, PointRecord, PruneLeafRecord, SECTION_ALIGN, SECTION_ENTRY_SIZE, SectionEntry,
    SectionKind, TriangleRecord, VertexRecord, image_format,
};

/// How sections are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Every section uncompressed: the whole file is usable in place from a memory map.
    None,
    /// zstd at the given level (1–22) for every section where it pays (spec §8); sections of at
    /// most [`SMALL_SECTION`] bytes at level 19 or above ([`section_level`]).
    Zstd {
        /// zstd compression level.
        level: i32,
    },
}

impl Default for Compression {
    /// zstd at [`DEFAULT_LEVEL`] (sections of at most [`SMALL_SECTION`] bytes at 19).
    fn default() -> Self {
        Self::Zstd { level: DEFAULT_LEVEL }
    }
}

/// The default zstd level, 6: the smallest level whose containers of the shared models are,
/// together, within 2 % of level 9's (the default before), at two thirds of its time.
///
/// Measured with [`ContainerData::to_bytes`] on containers of the shared models built with
/// default settings (16 AO rays) and decoded from `--compression none`; seconds on 2 cores, on
/// the global pool (2 threads) and on one, median of 7 runs, levels interleaved; sizes in MB (10⁶
/// bytes) and their change against level 9:
///
/// ```text
/// level  maple 669k (87.6 MB raw)          oak 23k (3.68 MB raw)    all 7 shared models
///        MB             2 thr s  1 thr s   MB      2 thr s          MB      worst model
///  1     29.80 +12.0 %  0.36     0.48      1.743   0.011            46.99   +12.0 %
///  3     28.37  +6.6 %  0.45     0.64      1.708   0.014            44.99    +6.6 %
///  5     27.38  +2.9 %  0.63     0.89      1.683   0.023            43.67    +2.9 %
///  6     27.03  +1.6 %  0.75     1.11      1.679   0.027            43.20    +1.6 %
///  7     26.92  +1.2 %  0.88     1.31      1.680   0.031            43.05    +1.2 %
///  8     26.90  +1.1 %  1.05     1.57      1.684   0.038            43.02    +1.1 %
///  9     26.60          1.14     1.67      1.684   0.040            42.72
/// 12     26.46  -0.5 %  2.07     3.30      1.680   0.064            42.53     0.0 %
/// 19     24.45  -8.1 %  22.8     31.3      1.573   0.335            39.52     0.0 %
/// ```
///
/// Level 6 is the knee: 7 saves 0.4 % of the maple for 17 % more time and 9 another 1.2 % for
/// 30 % more, while 5 costs 1.3 % for 16 % less (2.2 % over level 9 in all, past the 2 %). On the
/// smaller trees 6 is within 0.5 % of 9 (smaller on the oak), and every container stays below its
/// source (at most 0.98 of it, the pine's). Level 19 writes 8 % less in 20 times the time. Not
/// taken: zstd's window at level 9's 4 MiB (`windowLog` 22) brings level 7 within 0.3 % of 9
/// in three quarters of its time on the maple's byte-shuffled arrays, but it would change
/// the frames of every level.
pub const DEFAULT_LEVEL: i32 = 6;

/// Everything a container holds, as owned arrays. Empty optional arrays are not written.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ContainerData {
    /// `META`.
    pub metadata: Metadata,
    /// `BLOCK`.
    pub block: BlockRecord,
    /// `CELLS`: grid cells, then the block cell.
    pub cells: Vec<CellRecord>,
    /// `VERTICES`.
    pub vertices: Vec<VertexRecord>,
    /// `TRIANGLES`.
    pub triangles: Vec<TriangleRecord>,
    /// `POINTS`.
    pub points: Vec<PointRecord>,
    /// `MATERIALS`.
    pub materials: Vec<MaterialRecord>,
    /// `IMAGES`.
    pub images: Vec<ImageRecord>,
    /// `IMAGE_DATA`.
    pub image_data: Vec<u8>,
    /// `ELLIPSOIDS`.
    pub ellipsoids: Vec<EllipsoidRecord>,
    /// `LINES`.
    pub lines: Vec<LineRecord>,
    /// `FAR_LINES`: empty, or the block's far lines (spec §6.9.1; since 1.9).
    pub far_lines: Vec<LineRecord>,
    /// `PLANES`.
    pub planes: Vec<PlaneRecord>,
    /// `PLANE_LEAVES`: empty, or `leaf_count` records per plane (spec §6.10.1).
    pub plane_leaves: Vec<PlaneLeafRecord>,
    /// `PLANE_DIFFUSE`: empty, or one record per plane (spec §6.10.2; since 1.10).
    pub plane_diffuse: Vec<PlaneDiffuseRecord>,
    /// `PRUNE_LEAVES`.
    pub prune_leaves: Vec<PruneLeafRecord>,
    /// `PRUNE_TRIANGLES`.
    pub prune_triangles: Vec<TriangleRecord>,
    /// `PRUNE_SCALE`.
    pub prune_scale: Vec<CurveSample>,
    /// `PRUNE_LAMBDA`.
    pub prune_lambda: Vec<CurveSample>,
    /// `LOD_LEVELS` (baseline).
    pub lod_levels: Vec<LodLevelRecord>,
    /// `LOD_TRIANGLES` (baseline).
    pub lod_triangles: Vec<TriangleRecord>,
    /// `BILLBOARDS` (baseline).
    pub billboards: Vec<BillboardRecord>,
    /// `OCTAHEDRAL` (baseline; since 1.11).
    pub octahedral: Vec<OctahedralRecord>,
    /// `OCTAHEDRAL_DEPTH`: empty, or each octahedral view's depth plane, `frames²` per `OCTAHEDRAL`
    /// record in its order (spec §6.13.2; since 1.13).
    pub octahedral_depth: Vec<OctahedralDepthRecord>,
    /// `OCTAHEDRAL_NORMALS`: empty, or where each `OCTAHEDRAL` record's views' normals lie in its
    /// image, one per record in its order (spec §6.13.3; since 1.15).
    pub octahedral_normals: Vec<OctahedralNormalRecord>,
    /// `OCTAHEDRAL_NORMAL_GRIDS`: empty, or where each `OCTAHEDRAL` record's views' normals lie in
    /// its image and at what size, one per record in its order (spec §6.13.3; since 1.16). A
    /// file holds this or `octahedral_normals`, not both.
    pub octahedral_normal_grids: Vec<OctahedralNormalGridRecord>,
    /// `VERTEX_AO`: empty, or one byte per vertex ([`crate::encode_ao`]).
    pub vertex_ao: Vec<u8>,
    /// `POINT_AO`: empty, or one byte per point.
    pub point_ao: Vec<u8>,
    /// `PLANE_AO`: empty, or one byte per plane.
    pub plane_ao: Vec<u8>,
    /// `ELLIPSOID_AO`: empty, or one byte per ellipsoid (since 1.3).
    pub ellipsoid_ao: Vec<u8>,
    /// `LINE_AO`: empty, or one byte per line (since 1.4).
    pub line_ao: Vec<u8>,
    /// `FAR_LINE_AO`: empty, or one byte per far line (since 1.9).
    pub far_line_ao: Vec<u8>,
    /// `POINT_FACING`: empty, or one byte per point (spec §6.5.1; since 1.14).
    pub point_facing: Vec<u8>,
    /// `CALIBRATION`: empty, or each representation's error and cost by projected height (since
    /// 1.5).
    pub calibration: Vec<CalibrationRecord>,
    /// `CALIBRATION_ELEVATIONS`: empty, or the calibration per elevation of the views (since
    /// 1.7).
    pub calibration_elevations: Vec<ElevationCalibrationRecord>,
    /// `CHAIN_CALIBRATION`: empty, or each LoD chain level's error and cost by projected height
    /// (since 1.8).
    pub chain_calibration: Vec<ChainCalibrationRecord>,
    /// `CALIBRATION_ADDED`: empty, or the error and cost by projected height of the techniques
    /// added after 1.11, codes [`calibration_technique::FIRST_ADDED`](crate::calibration_technique::FIRST_ADDED)
    /// and up (spec §6.18; since 1.12).
    pub calibration_added: Vec<CalibrationRecord>,
    /// `CALIBRATION_ELEVATIONS_ADDED`: empty, or the calibration of those techniques per elevation
    /// of the views (spec §6.18; since 1.12).
    pub calibration_elevations_added: Vec<ElevationCalibrationRecord>,
    /// `CALIBRATION_FLIP`: empty, or each representation's mean LDR-FLIP error by projected height,
    /// over every view and per elevation of the views (spec §6.19; since 1.17).
    pub calibration_flip: Vec<FlipCalibrationRecord>,
    /// `CHAIN_CALIBRATION_FLIP`: empty, or each LoD chain level's mean LDR-FLIP error by projected
    /// height over every view (spec §6.20; since 1.18).
    pub chain_calibration_flip: Vec<ChainFlipCalibrationRecord>,
    /// Sections of kinds this version does not define (kind, bytes): private extensions, or data of
    /// a later minor version carried through. Written uncompressed with `record_size` 1.
    pub extra_sections: Vec<(u32, Vec<u8>)>,
}

impl ContainerData {
    /// The grid of the views' normals of impostor `index` of `octahedral`, as
    /// [`Container::octahedral_normal_grid`] reads it: its `OCTAHEDRAL_NORMAL_GRIDS` record, else
    /// the grid its `OCTAHEDRAL_NORMALS` record places.
    #[must_use]
    pub fn octahedral_normal_grid(&self, index: usize) -> Option<OctahedralNormalGridRecord> {
        crate::records::octahedral_normal_grid(
            &self.octahedral,
            &self.octahedral_normal_grids,
            &self.octahedral_normals,
            index,
        )
    }

    /// Copies every section of an open container back into owned arrays.
    #[must_use]
    pub fn from_container(c: &Container) -> Self {
        Self {
            metadata: c.metadata().clone(),
            block: *c.block(),
            cells: c.cells().to_vec(),
            vertices: c.vertices().to_vec(),
            triangles: c.triangles().to_vec(),
            points: c.points().to_vec(),
            materials: c.materials().to_vec(),
            images: c.images().to_vec(),
            image_data: c.image_data().to_vec(),
            ellipsoids: c.ellipsoids().to_vec(),
            lines: c.lines().to_vec(),
            far_lines: c.far_lines().to_vec(),
            planes: c.planes().to_vec(),
            plane_leaves: c.plane_leaves().to_vec(),
            plane_diffuse: c.plane_diffuse().to_vec(),
            prune_leaves: c.prune_leaves().to_vec(),
            prune_triangles: c.prune_triangles().to_vec(),
            prune_scale: c.prune_scale().to_vec(),
            prune_lambda: c.prune_lambda().to_vec(),
            lod_levels: c.lod_levels().to_vec(),
            lod_triangles: c.lod_triangles().to_vec(),
            billboards: c.billboards().to_vec(),
            octahedral: c.octahedral().to_vec(),
            octahedral_depth: c.octahedral_depth().to_vec(),
            octahedral_normals: c.octahedral_normals().to_vec(),
            octahedral_normal_grids: c.octahedral_normal_grids().to_vec(),
            vertex_ao: c.vertex_ao().to_vec(),
            point_ao: c.point_ao().to_vec(),
            plane_ao: c.plane_ao().to_vec(),
            ellipsoid_ao: c.ellipsoid_ao().to_vec(),
            line_ao: c.line_ao().to_vec(),
            far_line_ao: c.far_line_ao().to_vec(),
            point_facing: c.point_facing().to_vec(),
            calibration: c.calibration().to_vec(),
            calibration_elevations: c.calibration_elevations().to_vec(),
            chain_calibration: c.chain_calibration().to_vec(),
            calibration_added: c.calibration_added().to_vec(),
            calibration_elevations_added: c.calibration_elevations_added().to_vec(),
            calibration_flip: c.calibration_flip().to_vec(),
            chain_calibration_flip: c.chain_calibration_flip().to_vec(),
            extra_sections: c
                .sections()
                .iter()
                .filter(|s| s.kind().record_size().is_none() && !s.is_compressed())
                .map(|s| (s.entry.kind, c.stored_bytes(s).to_vec()))
                .collect(),
        }
    }

    /// The sections to write, in ascending kind order, as (kind, bytes, record size). Record arrays
    /// are borrowed, not copied: a large build encodes one section at a time.
    fn sections(&self) -> Result<Vec<SectionBytes<'_>>> {
        let meta = self.checked_metadata()?;
        Ok(Self::arrange(self.borrowed_sections(meta)))
    }

    /// As [`Self::sections`], but with the arrays moved out of the data rather than borrowed, so
    /// that each is freed as soon as its section is written.
    fn into_sections(mut self) -> Result<Vec<SectionBytes<'static>>> {
        let meta = self.checked_metadata()?;
        macro_rules! take {
            ($field:ident) => {{
                let payload: Box<dyn Payload> = Box::new(std::mem::take(&mut self.$field));
                payload
            }};
        }
        let mut out: Vec<SectionBytes<'static>> = vec![
            (SectionKind::META, Box::new(meta), 1),
            (SectionKind::BLOCK, Box::new(vec![self.block]), 0),
            (SectionKind::CELLS, take!(cells), 0),
        ];
        let optional = optional_sections!(take);
        out.extend(optional.into_iter().filter(|(_, b)| !b.bytes().is_empty()).map(|(k, b)| (k, b, 0)));
        out.extend(std::mem::take(&mut self.extra_sections).into_iter().map(|(kind, bytes)| {
            let payload: Box<dyn Payload> = Box::new(bytes);
            (SectionKind(kind), payload, 1)
        }));
        Ok(Self::arrange(out))
    }

    /// Every section borrowed, with `meta` as META, in field order; empty optional ones left out.
    fn borrowed_sections(&self, meta: Vec<u8>) -> Vec<SectionBytes<'_>> {
        macro_rules! borrow {
            ($field:ident) => {{
                let payload: Box<dyn Payload + '_> = Box::new(self.$field.as_slice());
                payload
            }};
        }
        let mut out: Vec<SectionBytes<'_>> = vec![
            (SectionKind::META, Box::new(meta), 1),
            (SectionKind::BLOCK, Box::new(std::slice::from_ref(&self.block)), 0),
            (SectionKind::CELLS, borrow!(cells), 0),
        ];
        let optional = optional_sections!(borrow);
        out.extend(optional.into_iter().filter(|(_, b)| !b.bytes().is_empty()).map(|(k, b)| (k, b, 0)));
        out.extend(self.extra_sections.iter().map(|(kind, bytes)| {
            let payload: Box<dyn Payload + '_> = Box::new(bytes.as_slice());
            (SectionKind(*kind), payload, 1)
        }));
        out
    }

    /// Sections in ascending kind order with the record sizes of known kinds.
    fn arrange(mut out: Vec<SectionBytes<'_>>) -> Vec<SectionBytes<'_>> {
        out.sort_by_key(|(k, _, _)| *k);
        for (kind, _, size) in &mut out {
            if let Some(known) = kind.record_size() {
                *size = known;
            }
        }
        out
    }

    /// META's bytes, after checking that the data makes a file this crate opens: the metadata
    /// within its limit, extra kinds unknown and distinct, record counts, block and cells.
    fn checked_metadata(&self) -> Result<Vec<u8>> {
        let meta = postcard::to_allocvec(&self.metadata).map_err(|e| Error::Write(format!("metadata: {e}")))?;
        if meta.len() as u64 > MAX_META_BYTES {
            return Err(Error::Write(format!("metadata is {} bytes, the limit is {MAX_META_BYTES}", meta.len())));
        }
        for (kind, _) in &self.extra_sections {
            let kind = SectionKind(*kind);
            if kind.record_size().is_some() {
                return Err(Error::Write(format!("extra section kind {kind} is a known kind")));
            }
        }
        let out = Self::arrange(self.borrowed_sections(Vec::new()));
        if out.windows(2).any(|w| w[0].0 == w[1].0) {
            return Err(Error::Write("an extra section kind appears twice".into()));
        }
        for (kind, bytes, size) in &out {
            if bytes.bytes().len() as u64 / u64::from((*size).max(1)) > u64::from(u32::MAX) {
                return Err(Error::Write(format!("section {kind} has more than 2^32-1 records")));
            }
        }
        let count = |kind: SectionKind| {
            out.iter()
                .find(|(k, _, _)| *k == kind)
                .map_or(0, |(_, b, size)| b.bytes().len() as u64 / u64::from((*size).max(1)))
        };
        // The writer never emits a file its own reader refuses (spec §6.1, §6.2).
        check_block_and_cells(std::slice::from_ref(&self.block), &self.cells, count)
            .map_err(|e| Error::Write(format!("the data breaks the spec: {e}")))?;
        Ok(meta)
    }

    /// Encodes the container (spec §3–§8). Deterministic: same data and compression, same bytes.
    ///
    /// # Errors
    /// [`Error::Write`] if the data cannot make a file this crate would open (wrong cell count, ranges
    /// that do not tile the arrays, too many records).
    pub fn to_bytes(&self, compression: Compression) -> Result<Vec<u8>> {
        let mut out = std::io::Cursor::new(Vec::new());
        self.encode(compression, &mut out).map_err(|e| match e {
            EncodeError::Data(e) => e,
            EncodeError::Io(e) => Error::Write(format!("in memory: {e}")),
        })?;
        Ok(out.into_inner())
    }

    /// Encodes and writes the container to `path` atomically: to a temporary file in the same
    /// directory, flushed, then renamed over `path`. On failure `path` is untouched. Sections are
    /// compressed in parallel on the current rayon pool, each into its own frame, then written in
    /// order (the same bytes on any number of threads), so the memory this takes beyond the data
    /// itself is the compressed sections: at most the file's size. Returns the file's size in
    /// bytes.
    ///
    /// # Errors
    /// [`Error::Write`] as [`Self::to_bytes`]; [`Error::Io`] naming the path if writing fails.
    pub fn write_to_path(&self, path: impl AsRef<Path>, compression: Compression) -> Result<u64> {
        write_sections_to_path(self.sections()?, path.as_ref(), compression, |_| Ok(()))
    }

    /// As [`Self::write_to_path`], consuming the data: each array is freed as soon as its section
    /// is compressed (or, where compressing does not pay, written), so the compressed sections
    /// take the place of the arrays rather than adding to them. Same bytes.
    ///
    /// # Errors
    /// As [`Self::write_to_path`].
    pub fn into_path(self, path: impl AsRef<Path>, compression: Compression) -> Result<u64> {
        self.into_path_checked(path, compression, |_| Ok(()))
    }

    /// As [`Self::into_path`], but the temporary file is opened and fully verified
    /// ([`Container::open`] and [`crate::verify`]) before it is renamed over `path`: a file that
    /// fails is removed and never replaces what was at `path`.
    ///
    /// # Errors
    /// As [`Self::into_path`]; [`Error::NotReplaced`] with the verification's error if the written
    /// file fails it (`path` is then untouched).
    pub fn into_path_verified(self, path: impl AsRef<Path>, compression: Compression) -> Result<u64> {
        self.into_path_checked(path, compression, verify_written)
    }

    /// As [`Self::into_path`], calling `check` on the complete, flushed temporary file before it
    /// is renamed over `path`. If `check` fails the temporary file is removed and `path` is left as
    /// it was (an existing file there is kept byte for byte).
    ///
    /// # Errors
    /// As [`Self::into_path`]; [`Error::NotReplaced`] holding the error of `check`.
    pub fn into_path_checked(
        self,
        path: impl AsRef<Path>,
        compression: Compression,
        check: impl FnOnce(&Path) -> Result<()>,
    ) -> Result<u64> {
        let path = path.as_ref();
        let sections = self.into_sections()?;
        write_sections_to_path(sections, path, compression, check)
    }

    /// Writes the file to `sink`: a zeroed header and table, each section's payload as it is
    /// encoded, then the real header and table. Returns the file size.
    fn encode<W: std::io::Write + std::io::Seek>(
        &self,
        compression: Compression,
        sink: &mut W,
    ) -> std::result::Result<u64, EncodeError> {
        encode_sections(self.sections()?, compression, sink)
    }
}

/// Writes `sections` to `path` atomically: to a temporary file in the same directory, flushed,
/// checked by `check`, then renamed over `path`. On any failure the temporary file is removed
/// (dropping it does) and `path` is untouched.
fn write_sections_to_path(
    sections: Vec<SectionBytes<'_>>,
    path: &Path,
    compression: Compression,
    check: impl FnOnce(&Path) -> Result<()>,
) -> Result<u64> {
    let io = |source| Error::Io { path: path.to_owned(), source };
    let mut tmp = temporary_beside(path)?;
    let mut sink = std::io::BufWriter::new(tmp.as_file_mut());
    let size = encode_sections(sections, compression, &mut sink).map_err(|e| match e {
        EncodeError::Data(e) => e,
        EncodeError::Io(e) => io(e),
    })?;
    sink.flush().map_err(io)?;
    drop(sink);
    tmp.as_file().sync_all().map_err(io)?;
    // Whatever `check` opened (a memory map) is closed when it returns, before the rename.
    check(tmp.path()).map_err(|source| Error::NotReplaced {
        path: path.to_owned(),
        kept: path.exists(),
        source: Box::new(strip_file(source)),
    })?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(size)
}

/// The error without the [`Error::InFile`] wrapper naming the temporary file, whose name means
/// nothing to the user (the error is reported for the output).
fn strip_file(error: Error) -> Error {
    match error {
        Error::InFile { source, .. } => strip_file(*source),
        other => other,
    }
}

/// Writes the file to `sink` ([`ContainerData::encode`]); each section's bytes are dropped once
/// written.
fn encode_sections<W: std::io::Write + std::io::Seek>(
    sections: Vec<SectionBytes<'_>>,
    compression: Compression,
    sink: &mut W,
) -> std::result::Result<u64, EncodeError> {
    let table_offset = HEADER_SIZE as u64;
    let table_len = sections.len() * SECTION_ENTRY_SIZE;
    let mut position = 0u64;
    let mut payload_offset = align(table_offset + table_len as u64);
    let mut entries = Vec::with_capacity(sections.len());
    // Each section is compressed into its own frame, all of them in parallel, and written in kind
    // order once all are done. No frame depends on another or on the thread that made it, so the
    // bytes do not depend on the thread count. zstd's own multithreading is not used: its frames
    // differ from these (not with its worker count: 1, 2 and 4 workers wrote the same bytes), and
    // on the maple's points (49 MB raw, level 6, one frame 0.66–0.80 s on one thread) one worker
    // took 0.49–0.52 s but held 38 MB more (its 8 MiB jobs), and with 2 MiB jobs 0.53 s and 9 MB
    // more; in the whole build (sections already compressed side by side on 2 cores) the write
    // stage went from 0.96–1.09 s to 0.80–0.92 s, and the build's peak from 121 to 155 MB.
    // Compressing the largest sections first (one task each, then put back in kind order; the
    // same bytes) was measured and not taken: the maple's default build wrote in 0.80–0.85 s
    // against 1.14–1.18 s but peaked at 124–126 MB against 120–121 (its points and vertices in
    // flight at once), and with `--ao-rays 0` it wrote in as long (medians 0.95 s) at 118 MB
    // against 123 (2 and 4 alternating runs).
    //
    // A section whose frame is kept frees its raw array as soon as it is compressed, so the
    // build's arrays and their compressed sections are never both whole in memory: the frames
    // replace the arrays they come from, each array is freed once written, and what the writing
    // adds is the frames in flight (at most the file's size).
    // Image formats of later minors mark the file too (spec §11): BC7 images are 1.6.
    let image_minor = sections
        .iter()
        .filter(|(kind, _, _)| *kind == SectionKind::IMAGES)
        .flat_map(|(_, payload, _)| payload.bytes().chunks_exact(size_of::<ImageRecord>()))
        .map(|bytes| image_format::marks_minor(bytemuck::pod_read_unaligned::<ImageRecord>(bytes).format))
        .max()
        .unwrap_or(0);
    let stored: Vec<Stored<'_>> = sections
        .into_par_iter()
        .map(|(kind, payload, record_size)| {
            let raw_length = payload.bytes().len() as u64;
            let (bytes, flags) = match pack_section(kind, payload.bytes(), record_size, compression)? {
                Some((frame, flags)) => (StoredBytes::Frame(frame), flags),
                None => (StoredBytes::Raw(payload), 0),
            };
            Ok(Stored { kind, record_size, raw_length, flags, bytes })
        })
        .collect::<Result<_>>()?;
    for section in stored {
        let bytes = section.bytes.bytes();
        entries.push(SectionEntry {
            kind: section.kind.0,
            flags: section.flags,
            offset: payload_offset,
            length: bytes.len() as u64,
            raw_length: section.raw_length,
            record_size: section.record_size,
            checksum: crc32fast::hash(bytes),
            reserved: 0,
        });
        zeros(sink, payload_offset - position)?;
        sink.write_all(bytes)?;
        position = payload_offset + bytes.len() as u64;
        payload_offset = align(position);
    }
    let file_size = entries.last().map_or(table_offset + table_len as u64, |e| e.offset + e.length);
    zeros(sink, file_size.saturating_sub(position))?;
    let mut header = Header {
        magic: MAGIC,
        major: MAJOR,
        // The smallest minor whose kinds the file holds (spec §11).
        minor: entries.iter().map(|e| SectionKind(e.kind).since_minor()).max().unwrap_or(0).max(image_minor).min(MINOR),
        header_size: HEADER_SIZE as u32,
        section_count: u32::try_from(entries.len()).map_err(|_| Error::Write("too many sections".into()))?,
        table_offset,
        file_size,
        flags: 0,
        reserved: [0; 16],
        header_checksum: 0,
    };
    let table: &[u8] = bytemuck::cast_slice(&entries);
    let mut crc = crc32fast::Hasher::new();
    crc.update(bytemuck::bytes_of(&header));
    crc.update(table);
    header.header_checksum = crc.finalize();
    sink.seek(std::io::SeekFrom::Start(0))?;
    sink.write_all(bytemuck::bytes_of(&header))?;
    sink.write_all(table)?;
    sink.seek(std::io::SeekFrom::Start(file_size))?;
    Ok(file_size)
}

/// A section to write: kind, raw bytes, record size.
type SectionBytes<'a> = (SectionKind, Box<dyn Payload + 'a>, u32);

/// A section's bytes: a record array, borrowed or owned; sent to the thread that compresses it.
trait Payload: Send + Sync {
    fn bytes(&self) -> &[u8];
}

impl<T: Pod + Send + Sync> Payload for Vec<T> {
    fn bytes(&self) -> &[u8] {
        bytemuck::cast_slice(self)
    }
}

impl<T: Pod + Sync> Payload for &[T] {
    fn bytes(&self) -> &[u8] {
        bytemuck::cast_slice(self)
    }
}

/// The optional record arrays in field order as (kind, payload), each made by `$payload!(field)`.
macro_rules! optional_sections {
    ($payload:ident) => {
        [
            (SectionKind::VERTICES, $payload!(vertices)),
            (SectionKind::TRIANGLES, $payload!(triangles)),
            (SectionKind::POINTS, $payload!(points)),
            (SectionKind::MATERIALS, $payload!(materials)),
            (SectionKind::IMAGES, $payload!(images)),
            (SectionKind::IMAGE_DATA, $payload!(image_data)),
            (SectionKind::ELLIPSOIDS, $payload!(ellipsoids)),
            (SectionKind::LINES, $payload!(lines)),
            (SectionKind::FAR_LINES, $payload!(far_lines)),
            (SectionKind::PLANES, $payload!(planes)),
            (SectionKind::PLANE_LEAVES, $payload!(plane_leaves)),
            (SectionKind::PLANE_DIFFUSE, $payload!(plane_diffuse)),
            (SectionKind::PRUNE_LEAVES, $payload!(prune_leaves)),
            (SectionKind::PRUNE_TRIANGLES, $payload!(prune_triangles)),
            (SectionKind::PRUNE_SCALE, $payload!(prune_scale)),
            (SectionKind::PRUNE_LAMBDA, $payload!(prune_lambda)),
            (SectionKind::LOD_LEVELS, $payload!(lod_levels)),
            (SectionKind::LOD_TRIANGLES, $payload!(lod_triangles)),
            (SectionKind::BILLBOARDS, $payload!(billboards)),
            (SectionKind::OCTAHEDRAL, $payload!(octahedral)),
            (SectionKind::OCTAHEDRAL_DEPTH, $payload!(octahedral_depth)),
            (SectionKind::OCTAHEDRAL_NORMALS, $payload!(octahedral_normals)),
            (SectionKind::OCTAHEDRAL_NORMAL_GRIDS, $payload!(octahedral_normal_grids)),
            (SectionKind::VERTEX_AO, $payload!(vertex_ao)),
            (SectionKind::POINT_AO, $payload!(point_ao)),
            (SectionKind::PLANE_AO, $payload!(plane_ao)),
            (SectionKind::ELLIPSOID_AO, $payload!(ellipsoid_ao)),
            (SectionKind::LINE_AO, $payload!(line_ao)),
            (SectionKind::FAR_LINE_AO, $payload!(far_line_ao)),
            (SectionKind::POINT_FACING, $payload!(point_facing)),
            (SectionKind::CALIBRATION, $payload!(calibration)),
            (SectionKind::CHAIN_CALIBRATION, $payload!(chain_calibration)),
            (SectionKind::CALIBRATION_ELEVATIONS, $payload!(calibration_elevations)),
            (SectionKind::CALIBRATION_ADDED, $payload!(calibration_added)),
            (SectionKind::CALIBRATION_ELEVATIONS_ADDED, $payload!(calibration_elevations_added)),
            (SectionKind::CALIBRATION_FLIP, $payload!(calibration_flip)),
            (SectionKind::CHAIN_CALIBRATION_FLIP, $payload!(chain_calibration_flip)),
        ]
    };
}
use optional_sections;

/// Why [`ContainerData::encode`] failed: the data, or the sink.
enum EncodeError {
    Data(Error),
    Io(std::io::Error),
}

impl From<Error> for EncodeError {
    fn from(e: Error) -> Self {
        Self::Data(e)
    }
}

impl From<std::io::Error> for EncodeError {
    fn from(e: std::io::Error) -> Self {
        Self::Io(e)
    }
}

fn zeros(sink: &mut impl std::io::Write, count: u64) -> std::io::Result<()> {
    std::io::copy(&mut std::io::repeat(0).take(count), sink).map(|_| ())
}

/// Longest file name (bytes) whose temporary files are named after it; longer names would make the
/// temporary name exceed the 255-byte limit of common file systems.
const MAX_NAMED_TEMPORARY: usize = 200;

/// Length of the random part of a temporary file's name.
const TEMPORARY_RANDOM_CHARS: usize = 6;

/// A temporary file in `path`'s directory, to be renamed over `path`: `.<file name>.<random>.tmp`
/// (see [`temporary_target`]), or `.treelod-<random>.tmp` for a file name that is very long or not
/// valid UTF-8.
fn temporary_beside(path: &Path) -> Result<tempfile::NamedTempFile> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let prefix = match path.file_name().and_then(|n| n.to_str()) {
        Some(name) if name.len() <= MAX_NAMED_TEMPORARY => format!(".{name}."),
        _ => ".treelod-".to_owned(),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp").rand_bytes(TEMPORARY_RANDOM_CHARS);
    // A temporary file is created 0600; the renamed result must get the mode any new file gets
    // (0666 less the umask), as a plain `File::create` would give it.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    builder.tempfile_in(dir).map_err(|source| Error::Io { path: path.to_owned(), source })
}

/// The file name a temporary file of [`ContainerData::write_to_path`] or [`write_atomically`] was
/// to be renamed to, if `file_name` is one: `.tree.treelod.Ab12Cd.tmp` gives `tree.treelod`.
///
/// A process killed while writing leaves its temporary file behind (the target is untouched); this
/// lets a later run recognise such leftovers by the file they were for and remove them. The random
/// part is six ASCII letters and digits.
#[must_use]
pub fn temporary_target(file_name: &str) -> Option<&str> {
    let inner = file_name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (target, random) = inner.rsplit_once('.')?;
    let random_ok = random.len() == TEMPORARY_RANDOM_CHARS && random.bytes().all(|b| b.is_ascii_alphanumeric());
    (random_ok && !target.is_empty()).then_some(target)
}

/// Writes `bytes` to `path` through a temporary file and a rename, so readers see the old file or
/// the new one, never a half-written one.
///
/// # Errors
/// [`Error::Io`] naming `path`.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |source| Error::Io { path: path.to_owned(), source };
    let mut tmp = temporary_beside(path)?;
    tmp.write_all(bytes).map_err(io)?;
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}

/// The check [`ContainerData::into_path_verified`] runs on the written file before renaming it:
/// it opens and fully verifies ([`crate::verify`]).
///
/// # Errors
/// Any error of [`Container::open`] or [`crate::verify`].
pub fn verify_written(path: &Path) -> Result<()> {
    crate::verify(&Container::open(path)?).map(drop)
}

/// Sections of at most this many bytes are compressed at level 19 or more, whatever the level
/// asked for: there the higher level costs milliseconds (19 compresses about 6 MB/s on one
/// core: ≤ 45 ms for such a section) and saves 7 % on the small trees whose containers would
/// otherwise outgrow their source (the 3k-triangle Quaternius tree: 163.1 kB at level 9, 151.0 kB
/// at 19, against its 158.7 kB glTF).
pub const SMALL_SECTION: usize = 256 << 10;

/// The level a section of `raw_len` bytes is compressed at when `level` is asked for
/// ([`SMALL_SECTION`]).
#[must_use]
pub fn section_level(raw_len: usize, level: i32) -> i32 {
    if raw_len <= SMALL_SECTION { level.max(19) } else { level }
}

/// A section as it is written: its frame, or its raw bytes where compressing does not pay.
struct Stored<'a> {
    kind: SectionKind,
    record_size: u32,
    /// Length of the raw bytes (the table's `raw_length`).
    raw_length: u64,
    /// [`FLAG_ZSTD`] and [`FLAG_SHUFFLE`] as the frame was made; 0 for raw bytes.
    flags: u32,
    bytes: StoredBytes<'a>,
}

/// The bytes of a [`Stored`] section.
enum StoredBytes<'a> {
    /// A zstd frame; the raw array it came from is already freed.
    Frame(Vec<u8>),
    /// The raw array itself.
    Raw(Box<dyn Payload + 'a>),
}

impl StoredBytes<'_> {
    fn bytes(&self) -> &[u8] {
        match self {
            Self::Frame(frame) => frame,
            Self::Raw(payload) => payload.bytes(),
        }
    }
}

/// A section's stored form under `compression`: `Some((frame, flags))` where compressing it pays
/// (spec §8), `None` to store it raw.
fn pack_section(
    kind: SectionKind,
    raw: &[u8],
    record_size: u32,
    compression: Compression,
) -> Result<Option<(Vec<u8>, u32)>> {
    let Compression::Zstd { level } = compression else { return Ok(None) };
    if !kind.compressible() || kind.record_size().is_none() || raw.is_empty() {
        return Ok(None);
    }
    let level = section_level(raw.len(), level);
    // Record arrays are byte-shuffled first: equal byte positions of neighbouring records
    // (exponents, high index bytes, zero fields) then sit side by side.
    let (packed, flags) = if record_size > 1 {
        (compress_shuffled(raw, record_size as usize, level)?, FLAG_ZSTD | FLAG_SHUFFLE)
    } else {
        (compress(raw, level)?, FLAG_ZSTD)
    };
    let pays = packed.len() < raw.len();
    let within_limit = raw.len() as u64 <= packed.len() as u64 * MAX_COMPRESSION_RATIO;
    Ok((pays && within_limit).then_some((packed, flags)))
}

fn compress(raw: &[u8], level: i32) -> Result<Vec<u8>> {
    let fail = |e: std::io::Error| Error::Write(format!("zstd: {e}"));
    let mut compressor = zstd::bulk::Compressor::new(level).map_err(fail)?;
    compressor.include_checksum(true).map_err(fail)?;
    compressor.include_contentsize(true).map_err(fail)?;
    compressor.compress(raw).map_err(fail)
}

/// [`compress`] of `raw` byte-shuffled into planes of `record_size` (spec §8), streamed into the
/// compressor a slice of one plane at a time, so that the shuffled copy is never whole in memory
/// (it was 49 MB for the points of the 669k-triangle maple). The frame records the content size,
/// as [`compress`]'s does, so a reader allocates it once.
///
/// Gathering four or eight planes at once, as the reader scatters them (words of as many records
/// transposed, a pass over the records per piece of planes instead of per plane, then handed to
/// the compressor in the same slices, which made the same frames), was measured and not taken:
/// the maple's `write` stage read 0.77–0.85 s against 0.79–0.83 s (3 alternating default builds,
/// the same bytes) and the build peaked 3–4.5 MB higher. The stage's time is zstd's own.
fn compress_shuffled(raw: &[u8], record_size: usize, level: i32) -> Result<Vec<u8>> {
    /// Records per slice: 16 KiB of one byte plane.
    const SLICE: usize = 16 << 10;
    let fail = |e: std::io::Error| Error::Write(format!("zstd: {e}"));
    let mut encoder = zstd::stream::write::Encoder::new(Vec::new(), level).map_err(fail)?;
    encoder.include_checksum(true).map_err(fail)?;
    encoder.include_contentsize(true).map_err(fail)?;
    encoder.set_pledged_src_size(Some(raw.len() as u64)).map_err(fail)?;
    let mut plane = vec![0u8; SLICE];
    for byte in 0..record_size {
        for records in raw.chunks(SLICE * record_size) {
            let count = records.len() / record_size;
            for (out, record) in plane.iter_mut().zip(records.chunks_exact(record_size)) {
                *out = record[byte];
            }
            encoder.write_all(&plane[..count]).map_err(fail)?;
        }
    }
    encoder.finish().map_err(fail)
}

fn align(offset: u64) -> u64 {
    offset.div_ceil(SECTION_ALIGN) * SECTION_ALIGN
}

#[cfg(test)]
mod tests {
    use super::{Compression, ContainerData, compress_shuffled, temporary_beside, temporary_target};
    use crate::error::{Error, ErrorClass};
    use crate::metadata::{Metadata, Setting, Source, Tree};
    use crate::pack::shuffle;
    use crate::records::{BlockRecord, CellRecord};

    /// A one-cell container with no geometry that verifies; with `unsorted`, its settings are out
    /// of order, which it still writes and opens but `verify` refuses.
    fn empty(unsorted: bool) -> ContainerData {
        let mut settings =
            vec![Setting { key: "a".into(), value: "1".into() }, Setting { key: "b".into(), value: "2".into() }];
        if unsorted {
            settings.reverse();
        }
        ContainerData {
            metadata: Metadata {
                generator: "test".into(),
                name: "empty".into(),
                trees: vec![Tree::default()],
                sources: vec![Source::default()],
                settings,
                ..Metadata::default()
            },
            block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
            cells: vec![CellRecord::default(); 2],
            ..ContainerData::default()
        }
    }

    /// The names in `dir`, sorted.
    fn names(dir: &std::path::Path) -> Vec<String> {
        let mut names: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        names
    }

    #[test]
    fn a_failed_check_keeps_the_old_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tree.treelod");
        empty(false).into_path_verified(&path, Compression::default()).unwrap();
        let old = std::fs::read(&path).unwrap();
        crate::verify(&crate::Container::open(&path).unwrap()).unwrap();

        // A check that fails: the file is not replaced, the temporary file is gone.
        let mut checked = None;
        let err = empty(false)
            .into_path_checked(&path, Compression::None, |written| {
                checked = Some(written.to_owned());
                assert!(written.exists() && written != path);
                Err(Error::Write("refused by the test".into()))
            })
            .unwrap_err();
        assert!(matches!(&err, Error::NotReplaced { path: p, kept: true, .. } if *p == path), "{err:?}");
        assert!(err.to_string().contains("refused by the test"), "{err}");
        assert!(err.to_string().ends_with("the old file is kept)"), "{err}");
        assert!(checked.is_some_and(|t| !t.exists()), "the temporary file is removed");
        assert_eq!(std::fs::read(&path).unwrap(), old, "the old file is byte-identical");
        assert_eq!(names(dir.path()), ["tree.treelod"]);

        // A file that writes and opens but fails verification does not replace the old one.
        let err = empty(true).into_path_verified(&path, Compression::default()).unwrap_err();
        assert_eq!(err.class(), ErrorClass::Invalid);
        let Error::NotReplaced { source, kept: true, .. } = &err else { panic!("{err:?}") };
        assert!(!matches!(**source, Error::InFile { .. }), "the temporary file is not named: {err}");
        assert!(err.to_string().contains("not sorted"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), old);
        assert_eq!(names(dir.path()), ["tree.treelod"]);

        // Nothing at the path: nothing is written, and the message says nothing was kept.
        let fresh = dir.path().join("fresh.treelod");
        let err = empty(true).into_path_verified(&fresh, Compression::None).unwrap_err();
        assert!(matches!(err, Error::NotReplaced { kept: false, .. }));
        assert!(!err.to_string().contains("kept"), "{err}");
        assert_eq!(names(dir.path()), ["tree.treelod"]);

        // Without a check the same data is written (and replaces the old file).
        empty(true).into_path(&path, Compression::None).unwrap();
        assert_ne!(std::fs::read(&path).unwrap(), old);
    }

    #[test]
    fn sections_compressed_in_parallel_give_the_same_bytes_on_any_thread_count() {
        // Sections above and below SMALL_SECTION, so both levels are compressed side by side.
        let mut data = empty(false);
        #[expect(clippy::cast_precision_loss, reason = "test values")]
        let vertex = |i: usize| crate::VertexRecord {
            position: [(i % 97) as f32 * 0.25, (i / 97) as f32 * 0.125, (i % 13) as f32],
            normal: (i as u32).wrapping_mul(0x9E37_79B9),
            uv: [(i % 31) as f32 / 31.0, 0.5],
            color: u32::MAX,
        };
        data.vertices = (0..40_000).map(vertex).collect();
        #[expect(clippy::cast_possible_truncation, reason = "test values")]
        let ao = (0..data.vertices.len()).map(|i| (i % 251) as u8).collect();
        data.vertex_ao = ao;
        let pool = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let encode = |threads| pool(threads).install(|| data.to_bytes(Compression::default()).unwrap());
        let one = encode(1);
        assert!(data.vertices.len() * 28 > super::SMALL_SECTION, "one section is compressed at the level asked for");
        assert_eq!(one, encode(4), "4 threads write what 1 does");
        assert_eq!(one, encode(2));
        // The consuming writer (arrays freed as they are compressed) writes the same file.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.treelod");
        for threads in [1, 4] {
            let written = pool(threads).install(|| data.clone().into_path(&path, Compression::default()).unwrap());
            assert_eq!(written, one.len() as u64);
            assert_eq!(std::fs::read(&path).unwrap(), one, "into_path on {threads} thread(s)");
        }
        // What a reader decodes is the data.
        std::fs::write(&path, &one).unwrap();
        let container = crate::Container::open(&path).unwrap();
        assert_eq!(container.vertices(), data.vertices.as_slice());
        assert_eq!(container.vertex_ao(), data.vertex_ao.as_slice());
        assert_eq!(super::section_level(super::SMALL_SECTION, 9), 19);
        assert_eq!(super::section_level(super::SMALL_SECTION + 1, 9), 9);
        assert_eq!(super::section_level(1, 22), 22);
    }

    #[test]
    fn streamed_shuffling_compresses_the_shuffled_bytes() {
        // Record counts below, at and across the slice size, with a partial last slice.
        for (records, record_size) in [(1usize, 48usize), (1000, 28), (16 << 10, 24), (40_000, 48)] {
            #[expect(clippy::cast_possible_truncation, reason = "test bytes")]
            let raw: Vec<u8> = (0..records * record_size).map(|i| (i % record_size * 7 + i / 4093) as u8).collect();
            let frame = compress_shuffled(&raw, record_size, 3).unwrap();
            assert_eq!(zstd::zstd_safe::get_frame_content_size(&frame).ok(), Some(Some(raw.len() as u64)));
            let mut expected = vec![0; raw.len()];
            shuffle(&raw, record_size, &mut expected);
            let decoded = zstd::bulk::decompress(&frame, raw.len()).unwrap();
            assert!(decoded == expected, "{records} records of {record_size} bytes");
        }
    }

    #[test]
    fn temporary_files_are_named_after_their_target() {
        let dir = tempfile::tempdir().unwrap();
        let tmp = temporary_beside(&dir.path().join("tree.treelod")).unwrap();
        let name = tmp.path().file_name().unwrap().to_str().unwrap().to_owned();
        assert!(name.starts_with(".tree.treelod.") && name.ends_with(".tmp"), "{name}");
        assert_eq!(temporary_target(&name), Some("tree.treelod"));
        let long = "x".repeat(240);
        let tmp = temporary_beside(&dir.path().join(&long)).unwrap();
        let name = tmp.path().file_name().unwrap().to_str().unwrap().to_owned();
        assert!(name.starts_with(".treelod-"), "a long name falls back to a short prefix: {name}");
    }

    #[test]
    fn only_temporary_names_have_a_target() {
        assert_eq!(temporary_target(".a.b.treelod.X1y2Z3.tmp"), Some("a.b.treelod"));
        let not_temporary =
            ["tree.treelod", ".tree.treelod", ".tree.treelod.tmp", "..Ab12Cd.tmp", ".tree.treelod.a-b_cd.tmp", "x.tmp"];
        for name in not_temporary {
            assert_eq!(temporary_target(name), None, "{name}");
        }
    }
}
