//! glTF 2.0 files made in code, for hostile-input tests and fuzzing of the importer: a small valid
//! tree ([`tree`]) whose JSON and binary buffer a test corrupts one field at a time, its valid
//! variants ([`valid_variants`]), and writers for the containers around it (GLB, data URIs, files
//! beside the model) and for the images inside it (PNG with stored deflate blocks, a JPEG header).
//!
//! Nothing here validates: the point is to make invalid files.
//!
//! ```
//! use treelod_tests::gltf::{tree, accessor};
//!
//! let mut doc = tree();
//! doc.json["accessors"][accessor::LEAF_INDICES]["componentType"] = 5126.into(); // FLOAT indices
//! let bytes = doc.to_gltf(); // one .gltf with the buffer as a data URI
//! assert!(bytes.starts_with(b"{"));
//! ```

use std::path::{Path, PathBuf};

use base64::Engine as _;
use serde_json::{Value, json};

/// glTF `componentType` values.
pub mod component {
    /// `BYTE`.
    pub const BYTE: u32 = 5120;
    /// `UNSIGNED_BYTE`.
    pub const UNSIGNED_BYTE: u32 = 5121;
    /// `SHORT`.
    pub const SHORT: u32 = 5122;
    /// `UNSIGNED_SHORT`.
    pub const UNSIGNED_SHORT: u32 = 5123;
    /// `UNSIGNED_INT`.
    pub const UNSIGNED_INT: u32 = 5125;
    /// `FLOAT`.
    pub const FLOAT: u32 = 5126;
}

/// Accessor indices of [`tree`]: accessor `i` reads buffer view `i + 1` (view 0 holds the PNG).
pub mod accessor {
    /// `meshes[0].primitives[0].attributes.POSITION` (leaves, `FLOAT VEC3`).
    pub const LEAF_POSITION: usize = 0;
    /// `meshes[0].primitives[0].attributes.NORMAL`.
    pub const LEAF_NORMAL: usize = 1;
    /// `meshes[0].primitives[0].attributes.TEXCOORD_0` (`FLOAT VEC2`).
    pub const LEAF_UV: usize = 2;
    /// `meshes[0].primitives[0].indices` (`UNSIGNED_SHORT`).
    pub const LEAF_INDICES: usize = 3;
    /// `meshes[1].primitives[0].attributes.POSITION` (bark).
    pub const BARK_POSITION: usize = 4;
    /// `meshes[1].primitives[0].attributes.NORMAL`.
    pub const BARK_NORMAL: usize = 5;
    /// `meshes[1].primitives[0].indices` (`UNSIGNED_INT`).
    pub const BARK_INDICES: usize = 6;
}

/// Leaf quads of [`tree`]; each has 4 vertices and 2 triangles.
pub const LEAF_QUADS: usize = 6;
/// Vertices of the leaf primitive of [`tree`].
pub const LEAF_VERTICES: usize = 4 * LEAF_QUADS;

/// A glTF document under construction: its JSON and the bytes of buffer 0.
///
/// Buffer 0's `uri` and `byteLength` are filled in by the writers unless the JSON already sets
/// them, so a test can declare a lying length or a hostile URI.
#[derive(Clone, Debug)]
pub struct Gltf {
    /// The JSON document.
    pub json: Value,
    /// Buffer 0.
    pub bin: Vec<u8>,
}

impl Default for Gltf {
    fn default() -> Self {
        Self::new()
    }
}

impl Gltf {
    /// An empty document (an asset and one empty scene).
    #[must_use]
    pub fn new() -> Self {
        Self {
            json: json!({
                "asset": {"version": "2.0", "generator": "treelod-tests"},
                "buffers": [{}],
                "bufferViews": [],
                "accessors": [],
                "images": [],
                "samplers": [],
                "textures": [],
                "materials": [],
                "meshes": [],
                "nodes": [],
                "scenes": [{"nodes": []}],
                "scene": 0,
            }),
            bin: Vec::new(),
        }
    }

    fn push(&mut self, array: &str, value: Value) -> usize {
        let list = self.json[array].as_array_mut().expect("an array");
        list.push(value);
        list.len() - 1
    }

