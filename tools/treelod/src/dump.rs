//! `treelod dump FILE [--json]`: print what a container holds.
//!
//! The content is gathered once into a [`Dump`] and rendered either as aligned text for humans or
//! as one JSON object (keys in declaration order). Both are deterministic: they depend only on the
//! file's bytes and on the path as it was passed.
//!
//! Only the cheap validation of `Container::open` (spec §9.1) has run, so record fields may hold
//! any value (NaN sizes, out-of-range indices, mismatched material counts): nothing here indexes
//! or computes in a way that could panic on them.

use std::path::{Path, PathBuf};

use serde::Serialize;
use treelod_format::{
    CellRecord, ChainFlipCalibrationRecord, Container, FLAG_SHUFFLE, FLAG_ZSTD, FlipCalibrationRecord, ImageRecord,
    PlaneDiffuseRecord, Section, SectionKind, Setting, Source, Tree, far_threshold, material_class,
};

use crate::report::{self, Failed};
use crate::table::{Align, Table};

/// Arguments of `treelod dump`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The container to describe.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// Print one JSON object with the same content instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `treelod dump`.
pub fn run(args: &Args) -> Result<(), Failed> {
    let container = report::open(&args.file)?;
    let dump = Dump::new(&args.file, &container);
    let text = if args.json { dump.to_json() } else { dump.to_text() };
    report::write_stdout(&text)
}

/// The measure each histogram buckets, as printed in the output.
const HISTOGRAM_NOTE: &str = "element sizes in metres, log2 buckets [2^k, 2^(k+1)); \
triangle: size; point: size; ellipsoid: 2*max(radii); line: |p1 - p0|; plane: 2*max(|axis_u|, |axis_v|)";

/// [`HISTOGRAM_NOTE`] as the text form's two header lines.
const HISTOGRAM_TEXT_HEADER: &str = "\nhistograms: log2 buckets [2^k, 2^(k+1)) of element sizes in metres\n  \
(triangle: size; point: size; ellipsoid: 2*max(radii); line: |p1 - p0|; plane: 2*max(|axis_u|, |axis_v|))\n";

/// Everything `dump` prints, in output order.
#[derive(Debug, Serialize)]
struct Dump<'a> {
    /// The path as passed on the command line.
    file: String,
    /// `major.minor` of the header.
    version: String,
    /// Bytes in the file (the header's `file_size`, equal to the file length after open).
    file_size: u64,
    /// Bytes in the header.
    header_size: u32,
    /// Offset of the section table.
    table_offset: u64,
    /// The section table in file order.
    sections: Vec<SectionInfo>,
    /// The `BLOCK` record.
    block: BlockInfo,
    /// The `META` section joined with the `MATERIALS` records.
    metadata: MetadataInfo<'a>,
    /// Per-cell record counts.
    cells: CellsInfo,
    /// The block's far lines (spec §6.9.1), when the container has any.
    #[serde(skip_serializing_if = "Option::is_none")]
    far_lines: Option<FarLinesInfo>,
    /// The pruning sections (spec §6.11), when the container has any of their records.
    #[serde(skip_serializing_if = "Option::is_none")]
    pruning: Option<PruningInfo>,
    /// The impostor planes and the images they sample (spec §6.10), when the container has planes.
    #[serde(skip_serializing_if = "Option::is_none")]
    impostors: Option<ImpostorInfo>,
    /// The baseline sections (spec §6.12, §6.13, §6.13.1, §6.13.2), when the container has any of
    /// their records.
    #[serde(skip_serializing_if = "Option::is_none")]
    baselines: Option<BaselineInfo>,
    /// The calibration (spec §6.15), its tables per elevation (§6.16), the LoD chain's per-level
    /// tables (§6.17) and the tables of the techniques added after 1.11 (§6.18), when the
    /// container has any of them.
    #[serde(skip_serializing_if = "Option::is_none")]
    calibration: Option<CalibrationInfo>,
    /// The calibration's FLIP error (`CALIBRATION_FLIP`, spec §6.19, version 1.17): one object per
    /// record, in file order; absent when the container has none (files before 1.17, or built
    /// without FLIP).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    calibration_flip: Vec<FlipSample>,
    /// The LoD chain levels' FLIP error (`CHAIN_CALIBRATION_FLIP`, spec §6.20, version 1.18): one
    /// object per record, in file order; absent when the container has none (files before 1.18,
    /// or built without FLIP or without a chain).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    chain_calibration_flip: Vec<ChainFlipSample>,
    /// What the renderer's policy draws a tree with by default, from the calibration (spec
    /// §10.2), when the container has calibration tables and verifies.
    #[serde(skip_serializing_if = "Option::is_none")]
    policy: Option<PolicyInfo>,
    /// Texture bytes per representation (spec §6.7), when the container has images.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    textures: Vec<TextureUse>,
    /// Size histograms of the hierarchical kinds.
    histograms: Histograms,
}

/// One entry of the section table.
#[derive(Debug, Serialize)]
struct SectionInfo {
    /// The raw kind value.
    kind: u32,
    /// The spec's name, or the kind in hex for kinds this version does not know.
    name: String,
    /// The raw flags.
    flags: u32,
    /// `zstd`, `shuffle`, and any other set bit in hex.
    flag_names: Vec<String>,
    /// Offset of the stored payload.
    offset: u64,
    /// Stored length.
    length: u64,
    /// Decoded length.
    raw_length: u64,
    /// `raw_length / length`, rounded to three decimals; `None` for an empty section.
    ratio: Option<f64>,
    /// Bytes per record.
    record_size: u32,
    /// `raw_length / record_size`.
    record_count: u64,
    /// CRC-32 of the stored bytes, as stored.
    checksum: u32,
}

/// The `BLOCK` record.
#[derive(Debug, Serialize)]
struct BlockInfo {
    /// Lower corner of the block bounds.
    bounds_min: [f32; 3],
    /// Upper corner.
    bounds_max: [f32; 3],
    /// Cells along x, y, z.
    grid: [u32; 3],
    /// Number of source trees.
    tree_count: u32,
}

/// The metadata, with materials joined to their records.
#[derive(Debug, Serialize)]
struct MetadataInfo<'a> {
    /// Tool that wrote the file.
    generator: &'a str,
    /// Block name.
    name: &'a str,
    /// Source files.
    sources: &'a [Source],
    /// Trees of the block.
    trees: &'a [Tree],
    /// One entry per material record or metadata entry, whichever are more.
    materials: Vec<MaterialOut>,
    /// Build settings.
    settings: &'a [Setting],
}

/// A material: its class from `MATERIALS`, its name and provenance from `META`.
#[derive(Debug, Serialize)]
struct MaterialOut {
    /// Index in `MATERIALS`.
    index: usize,
    /// The record's raw `class`, `None` if there is no record for this index.
    class: Option<u32>,
    /// `bark`, `leaf`, `other` or `unknown(N)`; `None` without record.
    class_name: Option<String>,
    /// The material's name, `None` without metadata entry.
    name: Option<String>,
    /// How the class was decided, `None` without metadata entry.
    classified_by: Option<String>,
}

/// Record counts of one cell or of all cells.
#[derive(Debug, Default, Serialize)]
struct Counts {
    /// `TRIANGLES` records.
    triangles: u64,
    /// `POINTS` records.
    points: u64,
    /// `ELLIPSOIDS` records.
    ellipsoids: u64,
    /// `LINES` records.
    lines: u64,
    /// `PLANES` records.
    planes: u64,
    /// `PRUNE_LEAVES` records.
    prune_leaves: u64,
}

impl Counts {
    /// The counts of a cell's ranges.
    fn of(cell: &CellRecord) -> Self {
        let n = |r: treelod_format::Range| u64::from(r.count);
        Self {
            triangles: n(cell.triangles),
            points: n(cell.points),
            ellipsoids: n(cell.ellipsoids),
            lines: n(cell.lines),
            planes: n(cell.planes),
            prune_leaves: n(cell.prune_leaves),
        }
    }

    /// Adds `other` to `self`.
    fn add(&mut self, other: &Self) {
        self.triangles += other.triangles;
        self.points += other.points;
        self.ellipsoids += other.ellipsoids;
        self.lines += other.lines;
        self.planes += other.planes;
        self.prune_leaves += other.prune_leaves;
    }

    /// The counts in column order.
    fn values(&self) -> [u64; 6] {
        [self.triangles, self.points, self.ellipsoids, self.lines, self.planes, self.prune_leaves]
    }

    /// Whether every count is zero.
    fn is_zero(&self) -> bool {
        self.values().iter().all(|&v| v == 0)
    }
}

