//! The `btf` method's far trees on the GPU (over 800 lines: the buffers, their growth and
//! the bind groups all follow one layout of `shaders/btf_far.wgsl`, kept in one place).
//! Most trees of a large forest are far enough to be one tree-level billboard each, and preparing
//! those on the CPU (level choice, view and light blends, VCM factors, the sort back to
//! front) costs tens of milliseconds per 100,000 trees. Here the CPU only finds the near
//! trees, through a grid over the forest: those within the distance where a tree may not
//! yet be at the tree level alone ([`BtfScene::near_radius`], [`BtfScene::is_near`]). It
//! prepares them itself (unsorted) and uploads their records after one slot per tree, and
//! one bit per tree marking them. Compute passes (`shaders/btf_far.wgsl`) take every other
//! tree: cull it as the CPU would and build its record as the CPU would; then sort all the
//! records, far and near, back to front (bitonic, on (depth, slot) keys, so the order is
//! the same every run) and gather them for one indirect draw. The keys are packed as the
//! records are made, and the sort runs over the next power of two above their count, its
//! dispatches sized on the GPU (`sort_plan`), not over a key for every slot. The per-tree
//! VCM factors are uploaded when the sun moves.
//!
//! With [`BtfSettings::gpu_near`] (the default) the CPU does not make the near trees'
//! records either: it chooses each near tree's levels and cross-fade as before and hands
//! one [`NearDrawGpu`] per level drawn to `near_build`, one thread per billboard, which
//! finds its part (the tree; a main branch or a trunk twig; a main branch's twig), places
//! it, and shades it as `TreeShading` does: the part's 8 cube maps read towards the sun in
//! its own frame (the main branches' and twigs' maps are in the tables, one byte a texel)
//! and its parents' factors at its centre. Its records and keys then go through the same
//! sort.
//! Past the far canopy's band ([`far_canopy`](super::far_canopy)), the build pass lights
//! each tree for the canopy instead (`btf_far_canopy.wgsl`) and makes no billboard for it.
//! How many billboards were made comes back a frame or two later (at once when the frame
//! is measured).
//!
//! Over 800 lines: the GPU state (buffers, bind groups, pipelines) is built in one
//! constructor that sizes every buffer against the GPU's limits, and the near trees' split
//! across two bindings shares its sizes; splitting the constructor from the passes is the
//! next step of the layout work.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use glam::Vec3;

use super::billboard::{BillboardGpu, BillboardMode};
use super::prepare::{BtfScene, NearDrawGpu, PrepareView, SortedBillboards};
use super::settings::{BtfSettings, PlaneMode};
use crate::Result;
use crate::model::Level;
use crate::model::mesh::Aabb;
use crate::render::GpuContext;
use crate::render::timing::{MappedRead, PassSpans};
use crate::render::world_gpu::TreeGpu;
use crate::sphere::{DirectionRows, DirectionSet};

/// The far trees' band widens by this share of its start: trees fade out and the canopy in
/// from `near` to `near · (1 + CANOPY_BAND)`.
pub const CANOPY_BAND: f32 = 0.25;

/// What the build pass needs for the far canopy this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CanopyFrame {
    /// A typical crown's width (m) and the on-screen width (px) below which a tree is
    /// drawn by the canopy.
    pub crown_width: f32,
    pub below_px: f32,
    /// The frame's sun, sky and ground light (colour x intensity).
    pub lights: [Vec3; 3],
}

/// One tree instance as the build pass reads it (`FarTree` in `btf_far.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FarTreeGpu {
    pub model: [[f32; 4]; 4],
    pub tint: [f32; 3],
    pub species: u32,
    pub bounds_min: [f32; 3],
    pub _pad0: f32,
    pub bounds_max: [f32; 3],
    pub _pad1: f32,
}

/// One tree's tree-level VCM factors (`FarShade`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FarShadeGpu {
    pub direct: [[f32; 4]; 2],
    pub sky: [[f32; 4]; 2],
}

/// Where a direction set's tables start in the tables buffer (`DirSet`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct DirSetGpu {
    pub level: u32,
    pub splits: u32,
    pub bary: u32,
    pub triangles: u32,
    pub directions: u32,
    pub count: u32,
    pub _pad0: u32,
    pub _pad1: u32,
}

/// The build pass's uniforms (`FarParams`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FarParamsGpu {
    pub camera: [f32; 3],
    pub count: u32,
    pub forward: [f32; 3],
    pub plane_count: u32,
    pub to_sun: [f32; 3],
    pub weight_threshold: f32,
    pub planes: [[f32; 4]; 6],
    pub overlay: [f32; 3],
    pub mode: u32,
    pub light_gain: f32,
    pub plane_mode: u32,
    pub vcm: u32,
    pub species: u32,
    pub views: DirSetGpu,
    pub lights: DirSetGpu,
    pub sort_n: u32,
    pub near_count: u32,
    pub limit: u32,
    pub vcm_res: u32,
    pub overlay_twig: [f32; 3],
    pub near_draws: u32,
    pub overlay_branch: [f32; 3],
    pub near_slots: u32,
    pub views_twig: DirSetGpu,
    pub views_branch: DirSetGpu,
    pub draws_at: u32,
    pub bits_at: u32,
    pub trees_at: u32,
    pub near_room: u32,
    /// Yaw bins of the light blends the tree level reads (0: none).
    pub light_bins: u32,
    /// The first light-blended image in the BTF atlas.
    pub light_blend_first: u32,
    /// The far canopy's fade band (m; both 0: no canopy).
    pub canopy_near: f32,
    pub canopy_far: f32,
    /// The frame's lights, which the canopy's colours are lit by.
    pub sun_color: [f32; 3],
    /// Where each BTF image's mean starts in the tables (one row an image).
    pub means_at: u32,
    pub sky_ambient: [f32; 3],
    /// Batches the billboards are drawn in, front to back, into the trees' layer (0: one
    /// draw, back to front).
    pub layer_batches: u32,
    pub ground_ambient: [f32; 3],
    /// The word of the draw arguments that counts the keys made ([`SORT_ARGS_AT`]).
    pub sort_args_at: u32,
}

/// One step of the bitonic sort (`SortStep`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SortStepGpu {
    pub k: u32,
    pub j: u32,
    pub _pad: [u32; 2],
}

const WORKGROUP: u32 = 64;

/// Words of one tree's VCM factors (`FarShadeGpu`) in the frame words.
const SHADE_WORDS: usize = std::mem::size_of::<FarShadeGpu>() / 4;

/// Words of the draw-arguments buffer: the indirect draw's 4, the far billboards made, the
/// near ones per level, the image fetches and the fetches saved, the billboards that read
/// the light blends, and 1 unused.
const DRAW_WORDS: u64 = 12;

/// Most batches the billboards are drawn in for the trees' layer; each has its indirect
/// draw's 4 words after [`DRAW_WORDS`].
pub const MAX_LAYER_BATCHES: u32 = 16;

