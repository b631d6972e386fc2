// GPU-driven selection: the compute twin of treelod_runtime::select_frame (crates/treelod-runtime/src/
// frame.rs), run by crates/treelod-render/src/gpu_select.rs. Two entry points:
//
// 1. `cull_blocks`, one invocation per instance block (64 instances in Morton order): a block
//    whose bounding sphere lies outside a frustum plane is skipped; a visible one is appended to
//    `visible_out` and counted into the x of the indirect dispatch of pass 2.
// 2. `select_instances`, one workgroup per visible block, one invocation per instance: the
//    instance's culling, depth, thresholds and prefixes exactly as `select_frame` computes them
//    (same operations, same order, same far path and far-list range), and one `DrawInfo` +
//    `DrawIndirectArgs` pair per non-empty range, appended to its model's triangle or point
//    bucket by an atomic counter (the count `multi_draw_indirect_count` reads). An instance the
//    CPU marks as drawn with its octahedral impostor or its billboards (the quad kind in the top
//    bits of `InstanceDraw::technique`; the CPU culled it) is appended to its model's quad or
//    billboard bucket as one draw of those quads.
//
// Keys that the CPU holds as ±∞ are uploaded as ±f32::MAX (selection thresholds are finite and
// non-negative, so every comparison gives the same result).

const OUTSIDE: u32 = 0u;
const INSIDE: u32 = 1u;

// `TECHNIQUE_COUNT` and `TECHNIQUE_TINTS` (each technique's `DrawInfo::tint` by `Technique::index`)
// are prepended by crates/treelod-render/src/gpu_select.rs (`shader`).
const STRADDLES: u32 = 2u;
const ROOTS_CELL: u32 = 0xFFFFFFFFu;
const F32_MAX: f32 = 3.40282347e+38;
// InstanceDraw::technique's first bit of the quads an instance is drawn with instead of the point
// tree's selection (InstanceDrawGpu::QUAD_SHIFT): 0 none, else 1 + QuadKind::index.
const QUAD_SHIFT: u32 = 30u;
// Buckets per model: triangles, points, octahedral impostor quads, billboard quads (gpu_select.rs,
// BUCKET_KINDS).
const BUCKET_KINDS: u32 = 4u;

// Rust twin: SelectFrameGpu (crates/treelod-render/src/gpu_select.rs).
struct SelectFrame {
    // Left, right, bottom, top, near, far: unit normal into the frustum (xyz), offset (w).
    planes: array<vec4<f32>, 6>,
    // Eye, world (xyz); world size per pixel at one metre, 2·tan(fovy/2)/H (w).
    eye: vec4<f32>,
    // s_min, s_max, depth bias k (pixels), far ratio.
    pixels: vec4<f32>,
    // L_m, L_M, shading on (1 or 0), Z needed (1 or 0: bias or shading on).
    shading: vec4<f32>,
    block_count: u32,
    // Index of the first statistics counter in `counters` (= BUCKET_KINDS × models).
    stats_at: u32,
    _pad0: u32,
    _pad1: u32,
}

// Rust twin: BlockGpu.
struct Block {
    centre: array<f32, 3>,
    radius: f32,
    first: u32,
    count: u32,
    _pad0: u32,
    _pad1: u32,
}

// Rust twin: InstanceGpu. `index` is the instance's index in `Renderer::set_instances`' list,
// where its transform is (`transforms`, the renderer's, which the tree shaders read too).
struct InstanceGpu {
    model: u32,
    index: u32,
}

// Rust twin: InstanceDrawGpu. What the selection draws of one instance this frame, indexed by
// `InstanceGpu::index`:
//   fade       0: skipped (drawn by the CPU with another technique, or not at all); else the
//              DrawInfo::fade of its draws, pack2x16unorm of the dither share [lo, hi) it keeps
//              (0xFFFF0000: every pixel). lo == 0: the technique it is assigned (counted as a
//              visible instance); lo > 0: only the draws of the point tree it leaves in a
//              transition (counted as leaving primitives).
//   technique  Technique::index of the technique its draws are tinted with and counted under;
//              (bits 0..30); bits 30..32 (QUAD_SHIFT) k > 0: the instance is drawn as its
//              model's quads of kind k - 1 (`ModelGpu::quads`: octahedral impostor, facing
//              billboard, crossed billboards) instead of through the point tree's selection.
struct InstanceDraw {
    fade: u32,
    technique: u32,
}

