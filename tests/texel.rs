//! Volumetric texels (issue 11): the bake's voxelisation gives the occupancy of known
//! objects and agrees with the slab-by-slab bake the seeds describe; a lone fir drawn as a
//! texel stays within a measured FLIP of the reference.

use canopy::bake::texel::{TexelGrid, bake_volume, bake_volume_by_slabs, bake_volume_from};
use canopy::format::{Baked, TexelVolume};
use canopy::model::mesh::{Aabb, Mesh, Vertex};
use canopy::model::params::TexelSource;
use canopy::model::tree::TreeModel;
use canopy::render::method::texel::TexelMode;
use canopy::render::{Camera, FrameDesc, Method, Reference, Renderer};
use canopy::scene::Scene;
use canopy::sphere::DirectionSet;
use glam::{Mat4, UVec3, Vec3};

use crate::common::*;

fn lone_tree(species: &str) -> Scene {
    let mut scene = load_scene("lone_tree.toml");
    scene.bake.texel_resolution = 64;
    if scene.species[0].name != species {
        // The fixture's own tree is the fir as its bounds were measured; another species
        // is the preset.
        scene.species[0].preset = Some(species.into());
        scene.species[0].params = None;
    }
    scene.species[0].name = species.into();
    scene
}

/// A tree model holding only `mesh` in `bounds`.
fn object(mesh: Mesh, bounds: Aabb) -> TreeModel {
    let p = canopy::model::species::preset("fir").unwrap();
    let mut o = TreeModel::generate(&p, 1).unwrap();
    o.trunk = mesh;
    o.branch_limb = Mesh::default();
    o.tree_branches.clear();
    o.branch_twigs.clear();
    o.tree_twigs.clear();
    o.tree_bounds = bounds;
    o
}

/// A bark vertex (one-sided: its back faces are culled in every pass, as the trunk's).
fn vertex(p: Vec3, n: Vec3) -> Vertex {
    Vertex::new(p, n, Vec3::splat(0.6), 0.0)
}

/// The closed surface of the box from `lo` to `hi`, faces outward.
fn box_mesh(lo: Vec3, hi: Vec3) -> Mesh {
    let mut m = Mesh::default();
    for axis in 0..3 {
        for side in [0.0f32, 1.0] {
            let mut n = Vec3::ZERO;
            n[axis] = if side > 0.5 { 1.0 } else { -1.0 };
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |a: f32, b: f32| {
                let mut p = Vec3::ZERO;
                p[axis] = if side > 0.5 { hi[axis] } else { lo[axis] };
                p[u] = if a > 0.5 { hi[u] } else { lo[u] };
                p[v] = if b > 0.5 { hi[v] } else { lo[v] };
                p
            };
            let i: Vec<u32> = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
                .iter()
                .map(|&(a, b)| m.push_vertex(vertex(corner(a, b), n)))
                .collect();
            m.push_triangle_facing(i[0], i[1], i[2], n);
            m.push_triangle_facing(i[0], i[2], i[3], n);
        }
    }
    m
}

/// A UV sphere of radius `r` around `c`.
fn sphere_mesh(c: Vec3, r: f32) -> Mesh {
    let mut m = Mesh::default();
    let (rings, segments) = (24u32, 48u32);
    for i in 0..=rings {
        let th = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..=segments {
            let ph = std::f32::consts::TAU * j as f32 / segments as f32;
            let n = Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
            m.push_vertex(vertex(c + n * r, n));
        }
    }
    for i in 0..rings {
        for j in 0..segments {
            let a = i * (segments + 1) + j;
            let b = a + segments + 1;
            let mid = |k: [u32; 3]| {
                k.iter()
                    .map(|&x| Vec3::from(m.vertices[x as usize].position))
                    .sum::<Vec3>()
                    / 3.0
                    - c
            };
            let f1 = mid([a, b, a + 1]);
            let f2 = mid([a + 1, b, b + 1]);
            m.push_triangle_facing(a, b, a + 1, f1);
            m.push_triangle_facing(a + 1, b, b + 1, f2);
        }
    }
    m
}

