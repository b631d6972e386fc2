//! The PNG plots of `treelod eval`: quality against primitives drawn per technique, and
//! per-frame curves along the path. Lines, markers and text are drawn with `embedded-graphics`
//! (its 6×10 bitmap font needs no font files) into an RGB canvas that becomes a PNG.

use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Circle, Line, PrimitiveStyle, Rectangle, Triangle};
use embedded_graphics::text::{Alignment, Baseline, Text, TextStyleBuilder};
use treelod_render::offscreen::Image;

use super::{Availability, Report, Row, TechniqueName};
use treelod_render::Technique;

/// Colours of series in the order they are drawn, where a series is not a technique (Tableau 10).
pub const PALETTE: [Rgb888; 12] = [
    Rgb888::new(31, 119, 180),
    Rgb888::new(255, 127, 14),
    Rgb888::new(44, 160, 44),
    Rgb888::new(214, 39, 40),
    Rgb888::new(148, 103, 189),
    Rgb888::new(140, 86, 75),
    Rgb888::new(227, 119, 194),
    Rgb888::new(127, 127, 127),
    Rgb888::new(188, 189, 34),
    Rgb888::new(23, 190, 207),
    Rgb888::new(120, 0, 60),
    Rgb888::new(0, 90, 70),
];

/// The shape of a technique's dots, so techniques stay apart where colours are hard to tell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    /// A filled circle.
    Circle,
    /// A filled square.
    Square,
    /// A filled triangle, point up.
    Triangle,
    /// A filled triangle, point down.
    TriangleDown,
    /// A filled diamond.
    Diamond,
    /// An ×.
    Cross,
    /// A +.
    Plus,
    /// An eight-pointed star (× over +).
    Star,
}

/// The shapes techniques take, in the order of [`Technique::ALL`].
const SHAPES: [Marker; 6] =
    [Marker::Circle, Marker::Square, Marker::Triangle, Marker::TriangleDown, Marker::Diamond, Marker::Cross];

/// The colour and marker of a technique in every plot: fixed per technique (not per position in
/// a run), each colour of [`PALETTE`] used once, so the same technique looks the same in every
/// plot and no two techniques share a look.
pub fn style(technique: Technique, full_1x: bool) -> (Rgb888, Marker) {
    let index = if full_1x { Technique::COUNT } else { technique.index() };
    // Shapes cycle through the list in its order, so neighbouring techniques (the point tree,
    // pruning, impostors, ellipsoids, the chain) differ in shape as well as colour, and a new
    // technique gets a look without a change here; the full mesh at 1x is the only +.
    let marker = if full_1x { Marker::Plus } else { SHAPES[technique.index() % SHAPES.len()] };
    (PALETTE[index % PALETTE.len()], marker)
}

/// The look of what a row measures.
pub fn style_of(name: TechniqueName) -> (Rgb888, Marker) {
    match name.technique() {
        Some(technique) => style(technique, name == TechniqueName::Full1x),
        // The policy: the last colour, a star among the techniques it chooses from.
        None => (PALETTE[Technique::COUNT + 1], Marker::Star),
    }
}

