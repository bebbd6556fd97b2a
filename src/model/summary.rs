//! A world in numbers, as `canopy info` prints it: the trees, the terrain and, per species,
//! the triangles of each level and the parts of one tree.

use rayon::prelude::*;
use serde::Serialize;

use super::World;
use super::silhouette::crown_coverage;

/// What a world holds.
#[derive(Clone, Debug, Serialize)]
pub struct WorldSummary {
    /// Placed trees.
    pub trees: usize,
    pub terrain: TerrainSummary,
    /// One per species, in the scene's order.
    pub species: Vec<SpeciesSummary>,
    /// How long building the world took (ms).
    pub build_ms: f64,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct TerrainSummary {
    /// Side length.
    pub size_m: f32,
    /// Heights per side.
    pub resolution: u32,
    /// Past the square, on the horizon ring (`[terrain] horizon`): the crown cover of the
    /// canopy surface that stands for the forest there, in its densest height band (0..1);
    /// `None` without a ring or without trees.
    pub far_forest_cover: Option<f32>,
}

#[derive(Clone, Debug, Serialize)]
pub struct SpeciesSummary {
    pub name: String,
    /// Placed trees of this species (by name).
    pub trees: usize,
    /// Triangles per level, each level with its children.
    pub triangles: LevelTriangles,
    pub main_branches: u64,
    /// Twigs in one tree.
    pub twigs: u64,
    /// Leaves or needles in one tree.
    pub leaves: u64,
    /// Height of the prototype's bounding box.
    pub height_m: f32,
    /// Side-view crown coverage: the share of the crown's silhouette hull its triangles
    /// cover, the mean of four azimuths ([`super::silhouette`]).
    pub crown_coverage: f32,
    /// The levels the species has: `twig`, `main branch`, `tree` for a grown one and for an
    /// imported one whose file gives them; `tree` alone otherwise.
    pub levels: Vec<&'static str>,
    /// An imported tree's levels: where its file gives them, or why it has the tree level
    /// only. `None` for a grown species.
    pub levels_found: Option<String>,
    /// Materials of an imported tree (0 for a grown one: vertex colours).
    pub materials: usize,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct LevelTriangles {
    pub twig: u64,
    pub main_branch: u64,
    pub tree: u64,
}

impl WorldSummary {
    /// The summary of `world`, which took `build_ms` to build.
    pub fn new(world: &World, build_ms: f64) -> Self {
        let species = world
            .species
            .par_iter()
            .map(|t| {
                let tri = t.triangle_counts();
                let parts = t.counts();
                let trees = world
                    .forest
                    .instances
                    .iter()
                    .filter(|i| {
                        world
                            .species
                            .get(i.species as usize)
                            .is_some_and(|s| s.name == t.name)
                    })
                    .count();
                SpeciesSummary {
                    name: t.name.clone(),
                    trees,
                    triangles: LevelTriangles {
                        twig: tri.twig,
                        main_branch: tri.branch,
                        tree: tri.tree,
                    },
                    main_branches: parts.main_branches,
                    twigs: parts.twigs,
                    leaves: parts.foliage,
                    height_m: t.tree_bounds.max.y - t.tree_bounds.min.y,
                    crown_coverage: crown_coverage(t).mean,
                    levels: if t.has_hierarchy() {
                        super::Level::ALL.iter().map(|l| l.name()).collect()
                    } else {
                        vec![super::Level::Tree.name()]
                    },
                    materials: t.surfaces.as_ref().map_or(0, |s| s.materials.len()),
                    levels_found: t.levels_note.clone(),
                }
            })
            .collect();
        Self {
            trees: world.forest.instances.len(),
            terrain: TerrainSummary {
                size_m: world.terrain.size,
                resolution: world.terrain.resolution,
                far_forest_cover: world.terrain.far_cover().map(|c| c.max_cover()),
            },
            species,
            build_ms,
        }
    }
}
