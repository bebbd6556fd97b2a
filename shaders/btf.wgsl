// BTF billboard pass (Meyer 2001, ch. 5 and annex A, on one fragment pass): each billboard
// blends its 3 nearest views x (3 nearest lights + the sky-lit image), weighted, from one
// texture array, and is composited back to front with premultiplied alpha,
// T = M + (1 - M_alpha) T0, which is the thesis' equation A.2 without its extra passes.

struct Billboard {
    // xyz: world centre; w: world radius (half the quad's side)
    center: vec4<f32>,
    // xyz: the quad's right axis in the world (unit); w: crossed-plane slot, or -1
    plane_right: vec4<f32>,
    // xyz: the quad's up axis in the world (unit); w: opacity (LOD fade)
    plane_up: vec4<f32>,
    // the quad's axes in the object frame, where the images were taken
    obj_right: vec4<f32>,
    obj_up: vec4<f32>,
    // xyz: sample indices of the 3 views; w: first layer of this object's image set
    view_index: vec4<u32>,
    // xyz: sample indices of the 3 lights; w: number of light samples
    light_index: vec4<u32>,
    // xyz: view weights (0 = culled); w: number of view samples
    view_weight: vec4<f32>,
    // xyz: light weights (0 = culled)
    light_weight: vec4<f32>,
    // rgb: colour tint of the tree (or the LOD overlay colour); a: 0 images, 1 the tint
    // alone, 2 the VCM sun factor in grey
    tint: vec4<f32>,
    // Visibility cube maps (Meyer 2001, 5.2): xyz: the billboard centre in its object's
    // box coordinates (0..1 from the box's min to its max corner); w: the coarser levels'
    // sun factor at the billboard's centre
    vcm_box_origin: vec4<f32>,
    // xyz: box coordinates per unit of `p`; w: the coarser levels' sky factor
    vcm_box_scale: vec4<f32>,
    // sun visibility at the 8 box corners (corner k: bit 0 = max x, bit 1 = max y,
    // bit 2 = max z), then sky visibility at the same corners
    vcm_direct: array<vec4<f32>, 2>,
    vcm_sky: array<vec4<f32>, 2>,
}

// Trilinear interpolation of 8 corner values at box coordinates u.
fn trilinear(lo: vec4<f32>, hi: vec4<f32>, u_in: vec3<f32>) -> f32 {
    let u = clamp(u_in, vec3<f32>(0.0), vec3<f32>(1.0));
    let z0 = mix(mix(lo.x, lo.y, u.x), mix(lo.z, lo.w, u.x), u.y);
    let z1 = mix(mix(hi.x, hi.y, u.x), mix(hi.z, hi.w, u.x), u.y);
    return mix(z0, z1, u.z);
}

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
    @location(2) @interpolate(flat) instance: u32,
}

