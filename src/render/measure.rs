//! Measuring a frame the way `canopy render` reports it: one untimed warm-up frame (it builds
//! the pipelines), then a number of timed frames whose median is the frame time, then, for
//! the methods with sun-dependent state, the cost of a sun move. [`FrameReport`] is what
//! `render --json` prints. The bench draws and times its frames itself (`bench/run.rs`).

use image::RgbaImage;
use serde::{Serialize, Serializer};

use super::knob::{KnobValue, KnobValues};
use super::method::btf::BtfStats;
use super::method::knobs_of;
use super::timing::PassTimes;
use super::{FrameDesc, FrameStats, GpuContext, Renderer};
use crate::Result;

/// Degrees the sun turns for each of the sun-move frames.
pub const SUN_STEP_DEG: f32 = 0.5;

/// How to measure a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeasureOptions {
    /// Timed frames after the warm-up (at least 1); the median is reported.
    pub frames: u32,
    /// Render this many times larger on each side and average down.
    pub supersample: u32,
}

impl Default for MeasureOptions {
    fn default() -> Self {
        Self {
            frames: 5,
            supersample: 1,
        }
    }
}

/// Where a frame time comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub enum TimeSource {
    /// GPU timestamp queries around the frame.
    #[serde(rename = "gpu-timestamps")]
    GpuTimestamps,
    /// The wall clock around the blocking render and read-back (no timestamp queries).
    #[serde(rename = "cpu-wall-clock")]
    CpuWallClock,
}

impl TimeSource {
    pub fn name(self) -> &'static str {
        match self {
            Self::GpuTimestamps => "gpu-timestamps",
            Self::CpuWallClock => "cpu-wall-clock",
        }
    }
}

/// The cost of one sun move on a warm renderer: the sun turned by [`SUN_STEP_DEG`] and let
/// go (full-size ground maps), then by as much again while held (preview-size maps, as
/// while dragged). Times are absent where the frame rebuilt nothing or the adapter has no
/// timestamp queries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct SunUpdate {
    /// CPU side of the move (VCM reads) plus the ground map pass, in ms.
    #[serde(rename = "sun_update_ms")]
    pub ms: Option<f64>,
    /// The same while the sun is held.
    #[serde(rename = "sun_update_drag_ms")]
    pub drag_ms: Option<f64>,
    /// GPU time of the ground map pass, from timestamp queries.
    #[serde(rename = "sun_update_gpu_ms")]
    pub gpu_ms: Option<f64>,
    /// The same while the sun is held.
    #[serde(rename = "sun_update_drag_gpu_ms")]
    pub drag_gpu_ms: Option<f64>,
    /// Side of the ground shadow maps after the move (present when both frames had them).
    pub ground_map_size: Option<u32>,
    /// The same while the sun is held.
    pub ground_map_drag_size: Option<u32>,
    /// GPU time of the `btf` tree level's light blends made again for the moved sun
    /// (the `light blend` pass; absent where they are off or not timed).
    #[serde(rename = "sun_update_light_blend_ms")]
    pub light_blend_ms: Option<f64>,
}

/// One measured frame.
#[derive(Clone, Debug)]
pub struct FrameMeasurement {
    /// The image of the last timed frame (at the asked size, after supersampling).
    pub image: RgbaImage,
    /// The statistics of the last timed frame.
    pub stats: FrameStats,
    /// Median time of the timed frames (ms).
    pub frame_ms: f64,
    pub source: TimeSource,
    /// Frames the median is taken over.
    pub frames_timed: usize,
    /// Median CPU time of the timed frames' preparation (cull, LOD, billboard expansion,
    /// sort, shading factors, uploads), ms.
    pub prepare_ms: f64,
    /// Each pass's median GPU time over the timed frames (empty without timestamps).
    pub passes: PassTimes,
    /// The cost of a sun move, for the methods with sun-dependent state (`btf`).
    pub sun_update: Option<SunUpdate>,
}

/// Measures `frame` at `width` x `height`: see the module's documentation.
pub fn measure_frame(
    renderer: &mut Renderer,
    ctx: &GpuContext,
    frame: &FrameDesc,
    width: u32,
    height: u32,
    opts: &MeasureOptions,
) -> Result<FrameMeasurement> {
    measure_frame_with(renderer, ctx, frame, width, height, opts, &mut || {})
}

