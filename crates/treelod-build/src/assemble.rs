//! The build pipeline: placed scenes in, [`ContainerData`] out.
//!
//! Stages, in order: classify parts; gather and filter triangles; bounds and grid; assign
//! triangles to cells by centroid; with pruning, the leaves' priority list and curves
//! ([`crate::prune`]); per cell (in parallel, results kept in cell order) leaf points, point
//! hierarchy and size-sorted triangles; vertices renumbered in first-use order; the pruned leaves
//! per cell; with impostors, their planes and atlas; with baselines, each tree's LoD chain and
//! billboards; materials, images and metadata. Each stage's wall-clock time is recorded in
//! [`BuildStats::stages`].

use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;
use treelod_format::{
    BillboardRecord, BlockRecord, CellRecord, ContainerData, ImageRecord, LodLevelRecord, MATERIAL_DOUBLE_SIDED,
    MaterialInfo, MaterialRecord, Metadata, NO_IMAGE, OctahedralDepthRecord, OctahedralNormalGridRecord,
    OctahedralRecord, PointRecord, PruneLeafRecord, Range, Setting, Source, Tree, TriangleRecord, VertexRecord,
    encode_ao, encode_point_facing, image_format, material_class, pack,
};

use crate::ambient::{AoConfig, AoTriangle, mean_occlusion, triangle_occlusion, vertex_occlusion};
use crate::atlas_format::AtlasFormat;
use crate::billboard::{Billboards, OctahedralConfig, build_billboards};
use crate::calibrate::CalibrationConfig;
use crate::classify::{ClassifyOptions, classify};
use crate::ellipsoid::{CellEllipsoids, EllipsoidConfig, EllipsoidMesh, Ellipsoids, build_ellipsoids};
use crate::error::BuildError;
use crate::gilet::{CellPoint, GiletConfig, LeafPoint, build_cell};
use crate::impostor::{Atlas, ImpostorConfig, ImpostorMesh, Impostors, LeafTriangle, Surface, build_impostors};
use crate::lines::{CellLines, LineConfig, LineMesh, Lines, build_lines};
use crate::lod_chain::{ChainTriangle, LodChainConfig, build_lod_chain};
use crate::precision::Precision;
use crate::prune::{MeshTriangle, PruneConfig, PruneMesh, PruneReport, Pruned};
use crate::raster::{AlphaMask, NO_ALPHA};
use crate::scene::{AlphaMode, Class, ImageEncoding, Material, Scene};
use crate::spt::FlattenError;
use crate::texture::{TriangleSurface, integrate, linear_to_srgb};

/// Triangles with less area than this (m²) are degenerate and dropped.
const MIN_AREA: f32 = 1e-12;

/// Triangles with a corner farther than this from the block's origin along an axis, metres, are
/// dropped with the non-finite ones: nothing a tree needs lies 1,000 km out, and the stages'
/// squared distances and covariances of coordinates near `f32::MAX` overflow to infinities that
/// the container may not hold.
const MAX_COORDINATE: f32 = 1e6;

/// Everything that controls a build. Recorded in the container's settings (spec §7.1).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildConfig {
    /// Grid cells along x, y, z; `None` chooses from the block's aspect (see [`auto_grid`]).
    pub grid: Option<[u32; 3]>,
    /// Point hierarchy tunables.
    pub gilet: GiletConfig,
    /// Leaf / bark overrides.
    pub classify: ClassifyOptions,
    /// Pruning (Neubert et al. 2011, spec §6.11): the leaves' priority lists, `s_opt(λ)` and
    /// `λ(h)`. Default `None`: pruning is opt-in, it adds the measuring of many coverage images
    /// to the build (see [`crate::prune`]).
    pub prune: Option<PruneConfig>,
    /// Leaf-cluster impostors (Garcia et al. 2005, spec §6.10): nested levels of textured planes
    /// per tree in the block cell, and their atlas image. Default `None`: impostors are opt-in,
    /// their atlas is several times larger than the rest of a container (see
    /// [`crate::impostor`]).
    pub impostors: Option<ImpostorConfig>,
    /// Leaf ellipsoids (Clasen et al. 2011, spec §6.8): per grid cell, one ellipsoid per leaf and
    /// nested levels of EM clusters above them, calibrated against the leaves' coverage (see
    /// [`crate::ellipsoid`]). Default `None`: opt-in, the clustering and calibration take a few
    /// seconds per 100k leaf triangles.
    pub ellipsoids: Option<EllipsoidConfig>,
    /// Branch lines (Clasen et al. 2011, spec §6.9): a skeleton of line segments from the bark
    /// mesh, simplified per grid cell by straighten and combine merges chosen by image error (see
    /// [`crate::lines`]); drawn with the ellipsoids. Default `None`: opt-in.
    pub lines: Option<LineConfig>,
    /// Baselines (spec §6.12, §6.13) for comparisons: each tree's discrete LoD chain from
    /// meshoptimizer's simplifiers ([`crate::lod_chain`]), and, when [`Self::impostors`] is set
    /// too, facing and crossed billboards each baked at the texel budget of the tree's impostor
    /// planes ([`crate::billboard`]). Default `None`.
    pub baselines: Option<LodChainConfig>,
    /// Precomputed ambient occlusion (Clasen et al. 2011 §5, spec §6.14): per vertex by rays
    /// through the block, per point and plane the mean of their leaves' ([`crate::ambient`]).
    /// `None` writes none; tools turn it on by default.
    pub ao: Option<AoConfig>,
    /// Calibration (spec §6.15): every representation's image error and primitive count by
    /// projected height, measured on the CPU rasteriser ([`crate::calibrate`]), which a runtime's
    /// policy chooses with. `None` writes none; tools turn it on by default.
    pub calibration: Option<CalibrationConfig>,
    /// How the atlases of impostors and billboards are stored (spec §6.7): BC7 by default, or
    /// RGBA8 as baked ([`crate::atlas_format`]).
    pub atlas_format: AtlasFormat,
    /// Significant bits kept of the written floats ([`crate::precision`]): by default rounded so
    /// that zstd compresses the container about a third smaller; [`Precision::FULL`] keeps every
    /// bit.
    pub precision: Precision,
    /// Told how far the long stages are (ambient occlusion); default none. Not a setting: it
    /// never changes what is built.
    pub progress: Progress,
}

/// Receives the progress of a long build stage: `(stage, done, total)`, `done` rising to
/// `total` (for [`Progress::AMBIENT_OCCLUSION`], vertices). It is called from the build's worker
/// threads a few hundred times per stage, so it should be cheap; it never changes what is built.
#[derive(Clone, Default)]
pub struct Progress(Option<Arc<ProgressFn>>);

/// What a [`Progress`] calls: `(stage, done, total)`.
type ProgressFn = dyn Fn(&'static str, u64, u64) + Send + Sync;

impl Progress {
    /// The ambient-occlusion stage's name.
    pub const AMBIENT_OCCLUSION: &'static str = "ambient occlusion";

    /// A hook calling `report`.
    pub fn new(report: impl Fn(&'static str, u64, u64) + Send + Sync + 'static) -> Self {
        Self(Some(Arc::new(report)))
    }

    /// Reports `done` of `total` for `stage` (nothing without a hook).
    pub fn report(&self, stage: &'static str, done: u64, total: u64) {
        if let Some(report) = &self.0 {
            report(stage, done, total);
        }
    }
}

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() { "Progress(hook)" } else { "Progress(none)" })
    }
}

/// Any two are equal: a hook does not change what is built.
impl PartialEq for Progress {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// The build settings a build with `config` records in the container's metadata (spec §7.1), sorted
/// by key: `grid` (the grid used, `X,Y,Z`), `grid.auto`, `points.cluster_max`, when given
/// `classify.leaves` and `classify.bark`, and with pruning `prune.order`, `prune.min_quality`,
/// `prune.resolution`, `prune.views` and `prune.seed`, and with impostors `impostors.levels`,
/// `impostors.alpha_scale`, `impostors.texels_per_metre`, `impostors.max_texels`,
/// `impostors.iterations` and `impostors.seed`. `grid` is the grid chosen for the block,
/// which is `config.grid` when that is set.
///
/// A tool that wants to know whether a container was built with `config` compares its settings with
/// these, taking `grid` from the container when `config.grid` is `None` (the automatic grid depends
/// only on the sources, which it compares by content hash).
#[must_use]
pub fn recorded_settings(config: &BuildConfig, grid: [u32; 3]) -> Vec<Setting> {
    let mut settings = vec![
        Setting { key: "grid".into(), value: format!("{},{},{}", grid[0], grid[1], grid[2]) },
        Setting { key: "grid.auto".into(), value: config.grid.is_none().to_string() },
        Setting { key: "points.cluster_max".into(), value: config.gilet.cluster_max.max(2).to_string() },
    ];
    if !config.classify.leaves.is_empty() {
        settings.push(Setting { key: "classify.leaves".into(), value: config.classify.leaves.join(" ") });
    }
    if !config.classify.bark.is_empty() {
        settings.push(Setting { key: "classify.bark".into(), value: config.classify.bark.join(" ") });
    }
    if let Some(prune) = &config.prune {
        settings.extend(prune.settings());
    }
    if let Some(impostors) = &config.impostors {
        settings.extend(impostors.settings());
        settings.push(Setting { key: "atlas.format".into(), value: config.atlas_format.name().into() });
    }
    if let Some(ellipsoids) = &config.ellipsoids {
        settings.extend(ellipsoids.settings());
    }
    if let Some(lines) = &config.lines {
        settings.extend(lines.settings());
    }
    if let Some(ao) = &config.ao {
        settings.extend(ao.settings());
    }
    if let Some(calibration) = &config.calibration {
        settings.extend(calibration.settings());
    }
    if let Some(chain) = &config.baselines {
        settings.extend(chain.settings());
        if config.impostors.is_some() {
            settings.push(Setting { key: "baselines.billboards".into(), value: "facing,crossed,octahedral".into() });
            settings.extend(chain.octahedral.settings());
        }
    }
    settings.push(Setting { key: "precision".into(), value: config.precision.setting() });
    settings.sort();
    settings
}

/// A scene placed in the block.
#[derive(Clone, Copy, Debug)]
pub struct Placed<'a> {
    /// The tree.
    pub scene: &'a Scene,
    /// Its offset in block space, metres.
    pub translation: Vec3,
}

