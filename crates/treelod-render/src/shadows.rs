//! Shadows of a directional sun: cascaded shadow maps fitted to the view, selected by the same
//! level-of-detail machinery as the frame from the light's view (sizes in shadow-map texels), and
//! drawn depth-only from every representation.
//!
//! - **Cascades.** The view's distance range up to [`Shadows::distance`] is split between a
//!   logarithmic and a uniform spacing (Zhang et al.'s practical split scheme, weight
//!   [`Shadows::split_lambda`]). Each slice of the view frustum gets the smallest sphere around
//!   it; a cascade is an orthographic view of that sphere along the sun. The sphere's radius
//!   depends only on the camera's field of view, aspect and the splits, so a texel stays the same
//!   size while the camera moves and turns, and the sphere's centre is snapped to whole texels of
//!   a light basis fixed by the sun's direction alone: the shadows' texels do not crawl along the
//!   ground as the camera moves (no shimmering).
//! - **Casters** between the sun and a cascade's sphere are in its depth range: the range starts at
//!   the farthest point of the scene's bounds towards the sun.
//! - **Selection.** Each cascade selects with a camera whose pixel is one texel of its map at the
//!   cascade's centre ([`Cascade::selection_camera`]), so trees cast shadows at the detail the map
//!   resolves: the thresholds that pick triangles, points, pruned leaves or impostor planes on
//!   screen pick them in texels.

use glam::{Mat4, Vec3, Vec4};
use treelod_runtime::Technique;

use crate::camera::Camera;

/// The most cascades the shaders hold.
pub const MAX_CASCADES: usize = 4;

/// Distance of the eye of a cascade's [`Cascade::selection_camera`] from the cascade's centre,
/// in cascade radii plus the casters' depth: far enough that its pixel footprint varies by
/// under 0.1 % over the cascade's depth.
const SELECTION_DISTANCE: f32 = 1000.0;

/// Reference distance of the logarithmic splits, metres (the split scheme's near plane).
const SPLIT_NEAR: f32 = 1.0;

/// Shadow-map settings ([`crate::Settings::shadows`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shadows {
    /// Texels per side of each cascade's map (at most the device's largest 2D texture).
    pub resolution: u32,
    /// Cascades, 1 to [`MAX_CASCADES`].
    pub cascades: u32,
    /// Distance from the eye, metres, up to which surfaces receive shadows.
    pub distance: f32,
    /// Weight of the logarithmic splits against uniform ones, 0..1: higher gives the near
    /// cascades more of the map.
    pub split_lambda: f32,
    /// How far a receiver is moved along its normal, towards the sun, before its lookup, in
    /// texels of the cascade it falls in: against self-shadowing ("acne") of surfaces at a
    /// grazing angle to the sun, on top of the shadow pass's slope-scaled depth bias.
    pub normal_offset: f32,
    /// Texels per pixel of the cascades' level-of-detail selection: the thresholds
    /// ([`crate::Settings::s_min`], [`crate::Settings::s_max`]) are taken in units of this many
    /// texels. The receivers' filter spans 4×4 texels, so detail under two texels is blurred away
    /// anyway; 1 selects as finely as the map resolves.
    pub lod_texels: f32,
    /// What the cascades cast each tree with ([`Casters`]; default: chosen at the coarser of
    /// the camera's and the light's view).
    pub casters: Casters,
}

/// What the shadow cascades cast each tree with ([`Shadows::casters`]). The first three choose
/// as the camera's trees are chosen ([`crate::Settings::policy`], else
/// [`crate::Settings::technique`]), at different heights, each cascade with hysteresis of its own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Casters {
    /// At the smaller of the tree's heights on screen and in the cascade's selection pixels
    /// ([`Shadows::lod_texels`] texels): a tree casts no more detail than the screen shows or
    /// the map resolves. As with every choice, a cascade chooses only the trees in its own
    /// frustum: a tree the camera sees outside it casts nothing into that cascade.
    #[default]
    Coarser,
    /// From the light's view alone, at the tree's height in the cascade's selection pixels: a
    /// tree its cascade resolves more finely than the screen casts more detail than it is drawn
    /// with, a far tree in a coarse cascade less.
    LightView,
    /// What the camera draws each tree with this frame: a tree casts the shadow of what is drawn.
    CameraView,
    /// One technique for every tree, for the shadow pass alone (e.g. [`Technique::Full`], the
    /// reference a shadow's error is measured against).
    Forced(Technique),
}

