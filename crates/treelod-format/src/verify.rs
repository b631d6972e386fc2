//! Full verification (spec §9.2): checksums, zero padding, every record rule of §6, the ordering
//! rules and the exact-cut invariants of §10, per cell and for the block's far lines (§6.9.1).
//!
//! [`verify`] runs on an opened [`Container`], so everything §9.1 checks at open already holds:
//! section bounds, record sizes, the cell count and the tiling of every per-cell kind. The exact-cut
//! check of one cell is also available on plain slices ([`check_spt`], [`check_point_cut`],
//! [`triangle_leaf_sizes`]) for builders and tests.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use crate::error::{Error, Result};
use crate::pack::unorm16x2_steps;
use crate::reader::{Container, check_section_checksum};
use crate::records::{
    AO_KINDS, BillboardRecord, BlockRecord, CalibrationRecord, CellRecord, ChainCalibrationRecord,
    ChainFlipCalibrationRecord, CurveSample, ElevationCalibrationRecord, EllipsoidRecord, FlipCalibrationRecord,
    ImageRecord, LineRecord, LodLevelRecord, MaterialRecord, NO_IMAGE, OctahedralDepthRecord,
    OctahedralNormalGridRecord, OctahedralNormalRecord, OctahedralRecord, PlaneDiffuseRecord, PlaneLeafRecord,
    PlaneRecord, PointRecord, PruneLeafRecord, Range, SECTION_ENTRY_SIZE, SectionKind, SptElement, TriangleRecord,
    VertexRecord, billboard_kind, calibration_technique, far_switch, far_threshold, image_format, leaf_slots,
    lines_drawn_at, plane_leaf_bases,
};

/// Largest image side in texels (spec §6.7, §12).
use crate::records::MAX_IMAGE_SIDE;
/// The PNG file signature (spec §6.7).
const PNG_SIGNATURE: [u8; 8] = [0x89, 0x50, 0x4E, 0x47, 0x0D, 0x0A, 0x1A, 0x0A];
/// The start of every JPEG file (spec §6.7).
const JPEG_SIGNATURE: [u8; 3] = [0xFF, 0xD8, 0xFF];

/// What a successful [`verify`] checked, for printing.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct VerifyReport {
    /// Sections whose checksum was verified (every entry of the table, known kind or not).
    pub sections: usize,
    /// Stored bytes covered by those checksums.
    pub checksummed_bytes: u64,
    /// Padding bytes (outside the header, the table and the sections) found zero.
    pub padding_bytes: u64,
    /// Cell records checked, the block cell included.
    pub cells: usize,
    /// Cells without any record (their bounds are all zero).
    pub empty_cells: usize,
    /// `VERTICES` records checked.
    pub vertices: u64,
    /// `TRIANGLES` records checked.
    pub triangles: u64,
    /// `POINTS` records checked.
    pub points: u64,
    /// `MATERIALS` records checked.
    pub materials: u64,
    /// `IMAGES` records checked.
    pub images: u64,
    /// Bytes of `IMAGE_DATA`.
    pub image_data_bytes: u64,
    /// `ELLIPSOIDS` records checked.
    pub ellipsoids: u64,
    /// `LINES` records checked.
    pub lines: u64,
    /// `FAR_LINES` records checked (spec §6.9.1).
    pub far_lines: u64,
    /// Leaves of the far lines' hierarchy: the `LINES` records with `hi = +∞` (spec §6.9.1).
    pub far_line_leaves: u64,
    /// `PLANES` records checked.
    pub planes: u64,
    /// `PLANE_LEAVES` records checked (indirect texturing, spec §6.10.1).
    pub plane_leaves: u64,
    /// `PLANES` records textured indirectly: their image is a `LEAF_SLOTS` image, whose slots in
    /// their rectangle were checked against their `leaf_count` (spec §6.10.1).
    pub indirect_planes: u64,
    /// `PLANE_DIFFUSE` records checked (spec §6.10.2): their count, one per `PLANES` record, at
    /// open; here that each record's shares sum to at most 1.
    pub plane_diffuse: u64,
    /// `PRUNE_LEAVES` records checked.
    pub prune_leaves: u64,
    /// `PRUNE_TRIANGLES` records checked.
    pub prune_triangles: u64,
    /// `PRUNE_SCALE` and `PRUNE_LAMBDA` samples checked.
    pub curve_samples: u64,
    /// `LOD_LEVELS` records checked (baseline).
    pub lod_levels: u64,
    /// `LOD_TRIANGLES` records checked (baseline).
    pub lod_triangles: u64,
    /// `BILLBOARDS` records checked (baseline).
    pub billboards: u64,
    /// `OCTAHEDRAL` records checked (baseline, spec §6.13.1): one octahedral impostor per tree
    /// that has one.
    pub octahedral: u64,
    /// `OCTAHEDRAL_DEPTH` records checked (spec §6.13.2): one depth plane per view of the
    /// `OCTAHEDRAL` records, each value finite and in `[−1, 1]`.
    pub octahedral_depth: u64,
    /// `OCTAHEDRAL_NORMALS` records checked (spec §6.13.3): one per `OCTAHEDRAL` record, its
    /// grid of normal cells inside the image.
    pub octahedral_normals: u64,
    /// `OCTAHEDRAL_NORMAL_GRIDS` records checked (spec §6.13.3, since 1.16): one per `OCTAHEDRAL`
    /// record, its grid of normal cells not empty, `uv_min < uv_max` per component. A file holds
    /// these or [`Self::octahedral_normals`], not both (checked at open).
    pub octahedral_normal_grids: u64,
    /// `CALIBRATION` records checked.
    pub calibration: u64,
    /// `CALIBRATION_ELEVATIONS` records checked (spec §6.16).
    pub calibration_elevations: u64,
    /// `CHAIN_CALIBRATION` records checked (spec §6.17).
    pub chain_calibration: u64,
    /// `CALIBRATION_ADDED` records checked (spec §6.18): the techniques added after 1.11.
    pub calibration_added: u64,
    /// `CALIBRATION_ELEVATIONS_ADDED` records checked (spec §6.18).
    pub calibration_elevations_added: u64,
    /// `CALIBRATION_FLIP` records checked (spec §6.19, since 1.17): each representation's mean
    /// LDR-FLIP error by projected height, over every view and per elevation.
    pub calibration_flip: u64,
    /// `CHAIN_CALIBRATION_FLIP` records checked (spec §6.20, since 1.18): each LoD chain level's
    /// mean LDR-FLIP error by projected height over every view.
    pub chain_calibration_flip: u64,
    /// `VERTEX_AO`, `POINT_AO`, `PLANE_AO`, `ELLIPSOID_AO`, `LINE_AO` and `FAR_LINE_AO` bytes (their
    /// counts are checked at open).
    pub ao: u64,
    /// `POINT_FACING` bytes (spec §6.5.1; every value is valid, the count is checked at open).
    pub point_facing: u64,
    /// Leaves whose exact cut was verified, summed over cells and the point, ellipsoid, line and
    /// plane hierarchies, and the far lines' (spec §10 rule 2).
    pub cut_leaves: u64,
    /// Deepest nesting of leaf runs met in any hierarchy (1 for a flat list of roots).
    pub max_depth: usize,
}

impl core::fmt::Display for VerifyReport {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        writeln!(
            f,
            "checksums: {} sections, {} bytes; padding: {} bytes, all zero",
            self.sections, self.checksummed_bytes, self.padding_bytes
        )?;
        writeln!(f, "cells: {} ({} empty)", self.cells, self.empty_cells)?;
        writeln!(
            f,
            "records: {} vertices, {} triangles, {} points, {} materials, {} images ({} data bytes)",
            self.vertices, self.triangles, self.points, self.materials, self.images, self.image_data_bytes
        )?;
        writeln!(
            f,
            "         {} ellipsoids, {} lines, {} planes, {} pruned leaves, {} pruned triangles, {} curve samples",
            self.ellipsoids, self.lines, self.planes, self.prune_leaves, self.prune_triangles, self.curve_samples
        )?;
        if self.lod_levels + self.billboards + self.octahedral > 0 {
            write!(
                f,
                "baselines: {} LoD levels, {} LoD triangles, {} billboards",
                self.lod_levels, self.lod_triangles, self.billboards
            )?;
            if self.octahedral > 0 {
                write!(f, ", {} octahedral impostors", self.octahedral)?;
            }
            if self.octahedral_depth > 0 {
                write!(f, ", {} octahedral depth planes", self.octahedral_depth)?;
            }
            if self.octahedral_normals > 0 {
                write!(f, ", {} octahedral normal grids", self.octahedral_normals)?;
            }
            if self.octahedral_normal_grids > 0 {
                write!(f, ", {} octahedral normal grids", self.octahedral_normal_grids)?;
            }
            writeln!(f)?;
        }
        if self.far_lines > 0 {
            writeln!(f, "far lines: {} records over {} leaves", self.far_lines, self.far_line_leaves)?;
        }
        if self.ao > 0 {
            writeln!(f, "ambient occlusion: {} values", self.ao)?;
        }
        if self.plane_leaves + self.indirect_planes > 0 {
            writeln!(f, "indirect texturing: {} planes, {} plane leaves", self.indirect_planes, self.plane_leaves)?;
        }
        if self.plane_diffuse > 0 {
            writeln!(f, "planes' diffuse response: {} records", self.plane_diffuse)?;
        }
        if self.point_facing > 0 {
            writeln!(f, "points' facing: {} values", self.point_facing)?;
        }
        write!(f, "exact cut: {} leaves, runs nested up to {} deep", self.cut_leaves, self.max_depth)
    }
}

/// What [`check_spt`] and [`check_point_cut`] found in one cell's hierarchy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SptSummary {
    /// `n`: the largest `leaf_first + leaf_count` of the records, 0 if none (spec §10 rule 2).
    pub leaves: u64,
    /// Deepest nesting of leaf runs (0 if there are no records).
    pub max_depth: usize,
}

