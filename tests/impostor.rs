//! The octahedral impostor bake on the GPU (lavapipe): each frame of the baked atlas is the
//! studio's picture of the tree level from that frame's direction, laid in its tile, so a
//! view exactly on a frame reproduces it; and (ignored, it prints figures) the FLIP of a
//! view between frames, made from the 3 frames around it, against the picture from that
//! view, at several frames per side: the measurement behind the default frame count.

use crate::common;

use canopy::bake::atlas::FrameMaps;
use canopy::bake::impostor::{bake_impostors, draw_frame};
use canopy::bake::{bounding_sphere, level_object};
use canopy::format::{BakeSettings, Impostor};
use canopy::model::{Level, World};
use canopy::render::{GpuContext, Renderer};
use canopy::sphere::{Frame, OctaGrid, OctaLayout, billboard_axes};
use glam::{Vec2, Vec3};
use image::RgbImage;

fn settings(frames: u32, resolution: u32) -> BakeSettings {
    BakeSettings {
        impostor_frames: frames,
        impostor_resolution: resolution,
        impostor_layout: OctaLayout::Full,
        ..canopy::bake::cache::settings_of(&common::lone_fir())
    }
}

fn fir_world() -> World {
    common::lone_fir().build_world().unwrap()
}

/// A renderer of the lone fir's tree level alone, and its bounding sphere.
fn studio(ctx: &GpuContext, world: &World) -> (Renderer, (Vec3, f32)) {
    let object = level_object(&world.species[0], Level::Tree);
    let sphere = bounding_sphere(&object.tree_bounds);
    let studio = World::lone(object, 1.0);
    (Renderer::new(ctx, &studio).unwrap(), sphere)
}

/// Frame `f`'s level-0 tile of `imp`'s albedo atlas.
fn tile(imp: &Impostor, f: Frame) -> Vec<u8> {
    tile_of(imp, &imp.albedo, f)
}

/// Frame `f`'s level-0 tile of one of `imp`'s atlases.
fn tile_of(imp: &Impostor, atlas: &[u8], f: Frame) -> Vec<u8> {
    let res = imp.resolution as usize;
    let row = imp.frames as usize * res;
    let mut out = Vec::with_capacity(res * res * 4);
    for y in 0..res {
        let at = ((f.j as usize * res + y) * row + f.i as usize * res) * 4;
        out.extend_from_slice(&atlas[at..at + res * 4]);
    }
    out
}

#[test]
fn a_view_exactly_on_a_frame_reproduces_that_frame() {
    let ctx = common::gpu();
    let world = fir_world();
    let s = settings(4, 32);
    let imps = bake_impostors(&ctx, &world, &s, &mut |_, _| {}).unwrap();
    assert_eq!(imps.len(), 1);
    let imp = &imps[0];
    assert_eq!((imp.frames, imp.resolution, imp.mip_levels), (4, 32, 4));
    let (mut renderer, sphere) = studio(&ctx, &world);
    let grid = OctaGrid::new(imp.layout, imp.frames);
    // A frame from above, one from the side, one from below; a view from each frame's own
    // direction (through the blend, which gives that frame alone).
    for f in [
        Frame { i: 1, j: 2 },
        Frame { i: 0, j: 1 },
        Frame { i: 3, j: 3 },
    ] {
        let dir = grid.frame_dir(f);
        let b = grid.blend(dir);
        let k = (0..3).find(|&k| b.weights[k] > 0.999).expect("one frame");
        // (On the full layout's border the blend may pick the frame's mirror twin: the same
        // view.)
        assert!(grid.frame_dir(b.frames[k]).angle_between(dir) < 1e-4);
        let view = draw_frame(&ctx, &mut renderer, sphere, dir, 32, s.supersample).unwrap();
        let baked = tile(imp, b.frames[k]);
        let covered = baked.chunks(4).filter(|p| p[3] > 0).count();
        assert!(
            covered > 20,
            "frame {f:?} shows the tree ({covered} texels)"
        );
        let worst = view
            .albedo
            .iter()
            .zip(&baked)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        assert!(worst <= 2, "frame {f:?}: a byte differs by {worst}");
        // The normals (object frame) of what is covered face the frame's camera, and the
        // depths lie inside the bounding sphere's span, away from its ends (measured: n·view
        // 0.72 to 0.78; depth 0.27 from below, where the lowest branches are nearest, to 0.54).
        let nd = tile_of(imp, &imp.normal_depth, b.frames[k]);
        let (mut facing, mut depth, mut n) = (0.0, 0.0, 0.0);
        for (a, d) in baked.chunks(4).zip(nd.chunks(4)) {
            if a[3] == 0 {
                continue;
            }
            let normal = Vec3::new(d[0].into(), d[1].into(), d[2].into()) / 127.5 - 1.0;
            assert!((normal.length() - 1.0).abs() < 0.05, "{normal}");
            facing += normal.dot(dir);
            depth += f32::from(d[3]) / 255.0;
            n += 1.0;
        }
        let (facing, depth) = (facing / n, depth / n);
        assert!(facing > 0.3, "frame {f:?}: mean n·view {facing}");
        assert!(
            (0.15..0.85).contains(&depth),
            "frame {f:?}: mean depth {depth}"
        );
    }
    // Another frame's tile is not this view: the test can tell frames apart.
    let dir = grid.frame_dir(Frame { i: 1, j: 2 });
    let view = draw_frame(&ctx, &mut renderer, sphere, dir, 32, s.supersample).unwrap();
    assert_ne!(view.albedo, tile(imp, Frame { i: 2, j: 1 }));

    // The hemi layout: its frames look from the upper hemisphere, laid out the same way.
    let hemi = BakeSettings {
        impostor_layout: OctaLayout::Hemi,
        ..settings(4, 16)
    };
    let imp = &bake_impostors(&ctx, &world, &hemi, &mut |_, _| {}).unwrap()[0];
    assert_eq!((imp.layout, imp.mip_levels), (OctaLayout::Hemi, 3));
    let grid = OctaGrid::new(OctaLayout::Hemi, 4);
    let f = Frame { i: 2, j: 1 };
    let dir = grid.frame_dir(f);
    assert!(dir.y > 0.3, "{dir}");
    let view = draw_frame(&ctx, &mut renderer, sphere, dir, 16, hemi.supersample).unwrap();
    let baked = tile(imp, f);
    assert!(baked.chunks(4).any(|p| p[3] > 0));
    assert!(
        view.albedo
            .iter()
            .zip(&baked)
            .all(|(a, b)| a.abs_diff(*b) <= 2),
        "hemi frame {f:?}"
    );
}

