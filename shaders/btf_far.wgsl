// The `btf` method's far trees on the GPU: every visible tree far enough to be drawn at the
// tree level alone (no cross-fade) gets its billboard record here, as `Pusher::push` in
// src/render/method/btf/prepare/ makes it on the CPU: the sphere-box frustum test, the 3
// nearest view and light samples with their weights (descent through the subdivided
// octahedron, `DirectionSet::blend` in src/sphere/blend.rs), image-weight culling, the
// light gain, the VCM factors read when the sun moved. Then a bitonic sort puts them back
// to front and a gather copies them in that order for one indirect draw.
// `billboard_record.wgsl` is prepended, `btf_far_canopy.wgsl` appended.
//
// Over 800 lines: every entry point shares the tree records, the tables, the sort keys and
// the bindings declared here (mirrored by src/render/method/btf/far/gpu_types.rs), and
// WGSL has no include to split them across files without prepending each part to every
// module (as `billboard_record.wgsl` is).

// One tree instance: `TreeGpu`'s model and tint, its species, its bounds in the world (7
// rows of `tables`, from `params.trees_at`).
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
    // Trees (at `trees_at` in `tables`).
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
    // Texels on a side of a cube map's face.
    vcm_res: u32,
    // The twig and main-branch levels' overlay colours; the near draws expanded here.
    overlay_twig: vec3<f32>,
    near_draws: u32,
    overlay_branch: vec3<f32>,
    // Slots of the billboards of those draws, after the near records.
    near_slots: u32,
    views_twig: DirSet,
    views_branch: DirSet,
    // Where the near draws start in `frame_words`, in words.
    draws_at: u32,
    // Where the near bits start in `frame_words`, in words (the shades start at 0).
    bits_at: u32,
    // Where the trees start in `tables`, in rows (7 a tree).
    trees_at: u32,
    // Slots of `near_records`; the near slots past them are in `near_records_b`.
    near_room: u32,
    // Yaw bins of the light blends (`light_blend.wgsl`) the tree level reads; 0: none, each
    // tree-level billboard blends its light images itself.
    light_bins: u32,
    // The first light-blended image in the BTF atlas (prototype 0, bin 0, view 0).
    light_blend_first: u32,
    // The far canopy (btf_far_canopy.wgsl, canopy.wgsl): trees from `canopy_near` (m, to
    // their bounds' centre) fade out by `canopy_far`, past which the canopy alone stands
    // for them; 0 and 0: no canopy.
    canopy_near: f32,
    canopy_far: f32,
    // The frame's lights (colour x intensity), which the canopy's colours are lit by.
    sun_color: vec3<f32>,
    // Where each BTF image's mean starts in `tables` (one row an image).
    means_at: u32,
    sky_ambient: vec3<f32>,
    // Batches the billboards are drawn in, front to back, for the trees' layer (0: one
    // draw, back to front).
    layer_batches: u32,
    ground_ambient: vec3<f32>,
    // The word of `draw_args` that counts the keys made this frame.
    sort_args_at: u32,
}

