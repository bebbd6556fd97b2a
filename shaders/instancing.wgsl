// The instanced tree hierarchy (tree instances x parts) and the vertex format, shared by the
// passes that draw meshes. Prepended after frame.wgsl.

// One tree in the world: its transform and a foliage colour variation.
struct TreeInstance {
    model: mat4x4<f32>,
    tint: vec4<f32>,
}

// A set of parts drawn with one mesh: the trunk (1 part), the main branches' limbs (one per
// branch) or every twig of the tree (one per twig), each with its transform in the tree frame.
// An imported tree's parts are drawn one set per material: `alpha_cutoff` is its alpha test
// (0 for every other part: nothing discarded).
struct PartSet {
    count: u32,
    alpha_cutoff: f32,
    // 0: the set is untextured (every procedural part): its texel is white, unread.
    // 1: its texture is an imported material's. 2: the terrain, whose coarse levels read
    // its maps (`terrain_texels`), the rest its vertex colours.
    textured: u32,
    _pad2: u32,
    // The terrain's maps: a world point's grid coordinates (texel (i, j) being grid
    // point (i, j)) are (xz + terrain_map.x) * terrain_map.y.
    terrain_map: vec4<f32>,
}

@group(1) @binding(0) var<storage, read> trees: array<TreeInstance>;
@group(2) @binding(0) var<storage, read> parts: array<mat4x4<f32>>;
@group(2) @binding(1) var<uniform> part_set: PartSet;
// The part set's base-colour texture: an imported material's, or 1x1 white.
@group(2) @binding(2) var part_texture: texture_2d<f32>;
@group(2) @binding(3) var part_sampler: sampler;
// The terrain's normals and heights (xyz, w); 1x1 white for every other part set.
@group(2) @binding(4) var part_normals: texture_2d<f32>;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec3<f32>,
    @location(3) foliage: f32,
    @location(4) uv: vec2<f32>,
}

// The part set's texture at `uv`, or nothing (the fragment discarded) where its alpha is
// below the set's cut-off. Call it first, in uniform control flow.
fn part_texel(uv: vec2<f32>) -> vec4<f32> {
    if part_set.textured != 1u {
        return vec4<f32>(1.0);
    }
    let t = textureSample(part_texture, part_sampler, uv);
    if t.a < part_set.alpha_cutoff {
        discard;
    }
    return t;
}

// The full-detail terrain at world point `xz`: its colour (linear), unit normal and height,
// interpolated over the full grid's triangle there from its three grid points, exactly as
// the full-detail mesh interpolates its vertices (cells split along the diagonal from
// (0, 1) to (1, 0), `model::terrain::Terrain::mesh`).
struct TerrainTexel {
    color: vec3<f32>,
    normal: vec3<f32>,
    height: f32,
}

fn terrain_texels(xz: vec2<f32>) -> TerrainTexel {
    let g = (xz + part_set.terrain_map.x) * part_set.terrain_map.y;
    let last = vec2<f32>(textureDimensions(part_texture)) - 2.0;
    let cell = clamp(floor(g), vec2<f32>(0.0), last);
    let f = g - cell;
    let i = vec2<i32>(cell);
    // Weights of the corners 00, 10, 01, 11: the lower triangle (00, 10, 01) where
    // f.x + f.y <= 1, the upper (10, 01, 11) elsewhere.
    let upper = f.x + f.y > 1.0;
    let w = select(
        vec4<f32>(1.0 - f.x - f.y, f.x, f.y, 0.0),
        vec4<f32>(0.0, 1.0 - f.y, 1.0 - f.x, f.x + f.y - 1.0),
        upper,
    );
    var c = vec3<f32>(0.0);
    var nh = vec4<f32>(0.0);
    let corners = array<vec2<i32>, 4>(vec2<i32>(0, 0), vec2<i32>(1, 0), vec2<i32>(0, 1), vec2<i32>(1, 1));
    for (var k = 0; k < 4; k++) {
        c += w[k] * textureLoad(part_texture, i + corners[k], 0).rgb;
        nh += w[k] * textureLoad(part_normals, i + corners[k], 0);
    }
    return TerrainTexel(c, normalize(nh.xyz + vec3<f32>(0.0, 1e-4, 0.0)), nh.w);
}

// Instance `i` of a draw is part `i % count` of tree `i / count`: the hierarchy is drawn
// as it is stored, never flattened into per-part world matrices.
fn instance_model(instance: u32) -> mat4x4<f32> {
    let count = max(part_set.count, 1u);
    return trees[instance / count].model * parts[instance % count];
}

fn instance_tint(instance: u32) -> vec3<f32> {
    let count = max(part_set.count, 1u);
    return trees[instance / count].tint.rgb;
}

// The tree's opacity: 1, or less while `hybrid` fades it in over its twig billboards.
fn instance_opacity(instance: u32) -> f32 {
    let count = max(part_set.count, 1u);
    return trees[instance / count].tint.a;
}

// A key naming the tree of a draw's slot `slot` (its index in the tree buffer) the same in
// every pass that draws it, whatever slot it has there: a hash of its position, never 0.
// Slot 0 is the terrain's, whose key is 0.
fn tree_key(slot: u32) -> u32 {
    if slot == 0u {
        return 0u;
    }
    let t = trees[slot].model[3];
    var h = 2166136261u;
    h = (h ^ bitcast<u32>(t.x)) * 16777619u;
    h = (h ^ bitcast<u32>(t.y)) * 16777619u;
    h = (h ^ bitcast<u32>(t.z)) * 16777619u;
    return h | 1u;
}

// The slot of instance `instance` of a draw in the tree buffer.
fn instance_slot(instance: u32) -> u32 {
    return instance / max(part_set.count, 1u);
}

// The reference's per-tree sun maps (src/render/self_shadow.rs): the light matrix of the
// tree in each slot of the tree buffer, a square around its bounding sphere seen from the
// sun (`SelfLightGpu`).
struct SelfLight {
    matrix: mat4x4<f32>,
    // World size of one texel of the tree's map.
    texel_world: f32,
    // Layer of the map array that holds the tree's map.
    layer: u32,
    _pad0: u32,
    _pad1: u32,
}
@group(3) @binding(2) var<storage, read> self_lights: array<SelfLight>;
