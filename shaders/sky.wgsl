// A sky gradient behind the trees (crates/treelod-render/src/sky.rs): one triangle over the whole target,
// drawn first in the pass, without depth. Colours are linear RGB.

struct SkyUniform {
    // Clip to world, to turn each pixel into the direction it looks along.
    inverse_view_proj: mat4x4<f32>,
    // Direction towards the sun (xyz).
    sun: vec4<f32>,
    zenith: vec4<f32>,
    horizon: vec4<f32>,
    // The colour looked at below the horizon (where no ground is drawn).
    below: vec4<f32>,
}

@group(0) @binding(0) var<uniform> sky: SkyUniform;

struct SkyVaryings {
    @builtin(position) clip: vec4<f32>,
    @location(0) ndc: vec2<f32>,
}

@vertex
fn vs_sky(@builtin(vertex_index) vertex_index: u32) -> SkyVaryings {
    // (-1, -1), (3, -1), (-1, 3): covers the viewport.
    let ndc = vec2<f32>(f32((vertex_index << 1u) & 2u) * 2.0 - 1.0, f32(vertex_index & 2u) * 2.0 - 1.0);
    var out: SkyVaryings;
    out.clip = vec4<f32>(ndc, 0.0, 1.0);
    out.ndc = ndc;
    return out;
}

@fragment
fn fs_sky(in: SkyVaryings) -> @location(0) vec4<f32> {
    let near = sky.inverse_view_proj * vec4<f32>(in.ndc, 0.0, 1.0);
    let far = sky.inverse_view_proj * vec4<f32>(in.ndc, 1.0, 1.0);
    let direction = normalize(far.xyz / far.w - near.xyz / near.w);
    let up = direction.y;
    var colour: vec3<f32>;
    if up >= 0.0 {
        colour = mix(sky.horizon.rgb, sky.zenith.rgb, pow(up, 0.6));
    } else {
        colour = mix(sky.horizon.rgb, sky.below.rgb, min(-up * 8.0, 1.0));
    }
    // A soft glow around the sun, so that its direction reads at a glance.
    let towards = max(dot(direction, normalize(sky.sun.xyz)), 0.0);
    colour += vec3<f32>(1.0, 0.95, 0.8) * (0.6 * pow(towards, 400.0) + 0.15 * pow(towards, 12.0));
    return vec4<f32>(colour, 1.0);
}