    /// Appends `bytes` to buffer 0 at the next multiple of 4 and adds a buffer view of them.
    pub fn view(&mut self, bytes: &[u8], stride: Option<usize>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut view = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(stride) = stride {
            view["byteStride"] = stride.into();
        }
        self.bin.extend_from_slice(bytes);
        self.push("bufferViews", view)
    }

    /// Adds an accessor of `count` elements of `ty` (`"VEC3"`, …) at the start of `view`.
    pub fn accessor(&mut self, view: usize, component_type: u32, count: usize, ty: &str) -> usize {
        self.push("accessors", json!({"bufferView": view, "componentType": component_type, "count": count, "type": ty}))
    }

    /// Adds a `FLOAT VEC3` accessor of `values` (in a view of its own) with `min` and `max`.
    pub fn vec3(&mut self, values: &[[f32; 3]]) -> usize {
        let view = self.view(&f32_bytes(values.as_flattened()), None);
        let index = self.accessor(view, component::FLOAT, values.len(), "VEC3");
        let (lo, hi) = bounds(values);
        self.json["accessors"][index]["min"] = json!(lo);
        self.json["accessors"][index]["max"] = json!(hi);
        index
    }

    /// Adds a `FLOAT VEC2` accessor of `values`.
    pub fn vec2(&mut self, values: &[[f32; 2]]) -> usize {
        let view = self.view(&f32_bytes(values.as_flattened()), None);
        self.accessor(view, component::FLOAT, values.len(), "VEC2")
    }

    /// Adds an `UNSIGNED_SHORT SCALAR` index accessor.
    pub fn indices_u16(&mut self, indices: &[u16]) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(view, component::UNSIGNED_SHORT, indices.len(), "SCALAR")
    }

    /// Adds an `UNSIGNED_INT SCALAR` index accessor.
    pub fn indices_u32(&mut self, indices: &[u32]) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(view, component::UNSIGNED_INT, indices.len(), "SCALAR")
    }

    /// Adds an image stored in a buffer view.
    pub fn image(&mut self, bytes: &[u8], mime: &str) -> usize {
        let view = self.view(bytes, None);
        self.push("images", json!({"bufferView": view, "mimeType": mime}))
    }

    /// The bytes of buffer view `view` (as its JSON declares them) inside buffer 0.
    ///
    /// # Panics
    /// If the view does not lie inside buffer 0.
    pub fn view_bytes_mut(&mut self, view: usize) -> &mut [u8] {
        let field =
            |key: &str| usize::try_from(self.json["bufferViews"][view][key].as_u64().unwrap_or(0)).expect("fits usize");
        let (offset, length) = (field("byteOffset"), field("byteLength"));
        &mut self.bin[offset..offset + length]
    }

    /// Adds `value` to the JSON array `array` (`"nodes"`, `"meshes"`, …) and returns its index.
    pub fn add(&mut self, array: &str, value: Value) -> usize {
        if !self.json[array].is_array() {
            self.json[array] = json!([]);
        }
        self.push(array, value)
    }

    /// Declares `name` in `extensionsUsed`, and in `extensionsRequired` if `required`.
    pub fn use_extension(&mut self, name: &str, required: bool) {
        for (key, wanted) in [("extensionsUsed", true), ("extensionsRequired", required)] {
            if wanted {
                if !self.json[key].is_array() {
                    self.json[key] = json!([]);
                }
                self.json[key].as_array_mut().expect("an array").push(name.into());
            }
        }
    }

    /// The JSON with buffer 0 completed by `uri` (unless it has one) and its byte length (unless
    /// set) and empty arrays removed (glTF allows no empty top-level arrays).
    #[must_use]
    pub fn finished_json(&self, uri: Option<&str>) -> Value {
        let mut json = self.json.clone();
        if let Some(buffer) = json["buffers"].get_mut(0) {
            if buffer.get("byteLength").is_none() {
                buffer["byteLength"] = self.bin.len().into();
            }
            if let Some(uri) = uri
                && buffer.get("uri").is_none()
            {
                buffer["uri"] = uri.into();
            }
        }
        if let Some(object) = json.as_object_mut() {
            object.retain(|_, v| v.as_array().is_none_or(|a| !a.is_empty()));
        }
        json
    }

    /// A `.gltf` file: the JSON with buffer 0 as a base64 data URI.
    #[must_use]
    pub fn to_gltf(&self) -> Vec<u8> {
        let json = self.finished_json(Some(&data_uri("application/octet-stream", &self.bin)));
        serde_json::to_vec(&json).expect("serialises")
    }

    /// A `.glb` file: buffer 0 is the binary chunk.
    #[must_use]
    pub fn to_glb(&self) -> Vec<u8> {
        let json = serde_json::to_vec(&self.finished_json(None)).expect("serialises");
        glb(&json, Some(&self.bin))
    }

    /// Writes `dir/<name>.gltf` with buffer 0 as `dir/<name>.bin` (unless the JSON names another
    /// URI) and returns the `.gltf` path.
    ///
    /// # Panics
    /// If the files cannot be written.
    #[must_use]
    pub fn write_files(&self, dir: &Path, name: &str) -> PathBuf {
        let bin = format!("{name}.bin");
        std::fs::write(dir.join(&bin), &self.bin).expect("writes the buffer");
        let path = dir.join(format!("{name}.gltf"));
        let json = serde_json::to_vec(&self.finished_json(Some(&bin))).expect("serialises");
        std::fs::write(&path, json).expect("writes the glTF");
        path
    }
}