/// [`measure_frame`], calling `on_frame` after the warm-up and after each timed frame
/// (`opts.frames + 1` calls, for a progress bar).
pub fn measure_frame_with(
    renderer: &mut Renderer,
    ctx: &GpuContext,
    frame: &FrameDesc,
    width: u32,
    height: u32,
    opts: &MeasureOptions,
    on_frame: &mut dyn FnMut(),
) -> Result<FrameMeasurement> {
    let ss = opts.supersample;
    // The first frame builds pipelines and is not timed; the image comes from the last.
    let (mut image, mut stats) = renderer.render_image(ctx, frame, width, height, ss)?;
    on_frame();
    let mut times = Vec::with_capacity(opts.frames as usize);
    let mut prepare = Vec::with_capacity(opts.frames as usize);
    let mut passes = Vec::with_capacity(opts.frames as usize);
    for _ in 0..opts.frames.max(1) {
        let t0 = std::time::Instant::now();
        let (img, s) = renderer.render_image(ctx, frame, width, height, ss)?;
        let wall = t0.elapsed().as_secs_f64() * 1e3;
        times.push(s.gpu_ms.unwrap_or(wall));
        prepare.push(s.prepare_ms);
        passes.push(s.passes);
        image = img;
        stats = s;
        on_frame();
    }
    // The methods with state that follows the sun (VCM reads, light blends, ground maps).
    let sun_update = if frame.method.follows_sun() {
        Some(measure_sun_update(renderer, ctx, frame, width, height, ss)?)
    } else {
        None
    };
    times.sort_by(f64::total_cmp);
    prepare.sort_by(f64::total_cmp);
    Ok(FrameMeasurement {
        image,
        frame_ms: times[times.len() / 2],
        prepare_ms: prepare[prepare.len() / 2],
        passes: PassTimes::median(&passes),
        source: if stats.gpu_ms.is_some() {
            TimeSource::GpuTimestamps
        } else {
            TimeSource::CpuWallClock
        },
        frames_timed: times.len(),
        stats,
        sun_update,
    })
}

/// Two more frames of `frame` (not kept) with the sun turned: see [`SunUpdate`].
fn measure_sun_update(
    renderer: &mut Renderer,
    ctx: &GpuContext,
    frame: &FrameDesc,
    width: u32,
    height: u32,
    supersample: u32,
) -> Result<SunUpdate> {
    let mut moved = *frame;
    moved.sun.azimuth_deg += SUN_STEP_DEG;
    let (_, full) = renderer.render_image(ctx, &moved, width, height, supersample)?;
    let gpu_ms = renderer
        .last_sun_update_gpu_ms()
        .filter(|_| full.sun_update);
    moved.sun.azimuth_deg += SUN_STEP_DEG;
    moved.sun_held = true;
    let (_, held) = renderer.render_image(ctx, &moved, width, height, supersample)?;
    let drag_gpu_ms = renderer
        .last_sun_update_gpu_ms()
        .filter(|_| held.sun_update);
    let sizes = full.ground_map_size.zip(held.ground_map_size);
    Ok(SunUpdate {
        ms: full.sun_update_ms,
        drag_ms: held.sun_update_ms,
        gpu_ms,
        drag_gpu_ms,
        ground_map_size: sizes.map(|s| s.0),
        ground_map_drag_size: sizes.map(|s| s.1),
        light_blend_ms: full.passes.get("light blend"),
    })
}

