//! Error reporting and exit codes shared by the subcommands.
//!
//! Nothing here panics: writes to stderr ignore failures (there is nowhere left to report them),
//! writes to stdout turn a closed pipe into a quiet stop and other failures into an I/O error.
//! While a progress bar is registered ([`set_progress_bar`]), every line is printed above it.

use std::cell::RefCell;
use std::io::{self, Write as _};
use std::path::Path;
use std::sync::{Mutex, PoisonError};

use treelod_format::{Container, Error, ErrorClass};

/// Exit code of invalid input ([`ErrorClass::Invalid`]).
pub const EXIT_INVALID: u8 = 3;
/// Exit code of an unsupported version or feature ([`ErrorClass::Unsupported`]).
pub const EXIT_UNSUPPORTED: u8 = 4;
/// Exit code of an operating-system error ([`ErrorClass::Io`]).
pub const EXIT_IO: u8 = 5;

/// A failure that has already been printed to stderr; only its class is left to decide the exit
/// code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Failed {
    /// The class of the failure.
    pub class: ErrorClass,
}

impl Failed {
    /// The process exit code of this failure's class.
    #[must_use]
    pub fn exit_code(self) -> u8 {
        match self.class {
            ErrorClass::Invalid => EXIT_INVALID,
            ErrorClass::Unsupported => EXIT_UNSUPPORTED,
            ErrorClass::Io => EXIT_IO,
        }
    }
}

/// The progress bar drawn on stderr, if any.
static PROGRESS: Mutex<Option<indicatif::ProgressBar>> = Mutex::new(None);

/// Registers `bar` (or none) as the progress bar that the printing functions of this module hide
/// while they write a line and redraw after, so lines and bar do not garble each other. A bar that
/// is not drawn (stderr is not a terminal) costs nothing.
pub fn set_progress_bar(bar: Option<indicatif::ProgressBar>) {
    *PROGRESS.lock().unwrap_or_else(PoisonError::into_inner) = bar;
}

/// Runs `print` with the registered progress bar, if any, hidden.
fn above_progress<R>(print: impl FnOnce() -> R) -> R {
    let bar = PROGRESS.lock().unwrap_or_else(PoisonError::into_inner).clone();
    match bar {
        Some(bar) => bar.suspend(print),
        None => print(),
    }
}

/// Opens and validates a container (spec §9.1), reporting a failure as [`file_error`] does.
///
/// A directory is refused up front with a clear message (mapping one fails with an obscure
/// operating-system error).
pub fn open(path: &Path) -> Result<Container, Failed> {
    open_unreported(path).map_err(|(message, class)| {
        print_error(&message);
        Failed { class }
    })
}

/// [`open`] without printing: a failure is its message (`PATH: reason`, what [`print_error`]
/// prints after `error: `) and its class, for a caller that prints it later (`verify` checks
/// files side by side and reports them in the order given).
pub fn open_unreported(path: &Path) -> Result<Container, (String, ErrorClass)> {
    if path.is_dir() {
        return Err((format!("{}: is a directory, not a .treelod file", path.display()), ErrorClass::Io));
    }
    Container::open(path).map_err(|e| file_error_message(path, &e))
}

/// Prints `error: PATH: reason` for an error concerning `path` and returns its class.
///
/// The format crate already wraps errors with a path ([`Error::InFile`], [`Error::Io`]); that
/// wrapper is taken off here so the line names the file exactly once, as it was passed.
pub fn file_error(path: &Path, error: &Error) -> Failed {
    let (message, class) = file_error_message(path, error);
    print_error(&message);
    Failed { class }
}

/// What [`file_error`] prints after `error: `, and the error's class.
pub fn file_error_message(path: &Path, error: &Error) -> (String, ErrorClass) {
    (format!("{}: {}", path.display(), reason(error)), error.class())
}

/// The error's message without the path of its file.
fn reason(error: &Error) -> String {
    match error {
        Error::InFile { source, .. } => reason(source),
        Error::Io { source, .. } => source.to_string(),
        Error::NotReplaced { path, .. } => {
            let text = error.to_string();
            let shown = format!("{}: ", path.display());
            text.strip_prefix(&shown).map_or_else(|| text.clone(), str::to_owned)
        }
        other => other.to_string(),
    }
}

thread_local! {
    /// The lines printed by this thread while [`capturing`] runs.
    static CAPTURED: RefCell<Option<Vec<String>>> = const { RefCell::new(None) };
}

