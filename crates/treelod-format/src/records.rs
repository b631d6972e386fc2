//! On-disk record types, one `#[repr(C)]` struct per table of `format-spec/treelod.md` §6.
//!
//! Every record is `Pod`, 4-byte aligned and free of implicit padding, so an array of them can be
//! viewed in place from a memory map. A size assertion sits beside each struct.

use crate::pack::unorm16x2_steps;
use bytemuck::{Pod, Zeroable};

/// The twelve magic bytes that open every file (spec §3): `\x89 TREELOD \r \n \x1A \n`.
pub const MAGIC: [u8; 12] = *b"\x89TREELOD\r\n\x1a\n";
/// Major version written and read by this crate (spec §11).
pub const MAJOR: u16 = 1;
/// The latest minor version this crate knows. The writer marks each file with the smallest minor
/// whose section kinds it holds ([`SectionKind::since_minor`]), so a file without 1.1's kinds is
/// a 1.0 file.
pub const MINOR: u16 = 18;
/// Size of the fixed header in bytes (spec §3).
pub const HEADER_SIZE: usize = 64;
/// Size of one section-table entry in bytes (spec §4).
pub const SECTION_ENTRY_SIZE: usize = 48;
/// Every section payload starts on a multiple of this (spec §1).
pub const SECTION_ALIGN: u64 = 16;
/// Section flag bit 0: the payload is one zstd frame (spec §4, §8).
pub const FLAG_ZSTD: u32 = 1;
/// Section flag bit 1: the zstd frame holds the records byte-transposed (spec §8). Only with
/// [`FLAG_ZSTD`] and a record size above 1.
pub const FLAG_SHUFFLE: u32 = 2;
/// The `image` value of a material without texture (spec §6.6).
pub const NO_IMAGE: u32 = u32::MAX;

/// A run of records `first .. first + count` in one array (spec §2).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Pod, Zeroable)]
pub struct Range {
    /// Index of the first record.
    pub first: u32,
    /// Number of records.
    pub count: u32,
}
const _: () = assert!(size_of::<Range>() == 8);

impl Range {
    /// The records as a `usize` range, for slicing.
    ///
    /// Computed in `u64` first, so it cannot overflow on any target with 64-bit `usize`.
    #[must_use]
    pub fn as_usize(self) -> core::ops::Range<usize> {
        let first = self.first as usize;
        first..first + self.count as usize
    }

    /// One past the last record, or `None` if that overflows `u32`.
    #[must_use]
    pub fn end(self) -> Option<u32> {
        self.first.checked_add(self.count)
    }
}

/// The fixed 64-byte header at offset 0 (spec §3).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct Header {
    /// [`MAGIC`].
    pub magic: [u8; 12],
    /// Major version, [`MAJOR`].
    pub major: u16,
    /// Minor version.
    pub minor: u16,
    /// Bytes in the header, 64 in 1.0.
    pub header_size: u32,
    /// Entries in the section table.
    pub section_count: u32,
    /// Byte offset of the section table.
    pub table_offset: u64,
    /// Total file length in bytes.
    pub file_size: u64,
    /// Reserved, 0.
    pub flags: u32,
    /// Reserved, 0.
    pub reserved: [u8; 16],
    /// CRC-32 of the header (this field as zero) followed by the section table.
    pub header_checksum: u32,
}
const _: () = assert!(size_of::<Header>() == HEADER_SIZE);

/// One entry of the section table (spec §4).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct SectionEntry {
    /// Section kind, see [`SectionKind`].
    pub kind: u32,
    /// Bit 0: zstd ([`FLAG_ZSTD`]); bit 1: byte shuffle ([`FLAG_SHUFFLE`]); others reserved.
    pub flags: u32,
    /// Byte offset of the stored payload, multiple of 16.
    pub offset: u64,
    /// Stored payload length in bytes.
    pub length: u64,
    /// Payload length after decoding.
    pub raw_length: u64,
    /// Bytes per record; 1 for byte sections.
    pub record_size: u32,
    /// CRC-32 of the stored bytes.
    pub checksum: u32,
    /// Reserved, 0.
    pub reserved: u64,
}
const _: () = assert!(size_of::<SectionEntry>() == SECTION_ENTRY_SIZE);

/// A section kind (spec §5). Unknown values are kept as raw numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SectionKind(pub u32);

impl SectionKind {
    /// Postcard metadata (§7.1).
    pub const META: Self = Self(0x0001);
    /// One [`BlockRecord`].
    pub const BLOCK: Self = Self(0x0002);
    /// [`CellRecord`]s, one per grid cell plus the block cell.
    pub const CELLS: Self = Self(0x0003);
    /// [`VertexRecord`]s.
    pub const VERTICES: Self = Self(0x0010);
    /// [`TriangleRecord`]s, size-sorted per cell.
    pub const TRIANGLES: Self = Self(0x0011);
    /// [`PointRecord`]s in SPT order per cell.
    pub const POINTS: Self = Self(0x0012);
    /// [`MaterialRecord`]s.
    pub const MATERIALS: Self = Self(0x0013);
    /// [`ImageRecord`]s.
    pub const IMAGES: Self = Self(0x0014);
    /// Texel bytes of the images.
    pub const IMAGE_DATA: Self = Self(0x0015);
    /// [`EllipsoidRecord`]s in SPT order per cell.
    pub const ELLIPSOIDS: Self = Self(0x0020);
    /// [`LineRecord`]s in SPT order per cell.
    pub const LINES: Self = Self(0x0021);
    /// [`LineRecord`]s of the block's far lines: one hierarchy over the lines the grid cells
    /// draw at its switch, merged across cells, in SPT order (spec §6.9.1). Since 1.9.
    pub const FAR_LINES: Self = Self(0x0022);
    /// [`PlaneRecord`]s in SPT order per cell.
    pub const PLANES: Self = Self(0x0030);
    /// [`PlaneLeafRecord`]s of planes with indirect texturing, per `PLANES` record in order,
    /// `leaf_count` of them each (spec §6.10.1). Since 1.3.
    pub const PLANE_LEAVES: Self = Self(0x0031);
    /// [`PruneLeafRecord`]s in priority order per cell.
    pub const PRUNE_LEAVES: Self = Self(0x0040);
    /// [`TriangleRecord`]s of the pruned leaves.
    pub const PRUNE_TRIANGLES: Self = Self(0x0041);
    /// [`CurveSample`]s of `s_opt(λ)`.
    pub const PRUNE_SCALE: Self = Self(0x0042);
    /// [`CurveSample`]s of `λ(projected height)`.
    pub const PRUNE_LAMBDA: Self = Self(0x0043);
    /// Baseline: [`LodLevelRecord`]s of a discrete level-of-detail chain per tree (spec §6.12).
    pub const LOD_LEVELS: Self = Self(0x0050);
    /// Baseline: [`TriangleRecord`]s of the chain's levels.
    pub const LOD_TRIANGLES: Self = Self(0x0051);
    /// Baseline: [`BillboardRecord`]s, camera-facing and crossed billboards per tree (spec §6.13).
    pub const BILLBOARDS: Self = Self(0x0052);
    /// Baseline: [`OctahedralRecord`]s, one octahedral impostor per tree: the tree baked from
    /// views over the upper hemisphere (spec §6.13.1). Since 1.11.
    pub const OCTAHEDRAL: Self = Self(0x0053);
    /// Baseline: [`OctahedralDepthRecord`]s, each octahedral view's depth plane: for each
    /// `OCTAHEDRAL` record in order, `frames²` records, view `(i, j)` at `j·frames + i` (spec
    /// §6.13.2). Since 1.13.
    pub const OCTAHEDRAL_DEPTH: Self = Self(0x0054);
    /// Baseline: [`OctahedralNormalRecord`]s, where each `OCTAHEDRAL` record's views' normals
    /// lie in its image, one per record in order (spec §6.13.3). Since 1.15.
    pub const OCTAHEDRAL_NORMALS: Self = Self(0x0055);
    /// Baseline: [`OctahedralNormalGridRecord`]s, where each `OCTAHEDRAL` record's views'
    /// normals lie in its image and at what size, one per record in order (spec §6.13.3). Since
    /// 1.16; a file holds it or `OCTAHEDRAL_NORMALS`, not both.
    pub const OCTAHEDRAL_NORMAL_GRIDS: Self = Self(0x0056);
    /// Ambient occlusion of each `VERTICES` record, one `unorm8` (spec §6.14). Since 1.2.
    pub const VERTEX_AO: Self = Self(0x0060);
    /// Ambient occlusion of each `POINTS` record, one `unorm8` (spec §6.14). Since 1.2.
    pub const POINT_AO: Self = Self(0x0061);
    /// Ambient occlusion of each `PLANES` record, one `unorm8` (spec §6.14). Since 1.2.
    pub const PLANE_AO: Self = Self(0x0062);
    /// Ambient occlusion of each `ELLIPSOIDS` record, one `unorm8` (spec §6.14). Since 1.3.
    pub const ELLIPSOID_AO: Self = Self(0x0063);
    /// Ambient occlusion of each `LINES` record, one `unorm8` (spec §6.14). Since 1.4.
    pub const LINE_AO: Self = Self(0x0064);
    /// Ambient occlusion of each `FAR_LINES` record, one `unorm8` (spec §6.14). Since 1.9.
    pub const FAR_LINE_AO: Self = Self(0x0065);
    /// [`PlaneDiffuseRecord`]s: how the leaves of each `PLANES` record take the sun (spec
    /// §6.10.2). Since 1.10.
    pub const PLANE_DIFFUSE: Self = Self(0x0066);
    /// How flat the surface of each `POINTS` record is, one `unorm8`: the share of its coverage
    /// that faces along its normal (spec §6.5.1). Since 1.14.
    pub const POINT_FACING: Self = Self(0x0067);
    /// [`CalibrationRecord`]s: each representation's measured image error and cost by projected
    /// height (spec §6.15). Since 1.5.
    pub const CALIBRATION: Self = Self(0x0070);
    /// [`ChainCalibrationRecord`]s: each level of the baseline LoD chain's measured image error
    /// and cost by projected height (spec §6.17). Since 1.8.
    pub const CHAIN_CALIBRATION: Self = Self(0x0071);
    /// [`ElevationCalibrationRecord`]s: the calibration of `CALIBRATION` per elevation of the
    /// views (spec §6.16). Since 1.7.
    pub const CALIBRATION_ELEVATIONS: Self = Self(0x0072);
    /// [`CalibrationRecord`]s of the techniques added after 1.11 (codes
    /// [`calibration_technique::FIRST_ADDED`] and up), which `CALIBRATION` does not hold: the same
    /// tables as `CALIBRATION`'s (spec §6.18). Since 1.12.
    pub const CALIBRATION_ADDED: Self = Self(0x0073);
    /// [`ElevationCalibrationRecord`]s of the techniques added after 1.11: the calibration of
    /// `CALIBRATION_ADDED` per elevation of the views, as `CALIBRATION_ELEVATIONS` is
    /// `CALIBRATION`'s (spec §6.18). Since 1.12.
    pub const CALIBRATION_ELEVATIONS_ADDED: Self = Self(0x0074);
    /// [`FlipCalibrationRecord`]s: each representation's mean LDR-FLIP error by projected
    /// height, over every view and per elevation of the views, of the same drawings as
    /// `CALIBRATION`'s and `CALIBRATION_ELEVATIONS`' (and their added sections') (spec §6.19).
    /// Since 1.17.
    pub const CALIBRATION_FLIP: Self = Self(0x0075);
    /// [`ChainFlipCalibrationRecord`]s: each level of the baseline LoD chain's mean LDR-FLIP
    /// error by projected height over every view, of the same drawings as `CHAIN_CALIBRATION`'s
    /// (spec §6.20). Since 1.18.
    pub const CHAIN_CALIBRATION_FLIP: Self = Self(0x0076);

