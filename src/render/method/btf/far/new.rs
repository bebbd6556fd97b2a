//! Building the far trees' GPU state: the checks against the GPU's limits, the tables, the
//! base uniforms, the fixed buffers, the layouts and the compute pipelines.

use glam::Vec3;

use super::super::billboard::{BillboardGpu, BillboardMode};
use super::super::prepare::BtfScene;
use super::buffers::{ShrinkWindow, bind_groups, buffer, entry};
use super::grid::Grid;
use super::readback::CountReadback;
use super::{
    DirSetGpu, FarGpu, FarParamsGpu, FarTreeGpu, MAX_SORT_STEPS, SHADE_WORDS, SORT_ARGS_AT,
    SortStepGpu, WORKGROUP,
};
use crate::Result;
use crate::model::mesh::Aabb;
use crate::render::GpuContext;
use crate::render::world_gpu::TreeGpu;
use crate::sphere::{DirectionRows, DirectionSet};

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
        let Some(limit) = records_per_binding(&limits, n) else {
            return Ok(None);
        };
        let far_trees = far_trees(trees, species, bounds);
        let (grid, max_scale) = grid_and_scale(scene, trees, species);
        let Some(tables) = Tables::new(scene, &far_trees, means, &limits) else {
            return Ok(None);
        };
        let base = tables.base_params(scene, n, limit);
        let words = u64::from(base.draws_at);
        let (tables_buf, params, frame_words, draw_args, canopy_colours) =
            fixed_buffers(ctx, &tables.rows, n, words)?;
        let [layout0, layout1, plan_layout] = compute_layouts(ctx);
        let [
            build,
            near_build,
            near_keys,
            sort_plan,
            sort,
            gather,
            finish,
        ] = pipelines(ctx, [&layout0, &layout1, &plan_layout])?;
        let (sort_args, plan_bind_group) = sort_plan_binding(ctx, &plan_layout)?;
        let step_stride = u64::from(limits.min_uniform_buffer_offset_alignment)
            .max(std::mem::size_of::<SortStepGpu>() as u64);
        let [records, keys_buf, sorted, near_first, near_second] = placeholders(ctx);
        let steps = buffer(
            ctx,
            "far sort steps",
            step_stride,
            wgpu::BufferUsages::UNIFORM,
        );
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
}

/// Most records one storage binding holds, if the GPU can take `n` trees at all: their
/// sort's keys and workgroups, their slots in one binding, and the storage bindings the
/// passes use.
fn records_per_binding(limits: &wgpu::Limits, n: usize) -> Option<u64> {
    let record = std::mem::size_of::<BillboardGpu>() as u64;
    let limit = limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
        / record;
    let keys = u32::try_from(n.max(2))
        .ok()
        .and_then(u32::checked_next_power_of_two)?;
    if keys.div_ceil(WORKGROUP) > limits.max_compute_workgroups_per_dimension
        || n as u64 >= limit
        || u64::from(keys) * 8 > limits.max_storage_buffer_binding_size
        || limits.max_storage_buffers_per_shader_stage < 10
    {
        return None;
    }
    Some(limit)
}

/// Every tree as the build pass reads it.
fn far_trees(trees: &[TreeGpu], species: &[u32], bounds: &[Aabb]) -> Vec<FarTreeGpu> {
    trees
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
        .collect()
}

/// The grid over the trees' centres, and the largest scale of any tree.
fn grid_and_scale(scene: &BtfScene, trees: &[TreeGpu], species: &[u32]) -> (Grid, f32) {
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
    (grid, max_scale)
}

/// The tables buffer's rows (`tables` in `btf_far.wgsl`) and where its parts start.
struct Tables {
    rows: Vec<[u32; 4]>,
    views: DirSetGpu,
    lights: DirSetGpu,
    views_twig: DirSetGpu,
    views_branch: DirSetGpu,
    vcm_res: u32,
    trees_at: u32,
    means_at: u32,
}

impl Tables {
    /// The scene's tables, the direction sets', the trees' and the BTF images' means; None
    /// (with a warning) when they pass one storage binding.
    fn new(
        scene: &BtfScene,
        far_trees: &[FarTreeGpu],
        means: &[[f32; 4]],
        limits: &wgpu::Limits,
    ) -> Option<Self> {
        let (mut tables, views, lights, vcm_res) = scene.gpu_tables();
        let views_twig = push_set(&mut tables, &views.twig);
        let views_branch = push_set(&mut tables, &views.branch);
        let views = push_set(&mut tables, &views.tree);
        let lights = push_set(&mut tables, lights);
        // The trees, 7 rows each (`tree_at`): their binding went to the second binding of
        // the near records.
        let trees_at = tables.len() as u32;
        tables.extend_from_slice(bytemuck::cast_slice::<FarTreeGpu, [u32; 4]>(far_trees));
        // Every BTF image's mean, for the far canopy's colours.
        let means_at = tables.len() as u32;
        tables.extend(means.iter().map(|m| m.map(f32::to_bits)));
        if (tables.len() * 16) as u64 > limits.max_storage_buffer_binding_size {
            log::warn!(
                "the trees' GPU tables ({} bytes, cube maps included) pass one storage binding",
                tables.len() * 16
            );
            return None;
        }
        Some(Self {
            rows: tables,
            views,
            lights,
            views_twig,
            views_branch,
            vcm_res,
            trees_at,
            means_at,
        })
    }

