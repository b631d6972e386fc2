//! Validated accessor reads (glTF 2.0 §3.6, §5.1): every accessor a primitive uses is checked
//! against the spec before a byte of it is read — component type, type and normalisation allowed
//! for its use, a count of at least one, every element (dense and sparse) inside its buffer view and
//! every view inside its buffer, strides no shorter than an element, sparse indices increasing and
//! below the count — and the output's size is charged to the import's byte budget before it is
//! allocated. A violation is [`BuildError::InvalidData`] naming the glTF path of the use
//! (`meshes[2].primitives[0].attributes.POSITION`) and the accessor (`accessors[5]`).
//!
//! The reads are our own rather than `gltf`'s readers, which panic (`unreachable!`, slice
//! assertions) or misread on accessors whose declared types do not match their use.

use std::borrow::Cow;
use std::path::Path;

use gltf::accessor::{DataType, Dimensions};

use super::limits::Budget;
use crate::BuildError;

/// What an accessor is read as, with the types glTF allows for it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Use {
    /// `POSITION`: `VEC3` `FLOAT` (or, with `KHR_mesh_quantization`, integer types).
    Position,
    /// `NORMAL`: `VEC3` `FLOAT` (or normalized `BYTE`/`SHORT` with `KHR_mesh_quantization`).
    Normal,
    /// `TEXCOORD_n`: `VEC2` `FLOAT` or normalized `UNSIGNED_BYTE`/`UNSIGNED_SHORT` (any integer
    /// type, normalized or not, with `KHR_mesh_quantization`).
    TexCoord,
    /// `COLOR_n`: `VEC3` or `VEC4`, `FLOAT` or normalized `UNSIGNED_BYTE`/`UNSIGNED_SHORT`.
    Color,
    /// `indices`: `SCALAR` `UNSIGNED_BYTE`/`UNSIGNED_SHORT`/`UNSIGNED_INT`, not normalized.
    Indices,
}

/// Where the accessors are read from, and what the file declares.
pub(super) struct Source<'a, 'b> {
    /// The buffers' bytes, by buffer index (each at least its declared length).
    pub buffers: &'a [Cow<'b, [u8]>],
    /// `KHR_mesh_quantization` is in `extensionsUsed`: integer positions, normals and texture
    /// coordinates are allowed.
    pub quantization: bool,
    /// The glTF file, for errors.
    pub path: &'a Path,
}

/// An accessor's element layout once validated.
struct Layout {
    component: DataType,
    normalized: bool,
    /// Components per element.
    components: usize,
    count: usize,
}

impl Source<'_, '_> {
    fn invalid(&self, use_path: &str, accessor: &gltf::Accessor<'_>, what: impl std::fmt::Display) -> BuildError {
        BuildError::InvalidData {
            path: self.path.to_owned(),
            what: format!("{use_path}: accessors[{}] {what}", accessor.index()),
        }
    }

