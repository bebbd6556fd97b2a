//! The CPU prepare step: levels, fades, expansion, culling by weight, sorting.

use super::*;
use crate::render::camera::Camera;
use crate::render::method::btf::{LOD_COLORS, NO_LIGHT_BLEND};

const BRANCHES: usize = 4;
const BRANCH_TWIGS: usize = 5;
const TRUNK_TWIGS: usize = 2;
/// Texel sizes (m): the tree level is valid beyond 0.1·f/s, the branch level beyond
/// 0.02·f/s (s the LOD scale).
const TEXELS: LevelTexels = PerLevel {
    twig: 0.004,
    branch: 0.02,
    tree: 0.1,
};
const FOCAL: f32 = 500.0;

fn aabb(min: [f32; 3], max: [f32; 3]) -> Aabb {
    Aabb {
        min: Vec3::from(min),
        max: Vec3::from(max),
    }
}

/// One species of 4 main branches of 5 twigs each and 2 twigs on the trunk; 18 view and
/// 18 light samples; no cube maps.
pub(crate) fn scene() -> BtfScene {
    let bounds = PerLevel {
        twig: aabb([-0.2, -0.2, 0.0], [0.2, 0.2, 0.4]),
        branch: aabb([-0.5, -0.5, 0.0], [0.5, 0.5, 3.0]),
        tree: aabb([-3.0, 0.0, -3.0], [3.0, 10.0, 3.0]),
    };
    let per_set = 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW);
    let sets = PerLevel::from_fn(|l| SetInfo {
        layer_base: l.index() as u32 * per_set,
        prototype: 0,
        center: bounds[l].center(),
        radius: (bounds[l].max - bounds[l].min).length() / 2.0,
        bounds: bounds[l],
    });
    let branches = (0..BRANCHES)
        .map(|i| {
            Mat4::from_translation(Vec3::new(0.0, 3.0 + i as f32 * 1.5, 0.0))
                * Mat4::from_rotation_y(i as f32 * 1.6)
                * Mat4::from_rotation_x(1.2)
        })
        .collect();
    let branch_twigs = (0..BRANCH_TWIGS)
        .map(|j| Mat4::from_translation(Vec3::new(0.0, 0.0, 0.5 + j as f32 * 0.5)))
        .collect();
    let trunk_twigs = (0..TRUNK_TWIGS)
        .map(|k| Mat4::from_translation(Vec3::new(0.3, 1.0 + k as f32, 0.0)))
        .collect();
    BtfScene {
        species: vec![SpeciesParts {
            branches,
            branch_twigs,
            trunk_twigs,
            frames: sets.map(|s| ObjectFrame {
                bounds: s.bounds,
                center: s.center,
            }),
            sets,
            texels: TEXELS,
            bounds: bounds.tree,
            finer: true,
            pending: false,
        }],
        views: PerLevel::from_fn(|_| DirectionSet::with_count(18).unwrap()),
        lights: DirectionSet::with_count(18).unwrap(),
        vcm: None,
        order: vec![0, 1, 2],
        bases: vec![0, per_set, 2 * per_set],
        layers: 3 * per_set,
        resolution: 16,
        light_bins: 0,
        light_blend_first: 0,
    }
}

fn tree_at(x: f32, z: f32, yaw: f32) -> TreeGpu {
    let m = Mat4::from_translation(Vec3::new(x, 0.0, z)) * Mat4::from_rotation_y(yaw);
    TreeGpu {
        model: m.to_cols_array_2d(),
        tint: [0.9, 1.0, 0.8, 1.0],
    }
}

/// Prepares `trees`, all visible, seen from `eye` looking at the origin's tree centre.
fn run(trees: &[TreeGpu], eye: Vec3, settings: &BtfSettings) -> (BtfFrame, Camera) {
    run_as(trees, eye, settings, false)
}

fn run_as(
    trees: &[TreeGpu],
    eye: Vec3,
    settings: &BtfSettings,
    hybrid: bool,
) -> (BtfFrame, Camera) {
    run_in(&scene(), trees, eye, settings, hybrid)
}

