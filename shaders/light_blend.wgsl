// The `btf` method's light blends, made again when the sun moves: for each tree-level image
// set, yaw bin and view sample, the 3 light images a tree of that yaw would blend, summed
// with their weights (normalised to 1; the billboard scales back by their sum) into one
// image of the same texture array, in layers after the baked images. One pass per mip
// level and layer of the blends; each image of the layer is an instanced quad over its
// square, each texel the weighted sum of the same texel of the same mip level of the 3
// baked images (the mips are box filters, linear, so the blend of each level is the level
// of the blend). `BTF_ATLAS_SIDE` is prepended by src/render/shaders.rs.

// One blended image: the baked images of its 3 lights (indices into the atlas) and their
// weights, summing to 1 (0 for a culled light).
struct BlendImage {
    source: vec4<u32>,
    weight: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> blend_images: array<BlendImage>;
// The baked images' layers alone (the blends' layers are the target).
@group(0) @binding(1) var btf_images: texture_2d_array<f32>;

struct BlendOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) image: u32,
    @location(1) @interpolate(flat) mip: u32,
}

// Instance: the blended image, counted from the first (which starts a layer); vertex: 6 a
// quad, the mip level drawn being `vertex_index / 6` (the draw's first vertex says which).
@vertex
fn vs_blend(@builtin(vertex_index) vi: u32, @builtin(instance_index) image: u32) -> BlendOut {
    var xs = array<f32, 6>(0.0, 1.0, 1.0, 0.0, 1.0, 0.0);
    var ys = array<f32, 6>(0.0, 0.0, 1.0, 0.0, 1.0, 1.0);
    let corner = vec2<f32>(xs[vi % 6u], ys[vi % 6u]);
    let slot = image % (BTF_ATLAS_SIDE * BTF_ATLAS_SIDE);
    let cell = vec2<f32>(f32(slot % BTF_ATLAS_SIDE), f32(slot / BTF_ATLAS_SIDE));
    // Texture rows run down, clip space up.
    let t = (cell + corner) / f32(BTF_ATLAS_SIDE);
    var out: BlendOut;
    out.clip = vec4<f32>(t.x * 2.0 - 1.0, 1.0 - t.y * 2.0, 0.0, 1.0);
    out.image = image;
    out.mip = vi / 6u;
    return out;
}

// Texel `local` of image `index` at level `mip` (`res` texels a side there).
fn btf_texel(index: u32, local: vec2<u32>, mip: u32, res: u32) -> vec4<f32> {
    let per_layer = BTF_ATLAS_SIDE * BTF_ATLAS_SIDE;
    let slot = index % per_layer;
    let cell = vec2<u32>(slot % BTF_ATLAS_SIDE, slot / BTF_ATLAS_SIDE);
    return textureLoad(btf_images, cell * res + local, i32(index / per_layer), i32(mip));
}

@fragment
fn fs_blend(in: BlendOut) -> @location(0) vec4<f32> {
    let res = max(textureDimensions(btf_images, i32(in.mip)).x / BTF_ATLAS_SIDE, 1u);
    let slot = in.image % (BTF_ATLAS_SIDE * BTF_ATLAS_SIDE);
    let cell = vec2<u32>(slot % BTF_ATLAS_SIDE, slot / BTF_ATLAS_SIDE);
    let local = min(vec2<u32>(in.clip.xy) - cell * res, vec2<u32>(res - 1u));
    let b = blend_images[in.image];
    var sum = vec4<f32>(0.0);
    for (var j = 0; j < 3; j++) {
        if b.weight[j] > 0.0 {
            sum += b.weight[j] * btf_texel(b.source[j], local, in.mip, res);
        }
    }
    return sum;
}
