//! `canopy tune`: model no more than a scene needs. Every configuration of a grid over the
//! `btf` knobs is measured along a flight against the cached truth (the bench's runner), and
//! the cheapest one whose mean FLIP and flicker ratio meet the targets is chosen. One grid
//! measured once: a looser target can only pick a configuration as cheap or cheaper.

use super::run::{Config, ConfigSummary};
use crate::render::method::btf::{BtfSettings, PlaneMode};
use crate::render::method::knobs_of;
use crate::render::{FrameDesc, Method};
use crate::{Error, Result};

/// The most a configuration may cost in error and flicker.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TuneTarget {
    /// Mean FLIP against the truth along the flight.
    pub max_error: f64,
    /// Mean frame-to-frame change over the truth's.
    pub max_flicker: f64,
}

/// Default flicker bound of `canopy tune`.
pub const DEFAULT_MAX_FLICKER: f64 = 1.2;

/// The bake settings `tune --bake` tries: views x lights x resolution. (66 views: 66 x 7 =
/// 462 images per image set, nearly 4 times an 18-view bake's time, for every bake tried.)
pub const BAKE_VIEWS: [u32; 2] = [6, 18];
pub const BAKE_LIGHTS: [u32; 2] = [6, 18];
pub const BAKE_RESOLUTIONS: [u32; 2] = [32, 64];
/// With `--bake`, the knob grid per bake: LOD scale x weight threshold (fade 0.2, single
/// planes), so that the whole search stays at 8 x 8 configurations.
pub const BAKE_LOD_SCALES: [f32; 4] = [0.5, 1.0, 2.0, 4.0];
pub const BAKE_WEIGHT_THRESHOLDS: [f32; 2] = [0.0, 0.2];

/// One bake's sampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct BakeChoice {
    pub views: u32,
    pub lights: u32,
    pub resolution: u32,
}

/// Every bake `tune --bake` tries, cheapest first.
pub fn bake_candidates() -> Vec<BakeChoice> {
    let mut out = Vec::new();
    for resolution in BAKE_RESOLUTIONS {
        for lights in BAKE_LIGHTS {
            for views in BAKE_VIEWS {
                out.push(BakeChoice {
                    views,
                    lights,
                    resolution,
                });
            }
        }
    }
    out
}

/// The knob grid tried with each bake of `tune --bake`.
pub fn bake_knob_candidates(base: &FrameDesc) -> Vec<Config> {
    let mut out = Vec::new();
    for weight_threshold in BAKE_WEIGHT_THRESHOLDS {
        for lod_scale in BAKE_LOD_SCALES {
            let mut d = *base;
            d.btf = BtfSettings {
                lod_scale,
                weight_threshold,
                lod_fade: 0.2,
                planes: PlaneMode::Single,
                ..base.btf
            };
            out.push(Config::from_frame(
                tune_label(Method::Btf, &d),
                Method::Btf,
                &d,
            ));
        }
    }
    out
}

/// `text` with `[table]`'s `keys` set (other keys of the table and the rest of the file
/// kept; the table appended when missing).
pub fn with_table_keys(text: &str, table: &str, keys: &[(&str, String)]) -> String {
    let header = format!("[{table}]");
    let lines: Vec<&str> = text.lines().collect();
    let Some(start) = lines.iter().position(|l| l.trim() == header) else {
        let mut out = text.to_string();
        if !out.is_empty() && !out.ends_with('\n') {
            out.push('\n');
        }
        out.push('\n');
        out.push_str(&header);
        out.push('\n');
        for (k, v) in keys {
            out.push_str(&format!("{k} = {v}\n"));
        }
        return out;
    };
    let end = lines[start + 1..]
        .iter()
        .position(|l| l.trim_start().starts_with('['))
        .map_or(lines.len(), |k| start + 1 + k);
    let key_of = |l: &str| l.split('=').next().map(|k| k.trim().to_string());
    let mut out: Vec<String> = Vec::new();
    out.extend(lines[..=start].iter().map(|l| l.to_string()));
    let mut done = vec![false; keys.len()];
    for l in &lines[start + 1..end] {
        match keys
            .iter()
            .position(|(k, _)| key_of(l).as_deref() == Some(*k))
        {
            Some(i) => {
                out.push(format!("{} = {}", keys[i].0, keys[i].1));
                done[i] = true;
            }
            None => out.push(l.to_string()),
        }
    }
    // Missing keys go after the table's last non-blank line.
    let mut at = out.len();
    while at > start + 1 && out[at - 1].trim().is_empty() {
        at -= 1;
    }
    for (i, (k, v)) in keys.iter().enumerate().rev() {
        if !done[i] {
            out.insert(at, format!("{k} = {v}"));
        }
    }
    out.extend(lines[end..].iter().map(|l| l.to_string()));
    let mut s = out.join("\n");
    s.push('\n');
    s
}

