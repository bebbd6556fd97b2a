//! The render core's images, kept as references: every method on the BTF test stand at a
//! near, a mid and a far view, 320x180 (`geometry` and `btf` as they were before the core
//! was split by method; `billboard`, `texel` and `hybrid` as they were before the methods
//! went behind one interface). A refactor that changes what a frame looks like fails here;
//! a deliberate change of the images re-writes the references with `UPDATE_SNAPSHOTS=1` and
//! says why in its commit.

use crate::common;

use canopy::render::{Camera, FrameDesc, Method, Renderer};
use glam::Vec3;

use crate::common::*;

/// lavapipe renders the same frame to the same bytes on one machine, so a structural change
/// measures 0 there. Its shaders are compiled for the host CPU, though, and a CPU with other
/// vector units rounds differently: `geometry` at the near view measures 0.0031 against
/// references made on another CPU (2026-11-27, an AVX-512 Xeon; the code before and after the
/// methods went behind one interface gave the same bytes there), `btf` there 0.0035. The
/// bound leaves room for that and nothing more: a change that moves what a frame shows
/// measures well above it.
const MAX_MEAN_FLIP: f32 = 0.005;

/// The same for `texel`, whose ray march through 31 slices a texel adds up more of those
/// roundings: its references, made on the Xeon, measure 0.0043 / 0.0054 / 0.0019 (near /
/// mid / far) on a 2-core AMD EPYC (2026-11-28, the same on the code of 2026-11-28's
/// first-bake work and after it), where `geometry` and `btf` measure 0.0000.
const MAX_MEAN_FLIP_TEXEL: f32 = 0.008;

/// The same for `surfel`: each surfel lands in one pixel, so a rounding that moves one
/// across a pixel's edge changes that pixel whole, and the coverage dither follows which
/// surfels are drawn. Its references were made on a 2-core Xeon (2026-12-07); the bound is
/// set well above the rounding and well below what changing a knob moves.
const MAX_MEAN_FLIP_SURFEL: f32 = 0.02;

const SIZE: (u32, u32) = (320, 180);

/// (name, camera, look-at): near (inside the stand, twig and branch levels), mid (the
/// stand from 90 m, branch and tree levels), far (the whole stand from 300 m, tree level).
const VIEWS: [(&str, [f32; 3], [f32; 3]); 3] = [
    ("near", [-14.0, 9.0, -16.0], [4.0, 7.0, 4.0]),
    ("mid", [40.0, 30.0, -80.0], [0.0, 8.0, 0.0]),
    ("far", [-120.0, 90.0, -260.0], [0.0, 6.0, 0.0]),
];

#[test]
fn every_method_matches_its_references_at_three_distances() {
    let ctx = gpu();
    // The references were drawn from an RGBA8 bake. Block compression changes the images
    // on purpose (btf near: 0.0077 against them); tests/compress.rs bounds that change,
    // this test keeps guarding the render core against refactors.
    let mut stand = btf_stand();
    stand.bake.compress = false;
    let (scene, world) = built(stand);
    let baked = common::baked(&scene);
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    renderer.attach_btf(&ctx, baked, &world).unwrap();
    let mut worst = 0.0f32;
    for (name, eye, at) in VIEWS {
        for &method in Method::ALL {
            // The stand is baked without impostors (tests/impostor_draw.rs draws them).
            if method == Method::Impostor {
                assert!(renderer.can_draw(method).is_err());
                continue;
            }
            let mut frame = FrameDesc::from_scene(&scene);
            frame.camera = Camera::look_at(Vec3::from(eye), Vec3::from(at), 50.0);
            frame.method = method;
            let (img, stats) = renderer
                .render_image(&ctx, &frame, SIZE.0, SIZE.1, 1)
                .unwrap();
            if method == Method::Btf {
                eprintln!(
                    "{name}: btf levels {:?}",
                    stats.btf.unwrap().trees_per_level
                );
            }
            let bound = match method {
                Method::Texel => MAX_MEAN_FLIP_TEXEL,
                Method::Surfel => MAX_MEAN_FLIP_SURFEL,
                _ => MAX_MEAN_FLIP,
            };
            let mean = check_snapshot(&format!("stand_{name}_{}", method.name()), &img, bound);
            eprintln!(
                "{name} {}: mean FLIP {mean:.5} against the reference",
                method.name()
            );
            worst = worst.max(mean);
        }
    }
    eprintln!("largest mean FLIP against the references: {worst:.5}");
}
