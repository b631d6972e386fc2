//! The viewer's panel (egui, on the right of the window): what is drawn and how, the camera, and
//! live counts with a graph of the last seconds. Every setting here is also a key (the panel shows
//! which); the panel adds what keys cannot say well: values, ranges, and the counts.

use std::collections::VecDeque;

use egui::{Color32, RichText, Ui};
use treelod_render::{DebugView, FrameStats, MAX_CASCADES, PerTechnique, Primitive, Settings, Shadows, Technique};

use super::rig::{Animation, DISTANCE_RANGE, Mode, Rig};
use super::{SELF_SHADOW, sun_angles, sun_from_angles, toggle_shadows};

/// Width of the panel, points.
pub const WIDTH: f32 = 300.0;
/// Seconds of history the graph shows.
const HISTORY_SECONDS: f64 = 10.0;

/// How many of the scene's models hold each technique's data (all hold the point tree and the
/// full mesh).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Holds {
    pub models: usize,
    pub by_technique: PerTechnique<usize>,
}

impl Holds {
    /// Counts what `containers` hold.
    #[must_use]
    pub fn of<'a>(containers: impl IntoIterator<Item = &'a treelod_format::Container>) -> Self {
        let containers: Vec<&treelod_format::Container> = containers.into_iter().collect();
        Self { models: containers.len(), by_technique: PerTechnique::held_by(containers) }
    }

    /// Models holding `technique`'s data.
    #[must_use]
    pub fn count(&self, technique: Technique) -> usize {
        self.by_technique.get(technique)
    }
}

/// One frame of the graph.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    /// Seconds since the viewer started.
    time: f64,
    frame_ms: f32,
    primitives: u64,
}

/// Frame times and primitive counts of the last [`HISTORY_SECONDS`].
#[derive(Debug, Default)]
pub struct History(VecDeque<Sample>);

impl History {
    /// Adds a frame at `time` seconds, forgetting those older than the graph shows.
    pub fn push(&mut self, time: f64, frame_ms: f32, primitives: u64) {
        self.0.push_back(Sample { time, frame_ms, primitives });
        while self.0.front().is_some_and(|s| s.time < time - HISTORY_SECONDS) {
            self.0.pop_front();
        }
    }

    /// Frames per second over the history (0 with fewer than two frames).
    #[must_use]
    pub fn fps(&self) -> f64 {
        match (self.0.front(), self.0.back()) {
            (Some(first), Some(last)) if last.time > first.time => (self.0.len() - 1) as f64 / (last.time - first.time),
            _ => 0.0,
        }
    }

    /// The largest frame time and primitive count held.
    fn maxima(&self) -> (f32, u64) {
        self.0.iter().fold((0.0f32, 0u64), |(ms, p), s| (ms.max(s.frame_ms), p.max(s.primitives)))
    }
}

/// What the panel shows of a build started by a dropped file.
pub struct BuildView<'a> {
    pub source: &'a str,
    pub stage: &'a str,
    pub fraction: Option<f32>,
    pub seconds: f32,
}

/// Everything the panel reads and changes in one frame.
pub struct Inputs<'a> {
    pub name: &'a str,
    pub settings: &'a mut Settings,
    /// The shadow settings turned back on.
    pub last_shadows: &'a mut Shadows,
    pub rig: &'a mut Rig,
    pub stats: &'a FrameStats,
    pub holds: Holds,
    pub instances: usize,
    pub history: &'a History,
    /// CPU milliseconds of the last frame's selection ([`treelod_render::Renderer::prepare`]).
    pub select_ms: f64,
    /// GPU milliseconds of the main pass, where the device has timestamp queries.
    pub gpu_ms: Option<f64>,
    pub gpu_selection: bool,
    /// The error view: the difference from the full mesh as a heat map.
    pub heat: &'a mut bool,
    /// Sample counts the window's formats allow, and the one in use.
    pub msaa_choices: &'a [u32],
    pub msaa: u32,
    pub build: Option<BuildView<'a>>,
    /// Errors and warnings of the last dropped file.
    pub messages: &'a [String],
}

/// What the panel asks of the viewer beyond its settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    ToggleGpuSelection,
    /// Draw with this many samples per pixel (the renderer is rebuilt).
    Msaa(u32),
}

