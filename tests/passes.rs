//! Every pass is timed (issue 34 item 1): each method's frame names the passes it encodes,
//! in order, and their GPU times add up to the frame's; where the adapter cannot time
//! inside a pass the main pass is one span, and without timestamp queries a frame has no
//! pass times and still draws.

use crate::common;

use canopy::format::Baked;
use canopy::model::World;
use canopy::render::{FrameDesc, FrameStats, GpuContext, Method, Renderer};
use canopy::scene::Scene;

use crate::common::*;

const W: u32 = 96;
const H: u32 = 64;

/// The lone-tree scene, with texel volumes so that every method draws.
fn scene() -> Scene {
    let mut scene = Scene::load(&data("lone_tree.toml")).expect("tests/data/lone_tree.toml parses");
    scene.bake.texel_resolution = 32;
    scene
}

/// The scene's bake, made once per run.
fn baked() -> &'static Baked {
    common::baked(&scene())
}

fn renderer(ctx: &GpuContext, world: &World) -> Renderer {
    let mut r = Renderer::new(ctx, world).unwrap();
    r.attach_btf(ctx, baked(), world).unwrap();
    r
}

/// A measured frame of `method` after a warm-up frame (pipelines built, ground maps made).
fn measured(ctx: &GpuContext, r: &mut Renderer, scene: &Scene, method: Method) -> FrameStats {
    measured_with(ctx, r, scene, method, |_| {})
}

fn measured_with(
    ctx: &GpuContext,
    r: &mut Renderer,
    scene: &Scene,
    method: Method,
    knobs: impl Fn(&mut FrameDesc),
) -> FrameStats {
    let mut frame = FrameDesc {
        method,
        ..FrameDesc::from_scene(scene)
    };
    knobs(&mut frame);
    r.render_image(ctx, &frame, W, H, 1).unwrap();
    r.render_image(ctx, &frame, W, H, 1).unwrap().1
}

fn names(stats: &FrameStats) -> Vec<&'static str> {
    stats.passes.iter().map(|p| p.name).collect()
}

/// The passes add up to the frame: spans do not overlap, so their sum is at most the
/// frame's time, and it falls short of it only by the gaps between passes (a flush on
/// lavapipe), which stay under a tenth of the frame plus a millisecond.
fn assert_adds_up(what: &str, stats: &FrameStats) {
    let frame = stats.gpu_ms.expect("a measured frame has a GPU time");
    let sum = stats.passes.total_ms();
    println!(
        "{what}: frame {frame:.2} ms, passes {sum:.2} ms: {:?}",
        stats.passes
    );
    assert!(
        sum <= frame * 1.0001 + 1e-3,
        "{what}: passes {sum} ms exceed the frame {frame} ms"
    );
    assert!(
        sum >= 0.9 * frame - 1.0,
        "{what}: passes {sum} ms leave too much of the frame {frame} ms untimed"
    );
    assert!(stats.passes.iter().all(|p| p.ms >= 0.0 && p.ms.is_finite()));
}

fn skip_without_timestamps(ctx: &GpuContext) -> bool {
    if !ctx.timestamps {
        println!(
            "skipped: the adapter {} has no timestamp queries",
            ctx.adapter_name()
        );
    }
    !ctx.timestamps
}

