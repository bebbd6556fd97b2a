//! The twig and main-branch levels of an imported tree, where its file gives them: the mesh
//! the file places most often (at least [`MIN_TWIGS`] times) is the twig; the mesh placed
//! at least twice whose nodes hold the twigs as descendants is the main branch, when every
//! main branch carries the same twigs in its own frame (canopy's levels are one twig and
//! one main branch prototype, instanced). Everything else is the trunk. `canopy export`
//! writes its trees this way, so a preset comes back with its three levels.
//!
//! Where the file does not have that shape the reason is returned, and the tree keeps the
//! tree level only (drawn whole as geometry where its tree billboard is too coarse).

use glam::{Mat3, Mat4};

use super::Material;
use crate::model::mesh::Mesh;

/// Fewest placements of one mesh that make it the twig.
pub const MIN_TWIGS: usize = 4;
/// Largest difference between two main branches' twig transforms (each element, relative
/// to the transforms' scale) for them to count as the same branch.
const SAME_TWIGS: f32 = 1e-3;

/// One placement of a mesh by a node.
#[derive(Clone, Debug)]
pub struct Placement {
    /// The file's mesh index and its name for messages.
    pub mesh: usize,
    pub mesh_name: String,
    pub node_name: String,
    /// Node transform in the tree frame.
    pub world: Mat4,
    /// The nearest ancestor node that places a mesh, as an index into the placements.
    pub parent: Option<usize>,
}

/// Triangles of one part, sorted by material, with each triangle's material.
#[derive(Clone, Debug, Default)]
pub struct Part {
    pub mesh: Mesh,
    pub triangle_materials: Vec<u32>,
}

impl Part {
    /// The meshes of `per_material` (indexed by material) one after another, each vertex
    /// flagged as foliage where its material is.
    pub fn combine(per_material: &[Mesh], materials: &[Material]) -> Part {
        let mut out = Part::default();
        for (m, part) in per_material.iter().enumerate() {
            let foliage = if materials.get(m).is_some_and(|m| m.foliage) {
                1.0
            } else {
                0.0
            };
            let first = out.mesh.vertices.len();
            out.mesh.append(part, Mat4::IDENTITY);
            for v in &mut out.mesh.vertices[first..] {
                v.foliage = foliage;
            }
            out.triangle_materials
                .extend(std::iter::repeat_n(m as u32, part.triangle_count()));
        }
        out
    }
}

/// An imported tree's three levels, as [`crate::model::TreeModel`] holds them.
#[derive(Clone, Debug)]
pub struct ImportedLevels {
    /// The twig mesh in its own frame.
    pub twig: Part,
    /// The main branch's own mesh (its limb) in its own frame.
    pub limb: Part,
    /// Everything else, in the tree frame.
    pub trunk: Part,
    /// Twigs of one main branch, in its frame.
    pub branch_twigs: Vec<Mat4>,
    /// Main branches in the tree frame.
    pub tree_branches: Vec<Mat4>,
    /// Twigs on no main branch, in the tree frame.
    pub tree_twigs: Vec<Mat4>,
    /// How they were found, for `info` and the gallery.
    pub found: String,
}

