// Clasen's ellipsoids (Clasen and Prohaska 2011 §5; spec §6.8), ray-cast as Sigg et al. (2006) do:
// a screen-facing quad bounds the ellipsoid's projection, and each fragment intersects its view
// ray with the ellipsoid in the ellipsoid's local frame, where it is the unit sphere. The hit
// writes its own depth, so ellipsoids meet triangles and planes where their surfaces do.

// Rust twin: treelod_format::EllipsoidRecord (64 bytes, spec §6.8). `orientation` holds the
// quaternion's snorm16 pairs (x, y) and (z, w).
struct EllipsoidRecord {
    center: array<f32, 3>,
    radii: array<f32, 3>,
    orientation: array<u32, 2>,
    color: u32,
    alpha_threshold: f32,
    noise_mip: f32,
    lo: f32,
    hi: f32,
    leaf_first: u32,
    leaf_count: u32,
    flags: u32,
}

// Clasen's ellipsoids (spec §6.8), and the white-noise cube map they sample (crates/treelod-render/src/
// noise.rs: alpha the grey noise, RGB a random unit vector; nearest texel of the nearest level).
@group(3) @binding(0) var<storage, read> ellipsoids: array<EllipsoidRecord>;
@group(3) @binding(1) var noise: texture_cube<f32>;
@group(3) @binding(2) var noise_sampler: sampler;

// How far the shading normal turns towards the noise's random unit vector (Clasen §3.1 calibrates
// it per level; the record has no field for it, so one constant).
const ELLIPSOID_NORMAL_NOISE: f32 = 0.5;

// Texels of the noise cube's level 0 per radian of the local hit direction (a 64-texel face
// spans π/2 radians, 32 texels per unit of face coordinate at its centre, 64 at its corners).
const NOISE_TEXELS_PER_RADIAN: f32 = 40.0;

// log2 of the noise cube's face size at level 0 (crates/treelod-render/src/noise.rs NOISE_SIZE): the
// paper's level l (2^l × 2^l texels per face) is mip NOISE_TOP_LEVEL − l.
const NOISE_TOP_LEVEL: f32 = 6.0;

struct EllipsoidVaryings {
    @builtin(position) clip: vec4<f32>,
    // A point of the quad, world space: on the fragment's view ray.
    @location(0) world: vec3<f32>,
    @location(1) @interpolate(flat) ellipsoid: u32,
    @location(2) @interpolate(flat) draw: u32,
    // The cell's shading or the debug views' colour.
    @location(3) @interpolate(flat) tint: vec3<f32>,
    // The level blend's dither range (`level_keep`): drawn where keep.x <= h < keep.y.
    @location(4) @interpolate(flat) keep: vec2<f32>,
}

// An ellipsoid of an instance, world space: centre, and the linear map from its local frame
// (where it is the unit sphere) to the world, `axes = model · R · diag(radii)`, with its inverse.
struct EllipsoidFrame {
    centre: vec3<f32>,
    axes: mat3x3<f32>,
    inverse: mat3x3<f32>,
}

fn ellipsoid_frame(draw: Draw, e: EllipsoidRecord) -> EllipsoidFrame {
    let q4 = vec4<f32>(unpack2x16snorm(e.orientation[0]), unpack2x16snorm(e.orientation[1]));
    let q = select(vec4<f32>(0.0, 0.0, 0.0, 1.0), normalize(q4), dot(q4, q4) > 1e-12);
    let x = q.x;
    let y = q.y;
    let z = q.z;
    let w = q.w;
    let rotation = mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
    // A flat ellipsoid (one leaf) keeps a thousandth of its largest radius, so the map inverts.
    let radii = vec3<f32>(e.radii[0], e.radii[1], e.radii[2]);
    let r = max(radii, vec3<f32>(max(max(radii.x, radii.y), max(radii.z, 1e-12)) * 1e-3));
    let model3 = mat3x3<f32>(draw.model[0].xyz, draw.model[1].xyz, draw.model[2].xyz);
    let axes = model3 * mat3x3<f32>(rotation[0] * r.x, rotation[1] * r.y, rotation[2] * r.z);
    var out: EllipsoidFrame;
    out.centre = (draw.model * vec4<f32>(e.center[0], e.center[1], e.center[2], 1.0)).xyz;
    out.axes = axes;
    // The inverse by the adjugate: rows cross(c1, c2), cross(c2, c0), cross(c0, c1) over det.
    let c12 = cross(axes[1], axes[2]);
    let det = dot(axes[0], c12);
    out.inverse = transpose(mat3x3<f32>(c12, cross(axes[2], axes[0]), cross(axes[0], axes[1]))) * (1.0 / det);
    return out;
}

