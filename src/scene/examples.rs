//! The scenes embedded in the binary: the default scene of the commands, the example
//! forest the viewer opens, and the scene menu's list.

use super::{Scene, SceneError};

/// The embedded default scene (1,000 trees on 1 km² of hills): the scene of every command
/// but the viewer, of the bench and of the tests; it documents the format.
pub const DEFAULT_SCENE_TOML: &str = include_str!("../../assets/default.toml");

/// The embedded example forest at real density (`assets/scenes/forest.toml`): what the
/// viewer opens when given no scene.
pub const FOREST_SCENE_TOML: &str = include_str!("../../assets/scenes/forest.toml");

/// One stand of the example forest, 250 m a side (`assets/scenes/stand.toml`).
pub const STAND_SCENE_TOML: &str = include_str!("../../assets/scenes/stand.toml");

/// Pine_5 (a glTF tree, Quaternius, CC0) among the fir and pine presets
/// (`assets/scenes/pines.toml`); its tree is embedded too ([`crate::model::gltf::embedded`]).
pub const PINES_SCENE_TOML: &str = include_str!("../../assets/scenes/pines.toml");

/// The example scenes embedded in the binary (the viewer's scene menu): name, a line on
/// what it is, and the scene file's text.
pub const EXAMPLE_SCENES: &[(&str, &str, &str)] = &[
    (
        "forest",
        "a forest at 600 trees per hectare: stands, clearings, meadows, about 36,000 trees (the viewer's default; a bake of about 5 minutes)",
        FOREST_SCENE_TOML,
    ),
    (
        "default",
        "1,000 trees spread over 1 km² of hills (the bench's and the tests' scene; a bake of about a minute)",
        DEFAULT_SCENE_TOML,
    ),
    (
        "stand",
        "one stand of that forest, 250 m a side at the same density: about 1,800 trees (a bake of minutes)",
        STAND_SCENE_TOML,
    ),
    (
        "pines",
        "a glTF tree among the presets: Pine_5 by Quaternius (CC0, assets/trees/pine5/SOURCE.md) with the fir and pine presets, about 300 trees (a bake of about 5 minutes)",
        PINES_SCENE_TOML,
    ),
];

/// The small test scene (used by tests; about 30 trees on 100 m).
#[cfg(test)]
pub const SMALL_TEST_SCENE_TOML: &str = include_str!("../../tests/data/small.toml");

impl Scene {
    /// The embedded example scene `name` (see [`EXAMPLE_SCENES`]), or `None` for a name
    /// that is not one.
    /// Its `gltf` species read their files from those embedded beside it.
    pub fn example(name: &str) -> Option<Result<Scene, SceneError>> {
        EXAMPLE_SCENES
            .iter()
            .find(|(n, _, _)| *n == name)
            .map(|(n, _, text)| {
                let mut scene = Scene::parse(text, &format!("{n}.toml"))?;
                let dir = crate::model::gltf::embedded::scenes_dir();
                for s in &mut scene.species {
                    s.base_dir = Some(dir.clone());
                }
                Ok(scene)
            })
    }

    /// The embedded default scene (`assets/default.toml`): 1,000 trees, the scene of every
    /// command but the viewer when none is named.
    pub fn default_scene() -> Scene {
        // Embedded text, not user input; a test checks that it parses.
        Scene::parse(DEFAULT_SCENE_TOML, "default.toml")
            .unwrap_or_else(|e| panic!("the embedded default scene is invalid: {e}"))
    }

    /// What the viewer opens when given no scene: the example forest at real density
    /// (`assets/scenes/forest.toml`, about 36,000 trees).
    pub fn viewer_scene() -> Scene {
        // Embedded text, not user input; a test checks that it parses.
        Scene::parse(FOREST_SCENE_TOML, "forest.toml")
            .unwrap_or_else(|e| panic!("the embedded example forest is invalid: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::test_support::*;

    #[test]
    fn example_scenes_parse_and_the_forest_is_dense() {
        for (name, _, _) in EXAMPLE_SCENES {
            match Scene::example(name) {
                Some(Ok(_)) => {}
                Some(Err(e)) => panic!("example `{name}`: {e}"),
                None => panic!("example `{name}` not found"),
            }
        }
        assert!(Scene::example("nope").is_none());
        // The glTF example builds from the files embedded beside it.
        let pines = match Scene::example("pines") {
            Some(Ok(s)) => s,
            _ => panic!("pines"),
        };
        let world = match pines.build_world() {
            Ok(w) => w,
            Err(e) => panic!("pines: {e}"),
        };
        assert_eq!(world.species[0].name, "pine5");
        assert!(world.species[0].triangle_counts().tree > 1_000);
        let forest = match Scene::example("forest") {
            Some(Ok(s)) => s,
            _ => panic!("forest"),
        };
        // Only the placement is needed here, not the species' meshes.
        let terrain = match crate::model::Terrain::generate(&forest.terrain) {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        };
        let placed =
            match crate::model::Forest::place(&forest.forest, &terrain, forest.species.len()) {
                Ok(f) => f,
                Err(e) => panic!("{e}"),
            };
        // The issue asks for at least 30,000 trees on 1 km².
        let n = placed.instances.len();
        assert!((30_000..=40_000).contains(&n), "{n} trees");
        let hist = placed.species_histogram(3);
        assert!(hist.iter().all(|h| *h > 3_000), "{hist:?}");
    }

    #[test]
    fn default_and_small_scenes_parse() {
        let d = Scene::default_scene();
        assert_eq!(d.forest.count, Some(1000));
        assert_eq!(d.terrain.resolution, 257);
        assert_eq!(d.species.len(), 2);
        assert_eq!(d.forest.mix.len(), 2);
        let small = Scene::parse(SMALL_TEST_SCENE_TOML, "small.toml");
        let small = match small {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        assert!((20..=40).contains(&small.forest.count.unwrap_or(0)));
        assert!((80.0..=120.0).contains(&small.terrain.size));
    }

    #[test]
    fn small_scene_builds_its_world() {
        let scene = small_world_scene();
        let w = match scene.build_world() {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(w.species.len(), scene.species.len());
        assert_eq!(
            w.forest.instances.len(),
            scene.forest.count.unwrap_or(0) as usize
        );
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
    fn default_scene_builds_its_world_deterministically() {
        let scene = Scene::default_scene();
        let start = std::time::Instant::now();
        let a = match scene.build_world() {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        eprintln!("default world built in {:.2?}", start.elapsed());
        assert_eq!(a.forest.instances.len(), 1000);
        let b = scene
            .build_world()
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
    fn unknown_preset_is_reported_by_the_world_build() {
        let mut scene = small_world_scene();
        scene.species[0].preset = Some("oak".into());
        scene.species[0].params = None;
        let e = scene
            .build_world()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("oak"), "{e}");
    }

    #[test]
    fn scene_round_trips_through_toml() {
        let d = Scene::default_scene();
        let text = toml::to_string(&d).unwrap_or_default();
        let back = Scene::parse(&text, "round.toml").ok();
        assert_eq!(back, Some(d));
    }
}