/// The word of the draw arguments, after the batches', that counts the sort's keys as they
/// are made.
const SORT_ARGS_AT: u64 = DRAW_WORDS + 4 * MAX_LAYER_BATCHES as u64;

/// Most steps of the sort: a bitonic network over 2^32 keys.
const MAX_SORT_STEPS: u64 = 32 * 33 / 2;

/// Batches the billboards are drawn in for the trees' layer, with the opaque pixels found
/// between them.
pub const LAYER_BATCHES: u32 = 8;
const _: () = assert!(LAYER_BATCHES >= 1 && LAYER_BATCHES <= MAX_LAYER_BATCHES);

/// A record buffer is given back only above this size.
const SHRINK_MIN_BYTES: u64 = 4 << 20;

/// The frames and the seconds a window of [`ShrinkWindow`] spans, both at least.
const SHRINK_FRAMES: u32 = 8;
const SHRINK_SECONDS: f64 = 5.0;

/// The most slots each record buffer needed over a window of frames (near records in
/// their two bindings, records, sorted): a larger frame's buffers are given back once a
/// whole window needed a quarter of them or less.
struct ShrinkWindow {
    began: std::time::Instant,
    frames: u32,
    peak: [u64; 4],
    /// The window's length, at least (frames, seconds), and the smallest buffer given
    /// back.
    frames_min: u32,
    seconds_min: f64,
    min_bytes: u64,
}

impl ShrinkWindow {
    fn new() -> Self {
        Self {
            began: std::time::Instant::now(),
            frames: 0,
            peak: [0; 4],
            frames_min: SHRINK_FRAMES,
            seconds_min: SHRINK_SECONDS,
            min_bytes: SHRINK_MIN_BYTES,
        }
    }

    /// Adds a frame's needs; at the window's end returns its peaks and begins the next.
    fn observe(&mut self, needs: [u64; 4]) -> Option<[u64; 4]> {
        for (p, n) in self.peak.iter_mut().zip(needs) {
            *p = (*p).max(n);
        }
        self.frames += 1;
        if self.frames < self.frames_min || self.began.elapsed().as_secs_f64() < self.seconds_min {
            return None;
        }
        let peak = self.peak;
        self.began = std::time::Instant::now();
        self.frames = 0;
        self.peak = [0; 4];
        Some(peak)
    }
}

/// The far trees' buffers and compute pipelines.
pub struct FarGpu {
    /// The near trees' billboards expanded by `near_build`, one slot per part: the first
    /// `near_room` slots, then the rest in the second buffer (its own binding).
    near_records: [wgpu::Buffer; 2],
    /// Slots each of `near_records` holds.
    near_slots: [u64; 2],
    /// Near slots the first binding takes (one binding's records).
    near_room: u64,
    /// The most slots the sized buffers needed lately, to give back what a larger frame
    /// left.
    shrink: ShrinkWindow,
    /// The sun the shades were read for (None: not uploaded yet).
    shade_sun: Option<Vec3>,
    tree_count: usize,
    /// Each tree's species.
    species: Vec<u32>,
    grid: Grid,
    /// The largest scale of any tree.
    max_scale: f32,
    tables: wgpu::Buffer,
    /// Each tree's far-canopy colour (`canopy_colours` in `btf_far_canopy.wgsl`).
    canopy_colours: wgpu::Buffer,
    params: wgpu::Buffer,
    base: FarParamsGpu,
    /// The frame's [`FarParamsGpu::layer_batches`].
    batches: u32,
    /// Each tree's VCM factors (`FarShade`, 16 words; uploaded when the sun moves), one bit
    /// per tree (the near ones), then the frame's near draws.
    frame_words: wgpu::Buffer,
    /// Words `frame_words` holds.
    frame_word_slots: u64,
    draw_args: wgpu::Buffer,
    /// Records: one slot per tree, then the near trees' billboards.
    records: wgpu::Buffer,
    record_slots: u64,
    /// Sort keys, a power of two of them.
    keys: wgpu::Buffer,
    key_slots: u32,
    /// The records back to front, at most `limit` of them.
    sorted: wgpu::Buffer,
    sorted_slots: u64,
    /// Most records one storage binding holds.
    limit: u64,
    /// Most workgroups one dispatch may have.
    max_groups: u32,
    /// Sort steps for `key_slots` keys, at `step_stride` bytes: (k, j) with k = 2, 4, ..
    step_stride: u64,
    steps: wgpu::Buffer,
    layouts: [wgpu::BindGroupLayout; 2],
    /// The btf pass's layout and its bindings 1..4.
    draw_layout: wgpu::BindGroupLayout,
    draw_resources: (wgpu::Buffer, wgpu::TextureView, wgpu::Sampler),
    bind_group: wgpu::BindGroup,
    step_bind_group: wgpu::BindGroup,
    /// The sort's dispatch arguments, written by `sort_plan`, and its bind group.
    sort_args: wgpu::Buffer,
    plan_bind_group: wgpu::BindGroup,
    /// The sorted records, bound as the btf pass's billboards.
    draw_bind_group: wgpu::BindGroup,
    build: wgpu::ComputePipeline,
    near_build: wgpu::ComputePipeline,
    near_keys: wgpu::ComputePipeline,
    sort_plan: wgpu::ComputePipeline,
    sort: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    finish: wgpu::ComputePipeline,
    /// The frame's uniforms once its near trees are found, before their records come.
    pending: Option<FarParamsGpu>,
    /// The frame's far-canopy band (m from the eye: trees fade out from the first, the
    /// canopy alone past the second); None without a canopy.
    canopy_band: Option<(f32, f32)>,
    /// The frame's near bits, written with the near draws.
    bits: Vec<u32>,
    /// The frame's key count, records to sort, and slots expanded by `near_build` (set by
    /// [`Self::upload_near`]).
    frame: Option<(u32, u32, u32)>,
    /// The far billboards made, read back from the build pass's counter.
    count: CountReadback,
}

/// The sort steps for `n` keys (a power of two): (k, j) in the order they run.
fn sort_steps(n: u32) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    let mut k = 2;
    while k <= n {
        let mut j = k / 2;
        while j > 0 {
            out.push((k, j));
            j /= 2;
        }
        k *= 2;
    }
    out
}

fn entry(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: b.as_entire_binding(),
    }
}