/// [`run_as`] with the scene `scene`.
fn run_in(
    scene: &BtfScene,
    trees: &[TreeGpu],
    eye: Vec3,
    settings: &BtfSettings,
    hybrid: bool,
) -> (BtfFrame, Camera) {
    let camera = Camera::look_at(eye, Vec3::new(0.0, 5.0, 0.0), 60.0);
    let frustum = camera.frustum(16.0 / 9.0);
    let view = PrepareView {
        camera: &camera,
        focal_px: FOCAL,
        to_sun: Vec3::new(0.3, 0.8, 0.2).normalize(),
        frustum: &frustum,
    };
    let visible = vec![(0..trees.len() as u32).collect::<Vec<_>>()];
    let frame = scene.prepare(trees, &visible, &view, settings, usize::MAX, hybrid);
    (frame, camera)
}

#[test]
fn tree_level_billboards_read_their_yaw_bins_light_blend() {
    use crate::render::method::btf::light_blend::{bin_direction, light_weights, yaw_bin};
    let bins = 8;
    let mut scene = scene();
    scene.set_light_blend(bins, 1000);
    let to_sun = Vec3::new(0.3, 0.8, 0.2).normalize();
    let camera = Camera::look_at(Vec3::new(0.0, 40.0, -300.0), Vec3::ZERO, 60.0);
    let frustum = camera.frustum(16.0 / 9.0);
    let view = PrepareView {
        camera: &camera,
        focal_px: FOCAL,
        to_sun,
        frustum: &frustum,
    };
    // Far (tree level), at yaws on and between the bins; one near (finer levels).
    let yaws = [0.0, 0.3, 1.0, 2.5, -2.0];
    let mut trees: Vec<TreeGpu> = yaws.iter().map(|&y| tree_at(0.0, 0.0, y)).collect();
    trees.push(tree_at(0.0, 0.0, 0.5));
    let s = BtfSettings {
        lod_fade: 0.0,
        ..BtfSettings::default()
    };
    let far = vec![(0..yaws.len() as u32).collect::<Vec<_>>()];
    let frame = scene.prepare(&trees, &far, &view, &s, usize::MAX, false);
    assert_eq!(frame.records.len(), yaws.len());
    assert_eq!(frame.stats.light_blended, yaws.len() as u32);
    // Per view used: the blend, the sky-lit and the ground-lit image.
    let views_used = |f: &BtfFrame| -> u64 {
        f.records
            .iter()
            .map(|r| r.view_weight.iter().filter(|&&w| w > 0.0).count() as u64)
            .sum()
    };
    assert_eq!(frame.stats.images_sampled, 3 * views_used(&frame));
    for (r, &yaw) in frame.records.iter().zip(&yaws) {
        let l_obj = Mat3::from_rotation_y(yaw).transpose() * to_sun;
        let bin = yaw_bin(l_obj, to_sun, bins);
        assert_eq!(r.light_blend, 1000 + bin * 18, "yaw {yaw}");
        let lb = light_weights(&scene.lights, bin_direction(to_sun, bin, bins), &s);
        assert_eq!((r.light_index, r.light_weight), (lb.index, lb.weight));
    }
    // Off: every billboard blends its lights itself, 15 reads.
    let off = BtfSettings {
        light_blend: false,
        ..s
    };
    let frame = scene.prepare(&trees, &far, &view, &off, usize::MAX, false);
    assert!(
        frame
            .records
            .iter()
            .all(|r| r.light_blend == NO_LIGHT_BLEND)
    );
    assert_eq!(frame.stats.images_sampled, 5 * views_used(&frame));
    // Near: the finer levels' billboards keep their 3 lights.
    let near_cam = Camera::look_at(Vec3::new(0.0, 5.0, -8.0), Vec3::new(0.0, 5.0, 0.0), 60.0);
    let near_frustum = near_cam.frustum(16.0 / 9.0);
    let near_view = PrepareView {
        camera: &near_cam,
        frustum: &near_frustum,
        ..view
    };
    let near = vec![vec![yaws.len() as u32]];
    let frame = scene.prepare(&trees, &near, &near_view, &s, usize::MAX, false);
    assert!(!frame.records.is_empty());
    assert_eq!(frame.stats.trees_per_level.tree, 0);
    assert!(
        frame
            .records
            .iter()
            .all(|r| r.light_blend == NO_LIGHT_BLEND)
    );
    assert_eq!(frame.stats.light_blended, 0);
}

