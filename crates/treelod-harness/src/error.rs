//! Why a run of `eval` or `bench`, or the writing of its report, failed.

use std::path::{Path, PathBuf};

use treelod_format::ErrorClass;
use treelod_render::RenderError;
use treelod_render::offscreen::GpuError;

use crate::scene::SceneError;

/// Why a run or a write failed. Every variant names the file concerned, or the input the run was
/// about where no one file is to blame ([`Error::path`]); its message is `PATH: reason`, as the
/// `treelod` command prints it after `error: `, except for [`Error::Container`],
/// [`Error::Build`] and [`Error::Write`], whose sources carry the path themselves.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A scene file or one of its models cannot be used (the message starts with the file).
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A container does not open.
    #[error("{}: {source}", path.display())]
    Container {
        /// The container.
        path: PathBuf,
        /// Why.
        source: treelod_format::Error,
    },
    /// A path named as a container is a directory.
    #[error("{}: is a directory, not a .treelod file", path.display())]
    ContainerIsDirectory {
        /// The path.
        path: PathBuf,
    },
    /// A built-in model could not be built.
    #[error("{}: {source}", path.display())]
    Build {
        /// What the error lines name for it (`bench` for the built-in forest).
        path: PathBuf,
        /// Why.
        source: treelod_build::BuildError,
    },
    /// A camera path file cannot be read or is not a valid path.
    #[error("{}: {message}", path.display())]
    CameraPath {
        /// The path file.
        path: PathBuf,
        /// What is wrong.
        message: String,
        /// Whether the file could not be read (rather than read and refused).
        io: bool,
    },
    /// A file to write names a directory.
    #[error("{}: is a directory; name the file to write", path.display())]
    OutputIsDirectory {
        /// The path.
        path: PathBuf,
    },
    /// Writing a file failed.
    #[error("{}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why (the format crate's atomic write).
        source: treelod_format::Error,
    },
    /// A report could not be encoded (`what`: `PNG` or `JSON`).
    #[error("{}: cannot encode the {what}: {message}", path.display())]
    Encode {
        /// The file it was for.
        path: PathBuf,
        /// `PNG` or `JSON`.
        what: &'static str,
        /// The encoder's error.
        message: String,
    },
    /// No technique asked for can be measured: the inputs hold none of their data.
    #[error("{}: none of the techniques asked for can be measured", input.display())]
    NoneMeasurable {
        /// The input.
        input: PathBuf,
        /// Every technique asked for with why it is absent, as the report's heading lists them
        /// (`technique NAME: absent: REASON`, one per line).
        absent: String,
    },
    /// No device to draw with.
    #[error("{}: cannot render: {source}", input.display())]
    NoDevice {
        /// The input.
        input: PathBuf,
        /// Why.
        source: GpuError,
    },
    /// The images asked for are larger than the device draws.
    #[error("{}: {message}", input.display())]
    TooLarge {
        /// The input.
        input: PathBuf,
        /// The sizes and the device's limit.
        message: String,
    },
    /// Drawing or reading back a frame failed.
    #[error("{}: cannot render: {source}", input.display())]
    Render {
        /// The input.
        input: PathBuf,
        /// Why.
        source: GpuError,
    },
    /// The renderer refused a model.
    #[error("{label}: {source}")]
    AddModel {
        /// The model, as the report labels it.
        label: String,
        /// Why.
        source: RenderError,
    },
    /// GPU selection could not be enabled.
    #[error("{}: cannot select on the GPU: {source}", input.display())]
    GpuSelection {
        /// The input.
        input: PathBuf,
        /// Why.
        source: RenderError,
    },
    /// The device refused a frame (a validation error, e.g. more draws than one buffer binds).
    #[error(
        "{}: the device refused a frame: {message} (a frame of this forest may need more draws than the device binds in one buffer: try fewer --trees)",
        input.display()
    )]
    DeviceRefused {
        /// The input.
        input: PathBuf,
        /// The device's message, on one line.
        message: String,
    },
    /// The options are not valid (a size of 0, a supersampling factor out of range, …).
    #[error("{}: {message}", input.display())]
    Options {
        /// The input.
        input: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A bug: images or masks of one run that do not match.
    #[error("{}: internal error: {message}", input.display())]
    Internal {
        /// The input (or the model's label).
        input: PathBuf,
        /// What went wrong.
        message: String,
    },
}

impl Error {
    /// The class of the failure, which a command line turns into its exit code: unreadable or
    /// unwritable files and failed frames are [`ErrorClass::Io`], no device, a device too small,
    /// nothing to measure and newer files [`ErrorClass::Unsupported`], bad input
    /// [`ErrorClass::Invalid`].
    #[must_use]
    pub fn class(&self) -> ErrorClass {
        match self {
            Self::Scene(e) => e.class(),
            Self::Container { source, .. } | Self::Write { source, .. } => source.class(),
            Self::Build { source, .. } => build_class(source),
            Self::CameraPath { io: false, .. } | Self::Options { .. } => ErrorClass::Invalid,
            Self::NoneMeasurable { .. }
            | Self::NoDevice { .. }
            | Self::TooLarge { .. }
            | Self::AddModel { .. }
            | Self::GpuSelection { .. }
            | Self::DeviceRefused { .. } => ErrorClass::Unsupported,
            Self::CameraPath { io: true, .. }
            | Self::ContainerIsDirectory { .. }
            | Self::OutputIsDirectory { .. }
            | Self::Encode { .. }
            | Self::Render { .. }
            | Self::Internal { .. } => ErrorClass::Io,
        }
    }

    /// The file the error is about, or the input of the run; `None` for [`Error::AddModel`],
    /// which names a model by its label.
    #[must_use]
    pub fn path(&self) -> Option<&Path> {
        match self {
            Self::Scene(_) | Self::AddModel { .. } => None,
            Self::Container { path, .. }
            | Self::ContainerIsDirectory { path }
            | Self::Build { path, .. }
            | Self::CameraPath { path, .. }
            | Self::OutputIsDirectory { path }
            | Self::Write { path, .. }
            | Self::Encode { path, .. } => Some(path),
            Self::NoneMeasurable { input, .. }
            | Self::NoDevice { input, .. }
            | Self::TooLarge { input, .. }
            | Self::Render { input, .. }
            | Self::GpuSelection { input, .. }
            | Self::DeviceRefused { input, .. }
            | Self::Options { input, .. }
            | Self::Internal { input, .. } => Some(input),
        }
    }
}

/// A build error's class: I/O errors are [`ErrorClass::Io`], unsupported glTF features and
/// inputs over a resource limit [`ErrorClass::Unsupported`], the rest [`ErrorClass::Invalid`].
fn build_class(error: &treelod_build::BuildError) -> ErrorClass {
    use treelod_build::BuildError;
    match error {
        BuildError::Io { .. } => ErrorClass::Io,
        BuildError::Unsupported { .. } | BuildError::Limit { .. } => ErrorClass::Unsupported,
        BuildError::Format(e) => e.class(),
        _ => ErrorClass::Invalid,
    }
}
