// The tree shaders' common part: the frame, the bindings every representation reads, the
// varyings of triangles, splats and quads, shading, and the coverage, dither and ray helpers. The
// tree shaders draw a tree container: vertex-pulled triangles (triangles.wgsl, pruned.wgsl),
// screen-facing disc splats (points.wgsl), fixed impostor planes (Garcia et al. 2005) textured
// from the model's atlas (planes.wgsl) and baseline billboards (billboards.wgsl), and ray-cast
// leaf ellipsoids (ellipsoids.wgsl) and branch lines (lines.wgsl) after Clasen and Prohaska 2011.
//
// Each pipeline's module is shared/records.wgsl, shared/draw.wgsl and shared/shadow.wgsl, then
// this file, then its representation's files (composed in crates/treelod-render/src/technique/mod.rs,
// `tree_wgsl!`; a representation's own bindings are in group 3).
// One indirect draw per selected range: `first_instance` is
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
// Rust twin: VertexGpu in crates/treelod-render/src/upload.rs.
struct VertexGpu {
    record: VertexRecord,
    ao: f32,
}


@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> draws: array<DrawInfo>;
@group(0) @binding(2) var<storage, read> triangles: array<TriangleRecord>;
@group(0) @binding(3) var<storage, read> points: array<PointRecord>;
@group(0) @binding(4) var<storage, read> instance_transforms: array<InstanceTransform>;
@group(1) @binding(0) var<storage, read> vertices: array<VertexGpu>;
@group(1) @binding(1) var<storage, read> materials: array<MaterialGpu>;
@group(1) @binding(2) var textures: texture_2d_array<f32>;
@group(1) @binding(3) var linear_sampler: sampler;

// A draw as the tree shaders read it: its `DrawInfo` joined to its instance's transform.
struct Draw {
    // Column-major world-from-model transform.
    model: mat4x4<f32>,
    tau_p: f32,
    tau_t: f32,
    cell: u32,
    // The transform's largest axis scale, for splat and line radii.
    scale: f32,
    shading: f32,
    leaf_scale: f32,
    instance: u32,
    tint: u32,
    fade: u32,
}

// Draw `index` (the indirect draw's instance index) with its instance's transform.
fn draw_at(index: u32) -> Draw {
    let d = draws[index];
    let t = instance_transforms[d.instance];
    return Draw(t.model, d.tau_p, d.tau_t, d.cell, t.scale, d.shading, d.leaf_scale, d.instance, d.tint, d.fade);
}

// The material as uploaded: the record's fields that shading needs, 32 bytes. Rust twin:
// MaterialGpu in crates/treelod-render/src/upload.rs.
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
    // The draw's `DrawInfo::fade` and instance, for the transition between techniques
    // (`fade_mask`).
    @location(10) @interpolate(flat) fade: vec2<u32>,
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

const CORNERS = array<vec2<f32>, 6>(
    vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
    vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
);

// Two-sided Lambert with ambient: leaves are lit from both faces; the sun's share is what the
// shadow maps let through at `world` (shared/shadow.wgsl), the ambient share what the
// precomputed ambient occlusion `ao` lets through.
fn shade(albedo: vec3<f32>, normal: vec3<f32>, world: vec3<f32>, ao: f32) -> vec3<f32> {
    return shade_diffuse(albedo, abs(dot(normalize(normal), frame.sun.xyz)), normal, world, ao);
}

// `sin x + (π/2 − x) cos x` for `x = acos c`: π times the mean of |(n·a)(n·b)| over unit normals
// n on the circle through two unit directions a, b at cosine `c` (spec §6.10.2).
fn lobe(c: f32) -> f32 {
    let k = clamp(c, 0.0, 1.0);
    let x = acos(k);
    return sin(x) + (1.5707964 - x) * k;
}

