//! Property tests: every synthetic container round-trips through the writer and the reader, is
//! written deterministically, passes `verify` and an independent check of the spec's rules here,
//! and survives a trip through a real file; a failed write leaves the destination untouched.

use proptest::prelude::*;
use treelod_format::{
    CellRecord, Compression, Container, ContainerData, Error, ErrorClass, FlipCalibrationRecord, LineRecord, NO_IMAGE,
    SectionKind, SptElement, image_format, leaf_slots, verify,
};
use treelod_tests::{NormalGrids, SyntheticOptions, synthetic};

fn range(max_start: u32, max_span: u32) -> impl Strategy<Value = core::ops::RangeInclusive<u32>> {
    (0..=max_start, 0..=max_span).prop_map(|(lo, span)| lo..=lo + span)
}

/// Small random options: grids up to 3×3×3, up to a dozen elements per cell and kind.
fn options() -> impl Strategy<Value = SyntheticOptions> {
    let kinds =
        prop::sample::subsequence(vec![0x0004, 0x00FF, 0x0100, 0xFFFF, 0x0001_0000, 0xFFFF_FFFF, 0x0011], 0..=3);
    (
        ([1u32..=3, 1u32..=3, 1u32..=3], range(3, 8), range(2, 5), range(2, 4), range(2, 4), range(2, 3)),
        (0u32..=7, 0u32..=5, 0u32..=4, 0u32..=3, any::<bool>(), 0u32..=3, kinds),
    )
        .prop_map(|((grid, triangles, ellipsoids, lines, planes, prune), rest)| {
            let (block_ellipsoids, curve_samples, materials, textures, png_image, tree_count, extension_kinds) = rest;
            SyntheticOptions {
                grid,
                triangles_per_cell: triangles,
                ellipsoids_per_cell: ellipsoids,
                lines_per_cell: lines,
                planes_per_cell: planes,
                prune_leaves_per_cell: prune,
                block_ellipsoids,
                curve_samples,
                // Baselines with some of the curve and image draws, so the tuple stays small.
                lod_levels: curve_samples.min(3),
                billboards: png_image,
                materials,
                textures,
                png_image,
                tree_count,
                extension_kinds,
                // Ambient occlusion with half of the grids.
                ao: grid[0] >= 2,
                // Indirectly textured planes with another half.
                indirect_planes: grid[2] >= 2,
                // Ellipsoid occlusion with a quarter.
                ellipsoid_ao: grid[0] >= 2 && grid[2] >= 2,
                // Line occlusion with another quarter.
                line_ao: grid[0] >= 2 && grid[2] < 2,
                // A calibration with half of the grids.
                calibration: grid[1] >= 2,
                // Its tables per elevation with a quarter (they need a calibration).
                calibration_elevations: grid[1] >= 2 && grid[0] >= 2,
                // The added techniques' tables with a quarter (they need a calibration), per
                // elevation where it has its tables per elevation.
                calibration_added: grid[1] >= 2 && grid[2] >= 2,
                // The chain's per-level tables with a quarter (they need a chain).
                chain_calibration: grid[1] >= 2 && curve_samples > 0,
                // Far lines with half of the grids (their occlusion where the lines have theirs).
                far_lines: grid[1] < 2,
                // The planes' diffuse response with half of the grids.
                plane_diffuse: grid[2] < 2,
                // Octahedral impostors with half of the grids (on the atlas, with billboards or not).
                octahedral: grid[0] < 2,
                // Of 2 to 16 views per side, as the presets draw them.
                octahedral_frames: 2..=16,
                // Their views' depth planes with half of those.
                octahedral_depth: grid[0] < 2 && grid[1] < 2,
                // The points' facing with half of the grids.
                point_facing: grid[2] >= 2,
                // Where their views' normals lie with another half of those (drawing no random
                // numbers, so the rest is the same as without them): 1.16's grids with half of
                // those, 1.15's with the other half.
                octahedral_normals: match (grid[0] < 2 && grid[1] >= 2, grid[2] >= 2) {
                    (false, _) => NormalGrids::None,
                    (true, true) => NormalGrids::HalfSize,
                    (true, false) => NormalGrids::ColourSize,
                },
                // The calibration's FLIP error with a quarter of the grids (self-describing rows:
                // it needs no other table).
                calibration_flip: grid[1] < 2 && grid[2] >= 2,
                // The chain levels' FLIP error with half of the chain's per-level tables (rows at
                // their levels and heights: without them it gives none).
                chain_calibration_flip: grid[1] >= 2 && curve_samples > 0 && grid[0] < 2,
                // No BC7 atlas: its blocks lie after the images that follow it in IMAGES, which
                // the generator check below refuses (the golden 1.6 to 1.8 files cover it).
                bc7_atlas: false,
                name: None,
            }
        })
}