/// The sky-lit volume's coverage per voxel (0..1).
fn coverage(v: &TexelVolume) -> Vec<f32> {
    let n = v.dims.iter().product::<u32>() as usize;
    let sky = v.lights as usize * n * 4;
    v.voxels[sky..sky + n * 4]
        .chunks_exact(4)
        .map(|p| f32::from(p[3]) / 255.0)
        .collect()
}

fn centre_of(g: &TexelGrid, i: usize) -> Vec3 {
    let d = g.dims;
    let (x, y, z) = (
        i as u32 % d.x,
        (i as u32 / d.x) % d.y,
        i as u32 / (d.x * d.y),
    );
    g.box_min + (UVec3::new(x, y, z).as_vec3() + 0.5) * g.voxel
}

/// Occupancy against the distance of each voxel's centre to the surface (`distance`): voxels
/// the surface crosses are covered, voxels more than a voxel away are empty. Returns (mean
/// coverage of voxels within a quarter voxel of the surface, largest coverage beyond 1.5
/// voxels).
fn occupancy(v: &TexelVolume, g: &TexelGrid, distance: impl Fn(Vec3) -> f32) -> (f32, f32) {
    let cov = coverage(v);
    let (mut near, mut n_near, mut far) = (0.0, 0, 0.0f32);
    for (i, &c) in cov.iter().enumerate() {
        let d = distance(centre_of(g, i)).abs() / g.voxel;
        if d < 0.25 {
            near += c;
            n_near += 1;
        } else if d > 1.5 {
            far = far.max(c);
        }
    }
    (near / n_near.max(1) as f32, far)
}

#[test]
fn the_voxelisation_gives_the_occupancy_of_a_box_and_a_sphere_and_agrees_with_the_slabs() {
    let ctx = gpu();
    let lights = DirectionSet::with_count(6).unwrap();
    // A box 2.75 x 1.75 x 2.25 m in a grid of 0.25 m voxels, its walls through voxel centres:
    // only its walls are there, and its inside stays empty (a mesh is a surface: a "solid"
    // box bakes as its shell).
    let (lo, hi) = (
        Vec3::new(-1.375, 0.425, -1.125),
        Vec3::new(1.375, 2.175, 1.125),
    );
    let grid = TexelGrid {
        box_min: Vec3::new(-2.0, -0.2, -2.0),
        dims: UVec3::splat(16),
        voxel: 0.25,
    };
    let shell = object(box_mesh(lo, hi), Aabb::new(lo, hi));
    let fast = bake_volume(&ctx, &shell, 0, &grid, &lights, 4, &mut || {}).unwrap();
    let box_distance = |p: Vec3| {
        // Distance to the nearest wall, for points on the walls' planes within the box.
        let inside = p.cmpge(lo - 0.01).all() && p.cmple(hi + 0.01).all();
        let d = (p - lo).min(hi - p);
        if inside { d.min_element() } else { 9.0 }
    };
    let (near, far) = occupancy(&fast, &grid, box_distance);
    eprintln!("box shell: coverage on the walls {near:.3}, largest away from them {far:.3}");
    // Measured 0.888: the walls' faces are fully covered, their rims (walls ending at voxel
    // centres) half.
    assert!(near > 0.8, "the walls are covered: {near}");
    assert_eq!(far, 0.0, "nothing away from the walls");
    // The seeds' way, one render per slab, gives the same volume.
    let slow = bake_volume_by_slabs(&ctx, &shell, 0, &grid, &lights, 4).unwrap();
    let (a, b) = (coverage(&fast), coverage(&slow));
    let diff =
        a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum::<f32>() / a.iter().sum::<f32>().max(1e-6);
    eprintln!("box shell: voxelisation vs slab renders, relative coverage difference {diff:.4}");
    // Measured 0.0000: both see the same surfaces in the same voxels.
    assert!(diff < 0.01, "{diff}");
    // And the same colours, in every light's volume and the sky's (mean over covered
    // voxels, 8-bit sRGB steps).
    let (mut sum, mut n) = (0.0f64, 0u32);
    for (p, q) in fast.voxels.chunks_exact(4).zip(slow.voxels.chunks_exact(4)) {
        if p[3] > 0 || q[3] > 0 {
            sum += (0..3)
                .map(|c| (f64::from(p[c]) - f64::from(q[c])).abs())
                .sum::<f64>()
                / 3.0;
            n += 1;
        }
    }
    let colour = sum / f64::from(n.max(1));
    eprintln!("box shell: mean colour difference {colour:.2} (of 255)");
    // Measured 0.01.
    assert!(colour < 1.0, "{colour}");

    // A sphere of radius 1.4 m: covered where its surface runs, empty inside and outside.
    let c = Vec3::new(0.0, 1.8, 0.0);
    let r = 1.4;
    let ball = object(
        sphere_mesh(c, r),
        Aabb::new(c - Vec3::splat(r), c + Vec3::splat(r)),
    );
    let sphere = bake_volume(&ctx, &ball, 0, &grid, &lights, 4, &mut || {}).unwrap();
    let (near, far) = occupancy(&sphere, &grid, |p| (p - c).length() - r);
    eprintln!("sphere: coverage on the surface {near:.3}, largest away from it {far:.3}");
    assert!(near > 0.7, "the surface is covered: {near}");
    assert_eq!(far, 0.0, "nothing away from the surface");
}

