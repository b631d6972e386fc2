//! Trees in the main world: the component that places them, and the scene collected from every
//! such component for the render world, rebuilt only when something changed.

use std::sync::Arc;

use bevy_asset::{AssetEvent, AssetId, Assets, Handle};
use bevy_camera::visibility::{InheritedVisibility, Visibility};
use bevy_ecs::prelude::*;
use bevy_transform::components::{GlobalTransform, Transform};
use treelod_format::Container;

use crate::asset::TreelodContainer;

/// Places one tree, or a forest of instances of one container, in the world.
///
/// Each instance is drawn at the entity's [`GlobalTransform`] times its own [`Transform`]
/// (rotation, translation and a uniform scale: the renderer measures a tree's size on screen by
/// its largest scale). The entity's [`Visibility`] hides or shows all of them; the renderer culls
/// instances against each camera's frustum itself. Until the container has loaded, nothing is
/// drawn.
///
/// ```no_run
/// # use bevy_ecs::prelude::*;
/// # use bevy_asset::AssetServer;
/// # use bevy_transform::components::Transform;
/// # use treelod_bevy::TreelodForest;
/// fn spawn(mut commands: Commands, assets: Res<AssetServer>) {
///     let oak = assets.load("oak.treelod");
///     commands.spawn((TreelodForest::tree(oak.clone()), Transform::from_xyz(0.0, 0.0, -10.0)));
///     let rows = (0..100).map(|i| Transform::from_xyz((i % 10) as f32 * 8.0, 0.0, (i / 10) as f32 * 8.0));
///     commands.spawn(TreelodForest::new(oak, rows));
/// }
/// ```
#[derive(Component, Clone, Debug)]
#[require(Transform, Visibility)]
pub struct TreelodForest {
    /// The container every instance draws.
    pub container: Handle<TreelodContainer>,
    /// The instances, relative to the entity.
    pub instances: Vec<Transform>,
}

impl TreelodForest {
    /// One tree at the entity's transform.
    #[must_use]
    pub fn tree(container: Handle<TreelodContainer>) -> Self {
        Self { container, instances: vec![Transform::IDENTITY] }
    }

    /// Instances of `container` at `instances`, relative to the entity.
    #[must_use]
    pub fn new(container: Handle<TreelodContainer>, instances: impl IntoIterator<Item = Transform>) -> Self {
        Self { container, instances: instances.into_iter().collect() }
    }
}

/// Every loaded container that a visible forest uses, and every instance, world space.
#[derive(Resource, Clone, Debug, Default)]
pub(crate) struct TreelodScene {
    /// The containers, each once.
    pub models: Vec<(AssetId<TreelodContainer>, Arc<Container>)>,
    /// Index into `models`, world from model.
    pub instances: Vec<(u32, glam::Mat4)>,
    /// Counts the rebuilds: the render world sets its instances again when it changes.
    pub revision: u64,
}

/// Bevy's matrix (its own glam) as the workspace's glam matrix.
pub(crate) fn to_glam(matrix: bevy_math::Mat4) -> glam::Mat4 {
    glam::Mat4::from_cols_array(&matrix.to_cols_array())
}

/// Forests added, changed, moved, shown or hidden since the system last ran.
type ForestChanged =
    (With<TreelodForest>, Or<(Changed<TreelodForest>, Changed<GlobalTransform>, Changed<InheritedVisibility>)>);

/// Rebuilds [`TreelodScene`] when a forest was added, changed, moved, shown, hidden or removed,
/// or a container loaded, changed or went away; otherwise leaves it untouched (so its change
/// tick says whether to extract it).
pub(crate) fn collect_scene(
    forests: Query<(&TreelodForest, &GlobalTransform, &InheritedVisibility)>,
    changed: Query<(), ForestChanged>,
    mut removed: RemovedComponents<TreelodForest>,
    mut asset_events: MessageReader<AssetEvent<TreelodContainer>>,
    containers: Res<Assets<TreelodContainer>>,
    mut scene: ResMut<TreelodScene>,
) {
    // Both readers are drained every frame, so that old messages do not count again.
    let removed_any = removed.read().count() > 0;
    let assets_changed = asset_events.read().count() > 0;
    if !removed_any && !assets_changed && changed.is_empty() {
        return;
    }
    let mut models: Vec<(AssetId<TreelodContainer>, Arc<Container>)> = Vec::new();
    let mut instances = Vec::new();
    for (forest, global, visibility) in &forests {
        if !visibility.get() || forest.instances.is_empty() {
            continue;
        }
        let id = forest.container.id();
        let Some(asset) = containers.get(id) else { continue };
        let model = match models.iter().position(|(m, _)| *m == id) {
            Some(model) => model,
            None => {
                models.push((id, Arc::clone(asset.container())));
                models.len() - 1
            }
        };
        let Ok(model) = u32::try_from(model) else { continue };
        let world = global.to_matrix();
        instances.extend(forest.instances.iter().map(|t| (model, to_glam(world * t.to_matrix()))));
    }
    let revision = scene.revision.wrapping_add(1);
    *scene = TreelodScene { models, instances, revision };
}
