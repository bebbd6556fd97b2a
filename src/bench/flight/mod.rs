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

use std::path::Path;

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::model::{Terrain, World};
use crate::render::{FrameDesc, Sun};
use crate::{Error, Result};

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

/// What the built-in flights are made from: the extent of the scene's forest and one tree
/// near its centre to look at.
#[derive(Clone, Copy, Debug)]
pub struct FlightContext<'a> {
    /// The ground, so cameras stay above it.
    pub terrain: &'a Terrain,
    /// Centre of the forest's bounding square (x, z).
    pub centre: Vec2,
    /// Half the side of the forest's bounding square (m), at least a few metres.
    pub half_size: f32,
    /// Base of the focus tree's trunk.
    pub focus: Vec3,
    /// Height of the focus tree (m).
    pub focus_height: f32,
}

impl<'a> FlightContext<'a> {
    /// The context of a built world: its forest's bounding square and the tree nearest its
    /// centre. A world without trees uses its terrain's square and a 10 m stand-in tree at
    /// the centre.
    pub fn from_world(world: &'a World) -> Self {
        let trees = &world.forest.instances;
        let terrain = &world.terrain;
        let (lo, hi) = trees.iter().fold(
            (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
            |(lo, hi), t| {
                let p = Vec2::new(t.position.x, t.position.z);
                (lo.min(p), hi.max(p))
            },
        );
        let (centre, half_size) = if trees.is_empty() {
            (Vec2::ZERO, 0.5 * terrain.size)
        } else {
            (0.5 * (lo + hi), 0.5 * (hi - lo).max_element())
        };
        let nearest = trees.iter().min_by(|a, b| {
            let d = |t: &crate::model::TreeInstance| {
                Vec2::new(t.position.x, t.position.z).distance_squared(centre)
            };
            d(a).total_cmp(&d(b))
        });
        let (focus, focus_height) = match nearest {
            Some(t) => {
                let h = world
                    .species
                    .get(t.species as usize)
                    .map(|s| s.tree_bounds.max.y * t.scale)
                    .filter(|h| h.is_finite() && *h > 0.0)
                    .unwrap_or(10.0);
                (t.position, h)
            }
            None => (
                Vec3::new(centre.x, terrain.height_at(centre.x, centre.y), centre.y),
                10.0,
            ),
        };
        FlightContext {
            terrain,
            centre,
            half_size: half_size.max(5.0),
            focus,
            focus_height,
        }
    }

    fn ground(&self, x: f32, z: f32) -> f32 {
        self.terrain.height_at(x, z)
    }

    /// A point `above` metres over the ground at (x, z).
    fn over_ground(&self, x: f32, z: f32, above: f32) -> Vec3 {
        Vec3::new(x, self.ground(x, z) + above, z)
    }

    /// Middle of the focus tree's crown region: what the close flights look at.
    fn focus_point(&self) -> Vec3 {
        self.focus + Vec3::Y * (0.5 * self.focus_height)
    }
}

/// The flight file as written.
#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct FlightFile {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    frames: Option<usize>,
    #[serde(default)]
    path: PathShape,
    #[serde(rename = "key", default)]
    keys: Vec<KeyFile>,
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct KeyFile {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    t: Option<f32>,
    position: [f32; 3],
    look_at: [f32; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sun: Option<[f32; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    lod_scale: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    weight_threshold: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    lod_fade: Option<f32>,
}

/// The names of the built-in flights, in the order they are listed.
const BUILTINS: [&str; 5] = ["overview", "walk", "approach", "sunset", "orbit"];

impl Flight {
    /// Names accepted by [`Flight::builtin`].
    pub fn builtin_names() -> &'static [&'static str] {
        &BUILTINS
    }

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

    /// Reads a flight file.
    pub fn load(path: &Path) -> Result<Flight> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            Error::BadInput(format!(
                "cannot read flight file {}: {e}; check the path",
                path.display()
            ))
        })?;
        Flight::parse(&text, &path.display().to_string())
    }

    /// Parses a flight file's text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Flight> {
        let bad = |what: String| Error::BadInput(format!("flight {origin}: {what}"));
        let file: FlightFile = toml::from_str(text).map_err(|e| {
            bad(format!(
                "{}; the file has an optional `frames` and `path` and `[[key]]` tables with \
                 `position`, `look_at` and optionally `t`, `sun`, `lod_scale`, \
                 `weight_threshold`, `lod_fade`",
                e.to_string().trim_end()
            ))
        })?;
        if file.keys.len() < 2 {
            return Err(bad(format!(
                "has {} [[key]] table(s); a flight needs at least 2 keys",
                file.keys.len()
            )));
        }
        if file.keys.len() > MAX_KEYS {
            return Err(bad(format!(
                "has {} keys; at most {MAX_KEYS} are allowed",
                file.keys.len()
            )));
        }
        let timed = file.keys.iter().filter(|k| k.t.is_some()).count();
        if timed != 0 && timed != file.keys.len() {
            return Err(bad(format!(
                "{timed} of {} keys have a `t`; give every key a time or none",
                file.keys.len()
            )));
        }
        if let Some(n) = file.frames
            && !(2..=MAX_FRAMES).contains(&n)
        {
            return Err(bad(format!("frames = {n}; use 2..={MAX_FRAMES}")));
        }
        let keys = file
            .keys
            .iter()
            .enumerate()
            .map(|(i, k)| FlightKey {
                t: k.t.unwrap_or(i as f32),
                position: Vec3::from(k.position),
                look_at: Vec3::from(k.look_at),
                sun: k.sun,
                knobs: Knobs {
                    lod_scale: k.lod_scale,
                    weight_threshold: k.weight_threshold,
                    lod_fade: k.lod_fade,
                },
            })
            .collect();
        let flight = Flight {
            name: origin.to_owned(),
            keys,
            path: file.path,
            default_frames: file.frames.unwrap_or(DEFAULT_FRAMES),
        };
        flight.check().map_err(bad)?;
        Ok(flight)
    }

    /// The flight as a flight file (built-ins can be saved, edited and read back).
    pub fn to_toml(&self) -> String {
        let file = FlightFile {
            frames: Some(self.default_frames),
            path: self.path,
            keys: self
                .keys
                .iter()
                .map(|k| KeyFile {
                    t: Some(k.t),
                    position: k.position.to_array(),
                    look_at: k.look_at.to_array(),
                    sun: k.sun,
                    lod_scale: k.knobs.lod_scale,
                    weight_threshold: k.knobs.weight_threshold,
                    lod_fade: k.knobs.lod_fade,
                })
                .collect(),
        };
        toml::to_string(&file).unwrap_or_default()
    }

    /// Checks the keys; the message says which key and what to change.
    fn check(&self) -> Result<(), String> {
        if self.keys.len() < 2 {
            return Err(format!(
                "has {} key(s); a flight needs at least 2",
                self.keys.len()
            ));
        }
        for (i, k) in self.keys.iter().enumerate() {
            let key = format!("key {} (the {} [[key]])", i + 1, ordinal(i + 1));
            let finite = |name: &str, v: &[f32]| {
                if v.iter().all(|x| x.is_finite()) {
                    Ok(())
                } else {
                    Err(format!(
                        "{key}: `{name}` = {v:?} is not a finite number; give real numbers"
                    ))
                }
            };
            finite("t", &[k.t])?;
            finite("position", &k.position.to_array())?;
            finite("look_at", &k.look_at.to_array())?;
            if k.position.distance(k.look_at) < 1e-3 {
                return Err(format!(
                    "{key}: `look_at` is where the camera is; look at a point away from `position`"
                ));
            }
            if let Some(sun) = k.sun {
                finite("sun", &sun)?;
                if !(-90.0..=90.0).contains(&sun[1]) {
                    return Err(format!(
                        "{key}: sun elevation {} is outside -90..=90 \
                         (`sun = [azimuth, elevation]` in degrees)",
                        sun[1]
                    ));
                }
            }
            let knobs = [
                ("lod_scale", k.knobs.lod_scale, 1e-3, 1e3),
                ("weight_threshold", k.knobs.weight_threshold, 0.0, 1.0),
                ("lod_fade", k.knobs.lod_fade, 0.0, 1.0),
            ];
            for (name, v, lo, hi) in knobs {
                if let Some(v) = v {
                    finite(name, &[v])?;
                    if !(lo..=hi).contains(&v) {
                        return Err(format!("{key}: `{name}` = {v} is outside {lo}..={hi}"));
                    }
                }
            }
            if i > 0 && k.t <= self.keys[i - 1].t {
                return Err(format!(
                    "{key}: t = {} is not after the previous key's t = {}; times must increase",
                    k.t,
                    self.keys[i - 1].t
                ));
            }
        }
        Ok(())
    }

    /// Time of the first and the last key.
    pub fn span(&self) -> (f32, f32) {
        let first = self.keys.first().map_or(0.0, |k| k.t);
        let last = self.keys.last().map_or(first, |k| k.t);
        (first, last)
    }

    /// `n` frames spread evenly in time from the first key to the last (both included).
    pub fn frames(&self, n: usize) -> Vec<FlightFrame> {
        let (t0, t1) = self.span();
        (0..n)
            .map(|i| {
                let t = if n < 2 {
                    t0
                } else if i == n - 1 {
                    t1
                } else {
                    t0 + (t1 - t0) * (i as f32 / (n - 1) as f32)
                };
                FlightFrame {
                    index: i,
                    ..self.at(t)
                }
            })
            .collect()
    }

    /// The flight at time `t` (held at the first and last key outside their times). The
    /// frame's `index` is 0.
    pub fn at(&self, t: f32) -> FlightFrame {
        let keys = &self.keys;
        let Some(first) = keys.first() else {
            return FlightFrame {
                index: 0,
                t,
                position: Vec3::ZERO,
                look_at: Vec3::Z,
                sun: None,
                knobs: Knobs::default(),
            };
        };
        let last = keys.len() - 1;
        // Segment k runs from key k to key k + 1.
        let k = keys.partition_point(|key| key.t <= t).clamp(1, last.max(1)) - 1;
        let k1 = (k + 1).min(last);
        let span = keys[k1].t - keys[k].t;
        let u = if span > 0.0 {
            ((t - keys[k].t) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (position, look_at) = match self.path {
            PathShape::Linear => (
                lerp(keys[k].position, keys[k1].position, u),
                lerp(keys[k].look_at, keys[k1].look_at, u),
            ),
            PathShape::CatmullRom => (
                catmull_rom(keys, k, u, |key| key.position),
                catmull_rom(keys, k, u, |key| key.look_at),
            ),
        };
        let sun = channel(keys, k, u, |key| key.sun.map(Vec2::from)).map(|v| v.to_array());
        let knobs = Knobs {
            lod_scale: channel(keys, k, u, |key| key.knobs.lod_scale),
            weight_threshold: channel(keys, k, u, |key| key.knobs.weight_threshold),
            lod_fade: channel(keys, k, u, |key| key.knobs.lod_fade),
        };
        FlightFrame {
            index: 0,
            t: t.clamp(first.t, keys[last].t),
            position,
            look_at,
            sun,
            knobs,
        }
    }

    /// A built-in flight over the scene `ctx` describes; `None` for an unknown name.
    pub fn builtin(name: &str, ctx: &FlightContext<'_>) -> Option<Flight> {
        let (keys, path, frames) = match name {
            "overview" => (overview(ctx), PathShape::CatmullRom, 120),
            "walk" => (walk(ctx), PathShape::Linear, 160),
            "approach" => (approach(ctx), PathShape::Linear, 120),
            "sunset" => (sunset(ctx), PathShape::Linear, 60),
            "orbit" => (orbit(ctx), PathShape::CatmullRom, 120),
            _ => return None,
        };
        let keys = keys
            .into_iter()
            .enumerate()
            .map(|(i, (position, look_at, sun))| FlightKey {
                t: i as f32,
                position,
                look_at,
                sun,
                knobs: Knobs::default(),
            })
            .collect();
        Some(Flight {
            name: name.to_owned(),
            keys,
            path,
            default_frames: frames,
        })
    }
}

fn ordinal(n: usize) -> String {
    let suffix = match (n % 10, n % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// Value of one optional channel in segment `k` at `u`: each key's own value, else the last
/// one set before it, else the first one set after it; linear between the two keys.
fn channel<T>(
    keys: &[FlightKey],
    k: usize,
    u: f32,
    get: impl Fn(&FlightKey) -> Option<T>,
) -> Option<T>
where
    T: Copy
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<f32, Output = T>,
{
    let held = |i: usize| {
        keys[..=i]
            .iter()
            .rev()
            .find_map(&get)
            .or_else(|| keys[i..].iter().find_map(&get))
    };
    let k1 = (k + 1).min(keys.len() - 1);
    Some(lerp(held(k)?, held(k1)?, u))
}

/// `a + (b - a) u`: exactly `a` at 0, exactly `b` at 1 and constant where `a == b` (glam's
/// `lerp` is neither).
fn lerp<T>(a: T, b: T, u: f32) -> T
where
    T: Copy
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<f32, Output = T>,
{
    if u <= 0.0 {
        a
    } else if u >= 1.0 {
        b
    } else {
        a + (b - a) * u
    }
}

/// A point on the Catmull-Rom spline through the keys' `get` values, in segment `k` at `u`:
/// cubic Hermite with tangents from the neighbouring keys (one-sided at the ends), scaled by
/// the keys' times so uneven spacing stays smooth.
fn catmull_rom(keys: &[FlightKey], k: usize, u: f32, get: impl Fn(&FlightKey) -> Vec3) -> Vec3 {
    let last = keys.len() - 1;
    let k1 = (k + 1).min(last);
    if u <= 0.0 || k1 == k {
        return get(&keys[k]);
    }
    if u >= 1.0 {
        return get(&keys[k1]);
    }
    let tangent = |i: usize| {
        let (a, b) = (i.saturating_sub(1), (i + 1).min(last));
        let dt = keys[b].t - keys[a].t;
        if dt > 0.0 {
            (get(&keys[b]) - get(&keys[a])) / dt
        } else {
            Vec3::ZERO
        }
    };
    let dt = keys[k1].t - keys[k].t;
    let (u2, u3) = (u * u, u * u * u);
    let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
    let h10 = u3 - 2.0 * u2 + u;
    let h01 = -2.0 * u3 + 3.0 * u2;
    let h11 = u3 - u2;
    get(&keys[k]) * h00 + tangent(k) * (h10 * dt) + get(&keys[k1]) * h01 + tangent(k1) * (h11 * dt)
}

/// A built-in key: position, look-at, sun.
type Key = (Vec3, Vec3, Option<[f32; 2]>);

/// Highest ground in the scene (m).
fn ground_top(ctx: &FlightContext<'_>) -> f32 {
    let top = ctx.terrain.bounds().max.y;
    if top.is_finite() { top } else { 0.0 }
}

/// A high diagonal pass over the whole forest, looking ahead and down.
fn overview(ctx: &FlightContext<'_>) -> Vec<Key> {
    let r = ctx.half_size;
    let altitude = ground_top(ctx) + (0.6 * r).max(60.0);
    let dir = Vec2::new(1.0, 0.6).normalize();
    (0..7)
        .map(|i| {
            let s = -1.3 + 2.6 * i as f32 / 6.0;
            let p = ctx.centre + dir * (s * r);
            let ahead = ctx.centre + dir * ((s + 0.5) * r);
            let position = Vec3::new(p.x, altitude, p.y);
            (position, ctx.over_ground(ahead.x, ahead.y, 0.0), None)
        })
        .collect()
}

/// Eye height of the walk above the ground (m).
const EYE: f32 = 2.0;
/// How far outside the forest's edge the walk starts (m).
const WALK_OUTSIDE: f32 = 600.0;

/// Low through the stand: from 600 m outside the forest's edge (beyond where a 20 m tree
/// baked at 64 texels drops to its coarsest level in a 1080p view) to its centre and on to
/// halfway to the far edge, so the near trees cross every LOD distance on the way. Keys
/// every 10 m so the camera follows the ground.
fn walk(ctx: &FlightContext<'_>) -> Vec<Key> {
    let r = ctx.half_size;
    let dir = Vec2::new(-0.6, 1.0).normalize();
    let (start, end) = (-(r + WALK_OUTSIDE), 0.5 * r);
    let steps = (((end - start) / 10.0).ceil() as usize).clamp(8, 1000);
    (0..=steps)
        .map(|i| {
            let s = start + (end - start) * i as f32 / steps as f32;
            let p = ctx.centre + dir * s;
            let ahead = ctx.centre + dir * (s + 40.0);
            (
                ctx.over_ground(p.x, p.y, EYE),
                ctx.over_ground(ahead.x, ahead.y, EYE),
                None,
            )
        })
        .collect()
}

/// Distance (m) of the approach's first and last key from the focus point.
pub const APPROACH_DISTANCES: (f32, f32) = (300.0, 5.0);

/// Towards the focus tree from 300 m to 5 m along one straight ray, the keys at geometric
/// distances (each about 0.7 of the one before) so near distances get as many frames as far
/// ones. The ray rises above the horizontal just enough to clear the ground along it.
fn approach(ctx: &FlightContext<'_>) -> Vec<Key> {
    let target = ctx.focus_point();
    let (far, near) = APPROACH_DISTANCES;
    let n = 12;
    let distances: Vec<f32> = (0..n)
        .map(|i| far * (near / far).powf(i as f32 / (n - 1) as f32))
        .collect();
    let ray = |azimuth: f32, elevation: f32| {
        let (sa, ca) = azimuth.to_radians().sin_cos();
        let (se, ce) = elevation.to_radians().sin_cos();
        Vec3::new(sa * ce, se, ca * ce)
    };
    let clears = |d: Vec3| {
        (1..=60).all(|j| {
            let p = target + d * (far * j as f32 / 60.0);
            p.y >= ctx.ground(p.x, p.z) + EYE
        })
    };
    let elevations = [5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 75.0];
    let azimuths = [200.0, 245.0, 155.0, 290.0, 110.0, 335.0, 65.0, 20.0];
    let dir = elevations
        .iter()
        .flat_map(|&e| azimuths.iter().map(move |&a| ray(a, e)))
        .find(|&d| clears(d))
        .unwrap_or(Vec3::Y);
    distances
        .into_iter()
        .map(|d| (target + dir * d, target, None))
        .collect()
}

/// A fixed view of the focus tree and the stand behind it while the sun goes down: elevation
/// 60° to 5°, azimuth 150° to 250°.
fn sunset(ctx: &FlightContext<'_>) -> Vec<Key> {
    let target = ctx.focus_point();
    let back = Vec2::new(0.3, -1.0).normalize() * (4.0 * ctx.focus_height).clamp(30.0, 120.0);
    let eye = Vec2::new(ctx.focus.x, ctx.focus.z) + back;
    let position = ctx.over_ground(eye.x, eye.y, 0.0);
    let position = Vec3::new(
        position.x,
        position.y.max(target.y) + 0.5 * ctx.focus_height,
        position.z,
    );
    let suns = [[150.0, 60.0], [200.0, 32.5], [250.0, 5.0]];
    suns.into_iter()
        .map(|s| (position, target, Some(s)))
        .collect()
}

/// A full turn around the focus tree at three tree heights' distance (20 to 80 m), a
/// little above its top, 24 keys (the last where the first is).
fn orbit(ctx: &FlightContext<'_>) -> Vec<Key> {
    let target = ctx.focus_point();
    let radius = (3.0 * ctx.focus_height).clamp(20.0, 80.0);
    let n = 24;
    (0..=n)
        .map(|i| {
            let a = std::f32::consts::TAU * i as f32 / n as f32;
            let p = Vec2::new(ctx.focus.x, ctx.focus.z) + Vec2::new(a.sin(), a.cos()) * radius;
            let y = (ctx.ground(p.x, p.y) + EYE).max(ctx.focus.y + 1.1 * ctx.focus_height);
            (Vec3::new(p.x, y, p.y), target, None)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_KEYS: &str = r#"
frames = 10
[[key]]
position = [0, 10, 0]
look_at = [0, 10, 100]
sun = [100, 40]
lod_scale = 1.0
[[key]]
position = [100, 10, 0]
look_at = [100, 10, 100]
sun = [200, 20]
lod_scale = 3.0
"#;

    fn parse(text: &str) -> Result<Flight> {
        Flight::parse(text, "test.toml")
    }

    fn err(text: &str) -> String {
        match parse(text) {
            Ok(f) => panic!("accepted: {f:?}"),
            Err(e) => e.to_string(),
        }
    }

    fn key(t: f32, x: f32) -> FlightKey {
        FlightKey {
            t,
            position: Vec3::new(x, 2.0 * x, 0.0),
            look_at: Vec3::new(x, 0.0, 50.0),
            sun: None,
            knobs: Knobs::default(),
        }
    }

    fn flight(keys: Vec<FlightKey>, path: PathShape) -> Flight {
        Flight {
            name: "t".into(),
            keys,
            path,
            default_frames: 10,
        }
    }

    #[test]
    fn a_file_parses_and_frames_go_from_key_to_key() {
        let f = parse(TWO_KEYS).unwrap();
        assert_eq!(f.default_frames, 10);
        assert_eq!(f.keys.len(), 2);
        assert_eq!((f.keys[0].t, f.keys[1].t), (0.0, 1.0));
        let frames = f.frames(11);
        assert_eq!(frames.len(), 11);
        assert_eq!(
            frames.iter().map(|f| f.index).collect::<Vec<_>>(),
            (0..11).collect::<Vec<_>>()
        );
        assert_eq!(frames[0].position, Vec3::new(0.0, 10.0, 0.0));
        assert_eq!(frames[10].position, Vec3::new(100.0, 10.0, 0.0));
        let mid = frames[5];
        assert!((mid.position.x - 50.0).abs() < 1e-3, "{mid:?}");
        assert_eq!(mid.sun.map(|s| s.map(|v| v.round())), Some([150.0, 30.0]));
        assert!((mid.knobs.lod_scale.unwrap() - 2.0).abs() < 1e-5);
        assert_eq!(mid.knobs.lod_fade, None, "no key sets it");
        assert!(f.frames(0).is_empty());
        assert_eq!(f.frames(1)[0].position, frames[0].position);
    }

    #[test]
    fn interpolation_hits_keys_at_their_times_and_stays_between_them() {
        let keys = vec![
            key(0.0, 0.0),
            key(1.0, 10.0),
            key(3.0, 20.0),
            key(3.5, 40.0),
        ];
        for shape in [PathShape::Linear, PathShape::CatmullRom] {
            let f = flight(keys.clone(), shape);
            for k in &keys {
                let at = f.at(k.t);
                assert_eq!(at.position, k.position, "{shape:?} at t={}", k.t);
                assert_eq!(at.look_at, k.look_at, "{shape:?} at t={}", k.t);
            }
            for w in keys.windows(2) {
                for j in 1..10 {
                    let t = w[0].t + (w[1].t - w[0].t) * j as f32 / 10.0;
                    let x = f.at(t).position.x;
                    assert!(
                        x > w[0].position.x && x < w[1].position.x,
                        "{shape:?}: x={x} at t={t} not between {} and {}",
                        w[0].position.x,
                        w[1].position.x
                    );
                }
            }
        }
        // Catmull-Rom is not the straight line between keys (the bend is rounded).
        let linear = flight(keys.clone(), PathShape::Linear).at(0.5).position;
        let smooth = flight(keys, PathShape::CatmullRom).at(0.5).position;
        assert!(linear.distance(smooth) > 1e-3);
    }

    #[test]
    fn keys_without_a_value_inherit_the_one_before() {
        let mut keys = vec![key(0.0, 0.0), key(1.0, 1.0), key(2.0, 2.0), key(3.0, 3.0)];
        keys[1].sun = Some([90.0, 30.0]);
        keys[1].knobs.weight_threshold = Some(0.1);
        keys[3].knobs.weight_threshold = Some(0.3);
        let f = flight(keys, PathShape::Linear);
        // Before the first key that sets the sun: its value.
        assert_eq!(f.at(0.0).sun, Some([90.0, 30.0]));
        // Key 2 sets nothing: the sun holds from key 1 to key 2.
        assert_eq!(f.at(1.5).sun, Some([90.0, 30.0]));
        assert_eq!(f.at(2.0).knobs.weight_threshold, Some(0.1));
        // From key 2 (inherited 0.1) to key 3 (0.3) linearly.
        let w = f.at(2.5).knobs.weight_threshold.unwrap();
        assert!((w - 0.2).abs() < 1e-6, "{w}");
    }

    #[test]
    fn explicit_times_space_the_frames() {
        let text = TWO_KEYS
            .replace("[[key]]\nposition = [0", "[[key]]\nt = 0\nposition = [0")
            .replace(
                "[[key]]\nposition = [100",
                "[[key]]\nt = 4\nposition = [100",
            );
        let f = parse(&text).unwrap();
        assert_eq!(f.span(), (0.0, 4.0));
        assert!((f.at(1.0).position.x - 25.0).abs() < 1e-4);
    }

    #[test]
    fn bad_files_are_errors_naming_the_file_and_the_fix() {
        let e = err("[[key]]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\n");
        assert!(e.contains("test.toml") && e.contains("at least 2"), "{e}");
        let e = err(&TWO_KEYS.replace("lod_scale = 1.0", "lod_scael = 1.0"));
        assert!(e.contains("test.toml") && e.contains("lod_scael"), "{e}");
        let e = err(&TWO_KEYS.replace("frames = 10", "frames = 10\nspeed = 2"));
        assert!(e.contains("speed"), "{e}");
        let e = err(&TWO_KEYS.replace("position = [0, 10, 0]", "position = [0, nan, 0]"));
        assert!(
            e.contains("key 1") && e.contains("position") && e.contains("finite"),
            "{e}"
        );
        let e = err(&TWO_KEYS.replace("sun = [200, 20]", "sun = [200, inf]"));
        assert!(e.contains("key 2") && e.contains("sun"), "{e}");
        let e = err(&TWO_KEYS.replace("lod_scale = 3.0", "lod_scale = -1.0"));
        assert!(e.contains("key 2") && e.contains("lod_scale"), "{e}");
        let e = err(&TWO_KEYS.replace("look_at = [0, 10, 100]", "look_at = [0, 10, 0]"));
        assert!(e.contains("key 1") && e.contains("look_at"), "{e}");
        let e = err(&TWO_KEYS.replace(
            "[[key]]\nposition = [100",
            "[[key]]\nt = 3\nposition = [100",
        ));
        assert!(e.contains("every key") && e.contains("`t`"), "{e}");
        let timed = TWO_KEYS
            .replace("[[key]]\nposition = [0", "[[key]]\nt = 2\nposition = [0")
            .replace(
                "[[key]]\nposition = [100",
                "[[key]]\nt = 1\nposition = [100",
            );
        let e = err(&timed);
        assert!(e.contains("key 2") && e.contains("increase"), "{e}");
        let e = err(&TWO_KEYS.replace("frames = 10", "frames = 1"));
        assert!(e.contains("frames = 1"), "{e}");
        let e = err(&TWO_KEYS.replace("sun = [100, 40]", "sun = [100, 95]"));
        assert!(e.contains("elevation"), "{e}");
    }

    fn hilly() -> Terrain {
        let mut t = Terrain::flat(1000.0, 65);
        for (i, h) in t.heights.iter_mut().enumerate() {
            let (x, z) = ((i % 65) as f32, (i / 65) as f32);
            *h = 30.0 + 25.0 * (x * 0.3).sin() * (z * 0.2).cos();
        }
        t
    }

    fn context(terrain: &Terrain) -> FlightContext<'_> {
        let focus = Vec3::new(20.0, terrain.height_at(20.0, -10.0), -10.0);
        FlightContext {
            terrain,
            centre: Vec2::new(10.0, 0.0),
            half_size: 400.0,
            focus,
            focus_height: 18.0,
        }
    }

    #[test]
    fn every_builtin_makes_finite_frames_above_the_ground() {
        let terrain = hilly();
        let ctx = context(&terrain);
        for &name in Flight::builtin_names() {
            let f = Flight::builtin(name, &ctx).unwrap();
            f.check().unwrap_or_else(|e| panic!("{name}: {e}"));
            let frames = f.frames(f.default_frames);
            assert_eq!(frames.len(), f.default_frames);
            for fr in &frames {
                let all = [fr.position.to_array(), fr.look_at.to_array()].concat();
                assert!(all.iter().all(|v| v.is_finite()), "{name}: {fr:?}");
                assert!(fr.distance() > 0.5, "{name}: {fr:?}");
                let ground = terrain.height_at(fr.position.x, fr.position.z);
                assert!(
                    fr.position.y > ground + 0.5,
                    "{name} frame {}: under ground {fr:?}",
                    fr.index
                );
            }
            // A built-in saved as a file reads back as the same flight.
            let back = Flight::parse(&f.to_toml(), name).unwrap();
            assert_eq!(back.frames(17), f.frames(17), "{name}");
        }
        assert!(Flight::builtin("nope", &ctx).is_none());
    }

    #[test]
    fn the_approach_closes_from_300_to_5_metres_monotonically() {
        let terrain = hilly();
        let ctx = context(&terrain);
        let f = Flight::builtin("approach", &ctx).unwrap();
        let frames = f.frames(120);
        let d: Vec<f32> = frames.iter().map(FlightFrame::distance).collect();
        assert!((d[0] - 300.0).abs() < 0.01, "{}", d[0]);
        assert!((d[119] - 5.0).abs() < 0.01, "{}", d[119]);
        assert!(d.windows(2).all(|w| w[1] < w[0]), "{d:?}");
        // Geometric spacing: as many frames under 30 m as over 100 m, give or take.
        let near = d.iter().filter(|&&x| x < 30.0).count();
        assert!(near > 30, "{near} frames nearer than 30 m");
    }

    #[test]
    fn the_walk_starts_outside_the_forest_and_ends_inside() {
        let terrain = hilly();
        let ctx = context(&terrain);
        let frames = Flight::builtin("walk", &ctx).unwrap().frames(100);
        let from_centre =
            |f: &FlightFrame| Vec2::new(f.position.x, f.position.z).distance(ctx.centre);
        assert!(from_centre(&frames[0]) > ctx.half_size + 0.9 * WALK_OUTSIDE);
        assert!(from_centre(&frames[99]) < ctx.half_size);
        let low = frames
            .iter()
            .all(|f| f.position.y - terrain.height_at(f.position.x, f.position.z) < 2.5);
        assert!(low, "the walk keeps to eye height");
    }

    #[test]
    fn the_sunset_sweeps_the_sun_down_from_a_fixed_camera_and_the_orbit_turns_once() {
        let terrain = hilly();
        let ctx = context(&terrain);
        let frames = Flight::builtin("sunset", &ctx).unwrap().frames(30);
        assert!(frames.iter().all(|f| f.position == frames[0].position));
        let el: Vec<f32> = frames.iter().map(|f| f.sun.unwrap()[1]).collect();
        assert_eq!((el[0], el[29]), (60.0, 5.0));
        assert!(el.windows(2).all(|w| w[1] < w[0]));
        let orbit = Flight::builtin("orbit", &ctx).unwrap().frames(97);
        let focus = Vec2::new(ctx.focus.x, ctx.focus.z);
        let angle = |f: &FlightFrame| {
            let v = Vec2::new(f.position.x, f.position.z) - focus;
            v.x.atan2(v.y)
        };
        let mut turned = 0.0;
        for w in orbit.windows(2) {
            let mut da = angle(&w[1]) - angle(&w[0]);
            da = (da + std::f32::consts::PI).rem_euclid(std::f32::consts::TAU)
                - std::f32::consts::PI;
            assert!(da > 0.0, "the orbit turns one way");
            turned += da;
        }
        assert!((turned - std::f32::consts::TAU).abs() < 0.01, "{turned}");
    }

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

    #[test]
    fn context_from_a_world_finds_the_forest_and_a_focus_tree() {
        use crate::model::{ForestParams, SpeciesEntry, TerrainParams};
        let world = World::build(
            &TerrainParams {
                size: 200.0,
                resolution: 17,
                relief: 5.0,
                ..TerrainParams::default()
            },
            &[SpeciesEntry::from_preset("fir", "fir", 1)],
            &ForestParams {
                count: Some(30),
                min_spacing: 6.0,
                mix: vec![1.0],
                ..ForestParams::default()
            },
        )
        .unwrap();
        let ctx = FlightContext::from_world(&world);
        assert!(
            ctx.half_size > 20.0 && ctx.half_size <= 100.0,
            "{}",
            ctx.half_size
        );
        assert!(
            ctx.focus_height > 2.0 && ctx.focus_height < 80.0,
            "{}",
            ctx.focus_height
        );
        let near = world
            .forest
            .instances
            .iter()
            .map(|t| Vec2::new(t.position.x, t.position.z).distance(ctx.centre))
            .fold(f32::INFINITY, f32::min);
        let focus = Vec2::new(ctx.focus.x, ctx.focus.z).distance(ctx.centre);
        assert_eq!(focus, near, "the focus is the tree nearest the centre");
    }
}
