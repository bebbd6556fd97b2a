//! Triangle meshes and axis-aligned bounding boxes: the CPU geometry every model part is made
//! of (vertex layout shared with the GPU), plus the small builders the generators use
//! (tapered tubes, triangles facing a given side).

use glam::{Mat3, Mat4, Vec3};

/// One vertex as uploaded to the GPU (`#[repr(C)]`, 48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    /// Position in the part's own frame (metres).
    pub position: [f32; 3],
    /// Unit normal. Flat leaves and needles have their normal on one side; the renderer
    /// flips it for back faces.
    pub normal: [f32; 3],
    /// Linear RGB albedo in 0..1.
    pub color: [f32; 3],
    /// 1.0 for leaves and needles (two-sided, drawn without culling), 0.0 for bark and ground.
    pub foliage: f32,
    /// Texture coordinates of an imported tree's base-colour texture (glTF convention: 0,0
    /// at the image's top left); 0 for procedural parts, which have no texture.
    pub uv: [f32; 2],
}

impl Vertex {
    /// A vertex from glam vectors.
    #[inline]
    pub fn new(position: Vec3, normal: Vec3, color: Vec3, foliage: f32) -> Self {
        Self {
            position: position.to_array(),
            normal: normal.to_array(),
            color: color.to_array(),
            foliage,
            uv: [0.0; 2],
        }
    }
}

/// An indexed triangle list. Triangles are counter-clockwise seen from the side their
/// normals point to.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// The vertices.
    pub vertices: Vec<Vertex>,
    /// Three indices per triangle.
    pub indices: Vec<u32>,
}

impl Mesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Bounds of all vertices ([`Aabb::EMPTY`] for an empty mesh).
    pub fn bounds(&self) -> Aabb {
        self.vertices
            .iter()
            .fold(Aabb::EMPTY, |b, v| b.including(Vec3::from(v.position)))
    }

    /// Exact bounds of the vertices after `transform` (tighter than transforming
    /// [`Mesh::bounds`]).
    pub fn bounds_transformed(&self, transform: Mat4) -> Aabb {
        self.vertices.iter().fold(Aabb::EMPTY, |b, v| {
            b.including(transform.transform_point3(Vec3::from(v.position)))
        })
    }

    /// Appends `other` with `transform` applied to its positions and, through the normal
    /// matrix (inverse transpose), to its normals. A mirroring transform (negative
    /// determinant) also reverses the triangles' winding so that they stay counter-clockwise
    /// seen from their normals' side.
    pub fn append(&mut self, other: &Mesh, transform: Mat4) {
        let linear = Mat3::from_mat4(transform);
        let det = linear.determinant();
        let normal_matrix = if det.abs() > 1e-30 {
            linear.inverse().transpose()
        } else {
            linear
        };
        // Index overflow would need more than 4 billion vertices (160 GB); not reachable with
        // validated parameters.
        let base = self.vertices.len() as u32;
        self.vertices.reserve(other.vertices.len());
        self.vertices.extend(other.vertices.iter().map(|v| {
            Vertex {
                position: transform
                    .transform_point3(Vec3::from(v.position))
                    .to_array(),
                normal: (normal_matrix * Vec3::from(v.normal))
                    .normalize_or_zero()
                    .to_array(),
                color: v.color,
                foliage: v.foliage,
                uv: v.uv,
            }
        }));
        self.indices.reserve(other.indices.len());
        if det < 0.0 {
            for t in other.indices.chunks_exact(3) {
                self.indices
                    .extend_from_slice(&[base + t[0], base + t[2], base + t[1]]);
            }
        } else {
            self.indices.extend(other.indices.iter().map(|i| base + i));
        }
    }

    /// Adds one vertex and returns its index.
    #[inline]
    pub fn push_vertex(&mut self, v: Vertex) -> u32 {
        let i = self.vertices.len() as u32;
        self.vertices.push(v);
        i
    }

    /// Adds the triangle `a b c`, reordered if needed so that it is counter-clockwise seen
    /// from the side `facing` points to (indices must refer to existing vertices; one that
    /// does not counts as the origin).
    pub fn push_triangle_facing(&mut self, a: u32, b: u32, c: u32, facing: Vec3) {
        let p = |i: u32| {
            self.vertices
                .get(i as usize)
                .map_or(Vec3::ZERO, |v| Vec3::from(v.position))
        };
        let n = (p(b) - p(a)).cross(p(c) - p(a));
        if n.dot(facing) < 0.0 {
            self.indices.extend_from_slice(&[a, c, b]);
        } else {
            self.indices.extend_from_slice(&[a, b, c]);
        }
    }

    /// Adds a tapered tube (bark) along the polyline `centres` with one radius per centre
    /// and `sides` sides, open at both ends, smooth normals, counter-clockwise seen from
    /// outside. Ring frames are parallel-transported along the polyline.
    pub fn add_tube(&mut self, centres: &[Vec3], radii: &[f32], sides: u32, color: Vec3) {
        let n = centres.len().min(radii.len());
        if n < 2 || sides < 3 {
            return;
        }
        let tangent = |k: usize| -> Vec3 {
            let a = centres[k.saturating_sub(1)];
            let b = centres[(k + 1).min(n - 1)];
            (b - a).try_normalize().unwrap_or(Vec3::Z)
        };
        // Initial frame: any unit vector perpendicular to the first tangent.
        let t0 = tangent(0);
        let helper = if t0.y.abs() < 0.9 { Vec3::Y } else { Vec3::X };
        let mut u = (helper - t0 * helper.dot(t0)).normalize_or_zero();
        let mut prev_t = t0;
        let base = self.vertices.len() as u32;
        for k in 0..n {
            let t = tangent(k);
            // Parallel transport: remove the component along the new tangent.
            u = (u - t * u.dot(t))
                .try_normalize()
                .unwrap_or_else(|| (prev_t.cross(t)).normalize_or_zero());
            prev_t = t;
            let v = t.cross(u); // (u, v, t) is right-handed: u × v = t
            for s in 0..sides {
                let a = std::f32::consts::TAU * s as f32 / sides as f32;
                let dir = u * a.cos() + v * a.sin();
                self.vertices
                    .push(Vertex::new(centres[k] + dir * radii[k], dir, color, 0.0));
            }
        }
        for k in 0..(n as u32 - 1) {
            for s in 0..sides {
                let s1 = (s + 1) % sides;
                let i0 = base + k * sides + s;
                let i1 = base + k * sides + s1;
                let i2 = base + (k + 1) * sides + s;
                let i3 = base + (k + 1) * sides + s1;
                self.indices.extend_from_slice(&[i0, i1, i2, i1, i3, i2]);
            }
        }
    }
}