impl Casters {
    /// Whether the cascades draw the full mesh (selected with zero thresholds), given whether the
    /// camera's view does.
    pub(crate) fn full_mesh(self, camera_full_mesh: bool) -> bool {
        match self {
            Self::Forced(technique) => technique == Technique::Full,
            Self::Coarser | Self::LightView | Self::CameraView => camera_full_mesh,
        }
    }
}

impl Default for Shadows {
    /// Three 2048² cascades over the first 150 m, splits weighted 0.75 towards logarithmic, a
    /// normal offset of 1.5 texels, selection in pixels of 2 texels, casters chosen at the
    /// coarser of the camera's and the light's view.
    fn default() -> Self {
        Self {
            resolution: 2048,
            cascades: 3,
            distance: 150.0,
            split_lambda: 0.75,
            normal_offset: 1.5,
            lod_texels: 2.0,
            casters: Casters::Coarser,
        }
    }
}

/// One cascade of a frame's shadow maps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cascade {
    /// World to clip of the cascade's orthographic light view (WebGPU depth 0..1).
    pub view_proj: Mat4,
    /// Centre of the cascade's sphere (snapped to whole texels across the sun), world space.
    pub centre: Vec3,
    /// Radius of the sphere, metres: the map spans `2 · radius` on a side.
    pub radius: f32,
    /// Metres per texel.
    pub texel: f32,
    /// The slice of view distances this cascade covers (it holds more: the whole sphere).
    pub split: (f32, f32),
    /// Unit direction towards the sun.
    pub sun: Vec3,
    /// The light view's right and up directions, world space.
    pub right: Vec3,
    /// See [`Self::right`].
    pub up: Vec3,
    /// Depth of the map's near plane in front of the centre along the sun, metres.
    pub reach: f32,
    /// Texels per side.
    pub resolution: u32,
    /// [`Shadows::lod_texels`].
    pub lod_texels: f32,
}

impl Cascade {
    /// The camera the cascade's trees are selected with: the orthographic view's frustum, and an
    /// eye far along the sun (1000 times the cascade's depth) whose pixel at the
    /// cascade's centre is [`Self::lod_texels`] texels, so `τ = s · lod_texels · texel` for every
    /// tree to within 0.1 %.
    #[must_use]
    pub fn selection_camera(&self) -> treelod_runtime::Camera {
        let distance = SELECTION_DISTANCE * (self.radius + self.reach);
        #[expect(clippy::cast_precision_loss, reason = "shadow-map resolutions are far below 2^24")]
        let texels = self.resolution.max(1) as f32;
        treelod_runtime::Camera {
            position: self.eye_far(),
            view_proj: self.view_proj,
            viewport_height: texels / self.lod_texels.max(1e-3),
            fovy: 2.0 * (0.5 * self.texel * texels / distance).atan(),
        }
    }

    /// The far eye of [`Self::selection_camera`] (also where billboards facing the camera turn
    /// to in the shadow pass).
    #[must_use]
    pub fn eye_far(&self) -> Vec3 {
        self.centre + self.sun * (SELECTION_DISTANCE * (self.radius + self.reach))
    }
}