#[test]
fn trees_left_out_of_the_sun_billboards_are_skipped() {
    let trees = [
        tree_at(0.0, 0.0, 0.0),
        tree_at(20.0, 0.0, 0.0),
        tree_at(40.0, 0.0, 0.0),
    ];
    let sun = Vec3::new(0.3, 0.8, 0.2).normalize();
    let all = scene().sun_billboards(&trees, &[0, 0, 0], sun, usize::MAX, &[]);
    let some = scene().sun_billboards(&trees, &[0, 0, 0], sun, usize::MAX, &[1]);
    assert_eq!((all.len(), some.len()), (3, 2));
    assert_eq!(some[1].center, all[2].center);
}

#[test]
fn hybrid_draws_a_tree_as_geometry_where_its_twig_texels_pass_the_bound() {
    let s = BtfSettings {
        lod_fade: 0.2,
        ..BtfSettings::default()
    };
    // The twig texel (4 mm) is 1 px at 2 m, 0.8 px (the band's start) at 2.5 m.
    assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 1.9, &s), 1.0);
    assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 2.6, &s), 0.0);
    let half = geometry_fade(&TEXELS, 1.0, FOCAL, 0.004 * FOCAL / 0.9, &s);
    assert!((half - 0.5).abs() < 1e-4, "{half}");
    // Abrupt without a band; a coarser LOD scale lets the twig images come closer.
    assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 2.2, &no_fade()), 0.0);
    let coarse = BtfSettings {
        lod_scale: 2.0,
        ..s
    };
    assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 1.5, &coarse), 0.0);

    let trees = [tree_at(0.0, 0.0, 0.3)];
    // Near: the whole tree as geometry, no billboards.
    let (near, _) = run_as(&trees, Vec3::new(0.0, 5.0, 1.5), &s, true);
    assert_eq!(near.stats.geometry_trees, 1);
    assert_eq!(near.twigs[0], vec![(0, 1.0)]);
    assert!(near.trunk_and_limbs[0].is_empty() && near.trunk_only[0].is_empty());
    assert!(near.records.is_empty() && near.stats.trees_per_level.iter().sum::<u32>() == 0);
    // The same view in `btf`: twig billboards, nothing as whole geometry.
    let (plain, _) = run_as(&trees, Vec3::new(0.0, 5.0, 1.5), &s, false);
    assert!(plain.twigs[0].is_empty() && plain.stats.billboards.twig > 0);
    // In the band: both, the billboards at the complement of the geometry's opacity.
    let z = 0.004 * FOCAL / 0.9;
    let (band, _) = run_as(&trees, Vec3::new(0.0, 5.0, z), &s, true);
    let (t, g) = band.twigs[0][0];
    assert!(t == 0 && (g - 0.5).abs() < 1e-3, "{g}");
    assert_eq!(band.stats.geometry_trees, 0);
    assert_eq!(band.stats.faded_trees, 1);
    assert!(band.trunk_and_limbs[0].is_empty());
    assert!(!band.records.is_empty());
    for r in &band.records {
        assert!((r.opacity - (1.0 - g)).abs() < 1e-4, "{}", r.opacity);
    }
    // Far: billboards only.
    let (far, _) = run_as(&trees, Vec3::new(0.0, 5.0, 8.0), &s, true);
    assert!(far.twigs[0].is_empty() && far.stats.geometry_trees == 0);
    assert_eq!(far.stats.trees_per_level.twig, 1);
}

