//! Slices parallel to the screen drawn as polygons (`--texel-mode polygons`), the way
//! Decaudin-Neyret draw volumetric billboards: each texel's box cut by the planes of
//! constant view depth that `fs_texel`'s ray march samples, each cut a convex polygon
//! (3 to 6 corners) drawn back to front, its fragments sampling the 3D texture once and
//! blending over what is behind. The same slices and the same samples as the ray march,
//! traded for one blended polygon per slice instead of one loop per pixel: kept to measure
//! which is faster (the bench's `texel_mode` knob).

use glam::{Mat4, Vec3};

use crate::render::pipelines::{storage_buffer_of, storage_entry, write_growing};

/// One polygon vertex as `texel.wgsl` reads it (`struct PolyVertex`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PolyVertex {
    pub position: [f32; 3],
    /// The texel record the slice belongs to.
    pub texel: u32,
}

/// The 12 edges of a box, as pairs of corner indices (bit 0 x, bit 1 y, bit 2 z).
const EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// The box from `box_min` to `box_min + box_size` (object frame, placed by `model`) cut by
/// the planes of view depth k·`spacing` (depth measured from `eye` along `forward`) that
/// cross it, back to front, each as a convex polygon in order around its centre (at most
/// `max` of them, the farthest dropped first).
pub fn slice_polygons(
    model: &Mat4,
    box_min: Vec3,
    box_size: Vec3,
    eye: Vec3,
    forward: Vec3,
    spacing: f32,
    max: usize,
) -> Vec<Vec<Vec3>> {
    if !(spacing > 0.0 && spacing.is_finite()) {
        return Vec::new();
    }
    let corners: [Vec3; 8] = std::array::from_fn(|i| {
        let c = Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32);
        model.transform_point3(box_min + c * box_size)
    });
    let depth: [f32; 8] = corners.map(|c| (c - eye).dot(forward));
    let (near, far) = depth
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &d| {
            (a.min(d), b.max(d))
        });
    let first = (near.max(0.0) / spacing).floor() as i64 + 1;
    let last = (far / spacing).ceil() as i64 - 1;
    if last < first {
        return Vec::new();
    }
    // A basis of the slice planes, to order each polygon's corners by angle.
    let side = forward.any_orthonormal_vector();
    let up = forward.cross(side);
    let mut out = Vec::new();
    // Near to far (so that the cap drops the farthest), reversed at the end.
    let mut k = first;
    while k <= last && out.len() < max {
        let d = k as f32 * spacing;
        let mut points: Vec<Vec3> = EDGES
            .iter()
            .filter_map(|&(a, b)| {
                let (da, db) = (depth[a] - d, depth[b] - d);
                if (da > 0.0) == (db > 0.0) || da == db {
                    return None;
                }
                let t = da / (da - db);
                Some(corners[a] + (corners[b] - corners[a]) * t)
            })
            .collect();
        if points.len() >= 3 {
            let centre = points.iter().copied().sum::<Vec3>() / points.len() as f32;
            points.sort_by(|p, q| {
                let a = (*p - centre).dot(up).atan2((*p - centre).dot(side));
                let b = (*q - centre).dot(up).atan2((*q - centre).dot(side));
                a.total_cmp(&b)
            });
            points.dedup_by(|a, b| (*a - *b).length_squared() < 1e-12);
            if points.len() >= 3 {
                out.push(points);
            }
        }
        k += 1;
    }
    out.reverse();
    out
}

/// `polygons` of texel `texel` as triangles (fans).
pub fn triangles(polygons: &[Vec<Vec3>], texel: u32, out: &mut Vec<PolyVertex>) {
    for p in polygons {
        for i in 1..p.len().saturating_sub(1) {
            for v in [p[0], p[i], p[i + 1]] {
                out.push(PolyVertex {
                    position: v.to_array(),
                    texel,
                });
            }
        }
    }
}

/// Slices drawn as triangles, both faces.
const POLYGONS: super::OverStyle = super::OverStyle {
    label: "texel.wgsl polygons",
    entry_points: ("vs_poly", "fs_poly"),
    cull: None,
    draw: super::OverDraw::Vertices,
};

