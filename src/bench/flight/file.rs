//! Flight files: reading one (with messages that name the file, the key and the fix) and
//! writing a flight back as one.

use std::path::Path;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::{DEFAULT_FRAMES, Flight, FlightKey, Knobs, MAX_FRAMES, MAX_KEYS, PathShape};
use crate::{Error, Result};

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

impl Flight {
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
    pub(super) fn check(&self) -> Result<(), String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::flight::test_support::{TWO_KEYS, parse};

    fn err(text: &str) -> String {
        match parse(text) {
            Ok(f) => panic!("accepted: {f:?}"),
            Err(e) => e.to_string(),
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
}
