// Sky pass: a full-screen triangle behind everything, a gradient from horizon to zenith and
// the sun's disc, so the background matches the ambient light the scene is lit with.

struct SkyOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) ndc: vec2<f32>,
}

@vertex
fn vs_sky(@builtin(vertex_index) i: u32) -> SkyOut {
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    let ndc = uv * 2.0 - 1.0;
    var out: SkyOut;
    out.clip = vec4<f32>(ndc, 0.0, 1.0);
    out.ndc = ndc;
    return out;
}

@fragment
fn fs_sky(in: SkyOut) -> @location(0) vec4<f32> {
    count_fragment(in.clip, 0u);
    if frame.pixel_classes != 0u {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let p = frame.inv_view_proj * vec4<f32>(in.ndc, 0.5, 1.0);
    let dir = normalize(p.xyz / p.w - frame.camera_pos);
    let up = clamp(dir.y, 0.0, 1.0);
    var c = mix(frame.sky_horizon, frame.sky_zenith, sqrt(up));
    if dir.y < 0.0 {
        c = mix(frame.sky_horizon, frame.ground_ambient, clamp(-dir.y * 4.0, 0.0, 1.0));
    }
    let cos_sun = dot(dir, frame.sun_dir);
    let sun = frame.sun_color / max(max(frame.sun_color.r, frame.sun_color.g), max(frame.sun_color.b, 1e-3));
    c += sun * (smoothstep(0.99995, 0.99998, cos_sun) * 4.0 + pow(max(cos_sun, 0.0), 200.0) * 0.25);
    return vec4<f32>(c * frame.exposure, 1.0);
}
