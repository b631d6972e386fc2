//! The benchmark's camera path, after Clasen 2011 §7: "The path starts with an overview, followed
//! by a descent down to human perspective inside the main forest. Then it heads towards a smaller
//! group of trees and turns back to the main forest."
//!
//! The path is a few key poses fitted to the [`Forest`] (its radius, the separate group, the
//! trees' height), each an eye position and a heading (yaw about +y, pitch), interpolated over time
//! by monotone cubic Hermite splines (Fritsch and Carlson 1980) of x, ln(height), z, yaw and
//! pitch: smooth, with no overshoot below the lowest key height, and the descent from the overview
//! to human height takes as long per halving of the height at every altitude.

use glam::{Vec2, Vec3};

use super::forest::Forest;
use crate::eval::path::Pose;

/// Height of the eye inside the forest, metres (clamped to 5–40 % of the trees' height for models
/// in other units).
const HUMAN_HEIGHT: f32 = 1.7;
/// The overview looks down at this angle, degrees.
const OVERVIEW_PITCH: f32 = 50.0;
/// The farthest the overview stands from the forest's centre, metres (the far plane is at 20 km).
const OVERVIEW_MAX_DISTANCE: f32 = 15_000.0;
/// Samples of the continuous path for [`ground_track`].
const TRACK_SAMPLES: usize = 256;

/// Which part of the path a frame belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Phase {
    /// High above, the whole forest in view: every tree a few pixels.
    Overview,
    /// Down from the overview to human height at the edge of the main forest.
    Descent,
    /// At human height through the main forest.
    Inside,
    /// Above the canopy towards the separate group.
    ToGroup,
    /// Past the separate group, turning back to look at the main forest from the side.
    Back,
}

impl Phase {
    /// The name in the CSV and the plot.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Overview => "overview",
            Self::Descent => "descent",
            Self::Inside => "inside",
            Self::ToGroup => "to-group",
            Self::Back => "back",
        }
    }
}

/// One frame of the path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// The camera.
    pub pose: Pose,
    /// The part of the path.
    pub phase: Phase,
}

/// A key pose: at time `t` (0..=1) the eye is at `eye`, heading `yaw` degrees (0 looks along −z,
/// 90 along +x) and `pitch` degrees (negative looks down); the segment to the next key belongs to
/// `phase`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Key {
    t: f32,
    eye: Vec3,
    yaw: f32,
    pitch: f32,
    phase: Phase,
}

/// The key poses fitted to `forest`, for a vertical field of view `fovy` (radians) and an image
/// `aspect` (width / height).
fn keys(forest: &Forest, fovy: f32, aspect: f32) -> Vec<Key> {
    let h = forest.tree_height.max(0.1);
    let human = HUMAN_HEIGHT.clamp(0.05 * h, 0.4 * h);
    let rm = forest.main_radius.max(h);
    let (sx, rs) = (forest.small_centre.x.max(rm), forest.small_radius);
    // The overview frames the main forest and the separate group: along x from −rm to sx + rs,
    // across the view's width; the main forest's depth, foreshortened, across its height.
    let centre_x = 0.5 * (sx + rs - rm);
    let half_width = 0.5 * (sx + rs + rm);
    let (half_v, pitch) = ((0.5 * fovy).tan(), OVERVIEW_PITCH.to_radians());
    let half_h = half_v * aspect.max(0.1);
    let d0 = (1.25 * (half_width / half_h).max(rm * pitch.sin() / half_v)).clamp(10.0 * h, OVERVIEW_MAX_DISTANCE);
    let overview =
        |x: f32, scale: f32| Vec3::new(centre_x + x * d0, scale * d0 * pitch.sin(), scale * d0 * pitch.cos());
    let low = (6.0 * h).max(0.06 * d0);
    let canopy = 1.6 * h;
    let gap = (sx - rs - rm).max(h);
    let key = |t, eye, yaw, pitch, phase| Key { t, eye, yaw, pitch, phase };
    vec![
        key(0.00, overview(-0.05, 1.0), 0.0, -OVERVIEW_PITCH, Phase::Overview),
        key(0.14, overview(0.05, 0.9), 0.0, -OVERVIEW_PITCH, Phase::Descent),
        key(0.30, Vec3::new(0.2 * rm, low, 1.15 * rm), -10.0, -25.0, Phase::Descent),
        key(0.42, Vec3::new(0.1 * rm, human, 0.7 * rm), 0.0, -2.0, Phase::Inside),
        key(0.54, Vec3::new(0.0, human, 0.2 * rm), 40.0, 0.0, Phase::Inside),
        key(0.66, Vec3::new(0.85 * rm, canopy, -0.05 * rm), 90.0, -3.0, Phase::ToGroup),
        // Around the group's south side, looking at it (a left turn), then west, back at the main
        // forest seen from the side.
        key(0.80, Vec3::new(sx - rs - 4.0 * h, canopy, 0.0), 90.0, -3.0, Phase::Back),
        key(0.88, Vec3::new(sx + 0.3 * rs, 2.0 * h, rs + 6.0 * h), 0.0, -5.0, Phase::Back),
        key(1.00, Vec3::new(sx - rs - 0.5 * gap, 3.0 * h, 0.4 * rm), -80.0, -4.0, Phase::Back),
    ]
}

