//! Draws `.treelod` containers in Bevy's main 3D pass, with Bevy's cameras and depth buffer.
//!
//! Add [`TreelodPlugin`] after Bevy's own plugins, load containers as assets, and place trees or
//! forests with [`TreelodForest`]:
//!
//! ```no_run
//! # use bevy_app::{App, Startup};
//! # use bevy_asset::AssetServer;
//! # use bevy_ecs::prelude::*;
//! # use bevy_transform::components::Transform;
//! use treelod_bevy::{TreelodForest, TreelodPlugin, TreelodSettings};
//!
//! # fn add_bevy_plugins(app: &mut App) {}
//! let mut app = App::new();
//! add_bevy_plugins(&mut app); // `DefaultPlugins`, or the sub-crates' plugins
//! app.add_plugins(TreelodPlugin)
//!     .insert_resource(TreelodSettings::default())
//!     .add_systems(Startup, |mut commands: Commands, assets: Res<AssetServer>| {
//!         let tree = assets.load("demo.treelod");
//!         let grid = (0..400).map(|i| Transform::from_xyz((i % 20) as f32 * 9.0, 0.0, (i / 20) as f32 * -9.0));
//!         commands.spawn(TreelodForest::new(tree, grid));
//!     });
//! ```
//!
//! **How it draws.** Each 3D camera gets a [`treelod_render::Renderer`] of its own, made for the
//! view's colour format (`Rgba16Float` with `Hdr`, the target's format otherwise), depth format
//! and MSAA sample count, read from the view's attachments, and remade when they change. Every
//! frame `Render`'s `PrepareBindGroups` set selects each tree's level of detail for the camera
//! (frustum culling included; the camera's projection and viewport as Bevy computed them), and a
//! system in the `Core3d` schedule's main pass — after the opaque and alpha-masked phases, before
//! the transparent one — records a render pass that loads and stores the view's colour target and
//! depth buffer and draws the trees into them: they hide and are hidden by Bevy's meshes, and
//! transparent meshes blend over them. Bevy's depth buffer is reverse Z (cleared to 0, near at 1,
//! an infinite far plane); the renderers are made with
//! [`treelod_render::DepthConvention::Reverse`] so their depth test matches. Orthographic cameras
//! are skipped (selection measures sizes in pixels through a field of view).
//!
//! **Occlusion.** After its trees' pass each camera's renderer measures how much of each tree
//! its depth buffer shows ([`treelod_render::Renderer::measure_occlusion`]), Bevy's opaque meshes
//! included, and the policy chooses a partly hidden tree at that visible fraction
//! ([`treelod_render::Policy::occlusion`], on by default), often with a cheaper representation.
//! While the settings measure occlusion ([`Settings::measures_occlusion`]) the plugin asks every
//! [`Camera3d`]'s depth buffer to be samplable (`TEXTURE_BINDING`); a camera whose viewport does
//! not start at its target's corner, or with a main-pass resolution override, is not measured.
//!
//! **Light.** Trees are shaded by treelod's own model (albedo × (ambient + direct · |n·l|), with
//! the containers' ambient occlusion), not by Bevy's PBR: with
//! [`TreelodSettings::sun_from_directional_light`] (the default) the direction and colour of the
//! brightest visible [`DirectionalLight`](bevy_light::DirectionalLight) are its sun; its
//! illuminance, the camera's exposure and Bevy's ambient light are not used.
//!
//! **Shadows.** With [`TreelodSettings::cast_bevy_shadows`] (the default) the trees cast into
//! the shadow cascades of Bevy's directional lights that have `shadow_maps_enabled`, so Bevy's
//! meshes receive them: each camera's renderer selects the trees from each cascade's light view
//! at the detail the cascade resolves ([`treelod_render::Renderer::set_host_shadow_views`]), and
//! a system in the `Core3d` schedule, after Bevy's shadow passes and before the main pass,
//! draws them depth-only into Bevy's maps (depth clamped to a cascade's near plane where the
//! device has `DEPTH_CLIP_CONTROL`, as Bevy's own casters are). With
//! [`TreelodSettings::receive_bevy_shadows`] (the default) the trees receive the cascades of the
//! directional light that is their sun, read from Bevy's shadow texture with the cascades'
//! matrices ([`treelod_render::Renderer::receive_host_shadows`]), in place of treelod's own
//! cascades: Bevy's meshes shadow the trees, and the trees each other. The finest cascade that
//! holds a point is read, with treelod's 3×3 filter and normal offset (Bevy's cascade blending,
//! soft shadows and the light's depth and normal biases are not used). Without a shadowed sun,
//! [`treelod_render::Settings::shadows`] gives the trees treelod's own cascades.
//!
//! **Assets.** See [`TreelodLoader`] for how `.treelod` files are read (bytes from Bevy's asset
//! reader; [`TreelodContainer::open`] keeps a file memory-mapped instead). A malformed file fails
//! to load with a [`TreelodLoadError`] saying why, as any Bevy asset does.
//!
//! **Requirements.** The render device needs [`treelod_render::Renderer::required_features`]
//! (Bevy's default `WgpuSettings` ask for every feature the adapter has); without them an error is
//! logged once and nothing is drawn. The crate depends on Bevy 0.20's own crates rather than the
//! `bevy` crate, with no default features; an application using `bevy` 0.20 gets the same types.

