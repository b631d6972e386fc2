//! Draws `.treelod` containers with wgpu inside a render pass the host owns.
//!
//! The host keeps its device, queue, targets and pass; treelod adds its draws:
//!
//! ```no_run
//! # fn frame(device: &wgpu::Device, queue: &wgpu::Queue, view: &wgpu::TextureView, depth: &wgpu::TextureView) -> Result<(), Box<dyn std::error::Error>> {
//! use treelod_render::{Camera, Instance, Renderer, RendererFormats, Settings};
//!
//! let formats = RendererFormats {
//!     color: wgpu::TextureFormat::Rgba8UnormSrgb,
//!     depth: wgpu::TextureFormat::Depth32Float,
//!     sample_count: 1,
//! };
//! let mut renderer = Renderer::new(device, formats, Settings::default());
//! let container = std::sync::Arc::new(treelod_format::Container::open("tree.treelod")?);
//! let tree = renderer.add_model(device, queue, container)?;
//! renderer.set_instances(&[Instance { model: tree, transform: glam::Mat4::IDENTITY }]);
//!
//! // Every frame:
//! let camera = Camera::look_at(glam::vec3(0.0, 3.0, 15.0), glam::vec3(0.0, 3.0, 0.0), 0.8, 1280, 720);
//! let stats = renderer.prepare(device, queue, &camera);
//! let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
//! // The shadow cascades first (nothing without `Settings::shadows`).
//! renderer.render_shadows(&mut encoder);
//! {
//!     let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
//!         color_attachments: &[Some(wgpu::RenderPassColorAttachment {
//!             view,
//!             depth_slice: None,
//!             resolve_target: None,
//!             ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::WHITE), store: wgpu::StoreOp::Store },
//!         })],
//!         depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
//!             view: depth,
//!             depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
//!             stencil_ops: None,
//!         }),
//!         ..Default::default()
//!     });
//!     renderer.render(&mut pass);
//! }
//! queue.submit([encoder.finish()]);
//! let triangles = stats.submitted[treelod_render::Primitive::Triangle];
//! println!("{} primitives, {triangles} of them triangles", stats.primitives());
//! # Ok(()) }
//! ```
//!
//! The device must have [`Renderer::required_features`] (indirect draws with a first instance).
//! Ask for `wgpu::Features::TEXTURE_COMPRESSION_BC` where the adapter offers it: BC7 atlases
//! (spec §6.7) are then uploaded as stored; without it they are decoded to RGBA8 on upload
//! (four times the texture memory, same image).
//! [`offscreen`] renders to an image with no window, for tools and tests.
//!
//! **Selection on the CPU or the GPU.** By default `prepare` selects with
//! [`treelod_runtime::select_frame`] on the CPU and streams the prefixes it needs. For
//! 10^5–10^6 instances, [`Renderer::enable_gpu_selection`] moves selection into two compute
//! dispatches (`shaders/select.wgsl`): blocks of 64 instances (Morton order, a bounding sphere
//! each) are culled first, then one workgroup per visible block selects its instances as
//! `select_frame` does — frustum culling of instances and cells, Gilet's depth bias and shading,
//! the far path and the far list's single range — and appends the indirect draws into one bucket per
//! model and kind, drawn with `multi_draw_indirect_count` (ask for
//! [`Renderer::gpu_selection_features`]). `prepare` and `render` stay the same calls with O(models)
//! CPU work per frame. GPU selection keeps every model's triangles and points resident whole
//! (a model over [`Settings::memory_budget`] is refused with
//! [`RenderError::GpuSelectionBudget`]) instead of streaming; its [`FrameStats`] counts come from a
//! read-back one or two frames old ([`FrameStats::gpu_selection`]). With the policy
//! ([`Settings::policy`]) the CPU assigns the trees and selects every technique but the point
//! tree, and the GPU selects the point tree's trees (a per-instance mask of which, and on which
//! share of a transition's dither). Frames with [`Settings::shadows`], and frames of a forced
//! technique other than [`Technique::Spt`], are still selected on the CPU.
//!
//! **Impostors.** With [`Technique::Impostors`], a tree whose container has impostor planes (Garcia
//! et al. 2005, spec §6.10) draws its leaves as those fixed, alpha-tested, depth-writing quads
//! (`vs_plane`/`fs_plane` in `shaders/tree/planes.wgsl`, from the model's uploaded `PLANES` and its atlas
//! bound as a texture of its own, clamped, nearest mip) at the level whose interval holds `τ` from
//! `s_min` at the block centre's distance, sliding each plane onto its parent's and cross-fading
//! the two before a level change ([`Settings::impostor_morph`]); its bark is, by default, its
//! container's branch lines where it has them, as ellipsoid trees draw them, else the bark of its
//! LoD chain at the level `s_min` allows where it has one, else all its bark triangles
//! ([`ImpostorBark`]).
//!
//! **Ellipsoids and lines.** With [`Technique::Ellipsoids`], a tree whose container has Clasen's
//! leaf ellipsoids (spec §6.8) draws them ray-cast per pixel (`vs_ellipsoid`/`fs_ellipsoid`), per
//! cell the level whose interval holds `τ`, the metres per pixel at the cell's distance; its bark
//! is its branch lines (spec §6.9, [`Settings::lines`]) at the level the same `τ` selects, each a
//! round cone ray-cast exactly (`vs_line`/`fs_line`), lines thinner than a pixel drawn one pixel
//! wide with their width as coverage; without lines, its bark triangles.
//!
//! **Shadows.** With [`Settings::shadows`], `prepare` fits cascaded shadow maps of the sun to the
//! camera ([`fit_cascades`]: practical splits, a sphere per slice, centres snapped to whole texels
//! so shadows do not shimmer as the camera moves) and selects every cascade with the same
//! machinery as the frame, from the light's view, with a pixel of [`Shadows::lod_texels`] texels:
//! triangles, points, pruned leaves, impostor planes and baselines all cast, each at the detail
//! the map resolves, and the cascades' prefixes stream with the camera's. The host records
//! [`Renderer::render_shadows`] (one depth-only pass per cascade) before the pass that calls
//! `render`; the trees then receive shadows (3×3 taps of a comparison sampler, the finest cascade
//! holding the point), and the host's own surfaces can too, by including [`SHADOW_WGSL`] and
//! binding [`Renderer::shadow_bind_group`] as group 2, as [`Ground`] does. Sub-texel splats and
//! minified alpha-tested leaves cast stochastically by the share of the texel they cover, so a
//! distant canopy's shadow keeps its density. [`FrameStats::shadow`] counts what the shadow pass
//! draws: on the built-in 10,000-tree fly-through (`treelod bench --shadows`), with the default
//! three 2048² cascades over 150 m, 0.78× the primitives of the main pass with the point trees.
//!
//! **Host shadow maps.** An engine that renders and samples shadow maps of its own (a
//! directional light's cascades) names them with [`Renderer::set_host_shadow_views`] (each map's
//! orthographic `clip_from_world` in the renderer's depth convention, and its size); `prepare`
//! then selects the trees from each map's light view as it selects for its own cascades, and
//! [`Renderer::render_host_shadow`] draws them depth-only into map `k` in the host's pass over
//! it, with the host's matrix, so the host's receivers read the trees' depth as its own
//! casters'. [`FrameStats::host_shadow`] counts what they drew. The trees receive the host's maps
//! in place of the renderer's own with [`Renderer::receive_host_shadows`] (the host's depth
//! texture array and its cascades' matrices and layers): shadows of the host's casters fall on
//! the trees, and the trees' own on each other.

