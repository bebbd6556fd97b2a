//! The far and near trees' billboards built on the GPU against what the CPU makes of the
//! same trees.

use super::*;

/// The far trees' records as the GPU builds and sorts them, read back.
fn gpu_far_records(
    scene: &BtfScene,
    trees: &[TreeGpu],
    view: &PrepareView,
    settings: &BtfSettings,
    budget: u64,
    near_room: Option<u64>,
    shrink: bool,
) -> Vec<BillboardGpu> {
    use crate::render::{AdapterPreference, GpuContext};
    let ctx = GpuContext::headless(AdapterPreference::Cpu).expect("a Vulkan adapter");
    let layout = super::super::super::btf_layout(&ctx.device);
    let axes = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: 16,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d {
            width: 1,
            height: 1,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8UnormSrgb,
        usage: wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    });
    let texture_view = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    let sampler = ctx
        .device
        .create_sampler(&wgpu::SamplerDescriptor::default());
    let species = vec![0u32; trees.len()];
    let bounds: Vec<Aabb> = trees
        .iter()
        .map(|t| {
            scene.species[0]
                .bounds
                .transformed(Mat4::from_cols_array_2d(&t.model))
        })
        .collect();
    let mut gpu = super::super::super::far::FarGpu::new(
        &ctx,
        scene,
        trees,
        &species,
        &bounds,
        &layout,
        (&axes, &texture_view, &sampler),
        &[],
    )
    .unwrap()
    .expect("the far trees fit");
    if let Some(room) = near_room {
        gpu.set_near_room(room);
    }
    // Buffers grown by a larger frame before, given back by this one.
    let grown = shrink.then(|| {
        gpu.grow_then_shrink_each_frame(&ctx, 400_000);
        gpu.bytes()
    });
    let (near, _) = gpu.prepare(&ctx, scene, trees, &bounds, view, settings, true, None);
    if settings.gpu_near {
        let (_, records, draws, slots) =
            scene.prepare_near(trees, &species, &near, view, settings, false, budget);
        assert!(slots <= budget);
        assert_eq!(records.is_empty(), budget == u64::MAX);
        assert!(gpu.upload_near(&ctx, &records, &draws, slots).unwrap());
    } else {
        let (_, records) = scene.prepare_sorted(trees, &near, view, settings, 0, false);
        assert!(gpu.upload_near(&ctx, &records, &[], 0).unwrap());
    }
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
    gpu.encode(&mut encoder, &crate::render::timing::PassSpans::off());
    ctx.queue.submit([encoder.finish()]);
    if let Some(grown) = grown {
        assert!(
            gpu.bytes() * 4 < grown,
            "the record buffers were not given back: {} of {grown} bytes",
            gpu.bytes()
        );
    }
    gpu.read_sorted(&ctx).unwrap()
}

/// The weight of sample `i` in slots (`index`, `weight`).
fn weight_of(index: [u32; 3], weight: [f32; 3], i: u32) -> f32 {
    (0..3).filter(|&k| index[k] == i).map(|k| weight[k]).sum()
}

#[test]
fn the_gpu_builds_the_far_trees_records_the_cpu_would_back_to_front() {
    // A crowd 90 to 400 m away: every tree past the tree level's fade band.
    gpu_against_cpu(FarCase {
        z_min: 90.0,
        ..Default::default()
    });
}

#[test]
fn near_trees_made_on_the_cpu_are_sorted_with_the_far_ones() {
    // From 4 m: trees at every level, fading, the near ones' billboards made on the
    // CPU and sorted with the far ones' on the GPU.
    gpu_against_cpu(FarCase {
        z_min: 4.0,
        near: true,
        ..Default::default()
    });
}

#[test]
fn near_trees_expanded_on_the_gpu_are_what_the_cpu_would_make() {
    // The same, the near trees' billboards expanded and shaded on the GPU: their parts'
    // cube maps read towards the sun in each part's frame, and the parents' factors.
    gpu_against_cpu(FarCase {
        z_min: 4.0,
        near: true,
        gpu_near: true,
        ..Default::default()
    });
    // And without cube maps (every factor 1), with the level overlay (a main-branch
    // draw's twigs in the main branch's colour).
    gpu_against_cpu(FarCase {
        z_min: 4.0,
        near: true,
        gpu_near: true,
        vcm: false,
        overlay: true,
        ..Default::default()
    });
}

#[test]
fn record_buffers_a_larger_frame_grew_are_given_back_and_the_frame_stays_right() {
    gpu_against_cpu(FarCase {
        z_min: 4.0,
        near: true,
        gpu_near: true,
        shrink: true,
        ..Default::default()
    });
}

