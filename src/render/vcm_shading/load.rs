//! Loading a bake's cube maps: each set matched to its tree instance, main branch, twig or
//! forest cell, and checked against the scene.

use glam::{Mat4, Vec3};

use super::VcmShading;
use super::cells::CellShading;
use super::maps::{Maps, ObjectVcm};
use crate::format::{Baked, VCM_CELL_SPECIES, VcmSet};
use crate::model::{Level, World};
use crate::vcm::billboard::AlphaSet;
use crate::vcm::cells::ForestCells;
use crate::vcm::{self, CORNERS};
use crate::{Error, Result};

impl VcmShading {
    /// The cube maps of `baked`, checked against `world`: every tree instance, main branch
    /// and twig needs its set. None when the bake holds no cube maps at all.
    pub fn new(baked: &Baked, world: &World) -> Result<Option<Self>> {
        if baked.vcm.is_empty() {
            return Ok(None);
        }
        let res = baked.settings.vcm_resolution;
        let mut slots = Slots::new(world);
        let cell_sets = baked
            .vcm
            .iter()
            .any(|s| s.species == VCM_CELL_SPECIES && s.level == Level::Tree);
        let cells = cell_sets.then(|| ForestCells::new(world));
        slots.cell_maps = (0..cells.as_ref().map_or(0, ForestCells::len))
            .map(|_| None)
            .collect();
        for set in &baked.vcm {
            slots.add(set, res, world)?;
        }
        let Slots {
            branches,
            twigs,
            trees,
            cell_maps,
            cell_res,
            bytes,
        } = slots;
        let (trees, cells) = match cells {
            None => (take_all(trees, "tree")?, None),
            Some(cells) => {
                if let Some(t) = trees.iter().position(Option::is_some) {
                    return Err(bad(format!(
                        "tree {t} has its own cube maps and the forest cells too"
                    )));
                }
                let maps = take_all(cell_maps, "forest cell")?;
                let alpha = tree_alpha(baked, world)?;
                let tree_corners = tree_corners(world)?;
                (
                    Vec::new(),
                    Some(CellShading {
                        cells,
                        res: cell_res.unwrap_or(res),
                        maps,
                        alpha,
                        trees: tree_corners,
                    }),
                )
            }
        };
        let branches = branches
            .into_iter()
            .map(|v| take_all(v, "main branch"))
            .collect::<Result<Vec<_>>>()?;
        let twigs = twigs
            .into_iter()
            .map(|v| take_all(v, "twig"))
            .collect::<Result<Vec<_>>>()?;
        let tree_count = world.forest.instances.len();
        let tree_sky = match &cells {
            Some(c) => c.sky(),
            None => trees.iter().map(|t| t.sky).collect(),
        };
        Ok(Some(Self {
            res,
            tree_direct: vec![[1.0; CORNERS]; tree_count],
            tree_sky,
            branches,
            twigs,
            trees,
            cells,
            sun: None,
            bytes,
        }))
    }
}

/// The error for cube maps that do not fit the scene.
fn bad(m: String) -> Error {
    Error::BadInput(format!(
        "baked visibility cube maps do not fit the scene: {m}; re-bake with `canopy bake`"
    ))
}

/// Every object's slot for its set while the bake's sets are matched to the scene, and the
/// bytes of the maps taken.
struct Slots {
    /// Per species: main branches, then twigs (the reference branch's, then the trunk's).
    branches: Vec<Vec<Option<ObjectVcm>>>,
    twigs: Vec<Vec<Option<ObjectVcm>>>,
    /// Per tree instance.
    trees: Vec<Option<ObjectVcm>>,
    /// Per forest cell, and the cells' resolution.
    cell_maps: Vec<Option<ObjectVcm>>,
    cell_res: Option<u32>,
    bytes: u64,
}

impl Slots {
    /// An empty slot for every tree instance, main branch and twig of `world` (and no
    /// forest cell).
    fn new(world: &World) -> Self {
        let branches: Vec<Vec<Option<ObjectVcm>>> = world
            .species
            .iter()
            .map(|t| (0..t.tree_branches.len()).map(|_| None).collect())
            .collect();
        let twigs: Vec<Vec<Option<ObjectVcm>>> = world
            .species
            .iter()
            .map(|t| {
                (0..t.branch_twigs.len() + t.tree_twigs.len())
                    .map(|_| None)
                    .collect()
            })
            .collect();
        let trees: Vec<Option<ObjectVcm>> =
            (0..world.forest.instances.len()).map(|_| None).collect();
        Self {
            branches,
            twigs,
            trees,
            cell_maps: Vec::new(),
            cell_res: None,
            bytes: 0,
        }
    }