mod asset;
mod draw;
mod forest;

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use bevy_app::{App, Plugin, PostUpdate};
use bevy_asset::AssetApp;
use bevy_camera::Camera3d;
use bevy_camera::visibility::VisibilitySystems;
use bevy_ecs::prelude::*;
use bevy_transform::TransformSystems;

pub use asset::{TreelodContainer, TreelodLoadError, TreelodLoader};
pub use forest::TreelodForest;
use forest::{TreelodScene, collect_scene};
pub use treelod_format;
pub use treelod_render;
pub use treelod_render::{FrameStats, Settings};

/// Draws [`TreelodForest`]s in every 3D camera: registers the [`TreelodContainer`] asset and its
/// loader, the [`TreelodSettings`] and [`TreelodStats`] resources, and the systems (see the crate
/// documentation). Add it after Bevy's asset, render and core-pipeline plugins.
#[derive(Clone, Copy, Debug, Default)]
pub struct TreelodPlugin;

impl Plugin for TreelodPlugin {
    fn build(&self, app: &mut App) {
        app.init_asset::<TreelodContainer>()
            .register_asset_loader(TreelodLoader)
            .init_resource::<TreelodSettings>()
            .init_resource::<TreelodStats>()
            .init_resource::<TreelodScene>()
            .add_systems(
                PostUpdate,
                (
                    collect_scene.after(TransformSystems::Propagate).after(VisibilitySystems::VisibilityPropagate),
                    samplable_depth,
                ),
            );
    }

    fn finish(&self, app: &mut App) {
        // Here rather than in `build`: the `Core3d` schedule and the render device exist by now
        // whatever the order of the plugins.
        draw::setup_render_app(app);
    }
}

/// While the settings use the trees' visible fractions ([`Settings::measures_occlusion`]: the
/// policy's occlusion, on by default), asks every 3D camera's depth buffer to be samplable
/// (`TEXTURE_BINDING` in [`Camera3d::depth_texture_usages`], as Bevy's own occlusion culling
/// does), so that each camera's renderer can measure them there after drawing its trees. The flag
/// stays when the settings change (Bevy would otherwise make the buffer again).
fn samplable_depth(settings: Res<TreelodSettings>, mut cameras: Query<&mut Camera3d>) {
    if !settings.render.measures_occlusion() {
        return;
    }
    let binding = wgpu::TextureUsages::TEXTURE_BINDING.bits();
    for mut camera in &mut cameras {
        if camera.depth_texture_usages.0 & binding == 0 {
            camera.depth_texture_usages.0 |= binding;
        }
    }
}

