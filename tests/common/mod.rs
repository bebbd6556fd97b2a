//! Helpers shared by the headless GPU tests: a CPU-adapter context, the small test scene,
//! and FLIP snapshot comparison that writes the actual and difference images on failure.

#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use canopy::format::Baked;
use canopy::model::World;
use canopy::render::{AdapterPreference, Camera, FrameDesc, GpuContext, Renderer};
use canopy::scene::Scene;
use glam::Vec3;
use image::RgbaImage;

pub fn gpu() -> GpuContext {
    GpuContext::headless(AdapterPreference::Cpu).expect(
        "no GPU adapter: install a Vulkan driver (on Debian: apt-get install mesa-vulkan-drivers)",
    )
}

pub fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// `tests/data/{name}`, parsed.
pub fn load_scene(name: &str) -> Scene {
    Scene::load(&data(name)).unwrap_or_else(|e| panic!("tests/data/{name} parses: {e:?}"))
}

pub fn small_scene() -> Scene {
    load_scene("small.toml")
}

/// `scene` and the world it builds.
pub fn built(scene: Scene) -> (Scene, World) {
    let world = scene.build_world().unwrap();
    (scene, world)
}

/// The BTF image sets of `scene`'s trees (no cube maps), baked on a fresh context.
pub fn bake_btf(scene: &Scene) -> Baked {
    let ctx = gpu();
    let world = scene.build_world().unwrap();
    let settings = canopy::bake::cache::settings_of(scene);
    canopy::bake::bake_btf(&ctx, &world, &settings, 0, &mut |_| {}).unwrap()
}

/// The BTF test stand (`tests/data/btf.toml`).
pub fn btf_stand() -> Scene {
    load_scene("btf.toml")
}

/// The BTF test stand's image sets (no cube maps), baked once per run.
pub fn btf_stand_btf() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| bake_btf(&btf_stand()))
}

/// One fir on flat ground, sun from the south-east at 45 degrees
/// (`tests/data/lone_tree.toml`).
pub fn lone_fir() -> Scene {
    load_scene("lone_tree.toml")
}

/// The lone fir's BTF image sets, baked once per run.
pub fn lone_fir_btf() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| bake_btf(&lone_fir()))
}

/// `world`'s bake: the lone fir's BTF and the cube maps of `world` (a world of firs).
pub fn fir_bake_for(world: &World) -> Baked {
    let mut baked = lone_fir_btf().clone();
    baked.vcm = canopy::bake::vcm::bake_vcm(world, &baked.btf, 32, &mut |_, _| {}).unwrap();
    baked
}

/// A world of firs at `trees` (positions with their scales) on the lone fir's flat ground.
pub fn firs_at(trees: &[(Vec3, f32)]) -> World {
    let mut world = lone_fir().build_world().unwrap();
    let tree = world.forest.instances[0];
    world.forest.instances = trees
        .iter()
        .map(|&(position, scale)| canopy::model::TreeInstance {
            position,
            scale,
            ..tree
        })
        .collect();
    world
}

/// A fresh directory `canopy-{name}-{process id}` in the system's temporary directory.
pub fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("canopy-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `scene`'s whole bake, made once per test run: every test that asks for the same scene
/// and bake settings (as the cache keys them, by `scene_hash`) shares it. Different scenes
/// bake at the same time; the same one is baked by the first test that asks, the others
/// wait for it. The files go to one directory of the run's.
pub fn baked(scene: &Scene) -> &'static Baked {
    type Once = &'static OnceLock<Baked>;
    static BAKES: Mutex<BTreeMap<u64, Once>> = Mutex::new(BTreeMap::new());
    let key = canopy::bake::cache::scene_hash(scene);
    let once: Once = *BAKES
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .entry(key)
        .or_insert_with(|| Box::leak(Box::new(OnceLock::new())));
    once.get_or_init(|| {
        load_or_bake(
            scene,
            &canopy::bake::cache::cache_path_in(&fixtures_dir(), scene),
        )
    })
}

/// The run's directory of shared bakes ([`baked`]).
fn fixtures_dir() -> PathBuf {
    std::env::temp_dir().join(format!("canopy-fixtures-{}", std::process::id()))
}

/// A fresh cache directory `dir` holding `scene`'s shared bake ([`baked`]), copied: a
/// `canopy` process started with `CANOPY_CACHE_DIR` set to it finds the bake done.
pub fn cache_holding(scene: &Scene, dir: &Path) -> PathBuf {
    baked(scene);
    std::fs::create_dir_all(dir).unwrap();
    let name = canopy::bake::cache::cache_path_in(dir, scene);
    std::fs::copy(
        canopy::bake::cache::cache_path_in(&fixtures_dir(), scene),
        &name,
    )
    .unwrap_or_else(|e| panic!("copying the shared bake to {}: {e}", name.display()));
    dir.to_path_buf()
}

