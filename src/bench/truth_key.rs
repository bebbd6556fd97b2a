//! The ground-truth cache. The reference render of a frame (full geometry, supersampled) is
//! the slowest thing the bench does and the same for every configuration, so it is kept on
//! disk under a key made of everything that decides its pixels: the scene's content, the
//! camera, the sun, the image size, the supersampling and [`TRUTH_REVISION`]. The key is
//! FNV-1a/64 over a canonical little-endian serialisation (never std's `DefaultHasher`,
//! which may change between Rust releases). Files live at `<cache>/truth/<key>.png`.

use std::path::{Path, PathBuf};

use glam::Vec3;
use image::RgbaImage;

use crate::scene::Scene;
use crate::{Error, Result};

/// Bumped whenever the reference renderer changes what it draws: old truths are re-rendered.
/// (3: the presets grew denser foliage and the horizon ring carries the far forest; 4: each
/// tree shades itself through a sun map of its own; 5: the cascades shade points past the
/// scene's bounds away from the sun, the horizon ring under the edge trees' shadows.)
pub const TRUTH_REVISION: u32 = 5;

/// Everything that decides the pixels of one reference frame.
#[derive(Clone, Copy, Debug)]
pub struct TruthRequest<'a> {
    /// The scene's content as bytes, e.g. [`scene_content`] of the parsed scene.
    pub scene: &'a [u8],
    pub position: Vec3,
    pub look_at: Vec3,
    pub fov_y_deg: f32,
    /// Unit vector towards the sun.
    pub sun_direction: Vec3,
    /// Sun colour times intensity.
    pub sun_radiance: Vec3,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel side.
    pub supersample: u32,
    /// Anything else the caller's reference render depends on (its settings serialised);
    /// empty when nothing.
    pub extra: &'a [u8],
}

/// The content of a scene that the truth depends on, canonically serialised (as parsed, so
/// comments and spacing do not matter): terrain, species, forest, sky and the sun's colour.
/// The start camera and the sun's angles are left out: every flight frame gives its own.
pub fn scene_content(scene: &Scene) -> Vec<u8> {
    #[derive(serde::Serialize)]
    struct Content<'a> {
        terrain: &'a crate::model::TerrainParams,
        species: &'a [crate::model::SpeciesEntry],
        forest: &'a crate::model::ForestParams,
        sky: &'a crate::scene::SkyParams,
        sun_color: [f32; 3],
        sun_intensity: f32,
    }
    toml::to_string(&Content {
        terrain: &scene.terrain,
        species: &scene.species,
        forest: &scene.forest,
        sky: &scene.sky,
        sun_color: scene.sun.color,
        sun_intensity: scene.sun.intensity,
    })
    .unwrap_or_default()
    .into_bytes()
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0100_0000_01b3;

/// FNV-1a, 64 bits: the same on every run, platform and Rust version.
fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(FNV_PRIME);
    }
    h
}

/// The cache key of one reference frame, with the size its image must have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TruthKey {
    pub hash: u64,
    pub width: u32,
    pub height: u32,
}

/// What the cache held for a key.
#[derive(Debug)]
pub enum TruthLookup {
    Hit(RgbaImage),
    /// No file: render it.
    Missing,
    /// A file that cannot be used (truncated, not a PNG, the wrong size): render it again;
    /// the reason is for the log.
    Unusable {
        path: PathBuf,
        reason: String,
    },
}