/// The distances splitting `0 ..= distance` into `count` slices: `λ` of the logarithmic split
/// (from 1 m) plus `1 − λ` of the uniform one. `count + 1` values from 0 to `distance`.
#[must_use]
pub fn cascade_splits(distance: f32, count: usize, lambda: f32) -> Vec<f32> {
    let far = distance.max(SPLIT_NEAR * 2.0);
    let lambda = lambda.clamp(0.0, 1.0);
    #[expect(clippy::cast_precision_loss, reason = "at most a few cascades")]
    let n = count.max(1) as f32;
    (0..=count.max(1))
        .map(|i| {
            #[expect(clippy::cast_precision_loss, reason = "at most a few cascades")]
            let t = i as f32 / n;
            if i == 0 { 0.0 } else { lambda * SPLIT_NEAR * (far / SPLIT_NEAR).powf(t) + (1.0 - lambda) * far * t }
        })
        .collect()
}

/// The smallest sphere around the slice `near ..= far` of a symmetric view frustum whose corners
/// lie `spread · d` off its axis at distance `d`: `(distance of the centre along the axis,
/// radius)`.
fn slice_sphere(near: f32, far: f32, spread: f32) -> (f32, f32) {
    let t2 = spread * spread;
    // Equidistant from the near and the far corners, unless that lies beyond the far plane.
    let along = (0.5 * (near + far) * (1.0 + t2)).min(far);
    let radius =
        ((along - near).powi(2) + t2 * near * near).sqrt().max(((far - along).powi(2) + t2 * far * far).sqrt());
    (along, radius)
}

/// The cascades of a frame seen by `camera` with the sun towards `sun`, casters within `scene`
/// (world bounds, min and max; `None`: only those inside each cascade's sphere).
#[must_use]
pub fn fit_cascades(camera: &Camera, sun: Vec3, shadows: &Shadows, scene: Option<(Vec3, Vec3)>) -> Vec<Cascade> {
    let sun = sun.normalize_or(Vec3::Y);
    let count = (shadows.cascades as usize).clamp(1, MAX_CASCADES);
    let resolution = shadows.resolution.max(1);
    #[expect(clippy::cast_precision_loss, reason = "shadow-map resolutions are far below 2^24")]
    let texels = resolution as f32;
    #[expect(clippy::cast_precision_loss, reason = "viewport sizes are far below 2^24")]
    let aspect = camera.width.max(1) as f32 / camera.height.max(1) as f32;
    let tan = (0.5 * camera.fovy).tan();
    let spread = tan * (1.0 + aspect * aspect).sqrt();
    let inverse = camera.view.inverse();
    let forward = -inverse.z_axis.truncate().normalize_or(Vec3::NEG_Z);
    // The light's basis depends on the sun alone, so its texel grid is fixed in the world.
    let up_ref = if sun.cross(Vec3::Y).length_squared() < 1e-6 { Vec3::Z } else { Vec3::Y };
    let basis = glam::camera::rh::view::look_to_mat4(Vec3::ZERO, -sun, up_ref);
    let unbasis = basis.inverse();
    let right = unbasis.x_axis.truncate();
    let up = unbasis.y_axis.truncate();
    let splits = cascade_splits(shadows.distance, count, shadows.split_lambda);
    splits
        .windows(2)
        .map(|pair| {
            let (near, far) = (pair[0], pair[1]);
            let (along, radius) = slice_sphere(near, far, spread);
            let texel = 2.0 * radius / texels;
            let centre = camera.position + forward * along;
            let mut local = basis.transform_point3(centre);
            local.x = (local.x / texel).round() * texel;
            local.y = (local.y / texel).round() * texel;
            let centre = unbasis.transform_point3(local);
            let reach = casters_reach(scene, centre, sun, radius);
            let eye = centre + sun * reach;
            let view = glam::camera::rh::view::look_to_mat4(eye, -sun, up_ref);
            let proj =
                glam::camera::rh::proj::directx::orthographic(-radius, radius, -radius, radius, 0.0, reach + radius);
            Cascade {
                view_proj: proj * view,
                centre,
                radius,
                texel,
                split: (near, far),
                sun,
                right,
                up,
                reach,
                resolution,
                lod_texels: shadows.lod_texels,
            }
        })
        .collect()
}

