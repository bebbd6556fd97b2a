//! A frame's run through the renderer ([`Renderer::render`]), step by step: what the frame
//! needs set up (the method, the targets, the pipelines), the method's CPU work, the frame
//! uniforms with the ground maps, then one encoder with the frame's passes, and after the
//! submission the timings and what the method counted.

use super::frame_bindings::{DepthTarget, FrameBindings};
use super::ground::{GroundBillboards, GroundMaps};
use super::meshes::{encode_cascades, studio_cascades_key};
use super::method::{AfterCx, DrawCx, Plan, PrepareCx, PrepareView, SunWork};
use super::overdraw::{self, OverdrawView};
use super::pipelines::ColorPipelines;
use super::shadow;
use super::timing::{GpuTimer, PassSpans};
use super::uniforms::FrameUniforms;
use super::world_gpu::TreeRun;
use super::{
    FrameDesc, FrameStats, FrameTarget, GpuContext, Renderer, Stage, layer, shaders, target,
};
use crate::model::terrain_lod::TerrainView;
use crate::{Error, Result};

/// What the first step settles for one frame: where it goes, the method that draws it and
/// which of the shared passes it has.
struct FrameRun<'a> {
    frame: &'a FrameDesc,
    target: FrameTarget<'a>,
    measure_gpu: bool,
    /// The method's place in the renderer's `methods`.
    index: usize,
    studio: bool,
    /// The ground shadow maps are drawn (an image-based method's ground in the sun).
    ground_on: bool,
    /// The overdraw view, when it is on (never in the studio).
    overdraw_view: Option<OverdrawView>,
}

/// What the method's CPU work gives the rest of the frame.
struct Prepared {
    aspect: f32,
    /// The terrain's chunks and levels in view, when the method draws them so.
    terrain_levels: Option<TerrainView>,
    plan: Plan,
    /// The reference's trees, drawn after the main pass batch by batch (None without them).
    self_batches: Option<Vec<Vec<TreeRun>>>,
    prepare_ms: f64,
}

/// What the frame's passes draw with.
struct PassParts<'a> {
    bindings: &'a FrameBindings,
    depth: &'a DepthTarget,
    pipes: &'a ColorPipelines,
    spans: &'a PassSpans,
    /// The reference's trees' batches (empty without them).
    batches: &'a [Vec<TreeRun>],
}

impl Renderer {
    /// Draws `frame` into `target` and submits the work. With `measure_gpu`, waits for the
    /// GPU and returns its frame time in the stats; otherwise the time arrives a few frames
    /// later in [`Self::last_gpu_ms`].
    ///
    /// The steps: the method's CPU work, the reference's own tree maps, the frame uniforms
    /// and the ground shadow maps (when the sun moved), then one encoder with the method's
    /// compute passes, the sun cascades, the main pass (sky, then the method's draws) and
    /// the reference's trees; after the submission, the timings and what the method counted.
    pub fn render(
        &mut self,
        ctx: &GpuContext,
        frame: &FrameDesc,
        target: FrameTarget<'_>,
        measure_gpu: bool,
    ) -> Result<FrameStats> {
        target::check_size(target.width, target.height, Some(ctx))?;
        if ctx.is_lost() {
            return Err(Error::Gpu("the GPU device was lost; restart canopy".into()));
        }
        let frame = &self.effective_frame(frame)?;
        let run = self.begin_frame(ctx, frame, target, measure_gpu)?;
        let prepared = self.prepare_frame(ctx, &run)?;
        let sun = self.write_frame_uniforms(ctx, &run, &prepared);
        let mut stats = FrameStats {
            width: target.width,
            height: target.height,
            prepare_ms: prepared.prepare_ms.max(0.0),
            sun_update: sun.moved,
            sun_update_ms: sun.moved.then_some(sun.ms),
            ground_map_size: self
                .ground
                .as_ref()
                .filter(|_| run.ground_on)
                .and_then(|g| g.built_size()),
            ..Default::default()
        };
        self.submit_frame(ctx, &run, &prepared, &mut stats)?;
        self.finish_frame(ctx, &run, stats)
    }