fn no_fade() -> BtfSettings {
    BtfSettings {
        lod_fade: 0.0,
        ..BtfSettings::default()
    }
}

#[test]
fn the_level_is_the_coarsest_whose_texels_project_below_the_scale() {
    let s = no_fade();
    // Tree level valid beyond 0.1 * 500 / 1 = 50 m, branch level beyond 10 m.
    assert_eq!(
        choose_level(&TEXELS, 1.0, FOCAL, 51.0, &s).level,
        Level::Tree
    );
    assert_eq!(
        choose_level(&TEXELS, 1.0, FOCAL, 49.0, &s).level,
        Level::Branch
    );
    assert_eq!(
        choose_level(&TEXELS, 1.0, FOCAL, 11.0, &s).level,
        Level::Branch
    );
    assert_eq!(
        choose_level(&TEXELS, 1.0, FOCAL, 9.0, &s).level,
        Level::Twig
    );
    // Up close nothing is valid: the twig level, blurred.
    assert_eq!(
        choose_level(&TEXELS, 1.0, FOCAL, 0.5, &s).level,
        Level::Twig
    );
    // A tree twice as large has texels twice as large: the bound moves out to 100 m.
    assert_eq!(
        choose_level(&TEXELS, 2.0, FOCAL, 90.0, &s).level,
        Level::Branch
    );
    // A LOD scale of 2 accepts texels of 2 px: the bound moves in to 25 m.
    let coarse = BtfSettings {
        lod_scale: 2.0,
        ..s
    };
    assert_eq!(
        choose_level(&TEXELS, 1.0, FOCAL, 30.0, &coarse).level,
        Level::Tree
    );
    assert!(
        choose_level(&TEXELS, 1.0, FOCAL, 30.0, &s)
            .fading_in
            .is_none()
    );
}

#[test]
fn inside_the_fade_band_the_finer_level_fades_in_and_opacities_sum_to_one() {
    let s = BtfSettings {
        lod_fade: 0.2,
        ..BtfSettings::default()
    };
    // The tree level's texel is 0.8 px at 62.5 m, the band's start; 1 px at 50 m.
    let outside = choose_level(&TEXELS, 1.0, FOCAL, 70.0, &s);
    assert_eq!(outside.fading_in, None);
    let half = choose_level(&TEXELS, 1.0, FOCAL, 0.1 * FOCAL / 0.9, &s);
    assert_eq!(half.level, Level::Tree);
    let (finer, fade) = half.fading_in.expect("inside the band");
    assert_eq!(finer, Level::Branch);
    assert!((fade - 0.5).abs() < 1e-4, "fade {fade}");
    let total: f32 = half.draws().map(|(_, o)| o).sum();
    assert!((total - 1.0).abs() < 1e-6);
    // Just before the bound the finer level is almost opaque: the switch changes little.
    let edge = choose_level(&TEXELS, 1.0, FOCAL, 50.01, &s);
    assert!(edge.fading_in.unwrap().1 > 0.99);
    // The twig level has nothing finer to fade to.
    let twig = choose_level(&TEXELS, 1.0, FOCAL, 9.0, &s);
    assert_eq!((twig.level, twig.fading_in), (Level::Twig, None));
}

