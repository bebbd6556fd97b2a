//! The bake stage by stage (`canopy::bake::stages`): every prototype's tree level is handed
//! over first, the finished cache is the file a one-shot bake writes, an interrupted bake
//! resumes from what it made, and the tree levels alone draw the forest (finer levels as
//! geometry).

use std::path::{Path, PathBuf};

use crate::common::*;
use canopy::bake::stages::{load_or_bake_progressive, partial_path};
use canopy::format::Baked;
use canopy::model::Level;
use canopy::render::{Camera, FrameDesc, Method, Renderer};
use canopy::scene::Scene;
use glam::Vec3;

/// The lone fir's scene (its coarse bake, texel volumes at their coarsest: every stage is
/// baked, cheaply) with a second species of two variants beside it (the fir's shape,
/// another seed): three prototypes, six trees.
fn two_species(dir: &Path) -> Scene {
    let text = std::fs::read_to_string(data("lone_tree.toml")).unwrap();
    let params = &text[text.find("[species.params]").unwrap()..text.find("[forest]").unwrap()];
    let second = format!("[[species]]\nname = \"fir2\"\nseed = 9\nvariants = 2\n{params}");
    let text = text
        .replace("[forest]", &format!("{second}[forest]"))
        .replace("count = 1\n", "count = 6\n")
        .replace("mix = [1.0]", "mix = [0.5, 0.5]")
        .replace("[bake]\n", "[bake]\ntexel_resolution = 16\n");
    let path = dir.join("two.toml");
    std::fs::write(&path, text).unwrap();
    Scene::load(&path).unwrap()
}

/// What a progressive bake at `cache` reported: its result, the tree levels it handed
/// over and the progress steps made before they came, and every progress step.
struct Run {
    baked: Baked,
    early: Vec<(Baked, usize)>,
    steps: Vec<u64>,
}

fn run(scene: &Scene, cache: &Path) -> Run {
    let ctx = gpu();
    let world = scene.build_world().unwrap();
    let mut steps = Vec::new();
    let mut early = Vec::new();
    let steps_cell = std::cell::RefCell::new(&mut steps);
    let (baked, _) = load_or_bake_progressive(
        cache,
        &ctx,
        scene,
        &world,
        &mut |p| steps_cell.borrow_mut().push(p.done),
        Some(&mut |b| early.push((b.clone(), steps_cell.borrow().len()))),
    )
    .unwrap();
    Run {
        baked,
        early,
        steps,
    }
}

fn one_shot(scene: &Scene, out: &Path) -> Vec<u8> {
    let ctx = gpu();
    let world = scene.build_world().unwrap();
    canopy::bake::bake_to(out, &ctx, scene, &world, &mut |_| {}).unwrap();
    std::fs::read(out).unwrap()
}

fn cache_in(dir: &Path, name: &str) -> PathBuf {
    let d = dir.join(name);
    std::fs::create_dir_all(&d).unwrap();
    d.join("scene.canopy")
}