/// The eye, heading and phase at time `t` (0..=1).
fn sample(keys: &[Key], t: f32) -> (Vec3, f32, f32, Phase) {
    let times: Vec<f32> = keys.iter().map(|k| k.t).collect();
    let component = |f: &dyn Fn(&Key) -> f32| {
        let values: Vec<f32> = keys.iter().map(f).collect();
        monotone_cubic(&times, &values, t)
    };
    let x = component(&|k| k.eye.x);
    let y = component(&|k| k.eye.y.max(1e-3).ln()).exp();
    let z = component(&|k| k.eye.z);
    let yaw = component(&|k| k.yaw);
    let pitch = component(&|k| k.pitch);
    let segment = keys.iter().rposition(|k| k.t <= t).unwrap_or(0).min(keys.len().saturating_sub(2));
    let phase = keys.get(segment).map_or(Phase::Overview, |k| k.phase);
    (Vec3::new(x, y, z), yaw, pitch, phase)
}

/// The pose looking from `eye` along `yaw` and `pitch` (degrees).
fn pose(eye: Vec3, yaw: f32, pitch: f32) -> Pose {
    let (yaw, pitch) = (yaw.to_radians(), pitch.to_radians());
    let direction = Vec3::new(pitch.cos() * yaw.sin(), pitch.sin(), -pitch.cos() * yaw.cos());
    Pose { eye, target: eye + 10.0 * direction }
}

/// `frames` frames evenly spread over the path (one frame: the first pose).
#[must_use]
pub fn fly_through(forest: &Forest, frames: usize, fovy: f32, aspect: f32) -> Vec<Frame> {
    let keys = keys(forest, fovy, aspect);
    (0..frames)
        .map(|i| {
            let t = if frames > 1 { i as f32 / (frames - 1) as f32 } else { 0.0 };
            let (eye, yaw, pitch, phase) = sample(&keys, t);
            Frame { pose: pose(eye, yaw, pitch), phase }
        })
        .collect()
}

/// The ground positions (x, z) of the path where the eye is lower than `height`, as runs of a
/// densely sampled polyline (independent of the frame count), for clearing trunks off it.
#[must_use]
pub fn ground_track(forest: &Forest, fovy: f32, aspect: f32, height: f32) -> Vec<Vec<Vec2>> {
    let keys = keys(forest, fovy, aspect);
    let mut runs: Vec<Vec<Vec2>> = Vec::new();
    let mut run = Vec::new();
    for i in 0..=TRACK_SAMPLES {
        let (eye, ..) = sample(&keys, i as f32 / TRACK_SAMPLES as f32);
        if eye.y < height {
            run.push(Vec2::new(eye.x, eye.z));
        } else if !run.is_empty() {
            runs.push(std::mem::take(&mut run));
        }
    }
    if !run.is_empty() {
        runs.push(run);
    }
    runs
}