/// Checks everything spec §9.2 lists: all section checksums, zero padding, every record rule of
/// §6, the ordering rules and the exact-cut invariants of §10.
///
/// Reserved fields, flags and `_pad` fields are not checked: readers ignore them (spec §2).
/// Cost is linear in the file size, plus `O(m log m)` per cell and kind for `m` hierarchy records.
///
/// # Errors
/// The first problem found: [`Error::ChecksumMismatch`] for a section whose bytes do not match its
/// checksum; [`Error::BadSection`] (or [`Error::BadHeader`] before the table) for a nonzero padding
/// byte; [`Error::BadRecord`] for a record that breaks a rule of its own (a field out of range, an
/// index out of range, the sort order); [`Error::BadCell`] for a cell whose bounds or hierarchy
/// break §6.2 or §10; [`Error::BadHierarchy`] for far lines whose hierarchy breaks §6.9.1 or §10
/// (see [`check_far_lines`]).
pub fn verify(c: &Container) -> Result<VerifyReport> {
    let mut report = VerifyReport::default();
    check_checksums(c, &mut report)?;
    check_padding(c, &mut report)?;

    let vertex_count = c.vertices().len();
    let material_count = c.materials().len();
    let image_count = c.images().len();
    check_vertices(c.vertices())?;
    check_materials(c.materials(), image_count)?;
    check_images(c.images(), c.image_data())?;
    check_triangle_fields(SectionKind::TRIANGLES, c.triangles(), vertex_count, material_count)?;
    check_triangle_fields(SectionKind::PRUNE_TRIANGLES, c.prune_triangles(), vertex_count, material_count)?;
    check_points(c.points())?;
    check_ellipsoids(c.ellipsoids())?;
    check_lines(SectionKind::LINES, c.lines())?;
    check_planes(c.planes(), image_count)?;
    report.indirect_planes =
        check_plane_leaves(c.plane_leaves(), c.planes(), c.images(), c.image_data(), material_count)?;
    check_plane_diffuse(c.plane_diffuse())?;
    check_prune(c.prune_leaves(), c.prune_triangles())?;
    check_curve(SectionKind::PRUNE_SCALE, c.prune_scale())?;
    check_curve(SectionKind::PRUNE_LAMBDA, c.prune_lambda())?;
    check_triangle_fields(SectionKind::LOD_TRIANGLES, c.lod_triangles(), vertex_count, material_count)?;
    let tree_count = c.block().tree_count;
    check_lod_levels(c.lod_levels(), c.lod_triangles().len(), tree_count)?;
    check_billboards(c.billboards(), image_count, tree_count)?;
    check_octahedral(c.octahedral(), image_count, tree_count)?;
    check_octahedral_depth(c.octahedral_depth(), c.octahedral())?;
    check_octahedral_normals(c.octahedral_normals(), c.octahedral())?;
    check_octahedral_normal_grids(c.octahedral_normal_grids())?;
    check_calibration(&BASE_TABLES, c.calibration())?;
    check_calibration_elevations(&BASE_TABLES, c.calibration_elevations(), c.calibration())?;
    check_calibration(&ADDED_TABLES, c.calibration_added())?;
    check_calibration_elevations(&ADDED_TABLES, c.calibration_elevations_added(), c.calibration_added())?;
    check_added_calibration(
        c.calibration(),
        c.calibration_elevations(),
        c.calibration_added(),
        c.calibration_elevations_added(),
    )?;
    check_chain_calibration(c.chain_calibration(), c.lod_levels())?;
    check_calibration_flip(c.calibration_flip())?;
    check_chain_calibration_flip(c.chain_calibration_flip(), c.lod_levels())?;
    check_slot_images_only_for_planes(c)?;
    check_metadata(c)?;

    // The cells side by side on the caller's rayon pool (each reads only its own records, which
    // the checks above have passed); the error is the first in the cells' order.
    let cuts: Vec<Result<SptSummary>> = {
        use rayon::prelude::*;
        c.cells().par_iter().enumerate().map(|(index, cell)| check_cell(c, index, cell)).collect()
    };
    for (cell, spt) in c.cells().iter().zip(cuts) {
        if cell.is_empty() {
            report.empty_cells += 1;
        }
        let spt = spt?;
        report.cut_leaves += spt.leaves;
        report.max_depth = report.max_depth.max(spt.max_depth);
    }
    // After the cells: the coarsest lines it is compared with have passed their own rules.
    let far = check_far_lines(c.far_lines(), c.lines(), c.block())?;
    report.cut_leaves += far.leaves;
    report.max_depth = report.max_depth.max(far.max_depth);
    report.far_line_leaves = far.leaves;

    report.cells = c.cells().len();
    report.vertices = vertex_count as u64;
    report.triangles = c.triangles().len() as u64;
    report.points = c.points().len() as u64;
    report.materials = material_count as u64;
    report.images = image_count as u64;
    report.image_data_bytes = c.image_data().len() as u64;
    report.ellipsoids = c.ellipsoids().len() as u64;
    report.lines = c.lines().len() as u64;
    report.far_lines = c.far_lines().len() as u64;
    report.planes = c.planes().len() as u64;
    report.plane_leaves = c.plane_leaves().len() as u64;
    report.plane_diffuse = c.plane_diffuse().len() as u64;
    report.prune_leaves = c.prune_leaves().len() as u64;
    report.prune_triangles = c.prune_triangles().len() as u64;
    report.curve_samples = (c.prune_scale().len() + c.prune_lambda().len()) as u64;
    report.lod_levels = c.lod_levels().len() as u64;
    report.lod_triangles = c.lod_triangles().len() as u64;
    report.billboards = c.billboards().len() as u64;
    report.octahedral = c.octahedral().len() as u64;
    report.octahedral_depth = c.octahedral_depth().len() as u64;
    report.octahedral_normals = c.octahedral_normals().len() as u64;
    report.octahedral_normal_grids = c.octahedral_normal_grids().len() as u64;
    report.calibration = c.calibration().len() as u64;
    report.calibration_elevations = c.calibration_elevations().len() as u64;
    report.chain_calibration = c.chain_calibration().len() as u64;
    report.calibration_added = c.calibration_added().len() as u64;
    report.calibration_elevations_added = c.calibration_elevations_added().len() as u64;
    report.calibration_flip = c.calibration_flip().len() as u64;
    report.chain_calibration_flip = c.chain_calibration_flip().len() as u64;
    report.ao = AO_KINDS.iter().map(|&(kind, _)| c.raw_bytes(kind).len() as u64).sum();
    report.point_facing = c.point_facing().len() as u64;
    Ok(report)
}

// ---------------------------------------------------------------------------------------------
// File level: checksums and padding (spec §3, §4, §8).

/// Spec §7.1: the metadata agrees with the records, and §1: the file ends at its last section.
fn check_metadata(c: &Container) -> Result<()> {
    let meta = c.metadata();
    let bad = |reason: String| Error::BadRecord { kind: SectionKind::META, index: 0, reason };
    let tree_count = c.block().tree_count as usize;
    if meta.trees.len() != tree_count {
        return Err(bad(format!("{} trees listed, BLOCK says tree_count = {tree_count}", meta.trees.len())));
    }
    if let Some((i, tree)) = meta.trees.iter().enumerate().find(|(_, t)| t.source as usize >= meta.sources.len()) {
        return Err(bad(format!("tree {i} names source {}, there are {}", tree.source, meta.sources.len())));
    }
    if meta.materials.len() != c.materials().len() {
        return Err(bad(format!(
            "{} material entries for {} MATERIALS records",
            meta.materials.len(),
            c.materials().len()
        )));
    }
    if let Some(pair) = meta.settings.windows(2).find(|w| w[0].key >= w[1].key) {
        return Err(bad(format!("settings are not sorted by unique key: {:?} before {:?}", pair[0].key, pair[1].key)));
    }
    let end = c.sections().iter().map(|s| s.entry.offset + s.entry.length).max();
    let table_end = c.header().table_offset + c.sections().len() as u64 * SECTION_ENTRY_SIZE as u64;
    let expected = end.unwrap_or(table_end).max(table_end);
    if c.header().file_size != expected {
        return Err(Error::BadHeader {
            field: "file_size",
            value: c.header().file_size,
            rule: "the file ends where its last section ends (spec §1)",
        });
    }
    Ok(())
}

fn check_checksums(c: &Container, report: &mut VerifyReport) -> Result<()> {
    for section in c.sections() {
        check_section_checksum(c.file_bytes(), section)?;
        c.release_stored(section);
        report.sections += 1;
        report.checksummed_bytes += section.entry.length;
    }
    Ok(())
}

/// Every byte outside the header, the table and the sections is zero (spec §3).
fn check_padding(c: &Container, report: &mut VerifyReport) -> Result<()> {
    let bytes = c.file_bytes();
    let header = c.header();
    let table_end = header.table_offset + u64::from(header.section_count) * SECTION_ENTRY_SIZE as u64;
    if let Some(offset) = first_nonzero(bytes, u64::from(header.header_size), header.table_offset, report) {
        return Err(Error::BadHeader {
            field: "padding",
            value: offset,
            rule: "the bytes between the header and the section table are zero (§3)",
        });
    }
    let mut gap_start = table_end;
    for (index, section) in c.sections().iter().enumerate() {
        let start = section.entry.offset;
        if let Some(offset) = first_nonzero(bytes, gap_start, start, report) {
            return Err(Error::BadSection {
                index,
                kind: section.kind(),
                reason: format!("nonzero padding byte at offset {offset} before the section (§3: padding is zero)"),
            });
        }
        gap_start = gap_start.max(start.saturating_add(section.entry.length));
    }
    if let Some(offset) = first_nonzero(bytes, gap_start, header.file_size, report) {
        let last = c.sections().len().saturating_sub(1);
        let kind = c.sections().last().map_or(SectionKind(0), |s| s.kind());
        return Err(Error::BadSection {
            index: last,
            kind,
            reason: format!("nonzero byte at offset {offset} after the last section (§1: the file ends with it)"),
        });
    }
    Ok(())
}

