//! `treelod scatter`: writes a scene file of many instances of a few containers, placed at random
//! on the ground plane.
//!
//! The placement is deterministic: a splitmix64 generator seeded with `--seed` draws, per
//! instance, the model, x, z, the rotation about y and the scale, in that order, so the same
//! arguments give the same bytes on every machine.

use std::path::{Component, Path, PathBuf};

use treelod_build::SplitMix64;
use treelod_format::ErrorClass;

use crate::report::{self, Failed};
use crate::scene;

/// Square metres of ground per tree when `--area` is not given.
const GROUND_PER_TREE: f64 = 25.0;

/// Arguments of `treelod scatter`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Containers to place; each instance picks one at random.
    #[arg(value_name = "MODEL", required = true)]
    pub models: Vec<PathBuf>,
    /// Where to write the scene file (JSON).
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Number of instances.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub count: u32,
    /// Side of the square (metres, centred on the origin) the trees stand in; default: one tree
    /// per 25 m², i.e. `5 * sqrt(N)`.
    #[arg(long, value_name = "METRES", value_parser = parse_area)]
    pub area: Option<f64>,
    /// Seed of the placement.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

fn parse_area(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1.0e7 => Ok(v),
        _ => Err(format!("{s:?} is not a side length in metres (a number above 0, at most 1e7)")),
    }
}

/// Runs `treelod scatter`.
pub fn run(args: &Args) -> Result<(), Failed> {
    // Every model must be a container that opens, so a typo fails now rather than at render time.
    for model in &args.models {
        report::open(model)?;
    }
    let scene_dir = match args.output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    let mut written_models = Vec::with_capacity(args.models.len());
    for model in &args.models {
        let path = scene_relative(model, &scene_dir);
        let Some(text) = path.to_str() else {
            report::message_error(model, "the path is not valid UTF-8 and cannot be written to a scene file");
            return Err(Failed { class: ErrorClass::Invalid });
        };
        // Scene files use `/` on every platform.
        written_models.push(text.replace('\\', "/"));
    }
    let area = args.area.unwrap_or_else(|| (f64::from(args.count) * GROUND_PER_TREE).sqrt());
    let text = scene_text(&written_models, args.count, area, args.seed);
    report::write_atomically(&args.output, text.as_bytes())?;
    report::write_stdout(&format!(
        "{}: {} instances of {} model(s) on {area:.1} m x {area:.1} m (seed {})\n",
        args.output.display(),
        args.count,
        args.models.len(),
        args.seed
    ))
}

/// The scene file: one instance per line, numbers rounded (millimetres, hundredths of a degree,
/// thousandths of scale) so the text is short and the same everywhere.
fn scene_text(models: &[String], count: u32, area: f64, seed: u64) -> String {
    let mut rng = SplitMix64(seed);
    let mut out = String::with_capacity(96 * count as usize + 64);
    out.push_str(&format!("{{\n  \"version\": {},\n  \"models\": [\n", scene::VERSION));
    for (i, model) in models.iter().enumerate() {
        let quoted = serde_json::Value::String(model.clone()).to_string();
        let comma = if i + 1 < models.len() { "," } else { "" };
        out.push_str(&format!("    {quoted}{comma}\n"));
    }
    out.push_str("  ],\n  \"instances\": [\n");
    let n = models.len() as u64;
    for i in 0..count {
        let model = rng.below(n);
        let x = (rng.next_f64() - 0.5) * area;
        let z = (rng.next_f64() - 0.5) * area;
        let rotation = rng.next_f64() * 360.0;
        let scale = 0.8 + 0.4 * rng.next_f64();
        let comma = if i + 1 < count { "," } else { "" };
        out.push_str(&format!(
            "    {{\"model\": {model}, \"translation\": [{}, 0.0, {}], \"rotation_y_degrees\": {}, \"scale\": {}}}{comma}\n",
            fixed(x, 3),
            fixed(z, 3),
            fixed(rotation, 2),
            fixed(scale, 3),
        ));
    }
    out.push_str("  ]\n}\n");
    out
}

