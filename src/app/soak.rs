//! Scripted viewer runs (`canopy view --script FILE`): the soak test. A script is a small
//! TOML file:
//!
//! ```toml
//! seconds = 120          # how long to run once the bake (and the ground's sky) is on show
//! sample_seconds = 60    # memory sampled this often (and at the start and the end)
//! every_frames = 4       # one action per this many frames, cycling through `actions`
//! report = "soak.csv"    # optional: the samples as CSV
//! actions = ["fly", "sun", "method texel", "resize 900x600", "screenshot", "lod_scale 2"]
//! ```
//!
//! Actions: `fly` (a few metres forward and a turn), `sun` (the sun swept 7 degrees),
//! `method NAME`, `resize WxH`, `screenshot` (written over one file in the temporary
//! folder), and `KNOB VALUE` for any method's knob (`lod_scale 2`, `texel_mode stacks`). Resident memory (from /proc, its floor and peak
//! over each interval), the GPU memory the renderer holds, what wgpu has allocated on the
//! device and the C heap are sampled; at the end the run fails if resident or GPU memory
//! grew by more than [`MAX_GROWTH`] from the first sample after the warm-up (at least one
//! interval, and every action run [`WARM_CYCLES`] times) to the last (see [`growth`]). A
//! slow machine runs past `seconds` until there is a full interval after its warm-up.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::render::Method;
use crate::render::knob::KnobValue;
use crate::render::method::knobs_named;
use crate::{Error, Result};

/// Largest growth allowed between the first sample after the warm-up and the last.
pub const MAX_GROWTH: f64 = 0.05;

/// The warm-up lasts until every action has run this many times (and at least one sample
/// interval): what is built on first use (the stack atlas, the tiles, pipelines, buffers
/// for each size) is built by then, however slow the frames.
pub const WARM_CYCLES: usize = 2;

/// A run goes on past its `seconds` until the growth can be judged, at most this many
/// times as long.
pub const MAX_STRETCH: f64 = 4.0;

/// The growth is measured from the first sample taken at or after this time.
pub fn baseline_after(sample_seconds: f64, warm_at: Option<f64>) -> f64 {
    warm_at.map_or(f64::INFINITY, |w| w.max(sample_seconds))
}

/// When the next sample is due: an interval after the last one (not at the next multiple
/// of the interval, which after one long frame would take a burst of samples, each
/// over a sliver of an interval).
pub fn next_due(samples: &[Sample], sample_seconds: f64) -> f64 {
    samples.last().map_or(0.0, |s| s.seconds + sample_seconds)
}

/// An interval whose resident peak rose by no more than this over the interval before it
/// has settled.
pub const SETTLED: f64 = 0.01;

/// The first sample whose whole interval lies after `after` (the one before it was taken
/// then or later) and whose resident peak has settled ([`SETTLED`]): it holds nothing of
/// the warm-up. Lavapipe's own allocations (the bulk of resident memory: heaptrack puts
/// 666 MB of the soak's peak under one call site on lavapipe's queue thread, millions of
/// small blocks) reach their high-water mark in steps of about 38 MB, at times set by how
/// the frames fall, up to a minute after every action has run twice (the small scene in
/// the debug profile, 2026-11); a leak never settles, and the run then stops at
/// [`MAX_STRETCH`] unjudged, which fails it.
fn baseline(samples: &[Sample], after: f64) -> Option<&Sample> {
    samples
        .windows(2)
        .find(|w| {
            w[0].seconds >= after - 1e-6
                && w[1].resident_peak_bytes as f64
                    <= w[0].resident_peak_bytes as f64 * (1.0 + SETTLED)
        })
        .map(|w| &w[1])
}

/// There is a baseline sample after the warm-up and a later one at least an interval
/// after it.
pub fn judgeable(samples: &[Sample], sample_seconds: f64, warm_at: Option<f64>) -> bool {
    let after = baseline_after(sample_seconds, warm_at);
    let Some(from) = baseline(samples, after) else {
        return false;
    };
    samples
        .last()
        .is_some_and(|l| l.seconds >= from.seconds + sample_seconds - 1e-6)
}

/// A soak script as written.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct ScriptFile {
    seconds: f64,
    #[serde(default = "default_sample")]
    sample_seconds: f64,
    #[serde(default = "default_every")]
    every_frames: u32,
    report: Option<PathBuf>,
    actions: Vec<String>,
}

fn default_sample() -> f64 {
    60.0
}
fn default_every() -> u32 {
    4
}

/// One scripted action.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    Fly,
    Sun,
    Method(Method),
    /// Set every method's knob of this name ([`crate::render::method::knobs_named`]).
    Knob(&'static str, KnobValue),
    Resize(u32, u32),
    Screenshot,
}

