//! The camera a frame is drawn and selected with.

use glam::{Mat4, Vec3};

/// A perspective camera: where it is, how it projects, and the viewport it fills.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, world space, metres.
    pub position: Vec3,
    /// World to view (right-handed, looking down −z).
    pub view: Mat4,
    /// View to clip, WebGPU depth range 0..1.
    pub proj: Mat4,
    /// Vertical field of view, radians.
    pub fovy: f32,
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
}

impl Camera {
    /// A camera at `eye` looking at `target` with Y up, vertical field of view `fovy` (radians),
    /// a `width`×`height` viewport, near plane 0.05 m and far plane 20 km.
    #[must_use]
    pub fn look_at(eye: Vec3, target: Vec3, fovy: f32, width: u32, height: u32) -> Self {
        let forward = (target - eye).normalize_or(Vec3::NEG_Z);
        // Looking straight up or down: any up vector not parallel to the view direction.
        let up = if forward.cross(Vec3::Y).length_squared() < 1e-8 { Vec3::Z } else { Vec3::Y };
        let aspect = width.max(1) as f32 / height.max(1) as f32;
        Self {
            position: eye,
            view: glam::camera::rh::view::look_at_mat4(eye, target, up),
            proj: glam::camera::rh::proj::directx::perspective(fovy, aspect, 0.05, 20_000.0),
            fovy,
            width,
            height,
        }
    }

    /// `proj · view`.
    #[must_use]
    pub fn view_proj(&self) -> Mat4 {
        self.proj * self.view
    }

    /// The camera's right and up directions in world space.
    #[must_use]
    pub fn right_up(&self) -> (Vec3, Vec3) {
        let inverse = self.view.inverse();
        (inverse.x_axis.truncate().normalize_or(Vec3::X), inverse.y_axis.truncate().normalize_or(Vec3::Y))
    }
}
