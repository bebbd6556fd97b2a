// The per-frame uniforms every pass sees. Prepended to each pass's file.

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
    // The sun's view of the whole scene, for the ground shadow maps.
    ground_light_view_proj: mat4x4<f32>,
    // x: 1 when the ground alpha shadow map applies; y: 1 when the terrain's depth from
    // the same pass replaces the cascades; z: world size of one of its texels; w: the
    // fraction of the textures' side in use (less while the sun is being dragged)
    ground_params: vec4<f32>,
}

@group(0) @binding(0) var<uniform> frame: Frame;