/// Voxels occupied by `a` and not `b`, and by `b` and not `a`, as fractions of `a`'s
/// occupied voxels (occupied: coverage at least `at`).
fn occupancy_difference(a: &TexelVolume, b: &TexelVolume, at: f32) -> (f32, f32) {
    let (ca, cb) = (coverage(a), coverage(b));
    let occupied = ca.iter().filter(|&&c| c >= at).count().max(1) as f32;
    let only_a = ca
        .iter()
        .zip(&cb)
        .filter(|&(&x, &y)| x >= at && y < at)
        .count() as f32;
    let only_b = ca
        .iter()
        .zip(&cb)
        .filter(|&(&x, &y)| x < at && y >= at)
        .count() as f32;
    (only_a / occupied, only_b / occupied)
}

/// Babahenini et al.'s voxel colouring (each depth pixel writes its colour, opaque, into
/// the voxel at its depth) finds the same surfaces as the slabs on objects every one of
/// whose surfaces some axis view sees first: a box shell and a sphere.
#[test]
fn voxel_colouring_finds_the_surfaces_the_slabs_find() {
    let ctx = gpu();
    let lights = DirectionSet::with_count(6).unwrap();
    let grid = TexelGrid {
        box_min: Vec3::new(-2.0, -0.2, -2.0),
        dims: UVec3::splat(16),
        voxel: 0.25,
    };
    let (lo, hi) = (
        Vec3::new(-1.375, 0.425, -1.125),
        Vec3::new(1.375, 2.175, 1.125),
    );
    let c = Vec3::new(0.0, 1.8, 0.0);
    let r = 1.4;
    let objects = [
        ("box shell", object(box_mesh(lo, hi), Aabb::new(lo, hi))),
        (
            "sphere",
            object(
                sphere_mesh(c, r),
                Aabb::new(c - Vec3::splat(r), c + Vec3::splat(r)),
            ),
        ),
    ];
    for (name, o) in &objects {
        let slabs = bake_volume(&ctx, o, 0, &grid, &lights, 4, &mut || {}).unwrap();
        let coloured = bake_volume_from(
            &ctx,
            o,
            0,
            &grid,
            &lights,
            4,
            TexelSource::VoxelColouring,
            &mut || {},
        )
        .unwrap();
        // Every voxel colouring writes is opaque.
        assert!(coverage(&coloured).iter().all(|&c| c == 0.0 || c == 1.0));
        // Holes: voxels the slabs cover a quarter or more and voxel colouring leaves empty.
        // False voxels: opaque where the slabs found nothing (under 1 % coverage).
        // Thickened: opaque where the slabs cover less than a quarter (a surface grazing
        // the voxel's corner), the price of writing alpha 255.
        let (holes, thickened) = occupancy_difference(&slabs, &coloured, 0.25);
        let (_, false_voxels) = occupancy_difference(&slabs, &coloured, 0.01);
        eprintln!(
            "{name}: voxel colouring against the slabs: holes {holes:.3}, false voxels {false_voxels:.3}, thickened {thickened:.3} (fractions of the voxels the slabs cover a quarter or more)"
        );
        // Measured: box shell 0.000, 0.000, 0.000; sphere 0.000, 0.000, 0.431.
        assert!(holes < 0.02, "{name}: {holes}");
        assert!(false_voxels < 0.02, "{name}: {false_voxels}");
    }
}

