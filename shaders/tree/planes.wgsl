// Impostor planes (Garcia et al. 2005, spec §6.10): fixed quads textured from the model's atlas,
// or indirectly from its leaf-slot image and the leaves' own textures. The baseline billboards
// (billboards.wgsl) share the quads' corner and fragment stages.

// Rust twin: treelod_format::PlaneRecord (64 bytes, spec §6.10).
struct PlaneRecord {
    center: array<f32, 3>,
    axis_u: array<f32, 3>,
    axis_v: array<f32, 3>,
    image: u32,
    uv_min: u32,
    uv_max: u32,
    lo: f32,
    hi: f32,
    leaf_first: u32,
    leaf_count: u32,
}

// Rust twin: treelod_format::PlaneLeafRecord (40 bytes, spec §6.10.1).
struct PlaneLeafRecord {
    uv0: array<f32, 2>,
    du: array<f32, 2>,
    dv: array<f32, 2>,
    uv_min: u32,
    uv_max: u32,
    material: u32,
    color: u32,
}

// The plane rule of spec §10: inside [lo, hi) at tau.
fn plane_drawn(p: PlaneRecord, tau: f32) -> bool {
    return p.lo <= tau && tau < p.hi;
}

// Impostors: the container's planes, and the atlas they sample (clamped, with its stored mips).
// As uploaded, a plane's `leaf_first` holds the index of its parent plane (0xFFFFFFFF for none).
@group(3) @binding(0) var<storage, read> planes: array<PlaneRecord>;
@group(3) @binding(1) var atlas: texture_2d<f32>;
@group(3) @binding(2) var atlas_sampler: sampler;
// Indirect texturing (spec §6.10.1): the leaf-slot image and the planes' leaves. As uploaded, an
// indirectly textured plane's `image` holds where its leaves start in `plane_leaves`
// (0xFFFFFFFF for a plane with an RGBA atlas).
@group(3) @binding(3) var leaf_slots: texture_2d<u32>;
@group(3) @binding(4) var<storage, read> plane_leaves: array<PlaneLeafRecord>;

// One corner of an impostor plane (spec §6.10): `center ± axis_u ± axis_v`, never turned to the
// camera, the corner `center − axis_u − axis_v` at `uv_min`. `first_vertex` is 6 × the range's
// first plane; planes outside the level `tau_p` selects are dropped. With `frame.morph`, over the
// last octave of its interval a plane's corners slide along its parent's normal onto the parent's
// plane (Garcia 2005 §2.4; Rust twins `morph_share` and `morph_corner` in treelod-runtime), and
// over its last quarter it cross-fades with its parent (`crossfade`).
@vertex
fn vs_plane(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draw_at(draw_index);
    let plane = planes[vertex_index / 6u];
    let has_parent = plane.leaf_first != 0xFFFFFFFFu;
    // Rust twin: treelod_runtime::crossfade.
    var keep = vec2<f32>(0.0, 2.0);
    let tau = draw.tau_p;
    if frame.morph == 1u {
        let lo_ext = plane.lo * (1.0 - crossfade);
        if !(lo_ext <= tau && tau < plane.hi) {
            return offscreen();
        }
        if tau < plane.lo {
            keep.y = (tau - lo_ext) / (plane.lo - lo_ext);
        }
        let start = plane.hi * (1.0 - crossfade);
        if has_parent && tau >= start && plane.hi > start {
            keep.x = (tau - start) / (plane.hi - start);
        }
    } else if !plane_drawn(plane, tau) {
        return offscreen();
    }
    let corner = CORNERS[vertex_index % 6u];
    let u = vec3<f32>(plane.axis_u[0], plane.axis_u[1], plane.axis_u[2]);
    let v = vec3<f32>(plane.axis_v[0], plane.axis_v[1], plane.axis_v[2]);
    var p = vec3<f32>(plane.center[0], plane.center[1], plane.center[2]) + corner.x * u + corner.y * v;
    let start = max(plane.lo, 0.5 * plane.hi);
    if frame.morph == 1u && has_parent && plane.hi > start {
        let parent = planes[plane.leaf_first];
        let share = clamp((tau - start) / (plane.hi - start), 0.0, 1.0);
        let pu = vec3<f32>(parent.axis_u[0], parent.axis_u[1], parent.axis_u[2]);
        let pv = vec3<f32>(parent.axis_v[0], parent.axis_v[1], parent.axis_v[2]);
        let pn = normalize(cross(pu, pv));
        let pc = vec3<f32>(parent.center[0], parent.center[1], parent.center[2]);
        p = p - share * dot(p - pc, pn) * pn;
    }
    let world = (draw.model * vec4<f32>(p, 1.0)).xyz;
    let normal = normalize((draw.model * vec4<f32>(cross(u, v), 0.0)).xyz);
    var out = quad_corner(draw, world, normal, plane.uv_min, plane.uv_max, corner, vec3<f32>(0.95, 0.75, 0.15));
    if frame.debug == 3u {
        out.tint = level_tint(plane.hi);
    }
    out.keep = keep;
    out.material = plane.image;
    // As uploaded, `leaf_count` holds the plane's ambient-occlusion byte and its diffuse response.
    out.ao = decode_ao(plane.leaf_count);
    out.color.x = plane_diffuse(normal, normalize(frame.eye.xyz - world), plane.leaf_count);
    return out;
}

