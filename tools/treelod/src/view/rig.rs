//! The viewer's camera: a fly camera (keys and mouse), or an orbit about the scene's centre at a
//! distance counted in bounding radii (the unit `eval` reports distances in), optionally animated
//! (turning about the scene, or approaching it and backing away) to watch transitions of level and
//! representation.

use glam::Vec3;

/// How the camera is moved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Keys W, A, S, D, Q, E and a mouse drag move a free camera.
    Fly,
    /// The camera looks at the scene's centre from [`Rig::distance`] bounding radii; a drag turns
    /// it about the centre.
    Orbit,
}

/// What the orbit does on its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Animation {
    /// Nothing.
    Still,
    /// Turns about the vertical through the centre at [`TURN_DEGREES_PER_SECOND`].
    Turn,
    /// Sweeps the distance from [`APPROACH_FAR`] to [`APPROACH_NEAR`] radii and back, evenly in
    /// its logarithm (each octave of distance, so each level of detail, gets the same time), over
    /// [`APPROACH_SECONDS`].
    Approach,
}

/// Degrees per second of [`Animation::Turn`].
pub const TURN_DEGREES_PER_SECOND: f32 = 20.0;
/// Nearest distance of [`Animation::Approach`], bounding radii.
pub const APPROACH_NEAR: f32 = 1.5;
/// Farthest distance of [`Animation::Approach`], bounding radii (beyond `eval`'s 32).
pub const APPROACH_FAR: f32 = 48.0;
/// Seconds of one approach and retreat.
pub const APPROACH_SECONDS: f32 = 24.0;
/// The range of the distance slider, bounding radii.
pub const DISTANCE_RANGE: (f32, f32) = (0.5, 256.0);
/// Elevation limit, radians (short of straight up or down, where the view's up is undefined).
const PITCH_LIMIT: f32 = 1.55;

/// The camera: its mode, the fly camera's pose and the orbit's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rig {
    pub mode: Mode,
    pub animation: Animation,
    /// Fly: eye position, metres.
    pub position: Vec3,
    /// Fly: turn about +y, radians; 0 looks down −z.
    pub yaw: f32,
    /// Fly: elevation of the view direction, radians.
    pub pitch: f32,
    /// Fly: metres per second.
    pub speed: f32,
    /// Orbit: the point looked at (the scene's centre).
    pub centre: Vec3,
    /// Orbit: the scene's bounding radius, metres (half its bounds' diagonal).
    pub radius: f32,
    /// Orbit: distance from the centre, bounding radii.
    pub distance: f32,
    /// Orbit: direction from the centre to the eye, about +y, radians (0: towards +z).
    pub azimuth: f32,
    /// Orbit: elevation of the eye above the centre, radians.
    pub elevation: f32,
    /// Seconds into [`Animation::Approach`]'s period.
    approach_time: f32,
}

impl Rig {
    /// A fly camera at `eye` looking at `target`, over a scene with bounds `(min, max)`.
    #[must_use]
    pub fn new(bounds: (Vec3, Vec3), eye: Vec3, target: Vec3) -> Self {
        let forward = (target - eye).normalize_or(Vec3::NEG_Z);
        let (min, max) = bounds;
        let mut rig = Self {
            mode: Mode::Fly,
            animation: Animation::Still,
            position: eye,
            yaw: forward.x.atan2(-forward.z),
            pitch: forward.y.clamp(-1.0, 1.0).asin().clamp(-PITCH_LIMIT, PITCH_LIMIT),
            speed: 0.25 * (max - min).length().max(4.0),
            centre: 0.5 * (min + max),
            radius: (0.5 * (max - min).length()).max(0.01),
            distance: 4.0,
            azimuth: 0.0,
            elevation: 0.0,
            approach_time: 0.0,
        };
        rig.orbit_from_fly();
        rig
    }

