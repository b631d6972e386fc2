//! `treelod build` and `treelod demo`: trees in, verified containers out, with a summary.

use std::collections::{BTreeMap, BTreeSet};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glam::Vec3;
use treelod_build::scene::Scene;
use treelod_build::{
    BuildConfig, BuildOutput, BuildStats, ImportLimits, Placed, PruneConfig, PruneOrder, PruneReport, StageTime,
    build_scenes,
};
use treelod_format::{Compression, CurveSample, ErrorClass, Setting};

use crate::report::{self, Failed};
use crate::table::{Align, Table};

/// Options shared by `build` and `demo`.
#[derive(clap::Args, Debug, Clone)]
pub struct BuildOptions {
    /// Grid cells along x,y,z (e.g. `4,4,4`); default: 4 along the shortest axis, proportionally
    /// more along the others, each axis 4..=16.
    #[arg(long, value_parser = parse_grid)]
    pub grid: Option<[u32; 3]>,
    /// Glob (case-insensitive, `*` and `?`) of material, mesh or node names that are leaves;
    /// repeatable.
    #[arg(long = "leaves", value_name = "PATTERN")]
    pub leaves: Vec<String>,
    /// Glob of material, mesh or node names that are bark; repeatable.
    #[arg(long = "bark", value_name = "PATTERN")]
    pub bark: Vec<String>,
    /// Largest point cluster left unsplit by the PCA clustering (Gilet: about 5).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(2..=64))]
    pub cluster_max: u32,
    /// Section compression: `zstd` (smaller files, decoded on open) or `none` (used in place
    /// from a memory map).
    #[arg(long, default_value = "zstd", value_parser = ["zstd", "none"])]
    pub compression: String,
    /// zstd level, 1..=22, of sections over 256 KiB (smaller ones are compressed at 19 or above,
    /// which costs milliseconds).
    #[arg(long, default_value_t = treelod_format::DEFAULT_LEVEL, value_parser = clap::value_parser!(i32).range(1..=22))]
    pub level: i32,
    /// Pruning (Neubert et al. 2011): write each cell's leaves as a priority list in this order,
    /// with the optimal scale s_opt(λ) and the fraction λ(h) per projected height (spec §6.11).
    /// `none` writes no lists. Measuring the curves renders coverage images on the CPU: it adds
    /// about as much time as the rest of the build on large trees.
    #[arg(long, default_value = "none", value_parser = ["none", "stochastic", "density", "orientation", "combined"])]
    pub prune: String,
    /// With --prune: the minimum quality Q = 1 - |(1 - P, 1 - R)| that λ(h) keeps, in [0, 1]. At
    /// each distance λ(h) reaches the quality of Cook's stochastic pruning there (Neubert et al.'s
    /// rule) and never less than Q; 0 follows Cook's quality everywhere.
    #[arg(long, default_value_t = 0.9, value_name = "Q", value_parser = parse_quality)]
    pub prune_quality: f32,
    /// With --prune: side in pixels of the coverage images s_opt is measured on (the tree's
    /// bounding sphere spans the image).
    #[arg(long, default_value_t = 256, value_name = "PIXELS", value_parser = clap::value_parser!(u32).range(16..=4096))]
    pub prune_resolution: u32,
    /// With --prune: view directions measured (2/3 around the tree, 1/3 from 45° above).
    #[arg(long, default_value_t = 8, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=64))]
    pub prune_views: u32,
    /// Leaf-cluster impostors (Garcia 2005): cluster each tree's leaves onto nested levels of
    /// planes (--impostor-levels) in the block cell and bake them into one atlas image (spec
    /// §6.10). The atlas is typically several times larger than the rest of the container.
    #[arg(long)]
    pub impostors: bool,
    /// With --impostors: planes per tree at each level, finest first, strictly decreasing.
    #[arg(long, value_name = "N,N,…", default_value = "32,16,8", value_parser = parse_levels, requires = "impostors")]
    pub impostor_levels: Levels,
    /// With --impostors: α of the clustering error as a fraction of the crown radius R,
    /// α = (SCALE·R)²: how far off a plane costs as much as a leaf at right angles to it.
    #[arg(long, value_name = "SCALE", default_value_t = 0.1, requires = "impostors")]
    pub impostor_alpha: f32,
    /// With --impostors: atlas texels per metre of plane (lowered if the atlas would exceed
    /// 4096 texels per side).
    #[arg(long, value_name = "N", default_value_t = 24.0, requires = "impostors")]
    pub impostor_texels: f32,
    /// With --impostors: how planes are textured. `direct`: an RGBA atlas of the leaves on each
    /// plane. `indirect` (Garcia's indirect texturing, spec §6.10.1): a low-resolution image of
    /// which leaf lies where, drawn from the leaves' own textures; for alpha-tested leaf cards
    /// only (other leaves fall back to `direct`, with a warning).
    #[arg(long, value_enum, value_name = "HOW", default_value_t = ImpostorTexturing::Direct, requires = "impostors")]
    pub impostor_texturing: ImpostorTexturing,
    /// With --impostor-texturing indirect: leaf-slot texels across a median leaf (its area's
    /// square root), in (0, 64].
    #[arg(long, value_name = "N", default_value_t = 2.0, value_parser = parse_slots_per_leaf, requires = "impostors")]
    pub impostor_slots_per_leaf: f32,
    /// How the atlases of impostor planes and billboards are stored (spec §6.7): `bc7` (BC7
    /// blocks, a quarter of the bytes, decoded by the GPU) or `rgba8` (the texels as baked).
    /// Recorded as the setting `atlas.format`.
    #[arg(long, value_enum, value_name = "FORMAT", default_value_t = AtlasFormatArg::Bc7)]
    pub atlas_format: AtlasFormatArg,
    /// Leaf ellipsoids (Clasen et al. 2011, spec §6.8): per grid cell one ellipsoid per leaf (PCA
    /// of its surface) and nested levels of EM clusters of them, each level's size calibrated
    /// against the leaves' coverage and drawn while its mean ellipsoid is about
    /// --ellipsoid-pixels across.
    #[arg(long)]
    pub ellipsoids: bool,
    /// With --ellipsoids: mean ellipsoid diameter on screen, pixels, at which the next coarser
    /// level takes over (Clasen: 5), in (0, 1000].
    #[arg(long, value_name = "PIXELS", default_value_t = 5.0, value_parser = parse_ellipsoid_pixels, requires = "ellipsoids")]
    pub ellipsoid_pixels: f32,
    /// With --ellipsoids: clusterings tried per level, the one of least image error kept
    /// (Clasen: 4).
    #[arg(long, value_name = "N", default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64), requires = "ellipsoids")]
    pub ellipsoid_tries: u32,
    /// With --ellipsoids: how levels are clustered: `em` (Clasen's Gaussian mixture) or
    /// `kmeans` (hard, spherical clusters; the baseline of the paper's comparison).
    #[arg(long, value_enum, value_name = "HOW", default_value_t = EllipsoidClustering::Em, requires = "ellipsoids")]
    pub ellipsoid_clustering: EllipsoidClustering,
    /// With --ellipsoids: seed of the clusterings' random starts.
    #[arg(long, value_name = "N", default_value_t = 1, requires = "ellipsoids")]
    pub ellipsoid_seed: u64,
    /// Branch lines (Clasen et al. 2011, spec §6.9): a skeleton of line segments from the bark
    /// mesh, simplified per grid cell by straighten and combine merges of least image error, each
    /// level drawn while its mean line is about --line-pixels wide. With --ellipsoids this is
    /// Clasen's whole representation (`render --ellipsoids` draws the bark as these lines).
    #[arg(long)]
    pub lines: bool,
    /// With --lines: mean line width on screen, pixels, at which the next coarser level takes
    /// over (Clasen: 1), in (0, 1000].
    #[arg(long, value_name = "PIXELS", default_value_t = 1.0, value_parser = parse_ellipsoid_pixels, requires = "lines")]
    pub line_pixels: f32,
    /// With --lines: random merge candidates whose image error is compared at each step
    /// (more: better merges, slower), in 1..=256.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=256), requires = "lines")]
    pub line_candidates: u32,
    /// With --lines: seed of the merge candidates' sampling.
    #[arg(long, value_name = "N", default_value_t = 1, requires = "lines")]
    pub line_seed: u64,
    /// Baselines to compare treelod with (spec §6.12, §6.13; `treelod eval --technique
    /// lod-chain,billboard,crossed`): each tree's discrete LoD chain from meshoptimizer's
    /// simplifiers (the regular one for bark, with the sloppy one as fallback for foliage, as
    /// gltfpack does), a camera-facing and a crossed (3 quads) billboard, each baked at the
    /// texel budget of the tree's impostor planes, and an octahedral impostor (views over the
    /// upper hemisphere, --octahedral-views and --octahedral-texels). Implies --impostors, which
    /// set that budget.
    #[arg(long)]
    pub baselines: bool,
    /// With --baselines: the chain's levels as shares of each tree's source triangles, finest
    /// first, strictly decreasing.
    #[arg(long, value_name = "F,F,…", default_value = "0.5,0.25,0.1,0.05,0.01", value_parser = parse_fractions, requires = "baselines")]
    pub lod_fractions: Fractions,
    /// With --baselines: leave out the chain's bark-first levels (each tree's leaves as the
    /// source has them with the bark of a level, placed among the levels by their share of the
    /// triangles), so that every level simplifies leaves and bark alike, as gltfpack does.
    #[arg(long, requires = "baselines")]
    pub no_bark_first: bool,
    /// With --baselines: views per side of each tree's octahedral impostor (spec §6.13.1), so
    /// N × N views over the upper hemisphere. Denser views differ less from the one seen; the
    /// atlas grows with N².
    #[arg(long, value_name = "N", default_value_t = treelod_build::billboard::OCTAHEDRAL_FRAMES, value_parser = parse_octahedral_views, requires = "baselines")]
    pub octahedral_views: u32,
    /// With --baselines: texels per side of each octahedral view's cell, a gutter of 4 on each
    /// side included: a multiple of 32 from 32 to 256. The default keeps a texel per pixel for a
    /// tree up to about 88 pixels high; the atlas grows with the square.
    #[arg(long, value_name = "T", default_value_t = treelod_build::billboard::OCTAHEDRAL_CELL, value_parser = parse_octahedral_texels, requires = "baselines")]
    pub octahedral_texels: u32,
    /// Ambient-occlusion rays per vertex (Clasen et al. 2011 §5, spec §6.14): each vertex's
    /// share of the sky that the tree hides, traced through the whole block; points and impostor
    /// planes get the mean of their leaves'. 0 writes no ambient occlusion.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = clap::value_parser!(u32).range(0..=4096))]
    pub ao_rays: u32,
    /// How the ambient-occlusion rays are traced: `parallel` (2N directions shared by every
    /// vertex, each traced from all vertices at once; a vertex traces about N, those on its
    /// side) or `traced` (N rays of its own per vertex through a BVH: slower, more memory, the
    /// reference of measurements).
    #[arg(long, value_enum, value_name = "METHOD", default_value_t = AoMethodArg::Parallel)]
    pub ao_method: AoMethodArg,
    /// Calibration views per elevation (spec §6.15, §6.16): every representation built is drawn
    /// at 7 projected heights (4 to 256 pixels) on the CPU, from N orthographic views around the
    /// tree at each of 0°, 30° and 60° elevation (N·64/h at a height h under 64 pixels, at most
    /// 8N) and straight down (one, 64/h under 64 pixels, each turned about the vertical), and its
    /// image error
    /// against the supersampled full mesh and its primitive count are stored, over every view and
    /// per elevation, for the renderer's policy to choose representations with. Default: 2 when
    /// the build holds a representation to choose besides the point tree (--prune, --impostors,
    /// --ellipsoids or --baselines), else 0. 0 writes none.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=64))]
    pub calibration_views: Option<u32>,
    /// Keep every bit of the written floats. By default positions and texture coordinates keep
    /// 16 significant bits, sizes 12 and normals 10 per component (0.15 mm on a 10 m tree), which
    /// zstd compresses about a third smaller.
    #[arg(long)]
    pub full_precision: bool,
    /// Refuse a glTF input that makes the import read or decode more than SIZE bytes in all (the
    /// file, its buffers, decoded images at 4 bytes per pixel, accessors read, counted per
    /// instance). Bytes, or with a binary suffix K, M or G (e.g. 512M). Not recorded: it changes
    /// no output that builds.
    #[arg(long, value_name = "SIZE", default_value_t = ByteSize(ImportLimits::default().max_decoded_bytes), value_parser = parse_size)]
    pub max_decoded_bytes: ByteSize,
    /// Refuse a glTF input with an image of more than N pixels (width × height, read from its
    /// header before decoding).
    #[arg(long, value_name = "N", default_value_t = ImportLimits::default().max_image_pixels, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_image_pixels: u64,
    /// Refuse a glTF input whose node hierarchy expands to more than N node instances (a node
    /// reached by several paths from the scene's roots counts once per path).
    #[arg(long, value_name = "N", default_value_t = ImportLimits::default().max_instances, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_instances: u64,
    /// Refuse a glTF input of more than N triangles, all instances together.
    #[arg(long, value_name = "N", default_value_t = ImportLimits::default().max_triangles, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_triangles: u64,
    /// Follow buffer and image URIs that lead outside the glTF file's directory (absolute
    /// paths, `..`, symbolic links pointing out). By default they are refused (exit 4), so a
    /// model can only read the files beside it.
    #[arg(long)]
    pub allow_external_uris: bool,
    /// Skip the full verification of each written file. By default the file is verified before
    /// it is renamed over the output, and one that fails is removed (the old output is kept).
    #[arg(long)]
    pub no_verify: bool,
    /// Print one JSON object per container instead of the text summary.
    #[arg(long)]
    pub json: bool,
    /// Told how far the build's long stages are (not an option: `build` and `demo` set it to
    /// draw a bar when stderr is a terminal).
    #[arg(skip)]
    pub progress: treelod_build::Progress,
}

