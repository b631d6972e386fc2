//! glTF 2.0 import: every scene node's triangle primitives, with world transforms applied, into a
//! [`Scene`] in metres, Y up (glTF's own conventions, so the unit scale is 1).
//!
//! Buffers come from the GLB binary chunk, data URIs or files beside a `.gltf`; base-colour
//! textures are decoded (PNG, JPEG) and kept with their original bytes. What cannot be read is a
//! typed error naming the file (compression extensions, missing buffers, indices out of range);
//! what can be skipped is a warning naming the primitive (points and lines, unknown image types).

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use base64::Engine as _;
use glam::{Mat3, Mat4, Vec3};
use sha2::Digest as _;

use crate::error::BuildError;
use crate::scene::{AlphaMode, Image, ImageEncoding, Material, Part, Scene, SourceInfo};

/// Extensions that change how geometry or images are stored, which treelod does not decode.
const UNDECODED: [&str; 3] = ["KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_texture_basisu"];

/// The name a tree imported from `path` gets: the file stem (`"tree"` if there is none). Outputs
/// written to a directory are named after it.
#[must_use]
pub fn scene_name(path: &Path) -> String {
    path.file_stem().map_or_else(|| "tree".to_owned(), |s| s.to_string_lossy().into_owned())
}

/// The content hash an import records for a source file of these bytes (spec §7.1
/// `Source::content_hash`): `"sha256:<lowercase hex>"`.
#[must_use]
pub fn content_hash(bytes: &[u8]) -> String {
    format!("sha256:{}", hex(&sha2::Sha256::digest(bytes)))
}

/// Reads the glTF (`.glb` or `.gltf`) at `path`.
///
/// # Errors
/// [`BuildError::Io`] if the file cannot be read; the other variants for a file that is not
/// valid glTF 2.0 or needs a feature treelod lacks.
pub fn import_gltf(path: &Path) -> Result<Scene, BuildError> {
    let bytes = std::fs::read(path).map_err(|source| BuildError::Io { path: path.to_owned(), source })?;
    import_gltf_bytes(&bytes, path, path.parent())
}

/// Reads a glTF held in memory. `path` names it in messages and metadata; `base_dir` resolves
/// relative buffer and image URIs (none: such URIs are missing).
///
/// # Errors
/// As [`import_gltf`].
pub fn import_gltf_bytes(bytes: &[u8], path: &Path, base_dir: Option<&Path>) -> Result<Scene, BuildError> {
    let gltf_error = |message: String| BuildError::Gltf { path: path.to_owned(), message };
    // As `gltf::Gltf::from_slice`, but parsed once and with the binary chunk borrowed from `bytes`
    // rather than copied; the required extensions are checked before validation, which would fail
    // on an undecoded one with a less helpful message.
    let (root, blob): (gltf::json::Root, Option<Cow<'_, [u8]>>) = if bytes.starts_with(b"glTF") {
        let glb = gltf::binary::Glb::from_slice(bytes).map_err(|e| gltf_error(e.to_string()))?;
        let root = gltf::json::deserialize::from_slice(&glb.json)
            .map_err(|e| gltf_error(gltf::Error::Deserialize(e).to_string()))?;
        (root, glb.bin)
    } else {
        let root = gltf::json::deserialize::from_slice(bytes)
            .map_err(|e| gltf_error(gltf::Error::Deserialize(e).to_string()))?;
        (root, None)
    };
    if let Some(ext) = root.extensions_required.iter().find(|ext| UNDECODED.contains(&ext.as_str())) {
        return Err(BuildError::Unsupported {
            path: path.to_owned(),
            what: format!("required extension {ext} (decode it first, e.g. with gltf-transform)"),
        });
    }
    // gltf-json's validation indexes `accessors` with a primitive's POSITION index unchecked
    // (gltf-json 1.4.1, mesh.rs): an index past the end would panic there, so it is refused here.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let position = gltf::json::validation::Checked::Valid(gltf::json::mesh::Semantic::Positions);
            if let Some(index) = primitive.attributes.get(&position)
                && index.value() >= root.accessors.len()
            {
                return Err(gltf_error(format!(
                    "invalid: meshes[{m}].primitives[{p}].attributes.POSITION: accessor {} does not exist ({} accessors)",
                    index.value(),
                    root.accessors.len()
                )));
            }
        }
    }
    let document = match gltf::Document::from_json(root) {
        Ok(d) => d,
        Err(gltf::Error::Validation(errors)) => {
            let list: Vec<String> = errors.iter().take(3).map(|(p, e)| format!("{p}: {e}")).collect();
            return Err(gltf_error(format!("invalid: {}", list.join("; "))));
        }
        Err(e) => return Err(gltf_error(e.to_string())),
    };
    let buffers = load_buffers(&document, blob, path, base_dir)?;
    let mut scene = Scene {
        name: scene_name(path),
        source: SourceInfo {
            path: path.to_string_lossy().replace('\\', "/"),
            content_hash: content_hash(bytes),
            byte_length: bytes.len() as u64,
            unit_scale: 1.0,
        },
        ..Scene::default()
    };
    scene.images = load_images(&document, &buffers, path, base_dir, &mut scene.warnings)?;
    let mut tex_coord_sets = Vec::new();
    for m in document.materials() {
        let pbr = m.pbr_metallic_roughness();
        let texture = pbr.base_color_texture();
        tex_coord_sets.push(texture.as_ref().map_or(0, gltf::texture::Info::tex_coord));
        let image = texture.map(|t| t.texture().source().index()).filter(|&i| scene.images[i].width > 0);
        scene.materials.push(Material {
            name: m.name().unwrap_or("").to_owned(),
            base_color: pbr.base_color_factor(),
            image,
            alpha_mode: match m.alpha_mode() {
                gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
                gltf::material::AlphaMode::Mask => AlphaMode::Mask,
                gltf::material::AlphaMode::Blend => AlphaMode::Blend,
            },
            alpha_cutoff: m.alpha_cutoff().unwrap_or(0.5),
            double_sided: m.double_sided(),
        });
    }
    let default_material = scene.materials.len();
    let roots: Vec<gltf::Node> = match document.default_scene().or_else(|| document.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let children: std::collections::BTreeSet<usize> =
                document.nodes().flat_map(|n| n.children().map(|c| c.index())).collect();
            document.nodes().filter(|n| !children.contains(&n.index())).collect()
        }
    };
    let mut stack: Vec<(gltf::Node, Mat4, usize)> = roots.into_iter().rev().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 256 {
            return Err(gltf_error("node hierarchy deeper than 256 levels (a cycle?)".into()));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            for primitive in mesh.primitives() {
                let material = primitive.material().index().unwrap_or(default_material);
                let set = tex_coord_sets.get(material).copied().unwrap_or(0);
                let part = read_primitive(
                    &primitive,
                    mesh.name().unwrap_or(""),
                    &buffers,
                    world,
                    set,
                    path,
                    &mut scene.warnings,
                )?;
                if let Some(mut part) = part {
                    part.node_name = node.name().unwrap_or("").to_owned();
                    part.mesh_name = mesh.name().unwrap_or("").to_owned();
                    part.material = material;
                    scene.parts.push(part);
                }
            }
        }
        stack.extend(node.children().collect::<Vec<_>>().into_iter().rev().map(|c| (c, world, depth + 1)));
    }
    if scene.parts.iter().any(|p| p.material == default_material) {
        scene.materials.push(Material { base_color: [1.0; 4], alpha_cutoff: 0.5, ..Material::default() });
    }
    Ok(scene)
}