/// Draws the panel's contents into `ui`; returns what the viewer must do beyond the settings.
pub fn show(ui: &mut Ui, inputs: Inputs<'_>) -> Vec<Action> {
    let mut actions = Vec::new();
    let Inputs { name, settings, last_shadows, rig, stats, holds, .. } = inputs;
    ui.heading(name);
    ui.label(format!(
        "{:.1} fps · selection {:.2} ms · GPU {}",
        inputs.history.fps(),
        inputs.select_ms,
        inputs.gpu_ms.map_or_else(|| "n/a".to_owned(), |ms| format!("{ms:.2} ms"))
    ));
    if let Some(build) = &inputs.build {
        ui.separator();
        ui.label(format!("building {} ({:.0} s)", build.source, build.seconds));
        match build.fraction {
            Some(f) => ui.add(egui::ProgressBar::new(f).show_percentage().text(build.stage)),
            None => {
                ui.horizontal(|ui| {
                    ui.spinner();
                    ui.label(build.stage);
                })
                .response
            }
        };
    }
    for message in inputs.messages {
        let colour =
            if message.starts_with("error") { Color32::from_rgb(230, 90, 80) } else { Color32::from_rgb(220, 180, 60) };
        ui.label(RichText::new(message).color(colour).small());
    }
    graph(ui, inputs.history);
    ui.separator();
    egui::ScrollArea::vertical().show(ui, |ui| {
        ui.spacing_mut().slider_width = 120.0;
        egui::CollapsingHeader::new("Representation").default_open(true).show(ui, |ui| {
            representation(ui, settings, holds);
            detail(ui, settings);
        });
        egui::CollapsingHeader::new("Counts").default_open(true).show(ui, |ui| counts(ui, stats, inputs.instances));
        egui::CollapsingHeader::new("Level of detail").default_open(true).show(ui, |ui| {
            lod(ui, settings, inputs.gpu_selection, &mut actions);
        });
        egui::CollapsingHeader::new("View").default_open(true).show(ui, |ui| {
            view(ui, settings, inputs.heat, inputs.msaa_choices, inputs.msaa, &mut actions);
            camera(ui, rig);
        });
        egui::CollapsingHeader::new("Light").default_open(false).show(ui, |ui| light(ui, settings, last_shadows));
    });
    actions
}

/// The panel's primitive budget when budget mode is first turned on: a million primitives, what a
/// current GPU draws in well under a millisecond.
const DEFAULT_BUDGET: u64 = 1_000_000;

fn representation(ui: &mut Ui, settings: &mut Settings, holds: Holds) {
    let mut on = settings.policy.is_some();
    let policy = ui
        .checkbox(&mut on, "policy: per tree, from the calibration")
        .on_hover_text("T: the cheapest representation within the target of the full mesh's error; trees of containers without calibration tables draw with the representation below");
    if policy.changed() {
        settings.policy = on.then(treelod_render::Policy::default);
    }
    if let Some(policy) = &mut settings.policy {
        ui.add(egui::Slider::new(&mut policy.target, 0.0..=0.05).text("target error"));
        // Budget mode: the renderer steers the target and s_min so a frame meets the count.
        let mut budgeted = policy.budget.is_some();
        ui.checkbox(&mut budgeted, "primitive budget").on_hover_text(
            "the target and s_min steered from frame to frame so the view draws about this many primitives",
        );
        match (budgeted, policy.budget) {
            (false, _) => policy.budget = None,
            (true, None) => policy.budget = Some(DEFAULT_BUDGET),
            (true, Some(mut budget)) => {
                ui.add(egui::Slider::new(&mut budget, 1_000..=10_000_000).logarithmic(true).text("primitives"));
                policy.budget = Some(budget.max(1));
            }
        }
    }
    let current = settings.technique;
    egui::ComboBox::from_id_salt("representation").width(ui.available_width()).selected_text(current.label()).show_ui(
        ui,
        |ui| {
            for t in Technique::ALL {
                let held = holds.count(t);
                let label = if held == holds.models {
                    t.label().to_owned()
                } else {
                    format!("{} ({held} of {} models)", t.label(), holds.models)
                };
                ui.selectable_value(&mut settings.technique, t, label);
            }
        },
    );
    if holds.count(settings.technique) < holds.models {
        ui.label(
            RichText::new("models without it draw with triangles + points (build with --prune, --impostors, --ellipsoids or --baselines)")
                .small()
                .weak(),
        );
    }
}