/// A marker of `diameter` pixels at `centre`.
pub fn marker(canvas: &mut Canvas, centre: Point, diameter: u32, colour: Rgb888, shape: Marker) {
    let fill = PrimitiveStyle::with_fill(colour);
    let r = diameter as i32 / 2;
    let Ok(()) = match shape {
        Marker::Circle => Circle::with_center(centre, diameter).into_styled(fill).draw(canvas),
        Marker::Square => {
            let side = (diameter * 4 / 5).max(1);
            Rectangle::with_center(centre, Size::new(side, side)).into_styled(fill).draw(canvas)
        }
        Marker::Triangle => {
            Triangle::new(centre + Point::new(0, -r), centre + Point::new(r, r), centre + Point::new(-r, r))
                .into_styled(fill)
                .draw(canvas)
        }
        Marker::TriangleDown => {
            Triangle::new(centre + Point::new(0, r), centre + Point::new(r, -r), centre + Point::new(-r, -r))
                .into_styled(fill)
                .draw(canvas)
        }
        Marker::Cross | Marker::Plus => {
            let width = (diameter / 4).max(2);
            let (a, b) = if shape == Marker::Cross {
                ((Point::new(-r, -r), Point::new(r, r)), (Point::new(-r, r), Point::new(r, -r)))
            } else {
                ((Point::new(-r, 0), Point::new(r, 0)), (Point::new(0, -r), Point::new(0, r)))
            };
            let stroke = PrimitiveStyle::with_stroke(colour, width);
            let _ = Line::new(centre + a.0, centre + a.1).into_styled(stroke).draw(canvas);
            Line::new(centre + b.0, centre + b.1).into_styled(stroke).draw(canvas)
        }
        Marker::Star => {
            marker(canvas, centre, diameter, colour, Marker::Plus);
            let r = r * 3 / 4;
            let width = (diameter / 5).max(2);
            let stroke = PrimitiveStyle::with_stroke(colour, width);
            let _ = Line::new(centre + Point::new(-r, -r), centre + Point::new(r, r)).into_styled(stroke).draw(canvas);
            Line::new(centre + Point::new(-r, r), centre + Point::new(r, -r)).into_styled(stroke).draw(canvas)
        }
        Marker::Diamond => {
            let (top, bottom) = (centre + Point::new(0, -r), centre + Point::new(0, r));
            let _ = Triangle::new(top, centre + Point::new(r, 0), bottom).into_styled(fill).draw(canvas);
            Triangle::new(top, centre + Point::new(-r, 0), bottom).into_styled(fill).draw(canvas)
        }
    };
}

/// Axes, ticks and text.
pub const BLACK: Rgb888 = Rgb888::new(0, 0, 0);
/// Grid lines.
pub const GRID: Rgb888 = Rgb888::new(225, 225, 225);
/// The reference's curves (dashed grey).
pub const REFERENCE: Rgb888 = Rgb888::new(110, 110, 110);

/// An RGB canvas, white when made.
pub struct Canvas {
    width: u32,
    height: u32,
    pixels: Vec<Rgb888>,
}

impl Canvas {
    /// A white canvas of `width` × `height` pixels.
    #[must_use]
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![Rgb888::WHITE; width as usize * height as usize] }
    }

    /// The canvas as an opaque RGBA image.
    #[must_use]
    pub fn into_image(self) -> Image {
        let rgba = self.pixels.iter().flat_map(|p| [p.r(), p.g(), p.b(), 255]).collect();
        Image { width: self.width, height: self.height, rgba }
    }
}

impl OriginDimensions for Canvas {
    fn size(&self) -> Size {
        Size::new(self.width, self.height)
    }
}

impl DrawTarget for Canvas {
    type Color = Rgb888;
    type Error = core::convert::Infallible;

    fn draw_iter<I>(&mut self, pixels: I) -> Result<(), Self::Error>
    where
        I: IntoIterator<Item = Pixel<Self::Color>>,
    {
        for Pixel(p, colour) in pixels {
            if let (Ok(x), Ok(y)) = (u32::try_from(p.x), u32::try_from(p.y))
                && x < self.width
                && y < self.height
            {
                self.pixels[y as usize * self.width as usize + x as usize] = colour;
            }
        }
        Ok(())
    }
}

/// Draws `text` at `at` (every drawing into a [`Canvas`] is infallible).
pub fn label(canvas: &mut Canvas, text: &str, at: Point, alignment: Alignment, baseline: Baseline, colour: Rgb888) {
    let style = TextStyleBuilder::new().alignment(alignment).baseline(baseline).build();
    let Ok(_) = Text::with_text_style(text, at, MonoTextStyle::new(&FONT_6X10, colour), style).draw(canvas);
}

/// A line `width` pixels wide from `from` to `to`.
pub fn line(canvas: &mut Canvas, from: Point, to: Point, colour: Rgb888, width: u32) {
    let Ok(()) = Line::new(from, to).into_styled(PrimitiveStyle::with_stroke(colour, width)).draw(canvas);
}

/// A filled circle of `diameter` pixels at `centre`.
pub fn dot(canvas: &mut Canvas, centre: Point, diameter: u32, colour: Rgb888) {
    let Ok(()) = Circle::with_center(centre, diameter).into_styled(PrimitiveStyle::with_fill(colour)).draw(canvas);
}

