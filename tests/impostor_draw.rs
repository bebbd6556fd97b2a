//! The `impostor` method on the GPU (lavapipe), on the lone fir baked with 12 x 12 frames of
//! 64 px: against the reference at a view on a baked frame and between frames; orbiting in
//! small steps (no step larger than 4x the median, the stability suite's rule for views
//! between samples); the sun swept across the sky (continuous, and it does relight); and
//! the crown with the sun behind the camera (its luminance against the reference's, with
//! btf's beside it).

use crate::common;

use std::sync::OnceLock;

use crate::common::{gpu, lone_fir, prepare_reference, rgb};
use canopy::format::Baked;
use canopy::model::World;
use canopy::render::{Camera, FrameDesc, GpuContext, Method, Renderer};
use canopy::sphere::{Frame, OctaGrid, OctaLayout};
use glam::{Mat3, Vec3};

const SIZE: u32 = 128;

/// The lone fir's BTF and its impostor (12 x 12 frames of 64 px, full sphere), baked once.
fn baked() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| {
        let ctx = gpu();
        let world = lone_fir().build_world().unwrap();
        let mut baked = common::lone_fir_btf().clone();
        let settings = canopy::format::BakeSettings {
            impostor_frames: 12,
            impostor_resolution: 64,
            impostor_layout: OctaLayout::Full,
            ..canopy::bake::cache::settings_of(&lone_fir())
        };
        baked.impostors =
            canopy::bake::impostor::bake_impostors(&ctx, &world, &settings, &mut |_, _| {})
                .unwrap();
        baked
    })
}

fn setup(ctx: &GpuContext) -> (World, Renderer) {
    let scene = lone_fir();
    let world = scene.build_world().unwrap();
    let mut r = Renderer::new(ctx, &world).unwrap();
    r.attach_btf(ctx, baked(), &world).unwrap();
    prepare_reference(&mut r, ctx, &scene, &world);
    (world, r)
}

/// The fir's bounding-sphere centre and radius in the world, and its rotation.
fn sphere(world: &World) -> (Vec3, f32, Mat3) {
    let imp = &baked().impostors[0];
    let tree = world.forest.instances[0];
    let rot = Mat3::from_rotation_y(tree.yaw);
    let center = tree.position + rot * Vec3::from(imp.center) * tree.scale;
    (center, imp.radius * tree.scale, rot)
}

/// The frame looking at the fir from world direction `dir` (unit, towards the camera),
/// `radii` of its bounding sphere away; the impostor alone (no geometry however near).
fn frame_at(world: &World, dir: Vec3, radii: f32) -> FrameDesc {
    let (center, radius, _) = sphere(world);
    let mut f = FrameDesc::from_scene(&lone_fir());
    f.fog_density = 0.0;
    f.camera = Camera::look_at(center + dir * (radii * radius), center, 40.0);
    f.impostor.geometry_px = 0.0;
    f
}

fn frame_from(world: &World, dir: Vec3) -> FrameDesc {
    frame_at(world, dir, 3.2)
}

fn draw(ctx: &GpuContext, r: &mut Renderer, frame: &FrameDesc, method: Method) -> image::RgbaImage {
    let mut f = *frame;
    f.method = method;
    r.render_image(ctx, &f, SIZE, SIZE, 1).unwrap().0
}

fn reference(ctx: &GpuContext, r: &mut Renderer, frame: &FrameDesc) -> image::RgbaImage {
    let mut f = *frame;
    f.method = Method::Geometry;
    f.reference = Some(canopy::render::Reference::default());
    r.render_image(ctx, &f, SIZE, SIZE, 2).unwrap().0
}

