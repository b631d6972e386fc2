// Drawing a tree container: vertex-pulled triangles, screen-facing disc splats, fixed impostor
// planes (Garcia et al. 2005) textured from the model's atlas, and ray-cast leaf ellipsoids and
// branch lines (Clasen and Prohaska 2011).
//
// Prepended with shared/records.wgsl. One indirect draw per selected range: `first_instance` is
// the index of the range's `DrawInfo`, `first_vertex` is 3 × its first triangle (or 6 × its first
// point) in the pool, so the vertex index names the element and its corner. The pool holds the
// streamed prefixes of every model in 48-byte units and is bound twice: as triangles (two per
// unit) and as points (one per unit).

struct Frame {
    view_proj: mat4x4<f32>,
    // Camera position (xyz), viewport height in pixels (w).
    eye: vec4<f32>,
    // Camera right (xyz) and the projection's y scale 1/tan(fovy/2) (w), for splats facing the
    // screen and their size in pixels.
    right: vec4<f32>,
    // Camera up (xyz) and the splat radius scale (w).
    up: vec4<f32>,
    // Direction towards the sun (xyz), ambient light (w).
    sun: vec4<f32>,
    // Colour of the sunlight, linear RGB (xyz).
    sun_colour: vec4<f32>,
    // 0 shaded, 1 colour by cell, 2 colour by kind.
    debug: u32,
    // 1: impostor planes morph towards their parents and cross-fade with them
    // (Settings::impostor_morph).
    morph: u32,
    // 1: the ambient share is scaled by the precomputed ambient occlusion
    // (Settings::ambient_occlusion).
    ambient_occlusion: u32,
    // β, octaves of tau over which ellipsoids and lines blend from one level to the next
    // (Settings::level_blend, clamped to [0, 2]; 0: switch at once). See `level_keep`.
    level_blend: f32,
    // 1: without MSAA, minified alpha-tested fragments cover their filtered alpha's share of the
    // pixels (Settings::stochastic_alpha). See `alpha_mask`.
    stochastic_alpha: u32,
}

// A vertex as uploaded: the record, then its ambient occlusion (spec §6.14; 0 without).
// Rust twin: VertexGpu in crates/treelod-render/src/renderer.rs.
struct VertexGpu {
    record: VertexRecord,
    ao: f32,
}


@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> draws: array<DrawInfo>;
@group(0) @binding(2) var<storage, read> triangles: array<TriangleRecord>;
@group(0) @binding(3) var<storage, read> points: array<PointRecord>;
@group(1) @binding(0) var<storage, read> vertices: array<VertexGpu>;
@group(1) @binding(1) var<storage, read> materials: array<MaterialGpu>;
@group(1) @binding(2) var textures: texture_2d_array<f32>;
@group(1) @binding(3) var linear_sampler: sampler;
// Pruning: the pruned leaves' triangles followed by the bark triangles, and the leaves (their
// centres are the pivots of the survivors' scaling).
@group(1) @binding(4) var<storage, read> extra_triangles: array<TriangleRecord>;
@group(1) @binding(5) var<storage, read> prune_leaves: array<PruneLeafRecord>;
// Impostors: the container's planes, and the atlas they sample (clamped, with its stored mips).
// As uploaded, a plane's `leaf_first` holds the index of its parent plane (0xFFFFFFFF for none).
@group(1) @binding(6) var<storage, read> planes: array<PlaneRecord>;
@group(1) @binding(7) var atlas: texture_2d<f32>;
@group(1) @binding(8) var atlas_sampler: sampler;
// Indirect texturing (spec §6.10.1): the leaf-slot image and the planes' leaves. As uploaded, an
// indirectly textured plane's `image` holds where its leaves start in `plane_leaves`
// (0xFFFFFFFF for a plane with an RGBA atlas).
@group(1) @binding(9) var leaf_slots: texture_2d<u32>;
@group(1) @binding(10) var<storage, read> plane_leaves: array<PlaneLeafRecord>;
// Clasen's ellipsoids (spec §6.8), and the white-noise cube map they sample (crates/treelod-render/src/
// noise.rs: alpha the grey noise, RGB a random unit vector; nearest texel of the nearest level).
@group(1) @binding(11) var<storage, read> ellipsoids: array<EllipsoidRecord>;
@group(1) @binding(12) var noise: texture_cube<f32>;
@group(1) @binding(13) var noise_sampler: sampler;
// Clasen's branch lines (spec §6.9). As uploaded, a line's `flags` holds its LINE_AO byte.
@group(1) @binding(14) var<storage, read> lines: array<LineRecord>;

