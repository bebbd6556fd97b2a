// Geometry pass: terrain, trunks, limbs and every leaf and needle as triangles. Lambert sun
// light through cascaded shadow maps, hemispherical sky ambient, two-sided leaves with some
// light let through from behind, distance fog towards the horizon colour.

@group(0) @binding(1) var shadow_map: texture_depth_2d_array;
@group(0) @binding(2) var shadow_sampler: sampler_comparison;
// Transmittance of the trees seen from the sun (1 = no tree in the way): the alpha shadow
// map of the image-based methods, whose trees are not in the depth shadow maps.
@group(0) @binding(3) var ground_alpha: texture_2d<f32>;
@group(0) @binding(4) var ground_sampler: sampler;
// The terrain's depth seen from the sun, drawn with the alpha map over the whole scene: the
// image-based methods' terrain shadows, in place of the cascades.
// (One layer, so that one PCF function serves it and the cascades.)
@group(0) @binding(5) var ground_depth: texture_depth_2d_array;
// The reference's sky visibility: the fraction of the sky each cell of a grid over the scene
// sees through the trees' leaf area and past the terrain (src/render/sky_visibility.rs),
// as a 3D texture with x, z, y as u, v, w.
struct SkyVolume {
    origin: vec4<f32>,
    inv_size: vec4<f32>,
}
@group(0) @binding(6) var sky_volume: texture_3d<f32>;
@group(0) @binding(7) var<uniform> sky_place: SkyVolume;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec3<f32>,
    @location(3) foliage: f32,
    @location(4) @interpolate(flat) opacity: f32,
    // 1 for a tree's parts, 0 for the terrain (drawn as instance 0).
    @location(5) @interpolate(flat) tree: f32,
    // The tree's slot in the tree buffer, and its key (`tree_key`): the reference's own
    // sun map of the tree, and the cascade texels it leaves out.
    @location(6) @interpolate(flat) slot: u32,
    @location(7) @interpolate(flat) key: u32,
    @location(8) uv: vec2<f32>,
}

// The fragment as its material colours it: the vertex colour times the part set's texture
// (1 for untextured parts), cut away below its alpha cut-off. First in every entry point.
// The terrain's coarse levels (uv.x < 0, `model::terrain_lod`) take their point, colour and
// normal from the terrain's maps, which keep the grid's detail between their vertices; its skirts
// carry in uv.y how far below the chunk's edge they hang: they are shaded as the edge above
// them, not as the ground's inside.
fn textured(in: VertexOut) -> VertexOut {
    var out = in;
    out.color = in.color * part_texel(in.uv).rgb;
    if in.tree == 0.0 {
        out.world.y += in.uv.y;
    }
    if part_set.textured == 2u && in.uv.x < 0.0 {
        // The point where the eye's ray meets the full-detail surface, found from the coarse
        // surface's point in two steps along the ray (each at most a few cells long).
        let ray = out.world - frame.camera_pos;
        let reach = 3.0 / (part_set.terrain_map.y * max(length(ray.xz), 1e-3));
        var p = out.world;
        for (var k = 0; k < 2; k++) {
            let h = terrain_texels(p.xz).height;
            let t = (h - p.y) / select(ray.y, -1e-6, abs(ray.y) < 1e-6);
            p += ray * clamp(t, -reach, reach);
        }
        let t = terrain_texels(p.xz);
        out.world = vec3<f32>(p.x, t.height, p.z);
        out.color = t.color;
        out.normal = t.normal;
        // On the full-detail surface: no lift for its own shadows.
        out.uv.x = -1.0;
    }
    return out;
}

// How far the terrain's point is raised for its own shadows: a coarse level's height error
// there (-1 - uv.x), so that the surface cutting below the hills is not shadowed by them.
fn shadow_lift(in: VertexOut) -> vec3<f32> {
    let lift = select(0.0, -1.0 - in.uv.x, in.tree == 0.0 && in.uv.x < 0.0);
    return vec3<f32>(0.0, lift, 0.0);
}

@vertex
fn vs_main(v: VertexIn, @builtin(instance_index) instance: u32) -> VertexOut {
    let model = instance_model(instance);
    let world = model * vec4<f32>(v.position, 1.0);
    var out: VertexOut;
    out.clip = frame.view_proj * world;
    out.world = world.xyz;
    out.normal = (model * vec4<f32>(v.normal, 0.0)).xyz;
    out.color = v.color * mix(vec3<f32>(1.0), instance_tint(instance), v.foliage);
    out.foliage = v.foliage;
    out.opacity = instance_opacity(instance);
    out.tree = select(1.0, 0.0, instance / max(part_set.count, 1u) == 0u);
    out.slot = instance_slot(instance);
    out.key = tree_key(out.slot);
    out.uv = v.uv;
    return out;
}

