// The `btf` method's far trees on the GPU: every visible tree far enough to be drawn at the
// tree level alone (no cross-fade) gets its billboard record here, as `Pusher::push` in
// src/render/method/btf/prepare.rs makes it on the CPU: the sphere-box frustum test, the 3
// nearest view and light samples with their weights (descent through the subdivided
// octahedron, `DirectionSet::blend` in src/sphere.rs), image-weight culling, the light gain,
// the VCM factors read when the sun moved. Then a bitonic sort puts them back to front and
// a gather copies them in that order for one indirect draw. `billboard_record.wgsl` is
// prepended.

// One tree instance: `TreeGpu`'s model and tint, its species, its bounds in the world.
struct FarTree {
    model: mat4x4<f32>,
    tint: vec3<f32>,
    species: u32,
    bounds_min: vec3<f32>,
    _pad0: f32,
    bounds_max: vec3<f32>,
    _pad1: f32,
}

// A tree's tree-level VCM factors at its 8 box corners, read when the sun moved.
struct FarShade {
    direct: array<vec4<f32>, 2>,
    sky: array<vec4<f32>, 2>,
}

// Where a direction set's tables start in `tables` (in vec4 rows), and its size.
struct DirSet {
    level: u32,
    splits: u32,
    bary: u32,
    triangles: u32,
    directions: u32,
    count: u32,
    _pad0: u32,
    _pad1: u32,
}