/// The monotone cubic Hermite interpolant (Fritsch–Carlson) of `values` at increasing `times`,
/// evaluated at `t` (clamped to the range): it overshoots no key value and is flat at a local
/// extremum.
fn monotone_cubic(times: &[f32], values: &[f32], t: f32) -> f32 {
    let n = times.len().min(values.len());
    match n {
        0 => return 0.0,
        1 => return values[0],
        _ => {}
    }
    let secant: Vec<f32> =
        (0..n - 1).map(|k| (values[k + 1] - values[k]) / (times[k + 1] - times[k]).max(f32::EPSILON)).collect();
    let mut slopes: Vec<f32> = (0..n)
        .map(|k| match k {
            0 => secant[0],
            k if k == n - 1 => secant[n - 2],
            k if secant[k - 1] * secant[k] > 0.0 => 0.5 * (secant[k - 1] + secant[k]),
            _ => 0.0,
        })
        .collect();
    for k in 0..n - 1 {
        if secant[k] == 0.0 {
            slopes[k] = 0.0;
            slopes[k + 1] = 0.0;
            continue;
        }
        let (a, b) = (slopes[k] / secant[k], slopes[k + 1] / secant[k]);
        // Slopes against the secant's direction would overshoot.
        if a < 0.0 {
            slopes[k] = 0.0;
        }
        if b < 0.0 {
            slopes[k + 1] = 0.0;
        }
        let r = a * a + b * b;
        if r > 9.0 {
            let tau = 3.0 / r.sqrt();
            slopes[k] = tau * a * secant[k];
            slopes[k + 1] = tau * b * secant[k];
        }
    }
    let t = t.clamp(times[0], times[n - 1]);
    let k = (0..n - 1).rfind(|&k| times[k] <= t).unwrap_or(0);
    let h = (times[k + 1] - times[k]).max(f32::EPSILON);
    let s = (t - times[k]) / h;
    let (s2, s3) = (s * s, s * s * s);
    (2.0 * s3 - 3.0 * s2 + 1.0) * values[k]
        + (s3 - 2.0 * s2 + s) * h * slopes[k]
        + (-2.0 * s3 + 3.0 * s2) * values[k + 1]
        + (s3 - s2) * h * slopes[k + 1]
}

#[cfg(test)]
mod tests {
    use super::super::forest::{Shape, layout};
    use super::*;

    #[test]
    fn the_interpolant_passes_the_keys_and_does_not_overshoot() {
        let times = [0.0, 0.3, 0.5, 1.0];
        let values = [10.0, 1.0, 1.0, 4.0];
        for (t, v) in times.iter().zip(values) {
            assert!((monotone_cubic(&times, &values, *t) - v).abs() < 1e-5);
        }
        for i in 0..=1000 {
            let t = i as f32 / 1000.0;
            let v = monotone_cubic(&times, &values, t);
            assert!((1.0 - 1e-5..=10.0 + 1e-5).contains(&v), "{t}: {v}");
            if (0.3..=0.5).contains(&t) {
                assert!((v - 1.0).abs() < 1e-5, "flat between equal keys: {t}: {v}");
            }
        }
        assert_eq!(monotone_cubic(&[0.0], &[3.0], 0.5), 3.0);
        assert_eq!(monotone_cubic(&[0.0, 1.0], &[3.0, 5.0], 7.0), 5.0);
    }

    #[test]
    fn the_path_flies_over_descends_walks_and_turns_back() {
        let forest = layout(10_000, 1, &[Shape { radius: 3.2, height: 5.5 }]);
        let frames = fly_through(&forest, 200, 50f32.to_radians(), 16.0 / 9.0);
        assert_eq!(frames.len(), 200);
        let phases: Vec<Phase> = frames.iter().map(|f| f.phase).collect();
        let mut order = phases.clone();
        order.dedup();
        assert_eq!(order, [Phase::Overview, Phase::Descent, Phase::Inside, Phase::ToGroup, Phase::Back]);
        // The overview is high above the forest, the walk at human height inside it.
        let first = frames[0].pose;
        assert!(first.eye.y > 500.0, "{first:?}");
        assert!((first.target - first.eye).y < 0.0, "looks down");
        for frame in frames.iter().filter(|f| f.phase == Phase::Inside).take(10) {
            let p = frame.pose.eye;
            assert!(p.y < 2.0 && p.y > 1.0, "{p}");
            assert!(Vec2::new(p.x, p.z).length() < forest.main_radius, "{p}");
        }
        // Every eye is above the ground and looks somewhere.
        assert!(frames.iter().all(|f| f.pose.eye.y > 1.0 && f.pose.eye.is_finite() && f.pose.eye != f.pose.target));
        // Towards the separate group (+x), then back: the last frame looks west at the forest.
        let last = frames[199].pose;
        assert!(last.eye.x > forest.main_radius && (last.target - last.eye).x < 0.0, "{last:?}");
        let closest = frames.iter().map(|f| Vec2::new(f.pose.eye.x, f.pose.eye.z).distance(forest.small_centre));
        assert!(closest.fold(f32::INFINITY, f32::min) < forest.small_radius + 40.0);
        // One frame: the first pose.
        assert_eq!(fly_through(&forest, 1, 1.0, 1.0).len(), 1);
        // The low part of the path is one run, inside the main forest.
        let track = ground_track(&forest, 50f32.to_radians(), 16.0 / 9.0, 1.5 * 5.5);
        assert_eq!(track.len(), 1, "{track:?}");
        assert!(track[0].len() > 20);
    }
}