impl Action {
    fn parse(s: &str) -> std::result::Result<Action, String> {
        let mut words = s.split_whitespace();
        let head = words.next().unwrap_or("");
        let arg = words.next();
        let need = |what: &str| format!("`{s}`: give {what}");
        let action = match (head, arg) {
            ("fly", None) => Action::Fly,
            ("sun", None) => Action::Sun,
            ("screenshot", None) => Action::Screenshot,
            ("method", Some(m)) => {
                Action::Method(Method::parse(m).ok_or_else(|| need("a method name"))?)
            }
            (name, Some(v)) if !knobs_named(name).is_empty() => {
                let k = knobs_named(name)[0];
                Action::Knob(k.name, k.parse(v).map_err(|e| format!("`{s}`: {e}"))?)
            }
            ("resize", Some(v)) => {
                let (w, h) = v.split_once('x').ok_or_else(|| need("WIDTHxHEIGHT"))?;
                let (w, h) = (w.parse::<u32>(), h.parse::<u32>());
                match (w, h) {
                    (Ok(w), Ok(h)) if (64..=8192).contains(&w) && (64..=8192).contains(&h) => {
                        Action::Resize(w, h)
                    }
                    _ => return Err(need("WIDTHxHEIGHT, each 64..=8192")),
                }
            }
            _ => {
                return Err(format!(
                    "`{s}` is not an action; the actions are fly, sun, method NAME, resize WxH, screenshot, and KNOB VALUE for any knob (e.g. lod_scale 2, texel_mode stacks)"
                ));
            }
        };
        if words.next().is_some() {
            return Err(format!("`{s}`: too many words"));
        }
        Ok(action)
    }
}

/// A checked soak script.
#[derive(Clone, Debug, PartialEq)]
pub struct Script {
    pub seconds: f64,
    pub sample_seconds: f64,
    pub every_frames: u32,
    pub report: Option<PathBuf>,
    pub actions: Vec<Action>,
}

impl Script {
    pub fn parse(text: &str, origin: &str) -> Result<Script> {
        let f: ScriptFile = toml::from_str(text)
            .map_err(|e| Error::BadInput(format!("{origin}: {}", e.message())))?;
        let bad = |what: String| Error::BadInput(format!("{origin}: {what}"));
        if !(f.seconds.is_finite() && f.seconds > 0.0 && f.seconds <= 86_400.0) {
            return Err(bad(format!("seconds = {}: give 0..=86400", f.seconds)));
        }
        if !(f.sample_seconds.is_finite() && f.sample_seconds >= 1.0) {
            return Err(bad(format!(
                "sample_seconds = {}: give at least 1",
                f.sample_seconds
            )));
        }
        if f.every_frames == 0 || f.actions.len() > 1000 {
            return Err(bad(
                "every_frames must be at least 1, and at most 1000 actions".into(),
            ));
        }
        let actions = f
            .actions
            .iter()
            .map(|a| Action::parse(a).map_err(bad))
            .collect::<Result<Vec<_>>>()?;
        Ok(Script {
            seconds: f.seconds,
            sample_seconds: f.sample_seconds,
            every_frames: f.every_frames,
            report: f.report,
            actions,
        })
    }

    pub fn load(path: &Path) -> Result<Script> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }
}

/// One memory sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub seconds: f64,
    /// The floor of resident memory over the interval before the sample (read every
    /// frame): what stays.
    pub resident_bytes: u64,
    /// The peak over the same interval. Either edge of the band alone moves by tens of
    /// megabytes from one interval to the next with no leak (a GPU memory block of
    /// lavapipe's freed or taken, a heap trim landing in the lightest or the heaviest
    /// moment of the action cycle); a leak lifts the whole band.
    pub resident_peak_bytes: u64,
    /// The scene data the renderer holds on the GPU (the bake's images, volumes and atlases,
    /// the meshes).
    pub gpu_bytes: u64,
    /// The peak over the interval of every buffer and texture wgpu has allocated on the
    /// device (its allocator's report; 0 where the backend keeps none): targets, maps and
    /// per-frame buffers too, which `gpu_bytes` does not count.
    pub device_peak_bytes: u64,
    /// The C heap (glibc's `mallinfo2`, every arena; `crate::render::memory::heap_bytes`): bytes
    /// handed out and not freed, mmapped blocks included; 0 where it cannot be read.
    pub heap_used_bytes: u64,
    /// Bytes the heap holds free in its arenas (freed, not given back to the system):
    /// resident growth here with `heap_used_bytes` flat is fragmentation, not a leak.
    pub heap_free_bytes: u64,
}

/// The lowest and highest of a series of readings, taken and reset at each sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Range {
    lo: Option<u64>,
    hi: u64,
}

impl Range {
    pub fn add(&mut self, v: u64) {
        self.lo = Some(self.lo.map_or(v, |l| l.min(v)));
        self.hi = self.hi.max(v);
    }

