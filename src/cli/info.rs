//! `canopy info`: a scene's species, triangles per level, trees, terrain and bake
//! estimate; `--map` draws it from above.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context as _;

use super::args::load_scene;
use super::bake::estimate_line;
use crate::model::summary::WorldSummary;

#[derive(clap::Args)]
pub struct InfoArgs {
    scene: Option<PathBuf>,
    #[arg(long)]
    json: bool,
    /// Write a map of the scene from above (terrain, stands, clearings, meadows, every
    /// tree's crown in its species' colour) as a PNG.
    #[arg(long, value_name = "MAP.png")]
    map: Option<PathBuf>,
    /// The map's side in pixels (16..8192).
    #[arg(long, default_value_t = 1024, value_name = "PX")]
    map_size: u32,
}

/// How the trees' own visibility cube maps are laid out and what they weigh.
fn tree_vcm_line(e: &crate::bake::estimate::Estimate, world: &crate::model::World) -> String {
    let per_1000 = if world.forest.instances.is_empty() {
        0.0
    } else {
        e.tree_vcm_bytes as f64 / world.forest.instances.len() as f64 * 1000.0 / 1e6
    };
    let layout = match world.tree_vcm {
        crate::model::TreeVcm::PerTree => format!("{} trees' own cube maps", e.tree_vcm_objects),
        crate::model::TreeVcm::Cells => format!(
            "{} forest cells of {:.1} m",
            e.tree_vcm_objects,
            crate::vcm::cells::ForestCells::side_for(world)
        ),
    };
    format!(
        "tree-level visibility cube maps: {layout}, {:.1} MB ({per_1000:.2} MB per 1,000 trees)",
        e.tree_vcm_bytes as f64 / 1e6
    )
}

/// The impostors the bake makes: frames, frame size, layout and bytes.
fn impostor_line(
    s: &crate::format::BakeSettings,
    e: &crate::bake::estimate::Estimate,
    species: usize,
) -> String {
    if s.impostor_frames == 0 {
        return "octahedral impostors: none (impostor_frames = 0)".into();
    }
    format!(
        "octahedral impostors: {species} ({} x {} frames of {}² pixels, {} layout, {} mip levels), {:.1} MB, about {:.0} s to bake",
        s.impostor_frames,
        s.impostor_frames,
        s.impostor_resolution,
        s.impostor_layout.name(),
        crate::format::impostor_mip_levels(s.impostor_resolution),
        e.impostor_bytes as f64 / 1e6,
        e.impostor_seconds
    )
}

/// The surfel trees the bake makes: their budget and bytes.
fn surfel_line(
    s: &crate::format::BakeSettings,
    e: &crate::bake::estimate::Estimate,
    species: usize,
) -> String {
    if s.surfel_budget == 0 {
        return "surfel trees: none (surfel_budget = 0; the surfel method samples them when it first draws)".into();
    }
    format!(
        "surfel trees: {species} (about {} level-0 surfels each, 12 bytes a surfel), about {:.1} MB ({:.1} MB a species)",
        s.surfel_budget,
        e.surfel_bytes as f64 / 1e6,
        e.surfel_bytes as f64 / 1e6 / species.max(1) as f64
    )
}

