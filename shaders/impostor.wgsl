// The `impostor` method: one camera-facing quad per tree showing its species' octahedral
// impostor (src/bake/impostor.rs), as the open implementations draw it. The 3 frames around
// the view direction (in the tree's own frame) are blended with their barycentric weights;
// each frame's point under the pixel is where the eye's ray meets that frame's plane,
// shifted along the ray to the depth the frame stored (parallax); albedo and normal are
// blended, then lit per pixel by the sun and the sky with the tree-level VCM factors
// `btf` gets (trilinear over the tree's box at the blended point). Alpha-tested with a
// dithered threshold, writing the blended point's depth: opaque, no sorting.
// `ImpostorGpu` and `ImpostorParams` in src/render/method/impostor/prepare.rs mirror the
// structs byte for byte (tests/gpu_layout.rs).

struct Impostor {
    // World centre and radius of the bounding sphere every frame frames.
    center: vec3<f32>,
    radius: f32,
    // The tree's own axes in the world (unit): the frame the impostor was baked in.
    axis_x: vec3<f32>,
    // The species' layer in the atlases.
    layer: u32,
    axis_y: vec3<f32>,
    // The cross-fade with the tree drawn as geometry: the share of the pixels drawn, those
    // the geometry leaves (its dither is `fade_threshold`'s: it keeps the pixels under its
    // opacity, 1 - this).
    opacity: f32,
    axis_z: vec3<f32>,
    // MODE_IMAGES, MODE_TINT (the LOD overlay) or MODE_SUN_FACTOR.
    mode: u32,
    // Colour tint of the tree, or the overlay's colour.
    tint: vec3<f32>,
    // The VCM factors of the coarser levels (none above the tree level: 1).
    parent_direct: f32,
    // Box coordinates of the sphere's centre and per unit (radius) of the object frame.
    vcm_box_origin: vec3<f32>,
    parent_sky: f32,
    vcm_box_scale: vec3<f32>,
    _pad: f32,
    // Sun, then sky visibility at the 8 box corners (corner k: bit 0 = max x, bit 1 =
    // max y, bit 2 = max z).
    vcm_direct: array<vec4<f32>, 2>,
    vcm_sky: array<vec4<f32>, 2>,
}

struct ImpostorParams {
    // Frames per side, layout (0 full sphere, 1 upper hemisphere), pixels a frame side at
    // level 0, mip levels stored.
    frames: u32,
    octa_layout: u32,
    resolution: u32,
    mips: u32,
    // The alpha test's threshold (dithered over [c - s, c + s], s = min(c, 1 - c)).
    alpha_cutoff: f32,
    // 1: each frame's point is moved to the depth the frame stored.
    parallax: u32,
    // Self-shadowing: the light's extinction per radius of crown between a point and the
    // surface the frame nearest the sun (or the zenith, for the sky) sees first.
    self_shadow: f32,
    _pad: u32,
}

@group(1) @binding(0) var<storage, read> impostors: array<Impostor>;
@group(1) @binding(1) var<uniform> params: ImpostorParams;
@group(1) @binding(2) var albedo_atlas: texture_2d_array<f32>;
@group(1) @binding(3) var normal_atlas: texture_2d_array<f32>;
@group(1) @binding(4) var atlas_sampler: sampler;

const MODE_IMAGES: u32 = 0u;
const MODE_TINT: u32 = 1u;
const MODE_SUN_FACTOR: u32 = 2u;

struct ImpostorOut {
    @builtin(position) clip: vec4<f32>,
    // The quad's point in the object frame, in radii from the centre.
    @location(0) p: vec3<f32>,
    @location(1) @interpolate(flat) instance: u32,
    // The eye in the object frame, in radii from the centre.
    @location(2) @interpolate(flat) eye: vec3<f32>,
    // The 3 frames (row-major indices) and their weights.
    @location(3) @interpolate(flat) frames: vec3<u32>,
    @location(4) @interpolate(flat) weights: vec3<f32>,
    // The frame nearest the sun's direction and the one nearest the zenith, in the
    // object frame: the impostor's own shadow maps.
    @location(5) @interpolate(flat) light_frames: vec2<u32>,
}

