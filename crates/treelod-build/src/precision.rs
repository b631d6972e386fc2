//! Precision trimming: rounding the float fields of a container to the precision they need, so
//! that zstd compresses them better, without changing the format.
//!
//! A tree's vertex positions carry 24 significant bits, of which the low ones are noise to a
//! renderer (a 10 m tree at 16 bits is resolved to 0.15 mm) and incompressible to zstd. Rounding
//! each float to `bits` significant mantissa bits (round to nearest, the low bits zero — as
//! meshoptimizer's `meshopt_quantizeFloat` does for the same reason) keeps every field an `f32`
//! (readers see no difference) and shrinks the compressed container by about a third.
//!
//! Every rounding is **monotone** (`a ≤ b ⇒ r(a) ≤ r(b)`) and applied to values, not to records:
//! equal values stay equal (a leaf point's `size` and its triangle's, a node's `hi` and its
//! parent's `lo`) and ordered values stay ordered (the size-sorted arrays), so the exact cut of
//! spec §10 holds after trimming exactly when it held before (an interval that rounds to empty is
//! skipped by the rule, and its neighbours still meet). Cell bounds are widened to hold the
//! rounded reference positions (spec §6.2).

use treelod_format::ContainerData;

/// Significant mantissa bits kept per kind of value (of an `f32`'s 23).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Precision {
    /// Positions (vertices, points, pruned leaves' centres): relative error `2^-(bits+1)`.
    pub position: u32,
    /// Texture coordinates.
    pub uv: u32,
    /// Sizes, radii, threshold bounds and leaf areas.
    pub size: u32,
    /// Bits per octahedral normal component (of 16).
    pub normal: u32,
}

impl Default for Precision {
    /// 16-bit positions and texture coordinates (0.15 mm on a 10 m tree; 0.06 texel of a 4096
    /// texture at coordinate 1), 12-bit sizes (0.01 % of a threshold), 10-bit normals (0.2°).
    fn default() -> Self {
        Self { position: 16, uv: 16, size: 12, normal: 10 }
    }
}

impl Precision {
    /// Every bit kept: no rounding.
    pub const FULL: Self = Self { position: 23, uv: 23, size: 23, normal: 16 };

    /// The settings value recorded in the container's metadata (spec §7.1), e.g.
    /// `position 16, uv 16, size 12, normal 10`.
    #[must_use]
    pub fn setting(&self) -> String {
        if *self == Self::FULL {
            return "full".to_owned();
        }
        format!("position {}, uv {}, size {}, normal {}", self.position, self.uv, self.size, self.normal)
    }
}

/// `v` rounded to nearest with `bits` significant mantissa bits; infinities, NaN, zero and values
/// that would round past the largest finite `f32` are kept as they are. Monotone.
#[must_use]
pub fn round_float(v: f32, bits: u32) -> f32 {
    if bits >= 23 || !v.is_finite() || v == 0.0 {
        return v;
    }
    let drop = 23 - bits;
    let raw = v.to_bits();
    // Adding half of the dropped unit to the magnitude rounds to nearest (ties away from zero);
    // a carry into the exponent is the correct next binade.
    let rounded = (raw + (1 << (drop - 1))) & !((1u32 << drop) - 1);
    let r = f32::from_bits(rounded);
    if r.is_finite() { r } else { v }
}

/// An octahedral normal (spec §2) with each snorm16 component rounded to `bits` bits. Monotone
/// per component.
#[must_use]
pub fn round_normal(packed: u32, bits: u32) -> u32 {
    if bits >= 16 {
        return packed;
    }
    let step = 1i32 << (16 - bits);
    #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "16-bit fields")]
    let round = |c: u16| -> u32 {
        let v = i32::from(c as i16);
        let r = (v + v.signum() * step / 2) / step * step;
        u32::from(r.clamp(-32767, 32767) as i16 as u16)
    };
    round((packed & 0xFFFF) as u16) | (round((packed >> 16) as u16) << 16)
}

