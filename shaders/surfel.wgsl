// The `surfel` method (src/render/method/surfel/): each drawn block of a tree's LDC tree
// splatted in compute, one surfel to one pixel, as Schuetz et al.'s point rasterisers do,
// then the holes filled by pull-push (Guennebaud and Paulin 2002, after Grossman and Dally).
//
// - `init`, a thread per pixel: the frame's depth (terrain, sky) as a view distance, the
//   start of each pixel's nearest-surfel distance; the sums cleared.
// - `depth`, a workgroup per block: each surfel in front of the frame's depth lowers its
//   pixel's nearest distance (atomic minimum on the float's bits: positive floats order as
//   their bits).
// - `colour`, the same surfels again: those within the block's tolerance of their pixel's
//   nearest distance are lit (sun and sky, the tree's VCM factors) and added to the pixel's
//   sums in fixed point.
// - `pull1`, `pull2`: the sums at half and quarter resolution, with the share of covered
//   pixels and the nearest distance of each.
// - `push`, a thread per pixel: a covered pixel its mean; an empty one with at least 6 of
//   its 8 neighbours covered their mean; where the surfels are spaced wider than a pixel
//   (`surfel_px` above 1.5 or 3), an empty one inside a covered region of the half- or
//   quarter-resolution level that level's colour; in each case only in front of the
//   frame's depth there (else it stays empty). Written into the trees' layer, which is then
//   put over the frame.
//
// Prepended: frame.wgsl. `SurfelParams`, `SurfelTreeGpu` and `SurfelItem` mirror the Rust
// structs of src/render/method/surfel/gpu.rs byte for byte (tests/gpu_layout.rs).

struct SurfelParams {
    size: vec2<u32>,
    half_size: vec2<u32>,
    quarter_size: vec2<u32>,
    // Blocks this frame splats.
    items: u32,
    // Workgroups of a dispatch's row (items are numbered x + y * this).
    row: u32,
    // Levels holes are filled from: 0 none; 1 a pixel's neighbours; 2 and 3 the half- and
    // quarter-resolution levels too (where the surfels are spaced wider than a pixel).
    fill: u32,
    // 1: each surfel takes its level's colour (the LOD overlay); 2: its sun factor.
    mode: u32,
    // Pixels per metre at one metre from the camera (0: orthographic, every surfel drawn).
    focal_px: f32,
    // Multiplies the trees' own extinction (0: no self-shadowing).
    self_shadow: f32,
}

struct SurfelTreeGpu {
    model: mat4x4<f32>,
    // The box the species' surfels are quantised in (tree frame).
    qmin: vec3<f32>,
    // The tree's index in the world (seeds its surfels' coverage dither).
    instance: u32,
    qsize: vec3<f32>,
    // Uniform scale of the model matrix.
    scale: f32,
    tint: vec3<f32>,
    _pad0: f32,
    // The VCM box (tree frame): u = (p - vcm_min) * vcm_inv_size.
    vcm_min: vec3<f32>,
    _pad1: f32,
    vcm_inv_size: vec3<f32>,
    _pad2: f32,
    vcm_direct: array<vec4<f32>, 2>,
    vcm_sky: array<vec4<f32>, 2>,
    // The species' density volume: its corner (tree frame), voxel side, size in voxels and
    // where it starts in `volumes`.
    vol_origin: vec3<f32>,
    vol_voxel: f32,
    vol_dims: vec3<u32>,
    vol_offset: u32,
}

struct SurfelItem {
    tree: u32,
    first: u32,
    count: u32,
    // Depth tolerance (m, world): surfels this far behind their pixel's nearest one count.
    tolerance: f32,
    level: u32,
    // The level's spacing in the world (m).
    spacing: f32,
    _pad: vec2<u32>,
}

@group(1) @binding(0) var<uniform> sp: SurfelParams;
@group(1) @binding(1) var<storage, read> surfels: array<u32>;
@group(1) @binding(2) var<storage, read> items: array<SurfelItem>;
@group(1) @binding(3) var<storage, read> trees: array<SurfelTreeGpu>;
@group(1) @binding(4) var<storage, read_write> nearest: array<atomic<u32>>;
@group(1) @binding(5) var<storage, read_write> sums: array<atomic<u32>>;
@group(1) @binding(6) var<storage, read_write> levels: array<vec4<f32>>;
@group(1) @binding(7) var scene_depth: texture_depth_2d;
@group(1) @binding(8) var layer_out: texture_storage_2d<rgba16float, write>;
@group(1) @binding(9) var<storage, read> volumes: array<f32>;