// -1 or 1, 0 counting as positive (src/sphere/octa.rs's `sign`).
fn sgn(x: f32) -> f32 {
    return select(1.0, -1.0, x < 0.0);
}

// The point of the unit square a unit direction maps to (`OctaLayout::dir_to_uv`).
fn dir_to_uv(d: vec3<f32>) -> vec2<f32> {
    if params.octa_layout == 0u {
        let p = d / (abs(d.x) + abs(d.y) + abs(d.z));
        var e = p.xz;
        if p.y < 0.0 {
            e = vec2<f32>((1.0 - abs(p.z)) * sgn(p.x), (1.0 - abs(p.x)) * sgn(p.z));
        }
        return clamp(e * 0.5 + 0.5, vec2<f32>(0.0), vec2<f32>(1.0));
    }
    var h = vec3<f32>(d.x, max(d.y, 0.0), d.z);
    if h.x == 0.0 && h.y == 0.0 && h.z == 0.0 {
        h = vec3<f32>(1.0, 0.0, 0.0);
    }
    let p = h / (abs(h.x) + h.y + abs(h.z));
    let e = vec2<f32>(p.x + p.z, p.x - p.z);
    return clamp(e * 0.5 + 0.5, vec2<f32>(0.0), vec2<f32>(1.0));
}

// The unit direction at a point of the unit square (`OctaLayout::uv_to_dir`).
fn uv_to_dir(uv: vec2<f32>) -> vec3<f32> {
    let e = clamp(uv, vec2<f32>(0.0), vec2<f32>(1.0)) * 2.0 - 1.0;
    var v: vec3<f32>;
    if params.octa_layout == 0u {
        let y = 1.0 - abs(e.x) - abs(e.y);
        if y >= 0.0 {
            v = vec3<f32>(e.x, y, e.y);
        } else {
            v = vec3<f32>((1.0 - abs(e.y)) * sgn(e.x), y, (1.0 - abs(e.x)) * sgn(e.y));
        }
    } else {
        let x = 0.5 * (e.x + e.y);
        let z = 0.5 * (e.x - e.y);
        v = vec3<f32>(x, max(1.0 - abs(x) - abs(z), 0.0), z);
    }
    let l = length(v);
    return select(vec3<f32>(0.0, 1.0, 0.0), v / l, l > 1e-12);
}

// Frame `index`'s direction (from the object towards its camera).
fn frame_dir(index: u32) -> vec3<f32> {
    let n = params.frames;
    let ij = vec2<f32>(f32(index % n), f32(index / n));
    return uv_to_dir(ij / f32(n - 1u));
}

// The image axes of a view along `dir` (`sphere::billboard_axes`): right, then up.
fn view_axes(dir: vec3<f32>) -> array<vec3<f32>, 2> {
    let hint = select(vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0), abs(dir.y) > 0.999);
    let right = normalize(cross(hint, dir));
    let up = normalize(cross(dir, right));
    return array<vec3<f32>, 2>(right, up);
}

// The frame whose direction is nearest to `dir` (object frame, unit).
fn nearest_frame(dir: vec3<f32>) -> u32 {
    let g = round(dir_to_uv(dir) * f32(params.frames - 1u));
    return u32(g.y) * params.frames + u32(g.x);
}