#[test]
fn each_level_expands_into_its_billboards_and_geometry_lists() {
    let s = no_fade();
    let trees = [tree_at(0.0, 0.0, 0.3)];
    let cases = [
        (Vec3::new(0.0, 5.0, 80.0), Level::Tree, 1),
        (
            Vec3::new(0.0, 5.0, 30.0),
            Level::Branch,
            BRANCHES + TRUNK_TWIGS,
        ),
        (
            Vec3::new(0.0, 5.0, 8.0),
            Level::Twig,
            BRANCHES * BRANCH_TWIGS + TRUNK_TWIGS,
        ),
    ];
    for (eye, level, count) in cases {
        let (f, _) = run(&trees, eye, &s);
        assert_eq!(f.stats.trees_per_level[level], 1, "{level:?}");
        assert_eq!(f.records.len(), count, "{level:?}");
        assert_eq!(f.stats.total_billboards() as usize, count);
        let twigs = f.stats.billboards.twig as usize;
        match level {
            Level::Tree => {
                assert_eq!(f.stats.billboards.tree, 1);
                assert!(f.trunk_only[0].is_empty() && f.trunk_and_limbs[0].is_empty());
            }
            Level::Branch => {
                assert_eq!(
                    (f.stats.billboards.branch as usize, twigs),
                    (BRANCHES, TRUNK_TWIGS)
                );
                assert_eq!((f.trunk_only[0].len(), f.trunk_and_limbs[0].len()), (1, 0));
            }
            Level::Twig => {
                assert_eq!(twigs, count);
                assert_eq!((f.trunk_only[0].len(), f.trunk_and_limbs[0].len()), (0, 1));
            }
        }
        // Every record points into its level's image set.
        let per_set = 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW);
        for r in &f.records {
            assert!(r.layer_base % per_set == 0 && r.layer_base / per_set <= 2);
        }
    }
}

#[test]
fn a_fading_tree_draws_both_levels_with_complementary_opacity() {
    let s = BtfSettings {
        lod_fade: 0.2,
        ..BtfSettings::default()
    };
    // The tree's centre at 55.5 m: inside the tree level's band.
    let trees = [tree_at(0.0, 0.0, 0.0)];
    let (f, _) = run(&trees, Vec3::new(0.0, 5.0, 55.5), &s);
    assert_eq!(f.stats.faded_trees, 1);
    assert_eq!(f.records.len(), 1 + BRANCHES + TRUNK_TWIGS);
    let tree: Vec<f32> = f
        .records
        .iter()
        .filter(|r| r.layer_base == 2 * 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW))
        .map(|r| r.opacity)
        .collect();
    let finer: Vec<f32> = f
        .records
        .iter()
        .filter(|r| r.layer_base != 2 * 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW))
        .map(|r| r.opacity)
        .collect();
    assert_eq!(tree.len(), 1);
    assert!(finer.iter().all(|&o| (o + tree[0] - 1.0).abs() < 1e-6));
    assert!(tree[0] > 0.0 && tree[0] < 1.0);
    // The trunk is geometry while the branch level shows.
    assert_eq!(f.trunk_only[0], vec![0]);
}

#[test]
fn weight_culling_drops_small_weights_and_renormalises() {
    // A crowd of trees at many angles, so that the blends vary.
    let trees: Vec<TreeGpu> = (0..40)
        .map(|i| tree_at((i % 8) as f32 * 9.0 - 30.0, -(i / 8) as f32 * 9.0, i as f32))
        .collect();
    let eye = Vec3::new(0.0, 30.0, 120.0);
    let (all, _) = run(&trees, eye, &no_fade());
    let threshold = 0.3;
    let culled_settings = BtfSettings {
        weight_threshold: threshold,
        ..no_fade()
    };
    let (culled, _) = run(&trees, eye, &culled_settings);
    assert_eq!(all.records.len(), culled.records.len());
    let mut dropped = 0;
    for r in &culled.records {
        // The light weights carry the light gain: they sum to it, at least 1.
        let gain: f32 = r.light_weight.iter().sum();
        assert!(
            (1.0 - 1e-5..=crate::sphere::MAX_LIGHT_GAIN + 1e-5).contains(&gain),
            "light weights {:?} sum to {gain}",
            r.light_weight
        );
        for w in [r.view_weight, r.light_weight.map(|x| x / gain)] {
            let sum: f32 = w.iter().sum();
            assert!((sum - 1.0).abs() < 1e-5, "weights {w:?} sum to {sum}");
            let largest = w.iter().copied().fold(0.0, f32::max);
            for x in w {
                assert!(
                    x == 0.0 || x >= threshold || x == largest,
                    "kept {x} in {w:?}"
                );
                dropped += usize::from(x == 0.0);
            }
        }
    }
    assert!(dropped > 0, "a threshold of {threshold} dropped nothing");
    assert!(culled.stats.images_sampled < all.stats.images_sampled);
    assert!(culled.stats.fetches_saved > all.stats.fetches_saved);
    // Images sampled plus those saved is 15 per billboard.
    let n = culled.records.len() as u64;
    assert_eq!(
        culled.stats.images_sampled + culled.stats.fetches_saved,
        15 * n
    );
}

