//! The GPU half of `canopy bench`: every frame of a flight rendered as the ground truth
//! (`geometry`, supersampled, cached by [`TruthKey`]) and by every configuration (a method
//! with one value of each swept knob), each timed and compared with the truth and with its
//! own previous frame.

use std::path::PathBuf;

use image::{RgbImage, RgbaImage};

use super::flight::FlightFrame;
use super::temporal::{Flicker, Pop, flicker};
use super::truth_key::{TruthKey, TruthLookup, TruthRequest};
use crate::metrics;
use crate::render::knob::{Knob, KnobValue, KnobValues};
use crate::render::measure::TimeSource;
use crate::render::method::{all_knobs, knobs_of};
use crate::render::{FrameDesc, GpuContext, Method, Renderer};
use crate::{Error, Result};

/// One `--sweep KEY=V1,V2,...`: the values of one knob name (every method's knob of that
/// name, [`crate::render::method::knobs_named`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Sweep {
    pub knob: &'static Knob,
    pub values: Vec<KnobValue>,
}

impl Sweep {
    /// Parses `KEY=V1,V2,...`, checking every value against the knob.
    pub fn parse(s: &str) -> Result<Sweep> {
        let names = || {
            all_knobs()
                .iter()
                .map(|k| k.name)
                .collect::<Vec<_>>()
                .join(", ")
        };
        let (key, values) = s.split_once('=').ok_or_else(|| {
            Error::BadInput(format!(
                "--sweep {s}: write KEY=V1,V2,... with KEY one of {}",
                names()
            ))
        })?;
        let key = key.trim().replace('-', "_");
        let knob = all_knobs()
            .into_iter()
            .find(|k| k.name == key)
            .ok_or_else(|| {
                Error::BadInput(format!(
                    "--sweep: unknown knob `{key}`; the knobs are {}",
                    names()
                ))
            })?;
        let values = values
            .split(',')
            .map(str::trim)
            .filter(|v| !v.is_empty())
            .map(|v| {
                knob.parse(v)
                    .map_err(|e| Error::BadInput(format!("--sweep {}={v}: {e}", knob.name)))
            })
            .collect::<Result<Vec<_>>>()?;
        if values.is_empty() {
            return Err(Error::BadInput(format!("--sweep {s}: no values")));
        }
        Ok(Sweep { knob, values })
    }

    /// The sweep changes `method` (reads a knob of its name).
    pub fn applies_to(&self, method: Method) -> bool {
        knobs_of(method).iter().any(|k| k.name == self.knob.name)
    }
}

/// One configuration: a method and the value of each of its knobs.
#[derive(Clone, Debug, PartialEq)]
pub struct Config {
    /// e.g. `btf lod_scale=2 weight_threshold=0.1`, or the method's name.
    pub label: String,
    pub method: Method,
    /// Every knob of the method ([`knobs_of`]), set on each frame it draws.
    pub knobs: KnobValues,
}

impl Config {
    /// `method`, labelled `label`, with every knob it reads as `frame` has them (the
    /// ground's too, where it has them: they then override the frame a run starts from).
    pub fn from_frame(label: impl Into<String>, method: Method, frame: &FrameDesc) -> Self {
        Self {
            label: label.into(),
            method,
            knobs: KnobValues::read(knobs_of(method), frame),
        }
    }
}

/// Most configurations one bench may run.
pub const MAX_CONFIGS: usize = 256;

