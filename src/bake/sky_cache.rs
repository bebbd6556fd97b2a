//! The sky visibility of a scene's world, kept in the bake cache beside its bake: computing
//! it takes seconds even for a small stand (12.7 s for `tests/data/btf.toml` on a 2-core
//! Xeon), and every `canopy render` of an image-based method with the ground's sky on, and
//! every reference frame, needs it. A file is used only when its header matches the scene's
//! key, the directions and the grid it would be computed on, and its checksum holds; any
//! other file is computed again and replaced (atomically), with a warning saying why.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::Vec3;

use crate::model::World;
use crate::render::sky_visibility::{self, SkyVolume};
use crate::scene::Scene;

/// The file's first bytes.
const MAGIC: &[u8; 8] = b"CNPYSKY1";
/// What the computation's results depend on besides the world and the directions (its grid
/// limits and algorithm): raise it when `SkyVolume::compute` changes.
pub const SKY_REVISION: u32 = 1;
/// Header: magic, revision, directions, terrain, key (u64), origin (3 f32), cell (f32),
/// dims (3 u32).
const HEADER: usize = 8 + 4 + 4 + 4 + 8 + 12 + 4 + 12;

/// Where the sky visibility of `scene` from `directions` directions (with its terrain, or
/// over the trees alone) is kept in the cache folder `dir`.
pub fn sky_path_in(dir: &Path, scene: &Scene, directions: u32, terrain: bool) -> PathBuf {
    path_for(dir, super::cache::scene_hash(scene), directions, terrain)
}

/// [`sky_path_in`] for the scene whose key is `key`.
fn path_for(dir: &Path, key: u64, directions: u32, terrain: bool) -> PathBuf {
    let kind = if terrain { "sky" } else { "trees-sky" };
    dir.join(format!("{key:016x}.{kind}{directions}"))
}

/// The sky visibility of `world` (made from `scene`) over its bounds, from `directions`
/// directions: read from the cache folder `dir` when a valid file is there, else computed
/// and written there (a failure to write is a warning: the volume is still returned).
pub fn sky_volume_in(
    dir: &Path,
    scene: &Scene,
    world: &World,
    directions: u32,
    terrain: bool,
) -> SkyVolume {
    let directions = directions.max(1);
    // The key once: it reads an imported tree's files.
    let key = super::cache::scene_hash(scene);
    let path = path_for(dir, key, directions, terrain);
    let bounds = sky_visibility::bounds_of(world, terrain);
    let grid = SkyVolume::grid(&bounds, terrain);
    if path.exists() {
        match read(&path, key, directions, terrain, grid) {
            Ok(v) => return v,
            Err(why) => log::warn!(
                "the cached sky visibility {} is not used ({why}): computing it again",
                path.display()
            ),
        }
    }
    let volume = SkyVolume::compute(world, &bounds, terrain, directions);
    if let Err(e) = std::fs::create_dir_all(dir)
        .map_err(|e| e.to_string())
        .and_then(|()| write(&path, key, directions, terrain, &volume))
    {
        log::warn!(
            "the sky visibility could not be kept in {}: {e}",
            path.display()
        );
    }
    volume
}

/// [`sky_volume_in`] the cache folder the bakes use ([`super::cache::cache_dir`]).
pub fn sky_volume(scene: &Scene, world: &World, directions: u32, terrain: bool) -> SkyVolume {
    sky_volume_in(
        &super::cache::cache_dir(),
        scene,
        world,
        directions,
        terrain,
    )
}

fn write(
    path: &Path,
    key: u64,
    directions: u32,
    terrain: bool,
    v: &SkyVolume,
) -> Result<(), String> {
    let mut bytes = Vec::with_capacity(HEADER + 4 * v.values.len() + 4);
    bytes.extend_from_slice(MAGIC);
    for w in [SKY_REVISION, directions, u32::from(terrain)] {
        bytes.extend_from_slice(&w.to_le_bytes());
    }
    bytes.extend_from_slice(&key.to_le_bytes());
    for f in [v.origin.x, v.origin.y, v.origin.z, v.cell] {
        bytes.extend_from_slice(&f.to_le_bytes());
    }
    for d in v.dims {
        let d = u32::try_from(d).map_err(|_| "a grid too large to keep".to_string())?;
        bytes.extend_from_slice(&d.to_le_bytes());
    }
    for x in &v.values {
        bytes.extend_from_slice(&x.to_le_bytes());
    }
    let crc = crc32fast::hash(&bytes);
    bytes.extend_from_slice(&crc.to_le_bytes());
    crate::atomic_file::write_atomic(path, |w: &mut dyn Write| w.write_all(&bytes))
        .map_err(|e| e.to_string())
}