fn load_buffers<'a>(
    document: &gltf::Document,
    mut blob: Option<Cow<'a, [u8]>>,
    path: &Path,
    base_dir: Option<&Path>,
) -> Result<Vec<Cow<'a, [u8]>>, BuildError> {
    let mut out = Vec::new();
    for buffer in document.buffers() {
        let missing = |uri: &str, reason: String| BuildError::MissingBuffer {
            path: path.to_owned(),
            index: buffer.index(),
            uri: uri.to_owned(),
            reason,
        };
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => {
                blob.take().ok_or_else(|| missing("GLB binary chunk", "the file has no binary chunk".into()))?
            }
            gltf::buffer::Source::Uri(uri) => {
                Cow::Owned(read_uri(uri, base_dir).map_err(|reason| missing(uri, reason))?)
            }
        };
        if data.len() < buffer.length() {
            let uri = match buffer.source() {
                gltf::buffer::Source::Bin => "GLB binary chunk",
                gltf::buffer::Source::Uri(u) => u,
            };
            return Err(missing(uri, format!("{} bytes, the file declares {}", data.len(), buffer.length())));
        }
        out.push(data);
    }
    Ok(out)
}

/// Bytes of a data URI or of a file relative to `base_dir`.
fn read_uri(uri: &str, base_dir: Option<&Path>) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, data) = rest.split_once(";base64,").ok_or("a data URI that is not base64")?;
        return base64::engine::general_purpose::STANDARD.decode(data).map_err(|e| format!("bad base64: {e}"));
    }
    let dir = base_dir.ok_or("no directory to resolve a relative URI")?;
    let decoded = percent_decode(uri);
    let file: PathBuf = dir.join(&decoded);
    std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))
}

