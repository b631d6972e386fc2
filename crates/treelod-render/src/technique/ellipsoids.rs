//! Clasen's leaf ellipsoids and branch lines (Clasen and Prohaska 2011, spec §6.8, §6.9;
//! [`Technique::Ellipsoids`]): their records as uploaded. The selection is
//! `treelod_runtime::ellipsoid::select`. WGSL: `shaders/tree/ellipsoids.wgsl`,
//! `shaders/tree/lines.wgsl`.

use treelod_format::{Container, EllipsoidRecord, LineRecord};
#[cfg(doc)]
use treelod_runtime::Technique;

use crate::upload::with_ao_in_flags;

/// The ellipsoids of `container` as uploaded: each one's `flags` (reserved in the file, spec
/// §6.8) holds its ambient occlusion byte (§6.14), 0 without `ELLIPSOID_AO`: never the file's own
/// flags.
pub(crate) fn gpu_ellipsoids(container: &Container) -> Vec<EllipsoidRecord> {
    with_ao_in_flags(container.ellipsoids(), container.ellipsoid_ao(), |e, flags| EllipsoidRecord { flags, ..e })
}

/// The branch lines of `container` as uploaded, likewise: each one's `flags` holds its `LINE_AO`
/// byte, never the file's flags.
pub(crate) fn gpu_lines(container: &Container) -> Vec<LineRecord> {
    with_ao_in_flags(container.lines(), container.line_ao(), |l, flags| LineRecord { flags, ..l })
}