/// The chosen representation's own settings.
fn detail(ui: &mut Ui, settings: &mut Settings) {
    match settings.technique {
        Technique::PruneOpt | Technique::PruneCook => {
            let pruning = &mut settings.pruning;
            ui.checkbox(&mut pruning.occlusion, "occlusion lowers hidden trees' leaves").on_hover_text("key O");
            ui.add(egui::Slider::new(&mut pruning.spt_below_pixels, 0.0..=512.0).text("point tree below, px"))
                .on_hover_text("trees shorter than this on screen draw with triangles + points");
        }
        Technique::Impostors => {
            ui.checkbox(&mut settings.impostor_morph, "morph and cross-fade levels").on_hover_text("key M");
        }
        Technique::Ellipsoids => {
            ui.checkbox(&mut settings.lines, "bark as lines").on_hover_text("key N");
            ui.add(egui::Slider::new(&mut settings.ellipsoid_quality, 0.25..=8.0).logarithmic(true).text("quality"))
                .on_hover_text("2: the level for pixels half as large");
            ui.add(egui::Slider::new(&mut settings.level_blend, 0.0..=2.0).text("level blend, octaves"))
                .on_hover_text("levels dither into each other over this range; 0 switches at once");
        }
        _ => {}
    }
}

fn lod(ui: &mut Ui, settings: &mut Settings, gpu_selection: bool, actions: &mut Vec<Action>) {
    let range = 1.0 / 64.0..=1024.0;
    ui.add(egui::Slider::new(&mut settings.s_min, range.clone()).logarithmic(true).text("s_min, px"))
        .on_hover_text("points are drawn down to this size (keys [ and ])");
    ui.add(egui::Slider::new(&mut settings.s_max, range).logarithmic(true).text("s_max, px"))
        .on_hover_text("triangles larger than this stay triangles (keys - and =)");
    settings.s_max = settings.s_max.max(settings.s_min);
    ui.add(egui::Slider::new(&mut settings.depth_bias_k, 0.0..=16.0).text("depth bias k, px"))
        .on_hover_text("Gilet's depth bias: finer in front, coarser behind (keys J and K)");
    ui.add(egui::Slider::new(&mut settings.point_scale, 0.25..=4.0).logarithmic(true).text("point scale"));
    let mut on = gpu_selection;
    if ui.checkbox(&mut on, "select on the GPU").on_hover_text("compute-shader selection (key G)").changed() {
        actions.push(Action::ToggleGpuSelection);
    }
}

fn light(ui: &mut Ui, settings: &mut Settings, last_shadows: &mut Shadows) {
    let (azimuth, elevation) = sun_angles(settings.sun);
    let (mut az, mut el) = (azimuth.to_degrees(), elevation.to_degrees());
    let a = ui.add(egui::Slider::new(&mut az, -180.0..=180.0).text("sun azimuth, °")).on_hover_text("keys ← and →");
    let e = ui.add(egui::Slider::new(&mut el, -85.0..=85.0).text("sun elevation, °")).on_hover_text("keys ↑ and ↓");
    if a.changed() || e.changed() {
        settings.sun = sun_from_angles(az.to_radians(), el.to_radians());
    }
    ui.add(egui::Slider::new(&mut settings.ambient, 0.0..=1.0).text("ambient share"));
    ui.checkbox(&mut settings.ambient_occlusion, "ambient occlusion").on_hover_text("key Y");
    let mut self_shadow = settings.shading.is_some();
    if ui.checkbox(&mut self_shadow, "Gilet's self-shadowing").on_hover_text("key L").changed() {
        settings.shading = self_shadow.then_some(SELF_SHADOW);
    }
    let mut shadows = settings.shadows.is_some();
    if ui.checkbox(&mut shadows, "shadow maps").on_hover_text("key H").changed() {
        toggle_shadows(&mut settings.shadows, last_shadows);
    }
    if let Some(shadows) = &mut settings.shadows {
        let before = *shadows;
        ui.add(egui::Slider::new(&mut shadows.cascades, 1..=MAX_CASCADES as u32).text("cascades"));
        egui::ComboBox::from_label("resolution").selected_text(format!("{}²", shadows.resolution)).show_ui(ui, |ui| {
            for r in [512, 1024, 2048, 4096] {
                ui.selectable_value(&mut shadows.resolution, r, format!("{r}²"));
            }
        });
        ui.add(egui::Slider::new(&mut shadows.distance, 5.0..=2000.0).logarithmic(true).text("distance, m"));
        if *shadows != before {
            *last_shadows = *shadows;
        }
    }
}

