//! The build's input: triangle soups with materials and decoded textures, in block space.
//!
//! Importers (glTF import, the procedural demo tree) produce a
//! [`Scene`]; every later stage reads only this, never the source format.

/// One source tree (or one source file) ready to build.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// Name of the tree, e.g. the file stem.
    pub name: String,
    /// Where it came from.
    pub source: SourceInfo,
    /// Triangle groups, each with one material; positions already in metres, Y up, with every node
    /// transform applied.
    pub parts: Vec<Part>,
    /// Materials referenced by [`Part::material`].
    pub materials: Vec<Material>,
    /// Decoded textures referenced by [`Material::image`].
    pub images: Vec<Image>,
    /// Things the importer skipped or fixed, one sentence each, naming the primitive.
    pub warnings: Vec<String>,
}

/// Provenance of a scene, recorded in the container's metadata.
#[derive(Clone, Debug, Default)]
pub struct SourceInfo {
    /// Path as given, `/` separators; empty for generated scenes.
    pub path: String,
    /// `"sha256:<hex>"` of the source file; empty for generated scenes.
    pub content_hash: String,
    /// Size of the source file in bytes.
    pub byte_length: u64,
    /// Metres per source unit applied on import.
    pub unit_scale: f32,
}

/// A group of triangles sharing one material: one glTF primitive under one node.
#[derive(Clone, Debug, Default)]
pub struct Part {
    /// Name of the node that instanced the mesh, empty if none.
    pub node_name: String,
    /// Name of the mesh, empty if none.
    pub mesh_name: String,
    /// Index of the primitive in its mesh.
    pub primitive: usize,
    /// Index into [`Scene::materials`].
    pub material: usize,
    /// Vertex positions, metres, block space.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals, one per vertex.
    pub normals: Vec<[f32; 3]>,
    /// Texture coordinates, one per vertex; empty if the source has none.
    pub uvs: Vec<[f32; 2]>,
    /// Linear RGBA vertex colours, one per vertex; empty if the source has none.
    pub colors: Vec<[f32; 4]>,
    /// Triangles as vertex indices, counter-clockwise front faces.
    pub triangles: Vec<[u32; 3]>,
}

impl Part {
    /// A readable label for messages: `mesh "leaves" primitive 0 (node "tree")`.
    #[must_use]
    pub fn label(&self) -> String {
        format!("mesh \"{}\" primitive {} (node \"{}\")", self.mesh_name, self.primitive, self.node_name)
    }
}

/// How a material's alpha is used (glTF `alphaMode`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AlphaMode {
    /// Alpha ignored.
    #[default]
    Opaque,
    /// Alpha-tested against the cutoff.
    Mask,
    /// Alpha-blended.
    Blend,
}

/// Leaf or bark: decides which representations a triangle feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// Branches and trunk.
    Bark,
    /// Leaves, needles, foliage cards.
    Leaf,
}

/// A material as the build needs it.
#[derive(Clone, Debug, Default)]
pub struct Material {
    /// Source name, empty if none.
    pub name: String,
    /// Linear RGBA factor (glTF `baseColorFactor`).
    pub base_color: [f32; 4],
    /// Index into [`Scene::images`] of the base-colour texture.
    pub image: Option<usize>,
    /// Alpha mode.
    pub alpha_mode: AlphaMode,
    /// Alpha-test threshold for [`AlphaMode::Mask`].
    pub alpha_cutoff: f32,
    /// Whether both faces are drawn.
    pub double_sided: bool,
}

/// The encoding a texture came in, kept so the container can store it unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageEncoding {
    /// A PNG file.
    Png,
    /// A JPEG file.
    Jpeg,
    /// Raw texels made by the build (the demo tree's generated leaf texture).
    Raw,
}

/// A decoded base-colour texture.
#[derive(Clone, Debug)]
pub struct Image {
    /// Texels across.
    pub width: u32,
    /// Texels down.
    pub height: u32,
    /// `width · height` RGBA8 texels, rows top to bottom, RGB sRGB-encoded.
    pub rgba: Vec<u8>,
    /// The source file's bytes for [`ImageEncoding::Png`] and [`ImageEncoding::Jpeg`], else empty.
    pub encoded: Vec<u8>,
    /// How `encoded` is encoded.
    pub encoding: ImageEncoding,
}

impl Image {
    /// An image no material samples (one the import skips or cannot decode): no texels, so a
    /// material with it is drawn untextured.
    pub const NONE: Self =
        Self { width: 0, height: 0, rgba: Vec::new(), encoded: Vec::new(), encoding: ImageEncoding::Raw };

    /// The texel at integer coordinates, wrapped (glTF's default `REPEAT` sampler).
    #[must_use]
    pub fn texel(&self, x: i64, y: i64) -> [u8; 4] {
        let w = i64::from(self.width.max(1));
        let h = i64::from(self.height.max(1));
        // Most coordinates are in range already: no division for them.
        let (x, y) = (
            if (0..w).contains(&x) { x } else { x.rem_euclid(w) },
            if (0..h).contains(&y) { y } else { y.rem_euclid(h) },
        );
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "rem_euclid is in 0..w·h")]
        let i = (y * w + x) as usize * 4;
        match self.rgba.get(i..i + 4) {
            Some(t) => [t[0], t[1], t[2], t[3]],
            None => [255; 4],
        }
    }
}
