//! The bake stage by stage, so that a viewer can draw a forest before it ends and an
//! interrupted bake loses nothing already made. A viewer's bake first makes a first look
//! (each scene entry's first variant's tree level at [`PREVIEW_VIEWS`] views, handed over and
//! never kept); then the tree levels (what draws nearly all of a forest): the first
//! variants' (handed over, a first variant standing in for its siblings), then the other
//! variants' (handed over again); then the finer levels, the visibility cube maps, the
//! texel volumes, the impostors and the surfel trees. After each stage but the last, what is made so far is
//! written beside the cache file (`<key>.partial.canopy`, the same format, neither block-
//! compressed nor deflated, so that keeping it costs the stages little); a bake that finds
//! one for its scene starts from it. The finished bake is the same file
//! whichever way it was made.

use std::path::{Path, PathBuf};

use super::{
    BakeTimes, Progress, Source, StageClock, cache, compress, impostor, surfel, texel, vcm,
};
use crate::format::{BakeSettings, Baked, Packing};
use crate::model::World;
use crate::model::params::TexelParams;
use crate::render::GpuContext;
use crate::{Error, Result};

/// View directions of the preview tree levels (when the scene's tree level has more).
pub const PREVIEW_VIEWS: u32 = 18;

/// A stage of the bake that has just finished.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BakeStage {
    /// The first variants' tree levels at [`PREVIEW_VIEWS`] views, for a viewer to draw
    /// the forest sooner (the bake's settings say so: its `tree_views`); not part of the
    /// bake, never kept.
    Preview,
    /// Every prototype's tree-level images: a forest can be drawn.
    TreeLevels,
    /// Every BTF image set.
    Images,
    /// The visibility cube maps.
    CubeMaps,
    /// The texel volumes.
    Texels,
}

/// What a bake that has handed over its tree levels still makes, for the viewer's panel.
pub const STILL_COMING: &str =
    "the twig and main-branch levels, cube maps, texel volumes, impostors and surfel trees";

/// Where a bake cached at `path` keeps what it has made so far.
pub fn partial_path(path: &Path) -> PathBuf {
    path.with_extension("partial.canopy")
}

