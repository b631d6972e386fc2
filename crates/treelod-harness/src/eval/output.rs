//! What `treelod eval` writes: the table on stdout, the per-frame CSV, the JSON summary and the
//! contact sheet.

use std::fmt::Write as _;
use std::path::PathBuf;

use serde::Serialize;
use treelod_render::offscreen::Image;

use super::metrics::{self, Coverage, LinearImage, Mask};
use super::{Adapter, Availability, Report, Row, SheetFrame, TechniqueName, TextureBytes};
use crate::table::{Align, Table};
use treelod_render::{Primitive, Technique};

/// What the time columns measure, said wherever they appear.
fn timing(timestamps: bool) -> &'static str {
    if timestamps {
        "prepare ms: wall clock of selection and submission; GPU ms: the render pass from GPU timestamp queries; \
         wall ms: wall clock of prepare + render + read-back"
    } else {
        "prepare ms: wall clock of selection and submission; GPU ms: none (the adapter offers no timestamp \
         queries); wall ms: wall clock of prepare + render + read-back"
    }
}
/// Width in pixels of the grey lines between the contact sheet's panels.
const GAP: u32 = 2;
/// Grey of those lines, sRGB.
const GAP_GREY: u8 = 128;

/// Per-technique figures over all frames.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// Frames measured.
    pub frames: usize,
    /// Means per frame.
    pub mean: Means,
    /// Sums over the frames.
    pub total: Totals,
    /// Precision, Recall and Q of all frames' pixels taken together (from the summed counts).
    pub pooled: Pooled,
}

/// Means per frame of one technique.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Means {
    /// Primitives submitted, every kind ([`Row::primitives`]).
    pub primitives: f64,
    /// Triangles submitted.
    pub triangles: f64,
    /// Points submitted.
    pub points: f64,
    /// Bytes of the records submitted, every kind ([`Row::geometry_bytes`]).
    pub geometry_bytes: f64,
    /// Bytes of model data resident on the GPU.
    pub bytes_resident: f64,
    /// True positive pixels.
    pub tp: f64,
    /// False positive pixels.
    pub fp: f64,
    /// False negative pixels.
    #[serde(rename = "fn")]
    pub fn_: f64,
    /// Precision.
    pub precision: f64,
    /// Recall.
    pub recall: f64,
    /// Neubert's Q.
    pub q: f64,
    /// Multi-scale RMSE summary (mean over levels).
    pub rmse: f64,
    /// Multi-scale RMSE per level, finest first.
    pub rmse_levels: Vec<f64>,
    /// Mean FLIP error against the reference.
    pub flip: f64,
    /// Temporal noise over frames 1.. (`None` with fewer than two frames).
    pub temporal_noise: Option<f64>,
    /// The reference's temporal noise over the same frames.
    pub reference_temporal_noise: Option<f64>,
    /// Wall milliseconds of `prepare` alone.
    pub prepare_ms: f64,
    /// GPU milliseconds of the render pass (`None` without timestamp queries).
    pub gpu_ms: Option<f64>,
    /// Wall milliseconds of prepare + render + read-back.
    pub wall_ms: f64,
}

/// Sums over the frames of one technique.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Totals {
    /// Primitives submitted, every kind.
    pub primitives: u64,
    /// Triangles submitted.
    pub triangles: u64,
    /// Points submitted.
    pub points: u64,
    /// Bytes of the records submitted, every kind.
    pub geometry_bytes: u64,
    /// True positive pixels.
    pub tp: u64,
    /// False positive pixels.
    pub fp: u64,
    /// False negative pixels.
    #[serde(rename = "fn")]
    pub fn_: u64,
}

/// Precision, Recall and Q of summed pixel counts.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Pooled {
    /// Precision.
    pub precision: f64,
    /// Recall.
    pub recall: f64,
    /// Q.
    pub q: f64,
}

