//! The crate's error type.

/// Why a metric cannot be computed from its inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum MetricError {
    /// Two images or masks compared differ in size, or pixel data does not match its stated size.
    #[error("image sizes differ: {}x{} and {}x{}", .expected.0, .expected.1, .got.0, .got.1)]
    SizeMismatch {
        /// The size expected, `(width, height)`.
        expected: (u32, u32),
        /// The size given (for a pixel buffer of the wrong length: its pixel count, 1).
        got: (u32, u32),
    },
    /// A reduction factor (supersampling) of 0, or one that does not divide the image's sides.
    #[error("a {width}x{height} image cannot be reduced by {factor} per side")]
    BadFactor {
        /// Pixels across.
        width: u32,
        /// Pixels down.
        height: u32,
        /// The factor asked for.
        factor: u32,
    },
    /// The metric needs at least one pixel.
    #[error("the image has no pixels ({width}x{height})")]
    Empty {
        /// Pixels across.
        width: u32,
        /// Pixels down.
        height: u32,
    },
}
