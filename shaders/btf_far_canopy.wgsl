// The far canopy's colours (appended to btf_far.wgsl): each tree the canopy stands for
// gets the colour its tree-level billboard would show on average this frame. The billboard's
// sum over its 3 views x (3 lights + the sky-lit and the ground-lit image) is taken with
// each image's mean (premultiplied, linear; one row of `tables` per image from
// `params.means_at`) instead of its texels, the VCM factors as the mean of the 8 corners',
// and divided by the mean coverage: the colour of the crown where it covers.

// Each tree's colour (rgb; w = 1 once made), read by `canopy.wgsl`.
@group(0) @binding(9) var<storage, read_write> canopy_colours: array<vec4<f32>>;

fn image_mean(image: u32) -> vec4<f32> {
    return bitcast<vec4<f32>>(tables[params.means_at + image]);
}

fn mean8(v: array<vec4<f32>, 2>) -> f32 {
    return dot(v[0] + v[1], vec4<f32>(0.125));
}

fn canopy_colour(i: u32, tree: FarTree) {
    let m = tree.model;
    let scale = length(m[0].xyz);
    if !(scale > 0.0 && scale <= 3.4e38) {
        return;
    }
    let set_at = set_row(tree.species, LEVEL_TREE);
    let center = (m * vec4<f32>(row3(set_at), 1.0)).xyz;
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
    var f = vec2<f32>(1.0);
    if params.vcm != 0u {
        let sh = shade_of(i);
        f.x = mean8(sh.direct);
        if params.vcm == 1u {
            f.y = mean8(sh.sky);
        }
    }
    let base = tables[set_at + 1u].w;
    let nv = params.views.count;
    let nl = params.lights.count;
    var colour = vec3<f32>(0.0);
    var alpha = 0.0;
    for (var k = 0u; k < 3u; k++) {
        let wv = vb.weight[k];
        if wv <= 0.0 {
            continue;
        }
        let v = vb.index[k];
        let amb = image_mean(base + nv * nl + v);
        let gnd = image_mean(base + nv * (nl + 1u) + v);
        var direct = vec3<f32>(0.0);
        for (var j = 0u; j < 3u; j++) {
            if lb.weight[j] > 0.0 {
                direct += lb.weight[j] * image_mean(base + v * nl + lb.index[j]).rgb;
            }
        }
        colour += wv * (amb.rgb * params.sky_ambient * f.y + gnd.rgb * params.ground_ambient
            + direct * params.sun_color * f.x);
        alpha += wv * amb.a;
    }
    canopy_colours[i] = vec4<f32>(colour * tree.tint / max(alpha, 1e-4), 1.0);
}