    /// Checks the accessor's types against `use_`; the element's components.
    fn layout(&self, accessor: &gltf::Accessor<'_>, use_: Use, use_path: &str) -> Result<Layout, BuildError> {
        use DataType::{F32, I8, I16, U8, U16, U32};
        let component = accessor.data_type();
        let normalized = accessor.normalized();
        let dims = accessor.dimensions();
        let components = match (use_, dims) {
            (Use::Position | Use::Normal, Dimensions::Vec3) => 3,
            (Use::TexCoord, Dimensions::Vec2) => 2,
            (Use::Color, Dimensions::Vec3) => 3,
            (Use::Color, Dimensions::Vec4) => 4,
            (Use::Indices, Dimensions::Scalar) => 1,
            _ => {
                let allowed = match use_ {
                    Use::Position | Use::Normal => "VEC3",
                    Use::TexCoord => "VEC2",
                    Use::Color => "VEC3 or VEC4",
                    Use::Indices => "SCALAR",
                };
                return Err(self.invalid(
                    use_path,
                    accessor,
                    format!("has type {}, must be {allowed}", dims_name(dims)),
                ));
            }
        };
        let q = self.quantization;
        let ok = match use_ {
            Use::Position => (component == F32 && !normalized) || (q && component != U32),
            Use::Normal => (component == F32 && !normalized) || (q && matches!(component, I8 | I16) && normalized),
            Use::TexCoord => {
                (component == F32 && !normalized)
                    || (matches!(component, U8 | U16) && normalized)
                    || (q && matches!(component, I8 | I16 | U8 | U16))
            }
            Use::Color => (component == F32 && !normalized) || (matches!(component, U8 | U16) && normalized),
            Use::Indices => matches!(component, U8 | U16 | U32) && !normalized,
        };
        if !ok {
            let norm = if normalized { "normalized " } else { "" };
            let hint = match use_ {
                Use::Position | Use::Normal | Use::TexCoord if !q && component != F32 && component != U32 => {
                    " (integer vertex attributes need the KHR_mesh_quantization extension)"
                }
                Use::Position | Use::Normal => " (must be FLOAT)",
                Use::TexCoord => " (must be FLOAT, or normalized UNSIGNED_BYTE or UNSIGNED_SHORT)",
                Use::Color => " (must be FLOAT, or normalized UNSIGNED_BYTE or UNSIGNED_SHORT)",
                Use::Indices => " (must be UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT, not normalized)",
            };
            return Err(self.invalid(
                use_path,
                accessor,
                format!("has component type {norm}{}{hint}", component_name(component)),
            ));
        }
        let count = accessor.count();
        if count == 0 {
            return Err(self.invalid(use_path, accessor, "has count 0 (at least 1)"));
        }
        Ok(Layout { component, normalized, components, count })
    }

    /// The bytes of `view`, checked to lie inside its buffer.
    fn view_bytes(&self, view: &gltf::buffer::View<'_>, use_path: &str) -> Result<&[u8], BuildError> {
        let buffer = self.buffers.get(view.buffer().index());
        let end = view.offset().checked_add(view.length());
        match (buffer, end) {
            (Some(data), Some(end)) if end <= data.len() => Ok(&data[view.offset()..end]),
            _ => Err(BuildError::InvalidData {
                path: self.path.to_owned(),
                what: format!(
                    "{use_path}: bufferViews[{}] (bytes {}..+{}) lies outside buffers[{}]",
                    view.index(),
                    view.offset(),
                    view.length(),
                    view.buffer().index()
                ),
            }),
        }
    }