#[test]
fn every_method_names_its_passes_and_they_add_up_to_the_frame() {
    let ctx = gpu();
    if skip_without_timestamps(&ctx) {
        return;
    }
    if !ctx.timestamps_inside_passes {
        println!("skipped: {} cannot time inside passes", ctx.adapter_name());
        return;
    }
    let scene = scene();
    let world = scene.build_world().unwrap();
    let mut r = renderer(&ctx, &world);
    let expected: [(Method, &[&str]); 6] = [
        (Method::Geometry, &["cascades", "sky", "terrain", "trees"]),
        (
            Method::Billboard,
            &["cascades", "sky", "terrain", "near trees", "billboards"],
        ),
        (
            Method::Btf,
            &[
                "far trees",
                "far sort",
                "cascades",
                "sky",
                "terrain",
                "near trees",
                "billboards",
            ],
        ),
        (
            Method::Texel,
            &["cascades", "sky", "terrain", "texel tiles", "texels"],
        ),
        (
            Method::Impostor,
            &["cascades", "sky", "terrain", "impostors"],
        ),
        (
            Method::Surfel,
            &[
                "cascades",
                "sky",
                "terrain",
                "surfel",
                "surfels: splat",
                "surfels: fill",
                "surfels",
            ],
        ),
    ];
    for (method, want) in expected {
        let stats = measured(&ctx, &mut r, &scene, method);
        assert_eq!(names(&stats), want, "{}'s passes", method.name());
        assert_adds_up(method.name(), &stats);
    }
    // `hybrid` draws its tree level as impostors (`impostor_px` at a LOD scale that puts
    // the lone tree there), or by default as BTF billboards: `btf`'s passes.
    let stats = measured_with(&ctx, &mut r, &scene, Method::Hybrid, |d| {
        d.btf.lod_scale = 16.0;
        d.btf.impostor_px = 16.0;
    });
    assert_eq!(
        names(&stats),
        [
            "cascades",
            "sky",
            "terrain",
            "near trees",
            "impostors",
            "billboards"
        ],
        "hybrid's passes"
    );
    assert_adds_up("hybrid with impostors", &stats);
    let stats = measured(&ctx, &mut r, &scene, Method::Hybrid);
    assert_eq!(
        names(&stats),
        [
            "far trees",
            "far sort",
            "cascades",
            "sky",
            "terrain",
            "near trees",
            "billboards"
        ],
        "hybrid's passes by default"
    );
    assert_adds_up("hybrid", &stats);
}

#[test]
fn without_timing_inside_passes_the_main_pass_is_one_span() {
    let mut ctx = gpu();
    if skip_without_timestamps(&ctx) {
        return;
    }
    ctx.timestamps_inside_passes = false;
    let scene = scene();
    let world = scene.build_world().unwrap();
    let mut r = renderer(&ctx, &world);
    let stats = measured(&ctx, &mut r, &scene, Method::Btf);
    assert_eq!(
        names(&stats),
        ["far trees", "far sort", "cascades", "main pass"]
    );
    assert_adds_up("btf, whole passes", &stats);
}

#[test]
fn without_timestamp_queries_a_frame_has_no_passes_and_still_draws() {
    let mut ctx = gpu();
    ctx.timestamps = false;
    ctx.timestamps_inside_passes = false;
    let scene = scene();
    let world = scene.build_world().unwrap();
    let mut r = renderer(&ctx, &world);
    for method in [Method::Geometry, Method::Btf] {
        let frame = FrameDesc {
            method,
            ..FrameDesc::from_scene(&scene)
        };
        let (img, stats) = r.render_image(&ctx, &frame, W, H, 1).unwrap();
        assert!(stats.gpu_ms.is_none() && stats.passes.is_empty());
        assert!(stats.trees_drawn > 0, "{} drew no tree", method.name());
        assert_eq!((img.width(), img.height()), (W, H));
    }
    assert!(r.last_passes().is_none());
}

/// Each span holds its own draws' cost: with the tree in view and then without it (the
/// same camera, `trees` off), the frame's difference shows in `trees` and not in the sky
/// or the terrain before it. (A timestamp recorded late, as lavapipe does where the draws
/// after it share its batch, would move the trees' cost into `terrain`.)
#[test]
fn the_trees_cost_shows_in_their_own_span() {
    let ctx = gpu();
    if skip_without_timestamps(&ctx) || !ctx.timestamps_inside_passes {
        println!("skipped: no timestamps inside passes");
        return;
    }
    let scene = scene();
    let world = scene.build_world().unwrap();
    let mut r = Renderer::new(&ctx, &world).unwrap();
    let tree = world.forest.instances[0];
    let crown = tree.position + glam::Vec3::Y * 0.6 * world.species[0].tree_bounds.max.y;
    let mut frame = FrameDesc::from_scene(&scene);
    frame.camera =
        canopy::render::Camera::look_at(crown + glam::Vec3::new(0.0, 1.0, 9.0), crown, 60.0);
    // Cascades off: the trees' cost in the main pass alone.
    frame.shadows.enabled = false;
    let mut median = |trees: bool| {
        let f = FrameDesc { trees, ..frame };
        r.render_image(&ctx, &f, W * 2, H * 2, 1).unwrap();
        let runs: Vec<_> = (0..5)
            .map(|_| r.render_image(&ctx, &f, W * 2, H * 2, 1).unwrap().1.passes)
            .collect();
        canopy::render::timing::PassTimes::median(&runs)
    };
    let with = median(true);
    let without = median(false);
    println!("with the tree {with:?}, without {without:?}");
    let d = |name: &str| with.get(name).unwrap_or(0.0) - without.get(name).unwrap_or(0.0);
    let main = d("sky") + d("terrain") + d("trees");
    assert!(main > 0.5, "the tree costs too little to tell: {main} ms");
    assert!(
        d("trees") > 0.6 * main,
        "the tree's {main} ms are not in `trees` ({} ms there)",
        d("trees")
    );
}