/// The pixels where the fir is drawn in either image (they differ from the bare ground
/// and sky by more than 4 levels).
fn tree_mask(
    ctx: &GpuContext,
    frame: &FrameDesc,
    a: &image::RgbaImage,
    b: &image::RgbaImage,
) -> Vec<bool> {
    let mut bare_scene = lone_fir();
    bare_scene.forest.count = Some(0);
    let bare_world = bare_scene.build_world().unwrap();
    let mut bare = Renderer::new(ctx, &bare_world).unwrap();
    let mut f = *frame;
    f.method = Method::Geometry;
    let (ground, _) = bare.render_image(ctx, &f, SIZE, SIZE, 1).unwrap();
    let differs = |x: &image::Rgba<u8>, y: &image::Rgba<u8>| {
        x.0.iter().zip(y.0.iter()).any(|(p, q)| p.abs_diff(*q) > 4)
    };
    let mask: Vec<bool> = a
        .pixels()
        .zip(b.pixels())
        .zip(ground.pixels())
        .map(|((p, q), g)| differs(p, g) || differs(q, g))
        .collect();
    assert!(
        mask.iter().filter(|&&m| m).count() > 500,
        "the fir is not in view"
    );
    mask
}

fn masked_flip(a: &image::RgbaImage, b: &image::RgbaImage, mask: &[bool]) -> f32 {
    let r = canopy::metrics::flip(&rgb(a), &rgb(b)).unwrap();
    let (sum, n) = r
        .errors
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .fold((0.0f64, 0usize), |(s, n), (e, _)| {
            (s + f64::from(*e), n + 1)
        });
    (sum / n.max(1) as f64) as f32
}

fn mean_flip(a: &image::RgbaImage, b: &image::RgbaImage) -> f32 {
    canopy::metrics::flip(&rgb(a), &rgb(b)).unwrap().stats.mean
}

/// Mean linear luminance over the masked pixels.
fn masked_luminance(img: &image::RgbaImage, mask: &[bool]) -> f32 {
    let lin = |c: u8| (f32::from(c) / 255.0).powf(2.2);
    let (sum, n) =
        img.pixels()
            .zip(mask)
            .filter(|(_, m)| **m)
            .fold((0.0f32, 0usize), |(s, n), (p, _)| {
                let l = 0.2126 * lin(p.0[0]) + 0.7152 * lin(p.0[1]) + 0.0722 * lin(p.0[2]);
                (s + l, n + 1)
            });
    sum / n.max(1) as f32
}

/// Mean FLIP over the fir against the reference, at a view on a baked frame (row 4,
/// column 3 of the 12 x 12 grid: 20 degrees above the horizon) and halfway between frames.
/// Measured on lavapipe: on the frame 0.214 (btf 0.209), between frames 0.216 (btf 0.209);
/// the images are written to `canopy-impostor-draw-*` in the temporary directory.
#[test]
fn a_lone_fir_as_an_impostor_against_the_reference() {
    let ctx = gpu();
    let (world, mut r) = setup(&ctx);
    let (_, _, rot) = sphere(&world);
    let grid = OctaGrid::new(OctaLayout::Full, 12);
    let on = grid.frame_dir(Frame { i: 3, j: 4 });
    let next = grid.frame_dir(Frame { i: 4, j: 4 });
    let between = (on + next).normalize();
    for (name, dir, bound) in [("on a frame", on, 0.26), ("between frames", between, 0.26)] {
        let frame = frame_from(&world, rot * dir);
        let truth = reference(&ctx, &mut r, &frame);
        let imp = draw(&ctx, &mut r, &frame, Method::Impostor);
        let btf = draw(&ctx, &mut r, &frame, Method::Btf);
        let mask = tree_mask(&ctx, &frame, &truth, &imp);
        let (e_imp, e_btf) = (
            masked_flip(&truth, &imp, &mask),
            masked_flip(&truth, &btf, &mask),
        );
        eprintln!("{name}: mean FLIP over the fir, impostor {e_imp:.4}, btf {e_btf:.4}");
        let dir = common::scratch_dir("impostor-draw");
        for (what, img) in [("reference", &truth), ("impostor", &imp), ("btf", &btf)] {
            let path = dir.join(format!("{}-{what}.png", name.replace(' ', "-")));
            canopy::imageio::save_png(&path, img).unwrap();
        }
        assert!(
            e_imp < bound,
            "{name}: impostor {e_imp} against the reference"
        );
    }
}