/// Rounds the float fields of `data` to `precision` and widens the cell bounds to hold the
/// rounded positions (see the module documentation for why the exact cut survives).
pub fn trim(data: &mut ContainerData, precision: &Precision) {
    let position = |p: &mut [f32; 3]| p.iter_mut().for_each(|c| *c = round_float(*c, precision.position));
    let size = |s: &mut f32| *s = round_float(*s, precision.size);
    for v in &mut data.vertices {
        position(&mut v.position);
        v.uv.iter_mut().for_each(|c| *c = round_float(*c, precision.uv));
        v.normal = round_normal(v.normal, precision.normal);
    }
    for t in data.triangles.iter_mut().chain(&mut data.prune_triangles) {
        size(&mut t.size);
    }
    for p in &mut data.points {
        position(&mut p.position);
        p.normal = round_normal(p.normal, precision.normal);
        size(&mut p.radius);
        size(&mut p.size);
        size(&mut p.lo);
        size(&mut p.hi);
    }
    for l in &mut data.prune_leaves {
        position(&mut l.center);
        size(&mut l.area);
    }
    // Cell bounds must hold every reference position (spec §6.2): widen them where rounding moved
    // one outside.
    let cells = data.cells.clone();
    for (cell, range_cell) in data.cells.iter_mut().zip(&cells) {
        if range_cell.is_empty() {
            continue;
        }
        let mut grow = |p: [f32; 3]| {
            for (axis, c) in p.into_iter().enumerate() {
                cell.bounds_min[axis] = cell.bounds_min[axis].min(c);
                cell.bounds_max[axis] = cell.bounds_max[axis].max(c);
            }
        };
        for t in data.triangles.get(range_cell.triangles.as_usize()).unwrap_or_default() {
            t.indices.iter().filter_map(|&i| data.vertices.get(i as usize)).for_each(|v| grow(v.position));
        }
        for p in data.points.get(range_cell.points.as_usize()).unwrap_or_default() {
            grow(p.position);
        }
        for l in data.prune_leaves.get(range_cell.prune_leaves.as_usize()).unwrap_or_default() {
            grow(l.center);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_keeps_the_requested_bits_and_is_monotone() {
        assert_eq!(round_float(1.0, 8), 1.0);
        // 1 + 2^-10 needs 10 bits: at 8 bits it rounds down to 1, at 10 it stays.
        let v = 1.0 + 2f32.powi(-10);
        assert_eq!(round_float(v, 8), 1.0);
        assert_eq!(round_float(v, 10), v);
        // Half a unit rounds away from zero; negative values mirror positive ones.
        assert_eq!(round_float(1.0 + 2f32.powi(-9), 8), 1.0 + 2f32.powi(-8));
        assert_eq!(round_float(-(1.0 + 2f32.powi(-9)), 8), -(1.0 + 2f32.powi(-8)));
        // A carry moves to the next binade.
        assert_eq!(round_float(2.0 - 2f32.powi(-20), 8), 2.0);
        for special in [0.0, -0.0, f32::INFINITY, f32::NEG_INFINITY, f32::MAX] {
            assert_eq!(round_float(special, 8).to_bits(), special.to_bits());
        }
        assert!(round_float(f32::NAN, 8).is_nan());
        let mut values: Vec<f32> = (0..20_000).map(|i| ((i as f32) * 0.7361).sin() * 10f32.powi(i % 7 - 3)).collect();
        values.sort_by(f32::total_cmp);
        let rounded: Vec<f32> = values.iter().map(|&v| round_float(v, 12)).collect();
        assert!(rounded.windows(2).all(|w| w[0] <= w[1]), "monotone");
        for (v, r) in values.iter().zip(&rounded) {
            assert!((v - r).abs() <= v.abs() * 2f32.powi(-13) * 1.0001, "{v} → {r}");
        }
    }

    #[test]
    fn normals_round_per_component_and_stay_close() {
        let n = glam::Vec3::new(0.3, -0.8, 0.52).normalize();
        let packed = treelod_format::pack::oct_encode(n.to_array());
        let rounded = round_normal(packed, 10);
        assert_eq!(rounded & 0x3F, 0, "low 6 bits of x cleared");
        let back = glam::Vec3::from_array(treelod_format::pack::oct_decode(rounded));
        assert!(back.angle_between(n) < 0.3f32.to_radians(), "{back} vs {n}");
        assert_eq!(round_normal(packed, 16), packed);
    }
}