mod assign;
mod camera;
mod draws;
mod gpu_select;
mod ground;
mod noise;
mod occlusion;
pub mod offscreen;
mod pipelines;
mod renderer;
mod settings;
mod shadows;
mod sky;
mod stats;
mod streaming;
mod technique;
mod textures;
mod upload;

pub use camera::Camera;
pub use draws::RecordedDraw;
pub use gpu_select::{GpuDraw, GpuQuadDraw};
pub use ground::Ground;
pub use renderer::{Instance, ModelId, RenderError, Renderer};
pub use settings::{DebugView, DepthConvention, ImpostorBark, Pruning, RendererFormats, Settings, prune_scale};
pub use shadows::{
    Cascade, Casters, HostShadowCascade, HostShadowError, HostShadowView, MAX_CASCADES, MAX_HOST_SHADOW_VIEWS, Shadows,
    cascade_splits, fit_cascades,
};
pub use sky::Sky;
pub use stats::{BudgetFrame, FrameStats, PreparePhases, ShadowStats};
pub use technique::DrawSource;

/// WGSL for receiving the renderer's shadows in a host's own pipeline: declares group 2
/// ([`Renderer::shadow_bind_group`]) and `fn sunlit(world: vec3<f32>, normal: vec3<f32>, sun:
/// vec3<f32>) -> f32`, the share of the sun reaching a point (1 lit, 0 shadowed).
pub const SHADOW_WGSL: &str = include_str!("../../../shaders/shared/shadow.wgsl");
pub use treelod_runtime::{
    BudgetController, Hysteresis, PerPrimitive, PerTechnique, Policy, Primitive, PruneScale, Technique,
};
