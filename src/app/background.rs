//! The viewer's background work: the bake (from the cache or made on its own thread and
//! device), the re-bake of an edited scene file, the ground's sky visibility, and attaching
//! each when it is done.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::{App, reload};
use crate::model::World;
use crate::render::sky_visibility::SKY_DIRECTIONS;
use crate::render::{AdapterPreference, GpuContext, Method, Renderer};
use crate::scene::Scene;
use crate::{Error, Result};

/// A bake running on its own thread and GPU device, so the viewer stays responsive.
pub(super) struct BakeJob {
    progress: Arc<Mutex<crate::bake::Progress>>,
    /// What the bake costs, estimated before it starts (shown under its progress bar).
    estimate: Option<String>,
    started: Instant,
    /// The tree levels of a bake being made, as soon as they are (taken when shown).
    early: Arc<Mutex<Option<crate::format::Baked>>>,
    handle: std::thread::JoinHandle<Result<(crate::format::Baked, crate::bake::Source)>>,
}

impl BakeJob {
    /// Loads `scene`'s bake from the cache, or bakes it, on its own thread.
    fn start(scene: &Scene, world: &World) -> Self {
        let settings = crate::bake::cache::settings_of(scene);
        let estimate = crate::bake::estimate::estimate(&settings, world)
            .ok()
            .map(|e| {
                format!(
                    "if not cached: about {:.0} s, {:.0} MB of data, {:.0} MB of memory",
                    e.seconds,
                    e.file_bytes as f64 / 1e6,
                    e.memory_bytes as f64 / 1e6
                )
            });
        let progress = Arc::new(Mutex::new(crate::bake::Progress {
            done: 0,
            total: 1,
            what: "starting".into(),
        }));
        let sink = progress.clone();
        let early = Arc::new(Mutex::new(None));
        let early_sink = early.clone();
        let scene = scene.clone();
        let world = world.clone();
        let handle = std::thread::spawn(move || {
            let ctx = GpuContext::headless(AdapterPreference::Default)?;
            crate::bake::stages::load_or_bake_progressive(
                &crate::bake::cache::cache_path(&scene),
                &ctx,
                &scene,
                &world,
                &mut |p| {
                    if let Ok(mut slot) = sink.lock() {
                        *slot = p.clone();
                    }
                },
                Some(&mut |tree_levels| {
                    if let Ok(mut slot) = early_sink.lock() {
                        *slot = Some(tree_levels.clone());
                    }
                }),
            )
        });
        Self {
            progress,
            estimate,
            started: Instant::now(),
            early,
            handle,
        }
    }
}

/// An edit of the scene file that changes the bake: its bake runs while the old scene
/// stays on show.
pub(super) struct Rebake {
    job: BakeJob,
    scene: Scene,
    world: World,
}

impl App {
    /// The background work of one frame: the heap's upkeep, the bake, the sky visibility and
    /// the scene file's edits.
    pub(super) fn tend_background(&mut self) {
        self.heap.tend();
        self.tend_bake();
        self.tend_sky();
        self.tend_reload();
    }

    /// The btf method needs a bake: start one in the background, or attach a finished one.
    pub(super) fn tend_bake(&mut self) {
        let Some(r) = &mut self.running else { return };
        if let Some((baked, path)) = self.preloaded.take() {
            self.message = Some(match r.renderer.attach_btf(&r.ctx, &baked, &self.world) {
                Ok(()) => {
                    self.timeline.bake_done(self.frames);
                    (format!("BTF images from {}", path.display()), false)
                }
                Err(e) => {
                    self.bake_failed = true;
                    (format!("cannot use {}: {e}", path.display()), true)
                }
            });
            return;
        }
        // The bake starts with the viewer (from the cache when it can), whatever the method.
        if !r.renderer.has_btf() && self.bake_job.is_none() && !self.bake_failed {
            self.bake_job = Some(BakeJob::start(&self.scene, &self.world));
        }
        // A bake being made hands its tree levels over first: the forest is drawn from
        // them (finer levels as geometry) while the rest is made.
        let early = self
            .bake_job
            .as_ref()
            .and_then(|j| j.early.lock().ok().and_then(|mut slot| slot.take()));
        if let Some(tree_levels) = early {
            match r.renderer.attach_btf(&r.ctx, &tree_levels, &self.world) {
                Ok(()) => {
                    log::info!(
                        "timeline: the bake's tree levels attached, {:.1} s after the viewer started",
                        self.timeline.seconds()
                    );
                    self.stats.bake_partial = true;
                    self.message = Some((
                        "trees drawn from their tree level (nearer ones as geometry) while the bake goes on".into(),
                        false,
                    ));
                }
                Err(e) => log::warn!("the bake's tree levels cannot be drawn yet: {e}"),
            }
        }
        self.stats.bake_progress = self
            .bake_job
            .as_ref()
            .or(self.rebake.as_ref().map(|r| &r.job))
            .and_then(|j| {
                j.progress.lock().ok().map(|p| {
                    let left = crate::progress::seconds_left(&p, j.started.elapsed());
                    (p.done, p.total, p.what.clone(), left)
                })
            });
        self.stats.bake_estimate = self
            .bake_job
            .as_ref()
            .or(self.rebake.as_ref().map(|r| &r.job))
            .and_then(|j| j.estimate.clone());
        if self
            .bake_job
            .as_ref()
            .is_some_and(|j| j.handle.is_finished())
        {
            let Some(job) = self.bake_job.take() else {
                return;
            };
            self.stats.bake_progress = None;
            self.stats.bake_partial = false;
            let result = job
                .handle
                .join()
                .unwrap_or_else(|_| Err(Error::Gpu("the bake thread stopped unexpectedly".into())))
                .and_then(|(baked, source)| {
                    r.renderer.attach_btf(&r.ctx, &baked, &self.world)?;
                    Ok(source)
                });
            if result.is_ok() {
                self.timeline.bake_done(self.frames);
            }
            self.message = Some(match result {
                Ok(crate::bake::Source::Cache) => {
                    ("BTF images loaded from the cache".into(), false)
                }
                Ok(crate::bake::Source::Baked {
                    not_cached: Some(why),
                    ..
                }) => (
                    format!(
                        "baked, but the bake could not be cached ({why}); it is used from memory and will be baked again next time"
                    ),
                    true,
                ),
                Ok(crate::bake::Source::Baked { replaced: None, .. }) => {
                    ("BTF images baked and cached".into(), false)
                }
                Ok(crate::bake::Source::Baked {
                    replaced: Some(why),
                    ..
                }) => (
                    format!("the cached bake could not be used ({why}); baked again"),
                    false,
                ),
                Err(e) => {
                    self.bake_failed = true;
                    self.frame.method = Method::Geometry;
                    (format!("bake failed: {e}"), true)
                }
            });
        }
        self.stats.btf_bytes = r.renderer.btf_bytes();
        self.stats.vcm_bytes = r.renderer.vcm_bytes();
        self.stats.vcm_resolution = r.renderer.vcm_resolution();
    }

