// The billboards of the image-based methods: one record per billboard in a storage buffer,
// drawn as an instanced quad. Shared by the btf pass and the ground-map pass. The record itself
// is in `billboard_record.wgsl`, prepended.

@group(1) @binding(0) var<storage, read> billboards: array<Billboard>;
// Two entries per view sample: the image's right and up axes in the object frame.
@group(1) @binding(1) var<storage, read> view_axes: array<vec4<f32>>;
@group(1) @binding(2) var btf_images: texture_2d_array<f32>;
@group(1) @binding(3) var btf_sampler: sampler;

struct BillboardOut {
    @builtin(position) clip: vec4<f32>,
    // position on the quad in the object frame, in units of the object's radius
    @location(0) p: vec3<f32>,
    @location(1) world: vec3<f32>,
    // On a single plane, where the pixel falls in the images of the 3 views (view 0's
    // uv, view 1's uv; then view 2's): linear across the quad, so found per vertex.
    @location(2) uv01: vec4<f32>,
    // the eye in the object frame, in radii (crossed planes)
    @location(3) @interpolate(flat) eye: vec3<f32>,
    // The record's fields a fragment reads, passed flat: set up once per triangle, where
    // loading the record from its buffer costs a CPU rasteriser a load per pixel
    // (`flat_billboard` puts them back together). `indices` holds the view and light
    // indices two to a word (16 bits each: view_index.x | .y, view_index.z | planes,
    // light_index.x | .y, light_index.z | light_count).
    @location(4) @interpolate(flat) indices: vec4<u32>,
    @location(5) uv2: vec2<f32>,
    @location(6) @interpolate(flat) layers: vec4<u32>,
    @location(7) @interpolate(flat) view_weight: vec4<f32>,
    @location(8) @interpolate(flat) light_weight: vec4<f32>,
    @location(9) @interpolate(flat) tint: vec4<f32>,
    @location(10) @interpolate(flat) box_origin: vec4<f32>,
    @location(11) @interpolate(flat) box_scale: vec4<f32>,
    @location(12) @interpolate(flat) direct_lo: vec4<f32>,
    @location(13) @interpolate(flat) direct_hi: vec4<f32>,
    @location(14) @interpolate(flat) sky_lo: vec4<f32>,
    @location(15) @interpolate(flat) sky_hi: vec4<f32>,
}

// The record as the vertex stage passed it on: every field a fragment reads (the quad's
// placement is left zero).
fn flat_billboard(in: BillboardOut) -> Billboard {
    var b: Billboard;
    let lo = in.indices & vec4<u32>(0xffffu);
    let hi = in.indices >> vec4<u32>(16u);
    b.view_index = vec3<u32>(lo.x, hi.x, lo.y);
    b.planes = hi.y;
    b.light_index = vec3<u32>(lo.z, hi.z, lo.w);
    b.light_count = hi.w;
    b.layer_base = in.layers.x;
    b.view_count = in.layers.y;
    b.light_blend = in.layers.z;
    b.mode = in.layers.w;
    b.view_weight = in.view_weight.xyz;
    b.opacity = in.view_weight.w;
    b.light_weight = in.light_weight.xyz;
    b.tint = in.tint.xyz;
    b.vcm_box_origin = in.box_origin.xyz;
    b.parent_direct = in.box_origin.w;
    b.vcm_box_scale = in.box_scale.xyz;
    b.parent_sky = in.box_scale.w;
    b.vcm_direct = array<vec4<f32>, 2>(in.direct_lo, in.direct_hi);
    b.vcm_sky = array<vec4<f32>, 2>(in.sky_lo, in.sky_hi);
    return b;
}

// Crossed planes reach sqrt(2) radii from the centre (a square's corner). A quad through
// the centre facing an eye at distance d covers a sphere of radius r when it is
// d / sqrt(d^2 - r^2) times larger than r; near the sphere the growth is capped.
fn crossed_half_side(center: vec3<f32>, radius: f32) -> f32 {
    let r = radius * sqrt(2.0);
    let d = max(length(frame.camera_pos - center), r * 1.05);
    return min(r * d / sqrt(d * d - r * r), 4.0 * r);
}