impl FarGpu {
    /// The buffers for every tree of `trees` (`species[i]` the species of tree `i`,
    /// `bounds[i]` its bounds in the world), the tables of `scene`, and the btf pass's
    /// `layout` with its bindings 1..4 (`draw`), and every BTF image's mean (`means`, for
    /// the far canopy's colours): None when the GPU cannot hold them (the CPU then prepares
    /// every tree).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        ctx: &GpuContext,
        scene: &BtfScene,
        trees: &[TreeGpu],
        species: &[u32],
        bounds: &[Aabb],
        layout: &wgpu::BindGroupLayout,
        draw: (&wgpu::Buffer, &wgpu::TextureView, &wgpu::Sampler),
        means: &[[f32; 4]],
    ) -> Result<Option<Self>> {
        let n = trees.len().min(species.len()).min(bounds.len());
        if n == 0 {
            return Ok(None);
        }
        let limits = ctx.device.limits();
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / record;
        let Some(keys) = u32::try_from(n.max(2))
            .ok()
            .and_then(u32::checked_next_power_of_two)
        else {
            return Ok(None);
        };
        if keys.div_ceil(WORKGROUP) > limits.max_compute_workgroups_per_dimension
            || n as u64 >= limit
            || u64::from(keys) * 8 > limits.max_storage_buffer_binding_size
            || limits.max_storage_buffers_per_shader_stage < 10
        {
            return Ok(None);
        }
        let far_trees: Vec<FarTreeGpu> = trees
            .iter()
            .zip(species)
            .zip(bounds)
            .map(|((t, &sp), b)| FarTreeGpu {
                model: t.model,
                tint: [t.tint[0], t.tint[1], t.tint[2]],
                species: sp,
                bounds_min: b.min.to_array(),
                _pad0: 0.0,
                bounds_max: b.max.to_array(),
                _pad1: 0.0,
            })
            .collect();
        let centres: Vec<Option<Vec3>> = trees
            .iter()
            .zip(species)
            .map(|(t, &sp)| scene.tree_center(sp as usize, t))
            .collect();
        let grid = Grid::new(&centres);
        let max_scale = trees
            .iter()
            .map(|t| Vec3::from_slice(&t.model[0][..3]).length())
            .filter(|s| s.is_finite())
            .fold(0.0f32, f32::max);
        let (mut tables, views, lights, vcm_res) = scene.gpu_tables();
        let views_twig = push_set(&mut tables, &views.twig);
        let views_branch = push_set(&mut tables, &views.branch);
        let views = push_set(&mut tables, &views.tree);
        let lights = push_set(&mut tables, lights);
        // The trees, 7 rows each (`tree_at`): their binding went to the second binding of
        // the near records.
        let trees_at = tables.len() as u32;
        tables.extend_from_slice(bytemuck::cast_slice::<FarTreeGpu, [u32; 4]>(&far_trees));
        // Every BTF image's mean, for the far canopy's colours.
        let means_at = tables.len() as u32;
        tables.extend(means.iter().map(|m| m.map(f32::to_bits)));
        if (tables.len() * 16) as u64 > limits.max_storage_buffer_binding_size {
            log::warn!(
                "the trees' GPU tables ({} bytes, cube maps included) pass one storage binding",
                tables.len() * 16
            );
            return Ok(None);
        }
        let base = FarParamsGpu {
            camera: [0.0; 3],
            count: 0,
            forward: [0.0; 3],
            plane_count: 0,
            to_sun: [0.0, 1.0, 0.0],
            weight_threshold: 0.0,
            planes: [[0.0; 4]; 6],
            overlay: [1.0; 3],
            mode: BillboardMode::Images as u32,
            light_gain: 0.0,
            plane_mode: 1,
            vcm: 0,
            species: 0,
            views,
            lights,
            sort_n: 2,
            near_count: 0,
            limit: limit.min(u64::from(u32::MAX)) as u32,
            vcm_res,
            overlay_twig: [1.0; 3],
            near_draws: 0,
            overlay_branch: [1.0; 3],
            near_slots: 0,
            views_twig,
            views_branch,
            draws_at: (SHADE_WORDS * n + n.div_ceil(32).max(1)) as u32,
            bits_at: (SHADE_WORDS * n) as u32,
            trees_at,
            near_room: limit.min(u64::from(u32::MAX)) as u32,
            light_bins: 0,
            light_blend_first: scene.light_blend_first(0, 0),
            canopy_near: 0.0,
            canopy_far: 0.0,
            sun_color: [0.0; 3],
            means_at,
            sky_ambient: [0.0; 3],
            layer_batches: 0,
            ground_ambient: [0.0; 3],
            sort_args_at: SORT_ARGS_AT as u32,
        };
        let init = |label: &str, contents: &[u8]| {
            wgpu::util::DeviceExt::create_buffer_init(
                &ctx.device,
                &wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage: wgpu::BufferUsages::STORAGE,
                },
            )
        };
        use wgpu::BufferUsages as U;
        let words = u64::from(base.draws_at);
        let bufs = ctx.checked("allocating the far trees' GPU buffers", || {
            (
                init("far tables", bytemuck::cast_slice(&tables)),
                buffer(
                    ctx,
                    "far params",
                    std::mem::size_of::<FarParamsGpu>() as u64,
                    U::STORAGE | U::COPY_DST,
                ),
                buffer(
                    ctx,
                    "far frame words",
                    words * 4,
                    U::STORAGE | U::COPY_DST | U::COPY_SRC,
                ),
                buffer(
                    ctx,
                    "far draw",
                    (SORT_ARGS_AT + 1) * 4,
                    U::STORAGE | U::INDIRECT | U::COPY_DST | U::COPY_SRC,
                ),
                // Zeroed: no tree has a colour before its first frame in the canopy.
                buffer(ctx, "canopy colours", 16 * n as u64, U::STORAGE),
            )
        })?;
        let (tables_buf, params, frame_words, draw_args, canopy_colours) = bufs;
        let storage = |binding: u32, read_only: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let uniform = |binding: u32, dynamic: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: dynamic,
                min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<SortStepGpu>() as u64)
                    .filter(|_| dynamic),
            },
            count: None,
        };
        let layout0 = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btf far"),
                entries: &[
                    storage(0, true),
                    storage(1, false),
                    storage(2, false),
                    storage(3, true),
                    storage(4, true),
                    storage(5, false),
                    storage(6, false),
                    storage(7, false),
                    storage(8, false),
                    storage(9, false),
                ],
            });
        let layout1 = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btf far sort step"),
                entries: &[uniform(0, true)],
            });
        let plan_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btf far sort plan"),
                entries: &[storage(1, false)],
            });
        let pipelines = ctx.checked("building the far trees' compute pipelines", || {
            let module = crate::render::pipelines::wgsl_module(
                &ctx.device,
                "btf_far.wgsl",
                &crate::render::shaders::btf_far(),
            );
            let pl = ctx
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("btf far"),
                    bind_group_layouts: &[Some(&layout0), Some(&layout1)],
                    immediate_size: 0,
                });
            let plan_pl = ctx
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("btf far sort plan"),
                    bind_group_layouts: &[Some(&layout0), Some(&plan_layout)],
                    immediate_size: 0,
                });
            let pipeline = |entry: &str, layout: &wgpu::PipelineLayout| {
                ctx.device
                    .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some(entry),
                        layout: Some(layout),
                        module: &module,
                        entry_point: Some(entry),
                        compilation_options: Default::default(),
                        cache: None,
                    })
            };
            [
                pipeline("build", &pl),
                pipeline("near_build", &pl),
                pipeline("near_keys", &pl),
                pipeline("sort_plan", &plan_pl),
                pipeline("sort_step", &pl),
                pipeline("gather", &pl),
                pipeline("finish", &pl),
            ]
        })?;
        let [
            build,
            near_build,
            near_keys,
            sort_plan,
            sort,
            gather,
            finish,
        ] = pipelines;
        let sort_args = ctx.checked("allocating the sort's dispatches", || {
            buffer(
                ctx,
                "far sort dispatch",
                12 * MAX_SORT_STEPS,
                U::STORAGE | U::INDIRECT,
            )
        })?;
        let plan_bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("btf far sort plan"),
            layout: &plan_layout,
            entries: &[entry(1, &sort_args)],
        });
        let step_stride = u64::from(limits.min_uniform_buffer_offset_alignment)
            .max(std::mem::size_of::<SortStepGpu>() as u64);
        // Placeholders until the first frame sizes them.
        let small = |label| buffer(ctx, label, 16, U::STORAGE);
        let one_record = |label| {
            buffer(
                ctx,
                label,
                std::mem::size_of::<BillboardGpu>() as u64,
                U::STORAGE,
            )
        };
        let (records, keys_buf, sorted, near_first, near_second) = (
            small("far records"),
            small("far keys"),
            small("far sorted"),
            one_record("near records"),
            one_record("near records, second binding"),
        );
        let steps = buffer(ctx, "far sort steps", step_stride, U::UNIFORM);
        let draw_resources = (draw.0.clone(), draw.1.clone(), draw.2.clone());
        let (bind_group, step_bind_group, draw_bind_group) = bind_groups(
            ctx,
            [&layout0, &layout1, layout],
            [&params, &near_second, &tables_buf, &canopy_colours],
            [
                &near_first,
                &frame_words,
                &records,
                &keys_buf,
                &draw_args,
                &sorted,
            ],
            &steps,
            &draw_resources,
        );
        let mut far = Self {
            near_records: [near_first, near_second],
            near_slots: [0; 2],
            near_room: limit,
            shrink: ShrinkWindow::new(),
            shade_sun: None,
            tree_count: n,
            species: species[..n].to_vec(),
            grid,
            max_scale,
            tables: tables_buf,
            canopy_colours,
            params,
            base,
            batches: 0,
            frame_words,
            frame_word_slots: words,
            draw_args,
            records,
            record_slots: 0,
            keys: keys_buf,
            key_slots: 0,
            sorted,
            sorted_slots: 0,
            limit,
            max_groups: limits.max_compute_workgroups_per_dimension,
            step_stride,
            steps,
            layouts: [layout0, layout1],
            draw_layout: layout.clone(),
            draw_resources,
            bind_group,
            step_bind_group,
            sort_args,
            plan_bind_group,
            draw_bind_group,
            build,
            near_build,
            near_keys,
            sort_plan,
            sort,
            gather,
            finish,
            pending: None,
            canopy_band: None,
            bits: Vec::new(),
            frame: None,
            count: CountReadback::new(ctx),
        };
        far.reserve(ctx, 0, 0, 0)?;
        Ok(Some(far))
    }

    /// GPU bytes of the buffers.
    pub fn bytes(&self) -> u64 {
        [
            &self.near_records[0],
            &self.near_records[1],
            &self.tables,
            &self.canopy_colours,
            &self.frame_words,
            &self.records,
            &self.keys,
            &self.sorted,
            &self.steps,
        ]
        .iter()
        .map(|b| b.size())
        .sum()
    }

    /// Grows the buffers for a frame of `near` records made on the CPU (after the trees'
    /// slots), `expanded` slots of `near_build` and `draws` near draws (after the shades
    /// and bits), and the sort's keys and steps to them all, rebinding what changed.
    fn reserve(&mut self, ctx: &GpuContext, near: u64, expanded: u64, draws: u64) -> Result<()> {
        let slots = self.tree_count as u64 + near;
        let total = slots + expanded;
        let keys = u32::try_from(total.max(2))
            .ok()
            .and_then(u32::checked_next_power_of_two)
            .ok_or_else(|| crate::Error::Gpu("too many billboards to sort".into()))?;
        let sorted = total.min(self.limit);
        let words = u64::from(self.base.draws_at) + 4 * draws;
        let [first, second] = self.near_split(expanded);
        use wgpu::BufferUsages as U;
        let needs = [first, second, slots, sorted];
        let shrunk = match self.shrink.observe(needs) {
            Some(peak) => self.shrink_to(ctx, peak)?,
            None => false,
        };
        if !shrunk
            && slots <= self.record_slots
            && first <= self.near_slots[0]
            && second <= self.near_slots[1]
            && keys <= self.key_slots
            && sorted <= self.sorted_slots
            && words <= self.frame_word_slots
        {
            return Ok(());
        }
        let max_words = ctx.device.limits().max_storage_buffer_binding_size / 4;
        if words > self.frame_word_slots {
            let word_slots = (u64::from(self.base.draws_at) + 4 * grow_slots(draws))
                .min(max_words)
                .max(words);
            let bigger = ctx.checked("allocating the near draws' buffer", || {
                buffer(
                    ctx,
                    "far frame words",
                    word_slots * 4,
                    U::STORAGE | U::COPY_DST | U::COPY_SRC,
                )
            })?;
            // The shades and bits already written this frame come along.
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("far frame words"),
                });
            encoder.copy_buffer_to_buffer(
                &self.frame_words,
                0,
                &bigger,
                0,
                self.frame_word_slots * 4,
            );
            ctx.queue.submit([encoder.finish()]);
            self.frame_words = bigger;
            self.frame_word_slots = word_slots;
        }
        for (k, need) in needs.into_iter().enumerate() {
            if need > self.record_buffer_slots(k) {
                self.set_record_buffer(ctx, k, need)?;
            }
        }
        if keys > self.key_slots {
            let steps_list = sort_steps(keys);
            let mut step_bytes =
                vec![0u8; (steps_list.len().max(1) as u64 * self.step_stride) as usize];
            for (i, &(k, j)) in steps_list.iter().enumerate() {
                let at = i * self.step_stride as usize;
                let s = SortStepGpu { k, j, _pad: [0; 2] };
                step_bytes[at..at + std::mem::size_of::<SortStepGpu>()]
                    .copy_from_slice(bytemuck::bytes_of(&s));
            }
            let (keys_buf, steps) = ctx.checked("allocating the sort's keys", || {
                (
                    buffer(
                        ctx,
                        "far keys",
                        u64::from(keys) * 8,
                        U::STORAGE | U::COPY_DST,
                    ),
                    wgpu::util::DeviceExt::create_buffer_init(
                        &ctx.device,
                        &wgpu::util::BufferInitDescriptor {
                            label: Some("far sort steps"),
                            contents: &step_bytes,
                            usage: U::UNIFORM,
                        },
                    ),
                )
            })?;
            self.keys = keys_buf;
            self.steps = steps;
            self.key_slots = keys;
        }
        let (bind_group, step_bind_group, draw_bind_group) = bind_groups(
            ctx,
            [&self.layouts[0], &self.layouts[1], &self.draw_layout],
            [
                &self.params,
                &self.near_records[1],
                &self.tables,
                &self.canopy_colours,
            ],
            [
                &self.near_records[0],
                &self.frame_words,
                &self.records,
                &self.keys,
                &self.draw_args,
                &self.sorted,
            ],
            &self.steps,
            &self.draw_resources,
        );
        self.bind_group = bind_group;
        self.step_bind_group = step_bind_group;
        self.draw_bind_group = draw_bind_group;
        Ok(())
    }

    /// The frame's near trees in view, per species in tree order, for the CPU to prepare;
    /// every other tree is left to the GPU. Uploads the near trees' bits, and the trees'
    /// VCM factors when the sun moved since the last upload (the milliseconds spent on
    /// those are returned too: the sun update's share). With `trees_on` false there are no
    /// trees at all. [`Self::upload_near`] then takes the near trees' records.
    #[allow(clippy::too_many_arguments)]
    pub fn prepare(
        &mut self,
        ctx: &GpuContext,
        scene: &BtfScene,
        trees: &[TreeGpu],
        bounds: &[Aabb],
        view: &PrepareView,
        settings: &BtfSettings,
        trees_on: bool,
        canopy: Option<&CanopyFrame>,
    ) -> (Vec<Vec<u32>>, f64) {
        self.frame = None;
        self.pending = None;
        self.canopy_band = None;
        let mut near = vec![Vec::new(); scene.species_count()];
        let count = self.tree_count as u32;
        if !trees_on || count == 0 {
            return (near, 0.0);
        }
        // The near trees: those in the grid's cells within the near radius, by the exact
        // test; their bits are set whether in view or not (the GPU skips them all).
        let bound = BtfScene::far_bound(settings);
        let radius = scene.near_radius(view.focal_px, bound, self.max_scale);
        // The canopy starts where a typical crown is narrower than its pixel bound on
        // screen, and never among the near trees, which the CPU prepares.
        let band = canopy.and_then(|c| {
            let near = (c.crown_width * view.focal_px / c.below_px).max(radius);
            (near.is_finite() && near > 0.0).then_some((near, near * (1.0 + CANOPY_BAND)))
        });
        self.canopy_band = band;
        let mut bits = vec![0u32; self.tree_count.div_ceil(32).max(1)];
        let cam = view.camera.position;
        self.grid.for_each_near(cam, radius, |t| {
            let i = t as usize;
            let (Some(&sp), Some(data)) = (self.species.get(i), trees.get(i)) else {
                return;
            };
            if scene.is_near(sp as usize, data, view, bound) {
                bits[i / 32] |= 1 << (i % 32);
                if let (Some(list), Some(b)) = (near.get_mut(sp as usize), bounds.get(i))
                    && view.frustum.intersects(b)
                {
                    list.push(t);
                }
            }
        });
        for list in &mut near {
            list.sort_unstable();
        }
        let vcm = scene.vcm().filter(|_| settings.vcm);
        let mut shade_ms = 0.0;
        if let Some(v) = vcm
            && (self.shade_sun.is_none() || self.shade_sun != v.sun())
        {
            let t0 = std::time::Instant::now();
            let shades: Vec<FarShadeGpu> = v
                .tree_factors(self.tree_count)
                .map(|(d, s)| FarShadeGpu {
                    direct: [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]],
                    sky: [[s[0], s[1], s[2], s[3]], [s[4], s[5], s[6], s[7]]],
                })
                .collect();
            ctx.queue
                .write_buffer(&self.frame_words, 0, bytemuck::cast_slice(&shades));
            self.shade_sun = v.sun();
            shade_ms = t0.elapsed().as_secs_f64() * 1e3;
        }
        let mut planes = [[0.0f32; 4]; 6];
        for (p, q) in planes.iter_mut().zip(&view.frustum.planes) {
            *p = q.to_array();
        }
        let (overlay, mode) = settings
            .overlay(Level::Tree)
            .unwrap_or(([1.0; 3], BillboardMode::Images));
        let overlay_of = |l| settings.overlay(l).map_or([1.0; 3], |o| o.0);
        self.pending = Some(FarParamsGpu {
            camera: cam.to_array(),
            count,
            forward: view.camera.forward().to_array(),
            plane_count: view.frustum.planes.len().min(6) as u32,
            to_sun: view.to_sun.to_array(),
            weight_threshold: settings.weight_threshold,
            planes,
            overlay,
            mode: mode as u32,
            overlay_twig: overlay_of(Level::Twig),
            overlay_branch: overlay_of(Level::Branch),
            light_gain: settings.light_gain,
            plane_mode: match settings.planes {
                PlaneMode::Single => 1,
                PlaneMode::Crossed => 3,
            },
            vcm: match vcm {
                None => 0,
                Some(_) if settings.vcm_sky => 1,
                Some(_) => 2,
            },
            light_bins: if settings.light_blend {
                scene.light_bins()
            } else {
                0
            },
            canopy_near: band.map_or(0.0, |b| b.0),
            canopy_far: band.map_or(0.0, |b| b.1),
            sun_color: canopy.map_or([0.0; 3], |c| c.lights[0].to_array()),
            sky_ambient: canopy.map_or([0.0; 3], |c| c.lights[1].to_array()),
            ground_ambient: canopy.map_or([0.0; 3], |c| c.lights[2].to_array()),
            layer_batches: layer_batches(settings, ctx.indirect_first_instance),
            ..self.base
        });
        self.bits = bits;
        (near, shade_ms)
    }

    /// Replaces the record buffers whose slots pass four times what the last window of
    /// frames needed at most (`peak`, in the order of [`ShrinkWindow::observe`]) by ones
    /// sized to that peak; true if any was. Each frame writes them whole before reading,
    /// so nothing is copied.
    fn shrink_to(&mut self, ctx: &GpuContext, peak: [u64; 4]) -> Result<bool> {
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let mut shrunk = false;
        for (k, peak) in peak.into_iter().enumerate() {
            let slots = self.record_buffer_slots(k);
            if slots * record >= self.shrink.min_bytes && slots > 4 * grow_slots(peak) {
                self.set_record_buffer(ctx, k, peak)?;
                shrunk = true;
            }
        }
        if shrunk {
            log::debug!(
                "btf: far trees' record buffers shrunk to {} MB",
                self.bytes() as f64 / 1e6
            );
        }
        Ok(shrunk)
    }

    /// The slots of record buffer `k`: the near records' two bindings, the records, the
    /// sorted ones.
    fn record_buffer_slots(&self, k: usize) -> u64 {
        match k {
            0 | 1 => self.near_slots[k],
            2 => self.record_slots,
            _ => self.sorted_slots,
        }
    }

    /// Makes record buffer `k` (as [`Self::record_buffer_slots`]) anew with room for
    /// `need` slots and half as much again, within one binding's records.
    fn set_record_buffer(&mut self, ctx: &GpuContext, k: usize, need: u64) -> Result<()> {
        use wgpu::BufferUsages as U;
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let room = if k < 2 { self.near_room } else { self.limit };
        let slots = grow_slots(need).min(room.max(need));
        let (what, label, usage) = match k {
            0 | 1 => ("the near trees' records", "near records", U::STORAGE),
            2 => (
                "the billboards' records",
                "far records",
                U::STORAGE | U::COPY_DST,
            ),
            _ => (
                "the sorted billboards",
                "far sorted",
                U::STORAGE | U::COPY_SRC,
            ),
        };
        let made = ctx.checked(&format!("allocating {what}"), || {
            buffer(ctx, label, slots * record, usage)
        })?;
        match k {
            0 | 1 => {
                self.near_records[k] = made;
                self.near_slots[k] = slots;
            }
            2 => {
                self.records = made;
                self.record_slots = slots;
            }
            _ => {
                self.sorted = made;
                self.sorted_slots = slots;
            }
        }
        Ok(())
    }

    /// The slots of `expanded` near billboards each binding takes: the first `near_room`,
    /// the second the rest.
    fn near_split(&self, expanded: u64) -> [u64; 2] {
        [
            expanded.min(self.near_room),
            expanded.saturating_sub(self.near_room),
        ]
    }

    /// Most billboards `near_build` can expand in one frame (two storage bindings'
    /// records).
    pub fn expand_limit(&self) -> u64 {
        2 * self.near_room
    }

    /// Gives the first binding of the near records room for `slots` only (tests: the
    /// second binding then takes the rest without frames of 524,288 slots).
    #[cfg(test)]
    pub(crate) fn set_near_room(&mut self, slots: u64) {
        self.near_room = slots.clamp(1, self.limit);
        self.base.near_room = self.near_room as u32;
    }

    /// Grows the record buffers for `expanded` near slots, and ends the window of frames
    /// that gives them back at every frame, for any size (tests).
    #[cfg(test)]
    pub(crate) fn grow_then_shrink_each_frame(&mut self, ctx: &GpuContext, expanded: u64) {
        self.reserve(ctx, 0, expanded, 0).unwrap();
        self.shrink.frames_min = 1;
        self.shrink.seconds_min = 0.0;
        self.shrink.min_bytes = 0;
        self.shrink.peak = [0; 4];
    }

    /// Takes the near trees' records made on the CPU (in any order: they are sorted with
    /// the far ones) and the near draws for `near_build` to expand into `draw_slots`
    /// billboards, and readies the frame's passes; false (and no frame) when the trees'
    /// slots and the CPU's records do not fit one storage binding, the expanded ones two
    /// ([`Self::expand_limit`]), or [`Self::prepare`] found no trees.
    pub fn upload_near(
        &mut self,
        ctx: &GpuContext,
        near: &SortedBillboards,
        draws: &[NearDrawGpu],
        draw_slots: u64,
    ) -> Result<bool> {
        let Some(mut params) = self.pending.take() else {
            return Ok(false);
        };
        let near_count = near.len() as u64;
        let slots = self.tree_count as u64 + near_count;
        let total = slots + draw_slots;
        // One binding's records each (the trees' and the CPU's, and those expanded), and
        // one dispatch's workgroups over the sort's keys and over the expanded slots.
        let groups = total
            .max(2)
            .next_power_of_two()
            .div_ceil(u64::from(WORKGROUP))
            .max(draw_slots.div_ceil(u64::from(WORKGROUP)));
        let draw_words = u64::from(self.base.draws_at) + 4 * draws.len() as u64;
        if slots > self.limit
            || draw_slots > self.expand_limit()
            || groups > u64::from(self.max_groups)
            || draw_words * 4 > ctx.device.limits().max_storage_buffer_binding_size
        {
            log::debug!(
                "the GPU cannot take this frame's billboards: {slots} slots of trees and CPU \
                 records, {draw_slots} to expand ({} draws), {groups} workgroups; one binding \
                 holds {} records, the expanded ones {}, one dispatch {} workgroups",
                draws.len(),
                self.limit,
                self.expand_limit(),
                self.max_groups
            );
            return Ok(false);
        }
        self.reserve(ctx, near_count, draw_slots, draws.len() as u64)?;
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        if let Some(size) = wgpu::BufferSize::new(near_count * record)
            && let Some(mut view) =
                ctx.queue
                    .write_buffer_with(&self.records, self.tree_count as u64 * record, size)
        {
            near.write_unsorted(view.slice(..));
        }
        ctx.queue.write_buffer(
            &self.frame_words,
            u64::from(self.base.bits_at) * 4,
            bytemuck::cast_slice(&self.bits),
        );
        if !draws.is_empty() {
            ctx.queue.write_buffer(
                &self.frame_words,
                u64::from(self.base.draws_at) * 4,
                bytemuck::cast_slice(draws),
            );
        }
        let keys = total.max(2).next_power_of_two() as u32;
        params.near_count = near_count as u32;
        params.near_draws = draws.len() as u32;
        params.near_slots = draw_slots as u32;
        params.sort_n = keys;
        params.limit = self.sorted_slots.min(self.limit) as u32;
        ctx.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        ctx.queue.write_buffer(
            &self.draw_args,
            0,
            bytemuck::cast_slice(&[6u32, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]),
        );
        ctx.queue
            .write_buffer(&self.draw_args, SORT_ARGS_AT * 4, bytemuck::bytes_of(&0u32));
        self.frame = Some((keys, total as u32, draw_slots as u32));
        self.batches = params.layer_batches;
        Ok(true)
    }

    /// The frame's compute passes (timed through `spans`): `far trees` builds the far
    /// records and keys the near ones; `far sort` sorts them, gathers them and sets the
    /// draw's count. Nothing without a frame.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        let Some((keys, slots, expanded)) = self.frame else {
            return;
        };
        let trees = self.tree_count as u32;
        encoder.clear_buffer(&self.keys, 0, Some(u64::from(keys) * 8));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("btf far trees"),
            timestamp_writes: spans.compute_pass("far trees"),
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_bind_group(1, &self.step_bind_group, &[0]);
        pass.set_pipeline(&self.build);
        pass.dispatch_workgroups(trees.div_ceil(WORKGROUP), 1, 1);
        if expanded > 0 {
            pass.set_pipeline(&self.near_build);
            pass.dispatch_workgroups(expanded.div_ceil(WORKGROUP), 1, 1);
        }
        let made_here = slots - trees - expanded;
        if made_here > 0 {
            pass.set_pipeline(&self.near_keys);
            pass.dispatch_workgroups(made_here.div_ceil(WORKGROUP), 1, 1);
        }
        drop(pass);
        // The keys are packed at the start; the sort runs over the next power of two
        // above their count, its dispatches sized on the GPU.
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("btf far sort"),
            timestamp_writes: spans.compute_pass("far sort"),
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_pipeline(&self.sort_plan);
        pass.set_bind_group(1, &self.plan_bind_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.sort);
        for (i, _) in sort_steps(keys).iter().enumerate() {
            let offset = (i as u64 * self.step_stride) as u32;
            pass.set_bind_group(1, &self.step_bind_group, &[offset]);
            pass.dispatch_workgroups_indirect(&self.sort_args, 12 * i as u64);
        }
        pass.set_bind_group(1, &self.step_bind_group, &[0]);
        pass.set_pipeline(&self.gather);
        pass.dispatch_workgroups(slots.div_ceil(WORKGROUP), 1, 1);
        pass.set_pipeline(&self.finish);
        pass.dispatch_workgroups(1, 1, 1);
        drop(pass);
        self.count.copy(encoder, &self.draw_args);
    }

    /// After the frame's submission: how many billboards were made, by the latest frame
    /// read back (this one's when `wait`, blocking): the far trees', then the near trees'
    /// expanded here per level (twig, main branch, tree), then their image fetches per
    /// pixel summed and the fetches image-weight culling saved; None before any.
    pub fn drawn(&self, ctx: &GpuContext, wait: bool) -> Option<[u32; 8]> {
        self.count.collect(ctx, wait)
    }

    /// Draws every billboard of the frame, sorted (the btf pipeline already set).
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>) -> bool {
        if self.frame.is_none() {
            return false;
        }
        pass.set_bind_group(1, &self.draw_bind_group, &[]);
        pass.draw_indirect(&self.draw_args, 0);
        true
    }

    /// Forgets the frame prepared (the CPU prepares every tree).
    pub fn clear(&mut self) {
        self.frame = None;
        self.pending = None;
        self.canopy_band = None;
    }

    /// The frame's far-canopy band (m from the eye), if it has a canopy.
    pub fn canopy_band(&self) -> Option<(f32, f32)> {
        self.canopy_band
    }

    /// Each tree's far-canopy colour, made by the build pass.
    pub fn canopy_colours(&self) -> &wgpu::Buffer {
        &self.canopy_colours
    }

    /// Whether the frame has GPU work.
    pub fn has_frame(&self) -> bool {
        self.frame.is_some()
    }

    /// Reads the last frame's sorted records back, back to front (for tests; blocking).
    pub fn read_sorted(&self, ctx: &GpuContext) -> Result<Vec<BillboardGpu>> {
        if self.frame.is_none() {
            return Ok(Vec::new());
        }
        let args = read_buffer(ctx, &self.draw_args, 16)?;
        let made = u64::from(u32::from_le_bytes([args[4], args[5], args[6], args[7]]));
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let bytes = read_buffer(ctx, &self.sorted, made * record)?;
        let mut records: Vec<BillboardGpu> = bytemuck::pod_collect_to_vec(&bytes);
        if self.layer_batches() > 0 {
            records.reverse();
        }
        Ok(records)
    }

    /// The batches this frame's billboards are drawn in, front to back, into the trees'
    /// layer (0: one draw, back to front over the frame).
    pub fn layer_batches(&self) -> u32 {
        self.batches
    }

    /// Draws batch `k` of [`Self::layer_batches`] (the btf pipeline for the layer already
    /// set).
    pub fn draw_batch(&self, pass: &mut wgpu::RenderPass<'_>, k: u32) {
        if self.frame.is_none() || k >= self.layer_batches() {
            return;
        }
        pass.set_bind_group(1, &self.draw_bind_group, &[]);
        pass.draw_indirect(&self.draw_args, (DRAW_WORDS + 4 * u64::from(k)) * 4);
    }
}

