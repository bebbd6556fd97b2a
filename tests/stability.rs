//! The stability suite: short flights on the BTF test stand where the methods are known to
//! fail, each with its metric and a bound set from measurement (stated with the figure that
//! set it), and each shown to fail when the thing it guards is switched off. The figures
//! come from the bench's own runner (`canopy::bench::run`), so a bench of the same flight on
//! any scene reports the same metrics.

use canopy::bench::flight::{FlightFrame, Knobs};
use canopy::bench::run::{self, BenchOptions, Config};
use canopy::format::Baked;
use canopy::model::World;
use canopy::render::knob::{Knob, KnobValues};
use canopy::render::method::btf::BtfSettings;
use canopy::render::{Camera, FrameDesc, GpuContext, Method, Renderer};
use canopy::scene::Scene;
use glam::Vec3;

use crate::common::*;

/// The stand's BTF image sets, made once per run.
fn baked() -> &'static Baked {
    btf_stand_btf()
}

fn setup(ctx: &GpuContext) -> (Scene, World, Renderer) {
    let (scene, world) = built(btf_stand());
    let mut renderer = Renderer::new(ctx, &world).unwrap();
    renderer.attach_btf(ctx, baked(), &world).unwrap();
    (scene, world, renderer)
}

/// The stand's first tree and the centre of its box, in the world.
fn first_tree(world: &World) -> (canopy::model::TreeInstance, Vec3) {
    let tree = world.forest.instances[0];
    let model = &world.species[tree.species as usize];
    (
        tree,
        tree.position + model.tree_bounds.center() * tree.scale,
    )
}

/// A frame of a hand-made flight.
fn frame(index: usize, position: Vec3, look_at: Vec3, sun: Option<[f32; 2]>) -> FlightFrame {
    FlightFrame {
        index,
        t: index as f32,
        position,
        look_at,
        sun,
        knobs: Knobs::default(),
    }
}

fn btf(label: &str, f: impl FnOnce(&mut BtfSettings)) -> Config {
    let mut btf = BtfSettings {
        vcm: false,
        ..BtfSettings::default()
    };
    f(&mut btf);
    // The btf knobs alone: each test's frame keeps its own ground knobs.
    let mut d = FrameDesc::from_scene(&Scene::default_scene());
    d.btf = btf;
    let own: Vec<&'static Knob> = canopy::render::method::btf::knobs::KNOBS.iter().collect();
    Config {
        label: label.into(),
        method: Method::Btf,
        knobs: KnobValues::read(&own, &d),
    }
}

/// The stand's frame for these flights: no fog, smaller shadow maps (the truth's cost).
fn base(scene: &Scene) -> FrameDesc {
    let mut f = FrameDesc::from_scene(scene);
    f.fog_density = 0.0;
    f.shadows.map_size = 1024;
    f
}

fn options(tag: &str, size: u32) -> BenchOptions {
    BenchOptions {
        width: size,
        height: size,
        truth_supersample: 1,
        repeats: 1,
        cache_dir: std::env::temp_dir()
            .join(format!("canopy-stability-{tag}-{}", std::process::id())),
        scene_content: tag.as_bytes().to_vec(),
        // The interactive geometry as the truth: its temporal changes are what these tests
        // judge the methods' against, and it costs a fraction of the reference.
        reference: None,
    }
}

/// The method's own frame-to-frame change along `frames` (FLIP between consecutive frames,
/// no truth needed): (mean, largest over median), printed.
fn steps(
    ctx: &GpuContext,
    renderer: &mut Renderer,
    base: &FrameDesc,
    frames: &[FlightFrame],
    config: &Config,
    size: u32,
    what: &str,
) -> (f64, f64) {
    let mut changes = Vec::new();
    let mut prev: Option<image::RgbImage> = None;
    for f in frames {
        let mut d = *base;
        d.method = config.method;
        config.knobs.apply_to(&mut d);
        f.apply(&mut d);
        let (img, _) = renderer.render_image(ctx, &d, size, size, 1).unwrap();
        let img = rgb(&img);
        if let Some(p) = &prev {
            changes.push(f64::from(
                canopy::metrics::flip(p, &img).unwrap().stats.mean,
            ));
        }
        prev = Some(img);
    }
    let mean = changes.iter().sum::<f64>() / changes.len().max(1) as f64;
    let mut sorted = changes.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let (at, max) = changes
        .iter()
        .copied()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    eprintln!(
        "{what}, {}: mean change {mean:.5}, median {median:.5}, largest {max:.5} at frame {} ({:.1}x the median)",
        config.label,
        at + 1,
        max / median.max(1e-9)
    );
    (mean, max / median.max(1e-9))
}