/// A lone tree of one species, baked (with texels) and ready to draw: the renderer with
/// the bake attached and the reference prepared, and the crown's centre.
struct LoneTree {
    ctx: canopy::render::GpuContext,
    scene: Scene,
    world: canopy::model::World,
    baked: Baked,
    renderer: Renderer,
    centre: Vec3,
}

impl LoneTree {
    fn new(species: &str) -> Self {
        let ctx = gpu();
        let scene = lone_tree(species);
        let world = scene.build_world().unwrap();
        let baked = baked(&scene);
        assert_eq!(baked.texels.len(), 1, "one species, one set of volumes");
        let tree = world.forest.instances[0];
        let centre = world.species[0]
            .tree_bounds
            .transformed(Mat4::from_translation(tree.position))
            .center();
        let mut renderer = Renderer::new(&ctx, &world).unwrap();
        renderer.attach_btf(&ctx, baked, &world).unwrap();
        assert!(renderer.has_texels());
        prepare_reference(&mut renderer, &ctx, &scene, &world);
        Self {
            ctx,
            scene,
            world,
            baked: baked.clone(),
            renderer,
            centre,
        }
    }

    /// Draws texels from `volume` instead of the bake's own.
    fn use_volume(&mut self, volume: TexelVolume) {
        let mut baked = self.baked.clone();
        baked.texels = vec![volume];
        self.renderer
            .attach_btf(&self.ctx, &baked, &self.world)
            .unwrap();
        assert!(self.renderer.has_texels());
    }

    /// The crown seen from `offset` away through a `fov`-degree lens, no fog.
    fn view(&self, offset: Vec3, fov: f32) -> FrameDesc {
        let mut frame = FrameDesc::from_scene(&self.scene);
        frame.camera = Camera::look_at(self.centre + offset, self.centre, fov);
        frame.fog_density = 0.0;
        frame
    }

    /// `frame` drawn with `method` (and its stats), at `w` x `h`.
    fn draw(
        &mut self,
        frame: FrameDesc,
        method: Method,
        w: u32,
        h: u32,
    ) -> (image::RgbImage, canopy::render::FrameStats) {
        let frame = FrameDesc { method, ..frame };
        let (img, stats) = self
            .renderer
            .render_image(&self.ctx, &frame, w, h, 1)
            .unwrap();
        (rgb(&img), stats)
    }

    /// `frame` drawn as texels sliced the `mode` way.
    fn texel(
        &mut self,
        mut frame: FrameDesc,
        mode: TexelMode,
        w: u32,
        h: u32,
    ) -> (image::RgbImage, canopy::render::FrameStats) {
        frame.texel.mode = mode;
        self.draw(frame, Method::Texel, w, h)
    }

    /// `frame` drawn as the reference, supersampled x2.
    fn truth(&mut self, frame: FrameDesc, w: u32, h: u32) -> image::RgbImage {
        let reference = FrameDesc {
            reference: Some(Reference::default()),
            ..frame
        };
        rgb(&self
            .renderer
            .render_image(&self.ctx, &reference, w, h, 2)
            .unwrap()
            .0)
    }
}

/// A lone tree's mean FLIP against the reference, drawn three ways.
struct LoneFlip {
    slices3d: f32,
    stacks: f32,
    btf: f32,
    /// The polygons mode against the ray march (the same slices and samples).
    polygons_vs_march: f32,
}

