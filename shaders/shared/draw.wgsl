// One indirect draw's constants, written by the CPU path (crates/treelod-render/src/draws.rs) or by
// the GPU selection (shaders/select.wgsl) and read by the tree shaders (shaders/tree/), which
// join it to its instance's transform (`InstanceTransform`, `draw_at` in tree/common.wgsl).
// Rust twin: `DrawInfo` in crates/treelod-render/src/draws.rs (32 bytes).

struct DrawInfo {
    // The thresholds the range was selected with (model units), then the cell index.
    tau_p: f32,
    tau_t: f32,
    cell: u32,
    // Gilet's estimated self-shadowing of the cell (1 without).
    shading: f32,
    // Size factor of pruned leaves about their centres (1 for everything else).
    leaf_scale: f32,
    // Index of the instance in the renderer's list: its transform (`InstanceTransform`), the
    // level blend's dither in tree/common.wgsl, read-backs.
    instance: u32,
    // The debug colour of the technique the instance is drawn with (`debug = 4`), linear RGB as
    // `pack4x8unorm` packs it (crates/treelod-render/src/draws.rs, `tint`).
    tint: u32,
    // The share [lo, hi) of the transition dither the draw keeps, as `pack2x16unorm` packs it:
    // [0, 1) (0xFFFF0000) outside a transition between techniques; see `fade_mask` in
    // tree/common.wgsl.
    fade: u32,
}

// One instance's transform, in the order of the renderer's list (`Renderer::set_instances`),
// uploaded when the list changes. Rust twin: `InstanceTransform` in
// crates/treelod-render/src/draws.rs (80 bytes).
struct InstanceTransform {
    // Column-major world-from-model transform.
    model: mat4x4<f32>,
    // Its largest axis scale, for splat and line radii.
    scale: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}