// Fixed-point units of a colour sum (1.0 = this many).
const SUM_SCALE: f32 = 256.0;
// The distance of a pixel with nothing drawn (the sky).
const FAR: f32 = 3.0e38;
const WG: u32 = 64u;

// The view distance (clip w) of the frame's depth at `pixel` (reversed Z: 0 is the sky).
fn scene_distance(pixel: vec2<u32>) -> f32 {
    let z = textureLoad(scene_depth, vec2<i32>(pixel), 0);
    if z <= 0.0 {
        return FAR;
    }
    let ndc = vec2<f32>(
        (f32(pixel.x) + 0.5) / f32(sp.size.x) * 2.0 - 1.0,
        1.0 - (f32(pixel.y) + 0.5) / f32(sp.size.y) * 2.0,
    );
    let h = frame.inv_view_proj * vec4<f32>(ndc, z, 1.0);
    return 1.0 / max(h.w, 1e-30);
}

@compute @workgroup_size(8, 8)
fn init(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= sp.size.x || id.y >= sp.size.y {
        return;
    }
    let p = id.y * sp.size.x + id.x;
    atomicStore(&nearest[p], bitcast<u32>(scene_distance(id.xy)));
    for (var k = 0u; k < 4u; k++) {
        atomicStore(&sums[4u * p + k], 0u);
    }
}

// One surfel, decoded and placed.
struct Placed {
    // Pixel index (or none: behind the camera, off screen, a bark surfel seen from behind).
    pixel: u32,
    ok: bool,
    distance: f32,
    world: vec3<f32>,
    normal: vec3<f32>,
    albedo: vec3<f32>,
    foliage: bool,
    // The share of the sky its own tree leaves open to it.
    openness: f32,
    // Box coordinates in the VCM box.
    u: vec3<f32>,
    // Where it is in the tree frame.
    local: vec3<f32>,
}

// A unit normal from its octahedral pair in [-1, 1]² (src/sphere/octa.rs's full layout:
// +y at the centre, a sign of 0 counting as positive).
fn octa_decode(e: vec2<f32>) -> vec3<f32> {
    let y = 1.0 - abs(e.x) - abs(e.y);
    var xz = e;
    if y < 0.0 {
        xz = (1.0 - abs(e.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), e >= vec2<f32>(0.0));
    }
    return normalize(vec3<f32>(xz.x, y, xz.y));
}

// A hash of `x` in [0, 1) (PCG's output permutation).
fn hash01(x: u32) -> f32 {
    var h = x * 747796405u + 2891336453u;
    h = ((h >> ((h >> 28u) + 4u)) ^ h) * 277803737u;
    h = (h >> 22u) ^ h;
    return f32(h >> 8u) / 16777216.0;
}

fn place(t: SurfelTreeGpu, i: u32, spacing: f32) -> Placed {
    var out: Placed;
    out.ok = false;
    let w0 = surfels[3u * i];
    let w1 = surfels[3u * i + 1u];
    let w2 = surfels[3u * i + 2u];
    // The layout of src/format/mod.rs's SURFEL TREE RECORD.
    let q = vec3<f32>(
        f32(w0 & 0x3fffu),
        f32((w0 >> 14u) & 0x3fffu),
        f32((w0 >> 28u) | ((w1 & 0x3ffu) << 4u)),
    ) / 16383.0;
    let p = t.qmin + q * t.qsize;
    out.world = (t.model * vec4<f32>(p, 1.0)).xyz;
    let e = vec2<f32>(f32((w1 >> 10u) & 0xffu), f32((w1 >> 18u) & 0xffu)) / 127.5 - 1.0;
    out.openness = f32(w1 >> 26u) / 63.0;
    out.normal = normalize((t.model * vec4<f32>(octa_decode(e), 0.0)).xyz);
    let c = vec3<f32>(f32(w2 & 0xffu), f32((w2 >> 8u) & 0xffu), f32((w2 >> 16u) & 0xffu)) / 255.0;
    out.albedo = c * c;
    out.foliage = ((w2 >> 24u) & 1u) != 0u;
    let coverage = f32(w2 >> 25u) / 127.0;
    out.u = (p - t.vcm_min) * t.vcm_inv_size;
    out.local = p;
    let clip = frame.view_proj * vec4<f32>(out.world, 1.0);
    if clip.w <= 1e-4 {
        return out;
    }
    let ndc = clip.xyz / clip.w;
    if abs(ndc.x) >= 1.0 || abs(ndc.y) >= 1.0 || ndc.z <= 0.0 || ndc.z > 1.0 {
        return out;
    }
    let to_eye = frame.camera_pos - out.world;
    if !out.foliage && dot(out.normal, to_eye) < 0.0 {
        return out;
    }
    // Drawn with a chance, by a hash of the surfel and its tree (the same surfels every
    // frame), such that the k surfels of a surface that fall in one pixel leave it empty
    // with the chance the surface leaves it open: 1 - (1 - c)^(1/k), c its cell's share
    // covered, k the pixel's area over the cell's as seen at its angle (the cell lies
    // across the axis the normal leans on most). A cell wholly covered is always drawn.
    if sp.focal_px > 0.0 && coverage < 1.0 {
        let pixel = clip.w / sp.focal_px;
        let n = abs(out.normal);
        let slant = abs(dot(out.normal, to_eye)) / (length(to_eye) * max(max(n.x, max(n.y, n.z)), 0.3));
        let per_pixel = (spacing * spacing) / (pixel * pixel) * slant;
        let chance = 1.0 - pow(1.0 - coverage, per_pixel);
        if chance < hash01(i ^ (t.instance * 0x9e3779b9u)) {
            return out;
        }
    }
    let px = min(vec2<u32>((ndc.xy * vec2<f32>(0.5, -0.5) + 0.5) * vec2<f32>(sp.size)), sp.size - 1u);
    out.pixel = px.y * sp.size.x + px.x;
    out.distance = clip.w;
    out.ok = true;
    return out;
}

