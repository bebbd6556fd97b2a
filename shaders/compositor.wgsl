// The tile compositor (src/render/compositor.rs): a frame's billboards, sorted front to
// back, composited in compute instead of rasterised, as the 3D Gaussian splatting tile
// rasterisers and Schuetz et al.'s compute point rasterisers do.
//
// - `setup`, one thread per billboard: the pixels its quad may cover (a rectangle), and a
//   bit for it in each 16x16-pixel tile that rectangle meets: each tile has a bit per
//   billboard, so its list is in the billboards' order (front to back) however the
//   threads ran, without a sort.
// - `composite`, one workgroup per tile, one invocation per pixel: every invocation goes
//   through the tile's bits in order, tests the billboard at its pixel (rectangle, then
//   the quad and the frame's depth, as the raster pass's coverage and depth tests decide)
//   and composites it "under", in float: C += T c, T *= 1 - a (T what the pixel still lets
//   through), shaded by `shade_billboard` (btf.wgsl) with the image gradients found from the
//   next pixels' rays (compute has no derivatives). A pixel stops where T falls below
//   `stop_below`. The layer is then put over the frame as the raster layer is.
//
// Every invocation of a tile reads the same records in the same order, so a GPU serves them
// from its caches; the loop has no barrier (a CPU Vulkan driver pays dearly for each: the
// first version, which gathered each tile's list 256 billboards at a time in workgroup
// memory, spent most of its time in them). Work is skipped with loops of 0 or 1 turns
// rather than branches: a CPU driver runs both sides of a branch for every invocation, but
// a loop only while some invocation is in it. Tiles are handed out through an atomic
// counter, not by workgroup id: a CPU driver runs a dispatch's workgroups in contiguous
// runs per thread, and the costly tiles (the stands) lie together.
//
// Prepended: frame.wgsl, the atlas side, billboard_record.wgsl, billboard.wgsl, btf.wgsl.

struct CompositorParams {
    // The target's width and height (px).
    size: vec2<u32>,
    // Tiles across and down.
    tiles: vec2<u32>,
    // A pixel stops compositing where it lets through less than this.
    stop_below: f32,
    // The word of `counts` holding the number of billboards.
    count_word: u32,
    // Billboards `rects` holds room for (no more are composited).
    capacity: u32,
    // Layers are shaded in full while the pixel lets through more than this; behind, by
    // their heaviest view sample alone.
    full_above: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    // Words of bits per tile in `tile_bits` (capacity / 32, rounded up), then of the
    // summary (a bit per word of bits: words / 32, rounded up).
    words: u32,
}

@group(2) @binding(0) var<uniform> cp: CompositorParams;
@group(2) @binding(1) var<storage, read> counts: array<u32>;
// Per billboard: its pixel rectangle, x0 | y0 << 16 and x1 | y1 << 16 (ends excluded).
@group(2) @binding(2) var<storage, read_write> rects: array<vec2<u32>>;
@group(2) @binding(3) var scene_depth: texture_depth_2d;
@group(2) @binding(4) var layer_out: texture_storage_2d<rgba16float, write>;
// What the composite counted: the next tile to hand out, then the statistics
// (COUNTER_* below).
@group(2) @binding(5) var<storage, read_write> counters: array<atomic<u32>>;
// Per tile (row by row), `words` words: bit i set where billboard i's rectangle meets it;
// then `words / 32` (rounded up) words of summary: bit w set where word w is not 0;
// set by `setup`, read by `composite` through a read-only binding of the same buffer (a
// CPU driver makes each atomic load a call of its own).
@group(2) @binding(6) var<storage, read_write> tile_bits: array<atomic<u32>>;
@group(2) @binding(7) var<storage, read> tile_list: array<u32>;

const TILE: u32 = 16u;
// Billboards a pixel finds (cheap test) before it shades them; then it finds the next.
const MAX_HITS: u32 = 16u;

// Words of `counters`: the next tile to hand out; layers shaded (summed over pixels);
// billboard tests (a billboard met by a tile's rectangle, per pixel); pixels stopped
// before their list ended; tiles stopped before their list ended; tiles composited.
const COUNTER_NEXT_TILE: u32 = 0u;
const COUNTER_LAYERS: u32 = 1u;
const COUNTER_TESTS: u32 = 2u;
const COUNTER_PIXELS_STOPPED: u32 = 3u;
const COUNTER_TILES_STOPPED: u32 = 4u;
const COUNTER_TILES: u32 = 5u;