    /// Every kind this version knows, in ascending order.
    pub const KNOWN: [Self; 40] = [
        Self::META,
        Self::BLOCK,
        Self::CELLS,
        Self::VERTICES,
        Self::TRIANGLES,
        Self::POINTS,
        Self::MATERIALS,
        Self::IMAGES,
        Self::IMAGE_DATA,
        Self::ELLIPSOIDS,
        Self::LINES,
        Self::FAR_LINES,
        Self::PLANES,
        Self::PLANE_LEAVES,
        Self::PRUNE_LEAVES,
        Self::PRUNE_TRIANGLES,
        Self::PRUNE_SCALE,
        Self::PRUNE_LAMBDA,
        Self::LOD_LEVELS,
        Self::LOD_TRIANGLES,
        Self::BILLBOARDS,
        Self::OCTAHEDRAL,
        Self::OCTAHEDRAL_DEPTH,
        Self::OCTAHEDRAL_NORMALS,
        Self::OCTAHEDRAL_NORMAL_GRIDS,
        Self::VERTEX_AO,
        Self::POINT_AO,
        Self::PLANE_AO,
        Self::ELLIPSOID_AO,
        Self::LINE_AO,
        Self::FAR_LINE_AO,
        Self::PLANE_DIFFUSE,
        Self::POINT_FACING,
        Self::CALIBRATION,
        Self::CHAIN_CALIBRATION,
        Self::CALIBRATION_ELEVATIONS,
        Self::CALIBRATION_ADDED,
        Self::CALIBRATION_ELEVATIONS_ADDED,
        Self::CALIBRATION_FLIP,
        Self::CHAIN_CALIBRATION_FLIP,
    ];

    /// The spec's name of a known kind.
    #[must_use]
    pub fn name(self) -> Option<&'static str> {
        Some(match self {
            Self::META => "META",
            Self::BLOCK => "BLOCK",
            Self::CELLS => "CELLS",
            Self::VERTICES => "VERTICES",
            Self::TRIANGLES => "TRIANGLES",
            Self::POINTS => "POINTS",
            Self::MATERIALS => "MATERIALS",
            Self::IMAGES => "IMAGES",
            Self::IMAGE_DATA => "IMAGE_DATA",
            Self::ELLIPSOIDS => "ELLIPSOIDS",
            Self::LINES => "LINES",
            Self::FAR_LINES => "FAR_LINES",
            Self::PLANES => "PLANES",
            Self::PLANE_LEAVES => "PLANE_LEAVES",
            Self::PRUNE_LEAVES => "PRUNE_LEAVES",
            Self::PRUNE_TRIANGLES => "PRUNE_TRIANGLES",
            Self::PRUNE_SCALE => "PRUNE_SCALE",
            Self::PRUNE_LAMBDA => "PRUNE_LAMBDA",
            Self::LOD_LEVELS => "LOD_LEVELS",
            Self::LOD_TRIANGLES => "LOD_TRIANGLES",
            Self::BILLBOARDS => "BILLBOARDS",
            Self::OCTAHEDRAL => "OCTAHEDRAL",
            Self::OCTAHEDRAL_DEPTH => "OCTAHEDRAL_DEPTH",
            Self::OCTAHEDRAL_NORMALS => "OCTAHEDRAL_NORMALS",
            Self::OCTAHEDRAL_NORMAL_GRIDS => "OCTAHEDRAL_NORMAL_GRIDS",
            Self::CALIBRATION_FLIP => "CALIBRATION_FLIP",
            Self::CHAIN_CALIBRATION_FLIP => "CHAIN_CALIBRATION_FLIP",
            Self::VERTEX_AO => "VERTEX_AO",
            Self::POINT_AO => "POINT_AO",
            Self::PLANE_AO => "PLANE_AO",
            Self::ELLIPSOID_AO => "ELLIPSOID_AO",
            Self::LINE_AO => "LINE_AO",
            Self::FAR_LINE_AO => "FAR_LINE_AO",
            Self::PLANE_DIFFUSE => "PLANE_DIFFUSE",
            Self::POINT_FACING => "POINT_FACING",
            Self::CALIBRATION => "CALIBRATION",
            Self::CHAIN_CALIBRATION => "CHAIN_CALIBRATION",
            Self::CALIBRATION_ELEVATIONS => "CALIBRATION_ELEVATIONS",
            Self::CALIBRATION_ADDED => "CALIBRATION_ADDED",
            Self::CALIBRATION_ELEVATIONS_ADDED => "CALIBRATION_ELEVATIONS_ADDED",
            _ => return None,
        })
    }

    /// Bytes per record of a known kind (1 for byte sections), `None` for unknown kinds.
    #[must_use]
    pub fn record_size(self) -> Option<u32> {
        let size = match self {
            Self::META
            | Self::IMAGE_DATA
            | Self::VERTEX_AO
            | Self::POINT_AO
            | Self::PLANE_AO
            | Self::ELLIPSOID_AO
            | Self::LINE_AO
            | Self::FAR_LINE_AO
            | Self::POINT_FACING => 1,
            Self::BLOCK => size_of::<BlockRecord>(),
            Self::CELLS => size_of::<CellRecord>(),
            Self::VERTICES => size_of::<VertexRecord>(),
            Self::TRIANGLES | Self::PRUNE_TRIANGLES | Self::LOD_TRIANGLES => size_of::<TriangleRecord>(),
            Self::POINTS => size_of::<PointRecord>(),
            Self::MATERIALS => size_of::<MaterialRecord>(),
            Self::IMAGES => size_of::<ImageRecord>(),
            Self::ELLIPSOIDS => size_of::<EllipsoidRecord>(),
            Self::LINES | Self::FAR_LINES => size_of::<LineRecord>(),
            Self::PLANES => size_of::<PlaneRecord>(),
            Self::PLANE_LEAVES => size_of::<PlaneLeafRecord>(),
            Self::PLANE_DIFFUSE => size_of::<PlaneDiffuseRecord>(),
            Self::PRUNE_LEAVES => size_of::<PruneLeafRecord>(),
            Self::PRUNE_SCALE | Self::PRUNE_LAMBDA => size_of::<CurveSample>(),
            Self::LOD_LEVELS => size_of::<LodLevelRecord>(),
            Self::BILLBOARDS => size_of::<BillboardRecord>(),
            Self::OCTAHEDRAL => size_of::<OctahedralRecord>(),
            Self::OCTAHEDRAL_DEPTH => size_of::<OctahedralDepthRecord>(),
            Self::OCTAHEDRAL_NORMALS => size_of::<OctahedralNormalRecord>(),
            Self::OCTAHEDRAL_NORMAL_GRIDS => size_of::<OctahedralNormalGridRecord>(),
            Self::CALIBRATION_FLIP => size_of::<FlipCalibrationRecord>(),
            Self::CHAIN_CALIBRATION_FLIP => size_of::<ChainFlipCalibrationRecord>(),
            Self::CALIBRATION | Self::CALIBRATION_ADDED => size_of::<CalibrationRecord>(),
            Self::CHAIN_CALIBRATION => size_of::<ChainCalibrationRecord>(),
            Self::CALIBRATION_ELEVATIONS | Self::CALIBRATION_ELEVATIONS_ADDED => {
                size_of::<ElevationCalibrationRecord>()
            }
            _ => return None,
        };
        #[expect(clippy::cast_possible_truncation, reason = "record sizes are below 100")]
        Some(size as u32)
    }

    /// The minor version of major 1 that introduced this kind (spec §5): 1 for the baselines
    /// (`LOD_LEVELS`, `LOD_TRIANGLES`, `BILLBOARDS`), 2 for ambient occlusion (`VERTEX_AO`,
    /// `POINT_AO`, `PLANE_AO`), 3 for indirect texturing (`PLANE_LEAVES`) and the ellipsoids'
    /// ambient occlusion (`ELLIPSOID_AO`), 4 for the lines' ambient occlusion (`LINE_AO`), 5 for
    /// the calibration tables (`CALIBRATION`), 7 for the tables per elevation
    /// (`CALIBRATION_ELEVATIONS`), 8 for the LoD chain's per-level tables (`CHAIN_CALIBRATION`), 9
    /// for the block's far lines (`FAR_LINES`, `FAR_LINE_AO`), 10 for the planes' diffuse response
    /// (`PLANE_DIFFUSE`), 11 for the octahedral impostors (`OCTAHEDRAL`), 12 for the calibration
    /// of the techniques added after 1.11 (`CALIBRATION_ADDED`, `CALIBRATION_ELEVATIONS_ADDED`), 13
    /// for the octahedral views' depth planes (`OCTAHEDRAL_DEPTH`), 14 for the points' facing
    /// (`POINT_FACING`), 15 for the octahedral views' normals (`OCTAHEDRAL_NORMALS`), 16 for
    /// their grids of any size (`OCTAHEDRAL_NORMAL_GRIDS`), 17 for the calibration's FLIP error
    /// (`CALIBRATION_FLIP`), 18 for the LoD chain levels' FLIP error (`CHAIN_CALIBRATION_FLIP`), 0
    /// for the other known kinds and for kinds this version does not
    /// know (private extensions do not raise a file's minor).
    #[must_use]
    pub fn since_minor(self) -> u16 {
        match self {
            Self::LOD_LEVELS | Self::LOD_TRIANGLES | Self::BILLBOARDS => 1,
            Self::VERTEX_AO | Self::POINT_AO | Self::PLANE_AO => 2,
            Self::PLANE_LEAVES | Self::ELLIPSOID_AO => 3,
            Self::LINE_AO => 4,
            Self::CALIBRATION => 5,
            Self::CALIBRATION_ELEVATIONS => 7,
            Self::CHAIN_CALIBRATION => 8,
            Self::FAR_LINES | Self::FAR_LINE_AO => 9,
            Self::PLANE_DIFFUSE => 10,
            Self::OCTAHEDRAL => 11,
            Self::CALIBRATION_ADDED | Self::CALIBRATION_ELEVATIONS_ADDED => 12,
            Self::OCTAHEDRAL_DEPTH => 13,
            Self::POINT_FACING => 14,
            Self::OCTAHEDRAL_NORMALS => 15,
            Self::OCTAHEDRAL_NORMAL_GRIDS => 16,
            Self::CALIBRATION_FLIP => 17,
            Self::CHAIN_CALIBRATION_FLIP => 18,
            _ => 0,
        }
    }

    /// Whether the writer may compress this kind (spec §8: never `BLOCK` or `CELLS`).
    #[must_use]
    pub fn compressible(self) -> bool {
        !matches!(self, Self::BLOCK | Self::CELLS)
    }
}

