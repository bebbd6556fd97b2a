use super::maps::{Maps, sample_bc4};
use super::*;
use crate::format::{Baked, VCM_CELL_SPECIES};
use crate::model::{Level, World};
use crate::vcm::FACES;
use crate::vcm::cells::ForestCells;

#[test]
fn a_bc4_cube_map_reads_as_its_decoded_bytes() {
    use crate::format::bc;
    for res in [4u32, 8, 16, 6] {
        let n = (res * res) as usize;
        let faces: Vec<Vec<u8>> = (0..FACES)
            .map(|f| {
                (0..n)
                    .map(|t| ((t * 37 + f * 91 + (t * t) % 17 * 11) % 256) as u8)
                    .collect()
            })
            .collect();
        let blocks: Vec<u8> = faces
            .iter()
            .flat_map(|f| bc::encode_bc4(f, res, res))
            .collect();
        let decoded: Vec<u8> = blocks
            .chunks_exact(bc::bc4_bytes(res, res) as usize)
            .flat_map(|b| bc::decode_bc4(b, res, res).unwrap())
            .collect();
        for k in 0..500 {
            let t = k as f32 * 0.61;
            let dir = Vec3::new(t.sin() * 1.3, (t * 0.7).cos(), (t * 1.9).sin() - 0.2);
            let (a, b) = (
                vcm::sample(&decoded, res, dir),
                sample_bc4(&blocks, res, dir),
            );
            assert_eq!(a, b, "res {res}, direction {dir}");
        }
        assert_eq!(sample_bc4(&blocks[..10], res, Vec3::X), 0.0);
    }
}

#[test]
fn an_object_behind_a_wall_reads_dark_towards_it_only() {
    let res = 8;
    let mut raster = vcm::CubeRaster::new(res);
    raster.draw(
        Vec3::ZERO,
        &vcm::PlainQuad {
            center: Vec3::new(0.0, 0.0, 2.0),
            right: Vec3::X * 50.0,
            up: Vec3::Y * 50.0,
            alpha: 1.0,
        },
    );
    let mut one = Vec::new();
    raster.finish(&mut one, false);
    let opacity: Vec<u8> = (0..CORNERS).flat_map(|_| one.iter().copied()).collect();
    let o = ObjectVcm {
        opacity: Maps::R8(opacity),
        sky: [0.5; CORNERS],
    };
    assert_eq!(o.direct(res, Vec3::Z), [0.0; CORNERS]);
    assert_eq!(o.direct(res, -Vec3::Z), [1.0; CORNERS]);
}

fn lone_world() -> World {
    let mut scene =
        crate::scene::Scene::parse(crate::scene::SMALL_TEST_SCENE_TOML, "small.toml").unwrap();
    scene.forest.count = Some(1);
    scene.build_world().unwrap()
}

fn set(species: u32, owner: u32, level: Level) -> crate::format::VcmSet {
    crate::format::VcmSet {
        species,
        owner,
        level,
        encoding: crate::format::MapEncoding::R8,
        resolution: 8,
        opacity: vec![0; CORNERS * FACES * 64],
        mean_opacity: [0.0; CORNERS],
    }
}

fn baked(vcm: Vec<crate::format::VcmSet>) -> Baked {
    Baked {
        scene_hash: 0,
        settings: crate::format::BakeSettings {
            views: 6,
            tree_views: 6,
            lights: 6,
            resolution: 32,
            supersample: 1,
            vcm_resolution: 8,
            texel_resolution: 0,
            impostor_frames: 0,
            impostor_resolution: 64,
            impostor_layout: Default::default(),
            compress: false,
            surfel_budget: 0,
        },
        btf: Vec::new(),
        vcm,
        texels: Vec::new(),
        impostors: Vec::new(),
        surfels: Vec::new(),
    }
}

/// Every set the world needs, for species `sp`'s tree at instance 0.
fn complete(world: &World) -> Vec<crate::format::VcmSet> {
    let sp = world.forest.instances[0].species;
    let mut v = vec![set(sp, 0, Level::Tree)];
    for (s, t) in world.species.iter().enumerate() {
        let s = s as u32;
        v.extend((0..t.tree_branches.len() as u32).map(|i| set(s, i, Level::Branch)));
        let twigs = (t.branch_twigs.len() + t.tree_twigs.len()) as u32;
        v.extend((0..twigs).map(|i| set(s, i, Level::Twig)));
    }
    v
}

