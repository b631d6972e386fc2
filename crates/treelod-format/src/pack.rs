//! Encoders and decoders for the packed fields of spec §2: octahedral normals, RGBA8 colours and
//! unorm16 pairs; and, for tests, the byte shuffle of compressed record arrays (spec §8) done
//! whole (the writer and reader stream it).

/// Encodes a unit vector as an octahedral `snorm16×2` normal (spec §2).
///
/// A zero or non-finite vector encodes as `+Z`.
#[must_use]
pub fn oct_encode(n: [f32; 3]) -> u32 {
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    if !(l1.is_finite() && l1 > 0.0) {
        return oct_encode([0.0, 0.0, 1.0]);
    }
    let (mut x, mut y) = (n[0] / l1, n[1] / l1);
    if n[2] < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sign(ox);
        y = (1.0 - ox.abs()) * sign(oy);
    }
    u32::from(snorm16(x)) | (u32::from(snorm16(y)) << 16)
}

/// Decodes an octahedral normal to a unit vector (spec §2).
#[must_use]
pub fn oct_decode(packed: u32) -> [f32; 3] {
    #[expect(clippy::cast_possible_truncation, reason = "taking the 16-bit halves")]
    let (x, y) = (unsnorm16(packed as u16), unsnorm16((packed >> 16) as u16));
    let mut v = [x, y, 1.0 - x.abs() - y.abs()];
    if v[2] < 0.0 {
        v[0] = (1.0 - y.abs()) * sign(x);
        v[1] = (1.0 - x.abs()) * sign(y);
    }
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / len, v[1] / len, v[2] / len]
}

/// Packs linear-alpha, sRGB-encoded channels in `[0, 1]` to RGBA8 (red in the low byte).
#[must_use]
pub fn rgba8(c: [f32; 4]) -> u32 {
    c.iter().enumerate().fold(0, |acc, (i, &v)| acc | (u32::from(unorm8(v)) << (8 * i)))
}

/// Unpacks RGBA8 to four values in `[0, 1]`.
#[must_use]
pub fn unpack_rgba8(packed: u32) -> [f32; 4] {
    core::array::from_fn(|i| f32::from(((packed >> (8 * i)) & 0xFF) as u8) / 255.0)
}

/// Packs two values in `[0, 1]` as unorm16 (first in the low half), as `PlaneRecord::uv_min`.
#[must_use]
pub fn unorm16x2(a: f32, b: f32) -> u32 {
    u32::from(unorm16(a)) | (u32::from(unorm16(b)) << 16)
}

/// Unpacks two unorm16 values.
#[must_use]
pub fn unpack_unorm16x2(packed: u32) -> [f32; 2] {
    [f32::from((packed & 0xFFFF) as u16) / 65535.0, f32::from((packed >> 16) as u16) / 65535.0]
}

/// The two unorm16 values of `packed` as their steps, `0..=65535` (first from the low half).
#[must_use]
pub fn unorm16x2_steps(packed: u32) -> [u32; 2] {
    [packed & 0xFFFF, packed >> 16]
}

fn sign(v: f32) -> f32 {
    if v >= 0.0 { 1.0 } else { -1.0 }
}

#[expect(clippy::cast_possible_truncation, reason = "clamped to the i16 range first")]
fn snorm16(v: f32) -> u16 {
    (v.clamp(-1.0, 1.0) * 32767.0).round() as i16 as u16
}

fn unsnorm16(v: u16) -> f32 {
    (f32::from(v as i16) / 32767.0).max(-1.0)
}

#[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to [0, 255]")]
fn unorm8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

#[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "clamped to [0, 65535]")]
fn unorm16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0).round() as u16
}

/// Byte shuffle (spec §8): byte `j` of record `i` of `records` goes to `out[j·n + i]` (`n` whole
/// records), grouping equal byte positions of neighbouring records. `out` holds at least `n`
/// records; bytes past the last whole record are not read.
#[cfg(test)]
pub(crate) fn shuffle(records: &[u8], record_size: usize, out: &mut [u8]) {
    let n = records.len() / record_size.max(1);
    for (i, record) in records.chunks_exact(record_size.max(1)).enumerate() {
        for (j, &byte) in record.iter().enumerate() {
            out[j * n + i] = byte;
        }
    }
}

/// Inverse of [`shuffle`]: byte `j·n + i` of `shuffled` goes to byte `j` of record `i` of `out`
/// (`n` whole records in `out`).
#[cfg(test)]
pub(crate) fn unshuffle(shuffled: &[u8], record_size: usize, out: &mut [u8]) {
    let n = out.len() / record_size.max(1);
    for (i, record) in out.chunks_exact_mut(record_size.max(1)).enumerate() {
        for (j, byte) in record.iter_mut().enumerate() {
            *byte = shuffled[j * n + i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octahedral_round_trip_is_within_a_thousandth() {
        let dirs = [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.577, -0.577, -0.577],
            [-0.3, 0.9, -0.3],
        ];
        for d in dirs {
            let len: f32 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let n = d.map(|c| c / len.sqrt());
            let back = oct_decode(oct_encode(n));
            for i in 0..3 {
                assert!((back[i] - n[i]).abs() < 1e-3, "{n:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn rgba8_is_red_in_the_low_byte() {
        assert_eq!(rgba8([1.0, 0.0, 0.0, 1.0]), 0xFF00_00FF);
        assert_eq!(unpack_rgba8(0xFF00_00FF), [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(unpack_unorm16x2(unorm16x2(0.0, 1.0)), [0.0, 1.0]);
    }
}