// The material as uploaded: the record's fields that shading needs, 32 bytes.
struct MaterialGpu {
    base_color: vec4<f32>,
    // Texture array layer, or -1 for none.
    layer: i32,
    alpha_mode: u32,
    alpha_cutoff: f32,
    material_class: u32,
}

struct Varyings {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) color: vec4<f32>,
    // Triangles: material index; points and quads: 0xFFFFFFFF; indirectly textured planes:
    // where their leaves start in `plane_leaves`.
    @location(3) @interpolate(flat) material: u32,
    @location(4) @interpolate(flat) tint: vec3<f32>,
    // Points: position on the unit disc; quads: the plane coordinates (s, t) ∈ [−1, 1]².
    @location(5) disc: vec2<f32>,
    // Impostor planes and billboards: drawn where the pixel's dither value h satisfies
    // keep.x <= h < keep.y (the cross-fade between levels of planes).
    @location(6) @interpolate(flat) keep: vec2<f32>,
    // World position the shadow maps are looked up at (a splat's centre: splats are shadowed
    // whole, as the points they stand for).
    @location(7) world: vec3<f32>,
    // Precomputed ambient occlusion (spec §6.14): interpolated over triangles, one per splat or
    // plane.
    @location(8) ao: f32,
    // Points: a hash of the point's position and the instance, the splat's coverage test
    // (`splat_mask`); 0 for the rest.
    @location(9) @interpolate(flat) id: u32,
}

// A colour per cell index, for `debug = 1`.
fn cell_tint(cell: u32) -> vec3<f32> {
    let h = cell * 2654435761u;
    return vec3<f32>(f32(h & 255u), f32((h >> 8u) & 255u), f32((h >> 16u) & 255u)) / 255.0 * 0.8 + 0.2;
}

// Colours of `debug = 3`, one per octave of an element's interval end, cycling: neighbouring
// levels always differ.
const LEVEL_PALETTE = array<vec3<f32>, 6>(
    vec3<f32>(0.9, 0.25, 0.2), vec3<f32>(0.95, 0.75, 0.15), vec3<f32>(0.3, 0.8, 0.3),
    vec3<f32>(0.2, 0.75, 0.85), vec3<f32>(0.3, 0.35, 0.95), vec3<f32>(0.8, 0.35, 0.85),
);

// The level view's colour of an element whose interval of tau ends at `hi` (model units): one per
// octave of `hi`, so a tree's levels read as bands that move as the camera does; dark grey for an
// unbounded interval (the coarsest level, drawn however far). Triangles, the finest level, are
// light grey.
fn level_tint(hi: f32) -> vec3<f32> {
    if !(hi < 1e30) {
        return vec3<f32>(0.3);
    }
    let octave = i32(floor(log2(max(hi, 1e-30))));
    return LEVEL_PALETTE[u32(octave + 600) % 6u];
}

fn offscreen() -> Varyings {
    var out: Varyings;
    out.clip = vec4<f32>(0.0, 0.0, -2.0, 1.0);
    return out;
}

