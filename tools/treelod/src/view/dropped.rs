//! Files dropped on the viewer's window: a `.treelod` container or a JSON scene is shown at once;
//! a glTF file (`.glb`, `.gltf`) is built with `treelod build`'s defaults on a background thread,
//! into a temporary directory the viewer removes on exit, while the panel shows the progress.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Instant;

use glam::Vec3;

use crate::build::{self, BuildOptions};
use crate::report::{self, Failed};
use treelod_format::ErrorClass;

/// How far a build is: the stage, and the share of it done where the stage reports one.
#[derive(Clone, Debug, PartialEq)]
pub struct Status {
    pub stage: String,
    pub fraction: Option<f32>,
}

/// What a finished build gives: the container written and the warnings printed, or the failure
/// and the lines printed.
pub type Outcome = Result<(PathBuf, Vec<String>), (Failed, Vec<String>)>;

/// A build of a dropped glTF file on its own thread.
pub struct DroppedBuild {
    /// The dropped file.
    pub source: PathBuf,
    /// When the build started.
    pub started: Instant,
    status: Arc<Mutex<Status>>,
    handle: Option<JoinHandle<Outcome>>,
}

impl DroppedBuild {
    /// Starts building `source` into `output` with the build's default options.
    #[must_use]
    pub fn start(source: PathBuf, output: PathBuf) -> Self {
        let status = Arc::new(Mutex::new(Status { stage: "importing".to_owned(), fraction: None }));
        let shared = Arc::clone(&status);
        let input = source.clone();
        let handle = std::thread::spawn(move || {
            let set = move |stage: &str, fraction: Option<f32>| {
                *shared.lock().unwrap_or_else(PoisonError::into_inner) = Status { stage: stage.to_owned(), fraction };
            };
            let (result, lines) = report::capturing(|| {
                let mut options = BuildOptions::defaults();
                let hook = set.clone();
                options.progress = treelod_build::Progress::new(move |stage, done, total| {
                    if done < total {
                        hook(stage, Some(done as f32 / total.max(1) as f32));
                    } else {
                        hook("building", None);
                    }
                });
                let scene = build::import(&input, &options)?;
                set("building", None);
                let name = scene.name.clone();
                build::build_container(&name, vec![(scene, Vec3::ZERO)], &[input.as_path()], &output, &options)
            });
            match result {
                Ok(_) => Ok((output, lines)),
                Err(failed) => Err((failed, lines)),
            }
        });
        Self { source, started: Instant::now(), status, handle: Some(handle) }
    }

    /// The build's current stage.
    #[must_use]
    pub fn status(&self) -> Status {
        self.status.lock().unwrap_or_else(PoisonError::into_inner).clone()
    }

    /// The outcome once the build has finished (once; `None` before and after).
    pub fn finished(&mut self) -> Option<Outcome> {
        if !self.handle.as_ref().is_some_and(JoinHandle::is_finished) {
            return None;
        }
        let handle = self.handle.take()?;
        Some(handle.join().unwrap_or_else(|_| {
            let line =
                format!("error: {}: the build stopped unexpectedly (a bug: please report it)", self.source.display());
            Err((Failed { class: ErrorClass::Invalid }, vec![line]))
        }))
    }
}

/// The container path a build of `source` writes in `directory`: its name with `.treelod`,
/// numbered `n` so that dropping the same file twice does not replace a container in use.
#[must_use]
pub fn output_path(directory: &Path, source: &Path, n: u32) -> PathBuf {
    let stem = source.file_stem().map_or_else(|| "dropped".into(), |s| s.to_string_lossy().into_owned());
    directory.join(format!("{stem}-{n}.treelod"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builds_are_numbered_so_a_second_drop_does_not_replace_a_container_in_use() {
        assert_eq!(output_path(Path::new("/tmp/x"), Path::new("lib/oak.glb"), 2), Path::new("/tmp/x/oak-2.treelod"));
    }

    #[test]
    fn a_bad_gltf_reports_its_error_lines_and_writes_nothing() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let source = dir.path().join("broken.glb");
        std::fs::write(&source, b"glTF but not really").expect("writes");
        let output = output_path(dir.path(), &source, 1);
        let mut build = DroppedBuild::start(source.clone(), output.clone());
        let outcome = loop {
            if let Some(outcome) = build.finished() {
                break outcome;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        };
        let (failed, lines) = outcome.expect_err("the build fails");
        assert_eq!(failed.class, ErrorClass::Invalid);
        assert!(lines.iter().any(|l| l.starts_with(&format!("error: {}", source.display()))), "{lines:?}");
        assert!(!output.exists());
        assert!(build.finished().is_none(), "the outcome is given once");
    }
}
