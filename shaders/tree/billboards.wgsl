// Baseline billboards (spec §6.13), drawn from the planes' binding with the billboards' atlas;
// composed after planes.wgsl, whose quad corner and fragment stages they share.

// One corner of a baseline billboard quad (spec §6.13), bound in place of the planes:
// `BillboardRecord` has `PlaneRecord`'s layout up to `uv_max`, and its `tree` and `kind` sit where
// a plane has `lo` and `hi` (read back with `bitcast`). A crossed quad is fixed like a plane; a
// facing one (kind 0) keeps its centre, `axis_v` and the length of `axis_u`, and turns `axis_u`
// about `axis_v` so that `axis_u × axis_v` points to the eye: the side its image was baked from.
@vertex
fn vs_billboard(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draw_at(draw_index);
    let quad = planes[vertex_index / 6u];
    let corner = CORNERS[vertex_index % 6u];
    let centre = (draw.model * vec4<f32>(quad.center[0], quad.center[1], quad.center[2], 1.0)).xyz;
    var u = (draw.model * vec4<f32>(quad.axis_u[0], quad.axis_u[1], quad.axis_u[2], 0.0)).xyz;
    let v = (draw.model * vec4<f32>(quad.axis_v[0], quad.axis_v[1], quad.axis_v[2], 0.0)).xyz;
    if bitcast<u32>(quad.hi) == 0u {
        let up = normalize(v);
        let to_eye = frame.eye.xyz - centre;
        let across = cross(up, to_eye);
        let len = length(across);
        if len > 1e-6 * length(to_eye) {
            u = across * (length(u) / len);
        }
    }
    let world = centre + corner.x * u + corner.y * v;
    return quad_corner(draw, world, normalize(cross(u, v)), quad.uv_min, quad.uv_max, corner, vec3<f32>(0.85, 0.35, 0.85));
}