/// The summary of the rows of `technique`.
#[must_use]
pub fn summarise(rows: &[Row], technique: TechniqueName) -> Summary {
    let rows: Vec<&Row> = rows.iter().filter(|r| r.technique == technique).collect();
    let n = rows.len().max(1) as f64;
    let mean = |f: &dyn Fn(&Row) -> f64| rows.iter().map(|r| f(r)).sum::<f64>() / n;
    let mean_of = |values: Vec<f64>| (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
    let levels = rows.first().map_or(0, |r| r.rmse.levels.len());
    let total = Totals {
        primitives: rows.iter().map(|r| r.primitives()).sum(),
        triangles: rows.iter().map(|r| r.stats.submitted[Primitive::Triangle]).sum(),
        points: rows.iter().map(|r| r.stats.submitted[Primitive::Point]).sum(),
        geometry_bytes: rows.iter().map(|r| r.geometry_bytes()).sum(),
        tp: rows.iter().map(|r| r.coverage.tp).sum(),
        fp: rows.iter().map(|r| r.coverage.fp).sum(),
        fn_: rows.iter().map(|r| r.coverage.fn_).sum(),
    };
    let pooled = Coverage { tp: total.tp, fp: total.fp, fn_: total.fn_ };
    Summary {
        frames: rows.len(),
        mean: Means {
            primitives: mean(&|r| r.primitives() as f64),
            triangles: mean(&|r| r.stats.submitted[Primitive::Triangle] as f64),
            points: mean(&|r| r.stats.submitted[Primitive::Point] as f64),
            geometry_bytes: mean(&|r| r.geometry_bytes() as f64),
            bytes_resident: mean(&|r| r.stats.bytes_resident as f64),
            tp: mean(&|r| r.coverage.tp as f64),
            fp: mean(&|r| r.coverage.fp as f64),
            fn_: mean(&|r| r.coverage.fn_ as f64),
            precision: mean(&|r| r.coverage.precision()),
            recall: mean(&|r| r.coverage.recall()),
            q: mean(&|r| r.coverage.quality()),
            rmse: mean(&|r| r.rmse.summary()),
            rmse_levels: (0..levels).map(|l| mean(&|r| r.rmse.levels.get(l).copied().unwrap_or(0.0))).collect(),
            flip: mean(&|r| r.flip),
            temporal_noise: mean_of(rows.iter().filter_map(|r| r.noise).collect()),
            reference_temporal_noise: mean_of(rows.iter().filter_map(|r| r.reference_noise).collect()),
            prepare_ms: mean(&|r| r.prepare_ms),
            gpu_ms: mean_of(rows.iter().filter_map(|r| r.gpu_ms).collect()),
            wall_ms: mean(&|r| r.wall_ms),
        },
        total,
        pooled: Pooled { precision: pooled.precision(), recall: pooled.recall(), q: pooled.quality() },
    }
}

/// Bands of the scene's projected height, pixels ([`super::projected_height`]), largest first:
/// `(lowest, label)`, each band from its lowest height up to the previous band's. The sizes on
/// screen at which a tree's look changes class: a close-up, a near tree, the mid field, the far
/// field, and a few pixels.
pub const BANDS: [(f64, &str); 5] =
    [(512.0, ">= 512 px"), (128.0, "128-512 px"), (32.0, "32-128 px"), (8.0, "8-32 px"), (0.0, "< 8 px")];

/// The index in [`BANDS`] of a projected height.
#[must_use]
pub fn band_of(height: f64) -> usize {
    BANDS.iter().position(|&(lowest, _)| height >= lowest).unwrap_or(BANDS.len() - 1)
}

/// One technique's figures over the frames of one band of projected height.
#[derive(Clone, Debug, Serialize)]
pub struct BandSummary {
    /// The band's label ([`BANDS`]).
    pub band: &'static str,
    /// The technique's name.
    pub technique: &'static str,
    /// Frames of the band.
    pub frames: usize,
    /// Mean primitives per frame, every kind.
    pub primitives: f64,
    /// Mean precision, recall and Q.
    pub precision: f64,
    /// Mean recall.
    pub recall: f64,
    /// Mean Q.
    pub q: f64,
    /// Mean multi-scale RMSE.
    pub rmse: f64,
    /// Mean FLIP.
    pub flip: f64,
    /// The first technique of the band (in order; the full mesh, drawn as the reference or at
    /// 1×, not counted) with at least [`DOMINATED_ERROR`] less error and [`DOMINATED_COST`]
    /// fewer primitives: one that is better and cheaper at this size on screen.
    pub dominated_by: Option<&'static str>,
}

/// A technique is dominated in a band where another has at most this share of its mean RMSE
/// (5 % less)...
pub const DOMINATED_ERROR: f64 = 0.95;

/// ...and at most this share of its mean primitives (10 % fewer).
pub const DOMINATED_COST: f64 = 0.90;

/// Per band of projected height (largest first) and measured technique (in order), the means of
/// its frames, and which technique dominates it there, if one does; bands without frames are
/// left out.
#[must_use]
pub fn by_band(report: &Report) -> Vec<BandSummary> {
    let mut out = Vec::new();
    for (band, &(_, label)) in BANDS.iter().enumerate() {
        for (name, availability) in &report.techniques {
            if *availability != Availability::Measured {
                continue;
            }
            let rows: Vec<&Row> = report
                .rows
                .iter()
                .filter(|r| r.technique == *name)
                .filter(|r| report.heights.get(r.frame).is_some_and(|&h| band_of(h) == band))
                .collect();
            if rows.is_empty() {
                continue;
            }
            let n = rows.len() as f64;
            let mean = |f: &dyn Fn(&Row) -> f64| rows.iter().map(|r| f(r)).sum::<f64>() / n;
            out.push(BandSummary {
                band: label,
                technique: name.name(),
                frames: rows.len(),
                primitives: mean(&|r| r.primitives() as f64),
                precision: mean(&|r| r.coverage.precision()),
                recall: mean(&|r| r.coverage.recall()),
                q: mean(&|r| r.coverage.quality()),
                rmse: mean(&|r| r.rmse.summary()),
                flip: mean(&|r| r.flip),
                dominated_by: None,
            });
        }
    }
    mark_dominated(&mut out);
    out
}

/// Sets each summary's [`BandSummary::dominated_by`] from the others of its band.
fn mark_dominated(bands: &mut [BandSummary]) {
    let full = [TechniqueName::FULL.name(), TechniqueName::Full1x.name()];
    let dominated: Vec<Option<&'static str>> = bands
        .iter()
        .map(|b| {
            bands
                .iter()
                .filter(|o| o.band == b.band && o.technique != b.technique && !full.contains(&o.technique))
                .find(|o| o.rmse <= DOMINATED_ERROR * b.rmse && o.primitives <= DOMINATED_COST * b.primitives)
                .map(|o| o.technique)
        })
        .collect();
    for (b, by) in bands.iter_mut().zip(dominated) {
        b.dominated_by = by;
    }
}

/// The description of a technique, for the JSON summary.
pub fn description(technique: TechniqueName) -> &'static str {
    match technique {
        TechniqueName::Full1x => "the full mesh drawn at the image size (no supersampling): the aliasing floor",
        TechniqueName::Policy => {
            "the policy: per tree, the cheapest representation whose calibrated error is within the target (the default renderer)"
        }
        TechniqueName::Technique(Technique::Full) => {
            "the full mesh drawn as the reference is (supersampled, box-filtered): must read perfect"
        }
        TechniqueName::Technique(t) => t.description(),
    }
}

