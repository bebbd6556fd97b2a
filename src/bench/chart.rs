//! The bench's PNG charts, drawn with `plotters` into memory and written atomically: speed
//! against accuracy (frame time on a log axis, mean FLIP, the Pareto front drawn and
//! labelled) and the per-frame view along a flight (FLIP and frame time, one line per
//! configuration). Text uses a font compiled into the binary (egui's Hack: plotters' glyph
//! placement ignores side bearings, which a monospaced face hides), so charts look the same
//! on every machine and need no system fonts.

use std::path::Path;
use std::sync::Once;

use image::RgbaImage;
use plotters::prelude::*;
use plotters::style::FontStyle;

use super::pareto::pareto_front;
use crate::{Error, Result};

/// Chart size when the caller has no preference (pixels).
pub const DEFAULT_CHART_SIZE: (u32, u32) = (1200, 800);
/// Up to this many configurations, every point of the chart is labelled.
const MAX_ALL_LABELLED: usize = 8;

/// Smallest chart side that still leaves room for axes and labels.
pub const MIN_CHART_SIDE: u32 = 200;
/// Largest chart side.
pub const MAX_CHART_SIDE: u32 = 8192;

/// One configuration on the speed/accuracy chart.
#[derive(Clone, Debug, PartialEq)]
pub struct ChartPoint {
    /// The configuration, e.g. `btf lod=1.5`.
    pub label: String,
    /// Its method: points are coloured by it.
    pub method: String,
    /// Mean frame time (ms).
    pub ms: f64,
    /// Mean FLIP against the truth.
    pub mean_flip: f64,
}

/// One configuration along a flight.
#[derive(Clone, Debug, PartialEq)]
pub struct FlightSeries {
    pub label: String,
    /// FLIP against the truth per frame.
    pub flip: Vec<f64>,
    /// Frame time per frame (ms).
    pub ms: Vec<f64>,
}

/// Colour-blind-safe colours (Okabe-Ito), then black.
const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(120, 120, 120),
    RGBColor(0, 0, 0),
];

const FONT: &str = "sans-serif";

/// Registers the embedded font as plotters' `sans-serif` (once per process).
fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The bytes are egui's own font, known to parse; a failure would only cost text.
        let _ = plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            epaint_default_fonts::HACK_REGULAR,
        );
    });
}

fn check_size((w, h): (u32, u32)) -> Result<()> {
    let side = MIN_CHART_SIDE..=MAX_CHART_SIDE;
    if side.contains(&w) && side.contains(&h) {
        Ok(())
    } else {
        Err(Error::BadSize {
            width: w,
            height: h,
            reason: "a chart side must be 200..=8192 pixels",
        })
    }
}

/// Draws with `draw` into an RGB buffer of `size` and writes it to `path` as a PNG,
/// atomically.
fn render(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(
        &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    ) -> std::result::Result<(), String>,
) -> Result<()> {
    check_size(size)?;
    register_font();
    let (w, h) = size;
    let mut rgb = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string()).and_then(|()| {
            draw(&root)?;
            root.present().map_err(|e| e.to_string())
        })
    }
    .map_err(|reason| Error::WriteImage {
        path: path.to_path_buf(),
        reason: format!("drawing the chart failed: {reason}"),
    })?;
    let rgba = RgbaImage::from_fn(w, h, |x, y| {
        let i = 3 * (y as usize * w as usize + x as usize);
        image::Rgba([rgb[i], rgb[i + 1], rgb[i + 2], 255])
    });
    crate::imageio::save_png(path, &rgba)
}

/// Tick values for a log axis over `lo..hi`: 1-2-5 in each decade, or every integer
/// multiple of the decade when that gives fewer than three.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let decades = (lo.log10().floor() as i32)..=(hi.log10().ceil() as i32);
    let ticks = |mults: &[f64]| -> Vec<f64> {
        decades
            .clone()
            .flat_map(|e| mults.iter().map(move |m| m * 10f64.powi(e)))
            .filter(|v| *v >= lo && *v <= hi)
            .collect()
    };
    let coarse = ticks(&[1.0, 2.0, 5.0]);
    if coarse.len() >= 3 {
        coarse
    } else {
        ticks(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    }
}

/// Where a label would be drawn, in pixels (top left corner, size).
#[derive(Clone, Copy, Debug, PartialEq)]
struct LabelBox {
    x: i32,
    y: i32,
    width: i32,
    height: i32,
}