// A threshold in [0, 1) per pixel, evenly spread over any small block of pixels
// (interleaved gradient noise): a tree of opacity `a` keeps the pixels under `a`.
fn dither_threshold(pixel: vec2<f32>) -> f32 {
    return fract(52.9829189 * fract(dot(floor(pixel), vec2<f32>(0.06711056, 0.00583715))));
}

fn cascade_for(view_depth: f32) -> u32 {
    if view_depth < frame.cascade_splits.x {
        return 0u;
    }
    if view_depth < frame.cascade_splits.y {
        return 1u;
    }
    return 2u;
}

// Where `world` falls in the ground shadow maps: texture coordinates (already scaled to
// the part in use) and depth; uv < 0 when outside them, or when `square_only` and past the
// scene's square. The terrain depth is read in the square only: the horizon ring's coarse
// cells, raised where its far forest stands, cast blocks of shadow across it in that map.
// The trees' transmittance is read wherever the maps reach, so the edge trees' shadows
// fall on the ring as they do in the reference (the ring is drawn into the same pass,
// with depth, so it hides the trees behind it from the sun).
fn ground_coords(world: vec3<f32>, square_only: bool) -> vec3<f32> {
    let lp = frame.ground_light_view_proj * vec4<f32>(world, 1.0);
    let ndc = lp.xyz / lp.w;
    let uv = ndc_to_uv(ndc.xy);
    let past = square_only && frame.ground_half > 0.0
        && max(abs(world.x), abs(world.z)) > frame.ground_half;
    if past || any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) {
        return vec3<f32>(-1.0, -1.0, ndc.z);
    }
    // Keep the filter footprint inside the part of the textures in use.
    let size = f32(textureDimensions(ground_depth).x);
    let scale = frame.ground_uv_scale;
    let t = clamp(uv * scale, vec2<f32>(0.5 / size), vec2<f32>(scale - 0.5 / size));
    return vec3<f32>(t, ndc.z);
}

// Fraction of a 3x3 block of depth comparisons around `uv` (`step` apart, in uv) that
// see the sun: percentage-closer filtering.
fn pcf3x3(map: texture_depth_2d_array, layer: i32, uv: vec2<f32>, depth: f32, step: f32) -> f32 {
    var lit = 0.0;
    for (var y = -1; y <= 1; y++) {
        for (var x = -1; x <= 1; x++) {
            let o = vec2<f32>(f32(x), f32(y)) * step;
            lit += textureSampleCompareLevel(map, shadow_sampler, uv + o, layer, depth);
        }
    }
    return lit / 9.0;
}

// Fraction of the sun the terrain lets reach `world`, 3x3 PCF on the ground depth map.
fn terrain_visibility(world: vec3<f32>, normal: vec3<f32>) -> f32 {
    // Offset along the normal and towards the sun by about a texel, against acne.
    let p = world + (normal * 1.5 + frame.sun_dir) * frame.ground_texel_world;
    let c = ground_coords(p, true);
    if c.x < 0.0 || c.z > 1.0 {
        return 1.0;
    }
    let texel = 1.0 / f32(textureDimensions(ground_depth).x);
    return pcf3x3(ground_depth, 0, c.xy, c.z, texel);
}

// Fraction of the sun that reaches `world` (1 = lit), 3x3 PCF on the cascade's map (or on
// the ground depth map, for the image-based methods).
fn sun_visibility(world: vec3<f32>, normal: vec3<f32>, view_depth: f32) -> f32 {
    if frame.shadows_on == 0u {
        return 1.0;
    }
    if frame.terrain_depth_on != 0u {
        return terrain_visibility(world, normal);
    }
    return cascade_visibility(world, normal, view_depth);
}

// The cascades' part of `sun_visibility` (1 past the last cascade).
fn cascade_visibility(world: vec3<f32>, normal: vec3<f32>, view_depth: f32) -> f32 {
    let c = cascade_coords(world, normal, view_depth);
    if c.w < 0.0 {
        return 1.0;
    }
    return pcf3x3(shadow_map, i32(c.w), c.xy, c.z, frame.cascade_texel_uv * frame.pcf_radius);
}