/// `value` with `digits` decimals, `-` for none.
fn opt(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

/// One line per technique that is not measured: `technique NAME: STATUS: REASON`.
#[must_use]
pub fn unavailable(techniques: &[(TechniqueName, Availability)]) -> String {
    let mut out = String::new();
    for (name, availability) in techniques {
        if let Some(reason) = availability.reason() {
            let _ = writeln!(out, "technique {}: {}: {reason}", name.name(), availability.status());
        }
    }
    out
}

/// The report as text: a heading, absent techniques, the table, the files written.
#[must_use]
pub fn text(report: &Report, files: [&Option<PathBuf>; 6]) -> String {
    let (w, h) = report.size;
    let k = report.supersample;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {} frame(s) ({}), {w}x{h}; reference: the full mesh drawn at {}x{} and box-filtered (supersample {k}){}",
        report.input.display(),
        report.poses.len(),
        report.camera_source,
        w * k,
        h * k,
        if report.msaa > 1 {
            format!("; techniques but full: {}x MSAA, alpha to coverage", report.msaa)
        } else {
            String::new()
        },
    );
    let _ = writeln!(
        out,
        "adapter: {} ({}, {}); times: {}",
        report.adapter.name,
        report.adapter.backend,
        report.adapter.device_type,
        timing(report.timestamps)
    );
    out.push_str(&unavailable(&report.techniques));
    let mut table = Table::new(&[
        ("frame", Align::Right),
        ("technique", Align::Left),
        ("primitives", Align::Right),
        ("triangles", Align::Right),
        ("points", Align::Right),
        ("geometry KiB", Align::Right),
        ("texture KiB", Align::Right),
        ("TP", Align::Right),
        ("FP", Align::Right),
        ("FN", Align::Right),
        ("P", Align::Right),
        ("R", Align::Right),
        ("Q", Align::Right),
        ("RMSE", Align::Right),
        ("FLIP", Align::Right),
        ("noise", Align::Right),
        ("ref noise", Align::Right),
        ("prepare ms", Align::Right),
        ("GPU ms", Align::Right),
        ("wall ms", Align::Right),
    ]);
    for row in &report.rows {
        table.row(vec![
            row.frame.to_string(),
            row.technique.name().to_owned(),
            row.primitives().to_string(),
            row.stats.submitted[Primitive::Triangle].to_string(),
            row.stats.submitted[Primitive::Point].to_string(),
            format!("{:.1}", row.geometry_bytes() as f64 / 1024.0),
            format!("{:.1}", textures_of(report, row.technique).total() as f64 / 1024.0),
            row.coverage.tp.to_string(),
            row.coverage.fp.to_string(),
            row.coverage.fn_.to_string(),
            format!("{:.4}", row.coverage.precision()),
            format!("{:.4}", row.coverage.recall()),
            format!("{:.4}", row.coverage.quality()),
            format!("{:.5}", row.rmse.summary()),
            format!("{:.5}", row.flip),
            opt(row.noise, 5),
            opt(row.reference_noise, 5),
            format!("{:.1}", row.prepare_ms),
            opt(row.gpu_ms, 2),
            format!("{:.1}", row.wall_ms),
        ]);
    }
    for (name, availability) in &report.techniques {
        if *availability != Availability::Measured {
            continue;
        }
        let s = summarise(&report.rows, *name);
        let m = &s.mean;
        table.row(vec![
            "mean".to_owned(),
            name.name().to_owned(),
            format!("{:.0}", m.primitives),
            format!("{:.0}", m.triangles),
            format!("{:.0}", m.points),
            format!("{:.1}", m.geometry_bytes / 1024.0),
            format!("{:.1}", textures_of(report, *name).total() as f64 / 1024.0),
            format!("{:.0}", m.tp),
            format!("{:.0}", m.fp),
            format!("{:.0}", m.fn_),
            format!("{:.4}", m.precision),
            format!("{:.4}", m.recall),
            format!("{:.4}", m.q),
            format!("{:.5}", m.rmse),
            format!("{:.5}", m.flip),
            opt(m.temporal_noise, 5),
            opt(m.reference_temporal_noise, 5),
            format!("{:.1}", m.prepare_ms),
            opt(m.gpu_ms, 2),
            format!("{:.1}", m.wall_ms),
        ]);
    }
    out.push_str(&table.render(""));
    let _ = writeln!(out, "{}", textures_text(report));
    let bands = by_band(report);
    if !bands.is_empty() {
        let _ = writeln!(
            out,
            "by projected height (the scene's bounds on screen at their centre's distance, pixels; means per frame):"
        );
        let mut table = Table::new(&[
            ("height", Align::Left),
            ("technique", Align::Left),
            ("frames", Align::Right),
            ("primitives", Align::Right),
            ("P", Align::Right),
            ("R", Align::Right),
            ("Q", Align::Right),
            ("RMSE", Align::Right),
            ("FLIP", Align::Right),
            ("dominated by", Align::Left),
        ]);
        for b in &bands {
            table.row(vec![
                b.band.to_owned(),
                b.technique.to_owned(),
                b.frames.to_string(),
                format!("{:.0}", b.primitives),
                format!("{:.4}", b.precision),
                format!("{:.4}", b.recall),
                format!("{:.4}", b.q),
                format!("{:.5}", b.rmse),
                format!("{:.5}", b.flip),
                b.dominated_by.unwrap_or("-").to_owned(),
            ]);
        }
        out.push_str(&table.render(""));
    }
    let names = ["csv", "json", "sheet", "quality plot", "frame plot", "band plot"];
    files_written(&mut out, &names, &files, &report.sheet);
    out
}