// The ellipsoid's support along the unit vector n: max over its points X of (X − centre)·n.
fn ellipsoid_support(f: EllipsoidFrame, n: vec3<f32>) -> f32 {
    return length(transpose(f.axes) * n);
}

fn offscreen_ellipsoid() -> EllipsoidVaryings {
    var out: EllipsoidVaryings;
    out.clip = vec4<f32>(0.0, 0.0, -2.0, 1.0);
    return out;
}

// One corner of the quad of an ellipsoid (spec §6.8). `first_vertex` is 6 × the range's first
// ellipsoid; those outside the level τ (`draw.tau_p`, metres per pixel) selects, widened by the
// level blend (`level_keep`), are dropped. The
// quad lies across the view ray through the centre, along the axes of the ellipse that the
// ellipsoid projects to in parallel along that ray, its half-extents the ellipsoid's support along
// them, widened by D / (D − h) (D the eye's distance, h the support towards the eye): every point
// of the ellipsoid projects into it from the eye, and it is tight for a distant ellipsoid and
// exact for an orthographic view.
@vertex
fn vs_ellipsoid(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> EllipsoidVaryings {
    let draw = draw_at(draw_index);
    let index = vertex_index / 6u;
    let e = ellipsoids[index];
    let keep = level_keep(e.lo, e.hi, draw.tau_p, frame.level_blend);
    if keep.x < 0.0 {
        return offscreen_ellipsoid();
    }
    let f = ellipsoid_frame(draw, e);
    let forward = normalize(view_ray(f.centre));
    let r3 = view_proj_row(3u);
    let w = dot(r3, vec4<f32>(f.centre, 1.0));
    // 1 / D: the clip w grows by r3·forward per metre along the ray (0 when orthographic).
    let inv_distance = dot(r3.xyz, forward) / w;
    let near = ellipsoid_support(f, forward) * inv_distance;
    if w <= 0.0 || near >= 0.999 {
        // Behind the eye, or the eye (nearly) inside it.
        return offscreen_ellipsoid();
    }
    var right = cross(forward, frame.up.xyz);
    if dot(right, right) < 1e-8 {
        right = cross(forward, frame.right.xyz);
    }
    right = normalize(right);
    let up = cross(right, forward);
    // The parallel projection's ellipse: S = [a b; b c] in (right, up); its axes at angle θ.
    let au = transpose(f.axes) * right;
    let av = transpose(f.axes) * up;
    let angle = 0.5 * atan2(2.0 * dot(au, av), dot(au, au) - dot(av, av));
    let e1 = cos(angle) * right + sin(angle) * up;
    let e2 = cos(angle) * up - sin(angle) * right;
    let widen = 1.0 / (1.0 - near);
    let corner = CORNERS[vertex_index % 6u];
    let world = f.centre
        + (corner.x * ellipsoid_support(f, e1) * e1 + corner.y * ellipsoid_support(f, e2) * e2) * widen;
    var out: EllipsoidVaryings;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.ellipsoid = index;
    out.draw = draw_index;
    out.keep = keep;
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u: { out.tint = vec3<f32>(0.2, 0.8, 0.8); }
        case 3u: { out.tint = level_tint(e.hi); }
        case 4u: { out.tint = unpack4x8unorm(draw.tint).rgb; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// Where a fragment's view ray meets an ellipsoid.
struct EllipsoidHit {
    // Whether it does.
    hit: bool,
    // The hit on the unit sphere of the local frame (its outward normal there).
    local: vec3<f32>,
    // World position, and the depth to write: of the hit moved `push` metres along the ray.
    world: vec3<f32>,
    depth: f32,
    // The noise's level at the hit: the record's level or, coarser, the one the pixel's footprint
    // asks for (like mip-mapping: Clasen §5 limits the noise frequency by fwidth).
    level: f32,
    record: EllipsoidRecord,
    frame: EllipsoidFrame,
}

// Intersects the fragment's view ray with its ellipsoid (Sigg et al. 2006): the quad's point and
// the ray's direction mapped into the local frame, |o + t·d| = 1 solved for the nearer t. Computes
// the noise level from screen derivatives, so call it in uniform control flow.
fn ellipsoid_hit(in: EllipsoidVaryings, push: f32) -> EllipsoidHit {
    let e = ellipsoids[in.ellipsoid];
    let f = ellipsoid_frame(draw_at(in.draw), e);
    let ray = normalize(view_ray(in.world));
    let o = f.inverse * (in.world - f.centre);
    let d = f.inverse * ray;
    let a = dot(d, d);
    let b = dot(o, d);
    let disc = b * b - a * (dot(o, o) - 1.0);
    let t = (-b - sqrt(max(disc, 0.0))) / a;
    let local = o + t * d;
    var out: EllipsoidHit;
    out.record = e;
    out.frame = f;
    out.local = normalize(local);
    out.world = in.world + t * ray;
    let clip = frame.view_proj * vec4<f32>(out.world + push * ray, 1.0);
    out.depth = clip.z / clip.w;
    out.hit = disc >= 0.0 && clip.w > 0.0 && out.depth >= 0.0 && out.depth <= 1.0;
    let footprint = max(length(dpdx(out.local)), length(dpdy(out.local))) * NOISE_TEXELS_PER_RADIAN;
    out.level = clamp(max(NOISE_TOP_LEVEL - e.noise_mip, log2(max(footprint, 1e-6))), 0.0, NOISE_TOP_LEVEL);
    return out;
}

struct EllipsoidOut {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
    @builtin(sample_mask) mask: u32,
}

@fragment
fn fs_ellipsoid(in: EllipsoidVaryings) -> EllipsoidOut {
    let hit = ellipsoid_hit(in, 0.0);
    let noise_texel = textureSampleLevel(noise, noise_sampler, hit.local, hit.level);
    let draw = draws[in.draw];
    let mask = level_mask(in.keep, in.clip, in.draw) & fade_mask(draw.fade, draw.instance, in.clip);
    // Holes where the grey noise is below the threshold (Clasen §3.1).
    if !hit.hit || noise_texel.a < hit.record.alpha_threshold || mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return EllipsoidOut(vec4<f32>(in.tint, 1.0), hit.depth, mask);
    }
    // The normal turned towards the noise's random vector (on the normal's side), in the local
    // frame, then to the world by the inverse transpose.
    var random = noise_texel.rgb * 2.0 - 1.0;
    random = select(-random, random, dot(random, hit.local) >= 0.0);
    let local_normal = normalize(mix(hit.local, normalize(random + vec3<f32>(1e-6)), ELLIPSOID_NORMAL_NOISE));
    let normal = normalize(transpose(hit.frame.inverse) * local_normal);
    let albedo = decode_color(hit.record.color).rgb;
    // As uploaded, `flags` holds the ellipsoid's ambient-occlusion byte (spec §6.14; 0 without).
    return EllipsoidOut(vec4<f32>(shade(albedo, normal, hit.world, decode_ao(hit.record.flags)) * in.tint, 1.0), hit.depth, mask);
}

// The shadow pass: the ray-cast depth (pushed ELLIPSOID_SHADOW_BIAS_TEXELS texels away from the
// sun against self-shadowing) with the same holes and the same level blend.
@fragment
fn fs_shadow_ellipsoid(in: EllipsoidVaryings) -> @builtin(frag_depth) f32 {
    // A cascade's frame holds its resolution in eye.w and 1 / its half-width in right.w.
    let texel = 2.0 / max(frame.right.w * frame.eye.w, 1e-12);
    let hit = ellipsoid_hit(in, ELLIPSOID_SHADOW_BIAS_TEXELS * texel);
    let alpha = textureSampleLevel(noise, noise_sampler, hit.local, hit.level).a;
    if !hit.hit || alpha < hit.record.alpha_threshold || level_mask(in.keep, in.clip, in.draw) == 0u {
        discard;
    }
    return hit.depth;
}