// Where `world` (offset along `normal` by about a texel of its cascade, against acne) falls
// in the cascade its view depth picks: uv, depth, and the cascade (w < 0: in none).
fn cascade_coords(world: vec3<f32>, normal: vec3<f32>, view_depth: f32) -> vec4<f32> {
    if view_depth >= frame.cascade_splits.z {
        return vec4<f32>(0.0, 0.0, 0.0, -1.0);
    }
    let c = cascade_for(view_depth);
    let p = world + normal * frame.cascade_texel_world[c] * 1.5;
    let lp = frame.light_view_proj[c] * vec4<f32>(p, 1.0);
    let ndc = lp.xyz / lp.w;
    let uv = ndc_to_uv(ndc.xy);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) {
        return vec4<f32>(0.0, 0.0, 0.0, -1.0);
    }
    // The maps' depth spans the scene's bounds. A point past their far side (the horizon
    // ring beyond them, away from the sun) is behind everything drawn in them: compared at
    // the far side, every caster over it shades it and open texels (cleared to 1) do not.
    return vec4<f32>(uv, min(ndc.z, 0.99999), f32(c));
}

// Fraction of the sky `world` sees (1 = all of it), read trilinearly from the volume half
// a cell along the normal (so that the ground does not read the cells under it).
fn sky_visibility(world: vec3<f32>, normal: vec3<f32>) -> f32 {
    if frame.sky_vis_count == 0u {
        return 1.0;
    }
    let p = world + normal * frame.sky_vis_texel_world * 0.5 - sky_place.origin.xyz;
    let uvw = vec3<f32>(p.x, p.z, p.y) * sky_place.inv_size.xyz;
    if uvw.z > 1.0 || any(uvw.xy < vec2<f32>(0.0)) || any(uvw.xy > vec2<f32>(1.0)) {
        return 1.0;
    }
    return textureSampleLevel(sky_volume, ground_sampler, uvw, 0.0).r;
}

// How much of the sun the trees let through to `world`, from the alpha shadow map.
fn ground_transmittance(world: vec3<f32>) -> f32 {
    let c = ground_coords(world, false);
    if c.x < 0.0 {
        return 1.0;
    }
    return textureSampleLevel(ground_alpha, ground_sampler, c.xy, 0.0).r;
}

// The lit colour of a fragment (before fog and exposure).
fn shade(in: VertexOut, front: bool) -> vec3<f32> {
    return shade_as(in, front, false);
}

// `shade`; with `own_cascades` (a `hybrid` tree drawn as geometry among image-based ones)
// the sun is hidden by the terrain's map and by the cascades, which hold the geometry trees
// alone, instead of by the trees' alpha map (which holds this tree as a billboard too).
fn shade_as(in: VertexOut, front: bool, own_cascades: bool) -> vec3<f32> {
    let n = surface_normal(in, front);
    let view_depth = dot(in.world - frame.camera_pos, frame.camera_forward);
    let offset_normal = shadow_offset_normal(in, n);
    var vis = sun_visibility(in.world + shadow_lift(in), offset_normal, view_depth);
    if own_cascades {
        vis = 1.0;
        if frame.shadows_on != 0u {
            vis = cascade_visibility(in.world, offset_normal, view_depth);
            if frame.terrain_depth_on != 0u {
                vis *= terrain_visibility(in.world, offset_normal);
            }
        }
    } else if frame.ground_alpha_on != 0u {
        vis *= ground_transmittance(in.world);
        if frame.hybrid_cascades != 0u {
            vis *= cascade_visibility(in.world, offset_normal, view_depth);
        }
    }
    return lit_by(in, n, vis);
}

// The normal that faces the viewer's side for a leaf (two-sided), the mesh's otherwise.
fn surface_normal(in: VertexOut, front: bool) -> vec3<f32> {
    let n = normalize(in.normal);
    if in.foliage > 0.5 && !front {
        return -n;
    }
    return n;
}

// The normal shadow lookups are offset along: a leaf's side towards the sun.
fn shadow_offset_normal(in: VertexOut, n: vec3<f32>) -> vec3<f32> {
    return select(n, sign(dot(n, frame.sun_dir)) * n, in.foliage > 0.5);
}

// The lit colour of a fragment of normal `n` that sees `vis` of the sun.
fn lit_by(in: VertexOut, n: vec3<f32>, vis: f32) -> vec3<f32> {
    let leaf = in.foliage > 0.5;
    let ndl = dot(n, frame.sun_dir);
    // Leaves let some light through: a leaf lit from behind still glows a little.
    var direct = max(ndl, 0.0);
    if leaf {
        direct = max(ndl, 0.0) + 0.3 * max(-ndl, 0.0);
    }
    // Hemispherical sky light; in the reference its sky part only where the sky is open.
    // (Leaves take the side of their normal that faces up.)
    let sky_normal = select(n, sign(n.y + 1e-6) * n, leaf);
    let sky_open = sky_visibility(in.world, sky_normal);
    let ambient = mix(frame.ground_ambient, frame.sky_ambient * sky_open, n.y * 0.5 + 0.5);
    return in.color * (frame.sun_color * direct * vis + ambient);
}