impl BuildOptions {
    /// The options `treelod build` takes without any flag (what the viewer builds a dropped file
    /// with).
    pub(crate) fn defaults() -> Self {
        #[derive(clap::Parser)]
        struct Defaults {
            #[command(flatten)]
            options: BuildOptions,
        }
        // No arguments: every option at its default (no option is required; a unit test checks).
        <Defaults as clap::Parser>::try_parse_from(["treelod"]).expect("every build option has a default").options
    }

    /// The calibration's views per elevation: `--calibration-views`, else 2 where the build holds more than the
    /// point tree to choose from and 0 where it does not (the policy would always draw the point
    /// tree, and the tables would only cost time and bytes).
    pub(crate) fn calibration_views(&self) -> u32 {
        let choice = self.impostors || self.ellipsoids || self.baselines || PruneOrder::parse(&self.prune).is_some();
        self.calibration_views.unwrap_or(if choice {
            treelod_build::CalibrationConfig::default().views as u32
        } else {
            0
        })
    }

    /// The build crate's configuration of these options.
    pub(crate) fn config(&self) -> BuildConfig {
        BuildConfig {
            grid: self.grid,
            gilet: treelod_build::gilet::GiletConfig { cluster_max: self.cluster_max as usize },
            classify: treelod_build::classify::ClassifyOptions { leaves: self.leaves.clone(), bark: self.bark.clone() },
            prune: PruneOrder::parse(&self.prune).map(|order| self.prune_config(order)),
            baselines: self.baselines.then(|| treelod_build::LodChainConfig {
                fractions: self.lod_fractions.0.clone(),
                bark_first: !self.no_bark_first,
                octahedral: treelod_build::OctahedralConfig {
                    views: self.octahedral_views,
                    texels: self.octahedral_texels,
                },
            }),
            impostors: (self.impostors || self.baselines).then(|| treelod_build::ImpostorConfig {
                levels: self.impostor_levels.0.clone(),
                alpha_scale: self.impostor_alpha,
                texels_per_metre: self.impostor_texels,
                texturing: match self.impostor_texturing {
                    ImpostorTexturing::Direct => treelod_build::Texturing::Direct,
                    ImpostorTexturing::Indirect => treelod_build::Texturing::Indirect,
                },
                slots_per_leaf: self.impostor_slots_per_leaf,
                ..treelod_build::ImpostorConfig::default()
            }),
            ellipsoids: self.ellipsoids.then(|| treelod_build::EllipsoidConfig {
                pixels: self.ellipsoid_pixels,
                tries: self.ellipsoid_tries,
                seed: self.ellipsoid_seed,
                clustering: match self.ellipsoid_clustering {
                    EllipsoidClustering::Em => treelod_build::Clustering::Em,
                    EllipsoidClustering::Kmeans => treelod_build::Clustering::KMeans,
                },
                ..treelod_build::EllipsoidConfig::default()
            }),
            lines: self.lines.then(|| treelod_build::LineConfig {
                pixels: self.line_pixels,
                candidates: self.line_candidates,
                seed: self.line_seed,
                ..treelod_build::LineConfig::default()
            }),
            ao: (self.ao_rays > 0).then(|| treelod_build::AoConfig {
                rays: self.ao_rays,
                method: match self.ao_method {
                    AoMethodArg::Parallel => treelod_build::AoMethod::Parallel,
                    AoMethodArg::Traced => treelod_build::AoMethod::Traced,
                },
                ..treelod_build::AoConfig::default()
            }),
            calibration: (self.calibration_views() > 0).then(|| treelod_build::CalibrationConfig {
                views: self.calibration_views() as usize,
                ..treelod_build::CalibrationConfig::default()
            }),
            atlas_format: match self.atlas_format {
                AtlasFormatArg::Bc7 => treelod_build::AtlasFormat::Bc7,
                AtlasFormatArg::Rgba8 => treelod_build::AtlasFormat::Rgba8,
            },
            precision: if self.full_precision {
                treelod_build::precision::Precision::FULL
            } else {
                treelod_build::precision::Precision::default()
            },
            progress: self.progress.clone(),
        }
    }