/// A value axis: linear or base-10 logarithmic over `[lo, hi]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    /// The value at the axis's start.
    pub lo: f64,
    /// The value at its end.
    pub hi: f64,
    /// Whether base-10 logarithmic.
    pub log: bool,
}

impl Axis {
    /// A linear axis over the values with a little room, widened to at least `min_span`.
    pub fn linear(values: impl Iterator<Item = f64>, min_span: f64) -> Self {
        let (mut lo, mut hi) = min_max(values).unwrap_or((0.0, 1.0));
        let span = (hi - lo).max(min_span);
        let middle = 0.5 * (lo + hi);
        lo = lo.min(middle - 0.5 * span);
        hi = hi.max(middle + 0.5 * span);
        let pad = 0.05 * (hi - lo);
        Self { lo: lo - pad, hi: hi + pad, log: false }
    }

    /// A logarithmic axis from the power of ten at or below the smallest positive value to the
    /// one at or above the largest.
    pub fn log(values: impl Iterator<Item = f64>) -> Self {
        let (lo, hi) = min_max(values.filter(|v| *v > 0.0)).unwrap_or((1.0, 10.0));
        let lo = 10f64.powf(lo.log10().floor());
        let hi = 10f64.powf(hi.log10().ceil()).max(lo * 10.0);
        Self { lo, hi, log: true }
    }

    /// Where `v` falls, 0 at `lo` and 1 at `hi` (non-positive values on a log axis at 0).
    fn fraction(&self, v: f64) -> f64 {
        if self.log {
            if v <= 0.0 {
                return 0.0;
            }
            (v.log10() - self.lo.log10()) / (self.hi.log10() - self.lo.log10())
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }

    /// The tick values: powers of ten on a log axis, else 1, 2 or 5 times a power of ten apart.
    fn ticks(&self) -> Vec<f64> {
        if self.log {
            let (a, b) = (self.lo.log10().round() as i32, self.hi.log10().round() as i32);
            return (a..=b).map(|e| 10f64.powi(e)).collect();
        }
        let raw = (self.hi - self.lo) / 5.0;
        let magnitude = 10f64.powf(raw.log10().floor());
        let step = [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * magnitude).find(|s| *s >= raw).unwrap_or(raw);
        let first = (self.lo / step).ceil() as i64;
        let last = (self.hi / step).floor() as i64;
        (first..=last).map(|i| i as f64 * step).collect()
    }

    /// A tick's text.
    fn tick_label(&self, v: f64) -> String {
        if self.log {
            return compact(v);
        }
        let step = self.ticks().windows(2).map(|w| w[1] - w[0]).next().unwrap_or(1.0);
        let digits = (-step.log10().floor()).max(0.0) as usize;
        format!("{v:.digits$}")
    }
}

/// `1`, `10`, `100`, `1k`, `10k`, `1M`, … for counts.
fn compact(v: f64) -> String {
    let (value, suffix) = if v >= 1e9 {
        (v / 1e9, "G")
    } else if v >= 1e6 {
        (v / 1e6, "M")
    } else if v >= 1e3 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    let text = format!("{value:.1}");
    format!("{}{suffix}", text.trim_end_matches('0').trim_end_matches('.'))
}

fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.filter(|v| v.is_finite()).fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// A plot area on a canvas with its two axes.
pub struct Panel {
    /// The plot area, pixels of the canvas.
    pub area: Rectangle,
    /// The horizontal axis.
    pub x: Axis,
    /// The vertical axis.
    pub y: Axis,
}

impl Panel {
    /// The pixel of the value `(x, y)`.
    #[must_use]
    pub fn point(&self, x: f64, y: f64) -> Point {
        let (left, top) = (self.area.top_left.x, self.area.top_left.y);
        let (w, h) = (self.area.size.width as f64, self.area.size.height as f64);
        let fx = self.x.fraction(x).clamp(0.0, 1.0);
        let fy = self.y.fraction(y).clamp(0.0, 1.0);
        Point::new(left + (fx * (w - 1.0)).round() as i32, top + ((1.0 - fy) * (h - 1.0)).round() as i32)
    }

