//! Camera paths of `treelod eval`: the path file format and the built-in paths (`--views`,
//! `--orbit`, `--approach`).
//!
//! A path file is a JSON array of frames, each an object with `eye` and `target` (metres, world
//! space), looked at with Y up:
//!
//! ```json
//! [
//!   {"eye": [0.0, 4.0, 20.0], "target": [0.0, 4.0, 0.0]},
//!   {"eye": [2.0, 4.0, 19.9], "target": [0.0, 4.0, 0.0]}
//! ]
//! ```
//!
//! At least one frame; unknown fields are refused; `eye` and `target` must differ and be finite
//! within `f32` range.

use std::path::Path;

use glam::{Quat, Vec3};
use serde::Deserialize;

/// One camera of a path: where the eye is and what it looks at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Eye position, metres.
    pub eye: Vec3,
    /// Point looked at, metres.
    pub target: Vec3,
}

/// One frame as written in a path file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseFile {
    eye: [f64; 3],
    target: [f64; 3],
}

/// Parses the text of a path file. The error is the reason, without the file's name.
///
/// # Errors
/// What is wrong: JSON syntax (with line and column), a missing or unknown field, no frames, a
/// number beyond `f32`, an eye equal to its target.
pub fn parse(bytes: &[u8]) -> Result<Vec<Pose>, String> {
    let frames: Vec<PoseFile> = serde_json::from_slice(bytes).map_err(|e| {
        let text = e.to_string();
        let position = format!(" at line {} column {}", e.line(), e.column());
        let message = text.strip_suffix(&position).unwrap_or(&text);
        format!("line {}, column {}: {message} (a path file is a JSON array of {{\"eye\": [x, y, z], \"target\": [x, y, z]}})", e.line(), e.column())
    })?;
    if frames.is_empty() {
        return Err("the path has no frames (a path file is a JSON array of {\"eye\", \"target\"} objects)".to_owned());
    }
    frames
        .iter()
        .enumerate()
        .map(|(i, frame)| {
            let vec = |what: &str, v: [f64; 3]| {
                let v = Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32);
                if v.is_finite() { Ok(v) } else { Err(format!("frame {i}: `{what}` is beyond the range of f32")) }
            };
            let (eye, target) = (vec("eye", frame.eye)?, vec("target", frame.target)?);
            if eye.distance_squared(target) < 1e-12 {
                return Err(format!("frame {i}: `eye` and `target` are the same point"));
            }
            Ok(Pose { eye, target })
        })
        .collect()
}

/// Reads and parses a path file; the error is the reason and whether the file could be read.
///
/// # Errors
/// `(true, reason)` if the file cannot be read, `(false, reason)` if its content is invalid.
pub fn load(path: &Path) -> Result<Vec<Pose>, (bool, String)> {
    if path.is_dir() {
        return Err((true, "is a directory, not a path file".to_owned()));
    }
    let bytes = std::fs::read(path).map_err(|e| (true, e.to_string()))?;
    parse(&bytes).map_err(|m| (false, m))
}

/// `count` cameras on a circle around `target` at `distance`, starting from the direction
/// `start` (from the target towards the eye) and turning about +y by `360° / count` each, at the
/// elevation of `start`.
#[must_use]
pub fn circle(target: Vec3, start: Vec3, distance: f32, count: usize) -> Vec<Pose> {
    let start = start.normalize_or(Vec3::Z);
    (0..count)
        .map(|i| {
            let angle = std::f32::consts::TAU * i as f32 / count.max(1) as f32;
            Pose { eye: target + Quat::from_rotation_y(angle) * start * distance, target }
        })
        .collect()
}

/// `count` cameras approaching `target` along the direction `start` (from the target towards the
/// eye), from `far` to `near`, the distances in geometric progression (each frame the same
/// fraction closer, so the image grows by the same factor from frame to frame), all looking at
/// `target`.
#[must_use]
pub fn approach(target: Vec3, start: Vec3, far: f32, near: f32, count: usize) -> Vec<Pose> {
    let start = start.normalize_or(Vec3::Z);
    let steps = count.saturating_sub(1).max(1) as f32;
    (0..count)
        .map(|i| {
            let distance = far * (near / far).powf(i as f32 / steps);
            Pose { eye: target + start * distance, target }
        })
        .collect()
}

/// Parses `--orbit D1,D2,…`: distances in bounding radii, each positive and finite.
///
/// # Errors
/// A message for the argument parser.
pub fn parse_distances(s: &str) -> Result<Vec<f32>, String> {
    let values: Vec<Option<f32>> =
        s.split(',').map(|v| v.trim().parse::<f32>().ok().filter(|v| v.is_finite() && *v > 0.0)).collect();
    if values.is_empty() || values.len() > 64 || values.iter().any(Option::is_none) {
        return Err(format!(
            "expected distances in bounding radii, positive numbers separated by commas (e.g. 2,6,20), got {s:?}"
        ));
    }
    Ok(values.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_file_parses_and_bad_ones_say_why() {
        let poses = parse(br#"[{"eye": [0, 4, 20], "target": [0, 4, 0]}, {"target": [1,2,3], "eye": [1,2,4]}]"#)
            .expect("valid");
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[0], Pose { eye: Vec3::new(0.0, 4.0, 20.0), target: Vec3::new(0.0, 4.0, 0.0) });
        for (text, expected) in [
            ("[]", "no frames"),
            ("", "line 1, column 0"),
            ("[{\"eye\": [0,0,1]}]", "missing field `target`"),
            ("[{\"eye\": [0,0,1], \"target\": [0,0,0], \"fov\": 3}]", "unknown field `fov`"),
            ("[{\"eye\": [0,0,0], \"target\": [0,0,0]}]", "frame 0: `eye` and `target` are the same point"),
            (
                "[{\"eye\": [0,0,1], \"target\": [0,0,0]}, {\"eye\": [1e300,0,1], \"target\": [0,0,0]}]",
                "frame 1: `eye`",
            ),
            ("{\"eye\": [0,0,1], \"target\": [0,0,0]}", "expected a sequence"),
        ] {
            let err = parse(text.as_bytes()).expect_err(text);
            assert!(err.contains(expected), "{text}: {err}");
        }
    }

    #[test]
    fn circles_turn_about_the_target_at_the_distance() {
        let target = Vec3::new(1.0, 2.0, 3.0);
        let poses = circle(target, Vec3::new(0.0, 1.0, 1.0), 10.0, 4);
        assert_eq!(poses.len(), 4);
        for pose in &poses {
            assert!((pose.eye.distance(target) - 10.0).abs() < 1e-4 && pose.target == target);
            assert!((pose.eye.y - target.y - 10.0 * std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-4);
        }
        let across = poses[0].eye - poses[2].eye;
        assert!(across.x.hypot(across.z) > 14.0, "opposite sides");
        assert_eq!(parse_distances("2, 6,20"), Ok(vec![2.0, 6.0, 20.0]));
        let near = approach(target, Vec3::Z, 1000.0, 1.0, 4);
        let distances: Vec<f32> = near.iter().map(|p| p.eye.distance(target)).collect();
        for (d, expected) in distances.iter().zip([1000.0, 100.0, 10.0, 1.0]) {
            assert!((d - expected).abs() < 1e-3 * expected, "{distances:?}");
        }
        for bad in ["", "0", "-1", "2,,3", "x", "inf"] {
            assert!(parse_distances(bad).is_err(), "{bad}");
        }
    }
}
