//! A small deterministic CPU rasteriser of coverage: which pixels of an orthographic view a triangle
//! soup covers, with alpha-tested textures. The build measures image error with it (pruning's
//! Precision and Recall, Neubert et al. 2011 §2.2), so no GPU is needed to build.
//!
//! - **Views** ([`View`]) are orthographic, square, `size` pixels across, fitted to a bounding
//!   sphere: its diameter spans the image. [`view_directions`] gives the standard set: directions
//!   around the vertical axis at 0° elevation over half a turn (the view from the opposite side
//!   is the mirror image), then a ring at 45° elevation (a third of the count) over a full turn,
//!   so no view repeats another's silhouette.
//! - **Sampling**: one sample at each pixel centre `(x + ½, y + ½)`; pixel `(0, 0)` is the top-left
//!   corner of the image, `y` grows downwards. Vertices are snapped to 1/256 pixel and the edge
//!   functions are evaluated exactly in 64-bit integers, with the top-left fill rule (a centre on
//!   an edge belongs to the triangle only if the edge is a top or a left edge), so two triangles
//!   sharing an edge leave no gap and the result is the same on every machine. Both faces are
//!   drawn (coverage does not depend on winding).
//! - **Alpha test**: a triangle with an [`AlphaMask`] covers a pixel only where the texel nearest
//!   to the interpolated UV passes, as the renderer's `fs_triangle` tests the base-colour alpha
//!   (texture alpha times the material's alpha factor) against the cutoff.
//! - **Coverage** is a bit-packed [`Mask`], one `u64` per 64 pixels of a row; images are compared
//!   by the metrics of `treelod_eval::metrics`, defined there once: [`coverage`] counts the
//!   pixel classification (Precision, Recall, `Q`) a word at a time, [`multiscale_rmse`] and
//!   [`multiscale_errors_of_grey`] compute the multi-scale RMSE of coverage in fast passes that
//!   the tests check against that definition.
//!
//! Everything is sequential per image; [`render_views`] runs views in parallel (rayon), each into
//! its own mask, so the result does not depend on the thread count.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use treelod_eval::metrics::{Coverage, Mask as CoverageMask, MultiScaleRmse};

use crate::scene::{AlphaMode, Image, Material};

/// The `alpha` of a [`RasterTriangle`] without alpha test: every covered pixel counts.
pub const NO_ALPHA: u32 = u32::MAX;

/// Sub-pixel precision of snapped vertices: 1/256 pixel.
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: i64 = 1 << SUBPIXEL_BITS;
/// Snapped coordinates are clamped to ±2^24 (±65536 pixels), so edge-function products stay far
/// inside `i64` whatever the input; triangles entirely outside the image are skipped before.
const COORD_LIMIT: f32 = (1u32 << 24) as f32;
/// Largest image side [`Mask::new`] accepts.
pub const MAX_SIZE: u32 = 16_384;

/// A square coverage bitmask: bit `x % 64` of word `y · stride + x / 64` is pixel `(x, y)`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mask {
    size: u32,
    stride: usize,
    words: Vec<u64>,
}

impl Mask {
    /// An empty mask of `size × size` pixels (`size` clamped to `1 ..= MAX_SIZE`).
    #[must_use]
    pub fn new(size: u32) -> Self {
        let size = size.clamp(1, MAX_SIZE);
        let stride = (size as usize).div_ceil(64);
        Self { size, stride, words: vec![0; stride * size as usize] }
    }

    /// Pixels along each side.
    #[must_use]
    pub fn size(&self) -> u32 {
        self.size
    }

    /// Words per row.
    #[must_use]
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The bits, rows top to bottom, `stride` words each; bits past `size` in a row are zero.
    #[must_use]
    pub fn words(&self) -> &[u64] {
        &self.words
    }

    /// Whether pixel `(x, y)` is covered; `false` outside the image.
    #[must_use]
    pub fn get(&self, x: u32, y: u32) -> bool {
        x < self.size && y < self.size && self.words[y as usize * self.stride + x as usize / 64] >> (x % 64) & 1 == 1
    }

    /// Covers pixel `(x, y)`; nothing outside the image.
    pub fn set(&mut self, x: u32, y: u32) {
        if x < self.size && y < self.size {
            self.words[y as usize * self.stride + x as usize / 64] |= 1 << (x % 64);
        }
    }

    /// Covered pixels.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.words.iter().map(|w| u64::from(w.count_ones())).sum()
    }

    /// Makes `self` a copy of `other`, reusing the allocation.
    pub fn copy_from(&mut self, other: &Self) {
        self.size = other.size;
        self.stride = other.stride;
        self.words.clone_from(&other.words);
    }
}

/// The pixel classification of coverage `test` against `reference` ([`Coverage`]: Precision,
/// Recall and `Q` are defined once, in `treelod_eval::metrics`), counted a word of 64 pixels at a
/// time.
///
/// # Panics
/// If the masks differ in size.
#[must_use]
pub fn coverage(test: &Mask, reference: &Mask) -> Coverage {
    assert_eq!(test.size, reference.size, "masks of different sizes");
    let mut c = Coverage::default();
    for (&t, &r) in test.words.iter().zip(&reference.words) {
        c.tp += u64::from((t & r).count_ones());
        c.fp += u64::from((t & !r).count_ones());
        c.fn_ += u64::from((!t & r).count_ones());
    }
    c
}

/// The mask as `treelod_eval`'s [`CoverageMask`] of flags, for checking the fast paths here
/// against the metrics' definitions.
#[must_use]
pub fn to_flags(mask: &Mask) -> CoverageMask {
    let n = mask.size;
    let covered = (0..n).flat_map(|y| (0..n).map(move |x| (x, y))).map(|(x, y)| mask.get(x, y)).collect();
    CoverageMask { width: n, height: n, covered }
}

/// The alpha test of one material: a bit per texel of its base-colour image, set where the texel
/// passes (texel alpha × the material's alpha factor ≥ cutoff).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AlphaMask {
    width: u32,
    height: u32,
    bits: Vec<u64>,
}

impl AlphaMask {
    /// The alpha test of `material` with its base-colour `image` as the renderer applies it:
    /// `None` for an opaque material (nothing is tested); `MASK` against the material's cutoff;
    /// `BLEND` as a mask at 0.5. A material without image tests its alpha factor alone (a 1 × 1
    /// mask). Vertex-colour alpha is not taken into account.
    #[must_use]
    pub fn for_material(material: &Material, image: Option<&Image>) -> Option<Self> {
        let cutoff = match material.alpha_mode {
            AlphaMode::Opaque => return None,
            AlphaMode::Mask => material.alpha_cutoff,
            AlphaMode::Blend => 0.5,
        };
        let factor = material.base_color[3];
        Some(match image {
            Some(image) => Self::from_image(image, factor, cutoff),
            None => Self { width: 1, height: 1, bits: vec![u64::from(factor >= cutoff)] },
        })
    }

    /// The texels of `image` whose alpha times `factor` is at least `cutoff`.
    #[must_use]
    pub fn from_image(image: &Image, factor: f32, cutoff: f32) -> Self {
        let (width, height) = (image.width.max(1), image.height.max(1));
        let n = width as usize * height as usize;
        let mut bits = vec![0u64; n.div_ceil(64)];
        for (i, word) in bits.iter_mut().enumerate() {
            for b in 0..64 {
                let t = i * 64 + b;
                if t >= n {
                    break;
                }
                // A short texel array (a malformed image) reads as opaque, as `Image::texel` does.
                let alpha = image.rgba.get(t * 4 + 3).copied().unwrap_or(255);
                if f32::from(alpha) / 255.0 * factor >= cutoff {
                    *word |= 1 << b;
                }
            }
        }
        Self { width, height, bits }
    }

    /// Whether the texel nearest to `uv` passes; UVs wrap (glTF's default `REPEAT`), as in
    /// [`Image::texel`].
    #[must_use]
    pub fn passes(&self, uv: Vec2) -> bool {
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        let (x, y) = (floor_i64(uv.x * self.width as f32), floor_i64(uv.y * self.height as f32));
        // Most coordinates lie in the texture: no division for those.
        let x = if (0..w).contains(&x) { x } else { x.rem_euclid(w) };
        let y = if (0..h).contains(&y) { y } else { y.rem_euclid(h) };
        #[expect(clippy::cast_sign_loss, clippy::cast_possible_truncation, reason = "wrapped into 0..w·h")]
        let t = (y * w + x) as usize;
        self.bits[t / 64] >> (t % 64) & 1 == 1
    }

    /// Texels across and down.
    #[must_use]
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The fraction of texels that pass.
    #[must_use]
    pub fn opaque_fraction(&self) -> f32 {
        let n = self.width as usize * self.height as usize;
        self.bits.iter().map(|w| w.count_ones() as usize).sum::<usize>() as f32 / n as f32
    }
}

/// One triangle of a soup to rasterise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RasterTriangle {
    /// Corners, metres.
    pub positions: [Vec3; 3],
    /// Texture coordinates of the corners (ignored without alpha test).
    pub uvs: [Vec2; 3],
    /// Index into the alpha masks, or [`NO_ALPHA`].
    pub alpha: u32,
}

/// An orthographic view fitted to a sphere: the sphere's diameter spans the `size`-pixel image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Unit vector from the model towards the viewer.
    pub direction: Vec3,
    /// Image `x` axis in model space (unit).
    pub right: Vec3,
    /// Image up axis in model space (unit; image `y` grows the other way).
    pub up: Vec3,
    /// The model-space point at the image centre.
    pub centre: Vec3,
    /// Pixels per metre.
    pub scale: f32,
    /// Pixels along each side.
    pub size: u32,
}

impl View {
    /// The view from `direction` (towards the viewer; need not be unit) of the sphere `centre`,
    /// `radius`, at `size × size` pixels. Up is +Y projected into the image plane (for a view
    /// along the vertical, −Z). A zero direction looks along −Z; a zero or non-finite radius
    /// counts as 1 mm.
    #[must_use]
    pub fn fit(direction: Vec3, centre: Vec3, radius: f32, size: u32) -> Self {
        let direction = direction.normalize_or(Vec3::Z);
        let reference = if direction.y.abs() > 0.999 { Vec3::NEG_Z * direction.y.signum() } else { Vec3::Y };
        let right = reference.cross(direction).normalize_or(Vec3::X);
        let up = direction.cross(right);
        let radius = if radius.is_finite() && radius > 1e-3 { radius } else { 1e-3 };
        let size = size.clamp(1, MAX_SIZE);
        Self { direction, right, up, centre, scale: size as f32 / (2.0 * radius), size }
    }

