//! Test data for treelod: a generator of synthetic, valid `.treelod` containers, byte-level
//! patching helpers for hostile-input tests, the golden-file recipes and the spec's hex dump; a
//! generator of valid and hostile glTF files ([`gltf`]) and a counting allocator ([`alloc`]).
//!
//! [`synthetic`] is the test data source of every crate: given a seed and [`SyntheticOptions`] it
//! builds a [`ContainerData`](treelod_format::ContainerData) that follows `format-spec/treelod.md` in every rule `verify` checks
//! (grid, per-cell triangle sets with a Gilet point hierarchy flattened by
//! [`treelod_build::flatten`], optional ellipsoid, line and plane hierarchies, pruning lists and
//! curves, materials, images with mip chains, metadata, extension sections). The same seed and
//! options always give the same data.
//!
//! ```
//! use treelod_format::{Compression, Container, ContainerData};
//! use treelod_tests::{SyntheticOptions, synthetic};
//!
//! let data = synthetic(7, &SyntheticOptions::everything());
//! let bytes = data.to_bytes(Compression::None)?;
//! let container = Container::from_bytes(&bytes)?;
//! assert_eq!(ContainerData::from_container(&container), data);
//! # Ok::<(), treelod_format::Error>(())
//! ```

pub mod alloc;
pub mod gltf;
mod hexdump;
pub mod raw;
mod rng;
mod synth;

use std::path::PathBuf;

pub use hexdump::spec_hex_dump;
pub use rng::SplitMix64;
pub use synth::{NormalGrids, SyntheticOptions, synthetic};
use treelod_format::Compression;

/// One golden file of `tests/data/v1_<minor>`: how it was made.
///
/// Golden files are written once by `cargo run -p treelod-tests --bin make-golden` and then kept
/// forever (spec §11). Tests read the files, never these recipes, so a later change of the
/// generator or the writer cannot silently change what the golden tests expect.
#[derive(Clone, Debug)]
pub struct GoldenFile {
    /// The minor version of major 1 it was written for: its directory `tests/data/v1_<minor>`,
    /// and the minor in its header.
    pub minor: u16,
    /// File name inside the golden directory, e.g. `minimal.treelod`.
    pub name: &'static str,
    /// What the file exercises.
    pub description: &'static str,
    /// Seed of [`synthetic`].
    pub seed: u64,
    /// Options of [`synthetic`].
    pub options: SyntheticOptions,
    /// How the sections were stored.
    pub compression: Compression,
}

