//! Tree species prototypes: grows one [`TreeModel`] from [`SpeciesParams`] and a seed as a
//! three-level hierarchy of instanced parts, kept un-flattened as in Meyer's thesis:
//! a twig (level 0, a stem carrying leaves or needles), a main branch (level 1, a limb
//! carrying twig instances) and a tree (level 2, a trunk carrying main-branch instances and
//! a few twigs of its own). The same hierarchy drives the geometry, the BTF levels and the
//! visibility cube maps.
//!
//! This file holds the prototype and what is read from it (counts, instance transforms,
//! flattened meshes); `grow` generates it.

mod grow;

use std::sync::Arc;

use glam::Mat4;

use super::gltf::{ImportedTree, Material};
use super::mesh::{Aabb, Mesh};
use super::species::FoliageKind;

/// Triangles per level, each level including all its children.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LevelCounts {
    /// One twig.
    pub twig: u64,
    /// One main branch: its limb and all its twigs.
    pub branch: u64,
    /// The whole tree.
    pub tree: u64,
}

/// Numbers of parts in one tree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PartCounts {
    /// Main-branch instances.
    pub main_branches: u64,
    /// Twig instances in the whole tree (on branches and on the trunk).
    pub twigs: u64,
    /// Leaves or needles in the whole tree.
    pub foliage: u64,
}

/// The bounds given to the twig and main-branch levels of a species that has none (an
/// imported tree whose file gives no hierarchy): a centimetre at the origin. Those levels
/// are not baked (the bake's `baked_levels`); `btf` draws the whole tree as geometry
/// where its tree level is too coarse.
pub const ABSENT_LEVEL_BOUNDS: Aabb = Aabb {
    min: glam::Vec3::splat(-0.005),
    max: glam::Vec3::splat(0.005),
};

/// One species prototype: a hierarchy of instanced parts (not flattened).
#[derive(Clone, Debug)]
pub struct TreeModel {
    /// Species name (set by [`crate::model::World::build`] from the scene; `generate` uses
    /// `conifer` or `broadleaf`).
    pub name: String,
    /// What the twigs carry.
    pub foliage: FoliageKind,
    /// Leaves or needles on one twig.
    pub foliage_per_twig: u32,
    /// Level 0: a stem with leaves or needles, in the twig's own frame (origin at the twig's
    /// base, growing along +Z, +Y its upper side).
    pub twig: Mesh,
    /// Level 1: the limb's own geometry in the main-branch frame (origin where it meets the
    /// trunk's axis, growing along +Z, +Y its upper side).
    pub branch_limb: Mesh,
    /// Twig instances in the main-branch frame.
    pub branch_twigs: Vec<Mat4>,
    /// Level 2: the trunk in the tree frame (origin at the ground, +Y up).
    pub trunk: Mesh,
    /// Main-branch instances in the tree frame (rotation and uniform scale).
    pub tree_branches: Vec<Mat4>,
    /// Twigs directly on the trunk (the leader at the top and its neighbours), tree frame.
    pub tree_twigs: Vec<Mat4>,
    /// Bounds of the twig in its own frame.
    pub twig_bounds: Aabb,
    /// Bounds of a main branch (limb and twigs) in its own frame.
    pub branch_bounds: Aabb,
    /// Bounds of the whole tree in the tree frame.
    pub tree_bounds: Aabb,
    /// An imported tree's materials and which of the trunk's triangles each covers; `None`
    /// for a procedural species (its vertices carry their colours, nothing is textured).
    pub surfaces: Option<Arc<Surfaces>>,
    /// An imported tree's levels: where they were found in its file, or why it has the tree
    /// level only. `None` for a procedural species.
    pub levels_note: Option<String>,
    /// Which variant of its scene entry it is (0: the first; the others follow it in the
    /// world's prototypes).
    pub variant: u32,
}

/// The look of an imported tree: its materials, and which triangles of each part are drawn
/// with each.
#[derive(Clone, Debug, PartialEq)]
pub struct Surfaces {
    pub materials: Vec<Material>,
    /// Runs of `trunk.indices`, one per material that has triangles, in index order.
    pub trunk: Vec<SurfaceRange>,
    /// Runs of `branch_limb.indices`.
    pub limb: Vec<SurfaceRange>,
    /// Runs of `twig.indices`.
    pub twig: Vec<SurfaceRange>,
}

/// The indices `first .. first + count` of a part, drawn with `material`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SurfaceRange {
    pub material: u32,
    pub first: u32,
    pub count: u32,
}

/// The runs of equal materials in a part whose triangles have `triangle_materials`.
fn ranges(triangle_materials: &[u32]) -> Vec<SurfaceRange> {
    let mut ranges: Vec<SurfaceRange> = Vec::new();
    for (t, &m) in triangle_materials.iter().enumerate() {
        match ranges.last_mut() {
            Some(r) if r.material == m => r.count += 3,
            _ => ranges.push(SurfaceRange {
                material: m,
                first: 3 * t as u32,
                count: 3,
            }),
        }
    }
    ranges
}

