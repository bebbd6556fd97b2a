//! What `canopy bench` leaves in its output folder: `results.csv` (a row per frame and
//! configuration), `summary.json` (per configuration), `chart.png` (speed against
//! accuracy), `flight.png` (FLIP and frame time along the flight) and `worst-N.png` (each
//! configuration's worst frame: truth, method, FLIP map).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use image::RgbaImage;

use super::chart::{
    ChartPoint, DEFAULT_CHART_SIZE, FlightSeries, flight_chart, speed_accuracy_chart,
};
use super::run::{BenchResults, ConfigSummary};
use crate::render::measure::TimeSource;
use crate::{Error, Result};

/// What the summary says about the run as a whole.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunInfo {
    pub scene: String,
    pub flight: String,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub truth_supersample: u32,
    pub repeats: u32,
    pub device: String,
    pub time_source: TimeSource,
    pub truth_rendered: usize,
    pub truth_cached: usize,
    /// Wall-clock seconds of the whole bench.
    pub seconds: f64,
}

#[derive(serde::Serialize)]
struct ConfigJson<'a> {
    #[serde(flatten)]
    summary: &'a ConfigSummary,
    /// Every knob of the configuration's method, by name.
    knobs: std::collections::BTreeMap<&'static str, crate::render::knob::KnobValue>,
}

#[derive(serde::Serialize)]
struct SummaryJson<'a> {
    #[serde(flatten)]
    run: &'a RunInfo,
    configurations: Vec<ConfigJson<'a>>,
}

/// `summary.json` read back through the types that wrote it: the run, and each
/// configuration's summary (its knobs, written beside it, are not read).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
pub struct Summary {
    #[serde(flatten)]
    pub run: RunInfo,
    pub configurations: Vec<ConfigSummary>,
}

impl Summary {
    /// Parses the text of a `summary.json`, or says what is wrong with it.
    pub fn parse(text: &str) -> std::result::Result<Self, String> {
        serde_json::from_str(text).map_err(|e| e.to_string())
    }
}

