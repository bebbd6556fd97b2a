//! The world: everything the model makes from one scene — the terrain, one prototype per
//! species (generated in parallel) and the placed forest.

use rayon::prelude::*;

use super::ModelError;
use super::forest::Forest;
use super::params::{ForestParams, SpeciesEntry, TerrainParams};
use super::terrain::Terrain;
use super::tree::TreeModel;

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
        let entries = species
            .iter()
            .map(|e| Ok((e.name.as_str(), e.try_params()?, e.seed)))
            .collect::<Result<Vec<_>, ModelError>>()?;
        let (terrain, species) = rayon::join(
            || Terrain::generate(terrain),
            || {
                entries
                    .par_iter()
                    .map(|(name, params, seed)| {
                        let mut model =
                            TreeModel::generate(params, *seed).map_err(|e| match e {
                                ModelError::InvalidParameter { error, .. } => {
                                    ModelError::invalid(format!("species `{name}`"), error)
                                }
                                other => other,
                            })?;
                        model.name = (*name).to_owned();
                        Ok(model)
                    })
                    .collect::<Result<Vec<_>, ModelError>>()
            },
        );
        let terrain = terrain?;
        let species = species?;
        let forest = Forest::place(forest, &terrain, species.len())?;
        Ok(World {
            terrain,
            species,
            forest,
        })
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
        SpeciesEntry {
            name: name.into(),
            preset: Some(preset.into()),
            params: None,
            seed,
        }
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
}
