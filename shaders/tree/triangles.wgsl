// Triangles (spec §6.4): vertex-pulled from the pool, alpha-tested by their material's texture.
// The pruned leaves and bark (pruned.wgsl) reuse the corner and fragment stages.

// One corner of triangle `tri`: vertex `v`, placed at `p` (model space).
fn triangle_corner(draw: Draw, tri: TriangleRecord, vertex: VertexGpu, p: vec3<f32>) -> Varyings {
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
    out.fade = vec2<u32>(draw.fade, draw.instance);
    switch frame.debug {
        case 1u: { out.tint = cell_tint(draw.cell); }
        case 2u: { out.tint = vec3<f32>(0.9, 0.3, 0.2); }
        case 3u: { out.tint = vec3<f32>(0.9); }
        case 4u: { out.tint = unpack4x8unorm(draw.tint).rgb; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

@vertex
fn vs_triangle(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draw_at(draw_index);
    let tri = triangles[vertex_index / 3u];
    let v = vertices[tri.indices[vertex_index % 3u]];
    return triangle_corner(draw, tri, v, vec3<f32>(v.record.position[0], v.record.position[1], v.record.position[2]));
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

// A triangle's albedo: its material's colour, times its vertex colour and its texture if it has
// one. Call it in uniform control flow (the texture is sampled with implicit derivatives).
fn triangle_albedo(material: MaterialGpu, in: Varyings) -> vec4<f32> {
    let texel = textureSample(textures, linear_sampler, in.uv, max(material.layer, 0));
    return material.base_color * in.color * select(vec4<f32>(1.0), texel, material.layer >= 0);
}

// Texels of the material textures per pixel at `uv` (derivatives: uniform control flow).
fn texel_footprint(uv: vec2<f32>) -> f32 {
    return max(length(dpdx(uv)), length(dpdy(uv))) * f32(textureDimensions(textures).x);
}

@fragment
fn fs_triangle(in: Varyings) -> TriangleOut {
    let material = materials[in.material];
    let albedo = triangle_albedo(material, in);
    let mask = alpha_mask(albedo.a, material_cutoff(material), texel_footprint(in.uv), in.clip)
        & fade_mask(in.fade.x, in.fade.y, in.clip);
    if mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    // The tint is the cell's estimated self-shadowing when shaded.
    return TriangleOut(vec4<f32>(shade(albedo.rgb, in.normal, in.world, in.ao) * in.tint, 1.0), mask);
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
