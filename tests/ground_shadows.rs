//! Ground shadows of the image-based methods: the alpha shadow map darkens the terrain under
//! a tree (and nowhere else), also past the scene's square on the horizon ring, and the
//! terrain's own depth shadows let a ridge shade the valley behind it at a low sun but not
//! at noon.

use canopy::model::World;
use canopy::model::forest::Forest;
use canopy::model::terrain::Terrain;
use canopy::render::{
    Camera, FrameDesc, GROUND_MAP_SIZE, Method, Renderer, ground_map_side, ground_preview_side,
};
use canopy::scene::Scene;

use glam::Vec3;

use crate::common::*;

/// One fir on flat ground, a coarse bake, but with 18 views rather than the file's 6 (at
/// every level): they include east at 45° up, where the proportion test puts the sun.
fn lone_tree() -> Scene {
    let mut scene = load_scene("lone_tree.toml");
    scene.bake.views = 18;
    scene.bake.tree_views = 18;
    scene
}

/// The lone fir's bake, made once per run.
fn lone_baked() -> &'static canopy::format::Baked {
    baked(&lone_tree())
}

#[test]
fn the_alpha_shadow_map_darkens_the_ground_under_a_tree_and_nowhere_else() {
    let ctx = gpu();
    let (scene, world) = built(lone_tree());
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    renderer.attach_btf(&ctx, lone_baked(), &world).unwrap();

    let (w, h) = (160u32, 160u32);
    let CrownShadow {
        mut frame,
        shadow_px: (sx, sy),
        lit_px: (lx, ly),
        ..
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
    assert_eq!(
        again.shadow_triangles, 0,
        "no depth cascades are drawn per frame: the terrain's depth map follows the sun"
    );
    // The maps follow the scene: this 80 m square gets smaller ones than the default scene.
    let side = ground_map_side(world.terrain.bounds().extent().length(), 16384);
    assert!(side < GROUND_MAP_SIZE, "{side}");
    assert_eq!(stats.ground_map_size, Some(side));

    // Dragging the sun: the maps follow it at the preview size, and are drawn at full size
    // on the first frame after it is let go.
    let mut dragged = frame;
    dragged.sun.azimuth_deg += 1.0;
    dragged.sun_held = true;
    let (held_img, held) = renderer.render_image(&ctx, &dragged, w, h, 1).unwrap();
    assert!(held.sun_update);
    assert_eq!(held.ground_map_size, Some(ground_preview_side(side)));
    let (_, held_still) = renderer.render_image(&ctx, &dragged, w, h, 1).unwrap();
    assert!(
        !held_still.sun_update,
        "a held sun that does not move costs nothing"
    );
    dragged.sun_held = false;
    let (let_go_img, let_go) = renderer.render_image(&ctx, &dragged, w, h, 1).unwrap();
    assert!(
        let_go.sun_update,
        "letting go of the sun draws the full maps"
    );
    assert_eq!(let_go.ground_map_size, Some(side));
    let preview_error = canopy::metrics::flip(&rgb(&let_go_img), &rgb(&held_img))
        .unwrap()
        .stats
        .mean;
    eprintln!("preview maps against full maps: mean FLIP {preview_error:.4}");
    assert!(preview_error < 0.05, "{preview_error}");

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

#[test]
fn a_tree_at_the_squares_edge_shadows_the_horizon_ring_past_it() {
    // The lone fir at the centre of a 10 m square with the horizon ring around it: its
    // crown's shadow falls about 11 m to the north-west, past the square, on the ring. The
    // trees' alpha map is read wherever it reaches (only the terrain's depth map stops at
    // the square), so btf shadows the ring there as the ground truth's cascades do.
    let ctx = gpu();
    let mut scene = lone_tree();
    scene.terrain.size = 10.0;
    scene.terrain.horizon = true;
    let mut world = scene.build_world().unwrap();
    // Bare ring: no far forest's canopy raised around so small a square.
    world.terrain.set_far_cover(None);
    world.forest.instances.truncate(1);
    world.forest.instances[0].position = Vec3::new(0.0, world.terrain.height_at(0.0, 0.0), 0.0);
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    // The 80 m scene's bake: the same fir (its tree cube maps were baked on that square;
    // they shade the crown, not the ground).
    renderer.attach_btf(&ctx, lone_baked(), &world).unwrap();
    let (w, h) = (96u32, 96u32);
    let CrownShadow {
        frame,
        shadow_at,
        shadow_px: (sx, sy),
        lit_px: (lx, ly),
    } = crown_shadow(&scene, &world, w, h);
    let half = 0.5 * world.terrain.size;
    assert!(
        shadow_at.x.abs().max(shadow_at.z.abs()) > half + 2.0,
        "the test needs the shadow past the square: {shadow_at}"
    );
    for method in [Method::Geometry, Method::Btf] {
        let mut f = frame;
        f.method = method;
        let (with, _) = renderer.render_image(&ctx, &f, w, h, 1).unwrap();
        f.ground_shadows = false;
        f.shadows.enabled = false;
        let (without, _) = renderer.render_image(&ctx, &f, w, h, 1).unwrap();
        let under = mean_luminance(&with, sx, sy, 3);
        let under_without = mean_luminance(&without, sx, sy, 3);
        let sunny = mean_luminance(&with, lx, ly, 3);
        let sunny_without = mean_luminance(&without, lx, ly, 3);
        eprintln!(
            "{method:?}: ring under the crown's shadow {under:.4} (no shadows: {under_without:.4}); sunny side {sunny:.4} ({sunny_without:.4})"
        );
        assert!(
            under < 0.8 * under_without,
            "{method:?}: the ring past the square should be shaded: {under} vs {under_without}"
        );
        assert!(
            (sunny - sunny_without).abs() < 0.05 * sunny_without,
            "{method:?}: {sunny} vs {sunny_without}"
        );
    }
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
    let species = scene.build_world().unwrap().species;
    World {
        terrain: Terrain {
            size,
            resolution: res,
            heights,
            far: None,
        },
        species,
        forest: Forest::default(),
        tree_vcm: Default::default(),
    }
}

#[test]
fn a_ridge_shades_the_valley_behind_it_at_a_low_sun_but_not_at_noon() {
    let ctx = gpu();
    let world = ridge_world();
    let scene = lone_tree();
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    // The lone fir's species data, without its tree's cube maps: this world has no trees.
    let mut species_only = lone_baked().clone();
    species_only
        .vcm
        .retain(|s| s.level != canopy::model::Level::Tree);
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

/// Per pixel, the fraction of the sun's direct light that reaches the ground, from three
/// renders of one view: lit (`lit`), without tree shadows (`open`) and without the sun
/// (`ambient`): (lit − ambient) / (open − ambient), in linear luminance. None where the
/// direct light is too faint to tell.
fn sun_fraction(
    lit: &image::RgbaImage,
    open: &image::RgbaImage,
    ambient: &image::RgbaImage,
) -> Vec<Option<f32>> {
    let (w, h) = lit.dimensions();
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let l = |img: &image::RgbaImage| mean_luminance(img, i64::from(x), i64::from(y), 0);
            let (a, o) = (l(ambient), l(open));
            out.push((o - a > 0.02).then(|| ((l(lit) - a) / (o - a)).clamp(0.0, 1.2)));
        }
    }
    out
}

/// Pixels where the camera sees the ground (the render with trees equals the one without).
fn ground_seen(with_trees: &image::RgbaImage, no_trees: &image::RgbaImage) -> Vec<bool> {
    with_trees
        .pixels()
        .zip(no_trees.pixels())
        .map(|(a, b)| (0..3).all(|c| a.0[c].abs_diff(b.0[c]) <= 2))
        .collect()
}

/// The shadow's darkness (1 − sun fraction) of every `cell` x `cell` block whose pixels all
/// show the ground in `seen`; None for the others.
fn cell_darkness(
    frac: &[Option<f32>],
    seen: &[bool],
    w: u32,
    h: u32,
    cell: u32,
) -> Vec<Option<f32>> {
    let mut out = Vec::new();
    for cy in 0..h / cell {
        for cx in 0..w / cell {
            let mut sum = 0.0;
            let mut ok = true;
            for y in cy * cell..(cy + 1) * cell {
                for x in cx * cell..(cx + 1) * cell {
                    let i = (y * w + x) as usize;
                    match (seen[i], frac[i]) {
                        (true, Some(f)) => sum += f,
                        _ => ok = false,
                    }
                }
            }
            out.push(ok.then(|| 1.0 - sum / (cell * cell) as f32));
        }
    }
    out
}

#[test]
fn the_alpha_shadow_map_darkens_the_ground_in_proportion_to_the_trees_opacity() {
    // The ground truth's shadow of one fir (its shadow map sees every needle) against the
    // alpha map's, block by block: where the crown lets half the sun through, the alpha map
    // should too.
    // The sun stands in the direction of one of the baked views (east, 45° up; the fir is
    // not turned), so the alpha map holds that view's image alone rather than a blend of
    // three views' silhouettes, which would blur the shadow across blocks.
    let ctx = gpu();
    let mut scene = lone_tree();
    scene.sun.azimuth = 90.0;
    scene.sun.elevation = 45.0;
    let world = scene.build_world().unwrap();
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    renderer.attach_btf(&ctx, lone_baked(), &world).unwrap();
    let (w, h) = (192u32, 192u32);
    let CrownShadow {
        mut frame,
        shadow_at,
        ..
    } = crown_shadow(&scene, &world, w, h);
    // Closer than the other shadow tests: about 0.15 m per pixel.
    frame.camera = Camera::look_at(shadow_at + Vec3::new(0.0, 40.0, 0.01), shadow_at, 40.0);

    let mut darkness = |method: Method, supersample: u32| {
        let mut f = frame;
        f.method = method;
        let mut shot = |f: &FrameDesc| renderer.render_image(&ctx, f, w, h, supersample).unwrap().0;
        let lit = shot(&f);
        let mut open = f;
        open.ground_shadows = false;
        open.shadows.enabled = false;
        let open_img = shot(&open);
        let mut dark = f;
        dark.sun.intensity = 0.0;
        let ambient = shot(&dark);
        let mut bare = open;
        bare.trees = false;
        let bare_img = shot(&bare);
        let frac = sun_fraction(&lit, &open_img, &ambient);
        (frac, ground_seen(&open_img, &bare_img))
    };
    let (frac_btf, seen_btf) = darkness(Method::Btf, 1);
    let (frac_geo, seen_geo) = darkness(Method::Geometry, 2);
    let seen: Vec<bool> = seen_btf
        .iter()
        .zip(&seen_geo)
        .map(|(a, b)| *a && *b)
        .collect();
    let cell = 12;
    let btf = cell_darkness(&frac_btf, &seen, w, h, cell);
    let geo = cell_darkness(&frac_geo, &seen, w, h, cell);
    let pairs: Vec<(f32, f32)> = geo
        .iter()
        .zip(&btf)
        .filter_map(|(g, b)| g.zip(*b))
        .collect();
    let shaded = pairs.iter().filter(|(g, _)| *g > 0.2).count();
    let n = pairs.len() as f32;
    let (mg, mb) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), (g, t)| (a + g / n, b + t / n));
    let (mut sgg, mut sbb, mut sgb, mut sg2, mut abs) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for (g, b) in &pairs {
        sgg += (g - mg) * (g - mg);
        sbb += (b - mb) * (b - mb);
        sgb += (g - mg) * (b - mb);
        sg2 += g * g;
        abs += (g - b).abs() / n;
    }
    let correlation = sgb / (sgg * sbb).sqrt().max(1e-9);
    // Least squares through the origin: btf darkness = slope x geometry darkness.
    let slope = pairs.iter().map(|(g, b)| g * b).sum::<f32>() / sg2.max(1e-9);
    let deepest = pairs.iter().map(|p| p.0).fold(0.0f32, f32::max);
    eprintln!(
        "{} blocks of {cell}² px on the ground ({shaded} in shadow, deepest {deepest:.3}): \
         correlation {correlation:.3}, slope {slope:.3}, mean |difference| {abs:.4}",
        pairs.len()
    );
    assert!(shaded >= 8, "too few shaded blocks to judge: {shaded}");
    assert!(
        deepest > 0.5,
        "the crown's core should block most of the sun: {deepest}"
    );
    // Measured on lavapipe: correlation 0.988, slope 0.973, mean |difference| 0.0042. A map
    // that darkened twice as much (transmittance squared) measures a slope of 1.32.
    assert!(correlation > 0.93, "correlation {correlation}");
    assert!((0.85..=1.15).contains(&slope), "slope {slope}");
    assert!(abs < 0.015, "mean |difference| {abs}");
}