/// `value` with `decimals` decimals, never `-0.000`.
fn fixed(value: f64, decimals: usize) -> String {
    let text = format!("{value:.decimals$}");
    if text.starts_with('-') && text.bytes().all(|b| matches!(b, b'-' | b'0' | b'.')) {
        text[1..].to_owned()
    } else {
        text
    }
}

/// `model` as a path relative to `scene_dir` when both resolve (the scene file's reader joins it to
/// its directory), else the model's absolute path, else the path as given.
fn scene_relative(model: &Path, scene_dir: &Path) -> PathBuf {
    let (Ok(model_abs), Ok(dir_abs)) = (std::fs::canonicalize(model), std::fs::canonicalize(scene_dir)) else {
        return model.to_owned();
    };
    relative_path(&model_abs, &dir_abs).unwrap_or(model_abs)
}

/// `to` relative to the directory `from`; both absolute and normalised. `None` if they share no
/// root (other drives on Windows).
fn relative_path(to: &Path, from: &Path) -> Option<PathBuf> {
    let to: Vec<Component<'_>> = to.components().collect();
    let from: Vec<Component<'_>> = from.components().collect();
    if to.first() != from.first() {
        return None;
    }
    let common = to.iter().zip(&from).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..from.len() {
        out.push("..");
    }
    for part in &to[common..] {
        out.push(part.as_os_str());
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scene_text_is_deterministic_and_parses() {
        let models = vec!["a.treelod".to_owned(), "sub dir/b \"quoted\".treelod".to_owned()];
        let text = scene_text(&models, 200, 70.0, 7);
        assert_eq!(text, scene_text(&models, 200, 70.0, 7));
        assert_ne!(text, scene_text(&models, 200, 70.0, 8));
        let scene = scene::parse(text.as_bytes(), Path::new("dir/forest.json")).expect("parses");
        assert_eq!(scene.models[1], Path::new("dir/sub dir/b \"quoted\".treelod"));
        assert_eq!(scene.instances.len(), 200);
        let mut used = [0usize; 2];
        for instance in &scene.instances {
            used[instance.model] += 1;
            let (scale, rotation, t) = instance.transform.to_scale_rotation_translation();
            assert!(t.x.abs() <= 35.0 && t.z.abs() <= 35.0 && t.y == 0.0, "{t}");
            assert!((0.799..=1.201).contains(&scale.x), "{scale}");
            assert!((rotation * glam::Vec3::Y - glam::Vec3::Y).length() < 1e-4, "rotation about y only");
        }
        assert!(used[0] > 50 && used[1] > 50, "both models are used: {used:?}");
    }

    #[test]
    fn relative_paths_climb_to_the_common_directory() {
        let rel = |to: &str, from: &str| relative_path(Path::new(to), Path::new(from));
        assert_eq!(rel("/a/b/c.treelod", "/a/b"), Some(PathBuf::from("c.treelod")));
        assert_eq!(rel("/a/b/c.treelod", "/a/d/e"), Some(PathBuf::from("../../b/c.treelod")));
        assert_eq!(rel("/c.treelod", "/a"), Some(PathBuf::from("../c.treelod")));
    }

    #[test]
    fn fixed_never_writes_negative_zero() {
        assert_eq!(fixed(-0.0001, 3), "0.000");
        assert_eq!(fixed(-0.5, 1), "-0.5");
        assert_eq!(fixed(12.3456, 2), "12.35");
    }

    #[test]
    fn below_stays_in_range() {
        let mut rng = SplitMix64(3);
        assert!((0..1000).all(|_| rng.below(3) < 3));
        assert!((0..1000).map(|_| rng.next_f64()).all(|v| (0.0..1.0).contains(&v)));
    }
}