/// The volume in `path`, or why it cannot be used for this key, directions, terrain and
/// grid (origin, cell, dims: [`SkyVolume::grid`]).
fn read(
    path: &Path,
    key: u64,
    directions: u32,
    terrain: bool,
    grid: (Vec3, f32, [usize; 3]),
) -> Result<SkyVolume, String> {
    let (origin, cell, dims) = grid;
    let cells: usize = dims.iter().product();
    let want = (HEADER + 4 * cells + 4) as u64;
    // The size the grid gives, checked before the file is read.
    let len = std::fs::metadata(path).map_err(|e| e.to_string())?.len();
    if len != want {
        return Err(format!(
            "{len} bytes, where this scene's grid of {dims:?} cells takes {want}"
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    let (body, tail) = bytes.split_at(bytes.len() - 4);
    let crc = u32::from_le_bytes(tail.try_into().map_err(|_| "truncated")?);
    if crc32fast::hash(body) != crc {
        return Err("its checksum does not match: the file is damaged".into());
    }
    if &body[..8] != MAGIC {
        return Err("it is not a sky visibility file".into());
    }
    let u32_at = |o: usize| u32::from_le_bytes(body[o..o + 4].try_into().unwrap_or([0; 4]));
    let f32_at = |o: usize| f32::from_bits(u32_at(o));
    let header = (u32_at(8), u32_at(12), u32_at(16));
    if header != (SKY_REVISION, directions, u32::from(terrain)) {
        return Err(format!(
            "it holds revision {} from {} directions (terrain {}), not revision {SKY_REVISION} from {directions} (terrain {})",
            header.0,
            header.1,
            header.2,
            u32::from(terrain)
        ));
    }
    let file_key = u64::from_le_bytes(body[20..28].try_into().unwrap_or([0; 8]));
    if file_key != key {
        return Err("it was computed for another scene".into());
    }
    let file_origin = Vec3::new(f32_at(28), f32_at(32), f32_at(36));
    let file_dims = [u32_at(44), u32_at(48), u32_at(52)].map(|d| d as usize);
    if file_origin != origin || f32_at(40) != cell || file_dims != dims {
        return Err("its grid is not the one this scene's bounds give".into());
    }
    let values: Vec<f32> = body[HEADER..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if values.iter().any(|v| !(0.0..=1.0).contains(v)) {
        return Err("it holds values outside 0..1".into());
    }
    Ok(SkyVolume {
        origin,
        cell,
        dims,
        values,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two volumes computed alike: the same up to the order of the threads' sums.
    fn close(a: &[f32], b: &[f32]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
    }

    /// The lone fir of the tests' scenes.
    fn small() -> (Scene, World) {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lone_tree.toml");
        let scene = Scene::load(&path).expect("scene");
        let world = scene.build_world().expect("world");
        (scene, world)
    }

    #[test]
    fn a_kept_volume_comes_back_as_computed_and_a_damaged_one_is_computed_again() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (scene, world) = small();
        let first = sky_volume_in(dir.path(), &scene, &world, 8, true);
        let path = sky_path_in(dir.path(), &scene, 8, true);
        assert!(path.exists());
        let key = super::super::cache::scene_hash(&scene);
        let bounds = sky_visibility::bounds_of(&world, true);
        let grid = SkyVolume::grid(&bounds, true);
        let again = read(&path, key, 8, true, grid).expect("the file it wrote");
        assert_eq!(
            (again.origin, again.cell, again.dims),
            (first.origin, first.cell, first.dims)
        );
        assert!(again.values == first.values, "read back bit for bit");
        // Other directions, another terrain flag or another scene: not this file.
        assert!(read(&path, key, 16, true, grid).is_err());
        assert!(read(&path, key, 8, false, grid).is_err());
        assert!(read(&path, key ^ 1, 8, true, grid).is_err());
        // A flipped byte fails the checksum; a truncated file its size; both are computed
        // again and replaced.
        let mut bytes = std::fs::read(&path).expect("read");
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x40;
        std::fs::write(&path, &bytes).expect("write");
        assert!(
            read(&path, key, 8, true, grid)
                .unwrap_err()
                .contains("checksum")
        );
        let fixed = sky_volume_in(dir.path(), &scene, &world, 8, true);
        assert!(close(&fixed.values, &first.values), "computed again");
        assert!(read(&path, key, 8, true, grid).is_ok(), "replaced");
        let mut moved = grid;
        moved.0.x += 1.0;
        assert!(
            read(&path, key, 8, true, moved)
                .unwrap_err()
                .contains("grid"),
            "another grid"
        );
        std::fs::write(&path, &bytes[..10]).expect("write");
        assert!(
            read(&path, key, 8, true, grid)
                .unwrap_err()
                .contains("bytes")
        );
        // An unwritable folder still gives the volume.
        let blocked = dir.path().join("file");
        std::fs::write(&blocked, b"x").expect("write");
        let v = sky_volume_in(&blocked, &scene, &world, 8, true);
        assert!(close(&v.values, &first.values), "computed");
    }
}