/// The ambient-occlusion kinds and the array each one parallels (spec §6.14).
pub const AO_KINDS: [(SectionKind, SectionKind); 6] = [
    (SectionKind::VERTEX_AO, SectionKind::VERTICES),
    (SectionKind::POINT_AO, SectionKind::POINTS),
    (SectionKind::PLANE_AO, SectionKind::PLANES),
    (SectionKind::ELLIPSOID_AO, SectionKind::ELLIPSOIDS),
    (SectionKind::LINE_AO, SectionKind::LINES),
    (SectionKind::FAR_LINE_AO, SectionKind::FAR_LINES),
];

/// Decodes a stored ambient-occlusion byte (spec §6.14) to the share of ambient light that is
/// blocked, in `[0, 1]`.
#[must_use]
pub fn decode_ao(stored: u8) -> f32 {
    f32::from(stored) / 255.0
}

/// Encodes a share of ambient light blocked (clamped to `[0, 1]`, NaN as 0) as stored (spec
/// §6.14): rounded to the nearest of 256 steps.
#[must_use]
pub fn encode_ao(occlusion: f32) -> u8 {
    // `as` saturates and maps NaN to 0.
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 0..=255")]
    let stored = (occlusion.clamp(0.0, 1.0) * 255.0).round() as u8;
    stored
}

/// Encodes the share `f` of a point's coverage that faces along its normal (clamped to `[0, 1]`,
/// NaN as 0) as `POINT_FACING` stores it (spec §6.5.1): rounded to the nearest of 256 steps.
#[must_use]
pub fn encode_point_facing(f: f32) -> u8 {
    encode_ao(f)
}

/// The factor on the area of a point's disc seen along a direction at cosine `cos` to its normal
/// (spec §6.5.1; its radius takes the square root): `1 − f + 2f·|cos|` for the stored facing
/// byte `stored` (`f = stored/255`), whose mean over directions is 1; 1 for `f = 0` (no
/// `POINT_FACING`: the disc has its mean area from every direction).
#[must_use]
pub fn point_facing_scale(stored: u8, cos: f32) -> f32 {
    let f = f32::from(stored) / 255.0;
    1.0 - f + 2.0 * f * cos.abs().min(1.0)
}

impl core::fmt::Display for SectionKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.name() {
            Some(name) => f.write_str(name),
            None => write!(f, "0x{:04X}", self.0),
        }
    }
}

/// The block: bounds and grid (spec §6.1). Exactly one per file.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BlockRecord {
    /// Block bounds, metres, block space.
    pub bounds_min: [f32; 3],
    /// Upper corner, `≥ bounds_min` per axis.
    pub bounds_max: [f32; 3],
    /// Cells along x, y, z: each `1 ..= 256`, product `≤ 65536`.
    pub grid: [u32; 3],
    /// Number of source trees in the block, `≥ 1`.
    pub tree_count: u32,
    /// Reserved, 0.
    pub flags: u32,
    /// Padding, 0.
    pub _pad: u32,
}
const _: () = assert!(size_of::<BlockRecord>() == 48);

impl BlockRecord {
    /// Number of grid cells (not counting the block cell).
    #[must_use]
    pub fn grid_cell_count(&self) -> usize {
        self.grid.iter().map(|&n| n as usize).product()
    }

    /// Index of grid cell `(x, y, z)`: `x + gx·(y + gy·z)` (spec §6.1).
    #[must_use]
    pub fn cell_index(&self, x: u32, y: u32, z: u32) -> usize {
        x as usize + self.grid[0] as usize * (y as usize + self.grid[1] as usize * z as usize)
    }

    /// The grid coordinates of cell `index` (inverse of [`Self::cell_index`]).
    #[must_use]
    pub fn cell_coords(&self, index: usize) -> [u32; 3] {
        let gx = self.grid[0] as usize;
        let gy = self.grid[1] as usize;
        #[expect(clippy::cast_possible_truncation, reason = "grid axes are at most 256")]
        [(index % gx) as u32, ((index / gx) % gy) as u32, (index / (gx * gy)) as u32]
    }
}

/// One grid cell, or the block cell that follows them (spec §6.2).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CellRecord {
    /// Tight bounds of the cell's content, metres; zero for an empty cell.
    pub bounds_min: [f32; 3],
    /// Upper corner.
    pub bounds_max: [f32; 3],
    /// Into `TRIANGLES`.
    pub triangles: Range,
    /// Into `POINTS`.
    pub points: Range,
    /// Into `ELLIPSOIDS`.
    pub ellipsoids: Range,
    /// Into `LINES`.
    pub lines: Range,
    /// Into `PLANES`.
    pub planes: Range,
    /// Into `PRUNE_LEAVES`.
    pub prune_leaves: Range,
    /// Reserved, 0.
    pub flags: u32,
    /// Padding, 0.
    pub _pad: u32,
}
const _: () = assert!(size_of::<CellRecord>() == 80);

