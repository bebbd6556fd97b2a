//! The trees a method draws as geometry among its stand-ins (`btf`'s and `hybrid`'s whole
//! trees, `impostor`'s near ones): their sun cascades, one map fitted to them alone, through
//! which they shade themselves and the rest, and the plan that leaves them out of the ground
//! alpha map (where their own stand-in would shade them).

use crate::model::mesh::Aabb;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::method::interface::{DrawCx, Plan, SunWork};
use crate::render::shadow::Cascades;
use crate::render::world_gpu::{PartKind, TreeRun, WorldGpu};

/// Draws the trees a method uploaded as geometry, faded (`runs`: trunks and limbs, then
/// twigs, as [`WorldGpu::upload_lists_faded`] gave them for the same list twice), timed as
/// `near trees`, and counts them in `stats`.
pub fn draw_faded_trees(
    pass: &mut wgpu::RenderPass<'_>,
    cx: &DrawCx<'_>,
    runs: &[Vec<TreeRun>],
    stats: &mut FrameStats,
) {
    cx.spans.rename("near trees");
    let faded = Some(cx.pipes.faded_meshes());
    let mut draw = |list: usize, kinds: &[PartKind]| match runs.get(list) {
        Some(r) => cx.world.draw(pass, r, faded, false, kinds),
        None => (0, 0, 0),
    };
    let (ta, _, ca) = draw(0, &[PartKind::Trunk, PartKind::Limbs]);
    let (tb, _, cb) = draw(1, &[PartKind::Twigs]);
    stats.triangles += ta + tb;
    stats.draw_calls += ca + cb;
}

/// The plan of a frame whose trees drawn as geometry (`trees`, per species, with their
/// opacities; uploaded as `whole`) shade themselves and the rest through one sun shadow
/// map of their own ([`geometry_tree_cascades`]) and leave the ground alpha map.
pub fn geometry_tree_plan(
    world: &WorldGpu,
    frame: &FrameDesc,
    trees: &[Vec<(u32, f32)>],
    whole: &[TreeRun],
    sun: SunWork,
) -> Plan {
    let cascades = geometry_tree_cascades(world, frame, trees);
    let on = cascades.is_some();
    let mut excluded: Vec<u32> = if on {
        trees.iter().flatten().map(|&(t, _)| t).collect()
    } else {
        Vec::new()
    };
    excluded.sort_unstable();
    Plan {
        cascades: cascades.unwrap_or_else(Cascades::none),
        shadows_on: on,
        // One map: the geometry trees, whole (the terrain has its own map).
        casters: on.then(|| vec![whole.to_vec()]),
        terrain_casts: false,
        geometry_tree_cascades: on,
        ground_excluded: excluded,
        self_shadowed: None,
        studio_casters: None,
        sun,
        layer: false,
    }
}

/// One sun shadow map around the trees drawn as geometry (`trees`, per species; every
/// cascade the same, the first one used), so that its texels stay small, reaching down
/// past them to the lowest ground their shadows can fall on; None when there are none,
/// shadows are off or the sun is down.
fn geometry_tree_cascades(
    world: &WorldGpu,
    frame: &FrameDesc,
    trees: &[Vec<(u32, f32)>],
) -> Option<Cascades> {
    if !frame.shadows.enabled || frame.sun.elevation_deg <= 0.0 {
        return None;
    }
    let bounds = trees
        .iter()
        .flatten()
        .filter_map(|&(t, _)| world.tree_bounds.get(t as usize))
        .fold(None, |u: Option<Aabb>, b| {
            Some(u.map_or(*b, |u| u.union(*b)))
        })?;
    let to_sun = frame.sun.direction();
    let radius = 0.5 * bounds.extent().length();
    // The shadow of the top reaches the ground at most this far along the sun's ray.
    let scene = &world.scene_bounds;
    let drop = (bounds.max.y - scene.min.y).max(0.0);
    let below = (drop / to_sun.y.max(0.05)).min(2000.0);
    Some(Cascades::fit_sphere_reaching(
        to_sun,
        bounds.center(),
        radius,
        below,
        frame.shadows.map_size,
    ))
}