/// How far down (pixels) each label moves so that none overlaps an earlier one: a line at
/// a time, at most 8 lines.
fn stack_labels(boxes: &[LabelBox]) -> Vec<i32> {
    let mut placed: Vec<LabelBox> = Vec::with_capacity(boxes.len());
    let mut shifts = Vec::with_capacity(boxes.len());
    for b in boxes {
        let overlaps = |c: &LabelBox, dy: i32| {
            b.x < c.x + c.width
                && c.x < b.x + b.width
                && b.y + dy < c.y + c.height
                && c.y < b.y + dy + b.height
        };
        let mut dy = 0;
        for _ in 0..8 {
            if !placed.iter().any(|c| overlaps(c, dy)) {
                break;
            }
            dy += b.height + 2;
        }
        placed.push(LabelBox { y: b.y + dy, ..*b });
        shifts.push(dy);
    }
    shifts
}

/// A number as a tick label: no trailing zeros, no exponent for chart-sized values.
fn tick_label(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_owned()
}

/// Frame time (log x) against mean FLIP (y): one point per configuration coloured by its
/// method, a legend of the methods, the Pareto front as a line with its points labelled.
/// Points without a positive, finite time or a finite FLIP are left out (the caption says
/// how many).
pub fn speed_accuracy_chart(path: &Path, points: &[ChartPoint], size: (u32, u32)) -> Result<()> {
    let usable: Vec<&ChartPoint> = points
        .iter()
        .filter(|p| p.ms.is_finite() && p.ms > 0.0 && p.mean_flip.is_finite())
        .collect();
    if usable.is_empty() {
        return Err(Error::BadInput(format!(
            "speed/accuracy chart {}: none of the {} configurations has a positive frame time \
             and a FLIP; measure at least one",
            path.display(),
            points.len()
        )));
    }
    let (x0, x1) = time_range(&usable);
    let ymax = usable.iter().map(|p| p.mean_flip).fold(0.0, f64::max);
    let y1 = if ymax > 0.0 { ymax * 1.15 } else { 0.1 };
    let methods = method_colours(&usable);
    let coords: Vec<(f64, f64)> = usable.iter().map(|p| (p.ms, p.mean_flip)).collect();
    let front = pareto_front(&coords);
    let left_out = points.len() - usable.len();
    let caption = if left_out == 0 {
        "Speed against accuracy".to_owned()
    } else {
        format!("Speed against accuracy ({left_out} configuration(s) without a time left out)")
    };
    let (w, h) = size;
    let text = |px: f64| (FONT, (px * f64::from(h.min(w)) / 800.0).max(10.0));

    render(path, size, |root| {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let mut chart = ChartBuilder::on(root)
            .caption(caption, text(30.0))
            .margin(15)
            .x_label_area_size((f64::from(h) * 0.08) as u32)
            .y_label_area_size((f64::from(w) * 0.08) as u32)
            .build_cartesian_2d(
                (x0..x1).log_scale().with_key_points(log_ticks(x0, x1)),
                0.0..y1,
            )
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc("frame time (ms, log scale)")
            .y_desc("mean FLIP against the truth (lower is better)")
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| format!("{v:.3}"))
            // Light lines fall evenly between ticks, which on a log axis would mislead.
            .x_max_light_lines(0)
            .axis_desc_style(text(20.0))
            .label_style(text(16.0))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        let front_line: Vec<(f64, f64)> = front.iter().map(|&i| coords[i]).collect();
        chart
            .draw_series(LineSeries::new(
                front_line,
                ShapeStyle::from(&RGBColor(60, 60, 60)).stroke_width(2),
            ))
            .map_err(e)?
            .label("Pareto front")
            .legend(|(x, y)| {
                PathElement::new(
                    vec![(x, y), (x + 20, y)],
                    ShapeStyle::from(&RGBColor(60, 60, 60)).stroke_width(2),
                )
            });
        let radius = (f64::from(h.min(w)) / 130.0).max(3.0) as i32;
        draw_points(&mut chart, &usable, &methods, radius)?;
        let labels = PointLabels {
            usable: &usable,
            coords: &coords,
            front: &front,
            x_range: (x0, x1),
            radius,
            label_px: text(15.0).1,
        };
        draw_point_labels(&mut chart, &labels)?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(text(17.0))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        Ok(())
    })
}

/// The frame time axis' ends for `usable`'s points: around their times, at least a factor
/// 4 wide.
fn time_range(usable: &[&ChartPoint]) -> (f64, f64) {
    let (lo, hi) = usable.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| {
        (lo.min(p.ms), hi.max(p.ms))
    });
    // At least a factor 4 wide, so the log axis has ticks to show.
    let mid = (lo * hi).sqrt();
    let half_ratio = (hi / lo).sqrt().max(2.0) * 1.25;
    (mid / half_ratio, mid * half_ratio)
}