fn item_index(wg: vec3<u32>) -> u32 {
    return wg.x + wg.y * sp.row;
}

@compute @workgroup_size(64)
fn depth(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let k = item_index(wg);
    if k >= sp.items {
        return;
    }
    let item = items[k];
    let t = trees[item.tree];
    for (var j = lane; j < item.count; j += WG) {
        let s = place(t, item.first + j, item.spacing);
        if s.ok {
            atomicMin(&nearest[s.pixel], bitcast<u32>(s.distance));
        }
    }
}

// The LOD overlay's colour of level `l`.
fn level_color(l: u32) -> vec3<f32> {
    let c = array<vec3<f32>, 6>(
        vec3<f32>(0.9, 0.2, 0.2), vec3<f32>(0.9, 0.6, 0.1), vec3<f32>(0.8, 0.9, 0.1),
        vec3<f32>(0.2, 0.8, 0.3), vec3<f32>(0.2, 0.6, 0.9), vec3<f32>(0.6, 0.3, 0.9),
    );
    return c[l % 6u];
}

// The tree's own optical depth from `p` (tree frame) along the unit `dir`, a voxel a step
// through its density volume, from half a voxel out.
fn optical_depth(t: SurfelTreeGpu, p: vec3<f32>, dir: vec3<f32>) -> f32 {
    let dims = vec3<f32>(t.vol_dims);
    var x = (p - t.vol_origin) / t.vol_voxel + 0.5 * dir;
    var tau = 0.0;
    for (var k = 0u; k < 64u; k++) {
        if any(x < vec3<f32>(0.0)) || any(x >= dims) {
            break;
        }
        let v = vec3<u32>(x);
        tau += volumes[t.vol_offset + (v.z * t.vol_dims.y + v.y) * t.vol_dims.x + v.x];
        x += dir;
    }
    return tau * t.vol_voxel;
}

// A surfel lit as the geometry lights its surface (geometry.wgsl's `lit_by`), with the
// tree-level VCM factors for the sun and the sky (as `impostor` and `btf`'s tree level).
fn lit(t: SurfelTreeGpu, s: Placed, level: u32) -> vec3<f32> {
    var n = s.normal;
    let to_eye = frame.camera_pos - s.world;
    if s.foliage && dot(n, to_eye) < 0.0 {
        n = -n;
    }
    var sun_f = trilinear(t.vcm_direct[0], t.vcm_direct[1], s.u);
    var sky_f = trilinear(t.vcm_sky[0], t.vcm_sky[1], s.u);
    // The tree's own shadow: its extinction towards the sun, in the tree frame (the
    // model's rotation and uniform scale undone), and the sky it leaves open (baked).
    for (var k = 0u; k < select(0u, 1u, sp.self_shadow > 0.0); k++) {
        let m = mat3x3<f32>(t.model[0].xyz, t.model[1].xyz, t.model[2].xyz);
        let to_sun = normalize(transpose(m) * frame.sun_dir);
        sun_f *= exp(-sp.self_shadow * optical_depth(t, s.local, to_sun));
        sky_f *= pow(max(s.openness, 1e-3), sp.self_shadow);
    }
    let ndl = dot(n, frame.sun_dir);
    var direct = max(ndl, 0.0);
    if s.foliage {
        direct += 0.3 * max(-ndl, 0.0);
    }
    let sky_normal = select(n, sign(n.y + 1e-6) * n, s.foliage);
    let ambient = mix(frame.ground_ambient, frame.sky_ambient * sky_f, sky_normal.y * 0.5 + 0.5);
    let albedo = select(s.albedo, s.albedo * t.tint, s.foliage);
    var c = albedo * (frame.sun_color * direct * sun_f + ambient);
    if sp.mode == 1u {
        c = level_color(level);
    } else if sp.mode == 2u {
        c = vec3<f32>(sun_f);
    }
    return fog_and_exposure(c, 1.0, length(to_eye));
}

