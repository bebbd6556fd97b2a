// The `texel` method, slices parallel to the screen (Decaudin-Neyret 2009, "Volumetric
// Billboards"): each tree is a box holding its species' baked volumes in one 3D texture.
// The box's faces are drawn; each fragment walks the eye's ray through the box and samples
// the volume where the ray crosses planes parallel to the screen, `spacing` metres of view
// depth apart, so that every box is cut by the same family of slices and no stack ever
// switches. Opacity is corrected for the step (alpha' = 1 - (1 - alpha)^(s / voxel)), the
// slices are composited front to back, and the result is blended over what lies behind
// with premultiplied alpha. `TexelGpu` in src/render/method/texel.rs mirrors the record
// byte for byte (checked by tests/gpu_layout.rs).

struct Texel {
    // Object to world (rotation x uniform scale + translation), and its inverse.
    model: mat4x4<f32>,
    world_to_object: mat4x4<f32>,
    // The box in the object frame.
    box_min: vec3<f32>,
    // View depth between two slices (m).
    spacing: f32,
    box_size: vec3<f32>,
    // Side of one voxel in the object frame (the baked slab thickness).
    voxel: f32,
    // Where volume 0 of the species starts in the 3D texture (uvw), and how far apart
    // (in w) its volumes lie: light k at k * volume_dw, the sky at lights * volume_dw.
    atlas_origin: vec3<f32>,
    volume_dw: f32,
    // The extent of one volume in uvw.
    atlas_extent: vec3<f32>,
    // Mip level to sample (from the voxel's projected size).
    lod: f32,
    // The 3 nearest baked lights of the sun in the object frame, and their weights.
    light_index: vec3<u32>,
    // MODE_VOLUME or MODE_SLICES.
    mode: u32,
    light_weight: vec3<f32>,
    // Light samples of the bake (the sky volume's index).
    lights: u32,
    tint: vec3<f32>,
    // Object-to-world scale.
    scale: f32,
    // The tree-level VCM box (object frame): its lowest corner and 1 / its size.
    vcm_min: vec3<f32>,
    // Most samples one ray may take.
    max_steps: f32,
    vcm_inv_size: vec3<f32>,
    // Slices this texel was given (for the overlay).
    slices: f32,
    // Sun and sky visibility at the 8 box corners (corner k: bit 0 = max x, bit 1 = max y,
    // bit 2 = max z).
    vcm_direct: array<vec4<f32>, 2>,
    vcm_sky: array<vec4<f32>, 2>,
}

const MODE_VOLUME: u32 = 0u;
// The slice count as a colour, times coverage (the "show slice count" overlay).
const MODE_SLICES: u32 = 1u;

@group(1) @binding(0) var<storage, read> texels: array<Texel>;
@group(1) @binding(1) var volumes: texture_3d<f32>;
@group(1) @binding(2) var volume_sampler: sampler;

struct TexelOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) @interpolate(flat) instance: u32,
}

// The "show slice count" overlay's colour: blue for 1 slice through green (11) to red
// (128 or more), on a log scale.
fn slice_count_colour(slices: f32) -> vec3<f32> {
    let x = clamp(log2(max(slices, 1.0)) / 7.0, 0.0, 1.0);
    return vec3<f32>(smoothstep(0.5, 1.0, x), 1.0 - abs(2.0 * x - 1.0), 1.0 - smoothstep(0.0, 0.5, x));
}

// Corner `i` (0..36) of the 12 triangles of the unit cube, counter-clockwise seen from
// outside.
fn cube_corner(i: u32) -> vec3<f32> {
    var corners = array<vec3<f32>, 36>(
        vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(1.0, 1.0, 0.0), vec3<f32>(1.0, 1.0, 1.0),
        vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(1.0, 1.0, 1.0), vec3<f32>(1.0, 0.0, 1.0),
        vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(0.0, 1.0, 1.0), vec3<f32>(0.0, 1.0, 0.0),
        vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 0.0),
        vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 1.0, 1.0), vec3<f32>(1.0, 1.0, 1.0),
        vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(1.0, 1.0, 1.0), vec3<f32>(1.0, 1.0, 0.0),
        vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(0.0, 0.0, 0.0), vec3<f32>(1.0, 0.0, 0.0),
        vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(1.0, 0.0, 1.0),
        vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(1.0, 0.0, 1.0), vec3<f32>(1.0, 1.0, 1.0),
        vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(1.0, 1.0, 1.0), vec3<f32>(0.0, 1.0, 1.0),
        vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0),
        vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(1.0, 1.0, 0.0),
    );
    return corners[i % 36u];
}

