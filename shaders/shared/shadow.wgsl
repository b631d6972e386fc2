// Receiving the sun's cascaded shadow maps (crates/treelod-render/src/shadows.rs): the renderer's
// own, or the host's (Renderer::receive_host_shadows). Bound as group 2 by the tree pipelines and by
// any host pipeline that includes this file (treelod_render::SHADOW_WGSL,
// Renderer::shadow_bind_group). Rust twin of the uniform: `ShadowUniform` in shadows.rs.

struct ShadowCascades {
    // World to clip of each cascade's orthographic light view (WebGPU depth 0..1), finest first.
    view_proj: array<mat4x4<f32>, 4>,
    // Metres per shadow-map texel of each cascade.
    texel: vec4<f32>,
    // The layer of shadow_map each cascade is in.
    layer: vec4<u32>,
    // Cascades in use; 0: shadows off, everything is lit.
    count: u32,
    // How far a receiver is moved along its normal (towards the sun) before the lookup, texels.
    normal_offset: f32,
    // 1 / the maps' resolution.
    inv_size: f32,
    // 1: the maps hold reverse depth (near the light 1, far 0; the sampler compares with >=).
    reverse_z: u32,
}

@group(2) @binding(0) var<uniform> shadow_cascades: ShadowCascades;
@group(2) @binding(1) var shadow_map: texture_depth_2d_array;
@group(2) @binding(2) var shadow_sampler: sampler_comparison;

// The share of the sunlight that reaches `world` (1 lit, 0 in shadow), a surface with `normal`
// lit from `sun` (unit, towards the sun) on whichever face the sun is: the finest cascade whose
// map holds the point, 3×3 taps of the hardware's 2×2 comparison filter (a 4×4-texel footprint).
fn sunlit(world: vec3<f32>, normal: vec3<f32>, sun: vec3<f32>) -> f32 {
    if shadow_cascades.count == 0u {
        return 1.0;
    }
    let n = normalize(normal);
    // Two-sided surfaces (leaf cards) are offset to their sunlit face.
    let towards = select(-n, n, dot(n, sun) >= 0.0);
    let margin = 2.0 * shadow_cascades.inv_size;
    for (var k = 0u; k < min(shadow_cascades.count, 4u); k += 1u) {
        let p = world + towards * (shadow_cascades.texel[k] * shadow_cascades.normal_offset);
        let clip = shadow_cascades.view_proj[k] * vec4<f32>(p, 1.0);
        let uv = vec2<f32>(0.5 * clip.x + 0.5, 0.5 - 0.5 * clip.y);
        let beyond = select(clip.z > 1.0, clip.z < 0.0, shadow_cascades.reverse_z != 0u);
        if any(uv < vec2<f32>(margin)) || any(uv > vec2<f32>(1.0 - margin)) || beyond {
            continue;
        }
        var lit = 0.0;
        for (var dy = -1; dy <= 1; dy += 1) {
            for (var dx = -1; dx <= 1; dx += 1) {
                let at = uv + vec2<f32>(f32(dx), f32(dy)) * shadow_cascades.inv_size;
                lit += textureSampleCompareLevel(shadow_map, shadow_sampler, at, shadow_cascades.layer[k], clip.z);
            }
        }
        return lit / 9.0;
    }
    return 1.0;
}
