// Baseline octahedral impostors (spec §6.13.1): one quad per tree facing the viewer, textured from
// the tree baked orthographically over the upper hemisphere (a grid of N × N views on a
// hemi-octahedral map), the three views of the grid triangle holding the view direction blended
// with barycentric weights, as engines' impostor bakers draw far trees.

// Rust twin: OctahedralGpu in crates/treelod-render/src/technique/baselines.rs, 64 bytes: the
// file's OctahedralRecord (48 bytes, spec §6.13.1), then where its normals lie.
struct OctahedralRecord {
    center: array<f32, 3>,
    radius: f32,
    image: u32,
    uv_min: u32,
    uv_max: u32,
    frames: u32,
    tree: u32,
    occlusion: f32,
    // PlaneDiffuseRecord's shares, flat in bits 0–15, scattered in bits 16–31 (unorm16).
    diffuse: u32,
    // Reserved in the file; as uploaded, the index of the impostor's first view in
    // `view_planes` (technique/baselines.rs, `gpu_octahedral`).
    depth_first: u32,
    // As uploaded (technique/baselines.rs, `OctahedralGpu`): the corners of the views' normal
    // grid (treelod_format::OctahedralNormalGridRecord, spec §6.13.3), and 1 where there is one.
    normals_uv_min: u32,
    normals_uv_max: u32,
    has_normals: u32,
    padding: u32,
}

// The planes' group layout (technique/impostors.rs, `GROUP`): the records in place of the planes,
// the atlas and its sampler; the leaf slots and plane leaves are bound blank and not read.
@group(3) @binding(0) var<storage, read> impostors: array<OctahedralRecord>;
@group(3) @binding(1) var atlas: texture_2d<f32>;
@group(3) @binding(2) var atlas_sampler: sampler;
// The views' depth planes (spec §6.13.2), three floats per view (treelod_format::
// OctahedralDepthRecord), each impostor's N² views in turn in the order of `impostors`, bound
// in place of the planes' leaves; empty for a container without them.
@group(3) @binding(4) var<storage, read> view_planes: array<f32>;

// View (i, j)'s depth plane (offset, slope_s, slope_t) of an impostor whose first view's is
// `first`, of a grid of `n` a side; the plane through the centre across the view (0, 0, 0)
// where none is bound.
fn view_plane(first: u32, n: u32, view: vec2<u32>) -> vec3<f32> {
    let at = 3u * (first + view.y * n + view.x);
    if at + 3u > arrayLength(&view_planes) {
        return vec3<f32>(0.0);
    }
    return vec3<f32>(view_planes[at], view_planes[at + 1u], view_planes[at + 2u]);
}

struct OctahedralVaryings {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    // The fragment's (s, t) in each of the three views, [−1, 1]² inside its cell, as
    // homogeneous coordinates (s·w, t·w, w).
    @location(1) st0: vec3<f32>,
    @location(2) st1: vec3<f32>,
    @location(3) st2: vec3<f32>,
    // Each view's cell corner in the atlas (uv) and the cells' size.
    @location(4) @interpolate(flat) cell01: vec4<f32>,
    @location(5) @interpolate(flat) cell2: vec2<f32>,
    @location(6) @interpolate(flat) cell_size: vec2<f32>,
    @location(7) @interpolate(flat) weights: vec3<f32>,
    // The sun's diffuse factor (x) and the ambient occlusion (y).
    @location(8) @interpolate(flat) light: vec2<f32>,
    @location(9) @interpolate(flat) normal: vec3<f32>,
    @location(10) @interpolate(flat) tint: vec3<f32>,
    @location(11) @interpolate(flat) fade: vec2<u32>,
    // Where the normal grid lies (spec §6.13.3): the colour grid's point `uv` has its normal at
    // `xy + uv · zw` (zw, the grids' ratio of sides, is 0 where the impostor has none); the sun's
    // direction in block space, where the normals are.
    @location(12) @interpolate(flat) normals: vec4<f32>,
    @location(13) @interpolate(flat) sun_block: vec3<f32>,
}

// The direction of view (i, j) of a grid of `n` a side, from the centre towards the viewer.
// Rust twin: treelod_format::OctahedralRecord::view_direction.
fn view_direction(n: u32, i: u32, j: u32) -> vec3<f32> {
    let last = f32(max(n, 2u) - 1u);
    let a = 2.0 * f32(i) / last - 1.0;
    let b = 2.0 * f32(j) / last - 1.0;
    let x = 0.5 * (a + b);
    let z = 0.5 * (a - b);
    return normalize(vec3<f32>(x, max(1.0 - abs(x) - abs(z), 0.0), z));
}