#[test]
fn past_the_gpus_room_the_farther_near_trees_billboards_are_made_on_the_cpu() {
    // Room for some of the near trees' billboards only: the nearest trees' go to the
    // GPU, the others' are made on the CPU, and together they are the CPU's frame.
    gpu_against_cpu(FarCase {
        z_min: 4.0,
        near: true,
        gpu_near: true,
        budget: 300,
        ..Default::default()
    });
}

#[test]
fn near_slots_past_one_bindings_room_go_to_a_second_binding() {
    // A first binding of 100 slots (lavapipe's holds 524,288 records, which a frame of
    // 100,000 trees at 1280x720 passes): the next 100 go to the second, the farther
    // near trees' billboards to the CPU, and together they are the CPU's frame.
    gpu_against_cpu(FarCase {
        z_min: 4.0,
        near: true,
        gpu_near: true,
        budget: 200,
        near_room: Some(100),
        ..Default::default()
    });
}

/// What a [`gpu_against_cpu`] case varies.
#[derive(Clone, Copy, Debug)]
struct FarCase {
    /// The trees stand from `z_min` to 400 m ahead.
    z_min: f32,
    /// Some trees are near.
    near: bool,
    /// The near trees' billboards are expanded on the GPU, at most `budget` slots of them.
    gpu_near: bool,
    budget: u64,
    /// With cube maps of random opacity.
    vcm: bool,
    /// Tinted by level.
    overlay: bool,
    /// The room of the GPU's first binding of near slots, when not the device's.
    near_room: Option<u64>,
    /// The record buffers grown by a larger frame before, given back by this one.
    shrink: bool,
}

impl Default for FarCase {
    /// Trees from 90 m, none near, with cube maps, no budget, no overlay.
    fn default() -> Self {
        FarCase {
            z_min: 90.0,
            near: false,
            gpu_near: false,
            budget: u64::MAX,
            vcm: true,
            overlay: false,
            near_room: None,
            shrink: false,
        }
    }
}

/// The scene of [`gpu_against_cpu`] (`vcm`: with cube maps of random opacity).
fn far_scene(vcm: bool) -> BtfScene {
    // The tree level at 66 views and 6 lights, as the default bake.
    let mut scene = scene();
    scene.views.tree = DirectionSet::with_count(66).unwrap();
    scene.views.branch = DirectionSet::with_count(18).unwrap();
    scene.views.twig = DirectionSet::with_count(6).unwrap();
    scene.lights = DirectionSet::with_count(6).unwrap();
    // The tree level reads light blends of 16 yaw bins (the record says which).
    scene.set_light_blend(16, 5000);
    if vcm {
        scene.vcm = Some(VcmShading::synthetic(
            4,
            &[(BRANCHES, BRANCH_TWIGS + TRUNK_TWIGS)],
            300,
        ));
    }
    scene
}

/// 300 trees of mixed yaw and scale from `z_min` to 400 m ahead, denser near the camera.
fn crowd(z_min: f32) -> Vec<TreeGpu> {
    let mut trees = Vec::new();
    let mut rng = 7u32;
    let mut next = || {
        rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (rng >> 8) as f32 / (1u32 << 24) as f32
    };
    while trees.len() < 300 {
        // Denser near the camera.
        let z = next().powi(2) * (400.0 - z_min) + z_min;
        let x = (next() * 2.6 - 1.3) * (z + 10.0);
        let s = 0.8 + 0.4 * next();
        let m = Mat4::from_translation(Vec3::new(x, 3.0 * next(), z))
            * Mat4::from_rotation_y(next() * std::f32::consts::TAU)
            * Mat4::from_scale(Vec3::splat(s));
        trees.push(TreeGpu {
            model: m.to_cols_array_2d(),
            tint: [next(), next(), next(), 1.0],
        });
    }
    trees
}

