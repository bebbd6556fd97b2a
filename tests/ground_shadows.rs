//! Ground shadows of the image-based methods: the alpha shadow map darkens the terrain under
//! a tree (and nowhere else), and the terrain's own depth shadows let a ridge shade the
//! valley behind it at a low sun but not at noon.

mod common;

use canopy::bake;
use canopy::model::World;
use canopy::model::forest::Forest;
use canopy::model::terrain::Terrain;
use canopy::render::{Camera, FrameDesc, Method, Renderer};
use canopy::scene::Scene;
use std::sync::OnceLock;

use glam::Vec3;

use common::*;

/// One fir on flat ground, a coarse bake.
fn lone_tree() -> Scene {
    Scene::load(&data("lone_tree.toml")).expect("tests/data/lone_tree.toml parses")
}

/// The lone fir's bake, made once per test process.
fn baked() -> &'static canopy::format::Baked {
    static BAKED: OnceLock<canopy::format::Baked> = OnceLock::new();
    BAKED.get_or_init(|| {
        let ctx = gpu();
        let scene = lone_tree();
        let world = World::build(&scene).unwrap();
        let cache =
            std::env::temp_dir().join(format!("canopy-ground-{}.canopy", std::process::id()));
        bake::load_or_bake_at(&cache, &ctx, &scene, &world, &mut |_| {})
            .unwrap()
            .0
    })
}

#[test]
fn the_alpha_shadow_map_darkens_the_ground_under_a_tree_and_nowhere_else() {
    let ctx = gpu();
    let scene = lone_tree();
    let world = World::build(&scene).unwrap();
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    renderer.attach_btf(&ctx, baked(), &world).unwrap();

    let (w, h) = (160u32, 160u32);
    let CrownShadow {
        mut frame,
        shadow_px: (sx, sy),
        lit_px: (lx, ly),
    } = crown_shadow(&scene, &world, w, h);
    frame.method = Method::Btf;
    let (with, stats) = renderer.render_image(&ctx, &frame, w, h, 1).unwrap();
    assert!(
        stats.sun_update,
        "the first frame builds the ground shadow map"
    );
    let (_, again) = renderer.render_image(&ctx, &frame, w, h, 1).unwrap();
    assert!(
        !again.sun_update,
        "the map is rebuilt only when the sun moves"
    );
    frame.ground_shadows = false;
    let (without, _) = renderer.render_image(&ctx, &frame, w, h, 1).unwrap();
    let under = mean_luminance(&with, sx, sy, 3);
    let under_without = mean_luminance(&without, sx, sy, 3);
    let sunny = mean_luminance(&with, lx, ly, 3);
    let sunny_without = mean_luminance(&without, lx, ly, 3);
    eprintln!(
        "btf ground under the crown {under:.4} (off: {under_without:.4}); sunny side {sunny:.4} ({sunny_without:.4})"
    );
    assert!(under < 0.8 * under_without, "{under} vs {under_without}");
    assert!(
        (sunny - sunny_without).abs() < 0.05 * sunny_without,
        "{sunny} vs {sunny_without}"
    );
}

/// A north-south ridge 30 m high at x = 0 on a 200 m square, flat elsewhere.
fn ridge_world() -> World {
    let res = 65u32;
    let size = 200.0f32;
    let mut heights = Vec::with_capacity((res * res) as usize);
    for _z in 0..res {
        for x in 0..res {
            let px = -0.5 * size + size * x as f32 / (res - 1) as f32;
            heights.push((30.0 - px.abs() * 1.5).max(0.0));
        }
    }
    let scene = lone_tree();
    let species = World::build(&scene).unwrap().species;
    World {
        terrain: Terrain {
            size,
            resolution: res,
            heights,
        },
        species,
        forest: Forest {
            instances: Vec::new(),
        },
    }
}

#[test]
fn a_ridge_shades_the_valley_behind_it_at_a_low_sun_but_not_at_noon() {
    let ctx = gpu();
    let world = ridge_world();
    let scene = lone_tree();
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    // The lone fir's species data, without its tree's cube maps: this world has no trees.
    let mut species_only = baked().clone();
    species_only
        .vcm
        .retain(|s| s.level != canopy::format::Level::Tree);
    renderer.attach_btf(&ctx, &species_only, &world).unwrap();
    let mut frame = FrameDesc::from_scene(&scene);
    frame.fog_density = 0.0;
    // The valley floor 30 m east of the ridge's foot, seen from above.
    let valley = Vec3::new(45.0, 0.0, 0.0);
    frame.camera = Camera::look_at(valley + Vec3::new(0.0, 80.0, 0.01), valley, 30.0);
    let (w, h) = (96u32, 96u32);
    let centre = (i64::from(w) / 2, i64::from(h) / 2);
    let mut valley_light = |azimuth: f32, elevation: f32, method: Method| {
        frame.sun.azimuth_deg = azimuth;
        frame.sun.elevation_deg = elevation;
        frame.method = method;
        let (img, _) = renderer.render_image(&ctx, &frame, w, h, 1).unwrap();
        mean_luminance(&img, centre.0, centre.1, 4)
    };
    // Geometry (the ground truth) and the image-based method's terrain shadows agree.
    for method in [Method::Geometry, Method::Btf] {
        // Sun low in the west (azimuth 270): the ridge stands between it and the valley.
        let low_west = valley_light(270.0, 12.0, method);
        // The same low sun from the east: nothing in the way.
        let low_east = valley_light(90.0, 12.0, method);
        let noon = valley_light(270.0, 80.0, method);
        eprintln!(
            "{method:?}: valley luminance, low sun behind the ridge {low_west:.4}, low sun in front {low_east:.4}, noon {noon:.4}"
        );
        assert!(
            low_west < 0.6 * low_east,
            "the ridge should shade the valley: {low_west} vs {low_east}"
        );
        assert!(noon > low_east, "at noon the valley is fully lit: {noon}");
    }
}