// A view's right vector: normalize(Y × d), +X straight above. Its up is d × right. Rust twin:
// treelod_format::OctahedralRecord::view_basis.
fn view_right(d: vec3<f32>) -> vec3<f32> {
    let r = vec3<f32>(d.z, 0.0, -d.x);
    let l = length(r);
    return select(vec3<f32>(1.0, 0.0, 0.0), r / l, l > 1e-6);
}

// The sun's diffuse factor of an impostor seen along unit `view` (world space): spec §6.13.1's
// mixture with the view's direction as the plane's normal, surfaces facing the viewer (share f)
// and turned every way (s), each weighted by the area it shows; those seen edge on show none.
// Rust twin: treelod_format::PlaneDiffuseRecord::diffuse(v, v, l).
fn octahedral_diffuse(view: vec3<f32>, packed: u32) -> f32 {
    let f = f32(packed & 0xFFFFu) / 65535.0;
    let s = min(f32(packed >> 16u) / 65535.0, 1.0 - f);
    let vl = abs(dot(view, frame.sun.xyz));
    let den = f + 0.5 * s;
    if den > 1e-6 {
        return clamp((f * vl + s * 2.0 / (3.0 * 3.1415927) * lobe(vl)) / den, 0.0, 1.0);
    }
    return vl;
}