#[test]
fn billboards_come_back_to_front_and_the_farthest_are_dropped_first() {
    let trees: Vec<TreeGpu> = (0..30)
        .map(|i| tree_at((i % 5) as f32 * 7.0 - 14.0, -(i / 5) as f32 * 7.0, i as f32))
        .collect();
    let eye = Vec3::new(0.0, 6.0, 25.0);
    let (f, camera) = run(&trees, eye, &no_fade());
    let depth = |r: &BillboardGpu| (Vec3::from(r.center) - eye).dot(camera.forward());
    assert!(f.records.len() > 30, "expected a mix of levels");
    assert!(f.records.windows(2).all(|w| depth(&w[0]) >= depth(&w[1])));
    // Capped: the nearest survive.
    let camera2 = Camera::look_at(eye, Vec3::new(0.0, 5.0, 0.0), 60.0);
    let frustum = camera2.frustum(16.0 / 9.0);
    let view = PrepareView {
        camera: &camera2,
        focal_px: FOCAL,
        to_sun: Vec3::Y,
        frustum: &frustum,
    };
    let visible = vec![(0..trees.len() as u32).collect::<Vec<_>>()];
    let cap = 10;
    let capped = scene().prepare(&trees, &visible, &view, &no_fade(), cap, false);
    assert_eq!(capped.records.len(), cap);
    assert_eq!(capped.stats.dropped as usize, f.records.len() - cap);
    let nearest: Vec<f32> = f.records[f.records.len() - cap..]
        .iter()
        .map(depth)
        .collect();
    let kept: Vec<f32> = capped.records.iter().map(depth).collect();
    assert_eq!(nearest, kept);
}

#[test]
fn a_crowd_prepared_in_chunks_is_what_its_trees_give_one_by_one() {
    // More trees than one chunk takes, at every level, so that the threads split them.
    let n = 3 * PREPARE_CHUNK + 17;
    let trees: Vec<TreeGpu> = (0..n)
        .map(|i| {
            let (row, col) = ((i / 40) as f32, (i % 40) as f32);
            tree_at(col * 6.0 - 120.0, -row * 6.0 + 20.0, i as f32 * 0.7)
        })
        .collect();
    let eye = Vec3::new(0.0, 6.0, 24.0);
    let (all, camera) = run(&trees, eye, &BtfSettings::default());
    // Each tree alone, joined in order, then sorted back to front (stable: ties keep
    // the order made).
    let mut one_by_one: Vec<BillboardGpu> = Vec::new();
    let mut stats = BtfStats::default();
    let (mut trunk_only, mut trunk_and_limbs) = (Vec::new(), Vec::new());
    for (i, t) in trees.iter().enumerate() {
        let (f, _) = run(std::slice::from_ref(t), eye, &BtfSettings::default());
        one_by_one.extend(f.records);
        stats.add(&f.stats);
        trunk_only.extend(f.trunk_only[0].iter().map(|_| i as u32));
        trunk_and_limbs.extend(f.trunk_and_limbs[0].iter().map(|_| i as u32));
    }
    let depth = |r: &BillboardGpu| (Vec3::from(r.center) - eye).dot(camera.forward());
    one_by_one.sort_by(|a, b| depth(b).total_cmp(&depth(a)));
    assert!(stats.trees_per_level.iter().all(|&c| c > 0), "{stats:?}");
    assert_eq!(all.stats, stats);
    assert_eq!(all.trunk_only[0], trunk_only);
    assert_eq!(all.trunk_and_limbs[0], trunk_and_limbs);
    assert_eq!(all.records.len(), one_by_one.len());
    assert!(
        all.records
            .iter()
            .zip(&one_by_one)
            .all(|(a, b)| bytemuck::bytes_of(a) == bytemuck::bytes_of(b))
    );
}

