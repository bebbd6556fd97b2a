// The far canopy (src/render/method/btf/far_canopy/): past the distance where a tree covers a
// few pixels, the forest is one layer over the ground instead of a billboard per tree. The
// layer is a lid of heights over the terrain (ground plus nearly the highest crown), drawn
// in tiles; each pixel reads the map of the forest seen from above (how much of the land
// the crowns cover, and which tree is seen there) at the level whose texels match the
// pixel, and takes those trees' colours, lit this frame as their billboards would be
// (`canopy_colour` in btf_far_canopy.wgsl). Seen at a slant, the light crosses more of the
// layer: its coverage c from above becomes 1 - (1 - c)^(1 / |cos|). It fades in over the
// band where the trees' billboards fade out, and is composited like them, premultiplied.

struct Canopy {
    // The map's (x, z) corner and the side of a level-0 texel (m).
    origin: vec2<f32>,
    texel: f32,
    // Level-0 texels per side, and the map's levels.
    side: u32,
    levels: u32,
    // Lid vertices per side; map texels per lid cell; lid cells per tile side.
    lid_side: u32,
    lid_texels: u32,
    tile_cells: u32,
    // The fade band (m from the eye): nothing before `near`, whole past `far`.
    near: f32,
    far: f32,
    // 1: every pixel in `overlay` (the LOD view's colour).
    show_overlay: u32,
    _pad0: u32,
    overlay: vec3<f32>,
    _pad1: u32,
}

@group(1) @binding(0) var<uniform> canopy: Canopy;
@group(1) @binding(1) var cover_map: texture_2d<f32>;
@group(1) @binding(2) var tree_map: texture_2d<u32>;
@group(1) @binding(3) var lid_map: texture_2d<f32>;
@group(1) @binding(4) var cover_sampler: sampler;
// Each tree's colour this frame (rgb; w = 1 once made), from `canopy_colour`.
@group(1) @binding(5) var<storage, read> colours: array<vec4<f32>>;
// The tiles drawn: their first lid cell (x, z).
@group(1) @binding(6) var<storage, read> tiles: array<vec2<u32>>;

struct LidOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
}

@vertex
fn vs_canopy(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> LidOut {
    // Two triangles a cell: corners (0,0) (1,0) (1,1), (0,0) (1,1) (0,1).
    var dx = array<u32, 6>(0u, 1u, 1u, 0u, 1u, 0u);
    var dz = array<u32, 6>(0u, 0u, 1u, 0u, 1u, 1u);
    let cell = vi / 6u;
    let k = vi % 6u;
    let tile = tiles[instance];
    let last = canopy.lid_side - 1u;
    let ci = min(tile.x + cell % canopy.tile_cells + dx[k], last);
    let cj = min(tile.y + cell / canopy.tile_cells + dz[k], last);
    let h = textureLoad(lid_map, vec2<u32>(ci, cj), 0).r;
    let step = canopy.texel * f32(canopy.lid_texels);
    let world = vec3<f32>(canopy.origin.x + f32(ci) * step, h, canopy.origin.y + f32(cj) * step);
    var out: LidOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    return out;
}

@fragment
fn fs_canopy(in: LidOut) -> @location(0) vec4<f32> {
    let side = f32(canopy.side);
    let uv = (in.world.xz - canopy.origin) / (canopy.texel * side);
    let cover = textureSample(cover_map, cover_sampler, uv).r;
    // The level whose texels are about a pixel wide.
    let tx = uv * side;
    let footprint = max(length(dpdx(tx)), length(dpdy(tx)));
    let level = u32(clamp(floor(log2(max(footprint, 1.0))), 0.0, f32(canopy.levels - 1u)));
    count_fragment(in.clip, 1u);
    let to_eye = frame.camera_pos - in.world;
    let dist = length(to_eye);
    let slant = max(abs(to_eye.y) / max(dist, 1e-3), 0.1);
    var alpha = 1.0 - pow(max(1.0 - cover, 0.0), 1.0 / slant);
    alpha *= smoothstep(canopy.near, canopy.far, dist);
    if alpha <= 1.0 / 512.0 {
        discard;
    }
    // The trees there, bilinear between the 4 texels around the pixel.
    let lside = max(canopy.side >> level, 1u);
    let p = uv * f32(lside) - 0.5;
    let base = floor(p);
    let f = p - base;
    var colour = vec3<f32>(0.0);
    var weight = 0.0;
    var reads = 4u;
    for (var k = 0u; k < 4u; k++) {
        let o = vec2<f32>(f32(k & 1u), f32(k >> 1u));
        let ij = vec2<u32>(clamp(base + o, vec2<f32>(0.0), vec2<f32>(f32(lside - 1u))));
        let t = textureLoad(tree_map, ij, level).r;
        if t == 0u {
            continue;
        }
        let c = colours[t - 1u];
        reads += 1u;
        if c.w <= 0.0 {
            continue;
        }
        let w = mix(1.0 - f.x, f.x, o.x) * mix(1.0 - f.y, f.y, o.y);
        colour += w * c.rgb;
        weight += w;
    }
    count_reads(in.clip, reads);
    if weight <= 0.0 {
        discard;
    }
    colour /= weight;
    if canopy.show_overlay != 0u {
        colour = canopy.overlay;
    }
    return vec4<f32>(fog_and_exposure(colour * alpha, alpha, dist), alpha);
}
