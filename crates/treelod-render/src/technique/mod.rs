//! What each representation owns in the renderer, and the one place they are listed.
//!
//! A representation is a module here (or a group of techniques sharing one): the records it
//! uploads (never a file record with a field reused for other data unless the module says so),
//! its bind group (group 3 of its pipelines: its buffers and textures, made by its `upload`), and
//! the shader stages of its draw buckets (its WGSL lies in `shaders/tree/<name>.wgsl`). Its
//! per-frame selection lives in the runtime (`treelod_runtime::{prune, impostor, ellipsoid,
//! baseline}::select`), which lists its draws in [`TreeDraws`]. This file joins them to the
//! renderer's core: the draw buckets ([`Bucket`], one pipeline each) with their stages and
//! group layouts, where each kind of draw ([`DrawSource`]) goes and what it counts as, and the
//! list of the representations' uploads ([`upload_groups`]). The core (`crate::draws`,
//! `crate::pipelines`, `crate::upload`, `crate::renderer`) names no representation.
//!
//! The sequential point tree, the full mesh and pruned trees own no group: their triangles and
//! points stream into the pool (group 0), and the whole-triangle list that pruned leaves, bark
//! and the LoD chain's levels are drawn from is the model's (group 1, `crate::upload`).

pub(crate) mod baselines;
pub(crate) mod ellipsoids;
pub(crate) mod impostors;

use treelod_runtime::{PrefixDraw, Primitive, TreeDraws};

use crate::renderer::RenderError;
use crate::upload::ModelUpload;

/// Where a recorded draw reads its elements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DrawSource {
    /// The leading `count` triangles of the cell's range (resident in the pool).
    Triangles,
    /// The leading `count` points of the cell's range (resident in the pool).
    Points,
    /// The cell's roots, from the model's pinned copy of the roots: the cell's points are not
    /// resident yet, or (for [`treelod_runtime::ROOTS_CELL`]) a far tree drawn with one range.
    Roots,
    /// The leading `count` triangles of the cell's pruned leaves (a pruned tree, uploaded whole
    /// at [`Renderer::add_model`](crate::Renderer::add_model)).
    PrunedLeaves,
    /// All `count` bark triangles of the model (a pruned tree or one drawn with impostors;
    /// `cell` is [`treelod_runtime::ROOTS_CELL`]).
    Bark,
    /// The leading `count` impostor planes of the cell's range (uploaded whole at
    /// [`Renderer::add_model`](crate::Renderer::add_model)); `tau_points` is the `τ` the shader
    /// tests them with.
    Planes,
    /// A baseline LoD chain level (or the full mesh) of the whole block (`cell` is
    /// [`treelod_runtime::ROOTS_CELL`]); `tau_points` is the instance's `τ`, `tau_triangles` the
    /// level's error (0 for the full mesh).
    LodLevel,
    /// Baseline billboard quads of the block (`cell` is [`treelod_runtime::ROOTS_CELL`]).
    Billboards,
    /// Baseline octahedral impostors of the block, a quad each (`cell` is
    /// [`treelod_runtime::ROOTS_CELL`]).
    Octahedral,
    /// The leading `count` ellipsoids of the cell's range (uploaded whole at
    /// [`Renderer::add_model`](crate::Renderer::add_model)); `tau_points` is the `τ` (metres per
    /// pixel) the shader tests them with.
    Ellipsoids,
    /// The leading `count` branch lines of the cell's range (uploaded whole at
    /// [`Renderer::add_model`](crate::Renderer::add_model)); `tau_points` is the `τ` (metres per
    /// pixel) the shader tests them with.
    Lines,
}

impl DrawSource {
    /// The kind of primitive each of the draw's `count` elements is, as frame statistics count
    /// it.
    #[must_use]
    pub const fn primitive(self) -> Primitive {
        match self {
            Self::Triangles | Self::PrunedLeaves | Self::Bark | Self::LodLevel => Primitive::Triangle,
            Self::Points | Self::Roots => Primitive::Point,
            Self::Planes => Primitive::Plane,
            Self::Billboards | Self::Octahedral => Primitive::Billboard,
            Self::Ellipsoids => Primitive::Ellipsoid,
            Self::Lines => Primitive::Line,
        }
    }

