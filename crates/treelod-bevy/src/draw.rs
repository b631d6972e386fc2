//! The render world: a treelod [`Renderer`] per 3D camera, made for that view's targets, which
//! selects each frame (in `Render`'s `PrepareBindGroups`, after Bevy made the view's textures)
//! and draws in the `Core3d` main pass, after the opaque and alpha-masked phases and before the
//! transparent one, into the view's colour target and depth buffer; before the main pass, after
//! Bevy's shadow passes, it casts the trees into the camera's cascades of Bevy's directional
//! lights.
//!
//! Bevy draws with reverse Z (depth cleared to 0, near at 1, an infinite far plane), so the
//! renderers are made with [`DepthConvention::Reverse`] and the camera's own projection; colour
//! format (HDR or not, or an image target's format), depth format and MSAA samples are read from
//! the view's attachments.

use std::collections::HashMap;
use std::sync::Arc;

use bevy_asset::AssetId;
use bevy_camera::{Camera3d, MainPassResolutionOverride, Viewport};
use bevy_color::ColorToComponents;
use bevy_core_pipeline::core_3d::{main_opaque_pass_3d, main_transparent_pass_3d};
use bevy_core_pipeline::{Core3dSystems, schedule::Core3d};
use bevy_ecs::prelude::*;
use bevy_light::DirectionalLight;
use bevy_log::{error, warn};
use bevy_pbr::{
    CORE_3D_SHADOW_MAP_FORMAT, ExtractedDirectionalLight, LATE_SHADOW_PASS, LightEntity, ShadowView, ViewLightEntities,
    ViewShadowBindings, per_view_shadow_pass,
};
use bevy_render::camera::ExtractedCamera;
use bevy_render::renderer::{RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy_render::sync_world::MainEntity;
use bevy_render::view::{ExtractedView, ViewDepthStencilTexture, ViewTarget};
use bevy_render::{Extract, ExtractSchedule, Render, RenderApp, RenderSystems};
use bevy_transform::components::GlobalTransform;
use treelod_format::Container;
use treelod_render::{
    Camera, DepthConvention, HostShadowCascade, HostShadowView, Instance, ModelId, Renderer, RendererFormats, Settings,
};

use crate::asset::TreelodContainer;
use crate::forest::{TreelodScene, to_glam};
use crate::{TreelodSettings, TreelodStats};

/// Adds the render world's resources and systems (from [`crate::TreelodPlugin::finish`]).
pub(crate) fn setup_render_app(app: &mut bevy_app::App) {
    let stats = app.world().resource::<TreelodStats>().clone();
    let Some(render_app) = app.get_sub_app_mut(RenderApp) else { return };
    render_app
        .insert_resource(stats)
        .init_resource::<Extracted>()
        .init_resource::<Views>()
        .add_systems(ExtractSchedule, extract)
        .add_systems(Render, prepare.in_set(RenderSystems::PrepareBindGroups))
        .add_systems(
            Core3d,
            (
                draw_shadows.after(per_view_shadow_pass::<LATE_SHADOW_PASS>).before(Core3dSystems::MainPass),
                draw.after(main_opaque_pass_3d).before(main_transparent_pass_3d).in_set(Core3dSystems::MainPass),
            ),
        );
}

/// What the main world says to draw: the scene (copied when it changed) and this frame's
/// settings with the sun filled in.
#[derive(Resource, Default)]
struct Extracted {
    scene: TreelodScene,
    settings: Settings,
    /// [`TreelodSettings::gpu_selection`].
    gpu_selection: bool,
    /// [`TreelodSettings::cast_bevy_shadows`].
    cast_bevy_shadows: bool,
    /// [`TreelodSettings::receive_bevy_shadows`].
    receive_bevy_shadows: bool,
}

/// Copies the scene when its revision changed, and the settings, taking the sun from the
/// brightest visible [`DirectionalLight`] when [`TreelodSettings::sun_from_directional_light`].
fn extract(
    scene: Extract<Res<TreelodScene>>,
    settings: Extract<Res<TreelodSettings>>,
    lights: Extract<Query<(&DirectionalLight, &GlobalTransform, &bevy_camera::visibility::InheritedVisibility)>>,
    mut extracted: ResMut<Extracted>,
) {
    if extracted.scene.revision != scene.revision {
        extracted.scene = scene.clone();
    }
    let mut render = settings.render;
    if settings.sun_from_directional_light
        && let Some((light, transform, _)) = lights
            .iter()
            .filter(|(_, _, visible)| visible.get())
            .max_by(|a, b| a.0.illuminance.total_cmp(&b.0.illuminance))
    {
        // The light shines along its forward axis; the renderer wants the way towards the sun.
        render.sun = glam::Vec3::from_array(transform.back().to_array());
        render.sun_colour = glam::Vec3::from_array(light.color.to_linear().to_vec3().to_array());
    }
    extracted.settings = render;
    extracted.gpu_selection = settings.gpu_selection;
    extracted.cast_bevy_shadows = settings.cast_bevy_shadows;
    extracted.receive_bevy_shadows = settings.receive_bevy_shadows;
}

/// One camera's renderer and what it holds.
struct ViewRenderer {
    renderer: Renderer,
    /// Per container: the one it was added from, and its model (`None`: adding it failed, and
    /// its instances are left out).
    models: HashMap<AssetId<TreelodContainer>, (Arc<Container>, Option<ModelId>)>,
    /// The scene revision whose instances are set.
    revision: Option<u64>,
    /// Instances set.
    instances: usize,
    /// GPU selection was asked for and refused (the models do not fit the memory budget): said
    /// once, not tried again until the setting is turned off and on or the renderer is made anew.
    gpu_refused: bool,
    /// The render-world entities of the shadow cascades of Bevy's directional lights handed to
    /// the renderer this frame, host map `k` ([`Renderer::set_host_shadow_views`]) at `k`.
    bevy_shadows: Vec<Entity>,
    /// Receiving Bevy's shadow maps failed: said once, until it succeeds again.
    receive_refused: bool,
}

/// The renderers, by render-world camera entity.
#[derive(Resource, Default)]
struct Views {
    views: HashMap<Entity, ViewRenderer>,
    /// The device lacks [`Renderer::required_features`]: said once, nothing drawn.
    unsupported: bool,
    /// An orthographic camera was skipped: said once.
    orthographic_reported: bool,
}

/// What `prepare` reads of a 3D camera: its entities, view, targets, and the shadow cascades of
/// Bevy's directional lights for it and the texture they are in.
type CameraItem = (
    Entity,
    &'static MainEntity,
    &'static ExtractedView,
    &'static ViewTarget,
    &'static ViewDepthStencilTexture,
    Option<&'static ViewLightEntities>,
    Option<&'static ViewShadowBindings>,
);

/// Per 3D camera: makes (or remakes) its renderer for the view's formats and the scene's
/// containers, sets the instances when the scene changed, the settings and the shadow cascades
/// of Bevy's directional lights for the camera to cast into and receive
/// ([`crate::TreelodSettings::cast_bevy_shadows`], [`crate::TreelodSettings::receive_bevy_shadows`]),
/// and selects for the camera and those cascades ([`Renderer::prepare`]), keeping the counts in
/// [`TreelodStats`].
#[expect(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn prepare(
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
    extracted: Res<Extracted>,
    cameras: Query<CameraItem, With<Camera3d>>,
    light_views: Query<(&ExtractedView, &LightEntity), With<ShadowView>>,
    directional: Query<&ExtractedDirectionalLight>,
    mut views: ResMut<Views>,
    stats: Res<TreelodStats>,
) {
    if device.is_changed() {
        // A new device (the first, or after a device loss): nothing made on the old one stays.
        views.views.clear();
    }
    let missing = Renderer::required_features() - device.features();
    if !missing.is_empty() {
        if !views.unsupported {
            error!("treelod: the render device lacks {missing:?}; trees are not drawn");
            views.unsupported = true;
        }
        return;
    }
    let scene = &extracted.scene;
    let views = &mut *views;
    // A camera gone or switched off (not extracted) releases its renderer; its last counts stay.
    views.views.retain(|entity, _| cameras.contains(*entity) && !scene.instances.is_empty());
    if scene.instances.is_empty() {
        return;
    }
    for (entity, main_entity, view, target, depth, lights, shadow_bindings) in &cameras {
        if view.clip_from_view.w_axis.w == 1.0 {
            // Nothing drawn, not even a renderer's last selection from before the switch.
            views.views.remove(&entity);
            if !views.orthographic_reported {
                warn!("treelod: trees are drawn for perspective cameras only; camera {main_entity:?} is orthographic");
                views.orthographic_reported = true;
            }
            continue;
        }
        let formats = RendererFormats {
            color: target.main_texture_format(),
            depth: depth.texture().format(),
            sample_count: depth.texture().sample_count(),
        };
        let stale = views.views.get(&entity).is_some_and(|v| {
            v.renderer.formats() != formats
                || v.models
                    .iter()
                    .any(|(id, (container, _))| !scene.models.iter().any(|(m, c)| m == id && Arc::ptr_eq(c, container)))
        });
        if stale {
            // New formats, or a container replaced or gone: the renderer cannot drop a model.
            views.views.remove(&entity);
        }
        let entry = views.views.entry(entity).or_insert_with(|| ViewRenderer {
            renderer: Renderer::with_depth_convention(
                device.wgpu_device(),
                formats,
                extracted.settings,
                DepthConvention::Reverse,
            ),
            models: HashMap::new(),
            revision: None,
            instances: 0,
            gpu_refused: false,
            bevy_shadows: Vec::new(),
            receive_refused: false,
        });
        let mut added = false;
        for (id, container) in &scene.models {
            if !entry.models.contains_key(id) {
                added = true;
                let model = entry
                    .renderer
                    .add_model(device.wgpu_device(), &queue, Arc::clone(container))
                    .map_err(|e| error!("treelod: cannot draw container {id:?}: {e}"))
                    .ok();
                entry.models.insert(*id, (Arc::clone(container), model));
            }
        }
        if entry.revision != Some(scene.revision) {
            let ids: Vec<Option<ModelId>> =
                scene.models.iter().map(|(id, _)| entry.models.get(id).and_then(|(_, model)| *model)).collect();
            let instances: Vec<Instance> = scene
                .instances
                .iter()
                .filter_map(|&(model, transform)| Some(Instance { model: (*ids.get(model as usize)?)?, transform }))
                .collect();
            entry.renderer.set_instances(&instances);
            entry.instances = instances.len();
            entry.revision = Some(scene.revision);
        }
        *entry.renderer.settings_mut() = extracted.settings;
        if !extracted.gpu_selection {
            if entry.renderer.gpu_selection_enabled() {
                entry.renderer.disable_gpu_selection();
            }
            entry.gpu_refused = false;
        } else if (added || !entry.renderer.gpu_selection_enabled()) && !entry.gpu_refused {
            // Made anew with every model: a model added since is not in the GPU's tables.
            if let Err(e) = entry.renderer.enable_gpu_selection(device.wgpu_device(), &queue) {
                error!("treelod: camera {main_entity:?} selects on the CPU: {e}");
                entry.gpu_refused = true;
            }
        }
        // Bevy's directional shadow cascades of this camera: the trees are drawn into them by
        // `draw_shadows`, and receive those of the light that is their sun.
        let mut host = Vec::new();
        let mut received = Vec::new();
        entry.bevy_shadows.clear();
        let sun = extracted.settings.sun.normalize_or_zero();
        let mut sun_light = None;
        // A light's cascades are the layers of Bevy's directional shadow texture in the order its
        // views are listed, each light's in turn.
        let directional_views = lights.map_or(&[][..], |l| &l.lights[..]).iter().filter_map(|&light| {
            let (light_view, kind) = light_views.get(light).ok()?;
            let LightEntity::Directional { light_entity, .. } = *kind else { return None };
            Some((light, light_view, light_entity))
        });
        for ((light, light_view, light_entity), layer) in directional_views.zip(0u32..) {
            let clip_from_world = to_glam(
                light_view
                    .clip_from_world
                    .unwrap_or_else(|| light_view.clip_from_view * light_view.world_from_view.to_matrix().inverse()),
            );
            if extracted.cast_bevy_shadows {
                host.push(HostShadowView { clip_from_world, resolution: light_view.viewport.z });
                entry.bevy_shadows.push(light);
            }
            // The first light shining from the sun's direction.
            let is_sun = || {
                directional.get(light_entity).is_ok_and(|l| {
                    glam::Vec3::from_array(l.transform.back().to_array()).normalize_or_zero().dot(sun) > 0.9999
                })
            };
            if extracted.receive_bevy_shadows && sun_light.is_none_or(|s| s == light_entity) && is_sun() {
                sun_light = Some(light_entity);
                received.push(HostShadowCascade { clip_from_world, layer });
            }
        }
        entry.renderer.set_host_shadow_views(device.wgpu_device(), CORE_3D_SHADOW_MAP_FORMAT, &host);
        match shadow_bindings {
            Some(bindings) if !received.is_empty() => {
                let maps: &wgpu::Texture = &bindings.directional_light_depth_texture;
                match entry.renderer.receive_host_shadows(device.wgpu_device(), &queue, maps, &received) {
                    Ok(_) => entry.receive_refused = false,
                    Err(e) => {
                        if !entry.receive_refused {
                            error!("treelod: camera {main_entity:?} cannot receive Bevy's shadow maps: {e}");
                            entry.receive_refused = true;
                        }
                    }
                }
            }
            _ => entry.renderer.stop_receiving_host_shadows(),
        }
        let camera = Camera::from_matrices(
            to_glam(view.world_from_view.to_matrix().inverse()),
            to_glam(view.clip_from_view),
            view.viewport.z,
            view.viewport.w,
        );
        let frame = entry.renderer.prepare(device.wgpu_device(), &queue, &camera);
        stats.insert(main_entity.id(), frame);
    }
}