/// A measured frame as `render --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub method: &'static str,
    pub width: u32,
    pub height: u32,
    pub supersample: u32,
    pub frame_ms: f64,
    pub frame_ms_source: TimeSource,
    pub frames_timed: usize,
    /// Median CPU preparation time of the timed frames (ms).
    pub prepare_ms: f64,
    /// Each pass's median GPU time (ms) in the order the passes ran: `[{name, ms}]`, empty
    /// without timestamp queries. They add up to `frame_ms` but for the gaps between
    /// passes (the ground maps, rebuilt only when the sun moves, are `sun_update_gpu_ms`).
    pub passes: PassTimes,
    /// The frame's counts (trees, triangles, shadow casters and triangles, draw calls).
    #[serde(flatten, serialize_with = "frame_counts")]
    pub stats: FrameStats,
    pub adapter: String,
    /// Where the image was written, if it was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub out: Option<String>,
    /// Where the memory is after the frame (`render` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory: Option<super::memory::MemoryReport>,
    /// What the `btf` method did (absent for other methods).
    #[serde(flatten)]
    pub btf: Option<BtfReport>,
    /// What the `texel` method did: `texels`, `tiles`, `slices_mean`, `slices_max`,
    /// `texel_bytes`, `texel_mode` (absent for other methods).
    #[serde(flatten)]
    pub texel: Option<crate::render::method::texel::TexelStats>,
    /// What the impostors did (`impostor`, or `hybrid`'s tree level), as an object:
    /// `impostors`, `geometry_trees`, `frames`, `frame_px`, `atlas_bytes` (absent where
    /// none were drawn).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub impostor: Option<crate::render::method::impostor::ImpostorStats>,
    /// What `surfel` did, as an object: `trees`, `blocks`, `surfels` (splatted), `finest`
    /// and `coarsest` (levels drawn), `surfel_bytes`, `surfels_held` (absent for other
    /// methods).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surfel: Option<crate::render::method::surfel::SurfelStats>,
    /// Every knob of the method, by name ([`crate::render::method::knobs_of`]).
    pub knobs: std::collections::BTreeMap<&'static str, KnobValue>,
    /// With the overdraw view on: `fragments_per_pixel` and `reads_per_pixel`.
    #[serde(flatten)]
    pub overdraw: Option<super::overdraw::OverdrawMeans>,
    /// The frame was the reference (`geometry` with sky visibility and whole-scene sun
    /// shadows).
    pub reference: bool,
    /// A reference frame's sun cascades' side (texels; absent for other frames).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sun_map_size: Option<u32>,
    /// A reference frame's per-tree sun maps' side (texels; 0: none, the cascades alone;
    /// absent for other frames).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub self_map_size: Option<u32>,
    /// An image-based method's ground saw the sky visibility (`FrameDesc::ground_sky`).
    pub ground_sky: bool,
    /// The sky visibility of a reference frame or of the ground (absent for other frames).
    #[serde(flatten)]
    pub sky: Option<SkyReport>,
}

/// The reference's sky visibility in a [`FrameReport`].
#[derive(Clone, Debug, Serialize)]
pub struct SkyReport {
    pub sky_directions: u32,
    /// Side of one cell of the sky visibility volume (m).
    pub sky_cell_m: f32,
    /// Bytes of the sky visibility volume on the GPU.
    pub sky_volume_bytes: u64,
}

/// The `btf` part of a [`FrameReport`].
#[derive(Clone, Debug, Serialize)]
pub struct BtfReport {
    /// Billboards and trees per level, fades, image fetches, VCM shading.
    #[serde(flatten, serialize_with = "btf_counts")]
    pub stats: BtfStats,
    /// The sky light was weighted by the cube maps too (VCM shading on and `vcm_sky`).
    pub vcm_sky: bool,
    /// The near trees' billboards were expanded on the GPU (`gpu_near` with `gpu_far`).
    pub gpu_near: bool,
    pub btf_bytes: u64,
    /// GPU bytes of the far trees' buffers (0 without them).
    pub far_bytes: u64,
    /// GPU bytes of the tree level's light blends (0 without them).
    pub light_blend_bytes: u64,
    /// GPU bytes of the far canopy's map and lid (0 before it is first drawn).
    pub canopy_bytes: u64,
    pub vcm_bytes: u64,
    pub vcm_resolution: Option<u32>,
    #[serde(flatten)]
    pub sun_update: SunUpdate,
    /// What the tile compositor did in the last frame (absent where it was off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compositor: Option<CompositorReport>,
}

/// The tile compositor's counts in a [`BtfReport`], per pixel of the frame.
#[derive(Clone, Debug, Serialize)]
pub struct CompositorReport {
    /// Billboard layers shaded a pixel.
    pub layers_per_pixel: f64,
    /// Billboards tested a pixel (their rectangle holds it).
    pub tests_per_pixel: f64,
    /// Share of the pixels that stopped (opaque) before their tile's list ended.
    pub pixels_stopped: f64,
    pub tiles: u32,
}