fn compression() -> impl Strategy<Value = Compression> {
    prop_oneof![Just(Compression::None), (1i32..=19).prop_map(|level| Compression::Zstd { level })]
}

/// The reference positions of a cell's records (spec §6.2).
fn reference_positions(data: &ContainerData, cell: &CellRecord) -> Vec<[f32; 3]> {
    let mut refs = Vec::new();
    for t in &data.triangles[cell.triangles.as_usize()] {
        refs.extend(t.indices.iter().filter_map(|&i| data.vertices.get(i as usize)).map(|v| v.position));
    }
    refs.extend(data.points[cell.points.as_usize()].iter().map(|p| p.position));
    refs.extend(data.ellipsoids[cell.ellipsoids.as_usize()].iter().map(|e| e.center));
    for l in &data.lines[cell.lines.as_usize()] {
        refs.extend([l.p0, l.p1]);
    }
    refs.extend(data.planes[cell.planes.as_usize()].iter().map(|p| p.center));
    refs.extend(data.prune_leaves[cell.prune_leaves.as_usize()].iter().map(|p| p.center));
    refs
}

/// Thresholds worth testing for a set of interval ends and sizes: each value, the midpoints
/// between neighbours, 0 and a value above all.
fn thresholds(mut values: Vec<f32>) -> Vec<f32> {
    values.retain(|v| v.is_finite());
    values.push(0.0);
    values.sort_by(f32::total_cmp);
    values.dedup();
    let mut out = values.clone();
    out.extend(values.windows(2).map(|w| 0.5 * (w[0] + w[1])));
    out.push(values.last().copied().unwrap_or(0.0) * 2.0 + 1.0);
    out.sort_by(f32::total_cmp);
    out
}

/// Spec §10 for an ellipsoid, line or plane array of one cell: for every `τ`, the drawn elements
/// (`lo ≤ τ < hi`) cover each leaf exactly once; sorted by `hi`, largest first.
fn check_exact_cut<T: SptElement>(what: &str, cell: usize, elements: &[T]) -> Result<(), String> {
    if elements.windows(2).any(|w| w[0].hi() < w[1].hi()) {
        return Err(format!("cell {cell}: {what} not sorted by hi"));
    }
    let leaves = elements.iter().map(|e| e.leaf_first() + e.leaf_count()).max().unwrap_or(0) as usize;
    let ends = elements.iter().flat_map(|e| [e.lo(), e.hi()]).collect();
    for tau in thresholds(ends) {
        let mut cover = vec![0u32; leaves];
        for e in elements.iter().filter(|e| e.lo() <= tau && tau < e.hi()) {
            for leaf in e.leaf_first()..e.leaf_first() + e.leaf_count() {
                cover[leaf as usize] += 1;
            }
        }
        if cover.iter().any(|&c| c != 1) {
            return Err(format!("cell {cell}: {what} cover {cover:?} at tau {tau}"));
        }
    }
    Ok(())
}