/// A lone tree from the side at 40 m, sun at 45 degrees: the texel (both modes) against
/// the reference (and btf, for scale).
fn lone_tree_flip(species: &str) -> LoneFlip {
    let mut lone = LoneTree::new(species);
    let frame = lone.view(Vec3::new(30.0, 6.0, 28.0), 40.0);
    let (w, h) = (240, 240);
    let truth = lone.truth(frame, w, h);
    let (texel, stats) = lone.texel(frame, TexelMode::Slices3d, w, h);
    let (stacks, stack_stats) = lone.texel(frame, TexelMode::Stacks, w, h);
    let (btf, _) = lone.draw(frame, Method::Btf, w, h);
    let (polygons, poly_stats) = lone.texel(frame, TexelMode::Polygons, w, h);
    assert_eq!(
        poly_stats.texel.map(|t| t.texel_mode),
        Some(TexelMode::Polygons)
    );
    let flip =
        |a: &image::RgbImage, b: &image::RgbImage| canopy::metrics::flip(a, b).unwrap().stats.mean;
    let f = LoneFlip {
        slices3d: flip(&truth, &texel),
        stacks: flip(&truth, &stacks),
        btf: flip(&truth, &btf),
        polygons_vs_march: flip(&texel, &polygons),
    };
    let t = stats.texel.expect("texel stats");
    let st = stack_stats.texel.expect("texel stats");
    eprintln!(
        "lone {species} at 40 m against the reference: texel slices3d {:.4} ({} slices, {} bytes), stacks {:.4} ({} slices, {} bytes), btf {:.4}; polygons against the ray march {:.4}",
        f.slices3d,
        t.slices_max,
        t.texel_bytes,
        f.stacks,
        st.slices_max,
        st.texel_bytes,
        f.btf,
        f.polygons_vs_march
    );
    let dir = std::env::temp_dir().join("canopy-texel");
    let _ = std::fs::create_dir_all(&dir);
    let _ = truth.save(dir.join(format!("{species}-reference.png")));
    let _ = texel.save(dir.join(format!("{species}-texel.png")));
    let _ = stacks.save(dir.join(format!("{species}-stacks.png")));
    let _ = btf.save(dir.join(format!("{species}-btf.png")));
    assert_eq!((t.texels, st.texels), (1, 1));
    assert_eq!(st.texel_mode, TexelMode::Stacks);
    // The stack atlas comes on top of the 3D texture.
    assert!(st.texel_bytes > t.texel_bytes);
    f
}

#[test]
fn a_lone_fir_as_a_texel_is_close_to_the_reference() {
    let f = lone_tree_flip("fir");
    // Measured 0.036 (btf 0.038): the 0.29 m voxels blur the needles and thicken the
    // trunk, but the crown's light and its shadow on the ground hold.
    assert!(f.slices3d < 0.05, "{}", f.slices3d);
    // Measured 0.031 (32 slices): the pre-composited levels keep each voxel's opacity
    // exactly along the stack's axis.
    assert!(f.stacks < 0.05, "{}", f.stacks);
    // Measured 0.0373 on lavapipe: btf's billboards against the same reference, the
    // yardstick for the texel's figures. Near 0 btf would have drawn the geometry itself
    // (a method that falls back); above 0.05 its billboards got worse.
    assert!((0.025..0.05).contains(&f.btf), "btf {}", f.btf);
    // Measured 0.0026: the same slices, sampled at the same depths.
    assert!(f.polygons_vs_march < 0.01, "{}", f.polygons_vs_march);
}

#[test]
fn a_lone_broadleaf_as_a_texel_is_close_to_the_reference() {
    let f = lone_tree_flip("broadleaf");
    // Measured 0.039 (btf 0.047).
    assert!(f.slices3d < 0.05, "{}", f.slices3d);
    // Measured 0.034.
    assert!(f.stacks < 0.05, "{}", f.stacks);
}

