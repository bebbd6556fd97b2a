//! The `surfel` method through the renderer's one interface.

use std::time::Instant;

use super::gpu::{SplatInput, Splatter, SurfelAssets};
use super::prepare::{SurfelFrame, near_geometry, prepare};
use super::sample::sample_species;
use super::settings::SurfelStats;
use crate::Result;
use crate::format::SurfelSet;
use crate::model::TreeModel;
use crate::render::GpuContext;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::geometry_trees::{draw_faded_trees, geometry_tree_plan};
use crate::render::method::info::{MethodInfo, StatRow, format_count, format_mb};
use crate::render::method::interface::{
    AfterCx, Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod, SunWork,
};
use crate::render::method::kind::Method;
use crate::render::pipelines::Layouts;
use crate::render::vcm_shading::TreeShades;
use crate::render::world_gpu::{TreeRun, WorldGpu};

/// Level-0 surfels a species is sampled with when the bake holds none (about; its levels
/// add a third).
pub const SURFEL_BUDGET: u32 = 250_000;
/// The finest spacing a species is sampled at (m).
pub const MIN_SPACING: f32 = 0.004;

/// Where the `surfel` method's LDC trees come from: the bake's, when it holds one for
/// every species, else the species sampled when a frame first asks for them.
#[derive(Default)]
pub struct SurfelSource {
    prototypes: Vec<TreeModel>,
    baked: Option<Vec<SurfelSet>>,
    /// Changes with every bake handed in, so that the method uploads the new trees.
    generation: u64,
}

impl SurfelSource {
    pub fn new(world: &crate::model::World) -> Self {
        Self {
            prototypes: world.species.clone(),
            baked: None,
            generation: 0,
        }
    }

    /// This source with `baked`'s surfel trees, when it holds one for every species (a
    /// bake without them, or handed over before they are made, leaves them to sampling).
    pub fn with_bake(self, baked: &crate::format::Baked) -> Self {
        let n = self.prototypes.len();
        let mut sets: Vec<SurfelSet> = baked
            .surfels
            .iter()
            .filter(|s| (s.species as usize) < n)
            .cloned()
            .collect();
        sets.sort_by_key(|s| s.species);
        let whole = sets.len() == n
            && sets
                .iter()
                .enumerate()
                .all(|(i, s)| s.species as usize == i);
        Self {
            baked: whole.then_some(sets),
            generation: self.generation + 1,
            ..self
        }
    }

    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Whether the trees come from the bake.
    pub fn is_baked(&self) -> bool {
        self.baked.is_some()
    }

    /// Every species' LDC tree: the bake's, or sampled now (in parallel).
    pub fn sets(&self) -> Vec<SurfelSet> {
        match &self.baked {
            Some(sets) => sets.clone(),
            None => sample_species(&self.prototypes, SURFEL_BUDGET, MIN_SPACING),
        }
    }
}

/// `surfel`: the species' surfels on the GPU, the splatting passes, the frame.
#[derive(Default)]
pub struct SurfelMethod {
    assets: Option<SurfelAssets>,
    /// The [`SurfelSource::generation`] the assets came from.
    generation: u64,
    splatter: Option<Splatter>,
    frame: SurfelFrame,
    /// Levels holes are filled from (surfel.wgsl's `fill`).
    fill: u32,
    mode: u32,
    /// The frame's pixels per metre at a metre (0: orthographic).
    focal_px: f32,
    /// The frame's `surfel_shadow` knob.
    self_shadow: f32,
    /// Trees drawn as geometry this frame (whole or fading in), and their runs: trunks and
    /// limbs, then twigs.
    geometry_trees: u32,
    runs: Vec<Vec<TreeRun>>,
}

impl SurfelMethod {
    /// Uploads the species' surfels (sampling them if the bake has none), on first use
    /// and for each new bake.
    fn ensure_assets(&mut self, bake: &Bake, ctx: &GpuContext) -> Result<()> {
        let generation = bake.surfels.generation();
        if self.assets.is_none() || self.generation != generation {
            self.assets = None;
            let t0 = Instant::now();
            let trees = bake.surfels.sets();
            log::info!(
                "surfels: {} species {} in {:.0} ms",
                trees.len(),
                if bake.surfels.is_baked() {
                    "loaded from the bake"
                } else {
                    "sampled"
                },
                t0.elapsed().as_secs_f64() * 1e3
            );
            self.assets = Some(SurfelAssets::new(ctx, trees)?);
            self.generation = generation;
        }
        Ok(())
    }
}

impl RenderMethod for SurfelMethod {
    fn method(&self) -> Method {
        Method::Surfel
    }

    fn check(&self, _bake: &Bake) -> Result<()> {
        // Without a bake the trees are drawn unshaded by visibility cube maps, with no
        // ground shadows.
        Ok(())
    }

    fn shades_ground(&self) -> bool {
        true
    }