@vertex
fn vs_texel(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> TexelOut {
    let t = texels[instance];
    let p = t.box_min + cube_corner(vi) * t.box_size;
    let world = (t.model * vec4<f32>(p, 1.0)).xyz;
    var out: TexelOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.instance = instance;
    return out;
}

fn sample_volume(t: Texel, uvw: vec3<f32>, volume: u32) -> vec4<f32> {
    let at = t.atlas_origin + uvw * t.atlas_extent + vec3<f32>(0.0, 0.0, f32(volume) * t.volume_dw);
    return textureSampleLevel(volumes, volume_sampler, at, t.lod);
}

@fragment
fn fs_texel(in: TexelOut) -> @location(0) vec4<f32> {
    let t = texels[in.instance];
    count_fragment(in.clip, 0u);
    let eye = (t.world_to_object * vec4<f32>(frame.camera_pos, 1.0)).xyz;
    let through = (t.world_to_object * vec4<f32>(in.world, 1.0)).xyz;
    let dir = normalize(through - eye);
    // The ray's stretch inside the box (object units along `dir`), from the eye on.
    let inv = 1.0 / select(dir, vec3<f32>(1e-8), abs(dir) < vec3<f32>(1e-8));
    let a = (t.box_min - eye) * inv;
    let b = (t.box_min + t.box_size - eye) * inv;
    let lo = min(a, b);
    let hi = max(a, b);
    let t_in = max(max(max(lo.x, lo.y), lo.z), 0.0);
    let t_out = min(min(hi.x, hi.y), hi.z);
    if t_out <= t_in {
        discard;
    }
    // View depth per unit of `dir`: the slices are planes of constant view depth.
    let dir_world = normalize(in.world - frame.camera_pos);
    let depth_per_t = t.scale * max(dot(dir_world, frame.camera_forward), 0.05);
    let dt = t.spacing / depth_per_t;
    // The first slice plane past the entry point, then every `dt`.
    let first = (floor(t_in * depth_per_t / t.spacing) + 1.0) * dt;
    // The baked alpha covers one voxel of depth; this step covers dt.
    let thickness = dt / t.voxel;
    let steps = min(ceil((t_out - first) / dt), t.max_steps);
    let inv_size = 1.0 / t.box_size;
    let half = 0.5 / (t.box_size / t.voxel);
    var color = vec3<f32>(0.0);
    var alpha = 0.0;
    var reads = 0u;
    for (var k = 0.0; k < steps; k += 1.0) {
        let p = eye + dir * (first + k * dt);
        let uvw = clamp((p - t.box_min) * inv_size, half, vec3<f32>(1.0) - half);
        let sky = sample_volume(t, uvw, t.lights);
        reads += 1u;
        if sky.a < 0.002 {
            continue;
        }
        reads += lights_read(t.light_weight);
        var direct = vec3<f32>(0.0);
        for (var j = 0; j < 3; j++) {
            let w = t.light_weight[j];
            if w > 0.0 {
                direct += w * sample_volume(t, uvw, t.light_index[j]).rgb;
            }
        }
        let u = (p - t.vcm_min) * t.vcm_inv_size;
        let f_sun = trilinear(t.vcm_direct[0], t.vcm_direct[1], u);
        let f_sky = trilinear(t.vcm_sky[0], t.vcm_sky[1], u);
        let c = direct * frame.sun_color * f_sun + sky.rgb * frame.sky_ambient * f_sky;
        let a_step = 1.0 - pow(1.0 - min(sky.a, 0.999), thickness);
        color += (1.0 - alpha) * c * (a_step / sky.a);
        alpha += (1.0 - alpha) * a_step;
        if alpha > 0.995 {
            break;
        }
    }
    count_reads(in.clip, reads);
    if alpha <= 0.0 {
        discard;
    }
    var shown = color * t.tint;
    if t.mode == MODE_SLICES {
        shown = slice_count_colour(t.slices) * alpha;
    }
    let dist = t_in * t.scale;
    return vec4<f32>(fog_and_exposure(shown, alpha, dist), alpha);
}

// The ground alpha shadow map (drawn from the sun with the ground pass's uniforms, where
// `view_proj` is the sun's view): how much light each texel lets through along the sun's
// rays, one sample per voxel, multiplied into the map (blend: dst x (1 - alpha)). Only the
// fragment where the ray enters the box counts (the box's far faces are discarded, whatever
// their winding in the light's view).
@fragment
fn fs_texel_opacity(in: TexelOut) -> @location(0) vec4<f32> {
    let t = texels[in.instance];
    let p = (t.world_to_object * vec4<f32>(in.world, 1.0)).xyz;
    let dir = normalize((t.world_to_object * vec4<f32>(-frame.sun_dir, 0.0)).xyz);
    let inv = 1.0 / select(dir, vec3<f32>(1e-8), abs(dir) < vec3<f32>(1e-8));
    let a = (t.box_min - p) * inv;
    let b = (t.box_min + t.box_size - p) * inv;
    let lo = min(a, b);
    let hi = max(a, b);
    let t_in = max(max(lo.x, lo.y), lo.z);
    let t_out = min(min(hi.x, hi.y), hi.z);
    // This fragment is on the box (t = 0): keep it only where the ray enters.
    if t_in < -0.01 * t.voxel || t_out <= t_in {
        discard;
    }
    let dt = t.voxel;
    let steps = min(ceil((t_out - t_in) / dt), t.max_steps);
    let inv_size = 1.0 / t.box_size;
    let half = 0.5 / (t.box_size / t.voxel);
    var transmit = 1.0;
    for (var k = 0.0; k < steps; k += 1.0) {
        let q = p + dir * (t_in + (k + 0.5) * dt);
        let uvw = clamp((q - t.box_min) * inv_size, half, vec3<f32>(1.0) - half);
        let a_step = sample_volume(t, uvw, t.lights).a;
        transmit *= 1.0 - a_step;
        if transmit < 0.005 {
            break;
        }
    }
    return vec4<f32>(0.0, 0.0, 0.0, 1.0 - transmit);
}

// ---------------------------------------------------------------------------------------
// The seeds' stacks (`--texel-mode stacks`; src/render/method/texel/stacks.rs): each texel
// drawn as the slices of its stack most facing the eye, one quad per slice, back to front,
// each slice a tile of the stack atlas (pre-composited levels: a slice of level k is the
// "over" of 2^k voxel slices, so no opacity correction). `StackGpu` mirrors `Stack`.

struct Stack {
    // uv of the species' group's first tile, of one tile, of a tile's used part.
    origin: vec2<f32>,
    tile: vec2<f32>,
    used: vec2<f32>,
    // The used part in texels (level 0).
    texels: vec2<f32>,
    // The stack's axis (0 x, 1 y, 2 z); tiles per row of the group; tiles per volume.
    axis: u32,
    cols: u32,
    per_volume: u32,
    // First tile of the drawn level and order within a volume; the level (2^level voxel
    // slices per drawn slice); the viewing order (0: lower slices in front).
    level_offset: u32,
    level: u32,
    order: u32,
    // Slices drawn.
    slices: u32,
    pad: u32,
}

@group(1) @binding(3) var stack_atlas: texture_2d<f32>;
@group(1) @binding(4) var<storage, read> stacks: array<Stack>;
// Per drawn quad: the texel and the slice of its level, back to front.
@group(1) @binding(5) var<storage, read> stack_quads: array<vec2<u32>>;

struct StackOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) object: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) @interpolate(flat) texel: u32,
    @location(4) @interpolate(flat) slice: u32,
}

