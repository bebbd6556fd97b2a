//! What every method's CPU work starts from: where the camera and the sun are.

use glam::Vec3;

use crate::render::camera::{Camera, Frustum};

/// Where the camera and sun are for a method's CPU work.
#[derive(Clone, Copy)]
pub struct PrepareView<'a> {
    pub camera: &'a Camera,
    /// Focal length in pixels (the texel criterion's scale).
    pub focal_px: f32,
    /// Unit direction to the sun.
    pub to_sun: Vec3,
    pub frustum: &'a Frustum,
}
