//! The `hybrid` method: `btf`'s hierarchy with each tree drawn as geometry wherever even
//! its twig level is too coarse (cross-faded), and its tree level drawn as the bake's
//! octahedral impostors where asked (`impostor_px`, when the bake has them): faster, and
//! more accurate on the overview flight, less on the walk, at sunset and at the default
//! start camera (docs/results/hybrid.md, "hybrid with impostors"; off by default).
//!
//! A tree's tree level becomes one impostor record (alpha-tested, depth-written, front to
//! back) with the opacity the level choice gave it; the finer levels' billboards, blended,
//! are drawn after the impostors, so a tree fading from its tree level to its main
//! branches shows the impostor in the share of its pixels that its opacity keeps.

use std::sync::LazyLock;

use super::btf::method::BtfMethod;
use super::btf::settings::LOD_COLORS;
use super::impostor::{ImpostorAssets, ImpostorSettings, ImpostorStats};
use super::info::{MethodInfo, StatRow, format_count};
use super::interface::{AfterCx, Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod};
use super::kind::Method;
use crate::Result;
use crate::model::Level;
use crate::render::GpuContext;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::knob::Knob;
use crate::render::pipelines::Layouts;
use crate::render::timing::PassSpans;
use crate::render::vcm_shading::TreeShades;
use crate::render::world_gpu::WorldGpu;

/// `hybrid`'s own knob: where its tree level is drawn as impostors.
static IMPOSTOR_PX: Knob = Knob::number(
    "impostor_px",
    "impostors below (px)",
    "where a tree's tree-level texels project below this many pixels its tree level is drawn as the bake's octahedral impostor (when it has them), cross-faded over the LOD band; 0: never; at the LOD scale or above: the whole tree level. Above 0 every tree is prepared on the CPU, without the far canopy",
    (0.0, 64.0),
    |d| d.btf.impostor_px,
    |d, v| d.btf.impostor_px = v,
)
.slider(0.0, 4.0, false);

/// `btf`'s knobs, `impostor_px`, and the impostor's knobs its impostors read (offered in
/// the panel while `impostor_px` is on). None offers `tune` values: `tune` searches `btf`
/// and `impostor`, not `hybrid`.
static KNOBS: LazyLock<Vec<Knob>> = LazyLock::new(|| {
    let mut knobs: Vec<Knob> = super::btf::knobs::KNOBS
        .iter()
        .map(|k| Knob { tune: &[], ..*k })
        .collect();
    knobs.push(IMPOSTOR_PX);
    let shared = ["alpha_cutoff", "parallax", "parallax_depth", "self_shadow"];
    for k in super::impostor::knobs::KNOBS {
        if shared.contains(&k.name) {
            knobs.push(Knob {
                tune: &[],
                enabled: |d| d.btf.impostor_px > 0.0,
                ..*k
            });
        }
    }
    knobs
});

/// `hybrid`: the BTF frame and geometry ([`BtfMethod`]), and the impostors of its tree level.
pub struct HybridMethod {
    btf: BtfMethod,
    /// The frame's impostor records (0: none, or the tree level drawn as billboards).
    impostors: u32,
    stats: Option<ImpostorStats>,
    /// The frame's `parallax_depth` knob.
    parallax_depth: bool,
}

impl Default for HybridMethod {
    fn default() -> Self {
        Self {
            btf: BtfMethod::new(true),
            impostors: 0,
            stats: None,
            parallax_depth: false,
        }
    }
}

/// The impostor knobs `hybrid`'s impostors are drawn with: the frame's, shaded by the
/// cube maps as `btf`'s billboards are, never geometry (the BTF levels decide that).
fn impostor_settings(frame: &FrameDesc) -> ImpostorSettings {
    ImpostorSettings {
        vcm: frame.btf.vcm,
        show_lod: frame.btf.show_lod,
        geometry_px: 0.0,
        ..frame.impostor
    }
}

impl RenderMethod for HybridMethod {
    fn method(&self) -> Method {
        Method::Hybrid
    }

    fn check(&self, bake: &Bake) -> Result<()> {
        self.btf.check(bake)
    }

    fn culls_itself(&self, bake: &Bake, frame: &FrameDesc) -> bool {
        self.btf.culls_itself(bake, frame)
    }