pub fn info(args: InfoArgs) -> anyhow::Result<()> {
    let InfoArgs {
        scene,
        json,
        map,
        map_size,
    } = args;
    if !(16..=crate::forest_map::MAX_MAP_SIZE).contains(&map_size) {
        return Err(crate::Error::BadInput(format!(
            "--map-size must be between 16 and {}, found {map_size}",
            crate::forest_map::MAX_MAP_SIZE
        ))
        .into());
    }
    let scene = load_scene(scene.as_deref())?;
    let t0 = Instant::now();
    let world = scene.build_world().map_err(crate::Error::from)?;
    if let Some(path) = &map {
        let img = crate::forest_map::draw(&world, &scene.species, &scene.forest, map_size);
        crate::imageio::save_png(path, &img)?;
        eprintln!("map written to {}", path.display());
    }
    let r = WorldSummary::new(&world, t0.elapsed().as_secs_f64() * 1e3);
    let settings = crate::bake::cache::settings_of(&scene);
    // A bake the format cannot hold is reported here, not refused: `info` only describes.
    let estimate = crate::bake::estimate::estimate(&settings, &world);
    let cache = cached(&scene);
    if json {
        #[derive(serde::Serialize)]
        struct Info<'a> {
            #[serde(flatten)]
            world: &'a WorldSummary,
            bake_estimate: Option<crate::bake::estimate::Estimate>,
            bake_refused: Option<String>,
            impostors: Impostors,
            cache: Option<Cached>,
        }
        #[derive(serde::Serialize)]
        struct Impostors {
            frames: u32,
            resolution: u32,
            layout: &'static str,
            mip_levels: u32,
            bytes: Option<u64>,
        }
        let info = Info {
            world: &r,
            bake_estimate: estimate.as_ref().ok().copied(),
            bake_refused: estimate.as_ref().err().map(|e| e.to_string()),
            impostors: Impostors {
                frames: settings.impostor_frames,
                resolution: settings.impostor_resolution,
                layout: settings.impostor_layout.name(),
                mip_levels: if settings.impostor_frames == 0 {
                    0
                } else {
                    crate::format::impostor_mip_levels(settings.impostor_resolution)
                },
                bytes: estimate.as_ref().ok().map(|e| e.impostor_bytes),
            },
            cache,
        };
        println!("{}", serde_json::to_string(&info).context("encoding JSON")?);
    } else {
        println!(
            "{} trees on a {} m terrain ({}x{} heights), built in {:.0} ms",
            r.trees, r.terrain.size_m, r.terrain.resolution, r.terrain.resolution, r.build_ms
        );
        if let Some(c) = r.terrain.far_forest_cover {
            println!(
                "  past the square, the forest goes on to the horizon as a canopy surface (crowns cover up to {:.0} % of its stands)",
                100.0 * c
            );
        }
        for s in &r.species {
            if let Some(found) = &s.levels_found {
                let levels = if s.levels.len() == 1 {
                    format!(
                        "{} triangles; levels: {found} (drawn whole as geometry where its tree billboard is too coarse)",
                        s.triangles.tree
                    )
                } else {
                    format!(
                        "triangles: twig {}, main branch {}, tree {}; {} main branches, {} twigs; levels: {found}",
                        s.triangles.twig,
                        s.triangles.main_branch,
                        s.triangles.tree,
                        s.main_branches,
                        s.twigs
                    )
                };
                println!(
                    "  {:<10} {} trees; imported, {} materials, {:.1} m tall, crown {:.0} % covered from the side; {levels}",
                    s.name,
                    s.trees,
                    s.materials,
                    s.height_m,
                    100.0 * s.crown_coverage
                );
                continue;
            }
            println!(
                "  {:<10} {} trees; triangles: twig {}, main branch {}, tree {}; {} main branches, {} twigs, {} leaves/needles, {:.1} m tall, crown {:.0} % covered from the side",
                s.name,
                s.trees,
                s.triangles.twig,
                s.triangles.main_branch,
                s.triangles.tree,
                s.main_branches,
                s.twigs,
                s.leaves,
                s.height_m,
                100.0 * s.crown_coverage
            );
        }
        match &estimate {
            Ok(e) => {
                println!("{}", estimate_line(e));
                println!("  {}", tree_vcm_line(e, &world));
                println!("  {}", impostor_line(&settings, e, world.species.len()));
                println!("  {}", surfel_line(&settings, e, world.species.len()));
            }
            Err(e) => println!("bake refused: {e}"),
        }
        if let Some(c) = &cache {
            println!(
                "cached bake: {}, {:.1} MB in the file for {:.1} MB of data",
                c.path,
                c.file_bytes as f64 / 1e6,
                c.data_bytes as f64 / 1e6
            );
            for k in &c.kinds {
                println!(
                    "  {:<14} {:>8.1} MB in the file, {:>8.1} MB of data ({} sections)",
                    k.kind,
                    k.file_bytes as f64 / 1e6,
                    k.data_bytes as f64 / 1e6,
                    k.sections
                );
            }
        }
    }
    Ok(())
}

/// The scene's cached bake as its section table gives it.
#[derive(serde::Serialize)]
struct Cached {
    path: String,
    file_bytes: u64,
    data_bytes: u64,
    /// Per kind of section, in file order.
    kinds: Vec<CachedKind>,
}

/// The sections of one kind in a cached bake.
#[derive(serde::Serialize)]
struct CachedKind {
    kind: &'static str,
    sections: usize,
    file_bytes: u64,
    data_bytes: u64,
}

/// The scene's cached bake, if there is one whose header reads.
fn cached(scene: &crate::scene::Scene) -> Option<Cached> {
    let path = crate::bake::cache::cache_path(scene);
    let sections = crate::format::sections(&path).ok()?;
    let mut kinds: Vec<CachedKind> = Vec::new();
    for s in &sections {
        let name = s.kind.name();
        let k = match kinds.iter().position(|k| k.kind == name) {
            Some(i) => &mut kinds[i],
            None => {
                kinds.push(CachedKind {
                    kind: name,
                    sections: 0,
                    file_bytes: 0,
                    data_bytes: 0,
                });
                kinds.last_mut().expect("pushed")
            }
        };
        k.sections += 1;
        k.file_bytes += s.stored_bytes;
        k.data_bytes += s.data_bytes;
    }
    Some(Cached {
        path: path.display().to_string(),
        file_bytes: std::fs::metadata(&path).map_or(0, |m| m.len()),
        data_bytes: sections.iter().map(|s| s.data_bytes).sum(),
        kinds,
    })
}