/// The whole bake of `world` with `settings`, the texel parameters and the scene's hash,
/// starting from `resume` (a partial bake of the same scene, whose finished parts are kept);
/// `staged` sees the bake after each stage that made something, uncompressed, and first,
/// with `preview`, the first variants' tree levels at [`PREVIEW_VIEWS`] views (when the
/// scene's tree level has more and none were resumed).
#[allow(clippy::too_many_arguments)]
pub fn bake_resumable(
    ctx: &GpuContext,
    world: &World,
    (settings, texel_params, scene_hash): (&BakeSettings, &TexelParams, u64),
    resume: Option<Baked>,
    preview: bool,
    progress: &mut dyn FnMut(&Progress),
    staged: &mut dyn FnMut(BakeStage, &Baked),
) -> Result<(Baked, BakeTimes)> {
    // Refused here, before any work, if the file or this machine cannot hold it.
    super::estimate::check(settings, world)?;
    let total = super::step_count(settings, world);
    let t0 = std::time::Instant::now();
    let mut clock = StageClock::new();
    let mut baked = resume
        .filter(|r| r.scene_hash == scene_hash && r.settings == *settings)
        .unwrap_or_else(|| Baked::empty(scene_hash, *settings));
    let sets_before = baked.btf.len();
    if preview && settings.tree_views > PREVIEW_VIEWS && sets_before == 0 {
        let preview = preview_tree_levels(ctx, world, (settings, scene_hash), &mut |p| {
            clock.step(&p.what);
            progress(&Progress { total, ..p.clone() })
        })?;
        staged(BakeStage::Preview, &preview);
    }
    let resumed = std::mem::take(&mut baked.btf);
    baked.btf = super::bake_btf_sets(
        ctx,
        world,
        settings,
        resumed,
        &mut |p| {
            clock.step(&p.what);
            progress(&Progress { total, ..p.clone() })
        },
        &mut |sets| {
            let so_far = Baked {
                btf: sets.to_vec(),
                ..Baked::empty(scene_hash, *settings)
            };
            staged(BakeStage::TreeLevels, &so_far);
        },
    )?;
    if baked.btf.len() > sets_before {
        staged(BakeStage::Images, &baked);
    }
    let btf_seconds = t0.elapsed().as_secs_f64();
    let images = super::image_count(settings, world);

    let t1 = std::time::Instant::now();
    if baked.vcm.is_empty() && vcm::object_count(world) > 0 {
        baked.vcm = vcm::bake_vcm(
            world,
            &baked.btf,
            settings.vcm_resolution,
            &mut |done, what| {
                clock.step(what);
                progress(&Progress {
                    done: images + done,
                    total,
                    what: what.to_owned(),
                })
            },
        )?;
        staged(BakeStage::CubeMaps, &baked);
    }
    let vcm_seconds = t1.elapsed().as_secs_f64();

    let t2 = std::time::Instant::now();
    let before_texels = images + vcm::object_count(world);
    if baked.texels.is_empty() && settings.texel_resolution > 0 {
        baked.texels = texel::bake_texels(
            ctx,
            world,
            settings.texel_resolution,
            settings.lights,
            settings.supersample,
            texel_params,
            &mut |done, what| {
                clock.step(what);
                progress(&Progress {
                    done: before_texels + done,
                    total,
                    what: what.to_owned(),
                })
            },
        )?;
        staged(BakeStage::Texels, &baked);
    }
    let texel_seconds = t2.elapsed().as_secs_f64();

    let t3 = std::time::Instant::now();
    let before_impostors =
        before_texels + texel::step_count(world, settings.texel_resolution, settings.lights);
    baked.impostors = impostor::bake_impostors(ctx, world, settings, &mut |done, what| {
        clock.step(what);
        progress(&Progress {
            done: before_impostors + done,
            total,
            what: what.to_owned(),
        })
    })?;
    let impostor_seconds = t3.elapsed().as_secs_f64();

    let t4 = std::time::Instant::now();
    let before_surfels = before_impostors + impostor::step_count(settings, world);
    if baked.surfels.is_empty() {
        baked.surfels = surfel::bake_surfels(world, settings, &mut |done, what| {
            clock.step(what);
            progress(&Progress {
                done: before_surfels + done,
                total,
                what: what.to_owned(),
            })
        });
    }
    let surfel_seconds = t4.elapsed().as_secs_f64();
    let compress = if settings.compress {
        compress::compress(&mut baked)
    } else {
        compress::CompressTimes::default()
    };
    let times = BakeTimes {
        seconds: t0.elapsed().as_secs_f64(),
        btf_seconds,
        vcm_seconds,
        texel_seconds,
        impostor_seconds,
        surfel_seconds,
        compress,
        write_seconds: 0.0,
        stages: clock.stages,
    };
    Ok((baked, times))
}

/// The tree levels of each scene entry's first variant at [`PREVIEW_VIEWS`] views, as a bake
/// of its own (its `tree_views` saying so). Its progress does not count towards the bake's.
fn preview_tree_levels(
    ctx: &GpuContext,
    world: &World,
    (settings, scene_hash): (&BakeSettings, u64),
    progress: &mut dyn FnMut(&Progress),
) -> Result<Baked> {
    let views = super::directions(PREVIEW_VIEWS)?;
    let lights = super::directions(settings.lights)?;
    let preview_settings = BakeSettings {
        tree_views: PREVIEW_VIEWS,
        ..*settings
    };
    let mut done = 0u64;
    let mut btf = Vec::new();
    for (s, tree) in world.species.iter().enumerate() {
        if tree.variant != 0 {
            continue;
        }
        btf.push(super::bake_btf_set(
            ctx,
            (s, tree, crate::model::Level::Tree),
            (&views, &lights),
            &preview_settings,
            (&mut done, 0),
            &mut |p| {
                progress(&Progress {
                    done: 0,
                    total: p.total,
                    what: format!("{} (a first look)", p.what),
                })
            },
        )?);
    }
    Ok(Baked {
        btf,
        ..Baked::empty(scene_hash, preview_settings)
    })
}