/// `renderer` made ready for reference frames of `world`, which `scene` built and nothing
/// changed since: its sky visibility from the reference's directions is computed once per
/// run for each scene (one test at a time; the others wait and read it) and kept in the
/// run's directory of shared bakes, as `canopy render` keeps it in its cache.
pub fn prepare_reference(renderer: &mut Renderer, ctx: &GpuContext, scene: &Scene, world: &World) {
    type Lock = &'static Mutex<()>;
    static LOCKS: Mutex<BTreeMap<u64, Lock>> = Mutex::new(BTreeMap::new());
    let directions = canopy::render::sky_visibility::SKY_DIRECTIONS;
    let lock: Lock = *LOCKS
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .entry(canopy::bake::cache::scene_hash(scene))
        .or_insert_with(|| Box::leak(Box::new(Mutex::new(()))));
    let volume = {
        let _one_at_a_time = lock.lock().unwrap_or_else(|e| e.into_inner());
        canopy::bake::sky_cache::sky_volume_in(&fixtures_dir(), scene, world, directions, true)
    };
    renderer
        .prepare_reference_with(ctx, world, directions, true, |_| volume)
        .unwrap();
}

/// The text of `tests/data/lone_tree.toml` baking what `btf` draws only: no texel volumes,
/// impostor or surfel tree (less than half its bake).
pub fn lone_fir_for_btf_only() -> String {
    std::fs::read_to_string(data("lone_tree.toml"))
        .unwrap()
        .replace("impostor_frames = 4", "impostor_frames = 0")
        .replace("surfel_budget = 20000", "surfel_budget = 0")
        .replace("[bake]\n", "[bake]\ntexel_resolution = 0\n")
}

/// `scene`'s world and a renderer for it with the scene's shared bake ([`baked`]) attached.
pub fn baked_renderer(ctx: &GpuContext, scene: &Scene) -> (World, Renderer) {
    let world = scene.build_world().unwrap();
    let mut renderer = Renderer::new(ctx, &world).unwrap();
    renderer.attach_btf(ctx, baked(scene), &world).unwrap();
    (world, renderer)
}

/// `scene`'s whole bake, read from `cache` or baked (on a fresh context) and written there.
pub fn load_or_bake(scene: &Scene, cache: &Path) -> Baked {
    let ctx = gpu();
    let world = scene.build_world().unwrap();
    canopy::bake::load_or_bake_at(cache, &ctx, scene, &world, &mut |_| {})
        .unwrap()
        .0
}

pub fn render(ctx: &GpuContext, world: &World, frame: &FrameDesc, w: u32, h: u32) -> RgbaImage {
    let mut r = Renderer::new(ctx, world).expect("renderer");
    r.render_image(ctx, frame, w, h, 1).expect("frame").0
}

pub fn rgb(img: &RgbaImage) -> image::RgbImage {
    image::DynamicImage::ImageRgba8(img.clone()).to_rgb8()
}

/// Compares `actual` with `tests/snapshots/{name}.png` by mean FLIP. With
/// UPDATE_SNAPSHOTS=1 the reference is (re)written instead; a missing reference fails the
/// test with that advice.
pub fn check_snapshot(name: &str, actual: &RgbaImage, max_mean_flip: f32) -> f32 {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots");
    let reference = dir.join(format!("{name}.png"));
    if std::env::var_os("UPDATE_SNAPSHOTS").is_some() {
        canopy::imageio::save_png(&reference, actual).unwrap();
        return 0.0;
    }
    assert!(
        reference.exists(),
        "missing snapshot {}; run with UPDATE_SNAPSHOTS=1 to create it",
        reference.display()
    );
    let want = canopy::metrics::load_rgb(&reference).unwrap();
    let got = rgb(actual);
    let result = canopy::metrics::flip(&want, &got).unwrap();
    let mean = result.stats.mean;
    if mean > max_mean_flip {
        let actual_path = dir.join(format!("{name}.actual.png"));
        let diff_path = dir.join(format!("{name}.diff.png"));
        canopy::imageio::save_png(&actual_path, actual).unwrap();
        let diff = image::DynamicImage::ImageRgb8(result.error_image()).to_rgba8();
        canopy::imageio::save_png(&diff_path, &diff).unwrap();
        panic!(
            "{name}: mean FLIP {mean:.4} > {max_mean_flip} (p90 {:.4}); wrote {} and {}",
            result.stats.p90,
            actual_path.display(),
            diff_path.display()
        );
    }
    mean
}

/// Mean linear luminance of the pixels in a square of `half` pixels around (cx, cy).
pub fn mean_luminance(img: &RgbaImage, cx: i64, cy: i64, half: i64) -> f32 {
    let mut sum = 0.0;
    let mut n = 0;
    for y in (cy - half)..=(cy + half) {
        for x in (cx - half)..=(cx + half) {
            if x < 0 || y < 0 || x >= i64::from(img.width()) || y >= i64::from(img.height()) {
                continue;
            }
            let p = img.get_pixel(x as u32, y as u32).0;
            let lin = |c: u8| (f32::from(c) / 255.0).powf(2.2);
            sum += 0.2126 * lin(p[0]) + 0.7152 * lin(p[1]) + 0.0722 * lin(p[2]);
            n += 1;
        }
    }
    assert!(n > 0, "window outside the image");
    sum / n as f32
}