/// The levels of the tree whose placements are `placements`, each mesh's triangles in its
/// own frame being `local[mesh]` (per material); the reason when the file has none.
pub fn find(
    placements: &[Placement],
    local: &dyn Fn(usize) -> Vec<Mesh>,
    materials: &[Material],
) -> Result<ImportedLevels, String> {
    let mut uses: std::collections::BTreeMap<usize, usize> = Default::default();
    for p in placements {
        *uses.entry(p.mesh).or_default() += 1;
    }
    // The twig: the mesh placed most often (the lower index on a tie).
    let (twig_mesh, twig_uses) = uses
        .iter()
        .map(|(&m, &n)| (m, n))
        .max_by_key(|&(m, n)| (n, std::cmp::Reverse(m)))
        .ok_or("the file places no mesh")?;
    if twig_uses < MIN_TWIGS {
        return Err(format!(
            "no mesh is placed {MIN_TWIGS} times or more (the most: {twig_uses}); a twig level is \
             a mesh the file places many times (leaf or twig cards as one instanced mesh)"
        ));
    }
    let twig_name = name_of(placements, twig_mesh);
    let twigs: Vec<usize> = (0..placements.len())
        .filter(|&i| placements[i].mesh == twig_mesh)
        .collect();
    // The main branch: the mesh most twigs hang from, placed at least twice.
    let mut holders: std::collections::BTreeMap<usize, usize> = Default::default();
    for &t in &twigs {
        if let Some(p) = placements[t].parent
            && placements[p].mesh != twig_mesh
        {
            *holders.entry(placements[p].mesh).or_default() += 1;
        }
    }
    let branch_mesh = holders
        .iter()
        .max_by_key(|&(&m, &n)| (n, std::cmp::Reverse(m)))
        .map(|(&m, _)| m)
        .filter(|m| uses.get(m).copied().unwrap_or(0) >= 2)
        .ok_or_else(|| {
            format!(
                "the twigs (mesh {twig_name}, placed {twig_uses} times) hang from no mesh placed \
                 twice or more; a main-branch level is a mesh placed several times with the \
                 twigs as its nodes' children"
            )
        })?;
    let branch_name = name_of(placements, branch_mesh);
    let branches: Vec<usize> = (0..placements.len())
        .filter(|&i| placements[i].mesh == branch_mesh)
        .collect();

    // Each branch's twigs in its own frame, which must be the same for every branch.
    let mut branch_twigs: Option<Vec<Mat4>> = None;
    for &b in &branches {
        let placed = &placements[b];
        check_similarity(placed)?;
        let to_branch = placed.world.inverse();
        let mine: Vec<Mat4> = twigs
            .iter()
            .filter(|&&t| placements[t].parent == Some(b))
            .map(|&t| to_branch * placements[t].world)
            .collect();
        match &branch_twigs {
            None => branch_twigs = Some(mine),
            Some(first) => {
                let same = first.len() == mine.len()
                    && first.iter().zip(&mine).all(|(a, b)| {
                        let tolerance = SAME_TWIGS * a.x_axis.truncate().length().max(1.0);
                        a.abs_diff_eq(*b, tolerance)
                    });
                if !same {
                    return Err(format!(
                        "the main branches (mesh {branch_name}, {} of them) do not all carry the \
                         same twigs ({} carries {}, {} carries {}); canopy's main-branch level is \
                         one branch placed many times",
                        branches.len(),
                        placements[branches[0]].node_name,
                        first.len(),
                        placed.node_name,
                        mine.len()
                    ));
                }
            }
        }
    }
    let branch_twigs = branch_twigs.unwrap_or_default();
    if branch_twigs.is_empty() {
        return Err(format!(
            "the main branches (mesh {branch_name}) carry no twigs of mesh {twig_name}"
        ));
    }
    let mut tree_twigs = Vec::new();
    for &t in &twigs {
        check_similarity(&placements[t])?;
        let on_branch = placements[t]
            .parent
            .is_some_and(|p| placements[p].mesh == branch_mesh);
        if !on_branch {
            tree_twigs.push(placements[t].world);
        }
    }

    // The trunk: every other placement, in the tree frame, by material.
    let mut trunk_parts: Vec<Mesh> = vec![Mesh::default(); materials.len()];
    let mut cache: std::collections::HashMap<usize, Vec<Mesh>> = Default::default();
    for p in placements {
        if p.mesh == twig_mesh || p.mesh == branch_mesh {
            continue;
        }
        let parts = cache.entry(p.mesh).or_insert_with(|| local(p.mesh));
        for (target, part) in trunk_parts.iter_mut().zip(parts.iter()) {
            target.append(part, p.world);
        }
    }
    let found = format!(
        "found in the file: mesh {twig_name} as the twig ({twig_uses} placed), mesh \
         {branch_name} as the main branch ({} placed, {} twigs each)",
        branches.len(),
        branch_twigs.len()
    );
    Ok(ImportedLevels {
        twig: Part::combine(&local(twig_mesh), materials),
        limb: Part::combine(&local(branch_mesh), materials),
        trunk: Part::combine(&trunk_parts, materials),
        branch_twigs,
        tree_branches: branches.iter().map(|&b| placements[b].world).collect(),
        tree_twigs,
        found,
    })
}

fn name_of(placements: &[Placement], mesh: usize) -> String {
    placements
        .iter()
        .find(|p| p.mesh == mesh)
        .map_or_else(|| mesh.to_string(), |p| p.mesh_name.clone())
}