fn view(
    ui: &mut Ui,
    settings: &mut Settings,
    heat: &mut bool,
    msaa_choices: &[u32],
    msaa: u32,
    actions: &mut Vec<Action>,
) {
    ui.horizontal_wrapped(|ui| {
        ui.label("colour by");
        // The error view compares shaded frames: it is a fourth choice, not a debug colour.
        let mut choice = if *heat { None } else { Some(settings.debug) };
        ui.radio_value(&mut choice, Some(DebugView::Shaded), "shading").on_hover_text("key 1");
        ui.radio_value(&mut choice, Some(DebugView::Cells), "cell").on_hover_text("key 2");
        ui.radio_value(&mut choice, Some(DebugView::Kinds), "kind").on_hover_text(
            "the representation: triangles red, points blue, pruned leaves green, impostor planes \
             yellow, billboards magenta, ellipsoids cyan, lines brown (key 3)",
        );
        ui.radio_value(&mut choice, Some(DebugView::Levels), "level").on_hover_text(
            "one colour per octave of each point's, plane's, ellipsoid's or line's interval of τ, \
             cycling; triangles light grey (key 4)",
        );
        ui.radio_value(&mut choice, Some(DebugView::Techniques), "technique").on_hover_text(
            "the technique each tree is drawn with, what the policy chose: full grey, spt blue, \
             prune-opt green, prune-cook dark green, impostors yellow, ellipsoids cyan, lod-chain \
             red, billboard magenta, crossed violet (key 6)",
        );
        ui.radio_value(&mut choice, None, "error").on_hover_text(format!(
            "the difference from the full mesh drawn at this resolution, per pixel: blue, yellow, \
             red at {} (RMS of linear RGB) (key 5)",
            super::heat::FULL_SCALE
        ));
        *heat = choice.is_none();
        settings.debug = choice.unwrap_or(DebugView::Shaded);
    });
    ui.horizontal(|ui| {
        ui.label("MSAA");
        for &n in msaa_choices {
            if ui.selectable_label(n == msaa, format!("{n}×")).clicked() && n != msaa {
                actions.push(Action::Msaa(n));
            }
        }
    });
}

fn camera(ui: &mut Ui, rig: &mut Rig) {
    ui.horizontal(|ui| {
        ui.label("camera");
        let mut mode = rig.mode;
        ui.radio_value(&mut mode, Mode::Fly, "fly").on_hover_text("keys W A S D Q E, Shift faster; drag to look");
        ui.radio_value(&mut mode, Mode::Orbit, "orbit").on_hover_text("drag to turn about the scene's centre");
        rig.set_mode(mode);
    });
    let mut distance = rig.distance;
    let slider = egui::Slider::new(&mut distance, DISTANCE_RANGE.0..=DISTANCE_RANGE.1).logarithmic(true);
    let response = ui.add(slider.text("distance, radii")).on_hover_text(format!(
        "from the centre, in bounding radii of the scene ({:.2} m): eval reports 2, 8 and 32",
        rig.radius
    ));
    if response.changed() {
        rig.set_mode(Mode::Orbit);
        if rig.animation == Animation::Approach {
            rig.animation = Animation::Still;
        }
        rig.distance = distance;
    }
    ui.horizontal(|ui| {
        ui.label("animate");
        let mut animation = if rig.mode == Mode::Orbit { rig.animation } else { Animation::Still };
        let before = animation;
        ui.radio_value(&mut animation, Animation::Still, "still");
        ui.radio_value(&mut animation, Animation::Turn, "orbit").on_hover_text("turn about the scene");
        ui.radio_value(&mut animation, Animation::Approach, "approach")
            .on_hover_text("come in from 48 radii to 1.5 and back out, evenly per octave");
        if animation != before {
            rig.animate(animation);
        }
    });
}