// Rust twin: ModelGpu. Pool indices: `triangle_base + i` is container triangle `i` in the pool
// bound as triangles, `point_base + i` container point `i` bound as points, `roots_at` the first
// of the model's far list (`ModelLod::far_list`, the roots first, copied contiguously), whose
// `hi` values are `keys[far_hi_at ..]`.
struct ModelGpu {
    centre: array<f32, 3>,
    radius: f32,
    cull_centre: array<f32, 3>,
    cull_radius: f32,
    cull_half: array<f32, 3>,
    first_cell: u32,
    cell_count: u32,
    far_tau: f32,
    largest: f32,
    cell_reach: f32,
    far_count: u32,
    root_cells: u32,
    roots_at: u32,
    far_hi_at: u32,
    triangle_base: u32,
    point_base: u32,
    // Triangle, point, octahedral impostor and billboard bucket: first slot of the draw buffers,
    // and slots.
    bucket_first: array<u32, 4>,
    bucket_capacity: array<u32, 4>,
    // Per quad kind (QuadKind::index: octahedral impostor, facing billboard, crossed billboards)
    // the model's quads, first and count, as the CPU path draws them (QuadDraw::first, count;
    // count 0 where the renderer cannot draw them).
    quads: array<u32, 6>,
}

// Rust twin: CellGpu. `sizes_at` / `hi_at` index `keys`.
struct CellGpu {
    centre: array<f32, 3>,
    index: u32,
    half: array<f32, 3>,
    block_cell: u32,
    triangles_first: u32,
    triangles_count: u32,
    points_first: u32,
    points_count: u32,
    sizes_at: u32,
    hi_at: u32,
    largest: f32,
    roots: u32,
    next_hi: f32,
    hi0: f32,
    _pad0: u32,
    _pad1: u32,
}


// wgpu::util::DrawIndirectArgs.
struct DrawIndirect {
    vertex_count: u32,
    instance_count: u32,
    first_vertex: u32,
    first_instance: u32,
}

struct DispatchArgs {
    x: atomic<u32>,
    y: u32,
    z: u32,
}

@group(0) @binding(0) var<uniform> frame: SelectFrame;
// cull_blocks
@group(0) @binding(1) var<storage, read> blocks: array<Block>;
@group(0) @binding(2) var<storage, read_write> visible_out: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read_write> dispatch: DispatchArgs;
// select_instances
@group(0) @binding(4) var<storage, read> visible: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> instances: array<InstanceGpu>;
@group(0) @binding(6) var<storage, read> models: array<ModelGpu>;
@group(0) @binding(7) var<storage, read> cells: array<CellGpu>;
@group(0) @binding(8) var<storage, read> keys: array<f32>;
// Per bucket (BUCKET_KINDS × model + kind) the ranges appended, then the statistics: instances
// visible, far, cells selected, cells culled, triangles, points, primitives of leaving draws, then
// primitives per technique (Technique::index), of the point tree's draws only (the CPU counts the
// octahedral impostors' trees it hands over).
@group(0) @binding(9) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(10) var<storage, read_write> draws: array<DrawInfo>;
@group(0) @binding(11) var<storage, read_write> indirect: array<DrawIndirect>;
@group(0) @binding(12) var<storage, read> instance_draws: array<InstanceDraw>;
@group(0) @binding(13) var<storage, read> transforms: array<InstanceTransform>;

fn v3(a: array<f32, 3>) -> vec3<f32> {
    return vec3<f32>(a[0], a[1], a[2]);
}

// Frustum::classify_sphere.
fn classify_sphere(centre: vec3<f32>, radius: f32) -> u32 {
    var inside = true;
    for (var i = 0u; i < 6u; i++) {
        let p = frame.planes[i];
        let d = dot(p.xyz, centre) + p.w;
        if d < -radius {
            return OUTSIDE;
        }
        inside = inside && d >= radius;
    }
    return select(STRADDLES, INSIDE, inside);
}