@vertex
fn vs_impostor(@builtin(vertex_index) vi: u32, @builtin(instance_index) instance: u32) -> ImpostorOut {
    let b = impostors[instance];
    var xs = array<f32, 6>(-1.0, 1.0, 1.0, -1.0, 1.0, -1.0);
    var ys = array<f32, 6>(-1.0, -1.0, 1.0, -1.0, 1.0, 1.0);
    let a = xs[vi % 6u];
    let c = ys[vi % 6u];
    // A quad through the centre facing the eye covers the sphere when it is
    // d / sqrt(d^2 - r^2) times larger than r (capped near the sphere).
    let to_eye = frame.camera_pos - b.center;
    let d = max(length(to_eye), b.radius * 1.05);
    let half = min(b.radius * d / sqrt(d * d - b.radius * b.radius), 4.0 * b.radius);
    let facing = to_eye / max(length(to_eye), 1e-6);
    let axes = view_axes(facing);
    let world = b.center + (a * axes[0] + c * axes[1]) * half;
    // World to object frame (the axes are orthonormal), in radii.
    let rot = mat3x3<f32>(b.axis_x, b.axis_y, b.axis_z);
    let q = (world - b.center) / b.radius;
    let e = to_eye / b.radius;
    var out: ImpostorOut;
    out.clip = frame.view_proj * vec4<f32>(world, 1.0);
    out.p = q * rot;
    out.eye = e * rot;
    out.instance = instance;
    // The 3 frames around the view direction and their barycentric weights
    // (`OctaGrid::blend_uv`).
    let last = params.frames - 1u;
    out.light_frames = vec2<u32>(
        nearest_frame(normalize(frame.sun_dir * rot)),
        nearest_frame(normalize(vec3<f32>(0.0, 1.0, 0.0) * rot)),
    );
    let g = dir_to_uv(normalize(out.eye)) * f32(last);
    let cell = clamp(floor(g), vec2<f32>(0.0), vec2<f32>(f32(last - 1u)));
    let f = clamp(g - cell, vec2<f32>(0.0), vec2<f32>(1.0));
    let base = u32(cell.y) * params.frames + u32(cell.x);
    let n = params.frames;
    if f.x + f.y <= 1.0 {
        out.frames = vec3<u32>(base, base + 1u, base + n);
        out.weights = vec3<f32>(1.0 - f.x - f.y, f.x, f.y);
    } else {
        out.frames = vec3<u32>(base + n + 1u, base + n, base + 1u);
        out.weights = vec3<f32>(f.x + f.y - 1.0, 1.0 - f.x, 1.0 - f.y);
    }
    return out;
}

// Where the ray from `eye` along `ray` meets the plane through the centre facing `dir`,
// moved to the height `s` (radii) along `dir` above that plane.
fn ray_at_height(eye: vec3<f32>, ray: vec3<f32>, dir: vec3<f32>, s: f32) -> vec3<f32> {
    let den = dot(ray, dir);
    let t = (s - dot(eye, dir)) / select(den, -1e-6, abs(den) < 1e-6);
    return eye + t * ray;
}

// The image coordinates of the object-frame point `h` in a frame of image axes `axes`.
fn frame_uv(axes: array<vec3<f32>, 2>, h: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(dot(h, axes[0]), -dot(h, axes[1])) * 0.5 + 0.5;
}

// The atlas coordinates of `uv` in frame `index`'s tile, kept half a texel of level `lod`
// inside the tile so that no neighbour bleeds in.
fn atlas_uv(index: u32, uv: vec2<f32>, lod: f32) -> vec2<f32> {
    let n = f32(params.frames);
    let cell = vec2<f32>(f32(index % params.frames), f32(index / params.frames));
    let half = 0.5 * exp2(ceil(lod)) / f32(params.resolution);
    return (cell + clamp(uv, vec2<f32>(half), vec2<f32>(1.0 - half))) / n;
}

// A frame's point under the pixel (object frame, radii) and its atlas coordinates.
struct FramePoint {
    uv: vec2<f32>,
    point: vec3<f32>,
}