/// Casts the current view's trees into the shadow cascades of Bevy's directional lights that
/// `prepare` named ([`crate::TreelodSettings::cast_bevy_shadows`]): one depth-only pass per
/// cascade over Bevy's map, after Bevy's own casters drew into it and before the main pass,
/// whose receivers sample it.
fn draw_shadows(
    view: ViewQuery<&ExtractedView>,
    views: Res<Views>,
    shadow_views: Query<&ShadowView>,
    mut ctx: RenderContext,
) {
    let Some(entry) = views.views.get(&view.entity()) else { return };
    if entry.instances == 0 {
        return;
    }
    for (k, light) in entry.bevy_shadows.iter().enumerate() {
        let Ok(shadow) = shadow_views.get(*light) else { continue };
        let mut pass = ctx.begin_tracked_render_pass(wgpu::RenderPassDescriptor {
            label: Some("treelod shadow"),
            color_attachments: &[],
            // Loaded where Bevy's casters drew first this frame, cleared otherwise.
            depth_stencil_attachment: Some(shadow.depth_attachment.get_attachment(wgpu::StoreOp::Store)),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        entry.renderer.render_host_shadow(k, pass.wgpu_pass());
    }
}

/// Draws the current view's trees: its cascades first when [`Settings::shadows`] is on, then a
/// pass over the view's colour target and depth buffer, both loaded and stored; then, where the
/// settings use the trees' visible fractions ([`Settings::measures_occlusion`]), measures them
/// in that depth buffer ([`Renderer::measure_occlusion`]), Bevy's opaque meshes included, for
/// the choices of later frames.
fn draw(
    view: ViewQuery<(&ExtractedCamera, &ViewTarget, &ViewDepthStencilTexture, Option<&MainPassResolutionOverride>)>,
    mut views: ResMut<Views>,
    device: Res<RenderDevice>,
    mut ctx: RenderContext,
) {
    let Some(entry) = views.views.get_mut(&view.entity()) else { return };
    if entry.instances == 0 {
        return;
    }
    let (camera, target, depth, resolution_override) = view.into_inner();
    entry.renderer.render_shadows(ctx.command_encoder());
    let color_attachments = [Some(target.get_color_attachment())];
    let mut pass = ctx.begin_tracked_render_pass(wgpu::RenderPassDescriptor {
        label: Some("treelod"),
        color_attachments: &color_attachments,
        depth_stencil_attachment: Some(depth.get_attachment(wgpu::StoreOp::Store)),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    if let Some(viewport) = Viewport::from_viewport_and_override(camera.viewport.as_ref(), resolution_override) {
        pass.set_camera_viewport(&viewport);
    }
    entry.renderer.render(pass.wgpu_pass());
    drop(pass);
    if occlusion_measurable(camera, depth, resolution_override.is_some()) {
        let depth_view: &wgpu::TextureView = &depth.attachment.texture.default_view;
        entry.renderer.measure_occlusion(device.wgpu_device(), ctx.command_encoder(), depth_view);
    }
}

/// Whether the trees' visible fractions can be measured in a view's depth buffer: it can be
/// sampled (`TEXTURE_BINDING`, which [`crate::samplable_depth`] asks of Bevy's `Camera3d` while the
/// settings measure occlusion; not yet in the frame they start to), and the view's pixels are the
/// buffer's from its corner on, as the measurement reads them: no viewport offset, no main-pass
/// resolution override. Elsewhere every tree counts as fully visible.
fn occlusion_measurable(camera: &ExtractedCamera, depth: &ViewDepthStencilTexture, resolution_override: bool) -> bool {
    let at_corner = camera.viewport.as_ref().is_none_or(|v| v.physical_position == bevy_math::UVec2::ZERO);
    depth.texture().usage().contains(wgpu::TextureUsages::TEXTURE_BINDING) && at_corner && !resolution_override
}