    /// (floor, peak) since the last take; zeros if nothing was read.
    pub fn take(&mut self) -> (u64, u64) {
        let r = (self.lo.unwrap_or(0), self.hi);
        *self = Range::default();
        r
    }
}

pub use crate::render::memory::resident_bytes;

/// The samples as CSV.
pub fn csv(samples: &[Sample]) -> String {
    let mut out = String::from(
        "seconds,resident_bytes,resident_peak_bytes,gpu_bytes,device_peak_bytes,heap_used_bytes,heap_free_bytes\n",
    );
    for s in samples {
        out.push_str(&format!(
            "{:.1},{},{},{},{},{},{}\n",
            s.seconds,
            s.resident_bytes,
            s.resident_peak_bytes,
            s.gpu_bytes,
            s.device_peak_bytes,
            s.heap_used_bytes,
            s.heap_free_bytes
        ));
    }
    out
}

/// Growth of resident and GPU memory from the baseline (the first sample whose interval
/// starts at `after` or later) to the last, as fractions; `None` without a later sample.
/// Resident memory grows when its whole band does: the lesser of the floor's growth and
/// the peak's (one edge alone moves with no leak, see [`Sample::resident_peak_bytes`]).
/// GPU memory grows when either the scene data or the device's peak allocation does.
pub fn growth(samples: &[Sample], after: f64) -> Option<(f64, f64)> {
    let from = baseline(samples, after)?;
    let to = samples.last()?;
    if std::ptr::eq(from, to) {
        return None;
    }
    let g = |a: u64, b: u64| (b as f64 - a as f64) / (a.max(1) as f64);
    Some((
        g(from.resident_bytes, to.resident_bytes)
            .min(g(from.resident_peak_bytes, to.resident_peak_bytes)),
        g(from.gpu_bytes, to.gpu_bytes).max(g(from.device_peak_bytes, to.device_peak_bytes)),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scripts_parse_and_bad_ones_say_what_is_wrong() {
        let s = Script::parse(
            "seconds = 120\nactions = [\"fly\", \"method texel\", \"resize 900x600\", \"lod_scale 2\"]\n",
            "s.toml",
        )
        .unwrap();
        assert_eq!(s.sample_seconds, 60.0);
        assert_eq!(
            s.actions,
            vec![
                Action::Fly,
                Action::Method(Method::Texel),
                Action::Resize(900, 600),
                Action::Knob("lod_scale", KnobValue::Number(2.0))
            ]
        );
        for (text, want) in [
            ("seconds = 1\nactions = [\"jump\"]", "not an action"),
            ("seconds = 1\nactions = [\"resize 10x10\"]", "WIDTHxHEIGHT"),
            ("seconds = 1\nactions = [\"method photo\"]", "method name"),
            ("seconds = 1\nactions = [\"lod_scale 100\"]", "0.05..=64"),
            (
                "seconds = 1\nactions = [\"texel_mode cubes\"]",
                "slices3d, stacks, polygons",
            ),
            ("seconds = -1\nactions = []", "seconds"),
            ("seconds = 1\nactons = []", "actons"),
        ] {
            let e = Script::parse(text, "s.toml").unwrap_err().to_string();
            assert!(e.contains("s.toml") && e.contains(want), "{text}: {e}");
        }
    }

    #[test]
    fn a_long_frame_does_not_make_a_burst_of_samples() {
        let at = |t: f64| Sample {
            seconds: t,
            resident_bytes: 1,
            resident_peak_bytes: 1,
            gpu_bytes: 1,
            device_peak_bytes: 1,
            heap_used_bytes: 0,
            heap_free_bytes: 0,
        };
        assert_eq!(next_due(&[], 60.0), 0.0);
        // A frame of 150 s ends at 155 s: one sample then, the next a minute later, not
        // again at 180 s.
        let mut samples = vec![at(0.0), at(60.0)];
        let mut t = 0.0;
        for frame in [5.0, 150.0, 1.0, 1.0, 30.0, 40.0] {
            t += frame;
            if t >= 60.0 && t >= next_due(&samples, 60.0) {
                samples.push(at(t));
            }
        }
        let times: Vec<f64> = samples.iter().map(|s| s.seconds).collect();
        assert_eq!(times, vec![0.0, 60.0, 155.0, 227.0]);
    }

    #[test]
    fn a_range_keeps_the_floor_and_the_peak_until_taken() {
        let mut r = Range::default();
        assert_eq!(r.take(), (0, 0));
        for v in [500, 300, 800, 400] {
            r.add(v);
        }
        assert_eq!(r.take(), (300, 800));
        r.add(600);
        assert_eq!(r.take(), (600, 600));
    }

    #[test]
    fn growth_is_measured_from_the_first_settled_interval_to_the_end() {
        let s = |t: f64, floor: u64, peak: u64, g: u64| Sample {
            seconds: t,
            resident_bytes: floor,
            resident_peak_bytes: peak,
            gpu_bytes: g,
            device_peak_bytes: g,
            heap_used_bytes: 0,
            heap_free_bytes: 0,
        };
        // The warm-up (0 to 60 s) does not count, nor the interval that holds its end:
        // the baseline is the first sample whose whole interval follows it, and whose
        // peak did not rise over the interval before.
        let samples = [
            s(0.0, 100, 150, 10),
            s(60.0, 200, 300, 20),
            s(120.0, 210, 300, 20),
        ];
        let after = baseline_after(60.0, Some(30.0));
        assert_eq!(growth(&samples, after), None);
        assert!(!judgeable(&samples, 60.0, Some(30.0)));
        let more = [samples[0], samples[1], samples[2], s(180.0, 231, 330, 20)];
        assert!(judgeable(&more, 60.0, Some(30.0)));
        let (r, g) = growth(&more, after).unwrap();
        assert!((r - 0.1).abs() < 1e-9 && g == 0.0, "{r} {g}");
        // Warm only at 70 s: the 120 s sample's interval holds the warm-up's end, and the
        // 180 s one's peak rose: not settled, so the baseline is the 240 s sample.
        assert_eq!(baseline_after(60.0, Some(70.0)), 70.0);
        assert!(!judgeable(&more, 60.0, Some(70.0)));
        assert!(!judgeable(&more, 60.0, None));
        let mut longer = more.to_vec();
        longer.push(s(240.0, 233, 331, 20));
        assert!(!judgeable(&longer, 60.0, Some(70.0)));
        longer.push(s(300.0, 235, 332, 20));
        assert!(judgeable(&longer, 60.0, Some(70.0)));
        let (r, _) = growth(&longer, baseline_after(60.0, Some(70.0))).unwrap();
        assert!((r - 1.0 / 331.0).abs() < 1e-9, "{r}");
        assert!(resident_bytes() > 0);
        assert!(csv(&samples).starts_with(
            "seconds,resident_bytes,resident_peak_bytes,gpu_bytes,device_peak_bytes,heap_used_bytes,heap_free_bytes\n0.0,100,150,10,10,0,0\n"
        ));
    }

    #[test]
    fn memory_that_never_settles_is_never_judged() {
        // A leak: the peak rises 3 % every interval, however long the run.
        let samples: Vec<Sample> = (0..20)
            .map(|i| Sample {
                seconds: 40.0 * f64::from(i),
                resident_bytes: (700.0 * 1.03f64.powi(i)) as u64,
                resident_peak_bytes: (800.0 * 1.03f64.powi(i)) as u64,
                gpu_bytes: 10,
                device_peak_bytes: 10,
                heap_used_bytes: 0,
                heap_free_bytes: 0,
            })
            .collect();
        assert!(!judgeable(&samples, 40.0, Some(30.0)));
        assert_eq!(growth(&samples, baseline_after(40.0, Some(30.0))), None);
    }

    #[test]
    fn resident_growth_is_the_whole_band_moving_up() {
        let s = |t: f64, floor: u64, peak: u64, device: u64| Sample {
            seconds: t,
            resident_bytes: floor,
            resident_peak_bytes: peak,
            gpu_bytes: 10,
            device_peak_bytes: device,
            heap_used_bytes: 0,
            heap_free_bytes: 0,
        };
        // The warm-up: its samples do not count.
        let after = baseline_after(40.0, Some(20.0));
        let (w0, w1) = (s(0.0, 300, 900, 10), s(40.0, 400, 1000, 90));
        // The floor alone jumps (a trim in the lightest moment of the cycle): no growth.
        let floor_only = [w0, w1, s(80.0, 700, 900, 50), s(120.0, 800, 902, 50)];
        let (r, g) = growth(&floor_only, after).unwrap();
        assert!((r - 2.0 / 900.0).abs() < 1e-9 && g == 0.0, "{r} {g}");
        // The peak alone jumps (a block taken at the heaviest moment): no growth either.
        let peak_only = [w0, w1, s(80.0, 700, 800, 50), s(120.0, 705, 900, 50)];
        assert!((growth(&peak_only, after).unwrap().0 - 5.0 / 700.0).abs() < 1e-9);
        // A leak lifts both edges.
        let leak = [w0, w1, s(80.0, 700, 800, 50), s(120.0, 770, 870, 50)];
        assert!((growth(&leak, after).unwrap().0 - 70.0 / 800.0).abs() < 1e-9);
        // Device allocations that grow are GPU growth though the scene data stays.
        let device = [w0, w1, s(80.0, 700, 800, 50), s(120.0, 700, 800, 60)];
        assert!((growth(&device, after).unwrap().1 - 0.2).abs() < 1e-9);
    }
}