/// Draws `usable`'s points of `radius` pixels, one series per method of `methods` in its
/// colour, with its legend entry.
fn draw_points(
    chart: &mut ChartContext<'_, BitMapBackend<'_>, SpeedAxes>,
    usable: &[&ChartPoint],
    methods: &[(&str, RGBColor)],
    radius: i32,
) -> std::result::Result<(), String> {
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    for &(m, c) in methods {
        let pts: Vec<(f64, f64)> = usable
            .iter()
            .filter(|p| p.method == m)
            .map(|p| (p.ms, p.mean_flip))
            .collect();
        chart
            .draw_series(
                pts.into_iter()
                    .map(|xy| Circle::new(xy, radius, ShapeStyle::from(&c).filled())),
            )
            .map_err(e)?
            .label(m.to_string())
            .legend(move |(x, y)| Circle::new((x + 10, y), radius, c.filled()));
    }
    Ok(())
}

/// Each method of `usable` in order of first appearance, with its colour.
fn method_colours<'p>(usable: &[&'p ChartPoint]) -> Vec<(&'p str, RGBColor)> {
    let mut methods: Vec<&str> = Vec::new();
    for p in usable {
        if !methods.contains(&p.method.as_str()) {
            methods.push(&p.method);
        }
    }
    // The render core's methods keep their colour from chart to chart; others follow.
    let known = |m: &str| {
        crate::render::Method::ALL
            .iter()
            .position(|x| x.name() == m)
    };
    let others: Vec<&str> = methods
        .iter()
        .copied()
        .filter(|m| known(m).is_none())
        .collect();
    let colour = |m: &str| {
        let i = known(m).unwrap_or_else(|| {
            crate::render::Method::ALL.len() + others.iter().position(|x| *x == m).unwrap_or(0)
        });
        PALETTE[i % PALETTE.len()]
    };
    methods.iter().map(|&m| (m, colour(m))).collect()
}

/// The speed/accuracy chart's axes: frame time on a log axis with its ticks, mean FLIP.
type SpeedAxes = plotters::coord::cartesian::Cartesian2d<
    plotters::coord::combinators::WithKeyPoints<plotters::coord::combinators::LogCoord<f64>>,
    plotters::coord::types::RangedCoordf64,
>;

/// What the speed/accuracy chart's point labels are placed by.
struct PointLabels<'a> {
    usable: &'a [&'a ChartPoint],
    /// Each usable point's (frame time, mean FLIP).
    coords: &'a [(f64, f64)],
    /// The Pareto front's points (indices into `usable`).
    front: &'a [usize],
    /// The frame time axis' ends.
    x_range: (f64, f64),
    /// A point's radius (pixels).
    radius: i32,
    /// A label's text size (pixels).
    label_px: f64,
}

/// Draws the labels of the speed/accuracy chart's points.
fn draw_point_labels(
    chart: &mut ChartContext<'_, BitMapBackend<'_>, SpeedAxes>,
    labels: &PointLabels<'_>,
) -> std::result::Result<(), String> {
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    let PointLabels {
        usable,
        coords,
        front,
        x_range: (x0, x1),
        radius,
        label_px,
    } = *labels;
    let label_style = TextStyle::from((FONT, label_px)).color(&BLACK);
    // The Pareto front's points are labelled, and every point when there are few (a
    // handful of configurations reads better named than by colour alone).
    let labelled: Vec<usize> = if usable.len() <= MAX_ALL_LABELLED {
        (0..usable.len()).collect()
    } else {
        front.to_vec()
    };
    // Labels of points in the right fifth go to their left, so they stay inside. (The
    // embedded font is monospaced: a character is 0.6 em wide.) Labels that would
    // overlap an earlier one move down a line.
    let boxes: Vec<LabelBox> = labelled
        .iter()
        .map(|&i| {
            let label = &usable[i].label;
            let width = (0.6 * label_px * label.chars().count() as f64) as i32;
            let right = (coords[i].0 / x0).ln() / (x1 / x0).ln() > 0.8;
            let dx = if right {
                -(radius + 3) - width
            } else {
                radius + 3
            };
            let (px, py) = chart.backend_coord(&coords[i]);
            LabelBox {
                x: px + dx,
                y: py - radius - label_px as i32,
                width,
                height: label_px as i32,
            }
        })
        .collect();
    let shifts = stack_labels(&boxes);
    let anchors: Vec<(i32, i32)> = labelled
        .iter()
        .map(|&i| chart.backend_coord(&coords[i]))
        .collect();
    chart
        .draw_series(labelled.iter().zip(&boxes).zip(&shifts).zip(&anchors).map(
            |(((&i, b), &dy), &(px, py))| {
                EmptyElement::at(coords[i])
                    + Text::new(
                        usable[i].label.clone(),
                        (b.x - px, b.y - py + dy),
                        label_style.clone(),
                    )
            },
        ))
        .map_err(e)?;
    Ok(())
}