@compute @workgroup_size(64)
fn colour(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let k = item_index(wg);
    if k >= sp.items {
        return;
    }
    let item = items[k];
    let t = trees[item.tree];
    for (var j = lane; j < item.count; j += WG) {
        let s = place(t, item.first + j, item.spacing);
        if !s.ok {
            continue;
        }
        let front = bitcast<f32>(atomicLoad(&nearest[s.pixel]));
        if s.distance > front + item.tolerance {
            continue;
        }
        let px = vec2<u32>(s.pixel % sp.size.x, s.pixel / sp.size.x);
        if s.distance >= scene_distance(px) {
            continue;
        }
        let c = min(lit(t, s, item.level), vec3<f32>(64.0)) * SUM_SCALE;
        atomicAdd(&sums[4u * s.pixel], u32(c.x + 0.5));
        atomicAdd(&sums[4u * s.pixel + 1u], u32(c.y + 0.5));
        atomicAdd(&sums[4u * s.pixel + 2u], u32(c.z + 0.5));
        atomicAdd(&sums[4u * s.pixel + 3u], 1u);
    }
}

// A full-resolution pixel: its mean colour and 1 where covered, and its nearest distance.
fn full_pixel(x: u32, y: u32) -> array<vec4<f32>, 2> {
    let p = y * sp.size.x + x;
    let n = atomicLoad(&sums[4u * p + 3u]);
    if n == 0u {
        return array<vec4<f32>, 2>(vec4<f32>(0.0), vec4<f32>(FAR, 0.0, 0.0, 0.0));
    }
    let c = vec3<f32>(
        f32(atomicLoad(&sums[4u * p])),
        f32(atomicLoad(&sums[4u * p + 1u])),
        f32(atomicLoad(&sums[4u * p + 2u])),
    ) / (SUM_SCALE * f32(n));
    let d = bitcast<f32>(atomicLoad(&nearest[p]));
    return array<vec4<f32>, 2>(vec4<f32>(c, 1.0), vec4<f32>(d, 0.0, 0.0, 0.0));
}

// The coarser pixel of 4 finer ones: covered where any of them is (Grossman and Dally's
// clamped weights), the mean colour of the covered ones, the nearest distance.
fn pull4(a: array<array<vec4<f32>, 2>, 4>) -> array<vec4<f32>, 2> {
    var c = vec3<f32>(0.0);
    var w = 0.0;
    var d = FAR;
    for (var k = 0u; k < 4u; k++) {
        c += a[k][0].rgb * a[k][0].a;
        w += a[k][0].a;
        d = min(d, a[k][1].x);
    }
    return array<vec4<f32>, 2>(vec4<f32>(c / max(w, 1e-6), min(w, 1.0)), vec4<f32>(d, 0.0, 0.0, 0.0));
}

// Level 1 lives at `levels[2 * i]` (colour and coverage) and `levels[2 * i + 1]` (distance),
// i = y * half width + x; level 2 after it.
fn level2_base() -> u32 {
    return 2u * sp.half_size.x * sp.half_size.y;
}

fn level_at(level: u32, x: i32, y: i32) -> array<vec4<f32>, 2> {
    var size = sp.half_size;
    var base = 0u;
    if level == 2u {
        size = sp.quarter_size;
        base = level2_base();
    }
    if x < 0 || y < 0 || u32(x) >= size.x || u32(y) >= size.y {
        return array<vec4<f32>, 2>(vec4<f32>(0.0), vec4<f32>(FAR, 0.0, 0.0, 0.0));
    }
    let i = base + 2u * (u32(y) * size.x + u32(x));
    return array<vec4<f32>, 2>(levels[i], levels[i + 1u]);
}