// A storage buffer, not a uniform one: lavapipe (Mesa 22) compiles a shader again at every
// bind, and keeps each compilation, where inlining a uniform buffer's values into its
// branches removes half of it (tests/frame_memory.rs).
@group(0) @binding(0) var<storage, read> params: FarParams;
// The near trees' billboards expanded by `near_build`, one slot per part of each draw: the
// first `params.near_room` slots here, the rest in the second binding (one binding holds
// 524,288 records on lavapipe, fewer than a large frame's near parts).
@group(0) @binding(1) var<storage, read_write> near_records_b: array<Billboard>;
@group(0) @binding(2) var<storage, read_write> near_records: array<Billboard>;
// Words: float bits, or indices (the triangles; the species' layer bases); then the
// species' part transforms, their cube maps' objects and the maps' bytes; then the trees.
@group(0) @binding(3) var<storage, read> tables: array<vec4<u32>>;
// Each tree's `FarShade` (16 words, from 0); at `params.bits_at` one bit per tree, set for
// the near trees, which the CPU prepares (or hands over as `NearDraw`s, at
// `params.draws_at`).
@group(0) @binding(4) var<storage, read> frame_words: array<u32>;
// One slot per tree (its record when it is far and in view), then the near trees' made on
// the CPU. (A key's slot past those is `near_records`' slot after them.)
@group(0) @binding(5) var<storage, read_write> records: array<Billboard>;
// One key per record made, (ordered depth, !slot), packed at the start as they are made
// (room for every slot, padded to a power of two, 0 past those made); sorted in decreasing
// order, back to front.
@group(0) @binding(6) var<storage, read_write> keys: array<vec2<u32>>;
// The indirect draw: vertex count, instance count, first vertex, first instance; then the
// far billboards made, and the near ones expanded here per level (twig, branch, tree);
// then the image fetches of every billboard made here, and those image-weight culling saved;
// then the billboards made here that read the light blends; then the trees in view past
// the far canopy's band (drawn by the canopy alone); then each layer batch's indirect draw
// (4 words); then the keys made (`params.sort_args_at`).
@group(0) @binding(7) var<storage, read_write> draw_args: array<atomic<u32>>;
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
// Per view a billboard samples its lights' images and 2 more (`AMBIENT_IMAGES_PER_VIEW` in
// src/format.rs); at most 3 views x (3 lights + 2) (`FETCHES_AT_MOST`).
const AMBIENT_IMAGES: u32 = 2u;
const FETCHES_AT_MOST: u32 = 15u;
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

fn tree_at(i: u32) -> FarTree {
    let r = params.trees_at + 7u * i;
    return FarTree(
        mat4x4<f32>(row(r), row(r + 1u), row(r + 2u), row(r + 3u)),
        row3(r + 4u),
        tables[r + 4u].w,
        row3(r + 5u),
        0.0,
        row3(r + 6u),
        0.0,
    );
}

// Near slot `s`, in whichever binding holds it.
fn put_near(s: u32, r: Billboard) {
    if s < params.near_room {
        near_records[s] = r;
    } else {
        near_records_b[s - params.near_room] = r;
    }
}

