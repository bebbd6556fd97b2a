// The ground shadow maps' pass, seen from the sun over the whole scene: the terrain white
// with depth (vertex stage `vs_shadow` of shadow.wgsl; it lets all light through, so it
// casts nothing in the alpha map, but it hides the trees behind it and its depth is the
// terrain's own shadow map), then every tree's billboard multiplying the transmittance.

@fragment
fn fs_white() -> @location(0) vec4<f32> {
    return vec4<f32>(1.0);
}

// Opacity only, for the ground alpha shadow map: blended as dst * (1 - alpha), so the map
// holds the transmittance of every tree between the sun and the ground.
@fragment
fn fs_opacity(in: BillboardOut) -> @location(0) vec4<f32> {
    let b = flat_billboard(in);
    let dpx = dpdx(in.p);
    let dpy = dpdy(in.p);
    var alpha = 0.0;
    for (var k = 0; k < 3; k++) {
        let wv = b.view_weight[k];
        if wv <= 0.0 {
            continue;
        }
        let v = b.view_index[k];
        let t = view_texcoords(v, in.p, dpx, dpy);
        alpha += wv * btf_sample(b.layer_base + b.view_count * b.light_count + v, t.uv, t.gx, t.gy).a;
    }
    return vec4<f32>(0.0, 0.0, 0.0, alpha * b.opacity);
}