/// The offset of the first nonzero byte of `start .. end`, counting the bytes checked.
fn first_nonzero(bytes: &[u8], start: u64, end: u64, report: &mut VerifyReport) -> Option<u64> {
    if end <= start {
        return None;
    }
    let slice = usize::try_from(start)
        .ok()
        .zip(usize::try_from(end).ok())
        .and_then(|(s, e)| bytes.get(s..e))
        // Open checked every offset against the file length; an unaddressable range reports its start.
        .ok_or(start);
    match slice {
        Err(start) => Some(start),
        Ok(slice) => {
            report.padding_bytes += slice.len() as u64;
            slice.iter().position(|&b| b != 0).map(|i| start + i as u64)
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Record rules of spec §6, per section.

fn bad(kind: SectionKind, index: usize, reason: String) -> Error {
    Error::BadRecord { kind, index, reason }
}

fn finite3(v: [f32; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Finite and `≥ 0` (`-0.0` counts as zero).
fn non_negative(v: f32) -> bool {
    v.is_finite() && v >= 0.0
}

fn unit(v: f32) -> bool {
    (0.0..=1.0).contains(&v)
}

fn check_vertices(vertices: &[VertexRecord]) -> Result<()> {
    let kind = SectionKind::VERTICES;
    for (i, v) in vertices.iter().enumerate() {
        if !finite3(v.position) {
            return Err(bad(kind, i, format!("position {:?} is not finite", v.position)));
        }
        if !v.uv.iter().all(|x| x.is_finite()) {
            return Err(bad(kind, i, format!("uv {:?} is not finite", v.uv)));
        }
    }
    Ok(())
}

fn check_materials(materials: &[MaterialRecord], image_count: usize) -> Result<()> {
    let kind = SectionKind::MATERIALS;
    for (i, m) in materials.iter().enumerate() {
        if !m.base_color.iter().all(|x| x.is_finite()) {
            return Err(bad(kind, i, format!("base_color {:?} is not finite", m.base_color)));
        }
        if m.image != NO_IMAGE && m.image as usize >= image_count {
            return Err(bad(
                kind,
                i,
                format!("image {} is out of range ({image_count} images, none = 0xFFFFFFFF)", m.image),
            ));
        }
        if !unit(m.alpha_cutoff) {
            return Err(bad(kind, i, format!("alpha_cutoff {} is outside [0, 1]", m.alpha_cutoff)));
        }
    }
    Ok(())
}

/// Spec §6.7: sizes, mip counts and data ranges; the data of PNG and JPEG images starts with the
/// format's signature; a `LEAF_SLOTS` image has one level of `width · height` texels of 4 bytes
/// (§6.10.1); a BC7 image's sides are multiples of 4 and its data is exactly its levels' blocks. Images of formats this version does not define are checked only for their data range.
fn check_images(images: &[ImageRecord], data: &[u8]) -> Result<()> {
    let kind = SectionKind::IMAGES;
    let data_len = data.len() as u64;
    let mut ranges: Vec<(u64, u64, usize)> = Vec::with_capacity(images.len());
    for (i, img) in images.iter().enumerate() {
        if img.data_offset % 16 != 0 {
            return Err(bad(kind, i, format!("data_offset {} is not a multiple of 16", img.data_offset)));
        }
        let end = img.data_offset.checked_add(img.data_length).filter(|&e| e <= data_len).ok_or_else(|| {
            bad(
                kind,
                i,
                format!("data {}+{} reaches past IMAGE_DATA ({data_len} bytes)", img.data_offset, img.data_length),
            )
        })?;
        if img.data_length > 0 {
            ranges.push((img.data_offset, end, i));
        }
        let known = matches!(
            img.format,
            image_format::RGBA8_SRGB
                | image_format::RGBA8_LINEAR
                | image_format::PNG
                | image_format::JPEG
                | image_format::LEAF_SLOTS
                | image_format::BC7_SRGB
                | image_format::BC7_LINEAR
        );
        if !known {
            continue;
        }
        for (name, side) in [("width", img.width), ("height", img.height)] {
            if !(1..=MAX_IMAGE_SIDE).contains(&side) {
                return Err(bad(kind, i, format!("{name} {side} is outside 1..=16384")));
            }
        }
        let bytes = usize::try_from(img.data_offset)
            .ok()
            .zip(usize::try_from(end).ok())
            .and_then(|(s, e)| data.get(s..e))
            .unwrap_or_default();
        match img.format {
            image_format::LEAF_SLOTS => {
                if img.mip_count != 1 {
                    return Err(bad(
                        kind,
                        i,
                        format!("mip_count {} but a LEAF_SLOTS image has 1 (§6.7, §6.10.1)", img.mip_count),
                    ));
                }
                let expected = u64::from(img.width) * u64::from(img.height) * 4;
                if img.data_length != expected {
                    return Err(bad(
                        kind,
                        i,
                        format!(
                            "data_length {} but a {}x{} LEAF_SLOTS image needs {expected} bytes (two u16 slots per texel)",
                            img.data_length, img.width, img.height
                        ),
                    ));
                }
            }
            image_format::PNG | image_format::JPEG => {
                if img.mip_count != 1 {
                    return Err(bad(kind, i, format!("mip_count {} but an encoded image has 1", img.mip_count)));
                }
                let (signature, name): (&[u8], _) =
                    if img.format == image_format::PNG { (&PNG_SIGNATURE, "PNG") } else { (&JPEG_SIGNATURE, "JPEG") };
                if !bytes.starts_with(signature) {
                    let head = &bytes[..bytes.len().min(signature.len())];
                    return Err(bad(
                        kind,
                        i,
                        format!("data starts with {head:02X?}, not the {name} signature {signature:02X?}"),
                    ));
                }
            }
            _ => {
                if image_format::is_bc7(img.format) && (!img.width.is_multiple_of(4) || !img.height.is_multiple_of(4)) {
                    return Err(bad(
                        kind,
                        i,
                        format!(
                            "a BC7 image is {}x{}; its width and height must be multiples of 4 (whole 4x4 blocks at \
                             level 0, §6.7)",
                            img.width, img.height
                        ),
                    ));
                }
                let max_mips = 32 - img.width.max(img.height).leading_zeros();
                if !(1..=max_mips).contains(&img.mip_count) {
                    return Err(bad(
                        kind,
                        i,
                        format!(
                            "mip_count {} is outside 1..={max_mips} for {}x{}",
                            img.mip_count, img.width, img.height
                        ),
                    ));
                }
                if img.expected_data_length() != Some(img.data_length) {
                    return Err(bad(
                        kind,
                        i,
                        format!(
                            "data_length {} but {}x{} with {} mip levels needs {:?} bytes",
                            img.data_length,
                            img.width,
                            img.height,
                            img.mip_count,
                            img.expected_data_length()
                        ),
                    ));
                }
            }
        }
    }
    ranges.sort_unstable();
    for pair in ranges.windows(2) {
        if let [(a_start, a_end, a), (b_start, b_end, b)] = *pair
            && b_start < a_end
        {
            return Err(bad(
                kind,
                b,
                format!("data {b_start}..{b_end} overlaps the data {a_start}..{a_end} of image {a}"),
            ));
        }
    }
    Ok(())
}

/// Spec §6.4 for `TRIANGLES` and `PRUNE_TRIANGLES`: indices, material, size. (Order and leaf ids
/// are per cell, see [`triangle_leaf_sizes`]; the leaf of a pruned triangle, [`check_prune`].)
fn check_triangle_fields(
    kind: SectionKind,
    triangles: &[TriangleRecord],
    vertex_count: usize,
    material_count: usize,
) -> Result<()> {
    for (i, t) in triangles.iter().enumerate() {
        if let Some(&v) = t.indices.iter().find(|&&v| v as usize >= vertex_count) {
            return Err(bad(kind, i, format!("vertex index {v} is out of range ({vertex_count} vertices)")));
        }
        if t.material as usize >= material_count {
            return Err(bad(kind, i, format!("material {} is out of range ({material_count} materials)", t.material)));
        }
        if !non_negative(t.size) {
            return Err(bad(kind, i, format!("size {} is not finite and >= 0", t.size)));
        }
    }
    Ok(())
}

fn check_points(points: &[PointRecord]) -> Result<()> {
    let kind = SectionKind::POINTS;
    for (i, p) in points.iter().enumerate() {
        if !finite3(p.position) {
            return Err(bad(kind, i, format!("position {:?} is not finite", p.position)));
        }
        if !non_negative(p.radius) {
            return Err(bad(kind, i, format!("radius {} is not finite and >= 0", p.radius)));
        }
        if !non_negative(p.size) {
            return Err(bad(kind, i, format!("size {} is not finite and >= 0", p.size)));
        }
    }
    Ok(())
}

fn check_ellipsoids(ellipsoids: &[EllipsoidRecord]) -> Result<()> {
    let kind = SectionKind::ELLIPSOIDS;
    for (i, e) in ellipsoids.iter().enumerate() {
        if !finite3(e.center) {
            return Err(bad(kind, i, format!("center {:?} is not finite", e.center)));
        }
        if !e.radii.iter().all(|&r| non_negative(r)) {
            return Err(bad(kind, i, format!("radii {:?} are not finite and >= 0", e.radii)));
        }
        if !unit(e.alpha_threshold) {
            return Err(bad(kind, i, format!("alpha_threshold {} is outside [0, 1]", e.alpha_threshold)));
        }
        if !non_negative(e.noise_mip) {
            return Err(bad(kind, i, format!("noise_mip {} is not finite and >= 0", e.noise_mip)));
        }
    }
    Ok(())
}

/// Spec §6.9: finite endpoints and radii `≥ 0`, for `LINES` and `FAR_LINES`.
fn check_lines(kind: SectionKind, lines: &[LineRecord]) -> Result<()> {
    for (i, l) in lines.iter().enumerate() {
        if !finite3(l.p0) || !finite3(l.p1) {
            return Err(bad(kind, i, format!("endpoints {:?}, {:?} are not finite", l.p0, l.p1)));
        }
        if !non_negative(l.r0) || !non_negative(l.r1) {
            return Err(bad(kind, i, format!("radii {}, {} are not finite and >= 0", l.r0, l.r1)));
        }
    }
    Ok(())
}

/// Spec §6.10.1: a `LEAF_SLOTS` image is no colour image; no material, billboard or octahedral
/// impostor (§6.13.1) names one.
fn check_slot_images_only_for_planes(c: &Container) -> Result<()> {
    let is_slots = |image: u32| c.images().get(image as usize).is_some_and(|i| i.format == image_format::LEAF_SLOTS);
    if let Some(i) = c.materials().iter().position(|m| is_slots(m.image)) {
        let image = c.materials()[i].image;
        return Err(bad(SectionKind::MATERIALS, i, format!("image {image} is a LEAF_SLOTS image, not a colour image")));
    }
    if let Some(i) = c.billboards().iter().position(|b| is_slots(b.image)) {
        let image = c.billboards()[i].image;
        return Err(bad(
            SectionKind::BILLBOARDS,
            i,
            format!("image {image} is a LEAF_SLOTS image, not a colour image"),
        ));
    }
    if let Some(i) = c.octahedral().iter().position(|o| is_slots(o.image)) {
        let image = c.octahedral()[i].image;
        return Err(bad(
            SectionKind::OCTAHEDRAL,
            i,
            format!("image {image} is a LEAF_SLOTS image, not a colour image"),
        ));
    }
    Ok(())
}

/// Spec §6.10.2: each record's shares of leaves in the plane and turned every way sum to at most
/// 1, `flat + scattered ≤ 65535` (their count, one per plane, was checked at open).
fn check_plane_diffuse(records: &[PlaneDiffuseRecord]) -> Result<()> {
    let kind = SectionKind::PLANE_DIFFUSE;
    for (i, r) in records.iter().enumerate() {
        if u32::from(r.flat) + u32::from(r.scattered) > u32::from(u16::MAX) {
            return Err(bad(
                kind,
                i,
                format!(
                    "flat {} + scattered {} is above 65535: the shares of leaves in the plane and turned every \
                     way sum to more than 1",
                    r.flat, r.scattered
                ),
            ));
        }
    }
    Ok(())
}

fn check_planes(planes: &[PlaneRecord], image_count: usize) -> Result<()> {
    let kind = SectionKind::PLANES;
    for (i, p) in planes.iter().enumerate() {
        check_quad(kind, i, [p.center, p.axis_u, p.axis_v], p.image, [p.uv_min, p.uv_max], image_count)?;
    }
    Ok(())
}

/// Spec §6.10, §6.13: a textured quad's centre and axes are finite, its image exists, and its
/// atlas rectangle's `uv_min ≤ uv_max` per component.
fn check_quad(
    kind: SectionKind,
    i: usize,
    [center, axis_u, axis_v]: [[f32; 3]; 3],
    image: u32,
    [uv_min, uv_max]: [u32; 2],
    image_count: usize,
) -> Result<()> {
    if !finite3(center) || !finite3(axis_u) || !finite3(axis_v) {
        return Err(bad(
            kind,
            i,
            format!("center {center:?}, axis_u {axis_u:?}, axis_v {axis_v:?} are not all finite"),
        ));
    }
    check_atlas_rectangle(kind, i, image, [uv_min, uv_max], image_count)
}

/// Spec §6.10, §6.13, §6.13.1: record `i` of `kind` samples an existing image, and its atlas
/// rectangle's `uv_min ≤ uv_max` per component.
fn check_atlas_rectangle(
    kind: SectionKind,
    i: usize,
    image: u32,
    [uv_min, uv_max]: [u32; 2],
    image_count: usize,
) -> Result<()> {
    if image as usize >= image_count {
        return Err(bad(kind, i, format!("image {image} is out of range ({image_count} images)")));
    }
    check_corner_order(kind, i, [uv_min, uv_max])
}

/// Record `i` of `kind`'s rectangle of the image, two packed `unorm16` corners: `uv_min ≤
/// uv_max` per component (spec §6.10, §6.13, §6.13.3).
fn check_corner_order(kind: SectionKind, i: usize, [uv_min, uv_max]: [u32; 2]) -> Result<()> {
    let ([min_u, min_v], [max_u, max_v]) = (unorm16x2_steps(uv_min), unorm16x2_steps(uv_max));
    if min_u > max_u || min_v > max_v {
        return Err(bad(
            kind,
            i,
            format!("uv_min ({min_u}, {min_v}) is not <= uv_max ({max_u}, {max_v}) per component"),
        ));
    }
    Ok(())
}

/// Spec §6.10.1, indirect texturing: `PLANE_LEAVES` is empty or holds `Σ leaf_count` records
/// (plane `p`'s leaves from `base(p)`, [`plane_leaf_bases`]); it is not empty if a plane's image
/// is `LEAF_SLOTS`; each record names an existing material, has finite `uv0`, `du`, `dv` and a
/// texture rectangle with `uv_min ≤ uv_max` per component (its colour may be any value); and
/// each texel of a `LEAF_SLOTS` plane's rectangle (the texels whose area meets it,
/// [`texel_span`]) holds slots `a, b ≤ leaf_count`. Returns the number of planes textured
/// indirectly.
///
/// Runs after [`check_images`] (a `LEAF_SLOTS` image's data is `width · height · 4` bytes inside
/// `IMAGE_DATA`) and [`check_planes`] (every plane's image exists, `uv_min ≤ uv_max`).
fn check_plane_leaves(
    leaves: &[PlaneLeafRecord],
    planes: &[PlaneRecord],
    images: &[ImageRecord],
    image_data: &[u8],
    material_count: usize,
) -> Result<u64> {
    let kind = SectionKind::PLANE_LEAVES;
    let bases = plane_leaf_bases(planes);
    let total = bases.last().copied().unwrap_or(0);
    if !leaves.is_empty() && leaves.len() as u64 != total {
        return Err(bad(
            kind,
            0,
            format!(
                "{} records, the PLANES records' leaf_count sum to {total}: PLANE_LEAVES is empty or holds \
                 leaf_count records per plane (§6.10.1)",
                leaves.len()
            ),
        ));
    }
    let slots_image = |p: &PlaneRecord| images.get(p.image as usize).filter(|i| i.format == image_format::LEAF_SLOTS);
    let indirect = planes.iter().filter(|p| slots_image(p).is_some()).count() as u64;
    if leaves.is_empty() {
        if let Some((i, p)) = planes.iter().enumerate().find(|(_, p)| slots_image(p).is_some()) {
            return Err(bad(
                SectionKind::PLANES,
                i,
                format!(
                    "image {} is LEAF_SLOTS (indirect texturing) but PLANE_LEAVES is empty; it holds the leaves \
                     its slots name (§6.10.1)",
                    p.image
                ),
            ));
        }
        return Ok(indirect);
    }
    // The plane whose leaves record `i` belongs to: the last plane with base ≤ i (planes with no
    // leaves share their base with the next one).
    let owner = |i: usize| bases.partition_point(|&b| b <= i as u64).saturating_sub(1);
    for (i, leaf) in leaves.iter().enumerate() {
        let whose = || {
            let p = owner(i);
            let j = bases.get(p).map_or(0, |&b| i as u64 - b);
            format!("(leaf {j} of plane {p})")
        };
        if leaf.material as usize >= material_count {
            return Err(bad(
                kind,
                i,
                format!("material {} is out of range ({material_count} materials) {}", leaf.material, whose()),
            ));
        }
        for (name, v) in [("uv0", leaf.uv0), ("du", leaf.du), ("dv", leaf.dv)] {
            if !v.iter().all(|x| x.is_finite()) {
                return Err(bad(kind, i, format!("{name} {v:?} is not finite {}", whose())));
            }
        }
        let (min, max) = (leaf.uv_min, leaf.uv_max);
        if min & 0xFFFF > max & 0xFFFF || min >> 16 > max >> 16 {
            return Err(bad(
                kind,
                i,
                format!(
                    "uv_min ({}, {}) is not <= uv_max ({}, {}) per component {}",
                    min & 0xFFFF,
                    min >> 16,
                    max & 0xFFFF,
                    max >> 16,
                    whose()
                ),
            ));
        }
    }

    // The slots: per LEAF_SLOTS image, a max pyramid built once, then one query per plane.
    let mut pyramids: Vec<Option<SlotPyramid<'_>>> = Vec::new();
    pyramids.resize_with(images.len(), || None);
    for (i, p) in planes.iter().enumerate() {
        let Some(image) = slots_image(p) else { continue };
        let index = p.image as usize;
        let Some(slot) = pyramids.get_mut(index) else { continue };
        let pyramid = slot.get_or_insert_with(|| SlotPyramid::new(image, image_data));
        let [x0, x1] = texel_span(p.uv_min & 0xFFFF, p.uv_max & 0xFFFF, image.width);
        let [y0, y1] = texel_span(p.uv_min >> 16, p.uv_max >> 16, image.height);
        let limit = u16::try_from(p.leaf_count).unwrap_or(u16::MAX);
        if let Some((x, y, a, b)) = pyramid.first_above(limit, [x0, x1], [y0, y1]) {
            return Err(bad(
                SectionKind::PLANES,
                i,
                format!(
                    "texel ({x}, {y}) of its LEAF_SLOTS image {index}, inside its rectangle (texels {x0}..={x1} x \
                     {y0}..={y1}), holds slots ({a}, {b}), above its leaf_count {} (§6.10.1)",
                    p.leaf_count
                ),
            ));
        }
    }
    Ok(indirect)
}

/// The texels along one axis of `side` texels that the coordinates `min/65535 ..= max/65535`
/// cover (spec §6.10.1): those whose extent `[k, k+1)/side` meets the closed interval in more
/// than a point, `floor(min·side/65535) ..= ceil(max·side/65535) − 1`, or the texel holding
/// `min` when the interval is a point on a texel edge; clamped to the image.
fn texel_span(min: u32, max: u32, side: u32) -> [u32; 2] {
    let side = u64::from(side.max(1));
    let first = u64::from(min) * side / 65_535;
    let last = (u64::from(max) * side).div_ceil(65_535).saturating_sub(1).max(first);
    let clamp = |v: u64| u32::try_from(v.min(side - 1)).unwrap_or(u32::MAX);
    [clamp(first), clamp(last)]
}

/// Texels per side of the finest level of a [`SlotPyramid`].
const SLOT_BLOCK: u32 = 4;

/// A `LEAF_SLOTS` image with the largest slot (`max(a, b)`) of each block of `SLOT_BLOCK`² texels
/// and of each coarser block of 2×2 blocks, up to one block: a rectangle whose blocks all hold
/// slots at most a plane's `leaf_count` is settled without reading its texels, so planes whose
/// rectangles overlap (or cover the whole image) do not cost their area each.
struct SlotPyramid<'a> {
    /// `width · height · 4` bytes (checked by [`check_images`]; a shorter slice reads as zeros).
    texels: &'a [u8],
    width: u32,
    height: u32,
    /// Finest first: the blocks across, down and their maxima, row by row.
    levels: Vec<(usize, usize, Vec<u16>)>,
}

impl<'a> SlotPyramid<'a> {
    fn new(image: &ImageRecord, image_data: &'a [u8]) -> Self {
        let (width, height) = (image.width.max(1), image.height.max(1));
        let texels = usize::try_from(image.data_offset)
            .ok()
            .zip(usize::try_from(image.data_length).ok())
            .and_then(|(start, len)| image_data.get(start..start.checked_add(len)?))
            .unwrap_or_default();
        let (bw, bh) = (width.div_ceil(SLOT_BLOCK) as usize, height.div_ceil(SLOT_BLOCK) as usize);
        let block = SLOT_BLOCK as usize;
        let mut finest = vec![0u16; bw * bh];
        for (y, row) in texels.chunks_exact(width as usize * 4).enumerate() {
            let Some(blocks) = finest.get_mut((y / block) * bw..(y / block + 1) * bw) else { break };
            for (x, texel) in row.chunks_exact(4).enumerate() {
                let (a, b) = leaf_slots([texel[0], texel[1], texel[2], texel[3]]);
                if let Some(m) = blocks.get_mut(x / block) {
                    *m = (*m).max(a).max(b);
                }
            }
        }
        let mut levels = vec![(bw, bh, finest)];
        while let Some((w, h, below)) = levels.last().filter(|(w, h, _)| *w > 1 || *h > 1) {
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            let mut up = vec![0u16; nw * nh];
            for (y, row) in below.chunks_exact(*w).enumerate() {
                let Some(ups) = up.get_mut((y / 2) * nw..(y / 2 + 1) * nw) else { break };
                for (x, &m) in row.iter().enumerate() {
                    if let Some(u) = ups.get_mut(x / 2) {
                        *u = (*u).max(m);
                    }
                }
            }
            levels.push((nw, nh, up));
        }
        Self { texels, width, height, levels }
    }

    /// A texel of the rectangle `x0 ..= x1` × `y0 ..= y1` (texels) holding a slot above `limit`,
    /// with its two slots: `(x, y, a, b)`. Blocks are visited depth first in row order, and those
    /// outside the rectangle or with no slot above `limit` are skipped whole.
    fn first_above(&self, limit: u16, [x0, x1]: [u32; 2], [y0, y1]: [u32; 2]) -> Option<(u32, u32, u16, u16)> {
        // Blocks to visit as (level, bx, by), coarsest first.
        let top = self.levels.len().checked_sub(1)?;
        let mut stack = vec![(top, 0u32, 0u32)];
        while let Some((level, bx, by)) = stack.pop() {
            let (w, _, maxima) = self.levels.get(level)?;
            let size = u64::from(SLOT_BLOCK) << level;
            let (left, top_y) = (u64::from(bx) * size, u64::from(by) * size);
            let meets = left <= u64::from(x1)
                && left + size > u64::from(x0)
                && top_y <= u64::from(y1)
                && top_y + size > u64::from(y0);
            let max = maxima.get(by as usize * *w + bx as usize).copied().unwrap_or(0);
            if !meets || max <= limit {
                continue;
            }
            if level == 0 {
                if let Some(found) = self.scan_block(limit, bx, by, [x0, x1], [y0, y1]) {
                    return Some(found);
                }
                continue;
            }
            let (cw, ch, _) = self.levels.get(level - 1)?;
            // Children pushed last-first, so they are visited in row order.
            for (dx, dy) in [(1, 1), (0, 1), (1, 0), (0, 0)] {
                let (cx, cy) = (2 * bx + dx, 2 * by + dy);
                if (cx as usize) < *cw && (cy as usize) < *ch {
                    stack.push((level - 1, cx, cy));
                }
            }
        }
        None
    }

    /// The first texel in row order of finest block `(bx, by)` inside the rectangle holding a slot
    /// above `limit`.
    fn scan_block(
        &self,
        limit: u16,
        bx: u32,
        by: u32,
        [x0, x1]: [u32; 2],
        [y0, y1]: [u32; 2],
    ) -> Option<(u32, u32, u16, u16)> {
        let xs = (bx * SLOT_BLOCK).max(x0)..=((bx + 1) * SLOT_BLOCK - 1).min(x1).min(self.width - 1);
        for y in (by * SLOT_BLOCK).max(y0)..=((by + 1) * SLOT_BLOCK - 1).min(y1).min(self.height - 1) {
            for x in xs.clone() {
                let at = (y as usize * self.width as usize + x as usize) * 4;
                let texel = self.texels.get(at..at + 4).map_or([0; 4], |t| [t[0], t[1], t[2], t[3]]);
                let (a, b) = leaf_slots(texel);
                if a > limit || b > limit {
                    return Some((x, y, a, b));
                }
            }
        }
        None
    }
}

/// Spec §6.12: levels sorted by `(tree, level)`, numbered without gaps per tree, fractions in
/// `(0, 1)` strictly decreasing and errors finite, `≥ 0` and non-decreasing along each chain; the
/// triangle ranges tile `LOD_TRIANGLES` in record order.
fn check_lod_levels(levels: &[LodLevelRecord], triangle_count: usize, tree_count: u32) -> Result<()> {
    let kind = SectionKind::LOD_LEVELS;
    let mut next = 0u64;
    let mut previous: Option<&LodLevelRecord> = None;
    for (i, l) in levels.iter().enumerate() {
        if l.tree >= tree_count {
            return Err(bad(kind, i, format!("tree {} is out of range ({tree_count} trees)", l.tree)));
        }
        if !non_negative(l.error) {
            return Err(bad(kind, i, format!("error {} is not finite and >= 0", l.error)));
        }
        if !(l.fraction > 0.0 && l.fraction < 1.0) {
            return Err(bad(kind, i, format!("fraction {} is outside (0, 1)", l.fraction)));
        }
        let expected_level = match previous {
            Some(p) if p.tree == l.tree => p.level + 1,
            Some(p) if p.tree > l.tree => {
                return Err(bad(kind, i, format!("tree {} after tree {}: not sorted by tree", l.tree, p.tree)));
            }
            _ => 0,
        };
        if l.level != expected_level {
            return Err(bad(kind, i, format!("level {}, expected {expected_level}", l.level)));
        }
        if let Some(p) = previous.filter(|p| p.tree == l.tree) {
            if l.fraction >= p.fraction {
                return Err(bad(
                    kind,
                    i,
                    format!("fraction {} is not below the previous level's {}", l.fraction, p.fraction),
                ));
            }
            if l.error < p.error {
                return Err(bad(kind, i, format!("error {} is below the previous level's {}", l.error, p.error)));
            }
        }
        if u64::from(l.triangles.first) != next {
            return Err(bad(
                kind,
                i,
                format!(
                    "triangles start at {}, expected {next} (the levels tile LOD_TRIANGLES in order)",
                    l.triangles.first
                ),
            ));
        }
        next += u64::from(l.triangles.count);
        previous = Some(l);
    }
    if next != triangle_count as u64 {
        return Err(bad(SectionKind::LOD_TRIANGLES, 0, format!("{triangle_count} triangles, the levels cover {next}")));
    }
    Ok(())
}

/// Spec §6.13: billboards' fields, sorted by `(tree, kind)`.
fn check_billboards(billboards: &[BillboardRecord], image_count: usize, tree_count: u32) -> Result<()> {
    let kind = SectionKind::BILLBOARDS;
    let mut previous = (0u32, 0u32);
    for (i, b) in billboards.iter().enumerate() {
        check_quad(kind, i, [b.center, b.axis_u, b.axis_v], b.image, [b.uv_min, b.uv_max], image_count)?;
        if b.tree >= tree_count {
            return Err(bad(kind, i, format!("tree {} is out of range ({tree_count} trees)", b.tree)));
        }
        if b.kind > billboard_kind::CROSSED {
            return Err(bad(kind, i, format!("kind {} is neither FACING (0) nor CROSSED (1)", b.kind)));
        }
        if (b.tree, b.kind) < previous {
            return Err(bad(kind, i, format!("(tree, kind) ({}, {}) after {previous:?}: not sorted", b.tree, b.kind)));
        }
        previous = (b.tree, b.kind);
    }
    Ok(())
}

/// Spec §6.13.1: octahedral impostors' fields (`frames` in `2 ..= 64`, finite `center`, finite
/// `radius > 0`, an existing image and an atlas rectangle with `uv_min ≤ uv_max`, `tree` in
/// range, `occlusion` in `[0, 1]`, the diffuse shares at most 1 together), sorted by `tree` with at
/// most one per tree.
/// That the image is a colour image (not `LEAF_SLOTS`) is checked with the billboards'
/// ([`check_slot_images_only_for_planes`]).
fn check_octahedral(records: &[OctahedralRecord], image_count: usize, tree_count: u32) -> Result<()> {
    let kind = SectionKind::OCTAHEDRAL;
    let mut previous: Option<u32> = None;
    for (i, o) in records.iter().enumerate() {
        if !(OctahedralRecord::MIN_FRAMES..=OctahedralRecord::MAX_FRAMES).contains(&o.frames) {
            return Err(bad(
                kind,
                i,
                format!(
                    "frames {} is outside {} ..= {} (views per side of the grid)",
                    o.frames,
                    OctahedralRecord::MIN_FRAMES,
                    OctahedralRecord::MAX_FRAMES
                ),
            ));
        }
        if !finite3(o.center) {
            return Err(bad(kind, i, format!("center {:?} is not finite", o.center)));
        }
        if !(o.radius.is_finite() && o.radius > 0.0) {
            return Err(bad(kind, i, format!("radius {} is not finite and > 0", o.radius)));
        }
        check_atlas_rectangle(kind, i, o.image, [o.uv_min, o.uv_max], image_count)?;
        if o.tree >= tree_count {
            return Err(bad(kind, i, format!("tree {} is out of range ({tree_count} trees)", o.tree)));
        }
        if !unit(o.occlusion) {
            return Err(bad(kind, i, format!("occlusion {} is not in [0, 1]", o.occlusion)));
        }
        if u32::from(o.diffuse.flat) + u32::from(o.diffuse.scattered) > u32::from(u16::MAX) {
            let (flat, scattered) = (o.diffuse.flat, o.diffuse.scattered);
            return Err(bad(kind, i, format!("diffuse shares flat {flat} + scattered {scattered} exceed 65535")));
        }
        if let Some(before) = previous
            && o.tree <= before
        {
            let why = if o.tree == before { "a second impostor of the tree" } else { "not sorted by tree" };
            return Err(bad(kind, i, format!("tree {} after tree {before}: {why}", o.tree)));
        }
        previous = Some(o.tree);
    }
    Ok(())
}

/// Spec §6.13.2: the octahedral views' depth planes belong to the `OCTAHEDRAL` records (the section
/// needs them), `frames²` per record in their order, and every value is finite and in `[−1, 1]`.
///
/// Runs after [`check_octahedral`], so every `frames` is in `2 ..= 64`.
fn check_octahedral_depth(records: &[OctahedralDepthRecord], octahedral: &[OctahedralRecord]) -> Result<()> {
    let kind = SectionKind::OCTAHEDRAL_DEPTH;
    if records.is_empty() {
        return Ok(());
    }
    if octahedral.is_empty() {
        return Err(bad(kind, 0, "the file has no OCTAHEDRAL, whose views these planes belong to".into()));
    }
    let views: u64 = octahedral.iter().map(|o| u64::from(o.frames) * u64::from(o.frames)).sum();
    if records.len() as u64 != views {
        return Err(bad(
            kind,
            0,
            format!(
                "{} records, the {} OCTAHEDRAL records have {views} views (frames² each): one plane per view",
                records.len(),
                octahedral.len()
            ),
        ));
    }
    let mut index = 0;
    for (k, o) in octahedral.iter().enumerate() {
        let n = o.frames as usize;
        for (view, r) in records[index..index + n * n].iter().enumerate() {
            let fields = [("offset", r.offset), ("slope_s", r.slope_s), ("slope_t", r.slope_t)];
            if let Some((name, value)) = fields.into_iter().find(|(_, v)| !(-1.0..=1.0).contains(v)) {
                return Err(bad(
                    kind,
                    index + view,
                    format!(
                        "{name} {value} is not finite and in [-1, 1] (view ({}, {}) of OCTAHEDRAL record {k})",
                        view % n,
                        view / n
                    ),
                ));
            }
        }
        index += n * n;
    }
    Ok(())
}

/// Spec §6.13.3: each impostor's grid of normal cells, of its colour grid's size from `uv_min`,
/// lies inside the image: `uv_min + (uv_max − uv_min) ≤ 65536` unorm16 steps per component (1 and
/// the one step both corners' rounding may add). One record per `OCTAHEDRAL` record is checked at
/// open.
///
/// Runs after [`check_octahedral`], so every colour grid has `uv_min ≤ uv_max`.
fn check_octahedral_normals(records: &[OctahedralNormalRecord], octahedral: &[OctahedralRecord]) -> Result<()> {
    let kind = SectionKind::OCTAHEDRAL_NORMALS;
    for (i, (r, o)) in records.iter().zip(octahedral).enumerate() {
        let ([u, v], [far_u, far_v]) = (unorm16x2_steps(r.uv_min), r.far_steps(o));
        let (w, h) = (far_u - u, far_v - v);
        if far_u > 0x1_0000 || far_v > 0x1_0000 {
            return Err(bad(
                kind,
                i,
                format!(
                    "the normal grid at ({u}, {v}) of the colour grid's size ({w}, {h}) leaves the image \
                     (unorm16 steps, at most 65536)"
                ),
            ));
        }
    }
    Ok(())
}

/// Spec §6.13.3 (1.16): each impostor's grid of normal cells has `uv_min ≤ uv_max` per component
/// and is not empty (`uv_min < uv_max` per component); its corners, two `unorm16` each, lie in the
/// image by construction. Its size need not be the colour grid's. One record per `OCTAHEDRAL`
/// record, and not with `OCTAHEDRAL_NORMALS`, is checked at open.
fn check_octahedral_normal_grids(records: &[OctahedralNormalGridRecord]) -> Result<()> {
    let kind = SectionKind::OCTAHEDRAL_NORMAL_GRIDS;
    for (i, r) in records.iter().enumerate() {
        check_corner_order(kind, i, [r.uv_min, r.uv_max])?;
        let ([min_u, min_v], [max_u, max_v]) = (unorm16x2_steps(r.uv_min), unorm16x2_steps(r.uv_max));
        if min_u == max_u || min_v == max_v {
            return Err(bad(
                kind,
                i,
                format!(
                    "the normal grid ({min_u}, {min_v}) .. ({max_u}, {max_v}) is empty (uv_min < uv_max per \
                     component)"
                ),
            ));
        }
    }
    Ok(())
}

/// Spec §6.11: pruned leaves' fields; their triangle ranges tile `PRUNE_TRIANGLES` in leaf order;
/// each pruned triangle's `leaf` is the index of the leaf whose range holds it.
fn check_prune(leaves: &[PruneLeafRecord], triangles: &[TriangleRecord]) -> Result<()> {
    let kind = SectionKind::PRUNE_LEAVES;
    let mut next = 0u64;
    for (i, leaf) in leaves.iter().enumerate() {
        if !finite3(leaf.center) {
            return Err(bad(kind, i, format!("center {:?} is not finite", leaf.center)));
        }
        if !non_negative(leaf.area) {
            return Err(bad(kind, i, format!("area {} is not finite and >= 0", leaf.area)));
        }
        if leaf.triangle_count == 0 {
            return Err(bad(kind, i, "triangle_count is 0, a pruned leaf has at least one triangle".into()));
        }
        if u64::from(leaf.first_triangle) != next {
            return Err(bad(
                kind,
                i,
                format!(
                    "first_triangle {}, expected {next} (the leaves' ranges tile PRUNE_TRIANGLES in order)",
                    leaf.first_triangle
                ),
            ));
        }
        let end = next + u64::from(leaf.triangle_count);
        let owned = usize::try_from(next)
            .ok()
            .zip(usize::try_from(end).ok())
            .and_then(|(s, e)| triangles.get(s..e))
            .ok_or_else(|| {
                bad(
                    kind,
                    i,
                    format!("triangles {next}..{end} reach past PRUNE_TRIANGLES ({} records)", triangles.len()),
                )
            })?;
        for (k, t) in owned.iter().enumerate() {
            if t.leaf as usize != i {
                #[expect(clippy::cast_possible_truncation, reason = "next indexes a slice, so it fits usize")]
                let index = next as usize + k;
                return Err(bad(
                    SectionKind::PRUNE_TRIANGLES,
                    index,
                    format!("leaf {} but the record lies in the range of pruned leaf {i}", t.leaf),
                ));
            }
        }
        next = end;
    }
    if next != triangles.len() as u64 {
        #[expect(clippy::cast_possible_truncation, reason = "next <= triangles.len()")]
        return Err(bad(
            SectionKind::PRUNE_TRIANGLES,
            next as usize,
            format!("belongs to no pruned leaf: the leaves' ranges end at {next}, the section has {}", triangles.len()),
        ));
    }
    Ok(())
}

/// One set of calibration tables (spec §6.15, §6.16, §6.18): the section of its means, the
/// section of its tables per elevation, and the techniques their records may name.
struct Tables {
    /// `CALIBRATION` or `CALIBRATION_ADDED`.
    mean: SectionKind,
    /// `CALIBRATION_ELEVATIONS` or `CALIBRATION_ELEVATIONS_ADDED`.
    per_elevation: SectionKind,
    /// The codes its records name: `first .. end`, or from `first` on (`None`: codes a later
    /// minor defines, which a reader skips).
    techniques: (u32, Option<u32>),
    /// The other set's sections (mean, per elevation), which hold the other defined codes.
    other: (SectionKind, SectionKind),
}

/// `CALIBRATION` and `CALIBRATION_ELEVATIONS` (spec §6.15, §6.16): the techniques a reader of 1.5
/// to 1.11 defines.
const BASE_TABLES: Tables = Tables {
    mean: SectionKind::CALIBRATION,
    per_elevation: SectionKind::CALIBRATION_ELEVATIONS,
    techniques: (0, Some(calibration_technique::FIRST_ADDED)),
    other: (SectionKind::CALIBRATION_ADDED, SectionKind::CALIBRATION_ELEVATIONS_ADDED),
};

/// `CALIBRATION_ADDED` and `CALIBRATION_ELEVATIONS_ADDED` (spec §6.18): the techniques added
/// after 1.11, and those later minors add (a reader skips the records of codes it does not
/// define, so a file of a later minor stays readable).
const ADDED_TABLES: Tables = Tables {
    mean: SectionKind::CALIBRATION_ADDED,
    per_elevation: SectionKind::CALIBRATION_ELEVATIONS_ADDED,
    techniques: (calibration_technique::FIRST_ADDED, None),
    other: (SectionKind::CALIBRATION, SectionKind::CALIBRATION_ELEVATIONS),
};

/// Spec §6.15, §6.16, §6.18: record `i` of `kind`, a calibration sample `(technique, height,
/// error, primitives)` of `tables`, names one of the techniques `tables` holds, at a finite,
/// positive height, with an error in `[0, 1]` and a finite primitive count `≥ 0`. A technique of
/// the other set is named, with the section it belongs in.
fn check_calibration_sample(
    tables: &Tables,
    kind: SectionKind,
    i: usize,
    (technique, height, error, primitives): (u32, f32, f32, f32),
) -> Result<()> {
    let (first, end) = tables.techniques;
    if technique < first || end.is_some_and(|end| technique >= end) {
        let elsewhere = calibration_technique::name(technique).map_or_else(String::new, |name| {
            let other = if kind == tables.mean { tables.other.0 } else { tables.other.1 };
            format!(": {name} belongs in {other}")
        });
        let range = end.map_or_else(|| format!("{first}.."), |end| format!("{first}..{end}"));
        return Err(bad(kind, i, format!("technique {technique} is not defined here ({range}){elsewhere}")));
    }
    check_measurement(kind, i, (height, error, primitives))
}

/// Spec §6.15–§6.17: record `i` of `kind` measures a positive, finite `height` in pixels, an
/// `error` in `[0, 1]` and a finite, non-negative count of `primitives`.
fn check_measurement(kind: SectionKind, i: usize, (height, error, primitives): (f32, f32, f32)) -> Result<()> {
    if !(height.is_finite() && height > 0.0) {
        return Err(bad(kind, i, format!("height {height} is not a positive number of pixels")));
    }
    if !unit(error) {
        return Err(bad(kind, i, format!("error {error} lies outside [0, 1]")));
    }
    if !non_negative(primitives) {
        return Err(bad(kind, i, format!("primitive count {primitives} is not a finite count")));
    }
    Ok(())
}

/// Spec §6.15, §6.18: the records of `tables.mean` name its techniques in ascending order,
/// heights finite, positive and strictly increasing within a technique, errors in `[0, 1]`,
/// primitive counts finite and `≥ 0`.
fn check_calibration(tables: &Tables, records: &[CalibrationRecord]) -> Result<()> {
    let kind = tables.mean;
    for (i, r) in records.iter().enumerate() {
        check_calibration_sample(tables, kind, i, (r.technique, r.height, r.error, r.primitives))?;
        if let Some(prev) = i.checked_sub(1).and_then(|p| records.get(p)) {
            if r.technique < prev.technique {
                return Err(bad(kind, i, format!("technique {} follows technique {}", r.technique, prev.technique)));
            }
            if r.technique == prev.technique && r.height <= prev.height {
                return Err(bad(
                    kind,
                    i,
                    format!("height {} does not increase strictly after {}", r.height, prev.height),
                ));
            }
        }
    }
    Ok(())
}

/// Spec §6.16, §6.18: the records of `tables.per_elevation` have elevations finite in `[0, 90]`
/// and non-decreasing, techniques of `tables` non-decreasing within an elevation, heights finite,
/// positive and strictly increasing within an elevation and technique, errors in `[0, 1]`,
/// primitive counts finite and `≥ 0`; and each elevation holds exactly the `(technique, height)`
/// pairs of `calibration` (the records of `tables.mean`), so a file with records also has those.
///
/// Runs after [`check_calibration`] of `calibration`: it is sorted by technique and strictly by
/// height within one, so a pair is found by binary search, and an elevation whose records are
/// sorted the same way, each a pair of `calibration`, holds them all exactly when it has as many
/// records.
fn check_calibration_elevations(
    tables: &Tables,
    records: &[ElevationCalibrationRecord],
    calibration: &[CalibrationRecord],
) -> Result<()> {
    let (kind, mean) = (tables.per_elevation, tables.mean);
    if records.is_empty() {
        return Ok(());
    }
    if calibration.is_empty() {
        return Err(bad(
            kind,
            0,
            format!("the file has no {mean}, whose (technique, height) pairs each elevation holds"),
        ));
    }
    let pair = |technique: u32, height: f32| {
        calibration.binary_search_by(|c| c.technique.cmp(&technique).then(c.height.total_cmp(&height)))
    };
    // The first record of the elevation being read.
    let mut start = 0;
    for (i, r) in records.iter().enumerate() {
        if !(r.elevation.is_finite() && (0.0..=90.0).contains(&r.elevation)) {
            return Err(bad(kind, i, format!("elevation {} lies outside [0, 90] degrees", r.elevation)));
        }
        check_calibration_sample(tables, kind, i, (r.technique, r.height, r.error, r.primitives))?;
        if let Some(prev) = i.checked_sub(1).and_then(|p| records.get(p)) {
            if r.elevation < prev.elevation {
                return Err(bad(kind, i, format!("elevation {} follows elevation {}", r.elevation, prev.elevation)));
            }
            if r.elevation > prev.elevation {
                check_elevation_pairs(tables, &records[start..i], start, calibration)?;
                start = i;
            } else if r.technique < prev.technique {
                return Err(bad(kind, i, format!("technique {} follows technique {}", r.technique, prev.technique)));
            } else if r.technique == prev.technique && r.height <= prev.height {
                return Err(bad(
                    kind,
                    i,
                    format!("height {} does not increase strictly after {}", r.height, prev.height),
                ));
            }
        }
        if pair(r.technique, r.height).is_err() {
            return Err(bad(kind, i, format!("technique {} at height {} has no {mean} record", r.technique, r.height)));
        }
    }
    check_elevation_pairs(tables, &records[start..], start, calibration)
}

/// Spec §6.16, §6.18: the records of one elevation of `tables.per_elevation`, from record
/// `start`, hold every `(technique, height)` pair of `calibration` (`tables.mean`'s). They are
/// sorted as `calibration` is and each is one of its pairs, so they hold all exactly when they
/// are as many; otherwise the first place the two differ names a pair the elevation lacks,
/// reported at its first record.
fn check_elevation_pairs(
    tables: &Tables,
    elevation: &[ElevationCalibrationRecord],
    start: usize,
    calibration: &[CalibrationRecord],
) -> Result<()> {
    if elevation.len() == calibration.len() {
        return Ok(());
    }
    let at = elevation.first().map_or(0.0, |r| r.elevation);
    let missing = calibration
        .iter()
        .enumerate()
        .find(|&(k, c)| {
            elevation.get(k).is_none_or(|r| r.technique != c.technique || r.height.to_bits() != c.height.to_bits())
        })
        .map_or_else(String::new, |(_, c)| format!(", not technique {} at height {}", c.technique, c.height));
    Err(bad(
        tables.per_elevation,
        start,
        format!(
            "elevation {at} holds {} of the {} (technique, height) pairs of {}{missing}",
            elevation.len(),
            calibration.len(),
            tables.mean
        ),
    ))
}

/// Spec §6.18: the added tables complete the others. `CALIBRATION_ADDED` needs `CALIBRATION`;
/// `CALIBRATION_ELEVATIONS_ADDED` needs `CALIBRATION_ELEVATIONS` and has exactly its elevations
/// (equal as stored); and a file with `CALIBRATION_ELEVATIONS` and `CALIBRATION_ADDED` has
/// `CALIBRATION_ELEVATIONS_ADDED`, so that every elevation has every technique.
///
/// Runs after [`check_calibration_elevations`] of both sets: `per_elevation` and
/// `added_per_elevation` are sorted by elevation, and `added_per_elevation` is empty or
/// `added` is not.
fn check_added_calibration(
    calibration: &[CalibrationRecord],
    per_elevation: &[ElevationCalibrationRecord],
    added: &[CalibrationRecord],
    added_per_elevation: &[ElevationCalibrationRecord],
) -> Result<()> {
    let (mean, elevations) = (SectionKind::CALIBRATION_ADDED, SectionKind::CALIBRATION_ELEVATIONS_ADDED);
    if !added.is_empty() && calibration.is_empty() {
        return Err(bad(mean, 0, "the file has no CALIBRATION, whose tables these complete".into()));
    }
    if added_per_elevation.is_empty() {
        if !added.is_empty() && !per_elevation.is_empty() {
            return Err(bad(
                mean,
                0,
                "the file has CALIBRATION_ELEVATIONS but no CALIBRATION_ELEVATIONS_ADDED, whose tables per \
                 elevation these need"
                    .into(),
            ));
        }
        return Ok(());
    }
    if per_elevation.is_empty() {
        return Err(bad(
            elevations,
            0,
            "the file has no CALIBRATION_ELEVATIONS, whose elevations these complete".into(),
        ));
    }
    // The elevations of each, as stored.
    let set = |records: &[ElevationCalibrationRecord]| {
        let mut bits: Vec<u32> = records.iter().map(|r| r.elevation.to_bits()).collect();
        bits.sort_unstable();
        bits.dedup();
        bits
    };
    let (theirs, ours) = (set(per_elevation), set(added_per_elevation));
    if let Some(i) = added_per_elevation.iter().position(|r| theirs.binary_search(&r.elevation.to_bits()).is_err()) {
        return Err(bad(
            elevations,
            i,
            format!("elevation {} is not an elevation of CALIBRATION_ELEVATIONS", added_per_elevation[i].elevation),
        ));
    }
    if let Some(&missing) = theirs.iter().find(|b| ours.binary_search(b).is_err()) {
        let missing = f32::from_bits(missing);
        // Reported where its records would be.
        let i = added_per_elevation
            .partition_point(|r| r.elevation < missing)
            .min(added_per_elevation.len().saturating_sub(1));
        return Err(bad(
            elevations,
            i,
            format!("has no records at elevation {missing}, an elevation of CALIBRATION_ELEVATIONS"),
        ));
    }
    Ok(())
}

/// Spec §6.19: the records of `CALIBRATION_FLIP` have elevations of exactly
/// [`FlipCalibrationRecord::EVERY_VIEW`] (−1, a row over every view) or finite in `[0, 90]`,
/// non-decreasing (so the rows over every view come first), techniques non-decreasing within an
/// elevation, heights finite, positive and strictly increasing within an elevation and technique,
/// and FLIP errors in `[0, 1]`.
///
/// Any technique code is valid, the base ones (§6.15) and the added ones (§6.18) alike, and codes
/// no minor defines yet as well: as in `CALIBRATION_ELEVATIONS_ADDED` (§6.18), a reader skips the
/// rows of a code it does not define, so a file of a later minor that adds a technique stays
/// readable. The rows are self-describing: they need no other section, and are not paired with
/// the RMSE tables' records.
fn check_calibration_flip(records: &[FlipCalibrationRecord]) -> Result<()> {
    let kind = SectionKind::CALIBRATION_FLIP;
    for (i, r) in records.iter().enumerate() {
        let every_view = r.elevation == FlipCalibrationRecord::EVERY_VIEW;
        let at_elevation = r.elevation.is_finite() && (0.0..=90.0).contains(&r.elevation);
        if !(every_view || at_elevation) {
            return Err(bad(
                kind,
                i,
                format!("elevation {} is neither -1 (every view) nor in [0, 90] degrees", r.elevation),
            ));
        }
        if !(r.height.is_finite() && r.height > 0.0) {
            return Err(bad(kind, i, format!("height {} is not a positive number of pixels", r.height)));
        }
        if !unit(r.flip) {
            return Err(bad(kind, i, format!("FLIP error {} lies outside [0, 1]", r.flip)));
        }
        let Some(prev) = i.checked_sub(1).and_then(|p| records.get(p)) else {
            continue;
        };
        if r.elevation < prev.elevation {
            return Err(bad(kind, i, format!("elevation {} follows elevation {}", r.elevation, prev.elevation)));
        }
        if r.elevation > prev.elevation {
            continue;
        }
        if r.technique < prev.technique {
            return Err(bad(kind, i, format!("technique {} follows technique {}", r.technique, prev.technique)));
        }
        if r.technique == prev.technique && r.height <= prev.height {
            return Err(bad(kind, i, format!("height {} does not increase strictly after {}", r.height, prev.height)));
        }
    }
    Ok(())
}

/// Spec §6.17: levels in ascending order, each a level every tree of `LOD_LEVELS` has (so the
/// section needs a chain), heights finite, positive and strictly increasing within a level, errors
/// in `[0, 1]`, primitive counts finite and `≥ 0`.
fn check_chain_calibration(records: &[ChainCalibrationRecord], levels: &[LodLevelRecord]) -> Result<()> {
    let kind = SectionKind::CHAIN_CALIBRATION;
    check_level_rows(
        kind,
        records,
        levels,
        |r| (r.level, r.height),
        |i, r| check_measurement(kind, i, (r.height, r.error, r.primitives)),
    )
}

/// The levels every tree of the chain has: `0 .. depth`, the least of the trees' level counts
/// (0 without a chain).
fn chain_depth(levels: &[LodLevelRecord]) -> u32 {
    let mut per_tree: Vec<(u32, u32)> = Vec::new();
    for l in levels {
        match per_tree.iter_mut().find(|(tree, _)| *tree == l.tree) {
            Some(entry) => entry.1 = entry.1.max(l.level.saturating_add(1)),
            None => per_tree.push((l.tree, l.level.saturating_add(1))),
        }
    }
    per_tree.iter().map(|&(_, n)| n).min().unwrap_or(0)
}

/// The rows of a per-level table of the LoD chain (`CHAIN_CALIBRATION`, §6.17;
/// `CHAIN_CALIBRATION_FLIP`, §6.20), each `(level, height)` by `key`: per record, its level one
/// every tree of `LOD_LEVELS` has, then its values by `values`, then the order, levels
/// non-decreasing and heights strictly increasing within a level. No records: nothing to check.
fn check_level_rows<R>(
    kind: SectionKind,
    records: &[R],
    levels: &[LodLevelRecord],
    key: impl Fn(&R) -> (u32, f32),
    values: impl Fn(usize, &R) -> Result<()>,
) -> Result<()> {
    if records.is_empty() {
        return Ok(());
    }
    let depth = chain_depth(levels);
    for (i, r) in records.iter().enumerate() {
        let (level, height) = key(r);
        if level >= depth {
            return Err(bad(kind, i, format!("level {level} is not a level of every tree's LoD chain (0..{depth})")));
        }
        values(i, r)?;
        let Some((prev_level, prev_height)) = i.checked_sub(1).and_then(|p| records.get(p)).map(&key) else {
            continue;
        };
        if level < prev_level {
            return Err(bad(kind, i, format!("level {level} follows level {prev_level}")));
        }
        if level == prev_level && height <= prev_height {
            return Err(bad(kind, i, format!("height {height} does not increase strictly after {prev_height}")));
        }
    }
    Ok(())
}

/// Spec §6.20: the records of `CHAIN_CALIBRATION_FLIP` have levels non-decreasing, each a level
/// every tree of `LOD_LEVELS` has (so the section needs a chain), heights finite, positive and
/// strictly increasing within a level, and FLIP errors in `[0, 1]`.
///
/// As `CALIBRATION_FLIP`'s (§6.19), the rows are not paired with the RMSE table's records
/// (`CHAIN_CALIBRATION`, §6.17): a reader interpolates each table on its own heights.
fn check_chain_calibration_flip(records: &[ChainFlipCalibrationRecord], levels: &[LodLevelRecord]) -> Result<()> {
    let kind = SectionKind::CHAIN_CALIBRATION_FLIP;
    check_level_rows(
        kind,
        records,
        levels,
        |r| (r.level, r.height),
        |i, r| {
            if !(r.height.is_finite() && r.height > 0.0) {
                return Err(bad(kind, i, format!("height {} is not a positive number of pixels", r.height)));
            }
            if !unit(r.flip) {
                return Err(bad(kind, i, format!("FLIP error {} lies outside [0, 1]", r.flip)));
            }
            Ok(())
        },
    )
}

fn check_curve(kind: SectionKind, samples: &[CurveSample]) -> Result<()> {
    for (i, s) in samples.iter().enumerate() {
        if !s.x.is_finite() || !s.y.is_finite() {
            return Err(bad(kind, i, format!("sample ({}, {}) is not finite", s.x, s.y)));
        }
        if let Some(prev) = i.checked_sub(1).and_then(|p| samples.get(p))
            && s.x <= prev.x
        {
            return Err(bad(kind, i, format!("x {} does not increase strictly after {}", s.x, prev.x)));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Cells: bounds (spec §6.2), order and exact cut (§6.4, §6.5, §10).

/// The records of one cell of one kind; open checked that the ranges tile the arrays.
fn cell_slice<T>(kind: SectionKind, cell: usize, all: &[T], range: Range) -> Result<&[T]> {
    all.get(range.as_usize()).ok_or_else(|| Error::BadCell {
        cell,
        reason: format!("{kind} range {}+{} lies outside the {} records", range.first, range.count, all.len()),
    })
}

/// Bounds, order and exact cut of one cell; returns the leaves and depth of its hierarchies.
fn check_cell(c: &Container, index: usize, cell: &CellRecord) -> Result<SptSummary> {
    let triangles = cell_slice(SectionKind::TRIANGLES, index, c.triangles(), cell.triangles)?;
    let points = cell_slice(SectionKind::POINTS, index, c.points(), cell.points)?;
    let ellipsoids = cell_slice(SectionKind::ELLIPSOIDS, index, c.ellipsoids(), cell.ellipsoids)?;
    let lines = cell_slice(SectionKind::LINES, index, c.lines(), cell.lines)?;
    let planes = cell_slice(SectionKind::PLANES, index, c.planes(), cell.planes)?;
    let prune = cell_slice(SectionKind::PRUNE_LEAVES, index, c.prune_leaves(), cell.prune_leaves)?;

    // Bounds (§6.2).
    let (lo, hi) = (cell.bounds_min, cell.bounds_max);
    if cell.is_empty() {
        if lo.iter().chain(&hi).any(|&v| v != 0.0) {
            return Err(Error::BadCell {
                cell: index,
                reason: format!("no records but bounds {lo:?}..{hi:?}; an empty cell has all-zero bounds"),
            });
        }
    } else if !finite3(lo) || !finite3(hi) || (0..3).any(|k| lo[k] > hi[k]) {
        return Err(Error::BadCell {
            cell: index,
            reason: format!("bounds {lo:?}..{hi:?} are not finite and ordered"),
        });
    }
    let inside = |p: [f32; 3]| (0..3).all(|k| lo[k] <= p[k] && p[k] <= hi[k]);
    let outside = |kind: SectionKind, first: u32, i: usize, what: &str, p: [f32; 3]| Error::BadCell {
        cell: index,
        reason: format!(
            "{kind} record {} {what} {p:?} lies outside the cell bounds {lo:?}..{hi:?}",
            first as usize + i
        ),
    };
    let vertices = c.vertices();
    for (i, t) in triangles.iter().enumerate() {
        for v in t.indices {
            // Indices were checked against the vertex count before.
            let p = vertices.get(v as usize).map_or([f32::NAN; 3], |v| v.position);
            if !inside(p) {
                return Err(outside(SectionKind::TRIANGLES, cell.triangles.first, i, &format!("vertex {v} at"), p));
            }
        }
    }
    for (i, p) in points.iter().enumerate() {
        if !inside(p.position) {
            return Err(outside(SectionKind::POINTS, cell.points.first, i, "position", p.position));
        }
    }
    for (i, e) in ellipsoids.iter().enumerate() {
        if !inside(e.center) {
            return Err(outside(SectionKind::ELLIPSOIDS, cell.ellipsoids.first, i, "center", e.center));
        }
    }
    for (i, l) in lines.iter().enumerate() {
        for (what, p) in [("p0", l.p0), ("p1", l.p1)] {
            if !inside(p) {
                return Err(outside(SectionKind::LINES, cell.lines.first, i, what, p));
            }
        }
    }
    for (i, p) in planes.iter().enumerate() {
        if !inside(p.center) {
            return Err(outside(SectionKind::PLANES, cell.planes.first, i, "center", p.center));
        }
    }
    for (i, p) in prune.iter().enumerate() {
        if !inside(p.center) {
            return Err(outside(SectionKind::PRUNE_LEAVES, cell.prune_leaves.first, i, "center", p.center));
        }
    }

    // Order and exact cut (§6.4, §6.5, §10).
    let leaf_sizes = triangle_leaf_sizes(index, cell.triangles.first as usize, triangles)?;
    let mut total = SptSummary::default();
    for s in [
        check_point_cut(index, cell.points.first as usize, points, &leaf_sizes)?,
        check_spt(SectionKind::ELLIPSOIDS, index, cell.ellipsoids.first as usize, ellipsoids)?,
        check_spt(SectionKind::LINES, index, cell.lines.first as usize, lines)?,
        check_spt(SectionKind::PLANES, index, cell.planes.first as usize, planes)?,
    ] {
        total.leaves += s.leaves;
        total.max_depth = total.max_depth.max(s.max_depth);
    }
    Ok(total)
}

/// Checks one cell's triangles (spec §6.4, §10 rule 3) and returns the size of each leaf id.
///
/// `first` is the index of `triangles[0]` in `TRIANGLES`, used in errors. Checks that every size is
/// finite and `≥ 0`, that sizes do not increase, and that the `leaf` values are exactly
/// `0 .. triangles.len()`. The result's entry `ℓ` is the size of the triangle with leaf `ℓ`.
///
/// # Errors
/// [`Error::BadRecord`] naming the first triangle that breaks a rule.
pub fn triangle_leaf_sizes(cell: usize, first: usize, triangles: &[TriangleRecord]) -> Result<Vec<f32>> {
    let kind = SectionKind::TRIANGLES;
    let t = triangles.len();
    // The triangle holding each leaf id; `usize::MAX` while none does.
    let mut owner = vec![usize::MAX; t];
    let mut prev = f32::INFINITY;
    for (i, tri) in triangles.iter().enumerate() {
        if !non_negative(tri.size) {
            return Err(bad(kind, first + i, format!("size {} is not finite and >= 0", tri.size)));
        }
        if tri.size > prev {
            return Err(bad(
                kind,
                first + i,
                format!(
                    "size {} is larger than {prev} of the record before (cell {cell} sorts by size, largest first)",
                    tri.size
                ),
            ));
        }
        prev = tri.size;
        let Some(slot) = owner.get_mut(tri.leaf as usize) else {
            return Err(bad(
                kind,
                first + i,
                format!(
                    "leaf {} is out of range: cell {cell} has {t} triangles, leaf ids are 0..{t} (§10 rule 3)",
                    tri.leaf
                ),
            ));
        };
        if *slot != usize::MAX {
            return Err(bad(
                kind,
                first + i,
                format!(
                    "leaf {} is also the leaf of record {} (cell {cell}; leaf ids are unique)",
                    tri.leaf,
                    first + *slot
                ),
            ));
        }
        *slot = i;
    }
    // `t` distinct ids below `t`: every id has its triangle.
    Ok(owner.iter().map(|&i| triangles.get(i).map_or(f32::NAN, |tri| tri.size)).collect())
}

/// Checks one cell's hierarchy of ellipsoids, lines or planes (spec §6.8–§6.10, §10 rules 1–2).
///
/// `first` is the index of `records[0]` in its section, used in errors. Checks every record's
/// interval (`lo` finite and `≥ 0`, `lo ≤ hi`, `hi` possibly `+∞`) and `leaf_count ≥ 1`, that `hi`
/// does not increase, that the leaf runs are laminar, and that for each leaf `ℓ < n` the non-empty
/// intervals of the records whose run holds `ℓ` chain from 0 to `+∞` without gap or overlap.
///
/// Cost: `O(m log m)` time and `O(m)` memory for `m` records, whatever the number of leaves.
///
/// # Errors
/// [`Error::BadRecord`] for a record's own fields or order, [`Error::BadCell`] for the hierarchy.
pub fn check_spt<T: SptElement>(kind: SectionKind, cell: usize, first: usize, records: &[T]) -> Result<SptSummary> {
    sweep(kind, Scope::Cell(cell), first, records, None)
}

/// Checks a block's far lines against its lines and bounds (spec §6.9.1).
///
/// `FAR_LINES` is empty, or: `LINES` is not empty; every record's endpoints are finite and lie
/// inside the block bounds (§6.1), its radii finite and `≥ 0`; the records form one hierarchy
/// that [`check_spt`] accepts (sorted by `hi`, largest first, §10 rules 1–2) over the leaves
/// `0 .. n`, `n` the number of `LINES` records drawn at the switch `τ_s` ([`far_switch`]:
/// `τ_far · 2^(−1/2)`, [`far_threshold`]; [`lines_drawn_at`]), the cells' lines of which the far
/// leaves are copies. Whether the leaves are bit-for-bit copies of those lines is not checked.
///
/// Cost: `O(m log m + l)` time for `m` far lines and `l` lines.
///
/// # Errors
/// [`Error::BadRecord`] naming `FAR_LINES` for a record's own fields, its bounds or its order, and
/// for far lines without lines; [`Error::BadHierarchy`] naming `FAR_LINES` for the hierarchy, its
/// leaf count and `τ_far`.
pub fn check_far_lines(far: &[LineRecord], lines: &[LineRecord], block: &BlockRecord) -> Result<SptSummary> {
    let kind = SectionKind::FAR_LINES;
    if far.is_empty() {
        return Ok(SptSummary::default());
    }
    if lines.is_empty() {
        return Err(bad(
            kind,
            0,
            format!("{} records but LINES is empty: far lines merge the cells' lines (§6.9.1)", far.len()),
        ));
    }
    check_lines(kind, far)?;
    let (lo, hi) = (block.bounds_min, block.bounds_max);
    let inside = |p: [f32; 3]| (0..3).all(|k| lo[k] <= p[k] && p[k] <= hi[k]);
    for (i, l) in far.iter().enumerate() {
        for (what, p) in [("p0", l.p0), ("p1", l.p1)] {
            if !inside(p) {
                return Err(bad(
                    kind,
                    i,
                    format!("{what} {p:?} lies outside the block bounds {lo:?}..{hi:?} (§6.1, §6.9.1)"),
                ));
            }
        }
    }
    let summary = sweep(kind, Scope::Section, 0, far, None)?;
    let (tau_far, switch) = (far_threshold(far), far_switch(far));
    // Far lines that never merge (`τ_far = +∞`) copy the cells' coarsest lines.
    let (drawn, at) = if switch.is_finite() {
        (
            lines_drawn_at(lines, switch),
            format!("drawn at the switch τ_s = τ_far·2^(-1/2) = {switch} (τ_far {tau_far})"),
        )
    } else {
        (lines.iter().filter(|l| l.hi == f32::INFINITY).count(), "with hi = +inf (τ_far is +inf)".to_owned())
    };
    if summary.leaves != drawn as u64 {
        return Err(Error::BadHierarchy {
            kind,
            reason: format!(
                "the runs cover leaves 0..{}, but LINES has {drawn} records {at}: far level 0 copies the lines the \
                 cells draw there, one far leaf each (§6.9.1)",
                summary.leaves
            ),
        });
    }
    Ok(summary)
}

/// Checks one cell's points against its triangles (spec §6.5, §10 rules 1–3).
///
/// Everything [`check_spt`] checks, and: the points cover exactly the leaves `0 .. t` of the
/// cell's `t` triangles (no points if there are no triangles), and every point with a non-empty
/// interval `[lo, hi)` has, for each leaf `ℓ` of its run, `size = size(ℓ)` or both `size ≤ lo` and
/// `size(ℓ) ≤ lo`. `leaf_sizes` is what [`triangle_leaf_sizes`] returns for the cell.
///
/// Cost: `O(m log m + t)` time and `O(m)` memory.
///
/// # Errors
/// As [`check_spt`]; [`Error::BadCell`] also for a non-finite or negative leaf size.
pub fn check_point_cut(cell: usize, first: usize, points: &[PointRecord], leaf_sizes: &[f32]) -> Result<SptSummary> {
    let kind = SectionKind::POINTS;
    if let Some(leaf) = leaf_sizes.iter().position(|&s| !non_negative(s)) {
        return Err(Error::BadCell {
            cell,
            reason: format!("leaf {leaf} has size {:?}, not finite and >= 0", leaf_sizes.get(leaf)),
        });
    }
    let summary = sweep(kind, Scope::Cell(cell), first, points, Some((leaf_sizes, |p: &PointRecord| p.size)))?;
    Ok(summary)
}

/// For points: the size of each leaf and the point's gate size (spec §10 rule 3).
type Gate<'a, T> = Option<(&'a [f32], fn(&T) -> f32)>;

/// What the sweep needs of one record, copied out so the sweep reads memory in order: records are
/// stored by `hi` but visited by leaf.
#[derive(Clone, Copy)]
struct Item {
    /// First leaf of the run.
    first: u32,
    /// Leaves in the run, `>= 1`.
    count: u32,
    lo: f32,
    hi: f32,
    /// The gate size of a point (rule 3); 0 for other kinds.
    size: f32,
    /// Index into the cell's records.
    index: u32,
}

impl Item {
    fn start(&self) -> u64 {
        u64::from(self.first)
    }

    /// One past the run's last leaf.
    fn end(&self) -> u64 {
        u64::from(self.first) + u64::from(self.count)
    }

    fn index(&self) -> usize {
        self.index as usize
    }
}

/// A record on the sweep's stack: its run is open at the current leaf.
struct Open {
    item: Item,
    /// Smallest and largest leaf size seen in the run so far (rule 3).
    min: f32,
    max: f32,
}

/// What a hierarchy the sweep checks belongs to: one cell's records of a per-cell kind, or a whole
/// section that is one hierarchy for the block (`FAR_LINES`, spec §6.9.1).
#[derive(Clone, Copy, Debug)]
enum Scope {
    /// Cell `index` (the block cell is the last).
    Cell(usize),
    /// The whole section.
    Section,
}

impl core::fmt::Display for Scope {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Cell(cell) => write!(f, "cell {cell}"),
            Self::Section => f.write_str("the section"),
        }
    }
}

/// The error of a hierarchy that breaks a rule of spec §10: [`Error::BadCell`] for a cell's,
/// [`Error::BadHierarchy`] for a section's.
fn spt_bad_cell(kind: SectionKind, scope: Scope, reason: String) -> Error {
    match scope {
        Scope::Cell(cell) => Error::BadCell { cell, reason: format!("{kind}: {reason}") },
        Scope::Section => Error::BadHierarchy { kind, reason },
    }
}

/// Rules 1–3 of spec §10 for one cell and kind.
///
/// Records are sorted by `(leaf_first, larger runs first)`, then swept leaf by leaf with a stack of
/// the runs open at the current leaf: a run that starts inside the top run but ends after it breaks
/// rule 1. Between two run boundaries the open runs do not change, so rule 2 is checked once per
/// such segment: the non-empty intervals chain from 0 to `+∞` exactly when, counting `+1` at each
/// `lo` and `−1` at each `hi`, every value sums to 0 except `0` (`+1`) and `+∞` (`−1`) — intervals
/// with `lo < hi` form a path of increasing values, so balanced degrees leave one path from 0 to
/// `+∞` through all of them. The balance is kept incrementally as runs open and close, which makes
/// each segment `O(1)`. For rule 3 each open run folds the min and max leaf size of its leaves.
fn sweep<T: SptElement>(
    kind: SectionKind,
    scope: Scope,
    first: usize,
    records: &[T],
    gate: Gate<'_, T>,
) -> Result<SptSummary> {
    // Each record's own fields and the order.
    let mut n = 0u64;
    let mut prev_hi = f32::INFINITY;
    if u32::try_from(records.len()).is_err() {
        return Err(spt_bad_cell(kind, scope, format!("{} records, a section holds at most 2^32-1", records.len())));
    }
    let mut items = Vec::with_capacity(records.len());
    for (index, r) in records.iter().enumerate() {
        let (lo, hi) = (r.lo(), r.hi());
        if !non_negative(lo) {
            return Err(bad(kind, first + index, format!("lo {lo} is not finite and >= 0")));
        }
        if hi.is_nan() || hi < lo {
            return Err(bad(kind, first + index, format!("hi {hi} is below lo {lo} or NaN")));
        }
        if r.leaf_count() == 0 {
            return Err(bad(kind, first + index, "leaf_count is 0".into()));
        }
        if hi > prev_hi {
            return Err(bad(
                kind,
                first + index,
                format!("hi {hi} is larger than {prev_hi} of the record before ({scope} sorts by hi, largest first)"),
            ));
        }
        prev_hi = hi;
        let (first, count) = (r.leaf_first(), r.leaf_count());
        n = n.max(u64::from(first) + u64::from(count));
        let size = gate.map_or(0.0, |(_, size_of)| size_of(r));
        #[expect(clippy::cast_possible_truncation, reason = "the record count fits u32, checked above")]
        items.push(Item { first, count, lo, hi, size, index: index as u32 });
    }
    let sizes = gate.map(|(sizes, _)| sizes);
    if let Some(sizes) = sizes {
        let t = sizes.len() as u64;
        if t == 0 && !records.is_empty() {
            return Err(spt_bad_cell(kind, scope, format!("{} records but no triangles (§10 rule 3)", records.len())));
        }
        if n != t {
            return Err(spt_bad_cell(
                kind,
                scope,
                format!("the runs cover leaves 0..{n}, the cell has {t} triangles (§10 rule 3)"),
            ));
        }
    }

    // Start order, larger runs first among equal starts, so a run comes after every run holding it.
    let items = sort_by_start(items, n);

    let mut state =
        Sweep { kind, scope, first, sizes, stack: Vec::new(), balance: Balance::default(), cur: 0, depth: 0 };
    for &item in &items {
        // Close the runs that end at or before this one's start, checking the segments on the way.
        loop {
            let stop = state.stack.last().map_or(item.start(), |top| top.item.end().min(item.start()));
            state.segment(stop)?;
            match state.stack.last() {
                Some(top) if top.item.end() <= item.start() => state.pop()?,
                _ => break,
            }
        }
        if let Some(top) = state.stack.last()
            && item.end() > top.item.end()
        {
            return Err(spt_bad_cell(
                kind,
                scope,
                format!(
                    "the leaf runs of records {} (leaves {}..{}) and {} (leaves {}..{}) overlap without nesting (§10 rule 1)",
                    first + top.item.index(),
                    top.item.start(),
                    top.item.end(),
                    first + item.index(),
                    item.start(),
                    item.end()
                ),
            ));
        }
        state.push(item);
    }
    while let Some(top) = state.stack.last() {
        let end = top.item.end();
        state.segment(end)?;
        state.pop()?;
    }
    Ok(SptSummary { leaves: n, max_depth: state.depth })
}

/// Sorts by `(start, end descending, index)`: by buckets of equal start when the leaves are not
/// many more than the records (the usual case: a hierarchy has about two records per leaf), else
/// by comparison.
fn sort_by_start(mut items: Vec<Item>, n: u64) -> Vec<Item> {
    let key = |it: &Item| (core::cmp::Reverse(it.count), it.index);
    let buckets = usize::try_from(n).ok().filter(|&n| n <= 4 * items.len() + 64);
    let Some(buckets) = buckets else {
        items.sort_unstable_by_key(|it| (it.first, core::cmp::Reverse(it.count), it.index));
        return items;
    };
    // `ends[s]`: one past the last slot of the records starting at leaf `s` (every start is < n).
    let mut ends = vec![0usize; buckets + 1];
    for it in &items {
        if let Some(c) = ends.get_mut(it.first as usize + 1) {
            *c += 1;
        }
    }
    for s in 1..ends.len() {
        ends[s] += ends[s - 1];
    }
    let mut next = ends.clone();
    let mut sorted = items.clone();
    for it in &items {
        if let Some(slot) = next.get_mut(it.first as usize) {
            if let Some(dst) = sorted.get_mut(*slot) {
                *dst = *it;
            }
            *slot += 1;
        }
    }
    for w in ends.windows(2) {
        if let [a, b] = *w
            && b > a + 1
            && let Some(bucket) = sorted.get_mut(a..b)
        {
            bucket.sort_unstable_by_key(key);
        }
    }
    sorted
}

/// The state of [`sweep`].
struct Sweep<'a> {
    kind: SectionKind,
    scope: Scope,
    first: usize,
    /// For points: the size of each leaf (rule 3).
    sizes: Option<&'a [f32]>,
    /// The runs open at leaf `cur`, outermost first.
    stack: Vec<Open>,
    /// `+1` per `lo`, `−1` per `hi` of the open records with a non-empty interval.
    balance: Balance,
    /// The first leaf not checked yet.
    cur: u64,
    /// Deepest stack seen.
    depth: usize,
}

impl Sweep<'_> {
    fn push(&mut self, item: Item) {
        if item.lo < item.hi {
            self.balance.add(item.lo, 1);
            self.balance.add(item.hi, -1);
        }
        self.stack.push(Open { item, min: f32::INFINITY, max: f32::NEG_INFINITY });
        self.depth = self.depth.max(self.stack.len());
    }

    /// Closes the top run: rule 3 over all its leaves, then its leaves' sizes go to the parent.
    fn pop(&mut self) -> Result<()> {
        let Some(open) = self.stack.pop() else {
            return Ok(());
        };
        let Item { lo, hi, size, .. } = open.item;
        let (start, end, index) = (open.item.start(), open.item.end(), open.item.index());
        if lo < hi {
            self.balance.add(lo, -1);
            self.balance.add(hi, 1);
            if let Some(sizes) = self.sizes {
                // For every leaf: size = size(ℓ), or size <= lo and size(ℓ) <= lo.
                let ok = if size <= lo { open.max <= lo } else { open.min == size && open.max == size };
                if !ok {
                    let leaf_size =
                        |l: u64| usize::try_from(l).ok().and_then(|l| sizes.get(l)).copied().unwrap_or(f32::NAN);
                    let leaf = (start..end)
                        .find(|&l| {
                            let s = leaf_size(l);
                            !(s == size || (size <= lo && s <= lo))
                        })
                        .unwrap_or(start);
                    return Err(spt_bad_cell(
                        self.kind,
                        self.scope,
                        format!(
                            "record {} (leaves {start}..{end}, size {size}, interval [{lo}, {hi})): leaf {leaf} has triangle size \
                             {}; the sizes must be equal or both <= lo (§10 rule 3)",
                            self.first + index,
                            leaf_size(leaf)
                        ),
                    ));
                }
            }
        }
        if let Some(parent) = self.stack.last_mut() {
            parent.min = parent.min.min(open.min);
            parent.max = parent.max.max(open.max);
        }
        Ok(())
    }

    /// Checks the leaves `cur .. stop`, which the open runs all hold, and moves `cur` to `stop`.
    fn segment(&mut self, stop: u64) -> Result<()> {
        if stop <= self.cur {
            return Ok(());
        }
        if !self.balance.is_chain() {
            return Err(self.chain_error(self.cur));
        }
        if let Some(sizes) = self.sizes
            && let Some(top) = self.stack.last_mut()
        {
            let leaves = usize::try_from(self.cur)
                .ok()
                .zip(usize::try_from(stop).ok())
                .and_then(|(a, b)| sizes.get(a..b))
                .unwrap_or_default();
            for &s in leaves {
                top.min = top.min.min(s);
                top.max = top.max.max(s);
            }
        }
        self.cur = stop;
        Ok(())
    }

    /// Describes why the open intervals at `leaf` do not chain from 0 to `+∞` (rule 2).
    fn chain_error(&self, leaf: u64) -> Error {
        let mut chain: Vec<(f32, f32, usize)> = self
            .stack
            .iter()
            .map(|o| (o.item.lo, o.item.hi, self.first + o.item.index()))
            .filter(|(lo, hi, _)| lo < hi)
            .collect();
        chain.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.2.cmp(&b.2)));
        let reason = match chain.as_slice() {
            [] => format!("leaf {leaf} is represented by no record with a non-empty interval (§10 rule 2)"),
            [(lo, hi, r), ..] if *lo != 0.0 => {
                format!("leaf {leaf}: its first interval, [{lo}, {hi}) of record {r}, does not start at 0 (§10 rule 2)")
            }
            _ => {
                let step = chain.windows(2).find_map(|w| match *w {
                    [(alo, ahi, a), (blo, bhi, b)] if ahi != blo => {
                        let what = if ahi < blo { "leave a gap" } else { "overlap" };
                        Some(format!(
                            "leaf {leaf}: the intervals [{alo}, {ahi}) of record {a} and [{blo}, {bhi}) of record {b} {what} (§10 rule 2)"
                        ))
                    }
                    _ => None,
                });
                match (step, chain.last()) {
                    (Some(step), _) => step,
                    (None, Some((lo, hi, r))) => {
                        format!(
                            "leaf {leaf}: its last interval, [{lo}, {hi}) of record {r}, does not end at +inf (§10 rule 2)"
                        )
                    }
                    (None, None) => format!("leaf {leaf}: the intervals do not chain from 0 to +inf (§10 rule 2)"),
                }
            }
        };
        spt_bad_cell(self.kind, self.scope, reason)
    }
}

