//! The one error type of the build crate. Variants name the file and the offending part.

use std::path::PathBuf;

/// Everything that can stop a build.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BuildError {
    /// An operating-system error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The glTF JSON or GLB container does not parse or validate.
    #[error("{path}: not a valid glTF 2.0 file: {message}")]
    Gltf {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The file needs a feature treelod does not read (a compression extension, a
    /// non-triangle-only model, an unsupported image type).
    #[error("{path}: unsupported: {what}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What is unsupported, naming the extension, primitive or image.
        what: String,
    },
    /// A buffer the file refers to cannot be found or read (missing, not a regular file, shorter
    /// than declared).
    #[error("{path}: buffer {index} ({uri}) cannot be read: {reason}")]
    MissingBuffer {
        /// The file.
        path: PathBuf,
        /// Buffer index.
        index: usize,
        /// Its URI, or "GLB binary chunk".
        uri: String,
        /// Why.
        reason: String,
    },
    /// Data inside the file is inconsistent (accessor out of range, index out of range, …).
    #[error("{path}: {what}")]
    InvalidData {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the mesh and primitive.
        what: String,
    },
    /// A texture does not decode.
    #[error("{path}: image {index} does not decode: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// Image index.
        index: usize,
        /// The decoder's message.
        message: String,
    },
    /// Nothing drawable is left (no triangles, or all degenerate).
    #[error("{name}: no drawable triangles ({reason})")]
    NoGeometry {
        /// The tree or block.
        name: String,
        /// Why, e.g. how many triangles were dropped.
        reason: String,
    },
    /// The input needs more than a resource limit of the import allows
    /// ([`crate::ImportLimits`]); the file may be valid, but this build refuses it.
    #[error("{path}: {what}: {amount} {limit} exceed the limit of {max} (raise it with {})", limit.option())]
    Limit {
        /// The file.
        path: PathBuf,
        /// What needs it, naming the glTF object (`images[0]`, `meshes[2].primitives[0]`, …).
        what: String,
        /// The limit exceeded.
        limit: crate::import::Limit,
        /// How much the import needs with it: a total for bytes, instances and triangles, the
        /// image's own pixels for an image (counting stops at the first refusal).
        amount: u64,
        /// The limit's value.
        max: u64,
    },
    /// A setting is out of range.
    #[error("invalid setting: {0}")]
    Setting(String),
    /// A hierarchy could not be flattened (an internal invariant broke).
    #[error(transparent)]
    Spt(#[from] crate::spt::FlattenError),
    /// The container could not be encoded or written.
    #[error(transparent)]
    Format(#[from] treelod_format::Error),
}
