//! Drawing offscreen for measuring: the camera that frames a scene, the clear colour of an sRGB
//! background, streaming settled before an image is taken, and PNG encoding; shared by `eval`,
//! `bench` and `treelod render`.

use glam::Vec3;
use treelod_render::offscreen::{Gpu, Image};
use treelod_render::{Camera, Renderer};

/// The direction from the target towards the eye when the camera frames the scene: in front
/// (+z), to the right and a little above.
pub const FRAMING_DIRECTION: Vec3 = Vec3::new(0.6, 0.45, 1.0);

/// Frames at most prepared before the image while streaming catches up with the selection.
const MAX_STREAMING_FRAMES: u32 = 1000;

/// Prepares frames until every draw's prefix is resident (the renderer streams triangles and
/// points within a per-frame upload budget), so the image shows the selection rather than the
/// coarser stand-ins of a first frame.
/// With shadows, the cascades' draws too ([`treelod_render::ShadowStats::ranges_clamped`]).
/// Trees in a transition between techniques ([`treelod_render::Policy::transition`]) finish it
/// too, so a still measures the policy's choice at the pose, not a blend with the last pose's.
pub fn settle_streaming(gpu: &Gpu, renderer: &mut Renderer, camera: &Camera) {
    for _ in 0..MAX_STREAMING_FRAMES {
        let stats = renderer.prepare(&gpu.device, &gpu.queue, camera);
        gpu.queue.submit([]);
        let streamed = (stats.ranges_clamped == 0 && stats.shadow.ranges_clamped == 0) || stats.bytes_uploaded == 0;
        if streamed && stats.transitions == 0 {
            break;
        }
    }
    // The queue's copies of what settling streamed (tens of megabytes on a large model) run on
    // the device after their submission: waited for here, so that the next frame's wall clock
    // (`bench`'s `selection_ms`) is that frame's own work, not the tail of the loading's.
    // A device lost here shows at the next frame's render or read-back.
    let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
}

/// The camera: `eye` and `target` as given; a missing target is the centre of `bounds`; a missing
/// eye stands back from the target along [`FRAMING_DIRECTION`] far enough that the sphere around
/// `bounds` (centred on the target) fits the field of view.
pub fn frame_camera(
    bounds: (Vec3, Vec3),
    eye: Option<Vec3>,
    target: Option<Vec3>,
    fovy: f32,
    width: u32,
    height: u32,
) -> Camera {
    let (lo, hi) = bounds;
    let target = target.unwrap_or(0.5 * (lo + hi));
    let eye = eye.unwrap_or_else(|| {
        // The farthest corner of the bounds from the target.
        let radius = (target - lo).abs().max((hi - target).abs()).length().max(0.1);
        let aspect = width.max(1) as f32 / height.max(1) as f32;
        let half_x = ((0.5 * fovy).tan() * aspect).atan();
        let half = (0.5 * fovy).min(half_x);
        let distance = 1.05 * radius / half.sin();
        target + FRAMING_DIRECTION.normalize() * distance
    });
    Camera::look_at(eye, target, fovy, width, height)
}

/// The clear colour whose sRGB encoding is `rgb` (the target is sRGB, the clear value linear).
pub fn clear_colour(rgb: [u8; 3]) -> wgpu::Color {
    let linear = |c: u8| {
        let c = f64::from(c) / 255.0;
        if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
    };
    wgpu::Color { r: linear(rgb[0]), g: linear(rgb[1]), b: linear(rgb[2]), a: 1.0 }
}

/// The image as an 8-bit RGBA PNG tagged sRGB.
/// # Errors
/// The PNG encoder's, if the image's pixels do not match its size.
pub fn encode_png(image: &Image) -> Result<Vec<u8>, png::EncodingError> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, image.width, image.height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&image.rgba)?;
        writer.finish()?;
    }
    Ok(bytes)
}
