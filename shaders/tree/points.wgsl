// Sequential point tree splats (spec §6.5): screen-facing discs, those under a pixel drawn as
// one-pixel squares that carry their coverage.

@vertex
fn vs_point(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draw_at(draw_index);
    let point = points[vertex_index / 6u];
    // The prefix holds points whose interval lies below tau_p: they are not part of the cut.
    if !point_drawn(point, draw.tau_p, draw.tau_t) {
        return offscreen();
    }
    let corner = CORNERS[vertex_index % 6u];
    let centre = draw.model * vec4<f32>(point.position[0], point.position[1], point.position[2], 1.0);
    // A drawn point is at most tau_p (about a pixel) across. Drawn a whole pixel wide, a disc
    // under a pixel would cover more than it stands for and fatten a far tree; drawn at its size
    // it would keep its coverage only on average, appearing and disappearing as it crosses pixel
    // centres (measured: a slow orbit of the orchid at 8 radii, temporal noise .00324 -> .00398
    // against the reference's .00204; docs/cli.md). It is drawn as a one-pixel square that
    // carries the disc's coverage, pi r^2 of the pixel (`splat_mask`): half of such splats,
    // chosen by their hash, are kept or dropped by it the same way every frame while their
    // coverage stays, the other half drawn as their disc covers the pixel's centre.
    let depth = max((frame.view_proj * centre).w, 1e-6);
    let pixel = 2.0 * depth / (frame.right.w * frame.eye.w);
    // The record's disc holds the mean over directions of the area its surface projects; the
    // share `f` of it that faces along the normal (as uploaded, bits 8-15 of `flags`, spec
    // §6.5.1) projects `2|n.v|` times that along the view `v`, the rest the mean. The disc drawn
    // has that area: a patch of a closed crown seen face on covers what is behind it, seen edge
    // on its sliver.
    let normal = normalize((draw.model * vec4<f32>(decode_normal(point.normal), 0.0)).xyz);
    let flat = f32((point.flags >> 8u) & 0xFFu) / 255.0;
    let facing = 1.0 - flat + 2.0 * flat * abs(dot(normal, normalize(view_ray(centre.xyz))));
    let disc_r = point.radius * draw.scale * frame.up.w * sqrt(facing);
    let r = max(disc_r, 0.5 * pixel);
    let world = centre.xyz + (corner.x * frame.right.xyz + corner.y * frame.up.xyz) * r;
    var out: Varyings;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = centre.xyz;
    out.normal = normal;
    out.uv = vec2<f32>(0.0);
    out.color = decode_color(point.color);
    // As uploaded, bits 0-7 of `flags` hold the point's ambient-occlusion byte.
    out.ao = decode_ao(point.flags);
    out.material = 0xFFFFFFFFu;
    out.fade = vec2<u32>(draw.fade, draw.instance);
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
        case 4u: { out.tint = unpack4x8unorm(draw.tint).rgb; }
        default: { out.tint = vec3<f32>(draw.shading); }
    }
    return out;
}

// The share of sub-pixel splats drawn as their disc covers the pixel's centre (`splat_mask`)
// rather than kept or dropped whole by their hash (spec §10.1). Each way keeps the discs' expected
// coverage. The hashed square ignores where in its pixel the point lies, so a point just inside a
// crown's outline colours the background pixel it falls in as often as one at the pixel's centre;
// the disc covers that pixel only when its centre is near the point, as the mesh does, but
// appears and disappears as it moves across pixel centres. Measured with `eval` on the seven
// shared models (docs/cli.md, `treelod build`, sub-pixel splats): drawing half of them as discs
// lowers the point tree's RMSE at 32 bounding radii on six of them, by up to a seventh (the
// Quaternius tree .00133 -> .00115; the orchid's +1 %), and keeps about half of the shimmer that
// drawing them all as discs adds.
const SPLAT_DISC_SHARE: f32 = 0.5;

// The samples a splat of `coverage` (the share of its one-pixel square its disc covers) covers,
// `id` its hash (0: discard it), `offset2` the squared distance in pixels from the point to the
// centre of the pixel being shaded. With one sample, a share `SPLAT_DISC_SHARE` of the splats,
// chosen by a hash of `id`, cover the pixel when their disc holds its centre (`offset2 <
// coverage / pi`); the others cover the whole square in a share `coverage` of them, chosen by
// their hash: such a splat is kept or dropped the same way every frame while its coverage stays,
// so a far canopy keeps its density (the expected coverage is the discs') without growing fat or
// shimmering; as the camera approaches, coverage grows and more splats appear, in a fixed order.
// With MSAA, `coverage · sample_count` samples rounded up or down by the hash (so the expected
// count is exact, down to splats of less than a sample), in a run starting at a sample the hash
// picks: splats over one pixel cover different samples and add up.
fn splat_mask(coverage: f32, id: u32, offset2: f32) -> u32 {
    if coverage >= 1.0 {
        return 0xFFFFFFFFu;
    }
    let h = f32(id >> 8u) / 16777216.0;
    if sample_count == 1u {
        if f32(mix_bits(id ^ 0x9e3779b9u) >> 8u) / 16777216.0 < SPLAT_DISC_SHARE {
            return select(0u, 0xFFFFFFFFu, offset2 * 3.14159265 < coverage);
        }
        return select(0u, 0xFFFFFFFFu, h < coverage);
    }
    return sample_run(u32(floor(coverage * f32(sample_count) + h)), mix_bits(id));
}

@fragment
fn fs_point(in: Varyings) -> TriangleOut {
    // On the one-pixel square (half-side half a pixel), `disc` reaches 1/sqrt(2) at its corners:
    // the fragment lies `disc / sqrt(2)` pixels from the point.
    let mask = splat_mask(in.keep.y, in.id, 0.5 * dot(in.disc, in.disc)) & fade_mask(in.fade.x, in.fade.y, in.clip);
    if dot(in.disc, in.disc) > 1.0 || mask == 0u {
        discard;
    }
    if frame.debug != 0u {
        return TriangleOut(vec4<f32>(in.tint, 1.0), mask);
    }
    return TriangleOut(vec4<f32>(shade(in.color.rgb, in.normal, in.world, in.ao) * in.tint, 1.0), mask);
}

// The shadow pass (see fs_shadow_triangle): a splat is kept with the probability of its
// coverage.
@fragment
fn fs_shadow_point(in: Varyings) {
    if dot(in.disc, in.disc) > 1.0 || layered_dither(in.clip) >= in.keep.y {
        discard;
    }
}