/// Counts of a finished build, for the summary a user sees.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BuildStats {
    /// Triangles read from the sources.
    pub triangles_in: u64,
    /// Triangles dropped as degenerate or non-finite.
    pub triangles_dropped: u64,
    /// Triangles classified as leaves (kept).
    pub leaf_triangles: u64,
    /// Triangles classified as bark (kept).
    pub bark_triangles: u64,
    /// Vertices written.
    pub vertices: u64,
    /// Triangles written.
    pub triangles: u64,
    /// Points written (leaf points and inner nodes).
    pub points: u64,
    /// Grid dimensions.
    pub grid: [u32; 3],
    /// Grid cells holding anything.
    pub nonempty_cells: u64,
    /// Pruned leaves written (0 without pruning).
    pub prune_leaves: u64,
    /// Triangles of the pruned leaves written.
    pub prune_triangles: u64,
    /// Impostor planes written (0 without impostors).
    pub planes: u64,
    /// Impostor planes per level, finest first, summed over the trees (empty without).
    pub planes_per_level: Vec<u32>,
    /// The impostor atlas, texels across and down (`[0, 0]` without); with indirect texturing,
    /// the leaf-slot image.
    pub atlas: [u32; 2],
    /// `PLANE_LEAVES` records written (0 unless the planes are textured indirectly).
    pub plane_leaves: u64,
    /// Baseline LoD chain levels written, summed over the trees (0 without baselines).
    pub lod_levels: u64,
    /// Triangles of the baseline LoD chains.
    pub lod_triangles: u64,
    /// Baseline billboard quads written.
    pub billboards: u64,
    /// Baseline octahedral impostors written (one per tree with billboards).
    pub octahedral: u64,
    /// The billboard atlas, texels across and down (`[0, 0]` without).
    pub billboard_atlas: [u32; 2],
    /// Leaf ellipsoids written (0 without).
    pub ellipsoids: u64,
    /// Leaf ellipsoids written per level of the cells' hierarchies, level 0 (the leaves) first,
    /// summed over the cells (empty without).
    pub ellipsoids_per_level: Vec<u32>,
    /// Branch lines written (0 without).
    pub lines: u64,
    /// Source segments of the bark skeleton (level 0 of the lines; 0 without).
    pub line_segments: u64,
    /// Branch lines drawn at each level of the cells' hierarchies, level 0 (the source segments)
    /// first, summed over the cells (empty without). A line unchanged over several levels is one
    /// record, counted at each of them.
    pub lines_per_level: Vec<u32>,
    /// The block's far lines at each level of their hierarchy (spec §6.9.1), level 0 (the lines
    /// the cells draw at the switch) first (empty without lines, or where none merge across
    /// cells).
    pub far_lines_per_level: Vec<u32>,
    /// Wall-clock time of each stage that ran, in the order they ran; together they tile the
    /// build from the gathering to the finished [`ContainerData`]. Not part of the container
    /// (a build's bytes never depend on its timing).
    pub stages: Vec<StageTime>,
}

impl BuildStats {
    /// Wall-clock time of the stage `name` ([`StageTime`]), whole milliseconds; 0 if it did not
    /// run (e.g. `"ellipsoids"`, `"lines"`, `"ao"`).
    #[must_use]
    pub fn stage_millis(&self, name: &str) -> u64 {
        self.stages
            .iter()
            .find(|stage| stage.name == name)
            .map_or(0, |stage| u64::try_from(stage.time.as_millis()).unwrap_or(u64::MAX))
    }
}

/// One stage of a build and how long it took ([`BuildStats::stages`]).
///
/// The build's stages, in order (those not asked for do not run and are not listed):
/// `gather` (classify parts, gather and filter triangles, free the scenes' geometry), `grid`
/// (bounds, grid, triangles assigned to cells), `prune` ([`crate::prune`]: the leaves' priority
/// list and curves), `ellipsoids` ([`crate::ellipsoid`]), `lines` ([`crate::lines`]), `cells`
/// (per cell the leaf points, point hierarchy and sorted triangles; vertices renumbered), `ao`
/// ([`crate::ambient`]: vertices and points), `records` (with any of those three, the cells'
/// pruned leaves, ellipsoids and lines, with the ellipsoids' and lines' occlusion), `impostors`
/// ([`crate::impostor`]: planes and atlas), `lod_chain` and `billboards` (the baselines,
/// [`crate::lod_chain`], [`crate::billboard`]), `triangles` (the triangle records in written
/// order), `images` (materials, images and atlases), `metadata`, and `precision` (the floats
/// rounded, [`crate::precision`]). Tools add their own around them (the `treelod` tool: `import`
/// before, `write` and `verify` after).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageTime {
    /// The stage's name, a lower-case identifier.
    pub name: &'static str,
    /// Wall-clock time of the stage.
    pub time: Duration,
}

/// Times the stages of a build one after another: each [`Self::lap`] records the time since the
/// previous lap under a stage's name, so the stages tile the build. Time before a stage that does
/// not run (microseconds of bookkeeping) counts to the next one.
struct StageClock {
    last: Instant,
}

impl StageClock {
    fn start() -> Self {
        Self { last: Instant::now() }
    }

    /// Ends the stage `name`: records its time in `stats`.
    fn lap(&mut self, stats: &mut BuildStats, name: &'static str) {
        let now = Instant::now();
        stats.stages.push(StageTime { name, time: now.duration_since(self.last) });
        self.last = now;
    }

    /// Runs the optional stage `name` with its `config` (nothing without one) and ends it.
    fn optional<C, T>(
        &mut self,
        stats: &mut BuildStats,
        name: &'static str,
        config: Option<&C>,
        stage: impl FnOnce(&C) -> Result<T, BuildError>,
    ) -> Result<Option<T>, BuildError> {
        let Some(config) = config else { return Ok(None) };
        let built = stage(config)?;
        self.lap(stats, name);
        Ok(Some(built))
    }
}

/// What a build returns.
#[derive(Clone, Debug)]
pub struct BuildOutput {
    /// The container, ready for `to_bytes`.
    pub data: ContainerData,
    /// Counts.
    pub stats: BuildStats,
    /// Warnings of the importers and of the build, one sentence each.
    pub warnings: Vec<String>,
}

/// The grid for a block of the given extent: 4 cells along the shortest axis and proportionally
/// more along the others, each axis in `4..=16` (Gilet: 4×4×4 for one tree, up to 4×16×16 for a
/// group).
#[must_use]
pub fn auto_grid(extent: Vec3) -> [u32; 3] {
    let longest = extent.max_element();
    // Axes thinner than 1 % of the longest do not set the scale (a flat group of trees).
    let shortest = extent.to_array().into_iter().filter(|&e| e > 0.01 * longest).fold(f32::INFINITY, f32::min);
    if !shortest.is_finite() || shortest <= 0.0 {
        return [4, 4, 4];
    }
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to 4..=16")]
    extent.to_array().map(|e| (4.0 * e / shortest).round().clamp(4.0, 16.0) as u32)
}

/// One kept triangle during the build: 24 bytes, so a large tree's triangles cost little before
/// the per-cell stage derives their points.
///
/// Laid out as a [`TriangleRecord`] (`part` in the place of `leaf`), so that the written records
/// take over the gathered triangles' memory ([`triangle_records`]).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Tri {
    /// Vertex ids: global ones (gathered order) until the vertices are renumbered after the
    /// per-cell stage, written ones after.
    v: [u32; 3],
    size: f32,
    /// Index into the build's part list, for the texture and vertex colours of the leaf point;
    /// once the triangle's cell is built, its leaf id in the cell's hierarchy.
    part: u32,
    material: u32,
}
const _: () = {
    assert!(size_of::<Tri>() == size_of::<TriangleRecord>());
    assert!(std::mem::offset_of!(Tri, v) == std::mem::offset_of!(TriangleRecord, indices));
    assert!(std::mem::offset_of!(Tri, size) == std::mem::offset_of!(TriangleRecord, size));
    assert!(std::mem::offset_of!(Tri, part) == std::mem::offset_of!(TriangleRecord, leaf));
    assert!(std::mem::offset_of!(Tri, material) == std::mem::offset_of!(TriangleRecord, material));
};

/// A source part as the per-cell stage sees it. It borrows nothing from the scene, so that the
/// scene's geometry can be freed once gathered ([`build_scenes`]).
struct PartRef {
    /// The part's vertex colours (linear; empty without), the only attribute the vertex records do
    /// not keep exactly.
    colors: Vec<[f32; 4]>,
    material: Material,
    /// (tree, image in its scene) of the material's image, if it has one.
    image: Option<(usize, usize)>,
    /// Global id of the part's first vertex.
    base: u32,
}

/// The triangles of a build, gathered from the placed scenes.
struct Gathered {
    /// (tree, source material, class) per output material, in first-use order.
    material_keys: Vec<(usize, usize, Class)>,
    material_info: Vec<MaterialInfo>,
    /// Every source vertex, in block space (global ids; renumbered when written).
    vertices: Vec<VertexRecord>,
    tris: Vec<Tri>,
    parts: Vec<PartRef>,
    /// Bounds of each tree's finite source positions in block space (the metadata's tree bounds).
    tree_bounds: Vec<(Vec3, Vec3)>,
    stats: BuildStats,
    warnings: Vec<String>,
}

