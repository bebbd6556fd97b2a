//! Fly-camera and sun controls, free of winit: the window shell translates events into these
//! calls, so the behaviour is tested without a window. WASD moves, Q/E go down/up, Shift is
//! faster, the wheel changes speed, the right button held turns the view, and the left button
//! held with Ctrl drags the sun.

use glam::Vec3;

use crate::render::{Camera, Sun};

/// Keys the controller cares about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FlyKey {
    Forward,
    Back,
    Left,
    Right,
    Down,
    Up,
    Fast,
}

#[derive(Clone, Debug)]
pub struct FlyController {
    /// Metres per second at normal speed.
    pub speed: f32,
    /// Radians per pixel of mouse motion.
    pub look_sensitivity: f32,
    held: [bool; 7],
    looking: bool,
    dragging_sun: bool,
}

impl Default for FlyController {
    fn default() -> Self {
        Self {
            speed: 20.0,
            look_sensitivity: 0.004,
            held: [false; 7],
            looking: false,
            dragging_sun: false,
        }
    }
}

impl FlyController {
    pub const MIN_SPEED: f32 = 0.5;
    pub const MAX_SPEED: f32 = 2000.0;

    pub fn key(&mut self, key: FlyKey, pressed: bool) {
        self.held[key as usize] = pressed;
    }

    pub fn is_held(&self, key: FlyKey) -> bool {
        self.held[key as usize]
    }

    /// Forgets held keys and buttons (the window lost focus).
    pub fn release_all(&mut self) {
        self.held = [false; 7];
        self.looking = false;
        self.dragging_sun = false;
    }

    /// Right button: look around while held.
    pub fn set_looking(&mut self, on: bool) {
        self.looking = on;
    }

    /// Left button with Ctrl: drag the sun while held.
    pub fn set_dragging_sun(&mut self, on: bool) {
        self.dragging_sun = on;
    }

    pub fn is_looking(&self) -> bool {
        self.looking
    }

    pub fn is_dragging_sun(&self) -> bool {
        self.dragging_sun
    }

    /// Mouse wheel: each notch scales the speed by 1.25.
    pub fn wheel(&mut self, notches: f32) {
        if notches.is_finite() {
            self.speed =
                (self.speed * 1.25f32.powf(notches)).clamp(Self::MIN_SPEED, Self::MAX_SPEED);
        }
    }

    /// Mouse motion in pixels: turns the camera or moves the sun, depending on what is held.
    /// Returns true if it changed something.
    pub fn mouse_moved(&mut self, dx: f32, dy: f32, camera: &mut Camera, sun: &mut Sun) -> bool {
        if !dx.is_finite() || !dy.is_finite() {
            return false;
        }
        if self.dragging_sun {
            sun.azimuth_deg = (sun.azimuth_deg + dx * 0.3).rem_euclid(360.0);
            sun.elevation_deg = (sun.elevation_deg - dy * 0.2).clamp(-10.0, 90.0);
            true
        } else if self.looking {
            camera.yaw -= dx * self.look_sensitivity;
            camera.pitch = (camera.pitch - dy * self.look_sensitivity)
                .clamp(-Camera::MAX_PITCH, Camera::MAX_PITCH);
            true
        } else {
            false
        }
    }

    /// Moves the camera for `dt` seconds of held keys. Returns true if it moved.
    pub fn update(&self, camera: &mut Camera, dt: f32) -> bool {
        let axis = |pos: FlyKey, neg: FlyKey| {
            f32::from(u8::from(self.is_held(pos))) - f32::from(u8::from(self.is_held(neg)))
        };
        let forward = camera.forward();
        let right = camera.right();
        let dir = forward * axis(FlyKey::Forward, FlyKey::Back)
            + right * axis(FlyKey::Right, FlyKey::Left)
            + Vec3::Y * axis(FlyKey::Up, FlyKey::Down);
        let dir = dir.normalize_or_zero();
        if dir == Vec3::ZERO || !dt.is_finite() || dt <= 0.0 {
            return false;
        }
        let boost = if self.is_held(FlyKey::Fast) { 5.0 } else { 1.0 };
        camera.position += dir * self.speed * boost * dt.min(0.25);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::look_at(Vec3::ZERO, Vec3::Z, 60.0)
    }

    fn sun() -> Sun {
        Sun {
            azimuth_deg: 0.0,
            elevation_deg: 30.0,
            color: Vec3::ONE,
            intensity: 1.0,
        }
    }

    #[test]
    fn w_moves_forward_and_shift_is_faster() {
        let mut c = cam();
        let mut f = FlyController::default();
        f.key(FlyKey::Forward, true);
        assert!(f.update(&mut c, 0.1));
        let slow = c.position.z;
        assert!((slow - 2.0).abs() < 1e-4, "{slow}");
        f.key(FlyKey::Fast, true);
        let mut c2 = cam();
        f.update(&mut c2, 0.1);
        assert!(c2.position.z > slow * 4.0);
    }

    #[test]
    fn opposite_keys_cancel_and_nothing_held_does_nothing() {
        let mut c = cam();
        let mut f = FlyController::default();
        assert!(!f.update(&mut c, 0.1));
        f.key(FlyKey::Up, true);
        f.key(FlyKey::Down, true);
        assert!(!f.update(&mut c, 0.1));
        f.key(FlyKey::Down, false);
        assert!(f.update(&mut c, 0.1));
        assert!(c.position.y > 0.0);
    }

    #[test]
    fn mouse_turns_only_while_looking_and_drags_the_sun_with_the_modifier() {
        let mut c = cam();
        let mut s = sun();
        let mut f = FlyController::default();
        assert!(!f.mouse_moved(50.0, 0.0, &mut c, &mut s));
        f.set_looking(true);
        assert!(f.mouse_moved(50.0, 0.0, &mut c, &mut s));
        assert!(c.yaw != 0.0);
        f.set_looking(false);
        f.set_dragging_sun(true);
        f.mouse_moved(100.0, -50.0, &mut c, &mut s);
        assert!((s.azimuth_deg - 30.0).abs() < 1e-3);
        assert!((s.elevation_deg - 40.0).abs() < 1e-3);
    }

    #[test]
    fn wheel_changes_speed_within_bounds() {
        let mut f = FlyController::default();
        f.wheel(1.0);
        assert!((f.speed - 25.0).abs() < 1e-4);
        f.wheel(1000.0);
        assert_eq!(f.speed, FlyController::MAX_SPEED);
        f.wheel(f32::NAN);
        assert_eq!(f.speed, FlyController::MAX_SPEED);
    }
}