// Frustum::intersects_box.
fn intersects_box(centre: vec3<f32>, a0: vec3<f32>, a1: vec3<f32>, a2: vec3<f32>) -> bool {
    for (var i = 0u; i < 6u; i++) {
        let p = frame.planes[i];
        let n = p.xyz;
        let reach = abs(dot(n, a0)) + abs(dot(n, a1)) + abs(dot(n, a2));
        if dot(n, centre) + p.w < -reach {
            return false;
        }
    }
    return true;
}

@compute @workgroup_size(64)
fn cull_blocks(@builtin(global_invocation_id) id: vec3<u32>) {
    let b = id.x;
    if b >= frame.block_count {
        return;
    }
    let block = blocks[b];
    if classify_sphere(v3(block.centre), block.radius) == OUTSIDE {
        return;
    }
    let slot = atomicAdd(&dispatch.x, 1u);
    visible_out[slot] = vec2<u32>(block.first, block.count);
}

// The instance being selected by this invocation.
var<private> current: InstanceGpu;
var<private> cur_model: ModelGpu;
var<private> cur_draw: InstanceDraw;
var<private> model_index: u32;
// World size per pixel per metre, divided by the instance's scale.
var<private> per_metre: f32;
var<private> tally_cells: u32;
var<private> tally_triangles: u32;
var<private> tally_points: u32;

// LodSettings::biased_pixels, then CellEmitter::thresholds: (τ_p, τ_t), model space.
fn thresholds(z: f32, distance: f32) -> vec2<f32> {
    let shift = frame.pixels.z * z;
    let s_min = max(frame.pixels.x + shift, 0.0);
    let s_max = max(frame.pixels.y + shift, s_min);
    let unit = max(distance, 0.0) * per_metre;
    return vec2<f32>(s_min * unit, s_max * unit);
}

// LodSettings::shading_at.
fn shading_at(z: f32) -> f32 {
    if frame.shading.z == 0.0 {
        return 1.0;
    }
    let l_min = frame.shading.x;
    let l_max = frame.shading.y;
    return l_max + 0.5 * (z - 1.0) * (l_max - l_min);
}