/// The lines naming the files written, `what: path`, in the order of `names` and `files` (those
/// not asked for skipped); the `sheet` line adds the frames of `sheet` and its columns (also
/// `treelod bench`'s).
pub(crate) fn files_written(out: &mut String, names: &[&str], files: &[&Option<PathBuf>], sheet: &[SheetFrame]) {
    for (what, file) in names.iter().zip(files) {
        if let Some(file) = file {
            let _ = write!(out, "{what}: {}", file.display());
            if *what == "sheet" {
                let frames: Vec<String> = sheet.iter().map(|f| f.frame.to_string()).collect();
                let _ = write!(
                    out,
                    " (frames {}; columns: reference, then each technique drawn and its difference)",
                    frames.join(", ")
                );
            }
            out.push('\n');
        }
    }
}

/// The texture bytes `technique` samples ([`TextureBytes`]); none for a technique the report
/// does not list.
fn textures_of(report: &Report, technique: TechniqueName) -> TextureBytes {
    report
        .techniques
        .iter()
        .position(|(name, _)| *name == technique)
        .and_then(|i| report.textures.get(i))
        .cloned()
        .unwrap_or_default()
}

/// The line saying what the texture column counts, with each measured technique's atlas bytes and
/// format.
fn textures_text(report: &Report) -> String {
    let atlases: Vec<String> = report
        .techniques
        .iter()
        .filter(|(_, a)| *a == Availability::Measured)
        .map(|(name, _)| (name, textures_of(report, *name)))
        .filter(|(_, t)| t.atlas_bytes > 0)
        .map(|(name, t)| format!("{} {} bytes {}", name.name(), t.atlas_bytes, t.atlas_formats.join("+")))
        .collect();
    format!(
        "texture KiB: the container images a technique samples, as stored (the sources' images{}){}",
        if atlases.is_empty() { "" } else { ", and its atlases" },
        if atlases.is_empty() { String::new() } else { format!("; atlases: {}", atlases.join(", ")) }
    )
}