    /// The pruning settings of these options with `order`.
    pub(crate) fn prune_config(&self, order: PruneOrder) -> PruneConfig {
        PruneConfig {
            order,
            min_quality: self.prune_quality,
            resolution: self.prune_resolution,
            views: self.prune_views,
            ..PruneConfig::default()
        }
    }

    /// The resource limits of a glTF import (`--max-*`, `--allow-external-uris`). Not recorded
    /// in the metadata: an input within them builds the same container whatever they are.
    pub(crate) fn import_limits(&self) -> ImportLimits {
        ImportLimits {
            max_decoded_bytes: self.max_decoded_bytes.0,
            max_image_pixels: self.max_image_pixels,
            max_instances: self.max_instances,
            max_triangles: self.max_triangles,
            allow_external_uris: self.allow_external_uris,
        }
    }

    /// How sections are stored.
    pub(crate) fn compression(&self) -> Compression {
        if self.compression == "none" { Compression::None } else { Compression::Zstd { level: self.level } }
    }

    /// The `compression` setting recorded in the metadata: `zstd:LEVEL` or `none`.
    fn compression_setting(&self) -> Setting {
        let value = match self.compression() {
            Compression::None => "none".to_owned(),
            Compression::Zstd { level } => format!("zstd:{level}"),
        };
        Setting { key: "compression".into(), value }
    }

    /// Every setting a container built with these options records (spec §7.1), sorted by key: the
    /// build crate's ([`treelod_build::recorded_settings`]) and `compression`. `grid` is the grid
    /// the block was built with.
    pub(crate) fn recorded_settings(&self, grid: [u32; 3]) -> Vec<Setting> {
        let mut settings = treelod_build::recorded_settings(&self.config(), grid);
        settings.push(self.compression_setting());
        settings.sort();
        settings
    }
}

/// The `generator` recorded in the metadata of every container this tool writes.
pub(crate) fn generator() -> String {
    format!("treelod {}", env!("CARGO_PKG_VERSION"))
}

/// A size in bytes (`--max-decoded-bytes`), shown with the largest binary suffix that divides it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ByteSize(pub u64);

impl std::fmt::Display for ByteSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let suffix = [("G", 30), ("M", 20), ("K", 10)]
            .into_iter()
            .find(|&(_, shift)| self.0 != 0 && self.0.trailing_zeros() >= shift);
        match suffix {
            Some((suffix, shift)) => write!(f, "{}{suffix}", self.0 >> shift),
            None => write!(f, "{}", self.0),
        }
    }
}

/// Parses `--max-decoded-bytes`: a positive number of bytes, optionally followed by a binary
/// suffix `K`, `M` or `G` (any case; 2^10, 2^20, 2^30).
fn parse_size(s: &str) -> Result<ByteSize, String> {
    let text = s.trim();
    let (digits, shift) = match text.char_indices().last() {
        Some((i, 'k' | 'K')) => (&text[..i], 10),
        Some((i, 'm' | 'M')) => (&text[..i], 20),
        Some((i, 'g' | 'G')) => (&text[..i], 30),
        _ => (text, 0),
    };
    digits
        .parse::<u64>()
        .ok()
        .filter(|&n| n > 0 && n.leading_zeros() >= shift)
        .map(|n| ByteSize(n << shift))
        .ok_or_else(|| {
            format!("{s:?} is not a size: a positive number of bytes, optionally with K, M or G (e.g. 512M)")
        })
}

/// `--atlas-format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AtlasFormatArg {
    /// BC7 blocks (spec §6.7 formats 6, 7).
    Bc7,
    /// RGBA8 texels (formats 1, 2).
    Rgba8,
}

/// `--ao-method`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AoMethodArg {
    /// Directions shared by every vertex, traced as parallel rays (spec §6.14).
    Parallel,
    /// Rays of its own per vertex through a BVH.
    Traced,
}