/// Prints each configuration's frame-to-frame change against the truth's, and its summary.
fn print_flight(r: &run::BenchResults, what: &str) {
    for (c, s) in r.summaries.iter().enumerate() {
        let changes: Vec<String> = r
            .rows
            .iter()
            .filter(|row| row.config == c)
            .filter_map(|row| Some(format!("{:.4}/{:.4}", row.change?, row.truth_change?)))
            .collect();
        eprintln!(
            "{}: change / truth's per frame {}",
            s.label,
            changes.join(" ")
        );
        eprintln!(
            "{what}, {}: worst pop {:?}, flicker ratio {:.3}, mean FLIP {:.4}",
            s.label, s.worst_pop, s.flicker_ratio, s.mean_flip
        );
    }
}

/// LOD switch: the camera dollies down onto a tree across the distance where the twig
/// level takes over from the main-branch level. The worst pop (the largest frame-to-frame
/// change beyond the truth's own, scaled: `bench::temporal::flicker`) with the cross-fade
/// must stay under this. Measured on lavapipe (llvmpipe 15, 128x128, 17 frames in 0.5 %
/// steps): cross-fade 0.2: 0.0003; abrupt (`lod_fade` 0): 0.0087 at the switch, where btf
/// changes 0.018 against its usual 0.009 (the truth: 0.020 every frame). The abrupt switch
/// must exceed the bound.
const LOD_SWITCH_MAX_POP: f64 = 0.003;

#[test]
fn lod_switch_the_cross_fade_keeps_the_worst_pop_under_its_bound() {
    let ctx = gpu();
    let (scene, world, mut renderer) = setup(&ctx);
    let (tree, centre) = first_tree(&world);
    let size = 128;
    let focal = Camera::look_at(Vec3::ZERO, Vec3::Z, 40.0).focal_px(size);
    let texels = renderer.btf_texels(tree.species as usize).unwrap();
    let bound = canopy::lod::valid_beyond(texels.branch * tree.scale, focal, 1.0);
    // 17 frames from 1.04 to 0.96 times the bound in 0.5 % steps, looking straight down:
    // steps small enough that the motion itself changes little.
    let n = 17;
    let frames: Vec<FlightFrame> = (0..n)
        .map(|i| {
            let z = bound * (1.04 - 0.005 * i as f32);
            frame(i, centre + Vec3::new(0.0, z, 0.001), centre, None)
        })
        .collect();
    let configs = [
        btf("fade 0.2", |s| s.lod_fade = 0.2),
        btf("abrupt", |s| s.lod_fade = 0.0),
    ];
    let mut b = base(&scene);
    b.camera.fov_y_deg = 40.0;
    let r = run::run(
        &ctx,
        &mut renderer,
        &b,
        &frames,
        &configs,
        &options("lod", size),
        &mut |_| {},
    )
    .unwrap();
    print_flight(&r, "LOD switch");
    let pop = |i: usize| {
        r.summaries[i]
            .worst_pop
            .expect("a flight of 14 frames")
            .excess
    };
    assert!(
        pop(0) < LOD_SWITCH_MAX_POP,
        "with the cross-fade the worst pop is {:.4}",
        pop(0)
    );
    assert!(
        pop(1) > LOD_SWITCH_MAX_POP,
        "the abrupt switch must show as a pop above the bound: {:.4}",
        pop(1)
    );
}

/// Light between samples: a fixed camera, the sun turned in 0.5 degree steps across a baked
/// light direction (the stand bakes 6 lights: the +x axis is one, at azimuth 90, elevation
/// 0; the sweep runs at 20 degrees up from azimuth 80 to 100). No frame-to-frame change may
/// be larger than this many times the sweep's median change. Measured on lavapipe (96x96,
/// 41 frames): blended 1.1x (median 0.0020); holding the light at the nearest sample
/// (threshold 1: one light, no blending) 5.3x, at the step where the nearest sample changes,
/// which must exceed the bound.
const LIGHT_STEP_MAX_OVER_MEDIAN: f64 = 4.0;