    /// The same view with what it shows turned by `radians` counter-clockwise on the image (the
    /// camera rolled about its direction): the calibration's views straight down, which see the
    /// crown through several turns of the pixel grid.
    #[must_use]
    pub fn rolled(self, radians: f32) -> Self {
        if radians == 0.0 {
            return self;
        }
        let (s, c) = radians.sin_cos();
        let (right, up) = (self.right * c - self.up * s, self.up * c + self.right * s);
        Self { right, up, ..self }
    }

    /// Pixel coordinates of a model-space point (`x` right, `y` down, pixel centres at `+½`).
    #[must_use]
    pub fn project(&self, p: Vec3) -> Vec2 {
        let d = p - self.centre;
        let half = 0.5 * self.size as f32;
        Vec2::new(half + d.dot(self.right) * self.scale, half - d.dot(self.up) * self.scale)
    }

    /// [`Self::project`] of the corners of [`CHUNK`] triangles at once, with whether each may
    /// hold a pixel centre of a `size × size` image: `corners[3·c + a]` holds axis `a` (x, y, z)
    /// of corner `c` of every triangle of the chunk (a padding triangle of NaN corners holds
    /// none). The arithmetic is [`Self::project`]'s and `Setup::new`'s tests before snapping,
    /// term for term, so a triangle marked as holding none is one [`triangle_pixels`] visits no
    /// pixel of, and the corners are the same floats; written a lane per triangle, without
    /// branches, so that the compiler runs the lanes side by side in vector registers. Most
    /// triangles of a large tree drawn in a small image hold no pixel centre, and testing them
    /// one at a time was most of what the calibration's small views cost (spec §6.15).
    #[expect(clippy::cast_precision_loss, reason = "an image side")]
    #[expect(clippy::needless_range_loop, reason = "lane `j` of nine arrays and three outputs")]
    pub fn project_chunk(&self, size: u32, corners: [&[f32; CHUNK]; 9], out: &mut ProjectedChunk) {
        let half = 0.5 * self.size as f32;
        let side = size as f32;
        let (c, r, u, scale) = (self.centre, self.right, self.up, self.scale);
        for j in 0..CHUNK {
            let mut x = [0.0f32; 3];
            let mut y = [0.0f32; 3];
            for k in 0..3 {
                let (dx, dy, dz) = (corners[3 * k][j] - c.x, corners[3 * k + 1][j] - c.y, corners[3 * k + 2][j] - c.z);
                // `Vec3::dot`'s order: (x·x + y·y) + z·z.
                x[k] = half + (dx * r.x + dy * r.y + dz * r.z) * scale;
                y[k] = half - (dx * u.x + dy * u.y + dz * u.z) * scale;
                out.x[k][j] = x[k];
                out.y[k][j] = y[k];
            }
            // The box as `Setup::new` takes it, corner 0, then 1, then 2 (glam's `min` and `max`
            // compare and select: `f32::min` and `max` answer otherwise where a corner is NaN).
            let p = [Vec2::new(x[0], y[0]), Vec2::new(x[1], y[1]), Vec2::new(x[2], y[2])];
            let (min, max) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
            out.may_hold[j] = !rejected_before_snapping(side, min, max);
        }
    }
}

/// Triangles projected at a time by [`View::project_chunk`].
pub const CHUNK: usize = 64;

/// A chunk of triangles projected by [`View::project_chunk`]: per corner and triangle its pixel
/// coordinates, and per triangle whether it may hold a pixel centre.
#[derive(Clone, Debug)]
pub struct ProjectedChunk {
    /// `x[c][j]`: the `x` of corner `c` of triangle `j`.
    pub x: [[f32; CHUNK]; 3],
    /// `y[c][j]`: the `y` of corner `c` of triangle `j`.
    pub y: [[f32; CHUNK]; 3],
    /// Whether triangle `j` may hold a pixel centre (else [`triangle_pixels`] visits none).
    pub may_hold: [bool; CHUNK],
}

impl Default for ProjectedChunk {
    fn default() -> Self {
        Self { x: [[0.0; CHUNK]; 3], y: [[0.0; CHUNK]; 3], may_hold: [false; CHUNK] }
    }
}

impl ProjectedChunk {
    /// The pixel corners of triangle `j`.
    #[must_use]
    pub fn corners(&self, j: usize) -> [Vec2; 3] {
        [
            Vec2::new(self.x[0][j], self.y[0][j]),
            Vec2::new(self.x[1][j], self.y[1][j]),
            Vec2::new(self.x[2][j], self.y[2][j]),
        ]
    }
}

/// `count` unit view directions (towards the viewer): `ceil(2·count/3)` around the vertical
/// axis at 0° elevation, spread over half a turn starting at +Z (an orthographic view from the
/// opposite side sees the mirror image, the same coverage), then the rest at 45° elevation over a
/// full turn, offset by half their step. 8 gives 6 horizontal views 30° apart and 2 from above.
#[must_use]
pub fn view_directions(count: usize) -> Vec<Vec3> {
    let horizontal = (2 * count).div_ceil(3);
    let elevated = count - horizontal;
    let ring = |n: usize, elevation: f32, turn: f32, offset: f32| {
        (0..n).map(move |k| {
            let azimuth = turn * (k as f32 + offset) / n as f32;
            let (s, c) = azimuth.sin_cos();
            Vec3::new(elevation.cos() * s, elevation.sin(), elevation.cos() * c)
        })
    };
    let (half, full) = (std::f32::consts::PI, std::f32::consts::TAU);
    ring(horizontal, 0.0, half, 0.0).chain(ring(elevated, std::f32::consts::FRAC_PI_4, full, 0.5)).collect()
}