/// The seeds' slices show their layers when seen edge-on; slices parallel to the screen are
/// never seen edge-on. A lone fir seen from the side up to nearly straight down (the view
/// sweeping across every angle a stack would be seen at): the texel stays within a bound of
/// the reference at every elevation.
#[test]
fn slices_parallel_to_the_screen_hold_from_the_side_to_straight_down() {
    let mut lone = LoneTree::new("fir");
    let (w, h) = (160, 160);
    let mut worst: f32 = 0.0;
    let mut worst_stacks: f32 = 0.0;
    let mut figures = Vec::new();
    for elevation in [5.0f32, 30.0, 60.0, 85.0] {
        let e = elevation.to_radians();
        let dir = Vec3::new(e.cos() * 0.6, e.sin(), e.cos() * 0.8);
        let frame = lone.view(dir * 40.0, 35.0);
        let truth = lone.truth(frame, w, h);
        let (texel, _) = lone.texel(frame, TexelMode::Slices3d, w, h);
        let (stacks, _) = lone.texel(frame, TexelMode::Stacks, w, h);
        let f = canopy::metrics::flip(&truth, &texel).unwrap().stats.mean;
        let g = canopy::metrics::flip(&truth, &stacks).unwrap().stats.mean;
        figures.push(format!("{elevation}°: {f:.4} / {g:.4}"));
        worst = worst.max(f);
        worst_stacks = worst_stacks.max(g);
    }
    eprintln!(
        "lone fir, texel vs reference by view elevation (slices3d / stacks): {}",
        figures.join(", ")
    );
    // Measured 0.047, 0.039, 0.039, 0.034 at 5, 30, 60, 85 degrees.
    assert!(worst < 0.06, "{figures:?}");
    // Stacks measured 0.041, 0.035, 0.038, 0.034: the seeds' grazing failure does not
    // show on a lone fir at 40 m (its slices are 0.29 m apart, under a pixel).
    assert!(worst_stacks < 0.08, "{figures:?}");
}

/// The two sources of a lone fir's volumes side by side: the voxel-colouring volume (from
/// the same passes seen as depth images, opaque) against the slabs' (coverage), in voxels
/// and drawn against the reference.
#[test]
fn voxel_colouring_of_a_lone_fir_against_the_slabs() {
    let mut lone = LoneTree::new("fir");
    let tree = &lone.world.species[0];
    let grid = canopy::bake::texel::grid_of(tree, lone.scene.bake.texel_resolution).unwrap();
    let lights = DirectionSet::with_count(lone.baked.settings.lights as usize).unwrap();
    let ss = lone.baked.settings.supersample;
    let t0 = std::time::Instant::now();
    let coloured = bake_volume_from(
        &lone.ctx,
        tree,
        0,
        &grid,
        &lights,
        ss,
        TexelSource::VoxelColouring,
        &mut || {},
    )
    .unwrap();
    let seconds = t0.elapsed().as_secs_f32();
    let slabs = lone.baked.texels[0].clone();
    let (holes, thickened) = occupancy_difference(&slabs, &coloured, 0.25);
    let (_, false_voxels) = occupancy_difference(&slabs, &coloured, 0.01);
    let count = |v: &TexelVolume| coverage(v).iter().filter(|&&c| c > 0.0).count();
    let frame = lone.view(Vec3::new(30.0, 6.0, 28.0), 40.0);
    let (w, h) = (240, 240);
    let truth = lone.truth(frame, w, h);
    let flip =
        |a: &image::RgbImage, b: &image::RgbImage| canopy::metrics::flip(a, b).unwrap().stats.mean;
    let (from_slabs, _) = lone.texel(frame, TexelMode::Slices3d, w, h);
    lone.use_volume(coloured.clone());
    let (from_colouring, _) = lone.texel(frame, TexelMode::Slices3d, w, h);
    let (f_slabs, f_colouring) = (flip(&truth, &from_slabs), flip(&truth, &from_colouring));
    eprintln!(
        "lone fir, voxel colouring against the slabs: {} voxels against {}; holes {holes:.3}, false voxels {false_voxels:.3}, thickened {thickened:.3}; {seconds:.1} s; drawn against the reference {f_colouring:.4} against {f_slabs:.4}",
        count(&coloured),
        count(&slabs)
    );
    let dir = std::env::temp_dir().join("canopy-texel");
    let _ = std::fs::create_dir_all(&dir);
    let _ = from_colouring.save(dir.join("fir-voxel-colouring.png"));
    // Measured: 1305 voxels against 1384; holes 0.057 (inner voxels no axis view sees
    // first: "regions unseen in every view remain empty"), no false voxels, none
    // thickened; 2.9 s, the slabs' passes; 0.055 against the reference where the slabs
    // give 0.036: every voxel opaque makes the crown solid and its shadow dark.
    assert!(holes < 0.1, "{holes}");
    assert!(false_voxels < 0.01, "{false_voxels}");
    assert!(f_colouring > f_slabs, "{f_colouring} against {f_slabs}");
}

