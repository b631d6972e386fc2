//! What `treelod bench` writes: the summary table on stdout, the per-frame CSV, the JSON summary
//! and the PNG plot (drawn with `eval`'s plot helpers).

use std::fmt::Write as _;
use std::path::PathBuf;

use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::Rectangle;
use embedded_graphics::text::{Alignment, Baseline};
use serde::Serialize;
use treelod_render::Technique;
use treelod_render::offscreen::Image;

use super::path::Phase;
use super::{Report, Row};
use crate::eval::plot::{self, Axis, BLACK, Canvas, Panel, REFERENCE};
use crate::eval::{Availability, TechniqueName};
use crate::table::{Align, Table};

/// What the time columns measure, said wherever they appear.
fn timing(report: &Report) -> String {
    let gpu = match (report.rendered, report.timestamps) {
        (false, _) => "none (--no-render)",
        (true, true) => "the render pass from GPU timestamp queries",
        (true, false) => "none (the adapter offers no timestamp queries)",
    };
    format!(
        "selection ms: wall clock of Renderer::prepare (culling, per-cell selection, streaming, draw records); \
         full: the runtime's selection with thresholds 0 over all instances (counted, not drawn); GPU ms: {gpu}{}",
        if report.quality.is_some() { " (full: the reference's pass)" } else { "" }
    )
}

/// Mean, median, 95th percentile and maximum of a series.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (the mean of the middle two for an even count).
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Largest value.
    pub max: f64,
}

/// The spread of `values`; `None` for none.
#[must_use]
pub fn spread(values: &[f64]) -> Option<Spread> {
    if values.is_empty() {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let median = if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) };
    let rank = ((0.95 * n as f64).ceil() as usize).clamp(1, n);
    Some(Spread { mean: sorted.iter().sum::<f64>() / n as f64, median, p95: sorted[rank - 1], max: sorted[n - 1] })
}

/// Per-technique figures over all frames.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// Frames measured.
    pub frames: usize,
    /// Selection milliseconds.
    pub selection_ms: Spread,
    /// Mean instances in view.
    pub instances_visible: f64,
    /// Mean triangles submitted.
    pub triangles: f64,
    /// Mean points submitted.
    pub points: f64,
    /// Mean ellipsoids submitted.
    pub ellipsoids: f64,
    /// Mean branch lines submitted.
    pub lines: f64,
    /// Mean primitives (triangles + points + quads + ellipsoids + lines).
    pub primitives: f64,
    /// Most primitives in a frame.
    pub primitives_max: u64,
    /// Mean primitives in the cut (what is rasterised: the points outside the cut left out).
    pub primitives_in_cut: f64,
    /// The full mesh's mean primitives over this technique's in the cut.
    pub full_ratio_in_cut: Option<f64>,
    /// The full mesh's mean primitives over this technique's (when `full` or `full-1x` was
    /// measured too; `full`'s where both were, the same counts).
    pub full_ratio: Option<f64>,
    /// Mean instances drawn with pruned leaves.
    pub instances_pruned: Option<f64>,
    /// Mean bytes streamed per frame.
    pub bytes_uploaded: Option<f64>,
    /// Mean draws made coarser while their data streamed in.
    pub ranges_clamped: Option<f64>,
    /// GPU milliseconds of the render pass.
    pub gpu_ms: Option<Spread>,
    /// Mean primitives of the shadow pass (with `--shadows`).
    pub shadow_primitives: Option<f64>,
    /// Those over the main pass's mean primitives.
    pub shadow_ratio: Option<f64>,
    /// Mean trees in a transition between techniques, drawn with both.
    pub transitions: Option<f64>,
    /// Mean precision against the reference.
    pub precision: Option<f64>,
    /// Mean recall.
    pub recall: Option<f64>,
    /// Mean Q.
    pub q: Option<f64>,
    /// Mean multi-scale RMSE.
    pub rmse: Option<f64>,
    /// Mean FLIP error.
    pub flip: Option<f64>,
    /// Mean temporal noise (frames 1..; `Row::noise`).
    pub noise: Option<f64>,
    /// The reference's mean temporal noise over the same frames.
    pub reference_noise: Option<f64>,
    /// The techniques its trees were drawn with, in [`Technique::ALL`]'s order, those with a
    /// tree or a primitive in some frame: the policy's mix, or a forced technique and the point
    /// tree drawing the trees whose models lack its data. Empty for the counted full mesh.
    pub drawn_with: Vec<DrawnWith>,
    /// For the policy in budget mode ([`Report::budget`]), how its frames met the budget.
    pub budget: Option<BudgetSummary>,
}

