// Pruned leaves and bark (Neubert et al. 2011, spec §6.11), from the model's extra triangle
// buffer; composed after triangles.wgsl, whose corner and fragment stages they share.

// Pruning: the pruned leaves' triangles followed by the bark triangles, and the leaves (their
// centres are the pivots of the survivors' scaling).
@group(1) @binding(4) var<storage, read> extra_triangles: array<TriangleRecord>;
@group(1) @binding(5) var<storage, read> prune_leaves: array<PruneLeafRecord>;

// Pruned leaves (scaled by `leaf_scale` about their leaf's centre, spec §6.11) and bark.
@vertex
fn vs_pruned(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) draw_index: u32) -> Varyings {
    let draw = draw_at(draw_index);
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