impl TruthKey {
    pub fn new(r: &TruthRequest<'_>) -> TruthKey {
        // Every field tagged and fixed-size or length-prefixed, so no two different
        // requests serialise to the same bytes.
        let mut bytes = Vec::with_capacity(r.scene.len() + r.extra.len() + 128);
        bytes.extend_from_slice(b"canopy-truth");
        bytes.extend_from_slice(&TRUTH_REVISION.to_le_bytes());
        let mut blob = |tag: &[u8], b: &[u8]| {
            bytes.extend_from_slice(tag);
            bytes.extend_from_slice(&(b.len() as u64).to_le_bytes());
            bytes.extend_from_slice(b);
        };
        blob(b"scene", r.scene);
        blob(b"extra", r.extra);
        let floats = [
            r.position.to_array(),
            r.look_at.to_array(),
            r.sun_direction.to_array(),
            r.sun_radiance.to_array(),
        ]
        .concat();
        for v in floats.into_iter().chain([r.fov_y_deg]) {
            // +0.0 for -0.0: the same picture must not get two keys.
            bytes.extend_from_slice(&(v + 0.0).to_le_bytes());
        }
        for v in [r.width, r.height, r.supersample] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        TruthKey {
            hash: fnv1a(&bytes, FNV_OFFSET),
            width: r.width,
            height: r.height,
        }
    }