/// Slots for `n` and half as much again, so that a growing frame does not rebind every
/// time.
fn grow_slots(n: u64) -> u64 {
    (n + n / 2).max(1024)
}

fn buffer(ctx: &GpuContext, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage,
        mapped_at_creation: false,
    })
}

/// The compute bind groups (fixed buffers: params, trees, tables; sized ones: near records,
/// frame words, records, keys, draw arguments, sorted), the sort step's, and the draw's.
fn bind_groups(
    ctx: &GpuContext,
    layouts: [&wgpu::BindGroupLayout; 3],
    fixed: [&wgpu::Buffer; 4],
    sized: [&wgpu::Buffer; 6],
    steps: &wgpu::Buffer,
    draw: &(wgpu::Buffer, wgpu::TextureView, wgpu::Sampler),
) -> (wgpu::BindGroup, wgpu::BindGroup, wgpu::BindGroup) {
    let compute = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf far"),
        layout: layouts[0],
        entries: &[
            entry(0, fixed[0]),
            entry(1, fixed[1]),
            entry(2, sized[0]),
            entry(3, fixed[2]),
            entry(4, sized[1]),
            entry(5, sized[2]),
            entry(6, sized[3]),
            entry(7, sized[4]),
            entry(8, sized[5]),
            entry(9, fixed[3]),
        ],
    });
    let step = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf far sort step"),
        layout: layouts[1],
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: steps,
                offset: 0,
                size: wgpu::BufferSize::new(std::mem::size_of::<SortStepGpu>() as u64),
            }),
        }],
    });
    let billboards = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf far billboards"),
        layout: layouts[2],
        entries: &[
            entry(0, sized[5]),
            entry(1, &draw.0),
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&draw.1),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(&draw.2),
            },
        ],
    });
    (compute, step, billboards)
}