struct FarParams {
    camera: vec3<f32>,
    // Trees in `trees`.
    count: u32,
    forward: vec3<f32>,
    plane_count: u32,
    to_sun: vec3<f32>,
    weight_threshold: f32,
    planes: array<vec4<f32>, 6>,
    // The overlay colour (`mode` != MODE_IMAGES) or unused.
    overlay: vec3<f32>,
    mode: u32,
    light_gain: f32,
    // 1 or 3 (crossed).
    plane_mode: u32,
    // 0: no VCM factors; 1: sun and sky; 2: the sun only.
    vcm: u32,
    // Rows of 3 per species in `tables`, from here.
    species: u32,
    views: DirSet,
    lights: DirSet,
    // Keys sorted: a power of two, at least `count + near_count`.
    sort_n: u32,
    // The near trees' billboards, made on the CPU, in `records` after the trees' slots.
    near_count: u32,
    // Most records `sorted` takes (the farthest are left out).
    limit: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: FarParams;
@group(0) @binding(1) var<storage, read> trees: array<FarTree>;
@group(0) @binding(2) var<storage, read> shades: array<FarShade>;
// Words: float bits, or indices (the triangles; the species' layer bases).
@group(0) @binding(3) var<storage, read> tables: array<vec4<u32>>;
// One bit per tree: set for the near trees, which the CPU prepares.
@group(0) @binding(4) var<storage, read> near_bits: array<u32>;
// One slot per tree (its record when it is far and in view), then the near trees'.
@group(0) @binding(5) var<storage, read_write> records: array<Billboard>;
// Per slot of `records` (padded to a power of two): (ordered depth, !slot), 0 for none;
// sorted in decreasing order, back to front.
@group(0) @binding(6) var<storage, read_write> keys: array<vec2<u32>>;
// The indirect draw: vertex count, instance count, first vertex, first instance; then the
// far billboards made.
@group(0) @binding(7) var<storage, read_write> draw_args: array<atomic<u32>, 8>;
@group(0) @binding(8) var<storage, read_write> sorted: array<Billboard>;

// One step of the bitonic sort: block size `k`, partner distance `j`.
struct SortStep {
    k: u32,
    j: u32,
    _pad0: u32,
    _pad1: u32,
}
@group(1) @binding(0) var<uniform> sort_at: SortStep;

const SNAP: f32 = 1e-6;
const MAX_LIGHT_GAIN: f32 = 2.0;

// glam's `normalize_or`: `v` over its length, or `fallback` where that is not finite.
fn normalize_or(v: vec3<f32>, fallback: vec3<f32>) -> vec3<f32> {
    let rcp = 1.0 / length(v);
    if rcp > 0.0 && rcp <= 3.4e38 {
        return v * rcp;
    }
    return fallback;
}

fn row(i: u32) -> vec4<f32> {
    return bitcast<vec4<f32>>(tables[i]);
}

fn row3(i: u32) -> vec3<f32> {
    return row(i).xyz;
}

// The triangle of the finest level holding `d` (`DirectionSet::locate`).
fn locate(ds: DirSet, d: vec3<f32>) -> u32 {
    var t = select(0u, 1u, d.x < 0.0) | select(0u, 2u, d.y < 0.0) | select(0u, 4u, d.z < 0.0);
    var offset = 0u;
    var count = 8u;
    for (var l = 0u; l < ds.level; l++) {
        let m = ds.splits + 3u * (offset + t);
        let r = vec3<f32>(dot(row3(m), d), dot(row3(m + 1u), d), dot(row3(m + 2u), d));
        let outside = select(0u, 1u, r.x < 0.0) | select(0u, 2u, r.y < 0.0) | select(0u, 4u, r.z < 0.0);
        t = 4u * t + ((0x1213u >> (2u * (outside & 7u))) & 3u);
        offset += count;
        count *= 4u;
    }
    return t;
}

struct Blend {
    index: vec3<u32>,
    weight: vec3<f32>,
}

// (weight, index) of slot a is above slot b's.
fn above(wa: f32, ia: u32, wb: f32, ib: u32) -> bool {
    return wa > wb || (wa == wb && ia > ib);
}

// `DirectionSet::blend`: the 3 samples around `d` with normalised barycentric weights, tiny
// ones snapped to 0, sorted by decreasing weight.
fn blend(ds: DirSet, d_in: vec3<f32>) -> Blend {
    var d = d_in;
    let m = max(abs(d.x), max(abs(d.y), abs(d.z)));
    if !(m >= 1e-15) || m > 3.4e38 {
        d = vec3<f32>(0.0, 1.0, 0.0);
    } else if m > 1e15 {
        d = d / m;
    }
    let t = locate(ds, d);
    let b = ds.bary + 3u * t;
    let raw = max(vec3<f32>(dot(row3(b), d), dot(row3(b + 1u), d), dot(row3(b + 2u), d)), vec3<f32>(0.0));
    let tri = tables[ds.triangles + t].xyz;
    let sum = raw.x + raw.y + raw.z;
    var w: vec3<f32>;
    if sum > 0.0 && sum <= 3.4e38 {
        w = raw / sum;
    } else if raw.x >= raw.y && raw.x >= raw.z {
        w = vec3<f32>(1.0, 0.0, 0.0);
    } else if raw.y >= raw.z {
        w = vec3<f32>(0.0, 1.0, 0.0);
    } else {
        w = vec3<f32>(0.0, 0.0, 1.0);
    }
    let small = w < vec3<f32>(SNAP);
    if any(small & (w > vec3<f32>(0.0))) {
        w = select(w, vec3<f32>(0.0), small);
        w /= w.x + w.y + w.z;
    }
    // Sort the three slots by decreasing (weight, index).
    var wi = array<f32, 3>(w.x, w.y, w.z);
    var ii = array<u32, 3>(tri.x, tri.y, tri.z);
    for (var a = 0u; a < 2u; a++) {
        for (var c = 0u; c < 2u - a; c++) {
            if above(wi[c + 1u], ii[c + 1u], wi[c], ii[c]) {
                let tw = wi[c];
                wi[c] = wi[c + 1u];
                wi[c + 1u] = tw;
                let ti = ii[c];
                ii[c] = ii[c + 1u];
                ii[c + 1u] = ti;
            }
        }
    }
    return Blend(vec3<u32>(ii[0], ii[1], ii[2]), vec3<f32>(wi[0], wi[1], wi[2]));
}

// `Blend::cull`: weights below `threshold` dropped (the largest kept), the rest renormalised.
fn cull(b: Blend, threshold: f32) -> Blend {
    let w = max(b.weight, vec3<f32>(0.0));
    var largest = 0u;
    if w.y > w[largest] {
        largest = 1u;
    }
    if w.z > w[largest] {
        largest = 2u;
    }
    var keep = w >= vec3<f32>(threshold);
    keep[largest] = true;
    if all(keep) {
        return b;
    }
    let kept = select(vec3<f32>(0.0), w, keep);
    let sum = kept.x + kept.y + kept.z;
    var out = b;
    if sum > 0.0 && sum <= 3.4e38 {
        out.weight = kept / sum;
    } else {
        out.weight = vec3<f32>(0.0);
        out.weight[largest] = 1.0;
    }
    return out;
}

// `DirectionSet::light_gain`: how much the blend must be brightened to light like `d`.
fn light_gain(ds: DirSet, b: Blend, d_in: vec3<f32>) -> f32 {
    let d = normalize_or(d_in, vec3<f32>(0.0));
    var sum = vec3<f32>(0.0);
    for (var i = 0u; i < 3u; i++) {
        sum += row3(ds.directions + b.index[i]) * b.weight[i];
    }
    let along = dot(sum, d);
    if along > 0.0 && along <= 3.4e38 {
        return clamp(1.0 / along, 1.0, MAX_LIGHT_GAIN);
    }
    return 1.0;
}

// `billboard_axes` in src/sphere.rs: the image axes (right, up) seen from `view`.
fn billboard_axes(view: vec3<f32>) -> array<vec3<f32>, 2> {
    let v = normalize_or(view, vec3<f32>(0.0, 0.0, 1.0));
    var hint = vec3<f32>(0.0, 1.0, 0.0);
    if abs(v.y) > 0.999 {
        hint = vec3<f32>(0.0, 0.0, 1.0);
    }
    let right = normalize_or(cross(hint, v), vec3<f32>(1.0, 0.0, 0.0));
    let up = normalize_or(cross(v, right), vec3<f32>(0.0, 1.0, 0.0));
    return array<vec3<f32>, 2>(right, up);
}

// A float's bits, ordered as the floats are.
fn ordered(f: f32) -> u32 {
    let b = bitcast<u32>(f);
    if (b & 0x80000000u) != 0u {
        return ~b;
    }
    return b | 0x80000000u;
}

@compute @workgroup_size(64)
fn build(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.count {
        return;
    }
    if ((near_bits[i / 32u] >> (i % 32u)) & 1u) != 0u {
        return;
    }
    let tree = trees[i];
    // The tree's bounds, then its billboard's sphere, against each plane
    // (`Frustum::intersects`), as the CPU culls then builds.
    for (var p = 0u; p < params.plane_count; p++) {
        let pl = params.planes[p];
        let corner = select(tree.bounds_min, tree.bounds_max, pl.xyz >= vec3<f32>(0.0));
        if dot(pl.xyz, corner) + pl.w < 0.0 {
            return;
        }
    }
    let m = tree.model;
    let scale = length(m[0].xyz);
    if !(scale > 0.0 && scale <= 3.4e38) {
        return;
    }
    let s = params.species + 3u * tree.species;
    let set_center = row3(s);
    let set_radius = row(s).w;
    let center = (m * vec4<f32>(set_center, 1.0)).xyz;
    let radius = set_radius * scale;
    for (var p = 0u; p < params.plane_count; p++) {
        let pl = params.planes[p];
        let corner = select(center - vec3<f32>(radius), center + vec3<f32>(radius), pl.xyz >= vec3<f32>(0.0));
        if dot(pl.xyz, corner) + pl.w < 0.0 {
            return;
        }
    }
    let rot = mat3x3<f32>(m[0].xyz, m[1].xyz, m[2].xyz) * (1.0 / scale);
    let to_object = transpose(rot);
    let v_obj = to_object * normalize_or(params.camera - center, vec3<f32>(0.0, 1.0, 0.0));
    let l_obj = to_object * params.to_sun;
    let vb = cull(blend(params.views, v_obj), params.weight_threshold);
    var lb = cull(blend(params.lights, l_obj), params.weight_threshold);
    let strength = clamp(params.light_gain, 0.0, 1.0);
    if strength > 0.0 {
        lb.weight *= pow(light_gain(params.lights, lb, l_obj), strength);
    }
    let axes = billboard_axes(v_obj);
    var r: Billboard;
    r.center = center;
    r.radius = radius;
    r.plane_right = normalize_or(rot * axes[0], vec3<f32>(1.0, 0.0, 0.0));
    r.planes = params.plane_mode;
    r.plane_up = normalize_or(rot * axes[1], vec3<f32>(0.0, 1.0, 0.0));
    r.opacity = 1.0;
    r.obj_right = axes[0];
    r._pad0 = 0.0;
    r.obj_up = axes[1];
    r._pad1 = 0.0;
    r.view_index = vb.index;
    r.layer_base = tables[s + 1u].w;
    r.light_index = lb.index;
    r.light_count = params.lights.count;
    r.view_weight = vb.weight;
    r.view_count = params.views.count;
    r.light_weight = lb.weight;
    r._pad2 = 0.0;
    r.tint = tree.tint;
    r.mode = params.mode;
    if params.mode != MODE_IMAGES {
        r.tint = params.overlay;
    }
    r.vcm_box_origin = row3(s + 1u);
    r.parent_direct = 1.0;
    r.vcm_box_scale = row3(s + 2u);
    r.parent_sky = 1.0;
    r.vcm_direct = array<vec4<f32>, 2>(vec4<f32>(1.0), vec4<f32>(1.0));
    r.vcm_sky = array<vec4<f32>, 2>(vec4<f32>(1.0), vec4<f32>(1.0));
    if params.vcm != 0u {
        let sh = shades[i];
        r.vcm_direct = sh.direct;
        if params.vcm == 1u {
            r.vcm_sky = sh.sky;
        }
    }
    records[i] = r;
    keys[i] = vec2<u32>(ordered(dot(center - params.camera, params.forward)), ~i);
    atomicAdd(&draw_args[4], 1u);
}

// The near trees' records (made on the CPU, after the trees' slots) get their keys.
@compute @workgroup_size(64)
fn near_keys(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.near_count {
        return;
    }
    let slot = params.count + gid.x;
    keys[slot] = vec2<u32>(ordered(dot(records[slot].center - params.camera, params.forward)), ~slot);
}

// One compare-exchange step of a bitonic sort over all of `keys`, into decreasing order.
@compute @workgroup_size(64)
fn sort_step(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let l = i ^ sort_at.j;
    if i >= params.sort_n || l <= i {
        return;
    }
    let a = keys[i];
    let b = keys[l];
    let a_less = a.x < b.x || (a.x == b.x && a.y < b.y);
    // Blocks with bit k clear end up decreasing, the others increasing; the last merge
    // (k past the array) is all decreasing.
    let decreasing = (i & sort_at.k) == 0u;
    if a_less == decreasing {
        keys[i] = b;
        keys[l] = a;
    }
}

// Every record made, far and near.
fn made() -> u32 {
    return atomicLoad(&draw_args[4]) + params.near_count;
}

// The records in sorted order, for the draw; past `limit`, the farthest are left out.
@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let total = made();
    let skip = select(0u, total - params.limit, total > params.limit);
    if i >= total || i < skip {
        return;
    }
    sorted[i - skip] = records[~keys[i].y];
}

// The draw's instance count.
@compute @workgroup_size(1)
fn finish() {
    atomicStore(&draw_args[1], min(made(), params.limit));
}