/// Where the seeds' stacks switch (the view crossing the diagonal between two axes, here
/// 45 degrees between +X and +Z), slices parallel to the screen change nothing. Orbiting a
/// lone fir 0.4 degrees at a time, away from the diagonal (40.8 to 41.2 degrees) and across
/// it (44.8 to 45.2): the texel's change from one view to the next, less the reference's own
/// change, is its pop. slices3d does not pop; the stacks do, across the diagonal only.
#[test]
fn orbiting_across_a_stack_switch_does_not_pop() {
    let mut lone = LoneTree::new("fir");
    let (w, h) = (160, 160);
    let flip =
        |a: &image::RgbImage, b: &image::RgbImage| canopy::metrics::flip(a, b).unwrap().stats.mean;
    // Per pair of views: (slices3d excess, stacks excess, reference change).
    let mut pops = Vec::new();
    for (from, to) in [(40.8f32, 41.2f32), (44.8, 45.2)] {
        let mut shots = Vec::new();
        for deg in [from, to] {
            let a = deg.to_radians();
            let dir = Vec3::new(a.sin(), 0.25, a.cos()).normalize();
            let frame = lone.view(dir * 18.0, 50.0);
            let truth = lone.truth(frame, w, h);
            let (texel, _) = lone.texel(frame, TexelMode::Slices3d, w, h);
            let (stacks, _) = lone.texel(frame, TexelMode::Stacks, w, h);
            shots.push((truth, texel, stacks));
        }
        let truth_change = flip(&shots[0].0, &shots[1].0);
        pops.push((
            flip(&shots[0].1, &shots[1].1) - truth_change,
            flip(&shots[0].2, &shots[1].2) - truth_change,
            truth_change,
        ));
    }
    eprintln!(
        "orbit, 0.4-degree steps (slices3d pop, stacks pop, reference change): at 41 degrees {:.4?}, at 45 degrees {:.4?}",
        pops[0], pops[1]
    );
    let (away, across) = (pops[0], pops[1]);
    // Measured -0.0096 and -0.0099 (the texel changes less than the reference: it is
    // blurrier).
    assert!(across.0 < 0.005 && away.0 < 0.005, "{pops:?}");
    // Measured -0.0093 at 41 degrees, -0.0017 at 45: the stacks switch across the diagonal and pop there, more than
    // away from it and more than slices3d.
    assert!(across.1 > away.1 + 0.005, "{pops:?}");
    assert!(across.1 > across.0 + 0.005, "{pops:?}");
}