fn frame_point(index: u32, layer: i32, eye: vec3<f32>, ray: vec3<f32>, lod: f32) -> FramePoint {
    let dir = frame_dir(index);
    let axes = view_axes(dir);
    var h = ray_at_height(eye, ray, dir, 0.0);
    // The parallax fades out as the frames are minified: a coarse level's depth is the
    // mean of the crown's front over a wide footprint, not the depth under the pixel, and
    // moving the point by it misplaces the crown (the default forest's start camera: mean
    // FLIP 0.0915 with it at every level, 0.0816 without, 0.0788 faded out by level 1).
    let k = clamp(1.0 - lod, 0.0, 1.0);
    if params.parallax != 0u && k > 0.0 {
        // Two steps towards where the ray meets the stored surface.
        var nd = textureSampleLevel(normal_atlas, atlas_sampler, atlas_uv(index, frame_uv(axes, h), lod), layer, lod);
        h = ray_at_height(eye, ray, dir, k * (1.0 - 2.0 * nd.a));
        nd = textureSampleLevel(normal_atlas, atlas_sampler, atlas_uv(index, frame_uv(axes, h), lod), layer, lod);
        h = ray_at_height(eye, ray, dir, k * (1.0 - 2.0 * nd.a));
    }
    return FramePoint(atlas_uv(index, frame_uv(axes, h), lod), h);
}

// The share of the light from `index`'s direction that reaches the object-frame point
// `p` through the crown: the frame's depth map is a shadow map of the tree from there. The
// light crosses what lies between `p` and the first surface the frame sees (if `p` is
// behind it), attenuated by `params.self_shadow` per radius, in the share of the texel
// the frame found covered.
fn self_visibility(index: u32, layer: i32, p: vec3<f32>, lod: f32) -> f32 {
    let dir = frame_dir(index);
    let uv = atlas_uv(index, frame_uv(view_axes(dir), p), lod);
    let front = 1.0 - 2.0 * textureSampleLevel(normal_atlas, atlas_sampler, uv, layer, lod).a;
    let covered = textureSampleLevel(albedo_atlas, atlas_sampler, uv, layer, lod).a;
    let inside = max(front - dot(p, dir), 0.0);
    return mix(1.0, exp(-params.self_shadow * inside), covered);
}

// A threshold in [0, 1) from a 4x4 ordered dither of the pixel.
fn dither(pixel: vec2<f32>) -> f32 {
    var bayer = array<f32, 16>(0.0, 8.0, 2.0, 10.0, 12.0, 4.0, 14.0, 6.0, 3.0, 11.0, 1.0, 9.0, 15.0, 7.0, 13.0, 5.0);
    let p = vec2<u32>(pixel) % vec2<u32>(4u);
    return (bayer[p.y * 4u + p.x] + 0.5) / 16.0;
}

// The geometry's dither (geometry.wgsl's `dither_threshold`: interleaved gradient noise).
fn fade_threshold(pixel: vec2<f32>) -> f32 {
    return fract(52.9829189 * fract(dot(floor(pixel), vec2<f32>(0.06711056, 0.00583715))));
}

struct ImpostorFragment {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
}

// The impostor with the depth of its blended point (`parallax_depth` on): the depth test
// runs after the shader, on every fragment.
@fragment
fn fs_impostor(in: ImpostorOut) -> ImpostorFragment {
    return impostor_fragment(in);
}

// The impostor at its quad's depth (`parallax_depth` off): the depth test runs before
// the shader, so the fragments behind nearer impostors are not shaded.
@fragment
fn fs_impostor_quad(in: ImpostorOut) -> @location(0) vec4<f32> {
    return impostor_fragment(in).color;
}

