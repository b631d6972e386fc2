// The container's records as the GPU reads them from storage buffers (vertex pulling).
//
// Each struct is the WGSL twin of the Rust record of the same name in
// crates/treelod-format/src/records.rs and of the byte table in format-spec/treelod.md §6. Only
// 4-byte scalars and arrays of them are used, so every struct has alignment 4 and its array
// stride equals the record size; crates/treelod-runtime/tests/wgsl_layout.rs checks sizes and offsets.
// The records every representation or the selection reads are here; a representation's own
// records are twinned at the top of its file in shaders/tree/ (planes, ellipsoids, lines).

// Rust twin: treelod_format::VertexRecord (28 bytes, spec §6.3).
struct VertexRecord {
    position: array<f32, 3>,
    normal: u32,
    uv: array<f32, 2>,
    color: u32,
}

// Rust twin: treelod_format::TriangleRecord (24 bytes, spec §6.4).
struct TriangleRecord {
    indices: array<u32, 3>,
    size: f32,
    leaf: u32,
    material: u32,
}

// Rust twin: treelod_format::PointRecord (48 bytes, spec §6.5).
struct PointRecord {
    position: array<f32, 3>,
    radius: f32,
    normal: u32,
    color: u32,
    size: f32,
    lo: f32,
    hi: f32,
    leaf_first: u32,
    leaf_count: u32,
    flags: u32,
}

// Rust twin: treelod_format::PruneLeafRecord (24 bytes, spec §6.11).
struct PruneLeafRecord {
    center: array<f32, 3>,
    area: f32,
    first_triangle: u32,
    triangle_count: u32,
}

// Octahedral normal (spec §2): x in the low 16 bits, y in the high, both snorm16.
fn decode_normal(packed: u32) -> vec3<f32> {
    let e = unpack2x16snorm(packed);
    var v = vec3<f32>(e.x, e.y, 1.0 - abs(e.x) - abs(e.y));
    if v.z < 0.0 {
        let s = select(vec2<f32>(-1.0), vec2<f32>(1.0), e >= vec2<f32>(0.0));
        v = vec3<f32>((1.0 - abs(e.yx)) * s, v.z);
    }
    return normalize(v);
}

// RGBA8 colour (spec §2): sRGB-encoded RGB, linear alpha; returns linear RGBA.
fn decode_color(packed: u32) -> vec4<f32> {
    let c = unpack4x8unorm(packed);
    let lo = c.rgb / 12.92;
    let hi = pow((c.rgb + 0.055) / 1.055, vec3<f32>(2.4));
    return vec4<f32>(select(hi, lo, c.rgb <= vec3<f32>(0.04045)), c.a);
}

// Ambient occlusion (spec §6.14) from its stored byte, in the low 8 bits of `packed`.
// Rust twin: treelod_format::decode_ao.
fn decode_ao(packed: u32) -> f32 {
    return f32(packed & 255u) / 255.0;
}

// The point rule of spec §10: inside [lo, hi) at tau_p and not larger than tau_t.
fn point_drawn(p: PointRecord, tau_p: f32, tau_t: f32) -> bool {
    return p.lo <= tau_p && tau_p < p.hi && p.size <= tau_t;
}

// Level blending of ellipsoids and lines (Settings::level_blend, `blend` = β octaves of tau,
// at most 2): whether an element of interval [lo, hi) is drawn at tau, inside
// [lo · 2^(−β/2), hi · 2^(β/2)), and on which fragments: vec2(from, to), drawn where the pixel's
// dither value h satisfies from <= h < to; from = −1 where the element is not drawn at all.
// `from` is 1 − the fade-in clamp(log2(tau/lo)/β + ½, 0, 1) (0 for lo = 0), `to` the fade-out
// clamp(log2(hi/tau)/β + ½, 0, 1) (2 for hi = ∞). At a boundary e the finer level's `to` and the
// coarser level's `from` are ½ ± (log2 e − log2 tau)/β, the same number, so with one h per pixel
// each pixel shows one level. β = 0: the hard rule [lo, hi) everywhere.
// Rust twin: treelod_runtime::spt_lod::level_keep.
fn level_keep(lo: f32, hi: f32, tau: f32, blend: f32) -> vec2<f32> {
    if blend <= 0.0 {
        return select(vec2<f32>(-1.0), vec2<f32>(0.0, 2.0), lo <= tau && tau < hi);
    }
    if !(lo * exp2(-0.5 * blend) <= tau && tau < hi * exp2(0.5 * blend)) {
        return vec2<f32>(-1.0);
    }
    var keep = vec2<f32>(0.0, 2.0);
    if lo > 0.0 {
        keep.x = clamp(0.5 - (log2(tau) - log2(lo)) / blend, 0.0, 1.0);
    }
    if hi < 3.0e38 {
        keep.y = clamp(0.5 + (log2(hi) - log2(tau)) / blend, 0.0, 1.0);
    }
    return keep;
}