#[test]
fn bc4_maps_are_kept_as_stored_and_read_as_their_decoded_bytes() {
    let world = lone_world();
    let mut bc4 = complete(&world);
    for (i, s) in bc4.iter_mut().enumerate() {
        for (t, o) in s.opacity.iter_mut().enumerate() {
            *o = ((t * 31 + i * 7 + (t / 64) * 50) % 256) as u8;
        }
        crate::format::bc::compress_vcm(s);
    }
    let decoded: Vec<crate::format::VcmSet> = bc4
        .iter()
        .map(|s| crate::format::VcmSet {
            encoding: crate::format::MapEncoding::R8,
            opacity: s.opacity_r8().unwrap().into_owned(),
            ..s.clone()
        })
        .collect();
    let r8: u64 = decoded.iter().map(|s| s.opacity.len() as u64).sum();
    let mut from_bc4 = VcmShading::new(&baked(bc4), &world).unwrap().unwrap();
    let mut from_r8 = VcmShading::new(&baked(decoded), &world).unwrap().unwrap();
    // Every level's maps stay BC4: half a byte a texel.
    assert_eq!(from_r8.bytes - from_bc4.bytes, r8 / 2);
    assert!(matches!(from_bc4.trees[0].opacity, Maps::Bc4(_)));
    assert!(matches!(from_bc4.branches[0][0].opacity, Maps::Bc4(_)));
    assert!(matches!(from_bc4.twigs[0][0].opacity, Maps::Bc4(_)));
    for sun in [
        Vec3::Y,
        Vec3::new(0.3, 0.8, -0.5),
        Vec3::new(-0.9, 0.2, 0.1),
    ] {
        from_bc4.set_sun(sun.normalize());
        from_r8.set_sun(sun.normalize());
        let a: Vec<Factors> = from_bc4.tree_factors(1).collect();
        let b: Vec<Factors> = from_r8.tree_factors(1).collect();
        assert_eq!(a, b);
        assert!(a[0].0.iter().any(|&v| v < 0.99), "{a:?}");
        for (x, y) in [
            (&from_bc4.branches[0], &from_r8.branches[0]),
            (&from_bc4.twigs[0], &from_r8.twigs[0]),
        ] {
            for (o, p) in x.iter().zip(y) {
                assert_eq!(o.direct(8, sun.normalize()), p.direct(8, sun.normalize()));
            }
        }
    }
    for sp in 0..world.species.len() {
        let (a, b) = (from_bc4.species_maps(sp), from_r8.species_maps(sp));
        assert_eq!(a, b);
    }
}

#[test]
fn cube_maps_that_do_not_fit_the_scene_are_refused() {
    let world = lone_world();
    let good = complete(&world);
    assert!(
        VcmShading::new(&baked(good.clone()), &world)
            .unwrap()
            .is_some()
    );
    assert!(
        VcmShading::new(&baked(Vec::new()), &world)
            .unwrap()
            .is_none()
    );
    let mut extra = good.clone();
    extra.push(set(0, 7, Level::Tree));
    let mut missing = good.clone();
    missing.remove(0);
    let mut twice = good.clone();
    twice.push(good[1].clone());
    for (v, want) in [
        (extra, "tree 7"),
        (missing, "no cube maps"),
        (twice, "two sets"),
    ] {
        let e = VcmShading::new(&baked(v), &world)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains(want) && e.contains("re-bake"), "{e}");
    }
}

