// The occlusion factor of pruned trees (crates/treelod-render/src/occlusion.rs): per tree, how many of
// its hull samples face the camera and how many of those the depth buffer shows.
//
// One workgroup per tree (a 2D dispatch of rows of 65535), one invocation per sample.
// `DEPTH_TEXTURE` is replaced by `texture_depth_2d` or `texture_depth_multisampled_2d`. Preceded by
// shaders/shared/draw.wgsl (`InstanceTransform`).

struct OcclusionFrame {
    view_proj: mat4x4<f32>,
    eye: vec4<f32>,
    // Viewport size, pixels.
    size: vec2<f32>,
    jobs: u32,
    _pad: u32,
}

// One tree. Rust twin: `Job` in crates/treelod-render/src/occlusion.rs.
struct OcclusionJob {
    // Into the renderer's instance transforms.
    instance: u32,
    // Into `models`.
    model: u32,
}

// A model's hull. Rust twin: `ModelGpu`.
struct OcclusionModel {
    // Hull centre (xyz) and culling radius (w), model space.
    centre: vec4<f32>,
    // Its samples.
    first: u32,
    count: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> frame: OcclusionFrame;
@group(0) @binding(1) var<storage, read> jobs: array<OcclusionJob>;
@group(0) @binding(2) var<storage, read> samples: array<vec4<f32>>;
// Per job: samples facing the camera, and of those the visible ones.
@group(0) @binding(3) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(4) var depth: DEPTH_TEXTURE;
@group(0) @binding(5) var<storage, read> transforms: array<InstanceTransform>;
@group(0) @binding(6) var<storage, read> models: array<OcclusionModel>;
// The depth buffer runs from 1 near to 0 far (settings.rs `DepthConvention::Reverse`).
override reverse_z: bool = false;
// How far samples move towards the eye, in culling radii (occlusion.rs `SAMPLE_MARGIN`).
override sample_margin: f32 = 0.25;

@compute @workgroup_size(64)
fn measure(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) i: u32) {
    let j = group.x + group.y * 65535u;
    if j >= frame.jobs {
        return;
    }
    let job = jobs[j];
    let model = models[job.model];
    if i >= model.count {
        return;
    }
    let transform = transforms[job.instance];
    let s = samples[model.first + i];
    let world = (transform.model * vec4<f32>(s.xyz, 1.0)).xyz;
    let centre = (transform.model * vec4<f32>(model.centre.xyz, 1.0)).xyz;
    let to_eye = frame.eye.xyz - world;
    // The far side of the hull is hidden by the tree itself: it says nothing about occluders.
    if dot(world - centre, to_eye) <= 0.0 {
        return;
    }
    atomicAdd(&counts[2u * j], 1u);
    // Off the leaf the sample sits on, towards the eye.
    let p = world + normalize(to_eye) * (sample_margin * (model.centre.w * transform.scale));
    let clip = frame.view_proj * vec4<f32>(p, 1.0);
    var visible = true;
    if clip.w > 0.0 {
        let ndc = clip.xyz / clip.w;
        if all(abs(ndc.xy) <= vec2<f32>(1.0)) && ndc.z >= 0.0 && ndc.z <= 1.0 {
            let last = vec2<i32>(frame.size) - vec2<i32>(1);
            let pixel = clamp(vec2<i32>(vec2<f32>(0.5 + 0.5 * ndc.x, 0.5 - 0.5 * ndc.y) * frame.size), vec2<i32>(0), last);
            let buffer = textureLoad(depth, pixel, 0);
            visible = select(ndc.z <= buffer, ndc.z >= buffer, reverse_z);
        }
    }
    if visible {
        atomicAdd(&counts[2u * j + 1u], 1u);
    }
}
