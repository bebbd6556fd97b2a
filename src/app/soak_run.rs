//! Running a soak script in the viewer: its actions frame by frame, memory samples when due,
//! and at the end the report and the verdict.

use std::time::Instant;

use winit::event_loop::ActiveEventLoop;

use super::{App, soak};
use crate::Error;

/// A soak script's run: its clock starts once the bake is on show.
pub(super) struct SoakRun {
    script: soak::Script,
    started: Option<Instant>,
    frames: u64,
    next_action: usize,
    samples: Vec<soak::Sample>,
    /// When every action had run [`soak::WARM_CYCLES`] times (what is built on first use
    /// is built by then, however slow the frames).
    warm_at: Option<f64>,
    /// Resident memory read every frame since the last sample: its floor and its peak.
    resident: soak::Range,
    /// The device's allocated bytes (wgpu's allocator) read every frame since the last
    /// sample.
    device: soak::Range,
}

impl SoakRun {
    /// The run of `script`, its clock not started.
    pub(super) fn new(script: soak::Script) -> Self {
        Self {
            script,
            started: None,
            frames: 0,
            next_action: 0,
            samples: Vec::new(),
            warm_at: None,
            resident: soak::Range::default(),
            device: soak::Range::default(),
        }
    }
}

impl App {
    /// One frame of the soak script: the next action, a memory sample when due, and at
    /// the end the report and the verdict.
    pub(super) fn tend_soak(&mut self, event_loop: &ActiveEventLoop) {
        let (Some(run), Some(r)) = (self.soak.as_mut(), self.running.as_ref()) else {
            return;
        };
        let gpu_bytes = r.renderer.scene_bytes();
        run.resident.add(soak::resident_bytes());
        if let Some(b) = r.ctx.device_allocated_bytes() {
            run.device.add(b);
        }
        let sample = |t: f64, resident: &mut soak::Range, device: &mut soak::Range| {
            let (heap_used_bytes, heap_free_bytes) = crate::render::memory::heap_bytes();
            let (floor, peak) = resident.take();
            soak::Sample {
                seconds: t,
                resident_bytes: floor,
                resident_peak_bytes: peak,
                gpu_bytes,
                device_peak_bytes: device.take().1,
                heap_free_bytes,
                heap_used_bytes,
            }
        };
        let Some(started) = run.started else {
            // The clock starts once the one-off background work is on show: the whole bake
            // (not the tree levels a running bake hands over first: the rest of it is still
            // being made, and its memory is not growth), and the ground's sky visibility
            // (`tend_sky`), whose allocations are not growth either.
            let baked = (r.renderer.has_btf() && self.bake_job.is_none()) || self.bake_failed;
            if baked && (r.renderer.has_sky() || !self.frame.ground_sky) {
                run.started = Some(Instant::now());
                run.samples
                    .push(sample(0.0, &mut run.resident, &mut run.device));
            }
            return;
        };
        let t = started.elapsed().as_secs_f64();
        run.frames += 1;
        let mut action = None;
        if run.frames % u64::from(run.script.every_frames) == 0 && !run.script.actions.is_empty() {
            action = Some(run.script.actions[run.next_action % run.script.actions.len()]);
            run.next_action += 1;
        }
        let cycles = soak::WARM_CYCLES * run.script.actions.len().max(1);
        if run.warm_at.is_none() && (run.next_action >= cycles || run.script.actions.is_empty()) {
            run.warm_at = Some(t);
        }
        if t >= soak::next_due(&run.samples, run.script.sample_seconds) {
            run.samples
                .push(sample(t, &mut run.resident, &mut run.device));
        }
        let judged = soak::judgeable(&run.samples, run.script.sample_seconds, run.warm_at);
        // The script's length, and past it until the growth can be judged (a slow machine
        // warms up later), but never past `MAX_STRETCH` times the length.
        let done = t >= run.script.seconds && judged || t >= run.script.seconds * soak::MAX_STRETCH;
        if done && !judged && run.samples.last().is_some_and(|s| s.seconds < t) {
            run.samples
                .push(sample(t, &mut run.resident, &mut run.device));
        }
        if done {
            let Some(run) = self.soak.take() else { return };
            let csv = soak::csv(&run.samples);
            print!("{csv}");
            if let Some(path) = &run.script.report
                && let Err(e) = std::fs::write(path, &csv)
            {
                self.fail(
                    event_loop,
                    Error::Io {
                        path: path.clone(),
                        source: e,
                    },
                );
                return;
            }
            let after = soak::baseline_after(run.script.sample_seconds, run.warm_at);
            match soak::growth(&run.samples, after) {
                None => {
                    self.fail(
                        event_loop,
                        Error::BadInput(format!(
                            "soak: no two samples after the warm-up ({} s, every action run {} times, and an interval whose resident peak rose by at most {:.0} %) within {:.0} s: memory still rising, or run longer",
                            run.script.sample_seconds,
                            soak::WARM_CYCLES,
                            soak::SETTLED * 100.0,
                            run.script.seconds * soak::MAX_STRETCH
                        )),
                    );
                }
                Some((res, gpu)) if res > soak::MAX_GROWTH || gpu > soak::MAX_GROWTH => {
                    self.fail(
                        event_loop,
                        Error::BadInput(format!(
                            "soak: memory grew after the warm-up ({:.0} s): resident {:+.1} %, GPU {:+.1} % (at most {:.0} %)",
                            after,
                            res * 100.0,
                            gpu * 100.0,
                            soak::MAX_GROWTH * 100.0
                        )),
                    );
                }
                Some((res, gpu)) => {
                    println!(
                        "soak: {} frames; after the warm-up ({:.0} s) resident memory {:+.1} %, GPU memory {:+.1} %",
                        run.frames,
                        after,
                        res * 100.0,
                        gpu * 100.0
                    );
                    event_loop.exit();
                }
            }
            return;
        }
        match action {
            Some(soak::Action::Fly) => {
                let c = &mut self.frame.camera;
                c.position += c.forward() * 3.0;
                c.yaw += 5f32.to_radians();
            }
            Some(soak::Action::Sun) => {
                self.frame.sun.azimuth_deg = (self.frame.sun.azimuth_deg + 7.0) % 360.0;
            }
            Some(soak::Action::Method(m)) => self.frame.method = m,
            Some(soak::Action::Knob(name, v)) => {
                for k in crate::render::method::knobs_named(name) {
                    k.set(&mut self.frame, v);
                }
            }
            Some(soak::Action::Resize(w, h)) => {
                let _ = r
                    .window
                    .request_inner_size(winit::dpi::PhysicalSize::new(w, h));
            }
            Some(soak::Action::Screenshot) => {
                let path =
                    std::env::temp_dir().join(format!("canopy-soak-{}.png", std::process::id()));
                self.screenshot(&path);
            }
            None => {}
        }
    }
}