/// Appends a direction set's tables to `tables`; where they start.
fn push_set(tables: &mut Vec<[u32; 4]>, set: &DirectionSet) -> DirSetGpu {
    let DirectionRows {
        splits,
        bary,
        triangles,
        directions,
    } = set.gpu_rows();
    let mut at = |rows: Vec<[u32; 4]>| {
        let start = tables.len() as u32;
        tables.extend(rows);
        start
    };
    DirSetGpu {
        level: set.level(),
        splits: at(splits),
        bary: at(bary),
        triangles: at(triangles),
        directions: at(directions),
        count: set.len() as u32,
        _pad0: 0,
        _pad1: 0,
    }
}

/// The first `size` bytes of `buffer` (which allows copies from it), blocking.
fn read_buffer(ctx: &GpuContext, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>> {
    if size == 0 {
        return Ok(Vec::new());
    }
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("far readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("far readback"),
        });
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
    ctx.queue.submit([encoder.finish()]);
    crate::render::target::map_read(ctx, &staging)
}

/// A uniform grid over the trees' centres in x and z, for finding the near trees without
/// visiting every tree.
struct Grid {
    origin: [f32; 2],
    cell: f32,
    side: [usize; 2],
    /// Trees of cell `c`: `trees[start[c]..start[c + 1]]`, ascending.
    start: Vec<u32>,
    trees: Vec<u32>,
    /// Trees with no finite centre, always visited.
    loose: Vec<u32>,
}