/// How the frames of the policy's budget mode met its budget: each frame's primitives (every
/// draw, those of the techniques trees in a transition leave included, as the steering counts
/// them) against it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct BudgetSummary {
    /// The budget, primitives per frame.
    pub budget: u64,
    /// The median frame's primitives (as [`Spread::median`]).
    pub median: f64,
    /// Frames over the budget by more than a tenth of it.
    pub over_tenth: usize,
    /// Of those, the frames within a tenth over it without the draws of the techniques trees in
    /// a transition are leaving: over only by the transitions' fading.
    pub over_tenth_fading: usize,
    /// Frames over twice the budget.
    pub over_twice: usize,
    /// Frames under half of the budget.
    pub under_half: usize,
    /// Of those, the frames drawn at the finest steering (`s_min` and the policy target at their
    /// floors, `BudgetFrame::finest`): the forest at the finest the policy chooses cost less than
    /// half the budget, so there was nothing left to spend it on.
    pub under_half_finest: usize,
    /// Frames in all.
    pub frames: usize,
}

impl BudgetSummary {
    /// The summary of frames of `primitives` each, `leaving` of them the draws of trees in a
    /// transition, drawn at the finest steering or not (`(primitives, leaving, finest)` per
    /// frame), against `budget`.
    #[must_use]
    pub fn of(budget: u64, frames: &[(u64, u64, bool)]) -> Self {
        let primitives: Vec<u64> = frames.iter().map(|&(p, _, _)| p).collect();
        #[expect(clippy::cast_precision_loss, reason = "a median needs no integer precision")]
        let all: Vec<f64> = primitives.iter().map(|&p| p as f64).collect();
        let count = |f: &dyn Fn(u128) -> bool| primitives.iter().filter(|&&p| f(u128::from(p))).count();
        // In whole numbers: `p > 1.1 N` as `10 p > 11 N`, `p < N / 2` as `2 p < N`.
        let n = u128::from(budget);
        let over = |p: u64| 10 * u128::from(p) > 11 * n;
        Self {
            budget,
            median: spread(&all).map_or(0.0, |s| s.median),
            over_tenth: count(&|p| 10 * p > 11 * n),
            over_tenth_fading: frames.iter().filter(|&&(p, l, _)| over(p) && !over(p.saturating_sub(l))).count(),
            over_twice: count(&|p| p > 2 * n),
            under_half: count(&|p| 2 * p < n),
            under_half_finest: frames.iter().filter(|&&(p, _, finest)| finest && 2 * u128::from(p) < n).count(),
            frames: primitives.len(),
        }
    }

    /// The summary in one line for `technique`'s report.
    #[must_use]
    pub fn line(&self, technique: &str) -> String {
        format!(
            "{technique} budget {} primitives a frame: median frame {:.0}; of {} frames {} over it by more than 10 % ({} \
             of them only by the draws of trees in a transition), {} over twice it, {} under half of it (the draws of \
             trees in a transition counted; {} of them at the finest steering, nothing left to spend)",
            self.budget,
            self.median,
            self.frames,
            self.over_tenth,
            self.over_tenth_fading,
            self.over_twice,
            self.under_half,
            self.under_half_finest
        )
    }
}

/// Of a technique's frames, the trees drawn with one technique and what they submitted.
#[derive(Clone, Debug, Default, Serialize)]
pub struct DrawnWith {
    /// The technique the trees were drawn with ([`Technique::name`]).
    pub technique: &'static str,
    /// Mean visible trees per frame drawn with it (`FrameStats::instances`).
    pub trees: f64,
    /// Mean primitives per frame they submitted (`FrameStats::by_technique`).
    pub primitives: f64,
    /// Those over all primitives submitted.
    pub share: f64,
}

