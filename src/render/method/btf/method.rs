//! The `btf` and `hybrid` methods through the renderer's one interface: the BTF hierarchy's
//! billboards, with the finer levels' trunks and limbs as geometry, and (`hybrid`) whole
//! trees as geometry where even the twig level is too coarse.

use std::time::Instant;

use super::prepare::BtfFrame;
use super::settings::{BtfSettings, GEOMETRY_COLOR};
use crate::Result;
use crate::render::GpuContext;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::geometry_trees::geometry_tree_plan;
use crate::render::method::info::{MethodInfo, StatRow, format_count};
use crate::render::method::interface::{
    AfterCx, Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod, SunWork,
};
use crate::render::method::kind::Method;
use crate::render::pipelines::Layouts;
use crate::render::timing::PassSpans;
use crate::render::world_gpu::{TreeRun, WorldGpu};

/// `btf` (or `hybrid`): its frame, the geometry runs it draws and its pipeline.
pub struct BtfMethod {
    hybrid: bool,
    frame: Option<BtfFrame>,
    runs: Vec<Vec<TreeRun>>,
    pipeline: Option<wgpu::RenderPipeline>,
    /// The billboards' pipeline into the trees' layer.
    layer_pipeline: Option<wgpu::RenderPipeline>,
}

impl BtfMethod {
    /// `btf`, or with `hybrid`, the BTF part of `hybrid` ([`crate::render::method::hybrid`]).
    pub fn new(hybrid: bool) -> Self {
        Self {
            hybrid,
            frame: None,
            runs: Vec::new(),
            pipeline: None,
            layer_pipeline: None,
        }
    }

    /// The frame's knobs as this method reads them: the tree level as impostors only in
    /// `hybrid` with a bake that has them (`impostors`), and then every tree prepared on
    /// the CPU.
    pub(crate) fn settings(&self, frame: &FrameDesc, impostors: bool) -> BtfSettings {
        let mut s = frame.btf;
        if !(self.hybrid && impostors && s.impostor_px > 0.0) {
            s.impostor_px = 0.0;
        }
        if s.impostor_px > 0.0 {
            s.gpu_far = false;
        }
        s
    }

    /// The frame prepared last (None before the first).
    pub(crate) fn frame(&self) -> Option<&BtfFrame> {
        self.frame.as_ref()
    }

    /// [`RenderMethod::prepare`] with the knobs `settings` ([`Self::settings`]).
    pub(crate) fn prepare_with(
        &mut self,
        bake: &mut Bake,
        cx: &PrepareCx<'_>,
        settings: &BtfSettings,
    ) -> Result<Plan> {
        let method = self.method();
        bake.need_btf(method)?;
        let Some(b) = bake.btf.as_mut() else {
            return Err(crate::Error::Gpu("the BTF images are not loaded".into()));
        };
        let frame = cx.frame;
        let mut sun = SunWork::default();
        if settings.vcm && frame.trees {
            let t0 = Instant::now();
            if b.update_sun(cx.view.to_sun) {
                sun.moved = true;
                sun.ms += t0.elapsed().as_secs_f64() * 1e3;
            }
        }
        // The tree level's light blends follow the sun: weights here, drawn before the
        // frame's other passes (`encode_compute`).
        if settings.light_blend && frame.trees {
            let t0 = Instant::now();
            if b.update_light_blend(cx.ctx, cx.view.to_sun, settings) {
                sun.moved = true;
                sun.ms += t0.elapsed().as_secs_f64() * 1e3;
            }
        }
        let culls = b.takes_far(settings);
        let (bf, shade_ms) = b.prepare(
            cx.ctx,
            cx.world,
            (!culls).then_some(&cx.visible[..]),
            frame.trees,
            cx.view.camera,
            cx.view.focal_px,
            cx.view.to_sun,
            cx.view.frustum,
            settings,
            self.hybrid,
            crate::render::uniforms::frame_lights(frame),
        );
        // The far trees' VCM factors, uploaded after the sun moved.
        sun.ms += shade_ms;
        let (runs, mut plan) = plan_geometry(cx.ctx, cx.world, frame, &bf, sun);
        plan.layer = bf.layer_batches > 0;
        self.runs = runs;
        self.frame = Some(bf);
        Ok(plan)
    }