/// One CSV row per frame and technique, with a header line.
#[must_use]
pub fn csv(report: &Report) -> String {
    let levels = report.rows.first().map_or(0, |r| r.rmse.levels.len());
    let mut out = String::from(
        "frame,technique,eye_x,eye_y,eye_z,target_x,target_y,target_z,instances_visible,triangles,points,\
         geometry_bytes,bytes_resident,tp,fp,fn,precision,recall,q,rmse",
    );
    for l in 0..levels {
        let _ = write!(out, ",rmse_{}px", 1u64 << l);
    }
    out.push_str(
        ",flip,temporal_noise,reference_temporal_noise,prepare_ms,gpu_ms,wall_ms,quads,primitives,ellipsoids,lines,\
         texture_bytes,atlas_bytes\n",
    );
    let optional = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
    for row in &report.rows {
        let pose = report
            .poses
            .get(row.frame)
            .copied()
            .unwrap_or(super::path::Pose { eye: glam::Vec3::ZERO, target: glam::Vec3::ZERO });
        let _ = write!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            row.frame,
            row.technique.name(),
            pose.eye.x,
            pose.eye.y,
            pose.eye.z,
            pose.target.x,
            pose.target.y,
            pose.target.z,
            row.stats.instances_visible,
            row.stats.submitted[Primitive::Triangle],
            row.stats.submitted[Primitive::Point],
            row.geometry_bytes(),
            row.stats.bytes_resident,
            row.coverage.tp,
            row.coverage.fp,
            row.coverage.fn_,
            row.coverage.precision(),
            row.coverage.recall(),
            row.coverage.quality(),
            row.rmse.summary(),
        );
        for level in &row.rmse.levels {
            let _ = write!(out, ",{level}");
        }
        let textures = textures_of(report, row.technique);
        let _ = writeln!(
            out,
            ",{},{},{},{:.3},{},{:.3},{},{},{},{},{},{}",
            row.flip,
            optional(row.noise),
            optional(row.reference_noise),
            row.prepare_ms,
            row.gpu_ms.map(|v| format!("{v:.4}")).unwrap_or_default(),
            row.wall_ms,
            super::quads(&row.stats),
            row.primitives(),
            row.stats.submitted[Primitive::Ellipsoid],
            row.stats.submitted[Primitive::Line],
            textures.total(),
            textures.atlas_bytes,
        );
    }
    out
}

/// The JSON summary, as written.
#[derive(Serialize)]
struct JsonReport<'a> {
    input: String,
    frames: usize,
    cameras: &'a str,
    size: [u32; 2],
    supersample: u32,
    msaa: u32,
    reference_size: [u32; 2],
    fov_degrees: f32,
    background: String,
    colour_space: &'static str,
    rmse_levels: usize,
    rmse_summary: &'static str,
    flip: &'static str,
    adapter: &'a Adapter,
    timing: &'static str,
    techniques: Vec<JsonTechnique>,
    bands: Vec<BandSummary>,
    poses: Vec<JsonPose>,
}

#[derive(Serialize)]
struct JsonTechnique {
    name: &'static str,
    status: &'static str,
    reason: Option<String>,
    description: &'static str,
    /// The container images it samples, bytes as stored.
    textures: TextureBytes,
    summary: Option<Summary>,
}

#[derive(Serialize)]
struct JsonPose {
    eye: [f32; 3],
    target: [f32; 3],
    /// The scene's height on screen, pixels.
    projected_height: f64,
}

/// The JSON summary, pretty-printed, with a final newline.
///
/// # Errors
/// If serialisation fails (it does not for these types).
pub fn json(report: &Report) -> Result<String, serde_json::Error> {
    let (w, h) = report.size;
    let k = report.supersample;
    let [r, g, b] = report.background;
    let value = JsonReport {
        input: report.input.display().to_string(),
        frames: report.poses.len(),
        cameras: &report.camera_source,
        size: [w, h],
        supersample: k,
        msaa: report.msaa,
        reference_size: [w * k, h * k],
        fov_degrees: report.fov_degrees,
        background: format!("{r:02x}{g:02x}{b:02x}"),
        colour_space: "linear",
        rmse_levels: metrics::level_count(w, h),
        rmse_summary: "mean over levels",
        flip: "mean of the LDR-FLIP error map against the reference, both 8-bit sRGB, at 67 pixels per degree",
        adapter: &report.adapter,
        timing: timing(report.timestamps),
        techniques: report
            .techniques
            .iter()
            .map(|(name, availability)| JsonTechnique {
                name: name.name(),
                status: availability.status(),
                reason: availability.reason().map(str::to_owned),
                description: description(*name),
                textures: textures_of(report, *name),
                summary: (*availability == Availability::Measured).then(|| summarise(&report.rows, *name)),
            })
            .collect(),
        bands: by_band(report),
        poses: report
            .poses
            .iter()
            .zip(&report.heights)
            .map(|(p, &h)| JsonPose { eye: p.eye.to_array(), target: p.target.to_array(), projected_height: h })
            .collect(),
    };
    let mut text = serde_json::to_string_pretty(&value)?;
    text.push('\n');
    Ok(text)
}