/// `--impostor-texturing`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ImpostorTexturing {
    /// An RGBA atlas of the leaves on each plane.
    Direct,
    /// A leaf-slot image and the leaves' own textures (spec §6.10.1).
    Indirect,
}

/// `--ellipsoid-clustering`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum EllipsoidClustering {
    /// EM on a Gaussian mixture with full covariances (Clasen et al. 2011).
    Em,
    /// Lloyd's k-means: hard, spherical clusters.
    Kmeans,
}

/// `--ellipsoid-pixels`, `--line-pixels`: a number in (0, 1000], the range the build accepts.
fn parse_ellipsoid_pixels(s: &str) -> Result<f32, String> {
    s.trim()
        .parse::<f32>()
        .ok()
        .filter(|n| *n > 0.0 && *n <= 1000.0)
        .ok_or_else(|| format!("{s:?} is not a number in (0, 1000]"))
}

/// `--impostor-levels`: plane counts per tree, finest first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Levels(pub Vec<u32>);

/// Parses `--impostor-levels`: plane counts, strictly decreasing, each in 1..=4096.
fn parse_levels(s: &str) -> Result<Levels, String> {
    let levels = s
        .split(',')
        .map(|v| v.trim().parse::<u32>().ok().filter(|n| (1..=4096).contains(n)))
        .collect::<Option<Vec<u32>>>()
        .ok_or_else(|| format!("{s:?}: expected numbers in 1..=4096 separated by commas"))?;
    if levels.windows(2).any(|w| w[1] >= w[0]) {
        return Err(format!("{s:?}: levels must decrease strictly (finest first)"));
    }
    Ok(Levels(levels))
}

/// `--lod-fractions`: shares of the source triangles, finest first.
#[derive(Clone, Debug, PartialEq)]
pub struct Fractions(pub Vec<f32>);

/// Parses `--lod-fractions`: numbers in (0, 1), strictly decreasing, at most 16.
fn parse_fractions(s: &str) -> Result<Fractions, String> {
    let fractions = s
        .split(',')
        .map(|v| v.trim().parse::<f32>().ok().filter(|f| *f > 0.0 && *f < 1.0))
        .collect::<Option<Vec<f32>>>()
        .ok_or_else(|| format!("{s:?}: expected numbers between 0 and 1 (exclusive) separated by commas"))?;
    if fractions.windows(2).any(|w| w[1] >= w[0]) {
        return Err(format!("{s:?}: fractions must decrease strictly (finest first)"));
    }
    if fractions.len() > 16 {
        return Err(format!("{s:?}: at most 16 levels"));
    }
    Ok(Fractions(fractions))
}

/// `--octahedral-views`: in the range the build accepts ([`treelod_build::OctahedralConfig::validate`]).
fn parse_octahedral_views(s: &str) -> Result<u32, String> {
    let views = s.trim().parse::<u32>().map_err(|_| format!("{s:?} is not a whole number"))?;
    treelod_build::OctahedralConfig { views, ..Default::default() }.validate().map_err(|e| e.to_string())?;
    Ok(views)
}

/// `--octahedral-texels`: in the range the build accepts ([`treelod_build::OctahedralConfig::validate`]).
fn parse_octahedral_texels(s: &str) -> Result<u32, String> {
    let texels = s.trim().parse::<u32>().map_err(|_| format!("{s:?} is not a whole number"))?;
    treelod_build::OctahedralConfig { texels, ..Default::default() }.validate().map_err(|e| e.to_string())?;
    Ok(texels)
}

/// Parses a quality in [0, 1] (`--prune-quality`).
fn parse_quality(s: &str) -> Result<f32, String> {
    s.trim()
        .parse::<f32>()
        .ok()
        .filter(|q| (0.0..=1.0).contains(q))
        .ok_or_else(|| format!("{s:?} is not a number in [0, 1]"))
}

/// `--impostor-slots-per-leaf`: a number in (0, 64], the range the build accepts.
fn parse_slots_per_leaf(s: &str) -> Result<f32, String> {
    s.trim()
        .parse::<f32>()
        .ok()
        .filter(|n| *n > 0.0 && *n <= 64.0)
        .ok_or_else(|| format!("{s:?} is not a number in (0, 64]"))
}

/// Parses `X,Y,Z`, each in 1..=256 (the `--grid` option and the recorded `grid` setting).
pub(crate) fn parse_grid(s: &str) -> Result<[u32; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("expected X,Y,Z (three numbers), got {s:?}"));
    };
    let n = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (1..=256).contains(n))
            .ok_or_else(|| format!("{v:?} is not a number in 1..=256"))
    };
    Ok([n(x)?, n(y)?, n(z)?])
}

/// Arguments of `treelod build`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Source trees: glTF 2.0 files (`.glb` or `.gltf`).
    #[arg(value_name = "INPUT", required_unless_present = "placement")]
    pub inputs: Vec<PathBuf>,
    /// Output: a `.treelod` file for one input or `--block`, otherwise a directory that receives
    /// `<input stem>.treelod` per input (created if missing).
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Put all inputs into one block (Gilet's compact group of trees), side by side along x, so
    /// one grid spans the group.
    #[arg(long)]
    pub block: bool,
    /// With `--block`: a placement file instead of side by side. One tree per line, `PATH X Y Z`
    /// (metres; PATH relative to the placement file; `#` starts a comment). Trees listed here are
    /// added after any INPUTs.
    #[arg(long, value_name = "FILE", requires = "block")]
    pub placement: Option<PathBuf>,
    /// Before building each input, compare the pruning orders on it and print the table: for
    /// each order with s_opt, and for Cook's stochastic order with s = 1/λ, the quality Q along
    /// λ and the λ that reaches --prune-quality (the geometry saved at equal quality), measured
    /// on the images of --prune-resolution and --prune-views.
    #[arg(long)]
    pub prune_report: bool,
    /// With --prune-report: also plot, for each output, s_opt(λ) of every order against Cook's
    /// 1/λ and the quality each reaches, as DIR/STEM.prune.png (STEM the output's file stem).
    #[arg(long, value_name = "DIR", requires = "prune_report")]
    pub prune_plot: Option<PathBuf>,
    /// After each build, print to stderr how long each stage took (import, the build's stages,
    /// write, verify): seconds and share of the total. `--json` holds the same as `stages`.
    #[arg(long)]
    pub timings: bool,
    /// Build settings.
    #[command(flatten)]
    pub options: BuildOptions,
}

/// Arguments of `treelod demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Where to write the container.
    #[arg(short, long, value_name = "PATH", default_value = "demo.treelod")]
    pub output: PathBuf,
    /// Seed of the procedural tree.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of leaf quads.
    #[arg(long, default_value_t = treelod_build::DemoTreeConfig::default().leaves, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub leaf_count: u32,
    /// Build settings.
    #[command(flatten)]
    pub options: BuildOptions,
}