impl FrameReport {
    /// The report of `m`, a measurement of `frame` with `opts` by `renderer` on `ctx`.
    pub fn new(
        m: &FrameMeasurement,
        frame: &FrameDesc,
        opts: &MeasureOptions,
        renderer: &Renderer,
        ctx: &GpuContext,
    ) -> Self {
        let reference = frame.reference_drawn();
        let btf = m.stats.btf.map(|stats| BtfReport {
            stats,
            vcm_sky: stats.vcm && frame.btf.vcm_sky,
            gpu_near: frame.btf.gpu_far && frame.btf.gpu_near,
            btf_bytes: renderer.btf_bytes(),
            far_bytes: renderer.far_bytes(),
            light_blend_bytes: renderer.light_blend_bytes(),
            canopy_bytes: renderer.canopy_bytes(),
            vcm_bytes: renderer.vcm_bytes(),
            vcm_resolution: renderer.vcm_resolution(),
            sun_update: m.sun_update.unwrap_or_default(),
            compositor: frame
                .btf
                .compositor
                .then(|| renderer.compositor_counters(ctx).ok().flatten())
                .flatten()
                .map(|c| {
                    let pixels = f64::from(m.image.width() * m.image.height()).max(1.0);
                    CompositorReport {
                        layers_per_pixel: f64::from(c.layers) / pixels,
                        tests_per_pixel: f64::from(c.tests) / pixels,
                        pixels_stopped: f64::from(c.pixels_stopped) / pixels,
                        tiles: c.tiles,
                    }
                }),
        });
        Self {
            method: frame.method.name(),
            width: m.image.width(),
            height: m.image.height(),
            supersample: opts.supersample,
            frame_ms: m.frame_ms,
            frame_ms_source: m.source,
            frames_timed: m.frames_timed,
            prepare_ms: m.prepare_ms,
            passes: m.passes,
            stats: m.stats,
            adapter: ctx.adapter_name(),
            out: None,
            memory: None,
            btf,
            texel: m.stats.texel,
            impostor: m.stats.impostor,
            surfel: m.stats.surfel,
            knobs: KnobValues::read(knobs_of(frame.method), frame).to_map(),
            overdraw: m.stats.overdraw,
            reference: reference.is_some(),
            sun_map_size: reference.map(|r| r.sun_map_size.max(frame.shadows.map_size)),
            self_map_size: reference.map(|r| r.self_map_size),
            ground_sky: renderer.ground_sky_applies(frame),
            sky: (reference.is_some() || renderer.ground_sky_applies(frame))
                .then(|| renderer.sky_visibility())
                .flatten()
                .map(|(sky_directions, sky_cell_m, sky_volume_bytes)| SkyReport {
                    sky_directions,
                    sky_cell_m,
                    sky_volume_bytes,
                }),
        }
    }
}

/// The keys of [`FrameStats`] that a report shows.
fn frame_counts<S: Serializer>(s: &FrameStats, ser: S) -> Result<S::Ok, S::Error> {
    #[derive(Serialize)]
    struct Counts {
        trees_drawn: u32,
        triangles: u64,
        shadow_casters: u32,
        shadow_triangles: u64,
        draw_calls: u32,
    }
    Counts {
        trees_drawn: s.trees_drawn,
        triangles: s.triangles,
        shadow_casters: s.shadow_casters,
        shadow_triangles: s.shadow_triangles,
        draw_calls: s.draw_calls,
    }
    .serialize(ser)
}

/// The keys of [`BtfStats`] that a report shows, per-level counts by level name.
fn btf_counts<S: Serializer>(b: &BtfStats, ser: S) -> Result<S::Ok, S::Error> {
    #[derive(Serialize)]
    struct Counts {
        billboards: crate::model::PerLevel<u32>,
        trees_per_level: crate::model::PerLevel<u32>,
        faded_trees: u32,
        geometry_trees: u32,
        images_per_billboard: f64,
        fetches_saved: u64,
        light_blended: u32,
        canopy_tiles: u32,
        canopy_trees: u32,
        gpu_billboards: u32,
        vcm: bool,
    }
    Counts {
        billboards: b.billboards,
        trees_per_level: b.trees_per_level,
        faded_trees: b.faded_trees,
        geometry_trees: b.geometry_trees,
        images_per_billboard: b.images_per_billboard(),
        fetches_saved: b.fetches_saved,
        light_blended: b.light_blended,
        canopy_tiles: b.canopy_tiles,
        canopy_trees: b.canopy_trees,
        gpu_billboards: b.gpu_billboards,
        vcm: b.vcm,
    }
    .serialize(ser)
}
