//! The built-in flights (overview, walk, approach, sunset, orbit), made from the extent of the
//! scene's forest and a tree near its centre.

use glam::{Vec2, Vec3};

use super::{Flight, FlightKey, Knobs, PathShape};
use crate::model::{Terrain, World};

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

/// The names of the built-in flights, in the order they are listed.
pub(super) const BUILTINS: [&str; 5] = ["overview", "walk", "approach", "sunset", "orbit"];

impl Flight {
    /// Names accepted by [`Flight::builtin`].
    pub fn builtin_names() -> &'static [&'static str] {
        &BUILTINS
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
    use crate::bench::flight::FlightFrame;
    use crate::bench::flight::test_support::{context, hilly};

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
        let from_center =
            |f: &FlightFrame| Vec2::new(f.position.x, f.position.z).distance(ctx.centre);
        assert!(from_center(&frames[0]) > ctx.half_size + 0.9 * WALK_OUTSIDE);
        assert!(from_center(&frames[99]) < ctx.half_size);
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
