//! Resource limits of a glTF import: what an untrusted file may make the build read, decode and
//! allocate before it is refused (`treelod build --max-*`, docs/cli.md "Limits").

use std::path::Path;

use crate::BuildError;

/// Limits on what one glTF import may read, decode and expand. Every default is far above what a
/// real tree needs (the 669k-triangle maple of the shared models decodes 72 MB) and far below what
/// would exhaust a build machine; a file over a limit is refused before the allocation, naming the
/// limit and the option that raises it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImportLimits {
    /// Bytes read and decoded in all: the file itself, external and data-URI buffers, every
    /// decoded image (4 bytes per pixel) and every accessor read, counted per instance. Default
    /// 2 GiB (`--max-decoded-bytes`).
    pub max_decoded_bytes: u64,
    /// Pixels of any one image, checked from its header before it is decoded. Default
    /// 8192 × 8192 (`--max-image-pixels`).
    pub max_image_pixels: u64,
    /// Node instances after expanding the node hierarchy (a node listed as the child of several
    /// nodes is instanced once per path from a root). Default 2^20 (`--max-instances`).
    pub max_instances: u64,
    /// Triangles of all instanced primitives together. Default 2^24 (`--max-triangles`).
    pub max_triangles: u64,
    /// Follow buffer and image URIs outside the model's directory (absolute paths, `..`, links
    /// pointing out). Default off (`--allow-external-uris`): a library's model can only read
    /// files beside it.
    pub allow_external_uris: bool,
}

impl Default for ImportLimits {
    fn default() -> Self {
        Self {
            max_decoded_bytes: 2 << 30,
            max_image_pixels: 8192 * 8192,
            max_instances: 1 << 20,
            max_triangles: 1 << 24,
            allow_external_uris: false,
        }
    }
}

/// Which limit of [`ImportLimits`] an input exceeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Limit {
    /// [`ImportLimits::max_decoded_bytes`].
    DecodedBytes,
    /// [`ImportLimits::max_image_pixels`].
    ImagePixels,
    /// [`ImportLimits::max_instances`].
    Instances,
    /// [`ImportLimits::max_triangles`].
    Triangles,
}

impl Limit {
    /// The command-line option that raises this limit.
    #[must_use]
    pub fn option(self) -> &'static str {
        match self {
            Self::DecodedBytes => "--max-decoded-bytes",
            Self::ImagePixels => "--max-image-pixels",
            Self::Instances => "--max-instances",
            Self::Triangles => "--max-triangles",
        }
    }

    /// What the limit counts, for messages.
    #[must_use]
    pub fn unit(self) -> &'static str {
        match self {
            Self::DecodedBytes => "decoded bytes",
            Self::ImagePixels => "pixels",
            Self::Instances => "node instances",
            Self::Triangles => "triangles",
        }
    }
}

impl std::fmt::Display for Limit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.unit())
    }
}

/// Reads a source file for an import: a regular file (not a FIFO, device or directory, which
/// could block or never end) of at most [`ImportLimits::max_decoded_bytes`], checked before
/// reading.
///
/// # Errors
/// [`BuildError::Io`] if it cannot be read or is not a regular file, [`BuildError::Limit`] if it
/// is larger than the limit.
pub fn read_source(path: &Path, limits: &ImportLimits) -> Result<Vec<u8>, BuildError> {
    super::read_regular_file(path, limits.max_decoded_bytes).map_err(|e| e.into_build_error(path, limits))
}

/// What an import has used of its [`ImportLimits`] so far; each `take_*` charges an amount
/// before the allocation or work it stands for, and refuses it once a limit would be passed.
pub(super) struct Budget<'a> {
    limits: &'a ImportLimits,
    path: &'a Path,
    decoded: u64,
    instances: u64,
    triangles: u64,
}

impl<'a> Budget<'a> {
    /// A fresh budget for the import of `path`.
    pub(super) fn new(limits: &'a ImportLimits, path: &'a Path) -> Self {
        Self { limits, path, decoded: 0, instances: 0, triangles: 0 }
    }

    /// The limits.
    pub(super) fn limits(&self) -> &ImportLimits {
        self.limits
    }

    fn charge(&self, used: u64, amount: u64, max: u64, limit: Limit, what: &str) -> Result<u64, BuildError> {
        let total = used.saturating_add(amount);
        if total > max {
            return Err(BuildError::Limit {
                path: self.path.to_owned(),
                what: what.to_owned(),
                limit,
                amount: total,
                max,
            });
        }
        Ok(total)
    }

    /// Bytes that may still be read or decoded.
    pub(super) fn bytes_left(&self) -> u64 {
        self.limits.max_decoded_bytes.saturating_sub(self.decoded)
    }

    /// Charges `bytes` read or decoded for `what`.
    pub(super) fn take_bytes(&mut self, what: &str, bytes: u64) -> Result<(), BuildError> {
        let max = self.limits.max_decoded_bytes;
        self.decoded = self.charge(self.decoded, bytes, max, Limit::DecodedBytes, what)?;
        Ok(())
    }

    /// Charges `instances` node instances for `what`.
    pub(super) fn take_instances(&mut self, what: &str, instances: u64) -> Result<(), BuildError> {
        let max = self.limits.max_instances;
        self.instances = self.charge(self.instances, instances, max, Limit::Instances, what)?;
        Ok(())
    }

    /// Charges `triangles` (of instanced primitives) for `what`.
    pub(super) fn take_triangles(&mut self, what: &str, triangles: u64) -> Result<(), BuildError> {
        let max = self.limits.max_triangles;
        self.triangles = self.charge(self.triangles, triangles, max, Limit::Triangles, what)?;
        Ok(())
    }

    /// Checks that one item, `what`, needs no more than `limit` allows on its own, charging
    /// nothing: an image's pixels, one primitive's triangles (named before the total is).
    pub(super) fn check(&self, limit: Limit, what: &str, amount: u64) -> Result<(), BuildError> {
        let max = match limit {
            Limit::DecodedBytes => self.limits.max_decoded_bytes,
            Limit::ImagePixels => self.limits.max_image_pixels,
            Limit::Instances => self.limits.max_instances,
            Limit::Triangles => self.limits.max_triangles,
        };
        self.charge(0, amount, max, limit, what).map(drop)
    }

    /// Checks an image's pixel count (from its header, before decoding) and charges its RGBA8
    /// texels.
    pub(super) fn take_image(&mut self, what: &str, width: u32, height: u32) -> Result<(), BuildError> {
        let pixels = u64::from(width) * u64::from(height);
        self.check(Limit::ImagePixels, what, pixels)?;
        self.take_bytes(what, pixels * 4)
    }
}
