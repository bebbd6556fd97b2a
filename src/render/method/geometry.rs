//! The `geometry` method: every leaf, needle and branch as triangles, lit by the sun
//! through cascaded shadow maps that follow the camera and are drawn every frame, and by the
//! hemispherical sky. The ground truth every other method is measured against.

use super::info::{MethodInfo, no_rows};
use super::interface::{Bake, DrawCx, Plan, PrepareCx, RenderMethod, SunWork};
use super::kind::Method;
use crate::Result;
use crate::render::camera::Frustum;
use crate::render::frame::{FrameDesc, FrameStats, Stage};
use crate::render::meshes::MeshPasses;
use crate::render::shadow::Cascades;
use crate::render::world_gpu::{TreeRun, WorldGpu};

/// The CPU side of one frame: where the cascades are and what each one draws.
#[derive(Clone, Debug)]
pub struct GeometryFrame {
    pub cascades: Cascades,
    /// The cascades are drawn and sampled (shadows enabled and a sun to cast them).
    pub shadows_on: bool,
    /// Trees per species: the camera's, then each cascade's casters (when on).
    pub lists: Vec<Vec<Vec<u32>>>,
}

impl GeometryFrame {
    /// Fits the cascades to the view (in the studio: around the object, from any sun
    /// direction) and culls each cascade's casters. `visible` is the camera's list. CPU only.
    pub fn prepare(
        world: &WorldGpu,
        frame: &FrameDesc,
        aspect: f32,
        visible: Vec<Vec<u32>>,
    ) -> Self {
        let studio = frame.stage == Stage::Studio;
        let shadows_on = frame.shadows.enabled && (frame.sun.elevation_deg > 0.0 || studio);
        let cascades = if shadows_on && studio {
            let b = &world.forest_bounds;
            Cascades::fit_sphere(
                frame.sun.direction(),
                b.center(),
                0.5 * b.extent().length(),
                frame.shadows.map_size,
            )
        } else if shadows_on {
            Cascades::fit(
                &frame.camera,
                aspect,
                frame.sun.direction(),
                &frame.shadows,
                &world.scene_bounds,
            )
        } else {
            Cascades::none()
        };
        let mut lists = vec![visible];
        if shadows_on {
            // The studio's one map serves every pixel (cascade 0, its split at infinity):
            // the other cascades are never read, so nothing is drawn into them.
            let used = if studio { 1 } else { cascades.matrices.len() };
            for m in cascades.matrices.iter().take(used) {
                lists.push(if frame.trees {
                    world.cull(&Frustum::from_ortho(*m))
                } else {
                    vec![Vec::new(); world.species.len()]
                });
            }
        }
        Self {
            cascades,
            shadows_on,
            lists,
        }
    }
}

/// The `geometry` method: the trees' meshes whole, shaded by cascades fitted to the view.
#[derive(Default)]
pub struct Geometry {
    /// The frame's instance runs: the camera's, then each cascade's.
    runs: Vec<Vec<TreeRun>>,
}

impl RenderMethod for Geometry {
    fn method(&self) -> Method {
        Method::Geometry
    }

    fn check(&self, _bake: &Bake) -> Result<()> {
        Ok(())
    }

    fn prepare(&mut self, _bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        let frame = cx.frame;
        let g = GeometryFrame::prepare(cx.world, frame, cx.aspect, cx.visible);
        self.runs = cx.world.upload_lists(cx.ctx, &g.lists);
        let studio = frame.stage == Stage::Studio;
        let self_maps = frame.reference.is_some_and(|r| r.self_map_size > 0);
        Ok(Plan {
            cascades: g.cascades,
            shadows_on: g.shadows_on,
            casters: g.shadows_on.then(|| self.runs[1..].to_vec()),
            terrain_casts: !studio,
            geometry_tree_cascades: false,
            ground_excluded: Vec::new(),
            self_shadowed: (g.shadows_on && self_maps && !studio)
                .then(|| (self.runs[0].clone(), g.lists[0].clone())),
            studio_casters: (studio && g.shadows_on).then(|| g.lists[1..].to_vec()),
            sun: SunWork::default(),
            layer: false,
        })
    }

    fn draw(
        &self,
        _bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    ) {
        let runs = match self.runs.first() {
            Some(r) if !cx.trees_after => &r[..],
            _ => &[],
        };
        cx.spans.rename("trees");
        MeshPasses::draw_main(pass, cx.world, runs, cx.pipes, stats);
    }
}

/// What the rest of the program asks of `geometry`.
pub const INFO: MethodInfo = MethodInfo {
    name: "geometry",
    summary: "every leaf, needle and branch as triangles: the ground truth (--reference: its reference mode)",
    needs_bake: false,
    follows_sun: false,
    stat_rows: no_rows,
};