    /// `count` elements of `element` bytes at `offset` with `stride` in `bytes` (a view's), checked.
    fn elements<'v>(
        &self,
        bytes: &'v [u8],
        offset: usize,
        stride: usize,
        element: usize,
        count: usize,
        what: impl Fn() -> String,
    ) -> Result<Strided<'v>, BuildError> {
        let end = (count as u128 - 1) * stride as u128 + offset as u128 + element as u128;
        if end > bytes.len() as u128 {
            return Err(BuildError::InvalidData {
                path: self.path.to_owned(),
                what: format!(
                    "{}: {count} elements of {element} bytes at offset {offset}, stride {stride}, end at byte {end}, past the {} bytes of its buffer view",
                    what(),
                    bytes.len()
                ),
            });
        }
        Ok(Strided { bytes, offset, stride })
    }

    /// The accessor's dense elements (`None` if it has no buffer view: all zeros).
    fn dense<'v>(
        &'v self,
        accessor: &gltf::Accessor<'_>,
        layout: &Layout,
        use_path: &str,
    ) -> Result<Option<Strided<'v>>, BuildError> {
        let Some(view) = accessor.view() else { return Ok(None) };
        let bytes = self.view_bytes(&view, use_path)?;
        let element = layout.component.size() * layout.components;
        let stride = view.stride().unwrap_or(element);
        if stride < element {
            return Err(BuildError::InvalidData {
                path: self.path.to_owned(),
                what: format!(
                    "{use_path}: accessors[{}]: bufferViews[{}] has byteStride {stride}, shorter than its {element}-byte elements",
                    accessor.index(),
                    view.index()
                ),
            });
        }
        let label = || format!("{use_path}: accessors[{}]", accessor.index());
        self.elements(bytes, accessor.offset(), stride, element, layout.count, label).map(Some)
    }

    /// Reads the accessor as `N` floats per element (integers converted, normalized ones to
    /// `[0, 1]` or `[−1, 1]`), charging the output to `budget` first.
    pub(super) fn read_floats<const N: usize>(
        &self,
        accessor: &gltf::Accessor<'_>,
        use_: Use,
        use_path: &str,
        budget: &mut Budget<'_>,
    ) -> Result<Vec<[f32; N]>, BuildError> {
        let layout = self.layout(accessor, use_, use_path)?;
        budget.take_bytes(use_path, (layout.count as u64).saturating_mul(4 * N as u64))?;
        let decode = |bytes: &[u8]| -> [f32; N] {
            // A colour's missing alpha is 1; other missing components are 0.
            let mut out = [if N == 4 { 1.0 } else { 0.0 }; N];
            for (c, o) in out.iter_mut().enumerate().take(layout.components) {
                *o = component_f32(bytes, c, layout.component, layout.normalized);
            }
            if N == 4 && layout.components == 3 {
                out[3] = 1.0;
            }
            out
        };
        let mut out: Vec<[f32; N]> = match self.dense(accessor, &layout, use_path)? {
            Some(elements) => (0..layout.count).map(|i| decode(elements.get(i))).collect(),
            None => vec![decode(&[0; 16][..layout.component.size() * layout.components]); layout.count],
        };
        self.apply_sparse(accessor, &layout, use_path, |i, bytes| out[i] = decode(bytes))?;
        // Texture coordinates and colours are written as they are: a non-finite one would make a
        // container that fails verification. (Non-finite positions drop their triangles in the
        // build, with a warning; non-finite normals become +Y.)
        if matches!(use_, Use::TexCoord | Use::Color)
            && let Some(i) = out.iter().position(|v| !v.iter().all(|x| x.is_finite()))
        {
            return Err(self.invalid(use_path, accessor, format!("element {i} is {:?}, not finite", out[i])));
        }
        Ok(out)
    }

    /// Reads an `indices` accessor.
    pub(super) fn read_indices(
        &self,
        accessor: &gltf::Accessor<'_>,
        use_path: &str,
        budget: &mut Budget<'_>,
    ) -> Result<Vec<u32>, BuildError> {
        let layout = self.layout(accessor, Use::Indices, use_path)?;
        budget.take_bytes(use_path, (layout.count as u64).saturating_mul(4))?;
        let decode = |bytes: &[u8]| component_u32(bytes, layout.component);
        let mut out = match self.dense(accessor, &layout, use_path)? {
            Some(elements) => (0..layout.count).map(|i| decode(elements.get(i))).collect(),
            None => vec![0; layout.count],
        };
        self.apply_sparse(accessor, &layout, use_path, |i, bytes| out[i] = decode(bytes))?;
        Ok(out)
    }

    /// The element count the accessor declares once its types are checked for `use_`.
    pub(super) fn count(&self, accessor: &gltf::Accessor<'_>, use_: Use, use_path: &str) -> Result<usize, BuildError> {
        self.layout(accessor, use_, use_path).map(|l| l.count)
    }

    /// Calls `set(index, element bytes)` for each sparse substitution, after checking the sparse
    /// storage (glTF §3.6.2.3): `1 ≤ sparse.count ≤ count`, indices of an unsigned type, strictly
    /// increasing and below `count`, both arrays inside their views.
    fn apply_sparse(
        &self,
        accessor: &gltf::Accessor<'_>,
        layout: &Layout,
        use_path: &str,
        mut set: impl FnMut(usize, &[u8]),
    ) -> Result<(), BuildError> {
        let Some(sparse) = accessor.sparse() else { return Ok(()) };
        let n = sparse.count();
        if n == 0 || n > layout.count {
            return Err(self.invalid(
                use_path,
                accessor,
                format!("has sparse.count {n}, must be in 1..={}", layout.count),
            ));
        }
        let indices = sparse.indices();
        let index_size = indices.index_type().size();
        let index_bytes = self.view_bytes(&indices.view(), use_path)?;
        let label = || format!("{use_path}: accessors[{}].sparse.indices", accessor.index());
        let index_elements = self.elements(index_bytes, indices.offset(), index_size, index_size, n, label)?;
        let values = sparse.values();
        let element = layout.component.size() * layout.components;
        let value_bytes = self.view_bytes(&values.view(), use_path)?;
        let label = || format!("{use_path}: accessors[{}].sparse.values", accessor.index());
        let value_elements = self.elements(value_bytes, values.offset(), element, element, n, label)?;
        let mut previous: Option<usize> = None;
        for k in 0..n {
            let bytes = index_elements.get(k);
            let index = match index_size {
                1 => u32::from(bytes[0]),
                2 => u32::from(u16::from_le_bytes([bytes[0], bytes[1]])),
                _ => u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
            } as usize;
            if index >= layout.count || previous.is_some_and(|p| index <= p) {
                return Err(self.invalid(
                    use_path,
                    accessor,
                    format!(
                        "has sparse index {index} at position {k}: sparse indices must increase strictly and stay below the count {}",
                        layout.count
                    ),
                ));
            }
            previous = Some(index);
            set(index, value_elements.get(k));
        }
        Ok(())
    }
}

