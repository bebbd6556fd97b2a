//! The bake cache: baked files are kept under a key made from the scene (as parsed, so
//! comments and spacing do not matter), the bake settings and the generator's revision.
//! A file that is missing, corrupt, of another version or of another scene is baked again.

use std::path::{Path, PathBuf};

use crate::format::{BakeSettings, Baked};
use crate::scene::Scene;

/// Bumped whenever the generator or the bake changes what it makes: old caches are rebaked.
pub const BAKE_REVISION: u32 = 9;
/// Bumped whenever the glTF reader changes what it makes of a file (its levels): only
/// scenes with imported trees are rebaked.
pub const IMPORT_REVISION: u32 = 2;

/// The bake settings a scene asks for.
pub fn settings_of(scene: &Scene) -> BakeSettings {
    BakeSettings {
        views: scene.bake.views,
        tree_views: scene.bake.tree_views,
        lights: scene.bake.lights,
        resolution: scene.bake.resolution,
        supersample: scene.bake.supersample,
        vcm_resolution: 32,
        texel_resolution: scene.bake.texel_resolution,
        impostor_frames: scene.bake.impostor_frames,
        impostor_resolution: scene.bake.impostor_resolution,
        impostor_layout: scene.bake.impostor_layout,
        compress: scene.bake.compress,
        surfel_budget: scene.bake.surfel_budget,
    }
}

/// FNV-1a, 64 bits: stable across runs, platforms and Rust versions.
fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// The key of a scene's bake: its species, terrain and forest, the bake settings and the
/// generator's revision (sun, sky and camera do not change what is baked).
pub fn scene_hash(scene: &Scene) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325;
    let species = toml::to_string(&SpeciesOnly {
        species: &scene.species,
    })
    .unwrap_or_default();
    h = fnv1a(species.as_bytes(), h);
    // An imported tree is baked from its files: their bytes are part of the key.
    for path in scene.species.iter().flat_map(|s| s.gltf_paths()) {
        h = fnv1a(&IMPORT_REVISION.to_le_bytes(), h);
        for file in crate::model::gltf::files_of(&path) {
            h = fnv1a(file.to_string_lossy().as_bytes(), h);
            h = fnv1a(
                &crate::model::gltf::file_bytes(&file).unwrap_or_default(),
                h,
            );
        }
    }
    // The horizon ring is drawn only: it changes nothing baked.
    let terrain = crate::model::params::TerrainParams {
        horizon: false,
        ..scene.terrain.clone()
    };
    let forest = toml::to_string(&ForestOnly {
        forest: &scene.forest,
        terrain: &terrain,
    })
    .unwrap_or_default();
    h = fnv1a(forest.as_bytes(), h);
    for v in settings_of(scene)
        .header_words()
        .into_iter()
        .chain([BAKE_REVISION])
    {
        h = fnv1a(&v.to_le_bytes(), h);
    }
    // How the trees' own cube maps are laid out.
    h = fnv1a(format!("{:?}", scene.bake.tree_vcm).as_bytes(), h);
    // How the texels are made, when not the default (so that default scenes keep their
    // caches).
    if scene.texel != crate::scene::TexelParams::default() {
        h = fnv1a(
            toml::to_string(&scene.texel).unwrap_or_default().as_bytes(),
            h,
        );
    }
    h
}

#[derive(serde::Serialize)]
struct SpeciesOnly<'a> {
    species: &'a [crate::scene::SpeciesEntry],
}

#[derive(serde::Serialize)]
struct ForestOnly<'a> {
    forest: &'a crate::scene::ForestParams,
    terrain: &'a crate::scene::TerrainParams,
}

/// Where baked files are kept: `$CANOPY_CACHE_DIR`, else `$XDG_CACHE_HOME/canopy`, else
/// `~/.cache/canopy`, else `.canopy-cache` in the working directory.
pub fn cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("CANOPY_CACHE_DIR") {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return Path::new(&d).join("canopy");
    }
    if let Some(h) = std::env::var_os("HOME") {
        return Path::new(&h).join(".cache").join("canopy");
    }
    PathBuf::from(".canopy-cache")
}