/// Whether `baked` can draw `world`'s forest: every prototype has its tree level, or its
/// scene entry's first variant has (which stands in for it).
pub fn drawable(baked: &Baked, world: &World) -> bool {
    let has = |sp: usize| {
        baked
            .btf
            .iter()
            .any(|s| s.species as usize == sp && s.level == crate::model::Level::Tree)
    };
    (0..world.species.len()).all(|sp| has(sp) || has(world.first_variant(sp)))
}

/// [`super::load_or_bake_at`] for a viewer: a bake made now hands its tree levels to
/// `early` as soon as they are made (or at once, when a partial bake of the scene is found
/// beside the cache and holds them), and keeps what it makes beside the cache until it is
/// done, so that an interrupted bake starts again from there.
pub fn load_or_bake_progressive(
    path: &Path,
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    world: &World,
    progress: &mut dyn FnMut(&Progress),
    early: Option<&mut dyn FnMut(&Baked)>,
) -> Result<(Baked, Source)> {
    let mut no_one = |_: &Baked| {};
    let preview = early.is_some();
    let early = early.unwrap_or(&mut no_one);
    let mut replaced = None;
    match cache::load(path, scene) {
        Some(Ok(b)) => return Ok((b, Source::Cache)),
        Some(Err(e)) => {
            log::warn!(
                "re-baking: the cached bake {} cannot be used: {e}",
                path.display()
            );
            replaced = Some(e.to_string());
        }
        None => {}
    }
    let hash = cache::scene_hash(scene);
    let partial = partial_path(path);
    let resume = if partial.exists() {
        match crate::format::read_expecting(&partial, hash) {
            Ok(b) => {
                log::info!(
                    "resuming the bake from {} ({} image sets, {} cube map sets, {} texel volumes)",
                    partial.display(),
                    b.btf.len(),
                    b.vcm.len(),
                    b.texels.len()
                );
                Some(b)
            }
            Err(e) => {
                log::warn!(
                    "the partial bake {} cannot be used ({e}); baking from the start",
                    partial.display()
                );
                None
            }
        }
    } else {
        None
    };
    let settings = cache::settings_of(scene);
    if let Some(r) = resume.as_ref().filter(|r| r.settings == settings)
        && drawable(r, world)
    {
        early(r);
    }
    let mut write_failed = false;
    let (baked, _) = bake_resumable(
        ctx,
        world,
        (&settings, &scene.texel, hash),
        resume,
        preview,
        progress,
        &mut |stage, so_far| {
            if matches!(stage, BakeStage::Preview | BakeStage::TreeLevels) {
                early(so_far);
            }
            if stage == BakeStage::Preview {
                return;
            }
            if !write_failed && let Err(e) = store(&partial, so_far, Packing::Plain) {
                // The bake goes on; an interruption then costs what was made.
                log::warn!(
                    "could not keep the partial bake at {}: {e}",
                    partial.display()
                );
                write_failed = true;
            }
        },
    )?;
    // A cache that cannot be written costs a re-bake next time, not this run.
    let not_cached = store(path, &baked, Packing::Deflate).err().map(|e| {
        log::warn!("could not cache the bake at {}: {e}", path.display());
        e.to_string()
    });
    if not_cached.is_none() {
        let _ = std::fs::remove_file(&partial);
    }
    Ok((
        baked,
        Source::Baked {
            replaced,
            not_cached,
        },
    ))
}

/// Writes `baked` to `path` atomically, creating its folder first, its sections packed as
/// asked.
pub(super) fn store(path: &Path, baked: &Baked, packing: Packing) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    crate::format::write_atomic_packed(path, baked, packing)?;
    Ok(())
}