/// The octahedral impostors (spec §6.13.1): each with 2 to 64 views per side, a finite centre, a
/// finite radius above 0, an existing colour image, `uv_min ≤ uv_max`, a tree in range, its
/// occlusion in `[0, 1]` and `reserved` 0; sorted by tree, at most one per tree. Their views' depth
/// planes (spec §6.13.2): none, or `frames²` per impostor, every value in `[−1, 1]`. Their normal
/// grids (spec §6.13.3): none, or one per impostor, either of its colour grid's size inside the
/// image (1.15, `OCTAHEDRAL_NORMALS`) or with two corners of their own, `uv_min < uv_max` per
/// component (1.16, `OCTAHEDRAL_NORMAL_GRIDS`), not both.
fn check_octahedral(data: &ContainerData) -> Result<(), String> {
    let (normals, grids) = (&data.octahedral_normals, &data.octahedral_normal_grids);
    for (what, count) in [("normal grids (1.15)", normals.len()), ("normal grids (1.16)", grids.len())] {
        if count != 0 && count != data.octahedral.len() {
            return Err(format!("{count} {what} for {} octahedral impostors", data.octahedral.len()));
        }
    }
    if !normals.is_empty() && !grids.is_empty() {
        return Err("both OCTAHEDRAL_NORMALS and OCTAHEDRAL_NORMAL_GRIDS".into());
    }
    for g in grids {
        let ([u0, v0], [u1, v1]) = ([g.uv_min & 0xFFFF, g.uv_min >> 16], [g.uv_max & 0xFFFF, g.uv_max >> 16]);
        if u0 >= u1 || v0 >= v1 {
            return Err(format!("normal grid {g:?} is empty or reversed"));
        }
    }
    // In unorm16 steps: the far corner at most 65536 (1 and the one step of both corners' rounding).
    let steps = |uv: u32| [uv & 0xFFFF, uv >> 16];
    for (n, o) in normals.iter().zip(&data.octahedral) {
        let ([u, v], [u0, v0], [u1, v1]) = (steps(n.uv_min), steps(o.uv_min), steps(o.uv_max));
        if u0 > u1 || v0 > v1 || u + (u1 - u0) > 0x1_0000 || v + (v1 - v0) > 0x1_0000 {
            return Err(format!("normal grid {n:?} of octahedral impostor {o:?} leaves the image"));
        }
    }
    let views: usize = data.octahedral.iter().map(|o| (o.frames as usize).pow(2)).sum();
    if !data.octahedral_depth.is_empty() && data.octahedral_depth.len() != views {
        return Err(format!("{} depth planes for {views} octahedral views", data.octahedral_depth.len()));
    }
    if let Some(p) = data
        .octahedral_depth
        .iter()
        .find(|p| [p.offset, p.slope_s, p.slope_t].iter().any(|v| !(-1.0..=1.0).contains(v)))
    {
        return Err(format!("depth plane {p:?} outside [-1, 1]"));
    }
    let mut previous: Option<u32> = None;
    for o in &data.octahedral {
        let image = data.images.get(o.image as usize).ok_or_else(|| format!("octahedral image {o:?}"))?;
        let [u0, v0] = treelod_format::pack::unpack_unorm16x2(o.uv_min);
        let [u1, v1] = treelod_format::pack::unpack_unorm16x2(o.uv_max);
        let valid = (2..=64).contains(&o.frames)
            && o.center.iter().all(|c| c.is_finite())
            && o.radius.is_finite()
            && o.radius > 0.0
            && image.format != image_format::LEAF_SLOTS
            && u0 <= u1
            && v0 <= v1
            && o.tree < data.block.tree_count
            && (0.0..=1.0).contains(&o.occlusion)
            && u32::from(o.diffuse.flat) + u32::from(o.diffuse.scattered) <= 65535
            && previous.is_none_or(|p| o.tree > p);
        if !valid {
            return Err(format!("octahedral impostor {o:?}"));
        }
        previous = Some(o.tree);
    }
    Ok(())
}

/// The far lines (spec §6.9.1): none, or an exact cut over one leaf per coarsest line (the `LINES`
/// records with `hi = +∞`), whose records with `lo = 0` are those lines' geometry, far level 0
/// lasting at least to their largest `lo`, every endpoint inside the block.
fn check_far_lines(data: &ContainerData) -> Result<(), String> {
    let far = &data.far_lines;
    if far.is_empty() {
        return if data.far_line_ao.is_empty() { Ok(()) } else { Err("far line occlusion without far lines".into()) };
    }
    if !data.far_line_ao.is_empty() && data.far_line_ao.len() != far.len() {
        return Err("far line occlusion of another length".into());
    }
    check_exact_cut("far lines", data.cells.len(), far)?;
    let coarsest: Vec<&LineRecord> = data.lines.iter().filter(|l| l.hi == f32::INFINITY).collect();
    let leaves = far.iter().map(|l| l.leaf_first + l.leaf_count).max().unwrap_or(0) as usize;
    if leaves != coarsest.len() {
        return Err(format!("{leaves} far leaves for {} coarsest lines", coarsest.len()));
    }
    let key = |l: &LineRecord| [l.p0, l.p1].map(|p| p.map(f32::to_bits));
    let mut level_0: Vec<_> = far.iter().filter(|l| l.lo == 0.0).map(key).collect();
    let mut sources: Vec<_> = coarsest.iter().map(|l| key(l)).collect();
    level_0.sort_unstable();
    sources.sort_unstable();
    if level_0 != sources {
        return Err("far level 0 is not the coarsest lines".into());
    }
    let tau_far = far.iter().map(|l| l.lo).filter(|&lo| lo > 0.0).fold(f32::INFINITY, f32::min);
    if coarsest.iter().any(|l| l.lo > tau_far) {
        return Err(format!("tau_far {tau_far} below a coarsest line's lo"));
    }
    let b = &data.block;
    if far
        .iter()
        .flat_map(|l| [l.p0, l.p1])
        .any(|p| (0..3).any(|i| !(b.bounds_min[i] <= p[i] && p[i] <= b.bounds_max[i])))
    {
        return Err("a far line's endpoint lies outside the block".into());
    }
    Ok(())
}

