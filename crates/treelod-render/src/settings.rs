//! The public settings of the renderer: the host's target formats and depth convention, and the
//! level-of-detail, technique and shading [`Settings`] with their parts ([`Pruning`],
//! [`ImpostorBark`], [`DebugView`]).

use glam::Vec3;
use treelod_runtime::spt_lod::PixelLevel;
use treelod_runtime::{Light, Policy, PruneScale, Technique};

use crate::shadows::Shadows;
#[cfg(doc)]
use crate::{FrameStats, Renderer};
#[cfg(doc)]
use treelod_runtime::LodSettings;

/// The target formats of the host's render pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RendererFormats {
    /// Colour attachment format.
    pub color: wgpu::TextureFormat,
    /// Depth attachment format (depth-tested, depth-written).
    pub depth: wgpu::TextureFormat,
    /// MSAA samples of both attachments (1 for none). With more than one, alpha-tested leaves
    /// write a sample mask from their filtered alpha where their texture is minified (alpha to
    /// coverage), keeping a distant canopy's density; the host resolves the colour target.
    pub sample_count: u32,
}

/// Which way the host's depth buffer runs: the depth test of the pipelines drawing into it, fixed
/// when the [`Renderer`] is made ([`Renderer::with_depth_convention`]).
///
/// The depth written is always the camera projection's `z / w`, so the projection decides the
/// values ([`Camera::proj`](crate::Camera::proj)); the convention says which of two depths is
/// nearer. Neither the shadow maps (the renderer's own) nor selection depend on it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum DepthConvention {
    /// 0 at the near plane, 1 at the far plane: the host clears depth to 1, and a fragment is
    /// kept where its depth is `Less` than the buffer's. What
    /// [`Camera::look_at`](crate::Camera::look_at) projects to, and [`Renderer::new`]'s.
    #[default]
    Standard,
    /// Reverse Z: 1 at the near plane, 0 at the far plane (or at infinity), for depth precision
    /// far away, as Bevy and many engines draw: the host clears depth to 0, and a fragment is
    /// kept where its depth is `Greater` than the buffer's. The camera's projection must map
    /// near to 1.
    Reverse,
}

impl DepthConvention {
    /// The depth test that keeps the nearer of two fragments.
    #[must_use]
    pub fn compare(self) -> wgpu::CompareFunction {
        match self {
            Self::Standard => wgpu::CompareFunction::Less,
            Self::Reverse => wgpu::CompareFunction::Greater,
        }
    }

    /// The depth comparison that passes the nearer of two depths or an equal one: a caster
    /// drawn into a map the host's casters wrote first, and a receiver lit where it is at least
    /// as near the light as the map's caster.
    #[must_use]
    pub(crate) fn nearer_or_equal(self) -> wgpu::CompareFunction {
        match self {
            Self::Standard => wgpu::CompareFunction::LessEqual,
            Self::Reverse => wgpu::CompareFunction::GreaterEqual,
        }
    }

    /// The depth a buffer is cleared to: the far end of the range.
    #[must_use]
    pub fn far(self) -> f32 {
        match self {
            Self::Standard => 1.0,
            Self::Reverse => 0.0,
        }
    }
}

/// What a frame shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DebugView {
    /// Shaded colours.
    #[default]
    Shaded,
    /// A flat colour per grid cell.
    Cells,
    /// Triangles red, points blue.
    Kinds,
    /// A colour per level: per octave of the end of each point's, plane's, ellipsoid's or line's
    /// interval of `τ` (neighbouring levels differ), triangles light grey, billboards as in
    /// [`Self::Kinds`].
    Levels,
    /// A colour per technique a tree is drawn with ([`Self::technique_colour`]): what the policy
    /// chose for each tree (a pruned tree below its pruning height keeps pruning's colour though
    /// the point tree draws it).
    Techniques,
}

impl DebugView {
    /// The colour, linear RGB, [`Self::Techniques`] draws `technique`'s trees with
    /// ([`Technique::colour`]).
    #[must_use]
    pub const fn technique_colour(technique: Technique) -> [f32; 3] {
        technique.colour()
    }
}

