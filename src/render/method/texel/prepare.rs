//! The `texel` method's CPU work for a frame: each visible tree's texel record, back to front.

use glam::{Mat3, Mat4, Vec3};

use super::scene::TexelScene;
use super::{TexelGpu, TexelSettings, TexelStats, polygons, stacks, tiles};
use crate::model::mesh::Aabb;
use crate::render::method::view::PrepareView;
use crate::render::vcm_shading::TreeShades;
use crate::render::world_gpu::TreeGpu;
use crate::slices::{self};

/// One frame's texels, back to front, and the count of those the eye is inside (the last
/// `inside` records).
pub struct TexelFrame {
    pub records: Vec<TexelGpu>,
    pub inside: u32,
    pub stats: TexelStats,
    /// In the stacks mode, each record's stack (same order) and the quads to draw.
    pub stacks: Vec<stacks::StackGpu>,
    pub quads: Vec<[u32; 2]>,
    /// Forest-cover tiles to draw first, back to front.
    pub tiles: Vec<tiles::TileGpu>,
    /// In the polygons mode, the slices' triangles, back to front.
    pub polygons: Vec<polygons::PolyVertex>,
}

/// The texels of the trees in `visible` (per species, indices into `trees`): slice counts,
/// lights, VCM factors (from `vcm`, the bake's BTF scene, when given), back to front,
/// at most `max` of them (the nearest kept). With `stack_atlas` (the stacks mode), each
/// texel's stack and level too.
#[allow(clippy::too_many_arguments)]
pub fn prepare(
    scene: &TexelScene,
    trees: &[TreeGpu],
    visible: &[Vec<u32>],
    view: &PrepareView,
    settings: &TexelSettings,
    vcm: Option<&dyn TreeShades>,
    stack_atlas: Option<&stacks::StackAtlas>,
    max: usize,
) -> TexelFrame {
    let bounds = settings.bounds.sanitized();
    let cam = view.camera.position;
    let forward = view.camera.forward();
    let mut stats = TexelStats {
        texel_mode: settings.mode,
        ..Default::default()
    };
    let mut sorted: Vec<(f32, bool, TexelGpu, Option<stacks::StackGpu>)> = Vec::new();
    for (sp, list) in visible.iter().enumerate() {
        let Some(vol) = scene.species(sp) else {
            continue;
        };
        for &t in list {
            let Some(data) = trees.get(t as usize) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let scale = m.x_axis.truncate().length();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let local = Aabb::new(vol.box_min, vol.box_min + vol.box_size);
            let world_box = local.transformed(m);
            if !view.frustum.intersects(&world_box) {
                continue;
            }
            let inv = m.inverse();
            // The box's depth along the view: its extent along the forward axis.
            let rot = Mat3::from_mat4(m);
            let f_obj = (rot.transpose() * forward) / scale;
            let depth = (vol.box_size * f_obj.abs()).element_sum() * scale;
            let center = m.transform_point3(local.center());
            let z = (center - cam).dot(forward).max(view.camera.near.max(0.1));
            let stack = stack_atlas.and_then(|a| {
                let eye_to_box = inv.transform_vector3(center - cam);
                a.choose(sp, eye_to_box, vol.voxel, scale, z, view.focal_px, &bounds)
            });
            let n = match &stack {
                Some(c) => c.slices,
                None if stack_atlas.is_some() => continue,
                None => slices::screen_slices(view.focal_px, depth, z, &bounds),
            };
            let spacing = depth / n as f32;
            // The mip level where one voxel covers about a pixel.
            let voxel_px = view.focal_px * vol.voxel * scale / z;
            let lod = (1.0 / voxel_px.max(1e-6))
                .log2()
                .clamp(0.0, (scene.mips - 1) as f32);
            let sun_obj = (rot.transpose() * view.to_sun).normalize_or(Vec3::Y);
            let blend = scene.lights.blend(sun_obj);
            let mut record = TexelGpu {
                model: m.to_cols_array_2d(),
                world_to_object: inv.to_cols_array_2d(),
                box_min: vol.box_min.to_array(),
                spacing,
                box_size: vol.box_size.to_array(),
                voxel: vol.voxel,
                atlas_origin: vol.atlas_origin.to_array(),
                volume_dw: vol.volume_dw,
                atlas_extent: vol.atlas_extent.to_array(),
                lod,
                light_index: blend.index,
                mode: u32::from(settings.show_slices),
                light_weight: blend.weight,
                lights: scene.lights.len() as u32,
                tint: [data.tint[0], data.tint[1], data.tint[2]],
                scale,
                vcm_min: vol.box_min.to_array(),
                max_steps: (n + 2) as f32,
                vcm_inv_size: (1.0 / vol.box_size).to_array(),
                slices: n as f32,
                vcm_direct: [[1.0; 4]; 2],
                vcm_sky: [[1.0; 4]; 2],
            };
            if let Some((shade, b)) = vcm
                .filter(|_| settings.vcm)
                .and_then(|v| v.tree_shade(t as usize, sp, &m))
            {
                let d = shade.direct;
                let k = shade.sky;
                record.vcm_min = b.min.to_array();
                record.vcm_inv_size = (1.0 / (b.max - b.min).max(Vec3::splat(1e-6))).to_array();
                record.vcm_direct = [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]];
                record.vcm_sky = [[k[0], k[1], k[2], k[3]], [k[4], k[5], k[6], k[7]]];
            }
            // The eye inside the box (with a margin for the near plane): drawn from its far
            // faces.
            let eye_obj = inv.transform_point3(cam);
            let margin = Vec3::splat(view.camera.near.max(0.1) * 2.0 / scale);
            let inside =
                eye_obj.cmpge(local.min - margin).all() && eye_obj.cmple(local.max + margin).all();
            stats.texels += 1;
            stats.slices_max = stats.slices_max.max(n);
            stats.slices_mean += n as f32;
            // Stacks have no inside: their quads are drawn in depth order whatever the eye.
            let inside = inside && stack.is_none();
            sorted.push((
                (center - cam).dot(forward),
                inside,
                record,
                stack.map(|c| c.record),
            ));
        }
    }
    // Back to front; the boxes the eye is inside last (they are the nearest).
    sorted.sort_by(|a, b| a.1.cmp(&b.1).then(b.0.total_cmp(&a.0)));
    if sorted.len() > max {
        stats.dropped = (sorted.len() - max) as u32;
        // The farthest outside boxes go first.
        sorted.drain(..sorted.len() - max);
    }
    if stats.texels > 0 {
        stats.slices_mean /= stats.texels as f32;
    }
    let inside = sorted.iter().filter(|s| s.1).count() as u32;
    let stack_records: Vec<stacks::StackGpu> = sorted.iter().filter_map(|s| s.3).collect();
    let quads = stacks::quads(&stack_records);
    TexelFrame {
        records: sorted.into_iter().map(|s| s.2).collect(),
        inside,
        stats,
        stacks: stack_records,
        quads,
        tiles: Vec::new(),
        polygons: Vec::new(),
    }
}