/// The componentwise minimum and maximum of `values` (glTF requires them of POSITION accessors).
#[must_use]
pub fn bounds<T: Copy + PartialOrd>(values: &[[T; 3]]) -> ([T; 3], [T; 3]) {
    let mut lo = values[0];
    let mut hi = values[0];
    for v in values {
        for k in 0..3 {
            if v[k] < lo[k] {
                lo[k] = v[k];
            }
            if v[k] > hi[k] {
                hi[k] = v[k];
            }
        }
    }
    (lo, hi)
}

/// Little-endian bytes of floats.
#[must_use]
pub fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|f| f.to_le_bytes()).collect()
}

/// A base64 data URI.
#[must_use]
pub fn data_uri(mime: &str, bytes: &[u8]) -> String {
    format!("data:{mime};base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
}

/// A GLB container (glTF 2.0 binary, version 2) of a JSON chunk and an optional binary chunk,
/// each padded to 4 bytes (JSON with spaces, binary with zeros).
#[must_use]
pub fn glb(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
    fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8], pad: u8) {
        let padded = data.len().next_multiple_of(4);
        out.extend_from_slice(&u32::try_from(padded).expect("under 4 GiB").to_le_bytes());
        out.extend_from_slice(kind);
        out.extend_from_slice(data);
        out.resize(out.len() + padded - data.len(), pad);
    }
    let mut out = b"glTF\x02\0\0\0\0\0\0\0".to_vec();
    chunk(&mut out, b"JSON", json, b' ');
    if let Some(bin) = bin {
        chunk(&mut out, b"BIN\0", bin, 0);
    }
    let length = u32::try_from(out.len()).expect("under 4 GiB");
    out[8..12].copy_from_slice(&length.to_le_bytes());
    out
}

/// The JSON and binary chunks of a GLB file, if it is one with well-formed chunk headers.
#[must_use]
pub fn split_glb(bytes: &[u8]) -> Option<(Vec<u8>, Option<Vec<u8>>)> {
    if bytes.len() < 20 || !bytes.starts_with(b"glTF") {
        return None;
    }
    let word =
        |at: usize| -> Option<usize> { Some(u32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?) as usize) };
    let json_len = word(12)?;
    let json = bytes.get(20..20usize.checked_add(json_len)?)?.to_vec();
    let at = 20 + json_len;
    let bin = match (word(at), bytes.get(at + 4..at + 8)) {
        (Some(len), Some(b"BIN\0")) => Some(bytes.get(at + 8..(at + 8).checked_add(len)?)?.to_vec()),
        _ => None,
    };
    Some((json, bin))
}