/// Refuses a placement that is not a rotation, a uniform scale and a translation: the
/// levels are drawn instanced, their normals turned by the placement itself.
fn check_similarity(p: &Placement) -> Result<(), String> {
    let m = Mat3::from_mat4(p.world);
    let lengths = [m.x_axis.length(), m.y_axis.length(), m.z_axis.length()];
    let (lo, hi) = lengths
        .iter()
        .fold((f32::MAX, 0.0f32), |(lo, hi), &l| (lo.min(l), hi.max(l)));
    let square =
        m.x_axis.dot(m.y_axis).abs() + m.y_axis.dot(m.z_axis).abs() + m.z_axis.dot(m.x_axis).abs();
    if lo <= 0.0 || hi > lo * 1.001 || square > 1e-3 * hi * hi || m.determinant() <= 0.0 {
        return Err(format!(
            "{} places mesh {} stretched or mirrored; canopy's levels take rotations and uniform \
             scales only",
            p.node_name, p.mesh_name
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec3};

    const TRUNK: usize = 0;
    const LIMB: usize = 1;
    const TWIG: usize = 2;

    fn place(mesh: usize, world: Mat4, parent: Option<usize>) -> Placement {
        Placement {
            mesh,
            mesh_name: format!("{mesh}"),
            node_name: format!("node of {mesh}"),
            world,
            parent,
        }
    }

    /// A trunk, `branches` limbs each carrying the same three twigs, and two twigs on the
    /// trunk (as `canopy export` writes a tree).
    fn tree(branches: usize) -> Vec<Placement> {
        let mut p = vec![place(TRUNK, Mat4::IDENTITY, None)];
        let twigs = [
            Mat4::from_translation(Vec3::new(0.0, 0.0, 0.5)),
            Mat4::from_rotation_translation(Quat::from_rotation_z(1.0), Vec3::new(0.0, 0.0, 1.0)),
            Mat4::from_scale_rotation_translation(
                Vec3::splat(0.7),
                Quat::from_rotation_y(0.4),
                Vec3::new(0.0, 0.0, 1.5),
            ),
        ];
        for b in 0..branches {
            let world = Mat4::from_scale_rotation_translation(
                Vec3::splat(1.0 - 0.1 * b as f32),
                Quat::from_rotation_y(b as f32),
                Vec3::new(0.0, 2.0 + b as f32, 0.0),
            );
            p.push(place(LIMB, world, None));
            let at = p.len() - 1;
            for t in twigs {
                p.push(place(TWIG, world * t, Some(at)));
            }
        }
        for y in [9.0, 10.0] {
            p.push(place(TWIG, Mat4::from_translation(Vec3::Y * y), None));
        }
        p
    }

    fn find_in(p: &[Placement]) -> Result<ImportedLevels, String> {
        find(p, &|_| Vec::new(), &[])
    }

    #[test]
    fn an_exported_shape_gives_its_twig_and_branch() {
        let p = tree(3);
        let l = find_in(&p).unwrap();
        assert_eq!(l.tree_branches.len(), 3);
        assert_eq!(l.branch_twigs.len(), 3);
        assert_eq!(l.tree_twigs.len(), 2);
        // Each branch times its twigs gives back where the file placed them.
        for (b, branch) in l.tree_branches.iter().enumerate() {
            for (t, twig) in l.branch_twigs.iter().enumerate() {
                let placed = p[1 + 4 * b + 1 + t].world;
                assert!((*branch * *twig).abs_diff_eq(placed, 1e-5));
            }
        }
        assert!(l.found.contains("3 placed, 3 twigs each"), "{}", l.found);
    }

    #[test]
    fn a_mesh_placed_once_has_no_levels() {
        let p = vec![place(TRUNK, Mat4::IDENTITY, None)];
        let why = find_in(&p).unwrap_err();
        assert!(why.contains("no mesh is placed 4 times"), "{why}");
    }

    #[test]
    fn twigs_on_no_repeated_mesh_have_no_branch_level() {
        // Twigs hanging from the trunk only.
        let mut p = vec![place(TRUNK, Mat4::IDENTITY, None)];
        for y in 0..6 {
            p.push(place(
                TWIG,
                Mat4::from_translation(Vec3::Y * y as f32),
                Some(0),
            ));
        }
        let why = find_in(&p).unwrap_err();
        assert!(why.contains("hang from no mesh placed twice"), "{why}");
    }

    #[test]
    fn branches_carrying_different_twigs_are_refused_as_levels() {
        let mut p = tree(3);
        // Move one twig of the second branch.
        p[6].world *= Mat4::from_translation(Vec3::X * 0.2);
        let why = find_in(&p).unwrap_err();
        assert!(why.contains("do not all carry the same twigs"), "{why}");
        // One twig fewer on the last branch.
        let mut p = tree(3);
        p.remove(12);
        let why = find_in(&p).unwrap_err();
        assert!(why.contains("carries 2"), "{why}");
    }

    #[test]
    fn stretched_or_mirrored_placements_are_refused_as_levels() {
        let mut p = tree(2);
        p[1].world *= Mat4::from_scale(Vec3::new(1.0, 2.0, 1.0));
        assert!(find_in(&p).unwrap_err().contains("stretched or mirrored"));
        let mut p = tree(2);
        let last = p.len() - 1;
        p[last].world = Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0));
        assert!(find_in(&p).unwrap_err().contains("stretched or mirrored"));
    }
}