@vertex
fn vs_billboard(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> BillboardOut {
    let b = billboards[instance];
    // Two triangles: corners (-1,-1) (1,-1) (1,1), (-1,-1) (1,1) (-1,1).
    var xs = array<f32, 6>(-1.0, 1.0, 1.0, -1.0, 1.0, -1.0);
    var ys = array<f32, 6>(-1.0, -1.0, 1.0, -1.0, 1.0, 1.0);
    let a = xs[vi % 6u];
    let c = ys[vi % 6u];
    let world = b.center.xyz + (a * b.plane_right.xyz + c * b.plane_up.xyz) * b.center.w;
    var out: BillboardOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.p = a * b.obj_right.xyz + c * b.obj_up.xyz;
    out.world = world;
    out.instance = instance;
    return out;
}

// Where the point `p` of the quad (object frame, in radii) falls in the image of view
// sample `v`, seen along that view, with the texture-coordinate gradients for filtering.
struct ViewTexcoords {
    uv: vec2<f32>,
    gx: vec2<f32>,
    gy: vec2<f32>,
}

fn view_texcoords(v: u32, p: vec3<f32>, dpx: vec3<f32>, dpy: vec3<f32>) -> ViewTexcoords {
    let r = view_axes[2u * v].xyz;
    let u = view_axes[2u * v + 1u].xyz;
    var t: ViewTexcoords;
    t.uv = vec2<f32>(dot(p, r), -dot(p, u)) * 0.5 + 0.5;
    t.gx = vec2<f32>(dot(dpx, r), -dot(dpx, u)) * 0.5;
    t.gy = vec2<f32>(dot(dpy, r), -dot(dpy, u)) * 0.5;
    return t;
}

// Opacity only, for the ground alpha shadow map: blended as dst * (1 - alpha), so the map
// holds the transmittance of every tree between the sun and the ground.
@fragment
fn fs_opacity(in: BillboardOut) -> @location(0) vec4<f32> {
    let b = billboards[in.instance];
    let dpx = dpdx(in.p);
    let dpy = dpdy(in.p);
    let lights = b.light_index.w;
    let views = u32(b.view_weight.w);
    let base = b.view_index.w;
    var alpha = 0.0;
    for (var k = 0; k < 3; k++) {
        let wv = b.view_weight[k];
        if wv <= 0.0 {
            continue;
        }
        let v = b.view_index[k];
        let t = view_texcoords(v, in.p, dpx, dpy);
        alpha += wv * textureSampleGrad(btf_images, btf_sampler, t.uv, i32(base + views * lights + v), t.gx, t.gy).a;
    }
    return vec4<f32>(0.0, 0.0, 0.0, alpha * b.plane_up.w);
}

@fragment
fn fs_billboard(in: BillboardOut) -> @location(0) vec4<f32> {
    let b = billboards[in.instance];
    // Derivatives in uniform control flow; the samples below use them explicitly.
    let dpx = dpdx(in.p);
    let dpy = dpdy(in.p);
    let slot = i32(b.plane_right.w);
    let lights = b.light_index.w;
    let views = u32(b.view_weight.w);
    let base = b.view_index.w;
    // The VCM factors at this point of the billboard: its own level's per pixel, the
    // coarser levels' from its centre.
    let u = b.vcm_box_origin.xyz + in.p * b.vcm_box_scale.xyz;
    let sun_factor = trilinear(b.vcm_direct[0], b.vcm_direct[1], u) * b.vcm_box_origin.w;
    let sky_factor = trilinear(b.vcm_sky[0], b.vcm_sky[1], u) * b.vcm_box_scale.w;
    var color = vec3<f32>(0.0);
    var alpha = 0.0;
    for (var k = 0; k < 3; k++) {
        let wv = b.view_weight[k];
        if wv <= 0.0 || (slot >= 0 && slot != k) {
            continue;
        }
        let v = b.view_index[k];
        let t = view_texcoords(v, in.p, dpx, dpy);
        let amb = textureSampleGrad(btf_images, btf_sampler, t.uv, i32(base + views * lights + v), t.gx, t.gy);
        var c = amb.rgb * frame.sky_ambient.rgb * sky_factor;
        var direct = vec3<f32>(0.0);
        for (var j = 0; j < 3; j++) {
            let wl = b.light_weight[j];
            if wl <= 0.0 {
                continue;
            }
            let layer = base + v * lights + b.light_index[j];
            let d = textureSampleGrad(btf_images, btf_sampler, t.uv, i32(layer), t.gx, t.gy);
            direct += wl * d.rgb;
        }
        c += direct * frame.sun_color.rgb * sun_factor;
        color += wv * c;
        alpha += wv * amb.a;
    }
    if b.tint.a > 1.5 {
        color = vec3<f32>(sun_factor) * alpha;
    } else if b.tint.a > 0.5 {
        color = b.tint.rgb * alpha;
    } else {
        color *= b.tint.rgb;
    }
    let dist = length(frame.camera_pos.xyz - in.world);
    let fog = 1.0 - exp(-dist * frame.camera_pos.w);
    color = mix(color, frame.sky_horizon.rgb * alpha, fog);
    let opacity = b.plane_up.w;
    return vec4<f32>(color * frame.shadow_params.z, alpha) * opacity;
}