@vertex
fn vs_billboard(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> BillboardOut {
    let b = billboards[instance];
    // Two triangles: corners (-1,-1) (1,-1) (1,1), (-1,-1) (1,1) (-1,1).
    var xs = array<f32, 6>(-1.0, 1.0, 1.0, -1.0, 1.0, -1.0);
    var ys = array<f32, 6>(-1.0, -1.0, 1.0, -1.0, 1.0, 1.0);
    let a = xs[vi % 6u];
    let c = ys[vi % 6u];
    var half = b.radius;
    if b.planes == 3u {
        half = crossed_half_side(b.center, b.radius);
    }
    let world = b.center + (a * b.plane_right + c * b.plane_up) * half;
    var out: BillboardOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.p = a * b.obj_right + c * b.obj_up;
    out.eye = vec3<f32>(0.0);
    if b.planes == 3u {
        out.p *= half / b.radius;
        // World to object frame: the quad's axes are the same directions in both frames.
        let to_eye = (frame.camera_pos - b.center) / b.radius;
        let plane_fwd = cross(b.plane_right, b.plane_up);
        let obj_fwd = cross(b.obj_right, b.obj_up);
        out.eye = dot(to_eye, b.plane_right) * b.obj_right + dot(to_eye, b.plane_up) * b.obj_up
            + dot(to_eye, plane_fwd) * obj_fwd;
    }
    out.world = world;
    out.indices = vec4<u32>(
        b.view_index.x | (b.view_index.y << 16u),
        b.view_index.z | (b.planes << 16u),
        b.light_index.x | (b.light_index.y << 16u),
        b.light_index.z | (b.light_count << 16u),
    );
    out.uv01 = vec4<f32>(view_uv(b.view_index.x, out.p), view_uv(b.view_index.y, out.p));
    out.uv2 = view_uv(b.view_index.z, out.p);
    out.layers = vec4<u32>(b.layer_base, b.view_count, b.light_blend, b.mode);
    out.view_weight = vec4<f32>(b.view_weight, b.opacity);
    out.light_weight = vec4<f32>(b.light_weight, 0.0);
    out.tint = vec4<f32>(b.tint, 0.0);
    out.box_origin = vec4<f32>(b.vcm_box_origin, b.parent_direct);
    out.box_scale = vec4<f32>(b.vcm_box_scale, b.parent_sky);
    out.direct_lo = b.vcm_direct[0];
    out.direct_hi = b.vcm_direct[1];
    out.sky_lo = b.vcm_sky[0];
    out.sky_hi = b.vcm_sky[1];
    return out;
}

// Where the point `p` of the quad (object frame, in radii) falls in the image of view
// sample `v`, seen along that view, with the texture-coordinate gradients for filtering.
struct ViewTexcoords {
    uv: vec2<f32>,
    gx: vec2<f32>,
    gy: vec2<f32>,
}

// A point or offset `x` of the object frame on the image of the view with right and up
// axes `r`, `u`, in image units of half the image (y down).
fn on_image(x: vec3<f32>, r: vec3<f32>, u: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(dot(x, r), -dot(x, u));
}

// The image coordinates alone (`view_texcoords`' uv).
fn view_uv(v: u32, p: vec3<f32>) -> vec2<f32> {
    return on_image(p, view_axes[2u * v].xyz, view_axes[2u * v + 1u].xyz) * 0.5 + 0.5;
}

fn view_texcoords(v: u32, p: vec3<f32>, dpx: vec3<f32>, dpy: vec3<f32>) -> ViewTexcoords {
    let r = view_axes[2u * v].xyz;
    let u = view_axes[2u * v + 1u].xyz;
    var t: ViewTexcoords;
    t.uv = on_image(p, r, u) * 0.5 + 0.5;
    t.gx = on_image(dpx, r, u) * 0.5;
    t.gy = on_image(dpy, r, u) * 0.5;
    return t;
}

// Image `index` of the BTF atlas (`BTF_ATLAS_SIDE`² images to a texture layer, row by row,
// each with its own mip chain; the constant is prepended by src/render/shaders.rs) at image
// coordinates `uv` with gradients `gx`, `gy`. `uv` is kept half a texel inside the image's
// square at the coarser of the two levels the gradients pick, as ClampToEdge did for one
// image per layer, so that no neighbour bleeds in.
fn btf_sample(index: u32, uv: vec2<f32>, gx: vec2<f32>, gy: vec2<f32>) -> vec4<f32> {
    let per_layer = BTF_ATLAS_SIDE * BTF_ATLAS_SIDE;
    let slot = index % per_layer;
    let cell = vec2<f32>(f32(slot % BTF_ATLAS_SIDE), f32(slot / BTF_ATLAS_SIDE));
    let res = f32(textureDimensions(btf_images).x) / f32(BTF_ATLAS_SIDE);
    let footprint = max(max(length(gx), length(gy)) * res, 1.0);
    let lod = min(ceil(log2(footprint)), log2(res));
    let half = 0.5 * exp2(lod) / res;
    let inside = clamp(uv, vec2<f32>(half), vec2<f32>(1.0 - half));
    let scale = 1.0 / f32(BTF_ATLAS_SIDE);
    return textureSampleGrad(
        btf_images,
        btf_sampler,
        (cell + inside) * scale,
        i32(index / per_layer),
        gx * scale,
        gy * scale,
    );
}

// Where the ray from `eye` through `p` (object frame, radii) meets the plane of view sample
// `v` (through the centre, facing that view), in the same frame; w: 1 when the hit lies in
// front of the eye and on the plane's square, else 0.
fn view_plane_hit(v: u32, eye: vec3<f32>, p: vec3<f32>) -> vec4<f32> {
    let r = view_axes[2u * v].xyz;
    let u = view_axes[2u * v + 1u].xyz;
    let n = cross(r, u);
    let d = p - eye;
    let denom = dot(d, n);
    let t = -dot(eye, n) / select(denom, 1e-12, abs(denom) < 1e-12);
    let h = eye + t * d;
    let on = t > 0.0 && abs(dot(h, r)) <= 1.0 && abs(dot(h, u)) <= 1.0;
    return vec4<f32>(h, select(0.0, 1.0, on));
}