#[test]
fn light_between_samples_changes_the_image_in_even_steps() {
    let ctx = gpu();
    let (scene, world, mut renderer) = setup(&ctx);
    let (_, centre) = first_tree(&world);
    let size = 96;
    let eye = centre + Vec3::new(-40.0, 10.0, -25.0);
    let frames: Vec<FlightFrame> = (0..41)
        .map(|i| frame(i, eye, centre, Some([80.0 + 0.5 * i as f32, 20.0])))
        .collect();
    let mut b = base(&scene);
    b.ground_shadows = false;
    let configs = [
        btf("blended", |s| s.lod_scale = 4.0),
        btf("nearest light only", |s| {
            s.lod_scale = 4.0;
            s.weight_threshold = 1.0;
        }),
    ];
    let mut ratios = Vec::new();
    for config in &configs {
        let mut changes = Vec::new();
        let mut prev: Option<image::RgbImage> = None;
        for f in &frames {
            let mut d = b;
            d.method = config.method;
            config.knobs.apply_to(&mut d);
            f.apply(&mut d);
            let (img, _) = renderer.render_image(&ctx, &d, size, size, 1).unwrap();
            let img = rgb(&img);
            if let Some(p) = &prev {
                changes.push(f64::from(
                    canopy::metrics::flip(p, &img).unwrap().stats.mean,
                ));
            }
            prev = Some(img);
        }
        let mut sorted = changes.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let (at, max) = changes
            .iter()
            .copied()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        eprintln!(
            "light sweep, {}: median change {median:.5}, largest {max:.5} at frame {} ({:.1}x the median)",
            config.label,
            at + 1,
            max / median.max(1e-9)
        );
        ratios.push(max / median.max(1e-9));
    }
    assert!(
        ratios[0] < LIGHT_STEP_MAX_OVER_MEDIAN,
        "blended lights: the largest step is {:.1}x the median",
        ratios[0]
    );
    assert!(
        ratios[1] > LIGHT_STEP_MAX_OVER_MEDIAN,
        "the nearest light alone must show its switch: {:.1}x the median",
        ratios[1]
    );
}

/// View between samples and the image-weight threshold: the camera orbits a tree at
/// mid distance in 1 degree steps, 10 degrees up, from 25 to 65 degrees of azimuth in the
/// tree's frame: across the middle between two baked views (the stand bakes 6: +z at 0,
/// +x at 90), where the nearest view changes. Measured on lavapipe (96x96, 41 frames):
/// largest step over the median: threshold 0: 2.8x, threshold 0.2: 3.1x, nearest view only:
/// 4.6x (at frame 20, the middle); mean change of threshold 0.2 over 0: 0.99. (Across 70 to
/// 110 degrees instead, threshold 0.2 steps 7.0x its median where a weight crosses 0.2: the
/// culling is discontinuous there; not bounded here.) Bounds: blended views, no step larger
/// than `VIEW_STEP_MAX_OVER_MEDIAN` times the median (the nearest view alone, threshold 1,
/// must exceed it); threshold 0.2 changes the image at most `THRESHOLD_MAX_FLICKER` times as
/// much per frame as threshold 0.
const VIEW_STEP_MAX_OVER_MEDIAN: f64 = 4.0;
const THRESHOLD_MAX_FLICKER: f64 = 1.5;

#[test]
fn orbiting_across_a_view_sample_changes_the_image_in_even_steps() {
    let ctx = gpu();
    let (scene, world, mut renderer) = setup(&ctx);
    let (tree, centre) = first_tree(&world);
    let size = 96;
    // The tree's own frame turns with its yaw: orbit around the sample's world azimuth.
    let yaw = tree.yaw;
    let frames: Vec<FlightFrame> = (0..41)
        .map(|i| {
            let az = (25.0 + i as f32).to_radians() + yaw;
            let el = 10f32.to_radians();
            let dir = Vec3::new(az.sin() * el.cos(), el.sin(), az.cos() * el.cos());
            frame(i, centre + dir * 30.0, centre, None)
        })
        .collect();
    let mut b = base(&scene);
    b.ground_shadows = false;
    b.trees = true;
    let tree_level = |label: &str, threshold: f32| {
        btf(label, |s| {
            s.lod_scale = 8.0;
            s.weight_threshold = threshold;
        })
    };
    let configs = [
        tree_level("threshold 0", 0.0),
        tree_level("threshold 0.2", 0.2),
        tree_level("nearest view only", 1.0),
    ];
    let r: Vec<(f64, f64)> = configs
        .iter()
        .map(|c| steps(&ctx, &mut renderer, &b, &frames, c, size, "orbit"))
        .collect();
    assert!(
        r[0].1 < VIEW_STEP_MAX_OVER_MEDIAN,
        "blended views: the largest step is {:.1}x the median",
        r[0].1
    );
    assert!(
        r[2].1 > VIEW_STEP_MAX_OVER_MEDIAN,
        "the nearest view alone must show its switch: {:.1}x the median",
        r[2].1
    );
    let ratio = r[1].0 / r[0].0;
    eprintln!("threshold 0.2 over 0: flicker ratio {ratio:.3}");
    assert!(
        ratio < THRESHOLD_MAX_FLICKER,
        "threshold 0.2 flickers {ratio:.2}x as much as 0"
    );
}

