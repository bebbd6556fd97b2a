//! The `impostor` method through the renderer's one interface.

use std::time::Instant;

use super::assets::ImpostorAssets;
use super::prepare::prepare;
use super::settings::ImpostorStats;
use crate::Result;
use crate::render::GpuContext;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::method::info::{MethodInfo, StatRow, format_count, format_mb};
use crate::render::method::interface::{
    Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod, SunWork,
};
use crate::render::method::kind::Method;
use crate::render::pipelines::Layouts;
use crate::render::vcm_shading::TreeShades;

use crate::render::geometry_trees::{draw_faded_trees, geometry_tree_plan};
use crate::render::world_gpu::{TreeRun, WorldGpu};

/// `impostor`: the frame's record count, the trees drawn as geometry and their runs, what
/// it reports.
#[derive(Default)]
pub struct ImpostorMethod {
    count: u32,
    /// Trees drawn as geometry alone (no impostor).
    whole: u32,
    /// The geometry trees' runs: trunks and limbs, then twigs, all faded.
    runs: Vec<Vec<TreeRun>>,
    stats: ImpostorStats,
    /// The frame's `parallax_depth` knob.
    parallax_depth: bool,
}

/// The impostor assets, or the error that says how to get them.
fn need(bake: &Bake) -> Result<&ImpostorAssets> {
    bake.need_btf(Method::Impostor)?;
    bake.impostor.as_ref().ok_or_else(|| {
        crate::Error::BadInput(bake.impostor_problem.clone().unwrap_or_else(|| {
            "this bake has no octahedral impostors: set `[bake] impostor_frames` (e.g. 12) in the scene file and bake again".into()
        }))
    })
}

impl RenderMethod for ImpostorMethod {
    fn method(&self) -> Method {
        Method::Impostor
    }

    fn check(&self, bake: &Bake) -> Result<()> {
        need(bake).map(|_| ())
    }

    fn shades_ground(&self) -> bool {
        true
    }

    fn knobs(&self) -> &'static [crate::render::knob::Knob] {
        super::knobs::KNOBS
    }

    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        need(bake)?;
        let settings = cx.frame.impostor;
        self.parallax_depth = settings.parallax_depth;
        let mut sun = SunWork::default();
        let (Some(btf), Some(imp)) = (bake.btf.as_mut(), bake.impostor.as_mut()) else {
            return Err(crate::Error::Gpu("the impostors are not loaded".into()));
        };
        if settings.vcm && cx.frame.trees {
            let t0 = Instant::now();
            if btf.update_sun(cx.view.to_sun) {
                sun.moved = true;
                sun.ms += t0.elapsed().as_secs_f64() * 1e3;
            }
        }
        let scene = btf.scene();
        let f = prepare(
            &imp.species,
            &cx.world.tree_data,
            &cx.visible,
            &cx.view,
            &settings,
            ImpostorAssets::max_records(&cx.ctx.device),
            &mut |t, sp, m| scene.tree_shade(t, sp, m),
        );
        imp.upload(cx.ctx, &f.records, &settings);
        self.count = f.records.len() as u32;
        self.stats = imp.with_atlas(f.stats);
        self.whole = f
            .geometry
            .iter()
            .flatten()
            .filter(|(_, o)| *o >= 1.0)
            .count() as u32;
        // The trees drawn as geometry, as `hybrid` draws its own: in sun cascades of their
        // own and out of the ground alpha map; but faded whole (trunk and limbs too), the
        // impostor drawn in the pixels they leave.
        let tint = settings
            .show_lod
            .then_some(crate::render::consts::GEOMETRY_COLOR);
        let runs = cx
            .world
            .upload_lists_faded(cx.ctx, &[], &[&f.geometry, &f.geometry], tint);
        let plan = geometry_tree_plan(cx.world, cx.frame, &f.geometry, &runs[0], sun);
        self.runs = runs;
        Ok(plan)
    }

    fn ground_casters(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        world: &WorldGpu,
        to_sun: glam::Vec3,
        excluded: &[u32],
    ) -> Option<GroundCasters> {
        // The same ground shadows as `btf`: the trees' tree-level images seen from the sun.
        bake.billboard_casters(ctx, layouts, world, to_sun, excluded)
    }

    fn ensure_pipelines(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        if let Some(imp) = bake.impostor.as_mut() {
            imp.ensure_pipeline(&ctx.device, layouts, format, self.parallax_depth);
        }
        Ok(())
    }

    fn draw(
        &self,
        bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    ) {
        let Some(imp) = &bake.impostor else {
            return;
        };
        cx.spans.rename("impostors");
        if self.stats.geometry_trees > 0 {
            draw_faded_trees(pass, cx, &self.runs, stats);
            cx.spans.mark(pass, "impostors");
        }
        imp.draw(pass, self.count);
        if self.count > 0 {
            stats.draw_calls += 1;
        }
        stats.triangles += 2 * u64::from(self.count);
        stats.trees_drawn = self.count + self.whole;
        stats.impostor = Some(self.stats);
    }
}

/// What the rest of the program asks of `impostor`.
pub const INFO: MethodInfo = MethodInfo {
    name: "impostor",
    summary: "one quad per tree showing its species' octahedral impostor: 3 baked frames blended with depth parallax, lit per pixel (needs a bake with impostors)",
    needs_bake: true,
    follows_sun: true,
    stat_rows,
};

/// The impostors of a frame (`impostor`'s, or `hybrid`'s tree level).
pub fn stat_rows(stats: &FrameStats, _frame: &FrameDesc) -> Vec<StatRow> {
    let Some(s) = &stats.impostor else {
        return Vec::new();
    };
    vec![
        StatRow::new("impostors drawn", format_count(u64::from(s.impostors))),
        StatRow::new(
            "frames (px a frame)",
            format!("{0} x {0} ({1} px)", s.frames, s.frame_px),
        ),
        StatRow::new("impostor atlases", format_mb(s.atlas_bytes)),
    ]
}