/// The first stage of a build: checks the settings, classifies parts and gathers their
/// triangles, dropping degenerate ones.
fn gather(name: &str, trees: &[Placed<'_>], config: &BuildConfig) -> Result<Gathered, BuildError> {
    if let Some(grid) = config.grid
        && grid.iter().any(|&g| g == 0 || g > treelod_format::MAX_GRID_AXIS)
    {
        return Err(BuildError::Setting(format!("grid {grid:?}: each axis must be in 1..=256")));
    }
    if let Some(prune) = &config.prune {
        prune.validate()?;
    }
    if let Some(ao) = &config.ao {
        ao.validate()?;
    }
    if let Some(impostors) = &config.impostors {
        impostors.validate()?;
    }
    if let Some(ellipsoids) = &config.ellipsoids {
        ellipsoids.validate()?;
    }
    if let Some(lines) = &config.lines {
        lines.validate()?;
    }
    if let Some(baselines) = &config.baselines {
        baselines.validate()?;
    }
    let mut stats = BuildStats::default();
    let mut warnings: Vec<String> = Vec::new();

    // Stage: classify parts; materials become (tree, material, class) triples in first-use order.
    let mut material_keys: Vec<(usize, usize, Class)> = Vec::new();
    let mut material_info: Vec<MaterialInfo> = Vec::new();
    let mut vertices: Vec<VertexRecord> = Vec::new();
    let mut tris: Vec<Tri> = Vec::new();
    let mut parts: Vec<PartRef> = Vec::new();
    let mut tree_bounds: Vec<(Vec3, Vec3)> = Vec::with_capacity(trees.len());
    // Reserved whole (at most what is read; degenerate triangles are dropped): grown piecemeal,
    // the two largest arrays of the build would be copied as they grow and leave holes behind.
    let all_parts = || trees.iter().flat_map(|placed| &placed.scene.parts);
    vertices.reserve_exact(all_parts().map(|p| p.positions.len()).sum());
    tris.reserve_exact(all_parts().map(|p| p.triangles.len()).sum());
    for (t, placed) in trees.iter().enumerate() {
        let scene = placed.scene;
        let (mut tmin, mut tmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for p in scene.parts.iter().flat_map(|p| &p.positions) {
            let v = Vec3::from_array(*p) + placed.translation;
            if v.is_finite() {
                tmin = tmin.min(v);
                tmax = tmax.max(v);
            }
        }
        tree_bounds.push((tmin, tmax));
        warnings.extend(scene.warnings.iter().map(|w| format!("{}: {w}", scene.name)));
        let classes = classify(scene, &config.classify);
        for (part, class) in scene.parts.iter().zip(&classes) {
            let key = (t, part.material, class.class);
            let material = match material_keys.iter().position(|k| *k == key) {
                Some(m) => m,
                None => {
                    material_keys.push(key);
                    let name = scene.materials.get(part.material).map_or(String::new(), |m| m.name.clone());
                    material_info.push(MaterialInfo { name, classified_by: class.by.as_str().to_owned() });
                    material_keys.len() - 1
                }
            };
            let source_material = scene.materials.get(part.material).cloned().unwrap_or_default();
            let image = source_material.image.filter(|&i| i < scene.images.len()).map(|i| (t, i));
            let base =
                u32::try_from(vertices.len()).map_err(|_| BuildError::Setting("more than 2^32 vertices".into()))?;
            #[expect(clippy::cast_possible_truncation, reason = "parts are fewer than vertices")]
            let part_id = parts.len() as u32;
            parts.push(PartRef { colors: part.colors.clone(), material: source_material, image, base });
            for (i, p) in part.positions.iter().enumerate() {
                let position = (Vec3::from_array(*p) + placed.translation).to_array();
                let normal = part.normals.get(i).copied().unwrap_or([0.0, 1.0, 0.0]);
                let uv = part.uvs.get(i).copied().unwrap_or([0.0, 0.0]);
                let color = part.colors.get(i).map_or(u32::MAX, |c| {
                    pack::rgba8([linear_to_srgb(c[0]), linear_to_srgb(c[1]), linear_to_srgb(c[2]), c[3]])
                });
                vertices.push(VertexRecord { position, normal: pack::oct_encode(normal), uv, color });
            }
            let mut dropped = 0u64;
            for tri in &part.triangles {
                stats.triangles_in += 1;
                if tri.iter().any(|&i| i as usize >= part.positions.len()) {
                    dropped += 1;
                    continue;
                }
                let [a, b, c] = tri.map(|i| Vec3::from_array(vertices[(base + i) as usize].position));
                let area: f32 = 0.5 * (b - a).cross(c - a).length();
                let in_range = [a, b, c].iter().all(|p| p.is_finite() && p.abs().max_element() <= MAX_COORDINATE);
                if !(in_range && area.is_finite() && area > MIN_AREA) {
                    dropped += 1;
                    continue;
                }
                let size = 2.0 * (area / std::f32::consts::PI).sqrt();
                match class.class {
                    Class::Leaf => stats.leaf_triangles += 1,
                    Class::Bark => stats.bark_triangles += 1,
                }
                #[expect(clippy::cast_possible_truncation, reason = "materials are few")]
                tris.push(Tri { v: tri.map(|i| base + i), material: material as u32, size, part: part_id });
            }
            if dropped > 0 {
                warnings.push(format!(
                    "{}: {}: dropped {dropped} degenerate or non-finite triangles (or beyond 1,000 km)",
                    scene.name,
                    part.label()
                ));
                stats.triangles_dropped += dropped;
            }
        }
    }
    if tris.is_empty() {
        return Err(BuildError::NoGeometry {
            name: name.to_owned(),
            reason: format!("{} triangles read, {} dropped", stats.triangles_in, stats.triangles_dropped),
        });
    }
    if stats.leaf_triangles == 0 {
        warnings.push(format!("{name}: no part was classified as leaves; pass --leaves PATTERN if that is wrong"));
    }
    Ok(Gathered { material_keys, material_info, vertices, tris, parts, tree_bounds, stats, warnings })
}

/// The bounds and grid of a block (spec §6.1).
struct BlockGrid {
    lo: Vec3,
    hi: Vec3,
    grid: [u32; 3],
    cell_count: usize,
}

impl BlockGrid {
    /// The bounds of `tris` and the grid of `config` (or the automatic one).
    fn new(tris: &[Tri], vertices: &[VertexRecord], config: &BuildConfig) -> Result<Self, BuildError> {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for t in tris {
            for &v in &t.v {
                let p = Vec3::from_array(vertices[v as usize].position);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        let grid = config.grid.unwrap_or_else(|| auto_grid(hi - lo));
        let cell_count = grid.iter().map(|&g| g as usize).product::<usize>();
        if cell_count > treelod_format::MAX_GRID_CELLS {
            return Err(BuildError::Setting(format!("grid {grid:?} has more than 65536 cells")));
        }
        Ok(Self { lo, hi, grid, cell_count })
    }

    /// The index of the cell holding `p` (a point outside the bounds goes to the nearest cell).
    fn cell_of(&self, p: Vec3) -> usize {
        let dims = Vec3::new(self.grid[0] as f32, self.grid[1] as f32, self.grid[2] as f32);
        let cell_size = (self.hi - self.lo) / dims;
        let rel = (p - self.lo) / cell_size.max(Vec3::splat(f32::MIN_POSITIVE));
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped into the grid")]
        let c = (rel.floor().max(Vec3::ZERO).min(dims - 1.0)).to_array().map(|v| v as usize);
        c[0] + self.grid[0] as usize * (c[1] + self.grid[1] as usize * c[2])
    }

    /// [`Self::cell_of`] as a `u32` (grids have at most 65536 cells).
    fn cell_id(&self, p: Vec3) -> u32 {
        #[expect(clippy::cast_possible_truncation, reason = "at most 65536 cells")]
        let cell = self.cell_of(p) as u32;
        cell
    }
}

/// The gathered triangles as pruning sees them: the leaf-class ones (with their ids in the
/// gathered triangles), the others, and one alpha test per alpha-tested output material.
struct PruneInput {
    leaves: Vec<MeshTriangle>,
    leaf_ids: Vec<u32>,
    bark: Vec<MeshTriangle>,
    alphas: Vec<AlphaMask>,
}

impl PruneInput {
    fn new(material_keys: &[(usize, usize, Class)], tris: &[Tri], trees: &[Placed<'_>]) -> Self {
        let mut alphas: Vec<AlphaMask> = Vec::new();
        let alpha_of: Vec<u32> = material_keys
            .iter()
            .map(|&(t, m, _)| {
                let scene = trees[t].scene;
                let material = scene.materials.get(m).cloned().unwrap_or_default();
                let image = material.image.and_then(|i| scene.images.get(i));
                AlphaMask::for_material(&material, image).map_or(NO_ALPHA, |mask| {
                    alphas.push(mask);
                    #[expect(clippy::cast_possible_truncation, reason = "materials are few")]
                    let id = (alphas.len() - 1) as u32;
                    id
                })
            })
            .collect();
        let (mut leaves, mut leaf_ids, mut bark) = (Vec::new(), Vec::new(), Vec::new());
        for (i, t) in tris.iter().enumerate() {
            let triangle = MeshTriangle { v: t.v, alpha: alpha_of[t.material as usize] };
            if material_keys[t.material as usize].2 == Class::Leaf {
                leaves.push(triangle);
                #[expect(clippy::cast_possible_truncation, reason = "fewer than 2^32 triangles")]
                leaf_ids.push(i as u32);
            } else {
                bark.push(triangle);
            }
        }
        Self { leaves, leaf_ids, bark, alphas }
    }

    fn mesh<'a>(&'a self, vertices: &'a [VertexRecord]) -> PruneMesh<'a> {
        PruneMesh { vertices, leaves: &self.leaves, bark: &self.bark, alphas: &self.alphas }
    }
}

/// Compares the priority orders of pruning on a block (`treelod build --prune-report`); see
/// [`crate::prune::compare`]. `config.prune` sets the images and the quality (the default
/// [`PruneConfig`] when `None`; its order is ignored).
///
/// # Errors
/// As [`build_block`]: [`BuildError::NoGeometry`], [`BuildError::Setting`].
pub fn prune_report(name: &str, trees: &[Placed<'_>], config: &BuildConfig) -> Result<PruneReport, BuildError> {
    let gathered = gather(name, trees, config)?;
    let grid = BlockGrid::new(&gathered.tris, &gathered.vertices, config)?;
    let input = PruneInput::new(&gathered.material_keys, &gathered.tris, trees);
    let prune = config.prune.clone().unwrap_or_default();
    crate::prune::compare(input.mesh(&gathered.vertices), |p| grid.cell_id(p), grid.hi.y - grid.lo.y, &prune)
}

/// The leaf ellipsoids of a block as a build with `config` makes them ([`crate::ellipsoid`]), with
/// each cell's levels, factors and image errors, without building the rest of the container:
/// for comparing clusterings (`config.ellipsoids`, the default [`EllipsoidConfig`] when `None`).
///
/// # Errors
/// As [`build_block`]: [`BuildError::NoGeometry`], [`BuildError::Setting`], [`BuildError::Spt`].
pub fn ellipsoid_report(name: &str, trees: &[Placed<'_>], config: &BuildConfig) -> Result<Ellipsoids, BuildError> {
    let gathered = gather(name, trees, config)?;
    let grid = BlockGrid::new(&gathered.tris, &gathered.vertices, config)?;
    let ellipsoid_config = config.ellipsoids.clone().unwrap_or_default();
    ellipsoid_config.validate()?;
    block_ellipsoids(
        &gathered.material_keys,
        &gathered.tris,
        &gathered.vertices,
        &gathered.parts,
        trees,
        |p| grid.cell_of(p),
        grid.cell_count,
        &ellipsoid_config,
    )
}

/// Builds a block from placed scenes (spec §6, Gilet 2005; with [`BuildConfig::prune`] also
/// Neubert's pruning, §6.11). `name` names the block; `generator` is recorded as the tool and
/// version.
///
/// # Errors
/// [`BuildError::NoGeometry`] if no drawable triangle remains, [`BuildError::Setting`] for a bad
/// grid or pruning setting, [`BuildError::Spt`] if an internal invariant breaks.
pub fn build_block(
    name: &str,
    trees: &[Placed<'_>],
    config: &BuildConfig,
    generator: &str,
) -> Result<BuildOutput, BuildError> {
    let mut clock = StageClock::start();
    let mut gathered = gather(name, trees, config)?;
    clock.lap(&mut gathered.stats, "gather");
    assemble(name, trees, gathered, config, generator, clock)
}

/// As [`build_block`] on owned scenes (each with its translation), giving the same output; each
/// scene's parts (its geometry) are freed as soon as they are gathered into the build's own arrays,
/// so the build does not hold the source geometry and its own copy at once. Only the scenes'
/// materials, images and source information are kept until the build ends.
///
/// # Errors
/// As [`build_block`].
pub fn build_scenes(
    name: &str,
    mut scenes: Vec<(Scene, Vec3)>,
    config: &BuildConfig,
    generator: &str,
) -> Result<BuildOutput, BuildError> {
    let mut clock = StageClock::start();
    let placed: Vec<Placed<'_>> =
        scenes.iter().map(|(scene, translation)| Placed { scene, translation: *translation }).collect();
    let mut gathered = gather(name, &placed, config)?;
    drop(placed);
    for (scene, _) in &mut scenes {
        scene.parts = Vec::new();
    }
    clock.lap(&mut gathered.stats, "gather");
    let placed: Vec<Placed<'_>> =
        scenes.iter().map(|(scene, translation)| Placed { scene, translation: *translation }).collect();
    assemble(name, &placed, gathered, config, generator, clock)
}

/// The stages of [`build_block`] after the gathering; reads only the scenes' materials, images,
/// names and sources (not their parts). `clock` times the stages from the end of the gathering.
fn assemble(
    name: &str,
    trees: &[Placed<'_>],
    gathered: Gathered,
    config: &BuildConfig,
    generator: &str,
    mut clock: StageClock,
) -> Result<BuildOutput, BuildError> {
    let Gathered { material_keys, material_info, vertices, mut tris, parts, tree_bounds, mut stats, mut warnings } =
        gathered;

    // Stage: bounds and grid.
    let block_grid = BlockGrid::new(&tris, &vertices, config)?;
    let BlockGrid { lo, hi, grid, cell_count } = block_grid;
    stats.grid = grid;

    // Stage: assign each triangle to the cell of its centroid.
    let mut per_cell: Vec<Vec<u32>> = vec![Vec::new(); cell_count];
    for (i, t) in tris.iter().enumerate() {
        #[expect(clippy::cast_possible_truncation, reason = "fewer than 2^32 triangles (checked via vertex count)")]
        per_cell[block_grid.cell_of(centroid(&vertices, t))].push(i as u32);
    }
    clock.lap(&mut stats, "grid");

    // Stage: pruning (Neubert 2011): leaves, their priority list, s_opt(λ) and λ(h).
    let pruned: Option<(Pruned, PruneInput)> = match &config.prune {
        Some(prune) => {
            let input = PruneInput::new(&material_keys, &tris, trees);
            let pruned = crate::prune::prune(input.mesh(&vertices), |p| block_grid.cell_id(p), hi.y - lo.y, prune)?;
            clock.lap(&mut stats, "prune");
            Some((pruned, input))
        }
        None => None,
    };

    // Stage: leaf ellipsoids (Clasen 2011), per cell; before the per-cell stage, which overwrites
    // the triangles' parts (the ellipsoids' colours need them).
    let cell_of = |p: Vec3| block_grid.cell_of(p);
    let ellipsoids: Option<Ellipsoids> = clock.optional(&mut stats, "ellipsoids", config.ellipsoids.as_ref(), |c| {
        block_ellipsoids(&material_keys, &tris, &vertices, &parts, trees, cell_of, cell_count, c)
    })?;
    // Stage: branch lines (Clasen 2011): the bark skeleton, per cell; here for the same reason.
    let lines: Option<Lines> = clock.optional(&mut stats, "lines", config.lines.as_ref(), |c| {
        block_lines(&material_keys, &tris, &vertices, &parts, trees, cell_of, cell_count, c)
    })?;

    // Stage: ambient occlusion of the vertices, in their gathered order (renumbered with them
    // below), and each triangle's coverage; before the per-cell stage, so that the rays are not
    // traced beside the points (49 MB of the maple's peak).
    let mut occlusion = match &config.ao {
        Some(ao) => {
            let progress = |done, total| config.progress.report(Progress::AMBIENT_OCCLUSION, done, total);
            let (vertex_ao, coverage) =
                gathered_occlusion(&tris, &vertices, &parts, &material_keys, trees, ao, &progress);
            clock.lap(&mut stats, "ao");
            Some((vertex_ao, coverage))
        }
        None => None,
    };
    // Stage: per cell, the leaf points, the point hierarchy as point records, and the triangles in
    // size order; then the records, cell by cell, with vertices renumbered by first use. Cells are
    // built in parallel a few at a time (results kept in cell order), and each batch is copied out
    // and freed before the next, so the per-cell results never hold a second copy of the points.
    // The batches keep both threads busy: on the maple the cells take 1.74 s of CPU, the largest
    // 0.13 s, and the batches' largest cells sum to 0.85 s, less than half the work; copying the
    // batches out takes 0.08 s. Integrating each cell's leaf points in parallel as well was
    // measured and not taken (the stage 1.07–1.30 s against 1.14–1.31 s, 5 alternating builds).
    //
    // The vertices and triangles are not copied: the loop records the new vertex ids (`remap`),
    // the written order of the triangles (`order`) and each one's leaf (in its `part`, which only
    // this stage reads); the gathered arrays are permuted into the written order in place
    // afterwards. On the 669k-triangle maple this keeps 36 MB (a second vertex and triangle
    // array) from the build's peak.
    let mut remap = vec![u32::MAX; vertices.len()];
    let mut used_vertices = 0u32;
    let mut order: Vec<u32> = Vec::with_capacity(tris.len());
    // An upper bound (a hierarchy has fewer inner nodes than leaves): reserved address space, of
    // which only what is written becomes resident.
    let mut points: Vec<PointRecord> = Vec::with_capacity(2 * tris.len());
    let mut point_facing: Vec<u8> = Vec::with_capacity(2 * tris.len());
    let mut cells: Vec<CellRecord> = Vec::with_capacity(cell_count + 1);
    let batch = 2 * rayon::current_num_threads().max(1);
    for cell_batch in per_cell.chunks_mut(batch) {
        let outputs: Vec<CellOutput> = cell_batch
            .par_iter_mut()
            .map(std::mem::take)
            .map(|ids| cell_output(&ids, &tris, &vertices, &parts, trees, &config.gilet))
            .collect::<Result<_, FlattenError>>()?;
        for cell in outputs {
            let (mut cmin, mut cmax) = cell.bounds;
            let first_triangle = order.len();
            for (id, leaf) in cell.order {
                for &v in &tris[id as usize].v {
                    let slot = &mut remap[v as usize];
                    if *slot == u32::MAX {
                        *slot = used_vertices;
                        used_vertices += 1;
                    }
                    let p = Vec3::from_array(vertices[v as usize].position);
                    cmin = cmin.min(p);
                    cmax = cmax.max(p);
                }
                order.push(id);
                tris[id as usize].part = leaf;
            }
            let first_point = points.len();
            points.extend(cell.points);
            point_facing.extend(cell.facing);
            let empty = first_triangle == order.len();
            cells.push(CellRecord {
                bounds_min: if empty { [0.0; 3] } else { cmin.to_array() },
                bounds_max: if empty { [0.0; 3] } else { cmax.to_array() },
                triangles: range(first_triangle, order.len()),
                points: range(first_point, points.len()),
                ..CellRecord::default()
            });
        }
    }
    // The vertices in first-use order (the written ones first; those of no kept triangle after
    // them, then cut), and the triangles' indices into that order.
    let mut vertices = vertices;
    let written_vertices = used_vertices as usize;
    for slot in remap.iter_mut().filter(|slot| **slot == u32::MAX) {
        *slot = used_vertices;
        used_vertices += 1;
    }
    for t in &mut tris {
        t.v = t.v.map(|v| remap[v as usize]);
    }
    // The vertices (and their occlusion) in the written order, cut to the written ones; then
    // each point's occlusion (its leaves' mean).
    scatter_in_place(remap, |i, j| {
        vertices.swap(i, j);
        if let Some((vertex_ao, _)) = &mut occlusion {
            vertex_ao.swap(i, j);
        }
    });
    vertices.truncate(written_vertices);
    vertices.shrink_to_fit();
    let (vertex_ao, point_ao, coverage) = match occlusion {
        Some((mut vertex_ao, coverage)) => {
            vertex_ao.truncate(written_vertices);
            let point_ao = point_occlusion(&tris, &order, &points, &cells, &vertex_ao, &coverage);
            (Some(vertex_ao), point_ao, coverage)
        }
        None => (None, Vec::new(), Vec::new()),
    };
    clock.lap(&mut stats, "cells");
    // Stage: the pruned leaves of each cell in priority order, their triangles in leaf order with
    // the vertices written above (every leaf triangle is also in TRIANGLES).
    let (mut prune_leaves, mut prune_triangles) = (Vec::new(), Vec::new());
    let (mut prune_scale, mut prune_lambda) = (Vec::new(), Vec::new());
    if let Some((pruned, input)) = pruned {
        // Cell bounds hold the leaves grown by the largest s_opt (an area factor: √ on distances).
        let grow = pruned.scale.iter().map(|s| s.y).fold(1.0f32, f32::max).sqrt();
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); cell_count];
        for &l in &pruned.order {
            lists[block_grid.cell_of(pruned.leaves.leaves[l as usize].centre)].push(l);
        }
        for (cell, list) in cells.iter_mut().zip(&lists) {
            let first = prune_leaves.len();
            let (mut cmin, mut cmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for &l in list {
                let leaf = &pruned.leaves.leaves[l as usize];
                #[expect(clippy::cast_possible_truncation, reason = "fewer leaves than triangles, which fit u32")]
                let (index, first_triangle) = (prune_leaves.len() as u32, prune_triangles.len() as u32);
                for &m in pruned.leaves.triangles_of(leaf) {
                    let t = &tris[input.leaf_ids[m as usize] as usize];
                    for &v in &t.v {
                        let p = leaf.centre + (Vec3::from_array(vertices[v as usize].position) - leaf.centre) * grow;
                        cmin = cmin.min(p);
                        cmax = cmax.max(p);
                    }
                    prune_triangles.push(TriangleRecord {
                        indices: t.v,
                        size: t.size,
                        leaf: index,
                        material: t.material,
                    });
                }
                cmin = cmin.min(leaf.centre);
                cmax = cmax.max(leaf.centre);
                prune_leaves.push(PruneLeafRecord {
                    center: leaf.centre.to_array(),
                    area: leaf.area,
                    first_triangle,
                    triangle_count: leaf.count,
                });
            }
            cell.prune_leaves = range(first, prune_leaves.len());
            if !list.is_empty() {
                if cell.triangles.count > 0 {
                    cmin = cmin.min(Vec3::from_array(cell.bounds_min));
                    cmax = cmax.max(Vec3::from_array(cell.bounds_max));
                }
                cell.bounds_min = cmin.to_array();
                cell.bounds_max = cmax.to_array();
            }
        }
        prune_scale = pruned.scale;
        prune_lambda = pruned.lambda;
    }
    // Stage: the ellipsoid records of each grid cell, after the pruned leaves (which reset the
    // bounds of cells without triangles); cell bounds grow to hold them.
    let mut ellipsoid_records = Vec::new();
    let mut ellipsoid_ao = Vec::new();
    if let Some(built) = ellipsoids {
        stats.ellipsoids_per_level = built.per_level();
        for (cell, cell_ellipsoids) in cells.iter_mut().zip(built.cells) {
            if let Some(vertex_ao) = &vertex_ao {
                ellipsoid_ao.extend(ellipsoid_occlusion(&cell_ellipsoids, &tris, vertex_ao, &coverage));
            }
            let first = ellipsoid_records.len();
            grow_bounds(cell, cell_ellipsoids.bounds);
            ellipsoid_records.extend(cell_ellipsoids.records);
            cell.ellipsoids = range(first, ellipsoid_records.len());
        }
    }
    // Stage: the line records of each grid cell; cell bounds grow to hold their endpoints.
    let mut line_records = Vec::new();
    let mut line_ao = Vec::new();
    let (mut far_lines, mut far_line_ao) = (Vec::new(), Vec::new());
    if let Some(built) = lines {
        stats.lines_per_level = built.per_level();
        stats.line_segments = built.source_segments;
        stats.far_lines_per_level = built.far.levels.iter().map(|l| l.count).collect();
        if let Some(vertex_ao) = &vertex_ao {
            far_line_ao = line_occlusion(&built.far, &tris, vertex_ao);
        }
        far_lines = built.far.records;
        for (cell, cell_lines) in cells.iter_mut().zip(built.cells) {
            if let Some(vertex_ao) = &vertex_ao {
                line_ao.extend(line_occlusion(&cell_lines, &tris, vertex_ao));
            }
            let first = line_records.len();
            grow_bounds(cell, cell_lines.bounds);
            line_records.extend(cell_lines.records);
            cell.lines = range(first, line_records.len());
        }
    }
    if config.prune.is_some() || config.ellipsoids.is_some() || config.lines.is_some() {
        clock.lap(&mut stats, "records");
    }
    // Stage: impostors (Garcia 2005): nested planes per tree and their atlas, in the block cell.
    let impostors = match &config.impostors {
        Some(impostor_config) => {
            let built =
                block_impostors(&material_keys, &tris, &vertices, vertex_ao.as_deref(), trees, impostor_config)?;
            clock.lap(&mut stats, "impostors");
            built
        }
        None => None,
    };
    // Stage: baselines: each tree's LoD chain (over the written vertices), and its billboards at
    // the texel budget of its impostor planes.
    let (mut lod_levels, mut lod_triangles) = (Vec::new(), Vec::new());
    let mut billboards = None;
    if let Some(chain_config) = &config.baselines {
        let chain_input: Vec<ChainTriangle> = tris
            .iter()
            .map(|t| {
                let (tree, _, class) = material_keys[t.material as usize];
                #[expect(clippy::cast_possible_truncation, reason = "a block holds few trees")]
                let tree = tree as u32;
                ChainTriangle { v: t.v, material: t.material, tree, leaf: class == Class::Leaf }
            })
            .collect();
        for level in build_lod_chain(&vertices, &chain_input, chain_config)? {
            let first = lod_triangles.len();
            lod_triangles.extend(level.triangles.iter().map(|&(indices, material)| {
                let [a, b, c] = indices.map(|v| Vec3::from_array(vertices[v as usize].position));
                let area = 0.5 * (b - a).cross(c - a).length();
                TriangleRecord { indices, size: 2.0 * (area / std::f32::consts::PI).sqrt(), leaf: 0, material }
            }));
            lod_levels.push(LodLevelRecord {
                tree: level.tree,
                level: level.level,
                triangles: range(first, lod_triangles.len()),
                error: level.error,
                fraction: level.fraction,
            });
        }
        clock.lap(&mut stats, "lod_chain");
        if let Some(impostors) = &impostors {
            billboards = block_billboards(
                &material_keys,
                &tris,
                &vertices,
                vertex_ao.as_deref(),
                trees,
                &impostors.texels_per_tree,
                &chain_config.octahedral,
            )?;
            clock.lap(&mut stats, "billboards");
        }
    }
    drop((per_cell, parts));
    let triangles = triangle_records(tris, &order);
    drop(order);
    clock.lap(&mut stats, "triangles");
    // The block cell: Gilet's representation and the pruned leaves live in the grid cells only;
    // the impostor planes of the whole block live here.
    let plane_count = impostors.as_ref().map_or(0, |i| i.planes.len());
    let (planes_min, planes_max) = impostors.as_ref().map_or((Vec3::ZERO, Vec3::ZERO), |i| i.bounds);
    cells.push(CellRecord {
        bounds_min: planes_min.to_array(),
        bounds_max: planes_max.to_array(),
        triangles: range(triangles.len(), triangles.len()),
        points: range(points.len(), points.len()),
        ellipsoids: range(ellipsoid_records.len(), ellipsoid_records.len()),
        lines: range(line_records.len(), line_records.len()),
        planes: range(0, plane_count),
        prune_leaves: range(prune_leaves.len(), prune_leaves.len()),
        ..CellRecord::default()
    });
    stats.nonempty_cells = cells[..cell_count].iter().filter(|c| !c.is_empty()).count() as u64;

    // Stage: the atlases in their stored format (BC7 blocks by default).
    let (mut impostors, mut billboards) = (impostors, billboards);
    if impostors.is_some() || billboards.is_some() {
        if let Some(i) = impostors.as_mut() {
            i.atlas = crate::atlas_format::store(std::mem::take(&mut i.atlas), config.atlas_format);
        }
        if let Some(b) = billboards.as_mut() {
            b.atlas = crate::atlas_format::store(std::mem::take(&mut b.atlas), config.atlas_format);
        }
        clock.lap(&mut stats, "atlas_format");
    }

    // Stage: materials and images (only those used, in first-use order).
    let mut images: Vec<ImageRecord> = Vec::new();
    let mut image_data: Vec<u8> = Vec::new();
    let mut image_keys: Vec<(usize, usize)> = Vec::new();
    let mut materials: Vec<MaterialRecord> = Vec::new();
    for &(t, m, class) in &material_keys {
        let scene = trees[t].scene;
        let source = scene.materials.get(m).cloned().unwrap_or_default();
        let image = match source.image.and_then(|i| scene.images.get(i).map(|img| (i, img))) {
            None => NO_IMAGE,
            Some((i, img)) => match image_keys.iter().position(|k| *k == (t, i)) {
                #[expect(clippy::cast_possible_truncation, reason = "images are few")]
                Some(existing) => existing as u32,
                None => {
                    let (format, bytes): (u32, &[u8]) = match img.encoding {
                        ImageEncoding::Png => (image_format::PNG, &img.encoded),
                        ImageEncoding::Jpeg => (image_format::JPEG, &img.encoded),
                        ImageEncoding::Raw => (image_format::RGBA8_SRGB, &img.rgba),
                    };
                    image_data.resize(image_data.len().div_ceil(16) * 16, 0);
                    images.push(ImageRecord {
                        width: img.width,
                        height: img.height,
                        mip_count: 1,
                        format,
                        data_offset: image_data.len() as u64,
                        data_length: bytes.len() as u64,
                    });
                    image_data.extend_from_slice(bytes);
                    image_keys.push((t, i));
                    #[expect(clippy::cast_possible_truncation, reason = "images are few")]
                    let id = (images.len() - 1) as u32;
                    id
                }
            },
        };
        materials.push(MaterialRecord {
            base_color: source.base_color,
            image,
            alpha_mode: match source.alpha_mode {
                AlphaMode::Opaque => 0,
                AlphaMode::Mask => 1,
                AlphaMode::Blend => 2,
            },
            alpha_cutoff: source.alpha_cutoff.clamp(0.0, 1.0),
            class: match class {
                Class::Bark => material_class::BARK,
                Class::Leaf => material_class::LEAF,
            },
            flags: if source.double_sided { MATERIAL_DOUBLE_SIDED } else { 0 },
            _pad: 0,
        });
    }

    // Stage: the impostor atlas after the materials' images; the planes point at it.
    let mut planes: Vec<treelod_format::PlaneRecord> = Vec::new();
    let mut plane_ao = Vec::new();
    let mut plane_diffuse = Vec::new();
    let mut plane_leaves = Vec::new();
    if let Some(impostors) = impostors {
        plane_ao = impostors.plane_ao.iter().map(|&a| encode_ao(a)).collect();
        plane_diffuse = impostors.plane_diffuse;
        warnings.extend(impostors.note);
        let atlas = impostors.atlas;
        let index = push_atlas(&mut images, &mut image_data, &atlas);
        planes = impostors.planes.into_iter().map(|p| treelod_format::PlaneRecord { image: index, ..p }).collect();
        plane_leaves = impostors.plane_leaves;
        stats.plane_leaves = plane_leaves.len() as u64;
        stats.planes = planes.len() as u64;
        stats.planes_per_level = impostors.planes_per_level;
        stats.atlas = [atlas.width, atlas.height];
    }
    // The billboard atlas after that.
    let mut billboard_records: Vec<BillboardRecord> = Vec::new();
    let mut octahedral_records: Vec<OctahedralRecord> = Vec::new();
    let mut octahedral_depth: Vec<OctahedralDepthRecord> = Vec::new();
    let mut octahedral_normal_grids: Vec<OctahedralNormalGridRecord> = Vec::new();
    if let Some(billboards) = billboards {
        let atlas = billboards.atlas;
        let index = push_atlas(&mut images, &mut image_data, &atlas);
        billboard_records = billboards.records.into_iter().map(|b| BillboardRecord { image: index, ..b }).collect();
        octahedral_records =
            billboards.octahedral.into_iter().map(|o| OctahedralRecord { image: index, ..o }).collect();
        octahedral_depth = billboards.octahedral_depth;
        octahedral_normal_grids = billboards.octahedral_normal_grids;
        stats.billboard_atlas = [atlas.width, atlas.height];
    }
    clock.lap(&mut stats, "images");

    // Stage: metadata.
    let mut sources: Vec<Source> = Vec::new();
    let mut tree_meta: Vec<Tree> = Vec::new();
    for (placed, &(tmin, tmax)) in trees.iter().zip(&tree_bounds) {
        let s = &placed.scene.source;
        let source = match sources
            .iter()
            .position(|x| x.path == s.path && x.content_hash == s.content_hash && !s.path.is_empty())
        {
            Some(i) => i,
            None => {
                sources.push(Source {
                    path: s.path.clone(),
                    content_hash: s.content_hash.clone(),
                    byte_length: s.byte_length,
                    unit_scale: s.unit_scale,
                });
                sources.len() - 1
            }
        };
        #[expect(clippy::cast_possible_truncation, reason = "sources are few")]
        tree_meta.push(Tree {
            name: placed.scene.name.clone(),
            source: source as u32,
            translation: placed.translation.to_array(),
            bounds_min: tmin.to_array(),
            bounds_max: tmax.to_array(),
        });
    }
    let settings = recorded_settings(config, grid);

    stats.vertices = vertices.len() as u64;
    stats.triangles = triangles.len() as u64;
    stats.points = points.len() as u64;
    stats.prune_leaves = prune_leaves.len() as u64;
    stats.prune_triangles = prune_triangles.len() as u64;
    stats.lod_levels = lod_levels.len() as u64;
    stats.lod_triangles = lod_triangles.len() as u64;
    stats.billboards = billboard_records.len() as u64;
    stats.octahedral = octahedral_records.len() as u64;
    stats.ellipsoids = ellipsoid_records.len() as u64;
    stats.lines = line_records.len() as u64;
    let data = ContainerData {
        metadata: Metadata {
            generator: generator.to_owned(),
            name: name.to_owned(),
            sources,
            trees: tree_meta,
            materials: material_info,
            settings,
        },
        block: BlockRecord {
            bounds_min: lo.to_array(),
            bounds_max: hi.to_array(),
            grid,
            #[expect(clippy::cast_possible_truncation, reason = "a block holds few trees")]
            tree_count: trees.len() as u32,
            flags: 0,
            _pad: 0,
        },
        cells,
        vertices,
        triangles,
        points,
        ellipsoids: ellipsoid_records,
        lines: line_records,
        far_lines,
        far_line_ao,
        materials,
        images,
        image_data,
        prune_leaves,
        prune_triangles,
        prune_scale,
        prune_lambda,
        planes,
        plane_leaves,
        lod_levels,
        lod_triangles,
        billboards: billboard_records,
        octahedral: octahedral_records,
        octahedral_depth,
        octahedral_normal_grids,
        vertex_ao: vertex_ao.map_or_else(Vec::new, |ao| ao.iter().map(|&a| encode_ao(a)).collect()),
        point_ao,
        point_facing,
        plane_ao,
        plane_diffuse,
        ellipsoid_ao,
        line_ao,
        ..ContainerData::default()
    };
    clock.lap(&mut stats, "metadata");
    let mut data = data;
    crate::precision::trim(&mut data, &config.precision);
    clock.lap(&mut stats, "precision");
    // Stage: calibration, of what is written (after the precision trim).
    if let Some(calibration) = &config.calibration {
        // A block whose sphere is wider than the views show (a stray vertex far from the tree,
        // or a row of trees in one block) is measured in the middle of each view: said, since
        // its bounds are likely not what the artist meant.
        let (lo, hi) = (Vec3::from_array(data.block.bounds_min), Vec3::from_array(data.block.bounds_max));
        let across = (hi - lo).length() / (hi.y - lo.y);
        if hi.y > lo.y && across > crate::calibrate::MAX_VIEW_HEIGHTS {
            warnings.push(format!(
                "the block's bounding sphere is {across:.1} times as wide as the block is high \
                 (bounds {:?} .. {:?}): calibration measures the middle {} heights of each view; \
                 are some vertices far from the rest?",
                data.block.bounds_min,
                data.block.bounds_max,
                crate::calibrate::MAX_VIEW_HEIGHTS
            ));
        }
        let calibrated = crate::calibrate::calibrate(&data, calibration);
        data.calibration = calibrated.mean;
        data.calibration_elevations = calibrated.elevations;
        data.calibration_added = calibrated.added;
        data.calibration_elevations_added = calibrated.elevations_added;
        data.calibration_flip = calibrated.flip;
        data.chain_calibration_flip = calibrated.chain_flip;
        data.chain_calibration = calibrated.chain_levels;
        clock.lap(&mut stats, "calibration");
    }
    Ok(BuildOutput { data, stats, warnings })
}

/// The impostors of a block's leaf-class triangles ([`crate::impostor`]): each tree's leaves
/// drawn with their source material and image.
fn block_impostors(
    material_keys: &[(usize, usize, Class)],
    tris: &[Tri],
    vertices: &[VertexRecord],
    vertex_ao: Option<&[f32]>,
    trees: &[Placed<'_>],
    config: &ImpostorConfig,
) -> Result<Option<Impostors>, BuildError> {
    let default_material = Material::default();
    let surfaces = surfaces(material_keys, trees, &default_material);
    let is_leaf = |t: &&Tri| material_keys[t.material as usize].2 == Class::Leaf;
    let leaves: Vec<LeafTriangle> = tris
        .iter()
        .filter(is_leaf)
        .map(|t| {
            #[expect(clippy::cast_possible_truncation, reason = "a block holds few trees")]
            let tree = material_keys[t.material as usize].0 as u32;
            LeafTriangle { v: t.v, material: t.material, tree }
        })
        .collect();
    let occlusion: Vec<f32> = vertex_ao
        .map_or_else(Vec::new, |ao| tris.iter().filter(is_leaf).map(|t| triangle_occlusion(ao, t.v)).collect());
    build_impostors(&ImpostorMesh { vertices, triangles: &leaves, surfaces: &surfaces, occlusion: &occlusion }, config)
}

/// The leaf ellipsoids of a block's leaf-class triangles ([`crate::ellipsoid`]): each triangle
/// with its material's alpha test and its colour as Gilet's leaf points take it (texture × factor
/// × vertex colour over the texels that pass). Reads the gathered triangles (global vertex ids,
/// parts); the cells' `leaf_triangles` are returned as indices into `tris`.
#[expect(clippy::too_many_arguments, reason = "the stage reads the build's arrays")]
fn block_ellipsoids(
    material_keys: &[(usize, usize, Class)],
    tris: &[Tri],
    vertices: &[VertexRecord],
    parts: &[PartRef],
    trees: &[Placed<'_>],
    cell_of: impl Fn(Vec3) -> usize + Sync,
    cell_count: usize,
    config: &EllipsoidConfig,
) -> Result<Ellipsoids, BuildError> {
    let input = PruneInput::new(material_keys, tris, trees);
    let colours: Vec<Vec4> =
        input.leaf_ids.par_iter().map(|&i| leaf_point(&tris[i as usize], vertices, parts, trees).color).collect();
    let mesh = EllipsoidMesh { vertices, triangles: &input.leaves, alphas: &input.alphas, colours: &colours };
    let mut built = build_ellipsoids(&mesh, cell_of, cell_count, config)?;
    // The leaves' triangles as indices into `tris` (the ambient-occlusion stage reads them).
    for cell in &mut built.cells {
        for t in cell.leaf_triangles.iter_mut().flatten() {
            *t = input.leaf_ids[*t as usize];
        }
    }
    Ok(built)
}

/// Grows `cell`'s bounds to hold `bounds` (those of records about to be added; nothing for
/// `None`); a cell with no records yet takes them as they are.
fn grow_bounds(cell: &mut CellRecord, bounds: Option<(Vec3, Vec3)>) {
    if let Some((lo, hi)) = bounds {
        let (lo, hi) = if cell.is_empty() {
            (lo, hi)
        } else {
            (lo.min(Vec3::from_array(cell.bounds_min)), hi.max(Vec3::from_array(cell.bounds_max)))
        };
        cell.bounds_min = lo.to_array();
        cell.bounds_max = hi.to_array();
    }
}

/// The branch lines of a block's bark ([`crate::lines`]): every triangle not of the leaf class,
/// with its colour as Gilet's points take it (texture × factor × vertex colour). The cells'
/// `segment_triangles` are returned as indices into `tris`.
#[expect(clippy::too_many_arguments, reason = "the stage reads the build's arrays")]
fn block_lines(
    material_keys: &[(usize, usize, Class)],
    tris: &[Tri],
    vertices: &[VertexRecord],
    parts: &[PartRef],
    trees: &[Placed<'_>],
    cell_of: impl Fn(Vec3) -> usize + Sync,
    cell_count: usize,
    config: &LineConfig,
) -> Result<Lines, BuildError> {
    #[expect(clippy::cast_possible_truncation, reason = "fewer than 2^32 triangles (checked via vertex count)")]
    let bark: Vec<u32> = (0..tris.len() as u32)
        .filter(|&i| material_keys[tris[i as usize].material as usize].2 != Class::Leaf)
        .collect();
    let triangles: Vec<[u32; 3]> = bark.iter().map(|&i| tris[i as usize].v).collect();
    let colours: Vec<Vec4> =
        bark.par_iter().map(|&i| leaf_point(&tris[i as usize], vertices, parts, trees).color).collect();
    let mesh = LineMesh { vertices, triangles: &triangles, colours: &colours };
    let mut built = build_lines(&mesh, cell_of, cell_count, config)?;
    for cell in built.cells.iter_mut().chain(std::iter::once(&mut built.far)) {
        for t in cell.segment_triangles.iter_mut().flatten() {
            *t = bark[*t as usize];
        }
    }
    Ok(built)
}

/// The ambient occlusion of one cell's line records, encoded (spec §6.14): the mean of the
/// occlusion of the bark triangles of the line's source segments (each its corners' mean),
/// weighted by area. `vertex_ao` is indexed by the written vertex ids that `tris` hold by now.
fn line_occlusion(cell: &CellLines, tris: &[Tri], vertex_ao: &[f32]) -> Vec<u8> {
    let items = |segments: &[Vec<u32>]| -> Vec<(f32, f32)> {
        segments
            .iter()
            .flatten()
            .map(|&id| {
                let t = &tris[id as usize];
                (triangle_occlusion(vertex_ao, t.v), t.size * t.size)
            })
            .collect()
    };
    cell.records
        .iter()
        .map(|l| {
            let run = l.leaf_first as usize..(l.leaf_first + l.leaf_count) as usize;
            let items = items(cell.segment_triangles.get(run).unwrap_or_default());
            // Degenerate triangles only: each counts equally.
            let weightless = items.iter().all(|&(_, w)| w == 0.0);
            encode_ao(mean_occlusion(items.into_iter().map(|(ao, w)| (ao, if weightless { 1.0 } else { w }))))
        })
        .collect()
}

/// Each triangle's coverage, the byte its leaf point stores as its alpha (spec §6.5; [`opacity`]
/// gives the share): the opaque share of its texture, what a ray through it loses. Taken before
/// the per-cell stage builds the points, from the same integration ([`leaf_point`]); opaque
/// materials cover all.
fn triangle_coverage(tris: &[Tri], vertices: &[VertexRecord], parts: &[PartRef], trees: &[Placed<'_>]) -> Vec<u8> {
    tris.par_iter()
        .map(|t| {
            if parts[t.part as usize].material.alpha_mode == AlphaMode::Opaque {
                return u8::MAX;
            }
            let alpha = leaf_point(t, vertices, parts, trees).color.w;
            (pack::rgba8([0.0, 0.0, 0.0, alpha]) >> 24) as u8
        })
        .collect()
}

/// The share of a triangle's area a coverage byte of [`triangle_coverage`] stands for.
fn opacity(coverage: u8) -> f32 {
    f32::from(coverage) / 255.0
}

/// The ambient occlusion of the gathered vertices ([`crate::ambient`]), and each triangle's
/// coverage ([`triangle_coverage`]): what a ray through it loses. A triangle gathers light on
/// both faces where its material is two-sided. `progress` is told the vertices done.
fn gathered_occlusion(
    tris: &[Tri],
    vertices: &[VertexRecord],
    parts: &[PartRef],
    material_keys: &[(usize, usize, Class)],
    trees: &[Placed<'_>],
    config: &AoConfig,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> (Vec<f32>, Vec<u8>) {
    let two_sided = |t: &Tri| {
        let (tree, material, _) = material_keys[t.material as usize];
        trees[tree].scene.materials.get(material).is_some_and(|m| m.double_sided)
    };
    let coverage = triangle_coverage(tris, vertices, parts, trees);
    let rays: Vec<AoTriangle> = tris
        .iter()
        .zip(&coverage)
        .map(|(t, &c)| AoTriangle { v: t.v, opacity: opacity(c), two_sided: two_sided(t) })
        .collect();
    (vertex_occlusion(vertices, &rays, config, progress), coverage)
}

/// Each point's ambient occlusion, encoded: the mean of its leaves' (their triangles' corners'
/// mean), weighted by their opaque area. A cell's triangles are `order[cell.triangles]`, each
/// with its leaf id in `part` and the written vertex ids that `vertex_ao` is indexed by.
fn point_occlusion(
    tris: &[Tri],
    order: &[u32],
    points: &[PointRecord],
    cells: &[CellRecord],
    vertex_ao: &[f32],
    coverage: &[u8],
) -> Vec<u8> {
    // Per cell, each leaf's (occlusion × weight, weight) in leaf order, then each point's run.
    let mut point_ao = vec![0u8; points.len()];
    for cell in cells {
        let mut by_leaf = vec![(0.0f32, 0.0f32); cell.triangles.count as usize];
        for &id in &order[cell.triangles.as_usize()] {
            let t = &tris[id as usize];
            let weight = t.size * t.size * opacity(coverage[id as usize]);
            if let Some(slot) = by_leaf.get_mut(t.part as usize) {
                *slot = (triangle_occlusion(vertex_ao, t.v), weight);
            }
        }
        for (i, p) in cell.points.as_usize().zip(&points[cell.points.as_usize()]) {
            let leaves = by_leaf.get(p.leaf_first as usize..(p.leaf_first + p.leaf_count) as usize).unwrap_or_default();
            // Fully transparent leaves count equally.
            let transparent = leaves.iter().all(|l| l.1 == 0.0);
            point_ao[i] =
                encode_ao(mean_occlusion(leaves.iter().map(|&(ao, w)| (ao, if transparent { 1.0 } else { w }))));
        }
    }
    point_ao
}

/// The ambient occlusion of one cell's ellipsoid records, encoded (spec §6.14): as for points,
/// the mean of the occlusion of the triangles of the ellipsoid's leaves (each its corners' mean),
/// weighted by their opaque area (`size² · α`, `α` the triangle's `coverage`); a run of fully
/// transparent leaves counts every triangle equally. `vertex_ao` is indexed by the written
/// vertex ids that `tris` hold by now.
fn ellipsoid_occlusion(cell: &CellEllipsoids, tris: &[Tri], vertex_ao: &[f32], coverage: &[u8]) -> Vec<u8> {
    // Per leaf id, its (occlusion, opaque area): the leaf's triangles' weighted mean and sum.
    let by_leaf: Vec<(f32, f32)> = cell
        .leaf_triangles
        .iter()
        .map(|triangles| {
            let items = || {
                triangles.iter().map(|&id| {
                    let t = &tris[id as usize];
                    (
                        triangle_occlusion(vertex_ao, t.v),
                        t.size * t.size * coverage.get(id as usize).copied().map_or(1.0, opacity),
                    )
                })
            };
            let weight: f32 = items().map(|(_, w)| w).sum();
            let mean =
                if weight > 0.0 { mean_occlusion(items()) } else { mean_occlusion(items().map(|(ao, _)| (ao, 1.0))) };
            (mean, weight)
        })
        .collect();
    cell.records
        .iter()
        .map(|e| {
            let leaves = by_leaf.get(e.leaf_first as usize..(e.leaf_first + e.leaf_count) as usize).unwrap_or_default();
            let transparent = leaves.iter().all(|l| l.1 == 0.0);
            encode_ao(mean_occlusion(leaves.iter().map(|&(ao, w)| (ao, if transparent { 1.0 } else { w }))))
        })
        .collect()
}

/// Appends a baked atlas (impostors, billboards) to `images` and its texels to `image_data`, on a
/// 16-byte boundary; returns its index in `IMAGES`.
fn push_atlas(images: &mut Vec<ImageRecord>, image_data: &mut Vec<u8>, atlas: &Atlas) -> u32 {
    image_data.resize(image_data.len().div_ceil(16) * 16, 0);
    #[expect(clippy::cast_possible_truncation, reason = "images are few")]
    let index = images.len() as u32;
    images.push(ImageRecord {
        width: atlas.width,
        height: atlas.height,
        mip_count: atlas.mip_count,
        format: atlas.format,
        data_offset: image_data.len() as u64,
        data_length: atlas.texels.len() as u64,
    });
    image_data.extend_from_slice(&atlas.texels);
    index
}

/// How each output material looks, for the bakes: its source material and image.
fn surfaces<'a>(
    material_keys: &[(usize, usize, Class)],
    trees: &[Placed<'a>],
    default_material: &'a Material,
) -> Vec<Surface<'a>> {
    material_keys
        .iter()
        .map(|&(t, m, _)| {
            let scene = trees[t].scene;
            let material = scene.materials.get(m).unwrap_or(default_material);
            Surface { material, image: material.image.and_then(|i| scene.images.get(i)) }
        })
        .collect()
}

/// The baseline billboards and octahedral impostors of a block ([`crate::billboard`]): every
/// triangle of each tree, bark and leaves, baked with its source material, at `budget` texels per
/// tree, the octahedral impostors as `octahedral` says; the impostors' occlusion from
/// `vertex_ao` where there is some.
fn block_billboards(
    material_keys: &[(usize, usize, Class)],
    tris: &[Tri],
    vertices: &[VertexRecord],
    vertex_ao: Option<&[f32]>,
    trees: &[Placed<'_>],
    budget: &[u64],
    octahedral: &OctahedralConfig,
) -> Result<Option<Billboards>, BuildError> {
    let default_material = Material::default();
    let surfaces = surfaces(material_keys, trees, &default_material);
    let all: Vec<LeafTriangle> = tris
        .iter()
        .map(|t| {
            #[expect(clippy::cast_possible_truncation, reason = "a block holds few trees")]
            let tree = material_keys[t.material as usize].0 as u32;
            LeafTriangle { v: t.v, material: t.material, tree }
        })
        .collect();
    #[expect(clippy::cast_possible_truncation, reason = "a block holds few trees")]
    let tree_count = trees.len() as u32;
    let occlusion: Vec<f32> =
        vertex_ao.map_or_else(Vec::new, |ao| tris.iter().map(|t| triangle_occlusion(ao, t.v)).collect());
    build_billboards(
        &ImpostorMesh { vertices, triangles: &all, surfaces: &surfaces, occlusion: &occlusion },
        tree_count,
        budget,
        Some(octahedral),
    )
}

/// What the per-cell stage hands to the serial one.
struct CellOutput {
    /// The cell's triangles, largest first: (triangle id, leaf id).
    order: Vec<(u32, u32)>,
    /// Its points in SPT order.
    points: Vec<PointRecord>,
    /// Each point's `POINT_FACING` byte.
    facing: Vec<u8>,
    /// Bounds of the points' discs.
    bounds: (Vec3, Vec3),
}

/// Builds one cell: its leaf points, their hierarchy, and its triangles in size order.
fn cell_output(
    ids: &[u32],
    tris: &[Tri],
    vertices: &[VertexRecord],
    parts: &[PartRef],
    trees: &[Placed<'_>],
    config: &GiletConfig,
) -> Result<CellOutput, FlattenError> {
    let leaves: Vec<LeafPoint> = ids.iter().map(|&i| leaf_point(&tris[i as usize], vertices, parts, trees)).collect();
    let hierarchy = build_cell(&leaves, config)?;
    drop(leaves);
    let mut order: Vec<(u32, u32)> =
        ids.iter().zip(&hierarchy.leaf_of_triangle).map(|(&id, &leaf)| (id, leaf)).collect();
    order.sort_by(|a, b| tris[b.0 as usize].size.total_cmp(&tris[a.0 as usize].size).then(a.1.cmp(&b.1)));
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let points = hierarchy
        .points
        .iter()
        .map(|p| {
            lo = lo.min(p.position - p.radius);
            hi = hi.max(p.position + p.radius);
            point_record(p)
        })
        .collect();
    let facing = hierarchy.points.iter().map(|p| encode_point_facing(p.facing)).collect();
    Ok(CellOutput { order, points, facing, bounds: (lo, hi) })
}

/// Moves item `i` to `dest[i]` for every `i`, in place, by `swap(i, j)` calls (of every array
/// that holds the items, so that several are permuted alike); `dest` is a permutation of the
/// indices. Each swap puts one item in its place, so this takes at most `n` swaps.
fn scatter_in_place(mut dest: Vec<u32>, mut swap: impl FnMut(usize, usize)) {
    for i in 0..dest.len() {
        loop {
            let j = dest[i] as usize;
            if j == i {
                break;
            }
            swap(i, j);
            dest.swap(i, j);
        }
    }
}

/// The written triangle records: `tris` (each with its leaf in `part`) in the order of `order`
/// (triangle ids, a permutation). Reuses the memory of `tris` (a [`Tri`] and a [`TriangleRecord`]
/// are both 24 bytes), so the triangles are never held twice.
fn triangle_records(mut tris: Vec<Tri>, order: &[u32]) -> Vec<TriangleRecord> {
    let mut dest = vec![0u32; tris.len()];
    for (k, &id) in order.iter().enumerate() {
        #[expect(clippy::cast_possible_truncation, reason = "fewer than 2^32 triangles")]
        let k = k as u32;
        dest[id as usize] = k;
    }
    scatter_in_place(dest, |i, j| tris.swap(i, j));
    // Field by field the same layout: `v` becomes `indices`, `part` (holding the leaf) `leaf`.
    bytemuck::allocation::cast_vec(tris)
}

fn centroid(vertices: &[VertexRecord], t: &Tri) -> Vec3 {
    let [a, b, c] = t.v.map(|v| Vec3::from_array(vertices[v as usize].position));
    (a + b + c) / 3.0
}

/// The point of one triangle (Gilet 2005 §4): centroid, equal-area size, unit normal, and the
/// colour and coverage of its texture integrated over it.
fn leaf_point(t: &Tri, vertices: &[VertexRecord], parts: &[PartRef], trees: &[Placed<'_>]) -> LeafPoint {
    let [a, b, c] = t.v.map(|v| Vec3::from_array(vertices[v as usize].position));
    let cross = (b - a).cross(c - a);
    let area = 0.5 * cross.length();
    let part = &parts[t.part as usize];
    let local = t.v.map(|v| (v - part.base) as usize);
    let surface = TriangleSurface {
        // The vertex records hold the part's texture coordinates unchanged ([0, 0] without).
        uv: t.v.map(|v| Vec2::from_array(vertices[v as usize].uv)),
        color: local.map(|i| Vec4::from_array(part.colors.get(i).copied().unwrap_or([1.0; 4]))),
    };
    LeafPoint {
        position: (a + b + c) / 3.0,
        normal: cross / (2.0 * area),
        area,
        color: integrate(&part.material, part.image.and_then(|(tree, i)| trees[tree].scene.images.get(i)), &surface),
        size: t.size,
    }
}

fn point_record(p: &CellPoint) -> PointRecord {
    let rgb = p.color.truncate().to_array().map(linear_to_srgb);
    PointRecord {
        position: p.position.to_array(),
        radius: p.radius,
        normal: pack::oct_encode(p.normal.to_array()),
        color: pack::rgba8([rgb[0], rgb[1], rgb[2], p.color.w]),
        size: p.size,
        lo: p.lo,
        hi: p.hi,
        leaf_first: p.leaf_first,
        leaf_count: p.leaf_count,
        flags: 0,
    }
}

#[expect(clippy::cast_possible_truncation, reason = "record counts fit u32 (checked by the writer)")]
fn range(first: usize, end: usize) -> Range {
    Range { first: first as u32, count: (end - first) as u32 }
}

#[cfg(test)]
mod tests {
    use super::{Tri, scatter_in_place, triangle_records};

    #[test]
    fn scattering_moves_each_item_to_its_destination() {
        // A permutation of several cycles, a fixed point among them.
        let dest = vec![3u32, 0, 4, 1, 2, 5, 7, 6];
        let mut items: Vec<char> = "abcdefgh".chars().collect();
        scatter_in_place(dest.clone(), |i, j| items.swap(i, j));
        for (i, &d) in dest.iter().enumerate() {
            assert_eq!(items[d as usize], "abcdefgh".as_bytes()[i] as char);
        }
    }

    #[test]
    fn triangle_records_follow_the_written_order_with_their_leaves() {
        let tri = |id: u32| Tri { v: [id, id + 1, id + 2], size: id as f32, part: 10 + id, material: id % 2 };
        let tris: Vec<Tri> = (0..5).map(tri).collect();
        let order = [2u32, 4, 0, 1, 3];
        let records = triangle_records(tris, &order);
        for (record, &id) in records.iter().zip(&order) {
            assert_eq!(record.indices, [id, id + 1, id + 2]);
            assert_eq!(record.size.to_bits(), (id as f32).to_bits());
            assert_eq!((record.leaf, record.material), (10 + id, id % 2));
        }
    }
}