/// Blur up close: the camera closes in on a tree's crown, from where the twig level's
/// texels project to 1 pixel to where they project to 4 (the finest level has nothing finer
/// to switch to, so it blurs). Mean FLIP against the truth per frame, as a function of
/// texels per pixel, is printed. Measured on lavapipe (128x128), LOD knob 1: 0.096, 0.128,
/// 0.173, 0.192, 0.188 at 1, 1.4, 2, 2.8, 4 px (mean 0.155; nearer, at 5.7 and 8 px with the
/// camera in the crown, it falls again to 0.147 and 0.104); LOD knob 16, coarser levels kept
/// up close: 0.249, 0.217, 0.259, 0.297, 0.299 (mean 0.264). Bounds: the mean with the knob
/// at 1 under `BLUR_MAX_FLIP`, the knob at 16 over it; and the blur grows: the FLIP at 2.8 px
/// at least 1.5 times the FLIP at 1 px.
const BLUR_MAX_FLIP: f64 = 0.21;

#[test]
fn blur_up_close_grows_with_the_texel_size_and_stays_bounded() {
    let ctx = gpu();
    let (scene, world, mut renderer) = setup(&ctx);
    let (tree, centre) = first_tree(&world);
    let size = 128;
    let fov = 40.0;
    let focal = Camera::look_at(Vec3::ZERO, Vec3::Z, fov).focal_px(size);
    let texels = renderer.btf_texels(tree.species as usize).unwrap();
    let twig = texels.twig * tree.scale;
    // Distances where a twig texel covers 1, 1.4, 2, 2.8 and 4 pixels, seen from the side
    // and a little above.
    let dir = Vec3::new(-0.8, 0.3, -0.5).normalize();
    let px: Vec<f32> = (0..5).map(|i| 2f32.powf(i as f32 * 0.5)).collect();
    let frames: Vec<FlightFrame> = px
        .iter()
        .enumerate()
        .map(|(i, &p)| frame(i, centre + dir * (twig * focal / p), centre, None))
        .collect();
    let mut b = base(&scene);
    b.camera.fov_y_deg = fov;
    let configs = [
        btf("lod 1", |s| s.lod_scale = 1.0),
        btf("lod 16", |s| s.lod_scale = 16.0),
    ];
    let r = run::run(
        &ctx,
        &mut renderer,
        &b,
        &frames,
        &configs,
        &options("blur", size),
        &mut |_| {},
    )
    .unwrap();
    let flip = |c: usize| -> Vec<f64> {
        r.rows
            .iter()
            .filter(|row| row.config == c)
            .map(|row| row.mean_flip)
            .collect()
    };
    let (fine, coarse) = (flip(0), flip(1));
    for (i, p) in px.iter().enumerate() {
        eprintln!(
            "twig texel {p:.1} px ({:.1} m): mean FLIP lod 1 {:.4}, lod 16 {:.4}",
            frames[i].distance(),
            fine[i],
            coarse[i]
        );
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&fine) < BLUR_MAX_FLIP,
        "up close with the LOD knob at 1: mean FLIP {:.4}",
        mean(&fine)
    );
    assert!(
        mean(&coarse) > BLUR_MAX_FLIP,
        "coarser levels up close must blur past the bound: {:.4}",
        mean(&coarse)
    );
    assert!(
        fine[3] > 1.5 * fine[0],
        "the blur grows with the texel size: {:.4} at 2.8 px, {:.4} at 1 px",
        fine[3],
        fine[0]
    );
}

/// `hybrid`'s switch to geometry: the camera comes at a tree across the distance where its
/// twig texels pass the LOD bound (from above, where that lies outside the crown), 17 frames
/// from 1.04 to 0.96 times that distance in 0.5 % steps. Past the bound the tree is
/// geometry (stats), before it twig billboards.
///
/// The suite's pop metric (change beyond the truth's, scaled to the method's median) does
/// not fit this switch: as the geometry fades in the method's frame-to-frame change rises
/// steadily from the billboards' level to the truth's (0.053 to 0.077 a frame against the
/// truth's 0.069 to 0.074), and the scaled excess of the last frames, 0.0106, measures that
/// regime change, not a pop (the abrupt switch: 0.092). So the switch is judged by the jump:
/// the largest rise of the method's change from one frame to the next beyond the truth's
/// rise there. Measured on lavapipe (128x128): cross-fade 0.2: 0.0030; abrupt (`lod_fade` 0):
/// 0.092 at the switch. Bound between them, and the abrupt switch must exceed it.
const HYBRID_SWITCH_MAX_JUMP: f64 = 0.015;