// One corner of an octahedral impostor's quad: a square of `radius` about its centre facing the
// direction to the eye, with that direction's basis (so the views' images keep their up), and
// the corner's place in the three views the direction lies between (block space: the instance's
// transform is a rotation, a uniform scale and a translation).
@vertex
fn vs_octahedral(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> OctahedralVaryings {
    let draw = draw_at(draw_index);
    let rec = impostors[vertex_index / 6u];
    let corner = CORNERS[vertex_index % 6u];
    let centre = vec3<f32>(rec.center[0], rec.center[1], rec.center[2]);
    let centre_world = (draw.model * vec4<f32>(centre, 1.0)).xyz;
    let to_eye = frame.eye.xyz - centre_world;
    let rotation = mat3x3<f32>(draw.model[0].xyz, draw.model[1].xyz, draw.model[2].xyz);
    var d = transpose(rotation) * to_eye;
    // Below the horizon: the horizon's views.
    d.y = max(d.y, 0.0);
    d = select(vec3<f32>(0.0, 0.0, 1.0), normalize(d), dot(d, d) > 1e-20);
    let right = view_right(d);
    let up = cross(d, right);
    // The eye from the centre, block space (the transform's scale is uniform).
    let e = transpose(rotation) * to_eye / dot(rotation[0], rotation[0]);

    // The grid triangle holding d's point on the map (treelod_format::OctahedralRecord::blend).
    let n = max(rec.frames, 2u);
    let last = n - 1u;
    let sum = abs(d.x) + d.y + abs(d.z);
    let x = d.x / sum;
    let z = d.z / sum;
    let g = clamp(vec2<f32>(x + z + 1.0, x - z + 1.0) * 0.5 * f32(last), vec2<f32>(0.0), vec2<f32>(f32(last)));
    let c = min(vec2<u32>(floor(g)), vec2<u32>(last - 1u));
    let f = g - vec2<f32>(c);
    var views: array<vec2<u32>, 3>;
    var weights: vec3<f32>;
    if f.x + f.y <= 1.0 {
        views = array<vec2<u32>, 3>(c, c + vec2<u32>(1u, 0u), c + vec2<u32>(0u, 1u));
        weights = vec3<f32>(1.0 - f.x - f.y, f.x, f.y);
    } else {
        views = array<vec2<u32>, 3>(c + vec2<u32>(1u, 1u), c + vec2<u32>(0u, 1u), c + vec2<u32>(1u, 0u));
        weights = vec3<f32>(f.x + f.y - 1.0, 1.0 - f.x, 1.0 - f.y);
    }
    // Each view's basis and depth plane (spec §6.13.2): the view shows its image on the plane
    // n·(p − centre) = offset·radius, n = d − slope_s·right − slope_t·up, seen through from the
    // eye; and how far the quad must reach to hold every view's square on its plane as the eye
    // sees it, the largest of its corners' places on the quad's plane (at least the radius).
    var basis: array<mat3x3<f32>, 3>;
    var planes: array<vec3<f32>, 3>;
    var reach = 1.0;
    for (var k = 0u; k < 3u; k++) {
        let dk = view_direction(n, views[k].x, views[k].y);
        let rk = view_right(dk);
        basis[k] = mat3x3<f32>(rk, cross(dk, rk), dk);
        planes[k] = view_plane(rec.depth_first, n, views[k]);
        for (var q = 0u; q < 4u; q++) {
            let st = vec2<f32>(select(-1.0, 1.0, (q & 1u) != 0u), select(-1.0, 1.0, (q & 2u) != 0u));
            let p = rec.radius * (basis[k] * vec3<f32>(st, planes[k].x + dot(planes[k].yz, st)));
            // Where the eye's ray to p meets the quad's plane (through the centre, across d); a
            // corner at or behind the eye's depth bounds nothing (the quad then reaches 4 radii).
            let towards = dot(d, e - p);
            let seen = select(4.0 * rec.radius, 0.0, towards > 1e-3 * rec.radius);
            let on = e + (p - e) * (dot(d, e) / max(towards, 1e-3 * rec.radius));
            reach = max(reach, max(seen, max(abs(dot(on, right)), abs(dot(on, up)))) / rec.radius);
        }
    }
    let offset = min(reach, 4.0) * rec.radius * (corner.x * right + corner.y * up);
    let uv_min = unpack2x16unorm(rec.uv_min);
    let uv_max = unpack2x16unorm(rec.uv_max);
    let cell_size = (uv_max - uv_min) / f32(n);
    // The fragment's (s, t) in view k, where the eye's ray through it meets the view's plane,
    // as homogeneous coordinates (numerators, denominator), each affine in the quad's point and
    // so interpolated exactly: with w = n·(offset − e), the ray e + λ·(offset − e) meets the
    // plane at λ = (offset_k·radius − n·e) / w.
    var st: array<vec3<f32>, 3>;
    var cells: array<vec2<f32>, 3>;
    for (var k = 0u; k < 3u; k++) {
        let nk = basis[k][2] - planes[k].y * basis[k][0] - planes[k].z * basis[k][1];
        let ray = offset - e;
        let w = dot(nk, ray);
        let lead = planes[k].x * rec.radius - dot(nk, e);
        st[k] = vec3<f32>(
            dot(basis[k][0], e) * w + lead * dot(basis[k][0], ray),
            dot(basis[k][1], e) * w + lead * dot(basis[k][1], ray),
            rec.radius * w,
        );
        cells[k] = uv_min + vec2<f32>(views[k]) * cell_size;
    }
    var out: OctahedralVaryings;
    let world = (draw.model * vec4<f32>(centre + offset, 1.0)).xyz;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.st0 = st[0];
    out.st1 = st[1];
    out.st2 = st[2];
    out.cell01 = vec4<f32>(cells[0], cells[1]);
    out.cell2 = cells[2];
    out.cell_size = cell_size;
    out.weights = weights;
    let view = normalize(to_eye);
    out.light = vec2<f32>(octahedral_diffuse(view, rec.diffuse), rec.occlusion);
    out.normal = view;
    let normal_min = unpack2x16unorm(rec.normals_uv_min);
    let sides = (unpack2x16unorm(rec.normals_uv_max) - normal_min) / max(uv_max - uv_min, vec2<f32>(1e-9));
    let ratio = select(vec2<f32>(0.0), sides, rec.has_normals != 0u);
    out.normals = vec4<f32>(normal_min - uv_min * ratio, ratio);
    out.sun_block = normalize(transpose(rotation) * frame.sun.xyz);
    out.fade = vec2<u32>(draw.fade, draw.instance);
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u, 3u: { out.tint = vec3<f32>(0.95, 0.5, 0.65); }
        case 4u: { out.tint = unpack4x8unorm(draw.tint).rgb; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// The texel of one of the three views, each taken at a pixel with the probability of its
// weight (by the pixel's dither value, `dither`): the views' silhouettes differ where thin
// branches stand, and blending their alphas before the test at one half would erode what only
// one or two of them cover; a pixel of one view keeps each view's coverage in expectation. A
// view's texel outside its cell (a corner of the quad past the view's square) is empty. Its
// alpha is the covered share, tested at one half as the billboards' (`quad_texel`). Sampled in
// uniform control flow, from the mip level one finer than the pixel's footprint: the levels keep
// the covered area (coverage-preserving alpha), but a level whose texels are as large as the
// pixels or larger blurs the crown's gaps before the test, which then draws them as solid blobs
// (a lone pine lost 3-11 % of the reference's ink, mean of 4 views, from 16 to 64 radii); a
// level finer keeps the gaps, as the leaves' own stochastic coverage does. Measured: 200 oaks in
// `bench --quality` RMSE .01816 -> .01763, FLIP .03550 -> .03372 (the point tree's .01847,
// .03412), 200 pines .01923 -> .01818, .04063 -> .03852, 200 Quaternius trees .01235 ->
// .01218, .02111 -> .02078; two levels finer gained less or lost (the oak alone at 8-32 px
// RMSE .00137 -> .00157). (A minified texel covering its share of the pixels by a hash of pixel
// and depth instead, as the point tree's splats and minified indirect leaves do at one sample,
// was measured and not taken: the pine at 8-32 px high in `eval --orbit 32` RMSE .00152 ->
// .00189, P .955 -> .808; 200 pines in `bench --quality` RMSE .01923 -> .02069, FLIP .04063 ->
// .04001: the hash's noise costs more at the finer scales than the softer edge gains. The colour
// blended over the three views by weight and coverage, the chosen view keeping the coverage, was
// measured and not taken too: 200 jacarandas, whose policy draws 110 of 112 trees so, RMSE
// .02041 -> .02040, FLIP .04330 -> .04325; the views' colours differ little, and what FLIP sees
// is the far crowns drawn as solid shapes where the reference shows their gaps.)
//
// With `normals`, also the chosen view's normal texel (spec §6.13.3), at the same place of its
// normal cell (whose grid is smaller than the colour's, half its side as builders write it) and
// from the level of the same footprint; (0, 0, 0, 0) without.
struct OctahedralTexel {
    colour: vec4<f32>,
    normal: vec4<f32>,
}

fn octahedral_texel(in: OctahedralVaryings, normals: bool) -> OctahedralTexel {
    let st = array<vec2<f32>, 3>(in.st0.xy / in.st0.z, in.st1.xy / in.st1.z, in.st2.xy / in.st2.z);
    let cells = array<vec2<f32>, 3>(in.cell01.xy, in.cell01.zw, in.cell2);
    let h = dither(in.clip);
    let chosen = select(select(2u, 1u, h < in.weights.x + in.weights.y), 0u, h < in.weights.x);
    var out = OctahedralTexel(vec4<f32>(0.0), vec4<f32>(0.0));
    var at = vec2<f32>(0.0);
    var dx = vec2<f32>(0.0);
    var dy = vec2<f32>(0.0);
    for (var k = 0u; k < 3u; k++) {
        let uv = cells[k] + clamp(0.5 * (st[k] + 1.0), vec2<f32>(0.0), vec2<f32>(1.0)) * in.cell_size;
        // One mip level finer than the pixel's footprint (half the derivatives): see above.
        let gx = 0.5 * dpdx(uv);
        let gy = 0.5 * dpdy(uv);
        let texel = textureSampleGrad(atlas, atlas_sampler, uv, gx, gy);
        if k == chosen && all(abs(st[k]) <= vec2<f32>(1.0)) {
            out.colour = texel;
            at = uv;
            dx = gx;
            dy = gy;
        }
    }
    if normals && in.normals.z > 0.0 && out.colour.a >= 0.5 {
        let ratio = in.normals.zw;
        out.normal = textureSampleGrad(atlas, atlas_sampler, in.normals.xy + at * ratio, dx * ratio, dy * ratio);
    }
    return out;
}

// The sun's diffuse factor of a texel whose decoded normal is `n` (block space; shorter where the
// surfaces it covers disagree), `light` the sun's direction in block space and `mixture` the
// impostor's diffuse mixture at this view: the surfaces' |n·l| where they agree (|n| = 1), the
// mixture where they agree no more than normals turned towards the viewer from every direction do
// (|n| ≤ 2/3), in between by c = 3|n| − 2. Rust twin:
// treelod_format::OctahedralNormalRecord::sun_factor.
fn octahedral_sun(n: vec3<f32>, light: vec3<f32>, mixture: f32) -> f32 {
    let size = length(n);
    let coherence = clamp(3.0 * size - 2.0, 0.0, 1.0);
    let facing = abs(dot(n, light)) / max(size, 1e-6);
    return clamp(coherence * facing + (1.0 - coherence) * mixture, 0.0, 1.0);
}

@fragment
fn fs_octahedral(in: OctahedralVaryings) -> TriangleOut {
    let sampled = octahedral_texel(in, true);
    let texel = sampled.colour;
    var mask = select(0u, 0xFFFFFFFFu, texel.a >= 0.5);
    mask &= fade_mask(in.fade.x, in.fade.y, in.clip);
    if mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    // Per texel where the views have normals (spec §6.13.3): the sun by the texel's normal, the
    // ambient light by its occlusion; else the whole view by the record's mixture and occlusion.
    var light = in.light;
    if in.normals.z > 0.0 {
        light = vec2<f32>(octahedral_sun(2.0 * sampled.normal.rgb - 1.0, in.sun_block, in.light.x), sampled.normal.a);
    }
    return TriangleOut(vec4<f32>(shade_diffuse(texel.rgb, light.x, in.normal, in.world, light.y) * in.tint, 1.0), mask);
}

// The shadow pass: the same coverage as the colour pass.
@fragment
fn fs_shadow_octahedral(in: OctahedralVaryings) {
    if octahedral_texel(in, false).colour.a < 0.5 {
        discard;
    }
}