    /// The key as 16 hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.hash)
    }

    /// `<cache_dir>/truth/<key>.png`.
    pub fn path_in(&self, cache_dir: &Path) -> PathBuf {
        cache_dir.join("truth").join(format!("{}.png", self.hex()))
    }

    /// The file under the canopy cache directory (the bake's, see `bake::cache::cache_dir`).
    pub fn path(&self) -> PathBuf {
        self.path_in(&crate::bake::cache::cache_dir())
    }

    /// The cached truth under `cache_dir`, if there is a usable one.
    pub fn load(&self, cache_dir: &Path) -> TruthLookup {
        let path = self.path_in(cache_dir);
        if !path.exists() {
            return TruthLookup::Missing;
        }
        let unusable = |reason: String| TruthLookup::Unusable {
            path: path.clone(),
            reason,
        };
        let img = match image::open(&path) {
            Ok(img) => img.to_rgba8(),
            Err(e) => return unusable(e.to_string()),
        };
        if img.dimensions() != (self.width, self.height) {
            let (w, h) = img.dimensions();
            return unusable(format!(
                "it is {w}x{h}, the frame is {}x{}",
                self.width, self.height
            ));
        }
        TruthLookup::Hit(img)
    }

    /// Stores `img` as the truth of this key under `cache_dir`, atomically (a temporary
    /// file renamed into place, so a reader never sees half a file). Returns its path.
    pub fn store(&self, cache_dir: &Path, img: &RgbaImage) -> Result<PathBuf> {
        let path = self.path_in(cache_dir);
        if img.dimensions() != (self.width, self.height) {
            let (w, h) = img.dimensions();
            return Err(Error::WriteImage {
                path,
                reason: format!(
                    "the truth image is {w}x{h} but its key is for {}x{}",
                    self.width, self.height
                ),
            });
        }
        crate::imageio::save_png(&path, img)?;
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(scene: &[u8]) -> TruthRequest<'_> {
        TruthRequest {
            scene,
            position: Vec3::new(10.0, 20.0, -30.0),
            look_at: Vec3::new(0.0, 5.0, 0.0),
            fov_y_deg: 50.0,
            sun_direction: Vec3::new(0.3, 0.8, 0.52),
            sun_radiance: Vec3::splat(3.0),
            width: 64,
            height: 48,
            supersample: 4,
            extra: b"",
        }
    }

    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("canopy-truth-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    fn picture(w: u32, h: u32) -> RgbaImage {
        RgbaImage::from_fn(w, h, |x, y| {
            image::Rgba([(x * 5) as u8, (y * 7) as u8, 90, 255])
        })
    }

    #[test]
    fn fnv1a_matches_the_reference_vectors() {
        assert_eq!(fnv1a(b"", FNV_OFFSET), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a", FNV_OFFSET), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a(b"foobar", FNV_OFFSET), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn same_inputs_same_key_and_every_input_counts() {
        let base = request(b"scene A");
        let k = TruthKey::new(&base);
        assert_eq!(k, TruthKey::new(&request(b"scene A")));
        assert_eq!(k.hex().len(), 16);
        let changed = [
            TruthRequest {
                scene: b"scene B",
                ..base
            },
            TruthRequest {
                sun_direction: Vec3::new(0.3, 0.81, 0.5),
                ..base
            },
            TruthRequest {
                sun_radiance: Vec3::splat(2.0),
                ..base
            },
            TruthRequest { width: 65, ..base },
            TruthRequest { height: 49, ..base },
            TruthRequest {
                supersample: 2,
                ..base
            },
            TruthRequest {
                position: base.position + Vec3::X * 0.01,
                ..base
            },
            TruthRequest {
                look_at: Vec3::ZERO,
                ..base
            },
            TruthRequest {
                fov_y_deg: 51.0,
                ..base
            },
            TruthRequest {
                extra: b"shadow 4096",
                ..base
            },
        ];
        for (i, c) in changed.iter().enumerate() {
            assert_ne!(TruthKey::new(c).hash, k.hash, "change {i} keeps the key");
        }
        // Bytes moved between the scene and the extra do not collide.
        let a = TruthRequest {
            scene: b"ab",
            extra: b"c",
            ..base
        };
        let b = TruthRequest {
            scene: b"a",
            extra: b"bc",
            ..base
        };
        assert_ne!(TruthKey::new(&a), TruthKey::new(&b));
        // Negative zero is zero.
        let z = TruthRequest {
            look_at: Vec3::new(-0.0, 5.0, 0.0),
            ..base
        };
        assert_eq!(TruthKey::new(&z), k);
    }

    #[test]
    fn the_scene_content_follows_the_forest_not_the_start_view() {
        let a = Scene::default_scene();
        let mut b = a.clone();
        b.camera.position[0] += 10.0;
        b.sun.azimuth += 30.0;
        assert_eq!(scene_content(&a), scene_content(&b));
        let mut c = a.clone();
        c.forest.seed += 1;
        assert_ne!(scene_content(&a), scene_content(&c));
        let mut d = a.clone();
        d.sky.intensity *= 2.0;
        assert_ne!(scene_content(&a), scene_content(&d));
        assert!(!scene_content(&a).is_empty());
    }

    #[test]
    fn the_path_is_under_truth_in_the_cache() {
        let k = TruthKey::new(&request(b"s"));
        let p = k.path_in(Path::new("/c"));
        assert_eq!(p, PathBuf::from(format!("/c/truth/{}.png", k.hex())));
    }

    #[test]
    fn store_then_load_round_trips() {
        let dir = temp_dir("roundtrip");
        let k = TruthKey::new(&request(b"s"));
        assert!(matches!(k.load(&dir), TruthLookup::Missing));
        let img = picture(64, 48);
        let path = k.store(&dir, &img).unwrap();
        assert!(path.starts_with(dir.join("truth")));
        match k.load(&dir) {
            TruthLookup::Hit(got) => assert_eq!(got, img),
            other => panic!("{other:?}"),
        }
        let files: Vec<_> = std::fs::read_dir(dir.join("truth")).unwrap().collect();
        assert_eq!(files.len(), 1, "no temporary file left behind");
        // An image of another size is refused.
        let e = k.store(&dir, &picture(10, 10)).unwrap_err().to_string();
        assert!(e.contains("10x10") && e.contains("64x48"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_truncated_or_foreign_file_is_a_reported_miss() {
        let dir = temp_dir("corrupt");
        let k = TruthKey::new(&request(b"s"));
        let path = k.store(&dir, &picture(64, 48)).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        match k.load(&dir) {
            TruthLookup::Unusable { path: p, reason } => {
                assert_eq!(p, path);
                assert!(!reason.is_empty());
            }
            other => panic!("truncated file: {other:?}"),
        }
        std::fs::write(&path, b"not a png at all").unwrap();
        assert!(matches!(k.load(&dir), TruthLookup::Unusable { .. }));
        // A valid PNG of the wrong size (another key's image copied over) is no hit either.
        picture(8, 8).save(&path).unwrap();
        match k.load(&dir) {
            TruthLookup::Unusable { reason, .. } => assert!(reason.contains("8x8"), "{reason}"),
            other => panic!("wrong size: {other:?}"),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