    /// The fly camera's unit view direction.
    #[must_use]
    pub fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(cp * sy, sp, -cp * cy)
    }

    /// Where the camera is and the point it looks at.
    #[must_use]
    pub fn eye_and_target(&self) -> (Vec3, Vec3) {
        match self.mode {
            Mode::Fly => (self.position, self.position + self.forward()),
            Mode::Orbit => (self.orbit_eye(), self.centre),
        }
    }

    fn orbit_eye(&self) -> Vec3 {
        let (sa, ca) = self.azimuth.sin_cos();
        let (se, ce) = self.elevation.sin_cos();
        self.centre + self.distance * self.radius * Vec3::new(ce * sa, se, ce * ca)
    }

    /// Switches to `mode`, starting from the current view: the orbit from where the fly camera
    /// stands (its distance and direction from the centre), the fly camera from the orbit's eye
    /// looking at the centre.
    pub fn set_mode(&mut self, mode: Mode) {
        if mode == self.mode {
            return;
        }
        match mode {
            Mode::Orbit => self.orbit_from_fly(),
            Mode::Fly => {
                let eye = self.orbit_eye();
                let forward = (self.centre - eye).normalize_or(Vec3::NEG_Z);
                self.position = eye;
                self.yaw = forward.x.atan2(-forward.z);
                self.pitch = forward.y.clamp(-1.0, 1.0).asin().clamp(-PITCH_LIMIT, PITCH_LIMIT);
                self.animation = Animation::Still;
            }
        }
        self.mode = mode;
    }

    fn orbit_from_fly(&mut self) {
        let offset = self.position - self.centre;
        let length = offset.length();
        if length > 1e-6 {
            self.distance = (length / self.radius).clamp(DISTANCE_RANGE.0, DISTANCE_RANGE.1);
            self.azimuth = offset.x.atan2(offset.z);
            self.elevation = (offset.y / length).clamp(-1.0, 1.0).asin().clamp(-PITCH_LIMIT, PITCH_LIMIT);
        }
    }

    /// A mouse drag of `(dx, dy)` radians: turns the fly camera's view, or the orbit's eye about
    /// the centre.
    pub fn drag(&mut self, dx: f32, dy: f32) {
        match self.mode {
            Mode::Fly => {
                self.yaw += dx;
                self.pitch = (self.pitch - dy).clamp(-PITCH_LIMIT, PITCH_LIMIT);
            }
            Mode::Orbit => {
                self.azimuth -= dx;
                self.elevation = (self.elevation + dy).clamp(-PITCH_LIMIT, PITCH_LIMIT);
            }
        }
    }

    /// Advances `dt` seconds: the fly camera by `movement` (forward, right, up, each −1..1, times
    /// `boost`), the orbit by its animation. Movement keys switch an orbit to flying.
    pub fn advance(&mut self, dt: f32, movement: Vec3, boost: f32) {
        if movement != Vec3::ZERO {
            self.set_mode(Mode::Fly);
        }
        match self.mode {
            Mode::Fly => {
                let forward = self.forward();
                let right = forward.cross(Vec3::Y).normalize_or(Vec3::X);
                let direction = forward * movement.x + right * movement.y + Vec3::Y * movement.z;
                self.position += direction.normalize_or_zero() * self.speed * boost * dt;
            }
            Mode::Orbit => match self.animation {
                Animation::Still => {}
                Animation::Turn => self.azimuth += TURN_DEGREES_PER_SECOND.to_radians() * dt,
                Animation::Approach => {
                    self.approach_time = (self.approach_time + dt) % APPROACH_SECONDS;
                    self.distance = approach_distance(self.approach_time);
                }
            },
        }
    }

    /// Starts `animation` (switching to the orbit); an approach starts from the current distance,
    /// moving in.
    pub fn animate(&mut self, animation: Animation) {
        self.set_mode(Mode::Orbit);
        if animation == Animation::Approach && self.animation != Animation::Approach {
            self.approach_time = approach_time_at(self.distance);
        }
        self.animation = animation;
    }
}

/// The approach's distance `t` seconds into its period: from [`APPROACH_FAR`] down to
/// [`APPROACH_NEAR`] over the first half, back over the second, linear in the logarithm.
#[must_use]
pub fn approach_distance(t: f32) -> f32 {
    let phase = (t / APPROACH_SECONDS).rem_euclid(1.0);
    let towards_near = 1.0 - (2.0 * phase - 1.0).abs();
    (APPROACH_FAR.ln() + (APPROACH_NEAR.ln() - APPROACH_FAR.ln()) * towards_near).exp()
}