/// Orbiting the fir 1.5 degrees a step, 20 degrees above the horizon: no step changes the
/// picture more than 4 times the median step.
#[test]
fn orbiting_the_fir_in_small_steps_changes_the_impostor_smoothly() {
    let ctx = gpu();
    let (world, mut r) = setup(&ctx);
    let images: Vec<image::RgbaImage> = (0..24)
        .map(|k| {
            let az = (20.0 + 1.5 * k as f32).to_radians();
            let el = 20f32.to_radians();
            let dir = Vec3::new(az.sin() * el.cos(), el.sin(), az.cos() * el.cos());
            draw(&ctx, &mut r, &frame_from(&world, dir), Method::Impostor)
        })
        .collect();
    let mut steps: Vec<f32> = images.windows(2).map(|w| mean_flip(&w[0], &w[1])).collect();
    let worst = steps.iter().copied().fold(0.0f32, f32::max);
    steps.sort_by(f32::total_cmp);
    let median = steps[steps.len() / 2];
    eprintln!("orbit steps: median {median:.4}, worst {worst:.4}");
    assert!(median > 0.0, "the picture never changed");
    assert!(
        worst <= 4.0 * median,
        "worst step {worst} > 4 x median {median}"
    );
}

/// The sun swept across the sky 10 degrees a step: the impostor follows it without jumps
/// (no step above 4x the median) and is relit (the first and last pictures differ).
#[test]
fn sweeping_the_sun_relights_the_impostor_continuously() {
    let ctx = gpu();
    let (world, mut r) = setup(&ctx);
    let base = frame_from(&world, Vec3::new(0.3, 0.35, 0.9).normalize());
    let images: Vec<image::RgbaImage> = (0..18)
        .map(|k| {
            let mut f = base;
            f.sun.azimuth_deg = 10.0 * k as f32;
            f.sun.elevation_deg = 35.0;
            draw(&ctx, &mut r, &f, Method::Impostor)
        })
        .collect();
    let mut steps: Vec<f32> = images.windows(2).map(|w| mean_flip(&w[0], &w[1])).collect();
    let worst = steps.iter().copied().fold(0.0f32, f32::max);
    steps.sort_by(f32::total_cmp);
    let median = steps[steps.len() / 2];
    let span = mean_flip(&images[0], &images[images.len() - 1]);
    eprintln!("sun sweep: median step {median:.4}, worst {worst:.4}, first to last {span:.4}");
    assert!(
        span > 0.01,
        "the sun does not relight the impostor ({span})"
    );
    assert!(
        worst <= 4.0 * median,
        "worst step {worst} > 4 x median {median}"
    );
}

/// Walking up to the fir through the band where its geometry fades in over the impostor
/// (frame texels of 1.6 to 2 px): no step changes the picture more than 4 times the median
/// step, far away it is an impostor alone and near it is geometry alone.
#[test]
fn walking_up_to_the_fir_through_the_geometry_band_does_not_pop() {
    let ctx = gpu();
    let (world, mut r) = setup(&ctx);
    let dir = Vec3::new(0.3, 0.3, 0.9).normalize();
    let mut geometry = Vec::new();
    let images: Vec<image::RgbaImage> = (0..16)
        .map(|k| {
            let mut f = frame_at(&world, dir, 4.0 - 0.1 * k as f32);
            f.impostor.geometry_px = 2.0;
            f.method = Method::Impostor;
            let (img, stats) = r.render_image(&ctx, &f, SIZE, SIZE, 1).unwrap();
            let s = stats.impostor.unwrap();
            geometry.push((s.impostors, s.geometry_trees));
            img
        })
        .collect();
    let mut steps: Vec<f32> = images.windows(2).map(|w| mean_flip(&w[0], &w[1])).collect();
    let worst = steps.iter().copied().fold(0.0f32, f32::max);
    steps.sort_by(f32::total_cmp);
    let median = steps[steps.len() / 2];
    eprintln!(
        "approach: median step {median:.4}, worst {worst:.4}; (impostors, geometry) {geometry:?}"
    );
    assert_eq!(geometry[0], (1, 0), "far away: the impostor alone");
    assert_eq!(geometry[15], (0, 1), "near: the geometry alone");
    assert!(
        geometry.contains(&(1, 1)),
        "a step inside the band draws both"
    );
    assert!(
        worst <= 4.0 * median,
        "worst step {worst} > 4 x median {median}"
    );
}