/// Runs `treelod build`.
pub fn run(args: &Args) -> Result<(), Failed> {
    if args.block {
        return run_block(args);
    }
    let to_directory =
        args.inputs.len() > 1 || args.output.is_dir() || args.output.as_os_str().to_string_lossy().ends_with('/');
    if to_directory {
        std::fs::create_dir_all(&args.output).map_err(|e| report::io_error(&args.output, &e))?;
    }
    let outputs: Vec<PathBuf> = args
        .inputs
        .iter()
        .map(|input| {
            if to_directory {
                args.output.join(format!("{}.treelod", treelod_build::scene_name(input)))
            } else {
                args.output.clone()
            }
        })
        .collect();
    report_leftovers(outputs.iter().map(PathBuf::as_path), args.options.json)?;
    // One input at a time: import, build, write, then drop it before the next, so a batch takes the
    // memory of its largest tree, and one bad file does not stop the others.
    let mut first_failure = None;
    let mut seen: Vec<PathBuf> = Vec::new();
    for (input, output) in args.inputs.iter().zip(outputs) {
        if seen.contains(&output) {
            report::message_error(
                input,
                &format!("another input also writes {}; rename one or use --block", output.display()),
            );
            first_failure.get_or_insert(Failed { class: ErrorClass::Invalid });
            continue;
        }
        seen.push(output.clone());
        let start = Instant::now();
        let result = import(input, &args.options).and_then(|scene| {
            let timing = Timing { import: Some(start.elapsed()), table: args.timings };
            let name = scene.name.clone();
            if args.prune_report {
                let plot = args.prune_plot.as_deref().map(|dir| prune_plot_path(dir, &output));
                print_prune_report(&name, &scene, input, &args.options, plot.as_deref())?;
            }
            build_one(&name, vec![(scene, Vec3::ZERO)], &[input.as_path()], &output, &args.options, timing)
        });
        if let Err(failed) = result {
            first_failure.get_or_insert(failed);
        }
    }
    first_failure.map_or(Ok(()), Err)
}

/// `--block`: every input (and every tree of the placement file) in one block.
fn run_block(args: &Args) -> Result<(), Failed> {
    report_leftovers([args.output.as_path()], args.options.json)?;
    let mut paths: Vec<PathBuf> = Vec::new();
    let mut x = 0.0f32;
    let mut scenes: Vec<(Scene, Vec3)> = Vec::new();
    let start = Instant::now();
    let progress = progress_bar(args.inputs.len() as u64);
    for input in &args.inputs {
        progress.set_message(format!("importing {}", input.display()));
        let scene = import(input, &args.options)?;
        // Side by side along x with a 10 % gap, each tree's own x extent apart.
        let (lo, hi) = scene_x_range(&scene);
        let offset = x - lo;
        x = offset + hi + 0.1 * (hi - lo).max(0.0);
        paths.push(input.clone());
        scenes.push((scene, Vec3::new(offset, 0.0, 0.0)));
        progress.inc(1);
    }
    if let Some(placement) = &args.placement {
        for (path, at) in read_placement(placement)? {
            progress.set_message(format!("importing {}", path.display()));
            scenes.push((import(&path, &args.options)?, at));
            paths.push(path);
        }
    }
    progress.finish_and_clear();
    let timing = Timing { import: Some(start.elapsed()), table: args.timings };
    let name = args.output.file_stem().map_or_else(|| "block".to_owned(), |s| s.to_string_lossy().into_owned());
    let sources: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
    if args.prune_report {
        let placed: Vec<Placed<'_>> =
            scenes.iter().map(|(scene, translation)| Placed { scene, translation: *translation }).collect();
        let config = args.options.config();
        let report = treelod_build::prune_report(&name, &placed, &config)
            .map_err(|e| report::build_error(sources.first().copied().unwrap_or(&args.output), &e))?;
        report::write_stdout(&prune_report_text(&name, &report, args.options.json))?;
        if let Some(dir) = &args.prune_plot {
            write_prune_plot(&prune_plot_path(dir, &args.output), &name, &report)?;
        }
    }
    build_one(&name, scenes, &sources, &args.output, &args.options, timing)
}

/// Compares the pruning orders on one tree and prints the table (`--prune-report`).
fn print_prune_report(
    name: &str,
    scene: &Scene,
    input: &Path,
    options: &BuildOptions,
    plot: Option<&Path>,
) -> Result<(), Failed> {
    let start = Instant::now();
    let placed = [Placed { scene, translation: Vec3::ZERO }];
    let report =
        treelod_build::prune_report(name, &placed, &options.config()).map_err(|e| report::build_error(input, &e))?;
    let mut text = prune_report_text(name, &report, options.json);
    if !options.json {
        text.push_str(&format!("  ({:.2} s)\n", start.elapsed().as_secs_f64()));
    }
    report::write_stdout(&text)?;
    match plot {
        Some(path) => write_prune_plot(path, name, &report),
        None => Ok(()),
    }
}

/// The `--prune-plot` file of the container written to `output`: `DIR/STEM.prune.png`.
fn prune_plot_path(dir: &Path, output: &Path) -> PathBuf {
    let stem = output.file_stem().map_or_else(|| "block".into(), |s| s.to_string_lossy().into_owned());
    dir.join(format!("{stem}.prune.png"))
}

/// Writes the `--prune-plot` PNG of one tree (or block) to `path`, in an existing directory.
fn write_prune_plot(path: &Path, name: &str, report: &PruneReport) -> Result<(), Failed> {
    if let Some(dir) = path.parent().filter(|d| !d.is_dir()) {
        report::message_error(dir, "is not a directory (--prune-plot names the directory the plots go into)");
        return Err(Failed { class: ErrorClass::Io });
    }
    crate::render::write_png(path, &crate::prune_plot::plot(name, report))
}

/// The `--prune-report` table as text, or as one JSON object.
pub(crate) fn prune_report_text(name: &str, report: &PruneReport, json: bool) -> String {
    let lambdas = treelod_build::prune::LAMBDAS;
    let saved = |lambda: f32| 1.0 - lambda / report.cook_lambda.max(f32::MIN_POSITIVE);
    if json {
        let orders: Vec<serde_json::Value> = report
            .orders
            .iter()
            .map(|o| {
                serde_json::json!({
                    "order": o.order.as_str(),
                    "s_opt": o.scale,
                    "quality": o.quality,
                    "lambda": o.lambda,
                    "saved": saved(o.lambda),
                })
            })
            .collect();
        let value = serde_json::json!({
            "name": name,
            "leaves": report.leaves,
            "resolution": report.resolution,
            "pixel_height": report.pixel_height,
            "min_quality": report.min_quality,
            "lambdas": lambdas,
            "cook": { "s": lambdas.iter().map(|l| 1.0 / l).collect::<Vec<f32>>(), "quality": report.cook_quality, "lambda": report.cook_lambda },
            "orders": orders,
        });
        return format!("{value}\n");
    }
    let mut out = format!(
        "{name}: pruning orders compared on {} leaves, {} px images (the tree {:.0} px high), Q >= {}\n",
        report.leaves, report.resolution, report.pixel_height, report.min_quality
    );
    let mut header = vec![("", Align::Left)];
    header.extend(lambdas.iter().map(|_| ("", Align::Right)));
    let mut t = Table::new(&header);
    let row = |label: &str, values: Vec<String>| {
        let mut cells = vec![label.to_owned()];
        cells.extend(values);
        cells
    };
    t.row(row("λ", lambdas.iter().map(|l| format!("{l}")).collect()));
    t.row(row("s_Cook = 1/λ", lambdas.iter().map(|l| format!("{:.2}", 1.0 / l)).collect()));
    t.row(row("Q stochastic + s_Cook", report.cook_quality.iter().map(|q| format!("{q:.3}")).collect()));
    for o in &report.orders {
        t.row(row(&format!("s_opt {}", o.order.as_str()), o.scale.iter().map(|s| format!("{s:.2}")).collect()));
        t.row(row(&format!("Q {} + s_opt", o.order.as_str()), o.quality.iter().map(|q| format!("{q:.3}")).collect()));
    }
    out.push_str(&t.render("  "));
    out.push_str(&format!("  λ for Q >= {} (leaf geometry saved against stochastic + s_Cook):\n", report.min_quality));
    out.push_str(&format!("    stochastic + s_Cook  {:.3}\n", report.cook_lambda));
    for o in &report.orders {
        out.push_str(&format!(
            "    {:<11} + s_opt   {:.3}  ({:+.1} %)\n",
            o.order.as_str(),
            o.lambda,
            100.0 * saved(o.lambda)
        ));
    }
    // The paper's comparison at a mid distance: Cook's own quality at λ = (1 − d)².
    for cook_lambda in [0.25f32] {
        let d = 1.0 - cook_lambda.sqrt();
        let target = report.cook_quality.get(lambdas.iter().position(|&l| l == cook_lambda).unwrap_or(0)).copied();
        let Some(target) = target else { continue };
        out.push_str(&format!(
            "  λ for Cook's quality at d = {d:.2} (λ = {cook_lambda}, Q = {target:.3}) (leaf geometry saved):\n"
        ));
        for o in &report.orders {
            let lambda = treelod_build::prune::lambda_reaching(&o.quality, target);
            out.push_str(&format!(
                "    {:<11} + s_opt   {:.3}  ({:+.1} %)\n",
                o.order.as_str(),
                lambda,
                100.0 * (1.0 - lambda / cook_lambda)
            ));
        }
    }
    out
}

