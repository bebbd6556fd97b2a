// The billboard record of the image-based methods, shared by the passes that draw billboards
// (`billboard.wgsl`) and the compute pass that builds the far trees' records on the GPU
// (`btf_far.wgsl`). `BillboardGpu` in src/render/method/btf/billboard.rs mirrors it byte for
// byte (checked by tests/gpu_layout.rs).

struct Billboard {
    // World centre of the quad.
    center: vec3<f32>,
    // World radius (half the quad's side).
    radius: f32,
    // The quad's right axis in the world (unit); with the up axis, it faces the eye.
    plane_right: vec3<f32>,
    // 1: a single plane facing the eye, each view's image reprojected onto it; 3: crossed
    // planes, each view's image on the plane facing that view (the quad then only bounds
    // them, and the fragment finds where the eye's ray meets each).
    planes: u32,
    // The quad's up axis in the world (unit).
    plane_up: vec3<f32>,
    // Opacity of the whole billboard (the LOD cross-fade).
    opacity: f32,
    // The quad's axes in the object frame, where the images were taken.
    obj_right: vec3<f32>,
    _pad0: f32,
    obj_up: vec3<f32>,
    _pad1: f32,
    // Sample indices of the 3 nearest views.
    view_index: vec3<u32>,
    // First layer of this object's image set in the texture array.
    layer_base: u32,
    // Sample indices of the 3 nearest lights.
    light_index: vec3<u32>,
    // Number of light samples of the bake.
    light_count: u32,
    // View weights (0 = culled).
    view_weight: vec3<f32>,
    // Number of view samples of the bake.
    view_count: u32,
    // Light weights (0 = culled).
    light_weight: vec3<f32>,
    // The first of this billboard's light-blended images in the texture array
    // (`light_blend.wgsl`; one per view sample, in view order), read instead of its lights'
    // images; NO_LIGHT_BLEND for none. They are the blend normalised: the light weights'
    // sum scales them back.
    light_blend: u32,
    // Colour tint of the tree, or the overlay colour.
    tint: vec3<f32>,
    // What the fragment shows: MODE_IMAGES, MODE_TINT or MODE_SUN_FACTOR.
    mode: u32,
    // Visibility cube maps (Meyer 2001, 5.2): the billboard centre in its object's box
    // coordinates (0..1 from the box's min to its max corner).
    vcm_box_origin: vec3<f32>,
    // The coarser levels' sun factor at the billboard's centre.
    parent_direct: f32,
    // Box coordinates per unit of `p`.
    vcm_box_scale: vec3<f32>,
    // The coarser levels' sky factor at the billboard's centre.
    parent_sky: f32,
    // Sun visibility at the 8 box corners (corner k: bit 0 = max x, bit 1 = max y,
    // bit 2 = max z), then sky visibility at the same corners.
    vcm_direct: array<vec4<f32>, 2>,
    vcm_sky: array<vec4<f32>, 2>,
}

// `Billboard::light_blend`: the billboard blends its light images itself.
const NO_LIGHT_BLEND: u32 = 0xffffffffu;

// `Billboard::mode`: the weighted images (the method itself).
const MODE_IMAGES: u32 = 0u;
// The tint alone, times coverage (the LOD-level overlay).
const MODE_TINT: u32 = 1u;
// The VCM sun factor in grey, times coverage.
const MODE_SUN_FACTOR: u32 = 2u;

