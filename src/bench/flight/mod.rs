//! Flights: the camera paths (and sun and knob sweeps) the bench renders frame by frame. A
//! flight is a list of keys (camera position and look-at, optionally the sun's angles and
//! the `btf` knobs) read from a small TOML file or made by name from the scene's extent;
//! [`Flight::frames`] spreads any number of frames over it.
//!
//! ```toml
//! frames = 120            # optional: frames when the bench is not told
//! path = "catmull-rom"    # optional: "linear" (default) or "catmull-rom"
//! [[key]]
//! position = [0, 30, -200]
//! look_at = [0, 10, 0]
//! sun = [180, 45]         # optional: azimuth, elevation (degrees)
//! lod_scale = 1.0         # optional knobs: lod_scale, weight_threshold, lod_fade
//! [[key]]
//! t = 2.5                 # optional: every key has a time or none does (then 0, 1, 2...)
//! position = [0, 30, 200]
//! look_at = [0, 10, 0]
//! ```
//!
//! A key that does not set the sun or a knob keeps the value of the key before it (the
//! first keys take the first value given); a value no key sets stays unset, for the caller
//! to take from the scene or the configuration. Sun angles and knobs go linearly from key
//! to key; positions and look-ats linearly or by Catmull-Rom in time.
//!
//! This file holds the types and picks a flight by name or path; `file` reads and writes
//! flight files, `interpolate` spreads frames over the keys and `builtin` makes the named
//! flights.

mod builtin;
mod file;
mod interpolate;
#[cfg(test)]
mod test_support;

use std::path::Path;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::render::{FrameDesc, Sun};
use crate::{Error, Result};
use builtin::BUILTINS;

pub use builtin::{APPROACH_DISTANCES, FlightContext};

/// Largest number of frames a flight may ask for.
pub const MAX_FRAMES: usize = 100_000;
/// Largest number of keys in a flight file.
pub const MAX_KEYS: usize = 10_000;
/// Frames of a flight that does not say.
pub const DEFAULT_FRAMES: usize = 120;

/// How positions and look-ats go from key to key.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PathShape {
    /// Straight lines between keys (the camera turns sharply at a key).
    #[default]
    Linear,
    /// A Catmull-Rom spline through the keys, tangents from the neighbouring keys' times.
    CatmullRom,
}

/// The `btf` knobs a flight may sweep; `None` leaves the configuration's own value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Knobs {
    pub lod_scale: Option<f32>,
    pub weight_threshold: Option<f32>,
    pub lod_fade: Option<f32>,
}

/// One key of a flight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlightKey {
    /// Time of the key (increasing from key to key; any unit).
    pub t: f32,
    pub position: Vec3,
    pub look_at: Vec3,
    /// Sun azimuth and elevation (degrees), when this key sets them.
    pub sun: Option<[f32; 2]>,
    pub knobs: Knobs,
}

/// One frame of a flight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlightFrame {
    /// Its index in the flight (0-based).
    pub index: usize,
    pub t: f32,
    pub position: Vec3,
    pub look_at: Vec3,
    /// Sun azimuth and elevation (degrees); `None` keeps the scene's sun.
    pub sun: Option<[f32; 2]>,
    pub knobs: Knobs,
}

impl FlightFrame {
    /// Puts this frame's camera (keeping `desc`'s field of view), sun angles (keeping its
    /// colour) and knobs into a frame description.
    pub fn apply(&self, desc: &mut FrameDesc) {
        let fov = desc.camera.fov_y_deg;
        desc.camera = crate::render::Camera::look_at(self.position, self.look_at, fov);
        if let Some([azimuth, elevation]) = self.sun {
            desc.sun = Sun {
                azimuth_deg: azimuth,
                elevation_deg: elevation,
                ..desc.sun
            };
        }
        let k = &self.knobs;
        if let Some(v) = k.lod_scale {
            desc.btf.lod_scale = v;
        }
        if let Some(v) = k.weight_threshold {
            desc.btf.weight_threshold = v;
        }
        if let Some(v) = k.lod_fade {
            desc.btf.lod_fade = v;
        }
    }

    /// Distance from the camera to what it looks at (m).
    pub fn distance(&self) -> f32 {
        self.position.distance(self.look_at)
    }
}

/// A flight: at least two keys in increasing time.
#[derive(Clone, Debug, PartialEq)]
pub struct Flight {
    /// The built-in's name or the file's path, for messages and reports.
    pub name: String,
    pub keys: Vec<FlightKey>,
    pub path: PathShape,
    /// Frames to render when the caller does not say.
    pub default_frames: usize,
}

impl Flight {
    /// A flight file, or a built-in by name: `name_or_path` is read as a file when it ends
    /// in `.toml` or names an existing file.
    pub fn resolve(name_or_path: &str, ctx: &FlightContext<'_>) -> Result<Flight> {
        let path = Path::new(name_or_path);
        if name_or_path.ends_with(".toml") || path.is_file() {
            return Flight::load(path);
        }
        Flight::builtin(name_or_path, ctx).ok_or_else(|| {
            Error::BadInput(format!(
                "unknown flight `{name_or_path}`: give a flight file (.toml) or one of {}",
                BUILTINS.join(", ")
            ))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use test_support::{TWO_KEYS, context, hilly, parse};

    #[test]
    fn resolve_takes_files_and_names_and_lists_the_names_otherwise() {
        let terrain = hilly();
        let ctx = context(&terrain);
        assert_eq!(Flight::resolve("orbit", &ctx).unwrap().name, "orbit");
        let e = Flight::resolve("orbitt", &ctx).unwrap_err().to_string();
        assert!(
            e.contains("orbitt") && BUILTINS.iter().all(|n| e.contains(n)),
            "{e}"
        );
        let e = Flight::resolve("no/such/flight.toml", &ctx)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no/such/flight.toml"), "{e}");
        let dir = std::env::temp_dir().join(format!("canopy-flight-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("mine.toml");
        std::fs::write(&path, TWO_KEYS).unwrap();
        let f = Flight::resolve(path.to_str().unwrap(), &ctx).unwrap();
        assert_eq!(f.keys.len(), 2);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn apply_puts_camera_sun_and_knobs_into_the_frame() {
        let f = parse(TWO_KEYS).unwrap();
        let fr = f.frames(3)[1];
        let mut desc = FrameDesc::from_scene(&crate::scene::Scene::default_scene());
        let fov = desc.camera.fov_y_deg;
        fr.apply(&mut desc);
        assert_eq!(desc.camera.position, fr.position);
        assert_eq!(desc.camera.fov_y_deg, fov);
        assert!(
            desc.camera
                .forward()
                .dot((fr.look_at - fr.position).normalize())
                > 0.9999
        );
        assert_eq!(desc.sun.azimuth_deg, 150.0);
        assert_eq!(desc.btf.lod_scale, 2.0);
    }
}
