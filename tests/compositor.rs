//! The tile compositor (`compositor`, `src/render/compositor.rs`): the picture of the
//! raster path front to back into the trees' layer, within a bound, on the GPU's sort and
//! on the CPU's; the early stop, which changes nothing at 0 and stops opaque pixels; and
//! every tile composited once.

use canopy::render::{FrameDesc, GpuContext, Renderer};
use canopy::scene::Scene;

use crate::common::*;
use crate::front_to_back::frame;

/// Mean FLIP over the trees' pixels between the compositor and the raster path front to
/// back (the same sum: the raster layer sums in half floats and leaves out what lies behind
/// a pixel its batches made opaque, the compositor sums in float and stops a pixel below
/// 1/256; and the raster derivatives are taken over 2x2 pixels, the compositor's from the
/// next pixels' rays). Measured on lavapipe (2026-12-07): see the eprintln of each run.
const MAX_MEAN_FLIP_TREES: f32 = 0.02;

/// The same over the whole frame (the goal: within 0.005 of the front-to-back frame).
const MAX_MEAN_FLIP_FRAME: f32 = 0.005;

const SIZE: (u32, u32) = (192, 128);

fn setup(ctx: &GpuContext) -> (Scene, Renderer) {
    let scene = load_scene("canopy_stand.toml");
    let (_, renderer) = baked_renderer(ctx, &scene);
    (scene, renderer)
}

fn render(ctx: &GpuContext, renderer: &mut Renderer, frame: &FrameDesc) -> image::RgbaImage {
    renderer
        .render_image(ctx, frame, SIZE.0, SIZE.1, 1)
        .unwrap()
        .0
}

/// `frame` through the raster layer and through the compositor, within the bounds of each
/// other.
fn check(ctx: &GpuContext, renderer: &mut Renderer, frame: &FrameDesc, what: &str) {
    let mut raster = *frame;
    raster.btf.front_to_back = true;
    raster.btf.compositor = false;
    let mut tiles = *frame;
    tiles.btf.front_to_back = false;
    tiles.btf.compositor = true;
    let a = render(ctx, renderer, &raster);
    let b = render(ctx, renderer, &tiles);
    let counters = renderer
        .compositor_counters(ctx)
        .unwrap()
        .expect("the frame did not go through the compositor");
    let mut bare = *frame;
    bare.trees = false;
    let bare = render(ctx, renderer, &bare);
    let (mean, covered, frame_mean) = flip_over_trees(&a, &b, &bare);
    eprintln!(
        "{what}: compositor against the raster layer: mean FLIP {mean:.4} over the trees ({covered} pixels), {frame_mean:.4} over the frame; {counters:?}"
    );
    assert!(covered > 4000, "the trees cover only {covered} pixels");
    let tiles_of = |n: u32| n.div_ceil(canopy::render::compositor::TILE);
    assert_eq!(
        counters.tiles,
        tiles_of(SIZE.0) * tiles_of(SIZE.1),
        "every tile is composited once"
    );
    assert!(counters.layers > 0, "{counters:?}");
    assert!(
        mean < MAX_MEAN_FLIP_TREES && frame_mean < MAX_MEAN_FLIP_FRAME,
        "{what}: the compositor differs from the raster layer: mean FLIP {mean} over the trees \
         (bound {MAX_MEAN_FLIP_TREES}), {frame_mean} over the frame (bound {MAX_MEAN_FLIP_FRAME})"
    );
}

#[test]
fn the_compositor_gives_the_raster_layers_picture_on_the_gpus_sort() {
    let ctx = gpu();
    let (scene, mut renderer) = setup(&ctx);
    let f = frame(&scene);
    assert!(f.btf.gpu_far, "the defaults changed");
    check(&ctx, &mut renderer, &f, "GPU sort");
}

#[test]
fn the_compositor_gives_the_raster_layers_picture_on_the_cpus_sort() {
    let ctx = gpu();
    let (scene, mut renderer) = setup(&ctx);
    let mut f = frame(&scene);
    f.btf.gpu_far = false;
    check(&ctx, &mut renderer, &f, "CPU sort");
}

/// With the stop at 0 every layer is shaded and no pixel stops; at the default, pixels
/// stop where they are opaque, fewer layers are shaded, and the picture moves by less
/// than what was left out.
#[test]
fn the_early_stop_changes_nothing_at_zero_and_stops_where_a_pixel_is_opaque() {
    let ctx = gpu();
    let (scene, mut renderer) = setup(&ctx);
    let mut f = frame(&scene);
    f.btf.compositor = true;
    f.btf.stop_below = 0.0;
    let all = render(&ctx, &mut renderer, &f);
    let c_all = renderer.compositor_counters(&ctx).unwrap().unwrap();
    f.btf.stop_below = canopy::render::compositor::STOP_BELOW;
    let stopped = render(&ctx, &mut renderer, &f);
    let c_stop = renderer.compositor_counters(&ctx).unwrap().unwrap();
    eprintln!("stop 0: {c_all:?}\nstop 1/256: {c_stop:?}");
    assert_eq!(c_all.pixels_stopped, 0, "{c_all:?}");
    assert_eq!(c_all.tiles_stopped, 0, "{c_all:?}");
    assert!(c_stop.pixels_stopped > 0, "{c_stop:?}");
    assert!(
        c_stop.layers < c_all.layers,
        "the stop shaded as many layers: {c_stop:?} against {c_all:?}"
    );
    let mean = canopy::metrics::flip(&rgb(&all), &rgb(&stopped))
        .unwrap()
        .stats
        .mean;
    eprintln!("stop 0 against 1/256: mean FLIP {mean:.5}");
    assert!(mean < 0.002, "the early stop moved the picture by {mean}");
}