impl CellRecord {
    /// Whether the cell holds no record of any kind.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.ranges().iter().all(|(_, r)| r.count == 0)
    }

    /// The cell's range for every per-cell kind, in spec order.
    #[must_use]
    pub fn ranges(&self) -> [(SectionKind, Range); 6] {
        [
            (SectionKind::TRIANGLES, self.triangles),
            (SectionKind::POINTS, self.points),
            (SectionKind::ELLIPSOIDS, self.ellipsoids),
            (SectionKind::LINES, self.lines),
            (SectionKind::PLANES, self.planes),
            (SectionKind::PRUNE_LEAVES, self.prune_leaves),
        ]
    }
}

/// A vertex of a triangle (spec §6.3).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct VertexRecord {
    /// Metres, block space.
    pub position: [f32; 3],
    /// Octahedral normal, see [`crate::pack::oct_encode`].
    pub normal: u32,
    /// Texture coordinates (glTF convention).
    pub uv: [f32; 2],
    /// RGBA8 vertex colour, `0xFFFF_FFFF` when the source has none.
    pub color: u32,
}
const _: () = assert!(size_of::<VertexRecord>() == 28);

/// A triangle of the Gilet hierarchy or of a pruned leaf (spec §6.4).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TriangleRecord {
    /// Indices into `VERTICES`, counter-clockwise front face.
    pub indices: [u32; 3],
    /// Diameter of the disc of equal area, metres; the sort key (largest first).
    pub size: f32,
    /// Leaf id in the cell's point hierarchy (in `PRUNE_TRIANGLES`: the pruned leaf's index).
    pub leaf: u32,
    /// Index into `MATERIALS`.
    pub material: u32,
}
const _: () = assert!(size_of::<TriangleRecord>() == 24);

/// A point of the Gilet hierarchy, with its SPT interval (spec §6.5).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PointRecord {
    /// Disc centre, metres.
    pub position: [f32; 3],
    /// Disc radius to draw, metres.
    pub radius: f32,
    /// Octahedral normal.
    pub normal: u32,
    /// RGBA8 colour; alpha is the opaque fraction of the represented area.
    pub color: u32,
    /// Selection size gated against `τ_t`, metres.
    pub size: f32,
    /// Lower end of the threshold interval, metres.
    pub lo: f32,
    /// Upper end of the threshold interval (`+∞` for a root); the sort key (largest first).
    pub hi: f32,
    /// First leaf (triangle leaf id) represented.
    pub leaf_first: u32,
    /// Number of leaves represented, `≥ 1`.
    pub leaf_count: u32,
    /// Reserved, 0.
    pub flags: u32,
}
const _: () = assert!(size_of::<PointRecord>() == 48);

/// A material of triangles (spec §6.6).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MaterialRecord {
    /// Linear RGBA factor.
    pub base_color: [f32; 4],
    /// Index into `IMAGES`, [`NO_IMAGE`] for none.
    pub image: u32,
    /// 0 opaque, 1 mask, 2 blend.
    pub alpha_mode: u32,
    /// Alpha-test threshold for mask, `[0, 1]`.
    pub alpha_cutoff: f32,
    /// 0 bark, 1 leaf, 2 other.
    pub class: u32,
    /// Bit 0: double-sided.
    pub flags: u32,
    /// Padding, 0.
    pub _pad: u32,
}
const _: () = assert!(size_of::<MaterialRecord>() == 40);

/// Material class values (spec §6.6).
pub mod material_class {
    /// Branches and trunk.
    pub const BARK: u32 = 0;
    /// Leaves, needles, foliage.
    pub const LEAF: u32 = 1;
    /// Anything else.
    pub const OTHER: u32 = 2;
}

/// Material flag bit 0: draw both faces.
pub const MATERIAL_DOUBLE_SIDED: u32 = 1;

/// The largest width or height of an image in a container, texels (spec §6.7).
pub const MAX_IMAGE_SIDE: u32 = 16_384;

/// An image: a texture or an impostor atlas (spec §6.7).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct ImageRecord {
    /// Texels, `1 ..= 16384`.
    pub width: u32,
    /// Texels, `1 ..= 16384`.
    pub height: u32,
    /// Mip levels, largest first.
    pub mip_count: u32,
    /// Texel encoding, see [`image_format`].
    pub format: u32,
    /// Byte offset into `IMAGE_DATA`, multiple of 16.
    pub data_offset: u64,
    /// Bytes of all mip levels.
    pub data_length: u64,
}
const _: () = assert!(size_of::<ImageRecord>() == 32);

/// Image format values (spec §6.7).
pub mod image_format {
    /// RGBA8 with sRGB colour.
    pub const RGBA8_SRGB: u32 = 1;
    /// RGBA8, linear.
    pub const RGBA8_LINEAR: u32 = 2;
    /// One PNG file, decoded on load.
    pub const PNG: u32 = 3;
    /// One JPEG file, decoded on load.
    pub const JPEG: u32 = 4;
    /// A leaf-distribution image of indirectly textured planes (spec §6.10.1): per texel two
    /// little-endian `u16` leaf slots, one mip level. Since 1.3.
    pub const LEAF_SLOTS: u32 = 5;
    /// BC7 blocks (BPTC), RGB sRGB-encoded, alpha linear: each mip level as `4 × 4`-texel blocks of
    /// 16 bytes. Since 1.6.
    pub const BC7_SRGB: u32 = 6;
    /// BC7 blocks, all channels linear. Since 1.6.
    pub const BC7_LINEAR: u32 = 7;

    /// Whether `format` is one of the BC7 formats (6, 7).
    #[must_use]
    pub const fn is_bc7(format: u32) -> bool {
        matches!(format, BC7_SRGB | BC7_LINEAR)
    }

    /// Whether `format` holds sRGB-encoded colour (1, 3, 4, 6).
    #[must_use]
    pub const fn is_srgb(format: u32) -> bool {
        matches!(format, RGBA8_SRGB | PNG | JPEG | BC7_SRGB)
    }

    /// The minor version a file holding an image of `format` is marked with at least (spec §11):
    /// 6 for BC7, 0 for the others (`LEAF_SLOTS`, of 1.3, marks its files through the kind
    /// `PLANE_LEAVES` that goes with it; the image alone does not).
    #[must_use]
    pub const fn marks_minor(format: u32) -> u16 {
        match format {
            BC7_SRGB | BC7_LINEAR => 6,
            _ => 0,
        }
    }

    /// The format's name as the spec writes it, `None` for a value this version does not define.
    #[must_use]
    pub const fn name(format: u32) -> Option<&'static str> {
        Some(match format {
            RGBA8_SRGB => "RGBA8_SRGB",
            RGBA8_LINEAR => "RGBA8_LINEAR",
            PNG => "PNG",
            JPEG => "JPEG",
            LEAF_SLOTS => "LEAF_SLOTS",
            BC7_SRGB => "BC7_SRGB",
            BC7_LINEAR => "BC7_LINEAR",
            _ => return None,
        })
    }
}

/// Bytes of one BC7 block (`4 × 4` texels, spec §6.7).
pub const BC7_BLOCK_BYTES: u64 = 16;

impl ImageRecord {
    /// The image's slice of `image_data` (the `IMAGE_DATA` section), `None` where it lies outside.
    #[must_use]
    pub fn bytes<'a>(&self, image_data: &'a [u8]) -> Option<&'a [u8]> {
        let start = usize::try_from(self.data_offset).ok()?;
        let end = start.checked_add(usize::try_from(self.data_length).ok()?)?;
        image_data.get(start..end)
    }

    /// Bytes the mip chain of formats 1 and 2 (raw texels) or 6 and 7 (BC7 blocks) needs (spec
    /// §6.7), `None` on overflow.
    #[must_use]
    pub fn expected_data_length(&self) -> Option<u64> {
        let mut total = 0u64;
        for level in 0..self.mip_count.min(32) {
            total = total.checked_add(self.level_length(level)?)?;
        }
        Some(total)
    }

    /// Texels across and down of mip `level`: `max(1, width >> level)` × `max(1, height >> level)`.
    #[must_use]
    pub fn level_size(&self, level: u32) -> (u32, u32) {
        (self.width.checked_shr(level).unwrap_or(0).max(1), self.height.checked_shr(level).unwrap_or(0).max(1))
    }

    /// Bytes of mip `level` of a raw (4 bytes a texel) or BC7 (16 bytes a block of `4 × 4`
    /// texels, a partial block at the right and bottom edges counting whole) image.
    #[must_use]
    pub fn level_length(&self, level: u32) -> Option<u64> {
        let (w, h) = self.level_size(level);
        let (w, h) = (u64::from(w), u64::from(h));
        if image_format::is_bc7(self.format) {
            w.div_ceil(4).checked_mul(h.div_ceil(4))?.checked_mul(BC7_BLOCK_BYTES)
        } else {
            w.checked_mul(h)?.checked_mul(4)
        }
    }
}