/// An independent check of the rules the generator must keep, so the generator is proven valid
/// even without `verify`: ranges, indices, ordering, bounds and the exact cut (spec §6, §10).
fn check_rules(data: &ContainerData) -> Result<(), String> {
    let cells = &data.cells;
    if cells.len() != data.block.grid_cell_count() + 1 {
        return Err("cell count".into());
    }
    let vertices = data.vertices.len() as u32;
    let materials = data.materials.len() as u32;
    let images = data.images.len() as u32;
    for (index, cell) in cells.iter().enumerate() {
        let refs = reference_positions(data, cell);
        if refs.is_empty() {
            if cell.bounds_min != [0.0; 3] || cell.bounds_max != [0.0; 3] {
                return Err(format!("cell {index}: empty but bounds are not zero"));
            }
        } else if refs.iter().any(|p| (0..3).any(|i| !(cell.bounds_min[i] <= p[i] && p[i] <= cell.bounds_max[i]))) {
            return Err(format!("cell {index}: bounds miss a reference position"));
        }
        // Reference positions of grid cells lie in their grid box (the builder's rule, spec §6.1).
        if index + 1 < cells.len() && !refs.is_empty() {
            let b = &data.block;
            let c = b.cell_coords(index);
            for p in &refs {
                for i in 0..3 {
                    let size = (b.bounds_max[i] - b.bounds_min[i]) / b.grid[i] as f32;
                    let lo = b.bounds_min[i] + c[i] as f32 * size;
                    if !(lo <= p[i] && p[i] <= lo + size) {
                        return Err(format!("cell {index}: position {p:?} outside the grid box"));
                    }
                }
            }
        }
        let tris = &data.triangles[cell.triangles.as_usize()];
        let points = &data.points[cell.points.as_usize()];
        if tris.windows(2).any(|w| w[0].size < w[1].size) {
            return Err(format!("cell {index}: triangles not sorted by size"));
        }
        let mut leaves: Vec<u32> = tris.iter().map(|t| t.leaf).collect();
        leaves.sort_unstable();
        if leaves != (0..tris.len() as u32).collect::<Vec<_>>() {
            return Err(format!("cell {index}: triangle leaf ids {leaves:?}"));
        }
        for t in tris {
            if t.indices.iter().any(|&i| i >= vertices) || t.material >= materials || t.size.is_nan() || t.size < 0.0 {
                return Err(format!("cell {index}: bad triangle {t:?}"));
            }
        }
        for p in points {
            if p.leaf_count == 1 && p.lo == 0.0 {
                let tri = tris.iter().find(|t| t.leaf == p.leaf_first).ok_or("leaf point without triangle")?;
                if tri.size.to_bits() != p.size.to_bits() {
                    return Err(format!("cell {index}: leaf point size {} != triangle size {}", p.size, tri.size));
                }
            }
        }
        check_exact_cut("points", index, points)?;
        // Triangles and points together: every τ_p ≤ τ_t draws each triangle exactly once.
        let size_of = |leaf: u32| tris.iter().find(|t| t.leaf == leaf).map_or(0.0, |t| t.size);
        let values =
            thresholds(points.iter().flat_map(|p| [p.lo, p.hi, p.size]).chain(tris.iter().map(|t| t.size)).collect());
        for (i, &tau_p) in values.iter().enumerate() {
            for &tau_t in &values[i..] {
                let mut cover = vec![0u32; tris.len()];
                for t in tris.iter().filter(|t| t.size > tau_t) {
                    cover[t.leaf as usize] += 1;
                }
                for p in points.iter().filter(|p| p.lo <= tau_p && tau_p < p.hi && p.size <= tau_t) {
                    for leaf in p.leaf_first..p.leaf_first + p.leaf_count {
                        cover[leaf as usize] += 1;
                    }
                }
                if cover.iter().any(|&c| c != 1) {
                    let sizes: Vec<f32> = (0..tris.len() as u32).map(size_of).collect();
                    return Err(format!(
                        "cell {index}: cover {cover:?} at tau_p {tau_p} tau_t {tau_t}, sizes {sizes:?}"
                    ));
                }
            }
        }
        check_exact_cut("ellipsoids", index, &data.ellipsoids[cell.ellipsoids.as_usize()])?;
        check_exact_cut("lines", index, &data.lines[cell.lines.as_usize()])?;
        let planes = &data.planes[cell.planes.as_usize()];
        check_exact_cut("planes", index, planes)?;
        if planes.iter().any(|p| p.image >= images) {
            return Err(format!("cell {index}: plane image out of range"));
        }
    }
    for m in &data.materials {
        if m.image != NO_IMAGE && m.image >= images {
            return Err("material image out of range".into());
        }
    }
    let mut end = 0;
    for img in &data.images {
        if img.data_offset % 16 != 0
            || img.data_offset < end
            || img.data_offset + img.data_length > data.image_data.len() as u64
        {
            return Err(format!("image data range {img:?}"));
        }
        if img.format <= 2 && img.expected_data_length() != Some(img.data_length) {
            return Err(format!("image data length {img:?}"));
        }
        if img.format == image_format::LEAF_SLOTS
            && (img.mip_count != 1 || img.data_length != u64::from(img.width * img.height * 4))
        {
            return Err(format!("LEAF_SLOTS image {img:?}"));
        }
        end = img.data_offset + img.data_length;
    }
    check_indirect_texturing(data)?;
    check_far_lines(data)?;
    // Spec §6.10.2: no diffuse records, or one per plane, each with shares summing to at most 1.
    if !data.plane_diffuse.is_empty() && data.plane_diffuse.len() != data.planes.len() {
        return Err(format!("{} diffuse records for {} planes", data.plane_diffuse.len(), data.planes.len()));
    }
    if let Some(r) = data.plane_diffuse.iter().find(|r| u32::from(r.flat) + u32::from(r.scattered) > 0xFFFF) {
        return Err(format!("diffuse shares {} + {} above 65535", r.flat, r.scattered));
    }
    check_octahedral(data)?;
    let mut next = 0;
    for (index, leaf) in data.prune_leaves.iter().enumerate() {
        if leaf.first_triangle != next || leaf.triangle_count == 0 {
            return Err(format!("pruned leaf {index} does not tile the triangles"));
        }
        for t in
            &data.prune_triangles[leaf.first_triangle as usize..(leaf.first_triangle + leaf.triangle_count) as usize]
        {
            if t.leaf != index as u32 || t.indices.iter().any(|&i| i >= vertices) || t.material >= materials {
                return Err(format!("pruned triangle {t:?} of leaf {index}"));
            }
        }
        next += leaf.triangle_count;
    }
    if next as usize != data.prune_triangles.len() {
        return Err("pruned triangles not all owned".into());
    }
    for curve in [&data.prune_scale, &data.prune_lambda] {
        if curve.windows(2).any(|w| w[0].x >= w[1].x) {
            return Err("curve x not strictly increasing".into());
        }
    }
    if data.prune_scale.iter().any(|s| !(s.x > 0.0 && s.x <= 1.0 && s.y >= 1.0)) {
        return Err("s_opt sample out of range".into());
    }
    let meta = &data.metadata;
    if meta.trees.len() != data.block.tree_count as usize || meta.materials.len() != data.materials.len() {
        return Err("metadata counts".into());
    }
    if meta.trees.iter().any(|t| t.source as usize >= meta.sources.len()) {
        return Err("tree source out of range".into());
    }
    if meta.settings.windows(2).any(|w| w[0].key >= w[1].key) {
        return Err("settings not sorted and unique".into());
    }
    Ok(())
}

