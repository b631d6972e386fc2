//! The WGSL twins of the records (`shaders/shared/records.wgsl`, and a representation's own at the
//! top of its file in `shaders/tree/`) have the sizes and field offsets of the Rust records (and so
//! of the spec's byte tables): a drift here would make the GPU read garbage.

use std::mem::offset_of;

use treelod_format::{
    EllipsoidRecord, LineRecord, PlaneRecord, PointRecord, PruneLeafRecord, TriangleRecord, VertexRecord,
};

/// The tree shaders' modules as the renderer composes them (`treelod_render`'s `tree_wgsl!`):
/// the shared files, the common part, then the representation's files.
fn modules() -> Vec<(&'static str, String)> {
    let shared = concat!(
        include_str!("../../../shaders/shared/records.wgsl"),
        include_str!("../../../shaders/shared/draw.wgsl"),
        include_str!("../../../shaders/shared/shadow.wgsl"),
        include_str!("../../../shaders/tree/common.wgsl"),
    );
    [
        ("triangles.wgsl", include_str!("../../../shaders/tree/triangles.wgsl")),
        ("points.wgsl", include_str!("../../../shaders/tree/points.wgsl")),
        ("planes.wgsl", include_str!("../../../shaders/tree/planes.wgsl")),
        ("ellipsoids.wgsl", include_str!("../../../shaders/tree/ellipsoids.wgsl")),
        ("lines.wgsl", include_str!("../../../shaders/tree/lines.wgsl")),
    ]
    .into_iter()
    .map(|(name, file)| (name, format!("{shared}{file}")))
    .collect()
}

/// (struct name, Rust size, Rust field offsets in declaration order).
fn rust_layouts() -> Vec<(&'static str, usize, Vec<usize>)> {
    vec![
        (
            "VertexRecord",
            size_of::<VertexRecord>(),
            vec![
                offset_of!(VertexRecord, position),
                offset_of!(VertexRecord, normal),
                offset_of!(VertexRecord, uv),
                offset_of!(VertexRecord, color),
            ],
        ),
        (
            "TriangleRecord",
            size_of::<TriangleRecord>(),
            vec![
                offset_of!(TriangleRecord, indices),
                offset_of!(TriangleRecord, size),
                offset_of!(TriangleRecord, leaf),
                offset_of!(TriangleRecord, material),
            ],
        ),
        (
            "PointRecord",
            size_of::<PointRecord>(),
            vec![
                offset_of!(PointRecord, position),
                offset_of!(PointRecord, radius),
                offset_of!(PointRecord, normal),
                offset_of!(PointRecord, color),
                offset_of!(PointRecord, size),
                offset_of!(PointRecord, lo),
                offset_of!(PointRecord, hi),
                offset_of!(PointRecord, leaf_first),
                offset_of!(PointRecord, leaf_count),
                offset_of!(PointRecord, flags),
            ],
        ),
        (
            "EllipsoidRecord",
            size_of::<EllipsoidRecord>(),
            vec![
                offset_of!(EllipsoidRecord, center),
                offset_of!(EllipsoidRecord, radii),
                offset_of!(EllipsoidRecord, orientation),
                offset_of!(EllipsoidRecord, color),
                offset_of!(EllipsoidRecord, alpha_threshold),
                offset_of!(EllipsoidRecord, noise_mip),
                offset_of!(EllipsoidRecord, lo),
                offset_of!(EllipsoidRecord, hi),
                offset_of!(EllipsoidRecord, leaf_first),
                offset_of!(EllipsoidRecord, leaf_count),
                offset_of!(EllipsoidRecord, flags),
            ],
        ),
        (
            "LineRecord",
            size_of::<LineRecord>(),
            vec![
                offset_of!(LineRecord, p0),
                offset_of!(LineRecord, r0),
                offset_of!(LineRecord, p1),
                offset_of!(LineRecord, r1),
                offset_of!(LineRecord, color),
                offset_of!(LineRecord, lo),
                offset_of!(LineRecord, hi),
                offset_of!(LineRecord, leaf_first),
                offset_of!(LineRecord, leaf_count),
                offset_of!(LineRecord, flags),
            ],
        ),
        (
            "PlaneRecord",
            size_of::<PlaneRecord>(),
            vec![
                offset_of!(PlaneRecord, center),
                offset_of!(PlaneRecord, axis_u),
                offset_of!(PlaneRecord, axis_v),
                offset_of!(PlaneRecord, image),
                offset_of!(PlaneRecord, uv_min),
                offset_of!(PlaneRecord, uv_max),
                offset_of!(PlaneRecord, lo),
                offset_of!(PlaneRecord, hi),
                offset_of!(PlaneRecord, leaf_first),
                offset_of!(PlaneRecord, leaf_count),
            ],
        ),
        (
            "PruneLeafRecord",
            size_of::<PruneLeafRecord>(),
            vec![
                offset_of!(PruneLeafRecord, center),
                offset_of!(PruneLeafRecord, area),
                offset_of!(PruneLeafRecord, first_triangle),
                offset_of!(PruneLeafRecord, triangle_count),
            ],
        ),
    ]
}

#[test]
fn wgsl_records_match_the_rust_records() {
    let parsed: Vec<(&str, naga::Module, naga::proc::Layouter)> = modules()
        .into_iter()
        .map(|(name, source)| {
            let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{name} parses: {e}"));
            naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
                .validate(&module)
                .unwrap_or_else(|e| panic!("{name} validates: {e:?}"));
            let mut layouter = naga::proc::Layouter::default();
            layouter.update(module.to_ctx()).expect("layouts compute");
            (name, module, layouter)
        })
        .collect();
    for (name, size, offsets) in rust_layouts() {
        let mut found = 0;
        for (file, module, layouter) in &parsed {
            let Some((handle, ty)) = module.types.iter().find(|(_, ty)| ty.name.as_deref() == Some(name)) else {
                continue;
            };
            found += 1;
            let naga::TypeInner::Struct { members, span } = &ty.inner else {
                panic!("{name} is not a struct in {file}");
            };
            assert_eq!(*span as usize, size, "{name} ({file}): WGSL size {span}, Rust {size}");
            assert_eq!(layouter[handle].alignment, naga::proc::Alignment::FOUR, "{name}: stride must equal size");
            let wgsl: Vec<usize> = members.iter().map(|m| m.offset as usize).collect();
            assert_eq!(wgsl, offsets, "{name} ({file}): field offsets differ");
        }
        assert!(found > 0, "{name} is twinned in no tree shader");
    }
}