/// The mix of techniques of `rows` ([`Summary::drawn_with`]).
fn drawn_with(rows: &[&Row]) -> Vec<DrawnWith> {
    let mixes: Vec<_> = rows.iter().filter_map(|r| r.drawn_with).collect();
    if mixes.is_empty() {
        return Vec::new();
    }
    let n = mixes.len() as f64;
    let total: u64 = mixes.iter().map(|(_, p)| p.total()).sum();
    Technique::ALL
        .into_iter()
        .filter_map(|t| {
            let trees: u64 = mixes.iter().map(|(i, _)| u64::from(i[t])).sum();
            let primitives: u64 = mixes.iter().map(|(_, p)| p[t]).sum();
            (trees + primitives > 0).then(|| DrawnWith {
                technique: t.name(),
                trees: trees as f64 / n,
                primitives: primitives as f64 / n,
                share: if total == 0 { 0.0 } else { primitives as f64 / total as f64 },
            })
        })
        .collect()
}

fn rows_of(report: &Report, technique: TechniqueName) -> impl Iterator<Item = &Row> {
    report.rows.iter().filter(move |r| r.technique == technique)
}

/// The summary of `technique`'s rows.
#[must_use]
pub fn summarise(report: &Report, technique: TechniqueName) -> Summary {
    let rows: Vec<&Row> = rows_of(report, technique).collect();
    let n = rows.len().max(1) as f64;
    let mean = |f: &dyn Fn(&Row) -> f64| rows.iter().map(|r| f(r)).sum::<f64>() / n;
    let mean_of = |values: Vec<f64>| (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
    let primitives = mean(&|r| r.primitives() as f64);
    let in_cut = mean(&|r| r.primitives_in_cut() as f64);
    // The counted full mesh, or where only `full-1x` was flown, the same triangles drawn: both
    // are every triangle of every tree in view, so the ratio the policy is judged by (the full
    // mesh's primitives over its own) needs no extra technique in the list.
    let full_rows = |name: TechniqueName| rows_of(report, name).map(|r| r.primitives() as f64).collect::<Vec<f64>>();
    let mut full = full_rows(TechniqueName::FULL);
    if full.is_empty() {
        full = full_rows(TechniqueName::Full1x);
    }
    let full_mean = mean_of(full);
    let selection: Vec<f64> = rows.iter().map(|r| r.selection_ms).collect();
    let gpu: Vec<f64> = rows.iter().filter_map(|r| r.gpu_ms).collect();
    let shadow_primitives = mean_of(rows.iter().filter_map(|r| r.shadow_primitives).map(|p| p as f64).collect());
    Summary {
        shadow_primitives,
        shadow_ratio: shadow_primitives.filter(|_| primitives > 0.0).map(|s| s / primitives),
        frames: rows.len(),
        selection_ms: spread(&selection).unwrap_or_default(),
        instances_visible: mean(&|r| f64::from(r.instances_visible)),
        triangles: mean(&|r| r.triangles as f64),
        points: mean(&|r| r.points as f64),
        ellipsoids: mean(&|r| r.ellipsoids as f64),
        lines: mean(&|r| r.lines as f64),
        primitives,
        primitives_max: rows.iter().map(|r| r.primitives()).max().unwrap_or(0),
        full_ratio: full_mean.filter(|_| primitives > 0.0).map(|f| f / primitives),
        primitives_in_cut: in_cut,
        full_ratio_in_cut: full_mean.filter(|_| in_cut > 0.0).map(|f| f / in_cut),
        instances_pruned: mean_of(rows.iter().filter_map(|r| r.instances_pruned).map(f64::from).collect()),
        bytes_uploaded: mean_of(rows.iter().filter_map(|r| r.bytes_uploaded).map(|b| b as f64).collect()),
        ranges_clamped: mean_of(rows.iter().filter_map(|r| r.ranges_clamped).map(f64::from).collect()),
        transitions: mean_of(rows.iter().filter_map(|r| r.transitions).map(f64::from).collect()),
        gpu_ms: spread(&gpu),
        precision: mean_of(rows.iter().filter_map(|r| r.coverage).map(|c| c.precision()).collect()),
        recall: mean_of(rows.iter().filter_map(|r| r.coverage).map(|c| c.recall()).collect()),
        q: mean_of(rows.iter().filter_map(|r| r.coverage).map(|c| c.quality()).collect()),
        rmse: mean_of(rows.iter().filter_map(|r| r.rmse).collect()),
        flip: mean_of(rows.iter().filter_map(|r| r.flip).collect()),
        noise: mean_of(rows.iter().filter_map(|r| r.noise).collect()),
        reference_noise: mean_of(rows.iter().filter_map(|r| r.reference_noise).collect()),
        drawn_with: drawn_with(&rows),
        budget: report.budget.filter(|_| technique == TechniqueName::Policy).map(|budget| {
            BudgetSummary::of(
                budget,
                &rows
                    .iter()
                    .map(|r| (r.primitives(), r.leaving.unwrap_or(0), r.budget.is_some_and(|b| b.finest)))
                    .collect::<Vec<_>>(),
            )
        }),
    }
}

/// The phases of the path as runs of frames `(phase, first, last)`.
#[must_use]
pub fn phases(report: &Report) -> Vec<(Phase, usize, usize)> {
    let mut runs: Vec<(Phase, usize, usize)> = Vec::new();
    for (i, frame) in report.frames.iter().enumerate() {
        match runs.last_mut() {
            Some((phase, _, last)) if *phase == frame.phase => *last = i,
            _ => runs.push((frame.phase, i, i)),
        }
    }
    runs
}

/// `value` with `digits` decimals, `-` for none.
fn opt(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

/// One line per technique that is not measured: `technique NAME: STATUS: REASON`.
#[must_use]
pub fn unavailable(techniques: &[(TechniqueName, Availability)]) -> String {
    let mut out = String::new();
    for (technique, availability) in techniques {
        if let Some(reason) = availability.reason() {
            let _ = writeln!(out, "technique {}: {}: {reason}", technique.name(), availability.status());
        }
    }
    out
}

/// The forest in one line.
fn forest_line(report: &Report) -> String {
    let f = &report.forest;
    let mut line = format!(
        "{} trees (layout seed {}) of {}: a main forest of {} trees in {} group(s) within {:.0} m of the origin",
        f.trees.len(),
        report.seed,
        report.models.source,
        f.main_trees,
        f.groups,
        f.main_radius
    );
    if f.small_trees > 0 {
        let _ = write!(
            line,
            " and a separate group of {} trees {:.0} m east (radius {:.0} m)",
            f.small_trees, f.small_centre.x, f.small_radius
        );
    }
    let _ = write!(line, "; {:.1} m² per tree in a group, trees {:.1} m tall", f.area_per_tree, f.tree_height);
    line
}

/// The report as text: the forest, the path, the adapter and timing, absent techniques, the
/// summary table, the files written.
#[must_use]
pub fn text(report: &Report, files: [&Option<PathBuf>; 4]) -> String {
    let (w, h) = report.size;
    let mut out = String::new();
    let _ = writeln!(out, "forest: {}", forest_line(report));
    let phases: Vec<String> = phases(report).iter().map(|(p, a, b)| format!("{} {a}-{b}", p.name())).collect();
    let _ = writeln!(
        out,
        "path: {} frame(s) at {w}x{h}, fov {}°: {}",
        report.frames.len(),
        report.fov_degrees,
        phases.join(", ")
    );
    let drawn = match (report.rendered, report.quality) {
        (false, _) => "nothing drawn (--no-render)".to_owned(),
        (true, None) => "every frame drawn once; full counted".to_owned(),
        (true, Some(reference)) => {
            let k = reference.supersample;
            format!(
                "every frame drawn once, and the full mesh as the reference at {}x{} ({})",
                w * k,
                h * k,
                if reference.stochastic_alpha {
                    format!("supersample {k}, box-filtered, stochastic alpha test")
                } else {
                    "--reference-1x: plain alpha test".to_owned()
                }
            )
        }
    };
    match &report.adapter {
        Some(a) => {
            let _ = writeln!(out, "adapter: {} ({}, {}); {drawn}", a.name, a.backend, a.device_type);
        }
        None => {
            let _ = writeln!(out, "adapter: none opened (the full mesh is counted on the CPU)");
        }
    }
    let _ = writeln!(out, "times: {}", timing(report));
    out.push_str(&unavailable(&report.techniques));
    let shadows = report.rows.iter().any(|r| r.shadow_primitives.is_some());
    let transitions = report.rows.iter().any(|r| r.transitions.is_some_and(|n| n > 0));
    // Only where a technique drew them, as the shadow columns.
    let ellipsoids = report.rows.iter().any(|r| r.ellipsoids + r.lines > 0);
    let mut columns = vec![
        ("technique", Align::Left),
        ("frames", Align::Right),
        ("visible", Align::Right),
        ("triangles", Align::Right),
        ("points", Align::Right),
    ];
    if ellipsoids {
        columns.extend([("ellipsoids", Align::Right), ("lines", Align::Right)]);
    }
    columns.extend([
        ("primitives", Align::Right),
        ("full/this", Align::Right),
        ("in cut", Align::Right),
        ("full/cut", Align::Right),
        ("select ms", Align::Right),
        ("median", Align::Right),
        ("p95", Align::Right),
        ("max", Align::Right),
        ("upload KiB", Align::Right),
        ("GPU ms", Align::Right),
        ("P", Align::Right),
        ("R", Align::Right),
        ("Q", Align::Right),
        ("RMSE", Align::Right),
        ("FLIP", Align::Right),
    ]);
    // Temporal noise where it was measured (`--quality`, two frames or more).
    let noise = report.rows.iter().any(|r| r.noise.is_some());
    if noise {
        columns.extend([("noise", Align::Right), ("ref noise", Align::Right)]);
    }
    if shadows {
        columns.extend([("shadow", Align::Right), ("shadow/this", Align::Right)]);
    }
    if transitions {
        columns.push(("fading", Align::Right));
    }
    let mut table = Table::new(&columns);
    // Where a technique's trees were drawn with more than one (the policy's mix; a forced
    // technique and the point tree for models lacking its data): which, and what each cost.
    let mut mixes = Vec::new();
    let mut budgets = Vec::new();
    for (technique, availability) in &report.techniques {
        if *availability != Availability::Measured {
            continue;
        }
        let s = summarise(report, *technique);
        let mut cells = vec![
            technique.name().to_owned(),
            s.frames.to_string(),
            format!("{:.0}", s.instances_visible),
            format!("{:.0}", s.triangles),
            format!("{:.0}", s.points),
        ];
        if ellipsoids {
            cells.extend([format!("{:.0}", s.ellipsoids), format!("{:.0}", s.lines)]);
        }
        cells.extend([
            format!("{:.0}", s.primitives),
            opt(s.full_ratio, 1),
            format!("{:.0}", s.primitives_in_cut),
            opt(s.full_ratio_in_cut, 1),
            format!("{:.2}", s.selection_ms.mean),
            format!("{:.2}", s.selection_ms.median),
            format!("{:.2}", s.selection_ms.p95),
            format!("{:.2}", s.selection_ms.max),
            opt(s.bytes_uploaded.map(|b| b / 1024.0), 1),
            opt(s.gpu_ms.map(|g| g.mean), 2),
            opt(s.precision, 4),
            opt(s.recall, 4),
            opt(s.q, 4),
            opt(s.rmse, 5),
            opt(s.flip, 5),
        ]);
        if noise {
            cells.extend([opt(s.noise, 5), opt(s.reference_noise, 5)]);
        }
        if shadows {
            cells.extend([opt(s.shadow_primitives, 0), opt(s.shadow_ratio, 2)]);
        }
        if transitions {
            cells.push(opt(s.transitions, 1));
        }
        table.row(cells);
        if let Some(budget) = s.budget {
            budgets.push(budget.line(technique.name()));
        }
        if s.drawn_with.len() > 1 {
            mixes.push((technique.name(), s.drawn_with));
        }
    }
    out.push_str(&table.render(""));
    let _ = writeln!(out, "means per frame; {:.1} s in all", report.seconds);
    for (technique, mix) in mixes {
        let parts: Vec<String> = mix
            .iter()
            .map(|d| {
                format!(
                    "{} {:.1} trees, {:.0} primitives ({:.0} %)",
                    d.technique,
                    d.trees,
                    d.primitives,
                    100.0 * d.share
                )
            })
            .collect();
        let _ = writeln!(out, "{technique} drew its trees with: {}", parts.join("; "));
    }
    for line in budgets {
        let _ = writeln!(out, "{line}");
    }
    for line in phase_lines(report) {
        let _ = writeln!(out, "{line}");
    }
    crate::eval::output::files_written(&mut out, &["csv", "json", "plot", "sheet"], &files, &report.sheet);
    out
}

/// Per technique the renderer drew, the mean over frames of each phase of `Renderer::prepare`
/// (`Renderer::prepare_phases`), e.g. `policy prepare ms: setup 0.01, assign 0.35, …`.
fn phase_lines(report: &Report) -> Vec<String> {
    let mut lines = Vec::new();
    for &(technique, _) in &report.techniques {
        let phases: Vec<_> = report.rows.iter().filter(|r| r.technique == technique).filter_map(|r| r.phases).collect();
        if phases.is_empty() {
            continue;
        }
        let n = phases.len() as f64;
        let means: Vec<String> = phases[0]
            .named()
            .iter()
            .enumerate()
            .map(|(i, (name, _))| {
                let ms = phases.iter().map(|p| p.named()[i].1.as_secs_f64() * 1e3).sum::<f64>() / n;
                format!("{name} {ms:.2}")
            })
            .collect();
        lines.push(format!("{} prepare ms: {}", technique.name(), means.join(", ")));
    }
    lines
}

/// The CSV header.
pub const CSV_HEADER: &str = "frame,phase,technique,eye_x,eye_y,eye_z,target_x,target_y,target_z,instances_visible,\
triangles,points,primitives,instances_pruned,leaves_pruned,ranges,ranges_clamped,bytes_uploaded,bytes_resident,selection_ms,gpu_ms,\
precision,recall,q,rmse,flip,points_in_cut,primitives_in_cut,quads,shadow_primitives,ellipsoids,lines,transitions,leaving,\
trees_full,trees_spt,trees_prune_opt,trees_prune_cook,trees_impostors,trees_ellipsoids,trees_lod_chain,trees_billboard,\
trees_crossed,trees_octahedral,primitives_full,primitives_spt,primitives_prune_opt,primitives_prune_cook,\
primitives_impostors,primitives_ellipsoids,primitives_lod_chain,primitives_billboard,primitives_crossed,\
primitives_octahedral,noise,ref_noise,draw_commands,setup_ms,assign_ms,select_ms,stream_ms,record_ms,upload_ms,\
budget_s_min,budget_target,budget_finest";

/// One CSV row per frame and technique, with a header line; empty fields where a figure was not
/// measured.
#[must_use]
pub fn csv(report: &Report) -> String {
    let mut out = format!("{CSV_HEADER}\n");
    let text = |v: Option<String>| v.unwrap_or_default();
    for row in &report.rows {
        let Some(frame) = report.frames.get(row.frame) else { continue };
        let (eye, target) = (frame.pose.eye, frame.pose.target);
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.4},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            row.frame,
            frame.phase.name(),
            row.technique.name(),
            eye.x,
            eye.y,
            eye.z,
            target.x,
            target.y,
            target.z,
            row.instances_visible,
            row.triangles,
            row.points,
            row.primitives(),
            text(row.instances_pruned.map(|v| v.to_string())),
            text(row.leaves_pruned.map(|v| v.to_string())),
            text(row.ranges.map(|v| v.to_string())),
            text(row.ranges_clamped.map(|v| v.to_string())),
            text(row.bytes_uploaded.map(|v| v.to_string())),
            text(row.bytes_resident.map(|v| v.to_string())),
            row.selection_ms,
            text(row.gpu_ms.map(|v| format!("{v:.4}"))),
            text(row.coverage.map(|c| c.precision().to_string())),
            text(row.coverage.map(|c| c.recall().to_string())),
            text(row.coverage.map(|c| c.quality().to_string())),
            text(row.rmse.map(|v| v.to_string())),
            text(row.flip.map(|v| v.to_string())),
            text(row.points_in_cut.map(|v| v.to_string())),
            row.primitives_in_cut(),
            row.quads,
            text(row.shadow_primitives.map(|v| v.to_string())),
            row.ellipsoids,
            row.lines,
            text(row.transitions.map(|v| v.to_string())),
            text(row.leaving.map(|v| v.to_string())),
            by_technique(row),
            text(row.noise.map(|v| v.to_string())),
            text(row.reference_noise.map(|v| v.to_string())),
            text(row.draw_commands.map(|v| v.to_string())),
            phase_fields(row),
            budget_fields(row),
        );
    }
    out
}