#[test]
fn hybrid_switches_a_near_tree_to_geometry_and_cross_fades_the_switch() {
    let ctx = gpu();
    let (scene, world, mut renderer) = setup(&ctx);
    let (tree, centre) = first_tree(&world);
    let size = 128;
    let focal = Camera::look_at(Vec3::ZERO, Vec3::Z, 40.0).focal_px(size);
    let texels = renderer.btf_texels(tree.species as usize).unwrap();
    let lod_scale = 1.0;
    let bound = canopy::lod::valid_beyond(texels.twig * tree.scale, focal, lod_scale);
    // From above and to the side, away from the neighbours.
    let dir = Vec3::new(-0.45, 0.75, -0.45).normalize();
    let hybrid = |label: &str, fade: f32| {
        let mut c = btf(label, |s| {
            s.lod_scale = lod_scale;
            s.lod_fade = fade;
        });
        c.method = Method::Hybrid;
        c
    };
    let mut b = base(&scene);
    b.camera.fov_y_deg = 40.0;

    // Stats: geometry inside the bound, billboards outside; the other trees stay images.
    let mut at = |k: f32, fade: f32| {
        let mut d = b;
        d.method = Method::Hybrid;
        hybrid("", fade).knobs.apply_to(&mut d);
        frame(0, centre + dir * bound * k, centre, None).apply(&mut d);
        let (_, stats) = renderer.render_image(&ctx, &d, size, size, 1).unwrap();
        stats.btf.expect("hybrid reports btf stats")
    };
    // The fade band runs from 1.25 times the bound (twig texels of 0.8 px) in to it.
    let inside = at(0.9, 0.2);
    let outside = at(1.3, 0.2);
    let band = at(1.12, 0.2);
    eprintln!(
        "hybrid at 0.9 / 1.3 / 1.12 times the bound {bound:.2} m: geometry trees {} / {} / {}, faded {} / {} / {}, twig trees {} / {} / {}",
        inside.geometry_trees,
        outside.geometry_trees,
        band.geometry_trees,
        inside.faded_trees,
        outside.faded_trees,
        band.faded_trees,
        inside.trees_per_level.twig,
        outside.trees_per_level.twig,
        band.trees_per_level.twig
    );
    // (A neighbour may be inside its own bound too.)
    assert!(inside.geometry_trees >= 1, "{inside:?}");
    assert_eq!(outside.geometry_trees, 0, "{outside:?}");
    assert!(outside.trees_per_level.twig >= 1, "{outside:?}");
    assert!(
        inside.trees_per_level.iter().sum::<u32>() >= 1,
        "far trees stay images"
    );
    assert!(
        band.faded_trees >= 1 && band.geometry_trees == 0,
        "{band:?}"
    );

    let n = 17;
    let frames: Vec<FlightFrame> = (0..n)
        .map(|i| {
            let k = 1.04 - 0.005 * i as f32;
            frame(i, centre + dir * bound * k, centre, None)
        })
        .collect();
    let configs = [hybrid("hybrid fade 0.2", 0.2), hybrid("hybrid abrupt", 0.0)];
    let r = run::run(
        &ctx,
        &mut renderer,
        &b,
        &frames,
        &configs,
        &options("hybrid", size),
        &mut |_| {},
    )
    .unwrap();
    print_flight(&r, "geometry switch");
    let jump = |c: usize| {
        let series: Vec<(f64, f64)> = r
            .rows
            .iter()
            .filter(|row| row.config == c)
            .filter_map(|row| Some((row.change?, row.truth_change?)))
            .collect();
        series
            .windows(2)
            .map(|w| (w[1].0 - w[0].0) - (w[1].1 - w[0].1))
            .fold(f64::MIN, f64::max)
    };
    let (fade, abrupt) = (jump(0), jump(1));
    eprintln!("geometry switch: largest jump, cross-fade {fade:.4}, abrupt {abrupt:.4}");
    assert!(
        fade < HYBRID_SWITCH_MAX_JUMP,
        "with the cross-fade the largest jump is {fade:.4}"
    );
    assert!(
        abrupt > HYBRID_SWITCH_MAX_JUMP,
        "the abrupt switch must show as a jump above the bound: {abrupt:.4}"
    );
}