/// The most host shadow maps a renderer draws into each frame
/// ([`crate::Renderer::set_host_shadow_views`]).
pub const MAX_HOST_SHADOW_VIEWS: usize = 8;

/// A shadow map the host renders and samples itself (an engine's directional-light cascade),
/// which the trees are cast into: selected from its light's view as the renderer's own cascades
/// are ([`Shadows::casters`], [`Shadows::lod_texels`]) and drawn depth-only into it by
/// [`crate::Renderer::render_host_shadow`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostShadowView {
    /// World to clip of the map's orthographic light view, in the renderer's depth convention
    /// ([`crate::DepthConvention`]: near the light at 1 for `Reverse`), as the host's own casters
    /// draw with and its receivers sample with.
    pub clip_from_world: Mat4,
    /// Texels per side of the map.
    pub resolution: u32,
}

impl Cascade {
    /// The cascade the trees cast into `view` with are selected with: `view`'s square (its
    /// larger half-extent across the light), and casters towards the light up to the farthest
    /// corner of `scene` along it (beyond the map's near plane: a host whose casters there are
    /// pancaked onto it, as unclipped depth does, gets their shadows). `None` for a view that
    /// is not an invertible orthographic projection. `view_proj` is the renderer's own for
    /// selection (standard depth); the trees are drawn with `view.clip_from_world`.
    #[must_use]
    pub fn from_host(
        view: &HostShadowView,
        depth: crate::DepthConvention,
        lod_texels: f32,
        scene: Option<(Vec3, Vec3)>,
    ) -> Option<Self> {
        let m = view.clip_from_world;
        // Orthographic: the clip w does not depend on the position.
        let w = m.row(3);
        if !m.is_finite() || w.truncate().length_squared() > 1e-12 || (w.w - 1.0).abs() > 1e-6 {
            return None;
        }
        let inverse = m.inverse();
        if !inverse.is_finite() {
            return None;
        }
        let near_z = 1.0 - depth.far();
        let at = |x: f32, y: f32, z: f32| inverse.project_point3(Vec3::new(x, y, z));
        let (near, far) = (at(0.0, 0.0, near_z), at(0.0, 0.0, depth.far()));
        let centre = 0.5 * (near + far);
        let towards = near - far;
        let half_depth = 0.5 * towards.length();
        let sun = towards.try_normalize()?;
        let (right, up) = (at(1.0, 0.0, 0.5) - at(0.0, 0.0, 0.5), at(0.0, 1.0, 0.5) - at(0.0, 0.0, 0.5));
        let radius = right.length().max(up.length());
        let (right, up) = (right.try_normalize()?, up.try_normalize()?);
        if !(radius > 0.0 && radius.is_finite() && half_depth.is_finite()) {
            return None;
        }
        #[expect(clippy::cast_precision_loss, reason = "shadow-map resolutions are far below 2^24")]
        let texels = view.resolution.max(1) as f32;
        let reach = casters_reach(scene, centre, sun, half_depth);
        let eye = centre + sun * reach;
        let look = glam::camera::rh::view::look_to_mat4(eye, -sun, up);
        let proj =
            glam::camera::rh::proj::directx::orthographic(-radius, radius, -radius, radius, 0.0, reach + half_depth);
        Some(Self {
            view_proj: proj * look,
            centre,
            radius,
            texel: 2.0 * radius / texels,
            split: (0.0, 0.0),
            sun,
            right,
            up,
            reach,
            resolution: view.resolution.max(1),
            lod_texels,
        })
    }
}

/// How far towards the sun from `centre` a map's casters reach: up to the farthest corner of
/// `scene` along the sun (its centre's distance plus the half-extents projected on |sun|), at
/// least `least` (the map's own half-depth; `scene` `None`: that alone).
fn casters_reach(scene: Option<(Vec3, Vec3)>, centre: Vec3, sun: Vec3, least: f32) -> f32 {
    scene.map_or(least, |(min, max)| {
        let farthest = (0.5 * (min + max) - centre).dot(sun) + (0.5 * (max - min)).dot(sun.abs());
        farthest.max(least)
    })
}