@vertex
fn vs_stack(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> StackOut {
    var quad = array<vec2<f32>, 6>(
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 0.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 1.0), vec2<f32>(0.0, 1.0),
    );
    let pick = stack_quads[instance];
    let t = texels[pick.x];
    let s = stacks[pick.x];
    let c = quad[vi % 6u];
    // Across the axis: the middle of the 2^level voxel slices this slice stands for.
    let along = (f32(pick.y) + 0.5) * f32(1u << s.level) * t.voxel;
    var p: vec3<f32>;
    if s.axis == 0u {
        p = vec3<f32>(along, c.x * t.box_size.y, c.y * t.box_size.z);
    } else if s.axis == 1u {
        p = vec3<f32>(c.x * t.box_size.x, along, c.y * t.box_size.z);
    } else {
        p = vec3<f32>(c.x * t.box_size.x, c.y * t.box_size.y, along);
    }
    p += t.box_min;
    let world = (t.model * vec4<f32>(p, 1.0)).xyz;
    var out: StackOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.object = p;
    out.uv = c;
    out.texel = pick.x;
    out.slice = pick.y;
    return out;
}

fn stack_sample(s: Stack, volume: u32, slice: u32, uv: vec2<f32>, lod: f32) -> vec4<f32> {
    let index = volume * s.per_volume + s.level_offset + slice;
    let cell = vec2<f32>(f32(index % s.cols), f32(index / s.cols));
    // Half a texel of the sampled mip level in from the used part's edges.
    let half = min(vec2<f32>(0.5), 0.5 * exp2(ceil(lod)) / s.texels);
    let at = s.origin + cell * s.tile + clamp(uv, half, vec2<f32>(1.0) - half) * s.used;
    return textureSampleLevel(stack_atlas, volume_sampler, at, lod);
}