impl TuneTarget {
    pub fn new(max_error: f64, max_flicker: f64) -> Result<Self> {
        if !(max_error.is_finite() && max_error > 0.0 && max_error < 1.0) {
            return Err(Error::BadInput(format!(
                "--max-error {max_error}: give a mean FLIP between 0 and 1, e.g. 0.05"
            )));
        }
        if !(max_flicker.is_finite() && max_flicker >= 1.0) {
            return Err(Error::BadInput(format!(
                "--max-flicker {max_flicker}: give a ratio of at least 1 (1 = as steady as the truth)"
            )));
        }
        Ok(Self {
            max_error,
            max_flicker,
        })
    }

    /// Whether a measured configuration meets the target.
    pub fn met_by(&self, s: &ConfigSummary) -> bool {
        s.mean_flip <= self.max_error && s.flicker_ratio <= self.max_flicker
    }
}

/// The methods `tune` searches: those whose knobs offer it values
/// ([`crate::render::knob::Knob::tune`]).
pub fn tuned_methods() -> Vec<Method> {
    Method::ALL
        .iter()
        .copied()
        .filter(|m| knobs_of(*m).iter().any(|k| !k.tune.is_empty()))
        .collect()
}

/// `tune`'s name of a configuration of `method`: the method and each knob it searches, as
/// `frame` has them.
pub fn tune_label(method: Method, frame: &FrameDesc) -> String {
    let mut s = String::from(method.name());
    for k in knobs_of(method).iter().filter(|k| !k.tune.is_empty()) {
        s.push_str(&format!(" {}={}", k.name, k.text(frame)));
    }
    s
}

/// Every configuration of `btf`'s grid ([`candidates_for`]).
pub fn candidates(base: &FrameDesc) -> Vec<Config> {
    candidates_for(Method::Btf, base)
}

/// Every configuration of `method`'s grid: each combination of the values its knobs offer
/// `tune` ([`crate::render::knob::Knob::tune`]; the first knob varies fastest), the other
/// knobs as `base` has them. Empty for a method `tune` does not search.
pub fn candidates_for(method: Method, base: &FrameDesc) -> Vec<Config> {
    let knobs = knobs_of(method);
    if knobs.iter().all(|k| k.tune.is_empty()) {
        return Vec::new();
    }
    let mut frames = vec![*base];
    for k in knobs.iter().rev().filter(|k| !k.tune.is_empty()) {
        frames = frames
            .iter()
            .flat_map(|d| {
                k.tune.iter().filter_map(move |text| {
                    let v = k.parse(text).ok()?;
                    let mut d = *d;
                    k.set(&mut d, v);
                    Some(d)
                })
            })
            .collect();
    }
    frames
        .iter()
        .map(|d| Config::from_frame(tune_label(method, d), method, d))
        .collect()
}

/// The cheapest measured configuration (by median frame time, then mean FLIP) that meets
/// `target`; `None` when none does.
pub fn choose(summaries: &[ConfigSummary], target: &TuneTarget) -> Option<usize> {
    summaries
        .iter()
        .enumerate()
        .filter(|(_, s)| target.met_by(s))
        .min_by(|a, b| {
            a.1.median_ms
                .total_cmp(&b.1.median_ms)
                .then(a.1.mean_flip.total_cmp(&b.1.mean_flip))
        })
        .map(|(i, _)| i)
}