/// The sun behind the camera: the crown's mean luminance over the reference's. Measured on
/// lavapipe: impostor 1.11 (1.20 without self-shadowing), btf 0.91.
#[test]
fn a_crown_lit_from_behind_the_camera_against_the_reference() {
    let ctx = gpu();
    let (world, mut r) = setup(&ctx);
    let dir = Vec3::new(0.5, 0.35, 0.8).normalize();
    let mut frame = frame_from(&world, dir);
    // The sun where the camera is.
    frame.sun.azimuth_deg = dir.x.atan2(dir.z).to_degrees();
    frame.sun.elevation_deg = dir.y.asin().to_degrees();
    let truth = reference(&ctx, &mut r, &frame);
    let imp = draw(&ctx, &mut r, &frame, Method::Impostor);
    let btf = draw(&ctx, &mut r, &frame, Method::Btf);
    let mask = tree_mask(&ctx, &frame, &truth, &imp);
    let l = masked_luminance(&truth, &mask);
    let (ri, rb) = (
        masked_luminance(&imp, &mask) / l,
        masked_luminance(&btf, &mask) / l,
    );
    eprintln!(
        "sun behind the camera: crown luminance over the reference's, impostor {ri:.3}, btf {rb:.3}"
    );
    assert!((0.9..1.3).contains(&ri), "impostor {ri}");
}

/// The sun behind the fir (the camera looks towards it, 35 degrees up): the crown's
/// luminance over the reference's with and without the impostor's self-shadowing, which
/// must bring it closer. Measured on lavapipe: 0.99 with, 1.03 without (btf 1.05).
#[test]
fn self_shadowing_darkens_a_crown_lit_from_behind_towards_the_reference() {
    let ctx = gpu();
    let (world, mut r) = setup(&ctx);
    let dir = Vec3::new(0.5, 0.35, 0.8).normalize();
    let mut frame = frame_from(&world, dir);
    frame.sun.azimuth_deg = (-dir.x).atan2(-dir.z).to_degrees();
    frame.sun.elevation_deg = 35.0;
    let truth = reference(&ctx, &mut r, &frame);
    let with = draw(&ctx, &mut r, &frame, Method::Impostor);
    frame.impostor.self_shadow = 0.0;
    let without = draw(&ctx, &mut r, &frame, Method::Impostor);
    let btf = draw(&ctx, &mut r, &frame, Method::Btf);
    let mask = tree_mask(&ctx, &frame, &truth, &with);
    let l = masked_luminance(&truth, &mask);
    let ratio = |img: &image::RgbaImage| masked_luminance(img, &mask) / l;
    let (rw, ro, rb) = (ratio(&with), ratio(&without), ratio(&btf));
    eprintln!(
        "sun behind the fir: crown luminance over the reference's, impostor {rw:.3} (without self-shadowing {ro:.3}), btf {rb:.3}"
    );
    assert!((rw - 1.0).abs() < (ro - 1.0).abs(), "{rw} vs {ro}");
    assert!(
        rw < ro - 0.01,
        "self-shadowing barely darkens: {rw} vs {ro}"
    );
}