fn percent_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%'
            && let Some(v) = s.get(i + 1..i + 3).and_then(|h| u8::from_str_radix(h, 16).ok())
        {
            out.push(v);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn load_images(
    document: &gltf::Document,
    buffers: &[Cow<'_, [u8]>],
    path: &Path,
    base_dir: Option<&Path>,
    warnings: &mut Vec<String>,
) -> Result<Vec<Image>, BuildError> {
    let mut images = Vec::new();
    for image in document.images() {
        let index = image.index();
        let (bytes, mime) = match image.source() {
            gltf::image::Source::View { view, mime_type } => {
                let data = buffers
                    .get(view.buffer().index())
                    .and_then(|b| b.get(view.offset()..view.offset() + view.length()));
                let data = data.ok_or_else(|| BuildError::Image {
                    path: path.to_owned(),
                    index,
                    message: "its buffer view lies outside the buffer".into(),
                })?;
                (data.to_vec(), Some(mime_type.to_owned()))
            }
            gltf::image::Source::Uri { uri, mime_type } => {
                let data = read_uri(uri, base_dir).map_err(|message| BuildError::Image {
                    path: path.to_owned(),
                    index,
                    message,
                })?;
                (data, mime_type.map(str::to_owned))
            }
        };
        let decoded = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
            treelod_format::image::decode_png(&bytes).map(|(w, h, rgba)| (w, h, rgba, ImageEncoding::Png))
        } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
            treelod_format::image::decode_jpeg(&bytes).map(|(w, h, rgba)| (w, h, rgba, ImageEncoding::Jpeg))
        } else {
            warnings.push(format!(
                "image {index} ({}) is neither PNG nor JPEG; its materials are drawn untextured",
                mime.unwrap_or_default()
            ));
            images.push(Image {
                width: 0,
                height: 0,
                rgba: Vec::new(),
                encoded: Vec::new(),
                encoding: ImageEncoding::Raw,
            });
            continue;
        };
        let (width, height, rgba, encoding) =
            decoded.map_err(|message| BuildError::Image { path: path.to_owned(), index, message })?;
        images.push(Image { width, height, rgba, encoded: bytes, encoding });
    }
    Ok(images)
}

/// One primitive as a [`Part`] in world space, or `None` (with a warning) if it holds no triangles.
fn read_primitive(
    primitive: &gltf::Primitive,
    mesh_name: &str,
    buffers: &[Cow<'_, [u8]>],
    world: Mat4,
    tex_coord_set: u32,
    path: &Path,
    warnings: &mut Vec<String>,
) -> Result<Option<Part>, BuildError> {
    let label = format!("mesh {mesh_name:?} primitive {}", primitive.index());
    let reader = primitive.reader(|b| buffers.get(b.index()).map(|c| &**c));
    let Some(positions) = reader.read_positions() else {
        warnings.push(format!("{label}: no positions, skipped"));
        return Ok(None);
    };
    let positions: Vec<[f32; 3]> = positions.map(|p| world.transform_point3(Vec3::from_array(p)).to_array()).collect();
    let n = positions.len();
    let corners: Vec<u32> = match reader.read_indices() {
        Some(indices) => indices.into_u32().collect(),
        #[expect(clippy::cast_possible_truncation, reason = "glTF accessor counts are u32")]
        None => (0..n as u32).collect(),
    };
    if let Some(bad) = corners.iter().find(|&&i| i as usize >= n) {
        return Err(BuildError::InvalidData {
            path: path.to_owned(),
            what: format!("{label}: index {bad} but only {n} vertices"),
        });
    }
    let triangles: Vec<[u32; 3]> = match primitive.mode() {
        gltf::mesh::Mode::Triangles => corners.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        gltf::mesh::Mode::TriangleStrip => corners
            .windows(3)
            .enumerate()
            .map(|(i, t)| if i % 2 == 0 { [t[0], t[1], t[2]] } else { [t[1], t[0], t[2]] })
            .collect(),
        gltf::mesh::Mode::TriangleFan => corners.windows(2).skip(1).map(|t| [corners[0], t[0], t[1]]).collect(),
        other => {
            warnings.push(format!("{label}: {other:?} primitive is not triangles, skipped"));
            return Ok(None);
        }
    };
    let flip = world.determinant() < 0.0;
    let triangles: Vec<[u32; 3]> = triangles.into_iter().map(|t| if flip { [t[0], t[2], t[1]] } else { t }).collect();
    let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
    let normals: Vec<[f32; 3]> = match reader.read_normals() {
        Some(ns) => ns.map(|v| (normal_matrix * Vec3::from_array(v)).normalize_or(Vec3::Y).to_array()).collect(),
        None => {
            warnings.push(format!("{label}: no normals, computed from the faces"));
            face_normals(&positions, &triangles)
        }
    };
    let uvs: Vec<[f32; 2]> = reader.read_tex_coords(tex_coord_set).map(|t| t.into_f32().collect()).unwrap_or_default();
    let colors: Vec<[f32; 4]> = reader.read_colors(0).map(|c| c.into_rgba_f32().collect()).unwrap_or_default();
    if normals.len() != n || (!uvs.is_empty() && uvs.len() != n) || (!colors.is_empty() && colors.len() != n) {
        return Err(BuildError::InvalidData {
            path: path.to_owned(),
            what: format!("{label}: attribute counts differ from the {n} positions"),
        });
    }
    Ok(Some(Part {
        primitive: primitive.index(),
        positions,
        normals,
        uvs,
        colors,
        triangles,
        material: 0,
        node_name: String::new(),
        mesh_name: String::new(),
    }))
}

/// Area-weighted vertex normals.
fn face_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| Vec3::from_array(positions[i as usize]));
        let n = (b - a).cross(c - a);
        if n.is_finite() {
            for &i in t {
                acc[i as usize] += n;
            }
        }
    }
    acc.into_iter().map(|n| n.normalize_or(Vec3::Y).to_array()).collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
