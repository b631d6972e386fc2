//! The white-noise cube map of Clasen's ellipsoids (Clasen and Prohaska 2011, §3.1 and §5): one
//! RGBA8 cube, `NOISE_SIZE`² texels per face, with every mip level down to 1×1. Alpha is the
//! grey noise of the alpha test (a texel is a hole where it is below the ellipsoid's
//! `alpha_threshold`), RGB a random unit vector `(n + 1) / 2` towards which the ellipsoid's normal
//! is blended. The paper's "mip-map texture for level `l` has 2^l × 2^l texels": level `l` is mip
//! `log2(NOISE_SIZE) − l` here.
//!
//! Each mip level is white noise of its own, uniform over `[0, 1]`, not the average of the finer
//! level (an average would pull alpha towards 1/2, and a threshold `t` would then remove less or
//! more than the share `t` of a distant ellipsoid's surface); it is sampled with the nearest texel
//! of the nearest level, so at every level a threshold `t` removes the share `t` of the surface.
//! Built on the CPU once per renderer, deterministically (a SplitMix64 hash of face, level and
//! texel).

/// Texels along a face's side at mip 0: the paper's level 6.
pub const NOISE_SIZE: u32 = 64;

/// Mip levels of the cube: `NOISE_SIZE` down to 1.
pub const NOISE_LEVELS: u32 = NOISE_SIZE.ilog2() + 1;

/// One SplitMix64 step from `x` ([`treelod_format::SplitMix64`]): a well-mixed 64-bit hash of `x`,
/// chained over a texel's values.
fn mix(x: u64) -> u64 {
    treelod_format::SplitMix64(x).next_u64()
}

/// The RGBA8 texels of one face at one level, rows top to bottom.
#[must_use]
pub fn face_texels(face: u32, level: u32) -> Vec<u8> {
    let side = (NOISE_SIZE >> level).max(1);
    let mut texels = Vec::with_capacity((side * side * 4) as usize);
    for i in 0..side * side {
        let mut h = mix((u64::from(level) << 40) ^ (u64::from(face) << 32) ^ u64::from(i));
        // A unit vector uniform on the sphere (Marsaglia's cylinder: z uniform, angle uniform).
        let mut unit = || {
            h = mix(h);
            #[expect(clippy::cast_precision_loss, reason = "24 bits of the hash are exact in f32")]
            let u = (h >> 40) as f32 / (1u64 << 24) as f32;
            u
        };
        let z = 2.0 * unit() - 1.0;
        let angle = std::f32::consts::TAU * unit();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let n = [r * angle.cos(), r * angle.sin(), z];
        #[expect(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "rounded into 0..=255")]
        let byte = |v: f32| ((v * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8;
        h = mix(h);
        // Alpha: 0..=255 uniformly.
        let alpha = (h >> 56) as u8;
        texels.extend_from_slice(&[byte(n[0]), byte(n[1]), byte(n[2]), alpha]);
    }
    texels
}

/// The sampler of the noise: nearest texel of the nearest level (see the module documentation).
#[must_use]
pub fn sampler(device: &wgpu::Device) -> wgpu::Sampler {
    device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("treelod ellipsoid noise"),
        mag_filter: wgpu::FilterMode::Nearest,
        min_filter: wgpu::FilterMode::Nearest,
        mipmap_filter: wgpu::MipmapFilterMode::Nearest,
        ..wgpu::SamplerDescriptor::default()
    })
}

/// Uploads the noise cube; returns its cube view and the bytes uploaded.
#[must_use]
pub fn upload(device: &wgpu::Device, queue: &wgpu::Queue) -> (wgpu::TextureView, u64) {
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("treelod ellipsoid noise"),
        size: wgpu::Extent3d { width: NOISE_SIZE, height: NOISE_SIZE, depth_or_array_layers: 6 },
        mip_level_count: NOISE_LEVELS,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let mut bytes = 0;
    for level in 0..NOISE_LEVELS {
        let side = (NOISE_SIZE >> level).max(1);
        for face in 0..6 {
            let texels = face_texels(face, level);
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: level,
                    origin: wgpu::Origin3d { x: 0, y: 0, z: face },
                    aspect: wgpu::TextureAspect::All,
                },
                &texels,
                wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(side * 4), rows_per_image: Some(side) },
                wgpu::Extent3d { width: side, height: side, depth_or_array_layers: 1 },
            );
            bytes += texels.len() as u64;
        }
    }
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::Cube),
        ..wgpu::TextureViewDescriptor::default()
    });
    (view, bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_build_reads_the_same_grey_and_random_vector_at_every_texel() {
        use glam::Vec3;
        use treelod_build::raster::{noise_grey, noise_vector};
        for level in 0..=NOISE_SIZE.ilog2() {
            let side = (NOISE_SIZE >> level).max(1);
            for face in 0..6u32 {
                let texels = face_texels(face, level);
                for (i, texel) in texels.chunks_exact(4).enumerate() {
                    // The texel's centre on the face, then the direction that samples it.
                    let (row, column) = (i as u32 / side, i as u32 % side);
                    let sc = 2.0 * (column as f32 + 0.5) / side as f32 - 1.0;
                    let tc = 2.0 * (row as f32 + 0.5) / side as f32 - 1.0;
                    let d = match face {
                        0 => Vec3::new(1.0, -tc, -sc),
                        1 => Vec3::new(-1.0, -tc, sc),
                        2 => Vec3::new(sc, 1.0, tc),
                        3 => Vec3::new(sc, -1.0, -tc),
                        4 => Vec3::new(sc, -tc, 1.0),
                        _ => Vec3::new(-sc, -tc, -1.0),
                    };
                    assert_eq!(noise_grey(d, level), texel[3], "level {level} face {face} texel {i}");
                    let rgb = Vec3::new(f32::from(texel[0]), f32::from(texel[1]), f32::from(texel[2])) / 255.0;
                    assert_eq!(noise_vector(d, level), rgb * 2.0 - Vec3::ONE, "level {level} face {face} texel {i}");
                }
            }
        }
    }

    #[test]
    fn every_level_is_uniform_white_noise_of_its_own() {
        for level in 0..NOISE_LEVELS - 2 {
            let texels: Vec<u8> = (0..6).flat_map(|face| face_texels(face, level)).collect();
            let alpha: Vec<f64> = texels.chunks_exact(4).map(|t| f64::from(t[3]) / 255.0).collect();
            let n = alpha.len() as f64;
            let below = |t: f64| alpha.iter().filter(|&&a| a < t).count() as f64 / n;
            // 6·64² texels at level 0, 6·4² at level 4: the share under t is t within sampling noise.
            let tolerance = 4.0 * (0.25 / n).sqrt() + 0.01;
            for t in [0.25, 0.5, 0.75] {
                assert!((below(t) - t).abs() < tolerance, "level {level}: {} below {t}", below(t));
            }
            for t in texels.chunks_exact(4) {
                let v = [t[0], t[1], t[2]].map(|c| f32::from(c) / 127.5 - 1.0);
                let length = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!((length - 1.0).abs() < 0.02, "a unit normal: {v:?}");
            }
        }
        assert_eq!(face_texels(2, 1), face_texels(2, 1), "deterministic");
        assert_ne!(face_texels(2, 1), face_texels(3, 1));
        assert_eq!(face_texels(0, NOISE_LEVELS - 1).len(), 4);
    }
}