/// Far away, a forest-cover tile stands for the trees in it: a lone fir 200 m off, its
/// tile beyond the tile distance, is drawn as the tile (no tree box), close to the tree's
/// own texel and to the reference.
#[test]
fn a_far_tile_stands_for_its_tree() {
    let mut lone = LoneTree::new("fir");
    let (w, h) = (160, 160);
    let mut frame = lone.view(Vec3::new(120.0, 60.0, 150.0), 12.0);
    frame.texel.tile_distance = 100.0;
    let truth = lone.truth(frame, w, h);
    let (tiled, stats) = lone.texel(frame, TexelMode::Slices3d, w, h);
    let t = stats.texel.expect("texel stats");
    assert_eq!((t.tiles, t.tiled_trees, t.texels), (1, 1, 0), "{t:?}");
    assert!(t.texel_bytes > 0);
    frame.texel.tiles = false;
    let (per_tree, stats) = lone.texel(frame, TexelMode::Slices3d, w, h);
    let t = stats.texel.expect("texel stats");
    assert_eq!((t.tiles, t.texels), (0, 1));
    let flip =
        |a: &image::RgbImage, b: &image::RgbImage| canopy::metrics::flip(a, b).unwrap().stats.mean;
    let (tile_vs_tree, tile_vs_truth, tree_vs_truth) = (
        flip(&per_tree, &tiled),
        flip(&truth, &tiled),
        flip(&truth, &per_tree),
    );
    eprintln!(
        "lone fir at 200 m: tile against its tree's texel {tile_vs_tree:.4}; against the reference: tile {tile_vs_truth:.4}, tree texel {tree_vs_truth:.4}"
    );
    let dir = std::env::temp_dir().join("canopy-texel");
    let _ = std::fs::create_dir_all(&dir);
    let _ = tiled.save(dir.join("fir-tile.png"));
    let _ = per_tree.save(dir.join("fir-far-texel.png"));
    let _ = truth.save(dir.join("fir-far-reference.png"));
    // Measured 0.0145 against the tree's texel; 0.0254 against the reference, where the
    // tree's texel gives 0.0210: its 4 m voxels make the fir a fainter column.
    assert!(tile_vs_tree > 0.0 && tile_vs_tree < 0.1, "{tile_vs_tree}");
    assert!(tile_vs_truth < 0.1, "{tile_vs_truth}");
}

/// Texel volumes that do not fit the scene leave the other methods working, and the texel
/// method says why it cannot draw.
#[test]
fn volumes_that_do_not_fit_the_scene_disable_only_the_texel_method() {
    let ctx = gpu();
    let (scene, world) = built(lone_tree("fir"));
    let mut baked = baked(&scene).clone();
    baked.texels[0].species = 5;
    let mut r = Renderer::new(&ctx, &world).unwrap();
    r.attach_btf(&ctx, &baked, &world).unwrap();
    assert!(!r.has_texels());
    let mut frame = FrameDesc::from_scene(&scene);
    frame.method = Method::Btf;
    r.render_image(&ctx, &frame, 32, 32, 1).unwrap();
    frame.method = Method::Texel;
    let e = r
        .render_image(&ctx, &frame, 32, 32, 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("species 5"), "{e}");
}

/// The texel volumes go to the GPU when a frame first draws them, not when the bake is
/// attached: a bake drawn with `btf` holds no 3D texture.
#[test]
fn texel_volumes_reach_the_gpu_when_first_drawn() {
    let ctx = gpu();
    let (scene, world) = built(lone_tree("fir"));
    let baked = baked(&scene);
    let mut r = Renderer::new(&ctx, &world).unwrap();
    r.attach_btf(&ctx, baked, &world).unwrap();
    assert!(r.has_texels());
    let on_gpu = |r: &Renderer| {
        r.memory_report(&ctx)
            .gpu_parts
            .iter()
            .find(|p| p.name == "texel volumes")
            .map(|p| p.bytes)
    };
    let mut frame = FrameDesc::from_scene(&scene);
    frame.method = Method::Btf;
    r.render_image(&ctx, &frame, 32, 32, 1).unwrap();
    assert_eq!(on_gpu(&r), None);
    assert_eq!(r.texel_bytes(), 0);
    frame.method = Method::Texel;
    r.render_image(&ctx, &frame, 32, 32, 1).unwrap();
    let bytes = on_gpu(&r).expect("the volumes are on the GPU once drawn");
    assert!(bytes >= r.texel_bytes() && r.texel_bytes() > 0, "{bytes}");
}