/// Per-cell counts.
#[derive(Debug, Serialize)]
struct CellsInfo {
    /// Number of grid cells (without the block cell).
    grid_cells: usize,
    /// Number of cells with at least one record, the block cell included.
    non_empty: usize,
    /// The non-empty cells in index order.
    list: Vec<CellInfo>,
    /// Sums over all cells.
    totals: Counts,
}

/// The block's far lines (spec §6.9.1): one hierarchy over the lines the cells draw at its switch.
#[derive(Debug, Serialize)]
struct FarLinesInfo {
    /// `FAR_LINES` records.
    records: u64,
    /// Leaves of the hierarchy, the largest `leaf_first + leaf_count` (the number of `LINES`
    /// records with `hi = +∞` in a file that verifies).
    leaves: u64,
    /// `τ_far`, metres per pixel: the least positive `lo`, the end of far level 0; `+∞` (`null`
    /// in JSON) when no record has one.
    tau_far: f32,
}

impl FarLinesInfo {
    /// The far lines of `container`, `None` if it has none.
    fn new(container: &Container) -> Option<Self> {
        let far = container.far_lines();
        (!far.is_empty()).then(|| Self {
            records: far.len() as u64,
            leaves: far.iter().map(|l| u64::from(l.leaf_first) + u64::from(l.leaf_count)).max().unwrap_or(0),
            tau_far: far_threshold(far),
        })
    }

    /// One line, after the cells' table.
    fn to_text(&self) -> String {
        format!("  far lines  {} records, leaves {}, τ_far {} m/px\n", self.records, self.leaves, self.tau_far)
    }
}

/// The pruning sections: the leaves' lists per cell and the two curves (spec §6.11).
#[derive(Debug, Serialize)]
struct PruningInfo {
    /// `PRUNE_LEAVES` records.
    leaves: u64,
    /// `PRUNE_TRIANGLES` records.
    triangles: u64,
    /// Cells whose list is not empty.
    cells: u64,
    /// Fewest, median and most leaves in a non-empty list (zeros without lists).
    leaves_per_cell: [u64; 3],
    /// `PRUNE_SCALE` as `[λ, s_opt]` pairs.
    scale: Vec<[f32; 2]>,
    /// `PRUNE_LAMBDA` as `[projected height in pixels, λ]` pairs.
    lambda: Vec<[f32; 2]>,
}

impl PruningInfo {
    /// The pruning content of `container`, `None` if it has no pruning records.
    fn new(container: &Container) -> Option<Self> {
        let (scale, lambda) = (container.prune_scale(), container.prune_lambda());
        let (leaves, triangles) = (container.prune_leaves().len(), container.prune_triangles().len());
        if leaves == 0 && triangles == 0 && scale.is_empty() && lambda.is_empty() {
            return None;
        }
        let mut counts: Vec<u64> =
            container.cells().iter().map(|c| u64::from(c.prune_leaves.count)).filter(|&n| n > 0).collect();
        counts.sort_unstable();
        let leaves_per_cell = match (counts.first(), counts.last()) {
            (Some(&min), Some(&max)) => [min, counts[(counts.len() - 1) / 2], max],
            _ => [0; 3],
        };
        Some(Self {
            leaves: leaves as u64,
            triangles: triangles as u64,
            cells: counts.len() as u64,
            leaves_per_cell,
            scale: scale.iter().map(|c| [c.x, c.y]).collect(),
            lambda: lambda.iter().map(|c| [c.x, c.y]).collect(),
        })
    }

    /// The text form: counts, then each curve as a two-row table.
    fn to_text(&self) -> String {
        let [min, median, max] = self.leaves_per_cell;
        let mut out = format!(
            "\npruning\n  leaves     {} in {} cells (per cell: min {min}, median {median}, max {max}), {} triangles\n",
            self.leaves, self.cells, self.triangles
        );
        let curve = |out: &mut String, title: &str, x: &str, y: &str, samples: &[[f32; 2]]| {
            out.push_str(&format!("  {title} ({} samples)\n", samples.len()));
            if samples.is_empty() {
                return;
            }
            let mut columns = vec![("", Align::Left)];
            columns.extend(samples.iter().map(|_| ("", Align::Right)));
            let mut t = Table::new(&columns);
            for (label, k) in [(x, 0), (y, 1)] {
                let mut row = vec![label.to_owned()];
                row.extend(samples.iter().map(|s| s[k].to_string()));
                t.row(row);
            }
            out.push_str(&t.render("    "));
        };
        curve(&mut out, "PRUNE_SCALE s_opt(λ)", "λ", "s_opt", &self.scale);
        curve(&mut out, "PRUNE_LAMBDA λ(h), h = projected block height in pixels", "h", "λ", &self.lambda);
        out
    }
}

/// The impostor planes (spec §6.10): how many, where, the atlas images they sample, for indirect
/// texturing (§6.10.1) the `LEAF_SLOTS` images and the `PLANE_LEAVES` count, and their diffuse
/// response (§6.10.2).
#[derive(Debug, Serialize)]
struct ImpostorInfo {
    /// `PLANES` records.
    planes: u64,
    /// Cells holding planes.
    cells: u64,
    /// Planes of the finest level (`lo = 0`).
    finest: u64,
    /// Planes of the coarsest level (`hi = +∞`).
    roots: u64,
    /// The images the planes sample.
    atlases: Vec<AtlasInfo>,
    /// `PLANE_LEAVES` records (spec §6.10.1), when the container has any or a plane samples a
    /// `LEAF_SLOTS` image.
    #[serde(skip_serializing_if = "Option::is_none")]
    plane_leaves: Option<u64>,
    /// The `PLANE_DIFFUSE` records (spec §6.10.2, version 1.10), when the container has any.
    #[serde(skip_serializing_if = "Option::is_none")]
    plane_diffuse: Option<PlaneDiffuseInfo>,
}

/// The planes' diffuse response (spec §6.10.2): the spread of the three shares of leaves over the
/// `PLANE_DIFFUSE` records, as a reader takes them ([`PlaneDiffuseRecord::shares`]: `s` clamped to
/// `1 − f`).
#[derive(Debug, Serialize)]
struct PlaneDiffuseInfo {
    /// `PLANE_DIFFUSE` records (one per plane: checked at open).
    records: u64,
    /// `f = flat / 65535`, the share of a plane's leaves lying in it: `[min, mean, max]`.
    in_plane: [f32; 3],
    /// `s = scattered / 65535`, the share turned every way: `[min, mean, max]`.
    scattered: [f32; 3],
    /// `r = 1 − f − s`, the share across the plane, every way about its normal: `[min, mean, max]`.
    across: [f32; 3],
    /// Records equal to `FLAT` (`f = 1`: the leaves lie in their plane, what a reader without the
    /// section assumes).
    flat: u64,
}

impl PlaneDiffuseInfo {
    /// The diffuse records of `container`, `None` if it has none.
    fn new(container: &Container) -> Option<Self> {
        let records = container.plane_diffuse();
        let shares: Vec<(f32, f32, f32)> = records.iter().map(|r| r.shares()).collect();
        let spread = |share: fn(&(f32, f32, f32)) -> f32| -> [f32; 3] {
            let values = shares.iter().map(|s| f64::from(share(s)));
            let min = values.clone().fold(f64::INFINITY, f64::min);
            let max = values.clone().fold(f64::NEG_INFINITY, f64::max);
            let mean = values.sum::<f64>() / shares.len() as f64;
            [min, mean, max].map(|v| v as f32)
        };
        (!records.is_empty()).then(|| Self {
            records: records.len() as u64,
            in_plane: spread(|s| s.0),
            scattered: spread(|s| s.1),
            across: spread(|s| s.2),
            flat: records.iter().filter(|&&r| r == PlaneDiffuseRecord::FLAT).count() as u64,
        })
    }

    /// One line, after the impostors' images: each share as `min .. max (mean)`, and how many
    /// records are `FLAT`.
    fn to_text(&self) -> String {
        let share = |[min, mean, max]: [f32; 3]| format!("{min} .. {max} (mean {mean})");
        format!(
            "  diffuse    {} records, shares of leaves in the plane {}, turned every way {}, across {}; {} flat\n",
            self.records,
            share(self.in_plane),
            share(self.scattered),
            share(self.across),
            self.flat
        )
    }
}

/// One image sampled by planes.
#[derive(Debug, Serialize)]
struct AtlasInfo {
    /// Index in `IMAGES`.
    image: u32,
    /// Texels across.
    width: u32,
    /// Texels down.
    height: u32,
    /// The `format` value (spec §6.7).
    format: u32,
    /// Mip levels stored.
    mip_count: u32,
    /// Bytes of its data in `IMAGE_DATA` (decoded).
    bytes: u64,
    /// Planes sampling it.
    planes: u64,
}