/// The receivers' uniform. WGSL twin: `ShadowCascades` in `shaders/shared/shadow.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ShadowUniform {
    view_proj: [[[f32; 4]; 4]; MAX_CASCADES],
    texel: [f32; 4],
    layer: [u32; 4],
    count: u32,
    normal_offset: f32,
    inv_size: f32,
    reverse_z: u32,
}

impl ShadowUniform {
    /// The uniform of `cascades` (none: shadows off), finest first, each its world-to-clip
    /// matrix, metres per texel and layer of maps of `resolution`² texels, in standard depth
    /// (`reverse_z` false: nearer the light is smaller) or reverse depth.
    pub(crate) fn new(
        cascades: impl IntoIterator<Item = (Mat4, f32, u32)>,
        resolution: u32,
        normal_offset: f32,
        reverse_z: bool,
    ) -> Self {
        #[expect(clippy::cast_precision_loss, reason = "shadow-map resolutions are far below 2^24")]
        let inv_size = 1.0 / resolution.max(1) as f32;
        let mut uniform = Self {
            view_proj: [Mat4::IDENTITY.to_cols_array_2d(); MAX_CASCADES],
            texel: [0.0; 4],
            layer: [0; 4],
            count: 0,
            normal_offset,
            inv_size,
            reverse_z: u32::from(reverse_z),
        };
        for (k, (view_proj, texel, layer)) in cascades.into_iter().take(MAX_CASCADES).enumerate() {
            uniform.view_proj[k] = view_proj.to_cols_array_2d();
            uniform.texel[k] = texel;
            uniform.layer[k] = layer;
            uniform.count = u32::try_from(k + 1).unwrap_or(0);
        }
        uniform
    }
}

/// The shadow maps on the GPU: a depth texture array (a layer per cascade), the receivers'
/// uniform and their bind group.
pub(crate) struct ShadowMaps {
    /// Texels per side and layers.
    pub(crate) size: (u32, u32),
    /// One view per layer, the shadow pass's attachments.
    pub(crate) layers: Vec<wgpu::TextureView>,
    pub(crate) uniform: wgpu::Buffer,
    pub(crate) bind_group: wgpu::BindGroup,
}

/// The depth format of the shadow maps.
pub(crate) const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

impl ShadowMaps {
    /// The layout of the receivers' bind group (group 2 of `shared/shadow.wgsl`).
    pub(crate) fn layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
        device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("treelod shadows"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                    count: None,
                },
            ],
        })
    }

    /// Maps of `resolution`² texels × `layers`, their uniform saying none is in use.
    pub(crate) fn new(device: &wgpu::Device, layout: &wgpu::BindGroupLayout, resolution: u32, layers: u32) -> Self {
        let (resolution, layers) = (resolution.max(1), layers.max(1));
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("treelod shadow maps"),
            size: wgpu::Extent3d { width: resolution, height: resolution, depth_or_array_layers: layers },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: SHADOW_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let array = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("treelod shadow maps"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..wgpu::TextureViewDescriptor::default()
        });
        let views: Vec<wgpu::TextureView> = (0..layers)
            .map(|layer| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("treelod shadow cascade"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: layer,
                    array_layer_count: Some(1),
                    ..wgpu::TextureViewDescriptor::default()
                })
            })
            .collect();
        let uniform = receivers_uniform(device);
        // The renderer's own maps hold standard depth.
        let compare = crate::DepthConvention::Standard.nearer_or_equal();
        let bind_group = receivers_group(device, layout, &uniform, &array, compare);
        Self { size: (resolution, layers), layers: views, uniform, bind_group }
    }
}

/// A receivers' uniform buffer, saying no cascade is in use.
fn receivers_uniform(device: &wgpu::Device) -> wgpu::Buffer {
    wgpu::util::DeviceExt::create_buffer_init(
        device,
        &wgpu::util::BufferInitDescriptor {
            label: Some("treelod shadow cascades"),
            contents: bytemuck::bytes_of(&ShadowUniform::new([], 1, 0.0, false)),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        },
    )
}