/// The overdraw view's means of `frame` (after a warm-up frame), and its image.
fn overdraw(
    ctx: &GpuContext,
    r: &mut Renderer,
    frame: &FrameDesc,
) -> (canopy::render::overdraw::OverdrawMeans, image::RgbaImage) {
    r.render_image(ctx, frame, W, H, 1).unwrap();
    let (img, stats) = r.render_image(ctx, frame, W, H, 1).unwrap();
    let m = stats
        .overdraw
        .expect("a measured frame with the view on has its means");
    println!("{m:?}");
    (m, img)
}

#[test]
fn the_overdraw_view_counts_a_known_stack_of_draws() {
    use canopy::render::Camera;
    use canopy::render::overdraw::OverdrawView;
    use glam::Vec3;
    let ctx = gpu();
    let scene = scene();
    let world = scene.build_world().unwrap();
    let mut r = renderer(&ctx, &world);
    let base = FrameDesc {
        overdraw: Some(OverdrawView::Fragments),
        ..FrameDesc::from_scene(&scene)
    };
    // Straight up: the sky's full-screen triangle alone, one fragment a pixel, no reads.
    let up = FrameDesc {
        camera: Camera::look_at(
            Vec3::new(25.0, 5.0, 25.0),
            Vec3::new(25.0, 100.0, 25.5),
            60.0,
        ),
        ..base
    };
    let (m, img) = overdraw(&ctx, &mut r, &up);
    assert_eq!((m.fragments_per_pixel, m.reads_per_pixel), (1.0, 0.0));
    // Drawn as a heat map: one colour above the legend, which sits at the bottom.
    let sky = *img.get_pixel(W - 1, 0);
    assert!(
        img.enumerate_pixels()
            .filter(|(_, y, _)| *y < H / 2)
            .all(|(_, _, p)| *p == sky)
    );
    assert!(sky[2] > 150 && sky[0] < 100, "the count 1 is blue: {sky:?}");
    assert_ne!(*img.get_pixel(3, H - 3), sky, "the legend");
    let (plain, _) = r
        .render_image(
            &ctx,
            &FrameDesc {
                overdraw: None,
                ..up
            },
            W,
            H,
            1,
        )
        .unwrap();
    assert_ne!(
        *plain.get_pixel(W - 1, 0),
        sky,
        "the view replaces the picture"
    );
    // Straight down at the flat ground beside the tree, trees off: sky and terrain, two
    // fragments on every pixel.
    let down = FrameDesc {
        camera: Camera::look_at(
            Vec3::new(25.0, 10.0, 25.0),
            Vec3::new(25.0, 0.0, 25.01),
            60.0,
        ),
        trees: false,
        ..base
    };
    let (m, _) = overdraw(&ctx, &mut r, &down);
    assert_eq!((m.fragments_per_pixel, m.reads_per_pixel), (2.0, 0.0));
    // The tree as btf billboards: what it adds to the trees-off frame are its billboards'
    // fragments, each reading 3 views x (its lights + the sky- and ground-lit images).
    let side = FrameDesc {
        method: Method::Btf,
        ..base
    };
    let (bare, _) = overdraw(
        &ctx,
        &mut r,
        &FrameDesc {
            trees: false,
            ..side
        },
    );
    let (with, _) = overdraw(&ctx, &mut r, &side);
    let fragments = with.fragments_per_pixel - bare.fragments_per_pixel;
    assert!(
        fragments > 0.05,
        "the tree covers some of the view: {fragments}"
    );
    let per = with.reads_per_pixel / fragments;
    assert!(
        (9.0..=15.0).contains(&per),
        "{per} reads a billboard fragment"
    );
}
