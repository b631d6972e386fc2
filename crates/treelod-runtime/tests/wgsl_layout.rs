//! The WGSL twins in `shaders/shared/records.wgsl` have the sizes and field offsets of the Rust
//! records (and so of the spec's byte tables): a drift here would make the GPU read garbage.

use std::mem::offset_of;

use treelod_format::{
    EllipsoidRecord, LineRecord, PlaneRecord, PointRecord, PruneLeafRecord, TriangleRecord, VertexRecord,
};

const SHADER: &str = include_str!("../../../shaders/shared/records.wgsl");

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
    let module = naga::front::wgsl::parse_str(SHADER).expect("records.wgsl parses");
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty())
        .validate(&module)
        .expect("records.wgsl validates");
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).expect("layouts compute");
    for (name, size, offsets) in rust_layouts() {
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, ty)| ty.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("{name} is missing from records.wgsl"));
        let naga::TypeInner::Struct { members, span } = &ty.inner else {
            panic!("{name} is not a struct");
        };
        assert_eq!(*span as usize, size, "{name}: WGSL size {span}, Rust {size}");
        assert_eq!(layouter[handle].alignment, naga::proc::Alignment::FOUR, "{name}: stride must equal size");
        let wgsl: Vec<usize> = members.iter().map(|m| m.offset as usize).collect();
        assert_eq!(wgsl, offsets, "{name}: field offsets differ");
    }
}
