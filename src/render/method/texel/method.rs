//! The `texel` method through the renderer's one interface: the trees (and far forest
//! tiles) as volumetric texels over the terrain, shaded by the trees' visibility cube maps
//! when the bake has them.

use std::time::Instant;

use super::{TexelFrame, TexelPipelines};
use crate::render::GpuContext;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::method::info::{MethodInfo, StatRow, format_mb};
use crate::render::method::interface::{
    Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod, SunWork,
};
use crate::render::method::kind::Method;
use crate::render::pipelines::Layouts;
use crate::render::world_gpu::WorldGpu;
use crate::{Error, Result};

/// `texel`: its frame and its pipelines.
#[derive(Default)]
pub struct TexelMethod {
    frame: Option<TexelFrame>,
    pipelines: Option<TexelPipelines>,
}

impl RenderMethod for TexelMethod {
    fn method(&self) -> Method {
        Method::Texel
    }

    fn check(&self, bake: &Bake) -> Result<()> {
        bake.need_btf(Method::Texel)?;
        if bake.has_texels() {
            return Ok(());
        }
        Err(Error::BadInput(match &bake.texel_problem {
            Some(p) => format!("the texel method cannot draw: {p}"),
            None => "the texel method needs baked texel volumes, and this bake has none: set texel_resolution above 0 in the scene's [bake] table and bake again".into(),
        }))
    }

    fn shades_ground(&self) -> bool {
        true
    }

    fn knobs(&self) -> &'static [crate::render::knob::Knob] {
        super::knobs::KNOBS
    }

    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        let frame = cx.frame;
        if bake.texel_ready(cx.ctx).is_none() {
            return Err(Error::Gpu(match &bake.texel_problem {
                Some(p) => format!("the texel volumes could not be loaded: {p}"),
                None => "the texel volumes are not loaded".into(),
            }));
        }
        let mut sun = SunWork::default();
        let vcm = match bake.btf.as_mut() {
            Some(b) if frame.texel.vcm && frame.trees => {
                let t0 = Instant::now();
                if b.update_sun(cx.view.to_sun) {
                    sun.moved = true;
                    sun.ms += t0.elapsed().as_secs_f64() * 1e3;
                }
                Some(b.scene() as &dyn crate::render::vcm_shading::TreeShades)
            }
            _ => None,
        };
        let Some(t) = bake.texel.as_mut() else {
            return Err(Error::Gpu("the texel volumes are not loaded".into()));
        };
        let tf = t.prepare_frame(cx.ctx, cx.world, &cx.visible, &cx.view, &frame.texel, vcm)?;
        // No tree parts as geometry; the list still holds the terrain's instance.
        cx.world
            .upload_lists(cx.ctx, &[vec![Vec::new(); cx.world.species.len()]]);
        self.frame = Some(tf);
        Ok(Plan::without_cascades(sun))
    }

    fn ground_casters(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        world: &WorldGpu,
        _to_sun: glam::Vec3,
        _excluded: &[u32],
    ) -> Option<GroundCasters> {
        let t = bake.texel_ready(ctx)?;
        let count = t.prepare_sun(ctx, world);
        Some(GroundCasters {
            pipeline: t
                .opacity_pipeline(&ctx.device, &layouts.shadow_frame)
                .clone(),
            bind_group: t.sun_bind_group().clone(),
            count,
            vertices: 36,
        })
    }

    fn ensure_pipelines(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        if let Some(t) = bake.texel_ready(ctx) {
            self.pipelines = Some(t.pipelines(&ctx.device, &layouts.frame, format));
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
        let Some(tf) = &self.frame else {
            return;
        };
        if let (Some(t), Some(p)) = (&bake.texel, &self.pipelines) {
            pass.set_bind_group(0, cx.frame_group, &[]);
            t.draw(pass, p, tf, cx.spans, stats);
        }
        stats.texel = Some(tf.stats);
    }
}

/// What the rest of the program asks of `texel`.
pub const INFO: MethodInfo = MethodInfo {
    name: "texel",
    summary: "each tree as a volumetric texel: its baked volumes sliced parallel to the screen (needs a bake with texel volumes)",
    needs_bake: true,
    follows_sun: false,
    stat_rows,
};

/// What `texel` drew in a frame.
fn stat_rows(stats: &FrameStats, _frame: &FrameDesc) -> Vec<StatRow> {
    let Some(s) = &stats.texel else {
        return Vec::new();
    };
    vec![
        StatRow::new("texels drawn", s.texels.to_string()),
        StatRow::new(
            "tiles drawn (trees)",
            format!("{} ({})", s.tiles, s.tiled_trees),
        ),
        StatRow::new(
            "slices mean / max",
            format!("{:.1} / {}", s.slices_mean, s.slices_max),
        ),
        StatRow::new("texel memory", format_mb(s.texel_bytes)),
    ]
}
