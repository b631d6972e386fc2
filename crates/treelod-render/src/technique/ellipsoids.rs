//! Clasen's leaf ellipsoids and branch lines (Clasen and Prohaska 2011, spec §6.8, §6.9;
//! [`Technique::Ellipsoids`]): their records as uploaded, their groups (the ellipsoids with the
//! white-noise cube they sample, `crate::noise`; the lines) and their stages. The selection is
//! `treelod_runtime::ellipsoid::select`. WGSL: `shaders/tree/ellipsoids.wgsl`,
//! `shaders/tree/lines.wgsl`.

use treelod_format::{Container, EllipsoidRecord, LineRecord};
#[cfg(doc)]
use treelod_runtime::Technique;
use wgpu::{SamplerBindingType, ShaderStages, TextureSampleType, TextureViewDimension};

use super::{Bucket, Stages, sampler, storage, texture, tree_wgsl};
use crate::renderer::RenderError;
use crate::upload::{ModelUpload, with_ao_in_flags};

/// Group 3 of the ellipsoids' pipelines: the ellipsoids, and the noise cube with its
/// nearest-texel sampler.
pub(crate) const ELLIPSOID_GROUP: &[wgpu::BindGroupLayoutEntry] = &[
    storage(0, ShaderStages::VERTEX_FRAGMENT),
    texture(1, TextureSampleType::Float { filterable: true }, TextureViewDimension::Cube),
    sampler(2, SamplerBindingType::NonFiltering),
];

/// Group 3 of the lines' pipelines: the lines.
pub(crate) const LINE_GROUP: &[wgpu::BindGroupLayoutEntry] = &[storage(0, ShaderStages::VERTEX_FRAGMENT)];

/// The ellipsoids' pipelines.
pub(crate) const ELLIPSOID_STAGES: Stages = Stages {
    module: "treelod tree/ellipsoids.wgsl",
    wgsl: tree_wgsl!("ellipsoids.wgsl"),
    vs: "vs_ellipsoid",
    fs: "fs_ellipsoid",
    label: "treelod ellipsoids",
    shadow_fs: "fs_shadow_ellipsoid",
    shadow_label: "treelod shadow ellipsoids",
};

/// The lines' pipelines.
pub(crate) const LINE_STAGES: Stages = Stages {
    module: "treelod tree/lines.wgsl",
    wgsl: tree_wgsl!("lines.wgsl"),
    vs: "vs_line",
    fs: "fs_line",
    label: "treelod lines",
    shadow_fs: "fs_shadow_line",
    shadow_label: "treelod shadow lines",
};

/// The ellipsoids' and the lines' groups of the model `up` uploads, each if it has them. The
/// first model with ellipsoids uploads the noise cube every model shares.
pub(crate) fn upload(
    up: &mut ModelUpload<'_>,
) -> Result<(Option<wgpu::BindGroup>, Option<wgpu::BindGroup>), RenderError> {
    let container = up.container;
    let ellipsoids = if container.ellipsoids().is_empty() {
        None
    } else {
        if up.noise.is_none() {
            let (view, bytes) = crate::noise::upload(up.device, up.queue);
            *up.noise = Some(view);
            up.bytes += bytes;
        }
        let buffer = up.buffer("ELLIPSOIDS", bytemuck::cast_slice(&gpu_ellipsoids(container)))?;
        let Some(noise) = up.noise.as_ref() else { unreachable!("uploaded above") };
        Some(up.group(
            Bucket::Ellipsoids,
            &[
                buffer.as_entire_binding(),
                wgpu::BindingResource::TextureView(noise),
                wgpu::BindingResource::Sampler(up.noise_sampler),
            ],
        ))
    };
    let lines = if container.lines().is_empty() {
        None
    } else {
        let far = up.representations.lines.as_ref().map_or(&[][..], |lines| lines.far_list());
        let buffer = up.buffer("LINES", bytemuck::cast_slice(&gpu_lines(container, far)))?;
        Some(up.group(Bucket::Lines, &[buffer.as_entire_binding()]))
    };
    Ok((ellipsoids, lines))
}

/// The ellipsoids of `container` as uploaded: `ELLIPSOIDS` then the far ellipsoids, copies of
/// every cell's coarsest level (`treelod_runtime::far_ellipsoids`; the runtime's far draws index
/// them so, `EllipsoidLod::far_first`), each one's `flags` (reserved in the file, spec §6.8)
/// holding its ambient occlusion byte (§6.14), 0 without `ELLIPSOID_AO`: never the file's own
/// flags.
pub(crate) fn gpu_ellipsoids(container: &Container) -> Vec<EllipsoidRecord> {
    let mut ellipsoids =
        with_ao_in_flags(container.ellipsoids(), container.ellipsoid_ao(), |e, flags| EllipsoidRecord { flags, ..e });
    if let Some((far, _)) = treelod_runtime::far_ellipsoids(container) {
        let copies: Vec<EllipsoidRecord> = far.iter().filter_map(|&i| ellipsoids.get(i as usize).copied()).collect();
        ellipsoids.extend(copies);
    }
    ellipsoids
}

/// The branch lines of `container` as uploaded, likewise: `LINES`, `FAR_LINES` (spec §6.9.1;
/// the runtime's far line draws index them so, `LineLod::far_first`), then copies of the lines
/// `far` lists, the far list of the runtime's `LineLod` over the cells (`SptLod::far_list`,
/// whose draws index them so, `SptLod::place_far_list`); each one's `flags` holding its
/// `LINE_AO` or `FAR_LINE_AO` byte, never the file's flags.
pub(crate) fn gpu_lines(container: &Container, far: &[u32]) -> Vec<LineRecord> {
    let with_ao = |l: LineRecord, flags| LineRecord { flags, ..l };
    let mut lines = with_ao_in_flags(container.lines(), container.line_ao(), with_ao);
    let copies: Vec<LineRecord> = far.iter().filter_map(|&i| lines.get(i as usize).copied()).collect();
    lines.extend(with_ao_in_flags(container.far_lines(), container.far_line_ao(), with_ao));
    lines.extend(copies);
    lines
}
