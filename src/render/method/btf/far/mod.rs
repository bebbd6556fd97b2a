//! The `btf` method's far trees on the GPU. Most trees of a large forest are far enough to
//! be one tree-level billboard each, and preparing those on the CPU (level choice, view and
//! light blends, VCM factors, the sort back to front) costs tens of milliseconds per
//! 100,000 trees. Here the CPU only finds the near trees, through a grid over the forest:
//! those within the distance where a tree may not yet be at the tree level alone
//! ([`BtfScene::near_radius`](super::prepare::BtfScene::near_radius),
//! [`BtfScene::is_near`](super::prepare::BtfScene::is_near)). It prepares them itself
//! (unsorted) and uploads their records after one slot per tree, and one bit per tree
//! marking them. Compute passes (`shaders/btf_far.wgsl`) take every other tree: cull it as
//! the CPU would and build its record as the CPU would; then sort all the records, far and
//! near, back to front (bitonic, on (depth, slot) keys, so the order is the same every run)
//! and gather them for one indirect draw. The keys are packed as the records are made, and
//! the sort runs over the next power of two above their count, its dispatches sized on the
//! GPU (`sort_plan`), not over a key for every slot. The per-tree VCM factors are uploaded
//! when the sun moves.
//!
//! With [`BtfSettings::gpu_near`] (the default) the CPU does not make the near trees'
//! records either: it chooses each near tree's levels and cross-fade as before and hands
//! one [`NearDrawGpu`](super::prepare::NearDrawGpu) per level drawn to `near_build`, one
//! thread per billboard, which finds its part (the tree; a main branch or a trunk twig; a
//! main branch's twig), places it, and shades it as `TreeShading` does: the part's 8 cube
//! maps read towards the sun in its own frame (the main branches' and twigs' maps are in
//! the tables, one byte a texel) and its parents' factors at its centre. Its records and
//! keys then go through the same sort.
//! Past the far canopy's band ([`far_canopy`](super::far_canopy)), the build pass lights
//! each tree for the canopy instead (`btf_far_canopy.wgsl`) and makes no billboard for it.
//! How many billboards were made comes back a frame or two later (at once when the frame
//! is measured).
//!
//! The GPU state (buffers, bind groups, pipelines) is built in [`FarGpu::new`] (`new.rs`),
//! which sizes every buffer against the GPU's limits; the sized buffers' growth and
//! shrinking are in `buffers.rs`, a frame's passes in `frame.rs`, the records and uniforms
//! as the shader reads them in `gpu_types.rs`, the grid that finds the near trees in
//! `grid.rs`, and the read-backs in `readback.rs`.

use glam::Vec3;

use super::settings::BtfSettings;

mod buffers;
mod frame;
mod gpu_types;
mod grid;
mod new;
mod readback;

pub use gpu_types::{DirSetGpu, FarParamsGpu, FarShadeGpu, FarTreeGpu, SortStepGpu};

use buffers::ShrinkWindow;
use grid::Grid;
use readback::CountReadback;

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

impl FarGpu {
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
}

/// The batches the billboards are drawn in for the trees' layer: [`LAYER_BATCHES`] front to
/// back; one where the draws cannot start past instance 0 (`first_instance` false: indirect
/// draws without `INDIRECT_FIRST_INSTANCE`); 0 (back to front) without `front_to_back` or
/// the compositor (which takes them front to back too).
pub fn layer_batches(settings: &BtfSettings, first_instance: bool) -> u32 {
    match (
        settings.front_to_back || settings.compositor,
        first_instance,
    ) {
        (false, _) => 0,
        (true, true) => LAYER_BATCHES,
        (true, false) => 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sort_steps_are_those_of_a_bitonic_network() {
        assert_eq!(sort_steps(2), vec![(2, 1)]);
        assert_eq!(sort_steps(8).len(), 6);
        assert_eq!(sort_steps(1 << 17).len(), 17 * 18 / 2);
        assert_eq!(sort_steps(8)[3], (8, 4));
    }
}
