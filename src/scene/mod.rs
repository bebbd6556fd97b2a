//! Scene files: the TOML description of a forest scene (terrain, species, placement, sun,
//! sky, start camera), its loading and validation. Every problem is reported with the file
//! name, the line and the dotted key, e.g.
//! `scene.toml:14: forest.count: invalid value: integer `-5`, expected a non-negative integer
//! no larger than 4294967295`.
//!
//! This file holds the schema (the types a scene file deserialises into) and the loading;
//! `check.rs` validates the values, `locate.rs` turns errors into `file:line: key` messages
//! and `examples.rs` holds the scenes embedded in the binary.

use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::{Deserialize, Serialize};

pub use crate::model::params::{
    BAKE_DIRECTIONS, BAKE_RESOLUTIONS, BakeParams, ForestParams, MAX_SPECIES, MAX_TREES,
    SpeciesEntry, TERRAIN_RESOLUTION, TerrainParams, TexelParams, TexelSource,
};

fn is_default_texel(t: &TexelParams) -> bool {
    *t == TexelParams::default()
}
use crate::model::{ModelError, World};

mod check;
mod examples;
mod locate;
#[cfg(test)]
mod test_support;

#[cfg(test)]
pub use examples::SMALL_TEST_SCENE_TOML;
pub use examples::{DEFAULT_SCENE_TOML, EXAMPLE_SCENES, FOREST_SCENE_TOML, STAND_SCENE_TOML};

/// Largest scene file accepted (bytes).
pub const MAX_SCENE_BYTES: u64 = 16 * 1024 * 1024;

/// A whole scene.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// `[terrain]`
    pub terrain: TerrainParams,
    /// `[[species]]`, one entry per species.
    pub species: Vec<SpeciesEntry>,
    /// `[forest]`
    pub forest: ForestParams,
    /// `[sun]`
    pub sun: SunParams,
    /// `[sky]`
    pub sky: SkyParams,
    /// `[camera]`
    pub camera: CameraParams,
    /// `[bake]`: how BTF images are sampled. Optional, every key too.
    #[serde(default)]
    pub bake: BakeParams,
    /// `[texel]`: how the texel volumes are made. Optional, every key too.
    #[serde(default, skip_serializing_if = "is_default_texel")]
    pub texel: TexelParams,
    /// `[render]`: the `btf` knobs the viewer and `render` start from (what `canopy tune`
    /// writes). Optional, every key too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderParams>,
}

/// `[render]`: starting values of the `btf` method's knobs.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderParams {
    /// A level is used while its largest texel projects below this many pixels (0.05..=64).
    pub lod_scale: Option<f32>,
    /// Images whose blending weight is below this are skipped (0..=1).
    pub weight_threshold: Option<f32>,
    /// Width of the LOD cross-fade band, as a fraction of the bound (0..=1).
    pub lod_fade: Option<f32>,
    /// `single` or `crossed`.
    pub planes: Option<String>,
    /// Draw the far forest as one canopy layer (true) or a billboard per tree (false).
    pub far_canopy: Option<bool>,
    /// The on-screen crown width (px) below which trees are drawn by the far canopy
    /// (0.5..=64).
    pub canopy_px: Option<f32>,
}

/// `[sun]`: the directional light.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SunParams {
    /// Degrees; 0 = towards +Z (north), 90 = towards +X (east), clockwise seen from above.
    pub azimuth: f32,
    /// Degrees above the horizon (-90..=90).
    pub elevation: f32,
    /// Linear RGB colour.
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub color: [f32; 3],
    /// Multiplier on `color`.
    pub intensity: f32,
}

impl SunParams {
    /// Unit vector from the ground towards the sun.
    pub fn direction(&self) -> Vec3 {
        sun_direction(self.azimuth, self.elevation)
    }

    /// Colour times intensity.
    pub fn radiance(&self) -> Vec3 {
        Vec3::from(self.color) * self.intensity
    }
}

/// `[sky]`: hemispherical ambient light.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SkyParams {
    /// Linear RGB of the sky at the zenith (ambient from above).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub color: [f32; 3],
    /// Linear RGB of the light bounced from the ground (ambient from below).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub ground_color: [f32; 3],
    /// Multiplier on both colours.
    pub intensity: f32,
}

/// `[camera]`: the start view.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraParams {
    /// Eye position (m, world).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub position: [f32; 3],
    /// Point looked at (m, world).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub look_at: [f32; 3],
    /// Vertical field of view (degrees).
    pub fov_deg: f32,
}

/// Unit vector pointing from the ground towards the sun. Azimuth in degrees: 0 = +Z
/// (north), clockwise seen from above towards +X (east) at 90; elevation in degrees above
/// the horizon.
pub fn sun_direction(azimuth_deg: f32, elevation_deg: f32) -> Vec3 {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vec3::new(az.sin() * el.cos(), el.sin(), az.cos() * el.cos())
        .try_normalize()
        .unwrap_or(Vec3::Y)
}

