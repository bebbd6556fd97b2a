//! One billboard as the GPU reads it, and where its image set sits in the texture array.

use glam::Vec3;

use crate::model::mesh::Aabb;
use crate::render::vcm_shading::Shade;

/// What a billboard's fragments show (`Billboard::mode` in `billboard.wgsl`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum BillboardMode {
    /// The weighted images: the method itself.
    Images = 0,
    /// The tint alone, times coverage (the LOD-level overlay).
    Tint = 1,
    /// The VCM sun factor in grey, times coverage.
    SunFactor = 2,
}

/// One billboard as `billboard.wgsl` reads it (`struct Billboard`), byte for byte: each
/// `[_; 3]` is a WGSL `vec3` and the scalar after it fills its 16-byte slot (checked against
/// the WGSL by tests/gpu_layout.rs).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BillboardGpu {
    /// World centre of the quad.
    pub center: [f32; 3],
    /// World radius (half the quad's side).
    pub radius: f32,
    /// The quad's right axis in the world (unit).
    pub plane_right: [f32; 3],
    /// 1: one plane facing the eye; 3: crossed planes, one facing each sampled view (the
    /// quad then bounds them and the fragment shader finds each plane's point).
    pub planes: u32,
    /// The quad's up axis in the world (unit).
    pub plane_up: [f32; 3],
    /// Opacity of the whole billboard (the LOD cross-fade).
    pub opacity: f32,
    /// The quad's axes in the object frame, where the images were taken.
    pub obj_right: [f32; 3],
    pub _pad0: f32,
    pub obj_up: [f32; 3],
    pub _pad1: f32,
    /// Sample indices of the 3 nearest views.
    pub view_index: [u32; 3],
    /// First layer of this object's image set in the texture array.
    pub layer_base: u32,
    /// Sample indices of the 3 nearest lights.
    pub light_index: [u32; 3],
    /// Number of light samples of the bake.
    pub light_count: u32,
    /// View weights (0 = culled).
    pub view_weight: [f32; 3],
    /// Number of view samples of the bake.
    pub view_count: u32,
    /// Light weights (0 = culled).
    pub light_weight: [f32; 3],
    /// The first of the billboard's light-blended images, one per view sample
    /// ([`super::light_blend`]), read instead of its lights' images (scaled by the light
    /// weights' sum); [`NO_LIGHT_BLEND`] for none.
    pub light_blend: u32,
    /// Colour tint of the tree, or the overlay colour.
    pub tint: [f32; 3],
    /// A [`BillboardMode`].
    pub mode: u32,
    /// Box coordinates of the billboard centre in its object's VCM box.
    pub vcm_box_origin: [f32; 3],
    /// The coarser levels' sun factor at the billboard's centre.
    pub parent_direct: f32,
    /// Box coordinates per unit of `p` (radii).
    pub vcm_box_scale: [f32; 3],
    /// The coarser levels' sky factor at the billboard's centre.
    pub parent_sky: f32,
    /// Sun visibility at the object's 8 box corners.
    pub vcm_direct: [[f32; 4]; 2],
    /// Sky visibility at the 8 corners.
    pub vcm_sky: [[f32; 4]; 2],
}

/// [`BillboardGpu::light_blend`] of a billboard that blends its light images itself
/// (`NO_LIGHT_BLEND` in `billboard_record.wgsl`).
pub const NO_LIGHT_BLEND: u32 = u32::MAX;

/// A billboard with every field zero and no VCM shading (all factors 1).
const NO_SHADE: BillboardGpu = BillboardGpu {
    center: [0.0; 3],
    radius: 0.0,
    plane_right: [0.0; 3],
    planes: 1,
    plane_up: [0.0; 3],
    opacity: 1.0,
    obj_right: [0.0; 3],
    _pad0: 0.0,
    obj_up: [0.0; 3],
    _pad1: 0.0,
    view_index: [0; 3],
    layer_base: 0,
    light_index: [0; 3],
    light_count: 0,
    view_weight: [0.0; 3],
    view_count: 0,
    light_weight: [0.0; 3],
    light_blend: NO_LIGHT_BLEND,
    tint: [0.0; 3],
    mode: BillboardMode::Images as u32,
    vcm_box_origin: [0.5, 0.5, 0.5],
    parent_direct: 1.0,
    vcm_box_scale: [0.0; 3],
    parent_sky: 1.0,
    vcm_direct: [[1.0; 4]; 2],
    vcm_sky: [[1.0; 4]; 2],
};

impl BillboardGpu {
    /// Every field zero and no VCM shading (all factors 1).
    pub const UNSHADED: BillboardGpu = NO_SHADE;

    /// Fills the VCM fields from `shade`, for an object of `bounds` whose billboard frame is
    /// `set`.
    pub(super) fn shade(mut self, shade: &Shade, set: &SetInfo) -> Self {
        let points = set.bounds;
        let ext = (points.max - points.min).max(Vec3::splat(1e-6));
        self.vcm_box_origin = ((set.center - points.min) / ext).to_array();
        self.vcm_box_scale = (Vec3::splat(set.radius) / ext).to_array();
        self.parent_direct = shade.parent_direct;
        self.parent_sky = shade.parent_sky;
        let d = shade.direct;
        let k = shade.sky;
        self.vcm_direct = [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]];
        self.vcm_sky = [[k[0], k[1], k[2], k[3]], [k[4], k[5], k[6], k[7]]];
        self
    }
}

/// Where one image set sits in the texture array, and its billboard frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct SetInfo {
    pub layer_base: u32,
    /// The prototype (species entry) whose set it is.
    pub prototype: u32,
    pub center: Vec3,
    pub radius: f32,
    /// The object's bounds in its own frame (its VCM box).
    pub bounds: Aabb,
}
