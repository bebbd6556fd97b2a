//! The one interface every method implements ([`RenderMethod`]), what the core lends a
//! method for each step of a frame, and what a method hands back ([`Plan`]).
//!
//! A frame runs the same steps whatever the method: the core culls the trees (unless the
//! method finds its own), the method does its CPU work and uploads what it draws
//! ([`RenderMethod::prepare`]), the core rebuilds the ground shadow maps when the sun moved
//! (asking the method for its casters, [`RenderMethod::ground_casters`]), then encodes the
//! method's compute passes, the sun cascades with the casters the plan names, the sky, the
//! method's draws ([`RenderMethod::draw`]), and after the submission lets the method read
//! back what it counted ([`RenderMethod::finish`]).

use super::btf::BtfAssets;
use super::impostor::ImpostorAssets;
use super::kind::Method;
use super::surfel::method::SurfelSource;
use super::texel::{PendingTexel, TexelAssets};
use super::view::PrepareView;
use crate::format::Baked;
use crate::model::World;
use crate::render::GpuContext;
use crate::render::frame::{FrameDesc, FrameStats};
use crate::render::pipelines::{ColorPipelines, Layouts};
use crate::render::shadow::Cascades;
use crate::render::timing::PassSpans;
use crate::render::world_gpu::{TreeRun, WorldGpu};
use crate::{Error, Result};

/// What a bake gives the image-based methods once on the GPU. Several methods draw from
/// the same assets (`btf`, `billboard` and `hybrid` from the BTF images; `texel` reads the
/// trees' visibility cube maps beside its volumes), so the renderer holds them once and
/// lends them to whichever method draws.
#[derive(Default)]
pub struct Bake {
    /// The BTF image sets and the visibility cube maps.
    pub btf: Option<BtfAssets>,
    /// The texel volumes on the GPU, once a frame of a method that draws them asked for
    /// them ([`Self::texel_ready`]).
    pub texel: Option<TexelAssets>,
    /// The bake's texel volumes, checked, until then.
    pub texel_pending: Option<PendingTexel>,
    /// Why the bake's texel volumes could not be loaded (the other methods still draw).
    pub texel_problem: Option<String>,
    /// The octahedral impostors, when the bake has them and they could be loaded.
    pub impostor: Option<ImpostorAssets>,
    /// Why they could not be loaded (the other methods still draw).
    pub impostor_problem: Option<String>,
    /// The species the `surfel` method samples its LDC trees from.
    pub surfels: SurfelSource,
}

impl Bake {
    /// No bake yet: what the methods that need none draw from (`surfel`'s species, which
    /// the renderer hands on to each bake it loads).
    pub fn unbaked(world: &World) -> Self {
        Self {
            surfels: SurfelSource::new(world),
            ..Default::default()
        }
    }

    /// Drops every render pipeline the assets built (they are built again on next use).
    pub fn forget_pipelines(&mut self) {
        if let Some(b) = self.btf.as_mut() {
            b.forget_pipelines();
        }
        if let Some(t) = self.texel.as_mut() {
            t.forget_pipelines();
        }
        if let Some(i) = self.impostor.as_mut() {
            i.forget_pipeline();
        }
    }

    /// Loads `baked` for `world`. Volumes that cannot be loaded leave `btf` and `billboard`
    /// working (the reason is kept for the `texel` method's error).
    pub fn load(ctx: &GpuContext, baked: &Baked, world: &World) -> Result<Self> {
        let mut bake = Self {
            btf: Some(BtfAssets::new(ctx, baked, world)?),
            ..Default::default()
        };
        // A bake handed over before it is done (its tree levels) lacks what its settings ask
        // for: the methods that draw it say it is still coming.
        const COMING: &str = "still being baked: it draws when the bake is done";
        if baked.texels.is_empty() && baked.settings.texel_resolution > 0 {
            bake.texel_problem = Some(format!("the texel volumes are {COMING}"));
        }
        if baked.impostors.is_empty() && baked.settings.impostor_frames > 0 {
            bake.impostor_problem = Some(format!("the impostors are {COMING}"));
        }
        if !baked.texels.is_empty() {
            let max_dim = ctx.device.limits().max_texture_dimension_3d;
            match PendingTexel::new(baked, world, max_dim) {
                Ok(t) => bake.texel_pending = Some(t),
                Err(e) => {
                    log::warn!("the texel method is unavailable: {e}");
                    bake.texel_problem = Some(e.to_string());
                }
            }
        }
        if !baked.impostors.is_empty() {
            match ImpostorAssets::new(ctx, baked, world) {
                Ok(t) => bake.impostor = Some(t),
                Err(e) => {
                    log::warn!("the impostor method is unavailable: {e}");
                    bake.impostor_problem = Some(e.to_string());
                }
            }
        }
        Ok(bake)
    }