impl ImpostorInfo {
    /// The planes of `container`, `None` if it has none.
    fn new(container: &Container) -> Option<Self> {
        let planes = container.planes();
        if planes.is_empty() {
            return None;
        }
        let mut images: Vec<u32> = planes.iter().map(|p| p.image).collect();
        images.sort_unstable();
        images.dedup();
        let atlases: Vec<AtlasInfo> = images
            .iter()
            .filter_map(|&image| {
                let r = container.images().get(image as usize)?;
                Some(AtlasInfo {
                    image,
                    width: r.width,
                    height: r.height,
                    format: r.format,
                    mip_count: r.mip_count,
                    bytes: r.data_length,
                    planes: planes.iter().filter(|p| p.image == image).count() as u64,
                })
            })
            .collect();
        let leaf_slots = atlases.iter().any(|a| a.format == treelod_format::image_format::LEAF_SLOTS);
        let plane_leaves = container.plane_leaves().len() as u64;
        Some(Self {
            planes: planes.len() as u64,
            cells: container.cells().iter().filter(|c| c.planes.count > 0).count() as u64,
            finest: planes.iter().filter(|p| p.lo == 0.0).count() as u64,
            roots: planes.iter().filter(|p| p.hi == f32::INFINITY).count() as u64,
            atlases,
            plane_leaves: (plane_leaves > 0 || leaf_slots).then_some(plane_leaves),
            plane_diffuse: PlaneDiffuseInfo::new(container),
        })
    }

    /// The text form.
    fn to_text(&self) -> String {
        let mut out = format!(
            "\nimpostors\n  planes     {} in {} cell(s): {} at the finest level (lo = 0), {} at the coarsest (hi = inf)\n",
            self.planes, self.cells, self.finest, self.roots
        );
        let plane_leaves = self.plane_leaves.unwrap_or(0);
        for a in &self.atlases {
            let format = image_format_name(a.format);
            if a.format == treelod_format::image_format::LEAF_SLOTS {
                // A leaf distribution (spec §6.10.1): its slots name PLANE_LEAVES records.
                out.push_str(&format!(
                    "  leaf slots image {}: {} x {} {format}, {} bytes, {} plane(s), {plane_leaves} plane-leaf records\n",
                    a.image, a.width, a.height, a.bytes, a.planes
                ));
            } else {
                out.push_str(&format!(
                    "  atlas      image {}: {} x {} {format}, {} mip(s), {} bytes, {} plane(s)\n",
                    a.image, a.width, a.height, a.mip_count, a.bytes, a.planes
                ));
            }
        }
        let slots = self.atlases.iter().any(|a| a.format == treelod_format::image_format::LEAF_SLOTS);
        if plane_leaves > 0 && !slots {
            out.push_str(&format!(
                "  leaves     {plane_leaves} plane-leaf records, no plane samples a LEAF_SLOTS image\n"
            ));
        }
        if let Some(diffuse) = &self.plane_diffuse {
            out.push_str(&diffuse.to_text());
        }
        out
    }
}

/// The baselines of a container (spec §6.12, §6.13, §6.13.1, §6.13.2, §6.13.3): each tree's LoD
/// chain, billboards and octahedral impostor (with where its views' normals lie), and the
/// impostors' depth planes.
#[derive(Debug, Serialize)]
struct BaselineInfo {
    /// `LOD_LEVELS` records in file order.
    lod_levels: Vec<LodLevelInfo>,
    /// Billboard quads per (tree, kind name), in file order.
    billboards: Vec<BillboardInfo>,
    /// `OCTAHEDRAL` records in file order (version 1.11), when the container has any.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    octahedral: Vec<OctahedralInfo>,
    /// The `OCTAHEDRAL_DEPTH` records (spec §6.13.2, version 1.13), when the container has any;
    /// absent, as in the files of 1.12 and before, the views are the planes through the
    /// impostors' centres.
    #[serde(skip_serializing_if = "Option::is_none")]
    octahedral_depth: Option<OctahedralDepthInfo>,
}

/// One level of a tree's chain.
#[derive(Debug, Serialize)]
struct LodLevelInfo {
    tree: u32,
    level: u32,
    fraction: f32,
    triangles: u32,
    /// Metres.
    error: f32,
}

/// The billboard quads of one tree and kind.
#[derive(Debug, Serialize)]
struct BillboardInfo {
    tree: u32,
    /// `facing` or `crossed` (or the raw value).
    kind: String,
    quads: u32,
    /// Texels of their atlas rectangles (mip 0).
    texels: u64,
}

/// One tree's octahedral impostor (spec §6.13.1).
#[derive(Debug, Serialize)]
struct OctahedralInfo {
    tree: u32,
    /// Views per side of the grid, `N` (`N²` views).
    frames: u32,
    /// Centre of the views, metres.
    center: [f32; 3],
    /// Half the side of each view's square, metres.
    radius: f32,
    /// The atlas, by index into `IMAGES`.
    image: u32,
    /// The rectangle of the views' cells, `[u, v]` each.
    uv_min: [f32; 2],
    uv_max: [f32; 2],
    /// Texels of the rectangle (mip 0), 0 when the image does not exist.
    texels: u64,
    /// Mean ambient occlusion of the surfaces the views show.
    occlusion: f32,
    /// How its surfaces take the sun (spec §6.13.1): the shares facing the viewer and turned
    /// every way, `flat / 65535` and `scattered / 65535`.
    diffuse: [f32; 2],
    /// The corner of its views' normal grid, `[u, v]` (spec §6.13.3): `OCTAHEDRAL_NORMAL_GRIDS`'
    /// `uv_min` (version 1.16) or `OCTAHEDRAL_NORMALS`' (1.15). Absent without either section, as
    /// in the files of 1.14 and before, whose views are lit as a whole.
    #[serde(skip_serializing_if = "Option::is_none")]
    normals_uv_min: Option<[f32; 2]>,
    /// The normal grid's far corner, `[u, v]`: `OCTAHEDRAL_NORMAL_GRIDS`' `uv_max`, or for 1.15
    /// the corner of a grid of the colour grid's size from `normals_uv_min` (held inside the image,
    /// `OctahedralNormalRecord::grid`). Absent as `normals_uv_min` is.
    #[serde(skip_serializing_if = "Option::is_none")]
    normals_uv_max: Option<[f32; 2]>,
}

/// The octahedral views' depth planes (spec §6.13.2): their spread over the `OCTAHEDRAL_DEPTH`
/// records, in units of each impostor's `radius`.
#[derive(Debug, Serialize)]
struct OctahedralDepthInfo {
    /// `OCTAHEDRAL_DEPTH` records: one per view (`frames²` per `OCTAHEDRAL` record, which
    /// `verify` checks).
    views: u64,
    /// The least `offset`, the depth along the view's direction at its centre.
    offset_min: f32,
    /// The greatest `offset`.
    offset_max: f32,
    /// The mean `offset`.
    offset_mean: f32,
    /// The greatest `|slope_s|` or `|slope_t|`.
    slope_max: f32,
}

impl OctahedralDepthInfo {
    /// The depth planes of `container`, `None` if it has none.
    fn new(container: &Container) -> Option<Self> {
        let records = container.octahedral_depth();
        if records.is_empty() {
            return None;
        }
        let offsets = records.iter().map(|r| f64::from(r.offset));
        let mean = offsets.clone().sum::<f64>() / records.len() as f64;
        Some(Self {
            views: records.len() as u64,
            offset_min: offsets.clone().fold(f64::INFINITY, f64::min) as f32,
            offset_max: offsets.fold(f64::NEG_INFINITY, f64::max) as f32,
            offset_mean: mean as f32,
            slope_max: records.iter().flat_map(|r| [r.slope_s.abs(), r.slope_t.abs()]).fold(0.0, f32::max),
        })
    }

    /// One line, after the octahedral impostors': the views, the spread of the offsets and the
    /// steepest slope.
    fn to_text(&self) -> String {
        format!(
            "  depth planes  {} views, offset {} .. {} (mean {}), slopes up to {}\n",
            self.views, self.offset_min, self.offset_max, self.offset_mean, self.slope_max
        )
    }
}

