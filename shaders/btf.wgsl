// BTF billboard pass (Meyer 2001, ch. 5 and annex A, on one fragment pass): each billboard
// blends its 3 nearest views x (3 nearest lights + the sky-lit and the ground-lit image),
// weighted, from one texture array (a tree-level billboard with `light_blend` reads its
// 3 lights' blend, made once per sun and yaw bin in the same array, instead of the 3
// lights: 9 reads), and is composited back to front with premultiplied alpha,
// T = M + (1 - M_alpha) T0, which is the thesis' equation A.2 without its extra passes.
// With crossed planes the sum M = sum of w_k M_k runs over the three planes where the eye's
// ray meets each at this pixel, so they too are blended as annex A says, never one plane
// "over" another.

// The VCM sun and sky factors at `p` (object frame, radii): the billboard's own level per
// point, times the coarser levels' from its centre.
fn vcm_factors(b: Billboard, p: vec3<f32>) -> vec2<f32> {
    let u = b.vcm_box_origin + p * b.vcm_box_scale;
    return vec2<f32>(
        trilinear(b.vcm_direct[0], b.vcm_direct[1], u) * b.parent_direct,
        trilinear(b.vcm_sky[0], b.vcm_sky[1], u) * b.parent_sky,
    );
}

@fragment
fn fs_billboard(in: BillboardOut) -> @location(0) vec4<f32> {
    let b = flat_billboard(in);
    let crossed = b.planes == 3u;
    // Each view sample's point under this pixel and its image coordinates with their
    // screen derivatives, taken in uniform control flow (the samples below use them
    // explicitly): on a single plane the quad's own point for every view, and the image
    // coordinates the vertex stage found; on crossed planes the point of that view's plane.
    // Loops of 0 or 1 turns rather than selects, which would do the crossed planes' work
    // for every billboard (a CPU rasteriser runs a loop's turns only where some fragment
    // takes them).
    var pts: array<vec4<f32>, 3>;
    var texs: array<ViewTexcoords, 3>;
    let uvs = array<vec2<f32>, 3>(in.uv01.xy, in.uv01.zw, in.uv2);
    let hit_from = select(1u, 0u, crossed);
    for (var k = 0; k < 3; k++) {
        var q = vec4<f32>(in.p, 1.0);
        for (var c = hit_from; c < 1u; c++) {
            q = view_plane_hit(b.view_index[k], in.eye, in.p);
        }
        let dqx = dpdx(q.xyz);
        let dqy = dpdy(q.xyz);
        var t = ViewTexcoords(uvs[k], dpdx(uvs[k]), dpdy(uvs[k]));
        for (var c = hit_from; c < 1u; c++) {
            t = view_texcoords(b.view_index[k], q.xyz, dqx, dqy);
        }
        pts[k] = q;
        texs[k] = t;
    }
    let s = shade_billboard(b, pts, texs, in.world, 3u);
    count_fragment(in.clip, s.reads);
    return s.color;
}

// A billboard's colour at one point, premultiplied, with the images read for it: `pts` and
// `texs` are each view sample's point on the billboard (object frame, radii; w 0 where
// that view's plane is missed) and its image coordinates with their screen gradients;
// `world` is the point in the world (for the fog); the first `views` view samples are
// blended (3: all, the method itself; 1: the first alone, at full weight, the tile
// compositor's cheap shade behind the layers that decide a pixel). The fragment pass and
// the tile compositor (`compositor.wgsl`) both shade through it.
struct Shaded {
    color: vec4<f32>,
    reads: u32,
}

fn shade_billboard(
    b: Billboard,
    pts_in: array<vec4<f32>, 3>,
    texs_in: array<ViewTexcoords, 3>,
    world: vec3<f32>,
    views: u32,
) -> Shaded {
    let pts = pts_in;
    let texs = texs_in;
    let alone = views < 3u;
    let lights = b.light_count;
    let base = b.layer_base;
    var color = vec3<f32>(0.0);
    var alpha = 0.0;
    var shadow = 0.0;
    var reads = 0u;
    // A loop of `views` turns: a CPU driver runs the turns some invocation takes.
    for (var k = 0; k < i32(views); k++) {
        let wv = select(b.view_weight[k], 1.0, alone);
        if wv <= 0.0 || pts[k].w == 0.0 {
            continue;
        }
        let v = b.view_index[k];
        let t = texs[k];
        let f = vcm_factors(b, pts[k].xyz);
        let amb = btf_sample(base + b.view_count * lights + v, t.uv, t.gx, t.gy);
        // The light the ground sends up, as the geometry's ambient has it: never hidden, so
        // no cube map darkens it.
        let gnd = btf_sample(base + b.view_count * (lights + 1u) + v, t.uv, t.gx, t.gy);
        reads += 2u;
        var c = amb.rgb * frame.sky_ambient * f.y + gnd.rgb * frame.ground_ambient;
        // The lights' images, weighted: 3 of them, or with `light_blend` one, their blend
        // made once for this sun and the billboard's yaw bin (normalised: their weights'
        // sum scales it back). A loop of 1 or 3 turns (the same for every fragment of a
        // billboard) rather than a branch: a CPU rasteriser runs both sides of a branch
        // but only the turns some fragment takes.
        let blended = b.light_blend != NO_LIGHT_BLEND;
        let turns = select(3u, 1u, blended);
        let wsum = b.light_weight.x + b.light_weight.y + b.light_weight.z;
        var direct = vec3<f32>(0.0);
        var j = 0u;
        loop {
            let wl = select(b.light_weight[j], wsum, blended);
            let layer = select(base + v * lights + b.light_index[j], b.light_blend + v, blended);
            if wl > 0.0 {
                direct += wl * btf_sample(layer, t.uv, t.gx, t.gy).rgb;
                reads += 1u;
            }
            continuing {
                j++;
                break if j >= turns;
            }
        }
        c += direct * frame.sun_color * f.x;
        color += wv * c;
        alpha += wv * amb.a;
        shadow += wv * amb.a * f.x;
    }
    if b.mode == MODE_SUN_FACTOR {
        color = vec3<f32>(shadow);
    } else if b.mode == MODE_TINT {
        color = b.tint * alpha;
    } else {
        color *= b.tint;
    }
    let dist = length(frame.camera_pos - world);
    return Shaded(vec4<f32>(fog_and_exposure(color, alpha, dist), alpha) * b.opacity, reads);
}
