//! The world: everything the model makes from one scene — the terrain, one prototype per
//! species (generated in parallel) and the placed forest.

use std::path::PathBuf;

use rayon::prelude::*;

use super::ModelError;
use super::far_cover::FarCover;
use super::forest::Forest;
use super::gltf::{ImportOptions, import};
use super::params::{ForestParams, SpeciesEntry, TerrainParams, TreeVcm};
use super::species::SpeciesParams;
use super::terrain::Terrain;
use super::tree::TreeModel;

/// Where a species prototype comes from.
enum Source {
    /// Grown from parameters and a seed.
    Grown(SpeciesParams, u64),
    /// Read from a glTF file.
    Gltf(PathBuf, ImportOptions),
}

/// Terrain, species prototypes and tree instances of one scene.
#[derive(Clone, Debug)]
pub struct World {
    /// The heightfield.
    pub terrain: Terrain,
    /// One prototype per scene species, in the scene's order (`TreeInstance::species`
    /// indexes this).
    pub species: Vec<TreeModel>,
    /// The placed trees.
    pub forest: Forest,
    /// How the trees' own visibility cube maps are baked and read (the scene's `[bake]
    /// tree_vcm`).
    pub tree_vcm: TreeVcm,
}

impl World {
    /// Builds the world of a scene's terrain, species entries and forest: the terrain and
    /// the species prototypes in parallel, then the forest on the terrain. Deterministic for
    /// its inputs.
    pub fn build(
        terrain: &TerrainParams,
        species: &[SpeciesEntry],
        forest: &ForestParams,
    ) -> Result<World, ModelError> {
        // One prototype per variant of each entry, in entry order: grown from parameters,
        // or read from a glTF file.
        let mut entries = Vec::new();
        for e in species {
            let files = e.gltf_paths();
            if !files.is_empty() {
                if e.preset.is_some() || e.params.is_some() {
                    return Err(ModelError::AmbiguousSpecies {
                        name: e.name.clone(),
                    });
                }
                let many = files.len() > 1;
                for (v, path) in files.into_iter().enumerate() {
                    let name = if many {
                        format!("{} {}", e.name, v + 1)
                    } else {
                        e.name.clone()
                    };
                    entries.push((
                        e.name.as_str(),
                        name,
                        v as u32,
                        Source::Gltf(path, e.import_options()),
                    ));
                }
                continue;
            }
            for v in 0..e.variants.max(1) {
                let (params, seed) = e.variant(v)?;
                let name = if e.variants > 1 {
                    format!("{} {}", e.name, v + 1)
                } else {
                    e.name.clone()
                };
                entries.push((e.name.as_str(), name, v, Source::Grown(params, seed)));
            }
        }
        let variants: Vec<u32> = species.iter().map(SpeciesEntry::prototypes).collect();
        let (terrain, species) = rayon::join(
            || Terrain::generate(terrain),
            || {
                entries
                    .par_iter()
                    .map(|(entry, name, variant, source)| {
                        let (params, seed) = match source {
                            Source::Grown(params, seed) => (params, *seed),
                            Source::Gltf(path, options) => {
                                let tree =
                                    import(path, *options).map_err(|error| ModelError::Import {
                                        name: (*entry).to_owned(),
                                        error,
                                    })?;
                                for w in &tree.warnings {
                                    log::warn!("species `{entry}` ({}): {w}", path.display());
                                }
                                let mut model = TreeModel::from_imported(name, tree);
                                model.variant = *variant;
                                return Ok(model);
                            }
                        };
                        let mut model = TreeModel::generate(params, seed).map_err(|e| match e {
                            ModelError::InvalidParameter { error, .. } => {
                                ModelError::invalid(format!("species `{entry}`"), error)
                            }
                            other => other,
                        })?;
                        model.name = name.clone();
                        model.variant = *variant;
                        Ok(model)
                    })
                    .collect::<Result<Vec<_>, ModelError>>()
            },
        );
        let mut terrain = terrain?;
        let species = species?;
        let forest = Forest::place_variants(forest, &terrain, &variants)?;
        if terrain.far.is_some() {
            terrain.set_far_cover(FarCover::measure(&terrain, &species, &forest));
        }
        Ok(World {
            terrain,
            species,
            forest,
            tree_vcm: TreeVcm::default(),
        })
    }

    /// A world holding `tree` once, at the origin, unturned, on flat ground `ground` metres
    /// a side: the bake's studio, and the viewer's species gallery.
    pub fn lone(tree: TreeModel, ground: f32) -> World {
        World {
            terrain: Terrain::flat(ground, 2),
            species: vec![tree],
            forest: Forest {
                instances: vec![crate::model::TreeInstance {
                    species: 0,
                    position: glam::Vec3::ZERO,
                    yaw: 0.0,
                    scale: 1.0,
                    tint: glam::Vec3::ONE,
                }],
                stands: None,
            },
            tree_vcm: TreeVcm::default(),
        }
    }