/// A leaf-cluster ellipsoid (Clasen 2011) with its SPT interval (spec §6.8).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct EllipsoidRecord {
    /// Centre, metres.
    pub center: [f32; 3],
    /// Semi-axis lengths, metres.
    pub radii: [f32; 3],
    /// Unit quaternion `(x, y, z, w)` as snorm16, local → block space.
    pub orientation: [i16; 4],
    /// RGBA8 colour.
    pub color: u32,
    /// Noise alpha-test threshold, `[0, 1]`.
    pub alpha_threshold: f32,
    /// Noise mip level.
    pub noise_mip: f32,
    /// Lower end of the threshold interval, metres.
    pub lo: f32,
    /// Upper end of the threshold interval; the sort key (largest first).
    pub hi: f32,
    /// First source leaf represented.
    pub leaf_first: u32,
    /// Number of leaves represented.
    pub leaf_count: u32,
    /// Reserved, 0.
    pub flags: u32,
}
const _: () = assert!(size_of::<EllipsoidRecord>() == 64);

/// A branch line (Clasen 2011) with its SPT interval (spec §6.9).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LineRecord {
    /// First endpoint, metres.
    pub p0: [f32; 3],
    /// Radius at `p0`, metres.
    pub r0: f32,
    /// Second endpoint, metres.
    pub p1: [f32; 3],
    /// Radius at `p1`, metres.
    pub r1: f32,
    /// RGBA8 colour.
    pub color: u32,
    /// Lower end of the threshold interval, metres.
    pub lo: f32,
    /// Upper end; the sort key (largest first).
    pub hi: f32,
    /// First source branch segment represented.
    pub leaf_first: u32,
    /// Number of segments represented.
    pub leaf_count: u32,
    /// Reserved, 0.
    pub flags: u32,
}
const _: () = assert!(size_of::<LineRecord>() == 56);

/// `τ_far` of a block's far lines (spec §6.9.1): the least positive `lo` among `far_lines`, the
/// upper end of far level 0, in metres per pixel; `+∞` when no record has a positive `lo` (no far
/// lines, or far lines that never merge). NaN values are skipped.
#[must_use]
pub fn far_threshold(far_lines: &[LineRecord]) -> f32 {
    far_lines.iter().map(|l| l.lo).filter(|&lo| lo > 0.0).fold(f32::INFINITY, f32::min)
}

/// How far below `τ_far` the far lines take over, in octaves (spec §6.9.1): half an octave, so
/// that with a level blend of up to an octave far level 0 is drawn whole there and level 1 has
/// not begun to fade in.
pub const FAR_SWITCH_OCTAVES: f32 = 0.5;

/// `τ_s`, where a runtime switches a tree from the cells' lines to the far lines (spec §6.9.1):
/// `τ_far · 2^(−1/2)` ([`far_threshold`], [`FAR_SWITCH_OCTAVES`]); `+∞` without a `τ_far`.
#[must_use]
pub fn far_switch(far_lines: &[LineRecord]) -> f32 {
    far_threshold(far_lines) * (-FAR_SWITCH_OCTAVES).exp2()
}

/// How many of `lines` are drawn at `tau` (`lo ≤ τ < hi`, spec §10): at [`far_switch`], the
/// `LINES` records that far level 0 copies (spec §6.9.1).
#[must_use]
pub fn lines_drawn_at(lines: &[LineRecord], tau: f32) -> usize {
    lines.iter().filter(|l| l.lo <= tau && tau < l.hi).count()
}

/// A leaf-cluster impostor plane (Garcia 2005) with its SPT interval (spec §6.10).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PlaneRecord {
    /// Centre, metres.
    pub center: [f32; 3],
    /// Half-extent vector along texture u, metres.
    pub axis_u: [f32; 3],
    /// Half-extent vector along texture v, metres.
    pub axis_v: [f32; 3],
    /// Index into `IMAGES`.
    pub image: u32,
    /// Atlas rectangle corner, two unorm16 (u low, v high).
    pub uv_min: u32,
    /// Opposite corner.
    pub uv_max: u32,
    /// Lower end of the threshold interval, metres.
    pub lo: f32,
    /// Upper end; the sort key (largest first).
    pub hi: f32,
    /// First source leaf represented.
    pub leaf_first: u32,
    /// Number of leaves represented.
    pub leaf_count: u32,
}
const _: () = assert!(size_of::<PlaneRecord>() == 64);

/// One leaf of an indirectly textured impostor plane (Garcia 2005 §2.3; spec §6.10.1): where the
/// plane's point `center + s·axis_u + t·axis_v` falls in the leaf's own texture, as the affine map
/// `uv = uv0 + s·du + t·dv` clipped to the leaf's texture rectangle, and what colours it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PlaneLeafRecord {
    /// Texture coordinates at the plane's centre (`s = t = 0`).
    pub uv0: [f32; 2],
    /// `∂uv/∂s`.
    pub du: [f32; 2],
    /// `∂uv/∂t`.
    pub dv: [f32; 2],
    /// The leaf's texture rectangle's corner, two `unorm16` (u bits 0–15, v bits 16–31): the
    /// leaf shows only where `uv` lies in `uv_min ..= uv_max`.
    pub uv_min: u32,
    /// The opposite corner, `≥ uv_min` per component.
    pub uv_max: u32,
    /// Index into `MATERIALS`: the leaf's material (its texture, factor and alpha test).
    pub material: u32,
    /// RGBA8 (§2): the leaf's mean vertex colour, multiplied with the material's.
    pub color: u32,
}
const _: () = assert!(size_of::<PlaneLeafRecord>() == 40);

/// How the leaves an impostor plane stands for take the sun (spec §6.10.2), as a mixture of three
/// ways their normals may lie about the plane's normal `N`: in the plane's normal (share `f`),
/// turned every way (share `s`) and across it, every way about it (share `1 − f − s`). Seen
/// along a unit direction `v` and lit from `l`, the leaves' diffuse factor is their mean `|n·l|`
/// weighted by the area each shows, `|n·v|`: [`PlaneDiffuseRecord::diffuse`]. A reader without
/// the record takes [`PlaneDiffuseRecord::FLAT`], the plane's own `|N·l|`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct PlaneDiffuseRecord {
    /// `f` as `unorm16`: the share of leaves lying in the plane.
    pub flat: u16,
    /// `s` as `unorm16`: the share of leaves turned every way (`f + s ≤ 1`; a reader clamps).
    pub scattered: u16,
}
const _: () = assert!(size_of::<PlaneDiffuseRecord>() == 4);

impl PlaneDiffuseRecord {
    /// What a reader without the record assumes: the leaves lie in the plane.
    pub const FLAT: Self = Self { flat: u16::MAX, scattered: 0 };

    /// The shares `(f, s, r)` of the three ways, `r = 1 − f − s`, each in `[0, 1]` and summing to
    /// 1 (`s` clamped to `1 − f`).
    #[must_use]
    pub fn shares(self) -> (f32, f32, f32) {
        let f = f32::from(self.flat) / 65535.0;
        let s = (f32::from(self.scattered) / 65535.0).min(1.0 - f);
        (f, s, (1.0 - f - s).max(0.0))
    }

    /// The diffuse factor of the plane of unit normal `normal` seen along unit `view` (towards the
    /// viewer; its sign does not matter) and lit from unit `light` (spec §6.10.2):
    /// `(f·|N·v||N·l| + s·S(v, l) + r·R(v, l)) / (f·|N·v| + s/2 + r·(2/π)·|v_p|)` with
    /// `S = (2/3π)(sin γ + (π/2 − γ) cos γ)`, `cos γ = |v·l|`, and
    /// `R = |v_p||l_p|(sin δ + (π/2 − δ) cos δ)/π`, `v_p`, `l_p` the parts of `v` and `l` in the
    /// plane and `cos δ = |v_p·l_p| / (|v_p||l_p|)`; the plane's own `|N·l|` where the
    /// denominator vanishes (a flat plane seen edge-on).
    #[must_use]
    pub fn diffuse(self, normal: [f32; 3], view: [f32; 3], light: [f32; 3]) -> f32 {
        use core::f32::consts::{FRAC_PI_2, PI};
        let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let (f, s, r) = self.shares();
        let (nv, nl) = (dot(normal, view), dot(normal, light));
        // The mean |cos| of two directions at angle x (cos x = c ≥ 0) over a circle of normals.
        let lobe = |c: f32| {
            let c = c.clamp(0.0, 1.0);
            let x = c.acos();
            x.sin() + (FRAC_PI_2 - x) * c
        };
        let vp = [view[0] - nv * normal[0], view[1] - nv * normal[1], view[2] - nv * normal[2]];
        let lp = [light[0] - nl * normal[0], light[1] - nl * normal[1], light[2] - nl * normal[2]];
        let (a, b) = (dot(vp, vp).max(0.0).sqrt(), dot(lp, lp).max(0.0).sqrt());
        let ring = if a * b > 1e-6 { a * b * lobe(dot(vp, lp).abs() / (a * b)) / PI } else { 0.0 };
        let num = f * nv.abs() * nl.abs() + s * 2.0 / (3.0 * PI) * lobe(dot(view, light).abs()) + r * ring;
        let den = f * nv.abs() + 0.5 * s + r * 2.0 / PI * a;
        if den > 1e-6 { (num / den).clamp(0.0, 1.0) } else { nl.abs() }
    }
}