/// A sphere holding `points`: the centre of their bounding box and the largest distance from it.
/// `(ZERO, 0)` for no (finite) points.
#[must_use]
pub fn bounding_sphere(points: impl Iterator<Item = Vec3> + Clone) -> (Vec3, f32) {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in points.clone().filter(|p| p.is_finite()) {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    if lo.x > hi.x {
        return (Vec3::ZERO, 0.0);
    }
    let centre = 0.5 * (lo + hi);
    let radius = points.filter(|p| p.is_finite()).map(|p| p.distance(centre)).fold(0.0, f32::max);
    (centre, radius)
}

/// Covers the pixels of the triangle with corners `p` (pixel coordinates, as [`View::project`])
/// whose centres it holds, after the alpha test with `alpha` at the interpolated `uv`. Pixels
/// already covered are not tested again.
pub fn fill_triangle(mask: &mut Mask, p: [Vec2; 3], uv: [Vec2; 3], alpha: Option<&AlphaMask>) {
    let Some(Setup { x0, x1, y0, y1, area, swapped, edges }) = Setup::new(mask.size, p) else { return };
    let mut uv = uv;
    if swapped {
        uv.swap(1, 2);
    }
    // Along a row each edge function changes by `slope` per pixel; `inverse` estimates where it
    // crosses zero without an integer division, and the estimate is corrected exactly below.
    let slope = edges.map(|e| -e.dy * SUBPIXEL);
    #[expect(clippy::cast_precision_loss, reason = "an estimate, corrected exactly")]
    let inverse = slope.map(|s| if s == 0 { 0.0 } else { 1.0 / s as f64 });
    let mut row_start = [edges[0].at(x0, y0), edges[1].at(x0, y0), edges[2].at(x0, y0)];
    let width = x1 - x0;
    #[expect(clippy::cast_precision_loss, reason = "barycentric weights need no more")]
    let inv_area = 1.0 / area as f32;
    let stride = mask.stride;
    for y in y0..=y1 {
        let at_x0 = row_start;
        for k in 0..3 {
            row_start[k] += edges[k].dx * SUBPIXEL;
        }
        // The row's span: each edge bounds x on one side (exact, with the estimate corrected).
        let (mut lo, mut hi) = (0i64, width);
        for k in 0..3 {
            let (w, s) = (at_x0[k], slope[k]);
            if s > 0 {
                if w < 0 {
                    // The first t with w + t·s ≥ 0.
                    #[expect(clippy::cast_precision_loss, reason = "an estimate, corrected exactly")]
                    let mut t = ceil_f64(-w as f64 * inverse[k]).clamp(0, width + 1);
                    if w + t * s < 0 {
                        t += 1;
                    } else if t > 0 && w + (t - 1) * s >= 0 {
                        t -= 1;
                    }
                    lo = lo.max(t);
                }
            } else if s < 0 {
                if w < 0 {
                    hi = -1;
                } else {
                    // The last t with w + t·s ≥ 0.
                    #[expect(clippy::cast_precision_loss, reason = "an estimate, corrected exactly")]
                    let mut t = floor_f64(w as f64 * -inverse[k]).clamp(0, width + 1);
                    if w + t * s < 0 {
                        t -= 1;
                    } else if w + (t + 1) * s >= 0 {
                        t += 1;
                    }
                    hi = hi.min(t);
                }
            } else if w < 0 {
                hi = -1;
            }
        }
        if lo > hi {
            continue;
        }
        #[expect(clippy::cast_sign_loss, clippy::cast_possible_truncation, reason = "0 <= x0 + lo <= x0 + hi < size")]
        let (row, first_x, last_x) = (y as usize * stride, (x0 + lo) as usize, (x0 + hi) as usize);
        for word in first_x / 64..=last_x / 64 {
            let first = if word == first_x / 64 { first_x % 64 } else { 0 };
            let last = if word == last_x / 64 { last_x % 64 } else { 63 };
            let span = (u64::MAX >> (63 - last)) & (u64::MAX << first);
            let slot = &mut mask.words[row + word];
            let Some(alpha) = alpha else {
                *slot |= span;
                continue;
            };
            // Only pixels not yet covered need the alpha test.
            let mut todo = span & !*slot;
            while todo != 0 {
                let bit = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                #[expect(clippy::cast_possible_wrap, reason = "x < size <= 16384")]
                let t = (word * 64 + bit) as i64 - x0;
                let (w0, w1) = (at_x0[0] + slope[0] * t, at_x0[1] + slope[1] * t);
                // Barycentrics from the biased edge values: off by 1/2^16 pixel at most.
                #[expect(clippy::cast_precision_loss, reason = "barycentric weights need no more")]
                let (b0, b1) = (w0 as f32 * inv_area, w1 as f32 * inv_area);
                if alpha.passes(uv[0] * b0 + uv[1] * b1 + uv[2] * (1.0 - b0 - b1)) {
                    *slot |= 1 << bit;
                }
            }
        }
    }
}

/// Calls `pixel(x, y, b)` for every pixel of a `size × size` image whose centre the triangle
/// with corners `p` (pixel coordinates) holds, by [`fill_triangle`]'s rule (corners snapped to
/// 1/256 pixel, exact edge functions, the top-left rule), so it visits the pixels that
/// `fill_triangle` without alpha test covers; `b` holds the barycentric weights of `p[0]`,
/// `p[1]` and `p[2]` at the centre. Rows top to bottom, left to right.
pub fn triangle_pixels(size: u32, p: [Vec2; 3], mut pixel: impl FnMut(usize, usize, [f32; 3])) {
    let Some(Setup { x0, x1, y0, y1, area, swapped, edges }) = Setup::new(size, p) else { return };
    // `order[k]`: the input corner at snapped corner `k`.
    let order = if swapped { [0, 2, 1] } else { [0, 1, 2] };
    #[expect(clippy::cast_precision_loss, reason = "barycentric weights need no more")]
    let inv_area = 1.0 / area as f32;
    for y in y0..=y1 {
        let mut w = [edges[0].at(x0, y), edges[1].at(x0, y), edges[2].at(x0, y)];
        for x in x0..=x1 {
            if w[0] >= 0 && w[1] >= 0 && w[2] >= 0 {
                let mut b = [0.0; 3];
                for k in 0..3 {
                    #[expect(clippy::cast_precision_loss, reason = "barycentric weights need no more")]
                    let weight = w[k] as f32 * inv_area;
                    b[order[k]] = weight;
                }
                #[expect(clippy::cast_sign_loss, clippy::cast_possible_truncation, reason = "0 <= x, y < size")]
                pixel(x as usize, y as usize, b);
            }
            for k in 0..3 {
                w[k] -= edges[k].dy * SUBPIXEL;
            }
        }
    }
}

/// A triangle snapped for rasterising into a `size × size` image: the pixel box whose centres
/// it may hold, its doubled area in fixed point (positive), whether corners 1 and 2 were swapped
/// to make it so, and its edges with the top-left rule.
struct Setup {
    x0: i64,
    x1: i64,
    y0: i64,
    y1: i64,
    area: i64,
    swapped: bool,
    edges: [Edge; 3],
}

impl Setup {
    /// `None` for a triangle entirely outside the image, not finite, or without area.
    fn new(size: u32, p: [Vec2; 3]) -> Option<Self> {
        let side = size as f32;
        // Entirely outside the image, or not finite: nothing to do.
        let (min, max) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        if rejected_before_snapping(side, min, max) {
            return None;
        }
        let corner = |q: Vec2| (snap(q.x), snap(q.y));
        let mut v = [corner(p[0]), corner(p[1]), corner(p[2])];
        // Pixel centres inside the snapped box: x·256 + 128 ∈ [min, max] (shifts divide by 256,
        // rounding down).
        let half = SUBPIXEL / 2;
        let last = i64::from(size) - 1;
        let (x0, x1) = (
            (-((half - v[0].0.min(v[1].0).min(v[2].0)) >> SUBPIXEL_BITS)).max(0),
            ((v[0].0.max(v[1].0).max(v[2].0) - half) >> SUBPIXEL_BITS).min(last),
        );
        let (y0, y1) = (
            (-((half - v[0].1.min(v[1].1).min(v[2].1)) >> SUBPIXEL_BITS)).max(0),
            ((v[0].1.max(v[1].1).max(v[2].1) - half) >> SUBPIXEL_BITS).min(last),
        );
        if x0 > x1 || y0 > y1 {
            return None;
        }
        let mut area = (v[1].0 - v[0].0) * (v[2].1 - v[0].1) - (v[1].1 - v[0].1) * (v[2].0 - v[0].0);
        if area == 0 {
            return None;
        }
        let swapped = area < 0;
        if swapped {
            v.swap(1, 2);
            area = -area;
        }
        // Edge k runs from v[k+1] to v[k+2], opposite corner k; inside where all edge functions
        // are positive, or zero on a top or left edge (y down: an edge going up, or a horizontal
        // edge going right), which the bias of −1 on the other edges turns into "≥ 0" everywhere.
        let edges: [Edge; 3] = core::array::from_fn(|k| {
            let (a, b) = (v[(k + 1) % 3], v[(k + 2) % 3]);
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let top_left = dy < 0 || (dy == 0 && dx > 0);
            Edge { a, dx, dy, bias: if top_left { 0 } else { -1 } }
        });
        Some(Self { x0, x1, y0, y1, area, swapped, edges })
    }
}

/// How far past a box [`holds_no_centre`] looks for a pixel centre, pixels: more than snapping
/// moves a corner (half of 1/256 pixel, and the rounding of `v·256 + 0.5`, at most 1/4096 pixel
/// within [`NO_CENTRE_REACH`]) plus the rounding of the test's own sums (at most 1/1024 pixel
/// there).
const NO_CENTRE_MARGIN: f32 = 1.0 / 64.0;

/// The coordinates, pixels, within which [`holds_no_centre`] tests a box (beyond them it answers
/// `false` and the snapped test decides).
const NO_CENTRE_REACH: f32 = 4096.0;

/// Whether the box `min..max` (pixel coordinates) is sure to hold no pixel centre once its
/// corners are snapped: along x or y no `k + 0.5` lies within it, even widened by
/// [`NO_CENTRE_MARGIN`]. A test in floats before snapping, for the triangles far smaller than a
/// pixel that make most of a large tree drawn in a small image; it answers `true` only where the
/// snapped box holds no centre either (so [`Setup::new`] returns what it would without it).
fn holds_no_centre(min: Vec2, max: Vec2) -> bool {
    let within =
        (min.x > -NO_CENTRE_REACH) & (min.y > -NO_CENTRE_REACH) & (max.x < NO_CENTRE_REACH) & (max.y < NO_CENTRE_REACH);
    // The last centre at or before `hi` (widened) is before `lo` (widened); the floors are exact
    // in floats within the reach ([`floor_small`]).
    let gap = |lo: f32, hi: f32| floor_small(hi - 0.5 + NO_CENTRE_MARGIN) < lo - 0.5 - NO_CENTRE_MARGIN;
    within & (gap(min.x, max.x) | gap(min.y, max.y))
}

/// Whether [`Setup::new`] rejects the box `min..max` (pixel coordinates) of a triangle before
/// snapping its corners: entirely outside a `side × side` image or not finite, or sure to hold
/// no pixel centre ([`holds_no_centre`]). Without branches, so that [`View::project_chunk`]'s
/// lanes run it side by side in vector registers; `Setup::new` asks the same of one triangle.
#[inline(always)]
fn rejected_before_snapping(side: f32, min: Vec2, max: Vec2) -> bool {
    let outside = !((max.x >= 0.0) & (max.y >= 0.0) & (min.x <= side) & (min.y <= side));
    outside | holds_no_centre(min, max)
}

/// A pixel coordinate in fixed point: the nearest multiple of 1/256 pixel, clamped to ±2^24.
fn snap(v: f32) -> i64 {
    floor_i64((v * SUBPIXEL as f32).clamp(-COORD_LIMIT, COORD_LIMIT) + 0.5)
}

/// `floor(v)` as an integer without a libm call (saturating; NaN gives 0).
#[expect(clippy::cast_possible_truncation, clippy::cast_precision_loss, reason = "saturating conversion")]
fn floor_i64(v: f32) -> i64 {
    let i = v as i64;
    if (i as f32) > v { i.saturating_sub(1) } else { i }
}

/// `floor(v)` in floats alone, exact for `|v| ≤ 2²²` ([`floor_i64`]'s value there; beyond it
/// not, and [`holds_no_centre`] does not read it there): adding `1.5·2²³` rounds `v` to the
/// nearest integer, which is one more than the floor where it lies above `v`. Branch-free, so
/// the compiler runs it in vector lanes.
fn floor_small(v: f32) -> f32 {
    const ROUND: f32 = 12_582_912.0;
    let nearest = (v + ROUND) - ROUND;
    if nearest > v { nearest - 1.0 } else { nearest }
}

/// `floor(v)` of an `f64` as an integer (saturating).
#[expect(clippy::cast_possible_truncation, clippy::cast_precision_loss, reason = "saturating conversion")]
pub(crate) fn floor_f64(v: f64) -> i64 {
    let i = v as i64;
    if (i as f64) > v { i.saturating_sub(1) } else { i }
}

/// `ceil(v)` of an `f64` as an integer (saturating).
#[expect(clippy::cast_possible_truncation, clippy::cast_precision_loss, reason = "saturating conversion")]
fn ceil_f64(v: f64) -> i64 {
    let i = v as i64;
    if (i as f64) < v { i.saturating_add(1) } else { i }
}

/// One edge of a snapped triangle (fixed point, [`SUBPIXEL`] units).
#[derive(Clone, Copy)]
struct Edge {
    /// Start.
    a: (i64, i64),
    dx: i64,
    dy: i64,
    /// 0 on a top or left edge, −1 on the others (the fill rule).
    bias: i64,
}

impl Edge {
    /// The biased edge function at the centre of pixel `(x, y)`: `≥ 0` on the inner side.
    fn at(&self, x: i64, y: i64) -> i64 {
        let half = SUBPIXEL / 2;
        self.dx * (y * SUBPIXEL + half - self.a.1) - self.dy * (x * SUBPIXEL + half - self.a.0) + self.bias
    }
}

/// Rasterises `triangles` into `mask` as seen from `view` (the mask's size should be the view's).
/// A triangle whose `alpha` is not an index into `alphas` is drawn without alpha test.
pub fn rasterize(mask: &mut Mask, view: &View, triangles: &[RasterTriangle], alphas: &[AlphaMask]) {
    for t in triangles {
        let alpha = alphas.get(t.alpha as usize);
        // Written out: `map` here was a call per corner (its closure not inlined).
        let [a, b, c] = t.positions;
        fill_triangle(mask, [view.project(a), view.project(b), view.project(c)], t.uvs, alpha);
    }
}

/// The coverage of `triangles` from each view, in view order (views in parallel; the result is
/// the same for any number of threads).
#[must_use]
pub fn render_views(views: &[View], triangles: &[RasterTriangle], alphas: &[AlphaMask]) -> Vec<Mask> {
    views
        .par_iter()
        .map(|view| {
            let mut mask = Mask::new(view.size);
            rasterize(&mut mask, view, triangles, alphas);
            mask
        })
        .collect()
}

/// The orthographic projection of the ellipsoid `{centre + Σ u_i·axes[i] : |u| ≤ 1}` (`axes`
/// its three semi-axis vectors, metres, mutually orthogonal or not) in `view`: the ellipse's
/// centre in pixels ([`View::project`]) and its 2 × 2 matrix `M = Σ (P a_i)(P a_i)ᵀ` as
/// `[m_xx, m_xy, m_yy]`, pixels², `P` the view's map to pixels (`x` right, `y` down). The ellipse
/// is `{p : (p − c)ᵀ M⁻¹ (p − c) ≤ 1}`: the image of the unit ball under `P·A` is the ellipse of
/// `P A (P A)ᵀ`, which for `A = R·diag(r)` is `P R diag(r²) Rᵀ Pᵀ`.
#[must_use]
pub fn project_ellipsoid(view: &View, centre: Vec3, axes: [Vec3; 3]) -> (Vec2, [f64; 3]) {
    let scale = f64::from(view.scale);
    let mut m = [0.0f64; 3];
    for a in axes {
        let x = f64::from(a.dot(view.right)) * scale;
        let y = -f64::from(a.dot(view.up)) * scale;
        m[0] += x * x;
        m[1] += x * y;
        m[2] += y * y;
    }
    (view.project(centre), m)
}

/// Covers the pixels whose centres lie in the ellipse `{p : (p − c)ᵀ M⁻¹ (p − c) ≤ 1}` (`m` =
/// `[m_xx, m_xy, m_yy]`, pixels², as [`project_ellipsoid`] gives it). Row by row: the slice of
/// the ellipse at height `dy` from its centre is centred at `dx = m_xy/m_yy·dy` with half-width
/// `sqrt(det M / m_yy · (1 − dy²/m_yy))`. An ellipse thinner than rounding (`m_yy` or `det M`
/// not positive) covers at most the centres on its segment, none in practice: a flat disc seen
/// edge-on covers nothing, as in a renderer.
pub fn fill_ellipse(mask: &mut Mask, centre: Vec2, m: [f64; 3]) {
    let stride = mask.stride;
    let words = &mut mask.words;
    ellipse_spans(mask.size, centre, m, |y, first_x, last_x| {
        let row = y * stride;
        for word in first_x / 64..=last_x / 64 {
            let first = if word == first_x / 64 { first_x % 64 } else { 0 };
            let end = if word == last_x / 64 { last_x % 64 } else { 63 };
            words[row + word] |= (u64::MAX >> (63 - end)) & (u64::MAX << first);
        }
    });
}

/// The spans `(y, x0, x1)` (inclusive) of the pixels of a `size × size` image whose centres lie
/// in the ellipse of [`fill_ellipse`], row by row.
pub fn ellipse_spans(size: u32, centre: Vec2, m: [f64; 3], mut span: impl FnMut(usize, usize, usize)) {
    let [a, b, c] = m;
    let det = a * c - b * b;
    if !(c > 0.0 && a > 0.0 && det.is_finite() && centre.is_finite()) {
        return;
    }
    let det = det.max(0.0);
    let (cx, cy) = (f64::from(centre.x), f64::from(centre.y));
    let half_height = c.sqrt();
    let width = f64::from(size);
    let (y0, y1) =
        (ceil_f64(cy - half_height - 0.5).max(0), floor_f64(cy + half_height - 0.5).min(i64::from(size) - 1));
    let last = i64::from(size) - 1;
    for y in y0..=y1 {
        #[expect(clippy::cast_precision_loss, reason = "a pixel row")]
        let dy = y as f64 + 0.5 - cy;
        let t = 1.0 - dy * dy / c;
        if t < 0.0 {
            continue;
        }
        let mid = cx + b / c * dy;
        let half = (det / c * t).sqrt();
        if mid + half < 0.0 || mid - half > width {
            continue;
        }
        let (x0, x1) = (ceil_f64(mid - half - 0.5).max(0), floor_f64(mid + half - 0.5).min(last));
        if x0 > x1 {
            continue;
        }
        #[expect(clippy::cast_sign_loss, clippy::cast_possible_truncation, reason = "0 <= x0 <= x1 < size")]
        span(y as usize, x0 as usize, x1 as usize);
    }
}

/// Texels along a side of a face of the renderer's noise cube at its finest level
/// (`crates/treelod-render/src/noise.rs` `NOISE_SIZE`).
pub const NOISE_SIZE: u32 = 64;

/// The renderer's noise cube (`crates/treelod-render/src/noise.rs`): the grey value, `0 ..= 255`, of
/// the texel of mip `level` (`NOISE_SIZE >> level` texels per side) that the direction `d`
/// (need not be unit) samples with the nearest texel (the cube-map face and `(s, t)` rules of
/// Vulkan and WebGPU: the face of `d`'s largest component, `+X −X +Y −Y +Z −Z` = 0..5). The same
/// hash as the renderer's texels, so the build sees the holes the renderer cuts.
#[must_use]
pub fn noise_grey(d: Vec3, level: u32) -> u8 {
    let (table, offsets) = noise_table();
    let level = level.min(NOISE_SIZE.ilog2());
    noise_lookup(&table[offsets[level as usize]..], NOISE_SIZE >> level, d)
}

/// The random unit vector of the noise cube's texel that `d` samples at mip `level`, as the
/// renderer reads it from the texel's RGB ([`noise_grey`]'s texel).
#[must_use]
pub fn noise_vector(d: Vec3, level: u32) -> Vec3 {
    let (_, offsets) = noise_table();
    let level = level.min(NOISE_SIZE.ilog2());
    noise_vectors()[offsets[level as usize] + noise_index(NOISE_SIZE >> level, d)]
}

/// [`noise_grey`] in one level's texels (`side` per face side).
#[inline]
fn noise_lookup(texels: &[u8], side: u32, d: Vec3) -> u8 {
    texels[noise_index(side, d)]
}

/// The index within a level of the texel the direction `d` samples ([`noise_grey`]).
#[inline]
fn noise_index(side: u32, d: Vec3) -> usize {
    let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
    let (face, sc, tc, ma) = if ax >= ay && ax >= az {
        if d.x >= 0.0 { (0u32, -d.z, -d.y, ax) } else { (1, d.z, -d.y, ax) }
    } else if ay >= az {
        if d.y >= 0.0 { (2, d.x, d.z, ay) } else { (3, d.x, -d.z, ay) }
    } else if d.z >= 0.0 {
        (4, d.x, -d.y, az)
    } else {
        (5, -d.x, -d.y, az)
    };
    let ma = ma.max(1e-30);
    #[expect(clippy::cast_precision_loss, reason = "at most 64")]
    let half = 0.5 * side as f32 / ma;
    // Truncation is the floor here (negative values saturate to 0).
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped into the face")]
    let texel = |v: f32| (((v + ma) * half) as u32).min(side - 1);
    (face * side * side + texel(tc) * side + texel(sc)) as usize
}

/// The random unit vectors of the noise cube's texels as the renderer stores them (RGB bytes
/// `(n + 1) / 2`, read back as `2·byte/255 − 1`), in the order of [`noise_table`]'s grey values.
fn noise_vectors() -> &'static [Vec3] {
    static TABLE: std::sync::OnceLock<Vec<Vec3>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut vectors = Vec::new();
        for level in 0..=NOISE_SIZE.ilog2() {
            let side = NOISE_SIZE >> level;
            for face in 0..6u32 {
                for i in 0..side * side {
                    let mut h = noise_mix((u64::from(level) << 40) ^ (u64::from(face) << 32) ^ u64::from(i));
                    let mut unit = || {
                        h = noise_mix(h);
                        (h >> 40) as f32 / (1u64 << 24) as f32
                    };
                    let z = 2.0 * unit() - 1.0;
                    let angle = std::f32::consts::TAU * unit();
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "rounded into 0..=255")]
                    let byte = |v: f32| f32::from(((v * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8);
                    let n = Vec3::new(byte(r * angle.cos()), byte(r * angle.sin()), byte(z));
                    vectors.push(n / 255.0 * 2.0 - Vec3::ONE);
                }
            }
        }
        vectors
    })
}