/// The time of the approach's first half at which it is `distance` away (clamped to its range).
fn approach_time_at(distance: f32) -> f32 {
    let d = distance.clamp(APPROACH_NEAR, APPROACH_FAR);
    let towards_near = (d.ln() - APPROACH_FAR.ln()) / (APPROACH_NEAR.ln() - APPROACH_FAR.ln());
    0.5 * towards_near * APPROACH_SECONDS
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> Rig {
        Rig::new(
            (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 4.0, 1.0)),
            Vec3::new(0.0, 2.0, 10.0),
            Vec3::new(0.0, 2.0, 0.0),
        )
    }

    #[test]
    fn the_fly_camera_starts_looking_at_its_target() {
        let rig = rig();
        let (eye, target) = rig.eye_and_target();
        assert_eq!(eye, Vec3::new(0.0, 2.0, 10.0));
        assert!(((target - eye).normalize() - Vec3::NEG_Z).length() < 1e-5);
    }

    #[test]
    fn switching_to_the_orbit_keeps_the_eye_and_looks_at_the_centre() {
        let mut rig = rig();
        rig.set_mode(Mode::Orbit);
        let (eye, target) = rig.eye_and_target();
        assert!((eye - Vec3::new(0.0, 2.0, 10.0)).length() < 1e-4, "{eye}");
        assert_eq!(target, Vec3::new(0.0, 2.0, 0.0));
        // Radius: half the diagonal of 2 × 4 × 2 m.
        assert!((rig.distance * rig.radius - 10.0).abs() < 1e-4);
        // And back: the fly camera takes the orbit's pose.
        rig.distance = 2.0;
        rig.set_mode(Mode::Fly);
        let (eye, target) = rig.eye_and_target();
        assert!((eye - Vec3::new(0.0, 2.0, 2.0 * rig.radius)).length() < 1e-4, "{eye}");
        assert!(((target - eye).normalize() - Vec3::NEG_Z).length() < 1e-5);
    }

    #[test]
    fn movement_keys_leave_the_orbit_for_flying_where_it_was() {
        let mut rig = rig();
        rig.animate(Animation::Turn);
        rig.advance(1.0, Vec3::ZERO, 1.0);
        assert_eq!(rig.mode, Mode::Orbit);
        assert!((rig.azimuth - TURN_DEGREES_PER_SECOND.to_radians()).abs() < 1e-5);
        let before = rig.eye_and_target().0;
        rig.advance(0.5, Vec3::X, 1.0);
        assert_eq!((rig.mode, rig.animation), (Mode::Fly, Animation::Still));
        let after = rig.eye_and_target().0;
        assert!(((after - before).length() - 0.5 * rig.speed).abs() < 1e-3, "{before} -> {after}");
    }

    #[test]
    fn the_approach_sweeps_the_distance_evenly_in_octaves_and_comes_back() {
        assert!((approach_distance(0.0) - APPROACH_FAR).abs() < 1e-3);
        assert!((approach_distance(0.5 * APPROACH_SECONDS) - APPROACH_NEAR).abs() < 1e-4);
        assert!((approach_distance(APPROACH_SECONDS) - APPROACH_FAR).abs() < 1e-3);
        // A quarter of the way in time is half way in the logarithm.
        let middle = (APPROACH_FAR * APPROACH_NEAR).sqrt();
        assert!((approach_distance(0.25 * APPROACH_SECONDS) - middle).abs() < 1e-3);
        // Starting an approach continues from the current distance, moving in.
        let mut rig = rig();
        rig.set_mode(Mode::Orbit);
        rig.distance = 8.0;
        rig.animate(Animation::Approach);
        rig.advance(1e-3, Vec3::ZERO, 1.0);
        assert!((rig.distance - 8.0).abs() < 0.01 && rig.distance < 8.0, "{}", rig.distance);
    }

    #[test]
    fn dragging_turns_the_view_or_the_orbit_within_the_elevation_limit() {
        let mut rig = rig();
        rig.drag(0.1, 10.0);
        assert!((rig.yaw - 0.1).abs() < 1e-6);
        assert!((rig.pitch + PITCH_LIMIT).abs() < 1e-6);
        rig.set_mode(Mode::Orbit);
        rig.drag(0.0, -10.0);
        assert!((rig.elevation + PITCH_LIMIT).abs() < 1e-6);
    }
}