/// The cache file of a scene.
pub fn cache_path(scene: &Scene) -> PathBuf {
    cache_path_in(&cache_dir(), scene)
}

/// Where `scene`'s bake is kept in the cache directory `dir`.
pub fn cache_path_in(dir: &Path, scene: &Scene) -> PathBuf {
    dir.join(format!("{:016x}.canopy", scene_hash(scene)))
}

/// Reads a scene's bake from `path` if it is there and valid for this scene. The error of a
/// file that exists but cannot be used is returned so the caller can say why it re-bakes.
/// A cache of an older format version that reads is written again as this version writes
/// it (its sections deflated: a quarter of the size or less, in under a second).
pub fn load(path: &Path, scene: &Scene) -> Option<Result<Baked, crate::format::FormatError>> {
    if !path.exists() {
        return None;
    }
    let result = crate::format::read_expecting(path, scene_hash(scene));
    if let Ok(baked) = &result
        && let Ok(version) = crate::format::version_of(path)
        && version < crate::format::VERSION
    {
        let size = |p: &Path| std::fs::metadata(p).map_or(0, |m| m.len());
        let before = size(path);
        match crate::format::write_atomic(path, baked) {
            Ok(()) => log::info!(
                "the cache {} was format version {version}: written again as version {}, {before} → {} bytes",
                path.display(),
                crate::format::VERSION,
                size(path)
            ),
            Err(e) => log::warn!(
                "could not write the cache {} again as format version {}: {e}",
                path.display(),
                crate::format::VERSION
            ),
        }
    }
    Some(result)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_older_cache_reads_and_is_written_again_smaller() {
        use crate::format::test_support::{as_version_7, compressible, sample, scratch_dir};
        let scene = Scene::default_scene();
        let mut baked = crate::format::Baked {
            scene_hash: scene_hash(&scene),
            ..compressible(sample())
        };
        // Version 7 has no surfel budget: it reads as 0.
        baked.settings.surfel_budget = 0;
        let dir = scratch_dir("old-cache");
        let path = dir.join("c.canopy");
        std::fs::write(&path, as_version_7(&crate::format::to_bytes(&baked))).unwrap();
        let old_len = std::fs::metadata(&path).unwrap().len();
        assert_eq!(crate::format::version_of(&path).unwrap(), 7);
        let loaded = load(&path, &scene).unwrap().unwrap();
        assert!(loaded == baked);
        assert_eq!(
            crate::format::version_of(&path).unwrap(),
            crate::format::VERSION
        );
        assert!(std::fs::metadata(&path).unwrap().len() < old_len * 3 / 4);
        assert!(load(&path, &scene).unwrap().unwrap() == baked);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn one_variant_keeps_the_bake_key_and_more_change_it() {
        let base = Scene::default_scene();
        let mut one = base.clone();
        one.species[1].variants = 1;
        assert_eq!(scene_hash(&base), scene_hash(&one));
        let mut three = base.clone();
        three.species[1].variants = 3;
        assert_ne!(scene_hash(&base), scene_hash(&three));
    }

    #[test]
    fn the_key_follows_what_is_baked_and_ignores_the_rest() {
        let a = Scene::default_scene();
        let mut b = a.clone();
        b.sun.azimuth += 10.0;
        b.camera.fov_deg += 5.0;
        assert_eq!(scene_hash(&a), scene_hash(&b));
        let mut c = a.clone();
        c.bake.views = 66;
        assert_ne!(scene_hash(&a), scene_hash(&c));
        let mut c = a.clone();
        c.bake.tree_views = 18;
        assert_ne!(scene_hash(&a), scene_hash(&c));
        let mut d = a.clone();
        d.forest.seed += 1;
        assert_ne!(scene_hash(&a), scene_hash(&d));
        let mut e = a.clone();
        e.species[0].seed += 1;
        assert_ne!(scene_hash(&a), scene_hash(&e));
        let mut f = a.clone();
        f.texel.source = crate::scene::TexelSource::VoxelColouring;
        assert_ne!(scene_hash(&a), scene_hash(&f));
    }
}
