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
    /// a `width`×`height` viewport: the runtime's projection ([`treelod_runtime::look_at_matrices`],
    /// near plane 0.05 m, far plane 20 km).
    #[must_use]
    pub fn look_at(eye: Vec3, target: Vec3, fovy: f32, width: u32, height: u32) -> Self {
        let (view, proj) = treelod_runtime::look_at_matrices(eye, target, fovy, width, height);
        Self { position: eye, view, proj, fovy, width, height }
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