// `shade` with the sun's diffuse factor given: an impostor plane's is its leaves' mean
// (`plane_diffuse`, spec §6.10.2), not its own normal's. Rust twin:
// treelod_runtime::Light::shade_diffuse.
fn shade_diffuse(albedo: vec3<f32>, diffuse: f32, normal: vec3<f32>, world: vec3<f32>, ao: f32) -> vec3<f32> {
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
// independent values. The depth is hashed as the depth buffer's `z` and as `w`, the reciprocal
// of the view depth under a perspective projection: far from a perspective camera the surfaces
// of a tree fall on few values of `z` (1 km away 40 m of depth span some thirty steps of an f32
// near 1, 3 km away 10 m about one), and layers hashed by `z` alone would share their values and
// cover one pixel share between them instead of adding up; `w` keeps its relative precision,
// and `z` separates the layers of an orthographic view (a shadow cascade), where `w` is 1.
fn pixel_depth_hash(fragment: vec4<f32>) -> u32 {
    let p = vec2<u32>(fragment.xy);
    let depth = (bitcast<u32>(fragment.z) * 0x5bd1e995u) ^ (bitcast<u32>(fragment.w) * 0x27d4eb2du);
    return ((p.x * 1973u) ^ (p.y * 9277u) ^ depth) * 2654435761u;
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

// The transition dither of a fragment of instance `instance`, in [0, 1): a hash of the pixel and
// the instance alone, so every draw of a tree in a transition between techniques (whatever its
// cell) gets the same value over a pixel and their ranges split the tree's pixels between the two
// techniques; seeded apart from `level_dither` and the coverage tests, so the split does not
// correlate with which pixels a technique's own levels and coverage keep.
fn transition_dither(fragment: vec4<f32>, instance: u32) -> f32 {
    let p = vec2<u32>(fragment.xy);
    let h = mix_bits(p.x ^ mix_bits(p.y ^ mix_bits(instance ^ 0x2545f491u)));
    return f32(h >> 8u) / 16777216.0;
}

// The samples a fragment of a draw with `DrawInfo::fade` `fade` and instance `instance` covers
// on account of a transition between techniques (0: discard it): all outside one, else those whose
// transition dither its range holds (`range_mask`). The colour pass only: shadow cascades switch
// at once.
fn fade_mask(fade: u32, instance: u32, fragment: vec4<f32>) -> u32 {
    let keep = unpack2x16unorm(fade);
    if keep.x <= 0.0 && keep.y >= 1.0 {
        return 0xFFFFFFFFu;
    }
    return range_mask(keep, transition_dither(fragment, instance));
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
// discard it): all where the range holds [0, 1), else those the range holds of the fragment's
// `level_dither` (`range_mask`).
fn level_mask(keep: vec2<f32>, fragment: vec4<f32>, draw_index: u32) -> u32 {
    if keep.x <= 0.0 && keep.y >= 1.0 {
        return 0xFFFFFFFFu;
    }
    return range_mask(keep, level_dither(fragment, draw_index));
}

// The samples of a pixel whose dither value is `h` that the range `keep` holds: with one
// sample, all or none as it holds h; with MSAA, sample s where it holds fract(h + s / n), so a
// pixel's samples take the range's share (to a sample) and complementary ranges split them.
fn range_mask(keep: vec2<f32>, h: f32) -> u32 {
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

// The alpha cutoff of a material: masked and blended materials are alpha-tested (blend is drawn
// as a mask at 0.5); opaque ones get -1, which passes everything.
fn material_cutoff(material: MaterialGpu) -> f32 {
    return select(select(material.alpha_cutoff, 0.5, material.alpha_mode == 2u), -1.0, material.alpha_mode == 0u);
}

// A value in [0, 1) per pixel and depth, for the shadow pass's stochastic tests: surfaces at
// different depths over one texel get independent values, so their coverages add up as
// overlapping layers do (a value of the texel alone would let every layer cover the same share).
fn layered_dither(fragment: vec4<f32>) -> f32 {
    return f32(pixel_depth_hash(fragment) >> 8u) / 16777216.0;
}

// ---------------------------------------------------------------------------------------------
// What the ray-cast representations (ellipsoids.wgsl, lines.wgsl) share: the view ray through a
// point, and the shadow pass's push of the depths they write.

// Where a shadow-map texel is, the shadow pass moves an ellipsoid's written depth this many
// texels away from the sun (the pipeline's slope-scaled bias applies to the quad's depth, not to
// a depth the shader writes).
const ELLIPSOID_SHADOW_BIAS_TEXELS: f32 = 1.5;

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