/// The receivers' bind group of `uniform` and the maps `array` (a depth 2D array view), with a
/// comparison sampler lit where `compare(receiver, map)` holds.
fn receivers_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    uniform: &wgpu::Buffer,
    array: &wgpu::TextureView,
    compare: wgpu::CompareFunction,
) -> wgpu::BindGroup {
    // Linear: the hardware's 2×2 percentage-closer filter.
    let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("treelod shadow sampler"),
        address_mode_u: wgpu::AddressMode::ClampToEdge,
        address_mode_v: wgpu::AddressMode::ClampToEdge,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        compare: Some(compare),
        ..wgpu::SamplerDescriptor::default()
    });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("treelod shadows"),
        layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(array) },
            wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::Sampler(&sampler) },
        ],
    })
}

/// A cascade of the host's shadow maps the trees receive ([`crate::Renderer::receive_host_shadows`]):
/// its light view and the layer of the host's depth texture array it is in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostShadowCascade {
    /// World to clip of the cascade's orthographic light view, in the renderer's depth
    /// convention, as the host's casters drew the layer with.
    pub clip_from_world: Mat4,
    /// The layer of the host's texture array.
    pub layer: u32,
}

/// Why the host's shadow maps cannot be received ([`crate::Renderer::receive_host_shadows`]).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum HostShadowError {
    /// The texture is not a 2D texture of a depth format.
    #[error("the host's shadow maps are a {dimension:?} texture of format {format:?}, not a 2D depth texture array")]
    NotDepth {
        /// Its dimension.
        dimension: wgpu::TextureDimension,
        /// Its format.
        format: wgpu::TextureFormat,
    },
    /// The texture cannot be sampled.
    #[error("the host's shadow maps lack TEXTURE_BINDING usage, so the trees cannot sample them")]
    NotSampled,
    /// The texture is multisampled.
    #[error("the host's shadow maps have {0} samples per texel; a receiver samples single-sampled maps")]
    Multisampled(u32),
    /// A cascade names a layer the texture does not have.
    #[error("a host shadow cascade names layer {layer}, the host's shadow maps have {layers} layer(s)")]
    NoLayer {
        /// The layer named.
        layer: u32,
        /// Layers of the texture.
        layers: u32,
    },
}

/// The host's shadow maps the trees receive: the cascades taken (finest first, each with its
/// metres per texel), the host's texture, the receivers' uniform and its bind
/// group over that texture.
pub(crate) struct HostReceiver {
    pub(crate) cascades: Vec<(HostShadowCascade, f32)>,
    maps: wgpu::Texture,
    pub(crate) resolution: u32,
    pub(crate) uniform: wgpu::Buffer,
    pub(crate) bind_group: wgpu::BindGroup,
}

