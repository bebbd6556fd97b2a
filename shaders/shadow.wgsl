// Shadow pass: depth only, seen from the sun, one cascade per pass. `frame.view_proj` holds
// the cascade's light matrix. Leaves are two-sided, so nothing is culled. An imported
// tree's cards cast the shadow of their texture's cut-out (`fs_shadow_cutout`).

struct LightOut {
    @builtin(position) clip: vec4<f32>,
    @location(1) uv: vec2<f32>,
}

@vertex
fn vs_shadow(v: VertexIn, @builtin(instance_index) instance: u32) -> LightOut {
    return LightOut(light_clip(v, instance), v.uv);
}

// The depth-only passes' fragment stage: the part set's alpha test, nothing written.
@fragment
fn fs_shadow_cutout(in: LightOut) {
    _ = part_texel(in.uv);
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
    @location(1) uv: vec2<f32>,
}

@vertex
fn vs_shadow_keyed(v: VertexIn, @builtin(instance_index) instance: u32) -> KeyedOut {
    var out: KeyedOut;
    out.clip = light_clip(v, instance);
    out.key = tree_key(instance_slot(instance));
    out.uv = v.uv;
    return out;
}

@fragment
fn fs_shadow_keyed(in: KeyedOut) -> @location(0) u32 {
    _ = part_texel(in.uv);
    return in.key;
}

// The reference's per-tree sun maps: each tree alone, seen from the sun through the light
// matrix of its slot (`self_lights`, instancing.wgsl).

@vertex
fn vs_self_shadow(v: VertexIn, @builtin(instance_index) instance: u32) -> LightOut {
    let world = instance_model(instance) * vec4<f32>(v.position, 1.0);
    return LightOut(self_lights[instance_slot(instance)].matrix * world, v.uv);
}
