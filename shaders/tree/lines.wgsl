// Clasen's branch lines (Clasen and Prohaska 2011 §4; spec §6.9): each line is a round cone, the
// convex hull of a sphere of radius r0 at p0 and one of radius r1 at p1 (a capsule whose radius
// goes linearly from r0 to r1, with spherical caps). A screen quad bounds its projection and each
// fragment intersects its view ray with it exactly, writing the hit's depth, as for ellipsoids.
//
// Lines thinner than a pixel (the build aims at a mean width of one pixel) would alias into
// broken dashes if ray-cast: where the line's width w at the fragment is below one pixel, the
// line is drawn one pixel wide instead (the pixels whose ray passes within half a pixel of its
// axis, which leaves no gap along it), covering the share w of each such pixel (alpha to coverage
// with MSAA, else a hash of pixel and depth as minified impostor leaves do), at the depth of the
// point of the ray nearest the axis. On average a line so covers w pixels per pixel of length, as
// much as its true width.

// Rust twin: treelod_format::LineRecord (56 bytes, spec §6.9).
struct LineRecord {
    p0: array<f32, 3>,
    r0: f32,
    p1: array<f32, 3>,
    r1: f32,
    color: u32,
    lo: f32,
    hi: f32,
    leaf_first: u32,
    leaf_count: u32,
    flags: u32,
}

// Clasen's branch lines (spec §6.9). As uploaded, a line's `flags` holds its LINE_AO byte.
@group(3) @binding(0) var<storage, read> lines: array<LineRecord>;

struct LineVaryings {
    @builtin(position) clip: vec4<f32>,
    // A point of the quad, world space: on the fragment's view ray.
    @location(0) world: vec3<f32>,
    @location(1) @interpolate(flat) line: u32,
    @location(2) @interpolate(flat) draw: u32,
    // The cell's shading or the debug views' colour.
    @location(3) @interpolate(flat) tint: vec3<f32>,
    // The level blend's dither range (`level_keep`): drawn where keep.x <= h < keep.y.
    @location(4) @interpolate(flat) keep: vec2<f32>,
}

// A line of an instance, world space: the axis from a to b, the radii there (instances scale
// uniformly).
struct LineFrame {
    a: vec3<f32>,
    b: vec3<f32>,
    ra: f32,
    rb: f32,
}

fn line_frame(draw: Draw, l: LineRecord) -> LineFrame {
    var out: LineFrame;
    out.a = (draw.model * vec4<f32>(l.p0[0], l.p0[1], l.p0[2], 1.0)).xyz;
    out.b = (draw.model * vec4<f32>(l.p1[0], l.p1[1], l.p1[2], 1.0)).xyz;
    out.ra = max(l.r0, 0.0) * draw.scale;
    out.rb = max(l.r1, 0.0) * draw.scale;
    return out;
}

// The clip w of the world point p: the view depth (1 for an orthographic view).
fn clip_w(p: vec3<f32>) -> f32 {
    return dot(view_proj_row(3u), vec4<f32>(p, 1.0));
}

// Metres across a pixel at clip w: 2·w·tan(fovy/2) / H for the camera; a cascade's frame holds
// 1 / its half-width in right.w and its resolution in eye.w, and w = 1, so its texel.
fn pixel_size(w: f32) -> f32 {
    return 2.0 * w / max(frame.right.w * frame.eye.w, 1e-12);
}

// The view's forward axis (away from the viewer).
fn view_forward() -> vec3<f32> {
    return normalize(cross(frame.up.xyz, frame.right.xyz));
}

fn offscreen_line() -> LineVaryings {
    var out: LineVaryings;
    out.clip = vec4<f32>(0.0, 0.0, -2.0, 1.0);
    return out;
}

