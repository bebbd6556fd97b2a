//! The bake: photographs every level of every species (twig, main branch, tree) from each
//! sampled view direction, lit by each sampled light direction (sun only, self-shadowed) and
//! by the sky alone (its own leaves hiding part of the sky, as in the reference), with the
//! same render core as the ground truth, offscreen and
//! supersampled so that alpha is coverage. Views and lights are in the object's own frame,
//! so one bake serves every rotated, scaled instance. Then the visibility cube maps of every
//! object of every level (`vcm`), drawn from the BTF images' alpha, each species' texel
//! volumes (`texel`), photographed slab by slab, and each species' octahedral impostor
//! (`impostor`, its frames' image work in `atlas`).

pub mod atlas;
pub mod cache;
pub mod compress;
pub mod estimate;
pub mod impostor;
pub mod report;
pub mod sky_cache;
pub mod stages;
pub mod surfel;
pub mod texel;
pub mod vcm;

use glam::{Mat4, Vec3};

use crate::format::{BakeSettings, Baked, BtfImageSet};
use crate::model::Level;
use crate::model::World;
use crate::model::mesh::{Aabb, Mesh};
use crate::model::tree::TreeModel;
use crate::render::sky_visibility::SKY_DIRECTIONS;
use crate::render::{
    Camera, FrameDesc, GpuContext, Method, Reference, Renderer, ShadowSettings, Sky, Stage, Sun,
};
use crate::sphere::{DirectionSet, billboard_axes};
use crate::{Error, Result};

/// One level of a species as an object of its own, in the level's frame: the twig alone;
/// a main branch (limb + its twigs); or the whole tree.
pub fn level_object(tree: &TreeModel, level: Level) -> TreeModel {
    let mut o = tree.clone();
    match level {
        Level::Twig => {
            o.trunk = Mesh::default();
            o.branch_limb = Mesh::default();
            o.tree_branches.clear();
            o.branch_twigs.clear();
            o.tree_twigs = vec![Mat4::IDENTITY];
            o.tree_bounds = tree.twig_bounds;
        }
        Level::Branch => {
            o.trunk = tree.branch_limb.clone();
            o.branch_limb = Mesh::default();
            o.tree_branches.clear();
            o.branch_twigs.clear();
            o.tree_twigs = tree.branch_twigs.clone();
            o.tree_bounds = tree.branch_bounds;
        }
        Level::Tree => {}
    }
    // An imported tree's materials follow its parts: at the twig level the trunk is empty
    // (the twig is the level's one twig), at the main-branch level it is the limb.
    if let Some(surf) = &tree.surfaces {
        let mut level_surfaces = (**surf).clone();
        match level {
            Level::Twig => level_surfaces.trunk.clear(),
            Level::Branch => level_surfaces.trunk = surf.limb.clone(),
            Level::Tree => {}
        }
        if level != Level::Tree {
            level_surfaces.limb.clear();
        }
        o.surfaces = Some(std::sync::Arc::new(level_surfaces));
    }
    o
}

/// The bounding sphere (centre, radius) of a box: the billboard's frame.
pub fn bounding_sphere(b: &Aabb) -> (Vec3, f32) {
    (b.center(), (0.5 * b.extent().length()).max(1e-3))
}

/// A world holding just `object`, once, at the origin.
fn studio_world(object: TreeModel) -> World {
    World::lone(object, 1.0)
}

/// What a bake step reports to a progress bar (defined beside the bars that show it).
pub use crate::progress::Progress;

/// The levels the bake makes images of for `tree`: all three, or the tree level alone for
/// an imported tree whose file gives no finer levels (drawn as geometry where its tree
/// level is too coarse).
pub fn baked_levels(tree: &TreeModel) -> &'static [Level] {
    if tree.has_hierarchy() {
        &Level::ALL
    } else {
        &[Level::Tree]
    }
}