    /// Looks at the scene file and applies an edit (see [`reload`]); finishes a re-bake.
    pub(super) fn tend_reload(&mut self) {
        let Some(r) = &mut self.running else { return };
        if let Some(w) = self.watch.as_mut()
            && let Some(text) = w.poll()
        {
            let origin = w.path.display().to_string();
            let edit = match text {
                Ok(text) => reload::classify(&self.scene, &text, &origin),
                Err(why) => reload::Reload::Broken(why),
            };
            match edit {
                reload::Reload::Unchanged => {}
                reload::Reload::Frame(new) => {
                    reload::apply_frame_edit(&self.scene, &new, &mut self.frame);
                    self.scene = *new;
                    log::info!("applied the edit of {origin}");
                    self.message = Some((format!("applied the edit of {origin}"), false));
                }
                reload::Reload::Rebake(new, world) => {
                    log::info!("{origin} changes what is baked: baking it");
                    self.rebake = Some(Rebake {
                        job: BakeJob::start(&new, &world),
                        scene: *new,
                        world: *world,
                    });
                    self.message = Some((
                        format!(
                            "{origin} changes what is baked: baking it; the old scene stays until then"
                        ),
                        false,
                    ));
                }
                reload::Reload::Broken(why) => {
                    log::warn!("{why} (the last good scene stays)");
                    self.message = Some((format!("{why} (the last good scene stays)"), true));
                }
            }
        }
        if !self
            .rebake
            .as_ref()
            .is_some_and(|b| b.job.handle.is_finished())
        {
            return;
        }
        let Some(done) = self.rebake.take() else {
            return;
        };
        let result = done
            .job
            .handle
            .join()
            .unwrap_or_else(|_| Err(Error::Gpu("the bake thread stopped unexpectedly".into())))
            .and_then(|(baked, _)| {
                let mut renderer = Renderer::new(&r.ctx, &done.world)?;
                renderer.attach_btf(&r.ctx, &baked, &done.world)?;
                Ok(renderer)
            });
        match result {
            Ok(renderer) => {
                r.renderer = renderer;
                reload::apply_frame_edit(&self.scene, &done.scene, &mut self.frame);
                self.scene = done.scene;
                self.world = done.world;
                self.bake_job = None;
                self.bake_failed = false;
                self.stats.trees_total = self.world.forest.instances.len();
                self.gallery.reset();
                log::info!("the edited scene is baked and on show");
                self.message = Some(("the edited scene is baked and on show".into(), false));
            }
            Err(e) => {
                self.message = Some((
                    format!("the edited scene could not be baked: {e} (the last good scene stays)"),
                    true,
                ));
            }
        }
    }

    /// The image-based methods' ground sees the sky through the trees
    /// (`FrameDesc::ground_sky`): its volume is computed on its own thread for the renderer
    /// on show, and attached when done (a renderer replaced meanwhile gets its own).
    pub(super) fn tend_sky(&mut self) {
        let Some(r) = &mut self.running else { return };
        if !self.frame.ground_sky || r.renderer.has_sky() {
            return;
        }
        match self.sky_job.take() {
            Some((id, job)) if id == r.renderer.id() && job.is_finished() => match job.join() {
                Ok(volume) => {
                    if let Err(e) = r.renderer.attach_sky(&r.ctx, &volume, SKY_DIRECTIONS) {
                        log::warn!("the ground's sky visibility could not be used: {e}");
                        self.frame.ground_sky = false;
                    }
                }
                Err(_) => {
                    log::warn!("the ground's sky visibility thread stopped unexpectedly");
                    self.frame.ground_sky = false;
                }
            },
            Some((id, job)) if id == r.renderer.id() => self.sky_job = Some((id, job)),
            // None yet, or one for a renderer no longer on show (left to finish unseen).
            _ => {
                let world = self.world.clone();
                let scene = self.scene.clone();
                let job = std::thread::spawn(move || {
                    crate::bake::sky_cache::sky_volume(&scene, &world, SKY_DIRECTIONS, true)
                });
                self.sky_job = Some((r.renderer.id(), job));
            }
        }
    }
}