/// Runs `treelod demo`: builds the built-in procedural tree (no input needed).
pub fn run_demo(args: &DemoArgs) -> Result<(), Failed> {
    let config = treelod_build::DemoTreeConfig {
        seed: args.seed,
        leaves: args.leaf_count,
        ..treelod_build::DemoTreeConfig::default()
    };
    report_leftovers([args.output.as_path()], args.options.json)?;
    let scene = treelod_build::demo_tree(&config);
    let name = scene.name.clone();
    build_one(&name, vec![(scene, Vec3::ZERO)], &[], &args.output, &args.options, Timing::default())?;
    if !args.options.json {
        report::write_stdout(&format!("next: treelod dump {}\n", args.output.display()))?;
    }
    Ok(())
}

/// Removes the temporary files a killed run left beside `outputs` ([`remove_leftovers`]) and, unless
/// `json`, says how many on stdout if there were any.
fn report_leftovers<'a>(outputs: impl IntoIterator<Item = &'a Path>, json: bool) -> Result<(), Failed> {
    match leftovers_line(remove_leftovers(outputs)) {
        Some(line) if !json => report::write_stdout(&line),
        _ => Ok(()),
    }
}

/// The line saying that `removed` leftover temporary files were removed; none for 0.
pub(crate) fn leftovers_line(removed: usize) -> Option<String> {
    (removed > 0).then(|| format!("removed {removed} temporary file(s) left beside outputs by an interrupted run\n"))
}

/// Removes the temporary files ([`treelod_format::temporary_target`]) that a killed run left beside
/// `outputs`, and only those: other processes writing other outputs into the same directories at
/// the same time (other shards of a batch) own the others. Returns how many were removed; failures
/// are ignored (such a file stays, harmless: it never has an output's name).
pub(crate) fn remove_leftovers<'a>(outputs: impl IntoIterator<Item = &'a Path>) -> usize {
    let mut by_dir: BTreeMap<&Path, BTreeSet<&OsStr>> = BTreeMap::new();
    for output in outputs {
        if let Some(name) = output.file_name() {
            let dir = output.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
            by_dir.entry(dir).or_default().insert(name);
        }
    }
    let mut removed = 0;
    for (dir, names) in by_dir {
        let Ok(entries) = std::fs::read_dir(dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let file_name = entry.file_name();
            let ours = file_name
                .to_str()
                .and_then(treelod_format::temporary_target)
                .is_some_and(|target| names.contains(OsStr::new(target)));
            if ours && entry.file_type().is_ok_and(|t| t.is_file()) && std::fs::remove_file(entry.path()).is_ok() {
                removed += 1;
            }
        }
    }
    removed
}

/// What [`build_one`] adds to a build's stages and prints of them.
#[derive(Clone, Copy, Debug, Default)]
struct Timing {
    /// How long the import of the scenes took (none for the demo tree, which is not imported).
    import: Option<Duration>,
    /// `--timings`: print the stages' table to stderr.
    table: bool,
}

/// Builds, writes atomically, reopens and verifies one container, then prints its summary (and
/// with `timing.table` the stages' times to stderr).
fn build_one(
    name: &str,
    scenes: Vec<(Scene, Vec3)>,
    sources: &[&Path],
    output: &Path,
    options: &BuildOptions,
    timing: Timing,
) -> Result<(), Failed> {
    // A bar for the long stages, only on a terminal: nothing else is printed differently.
    let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(stage_bar);
    let mut options = options.clone();
    if let Some(bar) = &bar {
        let shown = bar.clone();
        options.progress = treelod_build::Progress::new(move |stage, done, total| {
            shown.set_length(total);
            shown.set_position(done);
            shown.set_message(stage);
        });
        report::set_progress_bar(Some(bar.clone()));
    }
    let built = build_container(name, scenes, sources, output, &options);
    if let Some(bar) = bar {
        bar.finish_and_clear();
        report::set_progress_bar(None);
    }
    let mut built = built?;
    if let Some(import) = timing.import {
        built.stages.insert(0, StageTime { name: "import", time: import });
        built.seconds += import.as_secs_f64();
    }
    if timing.table {
        // After the bar is cleared; a failure to write to stderr is ignored, as warnings' are.
        let _ = std::io::Write::write_all(&mut std::io::stderr().lock(), timings_text(output, &built).as_bytes());
    }
    let summary = Summary { output, sources, built: &built };
    report::write_stdout(&if options.json { summary.to_json() } else { summary.to_text() })
}

/// What [`build_container`] built.
pub(crate) struct Built {
    /// Counts of the build.
    pub stats: BuildStats,
    /// Warnings of the import and the build (already printed to stderr).
    pub warnings: Vec<String>,
    /// Materials written.
    pub materials: usize,
    /// Images written.
    pub images: usize,
    /// Size of the written file.
    pub file_bytes: u64,
    /// Total size of the source files.
    pub source_bytes: u64,
    /// Wall-clock seconds from build to verification (with the import, once [`build_one`] adds
    /// it).
    pub seconds: f64,
    /// Wall-clock time of each stage, in order: the build's ([`BuildStats::stages`]), then `write`
    /// (encode, compress and write the sections, flushed to disk) and `verify` (open and fully
    /// check the written file, then rename it; not with `--no-verify`). They sum to at most
    /// `seconds`.
    pub stages: Vec<StageTime>,
    /// Whether the written file was fully verified (not with `--no-verify`).
    pub verified: bool,
    /// The pruning curves written: `s_opt(λ)` and `λ(h)` (empty without pruning).
    pub prune_curves: (Vec<CurveSample>, Vec<CurveSample>),
}