@fragment
fn fs_main(in_raw: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let in = textured(in_raw);
    count_fragment(in.clip, 0u);
    if frame.studio_output != 0u {
        return studio_map(in, front);
    }
    if frame.pixel_classes != 0u {
        return pixel_class(in);
    }
    return lit_and_fogged(in, front, false);
}

// The impostor bake's maps of a studio frame (`frame.studio_output`): 1, the unlit colour;
// 2, the normal as n * 0.5 + 0.5 with its sRGB encoding undone, so that the target's bytes
// hold it linearly, and the view depth mapped to [0, 1] in alpha (which is not encoded).
fn studio_map(in: VertexOut, front: bool) -> vec4<f32> {
    if frame.studio_output == 1u {
        return vec4<f32>(in.color, 1.0);
    }
    let n = surface_normal(in, front);
    let view_depth = dot(in.world - frame.camera_pos, frame.camera_forward);
    let depth = clamp((view_depth - frame.studio_depth_near) * frame.studio_depth_scale, 0.0, 1.0);
    return vec4<f32>(srgb_to_linear(n * 0.5 + 0.5), depth);
}

// The linear value whose sRGB encoding is `c` (IEC 61966-2-1).
fn srgb_to_linear(c: vec3<f32>) -> vec3<f32> {
    let lo = c / 12.92;
    let hi = pow((c + 0.055) / 1.055, vec3<f32>(2.4));
    return select(hi, lo, c <= vec3<f32>(0.04045));
}

// The pixel's class (see `Frame::pixel_classes`): ground red, near trees green (the
// distance matches NEAR_TREE_M in src/render/frame.rs), far trees blue.
fn pixel_class(in: VertexOut) -> vec4<f32> {
    if in.tree < 0.5 {
        return vec4<f32>(1.0, 0.0, 0.0, 1.0);
    }
    if length(frame.camera_pos - in.world) < 100.0 {
        return vec4<f32>(0.0, 1.0, 0.0, 1.0);
    }
    return vec4<f32>(0.0, 0.0, 1.0, 1.0);
}

fn lit_and_fogged(in: VertexOut, front: bool, own_cascades: bool) -> vec4<f32> {
    let dist = length(frame.camera_pos - in.world);
    return vec4<f32>(fog_and_exposure(shade_as(in, front, own_cascades), 1.0, dist), 1.0);
}

// `fs_main` for `hybrid`'s trees drawn as geometry: shadowed by their own cascades, and
// only the pixels under their opacity while they fade in.
@fragment
fn fs_faded(in_raw: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let in = textured(in_raw);
    count_fragment(in.clip, 0u);
    if dither_threshold(in.clip.xy) >= in.opacity {
        discard;
    }
    return lit_and_fogged(in, front, true);
}

// The texel bake's voxelisation (src/render/voxelize.rs): every fragment of an
// orthographic view marks its pixel as covered in the voxel it lies in and adds its lit
// colour there, so that one pass gives every slab at once. 6 words per voxel: fragments,
// red, green, blue (sums in fixed point, times `scale`), then a mask of the voxel's
// `ss` x `ss` pixels covered (64 bits: ss <= 8), so that two surfaces over one pixel of a
// voxel cover it once, as in a picture of the slab.
struct VoxelGrid {
    box_min: vec3<f32>,
    voxel: f32,
    dims: vec3<u32>,
    scale: f32,
    // Pixels per voxel side.
    ss: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}
@group(3) @binding(0) var<uniform> voxel_grid: VoxelGrid;
@group(3) @binding(1) var<storage, read_write> voxel_sums: array<atomic<u32>>;