/// The CSV's `budget_s_min`, `budget_target` and `budget_finest` (1 or 0) fields of `row`: the
/// steering of the policy's budget mode its frame was selected with (empty outside it).
fn budget_fields(row: &Row) -> String {
    match row.budget {
        Some(b) => format!("{},{},{}", b.s_min, b.target, u8::from(b.finest)),
        None => ",,".to_owned(),
    }
}

/// The CSV's `setup_ms` … `upload_ms` fields of `row`: where `Renderer::prepare` spent its
/// `selection_ms` (empty for the counted full mesh).
fn phase_fields(row: &Row) -> String {
    match row.phases {
        Some(p) => p.named().map(|(_, d)| format!("{:.4}", d.as_secs_f64() * 1e3)).join(","),
        None => ",,,,,".to_owned(),
    }
}

/// The CSV's `trees_*` and `primitives_*` fields of `row`, in [`Technique::ALL`]'s order (empty
/// for the counted full mesh).
fn by_technique(row: &Row) -> String {
    let fields: Vec<String> = match row.drawn_with {
        Some((trees, primitives)) => {
            trees.iter().map(|(_, n)| n.to_string()).chain(primitives.iter().map(|(_, n)| n.to_string())).collect()
        }
        None => vec![String::new(); 2 * Technique::COUNT],
    };
    fields.join(",")
}