// Words of `tile_bits` per tile: the bits, then their summary.
fn tile_stride() -> u32 {
    return cp.words + (cp.words + 31u) / 32u;
}

fn billboard_count() -> u32 {
    return min(counts[cp.count_word], cp.capacity);
}

// The clip-space corner of a billboard's quad (`a`, `c` in -1..1).
fn quad_corner(b: Billboard, half: f32, a: f32, c: f32) -> vec4<f32> {
    let world = b.center + (a * b.plane_right + c * b.plane_up) * half;
    return frame.view_proj * vec4<f32>(world, 1.0);
}

// The quad's half side as the vertex stage draws it.
fn quad_half(b: Billboard) -> f32 {
    if b.planes == 3u {
        return crossed_half_side(b.center, b.radius);
    }
    return b.radius;
}

@compute @workgroup_size(64)
fn setup(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= billboard_count() {
        return;
    }
    let b = billboards[i];
    let half = quad_half(b);
    var lo = vec2<f32>(1e30);
    var hi = vec2<f32>(-1e30);
    var behind = false;
    for (var k = 0u; k < 4u; k++) {
        let a = select(-1.0, 1.0, (k & 1u) != 0u);
        let c = select(-1.0, 1.0, (k & 2u) != 0u);
        let clip = quad_corner(b, half, a, c);
        if clip.w <= 1e-6 {
            behind = true;
        }
        let ndc = clip.xy / max(clip.w, 1e-6);
        let px = vec2<f32>(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5) * vec2<f32>(cp.size);
        lo = min(lo, px);
        hi = max(hi, px);
    }
    let size = vec2<f32>(cp.size);
    if behind {
        // A corner behind the eye: the whole screen (the quad test per pixel decides).
        lo = vec2<f32>(0.0);
        hi = size;
    }
    // Pixels whose centre may fall inside, half a pixel of slack for rounding.
    let x0 = clamp(floor(lo - 0.5), vec2<f32>(0.0), size);
    let x1 = clamp(ceil(hi + 0.5), vec2<f32>(0.0), size);
    let a = vec2<u32>(x0);
    let e = vec2<u32>(x1);
    rects[i] = vec2<u32>(a.x | (a.y << 16u), e.x | (e.y << 16u));
    if any(e <= a) {
        return;
    }
    // Its bit in every tile the rectangle meets.
    let t0 = a / TILE;
    let t1 = (e - 1u) / TILE;
    let word = i / 32u;
    let bit = 1u << (i % 32u);
    let stride = tile_stride();
    for (var ty = t0.y; ty <= t1.y; ty++) {
        for (var tx = t0.x; tx <= t1.x; tx++) {
            let at = (ty * cp.tiles.x + tx) * stride;
            atomicOr(&tile_bits[at + word], bit);
            atomicOr(&tile_bits[at + cp.words + word / 32u], 1u << (word % 32u));
        }
    }
}

// Whether the rectangle `r` holds `pixel`.
fn holds(r: vec2<u32>, pixel: vec2<u32>) -> bool {
    let r0 = vec2<u32>(r.x & 0xffffu, r.x >> 16u);
    let r1 = vec2<u32>(r.y & 0xffffu, r.y >> 16u);
    return all(pixel >= r0) && all(pixel < r1);
}

// The rays of one pixel's centre and of its right and lower neighbours (their
// directions, from the eye).
struct PixelRays {
    d: vec3<f32>,
    dx: vec3<f32>,
    dy: vec3<f32>,
}

fn ray_through(px: vec2<f32>) -> vec3<f32> {
    let size = vec2<f32>(cp.size);
    let ndc = vec2<f32>(px.x / size.x * 2.0 - 1.0, 1.0 - px.y / size.y * 2.0);
    let far = frame.inv_view_proj * vec4<f32>(ndc, 0.5, 1.0);
    return far.xyz / far.w - frame.camera_pos;
}

// Where a pixel's rays meet a billboard's quad: `q` the centre ray's point (x, y on the
// quad, -1..1; z the distance along the ray), `qx`, `qy` the next pixels' (for the image
// gradients); `hit` where the centre ray meets the quad in front of what the frame holds.
struct QuadHit {
    q: vec3<f32>,
    qx: vec3<f32>,
    qy: vec3<f32>,
    half: f32,
    hit: bool,
}