/// Every method once per combination of the values swept of its own knobs (a method none
/// of the sweeps applies to runs once), each knob not swept as `base` has it.
pub fn configurations(
    methods: &[Method],
    sweeps: &[Sweep],
    base: &FrameDesc,
) -> Result<Vec<Config>> {
    let mut out = Vec::new();
    for &method in methods {
        let start = KnobValues::read(knobs_of(method), base);
        let mut combos: Vec<(String, KnobValues)> = vec![(String::new(), start)];
        for sweep in sweeps.iter().filter(|s| s.applies_to(method)) {
            let own = knobs_of(method)
                .iter()
                .find(|k| k.name == sweep.knob.name)
                .copied()
                .unwrap_or(sweep.knob);
            let mut next = Vec::new();
            for (label, k) in &combos {
                for v in &sweep.values {
                    let mut k = k.clone();
                    k.set(own, *v);
                    next.push((format!("{label} {}={v}", own.name), k));
                }
            }
            combos = next;
            if combos.len() > MAX_CONFIGS {
                return Err(Error::BadInput(format!(
                    "the sweeps make more than {MAX_CONFIGS} configurations; sweep fewer values"
                )));
            }
        }
        for (label, k) in combos {
            out.push(Config {
                label: format!("{}{label}", method.name()),
                method,
                knobs: k,
            });
        }
    }
    if out.is_empty() {
        return Err(Error::BadInput(
            "--methods: name at least one method".into(),
        ));
    }
    Ok(out)
}

/// How to run a bench.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel side of the truth.
    pub truth_supersample: u32,
    /// Timed renders per frame and configuration (the median is kept).
    pub repeats: u32,
    /// Where the truth frames are cached.
    pub cache_dir: PathBuf,
    /// The scene's content ([`super::truth_key::scene_content`]), for the truth's key.
    pub scene_content: Vec<u8>,
    /// The truth is `geometry` drawn as the reference (sky visibility, whole-scene sun
    /// shadows); `None`: the interactive `geometry` (cheaper, for quick checks).
    pub reference: Option<crate::render::Reference>,
}

/// One frame of one configuration.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FrameRow {
    pub frame: usize,
    /// Index into the configurations.
    pub config: usize,
    /// Median frame time (ms) of the repeats.
    pub ms: f64,
    /// CPU time of culling and the method's prepare step (ms, median).
    pub prepare_ms: f64,
    /// Each pass's GPU time (ms, median of the repeats; empty without timestamps).
    pub passes: crate::render::timing::PassTimes,
    pub mean_flip: f64,
    pub p95_flip: f64,
    /// FLIP between this frame and the one before, of the method and of the truth (absent
    /// for the first frame).
    pub change: Option<f64>,
    pub truth_change: Option<f64>,
}

/// One configuration along the whole flight.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ConfigSummary {
    pub label: String,
    pub method: String,
    pub median_ms: f64,
    pub median_prepare_ms: f64,
    /// Median frame time of `geometry` over this one's (when geometry ran).
    pub speedup_vs_geometry: Option<f64>,
    pub mean_flip: f64,
    /// Mean over the frames of each frame's 95th percentile.
    pub p95_flip: f64,
    /// Mean frame-to-frame change of the method over the truth's (1: as steady as the truth).
    pub flicker_ratio: f64,
    /// The largest frame-to-frame change beyond the truth's, and its frame.
    pub worst_pop: Option<Pop>,
    /// The frame with the largest mean FLIP, and that FLIP.
    pub worst_frame: usize,
    pub worst_frame_flip: f64,
}

/// The images of a configuration's worst frame.
pub struct WorstFrame {
    pub frame: usize,
    pub truth: RgbaImage,
    pub method: RgbaImage,
    pub flip_map: RgbImage,
}

/// Everything a bench measured.
pub struct BenchResults {
    pub configs: Vec<Config>,
    pub rows: Vec<FrameRow>,
    pub summaries: Vec<ConfigSummary>,
    pub worst: Vec<Option<WorstFrame>>,
    pub frames: usize,
    pub time_source: TimeSource,
    /// Truth frames rendered now and found in the cache.
    pub truth_rendered: usize,
    pub truth_cached: usize,
}

