//! What the flight tests share: a two-key flight file, a hilly terrain and a context on it.

use glam::{Vec2, Vec3};

use super::{Flight, FlightContext};
use crate::Result;
use crate::model::Terrain;

pub(super) const TWO_KEYS: &str = r#"
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

pub(super) fn parse(text: &str) -> Result<Flight> {
    Flight::parse(text, "test.toml")
}

pub(super) fn hilly() -> Terrain {
    let mut t = Terrain::flat(1000.0, 65);
    for (i, h) in t.heights.iter_mut().enumerate() {
        let (x, z) = ((i % 65) as f32, (i / 65) as f32);
        *h = 30.0 + 25.0 * (x * 0.3).sin() * (z * 0.2).cos();
    }
    t
}

pub(super) fn context(terrain: &Terrain) -> FlightContext<'_> {
    let focus = Vec3::new(20.0, terrain.height_at(20.0, -10.0), -10.0);
    FlightContext {
        terrain,
        centre: Vec2::new(10.0, 0.0),
        half_size: 400.0,
        focus,
        focus_height: 18.0,
    }
}