/// Level-of-detail and shading settings; change them between frames with [`Renderer::settings_mut`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// `s_min`, pixels: points are drawn down to this projected size (Gilet's point threshold).
    pub s_min: f32,
    /// `s_max`, pixels: triangles projecting larger than this are drawn as triangles.
    pub s_max: f32,
    /// `k`, pixels: Gilet's depth bias, added to both thresholds times `Z_i ∈ [−1, 1]` from the
    /// front to the back of each tree ([`LodSettings::depth_bias_k`]); 0 for none.
    pub depth_bias_k: f32,
    /// `(L_m, L_M)`: Gilet's estimated self-shadowing, a brightness per cell from `L_m` at the
    /// front of each tree to `L_M` at the back as the paper writes it
    /// ([`LodSettings::shading_at`]); `None` for none.
    pub shading: Option<(f32, f32)>,
    /// Scale of the splat radii: 1 draws each point as a disc of the opaque area it stands for.
    pub point_scale: f32,
    /// How trees are drawn where [`Self::policy`] does not choose (no policy, or a container
    /// without calibration tables): one of treelod's representations, a baseline, or the full
    /// mesh ([`Technique::Full`]: every triangle and no point, for comparison). A tree whose
    /// container lacks the technique's data ([`Technique::held_by`]) is drawn with the
    /// sequential point tree ([`Technique::FALLBACK`]); [`FrameStats::instances`] counts each
    /// tree under the technique it was drawn with. Default: [`Technique::Spt`]. GPU selection
    /// ([`Renderer::enable_gpu_selection`]) selects the point tree's trees: every tree of a frame
    /// of [`Technique::Spt`] when the policy chooses none, the point tree's share of a policy
    /// frame; a frame without a policy of any other technique selects on the CPU.
    pub technique: Technique,
    /// The policy (`treelod_runtime::policy`, spec §10.2): each tree whose container has
    /// calibration tables (spec §6.15; `treelod build` writes them whenever it builds a
    /// representation besides the point tree) is drawn with the cheapest representation whose
    /// calibrated error at its projected height is within [`Policy::target`] of the least error
    /// there (spec §10.2), with hysteresis; a tree that changes representation fades from the
    /// old one to the new over [`Policy::transition`] frames, both drawn on complementary
    /// dithered pixels meanwhile ([`FrameStats::transitions`](crate::FrameStats)); a tree partly
    /// hidden behind others, as [`Renderer::measure_occlusion`] measured it after an earlier
    /// pass, is chosen with the target over the square root of its visible fraction
    /// ([`Policy::occlusion`]). Each shadow cascade chooses the same way, by default
    /// at the smaller of the tree's heights on screen and in the cascade's selection pixels
    /// ([`Shadows`]'s `casters`), so a far tree in a coarse cascade casts the shadow of a cheaper
    /// representation than it is drawn with. With [`Policy::budget`] the target and [`Self::s_min`] are
    /// steered from frame to frame so the camera's view meets that many primitives
    /// ([`Renderer::prepare`]). `None` draws every tree with [`Self::technique`] (to force one).
    /// Default: [`Policy::default`].
    pub policy: Option<Policy>,
    /// What to colour by.
    pub debug: DebugView,
    /// Direction towards the sun, world space.
    pub sun: Vec3,
    /// Colour of the sunlight, linear RGB (white: 1, 1, 1), multiplying its diffuse share.
    pub sun_colour: Vec3,
    /// Ambient share of the light, 0..1: a surface receives `ambient + (1 − ambient) · |n·l| ·
    /// sun_colour` of its albedo (both faces lit: leaves are cards).
    pub ambient: f32,
    /// Scale the ambient share by the containers' precomputed ambient occlusion `a` (spec
    /// §6.14), where they have it: `ambient · (1 − a)`. The sun's share is the shadow maps'
    /// business ([`Self::shadows`]).
    pub ambient_occlusion: bool,
    /// Bytes of triangles and points uploaded per frame at most: prefixes grow towards the
    /// selection by this much each frame, emptiest cells first.
    pub upload_budget: u64,
    /// Bytes of GPU memory for streamed triangles and points (fixed at [`Renderer::new`], and
    /// capped there by the device's storage-binding limit). When full, the finest halves of the
    /// least recently needed cells' prefixes are evicted.
    pub memory_budget: u64,
    /// With [`Technique::PruneOpt`] and [`Technique::PruneCook`] (near trees drawn with pruned
    /// leaves, Neubert et al. 2011, where their containers have priority lists): how many leaves.
    pub pruning: Pruning,
    /// With [`Technique::Impostors`] (the leaves of every tree whose container has impostor
    /// planes, Garcia et al. 2005, spec §6.10, drawn as those planes, its bark as
    /// [`Self::impostor_bark`] says; the level of planes is the one whose interval holds `τ` from
    /// [`Self::s_min`] pixels at the block centre's distance, as the point thresholds are chosen,
    /// spec §10.1): smooth changes of level. Garcia's interpolation of the planes:
    /// over the last octave of each plane's interval its corners slide onto the plane of the next
    /// coarser level, which takes over where they arrive ([`treelod_runtime::morph_share`]), so a
    /// change of level moves no leaf. And a cross-fade of the textures: over the last quarter of
    /// the interval the plane and its parent are drawn on complementary dithered pixels
    /// ([`treelod_runtime::crossfade`]). `false` switches levels at once.
    pub impostor_morph: bool,
    /// With [`Technique::Impostors`]: the bark drawn beside the planes. Default
    /// [`ImpostorBark::Lines`]: the branch lines where the container has them, else the LoD
    /// chain's bark at the level `s_min` allows, else every bark triangle.
    pub impostor_bark: ImpostorBark,
    /// With [`Technique::Ellipsoids`] (the leaves of every tree whose container has Clasen's
    /// ellipsoids, spec §6.8, ray-cast per pixel with their noise, its bark as Clasen's lines,
    /// spec §6.9, [`Self::lines`], where the container has them, else as triangles — every bark
    /// triangle, as [`ImpostorBark::All`]; per cell, the level drawn is the one whose interval
    /// holds `τ`, the metres per pixel at the cell's distance — the point threshold's
    /// `τ_p / s_min`, Gilet's depth bias included — divided by this quality, blended with the
    /// next over [`Self::level_blend`]; lines use the same `τ`): the user's quality factor `q`, `τ = mpp / q` (1: the level the
    /// build chose for the pixel size; 2: the level for pixels half as large, finer).
    pub ellipsoid_quality: f32,
    /// With [`Technique::Ellipsoids`]: `β`, octaves of `τ` over which ellipsoids and lines blend from
    /// one level to the next instead of switching at once (Clasen 2011 §5: the levels are close
    /// enough for image-space blending). An element of interval `[lo, hi)` fades in over `β`
    /// octaves centred on `lo` and out over `β` octaves centred on `hi`: it is drawn on the share
    /// `clamp(log2(τ/lo)/β + ½, 0, 1) · clamp(log2(hi/τ)/β + ½, 0, 1)` of its pixels (no fade at
    /// `lo = 0` or `hi = ∞`), chosen by a per-pixel dither of the cell and instance that is the
    /// same for both levels at a boundary (the samples of each pixel with MSAA), so each pixel
    /// shows exactly one of them: no doubled density, no holes
    /// ([`treelod_runtime::spt_lod::level_keep`]). Exact where adjacent boundaries are at least
    /// `β` octaves apart. The prefix drawn holds the records with `hi > τ · 2^(−β/2)`. Colour and
    /// shadow passes alike. 0 switches at once; clamped to `[0, 2]` (not finite: 0). Default 0.5.
    pub level_blend: f32,
    /// With [`Technique::Ellipsoids`]: draw the bark of ellipsoid trees as Clasen's lines when the
    /// container has them (spec §6.9); `false`: bark triangles. Each line is a round cone (a
    /// capsule whose radius goes linearly from `r0` to `r1`), ray-cast per pixel with its exact
    /// depth. Lines thinner than a pixel (Clasen's build aims at a mean width of one) are drawn
    /// one pixel wide, which leaves no gaps along them, covering the share of each pixel their
    /// true width `w < 1` px asks for: `w` of the samples with MSAA, else of the pixels (a hash of
    /// pixel and depth), at the depth of their axis.
    pub lines: bool,
    /// Cascaded shadow maps of the sun ([`Shadows`]); `None` for none. With shadows, each frame
    /// also selects every cascade from the light's view (on the CPU, also when GPU selection is
    /// on) and [`Renderer::render_shadows`] draws them before the host's pass.
    pub shadows: Option<Shadows>,
    /// Without MSAA: an alpha-tested fragment whose texture is minified (a texel under a pixel)
    /// is kept where its filtered alpha — the share of its footprint the leaf covers — exceeds a
    /// hash of the pixel and depth, as the shadow pass keeps it, instead of where it passes the
    /// material's cutoff. The plain test drops every texel less than half covered, so a canopy of
    /// thin leaves thins out and vanishes with distance; this one keeps its density (expected
    /// coverage exact; overlapping leaves at other depths independent) at the cost of noise that
    /// changes as the camera moves, which a temporal anti-aliasing pass averages (with MSAA, alpha
    /// to coverage does the same per sample without it). `eval` draws its reference so. Default
    /// off.
    pub stochastic_alpha: bool,
}

