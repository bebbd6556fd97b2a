//! A [`DirectionSet`]'s lookup tables as rows of 4 words, for a copy on the GPU.

use glam::Mat3A;

use super::DirectionSet;

impl DirectionSet {
    /// The tables of [`Self::blend`] and [`Self::light_gain`] as rows of 4 words, for a copy
    /// on the GPU: the descent's split matrices (3 rows of float bits each, the levels one
    /// after the other), the finest triangles' barycentric matrices (3 rows each), the
    /// triangles (one row of indices each) and the directions (one row each; `w` unused).
    pub fn gpu_rows(&self) -> DirectionRows {
        let mat = |m: &Mat3A| {
            let t = m.transpose();
            [t.x_axis, t.y_axis, t.z_axis].map(|r| [r.x, r.y, r.z, 0.0].map(f32::to_bits))
        };
        DirectionRows {
            splits: self.splits.iter().flat_map(mat).collect(),
            bary: self.bary.iter().flat_map(mat).collect(),
            triangles: self
                .triangles
                .iter()
                .map(|t| [t[0], t[1], t[2], 0])
                .collect(),
            directions: self
                .directions
                .iter()
                .map(|d| [d.x, d.y, d.z, 0.0].map(f32::to_bits))
                .collect(),
        }
    }
}

/// A [`DirectionSet`]'s tables as rows of 4 words ([`DirectionSet::gpu_rows`]).
#[derive(Clone, Debug, Default)]
pub struct DirectionRows {
    pub splits: Vec<[u32; 4]>,
    pub bary: Vec<[u32; 4]>,
    pub triangles: Vec<[u32; 4]>,
    pub directions: Vec<[u32; 4]>,
}