/// Bilinear sample of an RGBA8 frame (straight colour, coverage) at `uv` (0..1, v down),
/// as premultiplied linear colour and coverage; outside the frame, nothing.
fn sample(maps: &FrameMaps, uv: Vec2) -> [f32; 4] {
    let n = maps.side as f32;
    let p = uv * n - 0.5;
    let (x0, y0) = (p.x.floor(), p.y.floor());
    let (fx, fy) = (p.x - x0, p.y - y0);
    let mut out = [0.0; 4];
    for (dx, dy, w) in [
        (0.0, 0.0, (1.0 - fx) * (1.0 - fy)),
        (1.0, 0.0, fx * (1.0 - fy)),
        (0.0, 1.0, (1.0 - fx) * fy),
        (1.0, 1.0, fx * fy),
    ] {
        let (x, y) = (x0 + dx, y0 + dy);
        if x < 0.0 || y < 0.0 || x >= n || y >= n {
            continue;
        }
        let i = ((y as usize) * maps.side as usize + x as usize) * 4;
        let a = f32::from(maps.albedo[i + 3]) / 255.0;
        for (c, o) in out.iter_mut().enumerate() {
            let colour = if c < 3 {
                canopy::color::srgb_to_linear(maps.albedo[i + c])
            } else {
                1.0
            };
            *o += w * a * colour;
        }
    }
    out
}

/// Premultiplied linear colour and coverage over a mid grey, as an sRGB picture.
fn over_grey(side: u32, px: impl Fn(u32, u32) -> [f32; 4]) -> RgbImage {
    RgbImage::from_fn(side, side, |x, y| {
        let p = px(x, y);
        let c = |v: f32| canopy::color::linear_to_srgb(v + 0.2 * (1.0 - p[3]));
        image::Rgb([c(p[0]), c(p[1]), c(p[2])])
    })
}

/// The view from `dir` made as an impostor draws it without parallax: each pixel's ray
/// meets each of the 3 frames' planes (through the centre, facing the frame's direction),
/// and the frames' samples there are blended with the blend's weights.
fn from_frames(frames: &[(FrameMaps, Vec3, f32)], dir: Vec3, radius: f32, side: u32) -> RgbImage {
    let (right, up) = billboard_axes(dir);
    over_grey(side, |x, y| {
        let ndc = Vec2::new(
            (x as f32 + 0.5) / side as f32 * 2.0 - 1.0,
            1.0 - (y as f32 + 0.5) / side as f32 * 2.0,
        );
        let p = (ndc.x * right + ndc.y * up) * radius;
        let mut out = [0.0; 4];
        for (maps, fdir, w) in frames {
            let (fr, fu) = billboard_axes(*fdir);
            let q = p - dir * (p.dot(*fdir) / dir.dot(*fdir).max(1e-3));
            let uv = Vec2::new(q.dot(fr), -q.dot(fu)) / radius * 0.5 + 0.5;
            let s = sample(maps, uv);
            for c in 0..4 {
                out[c] += w * s[c];
            }
        }
        out
    })
}