/// The bark of a tree drawn with impostor planes ([`Settings::impostor_bark`]): defined by the
/// runtime, whose impostor selection draws it.
pub use treelod_runtime::ImpostorBark;
/// Pruning settings of [`Technique::PruneOpt`] and [`Technique::PruneCook`]
/// ([`Settings::pruning`]): defined by the runtime, whose pruned selection reads them; the
/// visible fraction they use is measured by [`Renderer::measure_occlusion`].
pub use treelod_runtime::Pruning;

/// How the survivors of a pruned tree are scaled with `technique`: `s_opt(λ)` from the container
/// for [`Technique::PruneOpt`], Cook's `1/λ` for [`Technique::PruneCook`]; `None` for techniques
/// that do not prune.
#[must_use]
pub fn prune_scale(technique: Technique) -> Option<PruneScale> {
    PruneScale::of(technique)
}

impl Settings {
    /// How ellipsoids and lines pick their levels: [`Self::ellipsoid_quality`] and
    /// [`Self::level_blend`].
    pub(crate) fn pixel_level(&self) -> PixelLevel {
        PixelLevel { quality: self.ellipsoid_quality, blend: self.level_blend }
    }
}

impl Settings {
    /// Whether these settings use the trees' visible fractions, which
    /// [`Renderer::measure_occlusion`] measures from a pass's depth buffer: a policy that chooses
    /// with occlusion ([`Policy::occlusion`], on by default), or pruning forced with its
    /// occlusion factor ([`Pruning::occlusion`]). A host whose depth attachment cannot be
    /// sampled makes it samplable ([`wgpu::TextureUsages::TEXTURE_BINDING`]) when this holds.
    #[must_use]
    pub fn measures_occlusion(&self) -> bool {
        self.policy.is_some_and(|p| p.occlusion) || (prune_scale(self.technique).is_some() && self.pruning.occlusion)
    }

    /// The default settings drawing every tree with `technique`, without the policy (for
    /// comparisons and tools that force one).
    #[must_use]
    pub fn forced(technique: Technique) -> Self {
        Self { technique, policy: None, ..Self::default() }
    }
}

impl Default for Settings {
    /// One-pixel points, triangles above two pixels, light from above and the side.
    fn default() -> Self {
        Self {
            s_min: 1.0,
            s_max: 2.0,
            depth_bias_k: 0.0,
            shading: None,
            point_scale: 1.0,
            technique: Technique::Spt,
            policy: Some(Policy::default()),
            debug: DebugView::Shaded,
            sun: Light::DEFAULT.sun,
            sun_colour: Light::DEFAULT.sun_colour,
            ambient: Light::DEFAULT.ambient,
            ambient_occlusion: true,
            upload_budget: 64 << 20,
            memory_budget: 1 << 30,
            pruning: Pruning::default(),
            impostor_morph: true,
            impostor_bark: ImpostorBark::default(),
            ellipsoid_quality: 1.0,
            level_blend: treelod_runtime::DEFAULT_LEVEL_BLEND,
            lines: true,
            shadows: None,
            stochastic_alpha: false,
        }
    }
}