    /// The first variant of prototype `sp`'s scene entry (`sp` itself for a first variant):
    /// an entry's variants follow one another in `species`.
    pub fn first_variant(&self, sp: usize) -> usize {
        self.species
            .get(sp)
            .map_or(sp, |t| sp.saturating_sub(t.variant as usize))
    }

    /// Triangles of the whole scene drawn as full geometry (terrain and every tree).
    pub fn total_triangles(&self) -> u64 {
        let trees: u64 = self
            .forest
            .instances
            .iter()
            .filter_map(|t| self.species.get(t.species as usize))
            .map(|s| s.triangle_counts().tree)
            .sum();
        trees + self.terrain_triangles()
    }

    /// Triangles of the terrain mesh.
    pub fn terrain_triangles(&self) -> u64 {
        let r = u64::from(self.terrain.resolution.max(2)) - 1;
        2 * r * r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn terrain() -> TerrainParams {
        TerrainParams {
            size: 120.0,
            resolution: 33,
            seed: 4,
            relief: 8.0,
            ..TerrainParams::default()
        }
    }

    fn entry(name: &str, preset: &str, seed: u64) -> SpeciesEntry {
        SpeciesEntry::from_preset(name, preset, seed)
    }

    fn forest(count: u32) -> ForestParams {
        ForestParams {
            count: Some(count),
            seed: 3,
            min_spacing: 5.0,
            mix: vec![0.5, 0.5],
            ..ForestParams::default()
        }
    }

    #[test]
    fn builds_every_species_and_tree_deterministically() {
        let species = [entry("fir", "fir", 1), entry("oak", "broadleaf", 2)];
        let build = || match World::build(&terrain(), &species, &forest(40)) {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        let a = build();
        assert_eq!(a.species.len(), 2);
        assert_eq!(a.species[1].name, "oak");
        assert_eq!(a.forest.instances.len(), 40);
        assert!(a.forest.species_histogram(2).iter().all(|&c| c > 0));
        assert!(a.total_triangles() > a.terrain_triangles());
        assert_eq!(a.forest.instances, build().forest.instances);
    }

    #[test]
    fn a_bad_species_entry_is_an_error_not_a_fallback() {
        let mut bad = entry("oak", "oak", 2);
        let species = |bad: &SpeciesEntry| [entry("fir", "fir", 1), bad.clone()];
        let e = World::build(&terrain(), &species(&bad), &forest(10))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("unknown preset `oak`"), "{e}");
        bad.preset = None;
        let e = World::build(&terrain(), &species(&bad), &forest(10))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("exactly one of"), "{e}");
    }

    #[test]
    fn variants_differ_and_repeat_by_seed() {
        let mut fir = entry("fir", "fir", 7);
        fir.variants = 3;
        let build = |e: &SpeciesEntry| match World::build(
            &terrain(),
            std::slice::from_ref(e),
            &ForestParams {
                mix: vec![1.0],
                ..forest(60)
            },
        ) {
            Ok(w) => w,
            Err(err) => panic!("{err}"),
        };
        let a = build(&fir);
        assert_eq!(a.species.len(), 3);
        let names: Vec<&str> = a.species.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["fir 1", "fir 2", "fir 3"]);
        // Variant 1 is the species as given.
        let plain = build(&entry("fir", "fir", 7));
        assert_eq!(
            a.species[0].flatten().vertices,
            plain.species[0].flatten().vertices
        );
        // The others differ in shape, and the trees use all three.
        let heights: Vec<f32> = a.species.iter().map(|s| s.tree_bounds.max.y).collect();
        let tris: Vec<u64> = a.species.iter().map(|s| s.triangle_counts().tree).collect();
        for i in 1..3 {
            assert!(
                (heights[i] - heights[0]).abs() > 0.05 || tris[i] != tris[0],
                "variant {i}: {heights:?} {tris:?}"
            );
        }
        assert!(heights[1] != heights[2] || tris[1] != tris[2]);
        let used = a.forest.species_histogram(3);
        assert!(used.iter().all(|n| *n > 5), "{used:?}");
        // The same seed gives the same variants and placement; another seed others.
        let b = build(&fir);
        assert_eq!(a.forest.instances, b.forest.instances);
        assert_eq!(
            heights,
            b.species
                .iter()
                .map(|s| s.tree_bounds.max.y)
                .collect::<Vec<_>>()
        );
        fir.seed = 8;
        let c = build(&fir);
        assert_ne!(heights[1], c.species[1].tree_bounds.max.y);
    }
}
