// The overdraw view (src/render/overdraw.rs), drawn over the finished frame with the sky's
// full-screen triangle: each pixel's count of shaded fragments (or of the images they read,
// `frame.overdraw.w` = 1) as a heat map on a fixed logarithmic scale, and that scale as a
// bar of labelled steps in the bottom-left corner. The counters are `overdraw_counts`
// (frame.wgsl), filled by `count_fragment` during the frame.

// The scale's steps: 0, then `step` x 1, 2, 4, ... 256 (step 1 for fragments, 8 for reads).
const STEPS: u32 = 10u;

// 3x5 pixel digits 0-9, row by row from the top, 3 bits a row, the left pixel highest.
const DIGITS = array<u32, 10>(31599u, 11415u, 29671u, 29647u, 23497u, 31183u, 31215u, 29257u, 31727u, 31695u);

fn scale_step() -> u32 {
    return select(1u, 8u, frame.overdraw.w == 1u);
}

// Black at 0; then blue, cyan, green, yellow, red and white as `t` goes from 0 to 1.
fn heat(t: f32) -> vec3<f32> {
    let stops = array<vec3<f32>, 6>(
        vec3<f32>(0.1, 0.1, 0.9),
        vec3<f32>(0.0, 0.8, 0.9),
        vec3<f32>(0.1, 0.85, 0.1),
        vec3<f32>(0.95, 0.9, 0.0),
        vec3<f32>(0.95, 0.1, 0.05),
        vec3<f32>(1.0, 1.0, 1.0),
    );
    let x = clamp(t, 0.0, 1.0) * 5.0;
    let i = min(u32(x), 4u);
    return mix(stops[i], stops[i + 1u], x - f32(i));
}

// The colour of a count: step k of the scale (count = step x 2^(k-1)) at k / (STEPS - 1).
fn count_colour(count: u32) -> vec3<f32> {
    if count == 0u {
        return vec3<f32>(0.0);
    }
    let k = log2(f32(count) / f32(scale_step())) + 1.0;
    return heat(clamp(k, 1.0, f32(STEPS - 1u)) / f32(STEPS - 1u));
}

// Whether pixel `p` (in glyph pixels from the number's top left) is lit in `value` written
// in decimal.
fn number_pixel(value: u32, p: vec2<u32>) -> bool {
    var digits = 1u;
    var v = value;
    while v >= 10u {
        v /= 10u;
        digits += 1u;
    }
    let d = p.x / 4u;
    let col = p.x % 4u;
    if d >= digits || col == 3u || p.y >= 5u {
        return false;
    }
    var place = 1u;
    for (var k = 0u; k + 1u + d < digits; k++) {
        place *= 10u;
    }
    let glyph = DIGITS[(value / place) % 10u];
    return ((glyph >> (14u - (p.y * 3u + col))) & 1u) == 1u;
}

// The legend at pixel `at`: its colour, alpha 1 where it covers the pixel.
fn legend(at: vec2<u32>) -> vec4<f32> {
    let s = select(1u, 2u, frame.overdraw.y >= 480u);
    let cell = 18u * s;
    let x0 = 4u * s;
    let bottom = frame.overdraw.z - min(4u * s, frame.overdraw.z);
    let bar_top = bottom - min(6u * s, bottom);
    let text_top = bar_top - min(7u * s, bar_top);
    let x1 = x0 + STEPS * cell;
    if at.x + 2u * s < x0 || at.x >= x1 + 2u * s || at.y + 2u * s < text_top || at.y >= bottom + 2u * s {
        return vec4<f32>(0.0);
    }
    let dark = vec4<f32>(0.08, 0.08, 0.08, 1.0);
    if at.x < x0 || at.x >= x1 {
        return dark;
    }
    let k = (at.x - x0) / cell;
    let value = select(0u, scale_step() << (k - 1u), k > 0u);
    if at.y >= bar_top && at.y < bottom {
        // A dark line between steps.
        if (at.x - x0) % cell < s {
            return dark;
        }
        return vec4<f32>(count_colour(value), 1.0);
    }
    if at.y >= text_top && at.y < text_top + 5u * s {
        let p = vec2<u32>((at.x - x0 - k * cell) / s, (at.y - text_top) / s);
        if p.x >= 1u && number_pixel(value, p - vec2<u32>(1u, 0u)) {
            return vec4<f32>(1.0);
        }
    }
    return dark;
}

@fragment
fn fs_overdraw(in: SkyOut) -> @location(0) vec4<f32> {
    let at = vec2<u32>(in.clip.xy);
    let l = legend(at);
    if l.a > 0.0 {
        return l;
    }
    let i = 2u * (at.y * frame.overdraw.y + at.x) + min(frame.overdraw.w, 1u);
    return vec4<f32>(count_colour(atomicLoad(&overdraw_counts[i])), 1.0);
}