    /// The bake's tree-level billboards as the sun sees them, for the ground alpha shadow
    /// map (the casters of `btf`, `hybrid`, `billboard` and `impostor` alike), leaving out
    /// `excluded` trees; None without BTF images.
    pub fn billboard_casters(
        &mut self,
        ctx: &GpuContext,
        layouts: &Layouts,
        world: &WorldGpu,
        to_sun: glam::Vec3,
        excluded: &[u32],
    ) -> Option<GroundCasters> {
        let b = self.btf.as_mut()?;
        let count = b.prepare_sun(ctx, world, to_sun, excluded);
        Some(GroundCasters {
            pipeline: b
                .opacity_pipeline(&ctx.device, &layouts.shadow_frame)
                .clone(),
            bind_group: b.sun_bind_group().clone(),
            count,
            vertices: 6,
        })
    }

    /// Bytes of the bake's images, volumes and atlases on the GPU, every method's.
    pub fn gpu_bytes(&self) -> u64 {
        self.btf.as_ref().map_or(0, |b| b.bytes)
            + self.texel.as_ref().map_or(0, TexelAssets::total_bytes)
            + self.impostor.as_ref().map_or(0, |i| i.bytes)
    }

    /// The bake has texel volumes that can be drawn (on the GPU or still waiting to be).
    pub fn has_texels(&self) -> bool {
        self.texel.is_some() || self.texel_pending.is_some()
    }

    /// The texel volumes on the GPU, uploaded now if no frame has drawn them yet. None
    /// without them, or when the upload failed (the reason is then `texel_problem`).
    pub fn texel_ready(&mut self, ctx: &GpuContext) -> Option<&mut TexelAssets> {
        if self.texel.is_none()
            && let Some(pending) = self.texel_pending.take()
        {
            match TexelAssets::new(ctx, pending) {
                Ok(t) => self.texel = Some(t),
                Err(e) => {
                    log::warn!("the texel method is unavailable: {e}");
                    self.texel_problem = Some(e.to_string());
                }
            }
        }
        self.texel.as_mut()
    }

    /// The BTF assets, or the error a method that needs them gives.
    pub fn need_btf(&self, method: Method) -> Result<&BtfAssets> {
        self.btf.as_ref().ok_or_else(|| {
            Error::BadInput(format!(
                "the {} method needs baked BTF images: run `canopy bake` (the viewer bakes on first use)",
                method.name()
            ))
        })
    }
}

/// What the core lends a method for its CPU work.
pub struct PrepareCx<'a> {
    pub ctx: &'a GpuContext,
    pub world: &'a WorldGpu,
    /// The frame, as the core draws it (the reference's larger shadow reach applied).
    pub frame: &'a FrameDesc,
    pub view: PrepareView<'a>,
    /// Width over height of the target.
    pub aspect: f32,
    /// The trees in the camera's view, per species; every list empty when the method
    /// finds its own trees ([`RenderMethod::culls_itself`]) or the frame draws none.
    pub visible: Vec<Vec<u32>>,
}

/// Sun-dependent work a method did while preparing (the trees' VCM reads): timed apart,
/// as the sun update, not as the frame's preparation.
#[derive(Clone, Copy, Debug, Default)]
pub struct SunWork {
    pub moved: bool,
    pub ms: f64,
}

/// What the core needs from a method's CPU work to run the frame's shared passes.
pub struct Plan {
    /// The sun cascades the method's geometry is shaded with.
    pub cascades: Cascades,
    /// The cascades are drawn and sampled.
    pub shadows_on: bool,
    /// Each cascade's casters (None: nothing is drawn into the cascades).
    pub casters: Option<Vec<Vec<TreeRun>>>,
    /// The terrain casts into the cascades too.
    pub terrain_casts: bool,
    /// The cascades hold the method's geometry trees alone, whose shadows then fall on the
    /// rest of the scene through them (`hybrid`); those trees are in `ground_excluded`.
    pub geometry_tree_cascades: bool,
    /// Trees left out of the ground alpha shadow map (they cast through the cascades).
    pub ground_excluded: Vec<u32>,
    /// The reference's trees that shade themselves through maps of their own: the main
    /// view's runs and its trees per species (the `geometry` method with shadows on).
    pub self_shadowed: Option<(Vec<TreeRun>, Vec<Vec<u32>>)>,
    /// In the studio, each cascade's casters per species: a frame with the same casters
    /// and matrices keeps the maps the last one drew.
    pub studio_casters: Option<Vec<Vec<Vec<u32>>>>,
    pub sun: SunWork,
    /// The method draws its blended trees front to back into the trees' layer after the
    /// main pass ([`RenderMethod::draw_after`]).
    pub layer: bool,
}

