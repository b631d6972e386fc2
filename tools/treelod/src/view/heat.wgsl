// The viewer's error heat map (tools/treelod/src/view/heat.rs): per pixel, how far the frame drawn
// with the chosen representation is from the full mesh drawn by a second renderer with the same
// camera, settings and light. Both are textures of the window's format, read as linear RGB.

@group(0) @binding(0) var drawn: texture_2d<f32>;
@group(0) @binding(1) var reference: texture_2d<f32>;

@vertex
fn vs_heat(@builtin(vertex_index) vertex_index: u32) -> @builtin(position) vec4<f32> {
    let ndc = vec2<f32>(f32((vertex_index << 1u) & 2u) * 2.0 - 1.0, f32(vertex_index & 2u) * 2.0 - 1.0);
    return vec4<f32>(ndc, 0.0, 1.0);
}

// Black, blue, cyan, yellow, red, as `t` goes from 0 to 1.
fn ramp(t: f32) -> vec3<f32> {
    let stops = array<vec3<f32>, 5>(
        vec3<f32>(0.0, 0.0, 0.0), vec3<f32>(0.05, 0.15, 0.9), vec3<f32>(0.0, 0.8, 0.85),
        vec3<f32>(0.95, 0.9, 0.1), vec3<f32>(1.0, 0.1, 0.05),
    );
    let x = clamp(t, 0.0, 1.0) * 4.0;
    let i = min(u32(x), 3u);
    return mix(stops[i], stops[i + 1u], x - f32(i));
}

@fragment
fn fs_heat(@builtin(position) position: vec4<f32>) -> @location(0) vec4<f32> {
    let p = vec2<i32>(position.xy);
    let a = textureLoad(drawn, p, 0).rgb;
    let b = textureLoad(reference, p, 0).rgb;
    // RMS over the channels, as eval's error; the ramp saturates at HEAT_FULL_SCALE.
    let error = sqrt(dot(a - b, a - b) / 3.0);
    // The reference's luminance, dimmed, under the heat so that the tree stays readable.
    let base = vec3<f32>(dot(b, vec3<f32>(0.2126, 0.7152, 0.0722)) * 0.05);
    let heat = ramp(error / HEAT_FULL_SCALE);
    return vec4<f32>(max(base, heat), 1.0);
}