    /// Grid, frame, tick labels, the title above and the x label below.
    pub fn draw_axes(&self, canvas: &mut Canvas, title: &str, x_label: Option<&str>) {
        let (left, top) = (self.area.top_left.x, self.area.top_left.y);
        let (right, bottom) = (left + self.area.size.width as i32 - 1, top + self.area.size.height as i32 - 1);
        for v in self.y.ticks() {
            let y = self.point(self.x.lo, v).y;
            line(canvas, Point::new(left, y), Point::new(right, y), GRID, 1);
            let text = self.y.tick_label(v);
            label(canvas, &text, Point::new(left - 4, y), Alignment::Right, Baseline::Middle, BLACK);
        }
        for v in self.x.ticks() {
            let x = self.point(v, self.y.lo).x;
            line(canvas, Point::new(x, top), Point::new(x, bottom), GRID, 1);
            if x_label.is_some() {
                let text = self.x.tick_label(v);
                label(canvas, &text, Point::new(x, bottom + 4), Alignment::Center, Baseline::Top, BLACK);
            }
        }
        let Ok(()) = self.area.into_styled(PrimitiveStyle::with_stroke(BLACK, 1)).draw(canvas);
        label(canvas, title, Point::new(left, top - 4), Alignment::Left, Baseline::Bottom, BLACK);
        if let Some(text) = x_label {
            label(
                canvas,
                text,
                Point::new(left + self.area.size.width as i32 / 2, bottom + 18),
                Alignment::Center,
                Baseline::Top,
                BLACK,
            );
        }
    }