impl HostReceiver {
    /// The receiver of `cascades` of the host's depth texture array `maps` (`previous`: an
    /// earlier one, whose uniform buffer is reused, and its bind group too when it was made
    /// over the same texture, as a host's per-frame calls mostly are), the orthographic ones
    /// among them, finest first, at most [`MAX_CASCADES`]; `Ok(None)` when none is.
    ///
    /// # Errors
    /// [`HostShadowError`] when `maps` is not a single-sampled, sampled 2D depth texture or a
    /// cascade's layer is not in it.
    pub(crate) fn new(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        maps: &wgpu::Texture,
        cascades: &[HostShadowCascade],
        depth: crate::DepthConvention,
        previous: Option<Self>,
    ) -> Result<Option<Self>, HostShadowError> {
        let format = maps.format();
        if maps.dimension() != wgpu::TextureDimension::D2 || !format.has_depth_aspect() {
            return Err(HostShadowError::NotDepth { dimension: maps.dimension(), format });
        }
        if !maps.usage().contains(wgpu::TextureUsages::TEXTURE_BINDING) {
            return Err(HostShadowError::NotSampled);
        }
        if maps.sample_count() > 1 {
            return Err(HostShadowError::Multisampled(maps.sample_count()));
        }
        let layers = maps.depth_or_array_layers();
        if let Some(bad) = cascades.iter().find(|c| c.layer >= layers) {
            return Err(HostShadowError::NoLayer { layer: bad.layer, layers });
        }
        let resolution = maps.width();
        let mut taken: Vec<(HostShadowCascade, f32)> = cascades
            .iter()
            .filter_map(|c| {
                let view = HostShadowView { clip_from_world: c.clip_from_world, resolution };
                Some((*c, Cascade::from_host(&view, depth, 1.0, None)?.texel))
            })
            .collect();
        // The shader takes the first cascade that holds the point: the finest first.
        taken.sort_by(|a, b| a.1.total_cmp(&b.1));
        taken.truncate(MAX_CASCADES);
        if taken.is_empty() {
            return Ok(None);
        }
        let previous = match previous {
            Some(previous) if previous.maps == *maps => {
                return Ok(Some(Self { cascades: taken, resolution, ..previous }));
            }
            other => other,
        };
        let array = maps.create_view(&wgpu::TextureViewDescriptor {
            label: Some("treelod host shadow maps"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            aspect: wgpu::TextureAspect::DepthOnly,
            ..wgpu::TextureViewDescriptor::default()
        });
        let uniform = previous.map_or_else(|| receivers_uniform(device), |p| p.uniform);
        let bind_group = receivers_group(device, layout, &uniform, &array, depth.nearer_or_equal());
        Ok(Some(Self { cascades: taken, maps: maps.clone(), resolution, uniform, bind_group }))
    }

    /// The receivers' uniform of the cascades.
    pub(crate) fn uniform(&self, normal_offset: f32, depth: crate::DepthConvention) -> ShadowUniform {
        let cascades = self.cascades.iter().map(|(host, texel)| (host.clip_from_world, *texel, host.layer));
        ShadowUniform::new(cascades, self.resolution, normal_offset, depth == crate::DepthConvention::Reverse)
    }
}

/// The frame uniform's camera fields for a cascade's shadow pass: `(eye, right, up)` as
/// `FrameUniform` holds them (eye with the map's resolution, right with the projection's y
/// scale `1 / radius`, so a splat's one-pixel minimum is one texel).
pub(crate) fn cascade_frame(cascade: &Cascade) -> (Vec4, Vec4, Vec3) {
    #[expect(clippy::cast_precision_loss, reason = "shadow-map resolutions are far below 2^24")]
    let texels = cascade.resolution.max(1) as f32;
    (cascade.eye_far().extend(texels), cascade.right.extend(1.0 / cascade.radius.max(1e-6)), cascade.up)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(eye: Vec3, target: Vec3) -> Camera {
        Camera::look_at(eye, target, 0.8, 640, 480)
    }

    #[test]
    fn splits_run_from_zero_to_the_distance_and_grow() {
        let splits = cascade_splits(150.0, 3, 0.75);
        assert_eq!(splits.len(), 4);
        assert_eq!(splits[0], 0.0);
        assert!((splits[3] - 150.0).abs() < 1e-3, "{splits:?}");
        assert!(splits.windows(2).all(|w| w[1] > w[0]), "{splits:?}");
        // Logarithmic splits give the first cascade less than uniform ones.
        assert!(cascade_splits(150.0, 3, 1.0)[1] < cascade_splits(150.0, 3, 0.0)[1]);
        assert!((cascade_splits(150.0, 3, 0.0)[1] - 50.0).abs() < 1e-3);
    }

    #[test]
    fn each_slice_lies_inside_its_cascade() {
        let cam = camera(Vec3::new(3.0, 2.0, 10.0), Vec3::new(-20.0, 0.0, -30.0));
        let sun = Vec3::new(0.4, 0.8, 0.3);
        let shadows = Shadows::default();
        let cascades = fit_cascades(&cam, sun, &shadows, None);
        assert_eq!(cascades.len(), 3);
        let inverse = cam.view.inverse();
        let tan = (0.5 * cam.fovy).tan();
        let aspect = 640.0 / 480.0;
        for cascade in &cascades {
            let (near, far) = cascade.split;
            for d in [near, far] {
                for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                    let corner = inverse.transform_point3(Vec3::new(sx * d * tan * aspect, sy * d * tan, -d));
                    let clip = cascade.view_proj.project_point3(corner);
                    assert!(clip.x.abs() <= 1.0 + 1e-3 && clip.y.abs() <= 1.0 + 1e-3, "{clip} outside");
                    assert!((0.0..=1.0).contains(&clip.z), "{clip} outside the depth range");
                }
            }
            assert!((cascade.texel - 2.0 * cascade.radius / 2048.0).abs() < 1e-6);
        }
        // Finer cascades first.
        assert!(cascades.windows(2).all(|w| w[0].texel < w[1].texel));
    }