/// The golden files of format versions 1.0 to 1.18, in the order `make-golden` writes them.
#[must_use]
pub fn golden_files() -> Vec<GoldenFile> {
    vec![
        GoldenFile {
            minor: 0,
            name: "minimal.treelod",
            description: "one grid cell, one triangle, its leaf point and one material; uncompressed",
            seed: 1,
            options: SyntheticOptions::minimal(),
            compression: Compression::None,
        },
        GoldenFile {
            minor: 0,
            name: "gilet.treelod",
            description: "a 3x2x2 grid of Gilet cells (triangles and point hierarchies), a texture; uncompressed",
            seed: 2,
            options: SyntheticOptions::gilet([3, 2, 2]),
            compression: Compression::None,
        },
        GoldenFile {
            minor: 0,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.0, zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                lod_levels: 0,
                billboards: false,
                ao: false,
                indirect_planes: false,
                ellipsoid_ao: false,
                line_ao: false,
                calibration: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 0,
            name: "extension.treelod",
            description: "a one-cell file with a reserved kind 0x0100 and a private kind 0x10000 readers skip",
            seed: 4,
            options: SyntheticOptions {
                extension_kinds: vec![0x0100, 0x0001_0000],
                triangles_per_cell: 2..=2,
                ..SyntheticOptions::minimal()
            },
            compression: Compression::None,
        },
        GoldenFile {
            minor: 1,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.1 (1.0's and the baselines), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                ao: false,
                indirect_planes: false,
                ellipsoid_ao: false,
                line_ao: false,
                calibration: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 2,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.2 (1.1's and ambient occlusion), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                indirect_planes: false,
                ellipsoid_ao: false,
                line_ao: false,
                calibration: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 3,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.3 (1.2's, indirectly textured planes: PLANE_LEAVES and a LEAF_SLOTS \
                          image, and ELLIPSOID_AO), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                line_ao: false,
                calibration: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 4,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.4 (1.3's and LINE_AO), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                calibration: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 5,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.5 (1.4's and CALIBRATION), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                calibration_elevations: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 6,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.5 and a BC7 impostor atlas (format 7 BC7_LINEAR, 1.6), zstd level 19 \
                          with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                calibration_elevations: false,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 7,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.7 (1.6's: the 1.5 kinds and a BC7 impostor atlas, and \
                          CALIBRATION_ELEVATIONS), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                chain_calibration: false,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 8,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.8 (1.7's: the 1.5 kinds, a BC7 impostor atlas and \
                          CALIBRATION_ELEVATIONS, and CHAIN_CALIBRATION), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                far_lines: false,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 9,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.9 (1.8's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS and CHAIN_CALIBRATION, and the block's far lines, FAR_LINES and \
                          FAR_LINE_AO), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                plane_diffuse: false,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 10,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.10 (1.9's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES and FAR_LINE_AO, and the planes' \
                          diffuse response, PLANE_DIFFUSE), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                octahedral: false,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 11,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.11 (1.10's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO and PLANE_DIFFUSE, and an \
                          octahedral impostor per tree on the billboards' atlas, OCTAHEDRAL), zstd level 19 with byte \
                          shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                calibration_added: false,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 12,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.12 (1.11's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE and \
                          OCTAHEDRAL, and the calibration of the techniques added after 1.11, CALIBRATION_ADDED and \
                          CALIBRATION_ELEVATIONS_ADDED), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                octahedral_depth: false,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 13,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.13 (1.12's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE, \
                          OCTAHEDRAL, CALIBRATION_ADDED and CALIBRATION_ELEVATIONS_ADDED, and the octahedral views' \
                          depth planes, OCTAHEDRAL_DEPTH), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                point_facing: false,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 14,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.14 (1.13's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE, \
                          OCTAHEDRAL, CALIBRATION_ADDED, CALIBRATION_ELEVATIONS_ADDED and OCTAHEDRAL_DEPTH, and the \
                          points' facing, POINT_FACING), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                octahedral_normals: NormalGrids::None,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 15,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.15 (1.14's: the 1.5 kinds, a BC7 impostor atlas, \
                          CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE, \
                          OCTAHEDRAL, CALIBRATION_ADDED, CALIBRATION_ELEVATIONS_ADDED, OCTAHEDRAL_DEPTH and \
                          POINT_FACING, and where the octahedral views' normals lie, OCTAHEDRAL_NORMALS), zstd level \
                          19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                octahedral_normals: NormalGrids::ColourSize,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 16,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.16 but OCTAHEDRAL_NORMALS (1.15's: the 1.5 kinds, a BC7 impostor \
                          atlas, CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE, \
                          OCTAHEDRAL, CALIBRATION_ADDED, CALIBRATION_ELEVATIONS_ADDED, OCTAHEDRAL_DEPTH and \
                          POINT_FACING, and the octahedral views' normal grids at half the colour grids' size, \
                          OCTAHEDRAL_NORMAL_GRIDS, in place of OCTAHEDRAL_NORMALS), zstd level 19 with byte shuffle \
                          where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                calibration_flip: false,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 17,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.17 but OCTAHEDRAL_NORMALS (1.16's: the 1.5 kinds, a BC7 impostor \
                          atlas, CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE, \
                          OCTAHEDRAL, CALIBRATION_ADDED, CALIBRATION_ELEVATIONS_ADDED, OCTAHEDRAL_DEPTH, POINT_FACING \
                          and OCTAHEDRAL_NORMAL_GRIDS, and the calibration's FLIP error, CALIBRATION_FLIP: rows over \
                          every view and at 30 and 90 degrees, of full and octahedral at three heights each), zstd \
                          level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions {
                bc7_atlas: true,
                chain_calibration_flip: false,
                ..SyntheticOptions::everything()
            },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 18,
            name: "every-kind-zstd.treelod",
            description: "every section kind of 1.18 but OCTAHEDRAL_NORMALS (1.17's: the 1.5 kinds, a BC7 impostor \
                          atlas, CALIBRATION_ELEVATIONS, CHAIN_CALIBRATION, FAR_LINES, FAR_LINE_AO, PLANE_DIFFUSE, \
                          OCTAHEDRAL, CALIBRATION_ADDED, CALIBRATION_ELEVATIONS_ADDED, OCTAHEDRAL_DEPTH, POINT_FACING, \
                          OCTAHEDRAL_NORMAL_GRIDS and CALIBRATION_FLIP, and the chain levels' FLIP error, \
                          CHAIN_CALIBRATION_FLIP: a row at the level and height of each CHAIN_CALIBRATION record, \
                          three heights of each of the three levels), zstd level 19 with byte shuffle where it pays",
            seed: 3,
            options: SyntheticOptions { bc7_atlas: true, ..SyntheticOptions::everything() },
            compression: Compression::Zstd { level: 19 },
        },
        GoldenFile {
            minor: 13,
            name: "octahedral-depth.treelod",
            description: "one grid cell with one triangle and one impostor plane on an RGBA8 atlas, the tree's \
                          octahedral impostor of 2 x 2 views on that atlas (OCTAHEDRAL) and the views' 4 depth \
                          planes (OCTAHEDRAL_DEPTH); uncompressed",
            seed: 13,
            options: SyntheticOptions {
                planes_per_cell: 1..=1,
                octahedral: true,
                octahedral_frames: 2..=2,
                octahedral_depth: true,
                name: Some("octahedral-depth".into()),
                ..SyntheticOptions::minimal()
            },
            compression: Compression::None,
        },
    ]
}

/// The directory of the golden files of version 1.0: `tests/data/v1_0` in the source tree.
#[must_use]
pub fn golden_dir() -> PathBuf {
    golden_dir_of(0)
}

/// The directory of the golden files of version 1.`minor`: `tests/data/v1_<minor>`.
#[must_use]
pub fn golden_dir_of(minor: u16) -> PathBuf {
    golden_root().join(format!("v1_{minor}"))
}

/// The directory holding every version's golden directory: `tests/data` in the source tree.
#[must_use]
pub fn golden_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data")
}

/// The spec file, `format-spec/treelod.md` in the source tree.
#[must_use]
pub fn spec_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("format-spec").join("treelod.md")
}

/// Marker line before the generated hex dump in the spec (§13.1).
pub const SPEC_EXAMPLE_BEGIN: &str = "<!-- spec-example:begin -->";
/// Marker line after the generated hex dump in the spec (§13.1).
pub const SPEC_EXAMPLE_END: &str = "<!-- spec-example:end -->";