    /// A line through `points` (values), solid or dashed.
    pub fn polyline(&self, canvas: &mut Canvas, points: &[(f64, f64)], colour: Rgb888, dashed: bool) {
        for (i, pair) in points.windows(2).enumerate() {
            if dashed && i % 2 == 1 {
                continue;
            }
            line(canvas, self.point(pair[0].0, pair[0].1), self.point(pair[1].0, pair[1].1), colour, 2);
        }
        if points.len() == 1 {
            dot(canvas, self.point(points[0].0, points[0].1), 5, colour);
        }
    }
}

/// The measured techniques with their colours and markers ([`style_of`]).
fn measured(report: &Report) -> Vec<(TechniqueName, Rgb888, Marker)> {
    report
        .techniques
        .iter()
        .filter(|(_, a)| *a == Availability::Measured)
        .map(|(name, _)| {
            let (colour, shape) = style_of(*name);
            (*name, colour, shape)
        })
        .collect()
}

fn rows_of(report: &Report, technique: TechniqueName) -> impl Iterator<Item = &Row> {
    report.rows.iter().filter(move |r| r.technique == technique)
}

/// Primitives a frame drew ([`Row::primitives`]).
fn primitives(row: &Row) -> f64 {
    row.primitives() as f64
}

/// A legend box at the top right of `area` whose entries show each series' marker beside its line.
/// Width of the margin right of a plot's panels that holds its legend ([`legend_with_markers`]),
/// so the legend hides no data: the top right of a quality plot is where the full mesh sits.
pub const LEGEND_MARGIN: u32 = 170;

/// The margin of [`LEGEND_MARGIN`] at the right of a canvas `width` wide, from `top` down.
fn legend_margin(width: u32, top: i32, height: u32) -> Rectangle {
    Rectangle::new(Point::new(width as i32 - LEGEND_MARGIN as i32, top), Size::new(LEGEND_MARGIN, height))
}

/// A legend in `area`: per entry its marker in its colour and its name.
pub fn legend_with_markers(canvas: &mut Canvas, area: &Rectangle, entries: &[(String, Rgb888, Marker)]) {
    let plain: Vec<(String, Rgb888)> = entries.iter().map(|(t, c, _)| (t.clone(), *c)).collect();
    legend(canvas, area, &plain);
    let width = 28 + 6 * entries.iter().map(|(t, _, _)| t.chars().count()).max().unwrap_or(0) as i32;
    let right = area.top_left.x + area.size.width as i32 - 6;
    for (i, (_, colour, shape)) in entries.iter().enumerate() {
        let centre = Point::new(right - width + 12, area.top_left.y + 6 + 9 + 12 * i as i32);
        marker(canvas, centre, 9, *colour, *shape);
    }
}

/// A legend box at the top right of `area`.
pub fn legend(canvas: &mut Canvas, area: &Rectangle, entries: &[(String, Rgb888)]) {
    let width = 28 + 6 * entries.iter().map(|(t, _)| t.chars().count()).max().unwrap_or(0) as i32;
    let height = 6 + 12 * entries.len() as i32;
    let right = area.top_left.x + area.size.width as i32 - 6;
    let top = area.top_left.y + 6;
    let frame = Rectangle::new(Point::new(right - width, top), Size::new(width as u32, height as u32));
    let Ok(()) = frame.into_styled(PrimitiveStyle::with_fill(Rgb888::WHITE)).draw(canvas);
    let Ok(()) = frame.into_styled(PrimitiveStyle::with_stroke(GRID, 1)).draw(canvas);
    for (i, (text, colour)) in entries.iter().enumerate() {
        let y = top + 9 + 12 * i as i32;
        line(canvas, Point::new(right - width + 5, y), Point::new(right - width + 19, y), *colour, 2);
        label(canvas, text, Point::new(right - width + 24, y), Alignment::Left, Baseline::Middle, BLACK);
    }
}

/// Quality `Q` (top) and mean FLIP error (bottom) against primitives drawn (log scale): a small
/// dot per frame and a large one at each technique's mean; the better technique sits further left
/// and higher in `Q`, lower in FLIP.
#[must_use]
pub fn quality_vs_primitives(report: &Report) -> Image {
    let (panel_height, gap) = (300u32, 60u32);
    let (width, height) = (720u32 + LEGEND_MARGIN, 36 + 2 * panel_height + gap + 48);
    let mut canvas = Canvas::new(width, height);
    let techniques = measured(report);
    type Metric = fn(&Row) -> f64;
    // Per panel: title, value, and the value its axis always shows (Q's best, FLIP's zero).
    let panels: [(&str, Metric, f64); 2] = [
        ("quality Q = 1 - |(1 - P, 1 - R)| against primitives drawn per frame", |r| r.coverage.quality(), 1.0),
        ("mean FLIP error against the reference, against primitives drawn per frame", |r| r.flip, 0.0),
    ];
    for (i, (title, metric, anchor)) in panels.iter().enumerate() {
        let x = Axis::log(report.rows.iter().map(primitives));
        let y = Axis::linear(report.rows.iter().map(metric).chain([*anchor]), 0.1);
        let top = 36 + i as i32 * (panel_height + gap) as i32;
        let area = Rectangle::new(Point::new(64, top), Size::new(720 - 64 - 24, panel_height));
        let panel = Panel { area, x, y };
        let last = i + 1 == panels.len();
        panel.draw_axes(&mut canvas, title, last.then_some("primitives, every kind (log)"));
        for &(name, colour, shape) in &techniques {
            for row in rows_of(report, name) {
                marker(&mut canvas, panel.point(primitives(row), metric(row)), 6, colour, shape);
            }
            let rows: Vec<&Row> = rows_of(report, name).collect();
            if !rows.is_empty() {
                let n = rows.len() as f64;
                let mean_x = rows.iter().map(|r| primitives(r)).sum::<f64>() / n;
                let mean_y = rows.iter().map(|r| metric(r)).sum::<f64>() / n;
                let centre = panel.point(mean_x, mean_y);
                marker(&mut canvas, centre, 15, BLACK, shape);
                marker(&mut canvas, centre, 11, colour, shape);
            }
        }
    }
    let entries: Vec<(String, Rgb888, Marker)> =
        techniques.iter().map(|(n, c, m)| (format!("{} (large: mean)", n.name()), *c, *m)).collect();
    legend_with_markers(&mut canvas, &legend_margin(width, 36, height - 84), &entries);
    canvas.into_image()
}

/// Multi-scale RMSE against primitives drawn (log), one panel per band of projected height that
/// has frames (largest first): a small marker per frame and a large one at each technique's mean
/// in the band, so the cheapest technique of acceptable error at each size on screen sits lowest
/// and furthest left. The panels share their axes.
#[must_use]
pub fn by_band(report: &Report) -> Image {
    use super::output::{BANDS, band_of};
    let techniques = measured(report);
    let band_of_row = |r: &Row| report.heights.get(r.frame).map(|&h| band_of(h));
    let bands: Vec<usize> =
        (0..BANDS.len()).filter(|&b| report.rows.iter().any(|r| band_of_row(r) == Some(b))).collect();
    let (panel_width, height) = (300u32, 420u32);
    let width = 64 + bands.len().max(1) as u32 * (panel_width + 24) + LEGEND_MARGIN;
    let mut canvas = Canvas::new(width, height);
    let x = Axis::log(report.rows.iter().map(primitives));
    let y = Axis::linear(report.rows.iter().map(|r| r.rmse.summary()).chain([0.0]), 1e-3);
    for (i, &band) in bands.iter().enumerate() {
        let left = 64 + i as i32 * (panel_width + 24) as i32;
        let area = Rectangle::new(Point::new(left, 36), Size::new(panel_width, height - 36 - 48));
        let panel = Panel { area, x, y };
        let title = format!("RMSE against primitives, {}", BANDS[band].1);
        panel.draw_axes(&mut canvas, &title, Some("primitives, every kind (log)"));
        for &(name, colour, shape) in &techniques {
            let rows: Vec<&Row> = rows_of(report, name).filter(|r| band_of_row(r) == Some(band)).collect();
            for row in &rows {
                marker(&mut canvas, panel.point(primitives(row), row.rmse.summary()), 5, colour, shape);
            }
            if !rows.is_empty() {
                let n = rows.len() as f64;
                let mean_x = rows.iter().map(|r| primitives(r)).sum::<f64>() / n;
                let mean_y = rows.iter().map(|r| r.rmse.summary()).sum::<f64>() / n;
                let centre = panel.point(mean_x, mean_y);
                marker(&mut canvas, centre, 15, BLACK, shape);
                marker(&mut canvas, centre, 11, colour, shape);
            }
        }
        if i == 0 {
            let entries: Vec<(String, Rgb888, Marker)> =
                techniques.iter().map(|(n, c, m)| (n.name().to_owned(), *c, *m)).collect();
            legend_with_markers(&mut canvas, &legend_margin(width, 36, height - 84), &entries);
        }
    }
    canvas.into_image()
}

/// Per-frame curves along the path, one panel each: Q, multi-scale RMSE, mean FLIP error,
/// primitives drawn (log) and temporal noise (the reference's dashed in grey).
#[must_use]
pub fn per_frame(report: &Report) -> Image {
    let (width, panel_height, gap) = (720u32, 150u32, 44u32);
    let panels = 5u32;
    let height = 24 + panels * (panel_height + gap);
    let mut canvas = Canvas::new(width, height);
    let techniques = measured(report);
    let frames = report.poses.len().max(1);
    let x = Axis { lo: 0.0, hi: (frames - 1).max(1) as f64, log: false };
    type Metric = fn(&Row) -> Option<f64>;
    // Per panel: title, value, log axis, and the value a linear axis always shows (Q's best, the
    // other figures' zero).
    let metrics: [(&str, Metric, bool, f64); 5] = [
        ("quality Q", |r| Some(r.coverage.quality()), false, 1.0),
        ("multi-scale RMSE (linear colour, mean over scales)", |r| Some(r.rmse.summary()), false, 0.0),
        ("mean FLIP error against the reference", |r| Some(r.flip), false, 0.0),
        ("primitives drawn, every kind (log)", |r| Some(primitives(r)), true, 0.0),
        ("temporal noise: multi-scale RMSE against the previous frame", |r| r.noise, false, 0.0),
    ];
    for (i, (title, metric, log, anchor)) in metrics.iter().enumerate() {
        let top = 24 + i as i32 * (panel_height + gap) as i32;
        let area = Rectangle::new(Point::new(64, top), Size::new(width - 64 - 24, panel_height));
        let mut values: Vec<f64> = report.rows.iter().filter_map(metric).collect();
        let noise_panel = i + 1 == metrics.len();
        if noise_panel {
            values.extend(report.rows.iter().filter_map(|r| r.reference_noise));
        }
        let y =
            if *log { Axis::log(values.into_iter()) } else { Axis::linear(values.into_iter().chain([*anchor]), 1e-3) };
        let panel = Panel { area, x, y };
        let last = i + 1 == metrics.len();
        panel.draw_axes(&mut canvas, title, last.then_some("frame"));
        if noise_panel {
            // The reference's noise, once (every technique's rows carry the same figure).
            if let Some((first, _, _)) = techniques.first() {
                let points: Vec<(f64, f64)> =
                    rows_of(report, *first).filter_map(|r| r.reference_noise.map(|n| (r.frame as f64, n))).collect();
                panel.polyline(&mut canvas, &points, REFERENCE, true);
            }
        }
        for (name, colour, _) in &techniques {
            let points: Vec<(f64, f64)> =
                rows_of(report, *name).filter_map(|r| metric(r).map(|v| (r.frame as f64, v))).collect();
            panel.polyline(&mut canvas, &points, *colour, false);
        }
        if i == 0 {
            let entries: Vec<(String, Rgb888, Marker)> =
                techniques.iter().map(|(n, c, m)| (n.name().to_owned(), *c, *m)).collect();
            legend_with_markers(&mut canvas, &area, &entries);
        }
        if noise_panel {
            legend(&mut canvas, &area, &[("reference (full mesh)".to_owned(), REFERENCE)]);
        }
    }
    canvas.into_image()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_place_values_and_choose_round_ticks() {
        let linear = Axis::linear([0.2, 0.9].into_iter(), 0.0);
        assert!(linear.lo < 0.2 && linear.hi > 0.9);
        assert!((linear.fraction(linear.lo)).abs() < 1e-12 && (linear.fraction(linear.hi) - 1.0).abs() < 1e-12);
        let ticks = linear.ticks();
        assert_eq!(ticks.len(), 4, "{ticks:?}");
        assert!(ticks.iter().zip([0.2, 0.4, 0.6, 0.8]).all(|(t, e)| (t - e).abs() < 1e-12), "{ticks:?}");
        assert_eq!(linear.tick_label(0.4), "0.4");
        let log = Axis::log([30.0, 45_000.0, 0.0].into_iter());
        assert_eq!((log.lo, log.hi), (10.0, 100_000.0));
        assert_eq!(log.ticks(), [10.0, 100.0, 1000.0, 10_000.0, 100_000.0]);
        assert!((log.fraction(1000.0) - 0.5).abs() < 1e-12);
        assert_eq!(log.tick_label(10_000.0), "10k");
        assert_eq!(
            (compact(1.0), compact(2_500_000.0), compact(1e9)),
            ("1".to_owned(), "2.5M".to_owned(), "1G".to_owned())
        );
        // A constant series still spans something.
        let flat = Axis::linear([0.5, 0.5].into_iter(), 1e-3);
        assert!(flat.hi > flat.lo);
    }

    /// The mean x and y of the pixels of `colour`.
    fn centroid(image: &Image, colour: Rgb888) -> (f64, f64) {
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for y in 0..image.height {
            for x in 0..image.width {
                if image.pixel(x, y)[..3] == [colour.r(), colour.g(), colour.b()] {
                    (sx, sy, n) = (sx + f64::from(x), sy + f64::from(y), n + 1.0);
                }
            }
        }
        assert!(n > 0.0, "no pixel of {colour:?}");
        (sx / n, sy / n)
    }

    #[test]
    fn the_quality_plot_puts_fewer_primitives_left_and_better_quality_higher() {
        let mut report = super::super::output::tests::report();
        report.techniques = vec![
            (TechniqueName::FULL, Availability::Measured),
            (TechniqueName::Technique(Technique::Spt), Availability::Measured),
        ];
        let mut rows = Vec::new();
        for frame in 0..2 {
            let mut full = report.rows[frame].clone();
            full.technique = TechniqueName::FULL;
            full.stats.submitted[treelod_render::Primitive::Triangle] = 100_000;
            full.coverage = super::super::metrics::Coverage { tp: 100, fp: 0, fn_: 0 };
            full.flip = 0.0;
            let mut spt = report.rows[frame].clone();
            spt.stats.submitted[treelod_render::Primitive::Triangle] = 500;
            spt.coverage = super::super::metrics::Coverage { tp: 80, fp: 20, fn_: 20 };
            spt.flip = 0.2;
            rows.extend([full, spt]);
        }
        report.rows = rows;
        let plot = quality_vs_primitives(&report);
        let (full_colour, spt_colour) =
            (style_of(TechniqueName::FULL).0, style_of(TechniqueName::Technique(Technique::Spt)).0);
        // The panels' halves, without the legend's margin (where both colours are too).
        let panels = plot.width - LEGEND_MARGIN;
        let half = |top: bool| {
            let rows = if top { 0..plot.height / 2 } else { plot.height / 2..plot.height };
            let rgba =
                rows.flat_map(|y| (0..panels).map(move |x| (x, y))).flat_map(|(x, y)| plot.pixel(x, y)).collect();
            Image { width: panels, height: plot.height / 2, rgba }
        };
        let (q, flip) = (half(true), half(false));
        let (full, spt) = (centroid(&q, full_colour), centroid(&q, spt_colour));
        assert!(spt.0 < full.0 - 200.0, "fewer primitives to the left: {spt:?} {full:?}");
        assert!(full.1 < spt.1 - 100.0, "higher Q higher up: {spt:?} {full:?}");
        let (full, spt) = (centroid(&flip, full_colour), centroid(&flip, spt_colour));
        assert!(spt.0 < full.0 - 200.0, "fewer primitives to the left: {spt:?} {full:?}");
        assert!(full.1 > spt.1 + 100.0, "lower FLIP lower down: {spt:?} {full:?}");
        let frames = per_frame(&report);
        assert_eq!((frames.width, frames.height), (720, 24 + 5 * (150 + 44)));
        centroid(&frames, full_colour);
        centroid(&frames, spt_colour);
        centroid(&frames, REFERENCE);
    }

    #[test]
    fn every_technique_has_its_own_colour_and_every_shape_is_drawn() {
        let looks: Vec<_> = TechniqueName::ALL.iter().map(|&n| style_of(n)).collect();
        for (i, a) in looks.iter().enumerate() {
            for b in &looks[i + 1..] {
                assert_ne!(a.0, b.0, "two techniques share a colour");
            }
        }
        // The techniques compared most often differ in shape too.
        let shapes: Vec<Marker> = [Technique::Spt, Technique::PruneOpt, Technique::Impostors, Technique::Ellipsoids]
            .into_iter()
            .map(|t| style(t, false).1)
            .chain([style(Technique::LodChain, false).1, style(Technique::Full, true).1])
            .collect();
        for (i, a) in shapes.iter().enumerate() {
            assert!(!shapes[i + 1..].contains(a), "{a:?} is shared: {shapes:?}");
        }
        for shape in [
            Marker::Circle,
            Marker::Square,
            Marker::Triangle,
            Marker::TriangleDown,
            Marker::Diamond,
            Marker::Cross,
            Marker::Plus,
        ] {
            let mut canvas = Canvas::new(21, 21);
            marker(&mut canvas, Point::new(10, 10), 13, BLACK, shape);
            let image = canvas.into_image();
            let dark = (0..21).flat_map(|y| (0..21).map(move |x| (x, y))).filter(|&(x, y)| image.pixel(x, y)[0] == 0);
            let n = dark.count();
            assert!((40..=169).contains(&n), "{shape:?} covers {n} pixels");
            assert_eq!(image.pixel(10, 10)[0], 0, "{shape:?} covers its centre");
        }
    }

    #[test]
    fn the_band_plot_has_a_panel_per_band_with_frames() {
        let report = super::super::output::tests::report();
        // Two frames, 600 px and 20 px high: two panels.
        let plot = by_band(&report);
        assert_eq!((plot.width, plot.height), (64 + 2 * (300 + 24) + LEGEND_MARGIN, 420));
        let spt = style_of(TechniqueName::Technique(Technique::Spt)).0;
        let width = plot.width - LEGEND_MARGIN;
        let rgba = (0..plot.height).flat_map(|y| (0..width).map(move |x| (x, y))).flat_map(|(x, y)| plot.pixel(x, y));
        let (x, _) = centroid(&Image { width, height: plot.height, rgba: rgba.collect() }, spt);
        // Markers in both panels: their mean lies between the panels' centres.
        assert!(x > 64.0 + 150.0 && x < 64.0 + 324.0 + 150.0, "{x}");
    }

    #[test]
    fn the_canvas_clips_what_falls_outside() {
        let mut canvas = Canvas::new(4, 3);
        line(&mut canvas, Point::new(-5, 1), Point::new(10, 1), BLACK, 1);
        let image = canvas.into_image();
        assert_eq!((image.width, image.height), (4, 3));
        assert!((0..4).all(|x| image.pixel(x, 1) == [0, 0, 0, 255]));
        assert_eq!(image.pixel(0, 0), [255, 255, 255, 255]);
    }
}