    /// The frame's method (checked against the bake), and what it draws into made ready:
    /// the ground maps, the depth target, the overdraw counters and the format's pipelines.
    fn begin_frame<'a>(
        &mut self,
        ctx: &GpuContext,
        frame: &'a FrameDesc,
        target: FrameTarget<'a>,
        measure_gpu: bool,
    ) -> Result<FrameRun<'a>> {
        let FrameTarget {
            format,
            width,
            height,
            ..
        } = target;
        let studio = frame.stage == Stage::Studio;
        let index = self
            .methods
            .iter()
            .position(|m| m.method() == frame.method)
            .ok_or_else(|| {
                Error::BadInput(format!("no method {} is registered", frame.method.name()))
            })?;
        self.methods[index].check(&self.bake)?;
        // Image-based trees are not geometry, so their shadows on the ground come from the
        // alpha shadow map, and the terrain's own shadows from the terrain depth drawn with
        // it, both rebuilt only when the sun moves.
        let ground_on = self.methods[index].shades_ground()
            && frame.ground_shadows
            && frame.sun.elevation_deg > 0.0
            && !studio;
        if ground_on && self.ground.is_none() {
            self.ground = Some(GroundMaps::new(ctx, &self.layouts, &self.world)?);
        }
        self.ensure_depth(ctx, width, height)?;
        let overdraw_view = frame.overdraw.filter(|_| !studio);
        let pixels = u64::from(width) * u64::from(height);
        if overdraw_view.is_some() && self.overdraw.pixels() < pixels {
            self.overdraw = overdraw::OverdrawCounts::new(ctx, pixels)?;
        }
        // Pipelines count fragments only while the view is on (`frame.wgsl`): built again
        // when it turns on or off.
        let counting = overdraw_view.is_some();
        if counting != self.counting {
            self.counting = counting;
            self.color_pipelines.clear();
            if let Some(s) = self.self_shadow.as_mut() {
                s.forget_pipelines();
            }
            self.bake.forget_pipelines();
        }
        shaders::set_counting(counting);
        if !self.color_pipelines.contains_key(&format) {
            let p = ctx.checked("building the render pipelines", || {
                ColorPipelines::new(&ctx.device, &self.layouts, format)
            })?;
            self.color_pipelines.insert(format, p);
        }
        Ok(FrameRun {
            frame,
            target,
            measure_gpu,
            index,
            studio,
            ground_on,
            overdraw_view,
        })
    }

    /// The method's CPU work, then what its plan needs ready: its pipelines, the cascades'
    /// maps and group 0, the trees' layer and the reference's tree maps.
    fn prepare_frame(&mut self, ctx: &GpuContext, run: &FrameRun<'_>) -> Result<Prepared> {
        let FrameRun { frame, .. } = *run;
        let FrameTarget {
            format,
            width,
            height,
            ..
        } = run.target;
        // The method's CPU work. Work that follows the sun, not the camera (the VCM reads
        // there, the ground maps below) is timed as the sun update.
        let prepare_start = std::time::Instant::now();
        let aspect = width as f32 / height as f32;
        let cam = &frame.camera;
        let frustum = cam.frustum(aspect);
        let method = &mut self.methods[run.index];
        let terrain_levels = (method.shades_ground() && frame.terrain_px > 0.0).then(|| {
            self.world.terrain_view(
                &frustum,
                cam.position,
                cam.focal_px(height),
                frame.terrain_px,
            )
        });
        let visible = if frame.trees && !method.culls_itself(&self.bake, frame) {
            self.world.cull(&frustum)
        } else {
            vec![Vec::new(); self.world.species.len()]
        };
        let plan = method.prepare(
            &mut self.bake,
            PrepareCx {
                ctx,
                world: &self.world,
                frame,
                view: PrepareView {
                    camera: cam,
                    focal_px: cam.focal_px(height),
                    to_sun: frame.sun.direction(),
                    frustum: &frustum,
                },
                aspect,
                visible,
            },
        )?;
        method.ensure_pipelines(&mut self.bake, ctx, &self.layouts, format)?;
        let casts = plan.casters.is_some() || plan.self_shadowed.is_some();
        self.frames_without_casters = if casts {
            0
        } else {
            self.frames_without_casters.saturating_add(1)
        };
        let held = self.bindings.as_ref().map(|b| b.cascades.size);
        let side = shadow::cascade_side(frame.shadows.map_size, held, self.frames_without_casters);
        self.ensure_bindings(ctx, side)?;
        if plan.layer {
            let layer = self
                .layer
                .get_or_insert_with(|| layer::TreeLayer::new(&ctx.device));
            layer.ensure(ctx, width, height, format)?;
        }
        let self_batches = self.prepare_self_shadow(ctx, frame, &plan, format)?;
        let prepare_ms = prepare_start.elapsed().as_secs_f64() * 1e3 - plan.sun.ms;
        Ok(Prepared {
            aspect,
            terrain_levels,
            plan,
            self_batches,
            prepare_ms,
        })
    }

    /// The uniforms, with the ground maps rebuilt first when the sun moved, written for
    /// the frame and the meshes' passes; returns the sun work (the plan's, and the ground
    /// maps' when rebuilt).
    fn write_frame_uniforms(
        &mut self,
        ctx: &GpuContext,
        run: &FrameRun<'_>,
        prepared: &Prepared,
    ) -> SunWork {
        let FrameRun { frame, .. } = *run;
        let plan = &prepared.plan;
        // The uniforms, with the ground maps rebuilt first when the sun moved.
        let sky_hidden = frame.reference_drawn().is_some() || self.ground_sky_applies(frame);
        let mut uniforms = self.frame_uniforms_for(
            frame,
            prepared.aspect,
            &plan.cascades,
            plan.shadows_on,
            sky_hidden,
        );
        uniforms.hybrid_cascades = u32::from(plan.geometry_tree_cascades && plan.shadows_on);
        if let Some(view) = run.overdraw_view {
            uniforms.overdraw = [1, run.target.width, run.target.height, view.index()];
        }
        let mut sun = plan.sun;
        if run.ground_on {
            self.update_ground(ctx, run, plan, &mut uniforms, &mut sun);
        }
        ctx.queue
            .write_buffer(&self.frame_uniforms, 0, bytemuck::bytes_of(&uniforms));
        self.meshes
            .write_uniforms(ctx, &uniforms, &plan.cascades, plan.shadows_on);
        sun
    }

    /// Encodes the frame's passes in one encoder, timed, and submits it; the cascade maps
    /// are kept as drawn when a studio frame draws them as the last one did.
    fn submit_frame(
        &mut self,
        ctx: &GpuContext,
        run: &FrameRun<'_>,
        prepared: &Prepared,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let spans = self
            .timer
            .as_mut()
            .map_or_else(PassSpans::off, GpuTimer::begin);
        let self_shadowed = self.self_shadow.is_some() && prepared.self_batches.is_some();
        let studio_key = prepared
            .plan
            .studio_casters
            .as_ref()
            .filter(|_| !self_shadowed)
            .map(|c| studio_cascades_key(&prepared.plan.cascades, run.frame.shadows.map_size, c));
        let keep = studio_key.is_some() && self.studio_cascades == studio_key;
        let mut encoder = self.encode_frame(ctx, run, prepared, &spans, keep, stats)?;
        if let Some(t) = &mut self.timer {
            t.resolve(spans, &mut encoder);
        }
        ctx.queue.submit([encoder.finish()]);
        self.studio_cascades = studio_key;
        Ok(())
    }

    /// The frame's encoder with its passes: the method's compute passes, the cascades, the
    /// main pass, the method's passes after it, the reference's trees and the overdraw view.
    fn encode_frame(
        &self,
        ctx: &GpuContext,
        run: &FrameRun<'_>,
        prepared: &Prepared,
        spans: &PassSpans,
        keep: bool,
        stats: &mut FrameStats,
    ) -> Result<wgpu::CommandEncoder> {
        let FrameTarget {
            view: target,
            format,
            width,
            height,
        } = run.target;
        let plan = &prepared.plan;
        let self_shadow = self
            .self_shadow
            .as_ref()
            .filter(|_| prepared.self_batches.is_some());
        let (Some(bindings), Some(depth), Some(pipes)) = (
            &self.bindings,
            &self.depth,
            self.color_pipelines.get(&format),
        ) else {
            return Err(Error::Gpu("render targets were not created".into()));
        };
        let method = &self.methods[run.index];
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        // Each pass is timed as a span of its own (see `timing`): the method's compute
        // passes, the cascades, then the main pass split into the sky, the terrain and the
        // method's draws where the adapter can time inside a pass.
        if run.overdraw_view.is_some() {
            self.overdraw.clear(&mut encoder, width, height);
        }
        method.encode_compute(&self.bake, &mut encoder, spans);
        encode_cascades(
            &mut encoder,
            bindings,
            &self.meshes,
            &self.world,
            plan.casters.as_deref().filter(|_| !keep),
            plan.terrain_casts,
            self_shadow,
            keep,
            spans,
            stats,
        );
        // The reference's trees are drawn after the main pass, batch by batch.
        let parts = PassParts {
            bindings,
            depth,
            pipes,
            spans,
            batches: prepared.self_batches.as_deref().unwrap_or(&[]),
        };
        self.encode_main_pass(&mut encoder, run, prepared, &parts, stats);
        if plan.layer
            && let Some(layer) = &self.layer
        {
            let cx = AfterCx {
                ctx,
                frame_group: &bindings.bind_group,
                depth,
                layer,
                target,
                format,
                spans,
            };
            method.draw_after(&self.bake, &mut encoder, &cx, stats);
        }
        if let Some(ss) = self_shadow.filter(|_| !parts.batches.is_empty()) {
            ss.draw_trees(
                &mut encoder,
                &self.world,
                &bindings.bind_group,
                (target, format, depth),
                parts.batches,
                spans,
                stats,
            )?;
        }
        if run.overdraw_view.is_some() {
            encode_overdraw_view(&mut encoder, target, &parts);
        }
        Ok(encoder)
    }

    /// The main pass: the sky and the terrain (but in the studio), then the method's draws.
    fn encode_main_pass(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        run: &FrameRun<'_>,
        prepared: &Prepared,
        parts: &PassParts<'_>,
        stats: &mut FrameStats,
    ) {
        let PassParts {
            bindings,
            depth,
            pipes,
            spans,
            batches,
        } = *parts;
        let studio = run.studio;
        let main = spans.open(if studio || !spans.splits_passes() {
            "main pass"
        } else {
            "sky"
        });
        let mut pass = depth.color_pass(
            encoder,
            "main",
            run.target.view,
            Some(if studio {
                wgpu::Color::TRANSPARENT
            } else {
                wgpu::Color::BLACK
            }),
            !batches.is_empty() || prepared.plan.layer,
            spans.render_writes(main, true, true),
        );
        pass.set_bind_group(0, &bindings.bind_group, &[]);
        if !studio {
            pass.set_pipeline(&pipes.sky);
            pass.draw(0..3, 0..1);
            stats.draw_calls += 1;
        }
        pass.set_bind_group(1, &self.world.trees_bind_group(), &[]);
        if !studio {
            // Instance 0 of every method's upload is the terrain's.
            spans.mark(&mut pass, "terrain");
            let (tris, calls) = match &prepared.terrain_levels {
                Some(levels) => {
                    pass.set_pipeline(pipes.meshes().opaque);
                    self.world.draw_terrain_levels(&mut pass, levels)
                }
                None => {
                    let (tris, _, calls) =
                        self.world
                            .draw(&mut pass, &[], Some(pipes.meshes()), true, &[]);
                    (tris, calls)
                }
            };
            stats.triangles += tris;
            stats.draw_calls += calls;
        }
        let method = &self.methods[run.index];
        spans.mark(&mut pass, method.method().name());
        let cx = DrawCx {
            world: &self.world,
            pipes,
            frame_group: &bindings.bind_group,
            trees_after: !batches.is_empty(),
            spans,
        };
        method.draw(&self.bake, &mut pass, &cx, stats);
    }

    /// After the submission: the GPU timings (waited for when measuring), what the method
    /// counted, the overdraw view's means, the ground maps' timing, and any GPU error.
    fn finish_frame(
        &mut self,
        ctx: &GpuContext,
        run: &FrameRun<'_>,
        mut stats: FrameStats,
    ) -> Result<FrameStats> {
        let measure_gpu = run.measure_gpu;
        if let Some(t) = &mut self.timer {
            t.after_submit();
            if let Some(timing) = t.collect(ctx, measure_gpu).filter(|_| measure_gpu) {
                stats.gpu_ms = Some(timing.frame_ms);
                stats.passes = timing.passes;
            }
        }
        self.methods[run.index].finish(&self.bake, ctx, measure_gpu, &mut stats);
        if run.overdraw_view.is_some() && measure_gpu {
            stats.overdraw = Some(
                self.overdraw
                    .means(ctx, run.target.width, run.target.height)?,
            );
        }
        if let Some(t) = self.ground.as_mut().and_then(|g| g.timer.as_mut()) {
            t.collect(ctx, measure_gpu);
        }
        if let Some(e) = ctx.take_error() {
            return Err(Error::Gpu(e));
        }
        Ok(stats)
    }

    /// Rebuilds the ground shadow maps when the sun moved (or the trees or casters changed),
    /// from the method's casters seen from the sun, and sets their uniforms; submitted on
    /// their own so that their cost can be timed (blocking, when measuring), as sun work.
    fn update_ground(
        &mut self,
        ctx: &GpuContext,
        run: &FrameRun<'_>,
        plan: &Plan,
        uniforms: &mut FrameUniforms,
        sun: &mut SunWork,
    ) {
        let FrameRun {
            frame,
            index,
            measure_gpu,
            ..
        } = *run;
        let Some(ground) = self.ground.as_mut() else {
            return;
        };
        let excluded_key = plan.ground_excluded.iter().fold(0u64, |h, &t| {
            (h ^ u64::from(t) ^ 0x9e37_79b9_7f4a_7c15).wrapping_mul(0x0100_0000_01b3)
        });
        let (want, rebuild) = ground.wanted(
            frame.sun.direction(),
            frame.trees,
            frame.method,
            frame.sun_held,
            excluded_key,
        );
        if rebuild {
            let t0 = std::time::Instant::now();
            let casters = if want.trees {
                self.methods[index].ground_casters(
                    &mut self.bake,
                    ctx,
                    &self.layouts,
                    &self.world,
                    want.to_sun,
                    &plan.ground_excluded,
                )
            } else {
                None
            };
            let billboards = casters.as_ref().map(|c| GroundBillboards {
                pipeline: &c.pipeline,
                bind_group: &c.bind_group,
                count: c.count,
                vertices: c.vertices,
            });
            ground.build(ctx, &self.world, uniforms, want, billboards);
            if measure_gpu {
                let _ = ctx.device.poll(wgpu::PollType::wait_indefinitely());
            }
            sun.moved = true;
            sun.ms += t0.elapsed().as_secs_f64() * 1e3;
        }
        ground.apply(uniforms, frame.shadows.enabled);
    }
}

/// The overdraw view over the frame: its counts as a heat map, drawn over the picture.
fn encode_overdraw_view(
    encoder: &mut wgpu::CommandEncoder,
    target: &wgpu::TextureView,
    parts: &PassParts<'_>,
) {
    let spans = parts.spans;
    let heat = spans.open("overdraw view");
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("overdraw view"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: target,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Load,
                store: wgpu::StoreOp::Store,
            },
        })],
        depth_stencil_attachment: None,
        timestamp_writes: spans.render_writes(heat, true, true),
        occlusion_query_set: None,
        multiview_mask: None,
    });
    pass.set_pipeline(&parts.pipes.overdraw);
    pass.set_bind_group(0, &parts.bindings.bind_group, &[]);
    pass.draw(0..3, 0..1);
}