/// Texels at mip 0 of the rectangle `uv_min ..= uv_max` of image `image`, 0 when there is no such
/// image (or the rectangle is reversed).
fn rectangle_texels(container: &Container, image: u32, uv_min: u32, uv_max: u32) -> u64 {
    container.images().get(image as usize).map_or(0, |image| {
        let [u0, v0] = treelod_format::pack::unpack_unorm16x2(uv_min);
        let [u1, v1] = treelod_format::pack::unpack_unorm16x2(uv_max);
        let w = ((u1 - u0) * image.width as f32).round() as u64;
        let h = ((v1 - v0) * image.height as f32).round() as u64;
        w * h
    })
}

impl BaselineInfo {
    /// The baselines of `container`, `None` if it has none.
    fn new(container: &Container) -> Option<Self> {
        let (levels, billboards, octahedral) = (container.lod_levels(), container.billboards(), container.octahedral());
        let octahedral_depth = OctahedralDepthInfo::new(container);
        if levels.is_empty() && billboards.is_empty() && octahedral.is_empty() && octahedral_depth.is_none() {
            return None;
        }
        let lod_levels = levels
            .iter()
            .map(|l| LodLevelInfo {
                tree: l.tree,
                level: l.level,
                fraction: l.fraction,
                triangles: l.triangles.count,
                error: l.error,
            })
            .collect();
        let mut out: Vec<BillboardInfo> = Vec::new();
        for b in billboards {
            let texels = rectangle_texels(container, b.image, b.uv_min, b.uv_max);
            let kind = match b.kind {
                treelod_format::billboard_kind::FACING => "facing".to_owned(),
                treelod_format::billboard_kind::CROSSED => "crossed".to_owned(),
                other => format!("kind {other}"),
            };
            match out.last_mut() {
                Some(last) if last.tree == b.tree && last.kind == kind => {
                    last.quads += 1;
                    last.texels += texels;
                }
                _ => out.push(BillboardInfo { tree: b.tree, kind, quads: 1, texels }),
            }
        }
        let octahedral = octahedral
            .iter()
            .enumerate()
            .map(|(k, o)| {
                // Spec §6.13.3: 1.16's record, or the grid 1.15's record places.
                let normals = container.octahedral_normal_grid(k).map(|g| {
                    (treelod_format::pack::unpack_unorm16x2(g.uv_min), treelod_format::pack::unpack_unorm16x2(g.uv_max))
                });
                OctahedralInfo {
                    tree: o.tree,
                    frames: o.frames,
                    center: o.center,
                    radius: o.radius,
                    image: o.image,
                    uv_min: treelod_format::pack::unpack_unorm16x2(o.uv_min),
                    uv_max: treelod_format::pack::unpack_unorm16x2(o.uv_max),
                    texels: rectangle_texels(container, o.image, o.uv_min, o.uv_max),
                    occlusion: o.occlusion,
                    diffuse: [f32::from(o.diffuse.flat) / 65535.0, f32::from(o.diffuse.scattered) / 65535.0],
                    normals_uv_min: normals.map(|(lo, _)| lo),
                    normals_uv_max: normals.map(|(_, hi)| hi),
                }
            })
            .collect();
        Some(Self { lod_levels, billboards: out, octahedral, octahedral_depth })
    }

    /// The text form.
    fn to_text(&self) -> String {
        let mut out = String::from(
            "
baselines
",
        );
        for l in &self.lod_levels {
            out.push_str(&format!(
                "  lod chain  tree {} level {}: {} of the source, {} triangles, error {} m\n",
                l.tree, l.level, l.fraction, l.triangles, l.error
            ));
        }
        for b in &self.billboards {
            out.push_str(&format!(
                "  billboard  tree {} {}: {} quad(s), {} texels\n",
                b.tree, b.kind, b.quads, b.texels
            ));
        }
        for o in &self.octahedral {
            out.push_str(&format!(
                "  octahedral tree {}: {}x{} views, radius {} m at {}, image {} rectangle [{}, {}] .. [{}, {}] ({} \
                 texels), occlusion {}, diffuse flat {:.4} scattered {:.4}{}\n",
                o.tree,
                o.frames,
                o.frames,
                o.radius,
                vec3(o.center),
                o.image,
                o.uv_min[0],
                o.uv_min[1],
                o.uv_max[0],
                o.uv_max[1],
                o.texels,
                o.occlusion,
                o.diffuse[0],
                o.diffuse[1],
                match (o.normals_uv_min, o.normals_uv_max) {
                    (Some(lo), Some(hi)) => format!(", normals [{}, {}] .. [{}, {}]", lo[0], lo[1], hi[0], hi[1]),
                    _ => String::new(),
                }
            ));
        }
        if let Some(depth) = &self.octahedral_depth {
            out.push_str(&depth.to_text());
        }
        out
    }
}

/// The calibration of a container (spec §6.15): per representation, its error and primitive
/// count at each projected height; then the same per elevation of the views (§6.16), per LoD
/// chain level over every view (§6.17), and for the techniques added after 1.11 over every view
/// and per elevation (§6.18).
#[derive(Debug, Serialize)]
struct CalibrationInfo {
    /// One entry per representation of `CALIBRATION`, in code order.
    techniques: Vec<CalibrationRow>,
    /// One entry per elevation (`CALIBRATION_ELEVATIONS`), in file order (ascending); absent when
    /// the container has none (files before 1.7).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    elevations: Vec<ElevationCalibration>,
    /// One entry per LoD chain level (`CHAIN_CALIBRATION`), finest first; absent when the
    /// container has none (files before 1.8).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    chain_levels: Vec<ChainLevelRow>,
    /// One entry per representation added after 1.11 (`CALIBRATION_ADDED`), in code order; absent
    /// when the container has none (files before 1.12).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    added_techniques: Vec<CalibrationRow>,
    /// One entry per elevation of those representations (`CALIBRATION_ELEVATIONS_ADDED`), in file
    /// order (ascending); absent when the container has none (files before 1.12).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    added_elevations: Vec<ElevationCalibration>,
    /// Whether the errors are of shaded colour (metadata `calibration.error = "colour"`, spec
    /// §6.15), else of coverage (earlier builds). The metadata block of the JSON says it too.
    #[serde(skip)]
    colour: bool,
}

/// The samples of one representation.
#[derive(Clone, Debug, Serialize)]
struct CalibrationRow {
    /// The technique's name (`--technique`), or `technique N` for an undefined code.
    technique: String,
    /// `[height in pixels, error, primitives]`, by increasing height.
    samples: Vec<[f32; 3]>,
}

/// The samples of one LoD chain level.
#[derive(Debug, Serialize)]
struct ChainLevelRow {
    /// The level, 0 the finest.
    level: u32,
    /// `[height in pixels, error, primitives]`, by increasing height.
    samples: Vec<[f32; 3]>,
}

/// The tables measured from the views at one elevation.
#[derive(Debug, Serialize)]
struct ElevationCalibration {
    /// Degrees above the block's horizontal plane.
    elevation: f32,
    /// One entry per representation, in code order.
    techniques: Vec<CalibrationRow>,
}

impl CalibrationInfo {
    /// The calibration of `container`, `None` if it has none of the tables.
    fn new(container: &Container) -> Option<Self> {
        let records = container.calibration();
        let per_elevation = container.calibration_elevations();
        let chain = container.chain_calibration();
        let added = container.calibration_added();
        let added_per_elevation = container.calibration_elevations_added();
        if records.is_empty()
            && per_elevation.is_empty()
            && chain.is_empty()
            && added.is_empty()
            && added_per_elevation.is_empty()
        {
            return None;
        }
        let techniques = rows(records.iter().map(|r| (r.technique, [r.height, r.error, r.primitives])));
        let added_techniques = rows(added.iter().map(|r| (r.technique, [r.height, r.error, r.primitives])));
        let elevations = elevation_tables(per_elevation);
        let added_elevations = elevation_tables(added_per_elevation);
        let chain_levels = chain
            .chunk_by(|a, b| a.level == b.level)
            .map(|run| ChainLevelRow {
                level: run[0].level,
                samples: run.iter().map(|r| [r.height, r.error, r.primitives]).collect(),
            })
            .collect();
        let colour = container.metadata().settings.iter().any(|s| s.key == "calibration.error" && s.value == "colour");
        Some(Self { techniques, elevations, chain_levels, added_techniques, added_elevations, colour })
    }

