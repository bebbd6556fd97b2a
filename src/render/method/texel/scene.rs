//! The species' texel volumes packed into one 3D texture: where each volume and its
//! mip levels sit.

use glam::{UVec3, Vec3};

use crate::format::{Baked, TexelVolume};
use crate::render::target::{linear_to_srgb, srgb_lut};
use crate::sphere::DirectionSet;
use crate::{Error, Result};

/// Where one species' volumes lie, in its frame and in the 3D texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeciesVolume {
    pub box_min: Vec3,
    pub box_size: Vec3,
    pub voxel: f32,
    pub dims: UVec3,
    /// uvw of volume 0's first voxel corner, uvw extent of one volume, w between volumes.
    pub atlas_origin: Vec3,
    pub atlas_extent: Vec3,
    pub volume_dw: f32,
}

/// What the `texel` method knows of a scene on the CPU.
pub struct TexelScene {
    species: Vec<Option<SpeciesVolume>>,
    pub(super) lights: DirectionSet,
    /// The 3D texture's size in voxels and its mip levels.
    atlas: UVec3,
    pub(super) mips: u32,
    /// Per species, where each of its volumes starts in the texture (voxels).
    slots: Vec<Vec<UVec3>>,
}

/// Slot sizes are rounded up to a multiple of this, so that the mip levels of one volume
/// never mix with its neighbours'.
const SLOT_ALIGN: u32 = 8;
/// Mip levels of the volumes (level k halves each side k times; 8 = 2^3).
const MIPS: u32 = 4;

impl TexelScene {
    /// The layout of `baked`'s texel volumes for `world`, or an error naming what does not
    /// fit (a species without volumes, a light count unlike the bake's, too large a
    /// texture for `max_dim`).
    pub fn new(baked: &Baked, species_count: usize, max_dim: u32) -> Result<Self> {
        let lights = baked.settings.lights;
        let mut species = vec![None; species_count];
        let mut volumes: Vec<&TexelVolume> = Vec::new();
        for t in &baked.texels {
            let s = t.species as usize;
            if s >= species.len() {
                return Err(Error::BadInput(format!(
                    "the bake has a texel volume for species {s} but the scene has {}",
                    species.len()
                )));
            }
            if t.lights != lights {
                return Err(Error::BadInput(format!(
                    "a texel volume has {} lights where the bake has {lights}",
                    t.lights
                )));
            }
            volumes.push(t);
        }
        if volumes.len() != species_count {
            return Err(Error::BadInput(format!(
                "the bake has texel volumes for {} of the scene's {} species: bake again with texel_resolution above 0",
                volumes.len(),
                species_count
            )));
        }
        let round = |v: u32| v.div_ceil(SLOT_ALIGN) * SLOT_ALIGN;
        let slot = volumes
            .iter()
            .fold(UVec3::ZERO, |m, t| m.max(UVec3::from(t.dims)))
            .map(round);
        let per_species = lights + 1;
        let count = volumes.len() as u32 * per_species;
        // Volumes along w, then further columns along u; a species' volumes never straddle
        // two columns (the shader steps between them along w), so a column holds whole
        // species (three species of three variants need 3 columns of 2048).
        let species_per_column = max_dim / (slot.z.max(1) * per_species);
        if species_per_column == 0 {
            return Err(Error::BadInput(format!(
                "the {per_species} texel volumes of one species need {} voxels along one side but this GPU allows {max_dim}; bake with a lower texel_resolution or fewer lights",
                slot.z * per_species
            )));
        }
        let per_column = species_per_column * per_species;
        let columns = count.div_ceil(per_column);
        let atlas = UVec3::new(slot.x * columns, slot.y, slot.z * count.min(per_column));
        if atlas.max_element() > max_dim {
            return Err(Error::BadInput(format!(
                "the texel volumes need a {}x{}x{} texture but this GPU allows {max_dim} per side; bake with a lower texel_resolution",
                atlas.x, atlas.y, atlas.z
            )));
        }
        let lights_set = DirectionSet::with_count(lights as usize)
            .map_err(|e| Error::BadInput(e.to_string()))?;
        let mut slots = vec![Vec::new(); species_count];
        let size = atlas.as_vec3();
        for (k, t) in volumes.iter().enumerate() {
            let s = t.species as usize;
            let mut starts = Vec::with_capacity(per_species as usize);
            for v in 0..per_species {
                let i = k as u32 * per_species + v;
                starts.push(UVec3::new(
                    (i / per_column) * slot.x,
                    0,
                    (i % per_column) * slot.z,
                ));
            }
            let dims = UVec3::from(t.dims);
            let first = starts[0];
            // A species' volumes sit in one column when they fit; otherwise w steps are
            // not uniform and the shader's volume_dw would be wrong.
            if starts.iter().any(|p| p.x != first.x) {
                return Err(Error::BadInput(format!(
                    "the texel volumes of species {s} do not fit one column of a {max_dim}-voxel texture; bake with a lower texel_resolution"
                )));
            }
            species[s] = Some(SpeciesVolume {
                box_min: Vec3::from(t.box_min),
                box_size: dims.as_vec3() * t.voxel,
                voxel: t.voxel,
                dims,
                atlas_origin: first.as_vec3() / size,
                atlas_extent: dims.as_vec3() / size,
                volume_dw: slot.z as f32 / size.z,
            });
            slots[s] = starts;
        }
        Ok(Self {
            species,
            lights: lights_set,
            atlas,
            mips: MIPS,
            slots,
        })
    }