/// Number of images the bake renders for `world`'s species.
pub fn image_count(settings: &BakeSettings, world: &World) -> u64 {
    let per_view = u64::from(settings.lights) + u64::from(crate::format::AMBIENT_IMAGES_PER_VIEW);
    let views: u64 = world
        .species
        .iter()
        .flat_map(|t| baked_levels(t).iter())
        .map(|&l| u64::from(settings.views_of(l)))
        .sum();
    per_view * views
}

/// Steps of a whole bake of `world` (what [`Progress::total`] counts): one per BTF image and
/// one per object whose 8 cube maps are baked.
pub fn step_count(settings: &BakeSettings, world: &World) -> u64 {
    image_count(settings, world)
        + vcm::object_count(world)
        + texel::step_count(world, settings.texel_resolution, settings.lights)
        + impostor::step_count(settings, world)
        + surfel::step_count(settings, world)
}

/// How long a bake and each of its parts took.
#[derive(Clone, Debug, Default)]
pub struct BakeTimes {
    /// The whole bake.
    pub seconds: f64,
    pub btf_seconds: f64,
    pub vcm_seconds: f64,
    pub texel_seconds: f64,
    pub impostor_seconds: f64,
    pub surfel_seconds: f64,
    /// The block compression of the images and cube maps (0 when `[bake] compress` is off).
    pub compress: compress::CompressTimes,
    /// Writing the file, its sections deflated (0 until it is written).
    pub write_seconds: f64,
    /// Seconds per stage, named as the progress names them (`fir 1 tree`, `fir 1 VCMs`,
    /// `tree VCMs`, `fir 1 texel volume`, `fir 1 impostor`), in the order they ran.
    pub stages: Vec<(String, f64)>,
}

impl BakeTimes {
    /// Seconds of the stage named `what` (0 if it did not run).
    pub fn stage(&self, what: &str) -> f64 {
        self.stages
            .iter()
            .filter(|(w, _)| w == what)
            .map(|(_, s)| s)
            .sum()
    }
}

/// Times each stage from the progress calls: the time since the previous call goes to the
/// step the call reports, and so to its stage.
struct StageClock {
    last: std::time::Instant,
    stages: Vec<(String, f64)>,
}

impl StageClock {
    fn new() -> Self {
        StageClock {
            last: std::time::Instant::now(),
            stages: Vec::new(),
        }
    }

    fn step(&mut self, what: &str) {
        let now = std::time::Instant::now();
        let dt = (now - self.last).as_secs_f64();
        self.last = now;
        match self.stages.last_mut() {
            Some((w, s)) if w == what => *s += dt,
            _ => self.stages.push((what.to_owned(), dt)),
        }
    }
}

/// The whole bake of `world`: the BTF image sets, the visibility cube maps, the texel
/// volumes and the impostors.
pub fn bake(
    ctx: &GpuContext,
    world: &World,
    settings: &BakeSettings,
    texel_params: &crate::model::params::TexelParams,
    scene_hash: u64,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Baked, BakeTimes)> {
    stages::bake_resumable(
        ctx,
        world,
        (settings, texel_params, scene_hash),
        None,
        false,
        progress,
        &mut |_, _| {},
    )
}