impl BenchResults {
    /// Appends the results of other configurations measured along the same frames (their
    /// indices follow this one's).
    pub fn append(&mut self, other: BenchResults) {
        let offset = self.configs.len();
        self.configs.extend(other.configs);
        self.rows.extend(other.rows.into_iter().map(|mut r| {
            r.config += offset;
            r
        }));
        self.worst.extend(other.worst);
        self.truth_rendered += other.truth_rendered;
        self.truth_cached += other.truth_cached;
        if other.time_source == TimeSource::CpuWallClock {
            self.time_source = TimeSource::CpuWallClock;
        }
        // Speed-ups are relative to a geometry run among all of them.
        self.summaries.extend(other.summaries);
        set_speedups(&mut self.summaries);
    }
}

/// What the bench is doing, for a progress bar.
#[derive(Clone, Copy, Debug)]
pub enum BenchStep<'a> {
    /// Rendering (or loading) the truth of frame `frame`.
    Truth { frame: usize, cached: bool },
    /// Rendering configuration `label` at frame `frame`.
    Config { frame: usize, label: &'a str },
    /// Frame `frame` is finished (`done` of `total` frames).
    FrameDone { done: usize, total: usize },
}

/// The `q` quantile of `v` (sorted in place).
fn quantile(v: &mut [f32], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    f64::from(v[((v.len() - 1) as f64 * q).round() as usize])
}