    pub fn species(&self, s: usize) -> Option<&SpeciesVolume> {
        self.species.get(s).and_then(|v| v.as_ref())
    }

    /// The 3D texture's side in voxels.
    pub fn atlas_size(&self) -> UVec3 {
        self.atlas
    }

    /// Bytes of the 3D texture with its mip levels.
    pub fn texture_bytes(&self) -> u64 {
        (0..self.mips)
            .map(|l| {
                let d = (self.atlas >> l).max(UVec3::ONE);
                u64::from(d.x) * u64::from(d.y) * u64::from(d.z) * 4
            })
            .sum()
    }

    /// The whole texture's level 0 then each mip level (RGBA8, sRGB, premultiplied), box
    /// filtered in linear light. Slots are multiples of 8 voxels, so no level mixes two
    /// volumes.
    pub fn atlas_levels(&self, baked: &Baked) -> Vec<(UVec3, Vec<u8>)> {
        let a = self.atlas;
        let mut level0 = vec![0u8; (a.x * a.y * a.z * 4) as usize];
        for t in &baked.texels {
            let Some(starts) = self.slots.get(t.species as usize) else {
                continue;
            };
            let d = UVec3::from(t.dims);
            let per = (d.x * d.y * d.z * 4) as usize;
            for (v, start) in starts.iter().enumerate() {
                let Some(src) = t.voxels.get(v * per..(v + 1) * per) else {
                    continue;
                };
                for z in 0..d.z {
                    for y in 0..d.y {
                        let from = (((z * d.y + y) * d.x) * 4) as usize;
                        let to =
                            ((((start.z + z) * a.y + start.y + y) * a.x + start.x) * 4) as usize;
                        let row = (d.x * 4) as usize;
                        level0[to..to + row].copy_from_slice(&src[from..from + row]);
                    }
                }
            }
        }
        let mut levels = vec![(a, level0)];
        let lut = srgb_lut();
        for _ in 1..self.mips {
            let Some((size, prev)) = levels.last() else {
                break;
            };
            let next = (*size >> 1u32).max(UVec3::ONE);
            let mut out = vec![0u8; (next.x * next.y * next.z * 4) as usize];
            for z in 0..next.z {
                for y in 0..next.y {
                    for x in 0..next.x {
                        let mut acc = [0.0f32; 4];
                        let mut n = 0.0;
                        for dz in 0..2 {
                            for dy in 0..2 {
                                for dx in 0..2 {
                                    let (sx, sy, sz) = (2 * x + dx, 2 * y + dy, 2 * z + dz);
                                    if sx >= size.x || sy >= size.y || sz >= size.z {
                                        continue;
                                    }
                                    let i = (((sz * size.y + sy) * size.x + sx) * 4) as usize;
                                    for c in 0..3 {
                                        acc[c] += lut[prev[i + c] as usize];
                                    }
                                    acc[3] += f32::from(prev[i + 3]) / 255.0;
                                    n += 1.0;
                                }
                            }
                        }
                        let o = (((z * next.y + y) * next.x + x) * 4) as usize;
                        for c in 0..3 {
                            out[o + c] = linear_to_srgb(acc[c] / n);
                        }
                        out[o + 3] = (acc[3] / n * 255.0 + 0.5) as u8;
                    }
                }
            }
            levels.push((next, out));
        }
        levels
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::BakeSettings;
    use crate::model::{TreeModel, World, preset};

    /// Nine prototypes (three species of three variants) with 6 lights: 63 volumes of up
    /// to 64 voxels, more than one 2048-voxel column holds. Each species' volumes stay in
    /// one column, every slot is distinct and inside the texture.
    #[test]
    fn many_prototypes_pack_into_columns_of_whole_species() {
        let tree = TreeModel::generate(&preset("broadleaf").unwrap(), 1).unwrap();
        let mut world = World::lone(tree.clone(), 10.0);
        world.species = vec![tree; 9];
        let lights = 6;
        let dims = [58, 64, 58];
        let texels = (0..9)
            .map(|s| TexelVolume {
                species: s,
                lights,
                dims,
                box_min: [0.0; 3],
                voxel: 0.2,
                voxels: Vec::new(),
            })
            .collect();
        let baked = Baked {
            scene_hash: 0,
            settings: BakeSettings {
                views: 18,
                tree_views: 18,
                lights,
                resolution: 64,
                supersample: 4,
                vcm_resolution: 32,
                texel_resolution: 64,
                impostor_frames: 0,
                impostor_resolution: 64,
                impostor_layout: Default::default(),
                compress: false,
                surfel_budget: 0,
            },
            btf: Vec::new(),
            vcm: Vec::new(),
            texels,
            impostors: Vec::new(),
            surfels: Vec::new(),
        };
        let scene = TexelScene::new(&baked, world.species.len(), 2048).unwrap();
        let atlas = scene.atlas_size();
        assert!(atlas.max_element() <= 2048, "{atlas}");
        let mut seen = std::collections::HashSet::new();
        for s in 0..9 {
            let starts = &scene.slots[s];
            assert_eq!(starts.len(), 7);
            assert!(starts.iter().all(|p| p.x == starts[0].x), "{starts:?}");
            for p in starts {
                assert!(seen.insert(*p), "slot {p} used twice");
                assert!(
                    (*p + UVec3::from(dims)).cmple(atlas).all(),
                    "{p} outside {atlas}"
                );
            }
        }
        // One species' volumes cannot fit at all: a clear error.
        let e = TexelScene::new(&baked, world.species.len(), 256)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("texel_resolution"), "{e}");
    }
}