/// Spec §6.10.1: `PLANE_LEAVES` empty or `leaf_count` records per plane, present if a plane
/// samples a `LEAF_SLOTS` image, with materials in range and finite maps; every texel whose centre
/// lies in such a plane's rectangle names one of its leaves or none.
fn check_indirect_texturing(data: &ContainerData) -> Result<(), String> {
    let total: u64 = data.planes.iter().map(|p| u64::from(p.leaf_count)).sum();
    if !data.plane_leaves.is_empty() && data.plane_leaves.len() as u64 != total {
        return Err(format!("{} plane leaves for {total} leaves of planes", data.plane_leaves.len()));
    }
    for leaf in &data.plane_leaves {
        let finite = leaf.uv0.iter().chain(&leaf.du).chain(&leaf.dv).all(|v| v.is_finite());
        if leaf.material as usize >= data.materials.len() || !finite {
            return Err(format!("plane leaf {leaf:?}"));
        }
    }
    for (index, plane) in data.planes.iter().enumerate() {
        let Some(image) = data.images.get(plane.image as usize).filter(|i| i.format == image_format::LEAF_SLOTS) else {
            continue;
        };
        if data.plane_leaves.is_empty() {
            return Err(format!("plane {index} samples LEAF_SLOTS without PLANE_LEAVES"));
        }
        let texels = &data.image_data[image.data_offset as usize..][..image.data_length as usize];
        let [u0, v0] = treelod_format::pack::unpack_unorm16x2(plane.uv_min);
        let [u1, v1] = treelod_format::pack::unpack_unorm16x2(plane.uv_max);
        for y in 0..image.height {
            for x in 0..image.width {
                let (cu, cv) = ((x as f32 + 0.5) / image.width as f32, (y as f32 + 0.5) / image.height as f32);
                if !(u0 <= cu && cu <= u1 && v0 <= cv && cv <= v1) {
                    continue;
                }
                let at = ((y * image.width + x) * 4) as usize;
                let (a, b) = leaf_slots([texels[at], texels[at + 1], texels[at + 2], texels[at + 3]]);
                if u32::from(a.max(b)) > plane.leaf_count {
                    return Err(format!("plane {index}: texel ({x}, {y}) holds slots ({a}, {b})"));
                }
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn synthetic_containers_round_trip_and_verify(seed in any::<u64>(), options in options(), compression in compression()) {
        let data = synthetic(seed, &options);
        prop_assert_eq!(&synthetic(seed, &options), &data, "the generator is deterministic");
        if let Err(rule) = check_rules(&data) {
            return Err(TestCaseError::fail(format!("generator broke a rule: {rule}")));
        }
        for compression in [Compression::None, compression] {
            let bytes = data.to_bytes(compression).unwrap();
            prop_assert_eq!(&data.to_bytes(compression).unwrap(), &bytes, "the writer is deterministic");
            let container = Container::from_bytes(&bytes).unwrap();
            prop_assert_eq!(container.header().file_size, bytes.len() as u64);
            prop_assert_eq!(&ContainerData::from_container(&container), &data);
            if let Err(e) = verify(&container) {
                return Err(TestCaseError::fail(format!("verify refused a synthetic container: {e}")));
            }
        }
    }
}

#[test]
fn presets_hold_what_they_promise() {
    let minimal = synthetic(1, &SyntheticOptions::minimal());
    assert_eq!((minimal.cells.len(), minimal.triangles.len(), minimal.points.len()), (2, 1, 1));
    assert_eq!((minimal.vertices.len(), minimal.materials.len()), (3, 1));
    assert!(minimal.images.is_empty() && minimal.ellipsoids.is_empty() && minimal.extra_sections.is_empty());

    let everything = synthetic(3, &SyntheticOptions::everything());
    let bytes = everything.to_bytes(Compression::Zstd { level: 19 }).unwrap();
    let container = Container::from_bytes(&bytes).unwrap();
    // Every kind but 1.15's normal grids, which 1.16's replace (a file holds one of the two).
    for kind in SectionKind::KNOWN {
        let expected = kind != SectionKind::OCTAHEDRAL_NORMALS;
        assert_eq!(container.section(kind).is_some(), expected, "{kind} in SyntheticOptions::everything()");
    }
    let block_cell = everything.cells.last().unwrap();
    assert!(block_cell.ellipsoids.count > 0, "the block cell has an ellipsoid hierarchy");
    assert!(everything.points.iter().any(|p| p.leaf_count > 1), "points have inner nodes");
    assert_eq!(container.header().minor, 18, "everything() holds the kinds of 1.18");
    assert_eq!(everything.octahedral.len(), everything.block.tree_count as usize, "an octahedral impostor per tree");
    let views: u32 = everything.octahedral.iter().map(|o| o.frames * o.frames).sum();
    assert_eq!(everything.octahedral_depth.len(), views as usize, "a depth plane per octahedral view");
    assert_eq!(everything.octahedral_normal_grids.len(), everything.octahedral.len(), "a normal grid per impostor");
    for (g, o) in everything.octahedral_normal_grids.iter().zip(&everything.octahedral) {
        let size = |min: u32, max: u32| [(max & 0xFFFF) - (min & 0xFFFF), (max >> 16) - (min >> 16)];
        let [w, h] = size(o.uv_min, o.uv_max);
        assert_eq!(size(g.uv_min, g.uv_max), [w / 2, h / 2], "half the colour grid's size: {g:?} of {o:?}");
    }
    // FLIP rows over every view and at two elevations, of two techniques at three heights each.
    let flip = &everything.calibration_flip;
    assert_eq!(flip.len(), 3 * 2 * 3, "{flip:?}");
    let mut elevations: Vec<f32> = flip.iter().map(|r| r.elevation).collect();
    elevations.dedup();
    assert_eq!(elevations, [FlipCalibrationRecord::EVERY_VIEW, 30.0, 90.0]);
    // The chain levels' FLIP rows at the levels and heights of the chain's per-level tables.
    let chain_flip = &everything.chain_calibration_flip;
    assert!(!chain_flip.is_empty() && chain_flip.len() == everything.chain_calibration.len(), "{chain_flip:?}");
    for (f, c) in chain_flip.iter().zip(&everything.chain_calibration) {
        assert_eq!((f.level, f.height), (c.level, c.height), "{f:?} of {c:?}");
        assert!((0.0..=1.0).contains(&f.flip), "{f:?}");
    }
    assert!(
        everything.planes.iter().all(|p| everything.images[p.image as usize].format == image_format::LEAF_SLOTS),
        "the planes are textured indirectly"
    );
    check_rules(&everything).unwrap();

    let extension =
        SyntheticOptions { extension_kinds: vec![0x0001_0000, 0x0100, 0x0002], ..SyntheticOptions::minimal() };
    let kinds: Vec<u32> = synthetic(1, &extension).extra_sections.iter().map(|(k, _)| *k).collect();
    assert_eq!(kinds, [0x0100, 0x0001_0000], "known kinds dropped, sorted");
}

#[test]
fn seeds_give_different_containers() {
    let options = SyntheticOptions::gilet([2, 2, 1]);
    assert_ne!(synthetic(1, &options), synthetic(2, &options));
}

#[test]
fn round_trip_through_a_memory_mapped_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = synthetic(11, &SyntheticOptions::everything());
    for (name, compression) in
        [("plain.treelod", Compression::None), ("packed.treelod", Compression::Zstd { level: 5 })]
    {
        let path = dir.path().join(name);
        let size = data.write_to_path(&path, compression).unwrap();
        // The streaming writer and the in-memory one give the same bytes.
        assert_eq!(std::fs::read(&path).unwrap(), data.to_bytes(compression).unwrap());
        assert_eq!(size, std::fs::metadata(&path).unwrap().len());
        let container = Container::open(&path).unwrap();
        assert_eq!(container.path(), Some(path.as_path()));
        assert_eq!(ContainerData::from_container(&container), data);
        verify(&container).unwrap();
        // Overwriting an existing file replaces it.
        let other = synthetic(12, &SyntheticOptions::minimal());
        other.write_to_path(&path, compression).unwrap();
        assert_eq!(ContainerData::from_container(&Container::open(&path).unwrap()), other);
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(leftovers.len(), 2, "no temporary files are left: {leftovers:?}");
}

#[test]
fn open_reports_missing_files_and_directories_as_io_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = Container::open(dir.path().join("absent.treelod")).unwrap_err();
    assert!(matches!(missing, Error::Io { .. }), "{missing:?}");
    assert_eq!(missing.class(), ErrorClass::Io);
    let directory = Container::open(dir.path()).unwrap_err();
    assert!(matches!(directory.class(), ErrorClass::Io | ErrorClass::Invalid), "{directory:?}");
    let empty = dir.path().join("empty.treelod");
    std::fs::write(&empty, b"").unwrap();
    let err = Container::open(&empty).unwrap_err();
    assert_eq!(err.class(), ErrorClass::Invalid);
    assert!(
        matches!(&err, Error::InFile { path, source } if path == &empty && matches!(**source, Error::Truncated { .. })),
        "{err:?}"
    );
}

#[test]
fn a_failed_write_leaves_the_destination_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tree.treelod");
    let old = synthetic(21, &SyntheticOptions::minimal());
    old.write_to_path(&path, Compression::None).unwrap();
    let old_bytes = std::fs::read(&path).unwrap();

    // Data that would make an invalid file: the writer refuses before touching the disk.
    let mut wrong_cells = synthetic(22, &SyntheticOptions::gilet([2, 1, 1]));
    wrong_cells.cells.pop();
    for compression in [Compression::None, Compression::Zstd { level: 3 }] {
        let err = wrong_cells.write_to_path(&path, compression).unwrap_err();
        assert!(matches!(err, Error::Write(_)), "{err:?}");
        assert_eq!(std::fs::read(&path).unwrap(), old_bytes, "the old file is unchanged");
    }
    let mut untiled = synthetic(23, &SyntheticOptions::minimal());
    untiled.cells[0].triangles.count = 0;
    assert!(matches!(untiled.write_to_path(&path, Compression::None), Err(Error::Write(_))));
    let mut known_extra = synthetic(24, &SyntheticOptions::minimal());
    known_extra.extra_sections.push((SectionKind::POINTS.0, vec![1, 2, 3]));
    assert!(matches!(known_extra.write_to_path(&path, Compression::None), Err(Error::Write(_))));
    assert_eq!(std::fs::read(&path).unwrap(), old_bytes);

    // The destination is a directory: the rename fails, the directory and its content stay.
    let target = dir.path().join("dir.treelod");
    std::fs::create_dir(&target).unwrap();
    std::fs::write(target.join("inside"), b"keep").unwrap();
    let err = old.write_to_path(&target, Compression::None).unwrap_err();
    assert_eq!(err.class(), ErrorClass::Io, "{err:?}");
    assert!(target.is_dir());
    assert_eq!(std::fs::read(target.join("inside")).unwrap(), b"keep");

    // A destination in a directory that does not exist.
    let err = old.write_to_path(dir.path().join("no/such/dir/x.treelod"), Compression::None).unwrap_err();
    assert_eq!(err.class(), ErrorClass::Io, "{err:?}");

    let mut names: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["dir.treelod", "tree.treelod"], "no temporary file is left behind");
}