    #[test]
    fn texels_stay_fixed_in_the_world_as_the_camera_moves_and_turns() {
        let sun = Vec3::new(-0.3, 0.9, 0.2);
        let shadows = Shadows::default();
        let a = fit_cascades(&camera(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 2.0, -10.0)), sun, &shadows, None);
        let b = fit_cascades(&camera(Vec3::new(0.37, 2.1, -0.61), Vec3::new(4.0, 1.0, -10.0)), sun, &shadows, None);
        for (a, b) in a.iter().zip(&b) {
            // Same texel size, and a world point falls at the same fraction of a texel.
            assert!((a.texel - b.texel).abs() < 1e-6);
            let p = Vec3::new(1.234, 0.5, -7.89);
            let texel_of = |c: &Cascade| {
                let ndc = c.view_proj.project_point3(p);
                let res = c.resolution as f32;
                (Vec3::new(0.5 * ndc.x + 0.5, 0.5 - 0.5 * ndc.y, 0.0) * res).truncate()
            };
            let (ta, tb) = (texel_of(a), texel_of(b));
            let fa = ta - ta.floor();
            let fb = tb - tb.floor();
            assert!((fa - fb).abs().max_element() < 2e-2, "{ta} vs {tb}");
        }
    }

    #[test]
    fn casters_towards_the_sun_are_in_the_depth_range() {
        let cam = camera(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 2.0, -10.0));
        let sun = Vec3::new(0.0, 1.0, 0.5).normalize();
        let scene = (Vec3::new(-100.0, 0.0, -100.0), Vec3::new(100.0, 300.0, 100.0));
        let cascades = fit_cascades(&cam, sun, &Shadows::default(), Some(scene));
        // A point high above the first cascade (towards the sun) is inside its depth range.
        let c = &cascades[0];
        let above = c.centre + sun * 250.0;
        let clip = c.view_proj.project_point3(above);
        assert!((0.0..=1.0).contains(&clip.z), "{clip}");
        assert!(clip.x.abs() < 1e-3 && clip.y.abs() < 1e-3);
    }

    #[test]
    fn a_selection_pixel_is_lod_texels_texels() {
        let cam = camera(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 2.0, -10.0));
        for lod_texels in [1.0, 2.0] {
            let shadows = Shadows { lod_texels, ..Shadows::default() };
            for cascade in fit_cascades(&cam, Vec3::new(0.2, 1.0, 0.1), &shadows, None) {
                let selection = cascade.selection_camera();
                let pixel = lod_texels * cascade.texel;
                let at_centre = selection.world_per_pixel() * selection.position.distance(cascade.centre);
                assert!((at_centre / pixel - 1.0).abs() < 1e-3, "{at_centre} vs {pixel}");
                // Across the sphere's depth the footprint stays within 0.1 %.
                let near = selection.world_per_pixel()
                    * selection.position.distance(cascade.centre + cascade.sun * cascade.radius);
                assert!((near / pixel - 1.0).abs() < 1.1e-3);
            }
        }
    }
}
