//! Each species' part sets uploaded: a procedural part as one set, an imported tree's parts
//! as one set per material with its texture.

use glam::Mat4;

use super::{PartKind, PartLook, PartSet, SpeciesGpu};
use crate::model::mesh::Mesh;
use crate::render::GpuContext;

/// What the part sets of each species are made with.
pub(super) struct SpeciesUpload<'a> {
    pub(super) ctx: &'a GpuContext,
    pub(super) parts_layout: &'a wgpu::BindGroupLayout,
    /// The look of an untextured, one-sided part.
    pub(super) plain: PartLook<'a>,
    pub(super) white: &'a wgpu::TextureView,
    pub(super) sampler: &'a wgpu::Sampler,
    /// The material textures uploaded so far ([`split_surfaces`]).
    pub(super) uploaded: Vec<(*const crate::model::gltf::Rgba8Image, wgpu::TextureView)>,
}

impl SpeciesUpload<'_> {
    /// The trunk, limb and twig part sets of `tree`.
    pub(super) fn species(&mut self, tree: &crate::model::TreeModel) -> SpeciesGpu {
        let plain = self.plain;
        let twigs = tree.twigs_in_tree_frame();
        let limbs = &tree.tree_branches;
        let mut parts = self.part_sets(
            tree,
            (PartKind::Trunk, "trunk"),
            &tree.trunk,
            &[Mat4::IDENTITY],
            plain,
        );
        parts.extend(self.part_sets(
            tree,
            (PartKind::Limbs, "limbs"),
            &tree.branch_limb,
            limbs,
            plain,
        ));
        parts.extend(self.part_sets(
            tree,
            (PartKind::Twigs, "twigs"),
            &tree.twig,
            &twigs,
            PartLook {
                two_sided: true,
                ..plain
            },
        ));
        SpeciesGpu {
            name: tree.name.clone(),
            parts,
        }
    }

    /// The part sets of `tree`'s part `kind` (called `what`): a procedural part is one set;
    /// an imported tree's parts are one set per material, each with its texture.
    fn part_sets(
        &mut self,
        tree: &crate::model::TreeModel,
        (kind, what): (PartKind, &str),
        mesh: &Mesh,
        instances: &[Mat4],
        look: PartLook,
    ) -> Vec<PartSet> {
        let (ctx, parts_layout) = (self.ctx, self.parts_layout);
        let Some(surf) = tree.surfaces.as_deref() else {
            return PartSet::new(
                ctx,
                parts_layout,
                kind,
                &format!("{} {what}", tree.name),
                mesh,
                instances,
                look,
            )
            .into_iter()
            .collect();
        };
        let runs = match kind {
            PartKind::Trunk => &surf.trunk,
            PartKind::Limbs => &surf.limb,
            PartKind::Twigs => &surf.twig,
        };
        let (meshes, textures) = split_surfaces(ctx, mesh, runs, surf, &mut self.uploaded);
        runs.iter()
            .zip(meshes)
            .zip(textures)
            .filter_map(|((range, mesh), texture)| {
                let m = surf.materials.get(range.material as usize)?;
                PartSet::new(
                    ctx,
                    parts_layout,
                    kind,
                    &format!("{} {what} {}", tree.name, m.name),
                    &mesh,
                    instances,
                    PartLook {
                        two_sided: m.double_sided,
                        texture: texture.as_ref().unwrap_or(self.white),
                        sampler: self.sampler,
                        alpha_cutoff: m.alpha_cutoff,
                        textured: texture.is_some() || m.alpha_cutoff > 0.0,
                        ..self.plain
                    },
                )
            })
            .collect()
    }
}

/// A part of an imported tree cut into one mesh per surface range (each with only the
/// vertices it uses), and each range's material texture uploaded (each image once over
/// `uploaded`).
fn split_surfaces(
    ctx: &GpuContext,
    part: &Mesh,
    runs: &[crate::model::tree::SurfaceRange],
    surfaces: &crate::model::tree::Surfaces,
    uploaded: &mut Vec<(*const crate::model::gltf::Rgba8Image, wgpu::TextureView)>,
) -> (Vec<Mesh>, Vec<Option<wgpu::TextureView>>) {
    let mut meshes = Vec::with_capacity(runs.len());
    let mut textures = Vec::with_capacity(runs.len());
    for r in runs {
        let first = r.first as usize;
        let indices = part
            .indices
            .get(first..first + r.count as usize)
            .unwrap_or(&[]);
        let mut remap = std::collections::HashMap::new();
        let mut mesh = Mesh::default();
        for &i in indices {
            let Some(v) = part.vertices.get(i as usize) else {
                continue;
            };
            let j = *remap.entry(i).or_insert_with(|| mesh.push_vertex(*v));
            mesh.indices.push(j);
        }
        meshes.push(mesh);
        let image = surfaces
            .materials
            .get(r.material as usize)
            .and_then(|m| m.texture.as_ref());
        textures.push(image.map(|img| {
            let key = std::sync::Arc::as_ptr(img);
            match uploaded.iter().find(|(k, _)| *k == key) {
                Some((_, view)) => view.clone(),
                None => {
                    let view = crate::render::material::upload(ctx, "material", img);
                    uploaded.push((key, view.clone()));
                    view
                }
            }
        }));
    }
    (meshes, textures)
}