fn near_at(s: u32) -> Billboard {
    if s < params.near_room {
        return near_records[s];
    }
    return near_records_b[s - params.near_room];
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

// `billboard_axes` in src/sphere/billboard.rs: the image axes (right, up) seen from `view`.
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

// Rows per species in `tables` from `params.species`: per level (twig, branch, tree) 3
// rows (the set's centre and radius; its VCM box origin and first layer; its VCM box scale);
// then (main branches, twigs per main branch, twigs on the trunk, first row of their
// transforms); (first row of the main branches' cube-map objects, of the twigs'); the
// tree's and the main branch's VCM boxes (min, max); the main branch's and the twig's
// billboard centres. A transform takes 4 rows (its columns); an object 3 (the row where its
// 8 maps' bytes start, or NO_MAP; its sky visibility at the 8 corners).
const SPECIES_ROWS: u32 = 17u;
const NO_MAP: u32 = 0xffffffffu;
const LEVEL_TWIG: u32 = 0u;
const LEVEL_BRANCH: u32 = 1u;
const LEVEL_TREE: u32 = 2u;

fn species_row(sp: u32) -> u32 {
    return params.species + SPECIES_ROWS * sp;
}

// The first of level `level`'s 3 set rows of species `sp`.
fn set_row(sp: u32, level: u32) -> u32 {
    return species_row(sp) + 3u * level;
}

fn transform(r: u32) -> mat4x4<f32> {
    return mat4x4<f32>(row(r), row(r + 1u), row(r + 2u), row(r + 3u));
}

const TAU: f32 = 6.283185307179586;

// `yaw_bin` in src/render/method/btf/light_blend.rs: the yaw bin of the sun's direction
// `l_obj` in an object's frame (its azimuth about the object's up axis, from the sun's
// own, in `params.light_bins` steps).
fn yaw_bin(l_obj: vec3<f32>) -> u32 {
    let bins = i32(params.light_bins);
    let a = atan2(l_obj.z, l_obj.x) - atan2(params.to_sun.z, params.to_sun.x);
    let b = i32(round(a / TAU * f32(bins)));
    return u32(((b % bins) + bins) % bins);
}

// `bin_direction`: the sun in the frame of an object of yaw bin `b` (its elevation kept).
fn bin_direction(b: u32) -> vec3<f32> {
    let s = params.to_sun;
    let phi = atan2(s.z, s.x) + TAU * f32(b) / f32(params.light_bins);
    let h = length(s.xz);
    return vec3<f32>(h * cos(phi), s.y, h * sin(phi));
}

// The record of a billboard of the set at rows `set` placed by `m`, as `Pusher::push`
// makes it (opacity 1, the tree's tint, no VCM factors); `planes` 0 when it is out of
// view or `m` has no valid scale. `blend_sp`: the species of a tree-level billboard, whose
// light images are blended once per yaw bin when `params.light_bins` > 0 (else u32 max).
fn make_record(m: mat4x4<f32>, set_at: u32, views: DirSet, tint: vec3<f32>, blend_sp: u32) -> Billboard {
    var r: Billboard;
    r.planes = 0u;
    let scale = length(m[0].xyz);
    if !(scale > 0.0 && scale <= 3.4e38) {
        return r;
    }
    let center = (m * vec4<f32>(row3(set_at), 1.0)).xyz;
    let radius = row(set_at).w * scale;
    for (var p = 0u; p < params.plane_count; p++) {
        let pl = params.planes[p];
        let corner = select(center - vec3<f32>(radius), center + vec3<f32>(radius), pl.xyz >= vec3<f32>(0.0));
        if dot(pl.xyz, corner) + pl.w < 0.0 {
            return r;
        }
    }
    let rot = mat3x3<f32>(m[0].xyz, m[1].xyz, m[2].xyz) * (1.0 / scale);
    let to_object = transpose(rot);
    let v_obj = to_object * normalize_or(params.camera - center, vec3<f32>(0.0, 1.0, 0.0));
    var l_obj = to_object * params.to_sun;
    var light_blend = NO_LIGHT_BLEND;
    if params.light_bins > 0u && blend_sp != 0xffffffffu {
        let bin = yaw_bin(l_obj);
        l_obj = bin_direction(bin);
        light_blend = params.light_blend_first + (blend_sp * params.light_bins + bin) * views.count;
    }
    let vb = cull(blend(views, v_obj), params.weight_threshold);
    var lb = cull(blend(params.lights, l_obj), params.weight_threshold);
    let strength = clamp(params.light_gain, 0.0, 1.0);
    if strength > 0.0 {
        lb.weight *= pow(light_gain(params.lights, lb, l_obj), strength);
    }
    let axes = billboard_axes(v_obj);
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
    r.layer_base = tables[set_at + 1u].w;
    r.light_index = lb.index;
    r.light_count = params.lights.count;
    r.view_weight = vb.weight;
    r.view_count = views.count;
    r.light_weight = lb.weight;
    r.light_blend = light_blend;
    r.tint = tint;
    r.mode = params.mode;
    r.vcm_box_origin = row3(set_at + 1u);
    r.parent_direct = 1.0;
    r.vcm_box_scale = row3(set_at + 2u);
    r.parent_sky = 1.0;
    r.vcm_direct = array<vec4<f32>, 2>(vec4<f32>(1.0), vec4<f32>(1.0));
    r.vcm_sky = array<vec4<f32>, 2>(vec4<f32>(1.0), vec4<f32>(1.0));
    // The image fetches per pixel, as the CPU counts them.
    let views_used = dot(vec3<u32>(vb.weight > vec3<f32>(0.0)), vec3<u32>(1u));
    var lights_used = dot(vec3<u32>(lb.weight > vec3<f32>(0.0)), vec3<u32>(1u));
    if light_blend != NO_LIGHT_BLEND {
        lights_used = 1u;
    }
    let fetches = views_used * (lights_used + AMBIENT_IMAGES);
    atomicAdd(&draw_args[8], fetches);
    if light_blend != NO_LIGHT_BLEND {
        atomicAdd(&draw_args[10], 1u);
    }
    atomicAdd(&draw_args[9], FETCHES_AT_MOST - min(fetches, FETCHES_AT_MOST));
    return r;
}

// Whether the tree's bounds meet the view (`Frustum::intersects`).
fn in_view(tree: FarTree) -> bool {
    for (var p = 0u; p < params.plane_count; p++) {
        let pl = params.planes[p];
        let corner = select(tree.bounds_min, tree.bounds_max, pl.xyz >= vec3<f32>(0.0));
        if dot(pl.xyz, corner) + pl.w < 0.0 {
            return false;
        }
    }
    return true;
}

// Tree `t`'s VCM factors, at the start of `frame_words`.
fn shade_of(t: u32) -> FarShade {
    let at = 16u * t;
    var w: array<f32, 16>;
    for (var k = 0u; k < 16u; k++) {
        w[k] = bitcast<f32>(frame_words[at + k]);
    }
    return FarShade(
        array<vec4<f32>, 2>(vec4<f32>(w[0], w[1], w[2], w[3]), vec4<f32>(w[4], w[5], w[6], w[7])),
        array<vec4<f32>, 2>(vec4<f32>(w[8], w[9], w[10], w[11]), vec4<f32>(w[12], w[13], w[14], w[15])),
    );
}

// The record's key: (ordered depth, !slot).
fn key_of(r: Billboard, slot: u32) -> vec2<u32> {
    return vec2<u32>(ordered(dot(r.center - params.camera, params.forward)), ~slot);
}

@compute @workgroup_size(64)
fn build(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.count {
        return;
    }
    if ((frame_words[params.bits_at + i / 32u] >> (i % 32u)) & 1u) != 0u {
        return;
    }
    let tree = tree_at(i);
    // Past the canopy's near distance the tree fades out, and the canopy takes its colour
    // (whether in view or not: a coarse canopy texel may show it from outside).
    var fade = 1.0;
    if params.canopy_far > 0.0 {
        let d = distance(params.camera, 0.5 * (tree.bounds_min + tree.bounds_max));
        if d > params.canopy_near {
            canopy_colour(i, tree);
        }
        if d >= params.canopy_far {
            if in_view(tree) {
                atomicAdd(&draw_args[11], 1u);
            }
            return;
        }
        fade = 1.0 - smoothstep(params.canopy_near, params.canopy_far, d);
    }
    // The tree's bounds, then its billboard's sphere, against each plane
    // (`Frustum::intersects`), as the CPU culls then builds.
    if !in_view(tree) {
        return;
    }
    var tint = tree.tint;
    if params.mode != MODE_IMAGES {
        tint = params.overlay;
    }
    var r = make_record(tree.model, set_row(tree.species, LEVEL_TREE), params.views, tint, tree.species);
    if r.planes == 0u {
        return;
    }
    r.opacity = fade;
    if params.vcm != 0u {
        let sh = shade_of(i);
        r.vcm_direct = sh.direct;
        if params.vcm == 1u {
            r.vcm_sky = sh.sky;
        }
    }
    records[i] = r;
    keys[next_key()] = key_of(r, i);
    atomicAdd(&draw_args[4], 1u);
}

// One byte of the cube-map data starting at row `map`, as opacity.
fn map_byte(map: u32, byte: u32) -> f32 {
    let word = byte / 4u;
    let w = tables[map + word / 4u][word % 4u];
    return f32((w >> (8u * (byte % 4u))) & 0xffu) / 255.0;
}

// `vcm::sample`: the opacity of corner `corner`'s cube map (of the maps at row `map`) in
// direction `dir`, bilinear inside the face, clamped at its edges; 0 for a zero direction.
fn cube_sample(map: u32, corner: u32, dir: vec3<f32>) -> f32 {
    let a = abs(dir);
    var axis = 2u;
    if a.x >= a.y && a.x >= a.z {
        axis = 0u;
    } else if a.y >= a.z {
        axis = 1u;
    }
    let m = a[axis];
    if !(m > 0.0) {
        return 0.0;
    }
    let face = 2u * axis + select(0u, 1u, dir[axis] < 0.0);
    let x = dir[(axis + 1u) % 3u] / m;
    let y = dir[(axis + 2u) % 3u] / m;
    let res = params.vcm_res;
    let last = f32(res - 1u);
    let fx = clamp((x + 1.0) * 0.5 * f32(res) - 0.5, 0.0, last);
    let fy = clamp((y + 1.0) * 0.5 * f32(res) - 0.5, 0.0, last);
    let i0 = u32(fx);
    let j0 = u32(fy);
    let i1 = min(i0 + 1u, res - 1u);
    let j1 = min(j0 + 1u, res - 1u);
    let u = fx - f32(i0);
    let v = fy - f32(j0);
    let base = (corner * 6u + face) * res * res;
    let a00 = map_byte(map, base + j0 * res + i0);
    let a10 = map_byte(map, base + j0 * res + i1);
    let a01 = map_byte(map, base + j1 * res + i0);
    let a11 = map_byte(map, base + j1 * res + i1);
    let top = a00 + (a10 - a00) * u;
    let bottom = a01 + (a11 - a01) * u;
    return top + (bottom - top) * v;
}

// Sun visibility (1 - opacity) at the 8 corners of the object at row `obj`, towards `dir`
// in its frame (1 without maps).
fn object_direct(obj: u32, dir: vec3<f32>) -> array<f32, 8> {
    var out: array<f32, 8>;
    let map = tables[obj].x;
    for (var k = 0u; k < 8u; k++) {
        out[k] = 1.0;
        if map != NO_MAP {
            out[k] = 1.0 - cube_sample(map, k, dir);
        }
    }
    return out;
}

fn object_sky(obj: u32) -> array<f32, 8> {
    let a = row(obj + 1u);
    let b = row(obj + 2u);
    return array<f32, 8>(a.x, a.y, a.z, a.w, b.x, b.y, b.z, b.w);
}

fn corners(v: array<vec4<f32>, 2>) -> array<f32, 8> {
    return array<f32, 8>(v[0].x, v[0].y, v[0].z, v[0].w, v[1].x, v[1].y, v[1].z, v[1].w);
}

fn pack8(v: array<f32, 8>) -> array<vec4<f32>, 2> {
    return array<vec4<f32>, 2>(vec4<f32>(v[0], v[1], v[2], v[3]), vec4<f32>(v[4], v[5], v[6], v[7]));
}

fn lerp1(a: f32, b: f32, t: f32) -> f32 {
    return a + (b - a) * t;
}

// `vcm::trilinear` of the corner values at `p` in the box at rows `bounds` (min, max): its
// box coordinates (`vcm::box_coords`), clamped to the box.
fn trilinear_at(v: array<f32, 8>, bounds: u32, p: vec3<f32>) -> f32 {
    let lo = row3(bounds);
    let hi = row3(bounds + 1u);
    let u = clamp((p - lo) / max(hi - lo, vec3<f32>(1e-6)), vec3<f32>(0.0), vec3<f32>(1.0));
    let x00 = lerp1(v[0], v[1], u.x);
    let x10 = lerp1(v[2], v[3], u.x);
    let x01 = lerp1(v[4], v[5], u.x);
    let x11 = lerp1(v[6], v[7], u.x);
    return lerp1(lerp1(x00, x10, u.y), lerp1(x01, x11, u.y), u.z);
}

// The unit `d` in the frame of a part whose transform is `m` (`TreeShading`'s frames).
fn into_frame(m: mat4x4<f32>, d: vec3<f32>) -> vec3<f32> {
    let scale = max(length(m[0].xyz), 1e-12);
    let rot = mat3x3<f32>(m[0].xyz, m[1].xyz, m[2].xyz) * (1.0 / scale);
    return normalize_or(transpose(rot) * d, vec3<f32>(0.0, 1.0, 0.0));
}

// A near tree's level to expand here: its billboards take the near slots from `first`.
struct NearDraw {
    tree: u32,
    level: u32,
    opacity: f32,
    first: u32,
}

fn near_draw(d: u32) -> NearDraw {
    let at = params.draws_at + 4u * d;
    return NearDraw(frame_words[at], frame_words[at + 1u], bitcast<f32>(frame_words[at + 2u]), frame_words[at + 3u]);
}

// One billboard of a near tree's level, as `expand` and `Pusher::push` make it on the CPU:
// the level's parts in order (the tree; its main branches, then the trunk's twigs; every
// main branch's twigs, branch by branch, then the trunk's), shaded as `TreeShading` does.
@compute @workgroup_size(64)
fn near_build(@builtin(global_invocation_id) gid: vec3<u32>) {
    let s = gid.x;
    if s >= params.near_slots || params.near_draws == 0u {
        return;
    }
    // The last draw starting at or before `s`.
    var lo = 0u;
    var hi = params.near_draws;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if frame_words[params.draws_at + 4u * mid + 3u] <= s {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let draw = near_draw(lo);
    if draw.tree >= params.count || s < draw.first {
        return;
    }
    let tree = tree_at(draw.tree);
    let sp = tree.species;
    let h = species_row(sp);
    let counts = tables[h + 9u];
    let branches = counts.x;
    let per_branch = counts.y;
    let trunk = counts.z;
    let mats = counts.w;
    let objects = tables[h + 10u];
    let k = s - draw.first;
    // The part: its transform in the tree frame, its set's level, and which it is.
    var part = mat4x4<f32>(vec4<f32>(1.0, 0.0, 0.0, 0.0), vec4<f32>(0.0, 1.0, 0.0, 0.0), vec4<f32>(0.0, 0.0, 1.0, 0.0), vec4<f32>(0.0, 0.0, 0.0, 1.0));
    var level = LEVEL_TREE;
    // The main branch it is (on), or none; the twig object it is, or none.
    var branch = NO_MAP;
    var twig = NO_MAP;
    var trunk_at = NO_MAP;
    if draw.level == LEVEL_BRANCH {
        if k < branches {
            branch = k;
            level = LEVEL_BRANCH;
            part = transform(mats + 4u * k);
        } else {
            trunk_at = k - branches;
        }
    } else if draw.level == LEVEL_TWIG {
        if k < branches * per_branch {
            branch = k / per_branch;
            twig = k % per_branch;
            level = LEVEL_TWIG;
            part = transform(mats + 4u * branch) * transform(mats + 4u * (branches + twig));
        } else {
            trunk_at = k - branches * per_branch;
        }
    } else if k != 0u {
        return;
    }
    if trunk_at != NO_MAP {
        if trunk_at >= trunk {
            return;
        }
        twig = per_branch + trunk_at;
        level = LEVEL_TWIG;
        part = transform(mats + 4u * (branches + per_branch + trunk_at));
    }
    // The overlay is the draw's level's (a main-branch draw's trunk twigs take the main
    // branch's colour, as on the CPU).
    var tint = tree.tint;
    if params.mode != MODE_IMAGES {
        if draw.level == LEVEL_TWIG {
            tint = params.overlay_twig;
        } else if draw.level == LEVEL_BRANCH {
            tint = params.overlay_branch;
        } else {
            tint = params.overlay;
        }
    }
    var views = params.views;
    if level == LEVEL_TWIG {
        views = params.views_twig;
    } else if level == LEVEL_BRANCH {
        views = params.views_branch;
    }
    let set_at = set_row(sp, level);
    let blend_sp = select(0xffffffffu, sp, level == LEVEL_TREE);
    var r = make_record(tree.model * part, set_at, views, tint, blend_sp);
    if r.planes == 0u {
        return;
    }
    r.opacity = draw.opacity;
    if params.vcm != 0u {
        let sh = shade_of(draw.tree);
        let tree_direct = corners(sh.direct);
        let tree_sky = corners(sh.sky);
        var direct = tree_direct;
        var sky = tree_sky;
        var parent_direct = 1.0;
        var parent_sky = 1.0;
        if level != LEVEL_TREE {
            let sun_tree = into_frame(tree.model, params.to_sun);
            let tree_box = h + 11u;
            let branch_box = h + 13u;
            let branch_centre = row3(h + 15u);
            let twig_centre = row3(h + 16u);
            if branch == NO_MAP || twig == NO_MAP {
                // A main branch (c per pixel) or a twig on the trunk (b per pixel), in the
                // tree frame: d at its centre.
                var obj = objects.x + 3u * branch;
                var centre = branch_centre;
                if branch == NO_MAP {
                    obj = objects.y + 3u * twig;
                    centre = twig_centre;
                }
                direct = object_direct(obj, sun_tree);
                sky = object_sky(obj);
                let placed = (part * vec4<f32>(centre, 1.0)).xyz;
                parent_direct = trilinear_at(tree_direct, tree_box, placed);
                parent_sky = trilinear_at(tree_sky, tree_box, placed);
            } else {
                // A main branch's twig: b per pixel, c·d at its centre.
                let branch_m = transform(mats + 4u * branch);
                let branch_obj = objects.x + 3u * branch;
                let c = object_direct(branch_obj, sun_tree);
                let c_sky = object_sky(branch_obj);
                let obj = objects.y + 3u * twig;
                direct = object_direct(obj, into_frame(branch_m, sun_tree));
                sky = object_sky(obj);
                let in_branch = (transform(mats + 4u * (branches + twig)) * vec4<f32>(twig_centre, 1.0)).xyz;
                let in_tree = (branch_m * vec4<f32>(in_branch, 1.0)).xyz;
                parent_direct = trilinear_at(c, branch_box, in_branch) * trilinear_at(tree_direct, tree_box, in_tree);
                parent_sky = trilinear_at(c_sky, branch_box, in_branch) * trilinear_at(tree_sky, tree_box, in_tree);
            }
        }
        r.vcm_direct = pack8(direct);
        r.parent_direct = parent_direct;
        if params.vcm == 1u {
            r.vcm_sky = pack8(sky);
            r.parent_sky = parent_sky;
        }
    }
    put_near(s, r);
    let slot = params.count + params.near_count + s;
    keys[next_key()] = key_of(r, slot);
    atomicAdd(&draw_args[5u + level], 1u);
}

// The near trees' records (made on the CPU, after the trees' slots) get their keys.
@compute @workgroup_size(64)
fn near_keys(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.near_count {
        return;
    }
    let slot = params.count + gid.x;
    keys[next_key()] = key_of(records[slot], slot);
}

// Where the next key goes: the keys are packed at the start of `keys`, in any order (the
// sort orders them by (depth, slot), whatever order they came in).
fn next_key() -> u32 {
    return atomicAdd(&draw_args[params.sort_args_at], 1u);
}

// The sort's dispatch arguments, 3 words a step (its own bind group: a buffer read as
// dispatch arguments cannot be bound for writing in the same dispatch).
@group(1) @binding(1) var<storage, read_write> sort_args: array<u32>;

// The sort's dispatches for the keys made: n, the next power of two, needs only the steps
// of the network for n keys (with k <= n), each over n keys. The later steps get no
// workgroups: the first n keys already run in decreasing order, the rest are zero.
@compute @workgroup_size(1)
fn sort_plan() {
    let made = atomicLoad(&draw_args[params.sort_args_at]);
    var n = 2u;
    while n < made && n < params.sort_n {
        n *= 2u;
    }
    var at = 0u;
    for (var k = 2u; k <= params.sort_n; k *= 2u) {
        for (var j = k / 2u; j > 0u; j /= 2u) {
            sort_args[at] = select(0u, (n + 63u) / 64u, k <= n);
            sort_args[at + 1u] = 1u;
            sort_args[at + 2u] = 1u;
            at += 3u;
        }
    }
}

// One compare-exchange step of a bitonic sort over the keys made (dispatched for the next
// power of two above their count), into decreasing order.
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
    var n = params.near_count;
    for (var w = 4u; w < 8u; w++) {
        n += atomicLoad(&draw_args[w]);
    }
    return n;
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
    let slot = ~keys[i].y;
    let cpu_end = params.count + params.near_count;
    // Back to front, or front to back for the trees' layer.
    var at = i - skip;
    if params.layer_batches > 0u {
        at = total - skip - 1u - at;
    }
    if slot < cpu_end {
        sorted[at] = records[slot];
    } else {
        sorted[at] = near_at(slot - cpu_end);
    }
}

// The draw's instance count, and for the trees' layer each batch's draw (words 12 on, 4 a
// batch: an equal share of the records, front to back).
@compute @workgroup_size(1)
fn finish() {
    let n = min(made(), params.limit);
    atomicStore(&draw_args[1], n);
    let batches = params.layer_batches;
    for (var k = 0u; k < batches; k++) {
        let first = n * k / batches;
        let end = n * (k + 1u) / batches;
        let at = 12u + 4u * k;
        atomicStore(&draw_args[at], 6u);
        atomicStore(&draw_args[at + 1u], end - first);
        atomicStore(&draw_args[at + 2u], 0u);
        atomicStore(&draw_args[at + 3u], first);
    }
}