impl TreeModel {
    /// An imported tree as a species prototype: with the twig and main-branch levels its
    /// file gives ([`crate::model::gltf::levels`]), or of the tree level only, its whole mesh
    /// the trunk.
    pub fn from_imported(name: &str, imported: ImportedTree) -> TreeModel {
        let bounds = imported.mesh.bounds();
        let foliage = if imported.materials.iter().any(|m| m.cards) {
            FoliageKind::Needles
        } else {
            FoliageKind::Leaves
        };
        let (levels, note) = match imported.levels {
            Ok(l) => {
                let note = l.found.clone();
                (Some(l), note)
            }
            Err(why) => (None, format!("tree only: {why}")),
        };
        let Some(l) = levels else {
            return TreeModel {
                name: name.to_owned(),
                foliage,
                foliage_per_twig: 0,
                twig: Mesh::default(),
                branch_limb: Mesh::default(),
                branch_twigs: Vec::new(),
                trunk: imported.mesh,
                tree_branches: Vec::new(),
                tree_twigs: Vec::new(),
                twig_bounds: ABSENT_LEVEL_BOUNDS,
                branch_bounds: ABSENT_LEVEL_BOUNDS,
                tree_bounds: bounds,
                surfaces: Some(Arc::new(Surfaces {
                    materials: imported.materials,
                    trunk: ranges(&imported.triangle_materials),
                    limb: Vec::new(),
                    twig: Vec::new(),
                })),
                levels_note: Some(note),
                variant: 0,
            };
        };
        let twig_bounds = l.twig.mesh.bounds();
        let branch_bounds = l.branch_twigs.iter().fold(l.limb.mesh.bounds(), |b, m| {
            b.union(l.twig.mesh.bounds_transformed(*m))
        });
        TreeModel {
            name: name.to_owned(),
            foliage,
            foliage_per_twig: 0,
            twig: l.twig.mesh,
            branch_limb: l.limb.mesh,
            branch_twigs: l.branch_twigs,
            trunk: l.trunk.mesh,
            tree_branches: l.tree_branches,
            tree_twigs: l.tree_twigs,
            twig_bounds,
            branch_bounds,
            tree_bounds: bounds,
            surfaces: Some(Arc::new(Surfaces {
                materials: imported.materials,
                trunk: ranges(&l.trunk.triangle_materials),
                limb: ranges(&l.limb.triangle_materials),
                twig: ranges(&l.twig.triangle_materials),
            })),
            levels_note: Some(note),
            variant: 0,
        }
    }

    /// Whether the species has main-branch and twig levels of its own (a procedural one, or
    /// an imported tree whose file gives them).
    pub fn has_hierarchy(&self) -> bool {
        !self.twig.indices.is_empty()
    }

    /// Every twig instance of the tree in the tree frame: each branch transform times each
    /// of the branch's twig transforms, then the twigs on the trunk.
    pub fn twigs_in_tree_frame(&self) -> Vec<Mat4> {
        let mut out = Vec::with_capacity(
            self.tree_branches.len() * self.branch_twigs.len() + self.tree_twigs.len(),
        );
        for b in &self.tree_branches {
            out.extend(self.branch_twigs.iter().map(|t| *b * *t));
        }
        out.extend_from_slice(&self.tree_twigs);
        out
    }

    /// Triangles per level, each level including its children.
    pub fn triangle_counts(&self) -> LevelCounts {
        let twig = self.twig.triangle_count() as u64;
        let branch =
            self.branch_limb.triangle_count() as u64 + self.branch_twigs.len() as u64 * twig;
        let tree = self.trunk.triangle_count() as u64
            + self.tree_branches.len() as u64 * branch
            + self.tree_twigs.len() as u64 * twig;
        LevelCounts { twig, branch, tree }
    }

    /// Main branches, twigs and leaves/needles in the whole tree.
    pub fn counts(&self) -> PartCounts {
        let twigs = self.tree_branches.len() as u64 * self.branch_twigs.len() as u64
            + self.tree_twigs.len() as u64;
        PartCounts {
            main_branches: self.tree_branches.len() as u64,
            twigs,
            foliage: twigs * u64::from(self.foliage_per_twig),
        }
    }

    /// One main branch (limb and twigs) as a single mesh in the main-branch frame.
    pub fn flatten_branch(&self) -> Mesh {
        let mut m = self.branch_limb.clone();
        for t in &self.branch_twigs {
            m.append(&self.twig, *t);
        }
        m
    }

    /// The whole tree as a single mesh in the tree frame (the full-geometry reference).
    pub fn flatten(&self) -> Mesh {
        let counts = self.triangle_counts();
        let mut m = Mesh::default();
        m.indices.reserve(counts.tree as usize * 3);
        m.append(&self.trunk, Mat4::IDENTITY);
        let branch = self.flatten_branch();
        for b in &self.tree_branches {
            m.append(&branch, *b);
        }
        for t in &self.tree_twigs {
            m.append(&self.twig, *t);
        }
        m
    }
}