/// Bakes the BTF image sets of every species and level of `world`.
pub fn bake_btf(
    ctx: &GpuContext,
    world: &World,
    settings: &BakeSettings,
    scene_hash: u64,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Baked> {
    let btf = bake_btf_sets(ctx, world, settings, Vec::new(), progress, &mut |_| {})?;
    Ok(Baked {
        btf,
        ..Baked::empty(scene_hash, *settings)
    })
}

/// Bakes the BTF image sets of `world`: the tree levels first, of each scene entry's first
/// variant, then of the other variants (after each of the two, `tree_levels` sees the sets
/// made so far: what a viewer can draw a forest with, a variant standing in for its
/// siblings until they come), then the finer levels. The sets in `done_sets` are kept, not
/// baked again. The sets come out species by species, each species' levels in
/// [`Level::ALL`] order, whatever order they were made in.
pub fn bake_btf_sets(
    ctx: &GpuContext,
    world: &World,
    settings: &BakeSettings,
    done_sets: Vec<BtfImageSet>,
    progress: &mut dyn FnMut(&Progress),
    tree_levels: &mut dyn FnMut(&[BtfImageSet]),
) -> Result<Vec<BtfImageSet>> {
    let view_sets = crate::model::PerLevel::try_from_fn(|l| directions(settings.views_of(l)))?;
    let lights = directions(settings.lights)?;
    let total = image_count(settings, world);
    let per_view = u64::from(settings.lights) + u64::from(crate::format::AMBIENT_IMAGES_PER_VIEW);
    let mut btf: Vec<BtfImageSet> = done_sets
        .into_iter()
        .filter(|set| {
            (set.species as usize) < world.species.len()
                && set.views == settings.views_of(set.level)
                && set.lights == settings.lights
                && set.resolution == settings.resolution
        })
        .collect();
    let mut done: u64 = btf.iter().map(|set| u64::from(set.views) * per_view).sum();
    // (level, whether the batch is the first variants' or the others'), in the order made.
    let batches = [
        (Level::Tree, Some(true)),
        (Level::Tree, Some(false)),
        (Level::Branch, None),
        (Level::Twig, None),
    ];
    for (level, first_variants) in batches {
        let mut made_any = false;
        for (s, tree) in world.species.iter().enumerate() {
            let made = btf
                .iter()
                .any(|set| set.species == s as u32 && set.level == level);
            let in_batch = first_variants.is_none_or(|first| (tree.variant == 0) == first);
            if made || !in_batch || !baked_levels(tree).contains(&level) {
                continue;
            }
            btf.push(bake_btf_set(
                ctx,
                (s, tree, level),
                (&view_sets[level], &lights),
                settings,
                (&mut done, total),
                progress,
            )?);
            made_any = true;
        }
        if level == Level::Tree && made_any {
            tree_levels(&btf);
        }
    }
    btf.sort_by_key(|set| (set.species, Level::ALL.iter().position(|&l| l == set.level)));
    Ok(btf)
}

/// The sampled direction set of `count` directions (one of the format's counts).
fn directions(count: u32) -> Result<DirectionSet> {
    DirectionSet::with_count(count as usize).map_err(|e| Error::BadInput(e.to_string()))
}

/// Bakes the image set of `level` of species `s` (`tree`), counting its images into
/// `done` out of `total`.
fn bake_btf_set(
    ctx: &GpuContext,
    (s, tree, level): (usize, &TreeModel, Level),
    (views, lights): (&DirectionSet, &DirectionSet),
    settings: &BakeSettings,
    (done, total): (&mut u64, u64),
    progress: &mut dyn FnMut(&Progress),
) -> Result<BtfImageSet> {
    let object = level_object(tree, level);
    let (center, radius) = bounding_sphere(&object.tree_bounds);
    let studio = studio_world(object);
    let mut renderer = Renderer::new(ctx, &studio)?;
    // The images are reference frames of the object alone: its own leaves hide
    // part of the sky from its inner leaves, as in the world's reference.
    renderer.prepare_reference(ctx, &studio, SKY_DIRECTIONS, false)?;
    let res = settings.resolution;
    let shadow_map = studio_shadow_map(res * settings.supersample);
    let image_bytes = (res * res * 4) as usize;
    let cameras: Vec<Camera> = views
        .directions()
        .iter()
        .map(|&v| {
            let (_, up) = billboard_axes(v);
            Camera::orthographic(center + v * (2.0 * radius), -v, up, radius)
        })
        .collect();
    // The frames light by light, each through every view: a light's shadow map is
    // the same from every view, and the renderer draws it once for them all. The
    // images are stored view-major: the direct image (v, l) at v * lights + l.
    let shots = studio_shots(lights);
    let (suns, ambient_shots) = shots.split_at(lights.len());
    let mut direct = vec![0u8; views.len() * lights.len() * image_bytes];
    for (l, &(sun, sky)) in suns.iter().enumerate() {
        for (v, &camera) in cameras.iter().enumerate() {
            let frame = studio_frame(camera, sun, sky, shadow_map);
            let (img, _) = renderer.render_image(ctx, &frame, res, res, settings.supersample)?;
            let at = (v * lights.len() + l) * image_bytes;
            let wrong_size = || Error::Gpu(format!("image ({v}, {l}) came back the wrong size"));
            let src = img.as_raw().get(..image_bytes).ok_or_else(wrong_size)?;
            direct
                .get_mut(at..at + image_bytes)
                .ok_or_else(wrong_size)?
                .copy_from_slice(src);
            *done += 1;
            progress(&Progress {
                done: *done,
                total,
                what: format!("{} {}", tree.name, level.name()),
            });
        }
    }
    // Each view's sky-lit image (the sky alone), then its ground-lit one (the light
    // the ground sends up, which the renderer's hemispherical ambient adds to the
    // sky's).
    let mut ambient = Vec::with_capacity(2 * views.len() * image_bytes);
    let mut ground = Vec::with_capacity(views.len() * image_bytes);
    for &camera in &cameras {
        let frames = ambient_shots
            .iter()
            .map(|&(sun, sky)| studio_frame(camera, sun, sky, shadow_map))
            .chain(std::iter::once(studio_ground_frame(camera, shadow_map)));
        for (k, frame) in frames.enumerate() {
            let (img, _) = renderer.render_image(ctx, &frame, res, res, settings.supersample)?;
            let dest = if k < ambient_shots.len() {
                &mut ambient
            } else {
                &mut ground
            };
            dest.extend_from_slice(img.as_raw());
            *done += 1;
            progress(&Progress {
                done: *done,
                total,
                what: format!("{} {}", tree.name, level.name()),
            });
        }
    }
    // Each view's sky-lit image, then each view's ground-lit image.
    ambient.extend_from_slice(&ground);
    Ok(BtfImageSet {
        encoding: crate::format::ImageEncoding::Rgba8,
        species: s as u32,
        level,
        views: views.len() as u32,
        lights: settings.lights,
        resolution: res,
        center: center.to_array(),
        radius,
        texel_size: 2.0 * radius / res as f32,
        direct,
        ambient,
    })
}

/// The lighting of one set of studio pictures: the sun alone from each of `lights` (white,
/// intensity 1, no sky), then the sky alone (sky intensity 1, no sun): (sun, sky).
fn studio_shots(lights: &DirectionSet) -> Vec<(Sun, f32)> {
    lights
        .directions()
        .iter()
        .map(|&l| (Sun::from_direction(l, Vec3::ONE, 1.0), 0.0))
        .chain(std::iter::once((
            Sun::from_direction(Vec3::Y, Vec3::ZERO, 0.0),
            1.0,
        )))
        .collect()
}

/// A studio frame: the object alone, lit by the sun only (`sky` = 0) or the sky only.
/// Side of the studio's shadow map for images of `pixels` a side: twice that, and at least
/// the reference's own map of a tree (`Reference::self_map_size`), so that an object at the
/// tree level shades itself in the bake as finely as each tree does in the reference (the
/// average light between needles depends on it even where the image cannot resolve them).
pub(crate) fn studio_shadow_map(pixels: u32) -> u32 {
    (2 * pixels)
        .max(crate::render::self_shadow::SELF_MAP_SIZE)
        .clamp(256, 2048)
}

fn studio_frame(camera: Camera, sun: Sun, sky: f32, shadow_map: u32) -> FrameDesc {
    FrameDesc {
        camera,
        sun,
        sky: Sky {
            color: Vec3::ONE,
            ground_color: Vec3::ZERO,
            intensity: sky,
        },
        method: Method::Geometry,
        shadows: ShadowSettings {
            enabled: sky == 0.0,
            map_size: shadow_map,
            distance: 0.0,
        },
        fog_density: 0.0,
        exposure: 1.0,
        stage: Stage::Studio,
        btf: Default::default(),
        texel: Default::default(),
        impostor: Default::default(),
        surfel: Default::default(),
        trees: true,
        ground_shadows: false,
        ground_sky: false,
        terrain_px: 0.0,
        sun_held: false,
        reference: Some(Reference::default()),
        render_scale: Default::default(),
        pixel_classes: false,
        overdraw: None,
        studio_output: Default::default(),
    }
}

/// A studio frame lit by the ground alone: no sun, a black sky, a white ground (the
/// ambient's lower half, which the renderer never hides).
fn studio_ground_frame(camera: Camera, shadow_map: u32) -> FrameDesc {
    let mut frame = studio_frame(
        camera,
        Sun::from_direction(Vec3::Y, Vec3::ZERO, 0.0),
        1.0,
        shadow_map,
    );
    frame.sky = Sky {
        color: Vec3::ZERO,
        ground_color: Vec3::ONE,
        intensity: 1.0,
    };
    frame
}

/// Where a bake came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    /// Read from the cache file.
    Cache,
    /// Baked now (and written to the cache); the reason the cache was not used, if it
    /// existed, and why the new bake could not be written to it, if it could not (a
    /// read-only or full cache folder: the bake is used from memory, and baked again next
    /// time).
    Baked {
        replaced: Option<String>,
        not_cached: Option<String>,
    },
}