/// Builds one container, writes it atomically (temporary file, then rename), opening and fully
/// verifying the temporary file before the rename unless `--no-verify` (a file that fails is
/// removed and the old file at `output` kept), and returns what was built; prints warnings and errors (naming the
/// first source, or `output` without one) to stderr, nothing to stdout. The metadata records the
/// tool as generator and [`BuildOptions::recorded_settings`].
///
/// The scenes' geometry is freed once gathered and the rest of them once built, and each built
/// array once its section is compressed (or written), before verification reads the file back, so
/// the stages do not hold each other's memory.
pub(crate) fn build_container(
    name: &str,
    scenes: Vec<(Scene, Vec3)>,
    sources: &[&Path],
    output: &Path,
    options: &BuildOptions,
) -> Result<Built, Failed> {
    let start = Instant::now();
    let source_label = sources.first().copied().unwrap_or(output);
    // The scenes are consumed: their geometry is freed once gathered, the rest when built.
    let built =
        build_scenes(name, scenes, &options.config(), &generator()).map_err(|e| report::build_error(source_label, &e));
    let BuildOutput { mut data, stats, warnings } = built?;
    for warning in &warnings {
        report::print_warning(source_label, warning);
    }
    data.metadata.settings.push(options.compression_setting());
    data.metadata.settings.sort();
    let (materials, images) = (data.materials.len(), data.images.len());
    let prune_curves = (data.prune_scale.clone(), data.prune_lambda.clone());
    // Consumed: each array is freed once its section is compressed (or, stored raw, written).
    // Verified before the rename, so a file that fails verification never replaces what was at
    // `output`.
    let write_start = Instant::now();
    let mut verify_start = None;
    let written = if options.no_verify {
        data.into_path(output, options.compression())
    } else {
        // As `into_path_verified`, noting when the writing ends and the verification begins.
        data.into_path_checked(output, options.compression(), |written| {
            verify_start = Some(Instant::now());
            treelod_format::verify_written(written)
        })
    };
    let file_bytes = written.map_err(|e| report::file_error(output, &e))?;
    let end = Instant::now();
    let verified = !options.no_verify;
    let mut stages = stats.stages.clone();
    let verify_start = verify_start.unwrap_or(end);
    stages.push(StageTime { name: "write", time: verify_start - write_start });
    if verified {
        stages.push(StageTime { name: "verify", time: end - verify_start });
    }
    let seconds = (end - start).as_secs_f64();
    let source_bytes: u64 = sources.iter().filter_map(|p| std::fs::metadata(p).ok()).map(|m| m.len()).sum();
    Ok(Built { stats, warnings, materials, images, file_bytes, source_bytes, seconds, stages, verified, prune_curves })
}

/// The `--timings` table of a finished build: each stage's seconds and share of the total, then
/// the total (the stages' sum falls short of it by the bookkeeping between them).
fn timings_text(output: &Path, built: &Built) -> String {
    let mut table = Table::new(&[("stage", Align::Left), ("seconds", Align::Right), ("share", Align::Right)]);
    let total = built.seconds;
    let share = |seconds: f64| if total > 0.0 { format!("{:.1} %", 100.0 * seconds / total) } else { "–".to_owned() };
    for stage in &built.stages {
        let seconds = stage.time.as_secs_f64();
        table.row(vec![stage.name.to_owned(), format!("{seconds:.3}"), share(seconds)]);
    }
    table.row(vec!["total".to_owned(), format!("{total:.3}"), share(total)]);
    format!("timings of {}:\n{}", output.display(), table.render("  "))
}

/// What a finished build prints.
struct Summary<'a> {
    output: &'a Path,
    sources: &'a [&'a Path],
    built: &'a Built,
}

impl Summary<'_> {
    fn to_text(&self) -> String {
        let s = &self.built.stats;
        let from = if self.sources.is_empty() {
            "the built-in demo tree".to_owned()
        } else {
            self.sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        };
        let ratio = if self.built.source_bytes > 0 {
            format!(" ({:.2}x the source)", self.built.file_bytes as f64 / self.built.source_bytes as f64)
        } else {
            String::new()
        };
        format!(
            "{}: built from {from} in {:.2} s\n  triangles in  {} (leaf {}, bark {}; dropped {})\n  written       {} vertices, {} triangles, {} points, {} material(s), {} image(s)\n  grid          {}x{}x{}, {} of {} cells non-empty\n  file          {} bytes{ratio}\n  verify        {}\n",
            self.output.display(),
            self.built.seconds,
            s.triangles_in,
            s.leaf_triangles,
            s.bark_triangles,
            s.triangles_dropped,
            s.vertices,
            s.triangles,
            s.points,
            self.built.materials,
            self.built.images,
            s.grid[0],
            s.grid[1],
            s.grid[2],
            s.nonempty_cells,
            s.grid.iter().product::<u32>(),
            self.built.file_bytes,
            if self.built.verified { "ok" } else { "skipped" },
        ) + &self.prune_text()
            + &self.impostor_text()
            + &self.ellipsoid_text()
            + &self.line_text()
            + &self.baseline_text()
    }

    /// The baseline lines of the text summary (none without baselines).
    fn baseline_text(&self) -> String {
        let s = &self.built.stats;
        if s.lod_levels == 0 && s.billboards == 0 {
            return String::new();
        }
        format!(
            "  baselines     LoD chain {} levels, {} triangles; {} billboard quads, {} octahedral impostor(s), atlas \
             {}x{}\n",
            s.lod_levels, s.lod_triangles, s.billboards, s.octahedral, s.billboard_atlas[0], s.billboard_atlas[1]
        )
    }

    /// The ellipsoid line of the text summary (none without ellipsoids).
    fn ellipsoid_text(&self) -> String {
        let s = &self.built.stats;
        if s.ellipsoids == 0 {
            return String::new();
        }
        let levels: Vec<String> = s.ellipsoids_per_level.iter().map(u32::to_string).collect();
        format!(
            "  ellipsoids    {} (per level {}), built in {:.2} s\n",
            s.ellipsoids,
            levels.join(", "),
            s.stage_millis("ellipsoids") as f64 / 1000.0
        )
    }

    /// The branch-line line of the text summary (none without lines).
    fn line_text(&self) -> String {
        let s = &self.built.stats;
        if s.lines == 0 {
            return String::new();
        }
        let levels: Vec<String> = s.lines_per_level.iter().map(u32::to_string).collect();
        let far: Vec<String> = s.far_lines_per_level.iter().map(u32::to_string).collect();
        let far = if far.is_empty() { String::new() } else { format!("; far lines per level {}", far.join(", ")) };
        format!(
            "  lines         {} from {} skeleton segments (per level {}{far}), built in {:.2} s\n",
            s.lines,
            s.line_segments,
            levels.join(", "),
            s.stage_millis("lines") as f64 / 1000.0
        )
    }

    /// The impostor line of the text summary (none without impostors).
    fn impostor_text(&self) -> String {
        let s = &self.built.stats;
        if s.planes == 0 {
            return String::new();
        }
        let levels: Vec<String> = s.planes_per_level.iter().map(u32::to_string).collect();
        let image = if s.plane_leaves > 0 {
            format!("leaf slots {}x{}, {} plane leaves", s.atlas[0], s.atlas[1], s.plane_leaves)
        } else {
            format!("atlas {}x{}", s.atlas[0], s.atlas[1])
        };
        format!("  impostors     {} planes (per level {}), {image}\n", s.planes, levels.join(", "))
    }

    /// The pruning lines of the text summary (none without pruning).
    fn prune_text(&self) -> String {
        let s = &self.built.stats;
        if s.prune_leaves == 0 {
            return String::new();
        }
        let (scale, lambda) = &self.built.prune_curves;
        let curve = |c: &[CurveSample], x: &dyn Fn(f32) -> String| {
            c.iter().map(|p| format!("{}:{:.2}", x(p.x), p.y)).collect::<Vec<_>>().join(" ")
        };
        format!(
            "  prune         {} leaves, {} triangles\n  s_opt(λ)      {}\n  λ(h pixels)   {}\n",
            s.prune_leaves,
            s.prune_triangles,
            curve(scale, &|x| format!("{x}")),
            curve(lambda, &|x| format!("{x:.0}")),
        )
    }

    fn to_json(&self) -> String {
        let (b, s) = (self.built, &self.built.stats);
        let value = serde_json::json!({
            "output": self.output.display().to_string(),
            "sources": self.sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
            "seconds": b.seconds,
            "triangles_in": s.triangles_in,
            "triangles_dropped": s.triangles_dropped,
            "leaf_triangles": s.leaf_triangles,
            "bark_triangles": s.bark_triangles,
            "vertices": s.vertices,
            "triangles": s.triangles,
            "points": s.points,
            "materials": b.materials,
            "images": b.images,
            "grid": s.grid,
            "nonempty_cells": s.nonempty_cells,
            "file_bytes": b.file_bytes,
            "source_bytes": b.source_bytes,
            "verified": b.verified,
            "prune_leaves": s.prune_leaves,
            "prune_triangles": s.prune_triangles,
            "prune_scale": b.prune_curves.0.iter().map(|c| [c.x, c.y]).collect::<Vec<_>>(),
            "prune_lambda": b.prune_curves.1.iter().map(|c| [c.x, c.y]).collect::<Vec<_>>(),
            "planes": s.planes,
            "planes_per_level": s.planes_per_level,
            "ellipsoids": s.ellipsoids,
            "ellipsoids_per_level": s.ellipsoids_per_level,
            "ellipsoid_seconds": s.stage_millis("ellipsoids") as f64 / 1000.0,
            "lines": s.lines,
            "line_segments": s.line_segments,
            "lines_per_level": s.lines_per_level,
            "far_lines_per_level": s.far_lines_per_level,
            "line_seconds": s.stage_millis("lines") as f64 / 1000.0,
            "ao_seconds": s.stage_millis("ao") as f64 / 1000.0,
            "stages": b
                .stages
                .iter()
                .map(|stage| serde_json::json!({ "name": stage.name, "seconds": stage.time.as_secs_f64() }))
                .collect::<Vec<_>>(),
            "atlas": s.atlas,
            "lod_levels": s.lod_levels,
            "lod_triangles": s.lod_triangles,
            "billboards": s.billboards,
            "octahedral": s.octahedral,
            "billboard_atlas": s.billboard_atlas,
            "warnings": b.warnings,
        });
        format!("{value}\n")
    }
}