// The cheap test of billboard `i` at a pixel (its rays `rays`, the frame's depth there
// `depth`), as the raster pass's coverage and depth tests decide, reading only the fields
// it needs (copying the whole record for every test costs a CPU driver more than the test).
fn record_hit(i: u32, rays: PixelRays, depth: f32) -> QuadHit {
    var out: QuadHit;
    let center = billboards[i].center;
    let right = billboards[i].plane_right;
    let up = billboards[i].plane_up;
    var half = billboards[i].radius;
    if billboards[i].planes == 3u {
        half = crossed_half_side(center, half);
    }
    out.half = half;
    let n = cross(right, up);
    let o = frame.camera_pos - center;
    let dn = dot(o, n);
    let t = -dn / dot(rays.d, n);
    let tx = -dn / dot(rays.dx, n);
    let ty = -dn / dot(rays.dy, n);
    let h = o + t * rays.d;
    let hx = o + tx * rays.dx;
    let hy = o + ty * rays.dy;
    out.q = vec3<f32>(dot(h, right) / half, dot(h, up) / half, t);
    out.qx = vec3<f32>(dot(hx, right) / half, dot(hx, up) / half, tx);
    out.qy = vec3<f32>(dot(hy, right) / half, dot(hy, up) / half, ty);
    let world = frame.camera_pos + t * rays.d;
    let clip = frame.view_proj * vec4<f32>(world, 1.0);
    // Reversed Z: kept where nearer than the frame's depth (the raster pass's `Greater`).
    out.hit = t > 0.0 && abs(out.q.x) <= 1.0 && abs(out.q.y) <= 1.0 && clip.z > depth * clip.w;
    return out;
}

// The billboard `b` shaded where the pixel's rays met it (`h`, from `record_hit`): its
// premultiplied colour and the images read.
fn shade_hit(b_in: Billboard, h: QuadHit, rays: PixelRays, full: bool) -> Shaded {
    var b = b_in;
    // The cheap shade: the heaviest view sample first, alone.
    for (var cheap = !full; cheap; cheap = false) {
        let w = b.view_weight;
        var k = select(0u, 1u, w.y > w.x);
        k = select(k, 2u, w.z > max(w.x, w.y));
        let first = b.view_index[k];
        b.view_index[k] = b.view_index.x;
        b.view_index.x = first;
        b.view_weight = vec3<f32>(1.0, 0.0, 0.0);
    }
    let crossed = b.planes == 3u;
    let scale = select(1.0, h.half / b.radius, crossed);
    let p = (h.q.x * b.obj_right + h.q.y * b.obj_up) * scale;
    let px = (h.qx.x * b.obj_right + h.qx.y * b.obj_up) * scale;
    let py = (h.qy.x * b.obj_right + h.qy.y * b.obj_up) * scale;
    var pts: array<vec4<f32>, 3>;
    var texs: array<ViewTexcoords, 3>;
    for (var k = 0; k < 3; k++) {
        let v = b.view_index[k];
        let uv = view_uv(v, p);
        pts[k] = vec4<f32>(p, 1.0);
        texs[k] = ViewTexcoords(uv, view_uv(v, px) - uv, view_uv(v, py) - uv);
    }
    // Crossed planes: each view's own plane where the eye's ray meets it (a loop of 0 or
    // 1 turns: a CPU driver runs both sides of a branch, but a loop only while some
    // invocation takes it).
    for (var c = crossed; c; c = false) {
        let to_eye = (frame.camera_pos - b.center) / b.radius;
        let obj_fwd = cross(b.obj_right, b.obj_up);
        let n = cross(b.plane_right, b.plane_up);
        let eye = dot(to_eye, b.plane_right) * b.obj_right + dot(to_eye, b.plane_up) * b.obj_up
            + dot(to_eye, n) * obj_fwd;
        for (var k = 0; k < 3; k++) {
            let v = b.view_index[k];
            let hc = view_plane_hit(v, eye, p);
            let hx = view_plane_hit(v, eye, px);
            let hy = view_plane_hit(v, eye, py);
            pts[k] = hc;
            texs[k] = view_texcoords(v, hc.xyz, hx.xyz - hc.xyz, hy.xyz - hc.xyz);
        }
    }
    let world = frame.camera_pos + h.q.z * rays.d;
    return shade_billboard(b, pts, texs, world, select(1u, 3u, full));
}

var<workgroup> tile_taken: u32;
var<workgroup> tile_pixels_stopped: atomic<u32>;

