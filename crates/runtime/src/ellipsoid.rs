//! Clasen's leaf ellipsoids at run time (Clasen and Prohaska 2011, §5; spec §6.8, §10): which
//! prefix of each cell's ellipsoids an instance draws.
//!
//! Every ellipsoid of one level of a cell shares the interval `[lo, hi) = [e_{k−1}, e_k)` of
//! *metres per pixel*, `e_k` being the size of a pixel at which level `k`'s mean ellipsoid is about
//! 5 px across (the build's business). Records are sorted by `hi`, largest first, per cell, so for
//! one `τ` the ellipsoids with `hi > τ` are a prefix found by binary search, and the vertex shader
//! drops the few of them with `lo > τ` ([`ellipsoid_drawn`]), exactly like impostor planes
//! ([`crate::impostor`]).
//!
//! `τ` is the metres per pixel at the cell's distance (spec §10.1), from the same camera maths that
//! gives the point threshold `τ_p = s_min · mpp` — so `mpp = τ_p / s_min`, Gilet's depth bias
//! included as for points (the block cell at the block centre's distance with `Z_i = 0`) — divided
//! by a quality factor: `τ = mpp / quality`, so a quality of 2 draws the level a camera twice as
//! near would draw.

use glam::{Mat4, Vec3};
use treelod_format::{Container, EllipsoidRecord, Range};

use crate::frame::{Camera, CellPrefix, Frustum, LodSettings, prefix_above, tau_per_metre};

/// Whether an ellipsoid is drawn at `τ` (spec §10): its interval holds `τ`. The WGSL twin is in
/// `vs_ellipsoid`.
#[must_use]
pub fn ellipsoid_drawn(ellipsoid: &EllipsoidRecord, tau: f32) -> bool {
    ellipsoid.lo <= tau && tau < ellipsoid.hi
}

/// One cell holding ellipsoids.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EllipsoidCell {
    /// Index of the cell in the container's `CELLS`.
    pub cell: u32,
    /// Its ellipsoids in the container's `ELLIPSOIDS`.
    pub ellipsoids: Range,
    /// Where `τ` is measured from, model space: the block centre for the block cell, else the
    /// centre of the cell's bounds.
    pub anchor: Vec3,
    /// Whether this is the block cell (`Z_i = 0` for the depth bias).
    pub block_cell: bool,
    /// Where the cell's `hi` values start in [`EllipsoidLod`]'s compact array.
    hi_at: u32,
}

/// One prefix of a cell's ellipsoids to draw.
pub type EllipsoidRange = CellPrefix;

/// What drawing a model's ellipsoids needs of its container, made once.
#[derive(Clone, Debug, PartialEq)]
pub struct EllipsoidLod {
    cells: Vec<EllipsoidCell>,
    hi: Vec<f32>,
    /// A sphere, model space, holding the block and every ellipsoid cell's bounds: culling.
    centre: Vec3,
    radius: f32,
    /// The block's centre and half diagonal, model space: `d_block` and `R` of Gilet's `Z_i`.
    block_centre: Vec3,
    block_radius: f32,
}

impl EllipsoidLod {
    /// The ellipsoids of an open container; `None` if it has none.
    #[must_use]
    pub fn from_container(container: &Container) -> Option<Self> {
        let ellipsoids = container.ellipsoids();
        if ellipsoids.is_empty() {
            return None;
        }
        let block = container.block();
        let (min, max) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        let block_cell = block.grid_cell_count();
        let (mut lo, mut hi) = (min, max);
        let mut lod = Self {
            cells: Vec::new(),
            hi: Vec::new(),
            centre: Vec3::ZERO,
            radius: 0.0,
            block_centre: 0.5 * (min + max),
            block_radius: 0.5 * (max - min).length(),
        };
        for (index, cell) in container.cells().iter().enumerate() {
            // Ranges were checked when the container was opened (spec §9.1).
            let Some(records) = ellipsoids.get(cell.ellipsoids.as_usize()).filter(|r| !r.is_empty()) else {
                continue;
            };
            let (Ok(index_u32), Ok(hi_at)) = (u32::try_from(index), u32::try_from(lod.hi.len())) else { break };
            let (cmin, cmax) = (Vec3::from_array(cell.bounds_min), Vec3::from_array(cell.bounds_max));
            if cmin.is_finite() && cmax.is_finite() {
                lo = lo.min(cmin);
                hi = hi.max(cmax);
            }
            // The cell's bounds hold the centres; the ellipsoids reach out by their radii.
            for e in records {
                let (c, r) = (Vec3::from_array(e.center), Vec3::from_array(e.radii).max_element());
                if c.is_finite() && r.is_finite() {
                    lo = lo.min(c - r);
                    hi = hi.max(c + r);
                }
            }
            let is_block = index == block_cell;
            let anchor = if is_block { lod.block_centre } else { 0.5 * (cmin + cmax) };
            lod.cells.push(EllipsoidCell {
                cell: index_u32,
                ellipsoids: cell.ellipsoids,
                anchor,
                block_cell: is_block,
                hi_at,
            });
            lod.hi.extend(records.iter().map(|e| e.hi));
        }
        lod.centre = 0.5 * (lo + hi);
        lod.radius = 0.5 * (hi - lo).length();
        Some(lod)
    }