/// The difference panel of a technique against the reference: red where only the technique
/// covers a pixel (false positive), blue where only the reference does (false negative), else a
/// grey level of the colour error (black where equal; the linear RMS over the channels times 4,
/// white from 0.25 on).
#[must_use]
pub fn difference(reference: (&LinearImage, &Mask), sample: (&LinearImage, &Mask)) -> Vec<[u8; 3]> {
    let (a, am) = reference;
    let (b, bm) = sample;
    a.pixels
        .iter()
        .zip(&b.pixels)
        .zip(am.covered.iter().zip(&bm.covered))
        .map(|((p, q), (&r, &s))| match (r, s) {
            (false, true) => [255, 40, 40],
            (true, false) => [40, 90, 255],
            _ => {
                let e = ((0..3).map(|c| (f64::from(p[c]) - f64::from(q[c])).powi(2)).sum::<f64>() / 3.0).sqrt();
                let v = (4.0 * 255.0 * e).round().clamp(0.0, 255.0) as u8;
                [v, v, v]
            }
        })
        .collect()
}

/// The contact sheet: one row per chosen frame; the reference, then per measured technique its
/// image and its [`difference`]; panels separated by grey lines.
#[must_use]
pub fn contact_sheet(report: &Report) -> Image {
    sheet(report.size, &report.sheet)
}

/// A contact sheet of `frames`, images of `size` pixels (also `treelod bench --sheet`'s): one row
/// per frame; the reference, then per technique its image and its [`difference`]; panels
/// separated by grey lines. A row with fewer techniques than the widest leaves its last panels
/// grey.
#[must_use]
pub fn sheet(size: (u32, u32), frames: &[SheetFrame]) -> Image {
    let (w, h) = size;
    let columns = 1 + 2 * frames.iter().map(|f| f.techniques.len()).max().unwrap_or(0) as u32;
    let rows = frames.len().max(1) as u32;
    let width = columns * w + (columns - 1) * GAP;
    let height = rows * h + (rows - 1) * GAP;
    let mut rgba: Vec<u8> = [GAP_GREY, GAP_GREY, GAP_GREY, 255].repeat(width as usize * height as usize);
    let mut put = |row: u32, column: u32, pixels: &[[u8; 3]]| {
        let (x0, y0) = (column * (w + GAP), row * (h + GAP));
        for (i, p) in pixels.iter().enumerate().take(w as usize * h as usize) {
            let (x, y) = (x0 + i as u32 % w, y0 + i as u32 / w);
            let at = (y as usize * width as usize + x as usize) * 4;
            rgba[at..at + 4].copy_from_slice(&[p[0], p[1], p[2], 255]);
        }
    };
    let srgb =
        |image: &LinearImage| -> Vec<[u8; 3]> { image.pixels.iter().map(|p| p.map(metrics::linear_to_srgb)).collect() };
    for (row, frame) in frames.iter().enumerate() {
        let row = row as u32;
        let (reference, reference_mask) = (&frame.reference.0, &frame.reference.1);
        put(row, 0, &srgb(reference));
        for (i, (_, image, mask)) in frame.techniques.iter().enumerate() {
            let column = 1 + 2 * i as u32;
            put(row, column, &srgb(image));
            put(row, column + 1, &difference((reference, reference_mask), (image, mask)));
        }
    }
    Image { width, height, rgba }
}

#[cfg(test)]
pub(super) mod tests {
    use treelod_render::{FrameStats, PerPrimitive};

    use super::super::metrics::MultiScaleRmse;
    use super::super::path::Pose;
    use super::super::{Adapter, Report, SheetFrame};
    use super::*;