    /// Puts `set` in its object's slot, checked against `world` and the file's resolution
    /// `res`.
    fn add(&mut self, set: &VcmSet, res: u32, world: &World) -> Result<()> {
        if set.species == VCM_CELL_SPECIES && set.level == Level::Tree {
            return self.add_cell(set);
        }
        if set.resolution != res {
            return Err(bad(format!(
                "a set has resolution {} but the file says {res}",
                set.resolution
            )));
        }
        let sp = set.species as usize;
        let o = set.owner as usize;
        let slot = match set.level {
            Level::Tree => self
                .trees
                .get_mut(o)
                .filter(|_| world.forest.instances[o].species == set.species),
            Level::Branch => self.branches.get_mut(sp).and_then(|v| v.get_mut(o)),
            Level::Twig => self.twigs.get_mut(sp).and_then(|v| v.get_mut(o)),
        };
        let Some(slot) = slot else {
            return Err(bad(format!(
                "no {} {o} of species {sp} in this scene",
                set.level.name()
            )));
        };
        if slot.is_some() {
            return Err(bad(format!(
                "the {} {o} of species {sp} has two sets",
                set.level.name()
            )));
        }
        let opacity = opacity_maps(set)?;
        self.bytes += opacity.bytes();
        *slot = Some(ObjectVcm {
            opacity,
            sky: set.mean_opacity.map(|m| 1.0 - m),
        });
        Ok(())
    }

    /// Puts the forest cell's `set` in its slot.
    fn add_cell(&mut self, set: &VcmSet) -> Result<()> {
        if *self.cell_res.get_or_insert(set.resolution) != set.resolution {
            return Err(bad(format!(
                "forest cells have cube maps of resolutions {} and {}",
                self.cell_res.unwrap_or_default(),
                set.resolution
            )));
        }
        let o = set.owner as usize;
        let Some(slot) = self.cell_maps.get_mut(o) else {
            return Err(bad(format!(
                "no forest cell {o} in this scene ({} cells)",
                self.cell_maps.len()
            )));
        };
        if slot.is_some() {
            return Err(bad(format!("forest cell {o} has two sets")));
        }
        let opacity = opacity_maps(set)?;
        self.bytes += opacity.bytes();
        *slot = Some(ObjectVcm {
            opacity,
            sky: set.mean_opacity.map(|m| 1.0 - m),
        });
        Ok(())
    }
}

/// The maps of `set` as held: BC4 sets stay as stored (a read decodes the blocks it falls
/// in). The GPU's tables get the finer levels' maps a byte a texel, decoded when they are
/// made (`species_maps`).
fn opacity_maps(set: &VcmSet) -> Result<Maps> {
    if set.encoding == crate::format::MapEncoding::Bc4
        && set.expected_opacity_len() == Some(set.opacity.len() as u64)
    {
        return Ok(Maps::Bc4(set.opacity.clone()));
    }
    set.opacity_r8()
        .map(|o| Maps::R8(o.into_owned()))
        .ok_or_else(|| {
            bad(format!(
                "the cube maps of {} {} hold {} bytes, not what resolution {} in {:?} has",
                set.level.name(),
                set.owner,
                set.opacity.len(),
                set.resolution,
                set.encoding
            ))
        })
}

/// Every slot's object, or an error naming `what` has none.
fn take_all(v: Vec<Option<ObjectVcm>>, what: &str) -> Result<Vec<ObjectVcm>> {
    let missing = |what: &str| bad(format!("the {what} has no cube maps"));
    v.into_iter()
        .map(|o| o.ok_or_else(|| missing(what)))
        .collect::<Result<Vec<_>>>()
}

/// Per species: the tree level's sky-lit images as occluders.
fn tree_alpha(baked: &Baked, world: &World) -> Result<Vec<AlphaSet>> {
    (0..world.species.len())
        .map(|s| {
            let set = baked
                .btf
                .iter()
                .find(|b| b.species as usize == s && b.level == Level::Tree)
                .ok_or_else(|| bad(format!("species {s} has no tree-level BTF images")))?;
            AlphaSet::new(set)
        })
        .collect::<Result<Vec<_>>>()
}

/// Per tree: its species, its placement, and its box's 8 corners in the world (kept above
/// the terrain as the bake keeps cube maps).
fn tree_corners(world: &World) -> Result<Vec<(u32, Mat4, [Vec3; CORNERS])>> {
    (0..world.forest.instances.len())
        .map(|t| {
            let inst = &world.forest.instances[t];
            let m = inst.transform();
            let bounds = world
                .species
                .get(inst.species as usize)
                .ok_or_else(|| bad(format!("tree {t} has no species")))?
                .tree_bounds;
            let corners = std::array::from_fn(|k| {
                let mut p = m.transform_point3(vcm::corner(&bounds, k));
                p.y =
                    p.y.max(world.terrain.height_at(p.x, p.z) + vcm::GROUND_CLEARANCE);
                p
            });
            Ok((inst.species, m, corners))
        })
        .collect::<Result<Vec<_>>>()
}