    /// [`RenderMethod::draw`], with `between` drawn after the meshes and before the
    /// billboards.
    pub(crate) fn draw_with(
        &self,
        bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
        between: super::Between<'_>,
    ) {
        draw_frame(
            bake,
            pass,
            cx,
            (&self.frame, &self.runs),
            self.pipeline.as_ref(),
            stats,
            between,
        );
    }
}

/// Uploads the geometry a BTF frame draws (the trunks of the trees at the main-branch
/// level, the trunks and limbs of those at the twig level, the trees drawn whole with their
/// twigs fading: `hybrid`'s, and those of a species without finer levels where its tree
/// level is too coarse) and plans its sun cascades: fitted to the trees drawn wholly as
/// geometry alone, which then cast and receive through them and are left out of the ground
/// alpha map (where their own billboard would shade them).
pub(crate) fn plan_geometry(
    ctx: &GpuContext,
    world: &WorldGpu,
    frame: &FrameDesc,
    bf: &BtfFrame,
    sun: SunWork,
) -> (Vec<Vec<TreeRun>>, Plan) {
    let t0 = Instant::now();
    // The trees drawn wholly as geometry, trunk and limbs at opacity 1.
    let whole: Vec<Vec<(u32, f32)>> = bf
        .twigs
        .iter()
        .map(|l| l.iter().map(|&(t, _)| (t, 1.0)).collect())
        .collect();
    let counts =
        [&bf.trunk_only, &bf.trunk_and_limbs].map(|l| l.iter().map(Vec::len).sum::<usize>());
    let runs = world.upload_lists_faded(
        ctx,
        &[bf.trunk_only.clone(), bf.trunk_and_limbs.clone()],
        &[&whole, &bf.twigs],
        frame.btf.show_lod.then_some(GEOMETRY_COLOR),
    );
    log::debug!(
        "btf prepare: the trunks' and limbs' lists ({} and {} trees) in {:.2} ms",
        counts[0],
        counts[1],
        t0.elapsed().as_secs_f64() * 1e3
    );
    let plan = geometry_tree_plan(world, frame, &whole, &runs[2], sun);
    (runs, plan)
}

/// The billboards' pipeline for `format` (the `btf` method's, which `billboard` draws with
/// too); None without BTF images.
pub(crate) fn billboard_pipeline(
    bake: &mut Bake,
    ctx: &GpuContext,
    layouts: &Layouts,
    format: wgpu::TextureFormat,
) -> Option<wgpu::RenderPipeline> {
    let b = bake.btf.as_mut()?;
    Some(b.pipeline(&ctx.device, &layouts.frame, format).clone())
}

/// The billboards' pipeline into the trees' layer; None without BTF images.
pub(crate) fn layer_pipeline(
    bake: &mut Bake,
    ctx: &GpuContext,
    layouts: &Layouts,
) -> Option<wgpu::RenderPipeline> {
    let b = bake.btf.as_mut()?;
    Some(b.layer_pipeline(&ctx.device, &layouts.frame).clone())
}

/// A prepared BTF frame's draws in the main pass: its geometry `runs`, then its billboards.
pub(crate) fn draw_frame(
    bake: &Bake,
    pass: &mut wgpu::RenderPass<'_>,
    cx: &DrawCx<'_>,
    (frame, runs): (&Option<BtfFrame>, &[Vec<TreeRun>]),
    pipeline: Option<&wgpu::RenderPipeline>,
    stats: &mut FrameStats,
    between: super::Between<'_>,
) {
    if let (Some(bf), Some(b)) = (frame, &bake.btf) {
        b.draw_main(pass, cx, runs, pipeline, bf, stats, between);
    }
}

impl RenderMethod for BtfMethod {
    fn method(&self) -> Method {
        if self.hybrid {
            Method::Hybrid
        } else {
            Method::Btf
        }
    }

    fn check(&self, bake: &Bake) -> Result<()> {
        bake.need_btf(self.method()).map(|_| ())
    }