/// Trees from `case.z_min` to 400 m ahead; the GPU's billboards, back to front, are the
/// CPU's (see [`FarCase`]).
fn gpu_against_cpu(case: FarCase) {
    let FarCase {
        z_min,
        near,
        gpu_near,
        budget,
        vcm,
        overlay,
        near_room,
        shrink,
    } = case;
    let mut scene = far_scene(vcm);
    let trees = crowd(z_min);
    let camera = Camera::look_at(Vec3::new(0.0, 6.0, -2.0), Vec3::new(0.0, 0.0, 200.0), 60.0);
    let frustum = camera.frustum(16.0 / 9.0);
    let view = PrepareView {
        camera: &camera,
        focal_px: FOCAL,
        to_sun: Vec3::new(0.3, 0.5, -0.6).normalize(),
        frustum: &frustum,
    };
    let settings = BtfSettings {
        weight_threshold: 0.15,
        gpu_near,
        show_lod: overlay,
        ..BtfSettings::default()
    };
    scene.update_sun(view.to_sun);
    // The trees in view by their bounds, as the renderer culls (the billboard's own
    // test then drops a few more).
    let visible = vec![
        (0..trees.len() as u32)
            .filter(|&t| {
                let m = Mat4::from_cols_array_2d(&trees[t as usize].model);
                frustum.intersects(&scene.species[0].bounds.transformed(m))
            })
            .collect::<Vec<_>>(),
    ];
    assert!(visible[0].len() < trees.len(), "some trees are out of view");
    let bound = BtfScene::far_bound(&settings);
    let near_trees = trees
        .iter()
        .filter(|t| scene.is_near(0, t, &view, bound))
        .count();
    assert_eq!(near_trees > 0, near, "{near_trees} near trees");
    let cpu_frame = scene.prepare(&trees, &visible, &view, &settings, usize::MAX, false);
    if near {
        let levels = cpu_frame.stats.trees_per_level;
        assert!(
            levels[Level::Twig] > 0 && levels[Level::Branch] > 0,
            "{levels:?}"
        );
        assert!(cpu_frame.stats.faded_trees > 0);
    }
    let mut cpu = cpu_frame.records;
    assert!(cpu.len() > 100, "{} billboards in view", cpu.len());
    let gpu = gpu_far_records(&scene, &trees, &view, &settings, budget, near_room, shrink);
    assert_eq!(gpu.len(), cpu.len(), "as many billboards");
    let forward = camera.forward();
    let depth = |r: &BillboardGpu| (Vec3::from(r.center) - camera.position).dot(forward);
    for (k, pair) in gpu.windows(2).enumerate() {
        assert!(
            depth(&pair[0]) >= depth(&pair[1]) - 1e-3,
            "record {k} is nearer than the next"
        );
    }
    for (k, g) in gpu.iter().enumerate() {
        // Its match among the CPU's records (the same object seen the same way).
        let m = cpu
            .iter()
            .position(|c| {
                (c.layer_base, c.opacity) == (g.layer_base, g.opacity)
                    && (c.radius - g.radius).abs() < 1e-4
                    && close(g.center, c.center, 1e-3)
                    && close(g.obj_right, c.obj_right, 1e-3)
            })
            .unwrap_or_else(|| panic!("record {k} is not the CPU's: {g:?}"));
        let c = cpu.swap_remove(m);
        assert_same_record(k, g, &c);
    }
}

/// Whether `a` and `b` differ by at most `tol` in each coordinate.
fn close(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
    (Vec3::from(a) - Vec3::from(b)).abs().max_element() <= tol
}

/// The GPU's record `k`, `g`, is the CPU's `c`.
fn assert_same_record(k: usize, g: &BillboardGpu, c: &BillboardGpu) {
    assert!(
        close(g.center, c.center, 1e-3),
        "record {k}: centre {g:?} against {c:?}"
    );
    assert!((g.radius - c.radius).abs() < 1e-4);
    assert!(
        close(g.plane_right, c.plane_right, 1e-4),
        "record {k}: {g:?} against {c:?}"
    );
    assert!(close(g.plane_up, c.plane_up, 1e-4));
    assert!(close(g.obj_right, c.obj_right, 1e-4));
    assert!(close(g.obj_up, c.obj_up, 1e-4));
    // The same weight on each of `n` directions, whatever the order of the three.
    let same_weights = |what: &str, n: u32, g: ([u32; 3], [f32; 3]), c: ([u32; 3], [f32; 3])| {
        for i in 0..n {
            let (wg, wc) = (weight_of(g.0, g.1, i), weight_of(c.0, c.1, i));
            assert!(
                (wg - wc).abs() < 1e-3,
                "record {k} {what} {i}: {wg} against {wc}"
            );
        }
    };
    same_weights(
        "view",
        66,
        (g.view_index, g.view_weight),
        (c.view_index, c.view_weight),
    );
    same_weights(
        "light",
        6,
        (g.light_index, g.light_weight),
        (c.light_index, c.light_weight),
    );
    assert_eq!(
        (g.layer_base, g.view_count, g.light_count, g.planes, g.mode),
        (c.layer_base, c.view_count, c.light_count, c.planes, c.mode)
    );
    assert_eq!((g.opacity, g.tint), (c.opacity, c.tint));
    assert_eq!(g.light_blend, c.light_blend, "record {k}: light blend");
    assert!(close(g.vcm_box_origin, c.vcm_box_origin, 1e-5));
    assert!(close(g.vcm_box_scale, c.vcm_box_scale, 1e-5));
    let factors = |r: &BillboardGpu| {
        let mut v = r.vcm_direct.concat();
        v.extend(r.vcm_sky.concat());
        v.extend([r.parent_direct, r.parent_sky]);
        v
    };
    for (i, (fg, fc)) in factors(g).into_iter().zip(factors(c)).enumerate() {
        assert!(
            (fg - fc).abs() < 1e-3,
            "record {k} factor {i}: {fg} against {fc}"
        );
    }
}