#[test]
fn trees_outside_the_view_make_no_billboards_and_overlays_tint_by_level() {
    let trees = [tree_at(0.0, 0.0, 0.0), tree_at(0.0, 400.0, 0.0)];
    // The second tree is behind the camera.
    let s = BtfSettings {
        show_lod: true,
        ..no_fade()
    };
    let (f, _) = run(&trees, Vec3::new(0.0, 5.0, 30.0), &s);
    assert_eq!(f.records.len(), BRANCHES + TRUNK_TWIGS);
    // The overlay colours a tree by the level it is drawn at: the twigs on the trunk of
    // a tree at the main-branch level show the main-branch colour.
    assert_eq!(f.stats.billboards.twig as usize, TRUNK_TWIGS);
    for r in &f.records {
        assert_eq!(r.mode, BillboardMode::Tint as u32);
        assert_eq!(r.tint, LOD_COLORS[Level::Branch]);
    }
}

mod far_gpu;

#[test]
fn hybrid_hands_the_tree_level_to_impostors_with_its_opacity() {
    let trees = [tree_at(0.0, 0.0, 0.3)];
    let s = BtfSettings {
        impostor_px: 1.0,
        ..BtfSettings::default()
    };
    // The tree texel (0.1 m) is 1 px at 50 m: at 100 m the tree level alone.
    let (far, _) = run_as(&trees, Vec3::new(0.0, 5.0, 100.0), &s, true);
    assert_eq!(far.impostors[0], vec![(0, 1.0)]);
    assert_eq!(far.stats.impostors, 1);
    assert!(
        far.records.is_empty(),
        "no tree billboard besides the impostor"
    );
    assert_eq!(far.stats.trees_per_level.tree, 1);
    // `btf` ignores the knob: its tree billboard.
    let (plain, _) = run_as(&trees, Vec3::new(0.0, 5.0, 100.0), &s, false);
    assert!(plain.impostors[0].is_empty() && plain.stats.impostors == 0);
    assert_eq!(plain.records.len(), 1);
    // Inside the band before the tree level's bound (0.8 to 1 px: 50 to 62.5 m), the
    // impostor fades out under the main branches' billboards, fading in.
    let (band, _) = run_as(&trees, Vec3::new(0.0, 5.0, 56.0), &s, true);
    let (t, o) = band.impostors[0][0];
    assert!(t == 0 && o > 0.1 && o < 0.9, "{o}");
    assert!(!band.records.is_empty());
    assert!(band.stats.billboards.branch > 0 && band.stats.billboards.tree == 0);
    for r in &band.records {
        assert!(
            (r.opacity - (1.0 - o)).abs() < 1e-4,
            "{} against {o}",
            r.opacity
        );
    }
    // Near: no tree level, no impostor.
    let (near, _) = run_as(&trees, Vec3::new(0.0, 5.0, 20.0), &s, true);
    assert!(near.impostors[0].is_empty() && !near.records.is_empty());
    // 0: never.
    let never = BtfSettings {
        impostor_px: 0.0,
        ..s
    };
    let (far, _) = run_as(&trees, Vec3::new(0.0, 5.0, 100.0), &never, true);
    assert!(far.impostors[0].is_empty() && far.records.len() == 1);
}