impl Grid {
    /// At most this many cells a side.
    const MAX_SIDE: usize = 256;

    fn new(centres: &[Option<Vec3>]) -> Self {
        let finite = |c: &Option<Vec3>| c.filter(|c| c.is_finite());
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for c in centres.iter().filter_map(finite) {
            lo = [lo[0].min(c.x), lo[1].min(c.z)];
            hi = [hi[0].max(c.x), hi[1].max(c.z)];
        }
        if lo[0] > hi[0] {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        // About 16 m cells, fewer over a wide forest.
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1.0);
        let cell = (extent / Self::MAX_SIDE as f32).max(16.0);
        let side = [
            (((hi[0] - lo[0]) / cell) as usize + 1).min(Self::MAX_SIDE),
            (((hi[1] - lo[1]) / cell) as usize + 1).min(Self::MAX_SIDE),
        ];
        let cell_of = |c: Vec3| {
            let x = (((c.x - lo[0]) / cell) as usize).min(side[0] - 1);
            let z = (((c.z - lo[1]) / cell) as usize).min(side[1] - 1);
            z * side[0] + x
        };
        let mut counts = vec![0u32; side[0] * side[1] + 1];
        let mut loose = Vec::new();
        for (t, c) in centres.iter().enumerate() {
            match finite(c) {
                Some(c) => counts[cell_of(c) + 1] += 1,
                None => loose.push(t as u32),
            }
        }
        for k in 1..counts.len() {
            counts[k] += counts[k - 1];
        }
        let start = counts.clone();
        let mut trees = vec![0u32; centres.len() - loose.len()];
        for (t, c) in centres.iter().enumerate() {
            if let Some(c) = finite(c) {
                let k = cell_of(c);
                trees[counts[k] as usize] = t as u32;
                counts[k] += 1;
            }
        }
        Self {
            origin: lo,
            cell,
            side,
            start,
            trees,
            loose,
        }
    }

