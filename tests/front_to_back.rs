//! The billboards front to back into the trees' layer (`front_to_back`,
//! `src/render/layer.rs`): the picture of drawing them back to front over the frame, within
//! a bound, on the GPU's sort and on the CPU's, with every billboard still drawn.

use canopy::model::World;
use canopy::render::{Camera, FrameDesc, FrameStats, GpuContext, Method, Reference, Renderer};
use canopy::scene::Scene;
use glam::Vec3;

use crate::common::*;

/// Mean FLIP between back to front and front to back over the pixels the trees cover. The
/// two are the same sum but for rounding: back to front rounds the frame to 8-bit sRGB after
/// each of the 20-60 billboards over a pixel (the trees come out about 1 % brighter), front
/// to back sums them in half floats and rounds once; and what lies behind a pixel the
/// layer made opaque (less than 0.4 % let through) is left out. Measured on lavapipe
/// (llvmpipe 15, 2026-11-28), the dense stand at 150 m: 0.048 over the trees (0.017 over
/// the frame), on the GPU's sort and on the CPU's alike. Drawn in the wrong order (the
/// far billboards over the near ones) the same frame measures 0.118.
const MAX_MEAN_FLIP: f32 = 0.07;

/// How much farther from the reference (mean FLIP over the frame) front to back may be
/// than back to front. Measured (same run): 0.0805 back to front, 0.0807 front to back;
/// the wrong order 0.0845.
const MAX_TRUTH_LOSS: f32 = 0.002;

const SIZE: (u32, u32) = (192, 128);

fn setup(ctx: &GpuContext) -> (Scene, World, Renderer) {
    let scene = load_scene("canopy_stand.toml");
    let (world, renderer) = baked_renderer(ctx, &scene);
    (scene, world, renderer)
}

/// The dense stand seen low across it, crown behind crown, the near trees at the finer
/// levels (the compositor's tests draw it too).
pub(crate) fn frame(scene: &Scene) -> FrameDesc {
    let mut f = FrameDesc::from_scene(scene);
    let target = Vec3::new(0.0, 6.0, 0.0);
    let dir = Vec3::new(0.2, 0.22, -1.0).normalize_or_zero();
    f.camera = Camera::look_at(target + dir * 150.0, target, 30.0);
    f.method = Method::Btf;
    f
}

/// The two frames of `frame`, back to front and front to back.
struct Pair {
    off: image::RgbaImage,
    on: image::RgbaImage,
    s_on: FrameStats,
}

/// `frame` back to front and front to back, checked alike (every billboard drawn, the
/// front-to-back ones in batches) and within [`MAX_MEAN_FLIP`] of each other over the
/// trees' pixels.
fn check(ctx: &GpuContext, renderer: &mut Renderer, frame: &FrameDesc, what: &str) -> Pair {
    let mut frame = *frame;
    frame.btf.front_to_back = false;
    let (off, s_off) = renderer
        .render_image(ctx, &frame, SIZE.0, SIZE.1, 1)
        .unwrap();
    frame.btf.front_to_back = true;
    let (on, s_on) = renderer
        .render_image(ctx, &frame, SIZE.0, SIZE.1, 1)
        .unwrap();
    frame.trees = false;
    let (bare, _) = renderer
        .render_image(ctx, &frame, SIZE.0, SIZE.1, 1)
        .unwrap();
    let (mean, covered, frame_mean) = flip_over_trees(&off, &on, &bare);
    assert!(covered > 4000, "the trees cover only {covered} pixels");
    let (b_off, b_on) = (s_off.btf.unwrap(), s_on.btf.unwrap());
    eprintln!(
        "{what}: mean FLIP {mean:.4} over the trees ({covered} pixels), {:.4} over the frame; {} billboards; draw calls {} -> {}",
        frame_mean,
        b_on.total_billboards(),
        s_off.draw_calls,
        s_on.draw_calls
    );
    assert!(
        b_on.billboards.branch > 0 && b_on.billboards.tree > 0,
        "{b_on:?}"
    );
    assert_eq!(b_off.total_billboards(), b_on.total_billboards());
    // The billboards go into the layer in batches: one draw each.
    assert!(
        s_on.draw_calls > s_off.draw_calls,
        "the billboards were not drawn in batches: {} draw calls, {} back to front",
        s_on.draw_calls,
        s_off.draw_calls
    );
    assert!(
        mean < MAX_MEAN_FLIP,
        "{what}: front to back vs back to front, mean FLIP {mean} over the trees, bound {MAX_MEAN_FLIP}"
    );
    Pair { off, on, s_on }
}

#[test]
fn front_to_back_is_as_near_the_reference_as_back_to_front_on_the_gpus_sort() {
    let ctx = gpu();
    let (scene, world, mut renderer) = setup(&ctx);
    let f = frame(&scene);
    assert!(f.btf.gpu_far, "the defaults changed");
    let p = check(&ctx, &mut renderer, &f, "GPU sort");
    assert!(p.s_on.btf.unwrap().gpu_billboards > 0);
    prepare_reference(&mut renderer, &ctx, &scene, &world);
    let mut t = f;
    t.method = Method::Geometry;
    t.reference = Some(Reference::default());
    let (truth, _) = renderer.render_image(&ctx, &t, SIZE.0, SIZE.1, 2).unwrap();
    let to_truth = |img: &image::RgbaImage| {
        canopy::metrics::flip(&rgb(&truth), &rgb(img))
            .unwrap()
            .stats
            .mean
    };
    let (off, on) = (to_truth(&p.off), to_truth(&p.on));
    eprintln!("against the reference: back to front {off:.4}, front to back {on:.4}");
    assert!(
        on <= off + MAX_TRUTH_LOSS,
        "front to back is farther from the reference: {on} against {off} back to front"
    );
}

#[test]
fn front_to_back_gives_the_back_to_front_picture_on_the_cpus_sort() {
    let ctx = gpu();
    let (scene, _, mut renderer) = setup(&ctx);
    let mut f = frame(&scene);
    f.btf.gpu_far = false;
    let p = check(&ctx, &mut renderer, &f, "CPU sort");
    assert_eq!(p.s_on.btf.unwrap().gpu_billboards, 0);
}