/// Where the first tree's crown shadow falls on flat ground, and the frame that looks
/// straight down on it from high above: the pixels under the crown's shadow and the pixels
/// mirrored to the tree's sunny side, for a `w` x `h` image.
pub struct CrownShadow {
    pub frame: FrameDesc,
    /// Where the sun projects the crown's centre onto the ground (what the camera looks at).
    pub shadow_at: Vec3,
    pub shadow_px: (i64, i64),
    pub lit_px: (i64, i64),
}

pub fn crown_shadow(scene: &Scene, world: &World, w: u32, h: u32) -> CrownShadow {
    let tree = world.forest.instances[0];
    let model = &world.species[tree.species as usize];
    // The crown's centre, and where the sun projects it onto the flat ground.
    let crown = tree.position + Vec3::Y * 0.6 * (model.tree_bounds.max.y * tree.scale);
    let to_sun = canopy::scene::sun_direction(scene.sun.azimuth, scene.sun.elevation);
    let shadow_at = crown - to_sun * (crown.y - tree.position.y) / to_sun.y;
    let lit_at = tree.position + (tree.position - shadow_at);
    let mut frame = FrameDesc::from_scene(scene);
    frame.fog_density = 0.0;
    frame.camera = Camera::look_at(shadow_at + Vec3::new(0.0, 70.0, 0.01), shadow_at, 40.0);
    let vp = frame.camera.view_projection(w as f32 / h as f32);
    let to_px = |p: Vec3| {
        let ndc = vp.project_point3(p);
        (
            ((ndc.x * 0.5 + 0.5) * w as f32) as i64,
            ((0.5 - ndc.y * 0.5) * h as f32) as i64,
        )
    };
    CrownShadow {
        frame,
        shadow_at,
        shadow_px: to_px(shadow_at),
        lit_px: to_px(lit_at),
    }
}

/// Mean FLIP of each of `methods` against the reference (2x2 supersampled) from each of
/// `views` (a name and a distance in metres from `centre` along `away`), at 160x120; the
/// pictures written to `dir`. Returned (and printed) as (view, method, FLIP).
#[allow(clippy::too_many_arguments)]
pub fn against_reference(
    ctx: &GpuContext,
    scene: &Scene,
    world: &World,
    baked: &Baked,
    (centre, away): (Vec3, Vec3),
    views: &[(&str, f32)],
    methods: &[canopy::render::Method],
    dir: &Path,
) -> Vec<(String, canopy::render::Method, f32)> {
    use canopy::render::{Method, Reference};
    let mut renderer = Renderer::new(ctx, world).unwrap();
    renderer.attach_btf(ctx, baked, world).unwrap();
    prepare_reference(&mut renderer, ctx, scene, world);
    let (w, h) = (160, 120);
    let mut out = Vec::new();
    for &(name, distance) in views {
        let mut frame = FrameDesc::from_scene(scene);
        frame.camera = Camera::look_at(centre + away * distance, centre, 50.0);
        let truth = FrameDesc {
            method: Method::Geometry,
            reference: Some(Reference::default()),
            ..frame
        };
        let (truth, _) = renderer.render_image(ctx, &truth, w, h, 2).unwrap();
        let _ = canopy::imageio::save_png(&dir.join(format!("{name}-truth.png")), &truth);
        for &method in methods {
            let (img, stats) = renderer
                .render_image(ctx, &FrameDesc { method, ..frame }, w, h, 1)
                .unwrap();
            let flip = canopy::metrics::flip(&rgb(&truth), &rgb(&img))
                .unwrap()
                .stats
                .mean;
            let _ =
                canopy::imageio::save_png(&dir.join(format!("{name}-{}.png", method.name())), &img);
            eprintln!(
                "{name} ({distance} m) {:9} against the reference {flip:.4}; btf levels {:?}",
                method.name(),
                stats.btf.map(|s| s.trees_per_level)
            );
            out.push((name.to_string(), method, flip));
        }
    }
    out
}

/// Mean FLIP between `a` and `b` over the pixels the trees cover (where `a` differs from
/// `bare`, the same frame without trees, by more than 4 levels in a channel), so that a
/// bound is not thinned by bare terrain: (that mean, those pixels, the whole frame's mean).
pub fn flip_over_trees(a: &RgbaImage, b: &RgbaImage, bare: &RgbaImage) -> (f32, usize, f32) {
    let mask: Vec<bool> = a
        .pixels()
        .zip(bare.pixels())
        .map(|(p, q)| p.0.iter().zip(q.0.iter()).any(|(x, y)| x.abs_diff(*y) > 4))
        .collect();
    let covered = mask.iter().filter(|&&m| m).count();
    let flip = canopy::metrics::flip(&rgb(a), &rgb(b)).unwrap();
    let sum: f64 = flip
        .errors
        .iter()
        .zip(&mask)
        .filter(|(_, m)| **m)
        .map(|(e, _)| f64::from(*e))
        .sum();
    (
        (sum / covered.max(1) as f64) as f32,
        covered,
        flip.stats.mean,
    )
}
