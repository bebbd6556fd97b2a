// Shadow pass: depth only, seen from the sun, one cascade per pass. `frame.view_proj` holds
// the cascade's light matrix. Leaves are two-sided, so nothing is culled.

@vertex
fn vs_shadow(v: VertexIn, @builtin(instance_index) instance: u32) -> @builtin(position) vec4<f32> {
    return light_clip(v, instance);
}

fn light_clip(v: VertexIn, instance: u32) -> vec4<f32> {
    let world = instance_model(instance) * vec4<f32>(v.position, 1.0);
    return frame.view_proj * world;
}

// The reference's cascades also keep which tree is nearest the sun in each texel
// (`tree_key`; 0 for the terrain), so that a tree can leave itself out of them and take its
// own shadows from its own map (src/render/self_shadow.rs).
struct KeyedOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) key: u32,
}

@vertex
fn vs_shadow_keyed(v: VertexIn, @builtin(instance_index) instance: u32) -> KeyedOut {
    var out: KeyedOut;
    out.clip = light_clip(v, instance);
    out.key = tree_key(instance_slot(instance));
    return out;
}

@fragment
fn fs_shadow_keyed(in: KeyedOut) -> @location(0) u32 {
    return in.key;
}

// The reference's per-tree sun maps: each tree alone, seen from the sun through the light
// matrix of its slot (`self_lights`, instancing.wgsl).

@vertex
fn vs_self_shadow(v: VertexIn, @builtin(instance_index) instance: u32) -> @builtin(position) vec4<f32> {
    let world = instance_model(instance) * vec4<f32>(v.position, 1.0);
    return self_lights[instance_slot(instance)].matrix * world;
}