    /// Calls `f` with every tree whose cell lies within `radius` of `p` in x and z (and
    /// the loose ones).
    fn for_each_near(&self, p: Vec3, radius: f32, mut f: impl FnMut(u32)) {
        for &t in &self.loose {
            f(t);
        }
        let range = |c: f32, o: f32, n: usize| {
            let a = ((c - radius - o) / self.cell).floor();
            let b = ((c + radius - o) / self.cell).floor();
            if !(a.is_finite() && b.is_finite()) || radius.is_nan() {
                // An infinite radius, or a camera far out: every cell.
                return 0..n;
            }
            let a = a.clamp(0.0, n as f32) as usize;
            let b = (b + 1.0).clamp(0.0, n as f32) as usize;
            a..b
        };
        let xs = range(p.x, self.origin[0], self.side[0]);
        for z in range(p.z, self.origin[1], self.side[1]) {
            for x in xs.clone() {
                let c = z * self.side[0] + x;
                for &t in &self.trees[self.start[c] as usize..self.start[c + 1] as usize] {
                    f(t);
                }
            }
        }
    }
}

/// The build passes' counts of billboards made (far; near per level), copied out after a
/// frame and read when the GPU has done it, without stalling (as the frame timer's
/// timestamps are).
struct CountReadback {
    read: MappedRead,
    /// This frame copied into `read`.
    copied: AtomicBool,
    /// The latest counts read (None before any).
    last: Mutex<Option<[u32; 8]>>,
}