/// The scene's bake from the cache, or baked now and cached (atomically: an interrupted
/// bake leaves no half file). `progress` sees every image.
pub fn load_or_bake(
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    world: &World,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Baked, Source)> {
    load_or_bake_at(&cache::cache_path(scene), ctx, scene, world, progress)
}

/// A baked file the user named (`--baked`): read and checked against `scene`, never baked
/// again. Any problem (missing, unreadable, corrupt, truncated, another version, another
/// scene or other bake settings) is bad input with its specific reason.
pub fn open_baked(path: &std::path::Path, scene: &crate::scene::Scene) -> Result<Baked> {
    crate::format::read_expecting(path, cache::scene_hash(scene)).map_err(|e| {
        let hint = match e {
            crate::format::FormatError::SceneMismatch { .. } => {
                " (pass the scene file it was baked from, or bake this scene with `canopy bake SCENE --out FILE`)"
            }
            _ => "",
        };
        Error::BadInput(format!(
            "cannot use the baked file {}: {e}{hint}",
            path.display()
        ))
    })
}

/// [`load_or_bake`] with the cache file at `path` (a partial bake beside it is resumed:
/// [`stages::load_or_bake_progressive`]).
pub fn load_or_bake_at(
    path: &std::path::Path,
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    world: &World,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Baked, Source)> {
    stages::load_or_bake_progressive(path, ctx, scene, world, progress, None)
}

