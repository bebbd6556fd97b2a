//! The reference's parts of the renderer: the sky visibility volume (also the image-based
//! methods' ground's), the frame adjustments of a reference frame and the trees' own sun
//! maps.

use super::frame::FrameDesc;
use super::sky_visibility::{self, SkyVisibility, SkyVolume};
use super::{GpuContext, Renderer, Stage, method::Plan, self_shadow, world_gpu};
use crate::model::World;
use crate::{Error, Result};

impl Renderer {
    /// The reference's sky visibility, once prepared: (directions, cell side in metres,
    /// bytes on the GPU).
    pub fn sky_visibility(&self) -> Option<(u32, f32, u64)> {
        self.sky_vis.as_ref().map(|s| (s.count, s.cell, s.bytes))
    }

    /// It has a sky visibility volume (the reference's, or the ground's).
    pub fn has_sky(&self) -> bool {
        self.sky_vis.is_some()
    }

    /// Uploads a sky visibility `volume` of this renderer's world, computed from
    /// `directions` directions (e.g. on another thread, by [`SkyVolume::compute`]).
    pub fn attach_sky(
        &mut self,
        ctx: &GpuContext,
        volume: &SkyVolume,
        directions: u32,
    ) -> Result<()> {
        self.sky_vis = Some(SkyVisibility::upload(ctx, volume, directions.max(1))?);
        Ok(())
    }

    /// Computes the reference's sky visibility of `world` (the world this renderer was made
    /// for) from `directions` directions: over the whole scene with its terrain, or over the
    /// trees alone in the studio (`terrain` false). Needed before reference frames; kept.
    pub fn prepare_reference(
        &mut self,
        ctx: &GpuContext,
        world: &World,
        directions: u32,
        terrain: bool,
    ) -> Result<()> {
        self.prepare_reference_with(ctx, world, directions, terrain, |bounds| {
            SkyVolume::compute(world, bounds, terrain, directions.max(1))
        })
    }

    /// [`Self::prepare_reference`] with the volume from `volume`, given the bounds it covers
    /// ([`sky_visibility::bounds_of`]): a cache's, or computed.
    pub fn prepare_reference_with(
        &mut self,
        ctx: &GpuContext,
        world: &World,
        directions: u32,
        terrain: bool,
        volume: impl FnOnce(&crate::model::mesh::Aabb) -> SkyVolume,
    ) -> Result<()> {
        if world.forest.instances.len() != self.world.tree_bounds.len()
            || world.species.len() != self.world.species.len()
        {
            return Err(Error::BadInput(format!(
                "the reference's world ({} trees, {} species) is not this renderer's ({} trees, {} species)",
                world.forest.instances.len(),
                world.species.len(),
                self.world.tree_bounds.len(),
                self.world.species.len()
            )));
        }
        let bounds = sky_visibility::bounds_of(world, terrain);
        if bounds.is_empty() {
            return Err(Error::BadInput(
                "the reference needs something to draw: the world is empty".into(),
            ));
        }
        let volume = volume(&bounds);
        self.attach_sky(ctx, &volume, directions)
    }

    /// Computes the sky visibility of `world` (trees and terrain, the reference's 64
    /// directions) once, for the image-based methods' ground (`FrameDesc::ground_sky`); a
    /// no-op when the reference's is there already.
    pub fn prepare_sky(&mut self, ctx: &GpuContext, world: &World) -> Result<()> {
        self.prepare_sky_with(ctx, world, |bounds| {
            SkyVolume::compute(world, bounds, true, sky_visibility::SKY_DIRECTIONS)
        })
    }

    /// [`Self::prepare_sky`] with the volume from `volume` (see
    /// [`Self::prepare_reference_with`]).
    pub fn prepare_sky_with(
        &mut self,
        ctx: &GpuContext,
        world: &World,
        volume: impl FnOnce(&crate::model::mesh::Aabb) -> SkyVolume,
    ) -> Result<()> {
        if self.sky_vis.is_some() {
            return Ok(());
        }
        self.prepare_reference_with(ctx, world, sky_visibility::SKY_DIRECTIONS, true, volume)
    }

    /// `frame` as the core draws it: a reference frame (the `geometry` method with
    /// [`FrameDesc::reference`]) checks the sky visibility is prepared and reaches every
    /// point of the scene with larger sun maps; other frames are drawn as given.
    pub(super) fn effective_frame(&self, frame: &FrameDesc) -> Result<FrameDesc> {
        let mut effective = *frame;
        let Some(r) = frame.reference_drawn() else {
            return Ok(effective);
        };
        match &self.sky_vis {
            Some(s) if s.count == r.sky_directions.max(1) => {}
            Some(s) => {
                return Err(Error::BadInput(format!(
                    "the reference frame asks for sky visibility from {} directions, the renderer has {}: call prepare_reference again",
                    r.sky_directions, s.count
                )));
            }
            None => {
                return Err(Error::BadInput(
                    "a reference frame needs the sky visibility: call Renderer::prepare_reference first".into(),
                ));
            }
        }
        // (The studio's one shadow map is fitted to the object already.)
        if frame.stage != Stage::Studio {
            effective.shadows.map_size = frame.shadows.map_size.max(r.sun_map_size);
            let far = self
                .world
                .scene_bounds
                .corners()
                .iter()
                .map(|c| c.distance(frame.camera.position))
                .fold(0.0f32, f32::max);
            effective.shadows.distance = frame.shadows.distance.max(far);
        }
        Ok(effective)
    }

    /// The reference's trees shade themselves through maps of their own, drawn in batches:
    /// their lights written for this frame (None when the plan has no such trees or the
    /// frame asks for no maps of their own).
    pub(super) fn prepare_self_shadow(
        &mut self,
        ctx: &GpuContext,
        frame: &FrameDesc,
        plan: &Plan,
        format: wgpu::TextureFormat,
    ) -> Result<Option<Vec<Vec<world_gpu::TreeRun>>>> {
        let size = frame.reference_drawn().map_or(0, |r| r.self_map_size);
        let Some((runs, trees)) = plan.self_shadowed.as_ref().filter(|_| size > 0) else {
            return Ok(None);
        };
        let ss = match self.self_shadow.take() {
            Some(ss) if ss.size == size => ss,
            _ => self_shadow::SelfShadow::new(
                ctx,
                &self.layouts,
                size,
                self_shadow::layers_for(size).min(self.world.tree_data.len().max(1) as u32),
                self.world.tree_data.len() + 1,
            )?,
        };
        let ss = self.self_shadow.insert(ss);
        ss.ensure_keys(ctx, frame.shadows.map_size)?;
        ss.ensure_pipelines(ctx, &self.layouts, format)?;
        Ok(Some(ss.write_lights(
            ctx,
            &self.world,
            runs,
            trees,
            frame.sun.direction(),
        )))
    }
}