#[test]
fn forest_cell_sets_that_do_not_fit_the_scene_are_refused() {
    let world = lone_world();
    let cells = ForestCells::new(&world).len() as u32;
    assert_eq!(cells, 1);
    let species_sets = || -> Vec<crate::format::VcmSet> { complete(&world)[1..].to_vec() };
    let cell = |owner: u32| crate::format::VcmSet {
        species: VCM_CELL_SPECIES,
        ..set(0, owner, Level::Tree)
    };
    let with = |extra: Vec<crate::format::VcmSet>| {
        let mut v = species_sets();
        v.extend(extra);
        VcmShading::new(&baked(v), &world)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    for (v, want) in [
        (vec![cell(0), cell(1)], "no forest cell 1"),
        (vec![cell(0), cell(0)], "forest cell 0 has two sets"),
        (
            vec![
                cell(0),
                set(world.forest.instances[0].species, 0, Level::Tree),
            ],
            "its own cube maps and the forest cells too",
        ),
        // A complete set, but no tree-level BTF images to draw the cell mates with.
        (vec![cell(0)], "no tree-level BTF images"),
    ] {
        let e = with(v);
        assert!(e.contains(want) && e.contains("re-bake"), "{want}: {e}");
    }
}

/// Two trees of one species in one forest cell, 16 m apart along x, with cube maps that
/// see nothing and tree-level images of opaque discs: only the cell mate can shade.
#[test]
fn a_cell_mate_shades_a_tree_towards_the_sun_only() {
    let mut world = lone_world();
    let first = world.forest.instances[0];
    // The second 16 m east of the first (their boxes apart), or west where east is
    // another cell.
    let mut east = 1.0;
    for e in [1.0, -1.0] {
        let second = crate::model::TreeInstance {
            position: first.position + Vec3::new(16.0 * e, 0.0, 0.0),
            ..first
        };
        world.forest.instances = vec![first, second];
        east = e;
        if ForestCells::new(&world).len() == 1 {
            break;
        }
    }
    assert_eq!(ForestCells::new(&world).len(), 1, "both trees in one cell");
    let sp = first.species;
    let b = world.species[sp as usize].tree_bounds;
    let image = (32 * 32 * 4) as usize;
    // Every view an opaque disc of 0.4 the image's side across (a crown's outline).
    let mut ambient = vec![0u8; 2 * 6 * image];
    for (i, px) in ambient.chunks_exact_mut(4).enumerate() {
        let (x, y) = ((i % 32) as f32 - 15.5, ((i / 32) % 32) as f32 - 15.5);
        if x * x + y * y < 12.8 * 12.8 {
            px[3] = 255;
        }
    }
    let mut v = complete(&world)[1..].to_vec();
    v.push(crate::format::VcmSet {
        species: VCM_CELL_SPECIES,
        ..set(0, 0, Level::Tree)
    });
    let mut bake = baked(v);
    for (s, t) in world.species.iter().enumerate() {
        let b = t.tree_bounds;
        bake.btf.push(crate::format::BtfImageSet {
            species: s as u32,
            level: Level::Tree,
            encoding: crate::format::ImageEncoding::Rgba8,
            views: 6,
            lights: 6,
            resolution: 32,
            center: (0.5 * (b.min + b.max)).to_array(),
            radius: 0.5 * (b.max - b.min).length(),
            texel_size: 0.1,
            direct: vec![0; 36 * image],
            ambient: ambient.clone(),
        });
    }
    let mut shading = VcmShading::new(&bake, &world).unwrap().unwrap();
    let frames = PerLevel {
        twig: ObjectFrame {
            bounds: b,
            center: Vec3::ZERO,
        },
        branch: ObjectFrame {
            bounds: b,
            center: Vec3::ZERO,
        },
        tree: ObjectFrame {
            bounds: b,
            center: Vec3::ZERO,
        },
    };
    let lit = |shading: &VcmShading, t: usize| -> f32 {
        let m = world.forest.instances[t].transform();
        let s = shading.for_tree(t, sp as usize, &m, &frames).tree();
        s.direct.iter().sum::<f32>() / CORNERS as f32
    };
    // The sun low towards the second tree: the first tree's corners look through it.
    shading.set_sun(Vec3::new(east, 0.15, 0.0).normalize());
    let (a, b2) = (lit(&shading, 0), lit(&shading, 1));
    assert!(a < 0.8, "the tree behind its cell mate: {a}");
    assert!(b2 > 0.99, "the tree in front: {b2}");
    // The sun on the other side: the other way round.
    shading.set_sun(Vec3::new(-east, 0.15, 0.0).normalize());
    let (a, b2) = (lit(&shading, 0), lit(&shading, 1));
    assert!(a > 0.99 && b2 < 0.8, "{a} {b2}");
    // Straight above: at most the one corner of each box that reaches under the
    // other's crown.
    shading.set_sun(Vec3::Y);
    assert!(lit(&shading, 0) >= 0.85 && lit(&shading, 1) >= 0.85);
    // The sky: each hides a share of the other's.
    let sky = |t: usize| shading.tree_sky[t].iter().sum::<f32>() / CORNERS as f32;
    assert!(sky(0) < 0.99 && sky(1) < 0.99, "{} {}", sky(0), sky(1));
}

#[test]
fn no_shading_is_one_everywhere() {
    assert_eq!(Shade::NONE.direct_at(Vec3::splat(0.3)), 1.0);
}