    fn shades_ground(&self) -> bool {
        true
    }

    fn knobs(&self) -> &'static [Knob] {
        &KNOBS
    }

    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        let settings = self.btf.settings(cx.frame, bake.impostor.is_some());
        let plan = self.btf.prepare_with(bake, &cx, &settings)?;
        self.impostors = 0;
        self.stats = None;
        let (Some(b), Some(imp), Some(bf)) =
            (bake.btf.as_ref(), bake.impostor.as_mut(), self.btf.frame())
        else {
            return Ok(plan);
        };
        if settings.impostor_px <= 0.0 {
            return Ok(plan);
        }
        let s = impostor_settings(cx.frame);
        let scene = b.scene();
        let records = super::impostor::prepare::records(
            &imp.species,
            &cx.world.tree_data,
            &bf.impostors,
            &cx.view,
            &s,
            s.show_lod.then_some(LOD_COLORS[Level::Tree]),
            ImpostorAssets::max_records(&cx.ctx.device),
            &mut |t, sp, m| scene.tree_shade(t, sp, m),
        );
        imp.upload(cx.ctx, &records, &s);
        self.impostors = records.len() as u32;
        self.parallax_depth = s.parallax_depth;
        self.stats = Some(imp.with_atlas(ImpostorStats {
            impostors: self.impostors,
            ..Default::default()
        }));
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
        bake.billboard_casters(ctx, layouts, world, to_sun, excluded)
    }

    fn ensure_pipelines(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        self.btf.ensure_pipelines(bake, ctx, layouts, format)?;
        if self.impostors > 0
            && let Some(imp) = bake.impostor.as_mut()
        {
            imp.ensure_pipeline(&ctx.device, layouts, format, self.parallax_depth);
        }
        Ok(())
    }

    fn encode_compute(&self, bake: &Bake, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        self.btf.encode_compute(bake, encoder, spans);
    }

    fn draw(
        &self,
        bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    ) {
        let count = self.impostors;
        let mut impostors = |pass: &mut wgpu::RenderPass<'_>, stats: &mut FrameStats| {
            let Some(imp) = bake.impostor.as_ref().filter(|_| count > 0) else {
                return;
            };
            cx.spans.mark(pass, "impostors");
            // Group 1 is the impostors'; the billboards after them bind their own.
            imp.draw(pass, count);
            stats.draw_calls += 1;
            stats.triangles += 2 * u64::from(count);
            stats.impostor = self.stats;
        };
        self.btf.draw_with(bake, pass, cx, stats, &mut impostors);
    }

    fn draw_after(
        &self,
        bake: &Bake,
        encoder: &mut wgpu::CommandEncoder,
        cx: &AfterCx<'_>,
        stats: &mut FrameStats,
    ) {
        self.btf.draw_after(bake, encoder, cx, stats);
    }

    fn finish(&self, bake: &Bake, ctx: &GpuContext, wait: bool, stats: &mut FrameStats) {
        self.btf.finish(bake, ctx, wait, stats);
    }
}

/// What the rest of the program asks of `hybrid`.
pub const INFO: MethodInfo = MethodInfo {
    name: "hybrid",
    summary: "btf, with a tree drawn as geometry wherever even its twig level's texels project above the LOD bound, cross-faded (needs a bake)",
    needs_bake: true,
    follows_sun: true,
    stat_rows,
};

/// `hybrid`'s statistics of a frame: `btf`'s, its trees drawn as geometry, and its tree
/// level's impostors.
fn stat_rows(stats: &FrameStats, frame: &FrameDesc) -> Vec<StatRow> {
    let mut rows = super::btf::method::stat_rows(stats, frame);
    if let Some(s) = &stats.btf {
        rows.push(StatRow::new(
            "trees as geometry",
            s.geometry_trees.to_string(),
        ));
        rows.push(StatRow::new(
            "tree level as impostors",
            match (frame.btf.impostor_px > 0.0, &stats.impostor) {
                (false, _) => "off".to_string(),
                (true, Some(_)) => format_count(u64::from(s.impostors)),
                (true, None) => "none baked ([bake] impostor_frames)".to_string(),
            },
        ));
    }
    rows.extend(super::impostor::method::stat_rows(stats, frame));
    rows
}