    /// The text form: a table of a row per representation (those of `CALIBRATION`, then those
    /// added after 1.11, of `CALIBRATION_ADDED`: together the file's tables, spec §6.18) and then
    /// per LoD chain level (`lod-chain level N`), `error (primitives)` per height; then one table of
    /// the representations per elevation, the added ones' rows after the others'. An elevation of
    /// the added tables that the others lack (an invalid file) gets a table of its own.
    fn to_text(&self) -> String {
        let measure = if self.colour { "shaded colour" } else { "coverage" };
        let levels = self
            .chain_levels
            .iter()
            .map(|l| CalibrationRow { technique: format!("lod-chain level {}", l.level), samples: l.samples.clone() });
        let mean: Vec<CalibrationRow> =
            self.techniques.iter().chain(&self.added_techniques).cloned().chain(levels).collect();
        let mut out = format!(
            "\ncalibration (multi-scale RMSE of {measure} against the supersampled full mesh, and primitives submitted, \
             by the block's projected height)\n{}",
            table(&mean).render("  ")
        );
        let added_at = |elevation: f32| self.added_elevations.iter().filter(move |a| a.elevation == elevation);
        let unmatched =
            self.added_elevations.iter().filter(|a| !self.elevations.iter().any(|e| e.elevation == a.elevation));
        let per_elevation = self.elevations.iter().map(|e| {
            let rows: Vec<CalibrationRow> =
                e.techniques.iter().chain(added_at(e.elevation).flat_map(|a| &a.techniques)).cloned().collect();
            (e.elevation, rows)
        });
        for (elevation, rows) in per_elevation.chain(unmatched.map(|a| (a.elevation, a.techniques.clone()))) {
            out.push_str(&format!(
                "\ncalibration at {elevation}° elevation (the same, from the views at that elevation)\n{}",
                table(&rows).render("  ")
            ));
        }
        out
    }
}

/// What the renderer's policy ([`treelod_runtime::Policy::default`]: its default target, spec
/// §10.2) draws a tree of this model with, by the elevation class it is seen from and its projected
/// height, chosen afresh (no hysteresis), fully visible and wholly in view, among the
/// representations the renderer can draw from the file ([`treelod_runtime::Representations`]): the
/// renderer's own [`treelod_runtime::Choices`], so an artist sees which representation each
/// distance gets before placing a forest.
#[derive(Debug, Serialize)]
struct PolicyInfo {
    /// The policy's target (multi-scale RMSE over the floor, spec §10.2).
    target: f32,
    /// One entry per elevation class (every 10° between the tables' elevations; one entry,
    /// `elevation` null, for a file whose tables are over every view only), lowest first.
    classes: Vec<PolicyClass>,
}