// ---------------------------------------------------------------------------------------------
// Images

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&u32::try_from(data.len()).expect("small chunk").to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32fast::hash(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A zlib stream of `data` in stored (uncompressed) deflate blocks.
#[must_use]
pub fn zlib_stored(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0x78, 0x01];
    let mut blocks = data.chunks(65535).peekable();
    if blocks.peek().is_none() {
        out.extend_from_slice(&[1, 0, 0, 0xFF, 0xFF]);
    }
    while let Some(block) = blocks.next() {
        out.push(u8::from(blocks.peek().is_none()));
        let len = u16::try_from(block.len()).expect("at most 65535");
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(&(!len).to_le_bytes());
        out.extend_from_slice(block);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &byte in data {
        a = (a + u32::from(byte)) % 65521;
        b = (b + a) % 65521;
    }
    out.extend_from_slice(&((b << 16) | a).to_be_bytes());
    out
}

fn png_ihdr(width: u32, height: u32, color_type: u8) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, color_type, 0, 0, 0]);
    png_chunk(&mut out, b"IHDR", &ihdr);
    out
}

/// A valid 8-bit PNG: `channels` 1 (grey), 3 (RGB) or 4 (RGBA), `pixels` row by row.
///
/// # Panics
/// If `pixels` does not hold `width × height × channels` bytes.
#[must_use]
pub fn png(width: u32, height: u32, channels: u8, pixels: &[u8]) -> Vec<u8> {
    let color_type = match channels {
        1 => 0,
        3 => 2,
        4 => 6,
        _ => panic!("1, 3 or 4 channels"),
    };
    let row = width as usize * usize::from(channels);
    assert_eq!(pixels.len(), row * height as usize, "pixel bytes");
    let mut raw = Vec::with_capacity((row + 1) * height as usize);
    for line in pixels.chunks(row.max(1)).take(height as usize) {
        raw.push(0); // filter: none
        raw.extend_from_slice(line);
    }
    let mut out = png_ihdr(width, height, color_type);
    png_chunk(&mut out, b"IDAT", &zlib_stored(&raw));
    png_chunk(&mut out, b"IEND", &[]);
    out
}

/// A PNG whose header declares `width × height` RGBA pixels but whose data is a few rows of a
/// stored stream that then ends: a reader that trusts the header allocates the full image.
#[must_use]
pub fn png_declaring(width: u32, height: u32) -> Vec<u8> {
    let mut out = png_ihdr(width, height, 6);
    // A stored block header declaring 65535 bytes, then only 1 KiB of them.
    let mut idat = vec![0x78, 0x01, 0, 0xFF, 0xFF, 0, 0];
    idat.resize(idat.len() + 1024, 0);
    png_chunk(&mut out, b"IDAT", &idat);
    png_chunk(&mut out, b"IEND", &[]);
    out
}

/// A PNG with a valid 4 × 4 RGBA header and an image data chunk (with a correct CRC) that is
/// not a zlib stream.
#[must_use]
pub fn png_corrupt() -> Vec<u8> {
    let mut out = png_ihdr(4, 4, 6);
    png_chunk(&mut out, b"IDAT", b"this is not a zlib stream, whatever the header says");
    png_chunk(&mut out, b"IEND", &[]);
    out
}

/// The first 150-odd bytes of a baseline JPEG declaring `width × height` greyscale pixels:
/// quantisation table, frame header, a Huffman table and the scan header, then end of image.
#[must_use]
pub fn jpeg_declaring(width: u16, height: u16) -> Vec<u8> {
    let mut out = vec![0xFF, 0xD8]; // SOI
    // DQT: table 0, 8-bit, all ones.
    out.extend_from_slice(&[0xFF, 0xDB, 0x00, 0x43, 0x00]);
    out.extend_from_slice(&[1; 64]);
    // SOF0: 8-bit, height, width, one component (id 1, 1x1 sampling, table 0).
    out.extend_from_slice(&[0xFF, 0xC0, 0x00, 0x0B, 0x08]);
    out.extend_from_slice(&height.to_be_bytes());
    out.extend_from_slice(&width.to_be_bytes());
    out.extend_from_slice(&[0x01, 0x01, 0x11, 0x00]);
    // DHT: DC table 0 with one code of length 1 for the value 0.
    out.extend_from_slice(&[0xFF, 0xC4, 0x00, 0x14, 0x00, 1]);
    out.extend_from_slice(&[0; 15]);
    out.push(0);
    // SOS: one component, tables 0/0, spectral 0..63, approximation 0.
    out.extend_from_slice(&[0xFF, 0xDA, 0x00, 0x08, 0x01, 0x01, 0x00, 0x00, 0x3F, 0x00]);
    out.extend_from_slice(&[0x00; 16]);
    out.extend_from_slice(&[0xFF, 0xD9]); // EOI
    out
}

