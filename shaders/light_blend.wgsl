// The `btf` method's light blends, made again when the sun moves: for each tree-level image
// set, yaw bin and view sample, the 3 light images a tree of that yaw would blend, summed
// with their weights (normalised to 1; the billboard scales back by their sum) into one
// image of the same texture array, in layers after the baked images. One compute pass:
// a dispatch per mip level over every texel of the blends' layers, each texel the weighted
// sum of the same texel of the same mip level of the 3 baked images (the mips are box
// filters, linear, so the blend of each level is the level of the blend), written as 8-bit
// sRGB. `BTF_ATLAS_SIDE` is prepended by src/render/shaders.rs.

// One blended image: the baked images of its 3 lights (indices into the atlas) and their
// weights, summing to 1 (0 for a culled light).
struct BlendImage {
    source: vec4<u32>,
    weight: vec4<f32>,
}

// What one dispatch writes: the blended images (counted from the one at the first blend
// layer's first slot) and the mip level.
struct BlendLevel {
    count: u32,
    mip: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> blend_images: array<BlendImage>;
// The baked images' layers alone, read as sRGB (decoded to linear).
@group(0) @binding(1) var btf_images: texture_2d_array<f32>;
// The blends' layers at this dispatch's mip level, written as plain 8-bit values (the
// texels are sRGB-encoded here).
@group(0) @binding(2) var blends: texture_storage_2d_array<rgba8unorm, write>;
@group(0) @binding(3) var<uniform> level: BlendLevel;

// Texel `local` of image `index` at level `mip` (`res` texels a side there).
fn btf_texel(index: u32, local: vec2<u32>, mip: u32, res: u32) -> vec4<f32> {
    let per_layer = BTF_ATLAS_SIDE * BTF_ATLAS_SIDE;
    let slot = index % per_layer;
    let cell = vec2<u32>(slot % BTF_ATLAS_SIDE, slot / BTF_ATLAS_SIDE);
    return textureLoad(btf_images, cell * res + local, i32(index / per_layer), i32(mip));
}

// Linear `x` as its 8-bit sRGB code (rounded to nearest), as a unorm value a quarter code
// above it: the same code whether the store rounds or truncates (both are allowed).
fn srgb_code(x: vec3<f32>) -> vec3<f32> {
    let c = clamp(x, vec3<f32>(0.0), vec3<f32>(1.0));
    let s = select(1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - 0.055, c * 12.92, c <= vec3<f32>(0.0031308));
    return (round(s * 255.0) + 0.25) / 255.0;
}

@compute @workgroup_size(8, 8, 1)
fn cs_blend(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(blends);
    if id.x >= size.x || id.y >= size.y || id.z >= textureNumLayers(blends) {
        return;
    }
    let res = max(size.x / BTF_ATLAS_SIDE, 1u);
    let cell = id.xy / res;
    let local = id.xy - cell * res;
    let image = id.z * BTF_ATLAS_SIDE * BTF_ATLAS_SIDE + cell.y * BTF_ATLAS_SIDE + cell.x;
    var sum = vec4<f32>(0.0);
    if image < level.count {
        let b = blend_images[image];
        for (var j = 0; j < 3; j++) {
            if b.weight[j] > 0.0 {
                sum += b.weight[j] * btf_texel(b.source[j], local, level.mip, res);
            }
        }
    }
    let alpha = (round(clamp(sum.a, 0.0, 1.0) * 255.0) + 0.25) / 255.0;
    textureStore(blends, id.xy, id.z, vec4<f32>(srgb_code(sum.rgb), alpha));
}
