// The trees' layer (src/render/layer.rs): blended trees drawn front to back into a
// transparent layer of their own ("under": each fragment adds what the layer in front of it
// still lets through), then put over the frame once. Two full-screen passes over it:
//
// - `fs_opaque`, between batches of trees: where the layer already lets less than
//   `OPAQUE_BELOW` through, the pixel's depth goes to the near plane, so that the early
//   depth test skips every later (farther) tree's fragments there;
// - `fs_composite`, at the end: the layer, premultiplied, over the frame.

@group(0) @binding(0) var layer: texture_2d<f32>;

// The transmittance below which a pixel counts as opaque (what is behind adds at most this
// fraction of its own colour).
override OPAQUE_BELOW: f32 = 0.004;

@vertex
fn vs_layer(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the screen, at the near plane (reversed Z: depth 1).
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 1.0, 1.0);
}

@fragment
fn fs_opaque(@builtin(position) p: vec4<f32>) {
    let alpha = textureLoad(layer, vec2<i32>(p.xy), 0).a;
    if 1.0 - alpha >= OPAQUE_BELOW {
        discard;
    }
}

@fragment
fn fs_composite(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    return textureLoad(layer, vec2<i32>(p.xy), 0);
}