/// The summary as `--json` prints it and `summary.json` holds it.
pub fn summary_json(run: &RunInfo, results: &BenchResults) -> String {
    let configurations = results
        .summaries
        .iter()
        .zip(&results.configs)
        .map(|(summary, c)| ConfigJson {
            summary,
            knobs: c.knobs.to_map(),
        })
        .collect();
    serde_json::to_string_pretty(&SummaryJson {
        run,
        configurations,
    })
    .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

/// The rows as CSV (the `csv` crate quotes and escapes each field as it needs): the
/// figures of each frame, then a column per pass any row timed (`pass_<name>_ms`, in the
/// order the passes first ran; empty where a row's method has no such pass).
pub fn results_csv(results: &BenchResults) -> String {
    let mut w = csv::Writer::from_writer(Vec::new());
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    let mut pass_names: Vec<&'static str> = Vec::new();
    for p in results.rows.iter().flat_map(|r| r.passes.iter()) {
        if !pass_names.contains(&p.name) {
            pass_names.push(p.name);
        }
    }
    let mut header: Vec<String> = [
        "frame",
        "configuration",
        "method",
        "ms",
        "prepare_ms",
        "mean_flip",
        "p95_flip",
        "change",
        "truth_change",
        "flicker_excess",
    ]
    .map(String::from)
    .to_vec();
    header.extend(pass_names.iter().map(|n| pass_column(n)));
    // Writing into a Vec cannot fail.
    let _ = w.write_record(&header);
    for r in &results.rows {
        let c = &results.configs[r.config];
        let excess = r.change.zip(r.truth_change).map(|(m, t)| m - t);
        let mut record = vec![
            r.frame.to_string(),
            c.label.clone(),
            c.method.name().to_owned(),
            format!("{:.4}", r.ms),
            format!("{:.4}", r.prepare_ms),
            format!("{:.6}", r.mean_flip),
            format!("{:.6}", r.p95_flip),
            opt(r.change),
            opt(r.truth_change),
            opt(excess),
        ];
        record.extend(pass_names.iter().map(|n| {
            r.passes
                .get(n)
                .map_or(String::new(), |ms| format!("{ms:.4}"))
        }));
        let _ = w.write_record(&record);
    }
    w.into_inner()
        .map(|bytes| String::from_utf8_lossy(&bytes).into_owned())
        .unwrap_or_default()
}

/// The CSV column of the pass `name`: `pass_far_trees_ms` for `far trees`.
pub fn pass_column(name: &str) -> String {
    format!("pass_{}_ms", name.replace(' ', "_"))
}

/// A plain table of the summaries, for the terminal.
pub fn summary_table(results: &BenchResults) -> String {
    let mut s = format!(
        "{:<44} {:>10} {:>9} {:>9} {:>9} {:>8} {:>14}\n",
        "configuration", "median ms", "speed-up", "mean FLIP", "p95 FLIP", "flicker", "worst pop"
    );
    for m in &results.summaries {
        let speedup = m
            .speedup_vs_geometry
            .map_or("-".into(), |x| format!("{x:.2}x"));
        let pop = m
            .worst_pop
            .map_or("-".into(), |p| format!("{:.4} @{}", p.excess, p.frame));
        let _ = writeln!(
            s,
            "{:<44} {:>10.2} {:>9} {:>9.4} {:>9.4} {:>8.2} {:>14}",
            m.label, m.median_ms, speedup, m.mean_flip, m.p95_flip, m.flicker_ratio, pop
        );
    }
    s
}

/// Writes `text` to `path` atomically ([`crate::atomic_file`]).
pub(super) fn write_text(path: &Path, text: &str) -> Result<()> {
    crate::atomic_file::write_atomic(path, |w| w.write_all(text.as_bytes()))
        .map_err(|e| Error::BadInput(format!("cannot write {}: {}", path.display(), e.source)))
}

/// Truth, method and FLIP map side by side.
fn triptych(w: &super::run::WorstFrame) -> RgbaImage {
    let (width, height) = w.truth.dimensions();
    let mut out = RgbaImage::new(width * 3, height);
    image::imageops::replace(&mut out, &w.truth, 0, 0);
    image::imageops::replace(&mut out, &w.method, i64::from(width), 0);
    let map = image::DynamicImage::ImageRgb8(w.flip_map.clone()).to_rgba8();
    image::imageops::replace(&mut out, &map, 2 * i64::from(width), 0);
    out
}

/// Writes every output into `dir` (created if needed); returns the files written.
pub fn write_all(dir: &Path, run: &RunInfo, results: &BenchResults) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| {
        Error::BadInput(format!(
            "cannot create the output folder {}: {e}; pass another with --out",
            dir.display()
        ))
    })?;
    let mut written = Vec::new();
    let csv = dir.join("results.csv");
    write_text(&csv, &results_csv(results))?;
    written.push(csv);
    let json = dir.join("summary.json");
    write_text(&json, &summary_json(run, results))?;
    written.push(json);
    let points: Vec<ChartPoint> = results
        .summaries
        .iter()
        .map(|s| ChartPoint {
            label: s.label.clone(),
            method: s.method.to_string(),
            ms: s.median_ms,
            mean_flip: s.mean_flip,
        })
        .collect();
    let chart = dir.join("chart.png");
    speed_accuracy_chart(&chart, &points, DEFAULT_CHART_SIZE)?;
    written.push(chart);
    let series: Vec<FlightSeries> = results
        .configs
        .iter()
        .enumerate()
        .map(|(c, config)| {
            let mine = results.rows.iter().filter(|r| r.config == c);
            FlightSeries {
                label: config.label.clone(),
                flip: mine.clone().map(|r| r.mean_flip).collect(),
                ms: mine.map(|r| r.ms).collect(),
            }
        })
        .collect();
    let flight = dir.join("flight.png");
    flight_chart(&flight, &series, DEFAULT_CHART_SIZE)?;
    written.push(flight);
    for (c, w) in results.worst.iter().enumerate() {
        if let Some(w) = w {
            let path = dir.join(format!("worst-{c}.png"));
            crate::imageio::save_png(&path, &triptych(w))?;
            written.push(path);
        }
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::run::Config;
    use crate::bench::temporal::Pop;
    use crate::render::Method;

    /// What `summary_json` writes, `Summary::parse` reads back, field for field.
    #[test]
    fn the_summary_reads_back_as_written() {
        let run = RunInfo {
            scene: "tests/data/btf.toml".into(),
            flight: "overview".into(),
            frames: 3,
            width: 96,
            height: 64,
            truth_supersample: 2,
            repeats: 1,
            device: "llvmpipe".into(),
            time_source: TimeSource::CpuWallClock,
            truth_rendered: 3,
            truth_cached: 0,
            seconds: 12.5,
        };
        let summary = |method: Method, pop: Option<Pop>| ConfigSummary {
            label: format!("{} label", method.name()),
            method: method.name().into(),
            median_ms: 8.5,
            median_prepare_ms: 0.25,
            speedup_vs_geometry: pop.is_none().then_some(1.0),
            mean_flip: 0.01,
            p95_flip: 0.05,
            flicker_ratio: 1.1,
            worst_pop: pop,
            worst_frame: 2,
            worst_frame_flip: 0.02,
        };
        let methods = [Method::Geometry, Method::Btf, Method::Texel];
        let summaries: Vec<ConfigSummary> = methods
            .iter()
            .enumerate()
            .map(|(i, &m)| {
                let pop = (i > 0).then_some(Pop {
                    frame: i,
                    excess: 0.5 * i as f64,
                });
                summary(m, pop)
            })
            .collect();
        let results = BenchResults {
            configs: methods
                .iter()
                .map(|&m| Config {
                    label: m.name().into(),
                    method: m,
                    knobs: Default::default(),
                })
                .collect(),
            rows: Vec::new(),
            summaries: summaries.clone(),
            worst: Vec::new(),
            frames: 3,
            time_source: TimeSource::CpuWallClock,
            truth_rendered: 3,
            truth_cached: 0,
        };
        let back = Summary::parse(&summary_json(&run, &results)).unwrap();
        assert_eq!(back.run, run);
        assert_eq!(back.configurations, summaries);
        // A summary without its configurations is refused, and says what is missing.
        let e = Summary::parse("{\"scene\": \"x\"}").unwrap_err();
        assert!(e.contains("missing field"), "{e}");
    }

    /// Every pass any row timed is a column, in the order the passes ran; a row without
    /// that pass leaves it empty.
    #[test]
    fn results_csv_has_a_column_per_pass() {
        use crate::bench::run::FrameRow;
        use crate::render::timing::PassTimes;
        let config = |m: Method| Config {
            label: m.name().into(),
            method: m,
            knobs: Default::default(),
        };
        let row = |config: usize, passes: &[(&'static str, f64)]| {
            let mut p = PassTimes::default();
            for &(n, ms) in passes {
                p.add(n, ms);
            }
            FrameRow {
                frame: 0,
                config,
                ms: 10.0,
                prepare_ms: 1.0,
                passes: p,
                mean_flip: 0.1,
                p95_flip: 0.2,
                change: None,
                truth_change: None,
            }
        };
        let results = BenchResults {
            configs: vec![config(Method::Geometry), config(Method::Btf)],
            rows: vec![
                row(0, &[("sky", 1.0), ("trees", 9.0)]),
                row(1, &[("far trees", 2.0), ("sky", 1.5), ("billboards", 6.5)]),
            ],
            summaries: Vec::new(),
            worst: Vec::new(),
            frames: 1,
            time_source: TimeSource::GpuTimestamps,
            truth_rendered: 0,
            truth_cached: 0,
        };
        let csv = results_csv(&results);
        let mut r = csv::Reader::from_reader(csv.as_bytes());
        let header: Vec<String> = r.headers().unwrap().iter().map(String::from).collect();
        assert_eq!(
            header[10..],
            [
                "pass_sky_ms",
                "pass_trees_ms",
                "pass_far_trees_ms",
                "pass_billboards_ms"
            ]
        );
        let rows: Vec<Vec<String>> = r
            .records()
            .map(|rec| rec.unwrap().iter().map(String::from).collect())
            .collect();
        assert_eq!(rows[0][10..], ["1.0000", "9.0000", "", ""]);
        assert_eq!(rows[1][10..], ["1.5000", "", "2.0000", "6.5000"]);
    }
}
