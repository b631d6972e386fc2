// A flat ground square that receives the renderer's shadows (crates/treelod-render/src/ground.rs): how a
// host's own surfaces use shared/shadow.wgsl, prepended to this file.

struct GroundUniform {
    view_proj: mat4x4<f32>,
    // Direction towards the sun (xyz), ambient share (w), as the trees are lit.
    sun: vec4<f32>,
    sun_colour: vec4<f32>,
    // Albedo, linear RGB.
    colour: vec4<f32>,
    // Centre (xyz) and half the side (w), metres.
    extent: vec4<f32>,
}

@group(0) @binding(0) var<uniform> ground: GroundUniform;

struct GroundVaryings {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
}

const GROUND_CORNERS = array<vec2<f32>, 6>(
    vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
    vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
);

@vertex
fn vs_ground(@builtin(vertex_index) vertex_index: u32) -> GroundVaryings {
    let corner = GROUND_CORNERS[vertex_index % 6u] * ground.extent.w;
    let world = ground.extent.xyz + vec3<f32>(corner.x, 0.0, corner.y);
    var out: GroundVaryings;
    out.clip = ground.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    return out;
}

@fragment
fn fs_ground(in: GroundVaryings) -> @location(0) vec4<f32> {
    let up = vec3<f32>(0.0, 1.0, 0.0);
    let diffuse = max(dot(up, ground.sun.xyz), 0.0) * sunlit(in.world, up, ground.sun.xyz);
    let light = ground.sun.w + (1.0 - ground.sun.w) * diffuse * ground.sun_colour.xyz;
    return vec4<f32>(ground.colour.rgb * light, 1.0);
}