fn impostor_fragment(in: ImpostorOut) -> ImpostorFragment {
    let b = impostors[in.instance];
    let ray = in.p - in.eye;
    // The level whose texels are a pixel wide on the quad (the frames' own planes are
    // seen nearly as the quad is).
    let footprint = max(length(dpdx(in.p)), length(dpdy(in.p))) * 0.5 * f32(params.resolution);
    let lod = clamp(log2(max(footprint, 1e-6)), 0.0, f32(params.mips - 1u));
    let layer = i32(b.layer);
    // The fade's dither first: a pixel it drops reads nothing.
    if fade_threshold(in.clip.xy) < 1.0 - b.opacity {
        count_fragment(in.clip, 0u);
        discard;
    }
    // Coverage and colour of the 3 frames, then the alpha test, then their normals: a
    // pixel of the quad outside the crown reads 3 texels (more with the parallax).
    var albedo = vec3<f32>(0.0);
    var point = vec3<f32>(0.0);
    var alpha = 0.0;
    var uvs: array<vec2<f32>, 3>;
    var weights = array<f32, 3>(0.0, 0.0, 0.0);
    for (var k = 0; k < 3; k++) {
        let w = in.weights[k];
        if w <= 0.0 {
            continue;
        }
        let f = frame_point(in.frames[k], layer, in.eye, ray, lod);
        let a = textureSampleLevel(albedo_atlas, atlas_sampler, f.uv, layer, lod);
        let wa = w * a.a;
        albedo += wa * a.rgb;
        point += wa * f.point;
        alpha += wa;
        uvs[k] = f.uv;
        weights[k] = wa;
    }
    let parallax_reads = select(0u, 6u, params.parallax != 0u && lod < 1.0);
    // Dithered alpha test: at a cut-off of 0.5 the threshold spans [0, 1], so a pixel's
    // chance to be drawn is its coverage; nearer 0 or 1 the edge is sharper.
    let spread = min(params.alpha_cutoff, 1.0 - params.alpha_cutoff);
    let d = dither(in.clip.xy);
    let threshold = params.alpha_cutoff + (2.0 * d - 1.0) * spread;
    if alpha <= max(threshold, 1e-3) {
        count_fragment(in.clip, 3u + parallax_reads);
        discard;
    }
    count_fragment(in.clip, 6u + parallax_reads + select(0u, 4u, params.self_shadow > 0.0));
    var normal = vec3<f32>(0.0);
    for (var k = 0; k < 3; k++) {
        if weights[k] <= 0.0 {
            continue;
        }
        let nd = textureSampleLevel(normal_atlas, atlas_sampler, uvs[k], layer, lod);
        normal += weights[k] * (nd.rgb * 2.0 - 1.0);
    }
    albedo /= alpha;
    point /= alpha;
    let rot = mat3x3<f32>(b.axis_x, b.axis_y, b.axis_z);
    let n_obj = normal / max(length(normal), 1e-6);
    let n = rot * n_obj;
    // The tree-level VCM factors at the point (btf's `vcm_factors`).
    let u = b.vcm_box_origin + point * b.vcm_box_scale;
    var sun_f = trilinear(b.vcm_direct[0], b.vcm_direct[1], u) * b.parent_direct;
    var sky_f = trilinear(b.vcm_sky[0], b.vcm_sky[1], u) * b.parent_sky;
    if params.self_shadow > 0.0 {
        // Soft: a level coarser than the view's.
        let l = min(lod + 1.0, f32(params.mips - 1u));
        sun_f *= self_visibility(in.light_frames.x, layer, point, l);
        sky_f *= self_visibility(in.light_frames.y, layer, point, l);
    }
    // Lit as the geometry lights a leaf (geometry.wgsl's `lit_by`): some light through it
    // from behind, the hemisphere's sky and ground light by the normal's height.
    let ndl = dot(n, frame.sun_dir);
    let direct = max(ndl, 0.0) + 0.3 * max(-ndl, 0.0);
    let ambient = mix(frame.ground_ambient, frame.sky_ambient * sky_f, n.y * 0.5 + 0.5);
    var color = albedo * (frame.sun_color * direct * sun_f + ambient) * b.tint;
    if b.mode == MODE_TINT {
        color = b.tint;
    } else if b.mode == MODE_SUN_FACTOR {
        color = vec3<f32>(sun_f);
    }
    let world = b.center + rot * point * b.radius;
    let clip = frame.view_proj * vec4<f32>(world, 1.0);
    var out: ImpostorFragment;
    let dist = length(frame.camera_pos - world);
    out.color = vec4<f32>(fog_and_exposure(color, 1.0, dist), 1.0);
    // The quad's own depth where the point falls behind the near plane.
    out.depth = select(in.clip.z, clamp(clip.z / clip.w, 0.0, 1.0), clip.w > 1e-4);
    return out;
}
