//! No edge of the world (issue 12 item 3): from anywhere inside the default forest, in
//! every direction, the terrain reaches past the distance where the fog hides 99 % of
//! anything, so flying never shows a cliff or the void.

use canopy::render::FrameDesc;
use canopy::scene::Scene;

#[test]
fn the_terrain_reaches_past_the_fog_in_every_direction() {
    let scene = Scene::default_scene();
    assert!(
        scene.terrain.horizon,
        "the default scene continues its hills"
    );
    let world = scene.build_world().unwrap();
    let frame = FrameDesc::from_scene(&scene);
    let fog_99 = 100f32.ln() / frame.fog_density;
    let half = 0.5 * world.terrain.drawn_size();
    let mesh = world.terrain.mesh();
    let extent = mesh
        .vertices
        .iter()
        .map(|v| v.position[0].abs().max(v.position[2].abs()))
        .fold(0.0f32, f32::max);
    assert!(
        (extent - half).abs() < 1.0,
        "the mesh reaches {extent}, not {half}"
    );
    let trees = &world.forest.instances;
    let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
    for t in trees {
        lo = [lo[0].min(t.position.x), lo[1].min(t.position.z)];
        hi = [hi[0].max(t.position.x), hi[1].max(t.position.z)];
    }
    let mut nearest = f32::MAX;
    for i in 0..=4 {
        for j in 0..=4 {
            let x = lo[0] + (hi[0] - lo[0]) * i as f32 / 4.0;
            let z = lo[1] + (hi[1] - lo[1]) * j as f32 / 4.0;
            for k in 0..32 {
                let a = k as f32 / 32.0 * std::f32::consts::TAU;
                let (dx, dz) = (a.cos(), a.sin());
                // Distance from (x, z) to the ring's outer square along (dx, dz).
                let to_edge = |p: f32, d: f32| {
                    if d.abs() < 1e-6 {
                        f32::MAX
                    } else {
                        ((d.signum() * half) - p) / d
                    }
                };
                let d = to_edge(x, dx).min(to_edge(z, dz));
                nearest = nearest.min(d);
            }
        }
    }
    eprintln!(
        "fog hides 99 % at {fog_99:.0} m; the terrain's edge is at least {nearest:.0} m from the forest"
    );
    assert!(nearest > fog_99, "{nearest} <= {fog_99}");
}
