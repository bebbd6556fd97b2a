//! The world: everything the model makes from one scene — the terrain, one prototype per
//! species (generated in parallel) and the placed forest.

use rayon::prelude::*;

use super::ModelError;
use super::forest::Forest;
use super::terrain::Terrain;
use super::tree::TreeModel;
use crate::scene::Scene;

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
    /// Builds the world of `scene`: the terrain and the species prototypes in parallel, then
    /// the forest on the terrain. Deterministic for the scene.
    pub fn build(scene: &Scene) -> Result<World, ModelError> {
        let entries = scene
            .species
            .iter()
            .map(|e| Ok((e.name.as_str(), e.try_params()?, e.seed)))
            .collect::<Result<Vec<_>, ModelError>>()?;
        let (terrain, species) = rayon::join(
            || Terrain::generate(&scene.terrain),
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
        let forest = Forest::place(&scene.forest, &terrain, species.len())?;
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

    fn small() -> Scene {
        match Scene::parse(crate::scene::SMALL_TEST_SCENE_TOML, "small.toml") {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn small_scene_builds() {
        let scene = small();
        let w = match World::build(&scene) {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(w.species.len(), scene.species.len());
        assert_eq!(w.forest.instances.len(), scene.forest.count as usize);
        assert_eq!(w.species[0].name, scene.species[0].name);
        let hist = w.forest.species_histogram(w.species.len());
        assert!(
            hist.iter().all(|&c| c > 0),
            "both species present: {hist:?}"
        );
        assert!(w.total_triangles() > w.terrain_triangles());
        // The camera sees the trees: the look-at point is near the forest's centre and the
        // camera is above the ground.
        let cam = glam::Vec3::from(scene.camera.position);
        assert!(cam.y > w.terrain.height_at(cam.x, cam.z) + 2.0);
    }

    #[test]
    fn default_scene_builds_deterministically() {
        let scene = Scene::default_scene();
        let start = std::time::Instant::now();
        let a = match World::build(&scene) {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        eprintln!("default world built in {:.2?}", start.elapsed());
        assert_eq!(a.forest.instances.len(), 1000);
        let b = World::build(&scene)
            .map(|w| w.forest.instances)
            .unwrap_or_default();
        assert_eq!(a.forest.instances, b);
        let hist = a.forest.species_histogram(a.species.len());
        eprintln!("species histogram {hist:?}");
        for s in &a.species {
            eprintln!(
                "{}: {:?} {:?} bounds {:?}",
                s.name,
                s.triangle_counts(),
                s.counts(),
                s.tree_bounds
            );
        }
        // Trees cover the whole terrain.
        let half = 0.5 * a.terrain.size;
        let xs: Vec<f32> = a.forest.instances.iter().map(|t| t.position.x).collect();
        let (lo, hi) = xs
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &x| (l.min(x), h.max(x)));
        assert!(lo < -0.8 * half && hi > 0.8 * half, "{lo}..{hi}");
        // The start camera stands above the terrain.
        let cam = glam::Vec3::from(scene.camera.position);
        let ground = a.terrain.height_at(cam.x, cam.z);
        eprintln!("camera {cam} ground {ground}");
        assert!(cam.y > ground + 10.0);
    }

    #[test]
    fn unknown_preset_is_reported() {
        let mut scene = small();
        scene.species[0].preset = Some("oak".into());
        scene.species[0].params = None;
        let e = World::build(&scene)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("oak"), "{e}");
    }
}
