//! The `surfel` method's CPU work: per tree in view, its LDC tree walked from the root,
//! each block culled against the frustum and drawn at the coarsest level whose spacing
//! projects to at most `surfel_px` pixels (the paper's traversal), and the tree's record
//! (placement, tint, VCM factors).

use glam::{Mat4, Vec3};

use super::gpu::{SurfelItem, SurfelTreeGpu};
use super::settings::{SurfelSettings, SurfelStats};
use crate::format::SurfelSet;
use crate::model::mesh::Aabb;
use crate::render::method::view::PrepareView;
use crate::render::vcm_shading::{Shade, TreeShade};
use crate::render::world_gpu::TreeGpu;

/// The frame's blocks and trees.
#[derive(Default)]
pub struct SurfelFrame {
    pub items: Vec<SurfelItem>,
    pub trees: Vec<SurfelTreeGpu>,
    pub stats: SurfelStats,
}

/// Distance from `p` to the box `b` (0 inside).
fn distance_to(b: &Aabb, p: Vec3) -> f32 {
    (b.min - p).max(p - b.max).max(Vec3::ZERO).length()
}

/// The blocks of `tree` (placed by `model`, of uniform scale `scale`) that `view` draws:
/// from the roots down, each in the frustum, at the coarsest level whose world spacing is
/// at most `surfel_px` pixels at the block's nearest point; `emit(node)` for each.
pub fn walk(
    tree: &SurfelSet,
    model: &Mat4,
    scale: f32,
    view: &PrepareView<'_>,
    surfel_px: f32,
    emit: &mut dyn FnMut(usize),
) {
    let eye = view.camera.position;
    let perspective = view.camera.ortho.is_none() && view.focal_px > 0.0;
    let mut stack: Vec<u32> = tree.roots.clone();
    while let Some(n) = stack.pop() {
        let Some(node) = tree.nodes.get(n as usize) else {
            continue;
        };
        let world = node.bounds.transformed(*model);
        if !view.frustum.intersects(&world) {
            continue;
        }
        let spacing = tree.spacing(node.level) * scale;
        let fine_enough = perspective
            && crate::lod::projected_px(spacing, view.focal_px, distance_to(&world, eye))
                <= surfel_px;
        if node.level == 0 || node.children.is_empty() || fine_enough {
            emit(n as usize);
        } else {
            stack.extend_from_slice(&node.children);
        }
    }
}

/// Per species, trees with their opacity as geometry (1: whole).
pub type FadedTrees = Vec<Vec<(u32, f32)>>;

/// The share of the fade over which a tree's geometry comes in, below `geometry_px`.
const GEOMETRY_FADE: f32 = 0.2;

/// The trees of `visible` (per species) drawn as geometry, per species with their opacity
/// (1: whole): those whose finest surfels (`species`' level-0 spacing, placed) project above
/// `geometry_px` pixels at the nearest point of their bounds (`bounds`, per tree), faded in
/// over the last fifth before it; and the rest of `visible`, the trees drawn as surfels
/// (those fading in too).
pub fn near_geometry(
    species: &[(SurfelSet, u32)],
    trees: &[TreeGpu],
    bounds: &[Aabb],
    visible: &[Vec<u32>],
    view: &PrepareView<'_>,
    geometry_px: f32,
) -> (FadedTrees, Vec<Vec<u32>>) {
    let mut geometry = vec![Vec::new(); visible.len()];
    let mut surfels = vec![Vec::new(); visible.len()];
    let on = geometry_px > 0.0 && view.camera.ortho.is_none() && view.focal_px > 0.0;
    for (sp, list) in visible.iter().enumerate() {
        for &t in list {
            let opacity = match (
                on,
                species.get(sp),
                trees.get(t as usize),
                bounds.get(t as usize),
            ) {
                (true, Some((tree, _)), Some(data), Some(b)) => {
                    let scale = Mat4::from_cols_array_2d(&data.model)
                        .x_axis
                        .truncate()
                        .length();
                    let z = distance_to(b, view.camera.position);
                    let px = crate::lod::projected_px(tree.spacing0 * scale, view.focal_px, z);
                    let start = geometry_px * (1.0 - GEOMETRY_FADE);
                    ((px - start) / (geometry_px - start)).clamp(0.0, 1.0)
                }
                _ => 0.0,
            };
            if opacity > 0.0 {
                geometry[sp].push((t, opacity));
            }
            if opacity < 1.0 {
                surfels[sp].push(t);
            }
        }
    }
    (geometry, surfels)
}

/// The frame of `visible` trees (per species, indices into `trees`): per species its LDC
/// tree and where its surfels start (`species`), and `shade(t, species, model)` the tree's
/// VCM factors and box (None: unshaded).
pub fn prepare(
    species: &[(SurfelSet, u32)],
    volume_offsets: &[u32],
    trees: &[TreeGpu],
    visible: &[Vec<u32>],
    view: &PrepareView<'_>,
    settings: &SurfelSettings,
    shade: &mut TreeShade<'_>,
) -> SurfelFrame {
    let mut f = SurfelFrame::default();
    f.stats.finest = u32::MAX;
    for (sp, list) in visible.iter().enumerate() {
        let Some((tree, base)) = species.get(sp) else {
            continue;
        };
        for &t in list {
            let Some(data) = trees.get(t as usize) else {
                continue;
            };
            let model = Mat4::from_cols_array_2d(&data.model);
            let scale = model.x_axis.truncate().length();
            let record = f.trees.len() as u32;
            let before = f.items.len();
            let tolerance = settings.tolerance;
            walk(tree, &model, scale, view, settings.surfel_px, &mut |n| {
                let node = &tree.nodes[n];
                f.items.push(SurfelItem {
                    tree: record,
                    first: base + node.first,
                    count: node.count,
                    tolerance: tolerance * tree.spacing(node.level) * scale,
                    level: node.level,
                    spacing: tree.spacing(node.level) * scale,
                    _pad: [0; 2],
                });
                f.stats.surfels += u64::from(node.count);
                f.stats.finest = f.stats.finest.min(node.level);
                f.stats.coarsest = f.stats.coarsest.max(node.level);
            });
            if f.items.len() == before {
                continue;
            }
            let (s, vbox) = shade(t as usize, sp, &model).unwrap_or((Shade::NONE, tree.bounds));
            let vsize = vbox.extent().max(Vec3::splat(1e-6));
            let corners = |c: &[f32; 8]| [[c[0], c[1], c[2], c[3]], [c[4], c[5], c[6], c[7]]];
            let mut direct = s.direct;
            let mut sky = s.sky;
            for k in 0..8 {
                direct[k] *= s.parent_direct;
                sky[k] *= s.parent_sky;
            }
            f.trees.push(SurfelTreeGpu {
                model: data.model,
                qmin: tree.bounds.min.to_array(),
                instance: t,
                qsize: tree.bounds.extent().to_array(),
                scale,
                tint: [data.tint[0], data.tint[1], data.tint[2]],
                _pad0: 0.0,
                vcm_min: vbox.min.to_array(),
                _pad1: 0.0,
                vcm_inv_size: vsize.recip().to_array(),
                _pad2: 0.0,
                vcm_direct: corners(&direct),
                vcm_sky: corners(&sky),
                vol_origin: tree.density.origin.to_array(),
                vol_voxel: tree.density.voxel,
                vol_dims: tree.density.dims,
                vol_offset: volume_offsets.get(sp).copied().unwrap_or(0),
            });
        }
    }
    f.stats.trees = f.trees.len() as u32;
    f.stats.blocks = f.items.len() as u32;
    if f.items.is_empty() {
        f.stats.finest = 0;
    }
    f
}