#[test]
fn the_rule_check_catches_broken_data() {
    let good = synthetic(31, &SyntheticOptions::everything());
    check_rules(&good).unwrap();
    type Mutation = Box<dyn Fn(&mut ContainerData)>;
    let mutations: Vec<(&str, Mutation)> = vec![
        ("leaf point size", Box::new(|d| d.points.iter_mut().find(|p| p.leaf_count == 1).unwrap().size *= 1.000_001)),
        ("point interval gap", Box::new(|d| d.points.iter_mut().find(|p| p.leaf_count == 1).unwrap().hi *= 0.5)),
        ("triangle order", Box::new(|d| d.triangles[0].size = 0.0)),
        ("ellipsoid interval", Box::new(|d| d.ellipsoids[0].hi = 1.0)),
        ("line run", Box::new(|d| d.lines.last_mut().unwrap().leaf_count += 1)),
        ("plane order", Box::new(|d| d.planes.reverse())),
        ("cell bounds", Box::new(|d| d.cells[0].bounds_max[1] = d.cells[0].bounds_min[1] - 1.0)),
        ("vertex index", Box::new(|d| d.triangles[0].indices[2] = d.vertices.len() as u32)),
        ("pruned triangle owner", Box::new(|d| d.prune_triangles[0].leaf += 1)),
        ("curve order", Box::new(|d| d.prune_scale.swap(0, 1))),
    ];
    for (what, mutate) in mutations {
        let mut bad = good.clone();
        mutate(&mut bad);
        assert!(check_rules(&bad).is_err(), "{what} not caught");
    }
}

#[cfg(unix)]
#[test]
fn written_files_get_the_mode_of_any_new_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain");
    std::fs::write(&plain, b"x").unwrap();
    let path = dir.path().join("tree.treelod");
    synthetic(1, &SyntheticOptions::minimal()).write_to_path(&path, Compression::None).unwrap();
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&path), mode(&plain), "umask-respecting mode, not the temporary file's 0600");
}