/// The level-of-detail, representation and shading settings of every camera's renderer, read
/// each frame.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct TreelodSettings {
    /// The renderer's settings: pixel thresholds (`s_min`, `s_max`), the policy choosing each
    /// tree's representation from its container's calibration tables ([`Settings::policy`], on
    /// by default), the technique trees are drawn with otherwise ([`Settings::technique`], a
    /// [`treelod_render::Technique`]: the sequential point trees by default, pruned leaves,
    /// impostor planes, ellipsoids, a baseline or the full mesh; trees whose container lacks the
    /// technique's data are drawn with the point trees) and its
    /// tuning (`pruning`, `impostor_bark`, `ellipsoid_quality`, …), shading, debug colours,
    /// shadows and streaming budgets (see [`treelod_render::Settings`]). `memory_budget` is taken
    /// when a camera's renderer is made (when the camera first draws trees, or its formats or
    /// containers change). [`TreelodStats`] counts each camera's trees by the technique each was
    /// drawn with ([`FrameStats::instances`]).
    pub render: Settings,
    /// Take [`Settings::sun`] and [`Settings::sun_colour`] from the brightest visible
    /// [`DirectionalLight`](bevy_light::DirectionalLight) (towards the light, and its colour in
    /// linear RGB); without one, or when `false`, `render`'s are used.
    pub sun_from_directional_light: bool,
    /// Select on the GPU ([`treelod_render::Renderer::enable_gpu_selection`]): compute shaders
    /// cull the instances and select the point tree's trees and the impostor and billboard
    /// quads, so in a forest of 10^5–10^6 trees the CPU keeps mostly the policy's choice per
    /// tree and the other representations' trees. Every container's triangles and points are then kept on the GPU whole; where
    /// they do not fit `render.memory_budget` an error is logged once per camera and that camera
    /// selects on the CPU. Turned on again whenever a container is added. Default `false`.
    pub gpu_selection: bool,
    /// Cast the trees into the shadow maps of Bevy's directional lights (those with
    /// `shadow_maps_enabled`): each camera's renderer selects the trees from each of the camera's
    /// cascades as it selects for its own cascades ([`treelod_render::Shadows::casters`] and
    /// `lod_texels` of `render.shadows`, their defaults without), and draws them depth-only into
    /// Bevy's map after Bevy's own casters, so Bevy's meshes receive the trees' shadows. Up to
    /// [`treelod_render::MAX_HOST_SHADOW_VIEWS`] cascades per camera. Default `true`.
    pub cast_bevy_shadows: bool,
    /// The trees receive the shadow maps of the Bevy directional light that is their sun (with
    /// `shadow_maps_enabled`, its direction that of `render.sun`, as
    /// [`Self::sun_from_directional_light`] makes it) in place of treelod's own cascades
    /// ([`treelod_render::Renderer::receive_host_shadows`]): the shadows of Bevy's meshes fall
    /// on the trees, and with [`Self::cast_bevy_shadows`] the trees' shadows on each other.
    /// While they do, `render.shadows`' own cascades are not rendered (its `normal_offset`,
    /// `casters` and `lod_texels` still apply). Default `true`.
    pub receive_bevy_shadows: bool,
}

impl Default for TreelodSettings {
    /// [`Settings::default`] (one-pixel points, triangles from two pixels), the sun from Bevy's
    /// directional light, selection on the CPU, the trees cast into and receive Bevy's shadow
    /// maps.
    fn default() -> Self {
        Self {
            render: Settings::default(),
            sun_from_directional_light: true,
            gpu_selection: false,
            cast_bevy_shadows: true,
            receive_bevy_shadows: true,
        }
    }
}

/// What each camera's renderer selected in the latest frame it drew trees, by camera entity (main
/// world): trees in view, triangles, points, bytes resident and uploaded ([`FrameStats`]).
///
/// Written by the render world, so with pipelined rendering the counts are a frame old. A camera
/// that stops drawing (switched off, despawned, no trees) keeps its last counts.
#[derive(Resource, Clone, Debug, Default)]
pub struct TreelodStats(Arc<Mutex<HashMap<Entity, FrameStats>>>);

impl TreelodStats {
    /// The latest counts of `camera`, if it drew trees.
    #[must_use]
    pub fn get(&self, camera: Entity) -> Option<FrameStats> {
        self.lock().get(&camera).copied()
    }

    /// The latest counts of every camera that drew trees.
    #[must_use]
    pub fn all(&self) -> Vec<(Entity, FrameStats)> {
        self.lock().iter().map(|(e, s)| (*e, *s)).collect()
    }

    fn insert(&self, camera: Entity, stats: FrameStats) {
        self.lock().insert(camera, stats);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<Entity, FrameStats>> {
        // The map holds plain counts: one a panicking writer left is still usable.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}
