//! The far trees' GPU records and uniforms, laid out as `shaders/btf_far.wgsl` reads them.

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
    /// The word of the draw arguments that counts the keys made
    /// ([`SORT_ARGS_AT`](super::SORT_ARGS_AT)).
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