/// The grey values of the noise cube, level by level, face by face, row by row (texel `i` of
/// face `f` at level `l` at `offsets[l] + f·side² + i`), hashed as the renderer hashes them.
fn noise_table() -> &'static (Vec<u8>, Vec<usize>) {
    static TABLE: std::sync::OnceLock<(Vec<u8>, Vec<usize>)> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let (mut table, mut offsets) = (Vec::new(), Vec::new());
        for level in 0..=NOISE_SIZE.ilog2() {
            offsets.push(table.len());
            let side = NOISE_SIZE >> level;
            for face in 0..6u32 {
                for i in 0..side * side {
                    let mut h = noise_mix((u64::from(level) << 40) ^ (u64::from(face) << 32) ^ u64::from(i));
                    // The renderer draws a random unit vector (two values) before the grey value.
                    for _ in 0..3 {
                        h = noise_mix(h);
                    }
                    table.push((h >> 56).to_le_bytes()[0]);
                }
            }
        }
        (table, offsets)
    })
}

/// One SplitMix64 step from `x`: the hash the renderer's noise chains over its texels.
fn noise_mix(x: u64) -> u64 {
    crate::rng::SplitMix64(x).next_u64()
}

/// The ellipsoid `{centre + Σ u_i·axes[i] : |u| ≤ 1}` (`axes` orthogonal, as a record's frame)
/// drawn as the renderer's `fs_ellipsoid` draws it, into `grey` (`size × size`, rows top to
/// bottom): each pixel of its projection ([`fill_ellipse`]'s pixels) is hit on the front surface
/// only (the nearer root of the ray; a hole shows what lies behind, never the ellipsoid's back),
/// at the local direction `u` of the hit, and gets the grey value `g` of the noise cube's texel of
/// mip `level` there ([`noise_grey`]). `grey` keeps per pixel `1 +` the largest `g` of the
/// ellipsoids drawn over it (0: none), so the pixel is covered under the alpha threshold `t`
/// (holes where `g / 255 < t`) if `grey ≥ 1 + ⌈255·t⌉` ([`noise_cut`]).
///
/// # Panics
/// If `grey` is not `view.size²` long.
pub fn fill_ellipsoid_noise(grey: &mut [u16], view: &View, centre: Vec3, axes: [Vec3; 3], level: u32) {
    let size = view.size as usize;
    assert_eq!(grey.len(), size * size, "grey image of the wrong size");
    ellipsoid_hits(view, centre, axes, level, |x, y, g, _, _| {
        let slot = &mut grey[y * size + x];
        *slot = (*slot).max(g);
    });
}