/// Imports the glTF at `path` within the options' limits.
/// Imports a glTF file within `options`' limits, printing a failure as `error: PATH: reason`.
pub(crate) fn import(path: &Path, options: &BuildOptions) -> Result<Scene, Failed> {
    treelod_build::import_gltf_with(path, &options.import_limits()).map_err(|e| report::build_error(path, &e))
}

fn scene_x_range(scene: &Scene) -> (f32, f32) {
    let xs = scene.parts.iter().flat_map(|p| &p.positions).map(|p| p[0]).filter(|x| x.is_finite());
    let (lo, hi) = xs.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
    if lo <= hi { (lo, hi) } else { (0.0, 0.0) }
}

/// Reads a placement file: `PATH X Y Z` per line, `#` comments, blank lines ignored.
fn read_placement(path: &Path) -> Result<Vec<(PathBuf, Vec3)>, Failed> {
    let text = std::fs::read_to_string(path).map_err(|e| report::io_error(path, &e))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split_whitespace().collect();
        let parsed = match fields.as_slice() {
            [p, x, y, z] => match (x.parse::<f32>(), y.parse::<f32>(), z.parse::<f32>()) {
                (Ok(x), Ok(y), Ok(z)) if x.is_finite() && y.is_finite() && z.is_finite() => {
                    Some((base.join(p), Vec3::new(x, y, z)))
                }
                _ => None,
            },
            _ => None,
        };
        match parsed {
            Some(entry) => out.push(entry),
            None => {
                report::message_error(
                    path,
                    &format!("line {}: expected `PATH X Y Z` with finite numbers, got {line:?}", n + 1),
                );
                return Err(Failed { class: ErrorClass::Invalid });
            }
        }
    }
    if out.is_empty() {
        report::message_error(path, "lists no trees");
        return Err(Failed { class: ErrorClass::Invalid });
    }
    Ok(out)
}

/// The bar of a build's long stages ([`treelod_build::Progress`]): drawn from its first report.
fn stage_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::with_draw_target(None, indicatif::ProgressDrawTarget::stderr());
    if let Ok(style) = indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {percent}% ({eta} left)") {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} [{pos}/{len}] {msg}") {
        bar.set_style(style);
    }
    bar
}

#[cfg(test)]
mod tests {
    use super::{BuildOptions, ByteSize, parse_size};

    #[test]
    fn the_default_options_parse_from_no_arguments() {
        let options = BuildOptions::defaults();
        assert!(!options.impostors && !options.ellipsoids && !options.baselines);
        assert!(options.ao_rays > 0, "ambient occlusion is on by default");
        assert_eq!(options.calibration_views(), 0, "nothing to choose from: no tables");
        let with = |flag: &str| {
            #[derive(clap::Parser)]
            struct Cli {
                #[command(flatten)]
                options: BuildOptions,
            }
            <Cli as clap::Parser>::try_parse_from(["treelod", flag]).expect("parses").options
        };
        assert_eq!(with("--baselines").calibration_views(), 2, "a choice: calibrated by default");
        assert_eq!(with("--ellipsoids").calibration_views(), 2);
        assert_eq!(with("--calibration-views=0").calibration_views(), 0);
        let mut options = with("--impostors");
        assert_eq!(options.calibration_views(), 2);
        options.calibration_views = Some(3);
        assert_eq!(options.calibration_views(), 3);
    }

    #[test]
    fn sizes_take_binary_suffixes_and_show_the_largest() {
        assert_eq!(parse_size("1024"), Ok(ByteSize(1024)));
        assert_eq!(parse_size("64K"), Ok(ByteSize(64 << 10)));
        assert_eq!(parse_size("512m"), Ok(ByteSize(512 << 20)));
        assert_eq!(parse_size(" 2G "), Ok(ByteSize(2 << 30)));
        assert_eq!(parse_size("17179869183G"), Ok(ByteSize(17_179_869_183 << 30)));
        for bad in ["0", "0K", "", "G", "-1", "1.5G", "2GB", "2 G", "12X", "17179869184G", "18446744073709551616"] {
            assert!(parse_size(bad).is_err(), "{bad:?}");
        }
        let shown: Vec<String> =
            [2 << 30, 512 << 20, 64 << 10, 1000, 1536, 3072, 3 << 29].map(|n| ByteSize(n).to_string()).to_vec();
        assert_eq!(shown, ["2G", "512M", "64K", "1000", "1536", "3K", "1536M"]);
        assert_eq!(ByteSize(treelod_build::ImportLimits::default().max_decoded_bytes).to_string(), "2G");
    }
}
