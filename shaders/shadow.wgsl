// Shadow pass: depth only, seen from the sun, one cascade per pass. `frame.view_proj` holds
// the cascade's light matrix. Leaves are two-sided, so nothing is culled.

@vertex
fn vs_shadow(v: VertexIn, @builtin(instance_index) instance: u32) -> @builtin(position) vec4<f32> {
    let world = instance_model(instance) * vec4<f32>(v.position, 1.0);
    return frame.view_proj * world;
}
