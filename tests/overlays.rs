//! The `btf` method's debug overlays render what they claim: `--show-lod` colours a tree by
//! the level it is drawn at, and `--show-shadow` draws the VCM sun factor in grey (darker
//! for a tree with another between it and the sun, 1 everywhere with VCMs off).
//!
//! Both overlays write `tint x alpha` (then fog, off here, and exposure; shaders/btf.wgsl),
//! composited over the ground with premultiplied alpha, so every covered pixel is, in linear light,
//! `p = (1 - a) B + a c`: `B` the same pixel without trees, `c` the overlay's colour and `a`
//! the billboards' coverage. The tests read `c` back through that model.

use canopy::format::Baked;
use canopy::model::{Level, PerLevel, World};
use canopy::render::method::btf::LOD_COLORS;
use canopy::render::{Camera, FrameDesc, GpuContext, Method, Renderer};
use glam::Vec3;
use image::RgbaImage;

use crate::common::*;

/// The LOD knob of these views: each level is valid up to 3 pixels a texel, so that a tree
/// drawn at its coarsest level still covers enough pixels to judge (at 1, a tree at the tree
/// level is smaller than its 32-texel image).
const LOD_SCALE: f32 = 3.0;

/// sRGB to linear, exactly (the offscreen target is `Rgba8UnormSrgb`).
fn linear(p: image::Rgba<u8>) -> Vec3 {
    let f = |c: u8| {
        let c = f32::from(c) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    Vec3::new(f(p[0]), f(p[1]), f(p[2]))
}

/// The pixels where `img` differs from `background` (any channel by more than 4 of 255),
/// as (index, linear colour, linear background).
fn covered(img: &RgbaImage, background: &RgbaImage) -> Vec<(usize, Vec3, Vec3)> {
    img.pixels()
        .zip(background.pixels())
        .enumerate()
        .filter(|(_, (a, b))| a.0.iter().zip(b.0.iter()).any(|(x, y)| x.abs_diff(*y) > 4))
        .map(|(i, (a, b))| (i, linear(*a), linear(*b)))
        .collect()
}

/// The coverage `a` (0..1) that best explains `p` as colour `c` over `b`, and the distance
/// (linear RGB) left between `p` and that composite.
fn unmix(p: Vec3, b: Vec3, c: Vec3) -> (f32, f32) {
    let d = c - b;
    let a = ((p - b).dot(d) / d.length_squared().max(1e-9)).clamp(0.0, 1.0);
    (a, (p - (b + a * d)).length())
}

/// A pixel is the overlay colour `c` over its background when the composite explains it to
/// within this distance (linear RGB; 8-bit sRGB steps are at most 0.017 in linear, at white).
const UNMIX_TOLERANCE: f32 = 0.03;

/// The tree changed a pixel visibly when it moved it this far (linear RGB): fainter pixels
/// fit any colour at a small enough coverage.
const VISIBLE_CHANGE: f32 = 0.02;

/// Of the `covered` pixels the tree changed visibly (returned second), the fraction each
/// LOD colour explains best, within the tolerance.
fn lod_fractions(covered: &[(usize, Vec3, Vec3)]) -> (PerLevel<f32>, usize) {
    let mut n = PerLevel::<usize>::default();
    let mut judged = 0;
    for &(_, p, b) in covered {
        if (p - b).length() <= VISIBLE_CHANGE {
            continue;
        }
        judged += 1;
        let (k, err) = Level::ALL
            .map(|k| (k, unmix(p, b, Vec3::from(LOD_COLORS[k])).1))
            .into_iter()
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .unwrap();
        if err < UNMIX_TOLERANCE {
            n[k] += 1;
        }
    }
    (n.map(|c| c as f32 / judged.max(1) as f32), judged)
}

// ---------------------------------------------------------------------------------------
// Show LOD, on the BTF test stand.

/// The stand's BTF image sets (no cube maps: the overlay draws no VCM shading, and the
/// stand's tree-level cube maps are per instance), baked once per run.
fn stand_btf() -> &'static Baked {
    btf_stand_btf()
}