/// Runs `f` and returns, beside its result, the error and warning lines this thread printed
/// meanwhile (`error: …` and `warning: …`): for a window that shows what the
/// terminal shows (the viewer's build of a dropped file). The lines are still printed.
pub fn capturing<R>(f: impl FnOnce() -> R) -> (R, Vec<String>) {
    let outer = CAPTURED.with(|c| c.replace(Some(Vec::new())));
    let result = f();
    let lines = CAPTURED.with(|c| c.replace(outer)).unwrap_or_default();
    (result, lines)
}

/// Keeps `line` for [`capturing`], if this thread is capturing.
fn capture(line: String) {
    CAPTURED.with(|c| {
        if let Some(lines) = c.borrow_mut().as_mut() {
            lines.push(line);
        }
    });
}

/// Writes `error: MESSAGE` to stderr, ignoring a failure to do so.
pub fn print_error(message: &str) {
    capture(format!("error: {message}"));
    above_progress(|| {
        let _ = writeln!(io::stderr().lock(), "error: {message}");
    });
}

/// Writes `text` to stdout and flushes it.
///
/// A closed pipe (`treelod dump x | head`) is not an error: the reader has what it wanted, the
/// rest is dropped. Any other failure is reported as an I/O error on `<stdout>`.
pub fn write_stdout(text: &str) -> Result<(), Failed> {
    let written = above_progress(|| {
        let mut out = io::stdout().lock();
        out.write_all(text.as_bytes()).and_then(|()| out.flush())
    });
    match written {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        Err(e) => {
            print_error(&format!("<stdout>: {e}"));
            Err(Failed { class: ErrorClass::Io })
        }
    }
}

/// Prints `error: PATH: reason` for an operating-system error on `path`.
pub fn io_error(path: &Path, error: &io::Error) -> Failed {
    print_error(&format!("{}: {error}", path.display()));
    Failed { class: ErrorClass::Io }
}

/// Prints `error: PATH: message` for a problem with the contents of `path`.
pub fn message_error(path: &Path, message: &str) {
    print_error(&format!("{}: {message}", path.display()));
}

/// Prints `warning: PATH: message`, ignoring a failure to do so.
pub fn print_warning(path: &Path, message: &str) {
    capture(format!("warning: {}: {message}", path.display()));
    above_progress(|| {
        let _ = writeln!(io::stderr().lock(), "warning: {}: {message}", path.display());
    });
}

/// Prints a build error as `error: PATH: reason` and returns its class: I/O errors are
/// [`ErrorClass::Io`], unsupported glTF features and inputs over a resource limit
/// ([`treelod_build::ImportLimits`]) [`ErrorClass::Unsupported`], the rest [`ErrorClass::Invalid`].
pub fn build_error(path: &Path, error: &treelod_build::BuildError) -> Failed {
    use treelod_build::BuildError;
    let class = match error {
        BuildError::Io { .. } => ErrorClass::Io,
        BuildError::Unsupported { .. } | BuildError::Limit { .. } => ErrorClass::Unsupported,
        BuildError::Format(e) => e.class(),
        _ => ErrorClass::Invalid,
    };
    // Errors about a file already start with its path; the others get the input's.
    let text = error.to_string();
    let shown = path.display().to_string();
    if text.starts_with(&shown) {
        print_error(&text);
    } else {
        print_error(&format!("{shown}: {text}"));
    }
    Failed { class }
}

/// Writes `bytes` to `path` through a temporary file and a rename
/// ([`treelod_format::write_atomically`]), reporting a failure as `error: FILE: reason`.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), Failed> {
    if path.is_dir() {
        message_error(path, "is a directory; name the file to write");
        return Err(Failed { class: ErrorClass::Io });
    }
    treelod_format::write_atomically(path, bytes).map_err(|e| file_error(path, &e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capturing_keeps_this_threads_errors_and_warnings_and_nests() {
        let ((), outer) = capturing(|| {
            message_error(Path::new("a.glb"), "bad");
            let ((), inner) = capturing(|| print_warning(Path::new("b.glb"), "odd"));
            assert_eq!(inner, ["warning: b.glb: odd"]);
            // Another thread's lines are not this capture's.
            std::thread::spawn(|| print_error("elsewhere")).join().expect("joins");
        });
        assert_eq!(outer, ["error: a.glb: bad"]);
        message_error(Path::new("c.glb"), "not captured");
    }
}