/// Errors from loading a scene file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read scene file `{}`: {source}", path.display())]
    Io {
        /// The path as given.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file is larger than [`MAX_SCENE_BYTES`].
    #[error("scene file `{}` is {size} bytes; scene files are limited to {MAX_SCENE_BYTES} bytes", path.display())]
    TooLarge {
        /// The path as given.
        path: PathBuf,
        /// Its size in bytes.
        size: u64,
    },
    /// The text is not valid TOML.
    #[error("{origin}:{line}: TOML syntax error: {message}")]
    Syntax {
        /// File name used in messages.
        origin: String,
        /// 1-based line.
        line: usize,
        /// What the TOML parser said.
        message: String,
    },
    /// A key is unknown, missing, of the wrong type or out of range.
    #[error("{origin}:{line}: {key}: {message}")]
    Invalid {
        /// File name used in messages.
        origin: String,
        /// 1-based line.
        line: usize,
        /// Dotted key, e.g. `forest.count` or `species[1].params.height`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

impl SceneError {
    /// The 1-based line the error points at, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            SceneError::Syntax { line, .. } | SceneError::Invalid { line, .. } => Some(*line),
            _ => None,
        }
    }

    /// The dotted key the error is about, if any.
    pub fn key(&self) -> Option<&str> {
        match self {
            SceneError::Invalid { key, .. } => Some(key),
            _ => None,
        }
    }
}

impl Default for Scene {
    /// The embedded default scene.
    fn default() -> Self {
        Scene::default_scene()
    }
}

impl Scene {
    /// Parses and validates scene text; `origin` is the file name used in messages.
    pub fn parse(text: &str, origin: &str) -> Result<Scene, SceneError> {
        let doc = locate::Document::parse(text, origin)?;
        let scene: Scene = doc.deserialize()?;
        scene.check().map_err(|e| doc.field_error(e))?;
        Ok(scene)
    }

    /// Reads, parses and validates the scene file at `path`.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let io = |source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        };
        let size = std::fs::metadata(path).map_err(io)?.len();
        if size > MAX_SCENE_BYTES {
            return Err(SceneError::TooLarge {
                path: path.to_path_buf(),
                size,
            });
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        let mut scene = Scene::parse(&text, &path.display().to_string())?;
        // A `gltf` species' path is relative to the scene file.
        let dir = path.parent().map(Path::to_path_buf);
        for s in &mut scene.species {
            s.base_dir.clone_from(&dir);
        }
        Ok(scene)
    }

    /// Builds the world of this scene: its terrain, species prototypes and forest
    /// (see [`World::build`]). Deterministic for the scene.
    pub fn build_world(&self) -> Result<World, ModelError> {
        let mut world = World::build(&self.terrain, &self.species, &self.forest)?;
        world.tree_vcm = self.bake.tree_vcm;
        Ok(world)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::test_support::*;

    #[test]
    fn base_scene_parses() {
        let s = Scene::parse(BASE, "scene.toml");
        let s = match s {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(s.species.len(), 2);
        assert_eq!(s.terrain.octaves, 5);
        assert_eq!(s.forest.tint_variation, 0.15);
        assert_eq!(
            s.species[1].try_params().unwrap().foliage,
            crate::model::FoliageKind::Leaves
        );
    }

    #[test]
    fn load_reports_missing_file_with_path() {
        let p = Path::new("/definitely/not/here/scene.toml");
        let msg = Scene::load(p)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(msg.contains("/definitely/not/here/scene.toml"), "{msg}");
        assert!(msg.contains("cannot read"), "{msg}");
    }

    #[test]
    fn load_rejects_huge_files_without_reading_them() {
        let dir = std::env::temp_dir().join(format!("canopy-scene-big-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        let path = dir.join("big.toml");
        std::fs::File::create(&path)
            .and_then(|f| f.set_len(MAX_SCENE_BYTES + 1))
            .unwrap_or_else(|e| panic!("making {}: {e}", path.display()));
        let msg = Scene::load(&path)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            msg.contains("big.toml") && msg.contains("limited to"),
            "{msg}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn sun_direction_convention() {
        let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
        assert!(close(sun_direction(0.0, 0.0), Vec3::Z), "north is +Z");
        assert!(close(sun_direction(90.0, 0.0), Vec3::X), "east is +X");
        assert!(close(sun_direction(180.0, 0.0), -Vec3::Z));
        assert!(close(sun_direction(123.0, 90.0), Vec3::Y), "zenith");
        let d = sun_direction(135.0, 35.0);
        assert!((d.length() - 1.0).abs() < 1e-5);
        assert!((d.y - 35f32.to_radians().sin()).abs() < 1e-5);
        assert!(d.x > 0.0 && d.z < 0.0, "south-east");
    }
}