@fragment
fn fs_stack(in: StackOut) -> @location(0) vec4<f32> {
    let t = texels[in.texel];
    let s = stacks[in.texel];
    let sky = stack_sample(s, t.lights, in.slice, in.uv, t.lod);
    count_fragment(in.clip, 1u + select(0u, lights_read(t.light_weight), sky.a >= 0.002));
    if sky.a < 0.002 {
        discard;
    }
    var direct = vec3<f32>(0.0);
    for (var j = 0; j < 3; j++) {
        let w = t.light_weight[j];
        if w > 0.0 {
            direct += w * stack_sample(s, t.light_index[j], in.slice, in.uv, t.lod).rgb;
        }
    }
    let u = (in.object - t.vcm_min) * t.vcm_inv_size;
    let f_sun = trilinear(t.vcm_direct[0], t.vcm_direct[1], u);
    let f_sky = trilinear(t.vcm_sky[0], t.vcm_sky[1], u);
    let alpha = sky.a;
    var shown = (direct * frame.sun_color * f_sun + sky.rgb * frame.sky_ambient * f_sky) * t.tint;
    if t.mode == MODE_SLICES {
        shown = slice_count_colour(t.slices) * alpha;
    }
    let dist = length(in.world - frame.camera_pos);
    return vec4<f32>(fog_and_exposure(shown, alpha, dist), alpha);
}

// ---------------------------------------------------------------------------------------
// Forest-cover tiles (src/render/method/texel/tiles.rs): a tile's volume follows the
// ground, world = (x, b(u, w) + lo + v * height, z) with b bilinear between the terrain at
// the tile's corners. Its world box is drawn; each fragment marches the eye's ray on
// planes parallel to the screen as `fs_texel` does, mapping each sample to tile
// coordinates. `TileGpu` mirrors `Tile`.

struct Tile {
    // The tile's lowest (x, z) corner and side (m), and the volume's floor above the ground.
    origin: vec2<f32>,
    size: f32,
    lo: f32,
    // Terrain height at (x0, z0), (x1, z0), (x0, z1), (x1, z1).
    corners: vec4<f32>,
    height: f32,
    // Side of a cube of one voxel's volume (what alpha is a thickness of).
    voxel: f32,
    spacing: f32,
    max_steps: f32,
    atlas_origin: vec3<f32>,
    volume_dw: f32,
    atlas_extent: vec3<f32>,
    lights: u32,
    light_index: vec3<u32>,
    slices: f32,
    light_weight: vec3<f32>,
    pad0: f32,
    box_min: vec3<f32>,
    pad1: f32,
    box_max: vec3<f32>,
    pad2: f32,
}

@group(1) @binding(6) var<storage, read> tiles: array<Tile>;
@group(1) @binding(7) var tile_volumes: texture_3d<f32>;