impl CountReadback {
    fn new(ctx: &GpuContext) -> Self {
        Self {
            read: MappedRead::new(ctx, "far count read", 32),
            copied: AtomicBool::new(false),
            last: Mutex::new(None),
        }
    }

    /// Copies the far count of `args` when the last copy has been read.
    fn copy(&self, encoder: &mut wgpu::CommandEncoder, args: &wgpu::Buffer) {
        if self.read.is_free() && !self.copied.swap(true, Ordering::SeqCst) {
            encoder.copy_buffer_to_buffer(args, 16, self.read.buffer(), 0, 32);
        }
    }

    /// Maps a copy just submitted; reads a mapped one; with `wait`, blocks until the
    /// copy is read. The latest count read.
    fn collect(&self, ctx: &GpuContext, wait: bool) -> Option<[u32; 8]> {
        if self.copied.swap(false, Ordering::SeqCst) {
            self.read.map();
        }
        let poll = if wait && self.read.is_pending() {
            wgpu::PollType::wait_indefinitely()
        } else {
            wgpu::PollType::Poll
        };
        let _ = ctx.device.poll(poll);
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = self.read.read(|view| {
            std::array::from_fn(|w| {
                u32::from_le_bytes([
                    view[4 * w],
                    view[4 * w + 1],
                    view[4 * w + 2],
                    view[4 * w + 3],
                ])
            })
        }) {
            *last = Some(n);
        }
        *last
    }
}

/// The batches the billboards are drawn in for the trees' layer: [`LAYER_BATCHES`] front to
/// back; one where the draws cannot start past instance 0 (`first_instance` false: indirect
/// draws without `INDIRECT_FIRST_INSTANCE`); 0 (back to front) without `front_to_back`.
pub fn layer_batches(settings: &BtfSettings, first_instance: bool) -> u32 {
    match (settings.front_to_back, first_instance) {
        (false, _) => 0,
        (true, true) => LAYER_BATCHES,
        (true, false) => 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_visits_every_tree_within_the_radius_once() {
        // Trees over 600 m with a cluster, one with no centre; cameras inside and outside.
        let mut rng = 3u32;
        let mut next = || {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (rng >> 8) as f32 / (1u32 << 24) as f32
        };
        let mut centres: Vec<Option<Vec3>> = (0..2000)
            .map(|_| {
                Some(Vec3::new(
                    next() * 600.0 - 300.0,
                    next() * 40.0,
                    next() * 600.0,
                ))
            })
            .collect();
        centres.extend((0..200).map(|_| Some(Vec3::new(next() * 3.0, 0.0, next() * 3.0))));
        centres.push(None);
        centres.push(Some(Vec3::new(f32::NAN, 0.0, 1.0)));
        let grid = Grid::new(&centres);
        for (cam, radius) in [
            (Vec3::new(0.0, 10.0, 100.0), 35.0),
            (Vec3::new(-290.0, 5.0, 590.0), 80.0),
            (Vec3::new(2000.0, 5.0, 0.0), 150.0),
            (Vec3::new(1.0, 2.0, 1.0), 0.5),
            (Vec3::new(0.0, 0.0, 0.0), f32::INFINITY),
        ] {
            let mut seen = vec![0u32; centres.len()];
            grid.for_each_near(cam, radius, |t| seen[t as usize] += 1);
            for (t, c) in centres.iter().enumerate() {
                assert!(seen[t] <= 1, "tree {t} visited twice");
                let within = match c {
                    Some(c) if c.is_finite() => {
                        (c.x - cam.x).abs() <= radius && (c.z - cam.z).abs() <= radius
                    }
                    _ => true,
                };
                if within {
                    assert_eq!(
                        seen[t], 1,
                        "tree {t} at {c:?} missed from {cam} within {radius}"
                    );
                }
            }
        }
    }

    #[test]
    fn sort_steps_are_those_of_a_bitonic_network() {
        assert_eq!(sort_steps(2), vec![(2, 1)]);
        assert_eq!(sort_steps(8).len(), 6);
        assert_eq!(sort_steps(1 << 17).len(), 17 * 18 / 2);
        assert_eq!(sort_steps(8)[3], (8, 4));
    }
}
