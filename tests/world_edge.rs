//! No edge of the world (issue 12 item 3): from anywhere inside the default forest, in
//! every direction, the terrain reaches past the distance where the fog hides 99 % of
//! anything, so flying never shows a cliff or the void.

use canopy::render::{FrameDesc, Method, Renderer};
use canopy::scene::Scene;

use crate::common::*;

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

/// The default scene's hills and horizon under the lone fir's bake, no trees.
fn bare_hills() -> (canopy::model::World, canopy::format::Baked) {
    let mut world = firs_at(&[]);
    world.terrain = Scene::default_scene().build_world().unwrap().terrain;
    let baked = fir_bake_for(&world);
    (world, baked)
}

/// The terrain drawn by chunks at coarser levels (`terrain_px`) against the terrain at
/// full detail, at the default scene's start camera: close (mean FLIP measured 0.0038 at
/// 0.5 px), with fewer triangles. (That skirts close the cracks between levels is checked
/// on the mesh, in `model::terrain_lod`'s tests.)
#[test]
fn coarse_terrain_chunks_stay_close_to_the_full_terrain() {
    let ctx = gpu();
    let (world, baked) = bare_hills();
    let mut r = Renderer::new(&ctx, &world).unwrap();
    r.attach_btf(&ctx, &baked, &world).unwrap();
    let scene = Scene::default_scene();
    let frame = |px: f32| FrameDesc {
        method: Method::Btf,
        terrain_px: px,
        ..FrameDesc::from_scene(&scene)
    };
    let (w, h) = (320, 180);
    let (full, full_stats) = r.render_image(&ctx, &frame(0.0), w, h, 1).unwrap();
    let (coarse, coarse_stats) = r.render_image(&ctx, &frame(0.5), w, h, 1).unwrap();
    let flip = canopy::metrics::flip(&rgb(&full), &rgb(&coarse))
        .unwrap()
        .stats
        .mean;
    println!(
        "start camera: {} triangles at full detail, {} by chunks; mean FLIP {flip:.4}",
        full_stats.triangles, coarse_stats.triangles
    );
    assert!(flip < 0.006, "mean FLIP {flip} against the full terrain");
    assert!(
        (coarse_stats.triangles as f64) < 0.7 * full_stats.triangles as f64,
        "{} triangles by chunks against {} at full detail",
        coarse_stats.triangles,
        full_stats.triangles
    );
}
