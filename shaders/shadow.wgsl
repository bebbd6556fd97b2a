// Shadow pass: depth only, seen from the sun, one cascade per pass. `frame.view_proj` holds
// the cascade's light matrix. Leaves are two-sided, so nothing is culled.

@vertex
fn vs_shadow(v: VertexIn, @builtin(instance_index) instance: u32) -> @builtin(position) vec4<f32> {
    let world = instance_model(instance) * vec4<f32>(v.position, 1.0);
    return frame.view_proj * world;
}

// The terrain in the ground alpha shadow map: white (it lets all light through, so it casts
// nothing there) but it writes depth, so it hides the trees behind it from the sun.
@fragment
fn fs_white() -> @location(0) vec4<f32> {
    return vec4<f32>(1.0);
}
