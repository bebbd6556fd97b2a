// The per-frame uniforms every pass sees, and the small helpers every pass shares.
// Prepended to each pass's file (WGSL has no include). Every flag and count has a field of
// its own; `FrameUniforms` in src/render/frame.rs mirrors this block byte for byte, and
// tests/gpu_layout.rs checks the two against each other.

struct Frame {
    view_proj: mat4x4<f32>,
    inv_view_proj: mat4x4<f32>,
    // The geometry method's shadow cascades, seen from the sun.
    light_view_proj: array<mat4x4<f32>, 3>,
    camera_pos: vec3<f32>,
    // Fog density (1/m): far things fade towards the horizon colour.
    fog_density: f32,
    // Unit view direction (picks the shadow cascade by view depth).
    camera_forward: vec3<f32>,
    // Every pass's colour is scaled by it.
    exposure: f32,
    // Unit vector towards the sun.
    sun_dir: vec3<f32>,
    // 1 when sun shadows apply (the cascades, or the ground depth map), else 0.
    shadows_on: u32,
    // Sun colour x intensity (0 when the sun is below the horizon).
    sun_color: vec3<f32>,
    // PCF radius of the cascades, in texels.
    pcf_radius: f32,
    // Sky ambient from above / from below (colour x intensity).
    sky_ambient: vec3<f32>,
    // Directions of the reference's sky visibility (0: the sky is never hidden).
    sky_vis_count: u32,
    ground_ambient: vec3<f32>,
    // Side of one cell of the sky visibility volume (m).
    sky_vis_texel_world: f32,
    // Background colours (not scaled by intensity).
    sky_zenith: vec3<f32>,
    // 1: every pass draws its pixels' class instead of their colour (sky black, ground red,
    // near trees green, far trees blue; src/render/frame.rs, `pixel_classes`).
    pixel_classes: u32,
    sky_horizon: vec3<f32>,
    // 1 when the cascades hold `hybrid`'s geometry trees alone (left out of the ground
    // alpha map): everything else takes their shadows from the cascades too.
    hybrid_cascades: u32,
    // Far distance of each cascade (view depth, m).
    cascade_splits: vec3<f32>,
    // 1 / the side of a cascade's map (one texel in uv).
    cascade_texel_uv: f32,
    // World size of one texel in each cascade.
    cascade_texel_world: vec3<f32>,
    // Half the side of the scene's square (m; 0: not built): past it, on the horizon
    // ring, the terrain depth map shades nothing (`ground_coords`).
    ground_half: f32,
    // The sun's view of the whole scene, for the ground shadow maps.
    ground_light_view_proj: mat4x4<f32>,
    // 1 when the ground alpha shadow map applies.
    ground_alpha_on: u32,
    // 1 when the terrain's depth from the same pass replaces the cascades.
    terrain_depth_on: u32,
    // World size of one texel of the ground maps.
    ground_texel_world: f32,
    // Fraction of the ground textures' side in use (less while the sun is being dragged).
    ground_uv_scale: f32,
    // The overdraw view (src/render/overdraw.rs): x = 0 off, 1 on; y, z = the target's width
    // and height (the counters' row length and rows); w = what the heat map shows (0:
    // fragments, 1: image reads).
    overdraw: vec4<u32>,
    // What a studio frame draws (the impostor bake's maps): 0 its lit picture, 1 albedo,
    // 2 normal and depth (geometry.wgsl, `studio_map`); 0 in the world.
    studio_output: u32,
    // The view depth (m) the depth map reads 0 at, and 1 / the depth it reads 1 further on.
    studio_depth_near: f32,
    studio_depth_scale: f32,
    studio_pad: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;

// Two counters per pixel of the target, row by row: fragments shaded there, and the images
// they read. Written only while the overdraw view is on.
@group(0) @binding(8) var<storage, read_write> overdraw_counts: array<atomic<u32>>;

// The overdraw view's counting is compiled into a pipeline only while the view is on: a
// fragment shader that may write to memory is depth-tested after it runs (lavapipe, and
// most GPUs), so with the counters in every pipeline nothing hidden would be skipped.
override COUNT_OVERDRAW: bool = false;

// Counts a colour pass's fragment at `pixel` (its @builtin(position)) with the `reads`
// images it samples, while the overdraw view is on. Call it once per fragment, before any
// `discard` (a fragment counts whether it is kept or not).
fn count_fragment(pixel: vec4<f32>, reads: u32) {
    let at = vec2<u32>(pixel.xy);
    if COUNT_OVERDRAW && frame.overdraw.x != 0u && at.x < frame.overdraw.y && at.y < frame.overdraw.z {
        let i = 2u * (at.y * frame.overdraw.y + at.x);
        atomicAdd(&overdraw_counts[i], 1u);
        atomicAdd(&overdraw_counts[i + 1u], reads);
    }
}

// Adds `reads` more image reads at `pixel` (a fragment counted already, whose reads are
// known only at its end).
fn count_reads(pixel: vec4<f32>, reads: u32) {
    let at = vec2<u32>(pixel.xy);
    if COUNT_OVERDRAW && frame.overdraw.x != 0u && at.x < frame.overdraw.y && at.y < frame.overdraw.z {
        atomicAdd(&overdraw_counts[2u * (at.y * frame.overdraw.y + at.x) + 1u], reads);
    }
}

// The number of the 3 light weights `w` above zero (the light images a fragment reads).
fn lights_read(w: vec3<f32>) -> u32 {
    return u32(w.x > 0.0) + u32(w.y > 0.0) + u32(w.z > 0.0);
}

// Texture coordinates of a point at `ndc` (x right, y up) in a map seen by the same view.
fn ndc_to_uv(ndc: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5);
}

// The tail of every colour pass: fog towards the horizon colour with distance (`coverage`
// scales the horizon colour for premultiplied, partly covered fragments), then exposure.
fn fog_and_exposure(c: vec3<f32>, coverage: f32, dist: f32) -> vec3<f32> {
    let fog = 1.0 - exp(-dist * frame.fog_density);
    return mix(c, frame.sky_horizon * coverage, fog) * frame.exposure;
}

// Trilinear interpolation of 8 box-corner values (corner k: bit 0 = max x, bit 1 = max y,
// bit 2 = max z; corners 0-3 in `lo`, 4-7 in `hi`) at box coordinates u: the VCM factors.
fn trilinear(lo: vec4<f32>, hi: vec4<f32>, u_in: vec3<f32>) -> f32 {
    let u = clamp(u_in, vec3<f32>(0.0), vec3<f32>(1.0));
    let z0 = mix(mix(lo.x, lo.y, u.x), mix(lo.z, lo.w, u.x), u.y);
    let z1 = mix(mix(hi.x, hi.y, u.x), mix(hi.z, hi.w, u.x), u.y);
    return mix(z0, z1, u.z);
}
