//! Writing reports: every file through a temporary file and a rename
//! ([`treelod_format::write_atomically`]), so a reader never sees half a report.

use std::path::Path;

use treelod_render::offscreen::Image;

use crate::Error;
use crate::offscreen::encode_png;

/// Writes `bytes` to `path` atomically.
///
/// # Errors
/// [`Error::OutputIsDirectory`] if `path` is a directory, [`Error::Write`] if writing fails.
pub fn atomically(path: &Path, bytes: &[u8]) -> Result<(), Error> {
    if path.is_dir() {
        return Err(Error::OutputIsDirectory { path: path.to_owned() });
    }
    treelod_format::write_atomically(path, bytes).map_err(|source| Error::Write { path: path.to_owned(), source })
}

/// Writes `image` as an 8-bit RGBA PNG tagged sRGB to `path`, atomically.
///
/// # Errors
/// [`Error::Encode`] if the PNG cannot be encoded, else as [`atomically`].
pub fn png(path: &Path, image: &Image) -> Result<(), Error> {
    let png =
        encode_png(image).map_err(|e| Error::Encode { path: path.to_owned(), what: "PNG", message: e.to_string() })?;
    atomically(path, &png)
}

/// Writes the JSON `text` (or the error that kept it from being encoded) to `path`, atomically.
///
/// # Errors
/// [`Error::Encode`] if the JSON could not be encoded, else as [`atomically`].
pub fn json(path: &Path, text: Result<String, serde_json::Error>) -> Result<(), Error> {
    let text = text.map_err(|e| Error::Encode { path: path.to_owned(), what: "JSON", message: e.to_string() })?;
    atomically(path, text.as_bytes())
}

/// Refuses any of `outputs` that is a directory, before a run spends its time.
///
/// # Errors
/// [`Error::OutputIsDirectory`] for the first that is.
pub fn check_outputs<'a>(outputs: impl IntoIterator<Item = &'a Path>) -> Result<(), Error> {
    for output in outputs {
        if output.is_dir() {
            return Err(Error::OutputIsDirectory { path: output.to_owned() });
        }
    }
    Ok(())
}