/// The policy's choices for the trees of one elevation class.
#[derive(Debug, Serialize)]
struct PolicyClass {
    /// Degrees above the horizontal plane the class's trees are seen from; null: every view.
    elevation: Option<f32>,
    /// `[height in pixels, technique]`: the technique from that height up to the next entry's,
    /// the first from the smallest calibrated height (above the largest: the last, or the point
    /// tree where only part of a tree is in view).
    runs: Vec<(f32, &'static str)>,
    /// `[height in pixels, technique]`: under that height every tree of the class gets that
    /// technique whatever its visibility and last choice, without being looked up
    /// (`Choices::uniform_below_in`); absent where none.
    #[serde(skip_serializing_if = "Option::is_none")]
    uniform_below: Option<(f32, &'static str)>,
}

impl PolicyInfo {
    /// The policy's choices for `container`: `None` without calibration tables, or where the
    /// file does not verify (spec §9.2; the renderer reads only verified files, and the
    /// representations' ranges are read from the records).
    fn new(container: &Container) -> Option<Self> {
        if container.calibration().is_empty() && container.calibration_added().is_empty() {
            return None;
        }
        treelod_format::verify(container).ok()?;
        let calibration = treelod_runtime::Calibration::from_container(container)?;
        let (representations, _) = treelod_runtime::Representations::from_container(container);
        let policy = treelod_runtime::Policy::default();
        let choices = treelod_runtime::Choices::new(&calibration, &policy, &representations);
        let elevations: Vec<Option<f32>> = if choices.elevations().is_empty() {
            vec![None]
        } else {
            choices.elevations().iter().copied().map(Some).collect()
        };
        let classes = elevations
            .into_iter()
            .enumerate()
            .map(|(e, elevation)| PolicyClass {
                elevation,
                runs: choices.runs_at(e).into_iter().map(|(h, t)| (h, t.name())).collect(),
                uniform_below: choices.uniform_below_in(e).map(|(h, t)| (h, t.name())),
            })
            .collect();
        Some(Self { target: policy.target(), classes })
    }

    /// The text form: a line per elevation class, each run as `height: technique` (the height to
    /// three significant digits), and the uniform height where the class has one.
    fn to_text(&self) -> String {
        let mut out = format!(
            "\npolicy (what the renderer draws a tree with by default, target {}: from each projected height \
             up, by the elevation it is seen from; fully visible, wholly in view, chosen afresh)\n",
            self.target
        );
        for class in &self.classes {
            let elevation = class.elevation.map_or_else(|| "every view".to_owned(), |e| format!("{e}°"));
            let runs: Vec<String> = class.runs.iter().map(|(h, t)| format!("{} px: {t}", pixels(*h))).collect();
            let uniform = class
                .uniform_below
                .map(|(h, t)| format!(" (every tree under {} px: {t})", pixels(h)))
                .unwrap_or_default();
            out.push_str(&format!("  {elevation:>10}  {}{uniform}\n", runs.join(", ")));
        }
        out
    }
}

/// A height in pixels to three significant digits (`4`, `5.66`, `45.3`, `215`).
fn pixels(h: f32) -> String {
    let decimals = if h < 10.0 {
        2
    } else if h < 100.0 {
        1
    } else {
        0
    };
    let text = format!("{h:.decimals$}");
    if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.').to_owned() } else { text }
}

/// One table per run of records of one elevation, in file order.
fn elevation_tables(records: &[treelod_format::ElevationCalibrationRecord]) -> Vec<ElevationCalibration> {
    records
        .chunk_by(|a, b| a.elevation == b.elevation)
        .map(|run| ElevationCalibration {
            elevation: run[0].elevation,
            techniques: rows(run.iter().map(|r| (r.technique, [r.height, r.error, r.primitives]))),
        })
        .collect()
}

/// Groups `(technique, [height, error, primitives])` samples into one row per run of one
/// technique.
fn rows(samples: impl Iterator<Item = (u32, [f32; 3])>) -> Vec<CalibrationRow> {
    let mut techniques: Vec<(u32, CalibrationRow)> = Vec::new();
    for (code, sample) in samples {
        match techniques.last_mut() {
            Some((last, row)) if *last == code => row.samples.push(sample),
            _ => {
                let technique = treelod_format::calibration_technique::name(code)
                    .map_or_else(|| format!("technique {code}"), str::to_owned);
                techniques.push((code, CalibrationRow { technique, samples: vec![sample] }));
            }
        }
    }
    techniques.into_iter().map(|(_, row)| row).collect()
}

/// A calibration table: a row per representation, a column per height, `error (primitives)`.
fn table(techniques: &[CalibrationRow]) -> Table {
    table_of(techniques, |s| format!("{:.4} ({})", s[1], s[2].round()))
}

/// A table of `techniques`: a row per representation, a column per height, each sample
/// `[height, value, …]` written by `cell`.
fn table_of(techniques: &[CalibrationRow], cell: impl Fn(&[f32; 3]) -> String) -> Table {
    let mut heights: Vec<f32> = techniques.iter().flat_map(|t| t.samples.iter().map(|s| s[0])).collect();
    heights.sort_by(f32::total_cmp);
    heights.dedup();
    let mut columns = vec![("technique".to_owned(), Align::Left)];
    columns.extend(heights.iter().map(|h| (format!("{h} px"), Align::Right)));
    let names: Vec<(&str, Align)> = columns.iter().map(|(n, a)| (n.as_str(), *a)).collect();
    let mut table = Table::new(&names);
    for t in techniques {
        let mut row = vec![t.technique.clone()];
        row.extend(heights.iter().map(|h| t.samples.iter().find(|s| s[0] == *h).map_or_else(String::new, &cell)));
        table.row(row);
    }
    table
}

/// One record of the calibration's FLIP error (`CALIBRATION_FLIP`, spec §6.19).
#[derive(Debug, Serialize)]
struct FlipSample {
    /// Degrees above the block's horizontal plane of the views measured, or -1 for a row over
    /// every view.
    elevation: f32,
    /// The technique's name (`--technique`), or `technique N` for an undefined code, as the
    /// calibration's rows name it.
    technique: String,
    /// Projected height of the block, pixels.
    height: f32,
    /// Mean LDR-FLIP error against the supersampled full mesh, `[0, 1]`.
    flip: f32,
}

impl FlipSample {
    /// The sample of record `r`.
    fn of(r: &FlipCalibrationRecord) -> Self {
        let technique = treelod_format::calibration_technique::name(r.technique)
            .map_or_else(|| format!("technique {}", r.technique), str::to_owned);
        Self { elevation: r.elevation, technique, height: r.height, flip: r.flip }
    }

    /// The text form of `samples`, the records in file order, and of the chain levels' `levels`:
    /// the table of the rows over every view, laid out as the calibration's (a row per
    /// representation, then per LoD chain level, `lod-chain level N`, as the calibration's table
    /// over every view has them; a column per height), then one table per run of records of one
    /// elevation; empty without records.
    fn text(samples: &[Self], levels: &[ChainFlipSample]) -> String {
        let rows = |samples: &[&Self], levels: &[ChainFlipSample]| {
            let mut out: Vec<CalibrationRow> = Vec::new();
            let named = samples.iter().map(|s| (s.technique.clone(), s.height, s.flip));
            let levels = levels.iter().map(|l| (format!("lod-chain level {}", l.level), l.height, l.flip));
            for (technique, height, flip) in named.chain(levels) {
                match out.last_mut() {
                    Some(row) if row.technique == technique => row.samples.push([height, flip, 0.0]),
                    _ => out.push(CalibrationRow { technique, samples: vec![[height, flip, 0.0]] }),
                }
            }
            table_of(&out, |s| format!("{:.4}", s[1])).render("  ")
        };
        let every_view: Vec<&Self> =
            samples.iter().filter(|s| s.elevation == FlipCalibrationRecord::EVERY_VIEW).collect();
        let mut out = String::new();
        if !every_view.is_empty() || !levels.is_empty() {
            out.push_str(&format!(
                "\ncalibration FLIP (mean LDR-FLIP of the shaded colour against the supersampled full mesh, by the \
                 block's projected height)\n{}",
                rows(&every_view, levels)
            ));
        }
        let per_elevation: Vec<&Self> =
            samples.iter().filter(|s| s.elevation != FlipCalibrationRecord::EVERY_VIEW).collect();
        for run in per_elevation.chunk_by(|a, b| a.elevation == b.elevation) {
            out.push_str(&format!(
                "\ncalibration FLIP at {}° elevation (the same, from the views at that elevation)\n{}",
                run[0].elevation,
                rows(run, &[])
            ));
        }
        out
    }
}

/// One record of the LoD chain levels' FLIP error (`CHAIN_CALIBRATION_FLIP`, spec §6.20).
#[derive(Debug, Serialize)]
struct ChainFlipSample {
    /// The chain level, 0 the finest.
    level: u32,
    /// Projected height of the block, pixels.
    height: f32,
    /// Mean LDR-FLIP error against the supersampled full mesh over every view, `[0, 1]`.
    flip: f32,
}

impl ChainFlipSample {
    /// The sample of record `r`.
    fn of(r: &ChainFlipCalibrationRecord) -> Self {
        Self { level: r.level, height: r.height, flip: r.flip }
    }
}

/// One non-empty cell.
#[derive(Debug, Serialize)]
struct CellInfo {
    /// Index in `CELLS`.
    index: usize,
    /// Whether this is the block cell (the last record).
    block: bool,
    /// Grid coordinates, `None` for the block cell.
    xyz: Option<[u32; 3]>,
    /// Its record counts.
    counts: Counts,
}

/// One histogram per hierarchical kind.
#[derive(Debug, Serialize)]
struct Histograms {
    /// What is measured, as in the text header.
    note: &'static str,
    /// Triangle `size`.
    triangles: Histogram,
    /// Point `size`.
    points: Histogram,
    /// Ellipsoid `2·max(radii)`.
    ellipsoids: Histogram,
    /// Line `|p1 − p0|`.
    lines: Histogram,
    /// Plane `2·max(|axis_u|, |axis_v|)`.
    planes: Histogram,
}

/// A log2-bucketed histogram of element sizes.
#[derive(Debug, Serialize)]
struct Histogram {
    /// The measure, e.g. `size`.
    measure: &'static str,
    /// Elements counted, including the special ones below.
    count: u64,
    /// Elements of size zero.
    zero: u64,
    /// Elements of negative size (invalid, but counted rather than hidden).
    negative: u64,
    /// Elements whose size is NaN or infinite.
    non_finite: u64,
    /// The non-empty buckets, smallest first.
    buckets: Vec<Bucket>,
}

/// The elements with a size in `[2^log2, 2^(log2+1))`.
#[derive(Debug, Serialize)]
struct Bucket {
    /// The bucket's exponent.
    log2: i32,
    /// `2^log2`, metres.
    min: f64,
    /// `2^(log2+1)`, metres.
    max: f64,
    /// Elements in the bucket.
    count: u64,
}

impl Histogram {
    /// Buckets `sizes`.
    fn new(measure: &'static str, sizes: impl Iterator<Item = f32>) -> Self {
        let mut h = Self { measure, count: 0, zero: 0, negative: 0, non_finite: 0, buckets: Vec::new() };
        let mut by_exponent = std::collections::BTreeMap::<i32, u64>::new();
        for size in sizes {
            h.count += 1;
            if !size.is_finite() {
                h.non_finite += 1;
            } else if size == 0.0 {
                h.zero += 1;
            } else if size < 0.0 {
                h.negative += 1;
            } else {
                *by_exponent.entry(floor_log2(size)).or_default() += 1;
            }
        }
        h.buckets = by_exponent
            .into_iter()
            .map(|(k, count)| Bucket { log2: k, min: 2f64.powi(k), max: 2f64.powi(k + 1), count })
            .collect();
        h
    }
}

/// `floor(log2(v))` of a finite positive `v`, exactly, from the bits (subnormals included).
fn floor_log2(v: f32) -> i32 {
    let bits = v.to_bits() & 0x7FFF_FFFF;
    let exponent = bits >> 23;
    let mantissa = bits & 0x7F_FFFF;
    #[expect(clippy::cast_possible_wrap, reason = "both values are below 256")]
    if exponent == 0 {
        // Subnormal: v = m·2^-149 with 0 < m < 2^23 (zero is counted apart by the caller).
        (31 - mantissa.leading_zeros().min(31)) as i32 - 149
    } else {
        exponent as i32 - 127
    }
}

/// Length of a 3-vector in `f32` (NaN or infinity propagate).
fn length(v: [f32; 3]) -> f32 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The larger of two sizes, NaN if either is NaN (so it is counted as non-finite).
fn max_or_nan(a: f32, b: f32) -> f32 {
    if a.is_nan() || b.is_nan() { f32::NAN } else { a.max(b) }
}

impl<'a> Dump<'a> {
    /// Gathers the content of `container`, opened from `path`.
    fn new(path: &Path, container: &'a Container) -> Self {
        let header = container.header();
        let block = container.block();
        let meta = container.metadata();
        let records = container.materials();
        let materials = (0..records.len().max(meta.materials.len()))
            .map(|index| {
                let record = records.get(index);
                let info = meta.materials.get(index);
                MaterialOut {
                    index,
                    class: record.map(|r| r.class),
                    class_name: record.map(|r| class_name(r.class)),
                    name: info.map(|i| i.name.clone()),
                    classified_by: info.map(|i| i.classified_by.clone()),
                }
            })
            .collect();

        let cell_records = container.cells();
        let grid_cells = block.grid_cell_count();
        let mut totals = Counts::default();
        let mut list = Vec::new();
        for (index, cell) in cell_records.iter().enumerate() {
            let counts = Counts::of(cell);
            totals.add(&counts);
            if !counts.is_zero() {
                let is_block = index >= grid_cells;
                let xyz = (!is_block).then(|| block.cell_coords(index));
                list.push(CellInfo { index, block: is_block, xyz, counts });
            }
        }

        let histograms = Histograms {
            note: HISTOGRAM_NOTE,
            triangles: Histogram::new("size", container.triangles().iter().map(|t| t.size)),
            points: Histogram::new("size", container.points().iter().map(|p| p.size)),
            ellipsoids: Histogram::new(
                "2*max(radii)",
                container.ellipsoids().iter().map(|e| 2.0 * max_or_nan(e.radii[0], max_or_nan(e.radii[1], e.radii[2]))),
            ),
            lines: Histogram::new(
                "|p1 - p0|",
                container.lines().iter().map(|l| length([l.p1[0] - l.p0[0], l.p1[1] - l.p0[1], l.p1[2] - l.p0[2]])),
            ),
            planes: Histogram::new(
                "2*max(|axis_u|, |axis_v|)",
                container.planes().iter().map(|p| 2.0 * max_or_nan(length(p.axis_u), length(p.axis_v))),
            ),
        };

        Self {
            file: path.display().to_string(),
            version: format!("{}.{}", header.major, header.minor),
            file_size: header.file_size,
            header_size: header.header_size,
            table_offset: header.table_offset,
            sections: container.sections().iter().map(section_info).collect(),
            block: BlockInfo {
                bounds_min: block.bounds_min,
                bounds_max: block.bounds_max,
                grid: block.grid,
                tree_count: block.tree_count,
            },
            metadata: MetadataInfo {
                generator: &meta.generator,
                name: &meta.name,
                sources: &meta.sources,
                trees: &meta.trees,
                materials,
                settings: &meta.settings,
            },
            cells: CellsInfo { grid_cells, non_empty: list.len(), list, totals },
            far_lines: FarLinesInfo::new(container),
            pruning: PruningInfo::new(container),
            impostors: ImpostorInfo::new(container),
            baselines: BaselineInfo::new(container),
            calibration: CalibrationInfo::new(container),
            calibration_flip: container.calibration_flip().iter().map(FlipSample::of).collect(),
            chain_calibration_flip: container.chain_calibration_flip().iter().map(ChainFlipSample::of).collect(),
            policy: PolicyInfo::new(container),
            textures: TextureUse::of(container),
            histograms,
        }
    }

    /// The JSON form: one pretty-printed object and a newline.
    fn to_json(&self) -> String {
        // Serializing plain structs of numbers and strings cannot fail (non-finite floats are
        // written as null); should it ever, the error is shown in place of the object.
        match serde_json::to_string_pretty(self) {
            Ok(mut json) => {
                json.push('\n');
                json
            }
            Err(e) => format!("{{\"error\": {:?}}}\n", e.to_string()),
        }
    }

    /// The text form.
    fn to_text(&self) -> String {
        let mut out = format!(
            "file       {}\nversion    {}\nfile size  {} bytes (header {}, section table at {})\n",
            self.file, self.version, self.file_size, self.header_size, self.table_offset
        );

        out.push_str(&format!("\nsections ({})\n", self.sections.len()));
        out.push_str(&self.sections_table().render("  "));

        let b = &self.block;
        out.push_str("\nblock\n");
        out.push_str(&format!("  bounds  {} .. {}\n", vec3(b.bounds_min), vec3(b.bounds_max)));
        out.push_str(&format!(
            "  grid    {} x {} x {} = {} cells + block cell\n",
            b.grid[0], b.grid[1], b.grid[2], self.cells.grid_cells
        ));
        out.push_str(&format!("  trees   {}\n", b.tree_count));

        out.push_str(&self.metadata_text());
        out.push_str(&self.cells_text());
        if let Some(far_lines) = &self.far_lines {
            out.push_str(&far_lines.to_text());
        }
        if let Some(pruning) = &self.pruning {
            out.push_str(&pruning.to_text());
        }
        if let Some(impostors) = &self.impostors {
            out.push_str(&impostors.to_text());
        }
        if let Some(baselines) = &self.baselines {
            out.push_str(&baselines.to_text());
        }
        if let Some(calibration) = &self.calibration {
            out.push_str(&calibration.to_text());
        }
        out.push_str(&FlipSample::text(&self.calibration_flip, &self.chain_calibration_flip));
        if let Some(policy) = &self.policy {
            out.push_str(&policy.to_text());
        }
        out.push_str(&TextureUse::text(&self.textures));
        out.push_str(&self.histograms_text());
        out
    }

    /// The section table as text.
    fn sections_table(&self) -> Table {
        let mut t = Table::new(&[
            ("kind", Align::Left),
            ("flags", Align::Left),
            ("offset", Align::Right),
            ("stored", Align::Right),
            ("raw", Align::Right),
            ("ratio", Align::Right),
            ("record", Align::Right),
            ("records", Align::Right),
            ("checksum", Align::Left),
        ]);
        for s in &self.sections {
            t.row(vec![
                s.name.clone(),
                if s.flag_names.is_empty() { "-".into() } else { s.flag_names.join("+") },
                s.offset.to_string(),
                s.length.to_string(),
                s.raw_length.to_string(),
                s.ratio.map_or_else(|| "-".into(), |r| format!("{r:.2}")),
                s.record_size.to_string(),
                s.record_count.to_string(),
                format!("{:#010x}", s.checksum),
            ]);
        }
        t
    }

    /// The metadata as text.
    fn metadata_text(&self) -> String {
        let m = &self.metadata;
        let mut out = String::from("\nmetadata\n");
        out.push_str(&format!("  generator  {:?}\n", m.generator));
        out.push_str(&format!("  name       {:?}\n", m.name));

        out.push_str(&format!("  sources ({})\n", m.sources.len()));
        if !m.sources.is_empty() {
            let mut t = Table::new(&[
                ("#", Align::Right),
                ("path", Align::Left),
                ("bytes", Align::Right),
                ("unit scale", Align::Right),
                ("content hash", Align::Left),
            ]);
            for (i, s) in m.sources.iter().enumerate() {
                t.row(vec![
                    i.to_string(),
                    format!("{:?}", s.path),
                    s.byte_length.to_string(),
                    s.unit_scale.to_string(),
                    format!("{:?}", s.content_hash),
                ]);
            }
            out.push_str(&t.render("    "));
        }

        out.push_str(&format!("  trees ({})\n", m.trees.len()));
        if !m.trees.is_empty() {
            let mut t = Table::new(&[
                ("#", Align::Right),
                ("name", Align::Left),
                ("source", Align::Right),
                ("translation", Align::Left),
                ("bounds", Align::Left),
            ]);
            for (i, tree) in m.trees.iter().enumerate() {
                t.row(vec![
                    i.to_string(),
                    format!("{:?}", tree.name),
                    tree.source.to_string(),
                    vec3(tree.translation),
                    format!("{} .. {}", vec3(tree.bounds_min), vec3(tree.bounds_max)),
                ]);
            }
            out.push_str(&t.render("    "));
        }

        out.push_str(&format!("  materials ({})\n", m.materials.len()));
        if !m.materials.is_empty() {
            let mut t = Table::new(&[
                ("#", Align::Right),
                ("class", Align::Left),
                ("classified by", Align::Left),
                ("name", Align::Left),
            ]);
            let missing = || "-".to_owned();
            for mat in &m.materials {
                t.row(vec![
                    mat.index.to_string(),
                    mat.class_name.clone().unwrap_or_else(missing),
                    mat.classified_by.as_ref().map_or_else(missing, |s| format!("{s:?}")),
                    mat.name.as_ref().map_or_else(missing, |s| format!("{s:?}")),
                ]);
            }
            out.push_str(&t.render("    "));
        }

        out.push_str(&format!("  settings ({})\n", m.settings.len()));
        for s in m.settings {
            out.push_str(&format!("    {} = {:?}\n", s.key.escape_debug(), s.value));
        }
        out
    }

    /// The per-cell counts as text.
    fn cells_text(&self) -> String {
        let c = &self.cells;
        let mut out = format!(
            "\ncells ({} of {} non-empty: {} grid cells + block cell)\n",
            c.non_empty,
            c.grid_cells + 1,
            c.grid_cells
        );
        let mut t = Table::new(&[
            ("cell", Align::Left),
            ("xyz", Align::Left),
            ("triangles", Align::Right),
            ("points", Align::Right),
            ("ellipsoids", Align::Right),
            ("lines", Align::Right),
            ("planes", Align::Right),
            ("prune leaves", Align::Right),
        ]);
        let row = |label: String, xyz: String, counts: &Counts| {
            let mut cells = vec![label, xyz];
            cells.extend(counts.values().iter().map(u64::to_string));
            cells
        };
        for cell in &c.list {
            let (label, xyz) = match cell.xyz {
                Some([x, y, z]) => (cell.index.to_string(), format!("({x},{y},{z})")),
                None => ("block".to_owned(), String::new()),
            };
            t.row(row(label, xyz, &cell.counts));
        }
        t.row(row("total".to_owned(), String::new(), &c.totals));
        out.push_str(&t.render("  "));
        out
    }

    /// The histograms as text.
    fn histograms_text(&self) -> String {
        let h = &self.histograms;
        let mut out = String::from(HISTOGRAM_TEXT_HEADER);
        let kinds = [
            ("triangles", &h.triangles),
            ("points", &h.points),
            ("ellipsoids", &h.ellipsoids),
            ("lines", &h.lines),
            ("planes", &h.planes),
        ];
        let mut any = false;
        for (name, hist) in kinds.into_iter().filter(|(_, hist)| hist.count > 0) {
            any = true;
            let plural = if hist.count == 1 { "" } else { "s" };
            out.push_str(&format!("  {name}: {} ({} element{plural})\n", hist.measure, hist.count));
            let mut t = Table::new(&[("", Align::Left), ("", Align::Left), ("", Align::Right), ("", Align::Left)]);
            let widest = hist.buckets.iter().map(|b| b.count).max().unwrap_or(0).max(1);
            let mut previous: Option<i32> = None;
            for b in &hist.buckets {
                // Gaps of up to two empty buckets are shown as such, longer ones as one line.
                let gap = previous.map_or(0, |p| b.log2 - p - 1);
                if gap > 2 {
                    t.row(vec!["...".into(), format!("({gap} empty buckets)")]);
                } else {
                    for k in b.log2 - gap..b.log2 {
                        t.row(vec![format!("2^{k}"), bucket_range(k), "0".into()]);
                    }
                }
                previous = Some(b.log2);
                t.row(vec![
                    format!("2^{}", b.log2),
                    bucket_range(b.log2),
                    b.count.to_string(),
                    "#".repeat(usize::try_from((b.count * 30).div_ceil(widest)).unwrap_or(30)),
                ]);
            }
            for (label, n) in [("zero", hist.zero), ("negative", hist.negative), ("non-finite", hist.non_finite)] {
                if n > 0 {
                    t.row(vec![label.to_owned(), String::new(), n.to_string(), String::new()]);
                }
            }
            out.push_str(&t.render("    "));
        }
        if !any {
            out.push_str("  (no elements)\n");
        }
        out
    }
}

/// A section-table entry for the dump.
fn section_info(section: &Section) -> SectionInfo {
    let e = &section.entry;
    let mut flag_names = Vec::new();
    if e.flags & FLAG_ZSTD != 0 {
        flag_names.push("zstd".to_owned());
    }
    if e.flags & FLAG_SHUFFLE != 0 {
        flag_names.push("shuffle".to_owned());
    }
    let other = e.flags & !(FLAG_ZSTD | FLAG_SHUFFLE);
    if other != 0 {
        flag_names.push(format!("{other:#x}"));
    }
    #[expect(clippy::cast_precision_loss, reason = "a ratio for display")]
    let ratio = (e.length > 0).then(|| (e.raw_length as f64 / e.length as f64 * 1000.0).round() / 1000.0);
    SectionInfo {
        kind: e.kind,
        name: SectionKind(e.kind).to_string(),
        flags: e.flags,
        flag_names,
        offset: e.offset,
        length: e.length,
        raw_length: e.raw_length,
        ratio,
        record_size: e.record_size,
        record_count: section.record_count(),
        checksum: e.checksum,
    }
}

/// The images one representation samples and their bytes in `IMAGE_DATA` (spec §6.7).
#[derive(Debug, Serialize)]
struct TextureUse {
    /// `materials` (the sources' images: triangles, points, LoD chain), `planes` (impostor
    /// atlases and leaf slots), `billboards`, `octahedral` (octahedral impostors' images that no
    /// billboard samples: the views share the billboards' atlas, spec §6.13.1), or `unused`.
    representation: &'static str,
    /// The images, by index.
    images: Vec<u32>,
    /// Their formats' names, each once, in image order.
    formats: Vec<String>,
    /// Their data bytes (each image once).
    bytes: u64,
}

impl TextureUse {
    /// Per representation that samples images, its images and bytes; an image no record names is
    /// `unused`. Empty without images.
    fn of(container: &Container) -> Vec<Self> {
        let images = container.images();
        let mut used = vec![false; images.len()];
        let mut uses = Vec::new();
        let mut billboard_images: Vec<u32> = container.billboards().iter().map(|b| b.image).collect();
        billboard_images.sort_unstable();
        billboard_images.dedup();
        // The octahedral impostors' views lie in the billboards' atlas (spec §6.13.1), counted
        // there; an image of theirs that no billboard samples is theirs.
        let octahedral_images: Vec<u32> = container
            .octahedral()
            .iter()
            .map(|o| o.image)
            .filter(|i| billboard_images.binary_search(i).is_err())
            .collect();
        let named: [(&'static str, Vec<u32>); 4] = [
            ("materials", container.materials().iter().map(|m| m.image).collect()),
            ("planes", container.planes().iter().map(|p| p.image).collect()),
            ("billboards", billboard_images),
            ("octahedral", octahedral_images),
        ];
        for (representation, mut list) in named {
            list.sort_unstable();
            list.dedup();
            list.retain(|&i| (i as usize) < images.len());
            for &i in &list {
                used[i as usize] = true;
            }
            if !list.is_empty() {
                uses.push(Self::new(representation, list, images));
            }
        }
        #[expect(clippy::cast_possible_truncation, reason = "image indices are u32")]
        let unused: Vec<u32> = (0..images.len()).filter(|&i| !used[i]).map(|i| i as u32).collect();
        if !unused.is_empty() {
            uses.push(Self::new("unused", unused, images));
        }
        uses
    }

    fn new(representation: &'static str, list: Vec<u32>, images: &[ImageRecord]) -> Self {
        let mut formats: Vec<String> = Vec::new();
        let mut bytes = 0;
        for &i in &list {
            let record = &images[i as usize];
            bytes += record.data_length;
            let name = image_format_name(record.format);
            if !formats.contains(&name) {
                formats.push(name);
            }
        }
        Self { representation, images: list, formats, bytes }
    }

    /// The text form: a `textures` block, empty without images.
    fn text(uses: &[Self]) -> String {
        if uses.is_empty() {
            return String::new();
        }
        let mut out = String::from(
            "
textures (bytes of IMAGE_DATA per representation)
",
        );
        for u in uses {
            out.push_str(&format!(
                "  {:<11}{:>12} bytes, {} image(s), {}
",
                u.representation,
                u.bytes,
                u.images.len(),
                u.formats.join(", ")
            ));
        }
        out
    }
}

/// The spec's name of an image `format` value (spec §6.7), or `format N` for values this version
/// does not define.
fn image_format_name(format: u32) -> String {
    use treelod_format::image_format;
    match format {
        image_format::RGBA8_SRGB => "RGBA8_SRGB".to_owned(),
        image_format::RGBA8_LINEAR => "RGBA8_LINEAR".to_owned(),
        image_format::PNG => "PNG".to_owned(),
        image_format::JPEG => "JPEG".to_owned(),
        image_format::LEAF_SLOTS => "LEAF_SLOTS".to_owned(),
        image_format::BC7_SRGB => "BC7_SRGB".to_owned(),
        image_format::BC7_LINEAR => "BC7_LINEAR".to_owned(),
        other => format!("format {other}"),
    }
}

/// The name of a material class value (spec §6.6).
fn class_name(class: u32) -> String {
    match class {
        material_class::BARK => "bark".into(),
        material_class::LEAF => "leaf".into(),
        material_class::OTHER => "other".into(),
        other => format!("unknown({other})"),
    }
}

/// `[x, y, z]` with the shortest exact form of each value.
fn vec3(v: [f32; 3]) -> String {
    format!("[{}, {}, {}]", v[0], v[1], v[2])
}

/// `[2^k, 2^(k+1))` for the text form.
fn bucket_range(k: i32) -> String {
    format!("[{}, {})", power_of_two(k), power_of_two(k + 1))
}

/// `2^k` as a decimal for moderate `k`, in exponent form beyond.
fn power_of_two(k: i32) -> String {
    let v = 2f64.powi(k);
    if (-20..=30).contains(&k) { v.to_string() } else { format!("{v:e}") }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_log2_is_exact_at_powers_of_two_and_for_subnormals() {
        assert_eq!(floor_log2(1.0), 0);
        assert_eq!(floor_log2(0.999_999_94), -1);
        assert_eq!(floor_log2(0.5), -1);
        assert_eq!(floor_log2(3.0), 1);
        assert_eq!(floor_log2(f32::MAX), 127);
        assert_eq!(floor_log2(f32::from_bits(1)), -149);
        assert_eq!(floor_log2(f32::MIN_POSITIVE), -126);
        assert_eq!(floor_log2(f32::MIN_POSITIVE / 2.0), -127);
    }

    #[test]
    fn histogram_counts_special_values_apart_and_keeps_non_empty_buckets() {
        let h = Histogram::new("size", [0.3, 1.5, 0.0, -1.0, f32::NAN, f32::INFINITY].into_iter());
        assert_eq!((h.count, h.zero, h.negative, h.non_finite), (6, 1, 1, 2));
        let buckets: Vec<(i32, u64)> = h.buckets.iter().map(|b| (b.log2, b.count)).collect();
        assert_eq!(buckets, [(-2, 1), (0, 1)]);
    }
}