// Number of leading keys[at .. at + n] (sorted largest first) above tau: partition_point.
fn leading_above(at: u32, n: u32, tau: f32) -> u32 {
    var lo = 0u;
    var hi = n;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if keys[at + mid] > tau {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// Appends one range: `kind` 0 triangles, 1 points (`first` a pool index), 2 the model's
// octahedral impostor quads, 3 its billboard quads (`first` a quad index, as the CPU path records
// a `QuadDraw`).
fn write_range(kind: u32, cell: u32, first: u32, count: u32, taus: vec2<f32>, shading: f32) {
    let s = atomicAdd(&counters[BUCKET_KINDS * model_index + kind], 1u);
    if s >= cur_model.bucket_capacity[kind] {
        return;
    }
    let slot = cur_model.bucket_first[kind] + s;
    draws[slot] = DrawInfo(taus.x, max(taus.y, taus.x), cell, shading, 1.0, current.index,
                           TECHNIQUE_TINTS[cur_draw.technique], cur_draw.fade);
    let corners = select(6u, 3u, kind == 0u);
    indirect[slot] = DrawIndirect(count * corners, 1u, first * corners, slot);
}

// ModelLod::far_points.
fn far_points(lowest: vec2<f32>) -> bool {
    return cur_model.far_count > 0u && lowest.x >= cur_model.far_tau && lowest.x > 0.0 && lowest.x < F32_MAX;
}

// ModelLod::far_list_pays (FAR_LIST_EXTRA is written before this file).
fn far_list_pays(tau_near: f32, tau_centre: f32) -> bool {
    let near = f32(leading_above(cur_model.far_hi_at, cur_model.far_count, tau_near));
    return near <= FAR_LIST_EXTRA * f32(leading_above(cur_model.far_hi_at, cur_model.far_count, tau_centre));
}

// CellEmitter::least_thresholds.
fn least_thresholds(needs_z: bool, distance: f32) -> vec2<f32> {
    if !needs_z {
        return thresholds(0.0, distance);
    }
    return min(thresholds(-1.0, distance), thresholds(1.0, distance));
}

// CellEmitter::emit_far: each cell's triangle prefix at taus, then the far list's prefix.
fn emit_far(taus: vec2<f32>) {
    if taus.y < cur_model.largest {
        let cell_end = cur_model.first_cell + cur_model.cell_count;
        for (var i = cur_model.first_cell; i < cell_end; i++) {
            let c = cells[i];
            if c.largest > taus.y {
                let triangles = leading_above(c.sizes_at, c.triangles_count, taus.y);
                tally_triangles += triangles;
                write_range(0u, c.index, cur_model.triangle_base + c.triangles_first, triangles, taus, shading_at(0.0));
            }
        }
    }
    let count = leading_above(cur_model.far_hi_at, cur_model.far_count, taus.x);
    tally_cells += cur_model.root_cells;
    tally_points += count;
    write_range(1u, ROOTS_CELL, cur_model.roots_at, count, taus, shading_at(0.0));
}

// CellEmitter::emit.
fn emit(c: CellGpu, z: f32, distance: f32) {
    let taus = thresholds(z, distance);
    let any_triangles = c.largest > taus.y;
    let any_points = c.hi0 > taus.x;
    var triangles = 0u;
    if any_triangles {
        triangles = leading_above(c.sizes_at, c.triangles_count, taus.y);
    }
    var points = 0u;
    if any_points {
        if taus.x >= c.next_hi && taus.x < F32_MAX {
            points = c.roots;
        } else {
            points = leading_above(c.hi_at, c.points_count, taus.x);
        }
    }
    tally_cells += 1u;
    tally_triangles += triangles;
    tally_points += points;
    let shading = shading_at(z);
    if triangles > 0u {
        write_range(0u, c.index, cur_model.triangle_base + c.triangles_first, triangles, taus, shading);
    }
    if points > 0u {
        write_range(1u, c.index, cur_model.point_base + c.points_first, points, taus, shading);
    }
}

@compute @workgroup_size(64)
fn select_instances(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let block = visible[group.x];
    if lane >= block.y {
        return;
    }
    current = instances[block.x + lane];
    cur_draw = instance_draws[current.index];
    if cur_draw.fade == 0u {
        return;
    }
    let quads = min(cur_draw.technique >> QUAD_SHIFT, 3u);
    cur_draw.technique = min(cur_draw.technique & ((1u << QUAD_SHIFT) - 1u), TECHNIQUE_COUNT - 1u);
    model_index = current.model;
    cur_model = models[model_index];
    if quads > 0u {
        // The CPU culled the tree (the policy's chooser tests its sphere as the CPU path does)
        // and counts it and its quads in the frame's statistics. Recorded as the CPU path's
        // `record_direct` records a `QuadDraw` (crates/treelod-render/src/draws.rs): the
        // octahedral impostor to bucket 2, billboards to bucket 3.
        let first = cur_model.quads[2u * (quads - 1u)];
        let count = cur_model.quads[2u * (quads - 1u) + 1u];
        if count > 0u {
            write_range(select(3u, 2u, quads == 1u), ROOTS_CELL, first, count, vec2<f32>(0.0), 1.0);
        }
        return;
    }
    let m = transforms[current.index].model;
    let ax = m[0].xyz;
    let ay = m[1].xyz;
    let az = m[2].xyz;
    let t = m[3].xyz;
    let scale = sqrt(max(max(dot(ax, ax), dot(ay, ay)), dot(az, az)));

    // cull_instance: the sphere, then the transformed box if the sphere straddles.
    let cc = v3(cur_model.cull_centre);
    let cull_centre = ax * cc.x + ay * cc.y + az * cc.z + t;
    let visibility = classify_sphere(cull_centre, cur_model.cull_radius * scale);
    if visibility == OUTSIDE {
        return;
    }
    let h = v3(cur_model.cull_half);
    if visibility == STRADDLES && !intersects_box(cull_centre, ax * h.x, ay * h.y, az * h.z) {
        return;
    }

    // select_instance.
    let mc = v3(cur_model.centre);
    let centre = t + ax * mc.x + ay * mc.y + az * mc.z;
    let radius = cur_model.radius * scale;
    let eye = frame.eye.xyz;
    let to_block = centre - eye;
    let d_block = length(to_block);
    var inv_radius = 0.0;
    if radius > 0.0 {
        inv_radius = 1.0 / radius;
    }
    per_metre = frame.eye.w / scale;
    let needs_z = frame.shading.w != 0.0;
    var far = 0u;
    var culled = 0u;
    let cell_end = cur_model.first_cell + cur_model.cell_count;
    // The least thresholds of a cell no nearer than d_block − cell_reach·scale: the near path's
    // far list is drawn at them.
    let nearest = least_thresholds(needs_z, d_block - cur_model.cell_reach * scale);

    if radius < frame.pixels.w * d_block {
        far = 1u;
        let lowest = least_thresholds(needs_z, d_block);
        if far_points(lowest) && far_list_pays(lowest.x, thresholds(0.0, d_block).x) {
            emit_far(lowest);
        } else if needs_z && d_block > 0.0 {
            let to_z = vec3<f32>(dot(ax, to_block), dot(ay, to_block), dot(az, to_block)) * (inv_radius / d_block);
            for (var i = cur_model.first_cell; i < cell_end; i++) {
                let c = cells[i];
                var z = 0.0;
                if c.block_cell == 0u {
                    z = clamp(dot(v3(c.centre) - mc, to_z), -1.0, 1.0);
                }
                emit(c, z, d_block);
            }
        } else {
            for (var i = cur_model.first_cell; i < cell_end; i++) {
                emit(cells[i], 0.0, d_block);
            }
        }
    } else if visibility != STRADDLES && frame.shading.z == 0.0
        && far_points(nearest) && far_list_pays(nearest.x, thresholds(0.0, d_block).x) {
        // Every cell in view and none nearer than d_block − cell_reach·scale, where the far list
        // draws few points more than the cells would.
        emit_far(nearest);
    } else {
        // Near path: exact per-cell distances; cells culled on their own if the block straddles.
        // Per plane: n·p + w as a function of the model-space point, and the reach of a unit
        // half-extent along each model axis.
        var planes: array<vec4<f32>, 6>;
        var reach: array<vec3<f32>, 6>;
        for (var j = 0u; j < 6u; j++) {
            let p = frame.planes[j];
            let n = p.xyz;
            let along = vec3<f32>(dot(n, ax), dot(n, ay), dot(n, az));
            planes[j] = vec4<f32>(along, dot(n, t) + p.w);
            reach[j] = abs(along);
        }
        let straddles = visibility == STRADDLES;
        for (var i = cur_model.first_cell; i < cell_end; i++) {
            let c = cells[i];
            if c.block_cell != 0u {
                emit(c, 0.0, d_block);
                continue;
            }
            let cc = v3(c.centre);
            if straddles {
                var out = false;
                for (var j = 0u; j < 6u; j++) {
                    out = out || dot(planes[j].xyz, cc) + planes[j].w < -dot(reach[j], v3(c.half));
                }
                if out {
                    culled += 1u;
                    continue;
                }
            }
            let d_cell = distance(t + ax * cc.x + ay * cc.y + az * cc.z, eye);
            var z = 0.0;
            if needs_z {
                z = clamp((d_cell - d_block) * inv_radius, -1.0, 1.0);
            }
            emit(c, z, d_cell);
        }
    }
    let at = frame.stats_at;
    let primitives = tally_triangles + tally_points;
    if (cur_draw.fade & 0xFFFFu) == 0u {
        atomicAdd(&counters[at], 1u);
        atomicAdd(&counters[at + 1u], far);
    } else {
        atomicAdd(&counters[at + 6u], primitives);
    }
    atomicAdd(&counters[at + 7u + cur_draw.technique], primitives);
    atomicAdd(&counters[at + 2u], tally_cells);
    atomicAdd(&counters[at + 3u], culled);
    atomicAdd(&counters[at + 4u], tally_triangles);
    atomicAdd(&counters[at + 5u], tally_points);
}