/// The JSON summary: models, forest, path, settings, adapter, and per technique its status and
/// summary.
///
/// # Errors
/// If serialisation fails (it does not for these types).
pub fn json(report: &Report) -> Result<String, serde_json::Error> {
    let f = &report.forest;
    let techniques: Vec<serde_json::Value> = report
        .techniques
        .iter()
        .map(|(technique, availability)| {
            serde_json::json!({
                "name": technique.name(),
                "description": super::description(*technique),
                "status": availability.status(),
                "reason": availability.reason(),
                "summary": (*availability == Availability::Measured).then(|| summarise(report, *technique)),
            })
        })
        .collect();
    let phases: Vec<serde_json::Value> = phases(report)
        .iter()
        .map(|(phase, first, last)| serde_json::json!({"phase": phase.name(), "first": first, "last": last}))
        .collect();
    let value = serde_json::json!({
        "models": {"source": report.models.source, "labels": report.models.labels},
        "forest": {
            "trees": f.trees.len(),
            "seed": report.seed,
            "groups": f.groups,
            "main_trees": f.main_trees,
            "main_radius_m": f.main_radius,
            "small_trees": f.small_trees,
            "small_centre_m": [f.small_centre.x, 0.0, f.small_centre.y],
            "small_radius_m": f.small_radius,
            "area_per_tree_m2": f.area_per_tree,
            "tree_height_m": f.tree_height,
        },
        "path": {"frames": report.frames.len(), "phases": phases},
        "size": [report.size.0, report.size.1],
        "fov_degrees": report.fov_degrees,
        "rendered": report.rendered,
        "quality": report.quality.map(|r| serde_json::json!({
            "supersample": r.supersample,
            "stochastic_alpha": r.stochastic_alpha,
            "flip": "mean of the LDR-FLIP error map against the reference, both 8-bit sRGB, at 67 pixels per degree",
        })),
        "adapter": report.adapter,
        "times": timing(report),
        "seconds": report.seconds,
        "techniques": techniques,
    });
    serde_json::to_string_pretty(&value).map(|mut s| {
        s.push('\n');
        s
    })
}