/// Where each plane's [`PlaneLeafRecord`]s start in `PLANE_LEAVES` (spec §6.10.1): `base(p) =
/// Σ_{q < p} leaf_count(q)`, one entry per plane and then the total, the length `PLANE_LEAVES`
/// must have when it is not empty.
#[must_use]
pub fn plane_leaf_bases(planes: &[PlaneRecord]) -> Vec<u64> {
    let mut bases = Vec::with_capacity(planes.len() + 1);
    let mut sum = 0u64;
    for plane in planes {
        bases.push(sum);
        sum += u64::from(plane.leaf_count);
    }
    bases.push(sum);
    bases
}

/// The two leaf slots `(a, b)` of a `LEAF_SLOTS` texel as stored (spec §6.10.1).
#[must_use]
pub fn leaf_slots(texel: [u8; 4]) -> (u16, u16) {
    (u16::from_le_bytes([texel[0], texel[1]]), u16::from_le_bytes([texel[2], texel[3]]))
}

/// A leaf of Neubert's priority list (spec §6.11).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PruneLeafRecord {
    /// Scaling pivot, metres.
    pub center: [f32; 3],
    /// One-sided leaf area, m².
    pub area: f32,
    /// Into `PRUNE_TRIANGLES`.
    pub first_triangle: u32,
    /// Number of triangles, `≥ 1`.
    pub triangle_count: u32,
}
const _: () = assert!(size_of::<PruneLeafRecord>() == 24);

/// Leaves drawn of a priority list of `count` leaves at the fraction `lambda` (spec §6.11):
/// `ceil(λ·count)`, at least one of a non-empty list and at most `count`. The one rule of builders
/// (which measure pruned images) and renderers.
#[must_use]
pub fn prune_leaves_drawn(count: u32, lambda: f32) -> u32 {
    if count == 0 {
        return 0;
    }
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 1..=count")]
    let n = (f64::from(lambda.clamp(0.0, 1.0)) * f64::from(count)).ceil().clamp(1.0, f64::from(count)) as u32;
    n
}

/// One sample of a piecewise-linear curve (spec §6.11).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CurveSample {
    /// Abscissa, strictly increasing within a section.
    pub x: f32,
    /// Value.
    pub y: f32,
}
const _: () = assert!(size_of::<CurveSample>() == 8);

/// One sample of a representation's calibration (spec §6.15): the image error and the cost of
/// drawing the block with `technique` when the block is `height` pixels high on screen. The
/// record of `CALIBRATION` and, for the techniques added after 1.11, of `CALIBRATION_ADDED`
/// (spec §6.18).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CalibrationRecord {
    /// The representation, one of [`calibration_technique`]: below
    /// [`calibration_technique::FIRST_ADDED`] in `CALIBRATION`, from it on in `CALIBRATION_ADDED`.
    pub technique: u32,
    /// Projected height of the block's bounds, pixels; strictly increasing within a technique.
    pub height: f32,
    /// Mean multi-scale RMSE against the supersampled full mesh (of shaded colour, or of coverage
    /// in files whose metadata lacks `calibration.error`; spec §6.15), `[0, 1]`.
    pub error: f32,
    /// Primitives submitted (triangles, points, ellipsoids, lines, planes, quads; spec §6.15),
    /// `≥ 0`.
    pub primitives: f32,
}
const _: () = assert!(size_of::<CalibrationRecord>() == 16);

/// One sample of a representation's calibration seen from one elevation (spec §6.16): as a
/// [`CalibrationRecord`], measured only from the views at `elevation` degrees above the block's
/// horizontal plane. The record of `CALIBRATION_ELEVATIONS` and, for the techniques added after
/// 1.11, of `CALIBRATION_ELEVATIONS_ADDED` (spec §6.18).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ElevationCalibrationRecord {
    /// Elevation of the views above the horizontal plane, degrees, `[0, 90]`; non-decreasing
    /// over the section.
    pub elevation: f32,
    /// The representation, one of [`calibration_technique`] (below
    /// [`calibration_technique::FIRST_ADDED`] in `CALIBRATION_ELEVATIONS`, from it on in
    /// `CALIBRATION_ELEVATIONS_ADDED`); non-decreasing within an elevation.
    pub technique: u32,
    /// Projected height of the block's bounds, pixels; strictly increasing within an elevation
    /// and technique.
    pub height: f32,
    /// Mean multi-scale RMSE against the supersampled full mesh over the views at `elevation`,
    /// of shaded colour as `CALIBRATION`'s (spec §6.15), `[0, 1]`.
    pub error: f32,
    /// Primitives submitted, as `CALIBRATION`'s, `≥ 0`.
    pub primitives: f32,
}
const _: () = assert!(size_of::<ElevationCalibrationRecord>() == 20);

/// One sample of a representation's calibration as FLIP sees it (spec §6.19): the mean LDR-FLIP
/// error of the block drawn with `technique` when it is `height` pixels high on screen, over the
/// views of one elevation or over every view, measured on the same drawings as the multi-scale
/// RMSE of `CALIBRATION` and `CALIBRATION_ELEVATIONS` (spec §6.15, §6.16) and their added
/// sections' (§6.18). The record of `CALIBRATION_FLIP` (since 1.17); rows are self-describing, so
/// the section needs no other.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FlipCalibrationRecord {
    /// Elevation of the views the row is measured over, degrees above the block's horizontal
    /// plane, `[0, 90]`; or [`Self::EVERY_VIEW`] (−1) for a row over every view, as
    /// `CALIBRATION`'s rows are. Non-decreasing over the section (rows over every view first).
    pub elevation: f32,
    /// The representation, one of [`calibration_technique`] (any code, the base ones and those
    /// added in 1.12 on alike). Non-decreasing within an elevation.
    pub technique: u32,
    /// Projected height of the block's bounds, pixels; strictly increasing within an elevation
    /// and technique.
    pub height: f32,
    /// Mean LDR-FLIP error (Andersson et al. 2020, 67 pixels per degree) of the 8-bit sRGB shaded
    /// image against the supersampled full mesh's, over the row's views, `[0, 1]`.
    pub flip: f32,
}
const _: () = assert!(size_of::<FlipCalibrationRecord>() == 16);

impl FlipCalibrationRecord {
    /// The `elevation` of a row over every view of every elevation (spec §6.19), as
    /// `CALIBRATION`'s rows are measured.
    pub const EVERY_VIEW: f32 = -1.0;
}

/// The representations a [`CalibrationRecord`] names (spec §6.15, §6.18), and a
/// [`FlipCalibrationRecord`] (§6.19).
pub mod calibration_technique {
    /// Every triangle of `TRIANGLES`.
    pub const FULL: u32 = 0;
    /// Gilet's triangles and points (`TRIANGLES`, `POINTS`, §10).
    pub const SPT: u32 = 1;
    /// Pruned leaves scaled by `PRUNE_SCALE` (Neubert et al.).
    pub const PRUNE_OPT: u32 = 2;
    /// Pruned leaves scaled by `1/λ` (Cook et al.).
    pub const PRUNE_COOK: u32 = 3;
    /// Impostor planes and the bark (`PLANES`).
    pub const IMPOSTORS: u32 = 4;
    /// Ellipsoids and branch lines (`ELLIPSOIDS`, `LINES`).
    pub const ELLIPSOIDS: u32 = 5;
    /// The baseline LoD chain (`LOD_LEVELS`).
    pub const LOD_CHAIN: u32 = 6;
    /// The baseline facing billboard.
    pub const BILLBOARD: u32 = 7;
    /// The baseline crossed billboards.
    pub const CROSSED: u32 = 8;
    /// The baseline octahedral impostor (`OCTAHEDRAL`, §6.13.1); only in the added sections
    /// (`CALIBRATION_ADDED`, `CALIBRATION_ELEVATIONS_ADDED`, since 1.12).
    pub const OCTAHEDRAL: u32 = 9;
    /// The first code defined in the added sections (`CALIBRATION_ADDED`,
    /// `CALIBRATION_ELEVATIONS_ADDED`, spec §6.18), which hold the codes `FIRST_ADDED .. COUNT`;
    /// `CALIBRATION` and `CALIBRATION_ELEVATIONS` hold the codes below it, those a reader of 1.5
    /// to 1.11 defines.
    pub const FIRST_ADDED: u32 = 9;
    /// Number of defined values.
    pub const COUNT: u32 = 10;

    /// The name of a value, as the `treelod` tools spell the technique (`--technique`).
    #[must_use]
    pub fn name(code: u32) -> Option<&'static str> {
        [
            "full",
            "spt",
            "prune-opt",
            "prune-cook",
            "impostors",
            "ellipsoids",
            "lod-chain",
            "billboard",
            "crossed",
            "octahedral",
        ]
        .get(code as usize)
        .copied()
    }
}