/// Covers the pixels of `mask` where the ellipsoid of [`fill_ellipsoid_noise`] is hit on a noise
/// texel that passes the cut `cut` ([`noise_cut`] of the ellipsoid's own alpha threshold): one
/// ellipsoid of a set whose thresholds differ, drawn into the union of their coverage.
pub fn fill_ellipsoid_cut(mask: &mut Mask, view: &View, centre: Vec3, axes: [Vec3; 3], level: u32, cut: u16) {
    let size = mask.size;
    if view.size != size {
        return;
    }
    ellipsoid_hits(view, centre, axes, level, |x, y, g, _, _| {
        if g >= cut {
            #[expect(clippy::cast_possible_truncation, reason = "x, y < size ≤ MAX_SIZE")]
            mask.set(x as u32, y as u32);
        }
    });
}

/// The pixels `(x, y)` of the ellipsoid's projection in `view`, the value `1 + g` of the noise
/// texel its front surface shows there (see [`fill_ellipsoid_noise`]), the hit in the
/// ellipsoid's local coordinates `u` (the point `centre + Σ u_i·axes[i]`, `|u| = 1`) and the
/// texel's random vector (the renderer turns the normal towards it).
pub fn ellipsoid_hits(
    view: &View,
    centre: Vec3,
    axes: [Vec3; 3],
    level: u32,
    mut pixel: impl FnMut(usize, usize, u16, Vec3, Vec3),
) {
    let (c, m) = project_ellipsoid(view, centre, axes);
    // The local coordinates of a model-space offset: axes are orthogonal, so A⁻¹ = diag(1/r²)·Aᵀ.
    let inverse = axes.map(|a| {
        let r2 = a.length_squared();
        if r2 > 0.0 { a / r2 } else { Vec3::ZERO }
    });
    let local = |v: Vec3| Vec3::new(inverse[0].dot(v), inverse[1].dot(v), inverse[2].dot(v));
    // The ray towards the model through a pixel: from its point on the image plane through the
    // centre, along −direction.
    let d = local(-view.direction);
    let dd = d.length_squared();
    if !(dd > 0.0 && dd.is_finite()) {
        return;
    }
    let half = 0.5 * view.size as f32;
    let base = view.centre - centre;
    let (table, offsets) = noise_table();
    let level = level.min(NOISE_SIZE.ilog2());
    let (texels, side) = (&table[offsets[level as usize]..], NOISE_SIZE >> level);
    let vectors = &noise_vectors()[offsets[level as usize]..];
    let inv_scale = 1.0 / view.scale;
    let (step, inv_dd) = (local(view.right * inv_scale), 1.0 / dd);
    ellipse_spans(view.size, c, m, |y, x0, x1| {
        #[expect(clippy::cast_precision_loss, reason = "a pixel row")]
        let py = (half - (y as f32 + 0.5)) * inv_scale;
        let row = local(base + view.up * py);
        for x in x0..=x1 {
            #[expect(clippy::cast_precision_loss, reason = "a pixel column")]
            let o = row + step * (x as f32 + 0.5 - half);
            let b = o.dot(d);
            let disc = (b * b - dd * (o.length_squared() - 1.0)).max(0.0);
            let t = (-b - disc.sqrt()) * inv_dd;
            let hit = o + d * t;
            let i = noise_index(side, hit);
            pixel(x, y, 1 + u16::from(texels[i]), hit, vectors[i]);
        }
    });
}

/// The least value of a [`fill_ellipsoid_noise`] image that is covered under the alpha threshold
/// `t`: `1 +` the least grey `g` with `g / 255 ≥ t` (the renderer's test, in `f32`).
#[must_use]
pub fn noise_cut(t: f32) -> u16 {
    (0..=255u16).find(|&g| f32::from(g) / 255.0 >= t).map_or(u16::MAX, |g| g + 1)
}

/// The coverage of a [`fill_ellipsoid_noise`] image under the cut `cut` ([`noise_cut`]).
///
/// # Panics
/// If `grey` is not `mask`'s size squared long.
pub fn threshold_into(mask: &mut Mask, grey: &[u16], cut: u16) {
    let size = mask.size as usize;
    assert_eq!(grey.len(), size * size, "grey image of the wrong size");
    mask.words.fill(0);
    for (y, row) in grey.chunks_exact(size).enumerate() {
        for (x, &g) in row.iter().enumerate() {
            if g >= cut {
                mask.words[y * mask.stride + x / 64] |= 1 << (x % 64);
            }
        }
    }
}

/// The multi-scale RMSE (Clasen et al. 2011 §4, defined in `treelod_eval::metrics`) of coverage
/// `test` against `reference` as images of 0 and 1: levels `0..=L` (`L = log2 n`, `n` the masks'
/// side, a power of two), level `l` the RMSE after each aligned `2^l × 2^l` block is replaced by
/// its mean, the last level the whole image. Computed in one pass along the Z-order (Morton)
/// curve, on which every block of every level is a contiguous run: each level keeps one running
/// sum, closed every `4^l` pixels. The first level comes from the bits directly (its squared
/// differences are the XOR's population count), the pass runs over the 2 × 2 block sums.
///
/// # Panics
/// If the masks differ in size or the size is not a power of two of at least 2.
#[must_use]
pub fn multiscale_rmse(test: &Mask, reference: &Mask) -> MultiScaleRmse {
    assert_eq!(test.size, reference.size, "masks of different sizes");
    let n = test.size as usize;
    assert!(n >= 2 && n.is_power_of_two(), "multi-scale RMSE needs a power-of-two side, got {n}");
    // Levels 0..=log2 n; the last is the whole image.
    let bands = n.trailing_zeros() as usize + 1;
    let mut squares = vec![0.0f64; bands];
    let differ: u64 = test.words.iter().zip(&reference.words).map(|(t, r)| u64::from((t ^ r).count_ones())).sum();
    squares[0] = differ as f64;
    // 2 × 2 block sums of the difference, in -4..=4, on an (n/2)² grid.
    let half = n / 2;
    let mut blocks = vec![0i8; half * half];
    let pairs = |w: u64| (w & 0x5555_5555_5555_5555) + ((w >> 1) & 0x5555_5555_5555_5555);
    for by in 0..half {
        for word in 0..test.stride {
            let (r0, r1) = ((2 * by) * test.stride + word, (2 * by + 1) * test.stride + word);
            let (t0, t1) = (pairs(test.words[r0]), pairs(test.words[r1]));
            let (q0, q1) = (pairs(reference.words[r0]), pairs(reference.words[r1]));
            for p in 0..32.min(half.saturating_sub(word * 32)) {
                let field = |w: u64| ((w >> (2 * p)) & 3) as i8;
                blocks[by * half + word * 32 + p] = field(t0) + field(t1) - field(q0) - field(q1);
            }
        }
    }
    // The pass along the Z-order curve of the block grid: sums[b] is the open block of level b.
    let mut sums = vec![0i64; bands + 1];
    for m in 0..half * half {
        let (x, y) = morton_decode(m);
        sums[1] = i64::from(blocks[y * half + x]);
        let mut b = 1;
        loop {
            #[expect(clippy::cast_precision_loss, reason = "small integers")]
            let mean = sums[b] as f64 / f64::from(1u32 << (2 * b));
            squares[b] += mean * mean;
            sums[b + 1] += sums[b];
            sums[b] = 0;
            if b + 1 >= bands {
                break;
            }
            // Level b + 1's block closes after every 4^b blocks of the 2 × 2 grid.
            if (m + 1) % (1 << (2 * b)) != 0 {
                break;
            }
            b += 1;
        }
    }
    let levels = squares
        .iter()
        .enumerate()
        .map(|(b, &sq)| {
            let side = (n >> b) as f64;
            (sq / (side * side)).sqrt()
        })
        .collect();
    MultiScaleRmse { levels }
}

/// A mask's pixels as 0 and 1, rows top to bottom (the reference of
/// [`multiscale_errors_of_grey`]).
#[must_use]
pub fn coverage_values(mask: &Mask) -> Vec<i32> {
    let n = mask.size as usize;
    // Bit `x % 64` of the row's word `x / 64` (for sides under 64, not `p % 64`).
    (0..n * n).map(|p| i32::from(mask.words[(p / n) * mask.stride + (p % n) / 64] >> ((p % n) % 64) & 1 == 1)).collect()
}

/// [`multiscale_error`] of the coverage of the [`fill_ellipsoid_noise`] image `grey` under each
/// cut of `cuts` ([`noise_cut`]) against the coverage `reference` ([`coverage_values`]), in one
/// pass per cut over a pyramid of block sums, levels `0..=log2 n` as [`multiscale_rmse`] (the
/// same numbers up to rounding).
///
/// # Panics
/// If `grey` and `reference` differ in length or are not `n²` long for a power of two `n ≥ 2`.
#[must_use]
pub fn multiscale_errors_of_grey(grey: &[u16], reference: &[i32], cuts: &[u16]) -> Vec<f64> {
    assert_eq!(grey.len(), reference.len(), "images of different sizes");
    let n = grey.len().isqrt();
    assert!(n >= 2 && n.is_power_of_two() && n * n == grey.len(), "multi-scale RMSE needs a power-of-two side");
    let bands = n.trailing_zeros() as usize + 1;
    let mut level = vec![0i32; n * n];
    let mut next = vec![0i32; n * n / 4];
    cuts.iter()
        .map(|&cut| {
            for ((l, &g), &r) in level.iter_mut().zip(grey).zip(reference) {
                *l = i32::from(g >= cut) - r;
            }
            let (mut side, mut total) = (n, 0.0f64);
            for b in 0..bands {
                // A 2^b block sums to at most 4^b: the square of the whole image's (4^b = n²) needs
                // 64 bits from n = 256 on.
                let squares: i64 = level[..side * side].iter().map(|&v| i64::from(v) * i64::from(v)).sum();
                // A level-b pixel is the block sum over 4^b: its square is sum² / 16^b.
                #[expect(
                    clippy::cast_precision_loss,
                    clippy::cast_possible_wrap,
                    clippy::cast_possible_truncation,
                    reason = "small numbers"
                )]
                let mean = squares as f64 / (16f64.powi(b as i32) * (side * side) as f64);
                total += mean.sqrt();
                if b + 1 < bands {
                    let half = side / 2;
                    for y in 0..half {
                        let (r0, r1) =
                            (&level[2 * y * side..(2 * y + 1) * side], &level[(2 * y + 1) * side..(2 * y + 2) * side]);
                        for (x, out) in next[y * half..(y + 1) * half].iter_mut().enumerate() {
                            *out = r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1];
                        }
                    }
                    level[..half * half].copy_from_slice(&next[..half * half]);
                    side = half;
                }
            }
            total / bands as f64
        })
        .collect()
}