/// The scene file's text with its `[render]` table set to `s` (replacing one that is there,
/// else appended); everything else, comments included, is kept as it was.
pub fn with_render_table(text: &str, s: &BtfSettings) -> String {
    let table = format!(
        "[render]\n# Chosen by `canopy tune`.\nlod_scale = {}\nweight_threshold = {}\nlod_fade = {}\nplanes = \"{}\"\nfar_canopy = {}\ncanopy_px = {}\n",
        s.lod_scale,
        s.weight_threshold,
        s.lod_fade,
        s.planes.name(),
        s.far_canopy,
        s.canopy_px
    );
    let lines: Vec<&str> = text.lines().collect();
    let is_header = |l: &str| l.trim_start().starts_with('[');
    let start = lines.iter().position(|l| l.trim() == "[render]");
    let mut out = String::new();
    match start {
        Some(i) => {
            let end = lines[i + 1..]
                .iter()
                .position(|l| is_header(l))
                .map_or(lines.len(), |k| i + 1 + k);
            for l in &lines[..i] {
                out.push_str(l);
                out.push('\n');
            }
            out.push_str(&table);
            if end < lines.len() {
                out.push('\n');
            }
            for l in &lines[end..] {
                out.push_str(l);
                out.push('\n');
            }
        }
        None => {
            out.push_str(text);
            if !text.ends_with('\n') && !text.is_empty() {
                out.push('\n');
            }
            out.push('\n');
            out.push_str(&table);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary(ms: f64, flip: f64, flicker: f64) -> ConfigSummary {
        ConfigSummary {
            label: format!("{ms} {flip}"),
            method: "btf".into(),
            median_ms: ms,
            median_prepare_ms: 0.0,
            speedup_vs_geometry: None,
            mean_flip: flip,
            p95_flip: flip,
            flicker_ratio: flicker,
            worst_pop: None,
            worst_frame: 0,
            worst_frame_flip: flip,
        }
    }

    #[test]
    fn the_cheapest_configuration_meeting_the_target_is_chosen() {
        let s = [
            summary(10.0, 0.03, 1.0),
            summary(6.0, 0.05, 1.1),
            summary(4.0, 0.08, 1.0),
            summary(3.0, 0.04, 1.5), // cheap and accurate, but flickers
            summary(2.0, 0.20, 1.0),
        ];
        let t = |e: f64| TuneTarget::new(e, DEFAULT_MAX_FLICKER).unwrap();
        assert_eq!(choose(&s, &t(0.05)), Some(1));
        assert_eq!(choose(&s, &t(0.03)), Some(0));
        assert_eq!(choose(&s, &t(0.10)), Some(2));
        assert_eq!(choose(&s, &t(0.01)), None);
        assert_eq!(
            choose(&s, &TuneTarget::new(0.05, 2.0).unwrap()),
            Some(3),
            "a looser flicker bound lets the flickering one in"
        );
        // A looser target never picks a costlier configuration.
        let mut last = f64::INFINITY;
        for e in [0.02, 0.03, 0.04, 0.05, 0.08, 0.1, 0.5] {
            if let Some(i) = choose(&s, &t(e)) {
                assert!(s[i].median_ms <= last, "{e}");
                last = s[i].median_ms;
            }
        }
    }

    #[test]
    fn targets_are_checked() {
        for (e, r) in [
            (0.0, 1.2),
            (1.5, 1.2),
            (f64::NAN, 1.2),
            (0.05, 0.5),
            (0.05, f64::INFINITY),
        ] {
            assert!(TuneTarget::new(e, r).is_err(), "{e} {r}");
        }
    }

    #[test]
    fn the_impostor_grid_is_its_own_knobs_and_other_methods_have_none() {
        let base = FrameDesc::from_scene(&crate::scene::Scene::default_scene());
        let c = candidates_for(Method::Impostor, &base);
        assert_eq!(c.len(), 3 * 2 * 3 * 4);
        assert!(c.iter().all(|c| c.method == Method::Impostor));
        assert_eq!(
            c[1].label,
            "impostor alpha_cutoff=0.5 parallax=off self_shadow=0 geometry_px=0"
        );
        let mut d = base;
        c[c.len() - 1].knobs.apply_to(&mut d);
        assert_eq!((d.impostor.alpha_cutoff, d.impostor.parallax), (0.7, true));
        assert_eq!(
            (d.impostor.self_shadow, d.impostor.geometry_px),
            (64.0, 4.0)
        );
        assert!(candidates_for(Method::Texel, &base).is_empty());
        assert!(candidates_for(Method::Hybrid, &base).is_empty());
        assert_eq!(
            tuned_methods(),
            [Method::Btf, Method::Impostor, Method::Surfel]
        );
    }

    #[test]
    fn the_grid_covers_every_knob_value_once() {
        let base = FrameDesc::from_scene(&crate::scene::Scene::default_scene());
        let c = candidates(&base);
        assert_eq!(c.len(), 5 * 4 * 2 * 2 * 2);
        assert_eq!(
            c[1].label,
            "btf lod_scale=1 weight_threshold=0 lod_fade=0 planes=single far_canopy=off"
        );
        let mut d = base;
        c[c.len() - 1].knobs.apply_to(&mut d);
        assert_eq!(
            (d.btf.lod_scale, d.btf.weight_threshold, d.btf.lod_fade),
            (8.0, 0.3, 0.2)
        );
        assert_eq!(d.btf.planes, PlaneMode::Crossed);
        assert!(d.btf.far_canopy);
        let mut labels: Vec<&str> = c.iter().map(|c| c.label.as_str()).collect();
        labels.sort();
        labels.dedup();
        assert_eq!(labels.len(), c.len());
        assert!(c.iter().all(|c| c.method == Method::Btf));
    }

    #[test]
    fn bake_keys_are_set_and_the_other_keys_kept() {
        let keys = [
            ("views", "6".to_string()),
            ("lights", "18".to_string()),
            ("resolution", "32".to_string()),
        ];
        let text = "[forest]\ncount = 3\n\n[bake]\nviews = 66 # many\nsupersample = 2\n\n[sky]\nintensity = 1.0\n";
        let out = with_table_keys(text, "bake", &keys);
        let t: toml::Table = toml::from_str(&out).unwrap();
        assert_eq!(t["bake"]["views"].as_integer(), Some(6));
        assert_eq!(t["bake"]["lights"].as_integer(), Some(18));
        assert_eq!(t["bake"]["resolution"].as_integer(), Some(32));
        assert_eq!(t["bake"]["supersample"].as_integer(), Some(2));
        assert_eq!(t["sky"]["intensity"].as_float(), Some(1.0));
        assert!(out.starts_with("[forest]\ncount = 3\n"));
        let appended = with_table_keys("[forest]\ncount = 3", "bake", &keys);
        let t: toml::Table = toml::from_str(&appended).unwrap();
        assert_eq!(t["bake"]["lights"].as_integer(), Some(18));
        assert_eq!(bake_candidates().len(), 8);
        let base = FrameDesc::from_scene(&crate::scene::Scene::default_scene());
        assert_eq!(bake_knob_candidates(&base).len(), 8);
    }

    #[test]
    fn the_render_table_is_replaced_or_appended_and_the_rest_kept() {
        let s = BtfSettings {
            lod_scale: 2.0,
            weight_threshold: 0.1,
            ..BtfSettings::default()
        };
        let plain = "# my forest\n[forest]\ncount = 3 # three\n";
        let out = with_render_table(plain, &s);
        assert!(out.starts_with(plain));
        assert!(out.contains("[render]\n# Chosen by `canopy tune`.\nlod_scale = 2\n"));
        let again = with_render_table(&out, &BtfSettings::default());
        assert_eq!(again.matches("[render]").count(), 1);
        assert!(again.contains("lod_scale = 1\n") && again.starts_with(plain));
        // A table in the middle keeps what follows it.
        let middle = "[render]\nlod_scale = 9\n\n[sky]\nintensity = 1.0\n";
        let out = with_render_table(middle, &s);
        assert!(out.contains("lod_scale = 2\n") && !out.contains("lod_scale = 9"));
        assert!(out.ends_with("[sky]\nintensity = 1.0\n"), "{out}");
        let parsed: toml::Table = toml::from_str(&out).unwrap();
        assert_eq!(parsed["render"]["planes"].as_str(), Some("single"));
    }
}