fn counts(ui: &mut Ui, stats: &FrameStats, instances: usize) {
    let mb = |bytes: u64| format!("{:.1} MB", bytes as f64 / 1e6);
    egui::Grid::new("counts").num_columns(2).striped(true).show(ui, |ui| {
        let mut row = |label: &str, value: String| {
            ui.label(label);
            ui.label(value);
            ui.end_row();
        };
        row("instances visible", format!("{} of {instances}", stats.instances_visible));
        for (technique, trees) in stats.instances.iter().filter(|&(_, n)| n > 0) {
            row(&format!("  trees, {}", technique.label()), trees.to_string());
        }
        if stats.transitions > 0 {
            row("  changing technique", stats.transitions.to_string());
        }
        row("primitives", stats.primitives().to_string());
        for (kind, count) in stats.submitted.iter().filter(|&(kind, n)| n > 0 || kind <= Primitive::Point) {
            row(&format!("  {}", kind.name()), count.to_string());
        }
        if stats.leaves_pruned > 0 {
            row("  pruned leaves", stats.leaves_pruned.to_string());
        }
        for (technique, count) in stats.by_technique.iter().filter(|&(_, n)| n > 0) {
            row(&format!("  by {}", technique.label()), count.to_string());
        }
        if stats.shadow.cascades > 0 {
            row("shadow primitives", stats.shadow.primitives().to_string());
        }
        row("draws", stats.ranges.to_string());
        row("resident", mb(stats.bytes_resident));
        row("uploaded", mb(stats.bytes_uploaded));
    });
}

/// Frame time (orange) and primitives (blue) over the last seconds, each scaled to its maximum.
fn graph(ui: &mut Ui, history: &History) {
    const MS: Color32 = Color32::from_rgb(240, 150, 40);
    const PRIMITIVES: Color32 = Color32::from_rgb(80, 150, 240);
    let (max_ms, max_primitives) = history.maxima();
    ui.horizontal(|ui| {
        ui.label(RichText::new(format!("frame ms ≤ {max_ms:.1}")).color(MS).small());
        ui.label(RichText::new(format!("primitives ≤ {max_primitives}")).color(PRIMITIVES).small());
    });
    let (rect, _) = ui.allocate_exact_size(egui::vec2(ui.available_width(), 44.0), egui::Sense::hover());
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    let Some(last) = history.0.back() else { return };
    let x = |time: f64| rect.right() - ((last.time - time) / HISTORY_SECONDS) as f32 * rect.width();
    let y = |share: f32| rect.bottom() - 2.0 - share.clamp(0.0, 1.0) * (rect.height() - 4.0);
    let ms: Vec<egui::Pos2> =
        history.0.iter().map(|s| egui::pos2(x(s.time), y(s.frame_ms / max_ms.max(1e-6)))).collect();
    let primitives: Vec<egui::Pos2> = history
        .0
        .iter()
        .map(|s| egui::pos2(x(s.time), y(s.primitives as f32 / max_primitives.max(1) as f32)))
        .collect();
    painter.add(egui::Shape::line(primitives, egui::Stroke::new(1.5, PRIMITIVES)));
    painter.add(egui::Shape::line(ms, egui::Stroke::new(1.5, MS)));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_history_keeps_ten_seconds_and_measures_the_rate() {
        let mut history = History::default();
        for frame in 0..=300 {
            history.push(f64::from(frame) / 20.0, 5.0 + f32::from(u8::try_from(frame % 7).unwrap_or(0)), frame as u64);
        }
        // 20 frames per second over the 10 s kept (frames 100..=300).
        assert_eq!(history.0.len(), 201);
        assert!((history.fps() - 20.0).abs() < 1e-9, "{}", history.fps());
        assert_eq!(history.maxima(), (11.0, 300));
    }

    #[test]
    fn primitives_add_every_kind() {
        // Triangles, points, planes, billboards, ellipsoids, lines.
        let stats =
            FrameStats { submitted: treelod_render::PerPrimitive([1, 2, 4, 32, 8, 16]), ..FrameStats::default() };
        assert_eq!(stats.primitives(), 63);
    }

    #[test]
    fn holds_counts_the_models_holding_each_technique() {
        let holds = Holds { models: 3, by_technique: PerTechnique([3, 3, 1, 1, 0, 2, 0, 0, 0, 0]) };
        assert_eq!(holds.count(Technique::Ellipsoids), 2);
        assert_eq!(holds.count(Technique::Spt), holds.models);
    }
}