impl Plan {
    /// A plan with no sun cascades and no reference: the cascades stay clear.
    pub fn without_cascades(sun: SunWork) -> Self {
        Self {
            cascades: Cascades::none(),
            shadows_on: false,
            casters: None,
            terrain_casts: false,
            geometry_tree_cascades: false,
            ground_excluded: Vec::new(),
            self_shadowed: None,
            studio_casters: None,
            sun,
            layer: false,
        }
    }
}

/// The casters of the ground alpha shadow map: instanced boxes or quads seen from the sun.
pub struct GroundCasters {
    pub pipeline: wgpu::RenderPipeline,
    pub bind_group: wgpu::BindGroup,
    pub count: u32,
    /// Vertices per instance (6 for a billboard's quad, 36 for a texel's box).
    pub vertices: u32,
}

/// What the core lends a method to draw in the main pass (group 0 and the trees' group 1
/// bound, the sky and the terrain drawn).
pub struct DrawCx<'a> {
    pub world: &'a WorldGpu,
    pub pipes: &'a ColorPipelines,
    /// The frame's group 0, for a method that binds its own groups and must restore it.
    pub frame_group: &'a wgpu::BindGroup,
    /// The reference draws its trees after the main pass, in batches: the main pass then
    /// draws the terrain only.
    pub trees_after: bool,
    /// The frame's timed passes. The method's draws are timed under its name; to time its
    /// parts apart, `spans.rename` names the first part and `spans.mark(pass, name)`
    /// begins each next one.
    pub spans: &'a PassSpans,
}

/// What the core lends a method after the main pass: the frame's depth and the trees'
/// layer, to draw blended trees front to back into ([`crate::render::layer`]).
pub struct AfterCx<'a> {
    pub ctx: &'a GpuContext,
    pub frame_group: &'a wgpu::BindGroup,
    pub depth: &'a crate::render::frame_bindings::DepthTarget,
    pub layer: &'a crate::render::layer::TreeLayer,
    /// The frame's colour target and its format, which the layer is put over.
    pub target: &'a wgpu::TextureView,
    pub format: wgpu::TextureFormat,
    pub spans: &'a PassSpans,
}

/// One way of drawing the forest. The renderer holds one of each ([`super::registry`]) and
/// runs the frame's steps through the one the frame names.
pub trait RenderMethod {
    /// The method this draws.
    fn method(&self) -> Method;

    /// Fails with what to do when the method cannot draw with `bake` (nothing baked, no
    /// volumes in the bake).
    fn check(&self, bake: &Bake) -> Result<()>;

    /// The method finds its own trees this frame (the core then skips its cull).
    fn culls_itself(&self, _bake: &Bake, _frame: &FrameDesc) -> bool {
        false
    }

    /// The method's trees shade the ground through the ground shadow maps and its ground
    /// sees the sky visibility (its trees are not geometry the cascades could draw).
    fn shades_ground(&self) -> bool {
        false
    }

    /// The method's own knobs (the panel's controls, the command line's flags, the bench's
    /// sweeps and `tune`'s grid follow them); the ground's are added where
    /// [`Self::shades_ground`].
    fn knobs(&self) -> &'static [crate::render::knob::Knob] {
        &[]
    }

    /// The frame's CPU work: levels of detail, expansion, sorting, shading factors, and the
    /// uploads of what the method draws.
    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan>;

    /// The method's trees as the sun sees them, for the ground alpha shadow map (None: it
    /// has none), leaving out `excluded` trees.
    fn ground_casters(
        &mut self,
        _bake: &mut Bake,
        _ctx: &GpuContext,
        _layouts: &Layouts,
        _world: &WorldGpu,
        _to_sun: glam::Vec3,
        _excluded: &[u32],
    ) -> Option<GroundCasters> {
        None
    }

    /// Builds (once per target format) the pipelines [`Self::draw`] uses.
    fn ensure_pipelines(
        &mut self,
        _bake: &mut Bake,
        _ctx: &GpuContext,
        _layouts: &Layouts,
        _format: wgpu::TextureFormat,
    ) -> Result<()> {
        Ok(())
    }

    /// Compute passes that open the frame, each timed through `spans`
    /// ([`PassSpans::compute_pass`] gives a named pass its timestamp writes).
    fn encode_compute(
        &self,
        _bake: &Bake,
        _encoder: &mut wgpu::CommandEncoder,
        _spans: &PassSpans,
    ) {
    }

    /// The method's draws in the main pass, after the sky.
    fn draw(
        &self,
        bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    );

    /// Where the plan asked for the trees' layer ([`Plan::layer`]): its passes after the
    /// main pass, which end with the layer put over the frame.
    fn draw_after(
        &self,
        _bake: &Bake,
        _encoder: &mut wgpu::CommandEncoder,
        _cx: &AfterCx<'_>,
        _stats: &mut FrameStats,
    ) {
    }

    /// After the frame's submission: what the GPU counted (this frame's when `wait`).
    fn finish(&self, _bake: &Bake, _ctx: &GpuContext, _wait: bool, _stats: &mut FrameStats) {}
}