/// One sample of a LoD chain level's calibration (spec §6.17): the image error and the cost of
/// drawing the block at chain level `level` (every tree's level of that number, as the runtime
/// switches a block's trees together) when the block is `height` pixels high on screen, measured
/// as `CALIBRATION`'s records are (spec §6.15).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ChainCalibrationRecord {
    /// The chain level, 0 the finest: the `level` of `LOD_LEVELS` records.
    pub level: u32,
    /// Projected height of the block's bounds, pixels; strictly increasing within a level.
    pub height: f32,
    /// Mean multi-scale RMSE against the supersampled full mesh, of the same image as the file's
    /// `CALIBRATION` records (shaded colour where the metadata's `calibration.error` says so;
    /// spec §6.15), `[0, 1]`.
    pub error: f32,
    /// Triangles submitted (every tree's triangles of the level), `≥ 0`.
    pub primitives: f32,
}
const _: () = assert!(size_of::<ChainCalibrationRecord>() == 16);

/// One sample of a LoD chain level's calibration as FLIP sees it (spec §6.20): the mean LDR-FLIP
/// error of the block drawn at chain level `level` when it is `height` pixels high on screen,
/// over every view, measured on the same drawings as the `CHAIN_CALIBRATION` record of that
/// level and height (spec §6.17) and as `CALIBRATION_FLIP`'s (§6.19). The record of
/// `CHAIN_CALIBRATION_FLIP` (since 1.18).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ChainFlipCalibrationRecord {
    /// The chain level, 0 the finest: the `level` of `LOD_LEVELS` records. Non-decreasing over
    /// the section.
    pub level: u32,
    /// Projected height of the block's bounds, pixels; strictly increasing within a level.
    pub height: f32,
    /// Mean LDR-FLIP error (Andersson et al. 2020, 67 pixels per degree) of the 8-bit sRGB shaded
    /// image against the supersampled full mesh's, over every view, `[0, 1]`.
    pub flip: f32,
}
const _: () = assert!(size_of::<ChainFlipCalibrationRecord>() == 12);

/// One level of a tree's baseline level-of-detail chain (spec §6.12): a general mesh
/// simplifier's output, drawn instead of the whole tree when its error projects small enough.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LodLevelRecord {
    /// The tree of the block (index into the metadata's trees).
    pub tree: u32,
    /// Position in the tree's chain, 0 the finest.
    pub level: u32,
    /// Into `LOD_TRIANGLES`.
    pub triangles: Range,
    /// Geometric error of the level against the source, metres: the simplifier's deviation bound.
    pub error: f32,
    /// Share of the tree's source triangles the level aimed at (e.g. 0.25).
    pub fraction: f32,
}
const _: () = assert!(size_of::<LodLevelRecord>() == 24);

/// Baseline billboard kinds (spec §6.13).
pub mod billboard_kind {
    /// One quad turned about its `axis_v` towards the camera.
    pub const FACING: u32 = 0;
    /// Fixed quads crossing on the tree's vertical axis.
    pub const CROSSED: u32 = 1;
}

/// A baseline billboard quad (spec §6.13): the whole tree baked onto one textured quad.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BillboardRecord {
    /// Centre, metres.
    pub center: [f32; 3],
    /// Half-extent vector along texture u, metres.
    pub axis_u: [f32; 3],
    /// Half-extent vector along texture v, metres.
    pub axis_v: [f32; 3],
    /// Index into `IMAGES`.
    pub image: u32,
    /// Atlas rectangle corner, two unorm16 (u low, v high).
    pub uv_min: u32,
    /// Opposite corner.
    pub uv_max: u32,
    /// The tree of the block.
    pub tree: u32,
    /// [`billboard_kind`].
    pub kind: u32,
    /// Reserved, 0.
    pub reserved: [u32; 2],
}
const _: () = assert!(size_of::<BillboardRecord>() == 64);

/// A baseline octahedral impostor (spec §6.13.1): one tree baked orthographically from
/// `frames × frames` directions over the upper hemisphere (a hemi-octahedral map), each view in
/// a square cell of an atlas rectangle; drawn as one quad facing the viewer, textured from the
/// views nearest the direction it is seen from.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct OctahedralRecord {
    /// Centre of the views, metres (block space).
    pub center: [f32; 3],
    /// Half the side of each view's square, metres: a view's cell shows
    /// `center + radius·(s·right + t·up)`, `s, t ∈ [−1, 1]`.
    pub radius: f32,
    /// Index into `IMAGES`: the atlas.
    pub image: u32,
    /// Corner of the rectangle of the views' cells, two unorm16 (u low, v high).
    pub uv_min: u32,
    /// Opposite corner.
    pub uv_max: u32,
    /// Views per side of the grid, `N ≥ 2`: `N²` views.
    pub frames: u32,
    /// The tree of the block.
    pub tree: u32,
    /// Mean ambient occlusion of the surfaces the views show, `[0, 1]` (spec §6.14): the share
    /// of the ambient light the impostor loses.
    pub occlusion: f32,
    /// How the tree's surfaces take the sun as a view shows them (spec §6.13.1): the shares of a
    /// [`PlaneDiffuseRecord`] whose plane's normal is the direction of the view, lit with
    /// [`PlaneDiffuseRecord::diffuse`] of `(d, d, light)`.
    pub diffuse: PlaneDiffuseRecord,
    /// Reserved, 0.
    pub reserved: u32,
}
const _: () = assert!(size_of::<OctahedralRecord>() == 48);

impl OctahedralRecord {
    /// The fewest views per side of the grid, `frames` (spec §6.13.1).
    pub const MIN_FRAMES: u32 = 2;
    /// The most views per side of the grid, `frames` (spec §6.13.1).
    pub const MAX_FRAMES: u32 = 64;

    /// The direction, from the centre towards the viewer (unit, block space, `+Y` up), of view
    /// `(i, j)` of a grid of `frames × frames` (spec §6.13.1): the hemi-octahedral map's point
    /// `a = 2i/(N−1) − 1`, `b = 2j/(N−1) − 1`, `x = (a + b)/2`, `z = (a − b)/2`,
    /// `y = 1 − |x| − |z|`, normalised.
    #[must_use]
    pub fn view_direction(frames: u32, i: u32, j: u32) -> [f32; 3] {
        let last = frames.saturating_sub(1).max(1) as f32;
        let (a, b) = (2.0 * i as f32 / last - 1.0, 2.0 * j as f32 / last - 1.0);
        let (x, z) = (0.5 * (a + b), 0.5 * (a - b));
        let y = (1.0 - x.abs() - z.abs()).max(0.0);
        let length = (x * x + y * y + z * z).sqrt();
        [x / length, y / length, z / length]
    }

    /// A view's basis (spec §6.13.1): `right = normalize(Y × d)`, or `+X` where that vanishes
    /// (`d = +Y`), and `up = d × right`.
    #[must_use]
    pub fn view_basis(d: [f32; 3]) -> ([f32; 3], [f32; 3]) {
        // Y × d = (d.z, 0, −d.x).
        let length = d[2].hypot(d[0]);
        let right = if length > 1e-6 { [d[2] / length, 0.0, -d[0] / length] } else { [1.0, 0.0, 0.0] };
        let up =
            [d[1] * right[2] - d[2] * right[1], d[2] * right[0] - d[0] * right[2], d[0] * right[1] - d[1] * right[0]];
        (right, up)
    }

    /// The views a reader blends for a viewer in direction `d` from the centre (block space,
    /// any length; below the horizon it takes the horizon's views): the three corners of the
    /// grid triangle holding `d`'s point on the hemi-octahedral map, as `(i, j, weight)` with
    /// barycentric weights summing to 1 (informative, spec §6.13.1).
    #[must_use]
    pub fn blend(frames: u32, d: [f32; 3]) -> [(u32, u32, f32); 3] {
        let y = d[1].max(0.0);
        let sum = d[0].abs() + y + d[2].abs();
        let (x, z) = if sum > 0.0 { (d[0] / sum, d[2] / sum) } else { (0.0, 0.0) };
        let last = frames.saturating_sub(1).max(1);
        let scale = last as f32;
        // The map's point in grid units, [0, N − 1]².
        let (gx, gy) = (((x + z) + 1.0) * 0.5 * scale, ((x - z) + 1.0) * 0.5 * scale);
        let (gx, gy) = (gx.clamp(0.0, scale), gy.clamp(0.0, scale));
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to the grid")]
        let (i0, j0) = ((gx.floor() as u32).min(last - 1), (gy.floor() as u32).min(last - 1));
        let (fx, fy) = (gx - i0 as f32, gy - j0 as f32);
        if fx + fy <= 1.0 {
            [(i0, j0, 1.0 - fx - fy), (i0 + 1, j0, fx), (i0, j0 + 1, fy)]
        } else {
            [(i0 + 1, j0 + 1, fx + fy - 1.0), (i0, j0 + 1, 1.0 - fx), (i0 + 1, j0, 1.0 - fy)]
        }
    }
}