    /// The bucket the draw is recorded into.
    pub(crate) const fn bucket(self) -> Bucket {
        match self {
            Self::Triangles => Bucket::Triangles,
            Self::Points | Self::Roots => Bucket::Points,
            Self::PrunedLeaves | Self::Bark | Self::LodLevel => Bucket::Pruned,
            Self::Planes => Bucket::Planes,
            Self::Billboards => Bucket::Billboards,
            Self::Octahedral => Bucket::Octahedral,
            Self::Ellipsoids => Bucket::Ellipsoids,
            Self::Lines => Bucket::Lines,
        }
    }

    /// Vertices drawn per element: 3 for a triangle, 6 (two triangles) for a splat or a quad.
    pub(crate) const fn corners(self) -> u32 {
        match self.primitive() {
            Primitive::Triangle => 3,
            Primitive::Point | Primitive::Plane | Primitive::Billboard | Primitive::Ellipsoid | Primitive::Line => 6,
        }
    }
}

/// The runtime's lists of draws that are prefixes of one cell's elements of a kind uploaded whole
/// (the level chosen in the shader by `τ`), each with what it draws.
pub(crate) fn prefix_lists(draws: &TreeDraws) -> [(&[PrefixDraw], DrawSource); 3] {
    [
        (&draws.planes, DrawSource::Planes),
        (&draws.ellipsoids, DrawSource::Ellipsoids),
        (&draws.lines, DrawSource::Lines),
    ]
}

/// A draw bucket of a model: one pipeline's draws, drawn in this order. A frame's buckets are
/// listed per model, [`Bucket::COUNT`] each ([`Bucket::of_model`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Bucket {
    /// Streamed triangles, from the pool.
    Triangles,
    /// Streamed points and the pinned roots, from the pool.
    Points,
    /// Pruned leaves and bark, and LoD chain levels, from each model's whole-triangle list.
    Pruned,
    /// Impostor planes ([`impostors`]).
    Planes,
    /// Baseline billboards ([`baselines`]).
    Billboards,
    /// Baseline octahedral impostors ([`baselines`]).
    Octahedral,
    /// Clasen's ellipsoids, ray-cast ([`ellipsoids`]).
    Ellipsoids,
    /// Clasen's branch lines, ray-cast round cones ([`ellipsoids`]).
    Lines,
}

impl Bucket {
    /// Draw buckets per model.
    pub(crate) const COUNT: usize = 8;

    /// Every bucket, in drawing order (`ALL[b as usize] == b`).
    pub(crate) const ALL: [Self; Self::COUNT] = [
        Self::Triangles,
        Self::Points,
        Self::Pruned,
        Self::Planes,
        Self::Billboards,
        Self::Octahedral,
        Self::Ellipsoids,
        Self::Lines,
    ];

    /// The index of model `model`'s bucket in a frame's list of buckets.
    pub(crate) fn of_model(self, model: usize) -> usize {
        Self::COUNT * model + self as usize
    }

    /// What the bucket is drawn with.
    pub(crate) const fn stages(self) -> Stages {
        match self {
            Self::Triangles => TRIANGLES,
            Self::Points => POINTS,
            Self::Pruned => PRUNED,
            Self::Planes => impostors::STAGES,
            Self::Billboards => baselines::STAGES,
            Self::Octahedral => baselines::OCTAHEDRAL_STAGES,
            Self::Ellipsoids => ellipsoids::ELLIPSOID_STAGES,
            Self::Lines => ellipsoids::LINE_STAGES,
        }
    }

    /// The entries of the bucket's own bind group (group 3), if it has one: the buffers and
    /// textures of its representation, as its module uploads them.
    pub(crate) const fn group_entries(self) -> Option<&'static [wgpu::BindGroupLayoutEntry]> {
        match self {
            Self::Triangles | Self::Points | Self::Pruned => None,
            Self::Planes | Self::Billboards | Self::Octahedral => Some(impostors::GROUP),
            Self::Ellipsoids => Some(ellipsoids::ELLIPSOID_GROUP),
            Self::Lines => Some(ellipsoids::LINE_GROUP),
        }
    }
}