/// Elements at a stride in a slice, every one checked to lie inside it.
struct Strided<'v> {
    bytes: &'v [u8],
    offset: usize,
    stride: usize,
}

impl<'v> Strided<'v> {
    /// Element `i`'s bytes (to the end of the slice; readers take what they need). In bounds for
    /// every `i < count` as [`Source::elements`] checked.
    fn get(&self, i: usize) -> &'v [u8] {
        &self.bytes[self.offset + i * self.stride..]
    }
}

/// Component `c` of an element as `f32`: normalized integers map to `[0, 1]` (unsigned) or
/// `[−1, 1]` (signed), as glTF §3.11 defines.
fn component_f32(bytes: &[u8], c: usize, ty: DataType, normalized: bool) -> f32 {
    let at = c * ty.size();
    let b = &bytes[at..at + ty.size()];
    match ty {
        DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        DataType::U8 => {
            let v = f32::from(b[0]);
            if normalized { v / 255.0 } else { v }
        }
        DataType::I8 => {
            let v = f32::from(i8::from_le_bytes([b[0]]));
            if normalized { (v / 127.0).max(-1.0) } else { v }
        }
        DataType::U16 => {
            let v = f32::from(u16::from_le_bytes([b[0], b[1]]));
            if normalized { v / 65535.0 } else { v }
        }
        DataType::I16 => {
            let v = f32::from(i16::from_le_bytes([b[0], b[1]]));
            if normalized { (v / 32767.0).max(-1.0) } else { v }
        }
        #[expect(clippy::cast_precision_loss, reason = "unsigned-int vertex attributes are not allowed; indices only")]
        DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
    }
}

/// An unsigned index component.
fn component_u32(bytes: &[u8], ty: DataType) -> u32 {
    match ty {
        DataType::U8 | DataType::I8 => u32::from(bytes[0]),
        DataType::U16 | DataType::I16 => u32::from(u16::from_le_bytes([bytes[0], bytes[1]])),
        DataType::U32 | DataType::F32 => u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
    }
}

/// The glTF name of a component type.
fn component_name(ty: DataType) -> &'static str {
    match ty {
        DataType::I8 => "BYTE",
        DataType::U8 => "UNSIGNED_BYTE",
        DataType::I16 => "SHORT",
        DataType::U16 => "UNSIGNED_SHORT",
        DataType::U32 => "UNSIGNED_INT",
        DataType::F32 => "FLOAT",
    }
}

/// The glTF name of an accessor type.
fn dims_name(d: Dimensions) -> &'static str {
    match d {
        Dimensions::Scalar => "SCALAR",
        Dimensions::Vec2 => "VEC2",
        Dimensions::Vec3 => "VEC3",
        Dimensions::Vec4 => "VEC4",
        Dimensions::Mat2 => "MAT2",
        Dimensions::Mat3 => "MAT3",
        Dimensions::Mat4 => "MAT4",
    }
}