@compute @workgroup_size(16, 16)
fn composite(@builtin(local_invocation_id) local: vec3<u32>) {
    let first = all(local.xy == vec2<u32>(0u));
    if first {
        tile_taken = atomicAdd(&counters[COUNTER_NEXT_TILE], 1u);
        atomicStore(&tile_pixels_stopped, 0u);
    }
    let tile = workgroupUniformLoad(&tile_taken);
    if tile >= cp.tiles.x * cp.tiles.y {
        return;
    }
    let origin = vec2<u32>(tile % cp.tiles.x, tile / cp.tiles.x) * TILE;
    let pixel = origin + local.xy;
    let inside = all(pixel < cp.size);
    var depth = 1.0;
    if inside {
        depth = textureLoad(scene_depth, pixel, 0);
    }
    let centre = vec2<f32>(pixel) + 0.5;
    let rays = PixelRays(
        ray_through(centre),
        ray_through(centre + vec2<f32>(1.0, 0.0)),
        ray_through(centre + vec2<f32>(0.0, 1.0)),
    );
    var color = vec3<f32>(0.0);
    var through = 1.0;
    var alive = inside;
    var layers = 0u;
    var tests = 0u;
    let words = (billboard_count() + 31u) / 32u;
    let base = tile * tile_stride();
    let end = words * 32u;
    // The next billboard of the tile's list this pixel has not looked at.
    var pos = 0u;
    var hits: array<u32, MAX_HITS>;
    // `pos` past the end of the bits stops the search (`end` is a whole number of words).
    loop {
        // Up to MAX_HITS billboards that cover the pixel in front of the frame's depth, in
        // order (the cheap test only)...
        var count = 0u;
        loop {
            if !alive || count >= MAX_HITS || pos >= end {
                break;
            }
            let w = pos / 32u;
            let bits = tile_list[base + w] & (0xffffffffu << (pos % 32u));
            if bits == 0u {
                // The next word that holds any, through the summary.
                pos = next_word(base, w + 1u) * 32u;
                continue;
            }
            let i = w * 32u + countTrailingZeros(bits);
            pos = i + 1u;
            if holds(rects[i], pixel) {
                tests += 1u;
                if record_hit(i, rays, depth).hit {
                    hits[count] = i;
                    count += 1u;
                }
            }
        }
        // ...then shaded front to back until the pixel is opaque.
        for (var k = 0u; k < count; k++) {
            if !alive {
                break;
            }
            let i = hits[k];
            let l = shade_hit(billboards[i], record_hit(i, rays, depth), rays, through > cp.full_above);
            layers += 1u;
            count_fragment(vec4<f32>(centre, 0.0, 1.0), l.reads);
            color += through * l.color.rgb;
            through *= 1.0 - l.color.a;
            alive = through >= cp.stop_below;
        }
        if !alive || pos >= end {
            break;
        }
    }
    // Stopped before the tile's list ended.
    let stopped = inside && !alive && bits_from(base, pos, words);
    if inside {
        textureStore(layer_out, pixel, vec4<f32>(color, 1.0 - through));
        atomicAdd(&counters[COUNTER_LAYERS], layers);
        atomicAdd(&counters[COUNTER_TESTS], tests);
        if stopped {
            atomicAdd(&counters[COUNTER_PIXELS_STOPPED], 1u);
            atomicAdd(&tile_pixels_stopped, 1u);
        }
    }
    workgroupBarrier();
    if first {
        atomicAdd(&counters[COUNTER_TILES], 1u);
        let covered = min(cp.size - origin, vec2<u32>(TILE));
        if atomicLoad(&tile_pixels_stopped) == covered.x * covered.y {
            atomicAdd(&counters[COUNTER_TILES_STOPPED], 1u);
        }
    }
}

// The first word from `w` on whose summary bit is set, or past it to the next summary
// word's first (the caller looks again from there); 32 x `words` at most.
fn next_word(base: u32, w: u32) -> u32 {
    let sw = w / 32u;
    if sw >= (cp.words + 31u) / 32u {
        return cp.words;
    }
    let summary = tile_list[base + cp.words + sw] & (0xffffffffu << (w % 32u));
    if summary == 0u {
        return (sw + 1u) * 32u;
    }
    return sw * 32u + countTrailingZeros(summary);
}

// Whether the tile's list holds any billboard from position `pos` on.
fn bits_from(base: u32, pos: u32, words: u32) -> bool {
    for (var w = pos / 32u; w < words; w++) {
        let bits = tile_list[base + w] & select(0xffffffffu, 0xffffffffu << (pos % 32u), w == pos / 32u);
        if bits != 0u {
            return true;
        }
    }
    return false;
}