    /// The cells holding ellipsoids, in container order.
    #[must_use]
    pub fn cells(&self) -> &[EllipsoidCell] {
        &self.cells
    }

    /// A sphere, model space, holding the block bounds and every ellipsoid: `(centre, radius)`.
    #[must_use]
    pub fn sphere(&self) -> (Vec3, f32) {
        (self.centre, self.radius)
    }

    /// Number of leading ellipsoids of `cell` with `hi > τ` (spec §10).
    #[must_use]
    pub fn prefix(&self, cell: &EllipsoidCell, tau: f32) -> u32 {
        prefix_above(&self.hi, cell.hi_at, cell.ellipsoids.count, tau)
    }

    /// The ellipsoids an instance with world-from-model `transform` draws for `camera`, appended
    /// to `out`: per cell holding ellipsoids, `τ = mpp / quality` with `mpp = d · 2·tan(fovy/2) / H`
    /// (spec §10.1; `d` the distance to the cell's anchor, divided by the transform's largest axis
    /// scale) times Gilet's depth bias `s_min_i / s_min` of `settings` (the point threshold's, so
    /// `mpp = τ_p / s_min`; `Z_i = clamp((d_cell − d_block) / R, −1, 1)`, 0 for the block cell),
    /// and the leading ellipsoids with `hi > τ`. Returns `false`, appending nothing, if the
    /// instance's sphere lies outside `frustum` or the transform is degenerate.
    pub fn select(
        &self,
        transform: Mat4,
        camera: &Camera,
        frustum: &Frustum,
        settings: &LodSettings,
        quality: f32,
        out: &mut Vec<EllipsoidRange>,
    ) -> bool {
        let Some(per_metre) = tau_per_metre(transform, camera, frustum, 1.0, (self.centre, self.radius)) else {
            return false;
        };
        let quality = if quality > 0.0 && quality.is_finite() { quality } else { 1.0 };
        let scale = camera.world_per_pixel() / per_metre;
        let d_block = transform.transform_point3(self.block_centre).distance(camera.position);
        let inv_radius = if self.block_radius > 0.0 { (self.block_radius * scale).recip() } else { 0.0 };
        for cell in &self.cells {
            let d_cell = transform.transform_point3(cell.anchor).distance(camera.position);
            let z = if cell.block_cell { 0.0 } else { ((d_cell - d_block) * inv_radius).clamp(-1.0, 1.0) };
            let bias = if settings.s_min > 0.0 { settings.biased_pixels(z).0 / settings.s_min } else { 1.0 };
            let tau = d_cell * per_metre * bias / quality;
            let count = self.prefix(cell, tau);
            if count > 0 {
                out.push(EllipsoidRange { cell: cell.cell, first: cell.ellipsoids.first, count, tau });
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use treelod_format::{BlockRecord, CellRecord, Compression, ContainerData, Metadata, Source, Tree};

    /// An ellipsoid at `center` of level interval `[lo, hi)` with leaves `leaves`.
    fn ellipsoid(center: [f32; 3], lo: f32, hi: f32, leaves: (u32, u32)) -> EllipsoidRecord {
        EllipsoidRecord {
            center,
            radii: [0.5, 0.3, 0.2],
            orientation: [0, 0, 0, i16::MAX],
            color: 0xff20_8040,
            alpha_threshold: 0.0,
            noise_mip: 2.0,
            lo,
            hi,
            leaf_first: leaves.0,
            leaf_count: leaves.1,
            flags: 0,
        }
    }

    /// A 2×1×1 grid: cell 0 holds two levels of a 4-leaf hierarchy (4 ellipsoids below
    /// `e1 = 0.01`, 1 above), cell 1 none, the block cell one level of 2 ellipsoids below `0.02`
    /// and 1 above; verified.
    fn container() -> Container {
        let e1 = 0.01;
        let cell0 = vec![
            ellipsoid([1.0, 1.0, 1.0], e1, f32::INFINITY, (0, 4)),
            ellipsoid([0.5, 1.0, 1.0], 0.0, e1, (0, 1)),
            ellipsoid([1.5, 1.0, 1.0], 0.0, e1, (1, 1)),
            ellipsoid([1.0, 0.5, 1.0], 0.0, e1, (2, 1)),
            ellipsoid([1.0, 1.5, 1.0], 0.0, e1, (3, 1)),
        ];
        let block = vec![
            ellipsoid([2.0, 1.0, 1.0], 0.02, f32::INFINITY, (0, 2)),
            ellipsoid([1.8, 1.0, 1.0], 0.0, 0.02, (0, 1)),
            ellipsoid([2.2, 1.0, 1.0], 0.0, 0.02, (1, 1)),
        ];
        let cell = |first: u32, n: u32, min: [f32; 3], max: [f32; 3]| CellRecord {
            bounds_min: if n == 0 { [0.0; 3] } else { min },
            bounds_max: if n == 0 { [0.0; 3] } else { max },
            ellipsoids: Range { first, count: n },
            ..CellRecord::default()
        };
        let data = ContainerData {
            metadata: Metadata {
                generator: "test".into(),
                sources: vec![Source::default()],
                trees: vec![Tree::default()],
                ..Metadata::default()
            },
            block: BlockRecord {
                bounds_min: [0.0; 3],
                bounds_max: [4.0, 2.0, 2.0],
                grid: [2, 1, 1],
                tree_count: 1,
                ..BlockRecord::default()
            },
            cells: vec![
                cell(0, 5, [0.5, 0.5, 1.0], [1.5, 1.5, 1.0]),
                cell(5, 0, [0.0; 3], [0.0; 3]),
                cell(5, 3, [1.8, 1.0, 1.0], [2.2, 1.0, 1.0]),
            ],
            ellipsoids: [cell0, block].concat(),
            ..ContainerData::default()
        };
        let container = Container::from_bytes(&data.to_bytes(Compression::None).unwrap()).unwrap();
        treelod_format::verify(&container).expect("a valid container");
        container
    }

    /// The leaves each cell's drawn ellipsoids cover at `τ`.
    fn covered(container: &Container, ranges: &[EllipsoidRange]) -> Vec<(u32, Vec<u32>, usize)> {
        ranges
            .iter()
            .map(|r| {
                let records = &container.ellipsoids()[r.first as usize..(r.first + r.count) as usize];
                let drawn: Vec<&EllipsoidRecord> = records.iter().filter(|e| ellipsoid_drawn(e, r.tau)).collect();
                let mut leaves: Vec<u32> =
                    drawn.iter().flat_map(|e| e.leaf_first..e.leaf_first + e.leaf_count).collect();
                leaves.sort_unstable();
                (r.cell, leaves, drawn.len())
            })
            .collect()
    }

    fn select_at(lod: &EllipsoidLod, distance: f32, settings: &LodSettings, quality: f32) -> Vec<EllipsoidRange> {
        let camera = Camera::look_at(Vec3::new(2.0, 1.0, 1.0 + distance), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
        let mut out = Vec::new();
        assert!(lod.select(
            Mat4::IDENTITY,
            &camera,
            &Frustum::from_view_proj(camera.view_proj),
            settings,
            quality,
            &mut out
        ));
        out
    }

    #[test]
    fn the_prefix_holds_the_level_whose_interval_holds_tau_and_covers_each_leaf_once() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        assert_eq!(lod.cells().iter().map(|c| c.cell).collect::<Vec<_>>(), [0, 2]);
        let (c0, block) = (lod.cells()[0], lod.cells()[1]);
        assert!(block.block_cell && !c0.block_cell);
        // Prefix by hi alone: everything below e1, the root alone from e1 on.
        assert_eq!(lod.prefix(&c0, 0.0), 5);
        assert_eq!(lod.prefix(&c0, 0.009), 5);
        assert_eq!(lod.prefix(&c0, 0.01), 1);
        assert_eq!(lod.prefix(&c0, 1e9), 1);
        assert_eq!(lod.prefix(&block, 0.019), 3);
        assert_eq!(lod.prefix(&block, 0.02), 1);

        let settings = LodSettings::default();
        // mpp at 512 px and fovy 0.8: 0.00165 per metre. 2 m: fine levels everywhere.
        let near = select_at(&lod, 2.0, &settings, 1.0);
        let got = covered(&container, &near);
        assert_eq!(got[0], (0, vec![0, 1, 2, 3], 4), "{near:?}");
        assert_eq!(got[1], (2, vec![0, 1], 2), "{near:?}");
        // 8 m: cell 0 (τ ≈ 0.0137) coarse, the block cell (τ ≈ 0.0132) still fine.
        let mid = select_at(&lod, 8.0, &settings, 1.0);
        let got = covered(&container, &mid);
        assert_eq!(got[0], (0, vec![0, 1, 2, 3], 1), "{mid:?}");
        assert_eq!(got[1], (2, vec![0, 1], 2), "{mid:?}");
        // With quality 2, τ halves: cell 0 is fine again.
        let fine = select_at(&lod, 8.0, &settings, 2.0);
        assert!((fine[0].tau - 0.5 * mid[0].tau).abs() < 1e-7);
        assert_eq!(covered(&container, &fine)[0].2, 4);
        // 20 m: both coarse.
        let far = select_at(&lod, 20.0, &settings, 1.0);
        assert_eq!(covered(&container, &far).iter().map(|c| c.2).collect::<Vec<_>>(), [1, 1]);
        // τ is metres per pixel at the anchor: 2·tan(0.4)/512 per metre.
        let per_metre = 2.0 * 0.4f32.tan() / 512.0;
        let d_block = Vec3::new(2.0, 1.0, 21.0).distance(Vec3::new(2.0, 1.0, 1.0));
        assert!((far[1].tau - d_block * per_metre).abs() < 1e-6 * far[1].tau.max(1.0), "{far:?}");
    }

    #[test]
    fn the_depth_bias_of_points_shifts_the_cells_but_not_the_block_cell() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        let plain = select_at(&lod, 8.0, &LodSettings::default(), 1.0);
        let biased = select_at(&lod, 8.0, &LodSettings { depth_bias_k: 0.5, ..LodSettings::default() }, 1.0);
        // Cell 0 (centre (1, 1, 1)) is as far as the block centre (2, 1, 1) to within its
        // lateral offset: Z_i > 0 slightly, so its τ grows; the block cell's is unchanged.
        assert!(biased[0].tau > plain[0].tau, "{plain:?} {biased:?}");
        assert_eq!(biased[1].tau, plain[1].tau);
        // With the bias, τ = τ_p / s_min: the point threshold's metres per pixel.
        let s = LodSettings { s_min: 2.0, depth_bias_k: 1.0, ..LodSettings::default() };
        let camera = Camera::look_at(Vec3::new(2.0, 1.0, 9.0), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
        let mut out = Vec::new();
        assert!(lod.select(Mat4::IDENTITY, &camera, &Frustum::from_view_proj(camera.view_proj), &s, 1.0, &mut out));
        let d_cell = Vec3::new(1.0, 1.0, 1.0).distance(camera.position);
        let d_block = Vec3::new(2.0, 1.0, 1.0).distance(camera.position);
        let z = ((d_cell - d_block) / (0.5 * Vec3::new(4.0, 2.0, 2.0).length())).clamp(-1.0, 1.0);
        let tau_p = s.biased_pixels(z).0 * d_cell * camera.world_per_pixel();
        assert!((out[0].tau - tau_p / s.s_min).abs() < 1e-6, "{out:?} {tau_p}");
    }

    #[test]
    fn scaled_instances_measure_tau_in_model_units_and_culled_ones_draw_nothing() {
        let container = container();
        let lod = EllipsoidLod::from_container(&container).unwrap();
        let camera = Camera::look_at(Vec3::new(2.0, 1.0, 21.0), Vec3::new(2.0, 1.0, 1.0), 0.8, 512, 512);
        let frustum = Frustum::from_view_proj(camera.view_proj);
        let settings = LodSettings::default();
        let (mut one, mut two) = (Vec::new(), Vec::new());
        assert!(lod.select(Mat4::IDENTITY, &camera, &frustum, &settings, 1.0, &mut one));
        // Twice as large about the block centre: same distance, half the τ in model units.
        let about = Vec3::new(2.0, 1.0, 1.0);
        let scaled =
            Mat4::from_translation(about) * Mat4::from_scale(Vec3::splat(2.0)) * Mat4::from_translation(-about);
        assert!(lod.select(scaled, &camera, &frustum, &settings, 1.0, &mut two));
        assert!((two[1].tau - 0.5 * one[1].tau).abs() < 1e-6, "{one:?} {two:?}");
        // Behind the camera.
        let mut out = Vec::new();
        let away = Mat4::from_translation(Vec3::new(0.0, 0.0, 100.0));
        assert!(!lod.select(away, &camera, &frustum, &settings, 1.0, &mut out));
        assert!(out.is_empty());
        // No ellipsoids: no lod.
        let empty = ContainerData {
            block: BlockRecord { bounds_max: [1.0; 3], grid: [1, 1, 1], tree_count: 1, ..BlockRecord::default() },
            cells: vec![CellRecord::default(); 2],
            ..ContainerData::default()
        };
        let empty = Container::from_bytes(&empty.to_bytes(Compression::None).unwrap()).unwrap();
        assert!(EllipsoidLod::from_container(&empty).is_none());
    }
}