// The sun's diffuse factor of a plane of unit `normal` seen along unit `view` (world space): its
// leaves' mean |n·l| weighted by the area each shows, |n·v|, for the mixture of leaves in the
// plane (share f), turned every way (s) and across it (r = 1 − f − s) of spec §6.10.2. As
// uploaded, bits 8–19 of `packed` hold f and bits 20–31 s (12-bit unorm). Rust twin:
// treelod_format::PlaneDiffuseRecord::diffuse.
fn plane_diffuse(normal: vec3<f32>, view: vec3<f32>, packed: u32) -> f32 {
    let pi = 3.1415927;
    let f = f32((packed >> 8u) & 4095u) / 4095.0;
    let s = min(f32(packed >> 20u) / 4095.0, 1.0 - f);
    let r = max(1.0 - f - s, 0.0);
    let light = frame.sun.xyz;
    let nv = dot(normal, view);
    let nl = dot(normal, light);
    let vp = view - nv * normal;
    let lp = light - nl * normal;
    let a = length(vp);
    let b = length(lp);
    var ring = 0.0;
    if a * b > 1e-6 {
        ring = a * b * lobe(abs(dot(vp, lp)) / (a * b)) / pi;
    }
    let num = f * abs(nv) * abs(nl) + s * 2.0 / (3.0 * pi) * lobe(abs(dot(view, light))) + r * ring;
    let den = f * abs(nv) + 0.5 * s + r * 2.0 / pi * a;
    if den > 1e-6 {
        return clamp(num / den, 0.0, 1.0);
    }
    return abs(nl);
}