/// Bakes `scene` now, whatever the cache holds, and writes it to `path` as
/// [`load_or_bake_at`] writes the cache (atomically, its folder created first), except that
/// a file that cannot be written is an error here.
pub fn bake_to(
    path: &std::path::Path,
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    world: &World,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Baked, BakeTimes)> {
    let (baked, mut times) = bake_scene(ctx, scene, world, progress)?;
    let t0 = std::time::Instant::now();
    store(path, &baked, crate::format::Packing::Deflate)?;
    times.write_seconds = t0.elapsed().as_secs_f64();
    Ok((baked, times))
}

/// Bakes `scene` (its `world` built) with the scene's settings, stamped with its hash.
fn bake_scene(
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    world: &World,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Baked, BakeTimes)> {
    bake(
        ctx,
        world,
        &cache::settings_of(scene),
        &scene.texel,
        cache::scene_hash(scene),
        progress,
    )
}

use stages::store;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_objects_hold_the_parts_of_their_level() {
        let p = crate::model::species::preset("fir").unwrap();
        let tree = TreeModel::generate(&p, 1).unwrap();
        let twig = level_object(&tree, Level::Twig);
        assert_eq!(twig.twigs_in_tree_frame().len(), 1);
        assert!(twig.trunk.indices.is_empty());
        let branch = level_object(&tree, Level::Branch);
        assert_eq!(branch.twigs_in_tree_frame().len(), tree.branch_twigs.len());
        assert_eq!(branch.trunk.indices, tree.branch_limb.indices);
        let whole = level_object(&tree, Level::Tree);
        assert_eq!(
            whole.twigs_in_tree_frame().len(),
            tree.twigs_in_tree_frame().len()
        );
    }
}
