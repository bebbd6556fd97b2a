//! A flight between its keys: frames spread over its time, positions and look-ats linearly
//! or by Catmull-Rom, the sun and the knobs linearly with values held from key to key.

use glam::{Vec2, Vec3};

use super::{Flight, FlightFrame, FlightKey, Knobs, PathShape};

impl Flight {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
