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

    /// A camera from a host's matrices: `view` (world to view, right-handed, looking down −z) and
    /// a perspective `proj` (view to clip) for a `width`×`height` viewport. Any depth convention
    /// and far plane will do — standard or reverse Z ([`crate::DepthConvention`]), finite or
    /// infinite — as long as the frustum's sides are symmetric about the view axis. The eye is
    /// where `view` puts the origin, the vertical field of view `2·atan(1 / proj.y_axis.y)`.
    ///
    /// Selection measures sizes in pixels through the field of view, so an orthographic `proj`
    /// (`proj.w_axis.w == 1`) has no meaning here: check for one before calling.
    #[must_use]
    pub fn from_matrices(view: Mat4, proj: Mat4, width: u32, height: u32) -> Self {
        let position = view.inverse().w_axis.truncate();
        let fovy = 2.0 * (1.0 / proj.y_axis.y).atan();
        Self { position, view, proj, fovy, width, height }
    }

    /// `proj · view`.
    #[must_use]
    pub fn view_proj(&self) -> Mat4 {
        self.proj * self.view
    }

    /// The camera as the runtime's selection and policy read it: the eye, `proj · view`, the
    /// viewport's height in pixels and the vertical field of view.
    #[must_use]
    pub(crate) fn selection(&self) -> treelod_runtime::Camera {
        treelod_runtime::Camera {
            position: self.position,
            view_proj: self.view_proj(),
            viewport_height: self.height as f32,
            fovy: self.fovy,
        }
    }

    /// The camera's right and up directions in world space.
    #[must_use]
    pub fn right_up(&self) -> (Vec3, Vec3) {
        let inverse = self.view.inverse();
        (inverse.x_axis.truncate().normalize_or(Vec3::X), inverse.y_axis.truncate().normalize_or(Vec3::Y))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_matrices_recovers_the_eye_and_field_of_view() {
        let eye = Vec3::new(3.0, 5.0, -12.0);
        let looked = Camera::look_at(eye, Vec3::new(-1.0, 2.0, 4.0), 0.7, 640, 360);
        let made = Camera::from_matrices(looked.view, looked.proj, 640, 360);
        assert!(made.position.distance(eye) < 1e-4, "{} against {eye}", made.position);
        assert!((made.fovy - 0.7).abs() < 1e-5, "{}", made.fovy);
        assert_eq!((made.view, made.proj, made.width, made.height), (looked.view, looked.proj, 640, 360));
        // Reverse Z with an infinite far plane (as Bevy projects) gives the same field of view.
        let reverse = glam::camera::rh::proj::directx::perspective_infinite_reverse(1.1, 16.0 / 9.0, 0.1);
        assert!((Camera::from_matrices(looked.view, reverse, 640, 360).fovy - 1.1).abs() < 1e-5);
    }
}