// The varyings of a textured quad's corner (impostor plane or billboard): texture coordinates
// from the atlas rectangle `uv_min ..= uv_max` at `corner ∈ [−1, 1]²`, and `kinds` as its colour
// in the kinds view.
fn quad_corner(
    draw: Draw,
    world: vec3<f32>,
    normal: vec3<f32>,
    uv_min: u32,
    uv_max: u32,
    corner: vec2<f32>,
    kinds: vec3<f32>,
) -> Varyings {
    var out: Varyings;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.normal = normal;
    out.uv = mix(unpack2x16unorm(uv_min), unpack2x16unorm(uv_max), 0.5 * (corner + 1.0));
    // `x`: the sun's diffuse factor the fragment stage lights the quad with (`vs_plane` sets an
    // impostor plane's leaves').
    out.color = vec4<f32>(abs(dot(normal, frame.sun.xyz)), 1.0, 1.0, 1.0);
    out.material = 0xFFFFFFFFu;
    out.disc = corner;
    out.keep = vec2<f32>(0.0, 2.0);
    out.ao = 0.0;
    out.fade = vec2<u32>(draw.fade, draw.instance);
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u, 3u: { out.tint = kinds; }
        case 4u: { out.tint = unpack4x8unorm(draw.tint).rgb; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// What a quad shows at a fragment: its albedo, and the share of the pixel it covers (0 or 1 where
// its texture is not minified).
struct QuadTexel {
    albedo: vec4<f32>,
    coverage: f32,
}

// An impostor plane's or billboard's texel. From an RGBA atlas: the baked leaves' colour
// (linear after the sRGB fetch) and, in alpha, the fraction of the texel they cover, tested at
// one half; the atlas's mips scale alpha so that the test keeps the covered fraction at every
// level (Castaño's alpha mipmaps), so the test is right at any distance, with or without MSAA.
//
// Indirectly textured (spec §6.10.1): the slot texel's two leaves, each sampled from its own
// texture with the footprint that the plane's screen derivatives give it. Magnified, the first
// whose alpha passes its material's test shows, with crisp edges. Minified, each leaf covers the
// share of the pixel its filtered alpha says (`filtered_coverage`, as alpha-tested triangles
// with MSAA), the two together `1 − (1 − c_a)(1 − c_b)` with their colours so weighted: a plain
// test of minified alpha would thin a distant crown, and one leaf alone would miss what the
// other covers of the texel. Call it in uniform control flow (derivatives and the atlas's
// implicit ones).
fn quad_texel(in: Varyings) -> QuadTexel {
    let st_dx = dpdx(in.disc);
    let st_dy = dpdy(in.disc);
    let direct = textureSample(atlas, atlas_sampler, in.uv);
    if in.material == 0xFFFFFFFFu {
        return QuadTexel(direct, select(0.0, 1.0, direct.a >= 0.5));
    }
    let size = vec2<i32>(textureDimensions(leaf_slots));
    let at = clamp(vec2<i32>(floor(in.uv * vec2<f32>(size))), vec2<i32>(0), size - 1);
    let slots = textureLoad(leaf_slots, at, 0).xy;
    var colour = vec3<f32>(0.0);
    var weight = 0.0;
    var uncovered = 1.0;
    for (var i = 0u; i < 2u; i++) {
        let slot = slots[i];
        if slot == 0u {
            continue;
        }
        let leaf = plane_leaves[in.material + slot - 1u];
        let material = materials[leaf.material];
        let du = vec2<f32>(leaf.du[0], leaf.du[1]);
        let dv = vec2<f32>(leaf.dv[0], leaf.dv[1]);
        let uv = vec2<f32>(leaf.uv0[0], leaf.uv0[1]) + in.disc.x * du + in.disc.y * dv;
        // Clipped to the leaf's texture rectangle, if it has one.
        let inside = leaf.uv_max == 0u
            || (all(uv >= unpack2x16unorm(leaf.uv_min)) && all(uv <= unpack2x16unorm(leaf.uv_max)));
        var gx = st_dx.x * du + st_dx.y * dv;
        var gy = st_dy.x * du + st_dy.y * dv;
        // A footprint at most half the leaf's texture rectangle: farther away, a pixel holds
        // more than the leaf, and a coarser mip would mix in the texture's other leaves (or the
        // empty space around them in an atlas of leaves); the slot texel under the pixel centre
        // already samples which leaf covers it.
        if leaf.uv_max != 0u {
            let extent = unpack2x16unorm(leaf.uv_max) - unpack2x16unorm(leaf.uv_min);
            let limit = 0.5 * max(extent.x, extent.y);
            let reach = max(length(gx), length(gy));
            if reach > limit && limit > 0.0 {
                gx *= limit / reach;
                gy *= limit / reach;
            }
        }
        let texel = textureSampleGrad(textures, linear_sampler, uv, max(material.layer, 0), gx, gy);
        let albedo = material.base_color * decode_color(leaf.color) * select(vec4<f32>(1.0), texel, material.layer >= 0);
        let footprint = max(length(gx), length(gy)) * f32(textureDimensions(textures).x);
        let cutoff = material_cutoff(material);
        var covered = select(filtered_coverage(albedo.a, cutoff, footprint), 1.0, cutoff < 0.0);
        if !inside {
            covered = 0.0;
        }
        if covered >= 1.0 {
            // Opaque here: what lies behind it in the texel does not show.
            return QuadTexel(vec4<f32>(albedo.rgb, 1.0), 1.0);
        }
        colour += covered * uncovered * albedo.rgb;
        weight += covered * uncovered;
        uncovered *= 1.0 - covered;
    }
    return QuadTexel(vec4<f32>(colour / max(weight, 1e-6), 1.0), 1.0 - uncovered);
}

@fragment
fn fs_plane(in: Varyings) -> TriangleOut {
    let texel = quad_texel(in);
    let h = dither(in.clip);
    // A partial coverage (a minified indirect leaf) covers that share of the samples with MSAA,
    // or of the pixels without (a hash of pixel and depth, so layers add up).
    var mask = coverage_mask(texel.coverage, in.clip);
    if sample_count == 1u {
        mask = select(0u, 0xFFFFFFFFu, texel.coverage >= 1.0 || texel.coverage > layered_dither(in.clip));
    }
    mask &= fade_mask(in.fade.x, in.fade.y, in.clip);
    if mask == 0u || h < in.keep.x || h >= in.keep.y {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    return TriangleOut(vec4<f32>(shade_diffuse(texel.albedo.rgb, in.color.x, in.normal, in.world, in.ao) * in.tint, 1.0), mask);
}

// The shadow pass (see fs_shadow_triangle): the same coverage and cross-fade as the colour pass.
@fragment
fn fs_shadow_plane(in: Varyings) {
    let texel = quad_texel(in);
    let h = dither(in.clip);
    let kept = texel.coverage >= 1.0 || texel.coverage > layered_dither(in.clip);
    if !kept || h < in.keep.x || h >= in.keep.y {
        discard;
    }
}