#[test]
fn hybrid_impostors_begin_below_impostor_px_cross_faded_with_the_tree_billboard() {
    let s = BtfSettings {
        impostor_px: 0.5,
        lod_fade: 0.2,
        ..BtfSettings::default()
    };
    // The tree texel (0.1 m) projects 0.5 px at 100 m, 0.4 px (the band's start) at 125 m.
    let share = |z: f32| impostor_share(&TEXELS, 1.0, FOCAL, z, &s);
    assert_eq!(share(90.0), 0.0);
    assert_eq!(share(130.0), 1.0);
    let mid = share(0.1 * FOCAL / 0.45);
    assert!((mid - 0.5).abs() < 1e-4, "{mid}");
    let whole = BtfSettings {
        impostor_px: 1.0,
        ..BtfSettings::default()
    };
    assert_eq!(impostor_share(&TEXELS, 1.0, FOCAL, 130.0, &whole), 1.0);
    assert_eq!(
        impostor_share(&TEXELS, 1.0, FOCAL, 130.0, &BtfSettings::default()),
        0.0,
        "off by default"
    );
    let trees = [tree_at(0.0, 0.0, 0.3)];
    let (billboard, _) = run_as(&trees, Vec3::new(0.0, 5.0, 90.0), &s, true);
    assert!(billboard.impostors[0].is_empty() && billboard.records.len() == 1);
    let (impostor, _) = run_as(&trees, Vec3::new(0.0, 5.0, 130.0), &s, true);
    assert_eq!(impostor.impostors[0], vec![(0, 1.0)]);
    assert!(impostor.records.is_empty());
    // In the band: the impostor and the tree billboard, their opacities summing to 1.
    let (band, _) = run_as(&trees, Vec3::new(0.0, 5.0, 0.1 * FOCAL / 0.45), &s, true);
    let (_, o) = band.impostors[0][0];
    assert!(o > 0.2 && o < 0.8, "{o}");
    assert_eq!(band.records.len(), 1);
    assert!((band.records[0].opacity + o - 1.0).abs() < 1e-4);
}

/// A species whose finer levels are not baked yet is drawn whole as geometry where its
/// tree level is too coarse, cross-faded with the tree billboard over the band; never at a
/// finer level.
#[test]
fn without_finer_levels_a_tree_is_geometry_where_its_tree_level_is_too_coarse() {
    let s = BtfSettings {
        lod_scale: 1.0,
        lod_fade: 0.2,
        ..BtfSettings::default()
    };
    let mut partial = scene();
    partial.species[0].finer = false;
    partial.species[0].texels = PerLevel {
        twig: 0.0,
        branch: 0.0,
        tree: TEXELS.tree,
    };
    let trees = [tree_at(0.0, 0.0, 0.3)];
    let at = |scene: &BtfScene, z: f32| run_in(scene, &trees, Vec3::new(0.0, 5.0, z), &s, false).0;
    // The tree level's texel is a pixel at 0.1 · 500 = 50 m; the band starts at 62.5 m.
    let near = at(&partial, 20.0);
    assert_eq!(near.twigs[0], vec![(0, 1.0)]);
    assert_eq!(near.stats.geometry_trees, 1);
    assert!(near.records.is_empty());
    let band = at(&partial, 0.1 * FOCAL / 0.9);
    let (t, g) = band.twigs[0][0];
    assert!(t == 0 && (g - 0.5).abs() < 1e-3, "{g}");
    assert_eq!(band.stats.trees_per_level.tree, 1);
    assert_eq!(band.records.len(), 1, "the tree billboard alone");
    assert!((band.records[0].opacity - 0.5).abs() < 1e-3);
    let far = at(&partial, 100.0);
    assert!(far.twigs[0].is_empty() && far.records.len() == 1);
    assert!((far.records[0].opacity - 1.0).abs() < 1e-6);

    // Finer levels still being baked: the tree level down to 4 times the LOD scale.
    partial.species[0].pending = true;
    let before = at(&partial, 20.0);
    assert!(
        before.twigs[0].is_empty() && before.records.len() == 1,
        "20 m: a billboard"
    );
    let close = at(&partial, 5.0);
    assert_eq!(close.twigs[0], vec![(0, 1.0)], "5 m: geometry");
}
