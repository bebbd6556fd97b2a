//! The terrain's maps of colours, normals and heights: one texel per grid point, that the
//! terrain's coarse levels are shaded from (`shaders/geometry.wgsl`, `textured`). A coarse
//! chunk's vertices skip grid points; interpolated over the full grid's triangles
//! (`terrain_texels` in `shaders/instancing.wgsl`), the maps give each of its fragments the
//! point, colour and normal the full-detail mesh has there.

use crate::model::mesh::Mesh;
use crate::model::terrain::Terrain;

use super::GpuContext;
use super::pipelines;

/// The two maps on the GPU, and where the world falls in them.
pub struct TerrainMaps {
    /// Linear colours (16-bit floats).
    pub color: wgpu::TextureView,
    /// Unit normals and heights (m) (16-bit floats).
    pub normal: wgpu::TextureView,
    /// A world point's grid coordinates are (xz + x) * y (`PartSet::terrain_map` in
    /// `shaders/instancing.wgsl`).
    pub placement: [f32; 4],
    /// Bytes of both maps.
    pub bytes: u64,
}

/// The maps' texels, RGBA 16-bit floats as their bits: linear colours, and normals with the
/// height in alpha, of the grid points of `mesh`, whose first `resolution`² vertices are
/// `terrain`'s grid ([`Terrain::mesh`]).
pub fn texels(terrain: &Terrain, mesh: &Mesh) -> Option<(Vec<u16>, Vec<u16>)> {
    let res = terrain.resolution.max(2);
    let grid = mesh.vertices.get(..(res as usize).pow(2))?;
    let mut color = Vec::with_capacity(grid.len() * 4);
    let mut normal = Vec::with_capacity(grid.len() * 4);
    for v in grid {
        color.extend(v.color.iter().map(|&c| half::f16::from_f32(c).to_bits()));
        color.push(half::f16::ONE.to_bits());
        normal.extend(v.normal.iter().map(|&n| half::f16::from_f32(n).to_bits()));
        normal.push(half::f16::from_f32(v.position[1]).to_bits());
    }
    Some((color, normal))
}

/// Where a world point falls in maps of `terrain`'s grid: grid coordinates
/// (xz + x) * y, grid point (i, j) being at x = -size/2 + i * cell.
pub fn placement(terrain: &Terrain) -> [f32; 4] {
    [0.5 * terrain.size, 1.0 / terrain.cell_size(), 0.0, 0.0]
}

impl TerrainMaps {
    /// The maps of `terrain`, whose grid is the first vertices of `mesh`; None where the
    /// mesh is shorter than the grid.
    pub fn new(ctx: &GpuContext, terrain: &Terrain, mesh: &Mesh) -> Option<Self> {
        let (color, normal) = texels(terrain, mesh)?;
        let res = terrain.resolution.max(2);
        let size = glam::UVec3::new(res, res, 1);
        let upload = |label: &str, data: &[u8]| {
            let texture = pipelines::texture(
                &ctx.device,
                label,
                wgpu::TextureDimension::D2,
                size,
                1,
                wgpu::TextureFormat::Rgba16Float,
                wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            );
            pipelines::write_texels(&ctx.queue, &texture, 0, glam::UVec3::ZERO, data, size, 8);
            texture.create_view(&wgpu::TextureViewDescriptor::default())
        };
        let normal: &[u8] = bytemuck::cast_slice(&normal);
        let color: &[u8] = bytemuck::cast_slice(&color);
        Some(Self {
            color: upload("terrain colours", color),
            normal: upload("terrain normals", normal),
            placement: placement(terrain),
            bytes: (color.len() + normal.len()) as u64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_point_falls_on_its_texel() {
        let t = Terrain {
            size: 100.0,
            resolution: 11,
            heights: vec![0.0; 121],
            far: None,
        };
        let p = placement(&t);
        let g = |x: f32| (x + p[0]) * p[1];
        // Grid point 0 at -50 m, point 10 at +50 m, 10 m apart.
        assert!(g(-50.0).abs() < 1e-5);
        assert!((g(50.0) - 10.0).abs() < 1e-5);
        assert!((g(-35.0) - 1.5).abs() < 1e-5);
    }

    #[test]
    fn the_maps_hold_the_grid() {
        let t = Terrain {
            size: 30.0,
            resolution: 4,
            heights: (0..16).map(|i| (i % 4) as f32 * 3.0).collect(),
            far: None,
        };
        let mesh = t.mesh();
        let (color, normal) = texels(&t, &mesh).unwrap();
        assert_eq!((color.len(), normal.len()), (64, 64));
        // Texel (1, 2) is grid vertex 2 * 4 + 1.
        let v = &mesh.vertices[9];
        let i = 9 * 4;
        for k in 0..3 {
            let n = half::f16::from_bits(normal[i + k]).to_f32();
            assert!((n - v.normal[k]).abs() < 0.01, "{n} {:?}", v.normal);
            let c = half::f16::from_bits(color[i + k]).to_f32();
            assert!((c - v.color[k]).abs() < 1e-3, "{c} {:?}", v.color);
        }
        assert_eq!(half::f16::from_bits(normal[i + 3]).to_f32(), v.position[1]);
        // A slope rising along x: the normal leans towards -x.
        assert!(half::f16::from_bits(normal[i]).to_f32() < -0.1);
        assert!(texels(&t, &Mesh::default()).is_none());
    }
}