/// The representations' bind groups of one model (group 3, per bucket; `None` where the bucket
/// has no group or the model draws nothing in it), uploaded by each representation's module. A
/// representation whose data cannot be drawn (an atlas that does not decode or fit) takes itself
/// out of `up`'s [`Representations`](treelod_runtime::Representations) and says why in its
/// warnings.
pub(crate) fn upload_groups(up: &mut ModelUpload<'_>) -> Result<[Option<wgpu::BindGroup>; Bucket::COUNT], RenderError> {
    let mut groups = [const { None }; Bucket::COUNT];
    groups[Bucket::Planes as usize] = impostors::upload(up)?;
    let (billboards, octahedral) = baselines::upload(up)?;
    groups[Bucket::Billboards as usize] = billboards;
    groups[Bucket::Octahedral as usize] = octahedral;
    let (ellipsoids, lines) = ellipsoids::upload(up)?;
    groups[Bucket::Ellipsoids as usize] = ellipsoids;
    groups[Bucket::Lines as usize] = lines;
    Ok(groups)
}

/// The shader stages of one bucket's pipelines and the WGSL they come from.
#[derive(Clone, Copy)]
pub(crate) struct Stages {
    /// The shader module's label.
    pub(crate) module: &'static str,
    /// The module's WGSL (`tree_wgsl!`).
    pub(crate) wgsl: &'static str,
    /// The vertex stage, shared by the colour and shadow pipelines.
    pub(crate) vs: &'static str,
    /// The colour pass's fragment stage and pipeline label.
    pub(crate) fs: &'static str,
    pub(crate) label: &'static str,
    /// The shadow pass's fragment stage and pipeline label.
    pub(crate) shadow_fs: &'static str,
    pub(crate) shadow_label: &'static str,
}

/// The WGSL of a tree pipeline: the record structs, the draw constants and the shadow receivers
/// (`shaders/shared/`), the tree shaders' common part, then the named files of `shaders/tree/`.
macro_rules! tree_wgsl {
    ($($file:literal),+) => {
        concat!(
            include_str!("../../../../shaders/shared/records.wgsl"),
            include_str!("../../../../shaders/shared/draw.wgsl"),
            include_str!("../../../../shaders/shared/shadow.wgsl"),
            include_str!("../../../../shaders/tree/common.wgsl"),
            $(include_str!(concat!("../../../../shaders/tree/", $file))),+
        )
    };
}
pub(crate) use tree_wgsl;

/// A storage buffer entry of a bind group layout, read only.
pub(crate) const fn storage(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A texture entry of a bind group layout, sampled in the fragment stage.
pub(crate) const fn texture(
    binding: u32,
    sample_type: wgpu::TextureSampleType,
    view_dimension: wgpu::TextureViewDimension,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture { sample_type, view_dimension, multisampled: false },
        count: None,
    }
}

/// A sampler entry of a bind group layout, used in the fragment stage.
pub(crate) const fn sampler(binding: u32, ty: wgpu::SamplerBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Sampler(ty),
        count: None,
    }
}

/// The streamed triangles of the point tree and the full mesh.
const TRIANGLES: Stages = Stages {
    module: "treelod tree/triangles.wgsl",
    wgsl: tree_wgsl!("triangles.wgsl"),
    vs: "vs_triangle",
    fs: "fs_triangle",
    label: "treelod triangles",
    shadow_fs: "fs_shadow_triangle",
    shadow_label: "treelod shadow triangles",
};

/// The streamed points of the point tree, and the pinned roots.
const POINTS: Stages = Stages {
    module: "treelod tree/points.wgsl",
    wgsl: tree_wgsl!("points.wgsl"),
    vs: "vs_point",
    fs: "fs_point",
    label: "treelod points",
    shadow_fs: "fs_shadow_point",
    shadow_label: "treelod shadow points",
};

/// Pruned leaves, bark and LoD chain levels: the triangles' fragment stages.
const PRUNED: Stages = Stages {
    module: "treelod tree/pruned.wgsl",
    wgsl: tree_wgsl!("triangles.wgsl", "pruned.wgsl"),
    vs: "vs_pruned",
    fs: "fs_triangle",
    label: "treelod pruned leaves and bark",
    shadow_fs: "fs_shadow_triangle",
    shadow_label: "treelod shadow pruned leaves and bark",
};