    fn culls_itself(&self, bake: &Bake, frame: &FrameDesc) -> bool {
        let settings = self.settings(frame, bake.impostor.is_some());
        bake.btf.as_ref().is_some_and(|b| b.takes_far(&settings))
    }

    fn shades_ground(&self) -> bool {
        true
    }

    fn knobs(&self) -> &'static [crate::render::knob::Knob] {
        super::knobs::KNOBS
    }

    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        let settings = self.settings(cx.frame, bake.impostor.is_some());
        self.prepare_with(bake, &cx, &settings)
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
        bake.billboard_casters(ctx, layouts, world, to_sun, excluded)
    }

    fn ensure_pipelines(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        self.pipeline = billboard_pipeline(bake, ctx, layouts, format);
        self.layer_pipeline = layer_pipeline(bake, ctx, layouts);
        if let Some(b) = bake.btf.as_mut() {
            if let Some(bf) = &self.frame {
                b.ensure_compositor(ctx, &layouts.frame, bf);
            }
            b.ensure_canopy_pipeline(&ctx.device, &layouts.frame, format);
        }
        Ok(())
    }

    fn encode_compute(&self, bake: &Bake, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        if let Some(b) = &bake.btf {
            b.encode_light_blend(encoder, spans);
        }
        if let (Some(bf), Some(b)) = (&self.frame, &bake.btf)
            && bf.far
        {
            b.encode_far(encoder, spans);
        }
    }

    fn draw(
        &self,
        bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    ) {
        self.draw_with(bake, pass, cx, stats, &mut |_, _| {});
    }

    fn draw_after(
        &self,
        bake: &Bake,
        encoder: &mut wgpu::CommandEncoder,
        cx: &AfterCx<'_>,
        stats: &mut FrameStats,
    ) {
        if let (Some(bf), Some(b)) = (&self.frame, &bake.btf) {
            b.draw_layer(encoder, cx, self.layer_pipeline.as_ref(), bf, stats);
        }
    }

    fn finish(&self, bake: &Bake, ctx: &GpuContext, wait: bool, stats: &mut FrameStats) {
        if let (Some(bf), Some(b)) = (&self.frame, &bake.btf)
            && bf.far
        {
            b.add_far_stats(ctx, wait, stats);
        }
    }
}

/// What the rest of the program asks of `btf`.
pub const INFO: MethodInfo = MethodInfo {
    name: "btf",
    summary: "BTF billboards of the twig / main branch / tree hierarchy, shaded by visibility cube maps (needs a bake)",
    needs_bake: true,
    follows_sun: true,
    stat_rows,
};

/// `btf`'s statistics of a frame: its billboards and trees per level and what they read.
pub fn stat_rows(stats: &FrameStats, _frame: &FrameDesc) -> Vec<StatRow> {
    let Some(s) = &stats.btf else {
        return Vec::new();
    };
    let mut rows = vec![
        StatRow::new(
            "billboards twig/branch/tree",
            format!(
                "{} / {} / {}",
                s.billboards.twig, s.billboards.branch, s.billboards.tree
            ),
        ),
        StatRow::new(
            "trees twig/branch/tree",
            format!(
                "{} / {} / {}",
                s.trees_per_level.twig, s.trees_per_level.branch, s.trees_per_level.tree
            ),
        ),
        StatRow::new("trees cross-fading", s.faded_trees.to_string()),
    ];
    if s.gpu_billboards > 0 {
        rows.push(StatRow::new(
            "built on the GPU",
            format_count(u64::from(s.gpu_billboards)),
        ));
    }
    if s.canopy_tiles > 0 {
        rows.push(StatRow::new(
            "far canopy: tiles, trees",
            format!(
                "{}, {}",
                s.canopy_tiles,
                format_count(u64::from(s.canopy_trees))
            ),
        ));
    }
    rows.push(StatRow::new(
        "images per billboard",
        format!("{:.2}", s.images_per_billboard()),
    ));
    rows.push(StatRow::new("fetches saved", format_count(s.fetches_saved)));
    rows
}
