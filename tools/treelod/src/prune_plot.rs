//! The plot of `treelod build --prune-report --prune-plot DIR`: per pruning order, the optimal
//! scale `s_opt(λ)` and the quality it reaches, against Cook's stochastic order with `s = 1/λ`.

use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::Rectangle;
use treelod_build::PruneReport;
use treelod_build::prune::LAMBDAS;
use treelod_render::offscreen::Image;

use crate::eval::plot::{Axis, Canvas, PALETTE, Panel, REFERENCE, legend};

/// Two panels over λ: `s_opt` of every order with Cook's `1/λ` dashed, and the quality `Q` of
/// every order with `s_opt` and of Cook's, with the minimum quality as a dashed line.
#[must_use]
pub fn plot(name: &str, report: &PruneReport) -> Image {
    let (width, panel_height, gap) = (720u32, 200u32, 48u32);
    let mut canvas = Canvas::new(width, 24 + 2 * (panel_height + gap));
    let x = Axis { lo: 0.0, hi: 1.0, log: false };
    let lambdas: Vec<f64> = LAMBDAS.iter().map(|&l| f64::from(l)).collect();
    let cook_scale: Vec<(f64, f64)> = lambdas.iter().map(|&l| (l, 1.0 / l)).collect();
    let mut entries: Vec<(String, Rgb888)> = report
        .orders
        .iter()
        .enumerate()
        .map(|(i, o)| (format!("{} with s_opt", o.order.as_str()), PALETTE[i % PALETTE.len()]))
        .collect();
    entries.push(("stochastic with s_Cook = 1/λ".to_owned(), REFERENCE));

    // s_opt: a log axis, since 1/λ reaches 20 at λ = 0.05.
    let area = Rectangle::new(Point::new(64, 24), Size::new(width - 64 - 24, panel_height));
    let scales =
        report.orders.iter().flat_map(|o| o.scale.iter().map(|&s| f64::from(s))).chain(cook_scale.iter().map(|p| p.1));
    let panel = Panel { area, x, y: Axis::log(scales) };
    panel.draw_axes(&mut canvas, &format!("{name}: optimal leaf scale s_opt (area factor, log) against λ"), None);
    panel.polyline(&mut canvas, &cook_scale, REFERENCE, true);
    for (o, (_, colour)) in report.orders.iter().zip(&entries) {
        let points: Vec<(f64, f64)> = lambdas.iter().zip(&o.scale).map(|(&l, &s)| (l, f64::from(s))).collect();
        panel.polyline(&mut canvas, &points, *colour, false);
    }
    legend(&mut canvas, &area, &entries);

    // Q = 1 − ‖(1 − P, 1 − R)‖.
    let top = 24 + (panel_height + gap) as i32;
    let area = Rectangle::new(Point::new(64, top), Size::new(width - 64 - 24, panel_height));
    let qualities = report
        .orders
        .iter()
        .flat_map(|o| o.quality.iter().copied())
        .chain(report.cook_quality.iter().copied())
        .chain([1.0, f64::from(report.min_quality)]);
    let panel = Panel { area, x, y: Axis::linear(qualities, 1e-3) };
    panel.draw_axes(
        &mut canvas,
        &format!(
            "quality Q of {} px coverage images over the views; dashed: Q = {}",
            report.resolution, report.min_quality
        ),
        Some("λ, the fraction of leaves drawn"),
    );
    let floor = f64::from(report.min_quality);
    panel.polyline(&mut canvas, &[(0.0, floor), (1.0, floor)], REFERENCE, true);
    let cook: Vec<(f64, f64)> = lambdas.iter().copied().zip(report.cook_quality.iter().copied()).collect();
    panel.polyline(&mut canvas, &cook, REFERENCE, false);
    for (o, (_, colour)) in report.orders.iter().zip(&entries) {
        let points: Vec<(f64, f64)> = lambdas.iter().copied().zip(o.quality.iter().copied()).collect();
        panel.polyline(&mut canvas, &points, *colour, false);
    }
    canvas.into_image()
}