/// The polygons' vertex buffer, its bind group (the texel records, volumes and sampler
/// beside it) and pipelines.
pub struct PolyAssets {
    pub(super) pass: super::OverPass,
    vertices: wgpu::Buffer,
}

impl PolyAssets {
    pub fn new(ctx: &crate::render::GpuContext) -> Self {
        let [records, volumes, sampler] = super::texel_layout_entries();
        let pass = super::OverPass::new(
            &ctx.device,
            "texel polygons",
            &[
                records,
                volumes,
                sampler,
                storage_entry(8, wgpu::ShaderStages::VERTEX_FRAGMENT),
            ],
            &POLYGONS,
        );
        Self {
            pass,
            vertices: storage_buffer_of::<PolyVertex>(&ctx.device, "texel polygons", 1024),
        }
    }

    /// Uploads the frame's polygon vertices and binds them with the texel `records`, the
    /// volumes' `view` and `sampler`.
    pub fn upload(
        &mut self,
        ctx: &crate::render::GpuContext,
        vertices: &[PolyVertex],
        records: &wgpu::Buffer,
        view: &wgpu::TextureView,
        sampler: &wgpu::Sampler,
    ) {
        write_growing(ctx, &mut self.vertices, "texel polygons", vertices);
        let [records, volumes, sampler] = super::texel_entries(records, view, sampler);
        self.pass.bind(
            &ctx.device,
            "texel polygons",
            &[
                records,
                volumes,
                sampler,
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: self.vertices.as_entire_binding(),
                },
            ],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_seen_along_an_axis_is_cut_into_squares_back_to_front() {
        // A 2 m cube from (0,0,10) to (2,2,12), the eye at the origin looking down +z,
        // slices every 0.5 m: planes at 10.5, 11 and 11.5 cross it.
        let polys = slice_polygons(
            &Mat4::IDENTITY,
            Vec3::new(0.0, 0.0, 10.0),
            Vec3::splat(2.0),
            Vec3::ZERO,
            Vec3::Z,
            0.5,
            100,
        );
        assert_eq!(polys.len(), 3);
        let depths: Vec<f32> = polys.iter().map(|p| p[0].z).collect();
        assert_eq!(depths, vec![11.5, 11.0, 10.5], "back to front");
        for p in &polys {
            assert_eq!(p.len(), 4);
            let area: f32 = (1..p.len() - 1)
                .map(|i| (p[i] - p[0]).cross(p[i + 1] - p[0]).length() / 2.0)
                .sum();
            assert!((area - 4.0).abs() < 1e-4, "{area}");
        }
        let mut tris = Vec::new();
        triangles(&polys, 7, &mut tris);
        assert_eq!(tris.len(), 3 * 2 * 3);
        assert!(tris.iter().all(|v| v.texel == 7));
        assert_eq!(
            slice_polygons(
                &Mat4::IDENTITY,
                Vec3::ZERO,
                Vec3::ONE,
                Vec3::ZERO,
                Vec3::Z,
                0.0,
                9
            ),
            Vec::<Vec<Vec3>>::new()
        );
    }

    #[test]
    fn a_box_seen_along_its_diagonal_gives_triangles_and_hexagons() {
        let eye = Vec3::splat(-10.0);
        let forward = Vec3::ONE.normalize();
        // The unit box cut every 0.05 along the diagonal, at most `cap` slices.
        let cut = |cap| {
            slice_polygons(
                &Mat4::IDENTITY,
                Vec3::ZERO,
                Vec3::ONE,
                eye,
                forward,
                0.05,
                cap,
            )
        };
        let polys = cut(1000);
        let sizes: Vec<usize> = polys.iter().map(|p| p.len()).collect();
        assert!(sizes.contains(&3) && sizes.contains(&6), "{sizes:?}");
        for p in &polys {
            let d = (p[0] - eye).dot(forward);
            for v in p {
                assert!(((*v - eye).dot(forward) - d).abs() < 1e-3, "on one plane");
                assert!(v.cmpge(Vec3::splat(-1e-4)).all() && v.cmple(Vec3::splat(1.0001)).all());
            }
        }
        // The cap keeps the nearest slices.
        let capped = cut(5);
        assert_eq!(capped.len(), 5);
        assert_eq!(capped[4], polys[polys.len() - 1]);
    }
}