// One corner of triangle `tri`: vertex `v`, placed at `p` (model space).
fn triangle_corner(draw: DrawInfo, tri: TriangleRecord, vertex: VertexGpu, p: vec3<f32>) -> Varyings {
    let v = vertex.record;
    let world = draw.model * vec4<f32>(p, 1.0);
    var out: Varyings;
    out.ao = vertex.ao;
    out.clip = frame.view_proj * world;
    out.world = world.xyz;
    out.normal = normalize((draw.model * vec4<f32>(decode_normal(v.normal), 0.0)).xyz);
    out.uv = vec2<f32>(v.uv[0], v.uv[1]);
    out.color = decode_color(v.color);
    out.material = tri.material;
    out.disc = vec2<f32>(0.0);
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u: { out.tint = vec3<f32>(0.9, 0.3, 0.2); }
        case 3u: { out.tint = vec3<f32>(0.9); }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

@vertex
fn vs_triangle(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draws[draw_index];
    let tri = triangles[vertex_index / 3u];
    let v = vertices[tri.indices[vertex_index % 3u]];
    return triangle_corner(draw, tri, v, vec3<f32>(v.record.position[0], v.record.position[1], v.record.position[2]));
}

// Pruned leaves (scaled by `leaf_scale` about their leaf's centre, spec §6.11) and bark.
@vertex
fn vs_pruned(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draws[draw_index];
    let tri = extra_triangles[vertex_index / 3u];
    let v = vertices[tri.indices[vertex_index % 3u]];
    var p = vec3<f32>(v.record.position[0], v.record.position[1], v.record.position[2]);
    if draw.leaf_scale != 1.0 {
        let leaf = prune_leaves[tri.leaf];
        let centre = vec3<f32>(leaf.center[0], leaf.center[1], leaf.center[2]);
        p = centre + (p - centre) * draw.leaf_scale;
    }
    var out = triangle_corner(draw, tri, v, p);
    if frame.debug == 2u && draw.cell != 0xFFFFFFFFu {
        // Pruned leaves green in the kinds view.
        out.tint = vec3<f32>(0.2, 0.75, 0.3);
    }
    return out;
}

const CORNERS = array<vec2<f32>, 6>(
    vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
    vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
);

@vertex
fn vs_point(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draws[draw_index];
    let point = points[vertex_index / 6u];
    // The prefix holds points whose interval lies below tau_p: they are not part of the cut.
    if !point_drawn(point, draw.tau_p, draw.tau_t) {
        return offscreen();
    }
    let corner = CORNERS[vertex_index % 6u];
    let centre = draw.model * vec4<f32>(point.position[0], point.position[1], point.position[2], 1.0);
    // A drawn point is at most tau_p (about a pixel) across. A disc under a pixel would fall
    // between pixel centres and thin the canopy, and drawn a whole pixel wide it would cover more
    // than it stands for and fatten a far tree: it is drawn as a one-pixel square that carries
    // the disc's coverage, pi r^2 of the pixel (`splat_mask`).
    let depth = max((frame.view_proj * centre).w, 1e-6);
    let pixel = 2.0 * depth / (frame.right.w * frame.eye.w);
    let disc_r = point.radius * draw.scale * frame.up.w;
    let r = max(disc_r, 0.5 * pixel);
    let world = centre.xyz + (corner.x * frame.right.xyz + corner.y * frame.up.xyz) * r;
    var out: Varyings;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = centre.xyz;
    out.normal = normalize((draw.model * vec4<f32>(decode_normal(point.normal), 0.0)).xyz);
    out.uv = vec2<f32>(0.0);
    out.color = decode_color(point.color);
    // As uploaded, `flags` holds the point's ambient-occlusion byte.
    out.ao = decode_ao(point.flags);
    out.material = 0xFFFFFFFFu;
    // A splat at the one-pixel minimum is a square: a disc inscribed in one pixel misses its centre
    // a fifth of the time.
    out.disc = select(corner, corner * 0.70710677, disc_r < 0.5 * pixel);
    // The share of that pixel its disc covers (1 for a disc drawn at its size): the colour pass
    // covers it (`splat_mask`) and the shadow pass keeps the splat with this probability, so
    // sub-pixel points cover the image, and sub-texel points shade the ground, by their area, not
    // by whole pixels or texels.
    let coverage = select(1.0, 3.14159265 * disc_r * disc_r / (pixel * pixel), disc_r < 0.5 * pixel);
    out.keep = vec2<f32>(0.0, min(coverage, 1.0));
    // Of the point's position and the instance, not of where its prefix was streamed to in the
    // pool: the same every frame and on the CPU and GPU selection paths.
    let bits = bitcast<vec3<u32>>(vec3<f32>(point.position[0], point.position[1], point.position[2]));
    out.id = mix_bits(bits.x ^ mix_bits(bits.y ^ mix_bits(bits.z ^ mix_bits(draw.instance ^ 0x68e31da4u))));
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u: { out.tint = vec3<f32>(0.2, 0.5, 0.95); }
        case 3u: { out.tint = level_tint(point.hi); }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// One corner of an impostor plane (spec §6.10): `center ± axis_u ± axis_v`, never turned to the
// camera, the corner `center − axis_u − axis_v` at `uv_min`. `first_vertex` is 6 × the range's
// first plane; planes outside the level `tau_p` selects are dropped. With `frame.morph`, over the
// last octave of its interval a plane's corners slide along its parent's normal onto the parent's
// plane (Garcia 2005 §2.4; Rust twins `morph_share` and `morph_corner` in treelod-runtime), and
// over its last quarter it cross-fades with its parent (`crossfade`).
@vertex
fn vs_plane(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draws[draw_index];
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
    // As uploaded, `leaf_count` holds the plane's ambient-occlusion byte.
    out.ao = decode_ao(plane.leaf_count);
    return out;
}

// The varyings of a textured quad's corner (impostor plane or billboard): texture coordinates
// from the atlas rectangle `uv_min ..= uv_max` at `corner ∈ [−1, 1]²`, and `kinds` as its colour
// in the kinds view.
fn quad_corner(
    draw: DrawInfo,
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
    out.color = vec4<f32>(1.0);
    out.material = 0xFFFFFFFFu;
    out.disc = corner;
    out.keep = vec2<f32>(0.0, 2.0);
    out.ao = 0.0;
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u, 3u: { out.tint = kinds; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// One corner of a baseline billboard quad (spec §6.13), bound in place of the planes:
// `BillboardRecord` has `PlaneRecord`'s layout up to `uv_max`, and its `tree` and `kind` sit where
// a plane has `lo` and `hi` (read back with `bitcast`). A crossed quad is fixed like a plane; a
// facing one (kind 0) keeps its centre, `axis_v` and the length of `axis_u`, and turns `axis_u`
// about `axis_v` so that `axis_u × axis_v` points to the eye: the side its image was baked from.
@vertex
fn vs_billboard(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draws[draw_index];
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

// Two-sided Lambert with ambient: leaves are lit from both faces; the sun's share is what the
// shadow maps let through at `world` (shared/shadow.wgsl), the ambient share what the
// precomputed ambient occlusion `ao` lets through.
fn shade(albedo: vec3<f32>, normal: vec3<f32>, world: vec3<f32>, ao: f32) -> vec3<f32> {
    let diffuse = abs(dot(normalize(normal), frame.sun.xyz));
    var sun = 0.0;
    if diffuse > 0.0 {
        sun = diffuse * sunlit(world, normal, frame.sun.xyz);
    }
    let ambient = frame.sun.w * select(1.0, 1.0 - ao, frame.ambient_occlusion == 1u);
    return albedo * (ambient + (1.0 - frame.sun.w) * sun * frame.sun_colour.xyz);
}

// MSAA samples of the target (set by the pipeline). With more than one, alpha-tested materials
// write a sample mask instead of testing: alpha to coverage.
override sample_count: u32 = 1u;

// Share of τ below a switch of level over which impostor planes cross-fade (set from
// treelod_runtime::CROSSFADE).
override crossfade: f32 = 0.25;

struct TriangleOut {
    @location(0) color: vec4<f32>,
    @builtin(sample_mask) mask: u32,
}

// The samples of a pixel that a fragment of `coverage` (0..1) covers: `coverage · sample_count`
// of them, rounded, starting at a sample chosen by a hash of the pixel and the fragment's depth,
// so neighbouring pixels do not repeat a pattern and leaves behind one another cover different
// samples and add up, as they do with a stochastic test (a hash of the pixel alone would let
// every layer of a quarter-covered canopy cover the same quarter).
fn coverage_mask(coverage: f32, fragment: vec4<f32>) -> u32 {
    let n = u32(floor(clamp(coverage, 0.0, 1.0) * f32(sample_count) + 0.5));
    return sample_run(n, pixel_depth_hash(fragment) >> 16u);
}

// `n` consecutive samples of the pixel's `sample_count`, starting at sample `start` (modulo the
// count) and wrapping around: all of them from `n = sample_count` on.
fn sample_run(n: u32, start: u32) -> u32 {
    if n >= sample_count {
        return 0xFFFFFFFFu;
    }
    let shift = start % sample_count;
    let run = (1u << n) - 1u;
    let all = (1u << sample_count) - 1u;
    return ((run << shift) | (run >> (sample_count - shift))) & all;
}

// A hash of the fragment's pixel and depth: surfaces at different depths over one pixel get
// independent values.
fn pixel_depth_hash(fragment: vec4<f32>) -> u32 {
    let p = vec2<u32>(fragment.xy);
    return ((p.x * 1973u) ^ (p.y * 9277u) ^ (bitcast<u32>(fragment.z) * 0x5bd1e995u)) * 2654435761u;
}

// The share of the pixel an alpha-tested fragment stands for, `footprint` texels per pixel.
// Alpha-tested images have binary alpha filtered into their mips (textures.rs), so a minified
// texel's alpha is the fraction of its footprint that is opaque: covering that fraction keeps a
// distant canopy's density where a test against the cutoff thins it out. Magnified (a texel over
// a pixel or more) the test itself keeps edges crisp; in between the two blend over one mip level.
fn filtered_coverage(alpha: f32, cutoff: f32, footprint: f32) -> f32 {
    let minified = clamp(log2(max(footprint, 1e-6)), 0.0, 1.0);
    let tested = select(0.0, 1.0, alpha >= cutoff);
    return mix(tested, alpha, minified);
}

// The samples an alpha-tested fragment covers (0: discard it): with one sample the test of
// `alpha` against `cutoff` (a negative cutoff passes everything), or with
// `frame.stochastic_alpha` the shadow pass's test of its filtered coverage against a hash of the
// pixel and depth; with MSAA alpha to coverage. `footprint` is texels per pixel.
fn alpha_mask(alpha: f32, cutoff: f32, footprint: f32, clip: vec4<f32>) -> u32 {
    var mask = 0xFFFFFFFFu;
    if sample_count == 1u && frame.stochastic_alpha != 0u {
        if stochastic_alpha_drops(alpha, cutoff, footprint, clip) {
            mask = 0u;
        }
    } else if sample_count == 1u || cutoff < 0.0 {
        if alpha < cutoff {
            mask = 0u;
        }
    } else {
        // Alpha to coverage.
        mask = coverage_mask(filtered_coverage(alpha, cutoff, footprint), clip);
    }
    return mask;
}

// Whether an alpha-tested fragment (`footprint` texels per pixel) is dropped by the stochastic
// test: kept where its filtered coverage exceeds the dither of its pixel and depth, so on average
// minified leaves cover their share of the pixels (or shadow-map texels). A negative `cutoff`
// (not alpha-tested) keeps everything.
fn stochastic_alpha_drops(alpha: f32, cutoff: f32, footprint: f32, fragment: vec4<f32>) -> bool {
    return cutoff >= 0.0 && filtered_coverage(alpha, cutoff, footprint) <= layered_dither(fragment);
}

// Interleaved gradient noise (Jimenez 2014) of the pixel, in [0, 1): the dither of the
// cross-fade.
fn dither(fragment: vec4<f32>) -> f32 {
    return fract(52.9829189 * fract(dot(floor(fragment.xy), vec2<f32>(0.06711056, 0.00583715))));
}

// The level blend's dither value of a fragment of draw `draw_index`, in [0, 1): a hash of the
// pixel and the draw's cell and instance, not of the depth, so the levels of one cell over a pixel
// get the same value and their dither ranges (`level_keep`) split the pixels between them, while
// other cells and trees get other patterns. Seeded apart from `pixel_depth_hash`, so it does not
// correlate with the coverage of thin lines and minified leaves.
fn level_dither(fragment: vec4<f32>, draw_index: u32) -> f32 {
    let draw = draws[draw_index];
    let p = vec2<u32>(fragment.xy);
    let h = mix_bits(p.x ^ mix_bits(p.y ^ mix_bits(draw.cell ^ mix_bits(draw.instance ^ 0x9e3779b9u))));
    return f32(h >> 8u) / 16777216.0;
}

// A 32-bit integer hash (Wellons' lowbias32): every input bit flips each output bit about half the
// time.
fn mix_bits(x: u32) -> u32 {
    var h = x;
    h ^= h >> 16u;
    h *= 0x7feb352du;
    h ^= h >> 15u;
    h *= 0x846ca68bu;
    h ^= h >> 16u;
    return h;
}

// The samples a fragment of an element with the level blend's dither range `keep` covers (0:
// discard it): all where the range holds [0, 1). Else, with one sample, all or none as the range
// holds the fragment's `level_dither` h; with MSAA, sample s where it holds fract(h + s / n), so
// a pixel's samples take the range's share (to a sample) and complementary ranges split them.
fn level_mask(keep: vec2<f32>, fragment: vec4<f32>, draw_index: u32) -> u32 {
    if keep.x <= 0.0 && keep.y >= 1.0 {
        return 0xFFFFFFFFu;
    }
    let h = level_dither(fragment, draw_index);
    if sample_count == 1u {
        return select(0u, 0xFFFFFFFFu, keep.x <= h && h < keep.y);
    }
    var mask = 0u;
    for (var s = 0u; s < sample_count; s++) {
        let hs = fract(h + f32(s) / f32(sample_count));
        if keep.x <= hs && hs < keep.y {
            mask |= 1u << s;
        }
    }
    return mask;
}

// A triangle's albedo: its material's colour, times its vertex colour and its texture if it has
// one. Call it in uniform control flow (the texture is sampled with implicit derivatives).
fn triangle_albedo(material: MaterialGpu, in: Varyings) -> vec4<f32> {
    let texel = textureSample(textures, linear_sampler, in.uv, max(material.layer, 0));
    return material.base_color * in.color * select(vec4<f32>(1.0), texel, material.layer >= 0);
}

// The alpha cutoff of a material: masked and blended materials are alpha-tested (blend is drawn
// as a mask at 0.5); opaque ones get -1, which passes everything.
fn material_cutoff(material: MaterialGpu) -> f32 {
    return select(select(material.alpha_cutoff, 0.5, material.alpha_mode == 2u), -1.0, material.alpha_mode == 0u);
}

// Texels of the material textures per pixel at `uv` (derivatives: uniform control flow).
fn texel_footprint(uv: vec2<f32>) -> f32 {
    return max(length(dpdx(uv)), length(dpdy(uv))) * f32(textureDimensions(textures).x);
}

@fragment
fn fs_triangle(in: Varyings) -> TriangleOut {
    let material = materials[in.material];
    let albedo = triangle_albedo(material, in);
    let mask = alpha_mask(albedo.a, material_cutoff(material), texel_footprint(in.uv), in.clip);
    if mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    // The tint is the cell's estimated self-shadowing when shaded.
    return TriangleOut(vec4<f32>(shade(albedo.rgb, in.normal, in.world, in.ao) * in.tint, 1.0), mask);
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
    if mask == 0u || h < in.keep.x || h >= in.keep.y {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    return TriangleOut(vec4<f32>(shade(texel.albedo.rgb, in.normal, in.world, in.ao) * in.tint, 1.0), mask);
}

// The samples a splat of `coverage` (the share of its one-pixel square its disc covers) covers,
// `id` its hash (0: discard it). With one sample, the whole square in a share `coverage` of the
// splats, chosen by their hash: a splat is kept or dropped the same way every frame while its
// coverage stays, so a far canopy keeps its density (the expected coverage is the discs') without
// growing fat or shimmering; as the camera approaches, coverage grows and more splats appear, in
// a fixed order. With MSAA, `coverage · sample_count` samples rounded up or down by the hash (so
// the expected count is exact, down to splats of less than a sample), in a run starting at a
// sample the hash picks: splats over one pixel cover different samples and add up.
fn splat_mask(coverage: f32, id: u32) -> u32 {
    if coverage >= 1.0 {
        return 0xFFFFFFFFu;
    }
    let h = f32(id >> 8u) / 16777216.0;
    if sample_count == 1u {
        return select(0u, 0xFFFFFFFFu, h < coverage);
    }
    return sample_run(u32(floor(coverage * f32(sample_count) + h)), mix_bits(id));
}

@fragment
fn fs_point(in: Varyings) -> TriangleOut {
    let mask = splat_mask(in.keep.y, in.id);
    if dot(in.disc, in.disc) > 1.0 || mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    return TriangleOut(vec4<f32>(shade(in.color.rgb, in.normal, in.world, in.ao) * in.tint, 1.0), mask);
}

// A value in [0, 1) per pixel and depth, for the shadow pass's stochastic tests: surfaces at
// different depths over one texel get independent values, so their coverages add up as
// overlapping layers do (a value of the texel alone would let every layer cover the same share).
fn layered_dither(fragment: vec4<f32>) -> f32 {
    return f32(pixel_depth_hash(fragment) >> 8u) / 16777216.0;
}

// The shadow pass (depth only, one pass per cascade, `frame` holding the light's view): the same
// vertex stages, and fragment stages that keep what the colour pass keeps. Alpha-tested leaves:
// where their texture is minified (a texel under a shadow-map texel), a test at the cutoff would
// thin a distant canopy's shadow as it would its image, so they are kept where their filtered
// alpha (the covered fraction) exceeds the texel's dither value: on average the leaves cover in
// the map what they cover in the world.
@fragment
fn fs_shadow_triangle(in: Varyings) {
    let material = materials[in.material];
    let alpha = triangle_albedo(material, in).a;
    if stochastic_alpha_drops(alpha, material_cutoff(material), texel_footprint(in.uv), in.clip) {
        discard;
    }
}

@fragment
fn fs_shadow_plane(in: Varyings) {
    let texel = quad_texel(in);
    let h = dither(in.clip);
    let kept = texel.coverage >= 1.0 || texel.coverage > layered_dither(in.clip);
    if !kept || h < in.keep.x || h >= in.keep.y {
        discard;
    }
}

@fragment
fn fs_shadow_point(in: Varyings) {
    if dot(in.disc, in.disc) > 1.0 || layered_dither(in.clip) >= in.keep.y {
        discard;
    }
}

// ---------------------------------------------------------------------------------------------
// Clasen's ellipsoids (Clasen and Prohaska 2011 §5; spec §6.8), ray-cast as Sigg et al. (2006) do:
// a screen-facing quad bounds the ellipsoid's projection, and each fragment intersects its view
// ray with the ellipsoid in the ellipsoid's local frame, where it is the unit sphere. The hit
// writes its own depth, so ellipsoids meet triangles and planes where their surfaces do.

// Where a shadow-map texel is, the shadow pass moves an ellipsoid's written depth this many
// texels away from the sun (the pipeline's slope-scaled bias applies to the quad's depth, not to
// a depth the shader writes).
const ELLIPSOID_SHADOW_BIAS_TEXELS: f32 = 1.5;

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

fn ellipsoid_frame(draw: DrawInfo, e: EllipsoidRecord) -> EllipsoidFrame {
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

// Row j of the view-projection.
fn view_proj_row(j: u32) -> vec4<f32> {
    let m = frame.view_proj;
    return vec4<f32>(m[0][j], m[1][j], m[2][j], m[3][j]);
}

// The direction, not normalised, of the view ray through the world point p, away from the viewer:
// p − eye for a perspective view, the view axis for an orthographic one (a shadow cascade). The
// points of the ray keep p's x and y in clip space: they lie on the planes (r0 − x·r3)·X = 0 and
// (r1 − y·r3)·X = 0 (r_i the view-projection's rows), so it runs along their normals' cross product.
fn view_ray(p: vec3<f32>) -> vec3<f32> {
    let r0 = view_proj_row(0u);
    let r1 = view_proj_row(1u);
    let r2 = view_proj_row(2u);
    let r3 = view_proj_row(3u);
    let h = vec4<f32>(p, 1.0);
    let w = dot(r3, h);
    let ndc = vec3<f32>(dot(r0, h), dot(r1, h), dot(r2, h)) / w;
    let d = cross(r0.xyz - ndc.x * r3.xyz, r1.xyz - ndc.y * r3.xyz);
    // Away from the viewer: the depth z/w grows along it.
    let grows = dot(r2.xyz, d) - ndc.z * dot(r3.xyz, d);
    return select(-d, d, grows > 0.0);
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
    let draw = draws[draw_index];
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
    let f = ellipsoid_frame(draws[in.draw], e);
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
    let mask = level_mask(in.keep, in.clip, in.draw);
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

// ---------------------------------------------------------------------------------------------
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

fn line_frame(draw: DrawInfo, l: LineRecord) -> LineFrame {
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
    let draw = draws[draw_index];
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
    let f = line_frame(draws[in.draw], lines[in.line]);
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