    fn knobs(&self) -> &'static [crate::render::knob::Knob] {
        super::knobs::KNOBS
    }

    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        let settings = cx.frame.surfel;
        // Holes are filled from a pixel's neighbours, and from the coarser levels where the
        // surfels are spaced wider than a pixel.
        self.fill = if settings.fill {
            1 + u32::from(settings.surfel_px > 1.5) + u32::from(settings.surfel_px > 3.0)
        } else {
            0
        };
        self.mode = u32::from(settings.show_lod);
        self.self_shadow = settings.self_shadow;
        self.focal_px = if cx.view.camera.ortho.is_none() {
            cx.view.focal_px
        } else {
            0.0
        };
        let mut sun = SunWork::default();
        if cx.frame.trees {
            self.ensure_assets(bake, cx.ctx)?;
        }
        let vcm = settings.vcm && cx.frame.trees && bake.btf.is_some();
        if vcm && let Some(btf) = bake.btf.as_mut() {
            let t0 = Instant::now();
            if btf.update_sun(cx.view.to_sun) {
                sun.moved = true;
                sun.ms += t0.elapsed().as_secs_f64() * 1e3;
            }
        }
        let scene = bake.btf.as_ref().map(|b| b.scene());
        let (geometry, visible) = match &self.assets {
            Some(a) if cx.frame.trees => near_geometry(
                &a.species,
                &cx.world.tree_data,
                &cx.world.tree_bounds,
                &cx.visible,
                &cx.view,
                settings.geometry_px,
            ),
            _ => (vec![Vec::new(); cx.visible.len()], cx.visible.clone()),
        };
        self.frame = match &self.assets {
            Some(a) if cx.frame.trees => prepare(
                &a.species,
                &a.volume_offsets,
                &cx.world.tree_data,
                &visible,
                &cx.view,
                &settings,
                &mut |t, sp, m| scene.filter(|_| vcm).and_then(|s| s.tree_shade(t, sp, m)),
            ),
            _ => SurfelFrame::default(),
        };
        // The trees drawn as geometry, as `impostor` draws its near ones: in sun cascades of
        // their own and out of the ground alpha map; faded whole (trunk and limbs too), the
        // surfels drawn in the pixels they leave (the splatting starts from the frame's
        // depth). Instance 0 is the terrain's.
        let runs = cx
            .world
            .upload_lists_faded(cx.ctx, &[], &[&geometry, &geometry], None);
        self.geometry_trees = geometry.iter().map(|l| l.len() as u32).sum();
        let mut plan = geometry_tree_plan(cx.world, cx.frame, &geometry, &runs[0], sun);
        self.runs = runs;
        plan.layer = true;
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
        _bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        _format: wgpu::TextureFormat,
    ) -> Result<()> {
        if self.splatter.is_none() {
            self.splatter = Some(ctx.checked("building the surfel passes", || {
                Splatter::new(&ctx.device, layouts)
            })?);
        }
        Ok(())
    }

    fn draw(
        &self,
        _bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    ) {
        if self.geometry_trees > 0 {
            draw_faded_trees(pass, cx, &self.runs, stats);
        }
        stats.trees_drawn = self.frame.stats.trees.max(self.geometry_trees);
    }

    fn draw_after(
        &self,
        _bake: &Bake,
        encoder: &mut wgpu::CommandEncoder,
        cx: &AfterCx<'_>,
        stats: &mut FrameStats,
    ) {
        let (Some(assets), Some(splatter)) = (&self.assets, &self.splatter) else {
            return;
        };
        let input = SplatInput {
            surfels: &assets.surfels,
            volumes: &assets.volumes,
            items: &self.frame.items,
            trees: &self.frame.trees,
            fill: self.fill,
            mode: self.mode,
            focal_px: self.focal_px,
            self_shadow: self.self_shadow,
        };
        if let Err(e) = splatter.splat(
            cx.ctx,
            encoder,
            cx.frame_group,
            &input,
            (cx.depth, cx.layer),
            (cx.target, cx.format),
            cx.spans,
        ) {
            log::warn!("surfels not drawn: {e}");
            return;
        }
        stats.surfel = Some(SurfelStats {
            surfel_bytes: assets.bytes,
            surfels_held: assets.count,
            geometry_trees: self.geometry_trees,
            ..self.frame.stats
        });
    }
}

/// What the rest of the program asks of `surfel`.
pub const INFO: MethodInfo = MethodInfo {
    name: "surfel",
    summary: "Guennebaud and Paulin's LDC trees of surfels, each block at the level whose spacing is about a pixel, splatted in compute and hole-filled by pull-push (a bake adds the VCM shading and ground shadows)",
    needs_bake: true,
    follows_sun: true,
    stat_rows,
};

/// The surfels of a frame.
pub fn stat_rows(stats: &FrameStats, _frame: &FrameDesc) -> Vec<StatRow> {
    let Some(s) = &stats.surfel else {
        return Vec::new();
    };
    vec![
        StatRow::new("surfels splatted", format_count(s.surfels)),
        StatRow::new(
            "blocks (trees)",
            format!("{} ({})", format_count(u64::from(s.blocks)), s.trees),
        ),
        StatRow::new("levels drawn", format!("{} to {}", s.finest, s.coarsest)),
        StatRow::new("trees as geometry", s.geometry_trees.to_string()),
        StatRow::new(
            "surfels held",
            format!(
                "{} ({})",
                format_count(s.surfels_held),
                format_mb(s.surfel_bytes)
            ),
        ),
    ]
}
