//! `.treelod` containers as Bevy assets: the asset type, its loader (see [`TreelodLoader`] for
//! why it reads bytes rather than mapping files), and the loader's errors.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevy_asset::io::Reader;
use bevy_asset::{Asset, AssetLoader, LoadContext};
use bevy_reflect::TypePath;
use treelod_format::Container;

/// A `.treelod` container (spec: `format-spec/treelod.md`), validated and ready to draw.
///
/// Load one with the [`AssetServer`](bevy_asset::AssetServer) (`asset_server.load("tree.treelod")`,
/// through [`TreelodLoader`]) or make one with [`Self::open`] (memory-mapped) or
/// [`Self::from_bytes`] and add it to `Assets<TreelodContainer>`.
#[derive(Asset, TypePath, Clone, Debug)]
pub struct TreelodContainer {
    container: Arc<Container>,
}

impl TreelodContainer {
    /// Maps the file at `path` and validates it ([`Container::open`]): the container stays
    /// memory-mapped, and the renderer streams its triangles and points from the map.
    ///
    /// # Errors
    /// [`TreelodLoadError::Container`] if the file cannot be read or is not a valid container.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, TreelodLoadError> {
        let path = path.as_ref();
        Container::open(path)
            .map(Self::from)
            .map_err(|source| TreelodLoadError::Container { path: path.to_owned(), source })
    }

    /// Validates a container held in memory ([`Container::from_bytes`], which copies `bytes`
    /// into an aligned buffer of its own).
    ///
    /// # Errors
    /// [`TreelodLoadError::Container`] (with an empty path) if `bytes` are not a valid container.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, TreelodLoadError> {
        Container::from_bytes(bytes)
            .map(Self::from)
            .map_err(|source| TreelodLoadError::Container { path: PathBuf::new(), source })
    }

    /// The container, shared with the render world.
    #[must_use]
    pub fn container(&self) -> &Arc<Container> {
        &self.container
    }
}

impl From<Container> for TreelodContainer {
    fn from(container: Container) -> Self {
        Self { container: Arc::new(container) }
    }
}

impl From<Arc<Container>> for TreelodContainer {
    fn from(container: Arc<Container>) -> Self {
        Self { container }
    }
}

/// Why a `.treelod` asset could not be loaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TreelodLoadError {
    /// Bevy's asset reader failed.
    #[error("{path}: cannot read the asset: {source}")]
    Read {
        /// The asset path.
        path: PathBuf,
        /// The reader's error.
        source: std::io::Error,
    },
    /// The bytes are not a valid container (corrupt, truncated, a newer major version...).
    #[error("{path}: not a valid .treelod container: {source}")]
    Container {
        /// The asset path (empty for [`TreelodContainer::from_bytes`]).
        path: PathBuf,
        /// What the container reader found.
        source: treelod_format::Error,
    },
}

/// Loads `.treelod` files as [`TreelodContainer`]s (registered by
/// [`TreelodPlugin`](crate::TreelodPlugin)).
///
/// The loader reads the bytes Bevy's asset reader gives and opens the container from them
/// ([`Container::from_bytes`], validated once as [`Container::open`] does). Bevy's readers are
/// not necessarily files (embedded assets, processed assets, HTTP sources, Android packages), and
/// a loader is not told where a file lies on disk, so a memory map is not something it can make in
/// general: a loaded container lives in memory, the size of its file. To keep a large container
/// memory-mapped instead, open it with [`TreelodContainer::open`] and add it to
/// `Assets<TreelodContainer>`; the renderer streams from either the same way.
#[derive(Clone, Copy, Debug, Default, TypePath)]
pub struct TreelodLoader;

impl AssetLoader for TreelodLoader {
    type Asset = TreelodContainer;
    type Settings = ();
    type Error = TreelodLoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        _settings: &(),
        load_context: &mut LoadContext<'_>,
    ) -> Result<TreelodContainer, TreelodLoadError> {
        let path = || PathBuf::from(load_context.path().to_string());
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes).await.map_err(|source| TreelodLoadError::Read { path: path(), source })?;
        Container::from_bytes(&bytes)
            .map(TreelodContainer::from)
            .map_err(|source| TreelodLoadError::Container { path: path(), source })
    }

    fn extensions(&self) -> &[&str] {
        &["treelod"]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_that_are_no_container_are_a_typed_error() {
        let Err(error) = TreelodContainer::from_bytes(b"not a container") else { panic!("opened garbage") };
        assert!(matches!(error, TreelodLoadError::Container { .. }), "{error:?}");
        assert!(error.to_string().contains("not a .treelod file"), "{error}");
    }

    #[test]
    fn a_missing_file_names_its_path() {
        let Err(error) = TreelodContainer::open("/nonexistent/tree.treelod") else { panic!("opened nothing") };
        assert!(error.to_string().starts_with("/nonexistent/tree.treelod: "), "{error}");
    }
}