@vertex
fn vs_tile(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> TexelOut {
    let t = tiles[instance];
    let world = t.box_min + cube_corner(vi) * (t.box_max - t.box_min);
    var out: TexelOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.instance = instance;
    return out;
}

fn sample_tile(t: Tile, uvw: vec3<f32>, volume: u32) -> vec4<f32> {
    let at = t.atlas_origin + uvw * t.atlas_extent + vec3<f32>(0.0, 0.0, f32(volume) * t.volume_dw);
    return textureSampleLevel(tile_volumes, volume_sampler, at, 0.0);
}

@fragment
fn fs_tile(in: TexelOut) -> @location(0) vec4<f32> {
    let t = tiles[in.instance];
    count_fragment(in.clip, 0u);
    let eye = frame.camera_pos;
    let dir = normalize(in.world - eye);
    let inv = 1.0 / select(dir, vec3<f32>(1e-8), abs(dir) < vec3<f32>(1e-8));
    let a = (t.box_min - eye) * inv;
    let b = (t.box_max - eye) * inv;
    let lo = min(a, b);
    let hi = max(a, b);
    let t_in = max(max(max(lo.x, lo.y), lo.z), 0.0);
    let t_out = min(min(hi.x, hi.y), hi.z);
    if t_out <= t_in {
        discard;
    }
    let depth_per_t = max(dot(dir, frame.camera_forward), 0.05);
    let dt = t.spacing / depth_per_t;
    let first = (floor(t_in * depth_per_t / t.spacing) + 1.0) * dt;
    let thickness = dt / t.voxel;
    let steps = min(ceil((t_out - first) / dt), t.max_steps);
    let cells = vec3<f32>(textureDimensions(tile_volumes)) * t.atlas_extent;
    let half = 0.5 / cells;
    var color = vec3<f32>(0.0);
    var alpha = 0.0;
    var reads = 0u;
    for (var k = 0.0; k < steps; k += 1.0) {
        let p = eye + dir * (first + k * dt);
        let u = (p.x - t.origin.x) / t.size;
        let w = (p.z - t.origin.y) / t.size;
        let ground = mix(mix(t.corners.x, t.corners.y, u), mix(t.corners.z, t.corners.w, u), w);
        let v = (p.y - ground - t.lo) / t.height;
        let uvw = vec3<f32>(u, v, w);
        if any(uvw < vec3<f32>(0.0)) || any(uvw > vec3<f32>(1.0)) {
            continue;
        }
        let at = clamp(uvw, half, vec3<f32>(1.0) - half);
        let sky = sample_tile(t, at, t.lights);
        reads += 1u;
        if sky.a < 0.002 {
            continue;
        }
        reads += lights_read(t.light_weight);
        var direct = vec3<f32>(0.0);
        for (var j = 0; j < 3; j++) {
            let wj = t.light_weight[j];
            if wj > 0.0 {
                direct += wj * sample_tile(t, at, t.light_index[j]).rgb;
            }
        }
        let c = direct * frame.sun_color + sky.rgb * frame.sky_ambient;
        let a_step = 1.0 - pow(1.0 - min(sky.a, 0.999), thickness);
        color += (1.0 - alpha) * c * (a_step / sky.a);
        alpha += (1.0 - alpha) * a_step;
        if alpha > 0.995 {
            break;
        }
    }
    count_reads(in.clip, reads);
    if alpha <= 0.0 {
        discard;
    }
    return vec4<f32>(fog_and_exposure(color, alpha, t_in), alpha);
}

// ---------------------------------------------------------------------------------------
// Slices parallel to the screen as polygons (`--texel-mode polygons`;
// src/render/method/texel/polygons.rs): the planes `fs_texel` samples, cut out of each box
// on the CPU and drawn back to front; each fragment is one of the ray march's samples.

struct PolyVertex {
    position: vec3<f32>,
    texel: u32,
}

@group(1) @binding(8) var<storage, read> poly_vertices: array<PolyVertex>;

@vertex
fn vs_poly(@builtin(vertex_index) vi: u32) -> TexelOut {
    let v = poly_vertices[vi];
    var out: TexelOut;
    out.clip = frame.view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.instance = v.texel;
    return out;
}

@fragment
fn fs_poly(in: TexelOut) -> @location(0) vec4<f32> {
    let t = texels[in.instance];
    let p = (t.world_to_object * vec4<f32>(in.world, 1.0)).xyz;
    let half = 0.5 / (t.box_size / t.voxel);
    let uvw = clamp((p - t.box_min) / t.box_size, half, vec3<f32>(1.0) - half);
    let sky = sample_volume(t, uvw, t.lights);
    count_fragment(in.clip, 1u + select(0u, lights_read(t.light_weight), sky.a >= 0.002));
    if sky.a < 0.002 {
        discard;
    }
    var direct = vec3<f32>(0.0);
    for (var j = 0; j < 3; j++) {
        let w = t.light_weight[j];
        if w > 0.0 {
            direct += w * sample_volume(t, uvw, t.light_index[j]).rgb;
        }
    }
    let u = (p - t.vcm_min) * t.vcm_inv_size;
    let f_sun = trilinear(t.vcm_direct[0], t.vcm_direct[1], u);
    let f_sky = trilinear(t.vcm_sky[0], t.vcm_sky[1], u);
    // The ray's length between two slices, in voxels: what this sample's alpha covers.
    let dir_world = normalize(in.world - frame.camera_pos);
    let dt = t.spacing / (t.scale * max(dot(dir_world, frame.camera_forward), 0.05));
    let a_step = 1.0 - pow(1.0 - min(sky.a, 0.999), dt / t.voxel);
    let c = direct * frame.sun_color * f_sun + sky.rgb * frame.sky_ambient * f_sky;
    var shown = c * (a_step / sky.a) * t.tint;
    if t.mode == MODE_SLICES {
        shown = slice_count_colour(t.slices) * a_step;
    }
    let dist = length(in.world - frame.camera_pos);
    return vec4<f32>(fog_and_exposure(shown, a_step, dist), a_step);
}