/// One octahedral view's depth plane (spec §6.13.2): the front-most surfaces the view shows lie
/// about `center + radius·(s·right + t·up + (offset + slope_s·s + slope_t·t)·d)`.
///
/// `OCTAHEDRAL_DEPTH` holds, for each [`OctahedralRecord`] in file order, `frames²` of them, view
/// `(i, j)` (column `i`, row `j` of spec §6.13.1) at `j·frames + i`; `s, t ∈ [−1, 1]` and
/// `right`, `up`, `d` are the view's ([`OctahedralRecord::view_basis`],
/// [`OctahedralRecord::view_direction`]). Every value is finite and in `[−1, 1]`. All three zero
/// (the [`Default`]) is the plane through `center` across `d`: what a reader takes for every view
/// without the section.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct OctahedralDepthRecord {
    /// Depth along `d` of the plane at the view's centre (`s = t = 0`), in units of `radius`;
    /// positive towards the viewer.
    pub offset: f32,
    /// Change of that depth per unit of `s` (along `right`), in units of `radius`.
    pub slope_s: f32,
    /// Change of that depth per unit of `t` (along `up`), in units of `radius`.
    pub slope_t: f32,
}
const _: () = assert!(size_of::<OctahedralDepthRecord>() == 12);

impl OctahedralDepthRecord {
    /// The depth along `d`, in units of `radius`, of the plane at the view's point `(s, t)`:
    /// `offset + slope_s·s + slope_t·t` (spec §6.13.2).
    #[must_use]
    pub fn depth(&self, s: f32, t: f32) -> f32 {
        self.offset + self.slope_s * s + self.slope_t * t
    }

    /// The plane's normal in block space, for the view's basis `right`, `up` and direction `d`
    /// (spec §6.13.2): `n = d − slope_s·right − slope_t·up`, not normalised. The plane is
    /// `n·(p − center) = offset·radius`.
    #[must_use]
    pub fn normal(&self, right: [f32; 3], up: [f32; 3], d: [f32; 3]) -> [f32; 3] {
        core::array::from_fn(|k| d[k] - self.slope_s * right[k] - self.slope_t * up[k])
    }
}

/// Where an octahedral impostor's views' normals lie (spec §6.13.3): a second grid of `frames²`
/// cells in the impostor's image, of the size of its colour grid, whose corner nearest `uv_min`
/// is at `uv_min` here; view `(i, j)`'s normals in the cell at the place of its colour cell.
///
/// `OCTAHEDRAL_NORMALS` is empty or holds one record per [`OctahedralRecord`], in file order. A
/// normal texel's RGB, decoded as the colour's is (sRGB), is `(n + 1)/2`: `n` the mean, over the
/// area the texel covers, of the unit shading normals of the surfaces the view shows there, each
/// turned towards the viewer (block space; shorter where they disagree); its alpha the mean ambient
/// occlusion of those surfaces (§6.14). A reader lights the texel with
/// [`OctahedralNormalRecord::sun_factor`] and scales the ambient light by one minus the alpha.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct OctahedralNormalRecord {
    /// Corner of the grid of the views' normal cells, two unorm16 (u low, v high).
    pub uv_min: u32,
}
const _: () = assert!(size_of::<OctahedralNormalRecord>() == 4);

/// Where an octahedral impostor's views' normals lie and at what size (spec §6.13.3, since
/// 1.16): a second grid of `frames²` cells in the impostor's image between `uv_min` and
/// `uv_max`, view `(i, j)`'s normals in the cell at the place of its colour cell, the point at
/// `(a, b)` of the colour grid's rectangle (`0..=1` across each side) at `(a, b)` of this one.
/// The grid may be smaller than the colour grid: a builder stores the normals at half the
/// colour's resolution, each normal texel the coverage-weighted mean of the four colour texels
/// it covers. Its texels are as [`OctahedralNormalRecord`]'s. `OCTAHEDRAL_NORMAL_GRIDS` is empty
/// or holds one record per [`OctahedralRecord`], in file order.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct OctahedralNormalGridRecord {
    /// Corner of the grid of the views' normal cells, two unorm16 (u low, v high).
    pub uv_min: u32,
    /// Opposite corner.
    pub uv_max: u32,
}
const _: () = assert!(size_of::<OctahedralNormalGridRecord>() == 8);

/// The grid of the views' normals of impostor `index` of `octahedral` (spec §6.13.3), from a
/// file's `OCTAHEDRAL_NORMAL_GRIDS` records `grids` (1.16), else from its `OCTAHEDRAL_NORMALS`
/// records `normals` (1.15, [`OctahedralNormalRecord::grid`]); `None` where it has neither or
/// there is no such impostor. What [`crate::Container::octahedral_normal_grid`] and
/// [`crate::ContainerData::octahedral_normal_grid`] read.
#[must_use]
pub fn octahedral_normal_grid(
    octahedral: &[OctahedralRecord],
    grids: &[OctahedralNormalGridRecord],
    normals: &[OctahedralNormalRecord],
    index: usize,
) -> Option<OctahedralNormalGridRecord> {
    let record = octahedral.get(index)?;
    grids.get(index).copied().or_else(|| normals.get(index).map(|n| n.grid(record)))
}

impl OctahedralNormalRecord {
    /// The far corner of the grid this record places for `octahedral`, its impostor, in unorm16
    /// steps: `uv_min` plus the colour grid's size, `uv_max − uv_min` of the impostor, per
    /// component. It may pass 65535 (verify allows one step, the rounding of both corners,
    /// §9.2).
    #[must_use]
    pub fn far_steps(&self, octahedral: &OctahedralRecord) -> [u32; 2] {
        let ([u0, v0], [u1, v1]) = (unorm16x2_steps(octahedral.uv_min), unorm16x2_steps(octahedral.uv_max));
        let [u, v] = unorm16x2_steps(self.uv_min);
        [u + u1.saturating_sub(u0), v + v1.saturating_sub(v0)]
    }

    /// The grid this record places for `octahedral`, its impostor: of the colour grid's size from
    /// `uv_min`, its far corner [`Self::far_steps`] held inside the image (at most 65535 steps).
    #[must_use]
    pub fn grid(&self, octahedral: &OctahedralRecord) -> OctahedralNormalGridRecord {
        let [u, v] = self.far_steps(octahedral).map(|s| s.min(0xFFFF));
        OctahedralNormalGridRecord { uv_min: self.uv_min, uv_max: (v << 16) | u }
    }

    /// The normal `n` a texel's decoded (linear) RGB stores: `2·rgb − 1`, of length at most 1.
    #[must_use]
    pub fn decode(rgb: [f32; 3]) -> [f32; 3] {
        rgb.map(|c| 2.0 * c - 1.0)
    }

    /// The sun's diffuse factor of a texel whose decoded normal is `n` (block space; see
    /// [`OctahedralNormalRecord::decode`]) under the unit light direction `light`, where the
    /// impostor's own mixture ([`OctahedralRecord::diffuse`] at the view) gives `mixture`:
    /// `c·|n̂·l| + (1 − c)·mixture` with `c = clamp(3|n| − 2, 0, 1)` (spec §6.13.3). Normals
    /// turned towards the viewer from every direction, each seen in proportion to the area it
    /// shows, average to a length of 2/3: a texel whose normals agree no more than that takes
    /// the mixture's response, one whose normals agree (`|n| = 1`) its own `|n̂·l|`.
    #[must_use]
    pub fn sun_factor(n: [f32; 3], light: [f32; 3], mixture: f32) -> f32 {
        let length = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let coherence = (3.0 * length - 2.0).clamp(0.0, 1.0);
        if coherence == 0.0 {
            return mixture.clamp(0.0, 1.0);
        }
        let facing = (n[0] * light[0] + n[1] * light[1] + n[2] * light[2]).abs() / length;
        (coherence * facing + (1.0 - coherence) * mixture).clamp(0.0, 1.0)
    }
}

/// Where each of `octahedral`'s records' views start in an `OCTAHEDRAL_DEPTH` section of `planes`
/// records (spec §6.13.2: `frames²` per record, in record order); `None` unless the section holds
/// exactly one plane per view of every record, where a reader draws every view on the plane
/// through the centre instead.
#[must_use]
pub fn octahedral_depth_starts(octahedral: &[OctahedralRecord], planes: usize) -> Option<Vec<usize>> {
    let mut next = 0usize;
    let starts = octahedral
        .iter()
        .map(|o| {
            let start = next;
            next = (o.frames as usize).checked_mul(o.frames as usize).and_then(|n| next.checked_add(n))?;
            Some(start)
        })
        .collect::<Option<Vec<usize>>>()?;
    (next == planes).then_some(starts)
}

/// The SPT view of a hierarchical record: interval and leaf run (spec §10).
pub trait SptElement: Pod {
    /// Lower end of the threshold interval.
    fn lo(&self) -> f32;
    /// Upper end of the threshold interval; the sort key.
    fn hi(&self) -> f32;
    /// First leaf represented.
    fn leaf_first(&self) -> u32;
    /// Number of leaves represented.
    fn leaf_count(&self) -> u32;
}

macro_rules! spt_element {
    ($($t:ty),*) => {$(
        impl SptElement for $t {
            fn lo(&self) -> f32 { self.lo }
            fn hi(&self) -> f32 { self.hi }
            fn leaf_first(&self) -> u32 { self.leaf_first }
            fn leaf_count(&self) -> u32 { self.leaf_count }
        }
    )*};
}
spt_element!(PointRecord, EllipsoidRecord, LineRecord, PlaneRecord);