@fragment
fn fs_voxel(in_raw: VertexOut, @builtin(front_facing) front: bool) {
    let in = textured(in_raw);
    let cell = vec3<i32>(floor((in.world - voxel_grid.box_min) / voxel_grid.voxel));
    if any(cell < vec3<i32>(0)) || any(cell >= vec3<i32>(voxel_grid.dims)) {
        return;
    }
    let c = max(shade(in, front), vec3<f32>(0.0)) * voxel_grid.scale;
    let d = voxel_grid.dims;
    let i = 6u * ((u32(cell.z) * d.y + u32(cell.y)) * d.x + u32(cell.x));
    atomicAdd(&voxel_sums[i], 1u);
    atomicAdd(&voxel_sums[i + 1u], u32(c.r + 0.5));
    atomicAdd(&voxel_sums[i + 2u], u32(c.g + 0.5));
    atomicAdd(&voxel_sums[i + 3u], u32(c.b + 0.5));
    // The image holds `ss` pixels per voxel side, aligned with the grid.
    let ss = max(voxel_grid.ss, 1u);
    let px = vec2<u32>(in.clip.xy);
    let bit = (px.y % ss) * ss + px.x % ss;
    if bit < 32u {
        atomicOr(&voxel_sums[i + 4u], 1u << bit);
    } else {
        atomicOr(&voxel_sums[i + 5u], 1u << (bit - 32u));
    }
}

// The reference's trees (src/render/self_shadow.rs): a tree's own needles shade it through
// its own sun map, a square around it alone, fine at any distance; everything else (other
// trees, the terrain) through the cascades, whose texels nearest the sun on this tree are
// left out (the tree would shade itself twice, the second time through coarse texels).
// (`SelfLight` and `self_lights` are in instancing.wgsl.)
@group(3) @binding(3) var self_maps: texture_depth_2d_array;
@group(3) @binding(4) var cascade_keys: texture_2d_array<u32>;

@fragment
fn fs_reference(in_raw: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let in = textured(in_raw);
    count_fragment(in.clip, 0u);
    if frame.studio_output != 0u {
        return studio_map(in, front);
    }
    if frame.pixel_classes != 0u {
        return pixel_class(in);
    }
    let n = surface_normal(in, front);
    let view_depth = dot(in.world - frame.camera_pos, frame.camera_forward);
    let offset_normal = shadow_offset_normal(in, n);
    var vis = 1.0;
    if frame.shadows_on != 0u {
        vis = others_visibility(in.world, offset_normal, view_depth, in.key)
            * own_visibility(in.world, offset_normal, in.slot);
    }
    let dist = length(frame.camera_pos - in.world);
    return vec4<f32>(fog_and_exposure(lit_by(in, n, vis), 1.0, dist), 1.0);
}

// `cascade_visibility` without the texels whose nearest caster is the tree `key`: each of
// the 3x3 taps a bilinear blend of 4 depth comparisons (as the comparison sampler's).
fn others_visibility(world: vec3<f32>, normal: vec3<f32>, view_depth: f32, key: u32) -> f32 {
    let cc = cascade_coords(world, normal, view_depth);
    if cc.w < 0.0 {
        return 1.0;
    }
    let uv = cc.xy;
    let c = i32(cc.w);
    let size = vec2<f32>(textureDimensions(shadow_map).xy);
    let step = frame.cascade_texel_uv * frame.pcf_radius;
    var lit = 0.0;
    for (var y = -1; y <= 1; y++) {
        for (var x = -1; x <= 1; x++) {
            let t = (uv + vec2<f32>(f32(x), f32(y)) * step) * size - 0.5;
            let f = fract(t);
            let i0 = vec2<i32>(floor(t));
            var s: array<f32, 4>;
            for (var k = 0; k < 4; k++) {
                let q = clamp(i0 + vec2<i32>(k & 1, k >> 1u), vec2<i32>(0), vec2<i32>(size) - 1);
                let d = textureLoad(shadow_map, q, c, 0);
                let own = textureLoad(cascade_keys, q, c, 0).r == key;
                s[k] = select(select(0.0, 1.0, cc.z <= d), 1.0, own);
            }
            lit += mix(mix(s[0], s[1], f.x), mix(s[2], s[3], f.x), f.y);
        }
    }
    return lit / 9.0;
}

// How much of the sun the tree in `slot` lets through to `world` (on it), from its own map.
fn own_visibility(world: vec3<f32>, normal: vec3<f32>, slot: u32) -> f32 {
    let l = self_lights[slot];
    let p = world + normal * l.texel_world * 1.5;
    let lp = l.matrix * vec4<f32>(p, 1.0);
    let ndc = lp.xyz / lp.w;
    let uv = ndc_to_uv(ndc.xy);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) || ndc.z > 1.0 {
        return 1.0;
    }
    let texel = 1.0 / f32(textureDimensions(self_maps).x);
    return pcf3x3(self_maps, i32(l.layer), uv, ndc.z, texel * max(frame.pcf_radius, 1.0));
}