/// What one panel of the flight chart shows of a series.
type Values = fn(&FlightSeries) -> &Vec<f64>;

/// Two panels along a flight, frame index across: FLIP against the truth per frame (top)
/// and frame time per frame (bottom), one line per configuration with a legend. Values that
/// are not finite are skipped.
pub fn flight_chart(path: &Path, series: &[FlightSeries], size: (u32, u32)) -> Result<()> {
    if series.is_empty() {
        return Err(Error::BadInput(format!(
            "flight chart {}: no configurations to draw",
            path.display()
        )));
    }
    let frames = series
        .iter()
        .map(|s| s.flip.len().max(s.ms.len()))
        .max()
        .unwrap_or(0)
        .max(2);
    let finite_max = |get: Values| {
        series
            .iter()
            .flat_map(|s| get(s).iter().copied())
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max)
    };
    let flip_max = finite_max(|s| &s.flip);
    let positive = || {
        series
            .iter()
            .flat_map(|s| s.ms.iter().copied())
            .filter(|v| v.is_finite() && *v > 0.0)
    };
    let (ms_lo, ms_hi) = positive().fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    // A log axis at least a factor 4 wide (times reach from btf's to geometry's).
    let (ms_lo, ms_hi) = if ms_hi > 0.0 {
        let mid = (ms_lo * ms_hi).sqrt();
        let half = (ms_hi / ms_lo).sqrt().max(2.0) * 1.2;
        (mid / half, mid * half)
    } else {
        (1.0, 10.0)
    };
    let top = |m: f64, room: f64| if m > 0.0 { m * room } else { 1.0 };
    let (w, h) = size;
    let text = |px: f64| (FONT, (px * f64::from(h.min(w)) / 800.0).max(10.0));
    let x_labels = (frames).min(12);
    let colour = |i: usize| -> RGBColor {
        if i < PALETTE.len() {
            PALETTE[i]
        } else {
            // Past the palette: hues spread by the golden ratio.
            let hsl = HSLColor((i as f64 * 0.618_034) % 1.0, 0.65, 0.42);
            let (r, g, b) = hsl.rgb();
            RGBColor(r, g, b)
        }
    };

    render(path, size, |root| {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let root = root.titled("Along the flight", text(28.0)).map_err(e)?;
        let (upper, lower) = root.split_vertically(root.dim_in_pixel().1 / 2);
        let line = |c: RGBColor| ShapeStyle::from(&c).stroke_width(2);
        // Finite values; on the log axis positive ones too.
        let points = |v: &[f64], log: bool| -> Vec<(f64, f64)> {
            v.iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite() && (!log || **v > 0.0))
                .map(|(k, v)| (k as f64, *v))
                .collect()
        };
        let mut chart = ChartBuilder::on(&upper)
            .margin(12)
            .x_label_area_size((f64::from(h) * 0.06) as u32)
            .y_label_area_size((f64::from(w) * 0.08) as u32)
            // Room above the lines for the legend.
            .build_cartesian_2d(0.0..(frames - 1) as f64, 0.0..top(flip_max, 1.35))
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc("FLIP against the truth")
            .x_labels(x_labels)
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| tick_label(*v))
            .axis_desc_style(text(18.0))
            .label_style(text(15.0))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        for (i, s) in series.iter().enumerate() {
            let c = colour(i);
            chart
                .draw_series(LineSeries::new(points(&s.flip, false), line(c)))
                .map_err(e)?
                .label(s.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], line(c)));
        }
        // One legend, over the top panel: the colours are the same below.
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(text(13.0))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        let mut chart = ChartBuilder::on(&lower)
            .margin(12)
            .x_label_area_size((f64::from(h) * 0.06) as u32)
            .y_label_area_size((f64::from(w) * 0.08) as u32)
            .build_cartesian_2d(
                0.0..(frames - 1) as f64,
                (ms_lo..ms_hi)
                    .log_scale()
                    .with_key_points(log_ticks(ms_lo, ms_hi)),
            )
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc("frame time (ms, log scale)")
            .x_labels(x_labels)
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| tick_label(*v))
            .axis_desc_style(text(18.0))
            .label_style(text(15.0))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        for (i, s) in series.iter().enumerate() {
            chart
                .draw_series(LineSeries::new(points(&s.ms, true), line(colour(i))))
                .map_err(e)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {

    #[test]
    fn overlapping_labels_move_down_and_apart_ones_stay() {
        let b = |x, y| LabelBox {
            x,
            y,
            width: 100,
            height: 15,
        };
        // Two labels at nearly the same place (two btf points side by side), one far away.
        let shifts = stack_labels(&[b(10, 50), b(14, 52), b(400, 50), b(12, 48)]);
        assert_eq!(shifts[0], 0);
        assert_eq!(shifts[2], 0);
        assert!(shifts[1] >= 15 - 2, "{shifts:?}");
        // The third near one clears both.
        assert!(shifts[3] > shifts[1], "{shifts:?}");
    }

    use super::*;
    use std::collections::HashSet;
    use std::path::PathBuf;

    fn out(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canopy-chart-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    fn point(label: &str, method: &str, ms: f64, mean_flip: f64) -> ChartPoint {
        ChartPoint {
            label: label.into(),
            method: method.into(),
            ms,
            mean_flip,
        }
    }

    fn sample_points() -> Vec<ChartPoint> {
        vec![
            point("geometry", "geometry", 42.0, 0.0),
            point("btf lod=0.5", "btf", 9.5, 0.06),
            point("btf lod=1", "btf", 6.0, 0.08),
            point("btf lod=2", "btf", 4.1, 0.12),
            point("btf lod=2 crossed", "btf", 5.0, 0.13),
            point("billboard", "billboard", 1.2, 0.31),
            point("texel d=16", "texel", 3.0, 0.2),
            point("texel d=32", "texel", 7.0, 0.15),
        ]
    }

    /// Checks the PNG at `path`: `size`, more than 20 distinct colours (not blank, not
    /// text-less), and the first `series` colours of the palette among them; then removes
    /// its folder.
    fn check_chart(path: &Path, size: (u32, u32), series: usize) {
        let img = image::open(path).unwrap().to_rgb8();
        let colours: HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        assert_eq!(img.dimensions(), size);
        assert!(
            colours.len() > 20,
            "{} colours: blank or text-less",
            colours.len()
        );
        for c in &PALETTE[..series] {
            assert!(colours.contains(&[c.0, c.1, c.2]), "{c:?} missing");
        }
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    #[test]
    fn the_speed_accuracy_chart_is_a_png_of_the_asked_size_with_color() {
        let path = out("speed.png");
        speed_accuracy_chart(&path, &sample_points(), (900, 600)).unwrap();
        // Each method's colour is there.
        check_chart(&path, (900, 600), 4);
    }

    #[test]
    fn the_flight_chart_is_a_png_of_the_asked_size_with_color() {
        let path = out("flight.png");
        let series: Vec<FlightSeries> = (0..3)
            .map(|i| FlightSeries {
                label: format!("config {i}"),
                flip: (0..60)
                    .map(|k| 0.05 * (i + 1) as f64 + 0.02 * (k as f64 * 0.3).sin())
                    .collect(),
                ms: (0..60)
                    .map(|k| 3.0 + i as f64 + (k % 7) as f64 * 0.1)
                    .collect(),
            })
            .collect();
        flight_chart(&path, &series, (800, 700)).unwrap();
        check_chart(&path, (800, 700), 3);
    }

    #[test]
    fn charts_refuse_bad_sizes_and_empty_input() {
        let path = out("bad.png");
        let e = speed_accuracy_chart(&path, &sample_points(), (50, 600)).unwrap_err();
        assert!(e.to_string().contains("50x600"), "{e}");
        let e = speed_accuracy_chart(&path, &[point("x", "btf", f64::NAN, 0.1)], (400, 300))
            .unwrap_err();
        assert!(e.to_string().contains("frame time"), "{e}");
        assert!(flight_chart(&path, &[], (400, 300)).is_err());
        assert!(!path.exists());
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    #[test]
    fn log_ticks_always_give_a_few_ticks() {
        assert_eq!(
            log_ticks(0.5, 60.0),
            vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0]
        );
        let narrow = log_ticks(3.1, 6.9);
        assert_eq!(narrow, vec![4.0, 5.0, 6.0]);
        assert_eq!(tick_label(0.5), "0.5");
        assert_eq!(tick_label(20.0), "20");
    }

    #[test]
    fn the_embedded_font_parses() {
        register_font();
        // Text measured with the registered family has a width: the font is there.
        let style = TextStyle::from((FONT, 20.0));
        let (w, _) = style.font.box_size("frame time").unwrap();
        assert!(w > 50, "{w}");
    }
}
