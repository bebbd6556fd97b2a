// Shared by every pass that draws the forest: the per-frame uniforms, the instanced tree
// hierarchy (tree instances x parts) and the vertex format. Prepended to each pass's file.

const CASCADES: u32 = 3u;

struct Frame {
    view_proj: mat4x4<f32>,
    inv_view_proj: mat4x4<f32>,
    light_view_proj: array<mat4x4<f32>, 3>,
    // xyz: camera position; w: fog density (1/m)
    camera_pos: vec4<f32>,
    // xyz: unit view direction (picks the shadow cascade by view depth)
    camera_forward: vec4<f32>,
    // xyz: unit vector towards the sun; w: 1 when shadows are on
    sun_dir: vec4<f32>,
    // rgb: sun colour x intensity (0 when the sun is below the horizon)
    sun_color: vec4<f32>,
    // rgb: sky ambient from above / from below (colour x intensity)
    sky_ambient: vec4<f32>,
    ground_ambient: vec4<f32>,
    // background colours (not scaled by intensity)
    sky_zenith: vec4<f32>,
    sky_horizon: vec4<f32>,
    // xyz: far distance of each cascade (view depth, m); w: 1 / shadow-map size
    cascade_splits: vec4<f32>,
    // xyz: world size of one shadow-map texel in each cascade
    cascade_texel: vec4<f32>,
    // y: PCF radius (texels); z: exposure
    shadow_params: vec4<f32>,
}

@group(0) @binding(0) var<uniform> frame: Frame;

// One tree in the world: its transform and a foliage colour variation.
struct TreeInstance {
    model: mat4x4<f32>,
    tint: vec4<f32>,
}

// A set of parts drawn with one mesh: the trunk (1 part), the main branches' limbs (one per
// branch) or every twig of the tree (one per twig), each with its transform in the tree frame.
struct PartSet {
    count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(1) @binding(0) var<storage, read> trees: array<TreeInstance>;
@group(2) @binding(0) var<storage, read> parts: array<mat4x4<f32>>;
@group(2) @binding(1) var<uniform> part_set: PartSet;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec3<f32>,
    @location(3) foliage: f32,
}

// Instance `i` of a draw is part `i % count` of tree `i / count`: the hierarchy is drawn
// as it is stored, never flattened into per-part world matrices.
fn instance_model(instance: u32) -> mat4x4<f32> {
    let count = max(part_set.count, 1u);
    return trees[instance / count].model * parts[instance % count];
}

fn instance_tint(instance: u32) -> vec3<f32> {
    let count = max(part_set.count, 1u);
    return trees[instance / count].tint.rgb;
}