    /// The uniforms every frame starts from, for `n` trees and `limit` records a binding.
    fn base_params(&self, scene: &BtfScene, n: usize, limit: u64) -> FarParamsGpu {
        FarParamsGpu {
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
            views: self.views,
            lights: self.lights,
            sort_n: 2,
            near_count: 0,
            limit: limit.min(u64::from(u32::MAX)) as u32,
            vcm_res: self.vcm_res,
            overlay_twig: [1.0; 3],
            near_draws: 0,
            overlay_branch: [1.0; 3],
            near_slots: 0,
            views_twig: self.views_twig,
            views_branch: self.views_branch,
            draws_at: (SHADE_WORDS * n + n.div_ceil(32).max(1)) as u32,
            bits_at: (SHADE_WORDS * n) as u32,
            trees_at: self.trees_at,
            near_room: limit.min(u64::from(u32::MAX)) as u32,
            light_bins: 0,
            light_blend_first: scene.light_blend_first(0, 0),
            canopy_near: 0.0,
            canopy_far: 0.0,
            sun_color: [0.0; 3],
            means_at: self.means_at,
            sky_ambient: [0.0; 3],
            layer_batches: 0,
            ground_ambient: [0.0; 3],
            sort_args_at: SORT_ARGS_AT as u32,
        }
    }
}

/// The buffers of fixed size: the tables (`rows`), the uniforms, the frame words (`words`
/// of them), the draw arguments and the `n` trees' canopy colours.
fn fixed_buffers(
    ctx: &GpuContext,
    rows: &[[u32; 4]],
    n: usize,
    words: u64,
) -> Result<(
    wgpu::Buffer,
    wgpu::Buffer,
    wgpu::Buffer,
    wgpu::Buffer,
    wgpu::Buffer,
)> {
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
    ctx.checked("allocating the far trees' GPU buffers", || {
        (
            init("far tables", bytemuck::cast_slice(rows)),
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
    })
}

/// The compute passes' layouts: the buffers', the sort step's and the sort plan's.
fn compute_layouts(ctx: &GpuContext) -> [wgpu::BindGroupLayout; 3] {
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
    [layout0, layout1, plan_layout]
}

/// The compute pipelines over `layouts` (as [`compute_layouts`]): build, near_build,
/// near_keys, sort_plan, sort_step, gather, finish.
fn pipelines(
    ctx: &GpuContext,
    layouts: [&wgpu::BindGroupLayout; 3],
) -> Result<[wgpu::ComputePipeline; 7]> {
    let [layout0, layout1, plan_layout] = layouts;
    ctx.checked("building the far trees' compute pipelines", || {
        let module = crate::render::pipelines::wgsl_module(
            &ctx.device,
            "btf_far.wgsl",
            &crate::render::shaders::btf_far(),
        );
        let pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("btf far"),
                bind_group_layouts: &[Some(layout0), Some(layout1)],
                immediate_size: 0,
            });
        let plan_pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("btf far sort plan"),
                bind_group_layouts: &[Some(layout0), Some(plan_layout)],
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
    })
}

/// The sort's dispatch arguments, written by `sort_plan`, and their bind group in
/// `plan_layout`.
fn sort_plan_binding(
    ctx: &GpuContext,
    plan_layout: &wgpu::BindGroupLayout,
) -> Result<(wgpu::Buffer, wgpu::BindGroup)> {
    use wgpu::BufferUsages as U;
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
        layout: plan_layout,
        entries: &[entry(1, &sort_args)],
    });
    Ok((sort_args, plan_bind_group))
}

/// Placeholders until the first frame sizes them: records, keys, sorted, and the near
/// records' two bindings.
fn placeholders(ctx: &GpuContext) -> [wgpu::Buffer; 5] {
    use wgpu::BufferUsages as U;
    let small = |label| buffer(ctx, label, 16, U::STORAGE);
    let one_record = |label| {
        buffer(
            ctx,
            label,
            std::mem::size_of::<BillboardGpu>() as u64,
            U::STORAGE,
        )
    };
    [
        small("far records"),
        small("far keys"),
        small("far sorted"),
        one_record("near records"),
        one_record("near records, second binding"),
    ]
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