fn rgb(img: &RgbaImage) -> RgbImage {
    image::DynamicImage::ImageRgba8(img.clone()).to_rgb8()
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The truth of one frame: from the cache, or rendered (geometry, supersampled) and stored.
fn truth_frame(
    ctx: &GpuContext,
    renderer: &mut Renderer,
    desc: &FrameDesc,
    f: &FlightFrame,
    opts: &BenchOptions,
) -> Result<(RgbaImage, bool)> {
    let mut truth = *desc;
    truth.method = Method::Geometry;
    truth.reference = opts.reference;
    let sun = truth.sun.direction();
    let key = TruthKey::new(&TruthRequest {
        scene: &opts.scene_content,
        position: f.position,
        look_at: f.look_at,
        fov_y_deg: truth.camera.fov_y_deg,
        sun_direction: sun,
        sun_radiance: truth.sun.color * truth.sun.intensity,
        width: opts.width,
        height: opts.height,
        supersample: opts.truth_supersample,
        extra: format!(
            "fog {} exposure {} sky {:?} shadows {:?} reference {:?}",
            truth.fog_density, truth.exposure, truth.sky, truth.shadows, truth.reference
        )
        .as_bytes(),
    });
    match key.load(&opts.cache_dir) {
        TruthLookup::Hit(img) => return Ok((img, true)),
        TruthLookup::Missing => {}
        TruthLookup::Unusable { path, reason } => {
            log::warn!(
                "truth {} unusable ({reason}); rendering it again",
                path.display()
            )
        }
    }
    let (img, _) =
        renderer.render_image(ctx, &truth, opts.width, opts.height, opts.truth_supersample)?;
    if let Err(e) = key.store(&opts.cache_dir, &img) {
        log::warn!("could not cache a truth frame: {e}");
    }
    Ok((img, false))
}

/// Runs every configuration along `frames` (from a flight), starting from `base` (the
/// scene's frame: sky, fog, exposure, sun colour). The renderer needs the bake attached
/// when a configuration draws baked images.
pub fn run(
    ctx: &GpuContext,
    renderer: &mut Renderer,
    base: &FrameDesc,
    frames: &[FlightFrame],
    configs: &[Config],
    opts: &BenchOptions,
    progress: &mut dyn FnMut(BenchStep),
) -> Result<BenchResults> {
    if frames.is_empty() {
        return Err(Error::BadInput("the flight has no frames".into()));
    }
    let (w, h) = (opts.width, opts.height);
    let mut rows = Vec::with_capacity(frames.len() * configs.len());
    let mut prev: Vec<Option<RgbImage>> = vec![None; configs.len()];
    let mut worst: Vec<Option<WorstFrame>> = configs.iter().map(|_| None).collect();
    let mut worst_flip = vec![0.0f64; configs.len()];
    let mut prev_truth: Option<RgbImage> = None;
    let (mut rendered, mut cached) = (0, 0);
    let mut source = TimeSource::GpuTimestamps;
    for (i, f) in frames.iter().enumerate() {
        let mut desc = *base;
        f.apply(&mut desc);
        let (truth, was_cached) = truth_frame(ctx, renderer, &desc, f, opts)?;
        progress(BenchStep::Truth {
            frame: i,
            cached: was_cached,
        });
        if was_cached {
            cached += 1;
        } else {
            rendered += 1;
        }
        let truth_rgb = rgb(&truth);
        let truth_change = match &prev_truth {
            Some(p) => Some(f64::from(metrics::flip(p, &truth_rgb)?.stats.mean)),
            None => None,
        };
        for (c, config) in configs.iter().enumerate() {
            progress(BenchStep::Config {
                frame: i,
                label: &config.label,
            });
            let mut d = desc;
            d.method = config.method;
            config.knobs.apply_to(&mut d);
            // The flight's own knobs win over the configuration's.
            f.apply(&mut d);
            if i == 0 {
                // The first frame builds pipelines: not timed.
                renderer.render_image(ctx, &d, w, h, 1)?;
            }
            let mut times = Vec::new();
            let mut prep = Vec::new();
            let mut passes = Vec::new();
            let mut image = None;
            for _ in 0..opts.repeats.max(1) {
                let t0 = std::time::Instant::now();
                let (img, stats) = renderer.render_image(ctx, &d, w, h, 1)?;
                let wall = t0.elapsed().as_secs_f64() * 1e3;
                if stats.gpu_ms.is_none() {
                    source = TimeSource::CpuWallClock;
                }
                times.push(stats.gpu_ms.unwrap_or(wall));
                prep.push(stats.prepare_ms);
                passes.push(stats.passes);
                image = Some(img);
            }
            let Some(img) = image else { continue };
            let img_rgb = rgb(&img);
            let mut res = metrics::flip(&truth_rgb, &img_rgb)?;
            let mean_flip = f64::from(res.stats.mean);
            let change = match &prev[c] {
                Some(p) => Some(f64::from(metrics::flip(p, &img_rgb)?.stats.mean)),
                None => None,
            };
            if worst[c].is_none() || mean_flip > worst_flip[c] {
                worst_flip[c] = mean_flip;
                worst[c] = Some(WorstFrame {
                    frame: i,
                    truth: truth.clone(),
                    method: img.clone(),
                    flip_map: res.error_image(),
                });
            }
            rows.push(FrameRow {
                frame: i,
                config: c,
                ms: median(&mut times),
                prepare_ms: median(&mut prep),
                passes: crate::render::timing::PassTimes::median(&passes),
                mean_flip,
                p95_flip: quantile(&mut res.errors, 0.95),
                change,
                truth_change,
            });
            prev[c] = Some(img_rgb);
        }
        prev_truth = Some(truth_rgb);
        progress(BenchStep::FrameDone {
            done: i + 1,
            total: frames.len(),
        });
    }
    let summaries = summarise(configs, &rows)?;
    Ok(BenchResults {
        configs: configs.to_vec(),
        rows,
        summaries,
        worst,
        frames: frames.len(),
        time_source: source,
        truth_rendered: rendered,
        truth_cached: cached,
    })
}

/// Each summary's speed-up against the `geometry` one among them (none without it).
fn set_speedups(summaries: &mut [ConfigSummary]) {
    let geo = summaries
        .iter()
        .find(|s| s.method == "geometry")
        .map(|s| s.median_ms);
    for s in summaries {
        s.speedup_vs_geometry = geo.filter(|_| s.median_ms > 0.0).map(|g| g / s.median_ms);
    }
}

/// Per configuration: the medians, means and temporal figures of its rows.
pub fn summarise(configs: &[Config], rows: &[FrameRow]) -> Result<Vec<ConfigSummary>> {
    let mut out = Vec::with_capacity(configs.len());
    for (c, config) in configs.iter().enumerate() {
        let mine: Vec<&FrameRow> = rows.iter().filter(|r| r.config == c).collect();
        let n = mine.len().max(1) as f64;
        let mut ms: Vec<f64> = mine.iter().map(|r| r.ms).collect();
        let mut prep: Vec<f64> = mine.iter().map(|r| r.prepare_ms).collect();
        let pairs: Vec<(f64, f64)> = mine
            .iter()
            .filter_map(|r| Some((r.change?, r.truth_change?)))
            .collect();
        let method: Vec<f64> = pairs.iter().map(|p| p.0).collect();
        let truth: Vec<f64> = pairs.iter().map(|p| p.1).collect();
        let Flicker {
            ratio, worst_pop, ..
        } = flicker(&method, &truth)?;
        // The temporal figures count from the flight's second frame.
        let worst_pop = worst_pop.map(|p| Pop {
            frame: mine
                .iter()
                .filter(|r| r.change.is_some())
                .nth(p.frame.saturating_sub(1))
                .map_or(p.frame, |r| r.frame),
            excess: p.excess,
        });
        let worst = mine
            .iter()
            .max_by(|a, b| a.mean_flip.total_cmp(&b.mean_flip))
            .copied();
        out.push(ConfigSummary {
            label: config.label.clone(),
            method: config.method.name().to_string(),
            median_ms: median(&mut ms),
            median_prepare_ms: median(&mut prep),
            speedup_vs_geometry: None,
            mean_flip: mine.iter().map(|r| r.mean_flip).sum::<f64>() / n,
            p95_flip: mine.iter().map(|r| r.p95_flip).sum::<f64>() / n,
            flicker_ratio: ratio,
            worst_pop,
            worst_frame: worst.map_or(0, |r| r.frame),
            worst_frame_flip: worst.map_or(0.0, |r| r.mean_flip),
        });
    }
    set_speedups(&mut out);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> FrameDesc {
        FrameDesc::from_scene(&crate::scene::Scene::default_scene())
    }

    #[test]
    fn sweeps_parse_and_refuse_unknown_knobs_and_bad_values() {
        let s = Sweep::parse("lod_scale=0.5,1, 2").unwrap();
        assert_eq!((s.knob.name, s.values.len()), ("lod_scale", 3));
        assert_eq!(
            Sweep::parse("planes=single,crossed").unwrap().values,
            [KnobValue::Choice("single"), KnobValue::Choice("crossed")]
        );
        assert_eq!(
            Sweep::parse("weight-threshold=0.1").unwrap().knob.name,
            "weight_threshold"
        );
        for bad in [
            "lod_scale",
            "lod_scal=1",
            "lod_scale=",
            "lod_scale=x",
            "lod_scale=-1",
            "vcm=maybe",
            "weight_threshold=2",
            "max_slices=2.5",
        ] {
            let e = Sweep::parse(bad).unwrap_err().to_string();
            assert!(e.contains("--sweep"), "{bad}: {e}");
        }
    }

    #[test]
    fn btf_runs_once_per_combination_and_the_others_once() {
        let sweeps = [
            Sweep::parse("lod_scale=0.5,1,2,4").unwrap(),
            Sweep::parse("weight_threshold=0,0.1,0.2").unwrap(),
        ];
        let methods = [Method::Geometry, Method::Btf, Method::Billboard];
        let c = configurations(&methods, &sweeps, &base()).unwrap();
        assert_eq!(c.len(), 1 + 12 + 1);
        assert_eq!(c[0].label, "geometry");
        assert_eq!(c[13].label, "billboard");
        assert_eq!(c[1].label, "btf lod_scale=0.5 weight_threshold=0");
        assert_eq!(
            (
                c[12].knobs.get("lod_scale"),
                c[12].knobs.get("weight_threshold")
            ),
            (Some(KnobValue::Number(4.0)), Some(KnobValue::Number(0.2)))
        );
        let mut d = base();
        c[12].knobs.apply_to(&mut d);
        assert_eq!((d.btf.lod_scale, d.btf.weight_threshold), (4.0, 0.2));
        let mut labels: Vec<&str> = c.iter().map(|c| c.label.as_str()).collect();
        labels.dedup();
        assert_eq!(labels.len(), 14, "labels are distinct");
        // Without sweeps btf runs once with the frame's knobs.
        let plain = configurations(&[Method::Btf], &[], &base()).unwrap();
        assert_eq!((plain.len(), plain[0].label.as_str()), (1, "btf"));
        assert_eq!(
            plain[0].knobs,
            KnobValues::read(knobs_of(Method::Btf), &base())
        );
        assert!(configurations(&[], &[], &base()).is_err());
    }

    #[test]
    fn a_knob_of_two_methods_is_swept_in_each_and_reaches_the_frame() {
        let sweeps = [
            Sweep::parse("ground_sky=on,off").unwrap(),
            Sweep::parse("vcm=off").unwrap(),
        ];
        assert!(Sweep::parse("ground_sky=maybe").is_err());
        let methods = [Method::Geometry, Method::Btf, Method::Hybrid, Method::Texel];
        let c = configurations(&methods, &sweeps, &base()).unwrap();
        let labels: Vec<&str> = c.iter().map(|c| c.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "geometry",
                "btf ground_sky=on vcm=off",
                "btf ground_sky=off vcm=off",
                "hybrid ground_sky=on vcm=off",
                "hybrid ground_sky=off vcm=off",
                "texel ground_sky=on vcm=off",
                "texel ground_sky=off vcm=off"
            ]
        );
        assert!(c[0].knobs.0.is_empty());
        let on = |i: usize| {
            let mut d = base();
            c[i].knobs.apply_to(&mut d);
            (d.ground_sky, d.btf.vcm, d.texel.vcm)
        };
        assert_eq!(on(1), (true, false, true));
        assert_eq!(on(2), (false, false, true));
        assert_eq!(on(6), (false, true, false), "texel's own vcm");
    }

    fn row(
        frame: usize,
        config: usize,
        ms: f64,
        flip: f64,
        change: Option<(f64, f64)>,
    ) -> FrameRow {
        FrameRow {
            frame,
            config,
            ms,
            prepare_ms: 0.1,
            passes: Default::default(),
            mean_flip: flip,
            p95_flip: 2.0 * flip,
            change: change.map(|c| c.0),
            truth_change: change.map(|c| c.1),
        }
    }

    #[test]
    fn summaries_find_the_speedup_the_worst_frame_and_the_pop() {
        let configs = configurations(&[Method::Geometry, Method::Btf], &[], &base()).unwrap();
        let mut rows = Vec::new();
        for f in 0..5 {
            let change = (f > 0).then_some((0.02, 0.02));
            rows.push(row(f, 0, 100.0, 0.01, change));
            // btf pops at frame 3: it changes 0.2 where the truth changes 0.02.
            let btf_change = change.map(|(_, t)| (if f == 3 { 0.2 } else { t }, t));
            rows.push(row(
                f,
                1,
                4.0 + f as f64,
                if f == 2 { 0.09 } else { 0.05 },
                btf_change,
            ));
        }
        let s = summarise(&configs, &rows).unwrap();
        assert_eq!(s[0].speedup_vs_geometry, Some(1.0));
        assert_eq!(s[1].median_ms, 6.0);
        assert!((s[1].speedup_vs_geometry.unwrap() - 100.0 / 6.0).abs() < 1e-9);
        assert!((s[0].flicker_ratio - 1.0).abs() < 1e-9);
        assert!(s[1].flicker_ratio > 2.0);
        let pop = s[1].worst_pop.unwrap();
        assert_eq!(pop.frame, 3);
        assert!((pop.excess - 0.18).abs() < 1e-9);
        assert_eq!((s[1].worst_frame, s[1].worst_frame_flip), (2, 0.09));
        assert!((s[1].mean_flip - 0.058).abs() < 1e-9);
        assert!((s[1].p95_flip - 0.116).abs() < 1e-9);
    }
}