/// At each level, at least this fraction of a lone tree's visibly changed pixels must be
/// that level's colour over the ground. Measured on lavapipe (Mesa llvmpipe), fir / broadleaf:
/// tree level 1.000 / 1.000, main branch 1.000 / 1.000, twig 0.960 / 0.929 (the rest are the
/// limbs and trunk, geometry at the twig level, seen or under a twig). Without the overlay
/// the trees' own colours pass for a LOD colour at 0.098 of the pixels at most.
const LOD_MIN_OWN_COLOUR: f32 = 0.85;
/// ... and at most this fraction any other level's colour (measured: 0.000 everywhere).
const LOD_MAX_OTHER_COLOUR: f32 = 0.02;

#[test]
fn show_lod_colours_a_lone_tree_by_the_level_it_is_drawn_at() {
    let ctx = gpu();
    let scene = btf_stand();
    let stand = scene.build_world().unwrap();
    let (w, h) = (96u32, 96u32);
    let fov = 40.0;
    let focal = Camera::look_at(Vec3::ZERO, Vec3::Z, fov).focal_px(h);
    for species in 0..stand.species.len() as u32 {
        // The stand's first tree of this species, alone: at the tree level a tree covers
        // fewer pixels than its image has texels (32 here), so a view of the stand holding
        // one tree big enough to judge would hold its neighbours too.
        let mut world = stand.clone();
        world.forest.instances.retain(|t| t.species == species);
        world.forest.instances.truncate(1);
        let tree = world.forest.instances[0];
        let model = &world.species[species as usize];
        let name = &model.name;
        let centre = tree.position + model.tree_bounds.center() * tree.scale;
        let top = tree.position.y + model.tree_bounds.max.y * tree.scale;
        let mut renderer = Renderer::new(&ctx, &world).unwrap();
        renderer.attach_btf(&ctx, stand_btf(), &world).unwrap();
        let texels = renderer.btf_texels(species as usize).unwrap();
        // Where each level is valid, with the LOD knob at `scale`.
        let from =
            |texel: f32, scale: f32| canopy::lod::valid_beyond(texel * tree.scale, focal, scale);
        // (level, LOD knob, camera height over the tree's centre). The tree level with the
        // knob at 3 (the tree covers 3 x more pixels than at 1); the twig level at 1, where
        // the camera is still above the treetop.
        let cases = [
            (Level::Tree, LOD_SCALE, 1.2 * from(texels.tree, LOD_SCALE)),
            (
                Level::Branch,
                LOD_SCALE,
                (from(texels.tree, LOD_SCALE) * from(texels.branch, LOD_SCALE)).sqrt(),
            ),
            (Level::Twig, 1.0, 0.8 * from(texels.branch, 1.0)),
        ];
        let mut frame = FrameDesc::from_scene(&scene);
        frame.method = Method::Btf;
        frame.fog_density = 0.0;
        frame.btf.lod_fade = 0.0;
        // The tree's shadow on the ground would differ from the bare ground too.
        frame.ground_shadows = false;
        for (level, scale, z) in cases {
            assert!(
                centre.y + z > top + 1.0,
                "{name}: the camera is above the tree"
            );
            frame.btf.lod_scale = scale;
            // Looking down at the tree from above.
            frame.camera = Camera::look_at(centre + Vec3::new(0.0, z, 0.001), centre, fov);
            let mut shot = |frame: &FrameDesc| renderer.render_image(&ctx, frame, w, h, 1).unwrap();
            frame.trees = false;
            let (bare, _) = shot(&frame);
            frame.trees = true;
            frame.btf.show_lod = true;
            let (lod, stats) = shot(&frame);
            // The second measurement: the same view in the tree's own colours.
            frame.btf.show_lod = false;
            let (plain, _) = shot(&frame);
            let li = level;
            let mut want = PerLevel::default();
            want[li] = 1;
            assert_eq!(
                stats.btf.unwrap().trees_per_level,
                want,
                "{name} at {z:.1} m"
            );
            let (f, judged) = lod_fractions(&covered(&lod, &bare));
            let (g, _) = lod_fractions(&covered(&plain, &bare));
            eprintln!(
                "{name} at the {level:?} level, {z:.1} m above: {judged} pixels; in the twig / branch / tree colours {f:.3?}; without the overlay {g:.3?}"
            );
            assert!(
                judged > 300,
                "{name}: the tree changes only {judged} pixels"
            );
            assert!(
                f[li] >= LOD_MIN_OWN_COLOUR,
                "{name} at the {level:?} level: only {:.3} of its pixels in the level's colour ({f:?})",
                f[li]
            );
            for j in Level::ALL {
                let fj = &f[j];
                if j != li {
                    assert!(
                        *fj <= LOD_MAX_OTHER_COLOUR,
                        "{name} at the {level:?} level: {fj:.3} of its pixels in the {j:?} level's colour ({f:?})"
                    );
                }
            }
            assert!(
                g.iter().all(|&x| x < LOD_MIN_OWN_COLOUR),
                "{name}: the measure must tell the overlay from the tree's own colours: {g:?}"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------
// Show shadow, on firs of the lone-tree scene (as in tests/vcm.rs).

/// A renderer of `world` with the fir's BTF and `world`'s cube maps.
fn fir_renderer(ctx: &GpuContext, world: &World) -> Renderer {
    let baked = fir_bake_for(world);
    let mut renderer = Renderer::new(ctx, world).unwrap();
    renderer.attach_btf(ctx, &baked, world).unwrap();
    renderer
}

/// The overlay colour `c` of every covered pixel, read through `p = (1 - a) B + a c` with
/// the coverage `a` of each pixel known (from a frame drawn in a known colour).
struct Unmixed {
    /// The overlay colour of each pixel read.
    colour: Vec<Vec3>,
}

impl Unmixed {
    /// Reads `img` over `bare` at the pixels and coverages of `matte`.
    fn new(img: &RgbaImage, bare: &RgbaImage, matte: &[(usize, f32)]) -> Self {
        let colour = matte
            .iter()
            .map(|&(i, a)| {
                let (w, _) = img.dimensions();
                let (x, y) = ((i as u32) % w, (i as u32) / w);
                let p = linear(*img.get_pixel(x, y));
                let b = linear(*bare.get_pixel(x, y));
                (p - (1.0 - a) * b) / a
            })
            .collect();
        Self { colour }
    }

    /// Mean of the channels' mean.
    fn mean_grey(&self) -> f32 {
        let s: f32 = self.colour.iter().map(|c| c.element_sum() / 3.0).sum();
        s / self.colour.len().max(1) as f32
    }

    /// The `q` quantile of each pixel's spread between its channels (max - min).
    fn spread(&self, q: f32) -> f32 {
        let mut v: Vec<f32> = self
            .colour
            .iter()
            .map(|c| c.max_element() - c.min_element())
            .collect();
        v.sort_by(f32::total_cmp);
        v[((v.len() - 1) as f32 * q) as usize]
    }

    /// The `q` quantile of each pixel's distance from grey `g` (largest channel deviation).
    fn off(&self, g: f32, q: f32) -> f32 {
        let mut v: Vec<f32> = self
            .colour
            .iter()
            .map(|c| (*c - Vec3::splat(g)).abs().max_element())
            .collect();
        v.sort_by(f32::total_cmp);
        v[((v.len() - 1) as f32 * q) as usize]
    }
}

/// The frames' exposure: the overlays are scaled by it (below 1 so that white is not
/// clipped).
const EXPOSURE: f32 = 0.8;
/// The show-shadow overlay is grey: at 95% of the pixels its channels lie within this of
/// each other. Measured on lavapipe: at most 0.0117 (95th percentile, VCM on and off, alone
/// and behind, both levels); the trees' own colours read the same way: at least 0.0521
/// (median).
const GREY_SPREAD: f32 = 0.025;
/// With VCMs off, 95% of the pixels lie within this of the exposure (the factor 1), and
/// their mean within 0.01. Measured on lavapipe: at most 0.0147 (mean at most 0.0014 off);
/// with VCMs on at the main-branch level, where sibling branches hide each other, 0.165.
const FROM_WHITE: f32 = 0.04;
/// Behind the second fir, the mean grey is darker than alone by at least this. Measured on
/// lavapipe: 0.0201 at the tree level (2.5 %), 0.0124 at the main-branch level (1.6 %);
/// with VCMs off the same difference is -0.0008 and -0.0009 (bound: half of this).
const MIN_DARKER: f32 = 0.006;

/// One view of one world, drawn every way the test reads it.
struct Shots {
    bare: RgbaImage,
    lod: RgbaImage,
    on: RgbaImage,
    off: RgbaImage,
    plain: RgbaImage,
    trees_per_level: PerLevel<u32>,
}

fn shots(ctx: &GpuContext, renderer: &mut Renderer, frame: &FrameDesc, w: u32, h: u32) -> Shots {
    let mut shot = |f: &FrameDesc| renderer.render_image(ctx, f, w, h, 1).unwrap();
    let mut f = *frame;
    f.trees = false;
    let (bare, _) = shot(&f);
    f.trees = true;
    f.btf.show_lod = true;
    let (lod, stats) = shot(&f);
    f.btf.show_lod = false;
    f.btf.show_shadow = true;
    let (on, s) = shot(&f);
    assert!(s.btf.unwrap().vcm, "VCM shading is on");
    f.btf.vcm = false;
    let (off, _) = shot(&f);
    f.btf.show_shadow = false;
    f.btf.vcm = true;
    let (plain, _) = shot(&f);
    Shots {
        bare,
        lod,
        on,
        off,
        plain,
        trees_per_level: stats.btf.unwrap().trees_per_level,
    }
}

#[test]
fn show_shadow_draws_the_sun_factor_in_grey_darker_behind_another_tree() {
    let ctx = gpu();
    let (w, h) = (96u32, 96u32);
    let fov = 40.0;
    let alone = firs_at(&[(Vec3::ZERO, 1.0)]);
    // A taller fir 7 m north, between the first and a northern sun (tests/vcm.rs).
    let pair = firs_at(&[(Vec3::ZERO, 1.0), (Vec3::new(0.0, 0.0, 7.0), 1.6)]);
    let fir = alone.forest.instances[0];
    let bounds = alone.species[0].tree_bounds;
    let centre = fir.position + bounds.center() * fir.scale;
    let top = fir.position.y + bounds.max.y * fir.scale;
    let mut renderers = [fir_renderer(&ctx, &alone), fir_renderer(&ctx, &pair)];
    let texels = renderers[0].btf_texels(0).unwrap();
    let focal = Camera::look_at(Vec3::ZERO, Vec3::Z, fov).focal_px(h);
    let from = |texel: f32| canopy::lod::valid_beyond(texel * fir.scale, focal, LOD_SCALE);
    let mut frame = FrameDesc::from_scene(&lone_fir());
    frame.method = Method::Btf;
    frame.fog_density = 0.0;
    frame.btf.lod_fade = 0.0;
    frame.btf.lod_scale = LOD_SCALE;
    // The trees' shadows on the ground would differ from the bare ground too.
    frame.ground_shadows = false;
    frame.sun.azimuth_deg = 0.0;
    frame.sun.elevation_deg = 25.0;
    frame.exposure = EXPOSURE;
    // The tree level (the factor d, trilinear over the tree's box) and the main-branch
    // level (c per pixel times d at each branch's centre).
    let cases = [
        (Level::Tree, 1.2 * from(texels.tree)),
        (
            Level::Branch,
            (from(texels.tree) * from(texels.branch)).sqrt(),
        ),
    ];
    for (level, z) in cases {
        assert!(centre.y + z > top + 1.0, "the camera is above the tree");
        // Looking down at the first fir from above.
        frame.camera = Camera::look_at(centre + Vec3::new(0.0, z, 0.001), centre, fov);
        let [a, b] = &mut renderers;
        let views = [shots(&ctx, a, &frame, w, h), shots(&ctx, b, &frame, w, h)];
        let li = level;
        let mut want = PerLevel::default();
        want[li] = 1;
        assert_eq!(views[0].trees_per_level, want, "{level:?} at {z:.1} m");
        // (The taller second fir, nearer to the camera for its size, may be at a finer
        // level.)
        assert!(views[1].trees_per_level[li] >= 1, "{level:?} at {z:.1} m");
        // The first fir's coverage, from its show-LOD frame alone: the level's colour
        // times the coverage. Read where it covers at least half of the pixel and the
        // second fir is not in front of it or behind it (its show-LOD frame is the same
        // there with and without the second fir).
        let colour = Vec3::from(LOD_COLORS[li]) * EXPOSURE;
        let matte: Vec<(usize, f32)> = covered(&views[0].lod, &views[0].bare)
            .into_iter()
            .map(|(i, p, b)| (i, unmix(p, b, colour).0))
            .filter(|&(i, a)| {
                let same = views[0].lod.as_raw()[4 * i..4 * i + 3]
                    .iter()
                    .zip(&views[1].lod.as_raw()[4 * i..4 * i + 3])
                    .all(|(x, y)| x.abs_diff(*y) <= 2);
                a >= 0.5 && same
            })
            .collect();
        let read = |v: &Shots, img: &RgbaImage| Unmixed::new(img, &v.bare, &matte);
        let alone_on = read(&views[0], &views[0].on);
        let alone_off = read(&views[0], &views[0].off);
        let alone_plain = read(&views[0], &views[0].plain);
        let pair_on = read(&views[1], &views[1].on);
        let pair_off = read(&views[1], &views[1].off);
        eprintln!(
            "{level:?} level, {z:.1} m above: {} pixels read",
            matte.len()
        );
        assert!(matte.len() > 150, "{level:?}: only {} pixels", matte.len());
        for (name, u) in [
            ("alone, VCM on", &alone_on),
            ("behind, VCM on", &pair_on),
            ("alone, VCM off", &alone_off),
            ("behind, VCM off", &pair_off),
            ("alone, no overlay", &alone_plain),
        ] {
            eprintln!(
                "  {name}: mean grey {:.4}; channel spread p50 {:.4} p95 {:.4}; from {EXPOSURE} p50 {:.4} p95 {:.4}",
                u.mean_grey(),
                u.spread(0.5),
                u.spread(0.95),
                u.off(EXPOSURE, 0.5),
                u.off(EXPOSURE, 0.95)
            );
        }
        // Grey: the channels of the overlay colour agree.
        for (name, u) in [
            ("alone, VCM on", &alone_on),
            ("behind, VCM on", &pair_on),
            ("alone, VCM off", &alone_off),
            ("behind, VCM off", &pair_off),
        ] {
            assert!(
                u.spread(0.95) < GREY_SPREAD,
                "{level:?}, {name}: not grey, channels apart by {} (95th percentile)",
                u.spread(0.95)
            );
        }
        assert!(
            alone_plain.spread(0.5) > GREY_SPREAD,
            "the measure must tell the trees' own colours from grey: {}",
            alone_plain.spread(0.5)
        );
        // VCMs off: the factor is 1 everywhere, the overlay white at the exposure.
        for (name, u) in [("alone", &alone_off), ("behind", &pair_off)] {
            assert!(
                u.off(EXPOSURE, 0.95) < FROM_WHITE && (u.mean_grey() - EXPOSURE).abs() < 0.01,
                "{level:?}, {name}, VCM off: mean {} and {} from {EXPOSURE} (95th percentile)",
                u.mean_grey(),
                u.off(EXPOSURE, 0.95)
            );
        }
        if level == Level::Branch {
            // The second measurement: with VCMs on, main branches hidden by their siblings
            // have a factor below 1, and the same measure sees it.
            assert!(
                alone_on.off(EXPOSURE, 0.95) > FROM_WHITE,
                "{}",
                alone_on.off(EXPOSURE, 0.95)
            );
        }
        // Darker behind the second fir with VCMs, and the same without them.
        let darker = alone_on.mean_grey() - pair_on.mean_grey();
        let without = alone_off.mean_grey() - pair_off.mean_grey();
        eprintln!("  darker behind the second fir by {darker:.4}; with VCMs off {without:.4}");
        assert!(
            darker > MIN_DARKER,
            "{level:?}: behind the second fir {} vs alone {}",
            pair_on.mean_grey(),
            alone_on.mean_grey()
        );
        assert!(
            without.abs() < MIN_DARKER / 2.0,
            "{level:?}: with VCMs off the second fir changes the overlay by {without}"
        );
    }
}