/// An axis-aligned bounding box. [`Aabb::EMPTY`] (min = +inf, max = -inf) is the identity
/// of [`Aabb::union`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box: contains nothing, `union` with it is a no-op.
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// A box from two corners (component-wise min and max are taken).
    pub fn new(a: Vec3, b: Vec3) -> Aabb {
        Aabb {
            min: a.min(b),
            max: a.max(b),
        }
    }

    /// The smallest box containing all `points` ([`Aabb::EMPTY`] if there are none).
    pub fn from_points(points: impl IntoIterator<Item = Vec3>) -> Aabb {
        points.into_iter().fold(Aabb::EMPTY, Aabb::including)
    }

    /// This box grown to contain `p`.
    #[inline]
    pub fn including(self, p: Vec3) -> Aabb {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// The smallest box containing both.
    #[inline]
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// True when the box contains no point (any min component greater than max).
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// The 8 corners; bit 0 of the index selects max x, bit 1 max y, bit 2 max z.
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }

    /// The box around the 8 corners after `m` (empty stays empty).
    pub fn transformed(&self, m: Mat4) -> Aabb {
        if self.is_empty() {
            return Aabb::EMPTY;
        }
        Aabb::from_points(self.corners().into_iter().map(|c| m.transform_point3(c)))
    }

    /// Centre point (zero for an empty box).
    pub fn center(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            (self.min + self.max) * 0.5
        }
    }

    /// Full size along each axis, `max - min` (zero for an empty box).
    pub fn extent(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    /// True when `p` is inside or on the boundary.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn triangle() -> Mesh {
        let mut m = Mesh::default();
        for p in [Vec3::ZERO, Vec3::X, Vec3::Y] {
            m.push_vertex(Vertex::new(p, Vec3::Z, Vec3::ONE, 0.0));
        }
        m.indices.extend_from_slice(&[0, 1, 2]);
        m
    }

    fn face_normal(m: &Mesh, t: usize) -> Vec3 {
        let p = |i: u32| Vec3::from(m.vertices[i as usize].position);
        let (a, b, c) = (m.indices[3 * t], m.indices[3 * t + 1], m.indices[3 * t + 2]);
        (p(b) - p(a)).cross(p(c) - p(a))
    }

    #[test]
    fn vertex_layout_is_48_bytes() {
        assert_eq!(std::mem::size_of::<Vertex>(), 48);
        let v = Vertex::new(Vec3::ONE, Vec3::Y, Vec3::ZERO, 1.0);
        assert_eq!(bytemuck::bytes_of(&v).len(), 48);
    }

    #[test]
    fn aabb_basics() {
        assert!(Aabb::EMPTY.is_empty());
        assert_eq!(Aabb::EMPTY.extent(), Vec3::ZERO);
        assert_eq!(Aabb::EMPTY.center(), Vec3::ZERO);
        let a = Aabb::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(-1.0, 0.0, 5.0));
        assert_eq!(a.min, Vec3::new(-1.0, 0.0, 3.0));
        assert_eq!(a.max, Vec3::new(1.0, 2.0, 5.0));
        assert_eq!(Aabb::EMPTY.union(a), a);
        assert_eq!(a.union(Aabb::EMPTY), a);
        assert_eq!(a.center(), Vec3::new(0.0, 1.0, 4.0));
        assert_eq!(a.extent(), Vec3::new(2.0, 2.0, 2.0));
        let c = a.corners();
        assert_eq!(c[0], a.min);
        assert_eq!(c[7], a.max);
        assert!(c.iter().all(|p| a.contains(*p)));
        assert!(Aabb::EMPTY.transformed(Mat4::IDENTITY).is_empty());
    }

    #[test]
    fn aabb_transformed_contains_rotated_corners() {
        let a = Aabb::new(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.0));
        let m = Mat4::from_rotation_y(0.7) * Mat4::from_translation(Vec3::new(3.0, 0.0, 0.0));
        let t = a.transformed(m);
        for c in a.corners() {
            let p = m.transform_point3(c);
            assert!(p.cmpge(t.min - 1e-5).all() && p.cmple(t.max + 1e-5).all());
        }
        let r90 = Aabb::new(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.0))
            .transformed(Mat4::from_rotation_y(std::f32::consts::FRAC_PI_2));
        assert!(
            (r90.extent() - Vec3::new(1.0, 1.0, 2.0))
                .abs()
                .max_element()
                < 1e-5
        );
    }

    #[test]
    fn append_transforms_positions_and_normals() {
        let tri = triangle();
        let mut m = Mesh::default();
        m.append(&tri, Mat4::IDENTITY);
        // Non-uniform scale: the normal must follow the inverse transpose.
        let s = Mat4::from_translation(Vec3::new(0.0, 0.0, 5.0))
            * Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2)
            * Mat4::from_scale(Vec3::new(2.0, 3.0, 4.0));
        m.append(&tri, s);
        assert_eq!(m.vertices.len(), 6);
        assert_eq!(m.indices, vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(m.triangle_count(), 2);
        let v = m.vertices[4];
        assert!((Vec3::from(v.position) - Vec3::new(2.0, 0.0, 5.0)).length() < 1e-5);
        // +Z rotated by -90° about X points to +Y.
        let n = Vec3::from(m.vertices[3].normal);
        assert!((n - Vec3::Y).length() < 1e-5, "{n}");
        assert!(face_normal(&m, 1).normalize_or_zero().dot(n) > 0.99);
        let b = m.bounds();
        assert!(
            (b.min - Vec3::new(0.0, 0.0, 0.0)).abs().max_element() < 1e-5,
            "{b:?}"
        );
        assert!(
            (b.max - Vec3::new(2.0, 1.0, 5.0)).abs().max_element() < 1e-5,
            "{b:?}"
        );
        assert_eq!(m.bounds_transformed(Mat4::IDENTITY), b);
    }

    #[test]
    fn append_mirror_keeps_winding_consistent() {
        let tri = triangle();
        let mut m = Mesh::default();
        m.append(&tri, Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0)));
        let n = Vec3::from(m.vertices[0].normal);
        assert!(face_normal(&m, 0).dot(n) > 0.0);
    }

    #[test]
    fn tube_faces_outwards() {
        let mut m = Mesh::default();
        let centres = [
            Vec3::ZERO,
            Vec3::new(0.0, 1.0, 0.2),
            Vec3::new(0.5, 2.0, 0.5),
            Vec3::new(0.5, 3.0, 0.5),
        ];
        m.add_tube(&centres, &[0.3, 0.25, 0.2, 0.1], 6, Vec3::splat(0.1));
        assert_eq!(m.vertices.len(), 24);
        assert_eq!(m.triangle_count(), 36);
        for t in 0..m.triangle_count() {
            let fnrm = face_normal(&m, t);
            let vn: Vec3 = (0..3)
                .map(|k| Vec3::from(m.vertices[m.indices[3 * t + k] as usize].normal))
                .sum();
            assert!(fnrm.dot(vn) > 0.0, "triangle {t} faces inwards");
        }
        for v in &m.vertices {
            assert!((Vec3::from(v.normal).length() - 1.0).abs() < 1e-4);
        }
    }

    #[test]
    fn triangle_facing_orders_winding() {
        let mut m = triangle();
        m.indices.clear();
        m.push_triangle_facing(0, 1, 2, -Vec3::Z);
        assert!(face_normal(&m, 0).z < 0.0);
        m.push_triangle_facing(0, 1, 2, Vec3::Z);
        assert!(face_normal(&m, 1).z > 0.0);
    }
}