/// The picture from `dir` itself.
fn truth(maps: &FrameMaps) -> RgbImage {
    let side = maps.side;
    over_grey(side, |x, y| {
        let i = ((y * side + x) * 4) as usize;
        let a = f32::from(maps.albedo[i + 3]) / 255.0;
        let c = |k: usize| a * canopy::color::srgb_to_linear(maps.albedo[i + k]);
        [c(0), c(1), c(2), a]
    })
}

/// The frames of a grid, drawn as the bake draws them (resolved and dilated).
fn frames_of(
    ctx: &GpuContext,
    renderer: &mut Renderer,
    sphere: (Vec3, f32),
    grid: &OctaGrid,
    res: u32,
    ss: u32,
) -> Vec<FrameMaps> {
    (0..grid.len())
        .map(|k| {
            draw_frame(
                ctx,
                renderer,
                sphere,
                grid.frame_dir(grid.frame(k)),
                res,
                ss,
            )
            .unwrap()
        })
        .collect()
}

#[test]
#[ignore = "prints figures: cargo test --test suite impostor:: -- --ignored --nocapture"]
fn views_between_frames_against_frames_per_side() {
    let ctx = common::gpu();
    let world = fir_world();
    let (mut renderer, sphere) = studio(&ctx, &world);
    let (res, ss) = (64, 2);
    // Views from 8 azimuths at 4 elevations, each moved to the middle of its grid triangle
    // (weights 1/3 each: the farthest from every frame).
    let views: Vec<Vec3> = [-20.0f32, 0.0, 20.0, 45.0]
        .iter()
        .flat_map(|&el| {
            (0..8).map(move |k| {
                let az = (k as f32 * 45.0 + 10.0).to_radians();
                let el = el.to_radians();
                Vec3::new(az.cos() * el.cos(), el.sin(), az.sin() * el.cos())
            })
        })
        .collect();
    println!("frames  bytes       FLIP on a frame  between frames (mean, worst view)");
    for n in [8u32, 12, 16] {
        let grid = OctaGrid::new(OctaLayout::Full, n);
        let frames = frames_of(&ctx, &mut renderer, sphere, &grid, res, ss);
        let (mut on, mut between, mut worst) = (0.0, 0.0, 0.0f32);
        for &v in &views {
            // On a frame: the nearest frame's own view.
            let b = grid.blend(v);
            let k = (0..3)
                .max_by(|&a, &c| b.weights[a].total_cmp(&b.weights[c]))
                .unwrap();
            let fdir = grid.frame_dir(b.frames[k]);
            let fk = &frames[grid.index(b.frames[k])];
            let set = [(fk.clone(), fdir, 1.0)];
            let e = canopy::metrics::flip(&truth(fk), &from_frames(&set, fdir, sphere.1, res));
            on += e.unwrap().stats.mean;
            // Between frames: the middle of the triangle around v.
            let uv = (Vec2::new(
                b.frames.iter().map(|f| f.i as f32).sum::<f32>(),
                b.frames.iter().map(|f| f.j as f32).sum::<f32>(),
            ) / 3.0)
                / (n - 1) as f32;
            let mid = grid.layout.uv_to_dir(uv);
            let mb = grid.blend_uv(uv);
            let set: Vec<(FrameMaps, Vec3, f32)> = (0..3)
                .map(|k| {
                    let f = mb.frames[k];
                    (
                        frames[grid.index(f)].clone(),
                        grid.frame_dir(f),
                        mb.weights[k],
                    )
                })
                .collect();
            let view = draw_frame(&ctx, &mut renderer, sphere, mid, res, ss).unwrap();
            let e = canopy::metrics::flip(&truth(&view), &from_frames(&set, mid, sphere.1, res))
                .unwrap()
                .stats
                .mean;
            between += e;
            worst = worst.max(e);
        }
        let count = views.len() as f32;
        let bytes =
            canopy::format::impostor_record_bytes(n, res, canopy::format::impostor_mip_levels(res));
        println!(
            "{n:>2} x {n:<2} {bytes:>10}  {:.4}           {:.4}, {:.4}",
            on / count,
            between / count,
            worst
        );
    }
}