/// A 4 × 4 RGBA leaf texture: green, transparent in one corner.
#[must_use]
pub fn leaf_png() -> Vec<u8> {
    let mut pixels = Vec::new();
    for y in 0..4u8 {
        for x in 0..4u8 {
            let alpha = if x == 3 && y == 3 { 0 } else { 255 };
            pixels.extend_from_slice(&[40 + 10 * x, 140 + 20 * y, 30, alpha]);
        }
    }
    png(4, 4, 4, &pixels)
}

// ---------------------------------------------------------------------------------------------
// The tree

/// The leaf quads of [`tree`], before the crown node's translation of `(0, 0.5, 0)`.
#[derive(Clone, Debug, Default)]
pub struct LeafGeometry {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Vertex normals.
    pub normals: Vec<[f32; 3]>,
    /// Texture coordinates.
    pub uvs: Vec<[f32; 2]>,
    /// Triangles, 16-bit.
    pub indices: Vec<u16>,
}

/// The leaf quads of [`tree`].
#[must_use]
pub fn leaf_geometry() -> LeafGeometry {
    let (mut positions, mut normals, mut uvs, mut indices) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for q in 0..LEAF_QUADS {
        #[expect(clippy::cast_precision_loss, reason = "small")]
        let angle = q as f32 * std::f32::consts::TAU / LEAF_QUADS as f32;
        #[expect(clippy::cast_precision_loss, reason = "small")]
        let (cx, cy, cz) = (0.6 * angle.cos(), 1.5 + 0.1 * q as f32, 0.6 * angle.sin());
        let base = u16::try_from(positions.len()).expect("small");
        for (dx, dy, u, v) in
            [(-0.15, -0.15, 0.0, 1.0), (0.15, -0.15, 1.0, 1.0), (0.15, 0.15, 1.0, 0.0), (-0.15, 0.15, 0.0, 0.0)]
        {
            positions.push([cx + dx, cy + dy, cz]);
            normals.push([0.0, 0.0, 1.0]);
            uvs.push([u, v]);
        }
        indices.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    LeafGeometry { positions, normals, uvs, indices }
}

/// A small valid tree: six textured leaf quads (mesh 0, `UNSIGNED_SHORT` indices, an alpha-masked
/// material with a 4 × 4 PNG in a buffer view) under node `crown`, two crossed bark quads (mesh 1,
/// `UNSIGNED_INT` indices, an untextured material) under node `trunk`, both children of node
/// `tree`. Accessor and view indices are fixed: see [`accessor`].
#[must_use]
pub fn tree() -> Gltf {
    let mut doc = Gltf::new();
    let image = doc.image(&leaf_png(), "image/png");
    let LeafGeometry { positions, normals, uvs, indices } = leaf_geometry();
    let a = [doc.vec3(&positions), doc.vec3(&normals), doc.vec2(&uvs), doc.indices_u16(&indices)];
    assert_eq!(a, [accessor::LEAF_POSITION, accessor::LEAF_NORMAL, accessor::LEAF_UV, accessor::LEAF_INDICES]);
    let bark_positions = [
        [-0.1, 0.0, 0.0],
        [0.1, 0.0, 0.0],
        [0.1, 1.6, 0.0],
        [-0.1, 1.6, 0.0],
        [0.0, 0.0, -0.1],
        [0.0, 0.0, 0.1],
        [0.0, 1.6, 0.1],
        [0.0, 1.6, -0.1],
    ];
    let bark_normals = [[0.0, 0.0, 1.0]; 4].into_iter().chain([[1.0, 0.0, 0.0]; 4]).collect::<Vec<_>>();
    let b =
        [doc.vec3(&bark_positions), doc.vec3(&bark_normals), doc.indices_u32(&[0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7])];
    assert_eq!(b, [accessor::BARK_POSITION, accessor::BARK_NORMAL, accessor::BARK_INDICES]);
    doc.add("samplers", json!({"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}));
    doc.add("textures", json!({"source": image, "sampler": 0}));
    doc.add(
        "materials",
        json!({"name": "leaf", "alphaMode": "MASK", "alphaCutoff": 0.5, "doubleSided": true,
               "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}),
    );
    doc.add("materials", json!({"name": "bark", "pbrMetallicRoughness": {"baseColorFactor": [0.3, 0.2, 0.1, 1.0]}}));
    doc.add(
        "meshes",
        json!({"name": "leaves", "primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
               "indices": 3, "material": 0}]}),
    );
    doc.add("meshes", json!({"name": "bark", "primitives": [{"attributes": {"POSITION": 4, "NORMAL": 5}, "indices": 6, "material": 1}]}));
    doc.add("nodes", json!({"name": "tree", "children": [1, 2]}));
    doc.add("nodes", json!({"name": "crown", "mesh": 0, "translation": [0.0, 0.5, 0.0]}));
    doc.add("nodes", json!({"name": "trunk", "mesh": 1}));
    doc.json["scenes"][0]["nodes"] = json!([0]);
    doc
}

/// [`tree`] with the leaves' positions and normals interleaved in one view (stride 24).
#[must_use]
pub fn tree_interleaved() -> Gltf {
    let mut doc = tree();
    let LeafGeometry { positions, normals, .. } = leaf_geometry();
    let mut bytes = Vec::new();
    for (p, n) in positions.iter().zip(&normals) {
        bytes.extend_from_slice(&f32_bytes(p));
        bytes.extend_from_slice(&f32_bytes(n));
    }
    let view = doc.view(&bytes, Some(24));
    let count = positions.len();
    doc.json["accessors"][accessor::LEAF_POSITION]["bufferView"] = view.into();
    doc.json["accessors"][accessor::LEAF_NORMAL] = json!({"bufferView": view, "byteOffset": 12, "componentType": component::FLOAT, "count": count, "type": "VEC3"});
    doc
}

/// Where the sparse accessor of [`tree_sparse`] moves leaf vertex 0 (before the node transform).
pub const SPARSE_VERTEX: [f32; 3] = [0.25, 1.25, 0.5];

/// [`tree`] whose leaf positions carry a sparse substitution of vertex 0 by [`SPARSE_VERTEX`].
#[must_use]
pub fn tree_sparse() -> Gltf {
    let mut doc = tree();
    let indices = doc.view(&[0, 0, 0, 0], None);
    let values = doc.view(&f32_bytes(&SPARSE_VERTEX), None);
    doc.json["accessors"][accessor::LEAF_POSITION]["sparse"] = json!({
        "count": 1,
        "indices": {"bufferView": indices, "componentType": component::UNSIGNED_BYTE},
        "values": {"bufferView": values},
    });
    // min/max (required for POSITION) cover the substituted value.
    let LeafGeometry { mut positions, .. } = leaf_geometry();
    positions[0] = SPARSE_VERTEX;
    let (lo, hi) = bounds(&positions);
    doc.json["accessors"][accessor::LEAF_POSITION]["min"] = json!(lo);
    doc.json["accessors"][accessor::LEAF_POSITION]["max"] = json!(hi);
    doc
}

/// [`tree`] with the leaf positions quantised (`KHR_mesh_quantization`, required): `SHORT VEC3`
/// in millimetres (stride 8), scaled by the crown node.
#[must_use]
pub fn tree_quantized() -> Gltf {
    let mut doc = tree();
    let LeafGeometry { positions, .. } = leaf_geometry();
    #[expect(clippy::cast_possible_truncation, reason = "millimetres of a 2 m tree")]
    let millimetres: Vec<[i16; 3]> = positions.iter().map(|p| p.map(|c| (c * 1000.0).round() as i16)).collect();
    let mut bytes = Vec::new();
    for p in &millimetres {
        for c in p {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
        bytes.extend_from_slice(&[0, 0]);
    }
    let view = doc.view(&bytes, Some(8));
    let (lo, hi) = bounds(&millimetres);
    doc.json["accessors"][accessor::LEAF_POSITION] = json!({"bufferView": view, "componentType": component::SHORT,
        "count": positions.len(), "type": "VEC3", "min": lo, "max": hi});
    doc.json["nodes"][1]["scale"] = json!([0.001, 0.001, 0.001]);
    doc.use_extension("KHR_mesh_quantization", true);
    doc
}

/// [`tree`] with a `KHR_texture_transform` (required) on the leaf texture: offset `(0.5, 0.25)`,
/// scale `(0.5, 0.5)`, so the leaf UV `(1, 1)` becomes `(1.0, 0.75)` and `(1, 0)` becomes `(1.0, 0.25)`.
#[must_use]
pub fn tree_texture_transform() -> Gltf {
    let mut doc = tree();
    doc.json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] =
        json!({"KHR_texture_transform": {"offset": [0.5, 0.25], "scale": [0.5, 0.5]}});
    doc.use_extension("KHR_texture_transform", true);
    doc
}

/// [`tree`] with leaf texture coordinates as normalised `UNSIGNED_SHORT` and vertex colours
/// `COLOR_0` as normalised `UNSIGNED_BYTE VEC4`.
#[must_use]
pub fn tree_normalized_attributes() -> Gltf {
    let mut doc = tree();
    let LeafGeometry { uvs, .. } = leaf_geometry();
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "0..=1 scaled")]
    let bytes: Vec<u8> = uvs.as_flattened().iter().flat_map(|&c| ((c * 65535.0) as u16).to_le_bytes()).collect();
    let view = doc.view(&bytes, None);
    doc.json["accessors"][accessor::LEAF_UV] = json!({"bufferView": view, "componentType": component::UNSIGNED_SHORT,
        "normalized": true, "count": uvs.len(), "type": "VEC2"});
    let colors: Vec<u8> = (0..LEAF_VERTICES).flat_map(|_| [200, 255, 100, 255]).collect();
    let view = doc.view(&colors, None);
    let colors = doc.add(
        "accessors",
        json!({"bufferView": view, "componentType": component::UNSIGNED_BYTE,
        "normalized": true, "count": LEAF_VERTICES, "type": "VEC4"}),
    );
    doc.json["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = colors.into();
    doc
}

/// [`tree`] with `extras` of every JSON kind but an object on the root, nodes, meshes,
/// primitives, materials, accessors and the asset.
#[must_use]
pub fn tree_extras() -> Gltf {
    let mut doc = tree();
    doc.json["extras"] = json!([1, "two", {"three": 3}]);
    doc.json["asset"]["extras"] = json!("a string");
    doc.json["nodes"][0]["extras"] = json!(42);
    doc.json["nodes"][1]["extras"] = json!(null);
    doc.json["nodes"][2]["extras"] = json!(true);
    doc.json["meshes"][0]["extras"] = json!([]);
    doc.json["meshes"][0]["primitives"][0]["extras"] = json!(-1.5e300);
    doc.json["materials"][0]["extras"] = json!("leafy");
    doc.json["accessors"][0]["extras"] = json!([[[]]]);
    doc.json["scenes"][0]["extras"] = json!({"nested": {"deeper": [1, 2, 3]}});
    doc
}

/// The valid documents the importer must read, by name: the tree and each of its variants.
#[must_use]
pub fn valid_variants() -> Vec<(&'static str, Gltf)> {
    vec![
        ("tree", tree()),
        ("interleaved", tree_interleaved()),
        ("sparse", tree_sparse()),
        ("quantized", tree_quantized()),
        ("texture-transform", tree_texture_transform()),
        ("normalized-attributes", tree_normalized_attributes()),
        ("extras", tree_extras()),
    ]
}

/// Every valid variant as a `.gltf` (data URI) and as a `.glb`, as (file name, bytes): seeds for
/// fuzzing the importer.
#[must_use]
pub fn valid_files() -> Vec<(String, Vec<u8>)> {
    valid_variants()
        .into_iter()
        .flat_map(|(name, doc)| [(format!("{name}.gltf"), doc.to_gltf()), (format!("{name}.glb"), doc.to_glb())])
        .collect()
}