fn full_at(x: i32, y: i32) -> array<vec4<f32>, 2> {
    if x < 0 || y < 0 || u32(x) >= sp.size.x || u32(y) >= sp.size.y {
        return array<vec4<f32>, 2>(vec4<f32>(0.0), vec4<f32>(FAR, 0.0, 0.0, 0.0));
    }
    return full_pixel(u32(x), u32(y));
}

@compute @workgroup_size(8, 8)
fn pull1(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= sp.half_size.x || id.y >= sp.half_size.y {
        return;
    }
    let x = 2 * i32(id.x);
    let y = 2 * i32(id.y);
    let v = pull4(array<array<vec4<f32>, 2>, 4>(
        full_at(x, y), full_at(x + 1, y), full_at(x, y + 1), full_at(x + 1, y + 1),
    ));
    let i = 2u * (id.y * sp.half_size.x + id.x);
    levels[i] = v[0];
    levels[i + 1u] = v[1];
}

@compute @workgroup_size(8, 8)
fn pull2(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= sp.quarter_size.x || id.y >= sp.quarter_size.y {
        return;
    }
    let x = 2 * i32(id.x);
    let y = 2 * i32(id.y);
    let v = pull4(array<array<vec4<f32>, 2>, 4>(
        level_at(1u, x, y), level_at(1u, x + 1, y), level_at(1u, x, y + 1), level_at(1u, x + 1, y + 1),
    ));
    let i = level2_base() + 2u * (id.y * sp.quarter_size.x + id.x);
    levels[i] = v[0];
    levels[i + 1u] = v[1];
}

// The 8 neighbours of a pixel.
const AROUND = array<vec2<i32>, 8>(
    vec2<i32>(-1, -1), vec2<i32>(0, -1), vec2<i32>(1, -1), vec2<i32>(-1, 0),
    vec2<i32>(1, 0), vec2<i32>(-1, 1), vec2<i32>(0, 1), vec2<i32>(1, 1),
);

// A hole of level 0: an empty pixel with at least 6 of its 8 neighbours covered takes their
// mean colour and their nearest distance (coverage 0 otherwise). An edge has fewer.
fn hole0(p: vec2<i32>) -> array<vec4<f32>, 2> {
    var c = vec3<f32>(0.0);
    var n = 0.0;
    var d = FAR;
    for (var k = 0u; k < 8u; k++) {
        let q = full_at(p.x + AROUND[k].x, p.y + AROUND[k].y);
        c += q[0].rgb * q[0].a;
        n += q[0].a;
        d = min(d, q[1].x);
    }
    if n < 6.0 {
        return array<vec4<f32>, 2>(vec4<f32>(0.0), vec4<f32>(FAR, 0.0, 0.0, 0.0));
    }
    return array<vec4<f32>, 2>(vec4<f32>(c / n, 1.0), vec4<f32>(d, 0.0, 0.0, 0.0));
}

// A coarser level's pixel, where it and at least 7 of its 8 neighbours are covered (inside
// a surface, not on its edge).
fn inside(level: u32, p: vec2<i32>) -> array<vec4<f32>, 2> {
    let own = level_at(level, p.x, p.y);
    var n = 0.0;
    for (var k = 0u; k < 8u; k++) {
        n += level_at(level, p.x + AROUND[k].x, p.y + AROUND[k].y)[0].a;
    }
    if own[0].a < 1.0 || n < 7.0 {
        return array<vec4<f32>, 2>(vec4<f32>(0.0), vec4<f32>(FAR, 0.0, 0.0, 0.0));
    }
    return own;
}

@compute @workgroup_size(8, 8)
fn push(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= sp.size.x || id.y >= sp.size.y {
        return;
    }
    var out = vec4<f32>(0.0);
    let own = full_pixel(id.x, id.y);
    if own[0].a > 0.0 {
        out = vec4<f32>(own[0].rgb, 1.0);
    } else if sp.fill != 0u && level_at(1u, i32(id.x / 2u), i32(id.y / 2u))[0].a > 0.0 {
        // (Where the half-resolution pixel over this one is empty, so are 3 of its 8
        // neighbours and the coarser levels there: nothing to fill.)
        let scene = scene_distance(id.xy);
        let p = vec2<i32>(id.xy);
        var fill = hole0(p);
        if fill[0].a < 1.0 && sp.fill >= 2u {
            fill = inside(1u, p / 2);
        }
        if fill[0].a < 1.0 && sp.fill >= 3u {
            fill = inside(2u, p / 4);
        }
        if fill[0].a >= 1.0 && fill[1].x < scene {
            out = vec4<f32>(fill[0].rgb, 1.0);
        }
    }
    textureStore(layer_out, vec2<i32>(id.xy), out);
}