// The radius, pixels, of a circle about the projection of the sphere (p, r) that holds the
// sphere's projection. Seen at angle θ off the view axis, a sphere of angular radius α projects
// to an ellipse reaching (r / w) / cos(θ + α) from p's projection in the image plane, w the view
// depth (Sigg et al. 2006 bound it likewise); an orthographic view has θ = α = 0.
fn sphere_pixels(p: vec3<f32>, r: f32, w: f32) -> f32 {
    let f = normalize(view_ray(p));
    let cos_theta = clamp(abs(dot(f, view_forward())), 0.0, 1.0);
    let sin_alpha = min(r * dot(view_proj_row(3u).xyz, f) / w, 0.95);
    let cos_sum = cos_theta * sqrt(1.0 - sin_alpha * sin_alpha) - sqrt(1.0 - cos_theta * cos_theta) * sin_alpha;
    return r / pixel_size(w) / max(cos_sum, 0.05);
}

// One corner of the quad of a line (spec §6.9). `first_vertex` is 6 × the range's first line;
// those outside the level τ (`draw.tau_p`, metres per pixel) selects, widened by the level blend
// (`level_keep`), are dropped. In pixels, the
// round cone's projection lies in the hull of the circles that hold its end spheres' projections
// (`sphere_pixels`, at least 0.75 px so thin lines get their one-pixel band, plus a margin); the
// quad is the trapezoid of that hull's two outer tangents, closed beyond each circle. Each end's
// corners are placed in the plane through that end parallel to the image, where world offsets
// along the camera's right and up axes map to pixels linearly, so the quad projects exactly to
// the trapezoid.
@vertex
fn vs_line(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> LineVaryings {
    let draw = draw_at(draw_index);
    let index = vertex_index / 6u;
    let l = lines[index];
    let keep = level_keep(l.lo, l.hi, draw.tau_p, frame.level_blend);
    if keep.x < 0.0 {
        return offscreen_line();
    }
    let f = line_frame(draw, l);
    var a = f.a;
    var b = f.b;
    var ra = f.ra;
    var rb = f.rb;
    var wa = clip_w(a);
    var wb = clip_w(b);
    if max(wa, wb) <= 0.0 {
        return offscreen_line();
    }
    // An end behind the eye moves along the axis to just in front of it (what lies nearer is
    // clipped anyway).
    let w_min = 1e-3 * max(wa, wb);
    if wa < w_min {
        let k = (w_min - wa) / (wb - wa);
        a = mix(a, b, k);
        ra = mix(ra, rb, k);
        wa = w_min;
    } else if wb < w_min {
        let k = (w_min - wb) / (wa - wb);
        b = mix(b, a, k);
        rb = mix(rb, ra, k);
        wb = w_min;
    }
    let right = frame.right.xyz;
    let up = frame.up.xyz;
    let eye = frame.eye.xyz;
    let pa = pixel_size(wa);
    let pb = pixel_size(wb);
    // The ends in pixels (about the view axis; only differences matter) and their circles.
    let sa = vec2<f32>(dot(a - eye, right), dot(a - eye, up)) / pa;
    let sb = vec2<f32>(dot(b - eye, right), dot(b - eye, up)) / pb;
    let margin = 0.5;
    let ca = max(1.02 * sphere_pixels(a, ra, wa), 0.75) + margin;
    let cb = max(1.02 * sphere_pixels(b, rb, wb), 0.75) + margin;
    let span = sb - sa;
    let len = length(span);
    let corner = CORNERS[vertex_index % 6u];
    var at_b = corner.x > 0.0;
    var px = vec2<f32>(0.0);
    if len > 1e-4 && abs(cb - ca) < 0.9 * len {
        // The outer tangents of the two circles: at angle ψ to the axis, sin ψ = (cb − ca) / len.
        let along = span / len;
        let across = vec2<f32>(-along.y, along.x);
        let sin_psi = (cb - ca) / len;
        let cos_psi = sqrt(1.0 - sin_psi * sin_psi);
        if at_b {
            px = sb + cb * along + corner.y * cb * (1.0 + sin_psi) / cos_psi * across;
        } else {
            px = sa - ca * along + corner.y * ca * (1.0 - sin_psi) / cos_psi * across;
        }
    } else {
        // One circle (nearly) holds the other: their bounding box, in the plane of the nearer end.
        let lo = min(sa - ca, sb - cb);
        let hi = max(sa + ca, sb + cb);
        px = select(lo, hi, corner > vec2<f32>(0.0));
        at_b = wb < wa;
    }
    var world = vec3<f32>(0.0);
    if at_b {
        world = b + ((px.x - sb.x) * right + (px.y - sb.y) * up) * pb;
    } else {
        world = a + ((px.x - sa.x) * right + (px.y - sa.y) * up) * pa;
    }
    var out: LineVaryings;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.line = index;
    out.draw = draw_index;
    out.keep = keep;
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u: { out.tint = vec3<f32>(0.55, 0.35, 0.15); }
        case 3u: { out.tint = level_tint(l.hi); }
        case 4u: { out.tint = unpack4x8unorm(draw.tint).rgb; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// The entry of the line o + t·d (d unit) into the sphere (c, r), if it comes before best.x:
// vec4(t, outward unit normal). The squared distance of the centre from the line is taken from
// the perpendicular itself, not as |o − c|² − b² (which loses a thin sphere to rounding).
fn sphere_entry(best: vec4<f32>, o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, r: f32) -> vec4<f32> {
    let oc = o - c;
    let b = dot(oc, d);
    let perp = oc - b * d;
    let h = r * r - dot(perp, perp);
    if h < 0.0 || r <= 0.0 {
        return best;
    }
    let t = -b - sqrt(h);
    if t >= best.x {
        return best;
    }
    return vec4<f32>(t, (oc + t * d) / r);
}

// Where the line o + t·d (d unit) first meets the round cone f: vec4(t, outward unit normal),
// t = 1e30 where it misses. The solid is the union of its two end spheres and the cone frustum
// between the circles where the cone touches them, all convex, so the first crossing is the
// smallest of: either sphere's entry, and the crossings of the cone's surface within those
// circles. With the axis u = (b − a)/L and sin φ = (ra − rb)/L, the cone's surface is the set of
// points at height y along the axis and distance q from it with q·cos φ = ra − y·sin φ; it
// touches sphere a at y = ra·sin φ and sphere b at y = L + rb·sin φ. Squared, along the line:
// cos²φ·q(t)² − (ra − y(t)·sin φ)² = 0, a quadratic in t; the band of heights keeps the crossings
// of the right nappe. (Where one sphere holds the other there is no cone: the spheres alone.)
fn round_cone_hit(o: vec3<f32>, d: vec3<f32>, f: LineFrame) -> vec4<f32> {
    var best = vec4<f32>(1e30, 0.0, 0.0, 0.0);
    best = sphere_entry(best, o, d, f.a, f.ra);
    best = sphere_entry(best, o, d, f.b, f.rb);
    let s = f.b - f.a;
    let len = length(s);
    if len <= 0.0 {
        return best;
    }
    let sin_phi = (f.ra - f.rb) / len;
    if abs(sin_phi) >= 1.0 {
        return best;
    }
    let axis = s / len;
    let cos2 = 1.0 - sin_phi * sin_phi;
    let w0 = o - f.a;
    let y0 = dot(w0, axis);
    let yd = dot(d, axis);
    // The offset from the axis, taken directly (|w0|² − y0² would round a thin line away).
    let radial0 = w0 - y0 * axis;
    let k = f.ra - y0 * sin_phi;
    let c2 = cos2 - yd * yd;
    let c1 = cos2 * dot(radial0, d) + sin_phi * yd * k;
    let c0 = cos2 * dot(radial0, radial0) - k * k;
    let disc = c1 * c1 - c0 * c2;
    if disc < 0.0 || abs(c2) < 1e-12 {
        return best;
    }
    let root = sqrt(disc);
    for (var i = 0u; i < 2u; i++) {
        let t = (-c1 + select(-root, root, i == 1u)) / c2;
        let y = y0 + t * yd;
        if y < f.ra * sin_phi || y > len + f.rb * sin_phi || t >= best.x {
            continue;
        }
        let radial = radial0 + t * (d - yd * axis);
        let n = normalize(radial) * sqrt(cos2) + axis * sin_phi;
        best = vec4<f32>(t, normalize(n));
    }
    return best;
}

// Where a fragment's view ray meets its line.
struct LineHit {
    // Whether the line is drawn at the fragment.
    hit: bool,
    // The share of the pixel it covers: 1, or the width in pixels of a line thinner than one.
    coverage: f32,
    // World position and normal at the hit, and the depth to write: of the hit moved `push`
    // metres along the ray.
    world: vec3<f32>,
    normal: vec3<f32>,
    depth: f32,
}

// Intersects the fragment's view ray with its line: exactly where the line is at least a pixel
// wide at the ray's nearest approach to its axis, else as the one-pixel band of coverage w (see
// the section's head).
fn line_hit(in: LineVaryings, push: f32) -> LineHit {
    let f = line_frame(draw_at(in.draw), lines[in.line]);
    let d = normalize(view_ray(in.world));
    let o = in.world;
    let s = f.b - f.a;
    // The nearest points of the ray and the axis segment: u along the segment, clamped, and t
    // along the ray.
    let w0 = o - f.a;
    let ss = dot(s, s);
    let sd = dot(s, d);
    let denom = ss - sd * sd;
    var u = 0.0;
    if denom > 1e-12 * ss {
        u = clamp((dot(s, w0) - dot(d, w0) * sd) / denom, 0.0, 1.0);
    }
    let t_axis = u * sd - dot(d, w0);
    let on_ray = o + t_axis * d;
    let off = on_ray - (f.a + u * s);
    let r = mix(f.ra, f.rb, u);
    let pixel = pixel_size(max(clip_w(on_ray), 1e-12));
    let width = 2.0 * r / pixel;
    var out: LineHit;
    var t = t_axis;
    if width >= 1.0 {
        let hit = round_cone_hit(o, d, f);
        out.hit = hit.x < 1e29;
        out.coverage = 1.0;
        out.normal = hit.yzw;
        t = hit.x;
    } else {
        out.hit = dot(off, off) <= 0.25 * pixel * pixel;
        out.coverage = width;
        // Across the axis, towards the viewer: the mean of the visible half's normals.
        let axis = s * inverseSqrt(max(ss, 1e-30));
        let facing = dot(d, axis) * axis - d;
        out.normal = select(-d, normalize(facing), dot(facing, facing) > 1e-12);
    }
    out.world = o + t * d;
    let clip = frame.view_proj * vec4<f32>(out.world + push * d, 1.0);
    out.depth = clip.z / clip.w;
    out.hit = out.hit && clip.w > 0.0 && out.depth >= 0.0 && out.depth <= 1.0;
    return out;
}

struct LineOut {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
    @builtin(sample_mask) mask: u32,
}

@fragment
fn fs_line(in: LineVaryings) -> LineOut {
    let hit = line_hit(in, 0.0);
    // A thin line's coverage: that share of the samples with MSAA, or of the pixels without.
    var mask = coverage_mask(hit.coverage, in.clip);
    if sample_count == 1u {
        mask = select(0u, 0xFFFFFFFFu, hit.coverage >= 1.0 || hit.coverage > layered_dither(in.clip));
    }
    // And the level blend's share, independent of it.
    mask &= level_mask(in.keep, in.clip, in.draw);
    // And the transition's between techniques.
    let draw = draws[in.draw];
    mask &= fade_mask(draw.fade, draw.instance, in.clip);
    if !hit.hit || mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return LineOut(vec4<f32>(in.tint, 1.0), hit.depth, mask);
    }
    let l = lines[in.line];
    // As uploaded, `flags` holds the line's ambient-occlusion byte (spec §6.14; 0 without).
    let colour = shade(decode_color(l.color).rgb, hit.normal, hit.world, decode_ao(l.flags)) * in.tint;
    return LineOut(vec4<f32>(colour, 1.0), hit.depth, mask);
}

// The shadow pass: the same hit (pushed ELLIPSOID_SHADOW_BIAS_TEXELS texels away from the sun),
// lines thinner than a texel kept on the share of texels their width covers, and the same level
// blend.
@fragment
fn fs_shadow_line(in: LineVaryings) -> @builtin(frag_depth) f32 {
    let hit = line_hit(in, ELLIPSOID_SHADOW_BIAS_TEXELS * pixel_size(1.0));
    let covered = hit.coverage >= 1.0 || hit.coverage > layered_dither(in.clip);
    if !hit.hit || !covered || level_mask(in.keep, in.clip, in.draw) == 0u {
        discard;
    }
    return hit.depth;
}