/// The plot: per-frame curves along the path, one panel each — primitives submitted and in the
/// cut (log), selection
/// milliseconds, GPU milliseconds (when measured) and Q (with `--quality`) — with the phases of
/// the path marked.
#[must_use]
pub fn plot(report: &Report) -> Image {
    type Metric = fn(&Row) -> Option<f64>;
    // Per panel: title, value, log axis, and the value a linear axis always shows (Q's best, the
    // times' zero).
    let mut panels: Vec<(&str, Metric, bool, f64)> = vec![
        (
            "primitives submitted per frame: triangles + points + quads + ellipsoids + lines (log)",
            |r| Some(r.primitives() as f64),
            true,
            0.0,
        ),
        (
            "primitives in the cut per frame: triangles + points kept + quads + ellipsoids + lines (log)",
            |r| Some(r.primitives_in_cut() as f64),
            true,
            0.0,
        ),
        ("selection ms per frame (Renderer::prepare; full: counting)", |r| Some(r.selection_ms), false, 0.0),
    ];
    if report.rows.iter().any(|r| r.gpu_ms.is_some()) {
        panels.push(("GPU ms per frame (render pass)", |r| r.gpu_ms, false, 0.0));
    }
    if report.rows.iter().any(|r| r.coverage.is_some()) {
        panels.push(("quality Q against the full mesh", |r| r.coverage.map(|c| c.quality()), false, 1.0));
    }
    let (width, panel_height, gap) = (960u32, 170u32, 44u32);
    let height = 24 + panels.len() as u32 * (panel_height + gap);
    let mut canvas = Canvas::new(width, height);
    let techniques: Vec<(TechniqueName, Rgb888)> = report
        .techniques
        .iter()
        .filter(|(_, a)| *a == Availability::Measured)
        .map(|(t, _)| (*t, plot::style_of(*t).0))
        .collect();
    let frames = report.frames.len().max(1);
    let x = Axis { lo: 0.0, hi: (frames - 1).max(1) as f64, log: false };
    let phases = phases(report);
    for (i, (title, metric, log, anchor)) in panels.iter().enumerate() {
        let top = 24 + i as i32 * (panel_height + gap) as i32;
        let area = Rectangle::new(Point::new(64, top), Size::new(width - 64 - 24, panel_height));
        let values = report.rows.iter().filter_map(metric);
        let y = if *log { Axis::log(values) } else { Axis::linear(values.chain([*anchor]), 1e-3) };
        let panel = Panel { area, x, y };
        panel.draw_axes(&mut canvas, title, (i + 1 == panels.len()).then_some("frame"));
        // Phase boundaries, dashed, with the phase's name at the top of the first panel.
        for (phase, first, _) in &phases {
            let at = panel.point(*first as f64, y.lo).x;
            if *first > 0 {
                let (a, b) = (panel.point(0.0, y.hi).y, panel.point(0.0, y.lo).y);
                let mut y0 = a;
                while y0 < b {
                    plot::line(&mut canvas, Point::new(at, y0), Point::new(at, (y0 + 4).min(b)), REFERENCE, 1);
                    y0 += 8;
                }
            }
            if i == 0 {
                plot::label(
                    &mut canvas,
                    phase.name(),
                    Point::new(at + 3, top + 3),
                    Alignment::Left,
                    Baseline::Top,
                    BLACK,
                );
            }
        }
        for (technique, colour) in &techniques {
            let points: Vec<(f64, f64)> =
                rows_of(report, *technique).filter_map(|r| metric(r).map(|v| (r.frame as f64, v))).collect();
            panel.polyline(&mut canvas, &points, *colour, false);
        }
        if i == 0 {
            let entries: Vec<(String, Rgb888)> = techniques.iter().map(|(t, c)| (t.name().to_owned(), *c)).collect();
            plot::legend(&mut canvas, &area, &entries);
        }
    }
    canvas.into_image()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_are_the_usual_statistics() {
        assert_eq!(spread(&[]), None);
        let s = spread(&[4.0, 1.0, 3.0, 2.0]).expect("values");
        assert_eq!((s.mean, s.median, s.max), (2.5, 2.5, 4.0));
        assert_eq!(s.p95, 4.0);
        let values: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = spread(&values).expect("values");
        assert_eq!((s.median, s.p95, s.max), (50.5, 95.0, 100.0));
        assert_eq!(spread(&[7.0]).expect("one").p95, 7.0);
    }

    #[test]
    fn a_budget_summary_counts_the_frames_over_and_under_it() {
        // At the bounds exactly: 110 and 200 are not over, 50 is not under.
        // The frames over by more than a tenth: 111 with 1 leaving (110 without: over only by the
        // fading), 200 with 95 leaving (105), 201 with 90 (111: over without it too), 1,000.
        // Of the frames under half, the one of 49 was drawn at the finest steering; so were those of
        // 50 (not under half) and 1,000 (over: the finest steering is no cap).
        let frames = [
            (0, 0, false),
            (49, 0, true),
            (50, 0, true),
            (100, 0, false),
            (110, 5, false),
            (111, 1, false),
            (200, 95, false),
            (201, 90, false),
            (1_000, 0, true),
        ];
        let s = BudgetSummary::of(100, &frames);
        assert_eq!((s.budget, s.frames, s.median), (100, 9, 110.0));
        assert_eq!((s.over_tenth, s.over_tenth_fading, s.over_twice, s.under_half), (4, 2, 2, 2));
        assert_eq!(s.under_half_finest, 1);
        assert_eq!(
            s.line("policy"),
            "policy budget 100 primitives a frame: median frame 110; of 9 frames 4 over it by more than 10 % (2 of \
             them only by the draws of trees in a transition), 2 over twice it, 2 under half of it (the draws of trees \
             in a transition counted; 1 of them at the finest steering, nothing left to spend)"
        );
        assert_eq!(BudgetSummary::of(100, &[]), BudgetSummary { budget: 100, ..BudgetSummary::default() });
        // Counts near u64::MAX do not overflow.
        assert_eq!(BudgetSummary::of(u64::MAX, &[(u64::MAX, 0, true)]).over_tenth, 0);
    }
}