#[test]
fn tree_levels_come_first_an_interrupted_bake_resumes_and_the_cache_is_the_one_shot_file() {
    let dir = scratch_dir("progressive");
    let scene = two_species(&dir);
    let species = scene.build_world().unwrap().species.len();
    assert_eq!(species, 3);
    let reference = one_shot(&scene, &dir.join("one-shot.canopy"));

    // A first bake, beside a damaged partial bake (a third of a file): the partial is set
    // aside and the bake starts from nothing; the tree levels come first, those of each
    // entry's first variant (the fir, the second species' first), then the second
    // species' second, long before the end; nothing is left beside the cache; the cache is
    // the one-shot file.
    let cache = cache_in(&dir, "first");
    let mut bytes = std::fs::read(dir.join("one-shot.canopy")).unwrap();
    bytes.truncate(bytes.len() / 3);
    std::fs::write(partial_path(&cache), bytes).unwrap();
    let first = run(&scene, &cache);
    assert_eq!(first.early.len(), 2, "first variants, then the rest");
    let (tree_levels, at) = &first.early[0];
    let tree_sets = |b: &Baked| {
        b.btf
            .iter()
            .map(|s| {
                assert_eq!(s.level, Level::Tree);
                s.species
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(tree_sets(tree_levels), vec![0, 1]);
    assert_eq!(tree_sets(&first.early[1].0), vec![0, 1, 2]);
    assert!(tree_levels.vcm.is_empty() && tree_levels.texels.is_empty());
    eprintln!(
        "tree levels after {at} and {} of {} progress steps",
        first.early[1].1,
        first.steps.len()
    );
    assert!(*at < first.steps.len() / 2, "{at} of {}", first.steps.len());
    let tree_images: u64 = tree_levels
        .btf
        .iter()
        .map(|s| u64::from(s.views) * u64::from(s.lights + canopy::format::AMBIENT_IMAGES_PER_VIEW))
        .sum();
    assert!(
        first.steps.first().is_some_and(|&d| d < tree_images),
        "the damaged partial is not used: the first step is {:?} of the tree levels' {tree_images}",
        first.steps.first()
    );
    assert!(!partial_path(&cache).exists());
    assert!(std::fs::read(&cache).unwrap() == reference);
    assert_eq!(first.baked.btf.len(), 3 * species);

    // An interrupted bake: what it had made (its tree levels) is beside the cache. The next
    // one hands them over before any work and does not make them again.
    let cache = cache_in(&dir, "resumed");
    canopy::format::write_atomic(partial_path(&cache), tree_levels).unwrap();
    let resumed = run(&scene, &cache);
    assert_eq!(
        resumed.early.len(),
        2,
        "what it had, then all the tree levels"
    );
    assert_eq!(resumed.early[0].1, 0, "handed over before any step");
    assert!(
        resumed.steps.first().is_some_and(|&d| d > tree_images),
        "the first step counts past the tree levels: {:?}",
        resumed.steps.first()
    );
    assert!(resumed.steps.len() < first.steps.len());
    assert!(!partial_path(&cache).exists());
    assert!(std::fs::read(&cache).unwrap() == reference);

    tree_levels_alone_draw_the_forest(&scene, tree_levels, &first.baked, &dir);
}

/// The first tree levels alone draw the forest: a near tree whole as geometry (as the
/// geometry method draws it), far trees at their tree level (as the finished bake draws
/// them, less the cube maps' shading, which is not there yet, and a second variant drawn
/// with its first's images).
fn tree_levels_alone_draw_the_forest(
    scene: &Scene,
    tree_levels: &Baked,
    whole: &Baked,
    dir: &Path,
) {
    let ctx = gpu();
    let world = scene.build_world().unwrap();
    let mut partial = Renderer::new(&ctx, &world).unwrap();
    partial.attach_btf(&ctx, tree_levels, &world).unwrap();
    let mut full = Renderer::new(&ctx, &world).unwrap();
    full.attach_btf(&ctx, whole, &world).unwrap();
    let tree = world.forest.instances[0].position;
    let centre = tree + Vec3::new(0.0, 8.0, 0.0);
    let flip = |a: &image::RgbaImage, b: &image::RgbaImage| {
        canopy::metrics::flip(&rgb(a), &rgb(b)).unwrap().stats.mean
    };
    // The methods that need what is still coming say so.
    for method in [Method::Texel, Method::Impostor] {
        let frame = FrameDesc {
            method,
            ..FrameDesc::from_scene(scene)
        };
        let e = partial.render_image(&ctx, &frame, 64, 64, 1).unwrap_err();
        assert!(e.to_string().contains("still being baked"), "{e}");
    }
    let mut figures = Vec::new();
    for (view, distance) in [("near", 14.0), ("far", 200.0)] {
        let mut frame = FrameDesc::from_scene(scene);
        frame.camera = Camera::look_at(
            centre + Vec3::new(1.0, 0.3, 1.0).normalize() * distance,
            centre,
            45.0,
        );
        frame.method = Method::Btf;
        let (early, stats) = partial.render_image(&ctx, &frame, 128, 128, 1).unwrap();
        let (done, _) = full.render_image(&ctx, &frame, 128, 128, 1).unwrap();
        let geometry = FrameDesc {
            method: Method::Geometry,
            ..frame
        };
        let (geo, _) = full.render_image(&ctx, &geometry, 128, 128, 1).unwrap();
        let _ = canopy::imageio::save_png(&dir.join(format!("{view}-tree-levels.png")), &early);
        let _ = canopy::imageio::save_png(&dir.join(format!("{view}-whole-bake.png")), &done);
        let _ = canopy::imageio::save_png(&dir.join(format!("{view}-geometry.png")), &geo);
        let s = stats.btf.unwrap();
        let (against_geometry, against_whole) = (flip(&early, &geo), flip(&early, &done));
        eprintln!(
            "{view} ({distance} m): {} trees as geometry, levels {:?}; mean FLIP against the geometry method {against_geometry:.4}, against the whole bake's btf {against_whole:.4}",
            s.geometry_trees, s.trees_per_level
        );
        assert_eq!(s.trees_per_level.twig + s.trees_per_level.branch, 0);
        figures.push((view, s.geometry_trees, against_geometry, against_whole));
    }
    // Measured on lavapipe (128x128), from the first variants' tree levels (the second
    // species' second variant drawn with its first's): near, 2 trees as geometry, 0.0520
    // against the geometry method (its sun shadows differ: cascades fitted to the trees
    // drawn as geometry); far, all 6 at the tree level, 0.0013 against the whole bake.
    let (_, near_geometry, near_flip, _) = figures[0];
    assert!(near_geometry >= 1, "the near tree is geometry");
    assert!(near_flip < 0.1, "{near_flip}");
    let (_, far_geometry, _, far_flip) = figures[1];
    assert_eq!(far_geometry, 0);
    assert!(far_flip < 0.01, "{far_flip}");
}

/// A viewer's bake of a scene whose tree level has more than 18 views first hands over a
/// preview: the first variants' tree levels at 18 views, drawable, never kept. (The lone fir
/// baked for `btf` alone: the other stages are the first test's.)
#[test]
fn a_viewer_bake_first_hands_over_a_preview_at_18_views() {
    let dir = scratch_dir("progressive-preview");
    let text = lone_fir_for_btf_only().replace("tree_views = 6", "tree_views = 66");
    let path = dir.join("fir66.toml");
    std::fs::write(&path, text).unwrap();
    let scene = Scene::load(&path).unwrap();
    let cache = cache_in(&dir, "cache");
    let r = run(&scene, &cache);
    assert_eq!(r.early.len(), 2, "the preview, then the tree level");
    let (preview, at) = &r.early[0];
    assert!(
        r.steps[..*at].iter().all(|&d| d == 0),
        "before any step of the bake itself"
    );
    assert_eq!(preview.settings.tree_views, 18);
    assert_eq!(preview.btf.len(), 1);
    assert_eq!(
        (preview.btf[0].level, preview.btf[0].views),
        (Level::Tree, 18)
    );
    assert_eq!(r.early[1].0.btf[0].views, 66);
    assert!(
        r.baked
            .btf
            .iter()
            .all(|s| s.level != Level::Tree || s.views == 66)
    );
    assert!(!partial_path(&cache).exists());
    // It draws the tree.
    let ctx = gpu();
    let world = scene.build_world().unwrap();
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    renderer.attach_btf(&ctx, preview, &world).unwrap();
    let frame = FrameDesc {
        method: Method::Btf,
        ..FrameDesc::from_scene(&scene)
    };
    let (_, stats) = renderer.render_image(&ctx, &frame, 64, 64, 1).unwrap();
    assert_eq!(stats.trees_drawn, 1);
}