/// Per interval end value (as normalised bits), `+1` per `lo` minus `1` per `hi`; zero entries are
/// removed, so it holds at most two entries per open record.
///
/// In a well-formed hierarchy a child's `hi` cancels its parent's `lo`, so only a handful of entries
/// are nonzero: they live in a small vector, and move to a hash map if a cell ever needs more.
#[derive(Default)]
struct Balance {
    small: Vec<(u32, i64)>,
    map: Option<HashMap<u32, i64, BuildHasherDefault<MixHasher>>>,
}

impl Balance {
    /// Entries kept in the vector before switching to the map.
    const SMALL: usize = 16;

    /// `-0.0` and `0.0` are the same threshold.
    fn key(v: f32) -> u32 {
        (v + 0.0).to_bits()
    }

    fn add(&mut self, v: f32, delta: i64) {
        let key = Self::key(v);
        if let Some(map) = &mut self.map {
            let entry = map.entry(key).or_insert(0);
            *entry += delta;
            if *entry == 0 {
                map.remove(&key);
            }
            return;
        }
        match self.small.iter().position(|&(k, _)| k == key) {
            Some(i) => {
                if let Some(entry) = self.small.get_mut(i) {
                    entry.1 += delta;
                    if entry.1 == 0 {
                        self.small.swap_remove(i);
                    }
                }
            }
            None if self.small.len() < Self::SMALL => self.small.push((key, delta)),
            None => {
                let mut map: HashMap<_, _, _> = self.small.drain(..).collect();
                map.insert(key, delta);
                self.map = Some(map);
            }
        }
    }

    fn get(&self, v: f32) -> i64 {
        let key = Self::key(v);
        match &self.map {
            Some(map) => map.get(&key).copied().unwrap_or(0),
            None => self.small.iter().find(|&&(k, _)| k == key).map_or(0, |&(_, d)| d),
        }
    }

    /// Whether the intervals counted form one chain from 0 to `+∞`.
    fn is_chain(&self) -> bool {
        let len = self.map.as_ref().map_or(self.small.len(), HashMap::len);
        len == 2 && self.get(0.0) == 1 && self.get(f32::INFINITY) == -1
    }
}

/// A fast hasher for `u32` keys (the `splitmix64` finaliser); [`Balance`] holds few keys.
#[derive(Default)]
struct MixHasher(u64);

impl Hasher for MixHasher {
    fn finish(&self) -> u64 {
        crate::SplitMix64(self.0).next_u64()
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 << 8) | u64::from(b);
        }
    }

    fn write_u32(&mut self, v: u32) {
        self.0 = u64::from(v);
    }
}