    fn row(frame: usize, technique: TechniqueName, tp: u64, noise: Option<f64>) -> Row {
        Row {
            frame,
            technique,
            // Triangles, points, planes, billboards, ellipsoids, lines.
            stats: FrameStats { submitted: PerPrimitive([10, 4, 0, 0, 3, 2]), ..FrameStats::default() },
            coverage: Coverage { tp, fp: 1, fn_: 2 },
            rmse: MultiScaleRmse { levels: vec![0.2, 0.1, 0.0] },
            flip: 0.01 * tp as f64,
            noise,
            reference_noise: noise.map(|n| n / 2.0),
            prepare_ms: 1.0,
            gpu_ms: Some(0.5),
            wall_ms: 3.0,
        }
    }

    /// A small report: `spt` measured over two frames, `ellipsoids` absent, one sheet frame.
    pub(in super::super) fn report() -> Report {
        let image = LinearImage::filled(3, 2, [0.5; 3]);
        let mask = Mask { width: 3, height: 2, covered: vec![true, true, false, false, true, false] };
        let mut other = mask.clone();
        other.covered = vec![true, false, true, false, true, false];
        Report {
            input: "demo.treelod".into(),
            camera_source: "--views 2".to_owned(),
            poses: vec![
                Pose { eye: glam::Vec3::new(0.0, 1.0, 5.0), target: glam::Vec3::ZERO },
                Pose { eye: glam::Vec3::new(5.0, 1.0, 0.0), target: glam::Vec3::ZERO },
            ],
            heights: vec![600.0, 20.0],
            size: (3, 2),
            supersample: 2,
            msaa: 1,
            fov_degrees: 50.0,
            background: [255, 255, 255],
            adapter: Adapter {
                name: "test".to_owned(),
                backend: "Vulkan".to_owned(),
                device_type: "Cpu".to_owned(),
                driver: String::new(),
            },
            timestamps: true,
            techniques: vec![
                (TechniqueName::Technique(Technique::Spt), Availability::Measured),
                (
                    TechniqueName::Technique(Technique::Ellipsoids),
                    Availability::Absent("this container holds no ellipsoids".to_owned()),
                ),
            ],
            rows: vec![
                row(0, TechniqueName::Technique(Technique::Spt), 5, None),
                row(1, TechniqueName::Technique(Technique::Spt), 7, Some(0.1)),
            ],
            sheet: vec![SheetFrame {
                frame: 0,
                reference: (image.clone(), mask),
                techniques: vec![(TechniqueName::Technique(Technique::Spt), image, other)],
            }],
            textures: vec![
                TextureBytes { source_bytes: 2048, atlas_bytes: 0, atlas_formats: Vec::new() },
                TextureBytes::default(),
            ],
        }
    }

    #[test]
    fn the_summary_averages_frames_and_pools_counts() {
        let s = summarise(&report().rows, TechniqueName::Technique(Technique::Spt));
        assert_eq!(s.frames, 2);
        let ellipsoid_and_line_bytes = 3 * size_of::<treelod_format::EllipsoidRecord>() as u64
            + 2 * size_of::<treelod_format::LineRecord>() as u64;
        assert_eq!(
            (s.total.tp, s.total.fp, s.total.fn_, s.total.geometry_bytes),
            (12, 2, 4, 2 * (240 + 192 + ellipsoid_and_line_bytes))
        );
        // Ellipsoids and lines are primitives: 10 + 4 + 3 + 2 per frame.
        assert_eq!((s.total.primitives, s.mean.primitives), (38, 19.0));
        assert!((s.mean.precision - (5.0 / 6.0 + 7.0 / 8.0) / 2.0).abs() < 1e-12);
        assert!((s.pooled.precision - 12.0 / 14.0).abs() < 1e-12 && (s.pooled.recall - 12.0 / 16.0).abs() < 1e-12);
        assert_eq!(s.mean.temporal_noise, Some(0.1), "frame 0 has no previous frame");
        assert_eq!(s.mean.reference_temporal_noise, Some(0.05));
        assert!((s.mean.rmse - 0.1).abs() < 1e-12 && s.mean.rmse_levels == [0.2, 0.1, 0.0]);
        assert!((s.mean.flip - 0.06).abs() < 1e-12, "{}", s.mean.flip);
    }