/// The summary of [`multiscale_rmse`], the mean of its levels: one number for comparing images.
#[must_use]
pub fn multiscale_error(test: &Mask, reference: &Mask) -> f64 {
    multiscale_rmse(test, reference).summary()
}

/// `(x, y)` of the `m`-th cell along the Z-order curve: the even bits of `m` are `x`, the odd `y`.
fn morton_decode(m: usize) -> (usize, usize) {
    let compact = |mut v: u64| {
        v &= 0x5555_5555_5555_5555;
        v = (v | (v >> 1)) & 0x3333_3333_3333_3333;
        v = (v | (v >> 2)) & 0x0F0F_0F0F_0F0F_0F0F;
        v = (v | (v >> 4)) & 0x00FF_00FF_00FF_00FF;
        v = (v | (v >> 8)) & 0x0000_FFFF_0000_FFFF;
        v = (v | (v >> 16)) & 0x0000_0000_FFFF_FFFF;
        v as usize
    };
    (compact(m as u64), compact(m as u64 >> 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ImageEncoding;

    fn square(mask: &mut Mask, lo: Vec2, hi: Vec2) {
        let uv = [Vec2::ZERO; 3];
        fill_triangle(mask, [lo, Vec2::new(hi.x, lo.y), hi], uv, None);
        fill_triangle(mask, [lo, hi, Vec2::new(lo.x, hi.y)], uv, None);
    }

    #[test]
    fn a_square_on_pixel_edges_covers_exactly_its_pixels() {
        // 4 × 3 pixels: its edges pass between pixel centres.
        let mut mask = Mask::new(16);
        square(&mut mask, Vec2::new(2.0, 5.0), Vec2::new(6.0, 8.0));
        assert_eq!(mask.count(), 12);
        for y in 0..16 {
            for x in 0..16 {
                assert_eq!(mask.get(x, y), (2..6).contains(&x) && (5..8).contains(&y), "pixel ({x}, {y})");
            }
        }
    }

    #[test]
    fn a_box_said_to_hold_no_centre_holds_none_once_snapped() {
        // Boxes near centres and near pixel edges, tiny to a pixel wide, at coordinates up to
        // the test's reach and past it: wherever the float test rejects one, the snapped box
        // (pixel centres x·256 + 128 between its snapped ends) holds no centre either; and it
        // rejects most boxes far narrower than a pixel.
        let mut rng = crate::rng::SplitMix64(11);
        let mut next = || rng.unit();
        let centre_between = |lo: f32, hi: f32| {
            let (a, b) = (snap(lo), snap(hi));
            // Some x with a ≤ 256·x + 128 ≤ b.
            (-((SUBPIXEL / 2 - a) >> SUBPIXEL_BITS)) <= ((b - SUBPIXEL / 2) >> SUBPIXEL_BITS)
        };
        let (mut rejected, mut tiny) = (0, 0);
        for i in 0..200_000 {
            let scale = [4.0, 64.0, 4000.0, 4200.0][i % 4];
            let base = Vec2::new((next() * 2.0 - 1.0) * scale, (next() * 2.0 - 1.0) * scale);
            // Snapped to a centre or an edge, then nudged by a few 256ths of a pixel.
            let anchor = if i % 3 == 0 { base.floor() + 0.5 } else { base.floor() };
            let nudge = Vec2::new(next() - 0.5, next() - 0.5) * (8.0 / 256.0);
            let size = Vec2::new(next(), next()) * [0.001, 0.005, 0.2, 1.2][(i / 4) % 4];
            let min = if i % 2 == 0 { anchor + nudge } else { base };
            let max = min + size;
            if holds_no_centre(min, max) {
                rejected += 1;
                assert!(
                    !(centre_between(min.x, max.x) && centre_between(min.y, max.y)),
                    "{min} – {max} holds a centre once snapped"
                );
            }
            tiny += usize::from(size.max_element() < 0.01 && min.abs().max(max.abs()).max_element() < 4000.0);
        }
        assert!(rejected > tiny / 2, "{rejected} of {tiny} tiny boxes rejected");
    }

    #[test]
    #[expect(clippy::needless_range_loop, reason = "lane `j` of nine arrays")]
    fn a_chunk_projects_as_one_corner_at_a_time_and_rejects_as_setup_does() {
        // Triangles far under a pixel to wider than the image, near pixel centres and edges, out
        // of the image, past the float test's reach, and not finite, in views of 5 to 700
        // pixels: each corner is `View::project`'s float, bit for bit, and a triangle is marked
        // as holding no centre exactly where `Setup::new` rejects its box before snapping (so
        // wherever `triangle_pixels` visits a pixel it is marked as holding one).
        let mut rng = crate::rng::SplitMix64(23);
        let mut next = || rng.unit();
        let mut chunk = ProjectedChunk::default();
        let (mut held, mut not_held) = (0, 0);
        for round in 0..400 {
            let size = [5, 16, 64, 700][round % 4];
            let direction = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5);
            let view = View::fit(direction, Vec3::new(1.0, 5.0, -2.0), 3.0 + 4.0 * next(), size);
            let mut corners = [[0.0f32; CHUNK]; 9];
            for j in 0..CHUNK {
                let reach = [0.001, 0.01, 0.3, 8.0, 5000.0][(round + j) % 5];
                let centre = Vec3::new(1.0, 5.0, -2.0) + Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 10.0;
                for k in 0..3 {
                    let p = centre + Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * reach;
                    corners[3 * k][j] = p.x;
                    corners[3 * k + 1][j] = p.y;
                    corners[3 * k + 2][j] = p.z;
                }
            }
            corners[round % 9][round % CHUNK] = [f32::NAN, f32::INFINITY][round % 2];
            view.project_chunk(size, corners.each_ref(), &mut chunk);
            for j in 0..CHUNK {
                let p: [Vec2; 3] = core::array::from_fn(|k| {
                    view.project(Vec3::new(corners[3 * k][j], corners[3 * k + 1][j], corners[3 * k + 2][j]))
                });
                let got = chunk.corners(j);
                for k in 0..3 {
                    assert_eq!(got[k].x.to_bits(), p[k].x.to_bits(), "round {round}, triangle {j}, corner {k}");
                    assert_eq!(got[k].y.to_bits(), p[k].y.to_bits(), "round {round}, triangle {j}, corner {k}");
                }
                let (min, max) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
                let side = size as f32;
                let outside = !(max.x >= 0.0 && max.y >= 0.0 && min.x <= side && min.y <= side);
                let rejected = outside || holds_no_centre(min, max);
                assert_eq!(chunk.may_hold[j], !rejected, "round {round}, triangle {j}: {p:?}");
                if chunk.may_hold[j] {
                    held += 1;
                } else {
                    not_held += 1;
                    let mut visited = false;
                    triangle_pixels(size, p, |_, _, _| visited = true);
                    assert!(!visited, "round {round}, triangle {j} marked as holding no centre holds one");
                }
            }
        }
        assert!(held > 1000 && not_held > 1000, "{held} held, {not_held} not");
    }

    #[test]
    fn floor_in_floats_is_the_integer_floor_within_its_reach() {
        let mut rng = crate::rng::SplitMix64(5);
        for i in 0..100_000 {
            let whole = (rng.unit() * 16_000.0 - 8_000.0).floor();
            // Whole numbers, halves, and a few ulps either side of them.
            let v = match i % 4 {
                0 => whole,
                1 => whole + 0.5,
                2 => f32::from_bits(whole.to_bits().wrapping_add(1)),
                _ => whole - rng.unit() * 1e-3,
            };
            #[expect(clippy::cast_precision_loss, reason = "|v| ≤ 8001")]
            let expected = floor_i64(v) as f32;
            assert_eq!(floor_small(v), expected, "{v}");
        }
    }

    #[test]
    fn the_top_left_rule_counts_a_centre_on_a_shared_edge_once() {
        // A square whose edges run through pixel centres: the left and top rows of centres are
        // in, the right and bottom ones out, and the diagonal shared by the two triangles leaves
        // no gap. Both windings cover the same.
        let (lo, hi) = (Vec2::new(2.5, 2.5), Vec2::new(6.5, 6.5));
        let mut mask = Mask::new(10);
        square(&mut mask, lo, hi);
        assert_eq!(mask.count(), 16);
        assert!(mask.get(2, 2) && mask.get(5, 5) && !mask.get(6, 2) && !mask.get(2, 6));
        let mut reversed = Mask::new(10);
        let uv = [Vec2::ZERO; 3];
        fill_triangle(&mut reversed, [lo, hi, Vec2::new(hi.x, lo.y)], uv, None);
        fill_triangle(&mut reversed, [lo, Vec2::new(lo.x, hi.y), hi], uv, None);
        assert_eq!(reversed, mask);
    }

    #[test]
    fn a_right_triangle_covers_the_centres_below_its_diagonal() {
        // Corners (0,0), (8,0), (0,8): centres with x + y + 1 < 8 are inside, x + y + 1 = 8 lies
        // on the hypotenuse (a right edge here: excluded) — 28 pixels.
        let mut mask = Mask::new(8);
        fill_triangle(&mut mask, [Vec2::ZERO, Vec2::new(8.0, 0.0), Vec2::new(0.0, 8.0)], [Vec2::ZERO; 3], None);
        assert_eq!(mask.count(), 28);
        assert!(mask.get(0, 6) && !mask.get(0, 7) && !mask.get(7, 0));
        // Degenerate and off-screen triangles cover nothing.
        let mut empty = Mask::new(8);
        fill_triangle(&mut empty, [Vec2::ZERO, Vec2::new(4.0, 4.0), Vec2::new(8.0, 8.0)], [Vec2::ZERO; 3], None);
        fill_triangle(&mut empty, [Vec2::splat(-9.0), Vec2::new(-1.0, -9.0), Vec2::splat(-1.0)], [Vec2::ZERO; 3], None);
        fill_triangle(&mut empty, [Vec2::splat(f32::NAN); 3], [Vec2::ZERO; 3], None);
        assert_eq!(empty.count(), 0);
    }

    /// Pixel `(x, y)` by the definition: the snapped triangle's edge functions at the centre.
    fn covers(p: [Vec2; 3], x: i64, y: i64) -> bool {
        let v = p.map(|q| (snap(q.x), snap(q.y)));
        let area = (v[1].0 - v[0].0) * (v[2].1 - v[0].1) - (v[1].1 - v[0].1) * (v[2].0 - v[0].0);
        if area == 0 {
            return false;
        }
        let (px, py) = (x * SUBPIXEL + SUBPIXEL / 2, y * SUBPIXEL + SUBPIXEL / 2);
        (0..3).all(|k| {
            let (a, b) = if area > 0 { (v[(k + 1) % 3], v[(k + 2) % 3]) } else { (v[(k + 2) % 3], v[(k + 1) % 3]) };
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let e = dx * (py - a.1) - dy * (px - a.0);
            e > 0 || (e == 0 && (dy < 0 || (dy == 0 && dx > 0)))
        })
    }

    #[test]
    fn spans_agree_with_the_edge_functions_at_every_pixel() {
        // Small, large, thin, partly off-screen and sub-pixel triangles against the definition.
        let mut rng = crate::rng::SplitMix64(11);
        for i in 0..400 {
            let scale = [0.7, 4.0, 30.0, 90.0][i % 4];
            let c = Vec2::new(rng.range(-10.0, 50.0), rng.range(-10.0, 50.0));
            let p = [0; 3].map(|_| c + scale * Vec2::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)));
            let mut mask = Mask::new(40);
            fill_triangle(&mut mask, p, [Vec2::ZERO; 3], None);
            for y in 0..40 {
                for x in 0..40 {
                    assert_eq!(
                        mask.get(x, y),
                        covers(p, i64::from(x), i64::from(y)),
                        "triangle {i} {p:?} pixel ({x}, {y})"
                    );
                }
            }
        }
    }

    #[test]
    fn an_alpha_tested_quad_covers_the_opaque_texels_only() {
        // A 4 × 4 texture whose left half is opaque, drawn over 16 × 16 pixels: 8 columns pass.
        let rgba = (0..16).flat_map(|i| [255, 255, 255, if i % 4 < 2 { 255 } else { 0 }]).collect();
        let image = Image { width: 4, height: 4, rgba, encoded: Vec::new(), encoding: ImageEncoding::Raw };
        let material =
            Material { base_color: [1.0; 4], alpha_mode: AlphaMode::Mask, alpha_cutoff: 0.5, ..Material::default() };
        let alpha = AlphaMask::for_material(&material, Some(&image)).expect("a masked material is tested");
        assert_eq!(alpha.opaque_fraction(), 0.5);
        let mut mask = Mask::new(16);
        let (a, b, c, d) = (Vec2::ZERO, Vec2::new(16.0, 0.0), Vec2::splat(16.0), Vec2::new(0.0, 16.0));
        let (ua, ub, uc, ud) = (Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y);
        fill_triangle(&mut mask, [a, b, c], [ua, ub, uc], Some(&alpha));
        fill_triangle(&mut mask, [a, c, d], [ua, uc, ud], Some(&alpha));
        assert_eq!(mask.count(), 8 * 16);
        assert!((0..16).all(|y| mask.get(7, y) && !mask.get(8, y)));
        // The alpha factor takes part: at half alpha nothing passes a cutoff of 0.6.
        let faint = Material { base_color: [1.0, 1.0, 1.0, 0.5], alpha_cutoff: 0.6, ..material.clone() };
        let none = AlphaMask::for_material(&faint, Some(&image)).expect("tested");
        assert_eq!(none.opaque_fraction(), 0.0);
        // Opaque materials are not tested; blend is a mask at 0.5.
        let opaque = Material { alpha_mode: AlphaMode::Opaque, ..material.clone() };
        assert!(AlphaMask::for_material(&opaque, Some(&image)).is_none());
        let blend = Material { alpha_mode: AlphaMode::Blend, alpha_cutoff: 0.9, ..material };
        assert_eq!(AlphaMask::for_material(&blend, Some(&image)).map(|m| m.opaque_fraction()), Some(0.5));
    }

    #[test]
    fn coverage_counts_words_as_the_metrics_count_flags() {
        let mut reference = Mask::new(70);
        let mut test = Mask::new(70);
        for x in 0..10 {
            reference.set(x, 0);
        }
        for x in 5..20 {
            test.set(x, 0);
        }
        test.set(69, 69);
        // tp 5, fp 11, fn 5.
        let c = coverage(&test, &reference);
        assert_eq!(c, Coverage { tp: 5, fp: 11, fn_: 5 });
        assert_eq!(c, Coverage::compare(&to_flags(&reference), &to_flags(&test)).expect("same size"));
        assert_eq!(c.precision_recall(), (5.0 / 16.0, 0.5));
        assert!((c.quality() - (1.0 - (11.0f64 / 16.0).hypot(0.5))).abs() < 1e-12);
        assert_eq!(coverage(&reference, &reference).precision_recall(), (1.0, 1.0));
        // Empty cases.
        let empty = Mask::new(70);
        assert_eq!(coverage(&empty, &empty).precision_recall(), (1.0, 1.0));
        assert_eq!(coverage(&empty, &reference).precision_recall(), (1.0, 0.0));
        assert_eq!(coverage(&reference, &empty).precision_recall(), (0.0, 1.0));
    }

    #[test]
    fn views_fit_the_sphere_and_look_from_the_given_directions() {
        let dirs = view_directions(12);
        assert_eq!(dirs.len(), 12);
        assert_eq!(dirs.iter().filter(|d| d.y.abs() < 1e-6).count(), 8);
        // No two directions are equal or opposite (an opposite view repeats the silhouette).
        for (i, a) in dirs.iter().enumerate() {
            assert!(dirs[i + 1..].iter().all(|b| a.dot(*b).abs() < 0.999), "{a} repeats a silhouette");
        }
        assert!(dirs.iter().all(|d| (d.length() - 1.0).abs() < 1e-5));
        assert_eq!(view_directions(1).len(), 1);
        let view = View::fit(Vec3::Z, Vec3::new(0.0, 1.0, 0.0), 2.0, 100);
        // The sphere's top and right reach the image edges; +Y is up.
        assert!(view.project(Vec3::new(0.0, 3.0, 0.0)).abs_diff_eq(Vec2::new(50.0, 0.0), 1e-4));
        assert!(view.project(Vec3::new(2.0, 1.0, 5.0)).abs_diff_eq(Vec2::new(100.0, 50.0), 1e-4));
        let top = View::fit(Vec3::Y, Vec3::ZERO, 1.0, 10);
        assert!(top.right.is_normalized() && top.up.is_normalized() && top.right.dot(top.up).abs() < 1e-6);
        // Turned a quarter counter-clockwise, the point at the image's right edge is at its top.
        let turned = view.rolled(std::f32::consts::FRAC_PI_2);
        assert!(turned.project(Vec3::new(2.0, 1.0, 5.0)).abs_diff_eq(Vec2::new(50.0, 0.0), 1e-4));
        assert!(turned.project(Vec3::new(0.0, 3.0, 0.0)).abs_diff_eq(Vec2::new(0.0, 50.0), 1e-4));
        assert_eq!((turned.direction, turned.centre, turned.scale), (view.direction, view.centre, view.scale));
        assert_eq!(view.rolled(0.0), view);
        let (c, r) = bounding_sphere([Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)].into_iter());
        assert_eq!((c, r), (Vec3::new(1.0, 0.5, 0.0), 1.25f32.sqrt()));
    }

    #[test]
    fn rendering_views_is_independent_of_the_thread_count() {
        let mut rng = crate::rng::SplitMix64(3);
        let triangles: Vec<RasterTriangle> = (0..300)
            .map(|_| {
                let c = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
                let mut corner = || c + 0.2 * Vec3::new(rng.unit(), rng.unit(), rng.unit());
                RasterTriangle { positions: [corner(), corner(), corner()], uvs: [Vec2::ZERO; 3], alpha: NO_ALPHA }
            })
            .collect();
        let views: Vec<View> = view_directions(6).into_iter().map(|d| View::fit(d, Vec3::ZERO, 2.0, 64)).collect();
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
        let a = one.install(|| render_views(&views, &triangles, &[]));
        let b = render_views(&views, &triangles, &[]);
        assert_eq!(a, b);
        assert!(a.iter().all(|m| m.count() > 100));
    }

    #[test]
    fn a_circle_and_an_ellipse_cover_their_areas() {
        let mut mask = Mask::new(128);
        fill_ellipse(&mut mask, Vec2::new(64.0, 64.0), [400.0, 0.0, 400.0]);
        let area = std::f64::consts::PI * 400.0;
        assert!((mask.count() as f64 - area).abs() < 0.02 * area, "{}", mask.count());
        assert!(mask.get(64, 64) && mask.get(83, 64) && !mask.get(85, 64) && !mask.get(64, 85));
        // Semi-axes 30 and 6, turned by 30°: M = R diag(900, 36) Rᵀ.
        let (s, c) = (0.5f64, 0.75f64.sqrt());
        let m = [900.0 * c * c + 36.0 * s * s, (900.0 - 36.0) * c * s, 900.0 * s * s + 36.0 * c * c];
        let mut turned = Mask::new(128);
        fill_ellipse(&mut turned, Vec2::new(60.0, 70.0), m);
        let area = std::f64::consts::PI * 30.0 * 6.0;
        assert!((turned.count() as f64 - area).abs() < 0.03 * area, "{}", turned.count());
        // Exactly the centres inside.
        let det = m[0] * m[2] - m[1] * m[1];
        for y in 0..128u32 {
            for x in 0..128u32 {
                let (dx, dy) = (f64::from(x) + 0.5 - 60.0, f64::from(y) + 0.5 - 70.0);
                let q = (m[2] * dx * dx - 2.0 * m[1] * dx * dy + m[0] * dy * dy) / det;
                if (q - 1.0).abs() > 1e-9 {
                    assert_eq!(turned.get(x, y), q < 1.0, "pixel ({x}, {y}), q {q}");
                }
            }
        }
        // Off the image, degenerate or not finite: nothing, and no panic.
        let mut none = Mask::new(16);
        fill_ellipse(&mut none, Vec2::new(-50.0, 8.0), [9.0, 0.0, 9.0]);
        fill_ellipse(&mut none, Vec2::new(8.0, 8.0), [9.0, 0.0, 0.0]);
        fill_ellipse(&mut none, Vec2::new(f32::NAN, 8.0), [9.0, 0.0, 9.0]);
        assert_eq!(none.count(), 0);
        // Partly off the image: clipped.
        fill_ellipse(&mut none, Vec2::new(0.0, 0.0), [16.0, 0.0, 16.0]);
        assert!(none.count() > 8 && none.count() < 20, "{}", none.count());
    }

    #[test]
    fn an_ellipsoid_projects_to_its_outline() {
        // Seen from +Z (right = +X, up = +Y), an ellipsoid with semi-axes 2 (x), 1 (y), 5 (z):
        // an ellipse of semi-axes 2 and 1 metres, at 10 pixels per metre.
        let view = View::fit(Vec3::Z, Vec3::ZERO, 6.4, 128);
        let (c, m) = project_ellipsoid(&view, Vec3::new(1.0, 1.0, 3.0), [Vec3::X * 2.0, Vec3::Y, Vec3::Z * 5.0]);
        let s = f64::from(view.scale);
        assert!(c.abs_diff_eq(Vec2::new(64.0 + view.scale, 64.0 - view.scale), 1e-4));
        assert!((m[0] - 4.0 * s * s).abs() < 1e-6 * s * s && m[1].abs() < 1e-9 && (m[2] - s * s).abs() < 1e-6 * s * s);
        // Turned by 90° about z, the long axis is vertical; the xy term follows the image's y-down.
        let (_, m) = project_ellipsoid(&view, Vec3::ZERO, [Vec3::Y * 2.0, -Vec3::X, Vec3::Z * 5.0]);
        assert!((m[0] - s * s).abs() < 1e-6 * s * s && (m[2] - 4.0 * s * s).abs() < 1e-6 * s * s);
        let diagonal = Vec3::new(1.0, 1.0, 0.0).normalize();
        let (_, m) = project_ellipsoid(&view, Vec3::ZERO, [diagonal * 2.0, Vec3::Z.cross(diagonal) * 0.1, Vec3::Z]);
        assert!(m[1] < 0.0, "a long axis up and to the right runs to smaller image y: {m:?}");
        // A sphere of radius r from any side: a circle of r·scale pixels.
        let top = View::fit(Vec3::new(1.0, 2.0, 0.5), Vec3::ZERO, 1.0, 64);
        let (_, m) = project_ellipsoid(&top, Vec3::ZERO, [Vec3::X * 0.5, Vec3::Y * 0.5, Vec3::Z * 0.5]);
        let r2 = (0.5 * f64::from(top.scale)).powi(2);
        assert!((m[0] - r2).abs() < 1e-3 * r2 && m[1].abs() < 1e-3 * r2 && (m[2] - r2).abs() < 1e-3 * r2);
    }

    #[test]
    fn multiscale_rmse_is_zero_for_equal_images_and_exact_for_known_differences() {
        let mut a = Mask::new(64);
        fill_ellipse(&mut a, Vec2::new(30.0, 20.0), [100.0, 20.0, 50.0]);
        let levels = multiscale_rmse(&a, &a.clone()).levels;
        assert_eq!(levels, vec![0.0; 7]);
        assert_eq!(multiscale_error(&a, &a), 0.0);
        // One pixel differs: level l has one block of mean 1/4^l among (n/2^l)² blocks, so its
        // RMSE is 1/(2^l·n), down to 1/n² for the whole image.
        let mut b = a.clone();
        let (x, y) = (37, 41);
        assert!(!b.get(x, y));
        b.set(x, y);
        for (level, rmse) in multiscale_rmse(&b, &a).levels.into_iter().enumerate() {
            let expected = 1.0 / (f64::from(1u32 << level) * 64.0);
            assert!((rmse - expected).abs() < 1e-12, "level {level}: {rmse} vs {expected}");
        }
        // A full image against an empty one: 1 at every level; a checkerboard: 1/√2 at the
        // finest level, 1/2 at every coarser one (each block is half covered).
        let (mut full, empty, mut checker) = (Mask::new(32), Mask::new(32), Mask::new(32));
        for y in 0..32 {
            for x in 0..32 {
                full.set(x, y);
                if (x + y) % 2 == 0 {
                    checker.set(x, y);
                }
            }
        }
        let levels = multiscale_rmse(&full, &empty).levels;
        assert!(levels.iter().all(|&r| (r - 1.0).abs() < 1e-12), "{levels:?}");
        let levels = multiscale_rmse(&checker, &empty).levels;
        assert_eq!(levels.len(), 6);
        assert!((levels[0] - 0.5f64.sqrt()).abs() < 1e-12);
        assert!(levels[1..].iter().all(|&r| (r - 0.5).abs() < 1e-12), "{levels:?}");
        // The sign of a difference counts at coarse levels: a block half too much and half too
        // little cancels there.
        let (mut left, mut right) = (Mask::new(4), Mask::new(4));
        left.set(0, 0);
        right.set(1, 0);
        let levels = multiscale_rmse(&left, &right).levels;
        assert!((levels[0] - (2.0f64 / 16.0).sqrt()).abs() < 1e-12 && levels[1..] == [0.0, 0.0], "{levels:?}");
        // The smallest image: the pixels and the whole image.
        assert_eq!(multiscale_rmse(&Mask::new(2), &Mask::new(2)).levels, vec![0.0, 0.0]);
    }

    /// A random square mask of side `2^k`, `k` in `1..=6`, and a second of the same side.
    fn mask_pair() -> impl proptest::strategy::Strategy<Value = (Mask, Mask)> {
        use proptest::prelude::*;
        (1u32..=6).prop_flat_map(|k| {
            let n = 1u32 << k;
            let bits = proptest::collection::vec(any::<bool>(), (n * n) as usize);
            (bits.clone(), bits).prop_map(move |(a, b)| {
                let build = |bits: Vec<bool>| {
                    let mut mask = Mask::new(n);
                    for (i, bit) in bits.into_iter().enumerate() {
                        if bit {
                            #[expect(clippy::cast_possible_truncation, reason = "at most 4096 pixels")]
                            mask.set(i as u32 % n, i as u32 / n);
                        }
                    }
                    mask
                };
                (build(a), build(b))
            })
        })
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(96))]

        /// The bit-mask pass, the grey-cut pass and the pixel counts compute the definitions of
        /// `treelod_eval::metrics`, written out block by block there.
        #[test]
        fn the_fast_paths_compute_the_metrics_definitions((test, reference) in mask_pair()) {
            let n = test.size();
            let (t, r) = (to_flags(&test), to_flags(&reference));
            let definition =
                treelod_eval::metrics::multiscale_rmse_by_blocks(n, n, 1, &t.values(), &r.values()).expect("same size");
            let fast = multiscale_rmse(&test, &reference);
            proptest::prop_assert_eq!(fast.levels.len(), definition.levels.len());
            for (f, d) in fast.levels.iter().zip(&definition.levels) {
                proptest::prop_assert!((f - d).abs() < 1e-12, "{:?} vs {:?}", fast.levels, definition.levels);
            }
            // The grey-cut pass: grey 2 where `test` covers, 0 elsewhere, cut at 1.
            let grey: Vec<u16> = t.covered.iter().map(|&c| if c { 2 } else { 0 }).collect();
            let of_grey = multiscale_errors_of_grey(&grey, &coverage_values(&reference), &[1])[0];
            proptest::prop_assert!((of_grey - definition.summary()).abs() < 1e-12, "{} vs {:?}", of_grey, definition);
            proptest::prop_assert!((multiscale_error(&test, &reference) - definition.summary()).abs() < 1e-12);
            proptest::prop_assert_eq!(coverage(&test, &reference), Coverage::compare(&r, &t).expect("same size"));
        }
    }

    #[test]
    fn morton_order_visits_blocks_contiguously() {
        let cells: Vec<(usize, usize)> = (0..16).map(morton_decode).collect();
        assert_eq!(&cells[..4], &[(0, 0), (1, 0), (0, 1), (1, 1)]);
        assert_eq!(cells[4], (2, 0));
        assert_eq!(cells[15], (3, 3));
    }

    #[test]
    fn the_noise_cube_is_uniform_per_level_and_hashed_as_the_renderer_hashes_it() {
        // Texel 0 of face 0, level 0, by the renderer's recipe: mix(key), two draws, then alpha.
        let mut h = noise_mix(0);
        for _ in 0..3 {
            h = noise_mix(h);
        }
        let expected = (h >> 56).to_le_bytes()[0];
        // The direction of face +X's corner texel (s, t) = (0, 0): sc = −z, tc = −y near −1.
        assert_eq!(noise_grey(Vec3::new(1.0, 0.999, 0.999), 0), expected);
        // Every level below 1×1 faces: about a share t of the texels is under t.
        for level in 0..4u32 {
            let side = NOISE_SIZE >> level;
            let (table, offsets) = noise_table();
            let texels = &table[offsets[level as usize]..offsets[level as usize] + 6 * (side * side) as usize];
            for t in [0.2f32, 0.4, 0.6] {
                let under = texels.iter().filter(|&&g| f32::from(g) / 255.0 < t).count() as f32 / texels.len() as f32;
                assert!((under - t).abs() < 0.12, "level {level} t {t}: {under}");
            }
        }
    }

    #[test]
    fn a_noisy_ellipsoid_covers_the_ellipse_at_threshold_zero_and_about_one_minus_t_above() {
        let view = View::fit(Vec3::new(0.3, 0.4, 1.0), Vec3::ZERO, 1.0, 128);
        let axes = [Vec3::new(0.8, 0.1, 0.0), Vec3::new(-0.05, 0.4, 0.0), Vec3::new(0.0, 0.0, 0.3)];
        let (c, m) = project_ellipsoid(&view, Vec3::ZERO, axes);
        let mut solid = Mask::new(128);
        fill_ellipse(&mut solid, c, m);
        let mut grey = vec![0u16; 128 * 128];
        fill_ellipsoid_noise(&mut grey, &view, Vec3::ZERO, axes, 2);
        let mut mask = Mask::new(128);
        threshold_into(&mut mask, &grey, noise_cut(0.0));
        assert_eq!(mask, solid);
        let area = solid.count() as f64;
        for t in [0.2f32, 0.4, 0.6] {
            threshold_into(&mut mask, &grey, noise_cut(t));
            let kept = mask.count() as f64 / area;
            assert!((kept - (1.0 - f64::from(t))).abs() < 0.15, "t {t}: {kept}");
            // The errors of the grey image are those of its thresholded masks.
            let reference = coverage_values(&solid);
            let fast = multiscale_errors_of_grey(&grey, &reference, &[noise_cut(t)])[0];
            assert!((fast - multiscale_error(&mask, &solid)).abs() < 1e-12, "{fast}");
        }
        assert_eq!(noise_cut(0.0), 1);
        assert_eq!(noise_cut(0.2), 1 + 51);
    }
}