    #[test]
    fn text_csv_and_json_hold_every_row_and_the_absent_technique() {
        let report = report();
        let text = text(&report, [&Some("e.csv".into()), &None, &None, &None, &None, &None]);
        assert!(text.contains("technique ellipsoids: absent: this container holds no ellipsoids"), "{text}");
        assert!(
            text.contains("wall ms") && text.contains("GPU ms: the render pass from GPU timestamp queries"),
            "{text}"
        );
        let frames = text.lines().filter(|l| l.contains(" spt ") && !l.contains(" px ")).count();
        assert_eq!(frames, 3, "two frames and the mean: {text}");
        assert!(text.ends_with("csv: e.csv\n"), "{text}");
        let csv = csv(&report);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3);
        let columns = lines[0].split(',').count();
        assert!(lines.iter().all(|l| l.split(',').count() == columns), "{csv}");
        assert!(
            lines[0].contains(",rmse_1px,rmse_2px,rmse_4px,flip,") && lines[1].starts_with("0,spt,0,1,5,"),
            "{csv}"
        );
        let flip = lines[0].split(',').position(|c| c == "flip").expect("a flip column");
        assert_eq!(lines[2].split(',').nth(flip), Some("0.07"), "{csv}");
        assert!(text.contains(" FLIP ") && text.contains("0.05000"), "{text}");
        let json: serde_json::Value = serde_json::from_str(&json(&report).expect("encodes")).expect("parses");
        assert_eq!(json["techniques"][0]["summary"]["frames"], 2);
        assert_eq!(json["techniques"][1]["status"], "absent");
        assert!(json["techniques"][1]["summary"].is_null());
        assert_eq!(json["adapter"]["backend"], "Vulkan");
        assert_eq!(json["rmse_levels"], 3);
        let flip = json["techniques"][0]["summary"]["mean"]["flip"].as_f64().expect("a mean FLIP");
        assert!((flip - 0.06).abs() < 1e-12, "{flip}");
        // One band per frame here: frame 0 at 600 px, frame 1 at 20 px.
        assert_eq!(json["bands"].as_array().map(Vec::len), Some(2));
        assert_eq!(json["bands"][0]["band"], ">= 512 px");
        assert_eq!(json["bands"][1]["band"], "8-32 px");
        assert_eq!(json["poses"][1]["projected_height"], 20.0);
        assert!(text.contains("by projected height") && text.contains("8-32 px"), "{text}");
    }

    #[test]
    fn a_technique_is_dominated_by_one_both_better_and_cheaper_in_its_band() {
        let summary = |band, technique, primitives, rmse| BandSummary {
            band,
            technique,
            frames: 1,
            primitives,
            precision: 1.0,
            recall: 1.0,
            q: 1.0,
            rmse,
            flip: 0.0,
            dominated_by: None,
        };
        let mut bands = vec![
            summary("8-32 px", "policy", 1000.0, 0.010),
            // Better but not 10 % cheaper, then cheaper but not 5 % better: neither dominates.
            summary("8-32 px", "spt", 901.0, 0.005),
            summary("8-32 px", "impostors", 100.0, 0.0096),
            // Both: dominates the policy.
            summary("8-32 px", "crossed", 899.0, 0.0094),
            // The full mesh never counts; another band does not either.
            summary("8-32 px", "full", 10.0, 0.0),
            summary("32-128 px", "billboard", 1.0, 0.001),
        ];
        mark_dominated(&mut bands);
        let by: Vec<Option<&str>> = bands.iter().map(|b| b.dominated_by).collect();
        assert_eq!(by, [Some("crossed"), None, None, None, None, None]);
    }

    #[test]
    fn heights_fall_into_the_bands_from_the_largest_down() {
        assert_eq!(band_of(4000.0), 0);
        assert_eq!(band_of(512.0), 0);
        assert_eq!(band_of(511.9), 1);
        assert_eq!(band_of(32.0), 2);
        assert_eq!(band_of(8.0), 3);
        assert_eq!(band_of(7.9), 4);
        assert_eq!(band_of(0.0), 4);
        let report = report();
        let bands = by_band(&report);
        assert_eq!(bands.len(), 2);
        assert_eq!((bands[0].frames, bands[1].frames), (1, 1));
        // Frame 0 has 5 true positives, frame 1 has 7.
        assert!((bands[0].precision - 5.0 / 6.0).abs() < 1e-12 && (bands[1].precision - 7.0 / 8.0).abs() < 1e-12);
    }

    #[test]
    fn the_contact_sheet_shows_reference_image_and_difference() {
        let report = report();
        let sheet = contact_sheet(&report);
        assert_eq!((sheet.width, sheet.height), (3 * 3 + 2 * GAP, 2));
        // Difference panel: pixel 1 is a false negative (blue), pixel 2 a false positive (red),
        // pixel 0 equal (black).
        let diff_x = 2 * (3 + GAP);
        assert_eq!(sheet.pixel(diff_x, 0), [0, 0, 0, 255]);
        assert_eq!(sheet.pixel(diff_x + 1, 0), [40, 90, 255, 255]);
        assert_eq!(sheet.pixel(diff_x + 2, 0), [255, 40, 40, 255]);
        assert_eq!(sheet.pixel(3, 0), [GAP_GREY, GAP_GREY, GAP_GREY, 255]);
        assert_eq!(sheet.pixel(0, 0), [188, 188, 188, 255]);
    }
}
